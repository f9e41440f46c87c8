//! Release-mode timing of the hot path (prints, never asserts): the shipped job runs 2 axes at
//! 10 kHz for 60 s with friction, backlash and sensor noise; physics + control must stay below
//! 1/500 of simulated time, i.e. 200 ns per cycle for both axes.

mod common;

use std::time::Instant;

/// CPU time of this thread, ns (from /proc/thread-self/schedstat; 0 where unavailable), so the
/// figure is not inflated by other processes sharing the cores.
fn cpu_ns() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| {
            s.split_whitespace()
                .next()
                .and_then(|v| v.parse::<f64>().ok())
        })
        .unwrap_or(0.0)
}

/// A torque pattern (precomputed so the timing measures the plant, not `sin`).
fn pattern(n: usize, w: f64) -> Vec<f64> {
    (0..n).map(|k| 0.3 * (k as f64 * w).sin()).collect()
}

use common::*;
use feedloop_control::axis_io::{AxisCommand, AxisSensor};
use feedloop_plant::Plant;

const SHIPPED: &str = r#"
[effects.coulomb_friction]
fc_nm = 0.1
[effects.stribeck_friction]
side = "load"
fc_n = 100
fs_n = 130
vs_m_per_s = 0.001
[effects.backlash]
gap_m = 5e-6
[sensor]
motor_counts_per_rev = 1048576
load_resolution_m = 1e-8
motor_pos_noise_rad = 2e-6
motor_vel_noise_rad_per_s = 0.002
load_pos_noise_m = 5e-9
seed = 1
"#;

#[test]
fn timing_of_two_axes_at_10_khz_for_60_s_with_friction_backlash_and_noise() {
    let h = 1e-4;
    let model = parse(&format!("{BALLSCREW}\n{SHIPPED}")).unwrap();
    let mut plant = Plant::from_models(&[&model, &model], h).unwrap();
    let r = 2.0 * std::f64::consts::PI / 0.01;
    let mut ctl = [Cascade::brief(h, r), Cascade::brief(h, r)];
    let mut s = [AxisSensor::default(); 2];
    let mut c = [AxisCommand::default(); 2];
    let n = 600_000;
    let traj: Vec<[(f64, f64); 2]> = (0..n)
        .map(|k| {
            let t = k as f64 * h;
            [
                trapezoid(t, 0.02, 0.1, 0.02, 0.05),
                trapezoid(t + 0.1, 0.02, 0.1, 0.02, 0.05),
            ]
        })
        .collect();
    let (t0, c0) = (Instant::now(), cpu_ns());
    let mut best = f64::MAX;
    for block in traj.chunks(10_000) {
        let tb = Instant::now();
        for tr in block {
            plant.sense(&mut s);
            for (i, ctl) in ctl.iter_mut().enumerate() {
                let (p, v) = tr[i];
                c[i].torque = ctl.torque(p, v, &s[i]);
            }
            plant.step(&c);
        }
        best = best.min(tb.elapsed().as_secs_f64() * 1e9 / block.len() as f64);
    }
    let total = t0.elapsed().as_secs_f64();
    let cpu = (cpu_ns() - c0) * 1e-9;
    let per_cycle = cpu / n as f64 * 1e9;
    std::hint::black_box(&s);

    // Plant alone (same torques replayed from a fixed pattern).
    let mut plant2 = Plant::from_models(&[&model, &model], h).unwrap();
    let (p0, p1) = (pattern(n, 2e-3), pattern(n, 1.7e-3));
    let c1 = cpu_ns();
    for k in 0..n {
        plant2.sense(&mut s);
        c[0].torque = p0[k];
        c[1].torque = p1[k];
        plant2.step(&c);
    }
    let plant_only = (cpu_ns() - c1) / n as f64;
    std::hint::black_box(&s);
    println!(
        "TIMING: physics + 2 cascades: {per_cycle:.1} ns per cycle for 2 axes ({:.1} ns per axis); \
         plant alone {plant_only:.1} ns per cycle ({:.1} ns per axis step) [thread CPU time]; \
         best 10000-cycle block {best:.1} ns per cycle; wall {:.2} s for 60 s simulated (ratio 1/{:.0}); \
         budget 200 ns per cycle",
        per_cycle / 2.0,
        plant_only / 2.0,
        total,
        60.0 / total
    );
}

#[test]
fn timing_per_axis_step_by_effect() {
    let h = 1e-4;
    let variants = [
        ("bare", ""),
        ("sensor", "[sensor]\nmotor_counts_per_rev = 1048576\nload_resolution_m = 1e-8\nmotor_pos_noise_rad = 2e-6\nmotor_vel_noise_rad_per_s = 0.002\nload_pos_noise_m = 5e-9\n"),
        ("coulomb motor", "[effects.coulomb_friction]\nfc_nm = 0.1\n"),
        ("stribeck load", "[effects.stribeck_friction]\nside = \"load\"\nfc_n = 100\nfs_n = 130\nvs_m_per_s = 0.001\n"),
        ("backlash", "[effects.backlash]\ngap_m = 5e-6\n"),
        ("shipped", SHIPPED),
        ("bare again", ""),
    ];
    for (name, extra) in variants {
        let mut ax = ballscrew_with(extra, h);
        let n = 300_000;
        let p = pattern(n, 2e-3);
        let c0 = cpu_ns();
        let mut best = f64::MAX;
        for block in p.chunks(10_000) {
            let t = Instant::now();
            for &u in block {
                let m = ax.sense_axis();
                std::hint::black_box(&m);
                ax.step_axis(u);
            }
            best = best.min(t.elapsed().as_secs_f64() * 1e9 / block.len() as f64);
        }
        let ns = (cpu_ns() - c0) / n as f64;
        println!(
            "TIMING {name}: {ns:.1} ns per axis step (CPU time), best 1 ms block {best:.1} ns"
        );
    }
}

#[test]
fn timing_reference_of_this_machine() {
    // A fixed reference workload (a 4x4 + 4x3 matrix-vector product chain, the core of one
    // axis step without effects) so the figures above can be scaled to another machine.
    let a = [
        [0.9, 0.01, 0.02, 0.0],
        [0.01, 0.9, 0.0, 0.02],
        [0.02, 0.0, 0.9, 0.01],
        [0.0, 0.02, 0.01, 0.9],
    ];
    let mut x = [1.0, 0.5, -0.5, 0.25];
    let n = 3_000_000;
    let c0 = cpu_ns();
    for k in 0..n {
        let u = (k & 7) as f64 * 1e-3;
        let mut y = [0.0; 4];
        for (j, col) in a.iter().enumerate() {
            for i in 0..4 {
                y[i] += col[i] * x[j];
            }
        }
        for yi in &mut y {
            *yi += 0.001 * u + 0.002 * u + 0.003 * u;
        }
        x = std::hint::black_box(y);
    }
    let ns = (cpu_ns() - c0) / n as f64;
    println!("TIMING reference 4x4 matrix-vector step: {ns:.1} ns (a dependent chain: about 12 ns on an idle 3 GHz core)");
}
