//! Property test: every built-in plugin, built from random (accepted) parameters and fed random
//! inputs, never lets a non-finite value out, and either builds or refuses with a named key.

use std::path::Path;

#[allow(dead_code)]
#[path = "../src/test_util.rs"]
mod test_util;

use feedloop_control::controller::{AxisContext, AxisSignals, CycleContext, PluginRegistry};
use feedloop_plugins::Builtins;
use proptest::prelude::*;

fn axis(jl: f64, kv: f64, tv: f64, lim: f64) -> AxisContext {
    test_util::ballscrew_axis_with(true, jl, kv, tv, lim, 1e-4)
}

fn value() -> impl Strategy<Value = f64> {
    prop_oneof![
        8 => -1.0e3..1.0e3f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-1.0e300),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    #[test]
    fn random_parameters_and_inputs_never_give_a_non_finite_output(
        jl in 1e-4..1e-1f64,
        kv in 1e-3..1e3f64,
        tv in 0.0..0.1f64,
        lim in 1e-3..1e4f64,
        kp in 0.0..1e3f64,
        vel_hz in 0.0..4000.0f64,
        notch_hz in 0.0..4000.0f64,
        fc in 0.0..10.0f64,
        inputs in proptest::collection::vec(proptest::array::uniform12(value()), 1..40),
    ) {
        let ax = axis(jl, kv, tv, lim);
        let params: Vec<(&str, String)> = vec![
            ("position_p", format!("kp_per_s = {kp}\nvel_filter_hz = {vel_hz}")),
            ("pi_velocity", format!("kv_nms_per_rad = {kv}\ntv_s = {tv}\ntorque_limit_nm = {lim}\nnotch_hz = {notch_hz}\ntorque_lowpass_hz = {vel_hz}")),
            ("inverse_feedforward", format!("jl_kgm2 = {jl}")),
            ("friction_feedforward", format!("fc_nm = {fc}")),
        ];
        for (id, text) in params {
            let table: toml::Table = text.parse().unwrap();
            let mut c = match Builtins.create(id, &table, &ax, Path::new("p.toml")) {
                Ok(c) => c,
                // A refusal must name the key it refuses.
                Err(e) => { prop_assert!(!e.key.is_empty(), "{id}: {e}"); continue; }
            };
            for (k, v) in inputs.iter().enumerate() {
                let mut io = AxisSignals {
                    reference: [v[0], v[1], v[2], v[3], v[4], v[5]],
                    load_pos: v[6],
                    motor_pos: v[7],
                    motor_vel: v[8],
                    vel_cmd: v[9],
                    torque_ff: v[10],
                    torque: v[11],
                };
                let ctx = CycleContext { period_s: 1e-4, cycle: k as u64, t_s: k as f64 * 1e-4 };
                c.step(&ctx, &mut io);
                // Outputs each stage owns: a velocity loop's torque, others' additions are
                // finite whenever their inputs were finite.
                if id == "pi_velocity" {
                    prop_assert!(io.torque.is_finite(), "{id}: torque {}", io.torque);
                    prop_assert!(io.torque.abs() <= lim * (1.0 + 1e-12), "{id}: {} over {lim}", io.torque);
                }
                if v.iter().all(|x| x.is_finite() && x.abs() < 1e6) {
                    prop_assert!(io.vel_cmd.is_finite() && io.torque_ff.is_finite(), "{id}: {io:?}");
                }
            }
        }
    }
}
