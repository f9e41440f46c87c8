//! `feedloop scope`: a live scope of a running loop (or of recorded traces) in the browser.
//!
//! The process attaches to the loop as one more iceoryx2 subscriber of the blocks its recorders
//! publish after writing them ([`feedloop_runtime::shared::scope`]), keeps the last seconds in
//! a bounded ring ([`store::Store`]) and serves a page (embedded in the binary) that draws them,
//! triggers on levels and on the loop's own events, saves and reloads captures as traces, and
//! talks to the loop's control service. Nothing here runs in the loop's processes.

pub mod guard;
mod http;
pub mod server;
pub mod store;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use feedloop_model::units::si;
use feedloop_runtime::scheduler::control::protocol::{Answer, Request, Status};
use feedloop_runtime::scheduler::control::{request, request_from, Origin};
use feedloop_runtime::shared::clock::{now_ns, sleep_until_ns};
use feedloop_runtime::shared::scope::{ReceivedBlock, ScopeRecords, ScopeSubscriber};
use feedloop_trace::Trace;

use store::Store;

/// Options of `feedloop scope`.
#[derive(clap::Args, Debug)]
pub struct ScopeArgs {
    /// Instance of the running loop to watch (`feedloop run ... --instance NAME`).
    #[arg(long, conflicts_with_all = ["trace", "report"])]
    pub instance: Option<String>,
    /// A recorded trace (format v1) to open instead of a running loop.
    #[arg(long)]
    pub trace: Option<PathBuf>,
    /// A folder of traces (e.g. a workbench report): every `*.csv` in it can be opened.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// TCP port of the page (0: any free port).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Address to listen on; the page carries the loop's control service, so only the local
    /// machine unless asked otherwise (beyond it, the token is the only protection and the
    /// traffic is not encrypted: prefer an SSH tunnel, docs/scope.md).
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: String,
    /// Watch only: triggers and captures work, swaps and retunes are refused.
    #[arg(long)]
    pub read_only: bool,
    /// Seconds of the loop kept for the page (a bounded ring; older cycles are overwritten).
    #[arg(long, default_value_t = 20.0)]
    pub history_s: f64,
    /// Folder where saved captures go.
    #[arg(long, default_value = "out/scope")]
    pub captures: PathBuf,
    /// Nice value of the scope process (0..19): a viewer yields the CPU to the loop it watches.
    #[arg(long, default_value_t = 10)]
    pub nice: i32,
    /// Stop after this many seconds (0: run until interrupted).
    #[arg(long, default_value_t = 0.0)]
    pub duration_s: f64,
}

/// Most cycles the ring holds, whatever `--history-s` asks (memory bound: 11 columns of f64
/// per axis).
const MAX_RING: usize = 2_000_000;
/// Pause of the feed when the loop's queue is empty.
const FEED_PAUSE: Duration = Duration::from_millis(50);
/// How often the loop's status is asked for (its answer is built in the scheduler's slack).
const STATUS_EVERY: Duration = Duration::from_secs(1);
/// A page that has not polled for this long has left; another may attach.
const LEASE: Duration = Duration::from_secs(3);
/// Answers to the page's control requests kept for display.
const MAX_ANSWERS: usize = 64;

/// One answer of the control service to a request from the page.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PageAnswer {
    /// Cycle the answer refers to (the swap cycle, else the newest cycle when it came).
    pub cycle: u64,
    /// Its time, s.
    pub t_s: f64,
    /// accepted | refused | rolled_back | error.
    pub outcome: String,
    /// One line for the plot.
    pub summary: String,
    /// The full answer.
    pub answer: serde_json::Value,
}

/// The page that is attached.
#[derive(Debug, Clone)]
pub struct Session {
    token: String,
    addr: String,
    since: std::time::SystemTime,
    last_seen: Instant,
}

/// State shared by the feed, the status poller and the page's requests.
pub struct Shared {
    /// The ring of the live loop, or the opened trace.
    pub store: Store,
    /// The last capture.
    pub capture: Option<store::Capture>,
    /// The view of the last capture (or a trace opened from the page), when there is one.
    pub capture_view: Option<Store>,
    /// What the page shows in its banner about the loop's connection.
    pub connection: String,
    /// Whether the loop is running now.
    pub running: bool,
    /// The loop's latest status.
    pub status: Option<Status>,
    /// Answers to the page's requests.
    pub answers: std::collections::VecDeque<PageAnswer>,
    /// Blocks that did not decode.
    pub bad_blocks: u64,
    /// The run being watched.
    pub run_id: Option<u64>,
    /// Runs seen (restarts + 1).
    pub runs: u64,
    /// The attached page.
    pub session: Option<Session>,
    /// Traces the page can open (`--report`, `--trace`).
    pub traces: Vec<PathBuf>,
    /// The job whose path the contour error is measured against.
    contour_job: Option<String>,
    /// Swap cycles already marked (the status lists recent ones again and again).
    seen_swaps: Vec<(u64, String, String)>,
}

impl Shared {
    /// A fresh ring for `axes` that keeps the armed trigger and the contour measure.
    fn renew_store(&mut self, axes: &[String], capacity: usize, period_s: f64) {
        let mut st = Store::live(axes, capacity);
        st.period_s = period_s;
        st.trigger = self.store.trigger.take();
        st.contour = self.store.contour.take();
        self.store = st;
    }

    /// Marks a swap on the plot once (the status lists recent swaps again and again).
    fn mark_swap(&mut self, ev: &feedloop_runtime::scheduler::control::protocol::SwapEvent) {
        let key = (ev.cycle, ev.axis.clone(), ev.stage.clone());
        if !self.seen_swaps.contains(&key) {
            self.seen_swaps.push(key);
            self.store.push_swap(ev);
        }
    }
}

/// Everything the server threads need.
pub struct Ctx {
    /// The state.
    pub shared: Mutex<Shared>,
    /// Instance watched (live mode).
    pub instance: Option<String>,
    /// Where captures are saved.
    pub captures: PathBuf,
    /// Cycles the ring holds.
    pub history_s: f64,
    /// Set to end the scope.
    pub stop: AtomicBool,
    /// Views (curve requests) served to the page.
    pub views: std::sync::atomic::AtomicU64,
    /// Who is answered (Host, token, Origin, read-only).
    pub guard: guard::Guard,
}

impl Ctx {
    /// The shared state, locked (a panicked holder leaves it usable: every update is whole).
    pub fn lock(&self) -> MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Prints a line on the command line (time-stamped), and keeps it for the page's banner.
    pub fn say(&self, line: String) {
        eprintln!("feedloop scope: {line}");
        self.lock().connection = line;
    }
}

fn ring_cycles(history_s: f64, period_s: f64) -> usize {
    ((history_s / period_s).ceil() as usize).clamp(1000, MAX_RING)
}

/// `feedloop scope`.
pub fn run(a: &ScopeArgs) -> Result<ExitCode> {
    checked(a)?;
    let opened = opened(a)?;
    if !(0..=19).contains(&a.nice) {
        bail!("--nice {}: 0..19", a.nice);
    }
    // SAFETY: plain setpriority on this process.
    unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, a.nice) };
    crate::signals::install();
    let server = http::bind(&a.bind, a.port)?;
    let addr = server.local_addr();
    let guard = guard::Guard::new(addr.ip(), addr.port(), a.read_only)?;
    if guard.beyond_loopback() {
        eprintln!(
            "feedloop scope: warning: listening on {addr}, beyond this machine: the token in the \
             address is the only protection, and the traffic (token included) is not encrypted; \
             prefer the default --bind 127.0.0.1 and an SSH tunnel (ssh -L {p}:127.0.0.1:{p} \
             HOST), see docs/scope.md",
            p = addr.port()
        );
    }
    println!("feedloop scope: open {}", guard.url());
    let ctx = Arc::new(context(a, opened, guard));
    let mut threads = http::serve(server.clone(), ctx.clone());
    if let Some(instance) = a.instance.clone() {
        let c = ctx.clone();
        threads.push(std::thread::spawn(move || feed(&c, &instance)));
        let c = ctx.clone();
        let instance = a.instance.clone().unwrap_or_default();
        threads.push(std::thread::spawn(move || poll_status(&c, &instance)));
    }
    let started = Instant::now();
    while !ctx.stop.load(Ordering::Relaxed) {
        if a.duration_s > 0.0 && started.elapsed().as_secs_f64() >= a.duration_s {
            break;
        }
        if crate::signals::STOP.load(Ordering::Relaxed) {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    ctx.stop.store(true, Ordering::Relaxed);
    server.stop();
    for t in threads {
        let _ = t.join();
    }
    Ok(ExitCode::SUCCESS)
}

/// The options checked that need nothing read.
fn checked(a: &ScopeArgs) -> Result<()> {
    if a.instance.is_none() && a.trace.is_none() && a.report.is_none() {
        bail!("feedloop scope needs --instance NAME (a running loop), or --trace T.csv / --report DIR (recordings)");
    }
    if !(a.history_s > 0.0 && a.history_s.is_finite()) {
        bail!(
            "--history-s must be a positive number of seconds, got {}",
            a.history_s
        );
    }
    if let Some(i) = &a.instance {
        if !feedloop_model::job::valid_name(i, true) {
            bail!("invalid instance name `{i}`: use lowercase letters, digits, `_` and `-` (at most 64)");
        }
    }
    Ok(())
}

/// The traces asked for (the first one read: it is shown), and what the banner says.
struct Opened {
    traces: Vec<PathBuf>,
    store: Store,
    connection: String,
}

/// Reads the traces asked for (the first one is shown), else makes an empty ring waiting for the
/// loop.
fn opened(a: &ScopeArgs) -> Result<Opened> {
    let mut traces = Vec::new();
    if let Some(dir) = &a.report {
        traces = csv_files(dir)?;
        if traces.is_empty() && a.trace.is_none() {
            bail!("{}: no trace (*.csv) in this folder", dir.display());
        }
    }
    if let Some(t) = &a.trace {
        traces.insert(0, t.clone());
    }
    let (store, connection) = match traces.first() {
        Some(t) => (
            Store::from_trace(&read_trace(t)?),
            format!("trace {}", t.display()),
        ),
        None => (
            Store::live(&[], 1000),
            format!(
                "waiting for loop `{}`",
                a.instance.as_deref().unwrap_or_default()
            ),
        ),
    };
    Ok(Opened {
        traces,
        store,
        connection,
    })
}

/// The scope's state at its start.
fn context(a: &ScopeArgs, o: Opened, guard: guard::Guard) -> Ctx {
    let Opened {
        traces,
        store,
        connection,
    } = o;
    Ctx {
        shared: Mutex::new(Shared {
            store,
            capture: None,
            capture_view: None,
            connection,
            running: false,
            status: None,
            answers: Default::default(),
            bad_blocks: 0,
            run_id: None,
            runs: 0,
            session: None,
            traces,
            seen_swaps: Vec::new(),
            contour_job: None,
        }),
        instance: a.instance.clone(),
        captures: a.captures.clone(),
        history_s: a.history_s,
        stop: AtomicBool::new(false),
        views: Default::default(),
        guard,
    }
}

fn csv_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).with_context(|| format!("reading folder {}", d.display()))? {
            let p = e?.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "csv") {
                out.push(p);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Reads a trace with the format's own errors (file, line, what is wrong).
pub fn read_trace(p: &Path) -> Result<Trace> {
    Ok(Trace::read(p)?)
}

/// The live feed: subscribes to the loop's scope services and fills the ring. Survives the loop
/// not running yet, ending and restarting.
fn feed(ctx: &Ctx, instance: &str) {
    // wake when asked, not up to 50 us later (the default timer slack), so the slot holds
    // SAFETY: plain prctl on the calling thread.
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1000, 0, 0, 0) };
    let Some(sub) = subscribe(ctx, instance) else {
        return;
    };
    let mut was_running: Option<bool> = None;
    let mut last_check = Instant::now() - Duration::from_secs(1);
    let mut bad = 0u64;
    while !ctx.stop.load(Ordering::Relaxed) {
        if last_check.elapsed() >= Duration::from_millis(250) {
            last_check = Instant::now();
            tell_running(ctx, instance, &sub, &mut was_running);
        }
        drain(ctx, instance, &sub, &mut bad);
        sleep_to_slack(ctx);
    }
}

/// The loop's scope services, retried once a second until they open; `None` when the scope
/// ends first.
fn subscribe(ctx: &Ctx, instance: &str) -> Option<ScopeSubscriber> {
    loop {
        match ScopeSubscriber::open(instance) {
            Ok(s) => return Some(s),
            Err(e) => {
                ctx.say(format!("cannot watch loop `{instance}`: {e}; retrying"));
                if ctx.stop.load(Ordering::Relaxed) {
                    return None;
                }
                std::thread::sleep(Duration::from_secs(1));
            }
        }
    }
}

/// Says when the loop starts or ends (`was_running`: what was said last, `None` before).
fn tell_running(ctx: &Ctx, instance: &str, sub: &ScopeSubscriber, was_running: &mut Option<bool>) {
    let (p, s) = sub.loop_running();
    let running = p && s;
    if *was_running != Some(running) {
        let newest = ctx.lock().store.newest;
        let line = match (running, *was_running, newest) {
            (true, _, _) => format!("attached to loop `{instance}`"),
            (false, None, _) => format!(
                "no loop of instance `{instance}` is running; waiting for one (start it \
                 with `feedloop run JOB --out DIR --instance {instance}`)"
            ),
            (false, Some(_), Some(k)) => format!(
                "loop `{instance}` ended after cycle {k}; the last {} s stay on the page; \
                 waiting for it to start again",
                ctx.history_s
            ),
            (false, Some(_), None) => format!("loop `{instance}` ended"),
        };
        ctx.say(line);
        let mut sh = ctx.lock();
        sh.running = running;
        *was_running = Some(running);
    }
}

/// Takes every block waiting in the queue into the ring.
fn drain(ctx: &Ctx, instance: &str, sub: &ScopeSubscriber, bad: &mut u64) {
    loop {
        match sub.receive(bad) {
            Ok(Some(b)) => {
                if let Some(runs) = take_block(ctx, &b, *bad) {
                    if runs > 1 {
                        ctx.say(format!(
                            "loop `{instance}` restarted (run {runs}): the page follows the new run"
                        ));
                    }
                }
            }
            Ok(None) => break,
            Err(e) => {
                ctx.say(format!("scope feed of `{instance}`: {e}"));
                break;
            }
        }
    }
}

/// Puts block `b` into the ring, a new ring when it starts a new run of the loop; returns the
/// run count when it did.
fn take_block(ctx: &Ctx, b: &ReceivedBlock, bad: u64) -> Option<u64> {
    let mut sh = ctx.lock();
    sh.bad_blocks = bad;
    let new_run = sh.run_id != Some(b.run_id) && matches!(b.records, ScopeRecords::Plant(_));
    if new_run {
        let names = sh
            .status
            .as_ref()
            .map(|s| s.axes.iter().map(|a| a.axis.clone()).collect())
            .filter(|n: &Vec<String>| n.len() == b.axis_count)
            .unwrap_or_else(|| (0..b.axis_count).map(|i| format!("axis{i}")).collect());
        // a trigger armed before the loop started waits for it
        sh.renew_store(&names, ring_cycles(ctx.history_s, b.period_s), b.period_s);
        sh.seen_swaps.clear();
        sh.run_id = Some(b.run_id);
        sh.runs += 1;
    }
    // (the run is told by the plant's blocks; the scheduler's carry its own
    // process's start, and land by cycle number in the plant's run)
    match &b.records {
        ScopeRecords::Plant(r) => {
            sh.store.ring_dropped = b.ring_dropped;
            sh.store.block_seen(0, b.block);
            sh.store.push_plant(r)
        }
        ScopeRecords::Scheduler(r) if sh.run_id.is_some() => {
            sh.store.block_seen(1, b.block);
            sh.store.push_sched(r)
        }
        ScopeRecords::Scheduler(_) => {}
    }
    new_run.then_some(sh.runs)
}

/// Sleeps until the feed looks again.
fn sleep_to_slack(ctx: &Ctx) {
    // Every wake-up of this process takes a core from the loop for a moment on a small
    // machine. So it drains the queue at once, looks again only FEED_PAUSE later (the queue
    // holds a quarter of a second), and, like the loop's own recorders, wakes in the slack
    // of a period rather than at a random moment that may fall on a round trip.
    let (anchor, period_s) = {
        let sh = ctx.lock();
        (sh.store.last_published_ns, sh.store.period_s)
    };
    let period_ns = (period_s * 1e9) as u64;
    let earliest = now_ns() + FEED_PAUSE.as_nanos() as u64;
    match slack_slot(anchor, period_ns, earliest) {
        Some(t) => sleep_until_ns(t),
        None => std::thread::sleep(FEED_PAUSE),
    }
}

/// The first time at or after `earliest_ns` that lies 0.4 of a period after a period's start
/// (`anchor_ns` is one, `period_ns` long); `None` before the loop's timing is known.
fn slack_slot(anchor_ns: u64, period_ns: u64, earliest_ns: u64) -> Option<u64> {
    if anchor_ns == 0 || period_ns == 0 {
        return None;
    }
    let first = anchor_ns + period_ns * 2 / 5;
    let k = earliest_ns.saturating_sub(first).div_ceil(period_ns);
    Some(first + k * period_ns)
}

/// Asks the loop's control service for its status once a second: axes, stages, and the swaps
/// other clients made.
fn poll_status(ctx: &Ctx, instance: &str) {
    while !ctx.stop.load(Ordering::Relaxed) {
        let running = ctx.lock().running;
        if running {
            if let Ok(Answer::Status(st)) =
                request(instance, &Request::Status, Duration::from_millis(800))
            {
                let mut sh = ctx.lock();
                let names: Vec<String> = st.axes.iter().map(|a| a.axis.clone()).collect();
                if sh.store.axes != names {
                    sh.store.rename_axes(&names);
                }
                for ev in &st.recent_swaps {
                    sh.mark_swap(ev);
                }
                let job = st.job.clone();
                sh.status = Some(st);
                let new_job = job.is_some() && sh.contour_job != job;
                drop(sh);
                if new_job {
                    let path = job.unwrap_or_default();
                    let f = contour_of(Path::new(&path));
                    let mut sh = ctx.lock();
                    match f {
                        Ok(f) => sh.store.contour = Some(f),
                        Err(e) => eprintln!("feedloop scope: no contour error ({path}: {e:#})"),
                    }
                    sh.contour_job = Some(path);
                }
            }
        }
        std::thread::sleep(STATUS_EVERY);
    }
}

/// The contour error of the job at `path`, as `feedloop run` measures it (the trajectory's own
/// contour, else the distance to the commanded path of the first two axes).
fn contour_of(path: &Path) -> Result<store::ContourFn> {
    let job = feedloop_model::job::Job::load(path)?;
    let cycle =
        feedloop_runtime::scheduler::cycle::ControlCycle::new(&job, &feedloop_plugins::Builtins)?;
    let judge = feedloop_analysis::sim::ContourJudge::new(&job, &cycle);
    Ok(Box::new(move |t, rows| judge.error_m(&cycle, t, rows)))
}

/// Sends a swap from the page at `peer` to the loop (its origin: that page) and keeps the answer
/// for the plot.
pub fn page_swap(ctx: &Ctx, body: &serde_json::Value, peer: &str) -> Result<PageAnswer> {
    let Some(instance) = &ctx.instance else {
        bail!("this scope shows recordings; swaps need a running loop (--instance)");
    };
    let get = |k: &str| body.get(k).and_then(|v| v.as_str()).map(str::to_string);
    let need = |k: &str| {
        get(k)
            .filter(|s| !s.is_empty())
            .with_context(|| format!("swap needs `{k}`"))
    };
    let params = get("params").filter(|p| !p.trim().is_empty());
    if let Some(p) = &params {
        feedloop_model::params::parse_toml(Path::new("<page params>"), p)?;
    }
    let req = Request::Swap(
        feedloop_runtime::scheduler::control::protocol::SwapRequest {
            axis: need("axis")?,
            stage: need("stage")?,
            plugin: need("plugin")?,
            params,
            lib: None,
            force: body.get("force").and_then(|v| v.as_bool()).unwrap_or(false),
            params_file: Some("<page params>".into()),
        },
    );
    let answer = request_from(
        instance,
        &req,
        Origin::scope_page(peer),
        Duration::from_secs(5),
    )?;
    let mut sh = ctx.lock();
    let newest = sh.store.newest.unwrap_or(0);
    let (cycle, outcome, summary) = match &answer {
        Answer::Swapped { swap } => (
            swap.cycle,
            "accepted",
            format!(
                "{} {} -> {}: torque step {} within bound {}",
                swap.axis,
                swap.stage,
                swap.to,
                si(swap.torque_step, "N m"),
                si(swap.allowed_step, "N m")
            ),
        ),
        Answer::Refused {
            error,
            swap: Some(swap),
        } => (swap.cycle, "rolled_back", format!("rolled back: {error}")),
        Answer::Refused { error, swap: None } => (newest, "refused", format!("refused: {error}")),
        Answer::Status(_) => (newest, "error", "unexpected answer".into()),
    };
    if let Answer::Swapped { swap }
    | Answer::Refused {
        swap: Some(swap), ..
    } = &answer
    {
        sh.mark_swap(swap);
    }
    let a = PageAnswer {
        cycle,
        t_s: cycle as f64 * sh.store.period_s,
        outcome: outcome.into(),
        summary,
        answer: serde_json::to_value(&answer)?,
    };
    if sh.answers.len() >= MAX_ANSWERS {
        sh.answers.pop_front();
    }
    sh.answers.push_back(a.clone());
    drop(sh);
    eprintln!(
        "feedloop scope: swap from the page at {peer}: {} ({})",
        a.summary, a.outcome
    );
    Ok(a)
}

/// Writes `cap` as a trace (format v1) into the captures folder; returns its path.
pub fn save_capture(ctx: &Ctx, cap: &store::Capture) -> Result<PathBuf> {
    std::fs::create_dir_all(&ctx.captures)
        .with_context(|| format!("creating {}", ctx.captures.display()))?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let p = ctx
        .captures
        .join(format!("capture-{stamp}-cycle{}.csv", cap.trigger_cycle));
    let tr = capture_trace(cap, &p, ctx.instance.as_deref())?;
    tr.write(&p)
        .with_context(|| format!("writing {}", p.display()))?;
    Ok(p)
}

/// A capture as a trace (format v1): `t`, then the store's columns; the trigger in the metadata.
pub fn capture_trace(cap: &store::Capture, path: &Path, instance: Option<&str>) -> Result<Trace> {
    let mut columns = vec!["t".to_string()];
    columns.extend(cap.columns.iter().cloned());
    let n = cap.data.first().map_or(0, Vec::len);
    let mut data = vec![(0..n)
        .map(|i| (cap.first_cycle + i as u64) as f64 * cap.period_s)
        .collect::<Vec<f64>>()];
    data.extend(cap.data.iter().cloned());
    let mut meta = vec![
        ("source".to_string(), "feedloop-scope".to_string()),
        ("period_s".to_string(), format!("{}", cap.period_s)),
        (
            "trigger".to_string(),
            cap.describe.replace(['\n', '\r'], " "),
        ),
        ("trigger_t_s".to_string(), format!("{}", cap.trigger_t_s)),
        ("held_cells".to_string(), cap.held_cells.to_string()),
    ];
    if let Some(i) = instance {
        meta.push(("instance".to_string(), i.to_string()));
    }
    Ok(Trace::from_columns(path, meta, columns, data)?)
}

/// A scope's state, its page server and the server's worker threads.
pub type Serving = (
    Arc<Ctx>,
    Arc<server::Server>,
    Vec<std::thread::JoinHandle<()>>,
);

/// The page's server of a scope started as `a` asks, on a free port of `a.bind`, but without the
/// loop's feed, the status poller or the signal handlers: what the request fuzz target and the
/// request property test drive ([`crate::scope_sandbox`]). Stop it by setting `ctx.stop` and
/// stopping the server. Its token is `token`.
pub fn serve_sandbox(a: &ScopeArgs, token: &str) -> Result<Serving> {
    checked(a)?;
    let opened = opened(a)?;
    let server = http::bind(&a.bind, 0)?;
    let addr = server.local_addr();
    let guard = guard::Guard::with_token(addr.ip(), addr.port(), a.read_only, token.into());
    let ctx = Arc::new(context(a, opened, guard));
    let threads = http::serve(server.clone(), ctx.clone());
    Ok((ctx, server, threads))
}

#[cfg(test)]
mod tests {
    use super::slack_slot;

    #[test]
    fn the_feed_wakes_four_tenths_into_a_period_not_before_it_is_due() {
        assert_eq!(slack_slot(0, 100, 5), None);
        assert_eq!(slack_slot(1_000, 100, 0), Some(1_040));
        assert_eq!(slack_slot(1_000, 100, 1_040), Some(1_040));
        assert_eq!(slack_slot(1_000, 100, 1_041), Some(1_140));
        assert_eq!(slack_slot(1_000, 100, 987_654), Some(987_740));
    }
}
