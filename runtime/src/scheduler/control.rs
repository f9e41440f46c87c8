//! The control service of an instance (iceoryx2 request-response `feedloop/<instance>/control`):
//! list plugins, read status, swap or retune a controller while the loop runs.
//!
//! Requests and responses are fixed-size `#[repr(C)]` buffers carrying JSON text, so the wire
//! layout never changes when a request gains a field. In the scheduler, [`ControlPlane`] polls
//! the server in the cycle's slack (non-blocking), hands swap requests to a builder thread that
//! parses and validates the new plugin outside the cycle, and switches the built controller in
//! at a cycle boundary, initialised from the old one's signals (bumpless). The first cycles after
//! a swap are a probation: a non-finite or out-of-limit torque rolls the swap back, and so does
//! a first cycle whose torque step exceeds the bumpless bound (unless the request says `force`).
//! Before that, the builder refuses a plugin in a stage it does not fill, and a gain set the loop
//! model (the one `feedloop tune` uses) finds unstable or marginal, unless `force`.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Duration;

use crate::scheduler::cycle::ControlCycle;
use crate::shared::clock::now_ns;
use crate::shared::ipc::{create_node, IpcError};
use crate::shared::wire::{ActuatorCommand, MAX_AXES};
use feedloop_control::controller::{AxisContext, Controller, PluginRegistry, Stage};
use feedloop_control::loop_model::{self, LoopGains};
use feedloop_model::job::Job;
use feedloop_model::params::ConfigError;
use iceoryx2::active_request::ActiveRequest;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;

pub mod protocol;

use crate::scheduler::plugin_lib::AbiError;
use protocol::{Answer, AxisStatus, Request, RequestError, StagePlugins, Status, SwapEvent};

/// Capacity of a request's JSON text, bytes.
pub const REQUEST_BYTES: usize = 8192;
/// Capacity of a response's JSON text, bytes.
pub const RESPONSE_BYTES: usize = 16384;

/// A control request: a [`Request`] as JSON text, e.g. `{"op":"swap","axis":"x","stage":"velocity","plugin":"pi_velocity","params":"kv_nms_per_rad = 4.0"}`.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("FeedloopControlRequestV1")]
pub struct ControlRequest {
    /// `wire::PROTOCOL_VERSION` of the sender.
    pub protocol: u32,
    /// Valid bytes in `text`.
    pub len: u32,
    /// UTF-8 JSON.
    pub text: [u8; REQUEST_BYTES],
}

/// A control response: an [`Answer`] as JSON text; `code` 0 = done, 1 = refused (reason in the
/// JSON's `error`).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("FeedloopControlResponseV1")]
pub struct ControlResponse {
    /// 0 ok, 1 refused.
    pub code: u32,
    /// Valid bytes in `text`.
    pub len: u32,
    /// UTF-8 JSON.
    pub text: [u8; RESPONSE_BYTES],
}

impl Default for ControlRequest {
    fn default() -> Self {
        Self {
            protocol: crate::shared::wire::PROTOCOL_VERSION,
            len: 0,
            text: [0; REQUEST_BYTES],
        }
    }
}

impl Default for ControlResponse {
    fn default() -> Self {
        Self {
            code: 0,
            len: 0,
            text: [0; RESPONSE_BYTES],
        }
    }
}

impl ControlRequest {
    /// A request holding `req` (refused when its JSON is longer than the buffer).
    pub fn new(req: &Request) -> Result<Self, RequestError> {
        let s = json_text(req);
        if s.len() > REQUEST_BYTES {
            return Err(RequestError::TooLong {
                len: s.len(),
                capacity: REQUEST_BYTES,
            });
        }
        let mut r = Self::default();
        r.text[..s.len()].copy_from_slice(s.as_bytes());
        r.len = s.len() as u32;
        Ok(r)
    }

    /// The request it holds.
    pub fn request(&self) -> Result<Request, RequestError> {
        let n = (self.len as usize).min(REQUEST_BYTES);
        Request::from_slice(&self.text[..n])
    }
}

impl ControlResponse {
    /// A response holding `answer` (replaced by a refusal when too long), with its code.
    pub fn new(answer: &Answer) -> Self {
        let mut s = json_text(answer);
        let mut code = answer.code();
        if s.len() > RESPONSE_BYTES {
            let short = Answer::refused("response too long for the control buffer");
            s = json_text(&short);
            code = short.code();
        }
        let mut r = Self::default();
        r.text[..s.len()].copy_from_slice(s.as_bytes());
        r.len = s.len() as u32;
        r.code = code;
        r
    }

    /// The answer it holds.
    pub fn answer(&self) -> Result<Answer, serde_json::Error> {
        let n = (self.len as usize).min(RESPONSE_BYTES);
        serde_json::from_slice(&self.text[..n])
    }
}

/// The JSON text of a request or an answer (their types always serialise).
fn json_text<T: serde::Serialize>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|e| unreachable!("control messages serialise: {e}"))
}

type CtlServer = Server<ipc::Service, ControlRequest, (), ControlResponse, ()>;
type CtlActive = ActiveRequest<ipc::Service, ControlRequest, (), ControlResponse, ()>;

fn service_name(instance: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(&format!("feedloop/{instance}/control")).map_err(|e| IpcError::Setup {
        what: "name the control service".into(),
        detail: format!("{e:?}"),
    })
}

/// Sends one request to the scheduler of `instance` and waits up to `timeout` for the answer.
pub fn request(instance: &str, req: &Request, timeout: Duration) -> Result<Answer, IpcError> {
    let node = create_node(instance, "control-client")?;
    let setup = |what: &str, e: &dyn std::fmt::Debug| IpcError::Setup {
        what: what.to_string(),
        detail: format!("{e:?}"),
    };
    let svc = node
        .service_builder(&service_name(instance)?)
        .request_response::<ControlRequest, ControlResponse>()
        .open()
        .map_err(|e| {
            setup(
                &format!("reach the control service of instance `{instance}` (is its scheduler running?)"),
                &e,
            )
        })?;
    let client = svc
        .client_builder()
        .create()
        .map_err(|e| setup("create a control client", &e))?;
    let msg = ControlRequest::new(req).map_err(|e| IpcError::Send(e.to_string()))?;
    let start = now_ns();
    let limit = timeout.as_nanos() as u64;
    // The server connects lazily: resend until a response arrives.
    let mut pending = client
        .send_copy(msg)
        .map_err(|e| IpcError::Send(format!("{e:?}")))?;
    let mut last_send = now_ns();
    loop {
        if let Some(r) = pending
            .receive()
            .map_err(|e| IpcError::Receive(format!("{e:?}")))?
        {
            return r
                .answer()
                .map_err(|e| IpcError::Receive(format!("malformed answer: {e}")));
        }
        if now_ns() - start > limit {
            return Err(IpcError::PeerTimeout {
                peer: "scheduler (control service)",
                instance: instance.to_string(),
                seconds: timeout.as_secs_f64(),
            });
        }
        if pending.number_of_server_connections() == 0 && now_ns() - last_send > 50_000_000 {
            pending = client
                .send_copy(msg)
                .map_err(|e| IpcError::Send(format!("{e:?}")))?;
            last_send = now_ns();
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

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
}

/// At most this many refusals are kept (the count goes on).
const MAX_REJECTIONS: usize = 4096;

struct BuildJob {
    axis: usize,
    stage: Stage,
    plugin: String,
    params: Option<String>,
    lib: Option<String>,
    force: bool,
    /// The file `params` came from (for errors).
    params_file: Option<String>,
}

/// A stage's plugin id and the parameters it was built from.
type StageEntry = (String, toml::Table);

/// What the builder thread is asked to do.
enum ToBuilder {
    /// Build a controller.
    Build(BuildJob),
    /// A swap passed its probation: its plugin and parameters are now the stage's current ones
    /// (the base a later retune of the same plugin merges its keys into). A rolled-back swap
    /// sends nothing, so the previous entry stays.
    Settled {
        axis: usize,
        stage: Stage,
        entry: (String, toml::Table),
        gains: LoopGains,
    },
    /// A controller taken out of the chain: dropped here, not in the cycle.
    Retire(Box<dyn Controller>),
}

/// Why a swap was refused.
#[derive(Debug, thiserror::Error)]
enum SwapError {
    /// No axis of that name.
    #[error("axis `{axis}` does not exist (axes: {known})")]
    UnknownAxis { axis: String, known: String },
    /// No stage of that name.
    #[error("unknown stage `{0}` (position, feedforward, compensator, velocity)")]
    UnknownStage(String),
    /// The plugin library refused.
    #[error(transparent)]
    Library(#[from] AbiError),
    /// The parameters, or the plugin built from them, were refused.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The plugin does not fill the stage asked for.
    #[error("{0}")]
    WrongStage(String),
    /// The loop model finds the axis unstable or marginal with the new controller.
    #[error("refused before it was applied: {0}; check the gains, or send it with --force to apply it anyway")]
    Unsafe(String),
}

struct Built {
    controller: Result<Box<dyn Controller>, SwapError>,
    /// The stage's current (plugin, parameters) once this controller is confirmed.
    entry: (String, toml::Table),
    /// What the builder found out about it.
    check: Checked,
}

/// The builder's findings on a new controller, carried into its [`SwapEvent`].
#[derive(Default)]
struct Checked {
    gains: LoopGains,
    margins: Option<(f64, f64)>,
    force: bool,
    warnings: Vec<String>,
}

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

const HISTORY: usize = 101;
const PROBATION_CYCLES: u32 = 10;

/// The scheduler's side of the control service.
pub struct ControlPlane {
    server: CtlServer,
    _node: iceoryx2::node::Node<ipc::Service>,
    to_builder: mpsc::Sender<ToBuilder>,
    from_builder: mpsc::Receiver<Built>,
    graveyard: mpsc::Sender<ToBuilder>,
    pending: Option<(CtlActive, usize, Stage)>,
    probation: Option<Probation>,
    /// Every swap so far.
    pub swaps: Vec<SwapEvent>,
    /// Refused requests (the first 4096).
    pub rejected: Vec<Rejection>,
    /// Refused requests, all of them.
    pub rejected_count: u64,
    /// The plant's deadline-miss count as of the latest sample (set by the scheduler loop).
    pub plant_deadline_misses: u32,
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
        let contexts: Vec<AxisContext> = cycle
            .chain()
            .axes()
            .iter()
            .map(|a| a.context.clone())
            .collect();
        let mut current: Vec<[(String, toml::Table); 4]> = Vec::new();
        let mut plugin_ids = Vec::new();
        let mut gains: Vec<[LoopGains; 4]> = Vec::new();
        for (i, a) in cycle.chain().axes().iter().enumerate() {
            let mut cur: [(String, toml::Table); 4] = Default::default();
            let mut ids = StagePlugins::default();
            let mut g = [LoopGains::default(); 4];
            for st in Stage::ALL {
                if let Some(c) = &a.stages[st.index()] {
                    g[st.index()] = c.loop_gains();
                    let params = job
                        .chain
                        .iter()
                        .find(|e| e.axis == i && e.stage == st)
                        .map(|e| e.params.clone())
                        .unwrap_or_default();
                    cur[st.index()] = (c.id().to_string(), params);
                    ids.set(st, Some(c.id().to_string()));
                }
            }
            current.push(cur);
            plugin_ids.push(ids);
            gains.push(g);
        }
        let model = LoopCheck {
            initial: gains.clone(),
            gains,
            delays_s: (0..job.axes.len())
                // this runtime applies a command within the period of its sample: the hold
                // and the model's own [effects.delay] are the loop's delay
                .map(|i| loop_model::loop_delay_s(job, i, 0))
                .collect(),
        };
        let (to_builder, jobs) = mpsc::channel::<ToBuilder>();
        let (done_tx, from_builder) = mpsc::channel::<Built>();
        let graveyard = to_builder.clone();
        let job_path: PathBuf = job.path.clone();
        std::thread::Builder::new()
            .name("feedloop-builder".into())
            .spawn(move || builder(jobs, done_tx, registry, contexts, current, model, job_path))
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
        let Some((req, axis, stage)) = self.pending.take() else {
            return;
        };
        match built.controller {
            Err(reason) => {
                self.refuse(&req, seq, "swap", reason.to_string());
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
                self.pending = Some((req, axis, stage));
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
    /// Kept as one function (about 125 lines): a swap's whole life after the cycle that applied
    /// it (probation checks, commit or rollback, the one answer) reads in the order it happens.
    pub fn after_cycle(&mut self, cycle: &mut ControlCycle, cmd: &ActuatorCommand, seq: u64) {
        let n = self.history.len().min(MAX_AXES);
        if let Some(p) = self.probation.as_mut() {
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
                if let Some((req, _, _)) = self.pending.take() {
                    respond(
                        &req,
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
                if let Some((req, _, _)) = self.pending.take() {
                    respond(
                        &req,
                        &Answer::Swapped {
                            swap: self.swaps[p.event].clone(),
                        },
                    );
                }
            }
        }
        for i in 0..n {
            self.history[i][self.hist_pos] = cmd.axes[i].torque;
        }
        self.hist_pos = (self.hist_pos + 1) % HISTORY;
        self.hist_len = (self.hist_len + 1).min(HISTORY);

        if self.pending.is_some() {
            return;
        }
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
            Request::Status => {
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
                let status = Status {
                    cycle: seq,
                    t_s: seq as f64 * self.period_s,
                    axes,
                    swaps: self.swaps.len() as u64,
                    nonfinite_faults: cycle.chain().nonfinite_faults,
                    deadline_misses: self.plant_deadline_misses,
                    rejected_requests: self.rejected_count,
                    recent_swaps: self.swaps
                        [self.swaps.len().saturating_sub(protocol::RECENT_SWAPS)..]
                        .to_vec(),
                    job: self.job_path.clone(),
                };
                respond(&req, &Answer::Status(status));
            }
            Request::Swap(swap) => match self.parse_swap(swap) {
                Err(e) => self.refuse(&req, seq, "swap", e.to_string()),
                Ok(job) => {
                    let (axis, stage) = (job.axis, job.stage);
                    if self.to_builder.send(ToBuilder::Build(job)).is_err() {
                        respond(&req, &Answer::refused("the plugin builder thread is gone"));
                    } else {
                        self.pending = Some((req, axis, stage));
                    }
                }
            },
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
            });
        }
    }

    fn parse_swap(&self, msg: protocol::SwapRequest) -> Result<BuildJob, SwapError> {
        let axis = self
            .names
            .iter()
            .position(|n| *n == msg.axis)
            .ok_or_else(|| SwapError::UnknownAxis {
                known: self.names.join(", "),
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

/// What the builder needs to judge a new controller with the loop model.
struct LoopCheck {
    /// Per axis, what each stage's current controller contributes.
    gains: Vec<[LoopGains; 4]>,
    /// The same for the chain the job started with (the loop its operator accepted).
    initial: Vec<[LoopGains; 4]>,
    /// Per axis, the transport delay of the margin check (the model's own), s.
    delays_s: Vec<f64>,
}

fn builder(
    jobs: mpsc::Receiver<ToBuilder>,
    done: mpsc::Sender<Built>,
    registry: Arc<dyn PluginRegistry>,
    contexts: Vec<AxisContext>,
    mut current: Vec<[(String, toml::Table); 4]>,
    mut model: LoopCheck,
    job_path: PathBuf,
) {
    // Blocks until there is work: no periodic wake-ups to preempt a spinning loop.
    loop {
        let job = match jobs.recv() {
            Ok(ToBuilder::Build(j)) => j,
            Ok(ToBuilder::Retire(old)) => {
                drop(old);
                continue;
            }
            Ok(ToBuilder::Settled {
                axis,
                stage,
                entry,
                gains,
            }) => {
                if let Some(slot) = current.get_mut(axis) {
                    slot[stage.index()] = entry;
                }
                if let Some(slot) = model.gains.get_mut(axis) {
                    slot[stage.index()] = gains;
                }
                continue;
            }
            Err(mpsc::RecvError) => return,
        };
        let built = match build_one(&job, registry.as_ref(), &contexts, &current, &job_path) {
            Ok((c, entry)) => match judge(&job, c.as_ref(), &contexts, &model) {
                Ok(check) => Built {
                    controller: Ok(c),
                    entry,
                    check,
                },
                Err(e) => {
                    drop(c);
                    Built {
                        controller: Err(e),
                        entry: Default::default(),
                        check: Checked::default(),
                    }
                }
            },
            Err(e) => Built {
                controller: Err(e),
                entry: Default::default(),
                check: Checked::default(),
            },
        };
        if done.send(built).is_err() {
            return;
        }
    }
}

/// The loop model's verdict on the axis with `new` in the stage of `job`: its margins, or the
/// refusal of an unstable or marginal set (a warning when the request says `force`).
fn judge(
    job: &BuildJob,
    new: &dyn Controller,
    contexts: &[AxisContext],
    model: &LoopCheck,
) -> Result<Checked, SwapError> {
    let ctx = &contexts[job.axis];
    let delay = model.delays_s[job.axis];
    let margins_of = |stages: &[LoopGains; 4]| {
        LoopGains::combine(stages)
            .and_then(|g| loop_model::margins(&ctx.plant, g, ctx.period_s, delay))
    };
    let mut stages = model.gains[job.axis];
    let gains = new.loop_gains();
    stages[job.stage.index()] = gains;
    let mut check = Checked {
        gains,
        force: job.force,
        ..Default::default()
    };
    match margins_of(&stages) {
        None => check.warnings.push(
            "margins not checked: the loop's gains are not all known (a plugin that reports none)"
                .into(),
        ),
        Some((pm, gm)) => {
            check.margins = Some((pm, gm));
            if let Some(why) = loop_model::margin_failure(pm, gm) {
                // a loop already short of margin (now, or as the job started it) is not blamed on
                // a swap that does not make it worse (a feedforward swap, a softer gain)
                let no_worse = [&model.gains[job.axis], &model.initial[job.axis]]
                    .into_iter()
                    .filter_map(margins_of)
                    .any(|(p0, g0)| pm >= p0 - 0.5 && gm >= g0 - 0.1);
                if no_worse {
                    check.warnings.push(format!(
                        "{why}: no worse than the loop before this swap or as the job started it"
                    ));
                } else if !job.force {
                    return Err(SwapError::Unsafe(why));
                } else {
                    check
                        .warnings
                        .push(format!("{why}: applied anyway (force)"));
                }
            }
        }
    }
    Ok(check)
}

fn build_one(
    job: &BuildJob,
    registry: &dyn PluginRegistry,
    contexts: &[AxisContext],
    current: &[[(String, toml::Table); 4]],
    job_path: &Path,
) -> Result<(Box<dyn Controller>, StageEntry), SwapError> {
    if let Some(lib) = &job.lib {
        let c = crate::scheduler::plugin_lib::LibController::load(
            Path::new(lib),
            &job.plugin,
            job.params.as_deref().unwrap_or(""),
            &contexts[job.axis],
        )?;
        if let Some(fits) = c.stages() {
            if !fits.contains(&job.stage) {
                return Err(SwapError::WrongStage(crate::scheduler::chain::wrong_stage(
                    &job.plugin,
                    job.stage,
                    &fits,
                )));
            }
        }
        // A library's parameters are its own text: a later built-in retune starts afresh.
        return Ok((
            Box::new(c),
            (format!("{}@{lib}", job.plugin), toml::Table::new()),
        ));
    }
    let fits = registry.stages(&job.plugin);
    if !fits.is_empty() && !fits.contains(&job.stage) {
        return Err(SwapError::WrongStage(crate::scheduler::chain::wrong_stage(
            &job.plugin,
            job.stage,
            &fits,
        )));
    }
    let src = Path::new(job.params_file.as_deref().unwrap_or("<swap --params>"));
    let (cur_id, cur_params) = &current[job.axis][job.stage.index()];
    let mut params = if *cur_id == job.plugin {
        cur_params.clone()
    } else {
        toml::Table::new()
    };
    if let Some(text) = &job.params {
        let t = feedloop_model::params::parse_toml(src, text)?;
        for (k, v) in t {
            params.insert(k, v);
        }
    }
    let c = registry.create(&job.plugin, &params, &contexts[job.axis], src)?;
    let _ = job_path;
    Ok((c, (job.plugin.clone(), params)))
}
