//! The run-level commands: spawning the two processes, the processes themselves, the
//! in-process simulation, and merging logs into `trace.csv` + `summary.json`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode};
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use serde_json::{json, Value};

use feedloop_analysis::sim::{simulate, ContourJudge};
use feedloop_model::job::{Job, Mode, WaitKind};

use crate::choice::{Choice, ModeArg, WaitArg};
use feedloop_plant::Plant;
use feedloop_plugins::Builtins;
use feedloop_runtime::plant::{
    run_plant, PlantEnd, PlantLoopConfig, PlantLoopError, PlantOutcome, StopCause,
};
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_runtime::scheduler::{run_scheduler, SchedulerConfig, SchedulerEnd};
use feedloop_runtime::shared::ipc::IpcError;
use feedloop_runtime::shared::ipc::{plant_endpoint, scheduler_endpoint};
use feedloop_trace::export::{
    human_summary, row_values, summary_json, trace_columns, EndInfo, SummaryInput,
};
use feedloop_trace::log::{read_log, PlantRecord, SchedRecord};
use feedloop_trace::summary::{timing, Tracking};
use feedloop_trace::TraceWriter;

use crate::signals;

/// A job with everything built from it validated.
struct Loaded {
    job: Job,
    cycle: ControlCycle,
    plant: Plant,
}

fn load(job_path: &Path) -> Result<Loaded> {
    let job = Job::load(job_path)?;
    let cycle = ControlCycle::new(&job, &Builtins)?;
    let mut plant = Plant::new(&job)?;
    plant.set_initial_positions(&cycle.initial_positions());
    Ok(Loaded { job, cycle, plant })
}

fn mode_of(job: &Job, mode: Option<String>) -> Result<Mode> {
    match mode {
        None => Ok(job.run.mode),
        Some(m) => {
            Mode::parse(&m).ok_or_else(|| anyhow!("--mode `{m}`: expected realtime or lockstep"))
        }
    }
}

fn wait_of(job: &Job, wait: Option<String>) -> Result<WaitKind> {
    match wait {
        None => Ok(job.run.wait),
        Some(w) => WaitKind::parse(&w)
            .ok_or_else(|| anyhow!("--wait `{w}`: expected busy, block or hybrid")),
    }
}

/// Writes pretty JSON.
pub fn write_json(path: &Path, v: &Value) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(v)? + "\n")
        .with_context(|| format!("writing {}", path.display()))
}

fn create_dir(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating output folder {}", out.display()))
}

/// Writes `summary.json` into `out` and prints it (pure JSON with `json_only`, else the human
/// summary and the files written).
fn write_summary(out: &Path, v: &Value, json_only: bool) -> Result<()> {
    write_json(&out.join("summary.json"), v)?;
    if json_only {
        println!("{}", serde_json::to_string_pretty(v)?);
    } else {
        print!("{}", human_summary(v));
        println!(
            "  wrote {} and {}",
            out.join("trace.csv").display(),
            out.join("summary.json").display()
        );
    }
    Ok(())
}

/// `feedloop sim`.
pub fn sim(job_path: &Path, out: &Path, json_only: bool, quiet: bool) -> Result<ExitCode> {
    let job = Job::load(job_path)?;
    // Validate everything before touching the output folder.
    ControlCycle::new(&job, &Builtins)?;
    Plant::new(&job)?;
    create_dir(out)?;
    let bar = if quiet || json_only {
        indicatif::ProgressBar::hidden()
    } else {
        let b = indicatif::ProgressBar::new(0);
        b.set_style(
            indicatif::ProgressStyle::with_template("sim {bar:40} {pos}/{len} cycles ({eta})")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    };
    let trace = out.join("trace.csv");
    let report = simulate(&job, &Builtins, Some(&trace), &mut |done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    let end = EndInfo::new("completed", report.cycles);
    let mut extra = BTreeMap::new();
    extra.insert("trace_export_s".to_string(), json!(report.trace_s));
    extra.insert("tracking_s".to_string(), json!(report.tracking_s));
    let v = summary_json(&SummaryInput {
        job: &job.name,
        mode: "sim",
        period_s: job.period_s,
        cycles: report.cycles,
        timing: None,
        pids: None,
        compute_s: report.compute_s,
        tracking: &report.tracking,
        end: &end,
        extra,
    });
    write_summary(out, &v, json_only)?;
    Ok(ExitCode::SUCCESS)
}

/// Options shared by the `plant` and `scheduler` processes.
#[derive(clap::Args, Debug, Clone)]
pub struct ProcArgs {
    /// Instance name (both processes of one loop use the same).
    #[arg(long)]
    pub instance: String,
    /// Job file.
    #[arg(long)]
    pub job: PathBuf,
    /// Output folder for this process' log and report.
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
    /// How the processes keep time (default: the job's).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// How a process waits for the next message (default: the job's).
    #[arg(long, value_enum)]
    pub wait: Option<WaitArg>,
    /// Run this many cycles instead of the job's duration.
    #[arg(long)]
    pub cycles: Option<u64>,
    /// Pin this process to a CPU.
    #[arg(long)]
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority (1..99); refused with the busy wait (real-time throttling).
    #[arg(long)]
    pub fifo: Option<i32>,
    /// Do not lock memory (mlockall).
    #[arg(long)]
    pub no_mlock: bool,
}

fn apply_rt(a: &ProcArgs, wait: WaitKind) -> Value {
    let mut req = feedloop_runtime::shared::rt::RtRequest {
        mlockall: !a.no_mlock,
        fifo_priority: a.fifo,
        cpu: a.cpu,
    };
    let mut note = None;
    if wait == WaitKind::Busy && a.fifo.is_some() {
        req.fifo_priority = None;
        note = Some("SCHED_FIFO refused with the busy wait: an unbounded spin at real-time priority is throttled by the kernel".to_string());
    }
    let mut applied = feedloop_runtime::shared::rt::apply(&req);
    applied.notes.extend(note);
    serde_json::to_value(&applied).unwrap_or(Value::Null)
}

/// What the plant and the scheduler process set up first.
struct ProcStart {
    loaded: Loaded,
    mode: Mode,
    wait: WaitKind,
    /// The real-time settings applied (for the process' JSON report).
    rt: Value,
    spin: Duration,
}

/// Installs the signal handlers, loads the job, resolves mode and wait, creates the output
/// folder and applies the real-time settings.
fn start_process(a: &ProcArgs) -> Result<ProcStart> {
    signals::install();
    let loaded = load(&a.job)?;
    let mode = mode_of(&loaded.job, a.mode.map(|m| m.id().to_string()))?;
    let wait = wait_of(&loaded.job, a.wait.map(|w| w.id().to_string()))?;
    create_dir(&a.out)?;
    let rt = apply_rt(a, wait);
    let spin = Duration::from_secs_f64(loaded.job.spin_s());
    Ok(ProcStart {
        loaded,
        mode,
        wait,
        rt,
        spin,
    })
}

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

fn default_instance() -> String {
    format!("run{}", std::process::id())
}

/// Starts `feedloop <role>` as a child process.
pub fn spawn(
    role: &str,
    instance: &str,
    job: &Path,
    out: &Path,
    mode: Mode,
    wait: WaitKind,
    extra: &[String],
) -> Result<Child> {
    let exe = std::env::current_exe().context("locating the feedloop binary")?;
    let mut cmd = Command::new(exe);
    cmd.arg(role)
        .args(["--instance", instance])
        .arg("--job")
        .arg(job)
        .arg("--out")
        .arg(out)
        .args(["--mode", mode.id(), "--wait", wait.id()]);
    if role == "plant" {
        cmd.arg("--no-export");
    }
    cmd.args(extra);
    // a launcher killed outright must not leave the loop running with nobody in charge
    signals::die_with_parent(&mut cmd);
    cmd.spawn()
        .with_context(|| format!("starting the {role} process"))
}

/// Parses `--pin A,B` (the plant's CPU, the scheduler's CPU).
pub fn parse_pin(pin: &str) -> Result<[usize; 2]> {
    let cpus: Vec<usize> = pin
        .split(',')
        .map(|c| {
            c.trim()
                .parse::<usize>()
                .with_context(|| format!("--pin `{pin}`: expected two CPU numbers like 0,1"))
        })
        .collect::<Result<_>>()?;
    match cpus[..] {
        [a, b] => Ok([a, b]),
        _ => bail!("--pin takes two CPUs (plant,scheduler), got {}", cpus.len()),
    }
}

/// Starts the plant and then the scheduler process (the plant is killed if the scheduler cannot
/// start).
fn spawn_both(
    instance: &str,
    job_path: &Path,
    out: &Path,
    mode: Mode,
    wait: WaitKind,
    cpus: Option<[usize; 2]>,
) -> Result<(Child, Child)> {
    let cpu_args = |i: usize| -> Vec<String> {
        cpus.map(|c| vec!["--cpu".to_string(), c[i].to_string()])
            .unwrap_or_default()
    };
    let mut plant = spawn("plant", instance, job_path, out, mode, wait, &cpu_args(0))?;
    match spawn(
        "scheduler",
        instance,
        job_path,
        out,
        mode,
        wait,
        &cpu_args(1),
    ) {
        Ok(sched) => Ok((plant, sched)),
        Err(e) => {
            let _ = plant.kill();
            let _ = plant.wait();
            Err(e)
        }
    }
}

/// Waits for both processes: the plant, forwarding an operator stop (SIGINT/SIGTERM to us) to
/// it once; then the scheduler, killed if it outlives the peer timeout (+2 s). Reports a
/// process that failed without writing its JSON file.
fn wait_both(plant: &mut Child, sched: &mut Child, job: &Job, out: &Path) -> Result<()> {
    let mut forwarded = false;
    let plant_status = loop {
        if let Some(st) = plant.try_wait().context("waiting for the plant process")? {
            break st;
        }
        if !forwarded && signals::STOP.load(std::sync::atomic::Ordering::Relaxed) {
            // SAFETY: sending a signal to our own child by pid.
            unsafe { libc::kill(plant.id() as libc::pid_t, libc::SIGTERM) };
            forwarded = true;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    // The scheduler ends on the plant's last sample or notices silence; bound the wait.
    let deadline =
        std::time::Instant::now() + Duration::from_secs_f64(job.run.peer_timeout_s + 2.0);
    let sched_status = loop {
        if let Some(s) = sched.try_wait()? {
            break Some(s);
        }
        if std::time::Instant::now() > deadline {
            let _ = sched.kill();
            let _ = sched.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    if !plant_status.success() && !out.join("plant.json").exists() {
        eprintln!("feedloop: the plant process failed ({plant_status})");
    }
    if let Some(s) = sched_status {
        if !s.success() && !out.join("scheduler.json").exists() {
            eprintln!("feedloop: the scheduler process failed ({s})");
        }
    }
    Ok(())
}

/// `feedloop run`.
pub fn run(
    job_path: &Path,
    out: &Path,
    mode: Option<ModeArg>,
    wait: Option<WaitArg>,
    instance: Option<String>,
    pin: Option<&str>,
    json_only: bool,
) -> Result<ExitCode> {
    let (mode, wait) = (
        mode.map(|m| m.id().to_string()),
        wait.map(|w| w.id().to_string()),
    );
    signals::install();
    // Validate everything before any process starts.
    let cpus = pin.map(parse_pin).transpose()?;
    let Loaded { job, .. } = load(job_path)?;
    let mode = mode_of(&job, mode)?;
    let wait = wait_of(&job, wait)?;
    let instance = instance.unwrap_or_else(default_instance);
    if !feedloop_model::job::valid_name(&instance, true) {
        bail!("--instance `{instance}`: use lowercase letters, digits, `_` and `-` (at most 64)");
    }
    create_dir(out)?;
    for f in [
        "plant.log",
        "plant.json",
        "scheduler.log",
        "scheduler.json",
        "trace.csv",
        "summary.json",
    ] {
        let _ = std::fs::remove_file(out.join(f));
    }
    let (mut plant, mut sched) = spawn_both(&instance, job_path, out, mode, wait, cpus)?;
    wait_both(&mut plant, &mut sched, &job, out)?;
    let (mut v, code) = merge(out, &job)?;
    v["processes"] = json!({"plant_pid": plant.id(), "scheduler_pid": sched.id()});
    write_summary(out, &v, json_only)?;
    Ok(code)
}

/// Reads a JSON file, if it is there and parses.
pub fn read_json(path: &Path) -> Option<Value> {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
}

/// `feedloop merge`.
pub fn merge_cmd(dir: &Path, job_path: &Path, json_only: bool) -> Result<ExitCode> {
    let job = Job::load(job_path)?;
    let (v, code) = merge(dir, &job)?;
    if json_only {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print!("{}", human_summary(&v));
    }
    Ok(code)
}

/// Writes `trace.csv` in `dir` from the plant's records; returns the tracking figures and the
/// plant's compute time, ns.
fn write_trace(
    dir: &Path,
    job: &Job,
    cycle: &ControlCycle,
    records: &[PlantRecord],
) -> Result<(Tracking, u64)> {
    let names = job.axis_names();
    let n = names.len();
    let judge = ContourJudge::new(job, cycle);
    let mut tracking = Tracking::for_job(job);
    let trace_path = dir.join("trace.csv");
    let f = std::fs::File::create(&trace_path)
        .with_context(|| format!("creating {}", trace_path.display()))?;
    let mut w = TraceWriter::new(
        std::io::BufWriter::with_capacity(1 << 20, f),
        &trace_columns(&names),
    )?
    .with_period(job.period_s)?;
    let mut row = Vec::with_capacity(1 + 5 * n);
    let mut plant_compute_ns = 0u64;
    for r in records {
        row_values(r.seq, job.period_s, &r.axes[..n], &mut row);
        w.write_cycle(r.seq, &row)?;
        let ce = judge.error_m(cycle, cycle.time_of(r.seq), &r.axes[..n]);
        tracking.push(&r.axes[..n], ce);
        plant_compute_ns += u64::from(r.compute_ns);
    }
    w.finish()?;
    Ok((tracking, plant_compute_ns))
}

/// How the run ended, from plant.json (`plant_lost` without it; `incomplete_log` when a
/// completed run logged fewer or more cycles than planned).
fn merged_end(plant_info: Option<&Value>, cycles: u64, cycle: &ControlCycle) -> EndInfo {
    let end = match plant_info {
        None => EndInfo::new("plant_lost", cycles),
        Some(p) => {
            let e = &p["end"];
            let mut info = EndInfo::new(
                e["reason"].as_str().unwrap_or("unknown"),
                e["cycle"].as_u64().unwrap_or(cycles),
            );
            if let Some(obj) = e.as_object() {
                for (k, v) in obj {
                    if k != "reason" && k != "cycle" {
                        info.extra.insert(k.clone(), v.clone());
                    }
                }
            }
            info
        }
    };
    let planned = plant_info
        .and_then(|p| p["planned_cycles"].as_u64())
        .unwrap_or(cycle.cycles());
    if end.reason == "completed" && cycles != planned {
        return EndInfo::new("incomplete_log", cycles);
    }
    end
}

/// The scheduler's part of the summary's extra keys: its swaps, rejected requests, deadline
/// misses near the swaps and elsewhere, and its whole report.
fn scheduler_extra(s: &Value, records: &[PlantRecord], extra: &mut BTreeMap<String, Value>) {
    extra.insert("swaps".into(), s["swaps"].clone());
    extra.insert("rejected_requests".into(), s["rejected_requests"].clone());
    let swap_cycles: Vec<u64> = s["swaps"]
        .as_array()
        .map(|a| a.iter().filter_map(|w| w["cycle"].as_u64()).collect())
        .unwrap_or_default();
    if !swap_cycles.is_empty() {
        let (near, elsewhere) = misses_near(records, &swap_cycles, SWAP_WINDOW);
        let stats = |c: &WindowCount| {
            json!({"cycles": c.cycles, "misses": c.misses,
                   "rate": c.misses as f64 / c.cycles.max(1) as f64,
                   "late_cycles": c.late, "late_rate": c.late as f64 / c.cycles.max(1) as f64})
        };
        let mut n = stats(&near);
        n["window_cycles"] = json!(SWAP_WINDOW);
        extra.insert("deadline_misses_near_swaps".into(), n);
        extra.insert("deadline_misses_elsewhere".into(), stats(&elsewhere));
    }
    extra.insert("scheduler".into(), s.clone());
}

/// Builds trace.csv and summary.json in `dir` from the processes' logs.
fn merge(dir: &Path, job: &Job) -> Result<(Value, ExitCode)> {
    let plant_log: PathBuf = dir.join("plant.log");
    let plant_recs = read_log::<PlantRecord>(&plant_log)
        .with_context(|| format!("reading {}", plant_log.display()))?;
    let sched_recs = read_log::<SchedRecord>(&dir.join("scheduler.log")).ok();
    let plant_info = read_json(&dir.join("plant.json"));
    let sched_info = read_json(&dir.join("scheduler.json"));
    let cycle = ControlCycle::new(job, &Builtins)?;
    let (tracking, plant_compute_ns) = write_trace(dir, job, &cycle, &plant_recs.records)?;
    let sched_compute_ns: u64 = sched_recs
        .as_ref()
        .map(|s| s.records.iter().map(|r| u64::from(r.compute_ns)).sum())
        .unwrap_or(0);
    let t = timing(&plant_recs.records);
    let mode = plant_info
        .as_ref()
        .and_then(|p| p["mode"].as_str().map(str::to_string))
        .unwrap_or_else(|| "unknown".into());
    let pids = match (&plant_info, &sched_info) {
        (Some(p), Some(s)) => Some((
            p["pid"].as_u64().unwrap_or(0) as u32,
            s["pid"].as_u64().unwrap_or(0) as u32,
        )),
        _ => None,
    };
    let cycles = plant_recs.records.len() as u64;
    let end = merged_end(plant_info.as_ref(), cycles, &cycle);
    let mut extra = BTreeMap::new();
    extra.insert(
        "wait".into(),
        plant_info
            .as_ref()
            .map(|p| p["wait"].clone())
            .unwrap_or(Value::Null),
    );
    extra.insert("bad_sequence".into(), json!(t.bad_sequence));
    extra.insert("late_commands".into(), json!(t.late_commands));
    extra.insert("duplicate_commands".into(), json!(t.duplicate_commands));
    extra.insert("torn_log_bytes".into(), json!(plant_recs.torn_bytes));
    if let Some(s) = plant_info.as_ref().map(|p| &p["startup"]) {
        if !s.is_null() {
            extra.insert("startup".into(), s.clone());
        }
    }
    if let Some(s) = &sched_info {
        scheduler_extra(s, &plant_recs.records, &mut extra);
    }
    let v = summary_json(&SummaryInput {
        job: &job.name,
        mode: &mode,
        period_s: job.period_s,
        cycles,
        timing: Some(&t),
        pids,
        compute_s: (plant_compute_ns + sched_compute_ns) as f64 * 1e-9,
        tracking: &tracking,
        end: &end,
        extra,
    });
    write_json(&dir.join("summary.json"), &v)?;
    // A completed run and an operator stop are clean exits; every fault stop is not.
    let code = if end.reason == "completed" || end.reason == "operator_stop" {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    };
    Ok((v, code))
}

/// Cycles after a swap (the swap cycle and the next ones) counted as "near" it.
const SWAP_WINDOW: u64 = 10;

/// Cycle counts of one part of a run.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct WindowCount {
    cycles: u64,
    /// Deadline misses as the summary defines them: no command while the plant was on time.
    misses: u64,
    /// Cycles with a miss or a plant overrun (any timing fault, also when the machine is busy).
    late: u64,
}

/// Counts within `window` cycles from each swap cycle on (a union: overlapping windows count
/// once), and in all other cycles.
fn misses_near(records: &[PlantRecord], swaps: &[u64], window: u64) -> (WindowCount, WindowCount) {
    use feedloop_trace::log::{REC_MISSED, REC_OVERRUN};
    let mut sorted = swaps.to_vec();
    sorted.sort_unstable();
    let mut near = WindowCount::default();
    let mut far = WindowCount::default();
    let mut next = 0usize;
    for r in records {
        while next < sorted.len() && sorted[next] + window < r.seq {
            next += 1;
        }
        let is_near =
            next < sorted.len() && sorted[next] <= r.seq && r.seq <= sorted[next] + window;
        let slot = if is_near { &mut near } else { &mut far };
        slot.cycles += 1;
        slot.misses += u64::from(feedloop_trace::log::is_deadline_miss(r.flags));
        slot.late += u64::from(r.flags & (REC_MISSED | REC_OVERRUN) != 0);
    }
    (near, far)
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

#[cfg(test)]
mod swap_window_tests {
    use super::*;
    use feedloop_trace::log::{REC_MISSED, REC_OVERRUN};

    #[test]
    fn misses_are_split_into_swap_windows_and_the_rest() {
        let recs: Vec<PlantRecord> = (0..100u64)
            .map(|k| PlantRecord {
                seq: k,
                flags: match k {
                    12 | 50 | 95 => REC_MISSED,
                    13 => REC_MISSED | REC_OVERRUN,
                    _ => 0,
                },
                ..Default::default()
            })
            .collect();
        // Windows [10, 20] and [15, 25] overlap: 16 cycles; [90, 100] is cut at 99: 10 cycles.
        let (near, far) = misses_near(&recs, &[15, 10, 90], 10);
        assert_eq!((near.cycles, near.misses, near.late), (16 + 10, 2, 3));
        assert_eq!((far.cycles, far.misses, far.late), (100 - 26, 1, 1));
    }
}
