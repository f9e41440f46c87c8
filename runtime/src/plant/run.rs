//! The plant process's loop: publish a sample, wait for its command, apply it for one period.
//!
//! - `realtime`: cycle k starts at the absolute deadline t0 + k T. The plant publishes sample k,
//!   waits for command k until deadline k+1 (or one period after publishing, when the plant
//!   itself was late), then steps the physics with it. A command that has not arrived by then,
//!   while the plant woke on time, is a deadline miss: the last command is held. Waking more
//!   than half a period late is a plant overrun; more than 1 ms, a stall (the machine stopped).
//!   Start-up: sample 0 waits up to `startup_grace_s` for its command, the axes held (nothing is
//!   stepped); its arrival closes the loop and starts the schedule (t0) and the watchdog, so
//!   no cycle runs or is judged on a command the scheduler never sent. Before sample 0 the
//!   plant watches its core for `phase_probe_s` and starts t0 at the phase of the period the
//!   host's periodic interruptions leave alone ([`crate::shared::phase`]); after a stall it
//!   skips the whole periods missed, so cycles keep that phase.
//! - `lockstep`: the plant steps as soon as the command for the cycle arrives.
//!
//! Every cycle is logged (what was measured and applied, how late) through a [`Recorder`].

use std::path::Path;
use std::time::Duration;

use crate::shared::clock::{now_ns, wait_until_ns};
use crate::shared::ipc::{IpcError, PlantEndpoint, WaitOutcome};
use crate::shared::phase::{next_at_phase, PhaseChoice};
use crate::shared::record::Recorder;
use crate::shared::scope::{scope_tap, ScopeSource};
use crate::shared::wire::{
    ActuatorCommand, SensorSample, FLAG_END, FLAG_FAULT, FLAG_HELLO, FLAG_STOP, PROTOCOL_VERSION,
};
use feedloop_model::job::{Mode, SafeStop, SafetyOptions, WaitKind};
use feedloop_trace::log::{
    AxisRecord, PlantRecord, REC_BAD_SEQ, REC_DUP_CMD, REC_LATE_CMD, REC_MISSED, REC_OVERRUN,
    REC_STALL, REC_STOPPING, REC_WAIT_INTERRUPTED,
};

pub use feedloop_control::device::PlantDevice;

/// Settings of one plant run.
#[derive(Debug, Clone)]
pub struct PlantLoopConfig {
    /// Instance name (for the handshake).
    pub instance: String,
    /// Pacing.
    pub mode: Mode,
    /// Wait strategy for commands and (realtime) for the next deadline.
    pub wait: WaitKind,
    /// Hybrid: spin time before blocking.
    pub spin: Duration,
    /// Period, s.
    pub period_s: f64,
    /// Cycles to run.
    pub cycles: u64,
    /// Realtime: consecutive on-time cycles without a command that mean the scheduler is lost.
    pub watchdog_cycles: u64,
    /// Lockstep and handshake: how long to wait for the scheduler, s.
    pub peer_timeout_s: f64,
    /// Realtime: how long cycle 0 waits for the first command (the loop closing), s. The axes
    /// are held meanwhile (the physics is not stepped) and the watchdog starts after it.
    pub startup_grace_s: f64,
    /// Realtime: before the first sample, watch the core this long and start the schedule at
    /// the phase of the period the host's periodic interruptions leave alone
    /// ([`crate::shared::phase`]), s; 0 starts it when the loop closes, at whatever phase.
    pub phase_probe_s: f64,
    /// Drive-side limits and the safe-stop behaviour.
    pub safety: SafetyOptions,
    /// Per axis: braking gain on motor velocity for `brake_ramp` (N m s/rad or N s/m).
    pub brake_gain: Vec<f64>,
    /// Per axis: torque (force) limit, N m (N).
    pub torque_limit: Vec<f64>,
    /// Called at the end of every cycle with its number (tests use it to count allocations).
    pub cycle_hook: Option<fn(u64)>,
}

/// Why the plant stopped the axes early (the reason names in `summary.json`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopCause {
    /// The scheduler stopped answering: `scheduler_lost`.
    SchedulerLost {
        /// Cycles without a command before the declaration.
        detected_after_cycles: u64,
    },
    /// SIGINT/SIGTERM or a stop request from the scheduler: `operator_stop`.
    OperatorStop,
    /// |cmd - load| above the limit on this axis: `following_error`.
    FollowingError {
        /// Axis index.
        axis: usize,
    },
    /// Torque at its limit for too long: `torque_saturation`.
    TorqueSaturation {
        /// Axis index.
        axis: usize,
    },
    /// Outside the soft travel limits: `soft_limit`.
    SoftLimit {
        /// Axis index.
        axis: usize,
    },
    /// The scheduler reported a failed (panicked) controller plugin: `plugin_fault`.
    PluginFault,
}

impl StopCause {
    /// The reason string of `summary.json`.
    pub fn reason(&self) -> &'static str {
        match self {
            StopCause::SchedulerLost { .. } => "scheduler_lost",
            StopCause::OperatorStop => "operator_stop",
            StopCause::FollowingError { .. } => "following_error",
            StopCause::TorqueSaturation { .. } => "torque_saturation",
            StopCause::SoftLimit { .. } => "soft_limit",
            StopCause::PluginFault => "plugin_fault",
        }
    }
}

/// Why a plant run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlantEnd {
    /// All cycles ran.
    Completed,
    /// The axes were brought to a safe stop early.
    Stopped {
        /// Why.
        cause: StopCause,
        /// Cycle at which the stop began.
        cycle: u64,
        /// How the axes were stopped.
        safe_stop: SafeStop,
    },
}

/// Summary counters of a plant run (the per-cycle detail is in the log).
#[derive(Debug, Clone, Copy)]
pub struct PlantOutcome {
    /// Why it ended.
    pub end: PlantEnd,
    /// Cycles run.
    pub cycles: u64,
    /// Records the recorder could not keep (ring full).
    pub dropped_records: u64,
    /// Sequence checks on the command service (messages, not cycles).
    pub sequence: CommandSequence,
    /// Time from publishing the first sample to receiving its command, s: when the loop closed.
    /// None when no command ever came (the scheduler was lost during start-up).
    pub loop_closed_after_s: Option<f64>,
    /// Realtime with a phase probe: what it saw and the phase the schedule kept.
    pub phase: Option<PhaseChoice>,
}

/// What the plant saw on the command service besides the one expected command per cycle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CommandSequence {
    /// Commands whose sequence number (or instance/axis count) matched no cycle of this run:
    /// numbers from the future or from elsewhere. Dropped.
    pub bad_sequence: u64,
    /// A second command for a cycle that had already been answered. Dropped.
    pub duplicates: u64,
    /// Answers to an earlier, unanswered cycle that arrived after its deadline. Dropped.
    pub late: u64,
    /// Cycles whose command never arrived in time (the last command was held).
    pub missing: u64,
}

/// Errors of a plant run.
#[derive(Debug, thiserror::Error)]
pub enum PlantLoopError {
    /// IPC failure.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// Log file failure.
    #[error("plant log {path}: {source}")]
    Log {
        /// Log path.
        path: String,
        /// I/O error.
        source: std::io::Error,
    },
}

const STALL_NS: u64 = 1_000_000;

/// Runs the plant side until all cycles ran, the scheduler is lost, or `stop` is set.
pub fn run_plant<P: PlantDevice>(
    cfg: &PlantLoopConfig,
    plant: &mut P,
    ep: &PlantEndpoint,
    log_path: &Path,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<PlantOutcome, PlantLoopError> {
    let n = plant.axis_count();
    let plan = Plan::new(cfg, n);
    let rec = start_recorder(cfg, log_path, n)?;

    // before the handshake: once the scheduler is through it, it waits for sample 0 only as
    // long as for any sample
    let phase = (cfg.mode == Mode::Realtime && cfg.phase_probe_s > 0.0)
        .then(|| crate::shared::phase::choose(plan.period_ns, cfg.phase_probe_s));
    if !handshake(ep, plan.tag, n as u32, plan.timeout_ns, &cfg.instance, stop)? {
        // stopped before the loop started: nothing moved
        finish_log(rec, log_path)?;
        return Ok(PlantOutcome {
            end: PlantEnd::Stopped {
                cause: StopCause::OperatorStop,
                cycle: 0,
                safe_stop: cfg.safety.safe_stop,
            },
            cycles: 0,
            dropped_records: 0,
            sequence: CommandSequence::default(),
            loop_closed_after_s: None,
            phase,
        });
    }

    let mut run = PlantLoop::new(cfg, plant, ep, stop, rec, plan, phase);
    let k = run.cycles()?;
    // Safe state: no torque. Tell the scheduler we are done.
    let off = ActuatorCommand::empty(n as u32, plan.tag);
    run.plant.step(&off.axes);
    run.sample.flags = FLAG_END;
    run.sample.seq = k;
    let _ = ep.send(run.sample);
    let dropped = run.rec.dropped();
    finish_log(run.rec, log_path)?;
    Ok(PlantOutcome {
        end: run.end,
        cycles: k,
        dropped_records: dropped,
        sequence: run.seqs,
        loop_closed_after_s: run.loop_closed_after_s,
        phase,
    })
}

/// The plant log's recorder, with the scope's tap.
fn start_recorder(
    cfg: &PlantLoopConfig,
    log_path: &Path,
    n: usize,
) -> Result<Recorder<PlantRecord>, PlantLoopError> {
    Recorder::<PlantRecord>::start_with_tap(
        log_path,
        1 << 16,
        Some(scope_tap(
            &cfg.instance,
            ScopeSource::Plant,
            cfg.period_s,
            n,
        )),
    )
    .map_err(|e| PlantLoopError::Log {
        path: log_path.display().to_string(),
        source: e,
    })
}

/// Writes out the rest of the plant log.
fn finish_log(rec: Recorder<PlantRecord>, log_path: &Path) -> Result<(), PlantLoopError> {
    rec.finish().map_err(|e| PlantLoopError::Log {
        path: log_path.display().to_string(),
        source: e,
    })?;
    Ok(())
}

/// The run's timing and limits, fixed before its first cycle.
#[derive(Debug, Clone, Copy)]
struct Plan {
    tag: u64,
    n: usize,
    period_ns: u64,
    timeout_ns: u64,
    spin_ns: u64,
    grace_ns: u64,
    max_sat_cycles: Option<u64>,
    /// Cycles of braking once stopping.
    brake_cycles: u64,
}

impl Plan {
    fn new(cfg: &PlantLoopConfig, n: usize) -> Self {
        Self {
            tag: crate::shared::wire::instance_tag(&cfg.instance),
            n,
            // at least 1 ns: the schedule divides by it
            period_ns: ((cfg.period_s * 1e9).round() as u64).max(1),
            timeout_ns: (cfg.peer_timeout_s * 1e9) as u64,
            spin_ns: match cfg.wait {
                WaitKind::Busy => u64::MAX,
                WaitKind::Block => 0,
                WaitKind::Hybrid => cfg.spin.as_nanos() as u64,
            },
            grace_ns: (cfg.startup_grace_s * 1e9) as u64,
            max_sat_cycles: cfg
                .safety
                .max_saturation_s
                .map(|s| (s / cfg.period_s).ceil() as u64),
            brake_cycles: match cfg.safety.safe_stop {
                SafeStop::TorqueOff => 1,
                SafeStop::BrakeRamp => {
                    ((cfg.safety.brake_time_s / cfg.period_s).ceil() as u64).max(1)
                }
            },
        }
    }
}

/// The plant loop's state from one period to the next. Its methods are the steps of a period,
/// called in the order they run by [`PlantLoop::cycles`]; none allocates, locks or logs.
struct PlantLoop<'a, P: PlantDevice> {
    cfg: &'a PlantLoopConfig,
    plant: &'a mut P,
    ep: &'a PlantEndpoint,
    stop: &'a std::sync::atomic::AtomicBool,
    rec: Recorder<PlantRecord>,
    plan: Plan,
    /// Where the schedule starts once the loop has closed: the quiet phase, if one was found.
    quiet: Option<crate::shared::phase::QuietPhase>,
    sample: SensorSample,
    applied: ActuatorCommand,
    end: PlantEnd,
    silent_cycles: u64,
    seqs: CommandSequence,
    deadline_misses: u32,
    /// Cycles that woke more than half a period late so far (saturating).
    plant_overruns: u32,
    /// Which of the last 64 cycles took a command (bit i: cycle k - i), to tell a duplicate from
    /// a late answer.
    answered: u64,
    prev_missed: bool,
    saturated_cycles: [u64; crate::shared::wire::MAX_AXES],
    /// Once stopping: cycles of braking left.
    stopping: Option<u64>,
    loop_closed_after_s: Option<f64>,
    t0: u64,
}

impl<'a, P: PlantDevice> PlantLoop<'a, P> {
    fn new(
        cfg: &'a PlantLoopConfig,
        plant: &'a mut P,
        ep: &'a PlantEndpoint,
        stop: &'a std::sync::atomic::AtomicBool,
        rec: Recorder<PlantRecord>,
        plan: Plan,
        phase: Option<PhaseChoice>,
    ) -> Self {
        let n = plan.n as u32;
        let t0 = now_ns() + 5_000_000;
        if cfg.mode == Mode::Realtime {
            rec.set_phase(t0, plan.period_ns);
        }
        Self {
            cfg,
            plant,
            ep,
            stop,
            rec,
            plan,
            quiet: phase.and_then(|p| p.quiet),
            sample: SensorSample::empty(n, plan.tag),
            applied: ActuatorCommand::empty(n, plan.tag),
            end: PlantEnd::Completed,
            silent_cycles: 0,
            seqs: CommandSequence::default(),
            deadline_misses: 0,
            plant_overruns: 0,
            answered: 0,
            prev_missed: false,
            saturated_cycles: [0; crate::shared::wire::MAX_AXES],
            stopping: None,
            loop_closed_after_s: None,
            t0,
        }
    }

    /// The periods, until all cycles ran or a stop has braked the axes; returns the cycles run.
    /// The steps of a period (wait for the deadline, sense, publish, wait for the command and
    /// check it, apply it, step, record) read top to bottom in the order they run.
    fn cycles(&mut self) -> Result<u64, PlantLoopError> {
        let (cfg, n) = (self.cfg, self.plan.n);
        let mut k = 0u64;
        loop {
            match self.stopping {
                Some(0) => break,
                None if k >= cfg.cycles => break,
                _ => {}
            }
            let mut cause: Option<StopCause> = None;
            if self.stopping.is_none() && self.stop.load(std::sync::atomic::Ordering::Relaxed) {
                cause = Some(StopCause::OperatorStop);
            }
            let (mut flags, wake_late_ns, cmd_deadline) = self.pace(k);

            let c0 = now_ns();
            self.sample.seq = k;
            self.sample.plant_time_s = k as f64 * cfg.period_s;
            let last = self.stopping.is_none() && k + 1 == cfg.cycles;
            self.sample.flags = if last || self.stopping.is_some() {
                FLAG_END
            } else {
                0
            };
            self.plant.sense(&mut self.sample.axes);
            self.sample.deadline_misses = self.deadline_misses;
            // both counts cover the cycles before this one (this one's miss is not known yet)
            self.sample.plant_overruns = self.plant_overruns;
            if flags & REC_OVERRUN != 0 {
                self.plant_overruns = self.plant_overruns.saturating_add(1);
            }
            let sense_ns = now_ns() - c0;
            let published = now_ns();
            let mut latency_ns = u64::MAX;
            if self.stopping.is_none() {
                self.ep.send(self.sample)?;
                // the next sample's loan, while the command is on its way
                self.ep.prepare_next(&self.sample);
                latency_ns =
                    self.take_command(k, cmd_deadline, published, &mut flags, &mut cause)?;
                if latency_ns == u64::MAX {
                    cause = cause.or(self.missed(k, &mut flags));
                } else {
                    self.silent_cycles = 0;
                }
                if cause.is_none() {
                    cause = check_limits(
                        cfg,
                        &self.sample,
                        &self.applied,
                        n,
                        &mut self.saturated_cycles,
                        self.plan.max_sat_cycles,
                    );
                }
            }
            self.prev_missed = flags & REC_MISSED != 0;
            if let Some(c) = cause {
                self.begin_stop(c, k);
            }
            if let Some(left) = self.stopping {
                self.brake();
                self.stopping = Some(left.saturating_sub(1));
            }

            let c1 = now_ns();
            self.plant.step(&self.applied.axes);
            let compute_ns = (now_ns() - c1 + sense_ns).min(u32::MAX as u64) as u32;

            let mut r = PlantRecord {
                seq: k,
                wake_late_ns,
                latency_ns,
                compute_ns,
                published_ns: published,
                flags: if self.stopping.is_some() {
                    flags | REC_STOPPING
                } else {
                    flags
                },
                ..Default::default()
            };
            for i in 0..n {
                r.axes[i] = AxisRecord::of(&self.sample.axes[i], &self.applied.axes[i]);
            }
            self.rec.push(r);
            if let Some(h) = cfg.cycle_hook {
                h(k);
            }
            k += 1;
            self.answered <<= 1;
        }
        Ok(k)
    }

    /// Realtime: waits for cycle `k`'s deadline and judges the wake-up; returns the record's
    /// flags so far, how late it woke and until when the command is waited for.
    #[inline]
    fn pace(&mut self, k: u64) -> (u8, u64, u64) {
        let p = self.plan;
        if self.cfg.mode != Mode::Realtime {
            return (0, 0, now_ns() + p.timeout_ns);
        }
        let mut flags = 0u8;
        let deadline = self.t0 + k * p.period_ns;
        wait_until_ns(deadline, p.spin_ns);
        let wake_late_ns = now_ns().saturating_sub(deadline);
        if wake_late_ns > p.period_ns / 2 {
            flags |= REC_OVERRUN;
        }
        if wake_late_ns > STALL_NS {
            // Re-anchor the schedule instead of racing through the missed deadlines: skip
            // the whole periods missed, so that cycles keep their phase.
            self.t0 += wake_late_ns / p.period_ns * p.period_ns;
            self.rec.set_phase(self.t0, p.period_ns);
            // A machine-wide stall, unless the lateness is our own: a timed-out blocking
            // wait for a missing command can overshoot by a timer tick (socket timeouts have
            // jiffy resolution), and must not excuse the silence from the watchdog.
            if !self.prev_missed {
                flags |= REC_STALL;
            }
        }
        let cmd_deadline = if k == 0 {
            // start-up: cycle 0 waits for the loop to close, the axes held meanwhile
            now_ns() + p.grace_ns.max(p.period_ns)
        } else {
            (deadline + p.period_ns).max(now_ns() + p.period_ns)
        };
        (flags, wake_late_ns, cmd_deadline)
    }

    /// Waits until `cmd_deadline` for cycle `k`'s command, dropping (and flagging) any other
    /// message; applies it, or takes its stop or fault into `cause`. Returns the latency from
    /// `published`, or `u64::MAX` when no command came.
    #[inline]
    fn take_command(
        &mut self,
        k: u64,
        cmd_deadline: u64,
        published: u64,
        flags: &mut u8,
        cause: &mut Option<StopCause>,
    ) -> Result<u64, IpcError> {
        let (tag, ep) = (self.plan.tag, self.ep);
        while let WaitOutcome::Got(c) = if k == 0 {
            // the start-up wait can be long: an operator stop ends it
            ep.receive_until_or_stop(cmd_deadline, self.stop)?
        } else {
            ep.receive_until(cmd_deadline)?
        } {
            if c.flags & FLAG_HELLO != 0 {
                continue;
            }
            let age = k.wrapping_sub(c.seq);
            if c.seq <= k && age < 64 && self.answered >> age & 1 == 1 && c.instance_tag == tag {
                // The same cycle answered twice: the first answer was applied.
                *flags |= REC_DUP_CMD;
                self.seqs.duplicates += 1;
                continue;
            }
            if c.seq < k && c.instance_tag == tag {
                // The answer to an earlier cycle, after its deadline: too late to apply.
                *flags |= REC_LATE_CMD;
                self.seqs.late += 1;
                continue;
            }
            if c.seq != k || c.instance_tag != tag || c.axis_count as usize != self.plan.n {
                *flags |= REC_BAD_SEQ;
                self.seqs.bad_sequence += 1;
                continue;
            }
            self.answered |= 1;
            let latency_ns = now_ns() - published;
            if k == 0 {
                self.loop_closed_after_s = Some(latency_ns as f64 * 1e-9);
                if self.cfg.mode == Mode::Realtime {
                    // The schedule starts when the loop has closed (at the quiet phase).
                    let now = now_ns();
                    self.t0 = match self.quiet {
                        Some(q) => next_at_phase(now, self.plan.period_ns, q.phase_ns),
                        None => now,
                    };
                    self.rec.set_phase(self.t0, self.plan.period_ns);
                }
            }
            if c.flags & FLAG_FAULT != 0 {
                *cause = cause.or(Some(StopCause::PluginFault));
            } else if c.flags & FLAG_STOP != 0 {
                *cause = cause.or(Some(StopCause::OperatorStop));
            } else {
                self.applied = c;
            }
            return Ok(latency_ns);
        }
        Ok(u64::MAX)
    }

    /// Cycle `k`'s command did not come: counts the miss and, from the silence, whether the
    /// scheduler is lost (the stop cause then).
    #[inline]
    fn missed(&mut self, k: u64, flags: &mut u8) -> Option<StopCause> {
        let cfg = self.cfg;
        *flags |= REC_MISSED;
        if cfg.mode == Mode::Realtime && self.ep.poll_gap_ns() >= self.plan.period_ns / 2 {
            *flags |= REC_WAIT_INTERRUPTED;
        }
        self.seqs.missing += 1;
        if feedloop_trace::log::is_deadline_miss(*flags) {
            self.deadline_misses = self.deadline_misses.saturating_add(1);
        }
        // Only a machine-wide stall excuses silence: a merely busy machine still counts.
        let on_time = *flags & REC_STALL == 0;
        if cfg.mode == Mode::Lockstep {
            self.silent_cycles = 1;
            Some(StopCause::SchedulerLost {
                detected_after_cycles: 1,
            })
        } else if k == 0 {
            // No command within the start-up grace: the scheduler never closed the loop
            // (unless an operator stop ended the wait).
            self.silent_cycles = 1;
            Some(if self.stop.load(std::sync::atomic::Ordering::Relaxed) {
                StopCause::OperatorStop
            } else {
                StopCause::SchedulerLost {
                    detected_after_cycles: 0,
                }
            })
        } else if on_time {
            self.silent_cycles += 1;
            (self.silent_cycles >= cfg.watchdog_cycles).then_some(StopCause::SchedulerLost {
                detected_after_cycles: self.silent_cycles,
            })
        } else {
            None
        }
    }

    /// Starts the safe stop for `cause` at cycle `k`.
    fn begin_stop(&mut self, cause: StopCause, k: u64) {
        self.end = PlantEnd::Stopped {
            cause,
            cycle: k,
            safe_stop: self.cfg.safety.safe_stop,
        };
        self.stopping = Some(self.plan.brake_cycles);
        // Tell the scheduler the run is over.
        let mut bye = self.sample;
        bye.flags = FLAG_END;
        let _ = self.ep.send(bye);
    }

    /// Safe stop: brake on the measured motor velocity, or torque off.
    #[inline]
    fn brake(&mut self) {
        let cfg = self.cfg;
        for i in 0..self.plan.n {
            let t = match cfg.safety.safe_stop {
                SafeStop::TorqueOff => 0.0,
                SafeStop::BrakeRamp => {
                    let lim = cfg.torque_limit.get(i).copied().unwrap_or(0.0);
                    let g = cfg.brake_gain.get(i).copied().unwrap_or(0.0);
                    (-g * self.sample.axes[i].motor_vel).clamp(-lim, lim)
                }
            };
            self.applied.axes[i].torque = if t.is_finite() { t } else { 0.0 };
        }
    }
}

/// Drive-side checks of one cycle: following error, soft limits, saturation time.
fn check_limits(
    cfg: &PlantLoopConfig,
    sample: &SensorSample,
    applied: &ActuatorCommand,
    n: usize,
    saturated_cycles: &mut [u64],
    max_sat_cycles: Option<u64>,
) -> Option<StopCause> {
    for (i, (s, a)) in sample.axes.iter().zip(&applied.axes).enumerate().take(n) {
        let load = s.load_pos;
        if let Some(max) = cfg.safety.max_following_error {
            if (a.reference - load).abs() > max {
                return Some(StopCause::FollowingError { axis: i });
            }
        }
        if let Some(Some((lo, hi))) = cfg.safety.soft_limits.get(i) {
            if load < *lo || load > *hi {
                return Some(StopCause::SoftLimit { axis: i });
            }
        }
        if let Some(maxc) = max_sat_cycles {
            let lim = cfg.torque_limit.get(i).copied().unwrap_or(f64::INFINITY);
            if a.torque.abs() >= 0.999 * lim {
                saturated_cycles[i] += 1;
                if saturated_cycles[i] > maxc {
                    return Some(StopCause::TorqueSaturation { axis: i });
                }
            } else {
                saturated_cycles[i] = 0;
            }
        }
    }
    None
}

/// The hello exchange with the scheduler; `Ok(false)` when `stop` was set before it completed.
fn handshake(
    ep: &PlantEndpoint,
    tag: u64,
    n: u32,
    timeout_ns: u64,
    instance: &str,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<bool, IpcError> {
    let start = now_ns();
    let mut hello = SensorSample::empty(n, tag);
    hello.flags = FLAG_HELLO;
    loop {
        if stop.load(std::sync::atomic::Ordering::Relaxed) {
            return Ok(false);
        }
        if now_ns() - start > timeout_ns {
            return Err(IpcError::PeerTimeout {
                peer: "scheduler",
                instance: instance.to_string(),
                seconds: timeout_ns as f64 * 1e-9,
            });
        }
        if ep.peer_connected() {
            ep.send(hello)?;
        }
        if let WaitOutcome::Got(c) = ep.receive_until(now_ns() + 2_000_000)? {
            if c.flags & FLAG_HELLO != 0 {
                if c.protocol != PROTOCOL_VERSION {
                    return Err(IpcError::Handshake(format!(
                        "scheduler speaks protocol {}, this plant {}",
                        c.protocol, PROTOCOL_VERSION
                    )));
                }
                if c.instance_tag != tag {
                    return Err(IpcError::Handshake(
                        "scheduler belongs to another instance".into(),
                    ));
                }
                if c.axis_count != n {
                    return Err(IpcError::Handshake(format!(
                        "scheduler drives {} axes, this plant has {n}: are both running the same job?",
                        c.axis_count
                    )));
                }
                // Let stale hello replies arrive, then discard them.
                std::thread::sleep(Duration::from_millis(2));
                ep.drain()?;
                return Ok(true);
            }
        }
    }
}
