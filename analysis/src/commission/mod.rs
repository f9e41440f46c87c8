//! One-command commissioning of a ball-screw axis: measure the axis first (friction, noise,
//! lost motion, total inertia), choose the excitation from what was found, identify the
//! stiffness and the load inertia (two-mass fit, checked by simulation matching), tune the
//! P/PI cascade with its margins, set the inverse-model and friction feedforwards, and verify
//! on a circle before and after. The axis is seen only through a [`device::Device`].
//!
//! Files by job: `device` (the axis behind its experiments), `facts` (data-sheet facts and the
//! jobs experiments are written as), `friction` (traverses and inertia moves), `excitation`
//! (the choice of the excitation and the two-mass fit with its repeats), `tuning` (gains,
//! margins, feedforwards, the inertia check), `verify` (the circle and the quadrant learning),
//! `report` (the output files).

pub mod device;
pub mod excitation;
pub mod facts;
pub mod friction;
pub mod inertia_check;
pub mod model_out;
pub mod report;
pub mod tuning;
pub mod verify;

use serde::Serialize;

use device::{Device, Recording};
use facts::Facts;

/// One experiment as the report tells it.
#[derive(Debug, Clone, Serialize)]
pub struct ExperimentNote {
    /// Name.
    pub name: String,
    /// Machine time, s.
    pub length_s: f64,
    /// Why it was run, and why with this length and amplitude.
    pub why: String,
    /// Why it was stopped early, if it was.
    pub stopped: Option<String>,
}

/// The experiments run so far, with a callback told each one's name and running machine time.
pub struct Notes<'a> {
    /// The experiments in order.
    pub list: Vec<ExperimentNote>,
    /// What did not go as planned, in words.
    pub warnings: Vec<String>,
    progress: &'a mut dyn FnMut(&str, f64),
}

impl<'a> Notes<'a> {
    /// Empty, reporting to `progress`.
    pub fn new(progress: &'a mut dyn FnMut(&str, f64)) -> Self {
        Self {
            list: Vec::new(),
            warnings: Vec::new(),
            progress,
        }
    }

    /// Notes one experiment.
    pub fn push(&mut self, name: &str, rec: &Recording, why: &str) {
        self.list.push(ExperimentNote {
            name: name.into(),
            length_s: rec.machine_s(),
            why: why.into(),
            stopped: rec.stopped.clone(),
        });
        let total = self.machine_s();
        (self.progress)(name, total);
    }

    /// Notes a warning.
    pub fn warn(&mut self, w: String) {
        self.warnings.push(w);
    }

    /// Machine time of all experiments, s.
    pub fn machine_s(&self) -> f64 {
        self.list.iter().map(|e| e.length_s).sum()
    }
}

/// Everything the procedure found and chose.
#[derive(Debug, Clone, Serialize)]
pub struct Commissioning {
    /// The data-sheet facts used.
    pub facts: Facts,
    /// Traverses and inertia moves.
    pub survey: friction::Survey,
    /// Stiffness and load inertia.
    pub identified: excitation::Identified,
    /// Gains, margins, feedforwards and the inertia check.
    pub tuned: tuning::Tuned,
    /// The circle before and after.
    pub verification: verify::Verification,
    /// Experiments in order.
    pub experiments: Vec<ExperimentNote>,
    /// What did not go as planned.
    pub warnings: Vec<String>,
    /// Machine time of all experiments, s.
    pub machine_s: f64,
}

/// Runs the whole procedure on `axis` of `dev`, tuning to the `asked` margins (deg, dB);
/// the identified model and the quadrant table are written into `dir`.
pub fn commission(
    dev: &mut dyn Device,
    facts: &Facts,
    axis: &str,
    asked: (f64, f64),
    dir: &std::path::Path,
    progress: &mut dyn FnMut(&str, f64),
) -> Result<Commissioning, String> {
    let mut notes = Notes::new(progress);
    let survey = friction::survey(dev, facts, axis, &mut notes)?;
    let identified = excitation::identify(dev, facts, axis, &survey, &mut notes)?;
    let tuned = tuning::tune(dev, facts, axis, &survey, &identified, asked, &mut notes)?;
    let model = dir.join("model.toml");
    let text = model_out::model_text(facts, &survey, &identified, tuned.jl_kgm2, tuned.gains);
    std::fs::write(&model, text).map_err(|e| format!("{}: {e}", model.display()))?;
    let verification = verify::verify(
        dev,
        facts,
        axis,
        &survey,
        &identified,
        &tuned,
        dir,
        &mut notes,
    )?;
    let machine_s = notes.machine_s();
    Ok(Commissioning {
        facts: facts.clone(),
        survey,
        identified,
        tuned,
        verification,
        experiments: notes.list,
        warnings: notes.warnings,
        machine_s,
    })
}
