//! A control cycle whose references were prepared ahead of its sample (what the scheduler does
//! in its slack) gives exactly the command of one that evaluates them itself, and a preparation
//! for another cycle is not used.

use std::path::Path;

use feedloop_model::job::Job;
use feedloop_plugins::Builtins;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_runtime::shared::wire::{ActuatorCommand, SensorSample};

fn full_chain() -> ControlCycle {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let job = Job::load(&root.join("examples/jobs/xc-full-chain.toml")).unwrap();
    ControlCycle::new(&job, &Builtins).unwrap()
}

#[test]
fn prepared_references_give_the_same_commands_and_stale_ones_are_ignored() {
    let (mut plain, mut ahead) = (full_chain(), full_chain());
    let mut s = SensorSample::empty(2, 0);
    let (mut a, mut b) = (ActuatorCommand::empty(2, 0), ActuatorCommand::empty(2, 0));
    let mut seq = 0u64;
    ahead.prepare(0);
    for k in 0..3000u64 {
        // a skipped cycle now and then (realtime catch-up): the prepared one goes unused
        seq += if k % 700 == 699 { 3 } else { 1 };
        s.seq = seq;
        // a measured motion that is not the reference, so every term of the chain works
        s.axes[0].load_pos = 0.2 + 1e-6 * (k as f64).sin();
        s.axes[1].motor_vel = 1e-3 * (k as f64).cos();
        plain.step(&s, &mut a);
        ahead.step(&s, &mut b);
        assert_eq!(a, b, "cycle {seq}");
        ahead.prepare(seq + 1);
    }
    assert!(a.axes[0].torque != 0.0 && a.axes[1].torque != 0.0);
    // a preparation for a cycle that never comes does not leak into another one
    ahead.prepare(seq + 500);
    s.seq = seq + 1;
    plain.step(&s, &mut a);
    ahead.step(&s, &mut b);
    assert_eq!(a, b);
}
