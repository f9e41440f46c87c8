//! The axis the procedure commissions, seen only through the experiments it runs: a [`Device`]
//! plays an experiment (a controller chain and a trajectory) and returns what was measured.
//! [`SimDevice`] plays a model file as the opaque plant, with its effects, sensor and noise,
//! through the same plant and controller code as `feedloop sim`; a drive bridge can take its place
//! without a change to the procedure.

use std::path::{Path, PathBuf};

use feedloop_model::job::Job;
use feedloop_model::model::ModelFile;
use feedloop_plugins::Builtins;
use feedloop_trace::log::AxisRecord;

use crate::sim::Simulation;

/// Bounds an experiment must stay inside; the device stops it at the first sample outside.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Largest |command - load position|, load units (m).
    pub following_m: f64,
    /// Largest |torque|, N m.
    pub torque_nm: f64,
    /// Largest |command - start|, load units (m).
    pub travel_m: f64,
}

/// One experiment: a job without its plant (`period_s`, `[axes.A]` without `model`, `[[chain]]`
/// with every gain and model key given, `[trajectory]`), and the bounds it must keep.
#[derive(Debug, Clone)]
pub struct Experiment {
    /// Short name (`traverse-4mm/s`, `excitation-1`, ...).
    pub name: String,
    /// The job table.
    pub job: toml::Table,
    /// Safety bounds.
    pub bounds: Bounds,
}

/// What a device measured.
#[derive(Debug, Clone)]
pub struct Recording {
    /// Rows per axis (`[axis][cycle]`, in the job's axis order).
    pub records: Vec<Vec<AxisRecord>>,
    /// Control period, s.
    pub period_s: f64,
    /// Why the experiment was stopped before its end (`None`: it ran to its end).
    pub stopped: Option<String>,
}

impl Recording {
    /// Machine time the experiment took, s.
    pub fn machine_s(&self) -> f64 {
        self.records.first().map_or(0, Vec::len) as f64 * self.period_s
    }
}

/// An axis that runs experiments.
pub trait Device {
    /// Runs `exp` and returns its record, stopped early (with the reason) when a bound is left.
    fn run(&mut self, exp: &Experiment) -> Result<Recording, String>;
}

/// A model file played as the axis: every axis of an experiment is this model.
pub struct SimDevice {
    model: PathBuf,
}

impl SimDevice {
    /// The device of the model file at `model` (checked now).
    pub fn new(model: &Path) -> Result<Self, String> {
        ModelFile::load(model).map_err(|e| e.to_string())?;
        let model = std::path::absolute(model).map_err(|e| format!("{}: {e}", model.display()))?;
        Ok(Self { model })
    }

    /// The job of `exp` on this model (each axis's `model` set to it).
    pub fn job(&self, exp: &Experiment) -> Result<Job, String> {
        let mut t = exp.job.clone();
        if let Some(toml::Value::Table(axes)) = t.get_mut("axes") {
            for (_, a) in axes.iter_mut() {
                if let toml::Value::Table(a) = a {
                    a.insert(
                        "model".into(),
                        toml::Value::String(self.model.display().to_string()),
                    );
                }
            }
        }
        let dir = self.model.parent().unwrap_or(Path::new("."));
        Job::from_table(&t, &dir.join(format!("{}.toml", exp.name))).map_err(|e| e.to_string())
    }
}

impl Device for SimDevice {
    fn run(&mut self, exp: &Experiment) -> Result<Recording, String> {
        let job = self.job(exp)?;
        let mut sim = Simulation::new(&job, &Builtins).map_err(|e| e.to_string())?;
        let n = job.axes.len();
        let cycles = sim.cycles() as usize;
        let mut out = vec![Vec::with_capacity(cycles); n];
        let mut rows = vec![AxisRecord::default(); n];
        let mut start: Option<Vec<f64>> = None;
        let mut stopped = None;
        for k in 0..cycles {
            sim.step(&mut rows);
            let s = start.get_or_insert_with(|| rows.iter().map(|r| r.cmd).collect());
            for (r, s0) in rows.iter().zip(s.iter()) {
                if let Some(why) = outside(r, *s0, &exp.bounds) {
                    stopped = Some(format!(
                        "{} stopped at {:.3} s: {why}",
                        exp.name,
                        k as f64 * job.period_s
                    ));
                }
            }
            for (o, r) in out.iter_mut().zip(&rows) {
                o.push(*r);
            }
            if stopped.is_some() {
                break;
            }
        }
        Ok(Recording {
            records: out,
            period_s: job.period_s,
            stopped,
        })
    }
}

/// Which bound a row leaves, in words.
fn outside(r: &AxisRecord, start: f64, b: &Bounds) -> Option<String> {
    let fe = (r.cmd - r.load).abs();
    if fe > b.following_m {
        return Some(format!(
            "following error {:.3} mm above the bound {:.3} mm",
            fe * 1e3,
            b.following_m * 1e3
        ));
    }
    if r.torque.abs() > b.torque_nm {
        return Some(format!(
            "torque {:.3} N m above the bound {:.3} N m",
            r.torque.abs(),
            b.torque_nm
        ));
    }
    let d = (r.cmd - start).abs();
    (d > b.travel_m).then(|| {
        format!(
            "command {:.2} mm from the start, beyond the travel {:.2} mm",
            d * 1e3,
            b.travel_m * 1e3
        )
    })
}
