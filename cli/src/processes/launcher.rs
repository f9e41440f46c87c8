//! `feedloop run`: starts the plant and the scheduler as two processes, waits for both and
//! merges their logs.

use std::path::Path;
use std::process::{Child, Command, ExitCode};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use serde_json::json;

use feedloop_model::job::{Job, Mode, WaitKind};

use crate::choice::{Choice, ModeArg, WaitArg};

use crate::signals;

use super::common::{create_dir, load, mode_of, wait_of, write_summary, Loaded};
use super::merge::merge;
use super::progress::RunProgress;

fn default_instance() -> String {
    format!("run{}", std::process::id())
}

/// Starts `feedloop <role>` as a child process.
pub fn spawn(
    role: &str,
    instance: &str,
    job: &Path,
    out: &Path,
    mode: Mode,
    wait: WaitKind,
    extra: &[String],
) -> Result<Child> {
    let exe = std::env::current_exe().context("locating the feedloop binary")?;
    let mut cmd = Command::new(exe);
    cmd.arg(role)
        .args(["--instance", instance])
        .arg("--job")
        .arg(job)
        .arg("--out")
        .arg(out)
        .args(["--mode", mode.id(), "--wait", wait.id()]);
    if role == "plant" {
        cmd.arg("--no-export");
    }
    cmd.args(extra);
    // a launcher killed outright must not leave the loop running with nobody in charge
    signals::die_with_parent(&mut cmd);
    cmd.spawn()
        .with_context(|| format!("starting the {role} process"))
}

/// Parses `--pin A,B` (the plant's CPU, the scheduler's CPU).
pub fn parse_pin(pin: &str) -> Result<[usize; 2]> {
    let cpus: Vec<usize> = pin
        .split(',')
        .map(|c| {
            c.trim()
                .parse::<usize>()
                .with_context(|| format!("--pin `{pin}`: expected two CPU numbers like 0,1"))
        })
        .collect::<Result<_>>()?;
    match cpus[..] {
        [a, b] => Ok([a, b]),
        _ => bail!("--pin takes two CPUs (plant,scheduler), got {}", cpus.len()),
    }
}

/// Starts the plant and then the scheduler process (the plant is killed if the scheduler cannot
/// start).
fn spawn_both(
    instance: &str,
    job_path: &Path,
    out: &Path,
    mode: Mode,
    wait: WaitKind,
    cpus: Option<[usize; 2]>,
) -> Result<(Child, Child)> {
    let cpu_args = |i: usize| -> Vec<String> {
        cpus.map(|c| vec!["--cpu".to_string(), c[i].to_string()])
            .unwrap_or_default()
    };
    let mut plant = spawn("plant", instance, job_path, out, mode, wait, &cpu_args(0))?;
    match spawn(
        "scheduler",
        instance,
        job_path,
        out,
        mode,
        wait,
        &cpu_args(1),
    ) {
        Ok(sched) => Ok((plant, sched)),
        Err(e) => {
            let _ = plant.kill();
            let _ = plant.wait();
            Err(e)
        }
    }
}

/// Waits for both processes: the plant, forwarding an operator stop (SIGINT/SIGTERM to us) to
/// it once; then the scheduler, killed if it outlives the peer timeout (+2 s). Reports a
/// process that failed without writing its JSON file.
fn wait_both(
    plant: &mut Child,
    sched: &mut Child,
    job: &Job,
    out: &Path,
    progress: &mut RunProgress,
) -> Result<()> {
    let mut forwarded = false;
    let plant_status = loop {
        if let Some(st) = plant.try_wait().context("waiting for the plant process")? {
            break st;
        }
        progress.tick();
        if !forwarded && signals::STOP.load(std::sync::atomic::Ordering::Relaxed) {
            // SAFETY: sending a signal to our own child by pid.
            unsafe { libc::kill(plant.id() as libc::pid_t, libc::SIGTERM) };
            forwarded = true;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    progress.finish();
    // The scheduler ends on the plant's last sample or notices silence; bound the wait.
    let deadline =
        std::time::Instant::now() + Duration::from_secs_f64(job.run.peer_timeout_s + 2.0);
    let sched_status = loop {
        if let Some(s) = sched.try_wait()? {
            break Some(s);
        }
        if std::time::Instant::now() > deadline {
            let _ = sched.kill();
            let _ = sched.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    if !plant_status.success() && !out.join("plant.json").exists() {
        eprintln!("feedloop: the plant process failed ({plant_status})");
    }
    if let Some(s) = sched_status {
        if !s.success() && !out.join("scheduler.json").exists() {
            eprintln!("feedloop: the scheduler process failed ({s})");
        }
    }
    Ok(())
}

/// `feedloop run` (`quiet`: no live line on standard error).
#[allow(clippy::too_many_arguments)]
pub fn run(
    job_path: &Path,
    out: &Path,
    mode: Option<ModeArg>,
    wait: Option<WaitArg>,
    instance: Option<String>,
    pin: Option<&str>,
    json_only: bool,
    quiet: bool,
) -> Result<ExitCode> {
    let (mode, wait) = (
        mode.map(|m| m.id().to_string()),
        wait.map(|w| w.id().to_string()),
    );
    signals::install();
    // Validate everything before any process starts.
    let cpus = pin.map(parse_pin).transpose()?;
    let Loaded { job, cycle, .. } = load(job_path)?;
    let mode = mode_of(&job, mode)?;
    let wait = wait_of(&job, wait)?;
    let instance = instance.unwrap_or_else(default_instance);
    if !feedloop_model::job::valid_name(&instance, true) {
        bail!("--instance `{instance}`: use lowercase letters, digits, `_` and `-` (at most 64)");
    }
    create_dir(out)?;
    for f in [
        "plant.log",
        "plant.json",
        "scheduler.log",
        "scheduler.json",
        "trace.csv",
        "summary.json",
    ] {
        let _ = std::fs::remove_file(out.join(f));
    }
    let (mut plant, mut sched) = spawn_both(&instance, job_path, out, mode, wait, cpus)?;
    let mut progress = RunProgress::new(
        out,
        cycle.cycles(),
        job.period_s,
        mode == Mode::Realtime,
        !(quiet || json_only),
    );
    wait_both(&mut plant, &mut sched, &job, out, &mut progress)?;
    let (mut v, code) = merge(out, &job)?;
    v["processes"] = json!({"plant_pid": plant.id(), "scheduler_pid": sched.id()});
    write_summary(out, &v, json_only)?;
    Ok(code)
}
