//! Faults: killed processes, operator stops, drive-side limits, and a second publisher.
//! Each test runs the real `feedloop` binary; kill trials are repeated at pseudo-random moments.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use feedloop_tests::{
    describe, feedloop_bin, process_lock, read_json, repo_file, scratch, signal,
    start_realtime_run, start_run, swap_x_velocity, trace_rows, wait_for_process,
    write_xy_circle_job, Circle,
};

const PERIOD: f64 = 0.0005;
const WATCHDOG: u64 = 20;

fn job(dir: &Path, name: &str, safety: &str, model_y: Option<&str>) -> PathBuf {
    write_xy_circle_job(
        &dir.join(format!("{name}.toml")),
        &format!("name = \"{name}\"\nperiod_s = {PERIOD}"),
        &format!("watchdog_cycles = {WATCHDOG}\npeer_timeout_s = 3.0\n[safety]\n{safety}"),
        model_y,
        &Circle {
            center_m: [-0.004, 0.0],
            radius_m: 0.004,
            feed_m_per_s: 0.02,
            turns: 1.0,
            ramp_s: 0.05,
        },
    )
}

/// Rows must be one per cycle from 0 on, without gaps.
fn assert_contiguous(trace: &Path) -> usize {
    let rows = trace_rows(trace);
    for (k, r) in rows.iter().enumerate() {
        let t = k as f64 * PERIOD;
        assert!(
            (r[0] - t).abs() < 1e-9,
            "row {k} has t = {} (expected {t})",
            r[0]
        );
    }
    rows.len()
}

fn trials() -> usize {
    std::env::var("FEEDLOOP_KILL_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20)
}

#[test]
fn killed_scheduler_is_detected_within_the_watchdog_and_the_axes_are_stopped() {
    let _g = process_lock();
    let dir = scratch("killsched");
    let job = job(&dir, "killsched", "", None);
    let mut seed = 0x9E37_79B9_7F4A_7C15u64;
    let n = trials();
    let mut detected = Vec::new();
    for i in 0..n {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        let delay_ms = 60 + seed % 500;
        let out = dir.join(format!("t{i}"));
        let inst = format!("kill-{}-{i}", std::process::id());
        let mut run = start_run(&job, &out, "realtime", &inst);
        let sched = wait_for_process(&["scheduler", "--instance", &inst]);
        std::thread::sleep(Duration::from_millis(delay_ms));
        signal(sched, "KILL");
        let st = run.wait().unwrap();
        assert!(
            !st.success(),
            "trial {i}: run exited 0 after its scheduler was killed"
        );
        let sum = read_json(&out.join("summary.json"));
        let end = &sum["end"];
        // A kill late in the run may land after the last cycle: then the run completed.
        if end["reason"] == "completed" {
            continue;
        }
        assert_eq!(end["reason"], "scheduler_lost", "trial {i}: {sum}");
        let after = end["detected_after_cycles"].as_u64().unwrap();
        assert!(
            after <= WATCHDOG,
            "trial {i}: detected after {after} cycles"
        );
        assert_eq!(end["safe_stop"], "brake_ramp");
        let rows = assert_contiguous(&out.join("trace.csv"));
        let stop_cycle = end["cycle"].as_u64().unwrap() as usize;
        // Complete up to the stop (a kill during the start-up handshake stops at cycle 0).
        assert!(
            rows >= stop_cycle,
            "trial {i}: trace ends at {rows} rows before the stop at {stop_cycle}"
        );
        detected.push(after);
    }
    assert!(
        detected.len() * 2 >= n,
        "too few trials hit a running loop: {detected:?}"
    );
    eprintln!(
        "{} kill trials, detected after {:?} cycles",
        detected.len(),
        detected
    );
    // The next run on a used instance name starts cleanly.
    let out = dir.join("after");
    let st = Command::new(feedloop_bin())
        .args(["run"])
        .arg(&job)
        .arg("--out")
        .arg(&out)
        .args([
            "--mode",
            "lockstep",
            "--wait",
            "block",
            "--instance",
            &format!("kill-{}-0", std::process::id()),
        ])
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", describe(&st));
}

/// `kill -9` of `feedloop run` (realtime): its children get the parent-death signal, brake to a
/// stop and exit within 1 s; their logs merge into a trace that says `launcher_lost`; the same
/// instance name starts again at once.
#[test]
fn a_killed_launcher_leaves_no_loop_running_and_its_logs_merge() {
    let _g = process_lock();
    let dir = scratch("killrun");
    let job = feedloop_tests::write_long_circle_job(&dir, "killrun");
    let inst = format!("killrun-{}", std::process::id());
    let out = dir.join("out");
    let mut run = start_run(&job, &out, "realtime", &inst);
    wait_for_process(&["scheduler", "--instance", &inst]);
    std::thread::sleep(feedloop_tests::after_start(Duration::from_millis(400)));
    signal(run.id(), "KILL");
    let _ = run.wait();
    let t = std::time::Instant::now();
    while find_loop(&inst) && t.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let gone = t.elapsed();
    assert!(
        !find_loop(&inst),
        "plant or scheduler still running 3 s after the kill"
    );
    assert!(
        gone < Duration::from_secs(1),
        "the loop outlived its launcher by {gone:?}"
    );
    eprintln!("loop gone {gone:?} after the launcher's kill");
    let m = Command::new(feedloop_bin())
        .arg("merge")
        .arg(&out)
        .arg("--job")
        .arg(&job)
        .args(["--json"])
        .output()
        .unwrap();
    let sum: serde_json::Value =
        serde_json::from_slice(&m.stdout).unwrap_or_else(|_| panic!("{}", describe(&m)));
    assert_eq!(sum["end"]["reason"], "launcher_lost", "{sum}");
    assert_eq!(sum["end"]["safe_stop"], "brake_ramp", "{sum}");
    assert!(!m.status.success(), "a launcher's death is not a clean end");
    let rows = trace_rows(&out.join("trace.csv")).len() as u64;
    assert_eq!(rows, sum["cycles"].as_u64().unwrap());
    assert!(rows > sum["end"]["cycle"].as_u64().unwrap(), "{sum}");
    // The instance is free again.
    let again = Command::new(feedloop_bin())
        .args(["run"])
        .arg(repo_file("examples/jobs/xy-circle.toml"))
        .arg("--out")
        .arg(dir.join("again"))
        .args(["--mode", "lockstep", "--wait", "block", "--instance", &inst])
        .output()
        .unwrap();
    assert!(again.status.success(), "{}", describe(&again));
}

/// Whether a plant or scheduler process of `inst` is still there (zombies are gone processes).
fn find_loop(inst: &str) -> bool {
    ["plant", "scheduler"].iter().any(|role| {
        feedloop_tests::find_process(&[role, "--instance", inst]).is_some_and(|pid| {
            std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .map(|s| !s.contains(") Z "))
                .unwrap_or(false)
        })
    })
}

#[test]
fn killed_plant_is_reported_as_plant_lost_with_the_trace_kept() {
    let _g = process_lock();
    let dir = scratch("killplant");
    let job = job(&dir, "killplant", "", None);
    let out = dir.join("out");
    let inst = format!("killplant-{}", std::process::id());
    let mut run = start_run(&job, &out, "realtime", &inst);
    let plant = wait_for_process(&["plant", "--instance", &inst]);
    std::thread::sleep(feedloop_tests::after_start(Duration::from_millis(300)));
    signal(plant, "KILL");
    let st = run.wait().unwrap();
    assert!(!st.success());
    let sum = read_json(&out.join("summary.json"));
    assert_eq!(sum["end"]["reason"], "plant_lost", "{sum}");
    assert_eq!(sum["scheduler"]["end"]["reason"], "plant_lost", "{sum}");
    let rows = assert_contiguous(&out.join("trace.csv"));
    assert!(rows > 0);
}

#[test]
fn operator_stop_of_the_run_or_the_scheduler_brakes_and_exits_cleanly() {
    let _g = process_lock();
    let dir = scratch("opstop");
    let job = job(&dir, "opstop", "", None);
    for target in ["run", "scheduler"] {
        let out = dir.join(target);
        let inst = format!("opstop-{}-{target}", std::process::id());
        let mut run = start_run(&job, &out, "realtime", &inst);
        let sched = wait_for_process(&["scheduler", "--instance", &inst]);
        std::thread::sleep(feedloop_tests::after_start(Duration::from_millis(300)));
        let pid = if target == "run" { run.id() } else { sched };
        signal(pid, "TERM");
        let st = run.wait().unwrap();
        let sum = read_json(&out.join("summary.json"));
        assert_eq!(sum["end"]["reason"], "operator_stop", "{target}: {sum}");
        assert_eq!(sum["end"]["safe_stop"], "brake_ramp");
        assert!(st.success(), "{target}: operator stop must exit 0");
        let rows = trace_rows(&out.join("trace.csv"));
        // Braked: the last motor velocities are near zero (x.motor_vel is column 4, y's 9).
        let last = rows.last().unwrap();
        assert!(
            last[4].abs() < 0.5 && last[9].abs() < 0.5,
            "{target}: still moving: {last:?}"
        );
    }
}

fn limit_stop(name: &str, safety: &str, model_y: Option<&str>, reason: &str) {
    let dir = scratch(name);
    let job = job(&dir, name, safety, model_y);
    let out = dir.join("out");
    let o = Command::new(feedloop_bin())
        .args(["run"])
        .arg(&job)
        .arg("--out")
        .arg(&out)
        .args(["--mode", "lockstep", "--wait", "block"])
        .output()
        .unwrap();
    assert!(
        !o.status.success(),
        "{name}: a limit stop must exit non-zero"
    );
    let sum = read_json(&out.join("summary.json"));
    assert_eq!(sum["end"]["reason"], reason, "{sum}");
    assert!(sum["end"]["axis"].is_string());
}

#[test]
fn following_error_above_the_limit_stops_the_run() {
    let _g = process_lock();
    // The circle lags by v / Kp = 0.02 / 50 = 0.4 mm: a 0.1 mm alarm must trip.
    limit_stop(
        "fe",
        "max_following_error_m = 1.0e-4",
        None,
        "following_error",
    );
}

#[test]
fn leaving_the_soft_travel_limits_stops_the_run() {
    let _g = process_lock();
    limit_stop(
        "soft",
        "soft_limits_m = { x = [-0.005, 0.005] }",
        None,
        "soft_limit",
    );
}

#[test]
fn torque_saturated_too_long_stops_the_run() {
    let _g = process_lock();
    let dir = scratch("satmodel");
    let weak = dir.join("weak-y.toml");
    let text = std::fs::read_to_string(repo_file("examples/models/xy-y.toml"))
        .unwrap()
        .replace("torque_limit_nm = 30.0", "torque_limit_nm = 0.02");
    std::fs::write(&weak, text).unwrap();
    limit_stop(
        "sat",
        "max_saturation_s = 0.02",
        Some(weak.to_str().unwrap()),
        "torque_saturation",
    );
}

#[test]
fn a_second_scheduler_cannot_attach_to_a_running_instance() {
    let _g = process_lock();
    let dir = scratch("second");
    let job = job(&dir, "second", "", None);
    let inst = format!("second-{}", std::process::id());
    let out = dir.join("out");
    let mut run = start_run(&job, &out, "realtime", &inst);
    wait_for_process(&["scheduler", "--instance", &inst]);
    std::thread::sleep(Duration::from_millis(200));
    let o = Command::new(feedloop_bin())
        .args(["scheduler", "--instance", &inst, "--job"])
        .arg(&job)
        .arg("--out")
        .arg(dir.join("intruder"))
        .output()
        .unwrap();
    assert!(
        !o.status.success(),
        "a second scheduler attached: {}",
        describe(&o)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("publisher"), "{err}");
    signal(run.id(), "TERM");
    let _ = run.wait();
    let sum = read_json(&out.join("summary.json"));
    // The intruder did not disturb the loop: no bad sequence numbers reached the plant.
    assert_eq!(sum["bad_sequence"], 0, "{sum}");
}

/// A long circle for the plugin-fault runs (about 12 s at 2 kHz, ended by the fault or a stop).
fn long_job(dir: &Path, name: &str) -> PathBuf {
    let text = std::fs::read_to_string(job(dir, name, "", None))
        .unwrap()
        .replace("turns = 1.0", "turns = 10.0");
    let p = dir.join(format!("{name}-long.toml"));
    std::fs::write(&p, text).unwrap();
    p
}

/// Starts a realtime run, swaps the example library plugin (with `params`) into axis x's
/// velocity stage, and returns the run, the swap's output, the out folder and the scratch
/// folder holding it (kept while the caller holds it).
fn swap_in_faulty_plugin(
    name: &str,
    params: &str,
) -> (
    std::process::Child,
    std::process::Output,
    PathBuf,
    feedloop_tests::Scratch,
) {
    let dir = scratch(name);
    let lib = feedloop_tests::build_example_plugin(&dir.join("t-plugin"), false);
    let job = long_job(&dir, name);
    let p = dir.join("params.toml");
    std::fs::write(&p, params).unwrap();
    let (run, inst, out) = start_realtime_run(&dir, &job, name, Duration::from_millis(300));
    let o = swap_x_velocity(
        &inst,
        &[
            "--plugin",
            "pi_velocity_c",
            "--lib",
            lib.to_str().unwrap(),
            "--params",
            p.to_str().unwrap(),
        ],
    );
    (run, o, out, dir)
}

#[test]
fn a_plugin_failing_during_its_probation_is_rolled_back_and_the_loop_runs_on() {
    let _g = process_lock();
    // NaN torque from the 4th cycle on: inside the 10-cycle probation.
    let (mut run, o, out, _dir) = swap_in_faulty_plugin(
        "probation",
        "kv_nms_per_rad = 5.0\ntest_fault = 2\ntest_fault_after_cycles = 3\n",
    );
    assert!(!o.status.success(), "{}", describe(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("rolled back"), "{text}");
    std::thread::sleep(Duration::from_millis(200));
    signal(run.id(), "TERM");
    assert!(run.wait().unwrap().success());
    let sum = read_json(&out.join("summary.json"));
    assert_eq!(sum["end"]["reason"], "operator_stop", "{sum}");
    let sw = &sum["swaps"][0];
    assert_eq!(sw["rolled_back"], true, "{sum}");
    assert!(
        sw["reason"].as_str().unwrap().contains("non-finite"),
        "{sw}"
    );
    assert!(sum["scheduler"]["nonfinite_faults"].as_u64().unwrap() >= 1);
    // No non-finite value reached the plant.
    for r in trace_rows(&out.join("trace.csv")) {
        assert!(r.iter().all(|v| v.is_finite()), "{r:?}");
    }
}

#[test]
fn a_plugin_producing_nan_after_its_probation_stops_the_axes_as_a_plugin_fault() {
    let _g = process_lock();
    for (kind, what) in [("1", "error code"), ("2", "NaN torque")] {
        let (mut run, o, out, _dir) = swap_in_faulty_plugin(
            &format!("nanlater{kind}"),
            &format!("kv_nms_per_rad = 5.0\ntest_fault = {kind}\ntest_fault_after_cycles = 400\n"),
        );
        assert!(o.status.success(), "{what}: {}", describe(&o));
        let st = run.wait().unwrap();
        assert!(!st.success(), "{what}: a plugin fault must exit non-zero");
        let sum = read_json(&out.join("summary.json"));
        assert_eq!(sum["end"]["reason"], "plugin_fault", "{what}: {sum}");
        assert_eq!(sum["end"]["safe_stop"], "brake_ramp", "{sum}");
        assert_eq!(sum["swaps"][0]["rolled_back"], false, "{sum}");
        // The stop began within a cycle or two of the fault: 400 plugin steps after the swap.
        let swap_cycle = sum["swaps"][0]["cycle"].as_u64().unwrap();
        let stop_cycle = sum["end"]["cycle"].as_u64().unwrap();
        assert!(
            stop_cycle >= swap_cycle + 400 && stop_cycle <= swap_cycle + 404,
            "{what}: swap at {swap_cycle}, stop at {stop_cycle}"
        );
        let rows = trace_rows(&out.join("trace.csv"));
        for r in &rows {
            assert!(r.iter().all(|v| v.is_finite()), "{what}: {r:?}");
        }
        let last = rows.last().unwrap();
        assert!(last[4].abs() < 0.5, "{what}: x still moving: {last:?}");
    }
}

#[test]
fn a_plugin_library_that_crashes_the_scheduler_is_handled_as_a_lost_scheduler() {
    let _g = process_lock();
    let (mut run, o, out, _dir) = swap_in_faulty_plugin(
        "crash",
        "kv_nms_per_rad = 5.0\ntest_fault = 3\ntest_fault_after_cycles = 400\n",
    );
    assert!(o.status.success(), "{}", describe(&o));
    let st = run.wait().unwrap();
    assert!(!st.success());
    let sum = read_json(&out.join("summary.json"));
    assert_eq!(sum["end"]["reason"], "scheduler_lost", "{sum}");
    assert_eq!(
        sum["end"]["detected_after_cycles"].as_u64(),
        Some(WATCHDOG),
        "{sum}"
    );
    let rows = assert_contiguous(&out.join("trace.csv"));
    assert!(rows > 400);
}
