//! Swapping the velocity controller of a running loop: every swap is bumpless, none rolls back,
//! and a bad request is refused without disturbing the loop.

use std::path::Path;
use std::time::Duration;

use feedloop_tests::{
    feedloop, process_lock, read_json, repo_file, scratch, start_run, wait_for_process,
};

const SWAPS: usize = 20;

#[test]
fn swapping_the_velocity_loop_while_running_is_bumpless_and_bad_requests_are_refused() {
    let _g = process_lock();
    let dir = scratch("swap");
    let models = repo_file("examples/models");
    let job = dir.join("swap.toml");
    std::fs::write(
        &job,
        format!(
            r#"name = "swap"
period_s = 0.0005
duration_s = 30.0
[run]
wait = "block"
[axes.x]
model = "{m}/xy-x.toml"
[axes.y]
model = "{m}/xy-y.toml"
[trajectory]
kind = "circle"
axes = ["x", "y"]
center_m = [-0.01, 0.0]
radius_m = 0.01
feed_m_per_s = 0.0333
turns = 100.0
ramp_s = 0.1
"#,
            m = models.display()
        ),
    )
    .unwrap();
    let p1 = dir.join("soft.toml");
    let p2 = dir.join("stiff.toml");
    std::fs::write(&p1, "kv_nms_per_rad = 4.0\ntv_s = 0.006\n").unwrap();
    std::fs::write(&p2, "kv_nms_per_rad = 6.0\ntv_s = 0.004\n").unwrap();
    let inst = format!("swap-{}", std::process::id());
    let out = dir.join("out");
    let mut run = start_run(&job, &out, "realtime", &inst);
    wait_for_process(&["scheduler", "--instance", &inst]);
    std::thread::sleep(Duration::from_millis(300));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    for i in 0..SWAPS {
        let params = if i % 2 == 0 { s(&p1) } else { s(&p2) };
        let o = feedloop(&[
            "swap",
            "--instance",
            &inst,
            "--axis",
            "x",
            "--stage",
            "velocity",
            "--plugin",
            "pi_velocity",
            "--params",
            &params,
        ]);
        assert!(
            o.status.success(),
            "swap {i}: {}",
            String::from_utf8_lossy(&o.stdout)
        );
    }
    // Refused requests, answered with a reason, loop undisturbed: the plant's deadline-miss
    // count (reported through the status service) is the same before and after them.
    let before = feedloop_tests::status(&inst);
    let mut refused = 0;
    for (args, why) in [
        (
            vec![
                "--axis",
                "q",
                "--stage",
                "velocity",
                "--plugin",
                "pi_velocity",
            ],
            "does not exist",
        ),
        (
            vec![
                "--axis",
                "x",
                "--stage",
                "velocity",
                "--plugin",
                "no_such_plugin",
            ],
            "unknown plugin",
        ),
        (
            vec![
                "--axis",
                "x",
                "--stage",
                "spindle",
                "--plugin",
                "pi_velocity",
            ],
            "unknown stage",
        ),
    ] {
        let mut a = vec!["swap", "--instance", inst.as_str()];
        a.extend(args);
        let o = feedloop(&a);
        assert!(!o.status.success());
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(text.contains(why), "{text}");
        refused += 1;
    }
    let st = feedloop_tests::status(&inst);
    assert!(
        st["cycle"].as_u64() > before["cycle"].as_u64(),
        "the loop kept running: {before} -> {st}"
    );
    assert_eq!(
        st["deadline_misses"], before["deadline_misses"],
        "refused requests disturbed the loop: {before} -> {st}"
    );
    assert_eq!(st["rejected_requests"].as_u64(), Some(refused));
    assert_eq!(st["swaps"].as_u64().unwrap() as usize, SWAPS);
    assert_eq!(st["axes"][0]["stages"]["velocity"], "pi_velocity");
    let pid = run.id();
    feedloop_tests::signal(pid, "TERM");
    let code = run.wait().unwrap();
    assert!(code.success());
    let sum = read_json(&out.join("summary.json"));
    let swaps = sum["swaps"].as_array().unwrap();
    assert_eq!(swaps.len(), SWAPS);
    for (i, w) in swaps.iter().enumerate() {
        let step = w["torque_step"].as_f64().unwrap();
        let allowed = w["allowed_step"].as_f64().unwrap();
        assert!(
            step <= allowed,
            "swap {i}: torque step {step} > allowed {allowed}: {w}"
        );
        assert_eq!(w["rolled_back"], false, "{w}");
        assert_eq!(w["from"], "pi_velocity");
    }
    assert_eq!(sum["bad_sequence"], 0);
    let rejected = sum["rejected_requests"].as_array().unwrap();
    assert_eq!(rejected.len() as u64, refused, "{rejected:?}");
    for r in rejected {
        assert_eq!(r["op"], "swap", "{r}");
        assert!(!r["error"].as_str().unwrap().is_empty(), "{r}");
    }
}
