//! The scheduler's side of the control service: [`ControlPlane`] polls requests in the cycle's
//! slack, switches built controllers in at a cycle boundary and runs their probation.

use std::path::PathBuf;
use std::sync::mpsc;
use std::sync::Arc;

use feedloop_control::controller::{Controller, PluginRegistry, Stage};
use feedloop_control::loop_model::LoopGains;
use feedloop_model::job::Job;
use iceoryx2::prelude::*;

use super::builder::{builder, BuildJob, Built, ChainState, SwapError, ToBuilder};
use super::origin::Origin;
use super::protocol::{self, Answer, AxisStatus, Request, StagePlugins, Status, SwapEvent};
use super::wire::{service_name, ControlRequest, ControlResponse, CtlActive, CtlServer};
use crate::scheduler::cycle::ControlCycle;
use crate::shared::ipc::{create_node, IpcError};
use crate::shared::wire::{ActuatorCommand, MAX_AXES};

/// A refused control request, as reported in `summary.json`'s `rejected_requests`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Rejection {
    /// Cycle in which the refusal was answered.
    pub cycle: u64,
    /// Time of that cycle, s.
    pub t_s: f64,
    /// The request's `op` (`swap`, `status`, or what was sent).
    pub op: String,
    /// The reason given to the client.
    pub error: String,
    /// Who sent it (null when the sender did not say).
    pub origin: Option<Origin>,
}

/// At most this many refusals are kept (the count goes on).
const MAX_REJECTIONS: usize = 4096;

struct Probation {
    axis: usize,
    stage: Stage,
    entry: Option<(String, toml::Table)>,
    gains: LoopGains,
    force: bool,
    /// The first cycle's torque step exceeded the bound: that cycle held the previous torque.
    vetoed: bool,
    /// Every stage of the axis just before the swap's first cycle (to undo it on a veto).
    states: [feedloop_control::controller::ControllerState; 4],
    old: Option<Box<dyn Controller>>,
    left: u32,
    event: usize,
    faults_before: u64,
}

/// A swap request handed to the builder, or switched in and on probation: its answer is owed.
struct Pending {
    req: CtlActive,
    axis: usize,
    stage: Stage,
    /// Who sent it (copied from the request: no allocation).
    origin: Option<Origin>,
}

const HISTORY: usize = 101;
const PROBATION_CYCLES: u32 = 10;

/// The scheduler's side of the control service.
pub struct ControlPlane {
    server: CtlServer,
    _node: iceoryx2::node::Node<ipc::Service>,
    to_builder: mpsc::Sender<ToBuilder>,
    from_builder: mpsc::Receiver<Built>,
    graveyard: mpsc::Sender<ToBuilder>,
    pending: Option<Pending>,
    probation: Option<Probation>,
    /// Every swap so far.
    pub swaps: Vec<SwapEvent>,
    /// Refused requests (the first 4096).
    pub rejected: Vec<Rejection>,
    /// Refused requests, all of them.
    pub rejected_count: u64,
    /// The plant's deadline-miss count as of the latest sample (set by the scheduler loop).
    pub plant_deadline_misses: u32,
    /// The plant's overrun count as of the latest sample (set by the scheduler loop).
    pub plant_overruns: u32,
    /// The job file, absolute (for the status).
    job_path: Option<String>,
    history: Vec<[f64; HISTORY]>,
    hist_pos: usize,
    hist_len: usize,
    names: Vec<String>,
    limits: Vec<f64>,
    period_s: f64,
    plugin_ids: Vec<StagePlugins>,
}

impl ControlPlane {
    /// Opens the control service of `instance` for `job`'s chain, with `registry` building plugins.
    pub fn open(
        instance: &str,
        job: &Job,
        cycle: &ControlCycle,
        registry: Arc<dyn PluginRegistry>,
    ) -> Result<Self, IpcError> {
        let node = create_node(instance, "control")?;
        let svc = node
            .service_builder(&service_name(instance)?)
            .request_response::<ControlRequest, ControlResponse>()
            .max_servers(1)
            .open_or_create()
            .map_err(|e| IpcError::Setup {
                what: "open the control service".into(),
                detail: format!("{e:?}"),
            })?;
        let server = svc.server_builder().create().map_err(|e| IpcError::Setup {
            what: "create the control server".into(),
            detail: format!("{e:?}"),
        })?;
        let (state, plugin_ids) = ChainState::of(job, cycle);
        let (to_builder, jobs) = mpsc::channel::<ToBuilder>();
        let (done_tx, from_builder) = mpsc::channel::<Built>();
        let graveyard = to_builder.clone();
        let job_path: PathBuf = job.path.clone();
        std::thread::Builder::new()
            .name("feedloop-builder".into())
            .spawn(move || builder(jobs, done_tx, registry, state, job_path))
            .map_err(|e| IpcError::Setup {
                what: "start the plugin builder thread".into(),
                detail: e.to_string(),
            })?;
        let n = cycle.chain().axis_count();
        Ok(Self {
            server,
            _node: node,
            to_builder,
            from_builder,
            graveyard,
            pending: None,
            probation: None,
            swaps: Vec::with_capacity(4096),
            job_path: std::fs::canonicalize(&job.path)
                .ok()
                .map(|p| p.display().to_string()),
            rejected: Vec::with_capacity(MAX_REJECTIONS),
            rejected_count: 0,
            plant_deadline_misses: 0,
            plant_overruns: 0,
            history: vec![[0.0; HISTORY]; n],
            hist_pos: 0,
            hist_len: 0,
            names: job.axis_names(),
            limits: job
                .axes
                .iter()
                .map(|a| a.model.controller.torque_limit.unwrap_or(f64::INFINITY))
                .collect(),
            period_s: job.period_s,
            plugin_ids,
        })
    }

    /// Whether a freshly swapped controller is on probation (its faults roll it back instead of
    /// stopping the axes).
    pub fn in_probation(&self) -> bool {
        self.probation.is_some()
    }

    /// At the start of cycle `seq`: switches in a controller the builder finished.
    pub fn before_cycle(&mut self, cycle: &mut ControlCycle, seq: u64) {
        if self.probation.is_some() {
            return;
        }
        let Ok(built) = self.from_builder.try_recv() else {
            return;
        };
        let Some(pending) = self.pending.take() else {
            return;
        };
        let (axis, stage) = (pending.axis, pending.stage);
        match built.controller {
            Err(reason) => {
                self.refuse(&pending.req, seq, "swap", reason.to_string());
            }
            Ok(new) => {
                let check = built.check;
                let new_id = new.id().to_string();
                let new_gain = new.gain();
                let old = cycle.chain_mut().replace(axis, stage, new);
                let from = old.as_ref().map(|o| o.id().to_string()).unwrap_or_default();
                let ratio = match (old.as_ref().and_then(|o| o.gain()), new_gain) {
                    (Some(a), Some(b)) if a > 0.0 && b > a => b / a,
                    _ => 1.0,
                };
                // 0.1 % of the torque limit, or of the largest recent torque without a limit
                // (an axis at rest has no cycle-to-cycle change to scale)
                let scale = finite_or(self.limits[axis], self.max_abs(axis)).max(1e-6);
                let allowed = self.max_step(axis) * ratio + 0.001 * scale;
                self.swaps.push(SwapEvent {
                    t_s: seq as f64 * self.period_s,
                    cycle: seq,
                    axis: self.names[axis].clone(),
                    stage: stage.id().to_string(),
                    from,
                    to: new_id.clone(),
                    torque_step: 0.0,
                    allowed_step: allowed,
                    rolled_back: false,
                    reason: None,
                    phase_margin_deg: check.margins.map(|m| m.0),
                    gain_margin_db: check.margins.map(|m| m.1),
                    forced: check.force,
                    warnings: check.warnings,
                    changed: built.changed,
                    origin: pending.origin,
                });
                self.plugin_ids[axis].set(stage, Some(new_id));
                self.probation = Some(Probation {
                    axis,
                    stage,
                    entry: Some(built.entry),
                    gains: check.gains,
                    force: check.force,
                    vetoed: false,
                    states: cycle.chain().snapshot_axis(axis),
                    old,
                    left: PROBATION_CYCLES,
                    event: self.swaps.len() - 1,
                    faults_before: cycle.chain().nonfinite_faults,
                });
                self.pending = Some(pending);
            }
        }
    }

    /// Between the cycle's chain and the command's publication: in the first cycle of a swap,
    /// measures the torque step of the new controller (`torque_step`) and, when it exceeds the
    /// bumpless bound and the request did not say `force`, holds the previous torque in `cmd`
    /// instead and undoes the cycle in the axis' stages (the swap is then rolled back after the
    /// cycle, the old controller continuing from the held torque). No allocation.
    #[inline]
    pub fn vet(&mut self, cycle: &mut ControlCycle, cmd: &mut ActuatorCommand) {
        let Some(p) = self.probation.as_mut() else {
            return;
        };
        if p.left != PROBATION_CYCLES {
            return;
        }
        let torque = cmd.axes[p.axis].torque;
        let prev = if self.hist_len > 0 {
            self.history[p.axis][(self.hist_pos + HISTORY - 1) % HISTORY]
        } else {
            torque
        };
        let ev = &mut self.swaps[p.event];
        ev.torque_step = (torque - prev).abs();
        // a NaN step is the non-finite check's
        if ev.torque_step > ev.allowed_step && !p.force {
            // the cycle did not happen for this axis: its stages' states back to before it
            // (integrators, filters), the torque actually sent in its signals
            cmd.axes[p.axis].torque = prev;
            cycle.chain_mut().undo_cycle(p.axis, &p.states, prev);
            p.vetoed = true;
        }
    }

    fn max_abs(&self, axis: usize) -> f64 {
        let n = self.hist_len.min(HISTORY);
        (0..n).fold(0.0f64, |m, j| m.max(self.history[axis][j].abs()))
    }

    fn max_step(&self, axis: usize) -> f64 {
        let h = &self.history[axis];
        let n = self.hist_len.min(HISTORY);
        let mut m = 0.0f64;
        for j in 1..n {
            let a = h[(self.hist_pos + HISTORY - j) % HISTORY];
            let b = h[(self.hist_pos + HISTORY - j - 1) % HISTORY];
            m = m.max((a - b).abs());
        }
        m
    }

    /// After cycle `seq` produced `cmd`: probation checks, rollbacks, answers, new requests.
    pub fn after_cycle(&mut self, cycle: &mut ControlCycle, cmd: &ActuatorCommand, seq: u64) {
        self.probation_cycle(cycle, cmd);
        self.record_torques(cmd);
        if self.pending.is_some() {
            return;
        }
        self.serve_request(cycle, cmd, seq);
    }

    /// One cycle of a swap's probation, if one runs: its checks, then its commit or rollback and
    /// the one answer, in the order they happen.
    fn probation_cycle(&mut self, cycle: &mut ControlCycle, cmd: &ActuatorCommand) {
        let Some(p) = self.probation.as_mut() else {
            return;
        };
        let torque = cmd.axes[p.axis].torque;
        if p.left == PROBATION_CYCLES && p.force {
            let ev = &mut self.swaps[p.event];
            if ev.torque_step > ev.allowed_step {
                ev.warnings
                    .push("torque step above the bumpless bound: kept (force)".to_string());
            }
        }
        let step_too_large = p.vetoed;
        let bad = if cycle.chain().nonfinite_faults > p.faults_before {
            Some("the new controller produced a non-finite torque")
        } else if torque.abs() > self.limits[p.axis] * 1.000_001 {
            Some("the new controller exceeded the torque limit")
        } else if step_too_large {
            Some("its first torque step would have exceeded the bumpless bound (allowed_step): that cycle held the previous torque; send it with --force to keep such a swap")
        } else {
            None
        };
        p.left -= 1;
        if let Some(reason) = bad {
            let p = self.probation.take().unwrap_or_else(|| unreachable!());
            if let Some(old) = p.old {
                let failed = cycle.chain_mut().replace(p.axis, p.stage, old);
                let id = cycle.chain().axes()[p.axis].stages[p.stage.index()]
                    .as_ref()
                    .map(|c| c.id().to_string());
                self.plugin_ids[p.axis].set(p.stage, id);
                if let Some(f) = failed {
                    let _ = self.graveyard.send(ToBuilder::Retire(f));
                }
            }
            let ev = &mut self.swaps[p.event];
            ev.rolled_back = true;
            ev.reason = Some(reason.to_string());
            if let Some(pending) = self.pending.take() {
                respond(
                    &pending.req,
                    &Answer::Refused {
                        error: format!("rolled back: {reason}"),
                        swap: Some(ev.clone()),
                    },
                );
            }
        } else if p.left == 0 {
            let mut p = self.probation.take().unwrap_or_else(|| unreachable!());
            if let Some(old) = p.old {
                let _ = self.graveyard.send(ToBuilder::Retire(old));
            }
            if let Some(entry) = p.entry.take() {
                let _ = self.to_builder.send(ToBuilder::Settled {
                    axis: p.axis,
                    stage: p.stage,
                    entry,
                    gains: p.gains,
                });
            }
            if let Some(pending) = self.pending.take() {
                respond(
                    &pending.req,
                    &Answer::Swapped {
                        swap: self.swaps[p.event].clone(),
                    },
                );
            }
        }
    }

    /// Keeps the cycle's torques in the history the bumpless bound is taken from.
    fn record_torques(&mut self, cmd: &ActuatorCommand) {
        let n = self.history.len().min(MAX_AXES);
        for i in 0..n {
            self.history[i][self.hist_pos] = cmd.axes[i].torque;
        }
        self.hist_pos = (self.hist_pos + 1) % HISTORY;
        self.hist_len = (self.hist_len + 1).min(HISTORY);
    }

    /// Takes a new request, if one waits (non-blocking), and answers it or hands it to the builder.
    fn serve_request(&mut self, cycle: &ControlCycle, cmd: &ActuatorCommand, seq: u64) {
        // New request? (non-blocking)
        let Ok(Some(req)) = self.server.receive() else {
            return;
        };
        let msg = match req.payload().request() {
            Ok(m) => m,
            Err(e) => {
                self.refuse(&req, seq, e.op(), e.to_string());
                return;
            }
        };
        match msg {
            Request::Status => respond(&req, &Answer::Status(self.status(cycle, cmd, seq))),
            Request::Swap(swap) => match self.parse_swap(swap) {
                Err(e) => self.refuse(&req, seq, "swap", e.to_string()),
                Ok(job) => {
                    let (axis, stage) = (job.axis, job.stage);
                    if self.to_builder.send(ToBuilder::Build(job)).is_err() {
                        respond(&req, &Answer::refused("the plugin builder thread is gone"));
                    } else {
                        let origin = Some(req.payload().origin).filter(Origin::is_known);
                        self.pending = Some(Pending {
                            req,
                            axis,
                            stage,
                            origin,
                        });
                    }
                }
            },
        }
    }

    /// The status after cycle `seq` produced `cmd`.
    fn status(&self, cycle: &ControlCycle, cmd: &ActuatorCommand, seq: u64) -> Status {
        let axes = self
            .names
            .iter()
            .zip(&self.plugin_ids)
            .zip(&cmd.axes)
            .map(|((name, ids), a)| AxisStatus {
                axis: name.clone(),
                stages: ids.clone(),
                torque: a.torque,
                reference: a.reference,
            })
            .collect();
        Status {
            cycle: seq,
            t_s: seq as f64 * self.period_s,
            axes,
            swaps: self.swaps.len() as u64,
            nonfinite_faults: cycle.chain().nonfinite_faults,
            deadline_misses: self.plant_deadline_misses,
            plant_overruns: self.plant_overruns,
            rejected_requests: self.rejected_count,
            recent_swaps: self.swaps[self.swaps.len().saturating_sub(protocol::RECENT_SWAPS)..]
                .to_vec(),
            job: self.job_path.clone(),
        }
    }

    /// Answers `req` with a refusal and keeps it for the summary.
    fn refuse(&mut self, req: &CtlActive, seq: u64, op: &str, error: String) {
        respond(req, &Answer::refused(error.as_str()));
        self.rejected_count += 1;
        if self.rejected.len() < MAX_REJECTIONS {
            self.rejected.push(Rejection {
                cycle: seq,
                t_s: seq as f64 * self.period_s,
                op: op.to_string(),
                error,
                origin: Some(req.payload().origin).filter(Origin::is_known),
            });
        }
    }

    fn parse_swap(&self, msg: protocol::SwapRequest) -> Result<BuildJob, SwapError> {
        build_job(&self.names, msg)
    }
}

/// The builder's job for swap request `msg` on a loop of axes `names`: its axis and stage found.
pub(super) fn build_job(
    names: &[String],
    msg: protocol::SwapRequest,
) -> Result<BuildJob, SwapError> {
    let axis = names
        .iter()
        .position(|n| *n == msg.axis)
        .ok_or_else(|| SwapError::UnknownAxis {
            known: names.join(", "),
            axis: msg.axis,
        })?;
    let stage = Stage::parse(&msg.stage).ok_or(SwapError::UnknownStage(msg.stage))?;
    Ok(BuildJob {
        axis,
        stage,
        plugin: msg.plugin,
        params: msg.params,
        lib: msg.lib,
        force: msg.force,
        params_file: msg.params_file,
    })
}

fn finite_or(x: f64, d: f64) -> f64 {
    if x.is_finite() {
        x
    } else {
        d
    }
}

fn respond(req: &CtlActive, answer: &Answer) {
    let _ = req.send_copy(ControlResponse::new(answer));
}
