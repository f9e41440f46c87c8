//! One plant step and one controller cycle, the two halves of every control period.
//!
//! `cargo bench -p feedloop-benches --bench step`

use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use feedloop_plant::Plant;
use feedloop_plugins::Builtins;
use feedloop_runtime::cycle::ControlCycle;
use feedloop_runtime::job::Job;
use feedloop_runtime::wire::{ActuatorCommand, SensorSample};

fn job(rel: &str) -> Job {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    Job::load(&root.join(rel)).expect("example job")
}

fn bench_steps(c: &mut Criterion) {
    let job = job("examples/jobs/xy-circle.toml");
    let n = job.axes.len() as u32;
    let mut cycle = ControlCycle::new(&job, &Builtins).unwrap();
    let mut plant = Plant::new(&job).unwrap();
    plant.set_initial_positions(&cycle.initial_positions());
    let mut sample = SensorSample::empty(n, 0);
    let mut cmd = ActuatorCommand::empty(n, 0);
    plant.sense(&mut sample);
    cycle.step(&sample, &mut cmd);

    let mut g = c.benchmark_group("xy-circle (2 axes)");
    g.bench_function("plant step + sense", |b| {
        b.iter(|| {
            plant.step(black_box(&cmd));
            plant.sense(black_box(&mut sample));
        })
    });
    let mut k = 0u64;
    g.bench_function("control cycle (trajectory + P/PI chain)", |b| {
        b.iter(|| {
            sample.seq = k % cycle.cycles();
            k += 1;
            cycle.step(black_box(&sample), black_box(&mut cmd));
        })
    });
    g.bench_function("closed loop (sense + control + step)", |b| {
        b.iter(|| {
            sample.seq = k % cycle.cycles();
            k += 1;
            plant.sense(&mut sample);
            cycle.step(&sample, &mut cmd);
            plant.step(black_box(&cmd));
        })
    });
    g.finish();
}

criterion_group!(benches, bench_steps);
criterion_main!(benches);
