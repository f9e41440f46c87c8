//! Sequence faults on both services are detected and counted: a hand-written peer that speaks the
//! wire protocol injects out-of-order, duplicated, missing, late, alien and future sequence numbers
//! into the real plant loop and the real scheduler loop, and the counters must match the
//! injection plan.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use feedloop_model::job::{Job, Mode, WaitKind};
use feedloop_plugins::Builtins;
use feedloop_runtime::plant::PlantEnd;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_runtime::scheduler::{run_scheduler, SchedulerConfig, SchedulerEnd};
use feedloop_runtime::shared::clock::now_ns;
use feedloop_runtime::shared::ipc::{plant_endpoint, scheduler_endpoint, WaitOutcome};
use feedloop_runtime::shared::wire::{
    instance_tag, ActuatorCommand, SensorSample, FLAG_END, FLAG_HELLO,
};
use feedloop_tests::{repo_file, scratch, spawn_plant_loop, PlantThread};

const CYCLES: u64 = 200;

fn job() -> Job {
    Job::load(&repo_file("examples/jobs/xy-circle.toml")).unwrap()
}

fn count(pred: impl Fn(u64) -> bool) -> u64 {
    (0..CYCLES).filter(|&k| pred(k)).count() as u64
}

/// The plant loop (realtime, 5 ms period so the injected faults are the only ones expected)
/// against a scheduler that answers every cycle except by plan:
/// - k % 10 == 1: first a command carrying another instance's tag (bad),
/// - k % 10 == 3: first a command numbered five cycles ahead (bad),
/// - k % 10 == 6: the right command twice (the second is a duplicate),
/// - k % 10 == 8: no command at all (missing: the plant holds the last one),
/// - k % 10 == 9: first the overdue answer for cycle k-1 (late), then the right one.
#[test]
fn the_plant_counts_bad_duplicate_late_and_missing_commands() {
    let _g = feedloop_tests::process_lock();
    let dir = scratch("seq_plant");
    let job = job();
    let n = job.axes.len();
    let instance = format!("seqp{}", std::process::id());
    let tag = instance_tag(&instance);
    let stop = Arc::new(AtomicBool::new(false));
    let period_s = 5e-3;

    let plant = spawn_plant_loop(
        &job,
        &instance,
        dir.join("plant.log"),
        stop.clone(),
        PlantThread {
            mode: Mode::Realtime,
            period_s,
            cycles: CYCLES,
            watchdog_cycles: 50,
            startup_grace_s: 2.0,
            phase_probe_s: 0.0,
            cycle_hook: None,
        },
    );

    let ep = scheduler_endpoint(&instance, WaitKind::Block, Duration::ZERO).unwrap();
    let mut hello = ActuatorCommand::empty(n as u32, tag);
    hello.flags = FLAG_HELLO;
    let give_up = now_ns() + 20_000_000_000;
    let mut started = false;
    let mut answered = 0u64;
    while now_ns() < give_up {
        let s = match ep.receive_until(now_ns() + 100_000_000).unwrap() {
            WaitOutcome::Got(s) => s,
            WaitOutcome::TimedOut => continue,
        };
        if s.flags & FLAG_HELLO != 0 {
            ep.send(hello).unwrap();
            started = true;
            continue;
        }
        assert!(started, "a sample before the handshake");
        let k = s.seq;
        let mut cmd = ActuatorCommand::empty(n as u32, tag);
        cmd.seq = k;
        match k % 10 {
            1 => {
                let mut alien = cmd;
                alien.instance_tag = instance_tag("someone-else");
                ep.send(alien).unwrap();
                ep.send(cmd).unwrap();
            }
            3 => {
                let mut future = cmd;
                future.seq = k + 5;
                ep.send(future).unwrap();
                ep.send(cmd).unwrap();
            }
            6 => {
                ep.send(cmd).unwrap();
                ep.send(cmd).unwrap();
            }
            8 => {}
            9 => {
                let mut overdue = cmd;
                overdue.seq = k - 1;
                ep.send(overdue).unwrap();
                ep.send(cmd).unwrap();
            }
            _ => ep.send(cmd).unwrap(),
        }
        answered += 1;
        if s.flags & FLAG_END != 0 {
            break;
        }
    }
    let out = plant.join().unwrap();
    assert_eq!(out.end, PlantEnd::Completed, "{out:?}");
    assert_eq!(out.cycles, CYCLES);
    assert_eq!(answered, CYCLES, "the rogue scheduler saw every sample");

    let seq = out.sequence;
    let planned_missing = count(|k| k % 10 == 8);
    // Cycles the machine itself made us miss (none expected at 5 ms, but a loaded CI host may
    // delay one): each can turn one planned duplicate into a late answer.
    let natural = seq.missing - planned_missing;
    assert!(seq.missing >= planned_missing, "{seq:?}");
    assert!(
        natural <= 5,
        "too many unplanned misses for this test to mean much: {seq:?}"
    );
    assert_eq!(
        seq.bad_sequence,
        count(|k| k % 10 == 1 || k % 10 == 3),
        "{seq:?}"
    );
    let planned_dups = count(|k| k % 10 == 6);
    assert!(
        seq.duplicates <= planned_dups && seq.duplicates + natural >= planned_dups,
        "{seq:?}"
    );
    assert!(seq.late >= count(|k| k % 10 == 9), "{seq:?}");
    assert!(seq.late <= count(|k| k % 10 == 9) + 2 * natural, "{seq:?}");
}

/// The scheduler loop against a plant that, after the answer to cycle k, by plan:
/// - k % 10 == 2: never sends sample k+1 (missing),
/// - k % 10 == 4: sends sample k again (duplicate) before k+1,
/// - k % 10 == 7: sends sample k-3 (out of order) before k+1.
///
/// Every valid sample must still be answered with its own sequence number.
#[test]
fn the_scheduler_counts_duplicated_out_of_order_and_missing_samples() {
    let _g = feedloop_tests::process_lock();
    let dir = scratch("seq_sched");
    let job = job();
    let n = job.axes.len();
    let instance = format!("seqs{}", std::process::id());
    let tag = instance_tag(&instance);
    let stop = Arc::new(AtomicBool::new(false));

    let scheduler = spawn_lockstep_scheduler(&job, &instance, CYCLES, &dir, &stop);

    let ep = plant_endpoint(&instance, WaitKind::Block, Duration::ZERO).unwrap();
    // Handshake, as the plant does it.
    let mut hello = SensorSample::empty(n as u32, tag);
    hello.flags = FLAG_HELLO;
    let give_up = now_ns() + 20_000_000_000;
    loop {
        assert!(now_ns() < give_up, "no handshake");
        if ep.peer_connected() {
            ep.send(hello).unwrap();
        }
        if let WaitOutcome::Got(c) = ep.receive_until(now_ns() + 2_000_000).unwrap() {
            if c.flags & FLAG_HELLO != 0 {
                break;
            }
        }
    }
    std::thread::sleep(Duration::from_millis(2));
    ep.drain().unwrap();

    let sample = |k: u64| numbered_sample(n as u32, tag, k, CYCLES, job.period_s);
    let mut answers = Vec::new();
    let mut k = 0u64;
    while k < CYCLES {
        ep.send(sample(k)).unwrap();
        answers.push(next_answer(&ep, k, &stop, &answers));
        match k % 10 {
            2 => k += 1,
            4 => ep.send(sample(k)).unwrap(),
            7 => ep.send(sample(k - 3)).unwrap(),
            _ => {}
        }
        k += 1;
    }
    let out = scheduler.join().unwrap();
    assert_eq!(out.end, SchedulerEnd::Completed, "{out:?}");
    let sent: Vec<u64> = (0..CYCLES).filter(|k| k % 10 != 3).collect();
    assert_eq!(
        answers, sent,
        "every valid sample is answered with its own number"
    );
    assert_eq!(out.commands, sent.len() as u64);
    assert_eq!(out.missing, count(|k| k % 10 == 3), "{out:?}");
    assert_eq!(out.duplicated, count(|k| k % 10 == 4), "{out:?}");
    assert_eq!(out.out_of_order, count(|k| k % 10 == 7), "{out:?}");
}

/// The plant's sample number `k` of a run of `cycles` (the last one carries the end flag).
fn numbered_sample(n: u32, tag: u64, k: u64, cycles: u64, period_s: f64) -> SensorSample {
    let mut s = SensorSample::empty(n, tag);
    s.seq = k;
    s.plant_time_s = k as f64 * period_s;
    if k + 1 == cycles {
        s.flags = FLAG_END;
    }
    s
}

/// The number of the next command the scheduler sends (hello replies skipped); without one
/// within 5 s the scheduler is stopped and the test fails, naming sample `k` and the `answers`
/// so far.
fn next_answer(
    ep: &feedloop_runtime::shared::ipc::PlantEndpoint,
    k: u64,
    stop: &AtomicBool,
    answers: &[u64],
) -> u64 {
    loop {
        match ep.receive_until(now_ns() + 5_000_000_000).unwrap() {
            WaitOutcome::Got(c) if c.flags & FLAG_HELLO != 0 => continue,
            WaitOutcome::Got(c) => return c.seq,
            WaitOutcome::TimedOut => {
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
                panic!("no answer to sample {k} (answered: {answers:?})")
            }
        }
    }
}

/// The real scheduler loop of `job` in lockstep on `instance`, in a thread, for `cycles` cycles.
fn spawn_lockstep_scheduler(
    job: &Job,
    instance: &str,
    cycles: u64,
    dir: &std::path::Path,
    stop: &Arc<AtomicBool>,
) -> std::thread::JoinHandle<feedloop_runtime::scheduler::SchedulerOutcome> {
    let (job, instance, log, stop) = (
        job.clone(),
        instance.to_string(),
        dir.join("scheduler.log"),
        stop.clone(),
    );
    std::thread::spawn(move || {
        let mut cycle = ControlCycle::new(&job, &Builtins).unwrap();
        cycle.set_cycles(cycles);
        let ep = scheduler_endpoint(&instance, WaitKind::Block, Duration::ZERO).unwrap();
        let cfg = SchedulerConfig {
            instance,
            mode: Mode::Lockstep,
            peer_timeout_s: 10.0,
            stale_after_s: 1.0,
            cycle_hook: None,
        };
        run_scheduler(&cfg, &mut cycle, job.axes.len(), &ep, &log, &stop, None).unwrap()
    })
}

/// A plant whose hello was repeated before the scheduler answered (a busy machine: the plant
/// says hello every 2 ms until it hears back) finds the repeat queued right before its cycle-0
/// sample. Both carry number 0; the sample must still be answered, not dropped as a duplicate
/// of the hello (the plant would then wait out its timeout and stop with the scheduler lost).
#[test]
fn a_repeated_hello_queued_before_the_first_sample_does_not_swallow_it() {
    let _g = feedloop_tests::process_lock();
    let dir = scratch("seq_hello");
    let job = job();
    let n = job.axes.len() as u32;
    let instance = format!("seqh{}", std::process::id());
    let tag = instance_tag(&instance);
    let stop = Arc::new(AtomicBool::new(false));
    let cycles = 5;
    let scheduler = spawn_lockstep_scheduler(&job, &instance, cycles, &dir, &stop);

    let ep = plant_endpoint(&instance, WaitKind::Block, Duration::ZERO).unwrap();
    let give_up = now_ns() + 20_000_000_000;
    while !ep.peer_connected() {
        assert!(now_ns() < give_up, "the scheduler never connected");
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut hello = SensorSample::empty(n, tag);
    hello.flags = FLAG_HELLO;
    let sample = |k: u64| numbered_sample(n, tag, k, cycles, job.period_s);
    // back to back, so that the repeat and the sample wait in the queue together
    ep.send(hello).unwrap();
    ep.send(hello).unwrap();
    ep.send(sample(0)).unwrap();
    let mut answers = Vec::new();
    for k in 0..cycles {
        if k > 0 {
            ep.send(sample(k)).unwrap();
        }
        answers.push(next_answer(&ep, k, &stop, &answers));
    }
    let out = scheduler.join().unwrap();
    assert_eq!(answers, (0..cycles).collect::<Vec<_>>());
    assert_eq!(out.end, SchedulerEnd::Completed, "{out:?}");
    assert_eq!(out.duplicated, 0, "{out:?}");
}
