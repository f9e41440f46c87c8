//! The scheduler process's loop: wait for a sample, run the control cycle, publish the command,
//! hand the cycle's record to the recorder.

use std::path::Path;

use crate::scheduler::cycle::ControlCycle;
use crate::shared::clock::now_ns;
use crate::shared::ipc::{IpcError, SchedulerEndpoint, WaitOutcome};
use crate::shared::record::Recorder;
use crate::shared::scope::{scope_tap, ScopeSource};
use crate::shared::wire::{
    ActuatorCommand, SensorSample, FLAG_END, FLAG_FAULT, FLAG_HELLO, FLAG_STOP, PROTOCOL_VERSION,
};
use feedloop_model::job::Mode;
use feedloop_trace::log::SchedRecord;

/// Settings of one scheduler run.
#[derive(Debug, Clone)]
pub struct SchedulerConfig {
    /// Instance name.
    pub instance: String,
    /// Pacing (the plant paces; this only sets how long silence is tolerated).
    pub mode: Mode,
    /// How long to wait for the plant at start-up, and in lockstep between samples, s.
    pub peer_timeout_s: f64,
    /// Realtime: silence longer than this means the plant is lost, s.
    pub stale_after_s: f64,
    /// Called after every answered cycle with its number (tests use it to count allocations).
    pub cycle_hook: Option<fn(u64)>,
}

/// Why a scheduler run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SchedulerEnd {
    /// The plant announced the last cycle and it was answered.
    Completed,
    /// The plant stopped sending samples.
    PlantLost {
        /// Last cycle answered.
        cycle: u64,
    },
    /// The plant ended the run early (its own stop).
    PlantEnded {
        /// Cycle of the plant's end message.
        cycle: u64,
    },
    /// A stop was requested.
    OperatorStop {
        /// Last cycle answered.
        cycle: u64,
    },
}

/// Counters of a scheduler run.
#[derive(Debug, Clone, Copy)]
pub struct SchedulerOutcome {
    /// Why it ended.
    pub end: SchedulerEnd,
    /// Commands sent.
    pub commands: u64,
    /// Samples whose sequence number went back behind the last one answered (dropped).
    pub out_of_order: u64,
    /// Samples that repeated the last answered sequence number (dropped).
    pub duplicated: u64,
    /// Samples skipped because a newer one was queued.
    pub skipped: u64,
    /// Sequence numbers never seen (gaps), excluding skipped ones.
    pub missing: u64,
    /// Records the recorder could not keep.
    pub dropped_records: u64,
}

impl SchedulerOutcome {
    /// Nothing counted yet; ends `Completed` unless told otherwise.
    fn new() -> Self {
        SchedulerOutcome {
            end: SchedulerEnd::Completed,
            commands: 0,
            out_of_order: 0,
            duplicated: 0,
            skipped: 0,
            missing: 0,
            dropped_records: 0,
        }
    }
}

/// Errors of a scheduler run.
#[derive(Debug, thiserror::Error)]
pub enum SchedulerError {
    /// IPC failure.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// Log failure.
    #[error("scheduler log {path}: {source}")]
    Log {
        /// Log path.
        path: String,
        /// I/O error.
        source: std::io::Error,
    },
}

/// Runs the scheduler side until the plant's last cycle is answered, the plant is lost, or `stop`.
/// One function on purpose (about 200 lines): the steps of a cycle (wait for the sample, run the
/// prepared cycle, publish, record, prepare the next references, serve the control service)
/// read top to bottom in the order they run, and the cycle's state stays in locals.
pub fn run_scheduler(
    cfg: &SchedulerConfig,
    cycle: &mut ControlCycle,
    axis_count: usize,
    ep: &SchedulerEndpoint,
    log_path: &Path,
    stop: &std::sync::atomic::AtomicBool,
    mut control: Option<&mut crate::scheduler::control::ControlPlane>,
) -> Result<SchedulerOutcome, SchedulerError> {
    let tag = crate::shared::wire::instance_tag(&cfg.instance);
    let log_err = |e: std::io::Error| SchedulerError::Log {
        path: log_path.display().to_string(),
        source: e,
    };
    let tap = scope_tap(
        &cfg.instance,
        ScopeSource::Scheduler,
        cycle.period_s(),
        axis_count,
    );
    let mut rec =
        Recorder::<SchedRecord>::start_with_tap(log_path, 1 << 16, Some(tap)).map_err(log_err)?;
    let mut cmd = ActuatorCommand::empty(axis_count as u32, tag);
    // the sample being answered (received into, cycle after cycle)
    let mut s = SensorSample::empty(axis_count as u32, tag);
    let mut hello = ActuatorCommand::empty(axis_count as u32, tag);
    hello.flags = FLAG_HELLO;
    let start_timeout = (cfg.peer_timeout_s * 1e9) as u64;
    let silence_ns = match cfg.mode {
        Mode::Lockstep => start_timeout,
        Mode::Realtime => (cfg.stale_after_s * 1e9) as u64,
    };
    let period_ns = (cycle.period_s() * 1e9) as u64;
    let mut started = false;
    let mut next_seq = 0u64;
    let mut out = SchedulerOutcome::new();
    let t_start = now_ns();
    let mut stop_sent = false;
    let mut fault_sent = false;
    let mut nonfinite_seen = 0u64;
    // end of the last answered cycle (command published), for the stretch before the next wait
    let mut prev_end_ns = u64::MAX;
    loop {
        let stop_now = stop.load(std::sync::atomic::Ordering::Relaxed);
        if stop_now && !started {
            out.end = SchedulerEnd::OperatorStop { cycle: 0 };
            break;
        }
        let wait = if started { silence_ns } else { start_timeout };
        let deadline = now_ns() + wait.max(1);
        // before the start an operator stop (or the launcher's death) ends the wait at once
        let got = if started {
            // into the buffer kept across cycles: no copy of the whole sample on the way
            ep.receive_until_into(deadline, &mut s)?
        } else {
            match ep.receive_until_or_stop(deadline, stop)? {
                WaitOutcome::Got(m) => {
                    s = m;
                    WaitOutcome::Got(())
                }
                WaitOutcome::TimedOut => WaitOutcome::TimedOut,
            }
        };
        match got {
            WaitOutcome::Got(()) => {}
            WaitOutcome::TimedOut => {
                if !started && stop.load(std::sync::atomic::Ordering::Relaxed) {
                    out.end = SchedulerEnd::OperatorStop { cycle: 0 };
                    break;
                }
                if !started {
                    return Err(IpcError::PeerTimeout {
                        peer: "plant",
                        instance: cfg.instance.clone(),
                        seconds: (now_ns() - t_start) as f64 * 1e-9,
                    }
                    .into());
                }
                let cycle = next_seq.saturating_sub(1);
                out.end = if stop_sent {
                    SchedulerEnd::OperatorStop { cycle }
                } else {
                    SchedulerEnd::PlantLost { cycle }
                };
                break;
            }
        };
        // the sample is held: the computation (and the catch-up, and the control plane's look)
        // starts now
        let c0 = now_ns();
        // Realtime catch-up: answer the newest sample; every other queued one is either skipped
        // (older than the newest, but not answered before) or a sequence fault (counted). Only
        // needed when the sample may not be the newest: one held shortly after a poll found the
        // queue empty is (the plant publishes once a period); one that was already waiting, or
        // held after a stall since that poll, may have newer ones behind it.
        let mut skipped = 0u32;
        let newest = ep
            .empty_poll_ns()
            .is_some_and(|t| c0.saturating_sub(t) < period_ns / 4);
        if started && newest {
            if !accept(&mut out, next_seq, &s) {
                continue;
            }
        } else if started {
            let mut best = screen(&mut out, next_seq, None, s);
            while let Some(newer) = ep.try_receive()? {
                if newer.flags & FLAG_HELLO == 0 {
                    let before = best.is_some();
                    best = screen(&mut out, next_seq, best, newer);
                    if before && best.map(|b| b.seq) == Some(newer.seq) {
                        skipped += 1;
                    }
                }
            }
            match best {
                Some(b) => s = b,
                None => continue,
            }
        }
        if s.flags & FLAG_HELLO != 0 {
            if s.protocol != PROTOCOL_VERSION {
                return Err(IpcError::Handshake(format!(
                    "plant speaks protocol {}, this scheduler {}",
                    s.protocol, PROTOCOL_VERSION
                ))
                .into());
            }
            if s.instance_tag != tag {
                return Err(IpcError::Handshake("plant belongs to another instance".into()).into());
            }
            if s.axis_count as usize != axis_count {
                return Err(IpcError::Handshake(format!(
                    "plant has {} axes, this scheduler drives {axis_count}: are both running the same job?",
                    s.axis_count
                ))
                .into());
            }
            ep.send(hello)?;
            started = true;
            continue;
        }
        if !started {
            // A plant that is already cycling (we restarted?): refuse rather than guess.
            continue;
        }
        if s.seq < next_seq {
            // `screen` let only the plant's goodbye after an early stop through (it repeats the
            // last cycle number).
            out.end = if stop_sent {
                SchedulerEnd::OperatorStop { cycle: s.seq }
            } else {
                SchedulerEnd::PlantEnded { cycle: s.seq }
            };
            break;
        }
        if s.seq > next_seq + u64::from(skipped) {
            out.missing += s.seq - next_seq - u64::from(skipped);
        }
        if s.flags & FLAG_END != 0 && (s.seq >= cycle.cycles() || stop_sent || fault_sent) {
            out.end = if stop_sent {
                SchedulerEnd::OperatorStop { cycle: s.seq }
            } else {
                SchedulerEnd::PlantEnded { cycle: s.seq }
            };
            break;
        }
        if let Some(c) = control.as_deref_mut() {
            c.plant_deadline_misses = s.deadline_misses;
            c.before_cycle(cycle, s.seq);
        }
        if cfg.mode == Mode::Realtime && s.seq.is_multiple_of(1024) {
            // samples arrive at the plant's cycle starts: keep the writer in the slack after them
            rec.set_phase(c0, period_ns);
        }
        let mut lost_ns = ep
            .poll_gap_ns()
            .max(c0.saturating_sub(ep.last_poll_ns()))
            .max(ep.wait_start_ns().saturating_sub(prev_end_ns));
        cycle.step(&s, &mut cmd);
        if let Some(c) = control.as_deref_mut() {
            c.vet(cycle, &mut cmd);
        }
        if stop_now {
            cmd.flags |= FLAG_STOP;
            stop_sent = true;
        } else {
            cmd.flags &= !FLAG_STOP;
        }
        let nonfinite = cycle.chain().nonfinite_faults > nonfinite_seen;
        nonfinite_seen = cycle.chain().nonfinite_faults;
        let on_probation = control.as_deref().is_some_and(|c| c.in_probation());
        if cycle.chain().plugin_panics > 0 || (nonfinite && !on_probation) {
            // A plugin panicked or produced a non-finite torque (zeroed by the chain): its output
            // can no longer be trusted, the plant stops the axes. A controller just swapped in is
            // rolled back by the control plane instead.
            cmd.flags |= FLAG_FAULT;
            fault_sent = true;
        }
        let c1 = now_ns();
        let compute_ns = (c1 - c0).min(u32::MAX as u64) as u32;
        ep.send(cmd)?;
        prev_end_ns = now_ns();
        lost_ns = lost_ns.max(prev_end_ns - c1);
        ep.prepare_next(&cmd);
        if let Some(c) = control.as_deref_mut() {
            c.after_cycle(cycle, &cmd, s.seq);
        }
        out.commands += 1;
        out.skipped += u64::from(skipped);
        next_seq = s.seq + 1;
        let mut r = SchedRecord {
            seq: s.seq,
            compute_ns,
            skipped,
            poll_gap_ns: lost_ns.min(u32::MAX as u64) as u32,
            received_ns: ep.last_poll_ns(),
            started_ns: c0,
            computed_ns: c1,
            sent_ns: prev_end_ns,
            ..Default::default()
        };
        for i in 0..axis_count {
            r.axes[i] = (cmd.axes[i].torque, cmd.axes[i].reference);
        }
        for (st, sg) in r.stages.iter_mut().zip(cycle.chain().signals()) {
            *st = (sg.vel_cmd, sg.torque_ff);
        }
        rec.push(r);
        // the next cycle's references, while the plant steps
        cycle.prepare(next_seq);
        if let Some(h) = cfg.cycle_hook {
            h(s.seq);
        }
        if s.flags & FLAG_END != 0 {
            if stop_sent {
                out.end = SchedulerEnd::OperatorStop { cycle: s.seq };
            } else if s.seq + 1 < cycle.cycles() {
                out.end = SchedulerEnd::PlantEnded { cycle: s.seq };
            }
            break;
        }
    }
    out.dropped_records = rec.dropped();
    rec.finish().map_err(log_err)?;
    Ok(out)
}

/// [`screen`] of a sample with no other queued (`best` = `None`), without copying it: whether
/// to answer it.
fn accept(out: &mut SchedulerOutcome, next_seq: u64, m: &SensorSample) -> bool {
    if m.flags & FLAG_END != 0 || m.seq >= next_seq {
        return true;
    }
    if m.seq + 1 == next_seq {
        out.duplicated += 1;
    } else {
        out.out_of_order += 1;
    }
    false
}

/// Keeps the sample to answer among `best` and the newly received `m`: a sample behind the last
/// answered one is counted (`duplicated` when it repeats the last answered number or the one
/// already held, `out_of_order` otherwise) and dropped; of two valid ones the newer wins. The
/// plant's end message always wins (its goodbye after an early stop repeats a cycle number).
fn screen(
    out: &mut SchedulerOutcome,
    next_seq: u64,
    best: Option<SensorSample>,
    m: SensorSample,
) -> Option<SensorSample> {
    if m.flags & FLAG_END != 0 {
        return Some(m);
    }
    if best.is_some_and(|b| b.flags & FLAG_END != 0) {
        return best;
    }
    let repeat = m.seq + 1 == next_seq || best.is_some_and(|b| b.seq == m.seq);
    if m.seq < next_seq || best.is_some_and(|b| m.seq <= b.seq) {
        if repeat {
            out.duplicated += 1;
        } else {
            out.out_of_order += 1;
        }
        return best;
    }
    Some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lone_sample_is_judged_as_the_catch_up_judges_it() {
        let next_seq = 10;
        for seq in [0u64, 5, 8, 9, 10, 11, 40] {
            for flags in [0, FLAG_END] {
                let mut m = SensorSample::empty(2, 1);
                m.seq = seq;
                m.flags = flags;
                let (mut a, mut b) = (SchedulerOutcome::new(), SchedulerOutcome::new());
                let kept = screen(&mut a, next_seq, None, m).is_some();
                assert_eq!(
                    accept(&mut b, next_seq, &m),
                    kept,
                    "seq {seq} flags {flags}"
                );
                assert_eq!(
                    (a.duplicated, a.out_of_order),
                    (b.duplicated, b.out_of_order),
                    "seq {seq} flags {flags}"
                );
            }
        }
        // a repeat of the last answered cycle is a duplicate, an older one out of order
        let mut o = SchedulerOutcome::new();
        let mut m = SensorSample::empty(2, 1);
        m.seq = 9;
        assert!(!accept(&mut o, 10, &m));
        m.seq = 3;
        assert!(!accept(&mut o, 10, &m));
        assert_eq!((o.duplicated, o.out_of_order), (1, 1));
    }
}
