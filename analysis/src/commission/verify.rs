//! The verification: a circle of two axes like the commissioned one (a slow circle, where
//! friction and backlash show most), run with the drive's starting gains and no feedforward,
//! then with the tuned gains, the inverse-model feedforward and the measured friction curve,
//! then with the quadrant compensation learned in two passes (seed 004) over that friction
//! feedforward. Contour error (distance of the table from the circle) and following error of
//! each run.

use std::path::Path;

use feedloop_model::job::Job;
use feedloop_plugins::QuadrantTable;
use feedloop_trace::log::AxisRecord;
use serde::Serialize;

use super::device::{Device, Experiment};
use super::excitation::Identified;
use super::facts::{cascade, experiment, Facts};
use super::friction::Survey;
use super::model_out::{chain, Compensation};
use super::tuning::Tuned;
use super::Notes;
use crate::learn::quadrant::{learn_quadrant, LearnOptions};

/// The contour ratio after commissioning asked for (starting gains without feedforward over the
/// commissioned loop).
pub const TARGET_RATIO: f64 = 20.0;
/// The lead-in left out of the figures: the feed ramp (0.1 s) and 0.2 s more, s.
pub const LEAD_IN_S: f64 = 0.3;
/// Quadrant learning passes.
pub const PASSES: usize = 2;

/// Figures of one circle run.
#[derive(Debug, Clone, Serialize, Default)]
pub struct CircleRun {
    /// Largest contour error, m.
    pub contour_max_m: f64,
    /// Its root mean square, m.
    pub contour_rms_m: f64,
    /// Largest following error (either axis), m.
    pub following_max_m: f64,
    /// Radial error over the angle (rad, m), thinned for the plot.
    #[serde(skip)]
    pub curve: Vec<(f64, f64)>,
}

/// The circle before and after.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Verification {
    /// Circle radius, m.
    pub radius_m: f64,
    /// Feed, m/s.
    pub feed_m_per_s: f64,
    /// Starting gains, no feedforward.
    pub before: CircleRun,
    /// Tuned gains, inverse-model and friction feedforward.
    pub feedforward: CircleRun,
    /// The same with the learned quadrant compensation.
    pub after: CircleRun,
    /// Reversal spike per pass (largest of the two axes), m: pass 0 is before learning.
    pub quadrant_spike_m: Vec<f64>,
    /// Reversal spike ratio after the passes.
    pub quadrant_ratio: f64,
    /// Largest contour error before over after.
    pub contour_ratio: f64,
    /// Whether the ratio reaches [`TARGET_RATIO`].
    pub met: bool,
    /// The quadrant table learned (absolute path).
    pub table: String,
}

/// The circle trajectory: R, feed, one turn, starting at the axes' rest position.
pub fn circle(r: f64, feed: f64) -> toml::Table {
    let mut t = toml::Table::new();
    t.insert("kind".into(), "circle".into());
    t.insert(
        "center_m".into(),
        toml::Value::Array(vec![(-r).into(), 0.0.into()]),
    );
    t.insert("radius_m".into(), r.into());
    t.insert("feed_m_per_s".into(), feed.into());
    t.insert("turns".into(), 1.0.into());
    t.insert("ramp_s".into(), 0.1.into());
    t.insert("dwell_after_s".into(), 0.1.into());
    t
}

/// Runs the three circles and the learning; `dir` holds the identified model and the table.
#[allow(clippy::too_many_arguments)]
pub fn verify(
    dev: &mut dyn Device,
    f: &Facts,
    axis: &str,
    s: &Survey,
    id: &Identified,
    t: &Tuned,
    dir: &Path,
    notes: &mut Notes,
) -> Result<Verification, String> {
    let r = (0.02f64).min(0.4 * f.travel_m);
    let feed = 0.02;
    let twin = format!("{axis}2");
    let axes = [axis, twin.as_str()];
    let traj = circle(r, feed);
    let bounds = f.bounds(0.01);
    let cas = |g| {
        let mut c = cascade(axis, g);
        c.extend(cascade(&twin, g));
        c
    };
    let before_exp = experiment(
        "circle before",
        f,
        &axes,
        cas(f.start),
        traj.clone(),
        bounds,
    );
    let before = measure(
        dev,
        &before_exp,
        r,
        notes,
        "the starting gains without feedforward",
    )?;
    let comp = |q: Option<String>| Compensation {
        inverse: true,
        friction: true,
        quadrant: q,
    };
    let both = |c: &Compensation| {
        let mut v = chain(axis, t.gains, c, f, s, id, t.jl_kgm2);
        v.extend(chain(&twin, t.gains, c, f, s, id, t.jl_kgm2));
        v
    };
    let ff_exp = experiment(
        "circle feedforward",
        f,
        &axes,
        both(&comp(None)),
        traj.clone(),
        bounds,
    );
    let feedforward = measure(
        dev,
        &ff_exp,
        r,
        notes,
        "tuned gains, inverse-model and friction feedforward",
    )?;
    let table = dir.join("quadrant.toml");
    let qexp = experiment(
        "circle quadrant",
        f,
        &axes,
        both(&comp(Some(table.display().to_string()))),
        traj,
        bounds,
    );
    let (spikes, after) = learned(dev, &qexp, &table, dir, r, &feedforward, notes)?;
    let contour_ratio = before.contour_max_m / after.contour_max_m.max(1e-12);
    Ok(Verification {
        radius_m: r,
        feed_m_per_s: feed,
        before,
        feedforward,
        after,
        quadrant_ratio: match (spikes.first(), spikes.last()) {
            (Some(a), Some(b)) => a / b.max(1e-15),
            _ => 1.0,
        },
        quadrant_spike_m: spikes,
        contour_ratio,
        met: contour_ratio >= TARGET_RATIO,
        table: table.display().to_string(),
    })
}

/// Learns the quadrant table of `exp` (its chain names `table`) in [`PASSES`] passes; the
/// largest spike of the two axes per pass.
fn learn(
    dev: &mut dyn Device,
    exp: &Experiment,
    table: &Path,
    dir: &Path,
    notes: &mut Notes,
) -> Result<Vec<f64>, String> {
    // The learner reads the job's structure (axes, chain, trajectory) from the identified model;
    // every run goes to the device.
    let mut jt = exp.job.clone();
    if let Some(toml::Value::Table(axes)) = jt.get_mut("axes") {
        for (_, a) in axes.iter_mut() {
            let mut m = toml::Table::new();
            // relative to the job's own file, which lies in `dir` beside the model
            m.insert("model".into(), "model.toml".into());
            *a = toml::Value::Table(m);
        }
    }
    let job = Job::from_table(&jt, &dir.join("learn.toml")).map_err(|e| e.to_string())?;
    let opts = LearnOptions {
        table: Some(table.to_path_buf()),
        ..LearnOptions::default()
    };
    let mut n = 0;
    let mut run = |_: &Job| -> Result<Vec<Vec<AxisRecord>>, String> {
        n += 1;
        let rec = dev.run(exp)?;
        notes.push(
            &format!("quadrant learning run {n}"),
            &rec,
            "quadrant learning (the quadrant-crossing patent): the reversal error of this pass",
        );
        match rec.stopped {
            Some(why) => Err(why),
            None => Ok(rec.records),
        }
    };
    let report = learn_quadrant(&job, PASSES, &opts, &mut run).map_err(|e| e.to_string())?;
    if std::env::var_os("FEEDLOOP_COMMISSION_DEBUG").is_some() {
        eprintln!("{:?}", report.passes);
    }
    Ok(report
        .passes
        .iter()
        .map(|p| p.axes.iter().map(|a| a.spike).fold(0.0, f64::max))
        .collect())
}

/// Runs one circle and reads its errors.
fn measure(
    dev: &mut dyn Device,
    exp: &Experiment,
    r: f64,
    notes: &mut Notes,
    why: &str,
) -> Result<CircleRun, String> {
    let rec = dev.run(exp)?;
    notes.push(&exp.name.replace('-', " "), &rec, why);
    if let Some(w) = rec.stopped {
        return Err(w);
    }
    let (x, y) = (&rec.records[0], &rec.records[1]);
    let mut run = CircleRun::default();
    let mut sq = 0.0;
    let step = (x.len() / 2000).max(1);
    // From the end of the feed ramp on (the lead-in: the nut leaves the middle of its gap at
    // the first motion, which no reversal compensation sees).
    let skip = (LEAD_IN_S / rec.period_s) as usize;
    for (k, (a, b)) in x.iter().zip(y).enumerate().skip(skip) {
        let (px, py) = (a.load + r, b.load);
        let e = px.hypot(py) - r;
        run.contour_max_m = run.contour_max_m.max(e.abs());
        sq += e * e;
        run.following_max_m = run
            .following_max_m
            .max((a.cmd - a.load).abs())
            .max((b.cmd - b.load).abs());
        if k % step == 0 {
            run.curve.push((py.atan2(px), e));
        }
    }
    run.contour_rms_m = (sq / x.len().saturating_sub(skip).max(1) as f64).sqrt();
    Ok(run)
}

/// Learns the quadrant table and runs the circle with it; without it (the learning stopped) the
/// feedforward's run stands, with a warning.
fn learned(
    dev: &mut dyn Device,
    qexp: &Experiment,
    table: &Path,
    dir: &Path,
    r: f64,
    feedforward: &CircleRun,
    notes: &mut Notes,
) -> Result<(Vec<f64>, CircleRun), String> {
    QuadrantTable::default()
        .save(table)
        .map_err(|e| format!("{}: {e}", table.display()))?;
    match learn(dev, qexp, table, dir, notes) {
        Ok(spikes) => {
            let why = "the commissioned loop: the learned pulses over the friction feedforward";
            Ok((spikes, measure(dev, qexp, r, notes, why)?))
        }
        Err(e) => {
            notes.warn(format!(
                "the quadrant learning was stopped ({e}); the loop is commissioned without it"
            ));
            QuadrantTable::default()
                .save(table)
                .map_err(|e| format!("{}: {e}", table.display()))?;
            Ok((vec![], feedforward.clone()))
        }
    }
}
