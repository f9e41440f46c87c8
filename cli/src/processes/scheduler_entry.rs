//! `feedloop scheduler`: the scheduler process, and its report `scheduler.json`.

use std::process::ExitCode;

use anyhow::Result;
use serde_json::json;

use feedloop_plugins::Builtins;
use feedloop_runtime::scheduler::{run_scheduler, SchedulerConfig, SchedulerEnd};
use feedloop_runtime::shared::ipc::scheduler_endpoint;

use crate::signals;

use super::common::{write_json, Loaded};
use super::process_start::{start_process, ProcArgs, ProcStart};

/// `feedloop scheduler`.
pub fn scheduler(a: &ProcArgs) -> Result<ExitCode> {
    let ProcStart {
        loaded: Loaded { job, mut cycle, .. },
        mode,
        wait,
        rt,
        spin,
    } = start_process(a)?;
    if let Some(c) = a.cycles {
        cycle.set_cycles(c);
    }
    let (instance, out) = (a.instance.as_str(), a.out.as_path());
    let ep = scheduler_endpoint(instance, wait, spin)?;
    let cfg = SchedulerConfig {
        instance: instance.to_string(),
        mode,
        peer_timeout_s: job.run.peer_timeout_s,
        stale_after_s: 0.5f64.max(job.period_s * 1000.0),
        cycle_hook: None,
    };
    let n = job.axes.len();
    let mut control = feedloop_runtime::scheduler::control::ControlPlane::open(
        instance,
        &job,
        &cycle,
        std::sync::Arc::new(Builtins),
    )?;
    let outcome = run_scheduler(
        &cfg,
        &mut cycle,
        n,
        &ep,
        &out.join("scheduler.log"),
        &signals::STOP,
        Some(&mut control),
    )?;
    drop(ep);
    let end = match outcome.end {
        SchedulerEnd::Completed => json!({"reason": "completed"}),
        SchedulerEnd::PlantLost { cycle } => json!({"reason": "plant_lost", "cycle": cycle}),
        SchedulerEnd::PlantEnded { cycle } => json!({"reason": "plant_ended", "cycle": cycle}),
        SchedulerEnd::OperatorStop { cycle } => json!({"reason": "operator_stop", "cycle": cycle}),
    };
    write_json(
        &out.join("scheduler.json"),
        &json!({"pid": std::process::id(), "commands": outcome.commands,
                "out_of_order": outcome.out_of_order, "duplicated": outcome.duplicated, "skipped": outcome.skipped, "missing": outcome.missing,
                "nonfinite_faults": cycle.chain().nonfinite_faults,
                "plugin_panics": cycle.chain().plugin_panics,
                "dropped_records": outcome.dropped_records, "end": end,
                "realtime": rt, "peak_rss_bytes": feedloop_runtime::shared::rt::peak_resident_bytes(),
                "swaps": control.swaps, "rejected_requests": control.rejected,
                "rejected_count": control.rejected_count}),
    )?;
    Ok(if outcome.end == SchedulerEnd::Completed {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
