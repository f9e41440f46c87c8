//! Start-up of a realtime loop: the plant holds the axes and waits (the start-up grace) for the
//! first command before its schedule and its watchdog begin, so a scheduler that is slow to
//! answer its first sample neither leaves cycles with no command in the trace (a false following
//! error of the whole start position) nor gets declared lost.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use feedloop_model::job::{Job, Mode, WaitKind};
use feedloop_runtime::plant::{PlantEnd, StopCause};
use feedloop_runtime::shared::clock::now_ns;
use feedloop_runtime::shared::ipc::{scheduler_endpoint, WaitOutcome};
use feedloop_runtime::shared::wire::{instance_tag, ActuatorCommand, FLAG_END, FLAG_HELLO};
use feedloop_tests::{repo_file, scratch, spawn_plant_loop, PlantThread};
use feedloop_trace::log::{read_log, PlantRecord};

const CYCLES: u64 = 300;

/// A scheduler that completes the handshake, waits `first_delay` before its first answer (or
/// never answers), then answers every sample at once with the reference `x_ref` on every axis.
fn rogue_scheduler(instance: &str, n: usize, first_delay: Option<Duration>, x_ref: f64) -> u64 {
    let tag = instance_tag(instance);
    let ep = scheduler_endpoint(instance, WaitKind::Block, Duration::ZERO).unwrap();
    let mut hello = ActuatorCommand::empty(n as u32, tag);
    hello.flags = FLAG_HELLO;
    let give_up = now_ns() + 20_000_000_000;
    let mut answered = 0u64;
    let mut first = true;
    while now_ns() < give_up {
        let s = match ep.receive_until(now_ns() + 100_000_000).unwrap() {
            WaitOutcome::Got(s) => s,
            WaitOutcome::TimedOut => continue,
        };
        if s.flags & FLAG_HELLO != 0 {
            ep.send(hello).unwrap();
            continue;
        }
        if s.flags & FLAG_END != 0 && (first_delay.is_none() || s.seq + 1 >= CYCLES) {
            break;
        }
        match first_delay {
            None => continue,
            Some(d) if first => std::thread::sleep(d),
            Some(_) => {}
        }
        first = false;
        let mut cmd = ActuatorCommand::empty(n as u32, tag);
        cmd.seq = s.seq;
        for a in cmd.axes.iter_mut().take(n) {
            a.reference = x_ref;
        }
        ep.send(cmd).unwrap();
        answered += 1;
    }
    answered
}

/// The job, a fresh instance name, the plant log's path of one test and the scratch folder
/// holding it (kept while the caller holds it).
fn start(name: &str) -> (Job, String, std::path::PathBuf, feedloop_tests::Scratch) {
    let job = Job::load(&repo_file("examples/jobs/xy-circle.toml")).unwrap();
    let instance = format!("{name}{}", std::process::id());
    let dir = scratch(name);
    let log = dir.join("plant.log");
    (job, instance, log, dir)
}

/// A realtime plant of [`CYCLES`] cycles at 10 kHz.
fn realtime(watchdog_cycles: u64, startup_grace_s: f64, phase_probe_s: f64) -> PlantThread {
    PlantThread {
        mode: Mode::Realtime,
        period_s: 1e-4,
        cycles: CYCLES,
        watchdog_cycles,
        startup_grace_s,
        phase_probe_s,
        cycle_hook: None,
    }
}

#[test]
fn a_scheduler_slow_to_answer_its_first_sample_closes_the_loop_without_a_false_start() {
    let _g = feedloop_tests::process_lock();
    let (job, instance, log, _dir) = start("startslow");
    let n = job.axes.len();
    let stop = Arc::new(AtomicBool::new(false));
    // 10 kHz with a 200-cycle watchdog: the 60 ms wait for the first answer is 600 periods,
    // which must not count against it.
    let plant = spawn_plant_loop(&job, &instance, log.clone(), stop, realtime(200, 2.0, 0.0));
    let answered = rogue_scheduler(&instance, n, Some(Duration::from_millis(60)), 0.004);
    let out = plant.join().unwrap();
    assert_eq!(out.end, PlantEnd::Completed, "{out:?}");
    let closed = out
        .loop_closed_after_s
        .expect("the loop closed: the start-up time is reported");
    assert!(
        (0.055..1.0).contains(&closed),
        "loop closed after {closed} s, the first answer came after 60 ms"
    );
    assert!(answered > 0);
    let recs = read_log::<PlantRecord>(&log).unwrap().records;
    assert_eq!(recs.len() as u64, CYCLES);
    // Every recorded cycle applied a command of the scheduler: none holds the empty start-up
    // command (reference 0) while the table sits elsewhere.
    let first = &recs[0];
    assert_eq!(first.seq, 0);
    assert_eq!(
        first.flags & feedloop_trace::log::REC_MISSED,
        0,
        "cycle 0 waited for its command"
    );
    for a in &first.axes[..n] {
        assert_eq!(a.cmd, 0.004, "cycle 0 recorded {a:?}");
    }
    assert!(
        out.sequence.missing * 10 < CYCLES,
        "{:?}: the first cycle must not count as missed",
        out.sequence
    );
}

#[test]
fn a_scheduler_that_never_answers_is_lost_after_the_start_up_grace_not_before() {
    let _g = feedloop_tests::process_lock();
    let (job, instance, log, _dir) = start("startnever");
    let n = job.axes.len();
    let stop = Arc::new(AtomicBool::new(false));
    let t0 = std::time::Instant::now();
    let plant = spawn_plant_loop(&job, &instance, log, stop, realtime(5, 0.3, 0.0));
    let answered = rogue_scheduler(&instance, n, None, 0.0);
    let out = plant.join().unwrap();
    let took = t0.elapsed().as_secs_f64();
    assert_eq!(answered, 0);
    assert!(out.loop_closed_after_s.is_none(), "{out:?}");
    match out.end {
        PlantEnd::Stopped {
            cause: StopCause::SchedulerLost {
                detected_after_cycles,
            },
            cycle,
            ..
        } => {
            assert_eq!((cycle, detected_after_cycles), (0, 0), "{out:?}");
        }
        other => panic!("expected scheduler_lost at cycle 0, got {other:?}"),
    }
    // The plant waited the whole grace (not 5 cycles of 100 us) before it gave up.
    assert!(took >= 0.3, "gave up after {took} s, grace 0.3 s");
}

#[test]
fn realtime_cycles_start_at_the_phase_the_probe_chose_and_keep_it() {
    let _g = feedloop_tests::process_lock();
    let (job, instance, log, _dir) = start("startphase");
    let n = job.axes.len();
    let stop = Arc::new(AtomicBool::new(false));
    let period_ns = 100_000u64;
    let plant = spawn_plant_loop(&job, &instance, log.clone(), stop, realtime(200, 2.0, 0.2));
    rogue_scheduler(&instance, n, Some(Duration::ZERO), 0.004);
    let out = plant.join().unwrap();
    assert_eq!(out.end, PlantEnd::Completed, "{out:?}");
    let phase = out.phase.expect("a realtime run with a probe reports it");
    assert!(phase.probe_s >= 0.2, "{phase:?}");
    let Some(q) = phase.quiet else {
        // nothing took the core during the probe: no phase to prefer
        assert_eq!(phase.interruptions, 0, "{phase:?}");
        eprintln!("the probe saw no interruption: nothing to check of the phase");
        return;
    };
    assert!(
        q.phase_ns < period_ns && q.hit_share <= q.worst_hit_share,
        "{q:?}"
    );
    // each cycle's deadline: the plant woke wake_late_ns after it and published a few us later
    // (unless the host took the core between)
    let recs = read_log::<PlantRecord>(&log).unwrap().records;
    let mut off: Vec<u64> = recs[1..]
        .iter()
        .map(|r| (r.published_ns - r.wake_late_ns + period_ns - q.phase_ns) % period_ns)
        .collect();
    off.sort_unstable();
    let median = off[off.len() / 2];
    assert!(
        median < 3_000,
        "cycles published {median} ns after the chosen phase {q:?} (median)"
    );
}
