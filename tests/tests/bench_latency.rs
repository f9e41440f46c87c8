//! `feedloop bench latency` end to end: a short realtime run of the full-chain job, checked for
//! the report's contract (the keys scripts read) and for consistency between its figures and the
//! logs the two processes left.

use feedloop_tests::{describe, feedloop, process_lock, read_json, scratch};
use feedloop_trace::log::{read_log, PlantRecord, SchedRecord, REC_MISSED};

#[test]
fn a_short_hybrid_run_reports_consistent_figures_and_its_references() {
    let _g = process_lock();
    let dir = scratch("bench-latency");
    let out = dir.join("lat");
    let o = feedloop(&[
        "bench",
        "latency",
        "--cycles",
        "3000",
        "--period-s",
        "1e-3",
        "--wait",
        "hybrid",
        "--reference-s",
        "0.3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    let v = read_json(&out.join("latency.json"));

    assert_eq!(v["cycles"], 3000, "{v}");
    assert_eq!(v["period_s"], 1e-3);
    assert_eq!(v["wait"], "hybrid");
    for h in ["latency_us", "jitter_us"] {
        let q: Vec<f64> = ["p50", "p99", "p999", "max"]
            .iter()
            .map(|k| v[h][k].as_f64().unwrap_or_else(|| panic!("{h}.{k}: {v}")))
            .collect();
        assert!(
            q[0] > 0.0 && q.windows(2).all(|w| w[0] <= w[1]),
            "{h}: {q:?}"
        );
    }
    let misses = v["deadline_misses"].as_u64().unwrap();
    let outside = v["misses_outside_stalls"].as_u64().unwrap();
    let explained = v["misses_during_core_losses"].as_u64().unwrap();
    let rest = v["misses_outside_stalls_and_core_losses"].as_u64().unwrap();
    assert!(v["core_losses"]["scheduler"].is_u64() && v["core_losses"]["plant_waits"].is_u64());
    assert!(outside <= misses && explained + rest == outside, "{v}");
    assert!(v["stalls"]["count"].is_u64() && v["stalls"]["max_ms"].is_number());
    assert!(v["realtime"]["mlockall"].is_boolean() && v["realtime"]["sched_fifo"].is_boolean());
    assert!(v["realtime"]["pinned"].is_array());

    // the figures agree with the logs
    let plant = read_log::<PlantRecord>(&out.join("plant.log"))
        .unwrap()
        .records;
    assert_eq!(plant.len(), 3000);
    let logged_misses = plant.iter().filter(|r| r.flags & REC_MISSED != 0).count() as u64;
    assert_eq!(logged_misses, misses);
    let answered = plant.iter().filter(|r| r.latency_ns != u64::MAX).count() as u64;
    assert_eq!(v["latency_us"]["count"].as_u64().unwrap(), answered);
    // the reported median is the logged one, within the histogram's three significant digits
    // (how fast the machine answers is the bench's figure, not this test's business)
    let mut lat: Vec<u64> = plant
        .iter()
        .filter(|r| r.latency_ns != u64::MAX)
        .map(|r| r.latency_ns.max(1))
        .collect();
    lat.sort_unstable();
    let lo = lat[(lat.len() - 1) / 2] as f64 / 1000.0;
    let hi = lat[lat.len() / 2] as f64 / 1000.0;
    let p50 = v["latency_us"]["p50"].as_f64().unwrap();
    assert!(
        p50 >= lo * (1.0 - 2e-3) - 1e-3 && p50 <= hi * (1.0 + 2e-3) + 1e-3,
        "p50 {p50} us vs the log's median {lo}..{hi} us"
    );
    let sched = read_log::<SchedRecord>(&out.join("scheduler.log"))
        .unwrap()
        .records;
    assert!(
        sched.len() as u64 >= answered,
        "{} < {answered}",
        sched.len()
    );
    // the full chain ran: the scheduler's job is the four-controller X-C grinder
    let job = std::fs::read_to_string(out.join("bench-job.toml")).unwrap();
    for id in [
        "position_p",
        "pi_velocity",
        "inverse_feedforward",
        "quadrant_compensator",
        "nl_pid_coupler",
    ] {
        assert!(job.contains(id), "{id} missing from the bench job");
    }
    // and it moved: the commanded torques are not all zero
    assert!(sched
        .iter()
        .any(|r| r.axes[0].0 != 0.0 && r.axes[1].0 != 0.0));

    // the reference loops ran on the same CPUs
    let r = &v["reference"];
    assert_eq!(r["seconds"], 0.3, "{v}");
    let sl = r["sleeping_loop"]["jitter_us"]["count"].as_u64().unwrap();
    let cpus = r["cpus"].as_array().unwrap().len() as u64;
    assert!(
        cpus >= 1 && sl == 300 * cpus,
        "{sl} wake-ups on {cpus} CPUs"
    );
    assert!(r["spinning_loop"]["interruptions"].is_u64());
    assert!(r["spinning_loop"]["max_us"].is_number());
    // the bare iceoryx2 ping-pong of the same messages, both paces, each round trip answered,
    // and the loop's ratio to it
    let pp = &v["iceoryx_pingpong"];
    // one paced ping in 8 is timed by the echo too: those split the floor into parts and are
    // left out of its figures
    let timed = 3000 / 8;
    assert_eq!(pp["breakdown_us"]["pings"], timed, "{v}");
    for part in ["to_echo", "turnaround", "publish", "to_pinger"] {
        assert!(
            pp["breakdown_us"][part]["p50"].as_f64().unwrap() > 0.0,
            "{part}: {v}"
        );
    }
    for (pace, n) in [("back_to_back_us", 3000), ("paced_us", 3000 - timed)] {
        assert_eq!(pp[pace]["count"], n, "{pace}: {v}");
        assert_eq!(pp["after"][pace]["count"], n, "after, {pace}: {v}");
        let (p50, p99) = (
            pp[pace]["p50"].as_f64().unwrap(),
            pp[pace]["p99"].as_f64().unwrap(),
        );
        assert!(p50 > 0.0 && p99 >= p50, "{pace}: {v}");
    }
    // the round trip in parts: every answered cycle split, each part measured
    let b = &v["breakdown_us"];
    assert_eq!(b["cycles"], v["latency_us"]["count"], "{v}");
    for part in [
        "to_scheduler",
        "before_compute",
        "chain",
        "publish",
        "to_plant",
    ] {
        assert!(b[part]["p50"].as_f64().unwrap() > 0.0, "{part}: {v}");
    }
    // the parts of one cycle add up to its round trip: so do their medians, roughly
    let sum: f64 = [
        "to_scheduler",
        "before_compute",
        "chain",
        "publish",
        "to_plant",
    ]
    .iter()
    .map(|p| b[*p]["p50"].as_f64().unwrap())
    .sum();
    let loop_p50 = v["latency_us"]["p50"].as_f64().unwrap();
    assert!(
        sum > 0.3 * loop_p50 && sum < 3.0 * loop_p50,
        "{sum} vs {loop_p50}: {v}"
    );
    // the series table reads the run back: one row with its ratio
    let t = feedloop(&["bench", "table", out.to_str().unwrap()]);
    assert!(t.status.success(), "{}", describe(&t));
    let text = String::from_utf8_lossy(&t.stdout);
    let rows: Vec<&str> = text.lines().filter(|l| l.contains("lat |")).collect();
    assert_eq!(rows.len(), 1, "{text}");
    assert_eq!(rows[0].matches('|').count(), 9, "{text}");
    // the last cell: the start phase the plant's probes chose against the worst one
    let phase_cell = rows[0].trim_end().trim_end_matches('|').trim_end();
    let probed = v["phase"]["loop"][0]["phase_us"].is_number();
    assert_eq!(phase_cell.ends_with("per cycle"), probed, "{text}");
    let ratio = v["iceoryx_pingpong"]["ratio"]["p50"].as_f64().unwrap();
    assert!(
        rows[0].contains(&format!("{} x", feedloop_model::units::sig(ratio))),
        "{text}"
    );
    let ratio = pp["ratio"]["p50"].as_f64().unwrap();
    let expected = loop_p50 / pp["paced_us"]["p50"].as_f64().unwrap();
    assert!((ratio / expected - 1.0).abs() < 0.01, "{v}");
    // the plot: axes with units and ticks, a legend, the period and the reference loops
    let svg = std::fs::read_to_string(out.join("latency.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains(r#"class="title""#));
    assert!(svg.contains(">percentile (%)<") && svg.contains(">time (us, log scale)<"));
    assert!(svg.matches(r#"class="x-tick""#).count() > 2);
    assert!(svg.matches(r#"class="y-tick""#).count() > 2);
    assert!(svg.contains(r#"class="legend""#));
    assert!(svg.contains(">control period 1 ms<"), "no period line");
    assert!(svg.contains(">reference: sleeping loop wake-up lateness<"));
    assert!(svg.contains(">reference: bare spinning loop, "));
}

#[test]
fn bad_arguments_are_refused_with_the_flag_named() {
    let dir = scratch("bench-latency-bad");
    let out = dir.join("x");
    for (args, needle) in [
        (vec!["--wait", "sometimes"], "--wait"),
        (vec!["--period-s", "0"], "--period-s"),
        (vec!["--pin", "0"], "--pin"),
        (vec!["--reference-s=-1"], "--reference-s"),
        (vec!["--phase-probe-s", "11"], "--phase-probe-s"),
    ] {
        let mut a = vec![
            "bench",
            "latency",
            "--cycles",
            "10",
            "--out",
            out.to_str().unwrap(),
        ];
        a.extend(args);
        let o = feedloop(&a);
        assert!(!o.status.success(), "{a:?} was accepted");
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(needle),
            "{a:?}: {}",
            describe(&o)
        );
    }
}

#[test]
fn a_run_in_parts_pools_every_part_and_its_share_of_the_ping_pong() {
    let _g = process_lock();
    let dir = scratch("bench-latency-parts");
    let out = dir.join("lat");
    let o = feedloop(&[
        "bench",
        "latency",
        "--cycles",
        "2001",
        "--period-s",
        "1e-3",
        "--wait",
        "hybrid",
        "--reference-s",
        "0",
        "--pingpong-cycles",
        "801",
        "--segments",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    let v = read_json(&out.join("latency.json"));
    assert_eq!(v["segments"], 2, "{v}");
    assert_eq!(v["cycles"], 2001, "{v}");
    // each part left its own logs: 1001 and 1000 cycles
    let mut answered = 0u64;
    for (k, n) in [(1, 1001usize), (2, 1000)] {
        let seg = out.join(format!("segment-{k}"));
        let plant = read_log::<PlantRecord>(&seg.join("plant.log"))
            .unwrap()
            .records;
        assert_eq!(plant.len(), n, "segment {k}");
        assert!(plant.iter().enumerate().all(|(i, r)| r.seq == i as u64));
        answered += plant.iter().filter(|r| r.latency_ns != u64::MAX).count() as u64;
        let sched = read_log::<SchedRecord>(&seg.join("scheduler.log")).unwrap();
        assert!(!sched.records.is_empty(), "segment {k}");
    }
    assert!(!out.join("plant.log").exists());
    assert_eq!(v["latency_us"]["count"].as_u64().unwrap(), answered, "{v}");
    assert_eq!(v["breakdown_us"]["cycles"], v["latency_us"]["count"], "{v}");
    // the ping-pong ran before each part: 401 + 400 pings of each pace, 50 + 50 of the paced
    // ones timed by the echo
    let pp = &v["iceoryx_pingpong"];
    assert_eq!(pp["segments"], 2, "{v}");
    assert_eq!(pp["back_to_back_us"]["count"], 801, "{v}");
    assert_eq!(pp["breakdown_us"]["pings"], 100, "{v}");
    assert_eq!(pp["paced_us"]["count"], 801 - 100, "{v}");
    assert!(pp["ratio"]["p50"].as_f64().unwrap() > 0.0, "{v}");
    // each part's loop and ping-pong probed the core (the default 0.5 s) before starting, and
    // started at a phase of the 1 ms period when the probe saw something to avoid
    let ph = &v["phase"];
    assert_eq!(ph["probe_s"], 0.5, "{v}");
    for side in ["loop", "pingpong"] {
        let parts = ph[side].as_array().unwrap_or_else(|| panic!("{side}: {v}"));
        assert_eq!(parts.len(), 2, "{v}");
        for p in parts {
            assert!(p["probe_s"].as_f64().unwrap() >= 0.5, "{p}");
            match p["phase_us"].as_f64() {
                Some(us) => {
                    assert!((0.0..1000.0).contains(&us), "{p}");
                    let (hit, worst) = (p["hit_share"].as_f64(), p["worst_hit_share"].as_f64());
                    assert!(hit.unwrap() <= worst.unwrap(), "{p}");
                }
                None => assert_eq!(p["interruptions"], 0, "{p}"),
            }
        }
    }
}
