//! One hundred swaps of a running 10 kHz loop: the X-Y circle in realtime with the blocking wait,
//! axis x's velocity controller swapped 100 times (the built-in PI with two parameter files and the
//! shared-library PI, alternating). Every swap is bumpless and none rolls back, and the
//! deadline-miss rate within 10 cycles of a swap is no higher than elsewhere in the run.
//!
//! The swaps are sent from this test process through the control service (the library call the
//! `feedloop swap` command makes), so no process start-up competes with the loop at swap time.
//!
//! Why blocking: with two spinning processes (`--wait hybrid --pin 0,1`) on this 2-core machine,
//! the swaps' own work (the scheduler's builder thread parsing and loading the new controller, the
//! request traffic of this process) has no free core and preempts the loop before each swap,
//! outside the 10-cycle window; misses elsewhere then rise to 5-20 % and a swap that follows a
//! skipped cycle can exceed its bumpless bound. That is a finding about swaps on a fully spun
//! 2-core machine, not a property this test can hold; the blocking wait leaves the cores idle
//! between cycles.

use std::time::Duration;

use feedloop_runtime::scheduler::control::protocol::{Request, SwapRequest};
use feedloop_tests::{
    process_lock, read_json, scratch, signal, start_realtime_run, write_xy_circle_job, Circle,
};

const SWAPS: usize = 100;

#[test]
fn a_hundred_swaps_at_10_khz_are_bumpless_and_do_not_raise_the_miss_rate() {
    let _g = process_lock();
    let dir = scratch("swap-storm");
    let lib = feedloop_tests::build_example_plugin(&dir.join("t-plugin"), false)
        .canonicalize()
        .unwrap();
    let job = write_xy_circle_job(
        &dir.join("storm.toml"),
        "name = \"swap-storm\"\nperiod_s = 1.0e-4",
        "",
        None,
        &Circle {
            center_m: [0.0, 0.0],
            radius_m: 0.01,
            feed_m_per_s: 0.0333333333333,
            turns: 8.0,
            ramp_s: 0.1,
        },
    );
    // Let the loop settle, so that the run has a stretch without swaps before the first one.
    let (mut run, inst, out) = start_realtime_run(&dir, &job, "storm", Duration::from_millis(800));

    let soft = "kv_nms_per_rad = 4.0\ntv_s = 0.006\n";
    let stiff = "kv_nms_per_rad = 6.0\ntv_s = 0.004\n";
    for i in 0..SWAPS {
        let swap = |plugin: &str, params: Option<&str>, lib: Option<&str>| {
            Request::Swap(SwapRequest {
                axis: "x".into(),
                stage: "velocity".into(),
                plugin: plugin.into(),
                params: params.map(str::to_string),
                lib: lib.map(str::to_string),
                force: false,
                params_file: None,
            })
        };
        let req = match i % 4 {
            0 => swap("pi_velocity", Some(soft), None),
            2 => swap("pi_velocity", Some(stiff), None),
            _ => swap("pi_velocity_c", None, lib.to_str()),
        };
        let answer =
            feedloop_runtime::scheduler::control::request(&inst, &req, Duration::from_secs(10))
                .unwrap_or_else(|e| panic!("swap {i}: {e}"));
        assert!(!answer.is_refused(), "swap {i}: {answer:?}");
        std::thread::sleep(Duration::from_millis(25));
    }
    std::thread::sleep(Duration::from_millis(800));
    signal(run.id(), "TERM");
    assert!(run.wait().unwrap().success());

    let sum = read_json(&out.join("summary.json"));
    let swaps = sum["swaps"].as_array().unwrap();
    assert_eq!(swaps.len(), SWAPS, "{sum}");
    for (i, w) in swaps.iter().enumerate() {
        assert_eq!(w["rolled_back"], false, "swap {i}: {w}");
        let step = w["torque_step"].as_f64().unwrap();
        let allowed = w["allowed_step"].as_f64().unwrap();
        assert!(step <= allowed, "swap {i}: {step} > {allowed}: {w}");
        let want = if i % 2 == 0 {
            "pi_velocity"
        } else {
            "pi_velocity_c"
        };
        assert_eq!(w["to"], want, "swap {i}");
    }
    let near = &sum["deadline_misses_near_swaps"];
    let far = &sum["deadline_misses_elsewhere"];
    let near_cycles = near["cycles"].as_u64().unwrap() as f64;
    // "No higher than elsewhere", with room for chance only: the count near swaps may exceed
    // what the rate elsewhere predicts by at most three Poisson standard deviations (plus three).
    // If swapping cost a miss per swap, this would be about 100 against a bound of a few.
    let n = near["misses"].as_u64().unwrap() as f64;
    let expected = far["rate"].as_f64().unwrap() * near_cycles;
    let bound = expected + 3.0 * expected.sqrt() + 3.0;
    eprintln!(
        "misses near swaps: {n} in {near_cycles} cycles; expected {expected:.2} at the rate elsewhere ({:.4} %); bound {bound:.2}",
        far["rate"].as_f64().unwrap() * 100.0
    );
    assert!(
        n <= bound,
        "misses: near swaps {near}, elsewhere {far}: {n} > {bound:.2}"
    );
    // All late cycles (misses and plant overruns) are reported, not asserted: with the blocking
    // wait at 10 kHz this VM overruns on most cycles, and the rate elsewhere swings between about
    // 60 % and 95 % from run to run with the machine's state (near swaps: about 80 %), so a
    // Poisson bound on it tests the VM's minute, not the swaps. Deadline misses are the measure
    // that stays meaningful here.
    eprintln!(
        "late cycles near swaps: {} in {near_cycles} cycles ({:.1} %); elsewhere {:.1} %",
        near["late_cycles"],
        near["late_rate"].as_f64().unwrap_or(f64::NAN) * 100.0,
        far["late_rate"].as_f64().unwrap_or(f64::NAN) * 100.0
    );
}
