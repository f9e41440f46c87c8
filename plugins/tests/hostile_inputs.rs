//! No plugin lets a non-finite value out, whatever it is fed.

use std::path::Path;

#[allow(dead_code)]
#[path = "../src/test_util.rs"]
mod test_util;

use feedloop_control::controller::{AxisContext, AxisSignals, CycleContext, PluginRegistry};
use feedloop_model::model::{ControllerParams, PlantParams, RigidParams};
use feedloop_plugins::Builtins;

fn ballscrew() -> AxisContext {
    test_util::ballscrew_axis_with(true, 3e-3, 5.0, 0.005, 30.0, 1e-4)
}

const VALUES: [f64; 7] = [0.0, 1.0, -3.5, 1e300, -1e300, f64::INFINITY, f64::NAN];

/// Signals whose every field cycles through `VALUES` with different strides.
fn hostile(k: usize) -> AxisSignals {
    let v = |s: usize| VALUES[(k * s + s) % VALUES.len()];
    AxisSignals {
        reference: [v(1), v(2), v(3), v(4), v(5), v(6)],
        load_pos: v(2),
        motor_pos: v(3),
        motor_vel: v(5),
        vel_cmd: 0.0,
        torque_ff: 0.0,
        torque: 0.0,
    }
}

#[test]
fn every_stage_keeps_its_outputs_finite_under_nan_inf_and_huge_inputs() {
    let dir = std::env::temp_dir().join(format!("feedloop-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("t.toml"),
        "format = \"feedloop-quadrant-table-1\"\n[[axes.x.to_positive]]\nstart_s = 0\npeak_s = 0.002\nend_s = 0.01\nrise_split = 0.3\nfall_split = 0.5\namplitude = 1e-6\n[[axes.x.to_negative]]\nstart_s = 0\npeak_s = 0.002\nend_s = 0.01\nrise_split = 0.3\nfall_split = 0.5\namplitude = -1e-6\n",
    )
    .unwrap();
    let job = dir.join("j.toml");
    let cases: [(&str, &str); 7] = [
        ("position_p", "vel_filter_hz = 300"),
        (
            "pi_velocity",
            "vel_filter_hz = 500\ntorque_lowpass_hz = 800\nnotch_hz = 600",
        ),
        ("inverse_feedforward", "structure = \"split\""),
        ("inverse_feedforward", "structure = \"literal\""),
        ("friction_feedforward", "fc_nm = 0.2"),
        ("quadrant_compensator", "table = \"t.toml\""),
        (
            "quadrant_compensator",
            "table = \"t.toml\"\ninject = \"torque\"",
        ),
    ];
    for (id, params) in cases {
        let t: toml::Table = params.parse().unwrap();
        let mut c = Builtins.create(id, &t, &ballscrew(), &job).unwrap();
        for k in 0..500 {
            let mut io = if k % 3 == 0 {
                // sane stretches in between, with velocity reversals
                let mut s = AxisSignals::default();
                s.reference[1] = ((k as f64) * 0.1).sin();
                s
            } else {
                hostile(k)
            };
            let ctx = CycleContext {
                period_s: 1e-4,
                cycle: k as u64,
                t_s: k as f64 * 1e-4,
            };
            c.step(&ctx, &mut io);
            assert!(
                io.vel_cmd.is_finite() && io.torque_ff.is_finite() && io.torque.is_finite(),
                "{id} ({params}) at step {k}: {io:?}"
            );
        }
    }
}

#[test]
fn coupler_keeps_velocity_commands_finite_under_hostile_inputs() {
    let x = AxisContext {
        name: "x".into(),
        plant: PlantParams::Rigid(RigidParams {
            mass_kg: 40.0,
            viscous_ns_per_m: 0.0,
        }),
        defaults: ControllerParams::default(),
        period_s: 1e-4,
    };
    let c = test_util::rotary_c_axis(2e5, 1e-4);
    let t: toml::Table = "wheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.005\ndisc_radius_m = 0.03"
        .parse()
        .unwrap();
    let mut cp = Builtins
        .create_coupler("nl_pid_coupler", &t, &[x, c], &[0, 1], Path::new("j.toml"))
        .unwrap();
    for k in 0..500 {
        let mut s = [hostile(k), hostile(k + 3)];
        cp.step(
            &CycleContext {
                period_s: 1e-4,
                cycle: k as u64,
                t_s: k as f64 * 1e-4,
            },
            &mut s,
        );
        for a in &s {
            assert!(a.vel_cmd.is_finite(), "step {k}: {a:?}");
        }
    }
}
