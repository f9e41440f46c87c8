//! The hot path allocates nothing of its own: 10,000 cycles of the scheduler loop (IPC receive, full chain,
//! command send, recorder hand-off, control-service polling) and of the plant loop (deadline,
//! physics, IPC, recorder) run with a counting allocator armed after start-up.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use feedloop_model::job::{Job, Mode, WaitKind};
use feedloop_plugins::Builtins;
use feedloop_runtime::plant::PlantEnd;
use feedloop_runtime::scheduler::control::ControlPlane;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_runtime::scheduler::{run_scheduler, SchedulerConfig, SchedulerEnd};
use feedloop_runtime::shared::ipc::scheduler_endpoint;
use feedloop_tests::{repo_file, scratch, spawn_plant_loop, PlantThread};

struct Counting;

/// Allocations and frees by feedloop's own code in armed cycles.
static ALLOCS: AtomicU64 = AtomicU64::new(0);
/// Allocations and frees inside iceoryx2's loan/send (one reference-counted block per message).
static IOX_ALLOCS: AtomicU64 = AtomicU64::new(0);

fn count() {
    if ARMED.with(Cell::get) {
        if feedloop_runtime::shared::ipc::in_iceoryx_send() {
            IOX_ALLOCS.fetch_add(1, Ordering::Relaxed);
        } else {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
    }
}
thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        count();
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

const WARMUP: u64 = 100;
const COUNTED: u64 = 10_000;
const TOTAL: u64 = WARMUP + COUNTED + 2;

fn hook(k: u64) {
    if k == WARMUP {
        ARMED.with(|a| a.set(true));
    }
    if k == WARMUP + COUNTED {
        ARMED.with(|a| a.set(false));
    }
}

#[test]
fn ten_thousand_cycles_of_both_loops_allocate_nothing_outside_iceoryx2_send() {
    let _g = feedloop_tests::process_lock();
    let dir = scratch("noalloc");
    let job = Job::load(&repo_file("examples/jobs/xy-circle.toml")).unwrap();
    let instance = format!("noalloc{}", std::process::id());
    let stop = Arc::new(AtomicBool::new(false));

    let plant = spawn_plant_loop(
        &job,
        &instance,
        dir.join("plant.log"),
        stop.clone(),
        PlantThread {
            mode: Mode::Lockstep,
            period_s: job.period_s,
            cycles: TOTAL,
            watchdog_cycles: 100,
            startup_grace_s: 2.0,
            phase_probe_s: 0.0,
            cycle_hook: Some(hook),
        },
    );

    let mut cycle = ControlCycle::new(&job, &Builtins).unwrap();
    cycle.set_cycles(TOTAL);
    let ep = scheduler_endpoint(&instance, WaitKind::Block, Duration::ZERO).unwrap();
    let mut control = ControlPlane::open(&instance, &job, &cycle, Arc::new(Builtins)).unwrap();
    let cfg = SchedulerConfig {
        instance: instance.clone(),
        mode: Mode::Lockstep,
        peer_timeout_s: 10.0,
        stale_after_s: 1.0,
        cycle_hook: Some(hook),
    };
    let n = job.axes.len();
    let out = run_scheduler(
        &cfg,
        &mut cycle,
        n,
        &ep,
        &dir.join("scheduler.log"),
        &stop,
        Some(&mut control),
    )
    .unwrap();
    let plant_out = plant.join().unwrap();
    assert_eq!(out.end, SchedulerEnd::Completed);
    assert_eq!(plant_out.end, PlantEnd::Completed);
    assert_eq!(plant_out.cycles, TOTAL);
    assert_eq!(out.commands, TOTAL);
    assert_eq!(
        ALLOCS.load(Ordering::Relaxed),
        0,
        "feedloop code allocated (or freed) inside {COUNTED} armed cycles"
    );
    // iceoryx2 0.10's loan_uninit allocates one reference-counted block per message and frees it
    // on send: at most 2 events per message, 2 messages per cycle (sample and command).
    let iox = IOX_ALLOCS.load(Ordering::Relaxed);
    eprintln!("allocation events inside iceoryx2 send over {COUNTED} cycles: {iox}");
    assert!(
        iox <= 4 * (COUNTED + 2),
        "iceoryx2 send allocated more than expected: {iox}"
    );
}
