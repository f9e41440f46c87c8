//! Shared helpers of the analysis tests (the controller experiments and the identification
//! tests): temp folders, model and job texts, run a job given as text, collect its records.
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

/// A fresh temporary folder, removed when the returned guard is dropped (kept when the test
/// fails, for a look).
pub fn temp_dir(tag: &str) -> feedloop_test_support::Scratch {
    feedloop_test_support::Scratch::new(tag, &NEXT.fetch_add(1, Ordering::SeqCst).to_string())
}

/// The brief's ball-screw X axis as a model file text: the plant and controller of
/// `examples/models/xy-x.toml` (JM 2e-3, JL 3e-3 kg m^2, KL 3000 N m/rad, 10 mm lead, Kp 50,
/// Kv 5, Tv 5 ms) without the torque limit; `tail` follows the `[controller]` keys (the torque
/// limit, more tables).
pub fn xy_x_model(tail: &str) -> String {
    format!(
        r#"
kind = "ballscrew"
jm_kgm2 = 2.0e-3
dm_nms_per_rad = 1.0e-3
kl_nm_per_rad = 3000.0
cl_nms_per_rad = 0.02
jl_kgm2 = 3.0e-3
dl_nms_per_rad = 2.0e-3
lead_m = 0.01
[controller]
kp_per_s = 50.0
kv_nms_per_rad = 5.0
tv_s = 0.005
{tail}"#
    )
}

/// The `[[chain]]` entries of a position/feedforward/velocity cascade on `axis`: `position_p`,
/// `inverse_feedforward` (with `ff_params` as its params when given) and `pi_velocity`.
pub fn ff_chain(axis: &str, ff_params: Option<&str>) -> String {
    let params = ff_params
        .map(|p| format!("params = {{ {p} }}\n"))
        .unwrap_or_default();
    format!(
        "[[chain]]\naxis = \"{axis}\"\nstage = \"position\"\nplugin = \"position_p\"\n\
         [[chain]]\naxis = \"{axis}\"\nstage = \"feedforward\"\nplugin = \"inverse_feedforward\"\n{params}\
         [[chain]]\naxis = \"{axis}\"\nstage = \"velocity\"\nplugin = \"pi_velocity\"\n"
    )
}

/// Writes `text` as a job file in a fresh temp folder (with `{examples}` replaced by the
/// examples folder) and loads it.
pub fn job_from_text(tag: &str, text: &str) -> Job {
    // the job is read whole on loading: its folder goes with the guard
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
