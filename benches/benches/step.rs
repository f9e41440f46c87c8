//! The two halves of every control period, and the in-process simulation that strings them:
//! - one plant step + sense of two axes: no effects (`xy-circle`), friction + backlash + noise
//!   (`xy-circle-effects`), every effect of the plant library (`xy-x-all-effects.toml` on both);
//! - one control cycle: trajectory + P/PI chain (`xy-circle`); the full chain of the four seed
//!   methods (`xc-full-chain`: P, PI, inverse-model feedforward and quadrant compensator on each
//!   axis, nonlinear PID contour coupler across both), with and without its X-C trajectory;
//! - `feedloop sim` throughput on `xy-circle-effects` (criterion's elements/s are cycles per
//!   second: divide by 10,000 for multiples of real time at 10 kHz).
//!
//! `cargo bench -p feedloop-benches --bench step`

use std::hint::black_box;
use std::path::{Path, PathBuf};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use feedloop_analysis::sim::Simulation;
use feedloop_control::controller::{CycleContext, REF_DERIVS};
use feedloop_model::job::Job;
use feedloop_motion::RefState;
use feedloop_plant::Plant;
use feedloop_plugins::Builtins;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_runtime::shared::wire::{ActuatorCommand, SensorSample, MAX_AXES};
use feedloop_trace::log::AxisRecord;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace root")
        .to_path_buf()
}

fn job(rel: &str) -> Job {
    Job::load(&root().join(rel)).expect("example job")
}

/// `xy-circle-effects` with `model` (relative to examples/models) on both axes.
fn job_with_model(model: &str) -> Job {
    let text = std::fs::read_to_string(root().join("examples/jobs/xy-circle-effects.toml"))
        .expect("example job")
        .replace("xy-x-effects.toml", model)
        .replace("xy-y-effects.toml", model);
    let dir = std::env::temp_dir().join(format!("feedloop-bench-step-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let models = root().join("examples/models");
    let text = text.replace("../models/", &format!("{}/", models.display()));
    let path = dir.join("job.toml");
    std::fs::write(&path, text).expect("temp job");
    Job::load(&path).expect("bench job")
}

fn plant_steps(c: &mut Criterion) {
    let mut g = c.benchmark_group("plant step + sense, 2 axes");
    for (name, job) in [
        (
            "no effects (xy-circle)",
            job("examples/jobs/xy-circle.toml"),
        ),
        (
            "friction + backlash + noise (xy-circle-effects)",
            job("examples/jobs/xy-circle-effects.toml"),
        ),
        (
            "every effect (xy-x-all-effects)",
            job_with_model("xy-x-all-effects.toml"),
        ),
    ] {
        let n = job.axes.len() as u32;
        let mut cycle = ControlCycle::new(&job, &Builtins).expect("cycle");
        let mut start = Plant::new(&job).expect("plant");
        start.set_initial_positions(&cycle.initial_positions());
        // The commands of the first REPLAY cycles of the closed loop (ramp-up and circling),
        // replayed open-loop: the same commands from the same start give the same motion.
        const REPLAY: usize = 4096;
        let mut sample = SensorSample::empty(n, 0);
        let mut cmds = vec![ActuatorCommand::empty(n, 0); REPLAY];
        let mut plant = start.clone();
        for (k, cmd) in cmds.iter_mut().enumerate() {
            sample.seq = k as u64;
            plant.sense(&mut sample.axes);
            cycle.step(&sample, cmd);
            plant.step(&cmd.axes);
        }
        let mut plant = start.clone();
        let mut j = 0usize;
        g.bench_function(name, |b| {
            b.iter(|| {
                if j == REPLAY {
                    plant = start.clone();
                    j = 0;
                }
                plant.step(black_box(&cmds[j].axes));
                plant.sense(black_box(&mut sample.axes));
                j += 1;
            })
        });
    }
    g.finish();
}

fn control_cycles(c: &mut Criterion) {
    let mut g = c.benchmark_group("control cycle, 2 axes");
    for (name, rel) in [
        (
            "trajectory + P/PI chain (xy-circle)",
            "examples/jobs/xy-circle.toml",
        ),
        (
            "trajectory + full chain (xc-full-chain)",
            "examples/jobs/xc-full-chain.toml",
        ),
    ] {
        let job = job(rel);
        let n = job.axes.len() as u32;
        let mut cycle = ControlCycle::new(&job, &Builtins).expect("cycle");
        let mut plant = Plant::new(&job).expect("plant");
        plant.set_initial_positions(&cycle.initial_positions());
        let mut sample = SensorSample::empty(n, 0);
        let mut cmd = ActuatorCommand::empty(n, 0);
        plant.sense(&mut sample.axes);
        let mut k = 0u64;
        g.bench_function(name, |b| {
            b.iter(|| {
                sample.seq = k % cycle.cycles();
                k += 1;
                cycle.step(black_box(&sample), black_box(&mut cmd));
            })
        });
    }
    // The chain alone (what the controllers cost), with the references of mid-run precomputed.
    let job = job("examples/jobs/xc-full-chain.toml");
    let n = job.axes.len();
    let mut cycle = ControlCycle::new(&job, &Builtins).expect("cycle");
    let mut plant = Plant::new(&job).expect("plant");
    plant.set_initial_positions(&cycle.initial_positions());
    let mut sample = SensorSample::empty(n as u32, 0);
    let mut cmd = ActuatorCommand::empty(n as u32, 0);
    let total = cycle.cycles();
    let refs: Vec<Vec<RefState>> = (0..256u64)
        .map(|j| {
            let mut r: Vec<RefState> = vec![[0.0; REF_DERIVS]; n];
            cycle
                .trajectory()
                .eval(cycle.time_of(total / 2 + j), &mut r);
            r
        })
        .collect();
    plant.sense(&mut sample.axes);
    let period_s = job.period_s;
    let mut k = 0u64;
    g.bench_function("full chain only (xc-full-chain, references given)", |b| {
        b.iter(|| {
            let j = (k % 256) as usize;
            let seq = total / 2 + (k % 256);
            k += 1;
            sample.seq = seq;
            let ctx = CycleContext {
                period_s,
                cycle: seq,
                t_s: seq as f64 * period_s,
            };
            cycle
                .chain_mut()
                .step(&ctx, black_box(&refs[j]), black_box(&sample), &mut cmd);
        })
    });
    g.finish();
}

fn sim_throughput(c: &mut Criterion) {
    let job = job("examples/jobs/xy-circle-effects.toml");
    let mut g = c.benchmark_group("feedloop sim");
    g.throughput(Throughput::Elements(1));
    let mut sim = Simulation::new(&job, &Builtins).expect("simulation");
    let mut rows = [AxisRecord::default(); MAX_AXES];
    let n = job.axes.len();
    g.bench_function(
        "one cycle of xy-circle-effects (elements/s = cycles/s)",
        |b| {
            b.iter(|| {
                if sim.position() >= sim.cycles() {
                    sim = Simulation::new(&job, &Builtins).expect("simulation");
                }
                sim.step(black_box(&mut rows[..n]));
            })
        },
    );
    g.finish();
}

criterion_group!(benches, plant_steps, control_cycles, sim_throughput);
criterion_main!(benches);
