//! What the plant and the scheduler process share: their options and their start (signals, the
//! job, real-time settings).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use serde_json::Value;

use feedloop_model::job::{Mode, WaitKind};

use crate::choice::{Choice, ModeArg, WaitArg};

use crate::signals;

use super::common::{create_dir, load, mode_of, wait_of, Loaded};

/// Options shared by the `plant` and `scheduler` processes.
#[derive(clap::Args, Debug, Clone)]
pub struct ProcArgs {
    /// Instance name (both processes of one loop use the same).
    #[arg(long)]
    pub instance: String,
    /// Job file.
    #[arg(long)]
    pub job: PathBuf,
    /// Output folder for this process' log and report.
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
    /// How the processes keep time (default: the job's).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// How a process waits for the next message (default: the job's).
    #[arg(long, value_enum)]
    pub wait: Option<WaitArg>,
    /// Run this many cycles instead of the job's duration.
    #[arg(long)]
    pub cycles: Option<u64>,
    /// Pin this process to a CPU.
    #[arg(long)]
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority (1..99); refused with the busy wait (real-time throttling).
    #[arg(long)]
    pub fifo: Option<i32>,
    /// Do not lock memory (mlockall).
    #[arg(long)]
    pub no_mlock: bool,
}

pub(super) fn apply_rt(a: &ProcArgs, wait: WaitKind) -> Value {
    let mut req = feedloop_runtime::shared::rt::RtRequest {
        mlockall: !a.no_mlock,
        fifo_priority: a.fifo,
        cpu: a.cpu,
    };
    let mut note = None;
    if wait == WaitKind::Busy && a.fifo.is_some() {
        req.fifo_priority = None;
        note = Some("SCHED_FIFO refused with the busy wait: an unbounded spin at real-time priority is throttled by the kernel".to_string());
    }
    let mut applied = feedloop_runtime::shared::rt::apply(&req);
    applied.notes.extend(note);
    serde_json::to_value(&applied).unwrap_or(Value::Null)
}

/// What the plant and the scheduler process set up first.
pub(super) struct ProcStart {
    pub(super) loaded: Loaded,
    pub(super) mode: Mode,
    pub(super) wait: WaitKind,
    /// The real-time settings applied (for the process' JSON report).
    pub(super) rt: Value,
    pub(super) spin: Duration,
}

/// Installs the signal handlers, loads the job, resolves mode and wait, creates the output
/// folder and applies the real-time settings.
pub(super) fn start_process(a: &ProcArgs) -> Result<ProcStart> {
    signals::install();
    let loaded = load(&a.job)?;
    let mode = mode_of(&loaded.job, a.mode.map(|m| m.id().to_string()))?;
    let wait = wait_of(&loaded.job, a.wait.map(|w| w.id().to_string()))?;
    create_dir(&a.out)?;
    let rt = apply_rt(a, wait);
    let spin = Duration::from_secs_f64(loaded.job.spin_s());
    Ok(ProcStart {
        loaded,
        mode,
        wait,
        rt,
        spin,
    })
}
