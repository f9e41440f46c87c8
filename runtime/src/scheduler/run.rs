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
pub fn run_scheduler(
    cfg: &SchedulerConfig,
    cycle: &mut ControlCycle,
    axis_count: usize,
    ep: &SchedulerEndpoint,
    log_path: &Path,
    stop: &std::sync::atomic::AtomicBool,
    control: Option<&mut crate::scheduler::control::ControlPlane>,
) -> Result<SchedulerOutcome, SchedulerError> {
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
    let rec =
        Recorder::<SchedRecord>::start_with_tap(log_path, 1 << 16, Some(tap)).map_err(log_err)?;
    let with = Parts {
        cfg,
        cycle,
        axis_count,
        ep,
        stop,
        control,
    };
    let mut run = SchedLoop::new(with, rec);
    run.cycles()?;
    let mut out = run.out;
    out.dropped_records = run.rec.dropped();
    run.rec.finish().map_err(log_err)?;
    Ok(out)
}

/// The scheduler loop's state from one cycle to the next. Its methods are the steps of a cycle,
/// called in the order they run by [`SchedLoop::cycles`]; none allocates, locks or logs.
struct SchedLoop<'a, 'c> {
    /// What it runs with.
    with: Parts<'a, 'c>,
    rec: Recorder<SchedRecord>,
    tag: u64,
    cmd: ActuatorCommand,
    /// The sample being answered (received into, cycle after cycle).
    s: SensorSample,
    hello: ActuatorCommand,
    start_timeout: u64,
    silence_ns: u64,
    period_ns: u64,
    started: bool,
    next_seq: u64,
    out: SchedulerOutcome,
    t_start: u64,
    stop_sent: bool,
    fault_sent: bool,
    nonfinite_seen: u64,
    /// End of the last answered cycle (command published), for the stretch before the next wait.
    prev_end_ns: u64,
}

/// What the scheduler loop runs with, borrowed for the run: its configuration, the controller
/// chains, the endpoint, the stop flag and the control plane.
struct Parts<'a, 'c> {
    cfg: &'a SchedulerConfig,
    cycle: &'a mut ControlCycle,
    axis_count: usize,
    ep: &'a SchedulerEndpoint,
    stop: &'a std::sync::atomic::AtomicBool,
    control: Option<&'c mut crate::scheduler::control::ControlPlane>,
}

impl<'a, 'c> SchedLoop<'a, 'c> {
    fn new(with: Parts<'a, 'c>, rec: Recorder<SchedRecord>) -> Self {
        let (cfg, cycle, axis_count) = (with.cfg, &with.cycle, with.axis_count);
        let tag = crate::shared::wire::instance_tag(&cfg.instance);
        let mut hello = ActuatorCommand::empty(axis_count as u32, tag);
        hello.flags = FLAG_HELLO;
        let start_timeout = (cfg.peer_timeout_s * 1e9) as u64;
        let silence_ns = match cfg.mode {
            Mode::Lockstep => start_timeout,
            Mode::Realtime => (cfg.stale_after_s * 1e9) as u64,
        };
        let period_ns = (cycle.period_s() * 1e9) as u64;
        Self {
            with,
            rec,
            tag,
            cmd: ActuatorCommand::empty(axis_count as u32, tag),
            s: SensorSample::empty(axis_count as u32, tag),
            hello,
            start_timeout,
            silence_ns,
            period_ns,
            started: false,
            next_seq: 0,
            out: SchedulerOutcome::new(),
            t_start: now_ns(),
            stop_sent: false,
            fault_sent: false,
            nonfinite_seen: 0,
            prev_end_ns: u64::MAX,
        }
    }

    /// The cycles, until the run ends (its end in `self.out.end`). The steps of a cycle (wait
    /// for the sample, run the prepared cycle, publish, record, prepare the next references,
    /// serve the control service) read top to bottom in the order they run.
    fn cycles(&mut self) -> Result<(), SchedulerError> {
        loop {
            let stop_now = self.with.stop.load(std::sync::atomic::Ordering::Relaxed);
            if stop_now && !self.started {
                self.out.end = SchedulerEnd::OperatorStop { cycle: 0 };
                break;
            }
            match self.wait_for_sample()? {
                WaitOutcome::Got(()) => {}
                WaitOutcome::TimedOut => {
                    self.out.end = self.silence_end()?;
                    break;
                }
            };
            // a hello (or a repeat sent while we were slow) is answered before any catch-up,
            // which would screen the cycle-0 sample behind it (the same number 0) and drop it
            if self.s.flags & FLAG_HELLO != 0 {
                self.check_hello()?;
                self.with.ep.send(self.hello)?;
                self.started = true;
                continue;
            }
            // the sample is held: the computation (and the catch-up, and the control plane's
            // look) starts now
            let c0 = now_ns();
            let skipped = if self.started {
                match self.catch_up(c0)? {
                    Some(skipped) => skipped,
                    None => continue,
                }
            } else {
                0
            };
            if !self.started {
                // A plant that is already cycling (we restarted?): refuse rather than guess.
                continue;
            }
            if let Some(end) = self.ended_before(skipped) {
                self.out.end = end;
                break;
            }
            let (s, cycle) = (&self.s, &mut *self.with.cycle);
            if let Some(c) = self.with.control.as_deref_mut() {
                c.plant_deadline_misses = s.deadline_misses;
                c.plant_overruns = s.plant_overruns;
                c.before_cycle(cycle, s.seq);
            }
            if self.with.cfg.mode == Mode::Realtime && s.seq.is_multiple_of(1024) {
                // samples arrive at the plant's cycle starts: keep the writer in the slack after
                // them
                self.rec.set_phase(c0, self.period_ns);
            }
            let ep = self.with.ep;
            let mut lost_ns = ep
                .poll_gap_ns()
                .max(c0.saturating_sub(ep.last_poll_ns()))
                .max(ep.wait_start_ns().saturating_sub(self.prev_end_ns));
            cycle.step(s, &mut self.cmd);
            if let Some(c) = self.with.control.as_deref_mut() {
                c.vet(cycle, &mut self.cmd);
            }
            self.flag_command(stop_now);
            let c1 = now_ns();
            let compute_ns = (c1 - c0).min(u32::MAX as u64) as u32;
            ep.send(self.cmd)?;
            self.prev_end_ns = now_ns();
            lost_ns = lost_ns.max(self.prev_end_ns - c1);
            ep.prepare_next(&self.cmd);
            let (s, cycle) = (&self.s, &mut *self.with.cycle);
            if let Some(c) = self.with.control.as_deref_mut() {
                c.after_cycle(cycle, &self.cmd, s.seq);
            }
            self.out.commands += 1;
            self.out.skipped += u64::from(skipped);
            self.next_seq = s.seq + 1;
            let r = SchedRecord {
                seq: s.seq,
                compute_ns,
                skipped,
                poll_gap_ns: lost_ns.min(u32::MAX as u64) as u32,
                received_ns: ep.last_poll_ns(),
                started_ns: c0,
                computed_ns: c1,
                sent_ns: self.prev_end_ns,
                ..Default::default()
            };
            self.push_record(r);
            // the next cycle's references, while the plant steps
            self.with.cycle.prepare(self.next_seq);
            let s = &self.s;
            if let Some(h) = self.with.cfg.cycle_hook {
                h(s.seq);
            }
            if s.flags & FLAG_END != 0 {
                self.end_with_answered();
                break;
            }
        }
        Ok(())
    }

    /// The plant's end message was answered: the run ends by the operator's stop, early by the
    /// plant's, or completed.
    fn end_with_answered(&mut self) {
        let seq = self.s.seq;
        if self.stop_sent {
            self.out.end = SchedulerEnd::OperatorStop { cycle: seq };
        } else if seq + 1 < self.with.cycle.cycles() {
            self.out.end = SchedulerEnd::PlantEnded { cycle: seq };
        }
    }

    /// Waits for the next sample, into `self.s`: after the start for the silence allowed, before
    /// it for the start-up timeout (which an operator stop ends at once).
    #[inline]
    fn wait_for_sample(&mut self) -> Result<WaitOutcome<()>, IpcError> {
        let wait = if self.started {
            self.silence_ns
        } else {
            self.start_timeout
        };
        let deadline = now_ns() + wait.max(1);
        // before the start an operator stop (or the launcher's death) ends the wait at once
        Ok(if self.started {
            // into the buffer kept across cycles: no copy of the whole sample on the way
            self.with.ep.receive_until_into(deadline, &mut self.s)?
        } else {
            match self
                .with
                .ep
                .receive_until_or_stop(deadline, self.with.stop)?
            {
                WaitOutcome::Got(m) => {
                    self.s = m;
                    WaitOutcome::Got(())
                }
                WaitOutcome::TimedOut => WaitOutcome::TimedOut,
            }
        })
    }

    /// How a wait that timed out ends the run (an error when the plant never came).
    fn silence_end(&self) -> Result<SchedulerEnd, SchedulerError> {
        if !self.started && self.with.stop.load(std::sync::atomic::Ordering::Relaxed) {
            return Ok(SchedulerEnd::OperatorStop { cycle: 0 });
        }
        if !self.started {
            return Err(IpcError::PeerTimeout {
                peer: "plant",
                instance: self.with.cfg.instance.clone(),
                seconds: (now_ns() - self.t_start) as f64 * 1e-9,
            }
            .into());
        }
        let cycle = self.next_seq.saturating_sub(1);
        Ok(if self.stop_sent {
            SchedulerEnd::OperatorStop { cycle }
        } else {
            SchedulerEnd::PlantLost { cycle }
        })
    }

    /// Realtime catch-up of a sample held at `c0`: answer the newest sample; every other queued
    /// one is either skipped (older than the newest, but not answered before) or a sequence
    /// fault (counted). Only needed when the sample may not be the newest: one held shortly after
    /// a poll found the queue empty is (the plant publishes once a period); one that was already
    /// waiting, or held after a stall since that poll, may have newer ones behind it. Returns the
    /// samples skipped, or `None` when there is none to answer.
    #[inline]
    fn catch_up(&mut self, c0: u64) -> Result<Option<u32>, IpcError> {
        let mut skipped = 0u32;
        let newest = self
            .with
            .ep
            .empty_poll_ns()
            .is_some_and(|t| c0.saturating_sub(t) < self.period_ns / 4);
        if newest {
            if !accept(&mut self.out, self.next_seq, &self.s) {
                return Ok(None);
            }
        } else {
            let mut best = screen(&mut self.out, self.next_seq, None, self.s);
            while let Some(newer) = self.with.ep.try_receive()? {
                if newer.flags & FLAG_HELLO == 0 {
                    let before = best.is_some();
                    best = screen(&mut self.out, self.next_seq, best, newer);
                    if before && best.map(|b| b.seq) == Some(newer.seq) {
                        skipped += 1;
                    }
                }
            }
            match best {
                Some(b) => self.s = b,
                None => return Ok(None),
            }
        }
        Ok(Some(skipped))
    }

    /// The plant's hello checked against this scheduler's protocol, instance and axes.
    fn check_hello(&self) -> Result<(), SchedulerError> {
        let s = &self.s;
        if s.protocol != PROTOCOL_VERSION {
            return Err(IpcError::Handshake(format!(
                "plant speaks protocol {}, this scheduler {}",
                s.protocol, PROTOCOL_VERSION
            ))
            .into());
        }
        if s.instance_tag != self.tag {
            return Err(IpcError::Handshake("plant belongs to another instance".into()).into());
        }
        if s.axis_count as usize != self.with.axis_count {
            return Err(IpcError::Handshake(format!(
                "plant has {} axes, this scheduler drives {}: are both running the same job?",
                s.axis_count, self.with.axis_count
            ))
            .into());
        }
        Ok(())
    }

    /// Counts the sequence numbers never seen before the held sample (besides the `skipped`
    /// ones), and whether the sample ends the run before it is answered: the plant's goodbye
    /// after an early stop, or its end message after the last cycle or a stop or fault sent.
    #[inline]
    fn ended_before(&mut self, skipped: u32) -> Option<SchedulerEnd> {
        let s = &self.s;
        let end = |cycle| {
            if self.stop_sent {
                SchedulerEnd::OperatorStop { cycle }
            } else {
                SchedulerEnd::PlantEnded { cycle }
            }
        };
        if s.seq < self.next_seq {
            // `screen` let only the plant's goodbye after an early stop through (it repeats the
            // last cycle number).
            return Some(end(s.seq));
        }
        if s.seq > self.next_seq + u64::from(skipped) {
            self.out.missing += s.seq - self.next_seq - u64::from(skipped);
        }
        if s.flags & FLAG_END != 0
            && (s.seq >= self.with.cycle.cycles() || self.stop_sent || self.fault_sent)
        {
            return Some(end(s.seq));
        }
        None
    }

    /// Sets the command's stop flag (an operator stop) and fault flag (a plugin fault).
    #[inline]
    fn flag_command(&mut self, stop_now: bool) {
        if stop_now {
            self.cmd.flags |= FLAG_STOP;
            self.stop_sent = true;
        } else {
            self.cmd.flags &= !FLAG_STOP;
        }
        let chain = self.with.cycle.chain();
        let nonfinite = chain.nonfinite_faults > self.nonfinite_seen;
        self.nonfinite_seen = chain.nonfinite_faults;
        let on_probation = self
            .with
            .control
            .as_deref()
            .is_some_and(|c| c.in_probation());
        if chain.plugin_panics > 0 || (nonfinite && !on_probation) {
            // A plugin panicked or produced a non-finite torque (zeroed by the chain): its output
            // can no longer be trusted, the plant stops the axes. A controller just swapped in is
            // rolled back by the control plane instead.
            self.cmd.flags |= FLAG_FAULT;
            self.fault_sent = true;
        }
    }

    /// Completes the cycle's record with the command and the stages' signals, and hands it on.
    #[inline]
    fn push_record(&mut self, mut r: SchedRecord) {
        for i in 0..self.with.axis_count {
            r.axes[i] = (self.cmd.axes[i].torque, self.cmd.axes[i].reference);
        }
        for (st, sg) in r.stages.iter_mut().zip(self.with.cycle.chain().signals()) {
            *st = (sg.vel_cmd, sg.torque_ff);
        }
        self.rec.push(r);
    }
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
