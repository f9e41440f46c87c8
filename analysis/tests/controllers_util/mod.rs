//! Shared helpers of the controller experiments: run a job given as text, collect its records.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use feedloop_analysis::sim::Simulation;
use feedloop_model::job::Job;
use feedloop_plugins::Builtins;
use feedloop_runtime::shared::wire::MAX_AXES;
use feedloop_trace::log::AxisRecord;

static NEXT: AtomicUsize = AtomicUsize::new(0);

/// The repository's `examples/` folder.
pub fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

/// A fresh temporary folder.
pub fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "feedloop-{tag}-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::SeqCst)
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Writes `text` as a job file in a fresh temp folder (with `{examples}` replaced by the
/// examples folder) and loads it.
pub fn job_from_text(tag: &str, text: &str) -> Job {
    let dir = temp_dir(tag);
    write_job(&dir, "job.toml", text)
}

/// Writes `text` as `dir/name` (with `{examples}` replaced) and loads it.
pub fn write_job(dir: &Path, name: &str, text: &str) -> Job {
    let text = text.replace("{examples}", &examples().display().to_string());
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    Job::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

/// Runs `job` in process; returns records per axis (`[axis][cycle]`, load units).
pub fn run(job: &Job) -> Vec<Vec<AxisRecord>> {
    try_run(job).unwrap_or_else(|e| panic!("{e}"))
}

/// Runs `job`, reporting configuration errors.
pub fn try_run(job: &Job) -> Result<Vec<Vec<AxisRecord>>, String> {
    let mut sim = Simulation::new(job, &Builtins).map_err(|e| e.to_string())?;
    let n = job.axes.len();
    let cycles = sim.cycles() as usize;
    let mut out = vec![Vec::with_capacity(cycles); n];
    let mut rows = [AxisRecord::default(); MAX_AXES];
    for _ in 0..cycles {
        sim.step(&mut rows[..n]);
        for (o, r) in out.iter_mut().zip(&rows[..n]) {
            o.push(*r);
        }
    }
    Ok(out)
}

/// Largest |cmd - load| of one axis' records.
pub fn max_following_error(rec: &[AxisRecord]) -> f64 {
    rec.iter()
        .map(|r| (r.cmd - r.load).abs())
        .fold(0.0, f64::max)
}
