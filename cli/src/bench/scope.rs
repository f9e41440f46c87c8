//! `feedloop bench scope`: does watching the loop cost the loop anything?
//!
//! Runs the benchmark chain of `bench latency` (X-C grinder, four controllers) in pairs: once
//! alone, once with `feedloop scope` attached and a headless Chromium drawing its page. Prints
//! both runs' latency percentiles and misses side by side and writes `scope-bench.json`; samples
//! the scope process's resident memory through each run it watched (flat over a long run, or
//! not).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use serde_json::{json, Value};

use feedloop_analysis::latency::{attribute_misses, RunFigures};
use feedloop_model::job::WaitKind;

use feedloop_trace::log::{read_log, PlantRecord, SchedRecord};

use super::job::{bench_job, run_processes, ChainArgs};

/// Options of `feedloop bench scope`.
#[derive(clap::Args, Debug)]
pub struct ScopeBenchArgs {
    /// Cycles of each run.
    #[arg(long, default_value_t = 300_000)]
    pub cycles: u64,
    #[command(flatten)]
    pub chain: ChainArgs,
    /// Pairs of runs (without, with), alternating.
    #[arg(long, default_value_t = 1)]
    pub pairs: u32,
    /// The browser that draws the page (default: chromium, chromium-browser or google-chrome on
    /// PATH).
    #[arg(long)]
    pub browser: Option<PathBuf>,
    /// Seconds between two samples of the scope's resident memory.
    #[arg(long, default_value_t = 5.0)]
    pub rss_every_s: f64,
    /// Nice value of the scope and the browser (0..19): the viewer yields the CPU to the loop.
    #[arg(long, default_value_t = 19)]
    pub viewer_nice: i32,
    /// Run the scope and the browser under SCHED_IDLE: only on a core the loop leaves idle
    /// (with a blocking or hybrid wait; a busy loop leaves none).
    #[arg(long)]
    pub viewer_idle: bool,
    /// Also a run with the scope attached but no browser, between the two.
    #[arg(long)]
    pub scope_only: bool,
    /// Only the runs with the scope (e.g. a long run for the scope's memory alone).
    #[arg(long)]
    pub with_only: bool,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

struct Kill(Child);

impl Drop for Kill {
    fn drop(&mut self) {
        // SAFETY: signalling our own child, then reaping it.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGINT) };
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(3) {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn find_browser(asked: Option<&Path>) -> Result<PathBuf> {
    if let Some(b) = asked {
        return Ok(b.to_path_buf());
    }
    feedloop_cli::browser::on_path().with_context(|| {
        format!(
            "{}: install Debian's `chromium`, or name one with --browser",
            feedloop_cli::browser::NOT_FOUND
        )
    })
}

/// Makes the child about to be started run at nice value `nice`, under SCHED_IDLE when `idle`
/// (a viewer yields to the loop).
fn lower_priority(cmd: &mut Command, nice: i32, idle: bool) {
    use std::os::unix::process::CommandExt;
    // SAFETY: setpriority and sched_setscheduler are async-signal-safe and touch no memory of
    // the parent.
    unsafe {
        cmd.pre_exec(move || {
            libc::setpriority(libc::PRIO_PROCESS, 0, nice);
            if idle {
                let p = libc::sched_param { sched_priority: 0 };
                libc::sched_setscheduler(0, libc::SCHED_IDLE, &p);
            }
            Ok(())
        });
    }
}

/// Resident set of process `pid`, bytes.
fn rss_bytes(pid: u32) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = s.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// A GET with the scope's token but without a page session (the scope's `/api/stats`).
fn get(addr: &str, token: &str, path: &str) -> Option<Value> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(2))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nx-scope-token: {token}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    serde_json::from_str(out.split_once("\r\n\r\n")?.1).ok()
}

fn figures(dir: &Path, period_ns: u64) -> Result<Value> {
    let recs = read_log::<PlantRecord>(&dir.join("plant.log"))?.records;
    let sched = read_log::<SchedRecord>(&dir.join("scheduler.log"))
        .map(|l| l.records)
        .unwrap_or_default();
    let f = RunFigures::from_records(&recs)?;
    let a = attribute_misses(&recs, &sched, period_ns);
    let q = |p: f64| f.latency.value_at_quantile(p) as f64 * 1e-3;
    Ok(json!({
        "cycles": recs.len(),
        "p50_us": q(0.5), "p99_us": q(0.99), "p999_us": q(0.999),
        "max_us": f.latency.max() as f64 * 1e-3,
        "jitter_p99_us": f.jitter.value_at_quantile(0.99) as f64 * 1e-3,
        "misses": f.misses, "misses_outside_stalls": f.misses_outside_stalls,
        "misses_unexplained": a.unexplained, "overruns": f.overruns, "stalls": f.stalls,
    }))
}

/// `feedloop bench scope`.
pub(super) fn run(a: &ScopeBenchArgs) -> Result<ExitCode> {
    let wait = checked(a)?;
    let browser = find_browser(a.browser.as_deref())?;
    let cpus = a.chain.cpus()?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let job = bench_job(
        &a.out,
        a.chain.period_s,
        wait,
        a.cycles,
        feedloop_model::job::DEFAULT_PHASE_PROBE_S,
    )?;
    let b = ScopeBench {
        a,
        wait,
        browser,
        cpus,
        job,
        period_ns: (a.chain.period_s * 1e9).round() as u64,
        exe: std::env::current_exe().context("locating the feedloop binary")?,
    };
    let mut pairs = Vec::new();
    for pair in 0..a.pairs {
        let mut row = serde_json::Map::new();
        // without: the loop alone (its recorders publish the scope feed to nobody);
        // scope_only: `feedloop scope` subscribed, no page; with_scope: and a browser drawing
        for (kind, name) in [(0u8, "without"), (1, "scope_only"), (2, "with_scope")] {
            if (a.with_only && kind < 2) || (kind == 1 && !a.scope_only) {
                continue;
            }
            row.insert(name.into(), b.one_run(pair, kind, name)?);
        }
        pairs.push(Value::Object(row));
    }
    let v = json!({
        "what": "the benchmark chain of `bench latency` run alone and with `feedloop scope` \
                 attached and a headless browser drawing its page, in alternating pairs",
        "cycles": a.cycles, "period_s": a.chain.period_s, "wait": wait.id(), "pin": a.chain.pin,
        "viewer_nice": a.viewer_nice, "viewer_idle": a.viewer_idle,
        "browser": b.browser.display().to_string(),
        "pairs": pairs,
    });
    let path = a.out.join("scope-bench.json");
    crate::processes::write_json(&path, &v)?;
    print_table(&v);
    println!("wrote {}", path.display());
    Ok(ExitCode::SUCCESS)
}

/// The options checked: the wait asked for.
fn checked(a: &ScopeBenchArgs) -> Result<WaitKind> {
    let wait = a.chain.checked()?;
    if a.cycles == 0 || a.pairs == 0 {
        bail!("--cycles and --pairs must be > 0");
    }
    if !(0..=19).contains(&a.viewer_nice) {
        bail!("--viewer-nice {}: 0..19", a.viewer_nice);
    }
    if !(a.rss_every_s > 0.0 && a.rss_every_s.is_finite()) {
        bail!("--rss-every-s must be a positive number of seconds");
    }
    Ok(wait)
}

/// A checked `bench scope` and what its runs share.
struct ScopeBench<'a> {
    a: &'a ScopeBenchArgs,
    wait: WaitKind,
    browser: PathBuf,
    cpus: Vec<usize>,
    job: PathBuf,
    period_ns: u64,
    /// this binary, started again as `feedloop scope`
    exe: PathBuf,
}

impl ScopeBench<'_> {
    /// One run of a pair, of `kind` 0 (alone), 1 (scope only) or 2 (scope and browser): its
    /// figures, with the scope's when it watched.
    fn one_run(&self, pair: u32, kind: u8, name: &str) -> Result<Value> {
        let a = self.a;
        let dir = a.out.join(format!("pair{pair}-{name}"));
        std::fs::create_dir_all(&dir)?;
        let instance = format!("scopebench{}x{pair}{kind}", std::process::id());
        eprintln!(
            "bench scope: pair {} of {}, {name}: {} cycles at {:.1} kHz, about {:.0} s",
            pair + 1,
            a.pairs,
            a.cycles,
            1e-3 / a.chain.period_s,
            a.cycles as f64 * a.chain.period_s
        );
        if kind == 0 {
            run_processes(
                &self.job, &dir, self.wait, a.cycles, &self.cpus, None, &instance,
            )?;
            return figures(&dir, self.period_ns);
        }
        self.watched_run(kind, &dir, &instance)
    }

    /// A run with the scope attached (and, for `kind` 2, a browser on its page): the scope
    /// first, then the browser, then the loop.
    fn watched_run(&self, kind: u8, dir: &Path, instance: &str) -> Result<Value> {
        let a = self.a;
        let (scope, url) = self.start_scope(dir, instance)?;
        // http://HOST:PORT/?token=T
        let rest = url.trim_start_matches("http://");
        let addr = rest.split('/').next().unwrap_or(rest).to_string();
        let token = url.split_once("token=").map_or("", |(_, t)| t).to_string();
        let chrome = if kind == 2 {
            Some(self.start_browser(dir, &url)?)
        } else {
            None
        };
        let sampler = RssSampler::start(scope.0.id(), Duration::from_secs_f64(a.rss_every_s));
        let before = get(&addr, &token, "/api/stats");
        let ran = run_processes(
            &self.job, dir, self.wait, a.cycles, &self.cpus, None, instance,
        );
        let after = get(&addr, &token, "/api/stats");
        let rss = sampler.stop();
        drop(chrome);
        drop(scope);
        ran?;
        let views = |v: &Option<Value>| v.as_ref().and_then(|v| v["views_served"].as_u64());
        let drawn = match (views(&before), views(&after)) {
            (Some(b), Some(a)) => a.saturating_sub(b),
            _ => 0,
        };
        let mut f = figures(dir, self.period_ns)?;
        let span = a.cycles as f64 * a.chain.period_s;
        let mb = |b: u64| b as f64 / 1048576.0;
        f["scope"] = json!({
            "views_served": drawn,
            "views_per_s": drawn as f64 / span.max(1e-9),
            "rss_mb": rss.iter().map(|(t, b)| json!([t, mb(*b)])).collect::<Vec<_>>(),
            "rss_first_mb": rss.first().map(|s| mb(s.1)),
            "rss_last_mb": rss.last().map(|s| mb(s.1)),
            "rss_max_mb": rss.iter().map(|s| mb(s.1)).fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v)))),
            "lost_blocks": after.as_ref().and_then(|v| v["lost_blocks"].as_u64()),
        });
        if drawn == 0 && kind == 2 {
            eprintln!("bench scope: warning: the browser fetched no view during the run");
        }
        Ok(f)
    }

    /// `feedloop scope` on `instance`, with the page's address it printed.
    fn start_scope(&self, dir: &Path, instance: &str) -> Result<(Kill, String)> {
        let mut scope = Command::new(&self.exe);
        scope
            .args(["scope", "--instance", instance, "--port", "0", "--captures"])
            .arg(dir.join("captures"))
            .stdout(Stdio::piped())
            .stderr(Stdio::null());
        crate::signals::die_with_parent(&mut scope);
        lower_priority(&mut scope, self.a.viewer_nice, self.a.viewer_idle);
        let mut scope = Kill(scope.spawn().context("starting feedloop scope")?);
        let mut line = String::new();
        BufReader::new(scope.0.stdout.take().context("scope's stdout")?).read_line(&mut line)?;
        let url = line
            .trim()
            .strip_prefix("feedloop scope: open ")
            .with_context(|| format!("feedloop scope printed `{}`", line.trim()))?
            .to_string();
        Ok((scope, url))
    }

    /// The headless browser drawing the page at `url`.
    fn start_browser(&self, dir: &Path, url: &str) -> Result<Kill> {
        let profile = dir.join("browser-profile");
        let mut chrome = Command::new(&self.browser);
        chrome
            .args(feedloop_cli::browser::HEADLESS_FLAGS)
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(url)
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        crate::signals::die_with_parent(&mut chrome);
        lower_priority(&mut chrome, self.a.viewer_nice, self.a.viewer_idle);
        Ok(Kill(chrome.spawn().with_context(|| {
            format!("starting {}", self.browser.display())
        })?))
    }
}

/// A thread sampling a process's resident memory every so often until stopped.
struct RssSampler {
    stop: Arc<AtomicBool>,
    thread: JoinHandle<Vec<(f64, u64)>>,
}

impl RssSampler {
    /// Samples process `pid` every `every`.
    fn start(pid: u32, every: Duration) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::spawn(move || {
            let t0 = Instant::now();
            let mut samples: Vec<(f64, u64)> = Vec::new();
            while !stop2.load(Ordering::Relaxed) {
                if let Some(r) = rss_bytes(pid) {
                    samples.push((t0.elapsed().as_secs_f64(), r));
                }
                let until = Instant::now() + every;
                while Instant::now() < until && !stop2.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(50));
                }
            }
            samples
        });
        Self { stop, thread }
    }

    /// The samples `(s since the start, bytes)`.
    fn stop(self) -> Vec<(f64, u64)> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap_or_default()
    }
}

/// The table of `scope-bench.json`'s runs side by side.
fn print_table(v: &Value) {
    println!(
        "| pair | run | p50 | p99 | p99.9 | max | misses (outside stalls, unexplained) | page views/s | scope RSS first -> last (max) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (i, p) in v["pairs"].as_array().into_iter().flatten().enumerate() {
        for name in ["without", "scope_only", "with_scope"] {
            let f = &p[name];
            if f.is_null() {
                continue;
            }
            let us = |k: &str| format!("{:.3} us", f[k].as_f64().unwrap_or(f64::NAN));
            let scope = if name != "without" {
                let s = &f["scope"];
                (
                    format!("{:.0}", s["views_per_s"].as_f64().unwrap_or(0.0)),
                    format!(
                        "{:.1} -> {:.1} ({:.1}) MB",
                        s["rss_first_mb"].as_f64().unwrap_or(f64::NAN),
                        s["rss_last_mb"].as_f64().unwrap_or(f64::NAN),
                        s["rss_max_mb"].as_f64().unwrap_or(f64::NAN)
                    ),
                )
            } else {
                ("-".into(), "-".into())
            };
            println!(
                "| {} | {} | {} | {} | {} | {} | {} ({}, {}) | {} | {} |",
                i + 1,
                name.replace('_', " "),
                us("p50_us"),
                us("p99_us"),
                us("p999_us"),
                us("max_us"),
                f["misses"],
                f["misses_outside_stalls"],
                f["misses_unexplained"],
                scope.0,
                scope.1
            );
        }
    }
}
