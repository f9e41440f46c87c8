//! What the run-level commands share: loading a job, the mode and wait asked for, the output
//! folder and its JSON files.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use serde_json::Value;

use feedloop_model::job::{Job, Mode, WaitKind};

use feedloop_plant::Plant;
use feedloop_plugins::Builtins;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_trace::export::human_summary;

/// A job with everything built from it validated.
pub(super) struct Loaded {
    pub(super) job: Job,
    pub(super) cycle: ControlCycle,
    pub(super) plant: Plant,
}

pub(super) fn load(job_path: &Path) -> Result<Loaded> {
    let job = Job::load(job_path)?;
    let cycle = ControlCycle::new(&job, &Builtins)?;
    let mut plant = Plant::new(&job)?;
    plant.set_initial_positions(&cycle.initial_positions());
    Ok(Loaded { job, cycle, plant })
}

pub(super) fn mode_of(job: &Job, mode: Option<String>) -> Result<Mode> {
    match mode {
        None => Ok(job.run.mode),
        Some(m) => {
            Mode::parse(&m).ok_or_else(|| anyhow!("--mode `{m}`: expected realtime or lockstep"))
        }
    }
}

pub(super) fn wait_of(job: &Job, wait: Option<String>) -> Result<WaitKind> {
    match wait {
        None => Ok(job.run.wait),
        Some(w) => WaitKind::parse(&w)
            .ok_or_else(|| anyhow!("--wait `{w}`: expected busy, block or hybrid")),
    }
}

/// Writes pretty JSON.
pub fn write_json(path: &Path, v: &Value) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(v)? + "\n")
        .with_context(|| format!("writing {}", path.display()))
}

pub(super) fn create_dir(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating output folder {}", out.display()))
}

/// Writes `summary.json` into `out` and prints it (pure JSON with `json_only`, else the human
/// summary and the files written).
pub(super) fn write_summary(out: &Path, v: &Value, json_only: bool) -> Result<()> {
    write_json(&out.join("summary.json"), v)?;
    if json_only {
        println!("{}", serde_json::to_string_pretty(v)?);
    } else {
        print!("{}", human_summary(v));
        println!(
            "  wrote {} and {}",
            out.join("trace.csv").display(),
            out.join("summary.json").display()
        );
    }
    Ok(())
}

/// Reads a JSON file, if it is there and parses.
pub fn read_json(path: &Path) -> Option<Value> {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
}
