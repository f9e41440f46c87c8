//! `feedloop plant`: the plant process, and its report `plant.json`.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;
use serde_json::{json, Value};

use feedloop_model::job::{Job, Mode, WaitKind};

use feedloop_runtime::plant::{
    run_plant, PlantEnd, PlantLoopConfig, PlantLoopError, PlantOutcome, StopCause,
};
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_runtime::shared::ipc::plant_endpoint;
use feedloop_runtime::shared::ipc::IpcError;
use feedloop_trace::export::human_summary;

use crate::signals;

use super::common::{write_json, Loaded};
use super::merge::merge;
use super::process_start::{start_process, ProcArgs, ProcStart};

/// The plant loop's configuration from the job and the command line.
fn plant_loop_config(
    a: &ProcArgs,
    job: &Job,
    cycle: &ControlCycle,
    mode: Mode,
    wait: WaitKind,
    spin: Duration,
) -> PlantLoopConfig {
    PlantLoopConfig {
        instance: a.instance.clone(),
        mode,
        wait,
        spin,
        period_s: job.period_s,
        cycles: a.cycles.unwrap_or(cycle.cycles()),
        watchdog_cycles: job.run.watchdog_cycles,
        peer_timeout_s: job.run.peer_timeout_s,
        startup_grace_s: job.run.startup_grace_s,
        phase_probe_s: job.run.phase_probe_s,
        safety: job.safety.clone(),
        brake_gain: job
            .axes
            .iter()
            .map(|a| {
                a.model
                    .controller
                    .kv
                    .unwrap_or(a.model.plant.total_inertia() * 200.0)
            })
            .collect(),
        torque_limit: job
            .axes
            .iter()
            .map(|a| a.model.controller.torque_limit.unwrap_or(f64::INFINITY))
            .collect(),
        cycle_hook: None,
    }
}

/// The plant's `end` object of plant.json.
fn plant_end_json(outcome: &PlantOutcome, job: &Job, realtime: bool) -> Value {
    match outcome.end {
        PlantEnd::Completed => json!({"reason": "completed", "cycle": outcome.cycles}),
        PlantEnd::Stopped {
            cause,
            cycle,
            safe_stop,
        } => {
            let mut e =
                json!({"reason": cause.reason(), "cycle": cycle, "safe_stop": safe_stop.id()});
            match cause {
                StopCause::SchedulerLost {
                    detected_after_cycles,
                } => {
                    e["detected_after_cycles"] = json!(detected_after_cycles);
                    if outcome.cycles == 0 {
                        // no hello within the peer timeout
                        e["during_handshake"] = json!(true);
                        e["peer_timeout_s"] = json!(job.run.peer_timeout_s);
                    } else if outcome.loop_closed_after_s.is_none() && realtime {
                        // hello, but no first command within the start-up grace
                        e["during_startup"] = json!(true);
                        e["startup_grace_s"] = json!(job.run.startup_grace_s);
                    }
                }
                StopCause::FollowingError { axis }
                | StopCause::TorqueSaturation { axis }
                | StopCause::SoftLimit { axis } => e["axis"] = json!(job.axes[axis].name),
                StopCause::OperatorStop | StopCause::PluginFault => {}
            }
            e
        }
    }
}

/// `feedloop plant`.
pub fn plant(a: &ProcArgs, export: bool) -> Result<ExitCode> {
    let ProcStart {
        loaded: Loaded { job, cycle, plant },
        mode,
        wait,
        rt,
        spin,
    } = start_process(a)?;
    let out = a.out.as_path();
    let ep = plant_endpoint(&a.instance, wait, spin)?;
    let cfg = plant_loop_config(a, &job, &cycle, mode, wait, spin);
    let mut dev = plant;
    let outcome = match run_plant(&cfg, &mut dev, &ep, &out.join("plant.log"), &signals::STOP) {
        Ok(o) => o,
        // The scheduler vanished before the first cycle: nothing moved, report it as lost.
        Err(PlantLoopError::Ipc(e @ IpcError::PeerTimeout { .. })) => {
            eprintln!("feedloop plant: {e}");
            PlantOutcome {
                end: PlantEnd::Stopped {
                    cause: StopCause::SchedulerLost {
                        detected_after_cycles: 0,
                    },
                    cycle: 0,
                    safe_stop: cfg.safety.safe_stop,
                },
                cycles: 0,
                dropped_records: 0,
                sequence: Default::default(),
                loop_closed_after_s: None,
                phase: None,
            }
        }
        Err(e) => return Err(e.into()),
    };
    drop(ep);
    let mut end = plant_end_json(&outcome, &job, mode == Mode::Realtime);
    let stopped = !matches!(outcome.end, PlantEnd::Completed);
    if !export && stopped && signals::PARENT_DIED.load(std::sync::atomic::Ordering::Relaxed) {
        // started by `feedloop run`, which died: the axes were stopped, nobody merges the logs
        end["reason"] = json!("launcher_lost");
        eprintln!(
            "feedloop plant: the launcher died; axes stopped ({}). Export the trace with: \
             feedloop merge {} --job {}",
            cfg.safety.safe_stop.id(),
            out.display(),
            a.job.display()
        );
    }
    write_json(
        &out.join("plant.json"),
        &json!({"pid": std::process::id(), "mode": mode.id(), "wait": wait.id(),
                "cycles": outcome.cycles, "planned_cycles": cfg.cycles, "dropped_records": outcome.dropped_records, "end": end,
                "commands": {"bad_sequence": outcome.sequence.bad_sequence, "duplicates": outcome.sequence.duplicates,
                             "late": outcome.sequence.late, "missing": outcome.sequence.missing},
                "startup": {"loop_closed_after_s": outcome.loop_closed_after_s, "grace_s": cfg.startup_grace_s},
                "phase": outcome.phase.map(phase_json),
                "realtime": rt, "peak_rss_bytes": feedloop_runtime::shared::rt::peak_resident_bytes()}),
    )?;
    if export {
        // Started by hand: give the scheduler a moment to write its own file, then export.
        for _ in 0..40 {
            if out.join("scheduler.json").exists() {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let (v, code) = merge(out, &job)?;
        print!("{}", human_summary(&v));
        return Ok(code);
    }
    Ok(if outcome.end == PlantEnd::Completed {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

/// `plant.json`'s `phase`: what the start-up probe saw of the host's interruptions and the
/// phase of the period the cycles kept (`phase_us` null: nothing to avoid).
pub(crate) fn phase_json(p: feedloop_runtime::shared::phase::PhaseChoice) -> serde_json::Value {
    json!({
        "probe_s": p.probe_s,
        "interruptions": p.interruptions,
        "longest_us": p.longest_ns as f64 * 1e-3,
        "window_us": p.window_ns as f64 * 1e-3,
        "phase_us": p.quiet.map(|q| q.phase_ns as f64 * 1e-3),
        "hit_share": p.quiet.map(|q| q.hit_share),
        "delay_us_per_cycle": p.quiet.map(|q| q.delay_ns * 1e-3),
        "worst_hit_share": p.quiet.map(|q| q.worst_hit_share),
        "worst_delay_us_per_cycle": p.quiet.map(|q| q.worst_delay_ns * 1e-3),
    })
}
