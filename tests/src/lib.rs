//! Helpers for the end-to-end tests: find (or build) the `feedloop` binary, make scratch
//! folders, run commands, and serialise the tests that spawn processes.
//!
//! The binary is looked up in this order: `$FEEDLOOP_BIN`; `$CARGO_TARGET_DIR/<profile>/feedloop`;
//! the target folder this test executable was built into (`<target>/<profile>/deps/..`). If it
//! is not there, it is built with `cargo build -p feedloop-cli` for the same profile.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::{Mutex, MutexGuard, OnceLock};

/// Root of the repository.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ lives in the repository root")
        .to_path_buf()
}

/// A file of the repository, e.g. `examples/jobs/xy-circle.toml`.
pub fn repo_file(rel: &str) -> PathBuf {
    repo_root().join(rel)
}

fn profile_and_target() -> (String, PathBuf) {
    let exe = std::env::current_exe().expect("current_exe");
    // <target>/<profile>/deps/<test-binary>
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("test binary lives in <target>/<profile>/deps");
    let profile = profile_dir
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "debug".into());
    let target = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(t) => PathBuf::from(t),
        None => profile_dir.parent().expect("target dir").to_path_buf(),
    };
    (profile, target)
}

/// Path of the `feedloop` binary, building it if needed.
pub fn feedloop_bin() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        if let Some(p) = std::env::var_os("FEEDLOOP_BIN") {
            return PathBuf::from(p);
        }
        let (profile, target) = profile_and_target();
        let bin = target.join(&profile).join("feedloop");
        if !bin.exists() {
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
            let mut cmd = Command::new(cargo);
            cmd.current_dir(repo_root())
                .args([
                    "build",
                    "-p",
                    "feedloop-cli",
                    "--bin",
                    "feedloop",
                    "--target-dir",
                ])
                .arg(&target);
            if profile == "release" {
                cmd.arg("--release");
            } else if profile != "debug" {
                cmd.args(["--profile", &profile]);
            }
            let st = cmd
                .status()
                .expect("running cargo build for the feedloop binary");
            assert!(st.success(), "building the feedloop binary failed");
        }
        assert!(
            bin.exists(),
            "feedloop binary not found at {}",
            bin.display()
        );
        bin
    })
    .clone()
}

/// Runs `feedloop` with `args` and returns its output.
pub fn feedloop(args: &[&str]) -> Output {
    Command::new(feedloop_bin())
        .args(args)
        .output()
        .expect("running feedloop")
}

pub use feedloop_test_support::Scratch;

/// A fresh scratch folder unique to this process and `name` (removed when the test passes).
pub fn scratch(name: &str) -> Scratch {
    Scratch::new("e2e", name)
}

/// Serialises tests that spawn plant/scheduler processes (2 cores: one at a time).
pub fn process_lock() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|p| p.into_inner())
}

/// Parses a JSON file.
pub fn read_json(path: &Path) -> serde_json::Value {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("parsing {}: {e}", path.display()))
}

/// Output as text, for assertion messages.
pub fn describe(o: &Output) -> String {
    format!(
        "status {}\n--- stdout\n{}\n--- stderr\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Pid of a running process whose command line contains every one of `words`.
pub fn find_process(words: &[&str]) -> Option<u32> {
    let me = std::process::id();
    for entry in std::fs::read_dir("/proc").ok()?.flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        if pid == me {
            continue;
        }
        let Ok(raw) = std::fs::read(entry.path().join("cmdline")) else {
            continue;
        };
        let args: Vec<String> = raw
            .split(|b| *b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        if words.iter().all(|w| args.iter().any(|a| a == w)) {
            return Some(pid);
        }
    }
    None
}

/// Sends `signal` to `pid`.
pub fn signal(pid: u32, signal: &str) {
    let st = Command::new("kill")
        .args([&format!("-{signal}"), &pid.to_string()])
        .status()
        .expect("running kill");
    assert!(st.success(), "kill -{signal} {pid} failed");
}

/// Rows of a trace file (excluding comments and the header).
pub fn trace_rows(path: &Path) -> Vec<Vec<f64>> {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(|c| c.parse::<f64>().unwrap()).collect())
        .collect()
}

/// Starts `feedloop run JOB --out OUT --mode MODE --wait block --instance INSTANCE` (stdout muted).
pub fn start_run(job: &Path, out: &Path, mode: &str, instance: &str) -> std::process::Child {
    start_run_waiting(job, out, mode, "block", instance, &[])
}

/// Starts `feedloop run JOB --out OUT --mode MODE --wait WAIT --instance INSTANCE [EXTRA..]`
/// (stdout muted).
pub fn start_run_waiting(
    job: &Path,
    out: &Path,
    mode: &str,
    wait: &str,
    instance: &str,
    extra: &[&str],
) -> std::process::Child {
    Command::new(feedloop_bin())
        .arg("run")
        .arg(job)
        .arg("--out")
        .arg(out)
        .args(["--mode", mode, "--wait", wait, "--instance", instance])
        .args(extra)
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("starting feedloop run")
}

/// Waits (at most 10 s) for a process whose command line holds `words`; returns its pid.
pub fn wait_for_process(words: &[&str]) -> u32 {
    let t = std::time::Instant::now();
    loop {
        if let Some(p) = find_process(words) {
            return p;
        }
        assert!(
            t.elapsed() < std::time::Duration::from_secs(10),
            "process {words:?} never appeared"
        );
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

/// Builds the out-of-tree example plugin (`examples/plugins/pi-velocity-c`) into `target` and
/// returns the library's path; `wrong_abi` builds the variant that reports another ABI version.
pub fn build_example_plugin(target: &Path, wrong_abi: bool) -> PathBuf {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(["build", "--release", "--offline", "--manifest-path"])
        .arg(repo_file("examples/plugins/pi-velocity-c/Cargo.toml"))
        .arg("--target-dir")
        .arg(target);
    if wrong_abi {
        cmd.args(["--features", "wrong-abi"]);
    }
    let st = cmd.status().expect("running cargo for the example plugin");
    assert!(st.success(), "building the example plugin failed");
    target.join("release/libfeedloop_plugin_pi_velocity_c.so")
}

/// `feedloop status --instance INST`, parsed (the test fails when the command does).
pub fn status(instance: &str) -> serde_json::Value {
    let o = feedloop(&["status", "--instance", instance]);
    assert!(o.status.success(), "{}", describe(&o));
    serde_json::from_slice(&o.stdout).expect("status prints JSON")
}

/// The circle an X-Y job of these tests runs (`[trajectory]` of kind `circle` on x and y).
pub struct Circle {
    pub center_m: [f64; 2],
    pub radius_m: f64,
    pub feed_m_per_s: f64,
    pub turns: f64,
    pub ramp_s: f64,
}

/// 100 turns of a 10 mm circle (about 190 s): longer than the tests that swap controllers.
pub const LONG_CIRCLE: Circle = Circle {
    center_m: [-0.01, 0.0],
    radius_m: 0.01,
    feed_m_per_s: 0.0333,
    turns: 100.0,
    ramp_s: 0.1,
};

/// Writes `dir/NAME.toml`: the [`LONG_CIRCLE`] at 2 kHz, stopped after 30 s.
pub fn write_long_circle_job(dir: &Path, name: &str) -> PathBuf {
    write_xy_circle_job(
        &dir.join(format!("{name}.toml")),
        &format!("name = \"{name}\"\nperiod_s = 0.0005\nduration_s = 30.0"),
        "",
        None,
        &LONG_CIRCLE,
    )
}

/// Writes `path`: a job on the X-Y table (`examples/models/xy-x.toml` on x; `y_model`, or
/// `xy-y.toml`, on y) running `circle`. `top` holds the top-level keys (name, period, ...);
/// `run` the lines after `[run]`'s `wait = "block"` (more `[run]` keys, other tables).
pub fn write_xy_circle_job(
    path: &Path,
    top: &str,
    run: &str,
    y_model: Option<&str>,
    circle: &Circle,
) -> PathBuf {
    let models = repo_file("examples/models");
    let m = models.display();
    let y = y_model
        .map(str::to_string)
        .unwrap_or_else(|| format!("{m}/xy-y.toml"));
    let Circle {
        center_m: [cx, cy],
        radius_m,
        feed_m_per_s,
        turns,
        ramp_s,
    } = circle;
    let text = format!(
        r#"{top}
[run]
wait = "block"
{run}
[axes.x]
model = "{m}/xy-x.toml"
[axes.y]
model = "{y}"
[trajectory]
kind = "circle"
axes = ["x", "y"]
center_m = [{cx:?}, {cy:?}]
radius_m = {radius_m:?}
feed_m_per_s = {feed_m_per_s:?}
turns = {turns:?}
ramp_s = {ramp_s:?}
"#
    );
    std::fs::write(path, text).expect("writing a job file");
    path.to_path_buf()
}

/// How long after a realtime run's processes appeared its loop has cycled for `settle`: the
/// plant first probes its core for the job's default `phase_probe_s`.
pub fn after_start(settle: std::time::Duration) -> std::time::Duration {
    std::time::Duration::from_secs_f64(feedloop_model::job::DEFAULT_PHASE_PROBE_S) + settle
}

/// Starts `feedloop run JOB --mode realtime` into `dir/out` on the instance `PREFIX-<pid>`,
/// waits for its scheduler and lets the loop cycle for `settle`; returns the run, the
/// instance and the out folder.
pub fn start_realtime_run(
    dir: &Path,
    job: &Path,
    prefix: &str,
    settle: std::time::Duration,
) -> (std::process::Child, String, PathBuf) {
    let inst = format!("{prefix}-{}", std::process::id());
    let out = dir.join("out");
    let run = start_run(job, &out, "realtime", &inst);
    wait_for_process(&["scheduler", "--instance", &inst]);
    std::thread::sleep(after_start(settle));
    (run, inst, out)
}

/// `feedloop swap --instance INST --axis x --stage velocity ARGS..`.
pub fn swap_x_velocity<S: AsRef<str>>(instance: &str, args: &[S]) -> Output {
    let mut a = vec![
        "swap",
        "--instance",
        instance,
        "--axis",
        "x",
        "--stage",
        "velocity",
    ];
    a.extend(args.iter().map(AsRef::as_ref));
    feedloop(&a)
}

/// How a plant loop thread of [`spawn_plant_loop`] runs.
pub struct PlantThread {
    pub mode: feedloop_model::job::Mode,
    pub period_s: f64,
    pub cycles: u64,
    pub watchdog_cycles: u64,
    /// Realtime: how long cycle 0 waits for the first command, s.
    pub startup_grace_s: f64,
    /// Realtime: the plant's phase probe before the first sample, s (0: none).
    pub phase_probe_s: f64,
    pub cycle_hook: Option<fn(u64)>,
}

/// Starts the real plant loop of `job` on a thread, as `feedloop plant` would (blocking wait,
/// 10 s peer timeout, brake gain 5 and torque limit 30 on every axis, initial positions from
/// the job's control cycle), logging to `log`.
pub fn spawn_plant_loop(
    job: &feedloop_model::job::Job,
    instance: &str,
    log: PathBuf,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    how: PlantThread,
) -> std::thread::JoinHandle<feedloop_runtime::plant::PlantOutcome> {
    use feedloop_model::job::WaitKind;
    use std::time::Duration;
    let job = job.clone();
    let instance = instance.to_string();
    std::thread::spawn(move || {
        let cycle = feedloop_runtime::scheduler::cycle::ControlCycle::new(
            &job,
            &feedloop_plugins::Builtins,
        )
        .unwrap();
        let mut p = feedloop_plant::Plant::new(&job).unwrap();
        p.set_initial_positions(&cycle.initial_positions());
        let ep = feedloop_runtime::shared::ipc::plant_endpoint(
            &instance,
            WaitKind::Block,
            Duration::ZERO,
        )
        .unwrap();
        let cfg = feedloop_runtime::plant::PlantLoopConfig {
            instance,
            mode: how.mode,
            wait: WaitKind::Block,
            spin: Duration::ZERO,
            period_s: how.period_s,
            cycles: how.cycles,
            watchdog_cycles: how.watchdog_cycles,
            peer_timeout_s: 10.0,
            startup_grace_s: how.startup_grace_s,
            phase_probe_s: how.phase_probe_s,
            safety: job.safety.clone(),
            brake_gain: vec![5.0; job.axes.len()],
            torque_limit: vec![30.0; job.axes.len()],
            cycle_hook: how.cycle_hook,
        };
        feedloop_runtime::plant::run_plant(&cfg, &mut p, &ep, &log, &stop).unwrap()
    })
}
