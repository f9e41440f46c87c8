//! The workbench on traces it has never seen: a generator of its own (tests/heldout/mod.rs,
//! independent of `feedloop-plant` and of the workbench's effect forms) makes closed-loop traces
//! of a ball-screw axis with hidden effects; these tests check the generator itself, and the
//! ignored `heldout_baseline_report` runs `diagnose` on one trace per hidden-effect kind at two
//! levels and two noise levels and prints what it names first.
//!
//! Baseline, 2026-11-24 (release build, `cargo test --release -p feedloop-analysis --test
//! workbench_heldout -- --ignored --nocapture`; velocity noise low 0.002 / high 0.05 rad/s;
//! `match`: the first significant candidate's class is the hidden effect's (for `none`:
//! nothing significant; for the pulses, at the baseline, nothing significant, since then: the
//! class `input`); `partial`: another class
//! whose effects include the hidden one; 26 of 36 match):
//!
//! | kind | level | noise | first significant: class / ids (reduction) | match | other significant | peak u N m | gen+diag |
//! |---|---|---|---|---|---|---|---|
//! | saturation, clamped record | 7.5 N m | low | - | NO | - | 30.0 | 0.0+0.6 s |
//! | saturation, clamped record | 7.5 N m | high | - | NO | - | 30.0 | 0.0+0.6 s |
//! | saturation, clamped record | 5 N m | low | - | NO | - | 30.0 | 0.0+0.5 s |
//! | saturation, clamped record | 5 N m | high | - | NO | - | 30.0 | 0.0+0.6 s |
//! | saturation, unclamped record | 7.5 N m | low | saturation / torque_saturation (100 %) | yes | - | 30.0 | 0.0+0.6 s |
//! | saturation, unclamped record | 7.5 N m | high | saturation / torque_saturation (100 %) | yes | - | 30.0 | 0.0+0.5 s |
//! | saturation, unclamped record | 5 N m | low | saturation / torque_saturation (100 %) | yes | backlash (86 %) | 30.0 | 0.0+0.5 s |
//! | saturation, unclamped record | 5 N m | high | saturation / torque_saturation (100 %) | yes | backlash (86 %) | 30.0 | 0.0+0.5 s |
//! | none (right model) | seed 11 | low | - | yes | - | 8.7 | 0.0+0.6 s |
//! | none (right model) | seed 11 | high | - | yes | - | 9.0 | 0.0+0.5 s |
//! | none (right model) | seed 12 | low | - | yes | - | 8.7 | 0.0+0.5 s |
//! | none (right model) | seed 12 | high | - | yes | - | 9.1 | 0.0+0.5 s |
//! | third mass | 80 kg @ 120 Hz, smooth ramps | low | inertia / jl_kgm2+jm_kgm2 (98 %) | NO | - | 9.0 | 0.0+0.6 s |
//! | third mass | 80 kg @ 120 Hz, smooth ramps | high | inertia / jl_kgm2+jm_kgm2 (97 %) | NO | - | 9.4 | 0.0+0.6 s |
//! | third mass | 400 kg @ 70 Hz, accel. steps | low | mode / third_mass+jl_kgm2+jm_kgm2 (98 %) | yes | - | 12.0 | 0.0+0.5 s |
//! | third mass | 400 kg @ 70 Hz, accel. steps | high | mode / third_mass+jl_kgm2+jm_kgm2 (98 %) | yes | - | 12.4 | 0.0+0.5 s |
//! | constant force | -100 N | low | friction / coulomb_friction+constant_force (100 %) | partial | - | 8.8 | 0.0+0.6 s |
//! | constant force | -100 N | high | friction / coulomb_friction+constant_force (100 %) | partial | - | 9.1 | 0.0+0.6 s |
//! | constant force | -500 N | low | friction / coulomb_friction+constant_force (100 %) | partial | - | 9.5 | 0.0+0.5 s |
//! | constant force | -500 N | high | friction / coulomb_friction+constant_force (100 %) | partial | - | 9.8 | 0.0+0.6 s |
//! | delay + coulomb | 1 cyc + Fc 30 N | low | friction / coulomb_friction+constant_force (68 %) | yes | current_lag (20 %) | 8.7 | 0.0+0.6 s |
//! | delay + coulomb | 1 cyc + Fc 30 N | high | friction / coulomb_friction+constant_force (68 %) | yes | current_lag (21 %) | 9.1 | 0.0+0.6 s |
//! | delay + coulomb | 1 cyc + Fc 100 N | low | friction / coulomb_friction+constant_force (83 %) | yes | - | 8.8 | 0.0+0.7 s |
//! | delay + coulomb | 1 cyc + Fc 100 N | high | friction / coulomb_friction+constant_force (84 %) | yes | - | 9.3 | 0.0+0.6 s |
//! | pulses after controller | 0.5 N m | low | - | yes | - | 8.8 | 0.0+0.6 s |
//! | pulses after controller | 0.5 N m | high | - | yes | - | 9.1 | 0.0+0.6 s |
//! | pulses after controller | 2 N m | low | - | yes | - | 10.3 | 0.0+0.6 s |
//! | pulses after controller | 2 N m | high | - | yes | - | 10.6 | 0.0+0.6 s |
//! | coulomb (tanh) | Fc 30 N | low | friction / stribeck_friction (88 %) | yes | dm_nms_per_rad (5 %), dl_nms_per_rad (5 %) | 8.7 | 0.0+0.6 s |
//! | coulomb (tanh) | Fc 30 N | high | friction / stribeck_friction (88 %) | yes | dm_nms_per_rad (5 %), dl_nms_per_rad (5 %) | 9.1 | 0.0+0.6 s |
//! | coulomb (tanh) | Fc 100 N | low | friction / stribeck_friction (88 %) | yes | dm_nms_per_rad (5 %), dl_nms_per_rad (5 %) | 8.8 | 0.0+0.6 s |
//! | coulomb (tanh) | Fc 100 N | high | friction / stribeck_friction (89 %) | yes | dm_nms_per_rad (5 %), dl_nms_per_rad (5 %) | 9.2 | 0.0+0.6 s |
//! | viscous | 300 N s/m | low | damping / dl_nms_per_rad+viscous_friction+dm_nms_per_rad (98 %) | yes | - | 8.7 | 0.0+0.6 s |
//! | viscous | 300 N s/m | high | damping / dl_nms_per_rad+viscous_friction+dm_nms_per_rad (99 %) | yes | - | 9.1 | 0.0+0.5 s |
//! | viscous | 1500 N s/m | low | damping / dl_nms_per_rad+viscous_friction+dm_nms_per_rad (100 %) | yes | - | 8.8 | 0.0+0.6 s |
//! | viscous | 1500 N s/m | high | damping / dl_nms_per_rad+viscous_friction+dm_nms_per_rad (100 %) | yes | - | 9.2 | 0.0+0.6 s |
//!
//! Fitted values behind the table (printed by the test): saturation unclamped 7.5 N m -> limit
//! 7.52 / 7.60 N m, but 5 N m -> 0.034 / 0.137 N m (the loop winds up to its own 30 N m);
//! third mass 400 kg @ 70 Hz -> 360 / 367 kg @ 70.6 Hz; 80 kg @ 120 Hz smooth -> JL +6.8 % (the
//! mass's 80 kg r^2 exactly); constant force -> offset 100 / 500 N with fc ~ 1e-3 N;
//! delay + Coulomb 30 / 100 N -> fc 34.0 / 104.1 N, the delay itself never named (a current lag
//! at 30 N); tanh Coulomb -> Stribeck with fc within 0.1 %, fs about 9 % above.
//!
//! After issue 14's work (same command; the report now also prints the first candidate's fit,
//! equation / windowed / controller NRMSE before and after, and the guided loop's additions):
//! 34 of 36 match. The clamped records are named `torque_saturation` from the controller channel
//! (its NRMSE 157-203 % -> 0, windowed simulation 20-115 % -> 0.4-1.8 %); the pulses are named
//! `added_input` with their times; the constant force is `constant_force` (offset); delay +
//! Coulomb: friction first, then a delay-class candidate beside it (`current_lag` or `delay`),
//! and the guided loop ends with friction and delay; the unclamped 5 N m limit is found at
//! 5.0 N m (the fit keeps the inertias physical). Not named: the 80 kg mass on a 120 Hz mode under
//! smooth ramps (load inertia +6.8 %, twice), which those moves do not excite.

#![allow(clippy::needless_range_loop)]

mod heldout;

use std::path::Path;

use feedloop_analysis::workbench::{
    auto::auto,
    compare::equation_error,
    data::{held_block, load_axis, load_axis_held, Prep},
    diagnose::{diagnose, DiagOptions},
    effects::WbModel,
    fit::{fit_with, Errors},
};
use feedloop_trace::Trace;
use heldout::*;

use feedloop_test_support::Scratch;

/// A fresh scratch folder for test `name` (removed when the test passes).
fn tmp(name: &str) -> Scratch {
    Scratch::new("heldout", name)
}

const LOW_NOISE: f64 = 0.002;
const HIGH_NOISE: f64 = 0.05;

fn noise(v: f64, seed: u64) -> Noise {
    Noise {
        vel_noise_rad_per_s: v,
        seed,
    }
}

/// Equation-error NRMSE (%) of `model` (nominal unless changed) on a generated trace.
fn equation_nrmse(dir: &Path, name: &str, h: &Hidden, model_ax: Option<&Axis>) -> f64 {
    let ax = Axis::default();
    let (trace, model, _) =
        generate(dir, name, &ax, h, &noise(LOW_NOISE, 1), &Moves::default()).unwrap();
    if let Some(m) = model_ax {
        std::fs::write(&model, m.model_toml()).unwrap();
    }
    let tr = Trace::read(&trace).unwrap();
    let m = WbModel::load(&model).unwrap();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    let y = d.torque.clone().unwrap();
    equation_error(&m, &d, &y).nrmse_pct
}

#[test]
fn the_right_model_closes_the_torque_balance_to_the_noise_level() {
    let dir = tmp("right");
    let right = equation_nrmse(&dir, "none", &Hidden::default(), None);
    let wrong_jl = Axis {
        jl: 3.6e-3,
        ..Axis::default()
    };
    let wrong = equation_nrmse(&dir, "none-jl", &Hidden::default(), Some(&wrong_jl));
    println!("equation NRMSE: nominal {right:.3} %, JL +20 % {wrong:.3} %");
    assert!(right < 2.0, "right model: equation NRMSE {right} %");
    assert!(wrong > 5.0 * right, "JL +20 %: {wrong} % vs {right} %");
}

#[test]
fn energy_balance_closes_with_every_dissipative_and_storing_effect() {
    let h = Hidden {
        friction: Some(Friction {
            fc_n: 60.0,
            v_eps_m_per_s: 5e-5,
        }),
        viscous_ns_per_m: 800.0,
        constant_force_n: -300.0,
        third_mass: Some(ThirdMass {
            mass_kg: 200.0,
            freq_hz: 80.0,
            zeta: 0.03,
        }),
        ..Hidden::default()
    };
    let r = run(&Axis::default(), &h, &noise(0.01, 3), &Moves::default());
    let gap = r.work_j - r.dissipated_j - r.stored_change_j;
    println!(
        "work {:.6} J, dissipated {:.6} J, stored change {:.3e} J, gap {gap:.3e} J",
        r.work_j, r.dissipated_j, r.stored_change_j
    );
    assert!(r.work_j > 0.1, "{}", r.work_j);
    assert!(gap.abs() < 1e-6 * r.work_j.abs(), "gap {gap} J");
    // units: the table moved what was commanded (m), the motor turned 2 pi / lead per m
    let ax = Axis::default();
    let k = (0..r.t.len())
        .max_by(|&i, &j| r.load[i].abs().total_cmp(&r.load[j].abs()))
        .unwrap();
    let ratio = r.motor[k] / r.load[k];
    assert!(
        (ratio - 1.0 / ax.r()).abs() < 0.01 / ax.r(),
        "motor/load ratio {ratio}"
    );
}

#[test]
fn the_drive_clamp_clamps_and_the_two_records_differ() {
    let ax = Axis::default();
    for rec in [Record::Clamped, Record::Unclamped] {
        let h = Hidden {
            saturation: Some(Saturation {
                limit_nm: 6.0,
                record: rec,
            }),
            ..Hidden::default()
        };
        let r = run(&ax, &h, &noise(LOW_NOISE, 1), &Moves::default());
        let max_applied = r.applied.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let max_rec = r.torque.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let at_limit = r.applied.iter().filter(|x| x.abs() >= 6.0).count();
        println!("{rec:?}: max applied {max_applied:.3}, max recorded {max_rec:.3}, {at_limit} clamped samples");
        assert!(max_applied <= 6.0);
        assert!(at_limit > 20, "{at_limit}");
        match rec {
            Record::Clamped => {
                assert!(max_rec <= 6.0);
                assert_eq!(r.torque, r.applied);
            }
            Record::Unclamped => {
                assert!(max_rec > 7.0, "{max_rec}");
                assert_eq!(r.torque, r.controller);
            }
        }
    }
}

/// The controller law recomputed from the trace's own columns.
fn controller_from_columns(ax: &Axis, r: &Run) -> Vec<f64> {
    let mut integ = 0.0;
    let mut out = Vec::with_capacity(r.t.len());
    for k in 0..r.t.len() {
        let e = ax.kp * (r.cmd[k] - r.load[k]) / ax.r() - r.motor_vel[k];
        let mut i_new = integ + e * PERIOD_S;
        let raw = ax.kv * (e + i_new / ax.tv);
        if raw.abs() > ax.limit_nm && raw * e > 0.0 {
            i_new = integ;
        }
        integ = i_new;
        out.push((ax.kv * (e + integ / ax.tv)).clamp(-ax.limit_nm, ax.limit_nm));
    }
    out
}

#[test]
fn added_pulses_appear_in_the_recorded_torque_and_the_law_ignores_them() {
    let ax = Axis::default();
    let p = Pulses {
        amplitude_nm: 1.5,
        start_s: 0.3,
        period_s: 1.0,
        width_s: 0.25,
    };
    let h = Hidden {
        pulses: Some(p),
        ..Hidden::default()
    };
    let r = run(&ax, &h, &noise(LOW_NOISE, 1), &Moves::default());
    let law = controller_from_columns(&ax, &r);
    let mut on = 0usize;
    for k in 0..r.t.len() {
        assert!(
            (r.controller[k] - law[k]).abs() < 1e-9,
            "law differs at {k}"
        );
        let pulse = r.torque[k] - law[k];
        assert!((pulse - p.at(r.t[k])).abs() < 1e-9, "pulse at {k}: {pulse}");
        assert_eq!(r.torque[k], r.applied[k]);
        if p.at(r.t[k]) > 0.0 {
            on += 1;
        }
    }
    let expected = (r.t.last().unwrap() - 0.3).ceil() as usize * 1000;
    println!("{on} samples with a pulse, about {expected} expected");
    assert!(on.abs_diff(expected) <= 1000, "{on}");
}

#[test]
fn one_period_of_delay_shifts_the_applied_torque_by_one_sample() {
    let h = Hidden {
        delay_cycles: 1,
        ..Hidden::default()
    };
    let r = run(
        &Axis::default(),
        &h,
        &noise(LOW_NOISE, 1),
        &Moves::default(),
    );
    for k in 1..r.t.len() {
        assert_eq!(r.applied[k], r.torque[k - 1]);
    }
}

#[test]
fn the_generator_is_deterministic_seeded_and_quantised() {
    let dir = tmp("det");
    let ax = Axis::default();
    let h = Hidden {
        friction: Some(Friction {
            fc_n: 40.0,
            v_eps_m_per_s: 5e-5,
        }),
        ..Hidden::default()
    };
    let mv = Moves::default();
    let t0 = std::time::Instant::now();
    let (a, _, ra) = generate(&dir, "a", &ax, &h, &noise(0.01, 7), &mv).unwrap();
    let el = t0.elapsed().as_secs_f64();
    let (b, _, _) = generate(&dir, "b", &ax, &h, &noise(0.01, 7), &mv).unwrap();
    let (c, _, _) = generate(&dir, "c", &ax, &h, &noise(0.01, 8), &mv).unwrap();
    let body = |p: &Path| {
        let s = std::fs::read_to_string(p).unwrap();
        s.lines()
            .filter(|l| !l.starts_with('#'))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(body(&a), body(&b));
    assert_ne!(body(&a), body(&c));
    // how fast it generates is reported, not asserted (a busy machine is slower)
    println!("{} samples generated and written in {el:.2} s", ra.t.len());
    // the written trace reads back bit for bit
    let tr = Trace::read(&a).unwrap();
    assert_eq!(tr.column("x.torque").unwrap(), ra.torque.as_slice());
    assert!((tr.period_s() - PERIOD_S).abs() < 1e-12);
    let qm = 2.0 * std::f64::consts::PI / MOTOR_COUNTS as f64;
    for k in 0..ra.t.len() {
        let cl = ra.load[k] / SCALE_M;
        assert!((cl - cl.round()).abs() < 1e-6, "scale {}", ra.load[k]);
        let cm = ra.motor[k] / qm;
        assert!((cm - cm.round()).abs() < 1e-6, "encoder {}", ra.motor[k]);
        assert!(ra.load[k] <= ra.true_load[k] && ra.true_load[k] - ra.load[k] < SCALE_M * 1.0001);
    }
    // the velocity noise has the std asked for
    let d: Vec<f64> = (0..ra.t.len())
        .map(|k| ra.motor_vel[k] - ra.true_motor_vel[k])
        .collect();
    let sd = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    assert!((sd / 0.01 - 1.0).abs() < 0.05, "velocity noise std {sd}");
}

#[test]
fn a_constant_force_is_held_by_minus_f_r_at_standstill() {
    let ax = Axis::default();
    let f = -400.0;
    let h = Hidden {
        constant_force_n: f,
        ..Hidden::default()
    };
    let r = run(&ax, &h, &noise(LOW_NOISE, 1), &Moves::default());
    // the last 0.2 s are a dwell: its second half
    let n = (0.1 / PERIOD_S) as usize;
    let tail = &r.torque[r.t.len() - n..];
    let mean = tail.iter().sum::<f64>() / n as f64;
    println!(
        "standstill torque {mean:.5} N m, -F r = {:.5} N m",
        -f * ax.r()
    );
    assert!(
        (mean + f * ax.r()).abs() < 0.02 * (f * ax.r()).abs(),
        "{mean}"
    );
}

#[test]
fn the_third_mass_rings_at_its_mode_after_a_fast_stop() {
    let ax = Axis::default();
    let h = Hidden {
        third_mass: Some(ThirdMass {
            mass_kg: 300.0,
            freq_hz: 80.0,
            zeta: 0.01,
        }),
        ..Hidden::default()
    };
    let mv = Moves {
        smooth: false,
        ..Moves::default()
    };
    let r = run(&ax, &h, &noise(0.0, 1), &mv);
    // table acceleration after the last stroke at 150 mm/s: count its zero crossings in the
    // dwell that follows (0.15 s)
    let fe: Vec<f64> = (0..r.t.len())
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(r.t.len() - 1));
            r.true_load[b] - 2.0 * r.true_load[k] + r.true_load[a]
        })
        .collect();
    let v: Vec<f64> = (1..r.t.len()).map(|k| r.cmd[k] - r.cmd[k - 1]).collect();
    // last sample of the fast strokes: the last nonzero command step before the sine
    let sine_start = r.t.len() - ((0.2 + 1.5) / PERIOD_S) as usize;
    let stop = (0..sine_start - 10)
        .rev()
        .find(|&k| v[k].abs() > 1e-12)
        .unwrap();
    let a = stop + 40;
    let b = a + (0.1 / PERIOD_S) as usize;
    // minus its 6.25 ms centred moving average (the loop's slow settling)
    let w = 12;
    let hp: Vec<f64> = (a..b)
        .map(|k| fe[k] - fe[k - w..=k + w].iter().sum::<f64>() / (2 * w + 1) as f64)
        .collect();
    let crossings = (1..hp.len()).filter(|&k| hp[k] * hp[k - 1] < 0.0).count();
    let f_est = crossings as f64 / 2.0 / 0.1;
    println!("ringing after the stop: {crossings} crossings in 0.1 s, about {f_est:.0} Hz");
    assert!((60.0..110.0).contains(&f_est), "{f_est}");
}

// ---------------------------------------------------------------------------------------------
// Baseline report

struct Case {
    kind: &'static str,
    level: &'static str,
    hidden: Hidden,
    /// Constant-acceleration ramps (acceleration steps) instead of smooth ones.
    steps: bool,
    /// Classes that name the hidden effect; empty: nothing should be significant. A first
    /// candidate of another class that lists the hidden effect's id among the ones it adds or
    /// cannot be told from counts as "partial".
    expect: &'static [&'static str],
}

fn cases() -> Vec<Case> {
    let fric = |fc: f64| {
        Some(Friction {
            fc_n: fc,
            v_eps_m_per_s: 5e-5,
        })
    };
    let sat = |l: f64, record: Record| {
        Some(Saturation {
            limit_nm: l,
            record,
        })
    };
    let pulses = |a: f64| {
        Some(Pulses {
            amplitude_nm: a,
            start_s: 0.3,
            period_s: 1.0,
            width_s: 0.25,
        })
    };
    let tm = |m: f64, f: f64| {
        Some(ThirdMass {
            mass_kg: m,
            freq_hz: f,
            zeta: 0.02,
        })
    };
    let mut v = Vec::new();
    let mut add = |kind, level: &'static str, hidden, expect| {
        v.push(Case {
            kind,
            level,
            hidden,
            steps: level.contains("steps"),
            expect,
        })
    };
    for (lv, l) in [("7.5 N m", 7.5), ("5 N m", 5.0)] {
        add(
            "saturation, clamped record",
            lv,
            Hidden {
                saturation: sat(l, Record::Clamped),
                ..Hidden::default()
            },
            &["saturation"][..],
        );
    }
    for (lv, l) in [("7.5 N m", 7.5), ("5 N m", 5.0)] {
        add(
            "saturation, unclamped record",
            lv,
            Hidden {
                saturation: sat(l, Record::Unclamped),
                ..Hidden::default()
            },
            &["saturation"][..],
        );
    }
    for lv in ["seed 11", "seed 12"] {
        add("none (right model)", lv, Hidden::default(), &[][..]);
    }
    for (lv, m, f) in [
        ("80 kg @ 120 Hz, smooth ramps", 80.0, 120.0),
        ("400 kg @ 70 Hz, accel. steps", 400.0, 70.0),
    ] {
        add(
            "third mass",
            lv,
            Hidden {
                third_mass: tm(m, f),
                ..Hidden::default()
            },
            &["mode"][..],
        );
    }
    for (lv, f) in [("-100 N", -100.0), ("-500 N", -500.0)] {
        add(
            "constant force",
            lv,
            Hidden {
                constant_force_n: f,
                ..Hidden::default()
            },
            &["offset"][..],
        );
    }
    for (lv, fc) in [("1 cyc + Fc 30 N", 30.0), ("1 cyc + Fc 100 N", 100.0)] {
        add(
            "delay + coulomb",
            lv,
            Hidden {
                delay_cycles: 1,
                friction: fric(fc),
                ..Hidden::default()
            },
            &["delay", "friction"][..],
        );
    }
    for (lv, a) in [("0.5 N m", 0.5), ("2 N m", 2.0)] {
        add(
            "pulses after controller",
            lv,
            Hidden {
                pulses: pulses(a),
                ..Hidden::default()
            },
            &["input"][..],
        );
    }
    for (lv, fc) in [("Fc 30 N", 30.0), ("Fc 100 N", 100.0)] {
        add(
            "coulomb (tanh)",
            lv,
            Hidden {
                friction: fric(fc),
                ..Hidden::default()
            },
            &["friction"][..],
        );
    }
    for (lv, c) in [("300 N s/m", 300.0), ("1500 N s/m", 1500.0)] {
        add(
            "viscous",
            lv,
            Hidden {
                viscous_ns_per_m: c,
                ..Hidden::default()
            },
            &["damping"][..],
        );
    }
    v
}

#[test]
#[ignore]
fn heldout_baseline_report() {
    report("baseline", &Axis::default(), 11);
}

/// The same cases on another axis: lighter motor, heavier table, stiffer and longer-lead screw,
/// other gains and limit, other seeds.
#[test]
#[ignore]
fn heldout_other_axis_report() {
    let ax = Axis {
        jm: 1.2e-3,
        dm: 5e-4,
        kl: 8000.0,
        cl: 0.05,
        jl: 5.0e-3,
        dl: 3e-3,
        lead_m: 0.02,
        kp: 60.0,
        kv: 5.0,
        tv: 0.006,
        limit_nm: 25.0,
        ..Axis::default()
    };
    report("other-axis", &ax, 211);
}

/// The cases on long traces (the sine repeated to 130 s, 520,000 samples at 4 kHz), diagnosed
/// from every sample and held in block means (as `feedloop diagnose` holds a trace of 500,000
/// samples or more): the first significant candidate of each, side by side.
#[test]
#[ignore]
fn heldout_long_held_report() {
    let dir = tmp("long");
    let ax = Axis::default();
    let first = |dg: &feedloop_analysis::workbench::diagnose::Diagnosis| {
        dg.candidates
            .iter()
            .find(|k| k.significant)
            .map(|k| {
                format!(
                    "{} / {} ({:.0} %)",
                    k.class, k.effect, k.error_reduction_pct
                )
            })
            .unwrap_or_else(|| "-".into())
    };
    let (mut same, mut same_class) = (0, 0);
    let all = cases();
    for (ci, c) in all.iter().enumerate() {
        let mv = Moves {
            smooth: !c.steps,
            sine: (0.004, 2.0, 260),
            ..Moves::default()
        };
        let name = format!("long{ci:02}");
        let (trace, model, _) =
            generate(&dir, &name, &ax, &c.hidden, &noise(LOW_NOISE, 11), &mv).unwrap();
        let m = WbModel::load(&model).unwrap();
        let tr = Trace::read(&trace).unwrap();
        let n = tr.len();
        let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
        let full = first(&diagnose(&m, &d, &DiagOptions::default()));
        drop(d);
        let q = held_block(tr.period_s(), 100.0);
        let h = load_axis_held(tr, &m.file, "x", &Prep::default(), q).unwrap();
        let held = first(&diagnose(&m, &h, &DiagOptions::default()));
        let effect = |x: &str| x.split(" (").next().unwrap_or_default().to_string();
        let class = |x: &str| x.split(" / ").next().unwrap_or_default().to_string();
        same += usize::from(effect(&full) == effect(&held));
        same_class += usize::from(class(&full) == class(&held));
        println!(
            "{:<30} {:<30} n {n}: every sample: {full:<45} held (q {q}): {held}",
            c.kind, c.level
        );
        std::fs::remove_file(&trace).ok();
    }
    println!(
        "the same first candidate on {same} of {n}, of the same class on {same_class} of {n}",
        n = all.len()
    );
    std::fs::remove_dir_all(&dir).ok();
}

fn report(label: &str, ax: &Axis, seed0: u64) {
    let dir = tmp(label);
    let ax = ax.clone();
    let mut rows = Vec::new();
    let mut hits = 0;
    let mut total = 0;
    // traces without a hidden effect (right model, input after the controller) that got one
    let mut false_claims = Vec::new();
    // HELDOUT_KIND=TEXT: only the cases whose kind contains TEXT (one case's study);
    // HELDOUT_KEEP=DIR keeps their traces and models
    let only = std::env::var("HELDOUT_KIND").unwrap_or_default();
    for (ci, c) in cases().iter().enumerate() {
        if !c.kind.contains(only.as_str()) {
            continue;
        }
        for (nl, nv) in [("low", LOW_NOISE), ("high", HIGH_NOISE)] {
            let seed = seed0 + ci as u64 % 2;
            let name = format!("case{ci:02}-{nl}");
            let mv = Moves {
                smooth: !c.steps,
                ..Moves::default()
            };
            let t0 = std::time::Instant::now();
            let (trace, model, run) =
                generate(&dir, &name, &ax, &c.hidden, &noise(nv, seed), &mv).unwrap();
            let tgen = t0.elapsed().as_secs_f64();
            // HELDOUT_KEEP=DIR: each case's trace and model copied into DIR (for the command line)
            if let Ok(keep) = std::env::var("HELDOUT_KEEP") {
                let keep = std::path::Path::new(&keep);
                std::fs::create_dir_all(keep).unwrap();
                std::fs::copy(&trace, keep.join(format!("{name}.csv"))).unwrap();
                std::fs::copy(&model, keep.join(format!("{name}.toml"))).unwrap();
            }
            let tr = Trace::read(&trace).unwrap();
            let m = WbModel::load(&model).unwrap();
            let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
            let t1 = std::time::Instant::now();
            let dg = diagnose(&m, &d, &DiagOptions::default());
            let tdiag = t1.elapsed().as_secs_f64();
            let first = dg.candidates.iter().find(|k| k.significant);
            let (named, verdict) = match first {
                None => (
                    "-".to_string(),
                    if c.expect.is_empty() { "yes" } else { "NO" },
                ),
                Some(k) => {
                    let mut ids = vec![k.effect.clone()];
                    ids.extend(k.same_as.iter().cloned());
                    for e in &k.add {
                        if !ids.contains(&e.id.to_string()) {
                            ids.push(e.id.to_string());
                        }
                    }
                    let ok = c.expect.contains(&k.class.as_str());
                    let partial = c.expect.iter().any(|e| {
                        let want = match *e {
                            "offset" => "constant_force",
                            "mode" => "third_mass",
                            "saturation" => "torque_saturation",
                            other => other,
                        };
                        ids.iter().any(|i| i == want)
                    });
                    let params: Vec<String> = k
                        .params
                        .iter()
                        .map(|(p, v)| format!("{p}={v:.3e}"))
                        .collect();
                    println!("    first: {} {}", k.effect, params.join(" "));
                    (
                        format!(
                            "{} / {} ({:.0} %)",
                            k.class,
                            ids.join("+"),
                            k.error_reduction_pct
                        ),
                        if ok {
                            "yes"
                        } else if partial {
                            "partial"
                        } else {
                            "NO"
                        },
                    )
                }
            };
            // the first candidate's fit: the error of the channel where it shows, before and
            // after, and the other channels; then the guided loop's additions
            if let Some(k) = first.filter(|k| !k.add.is_empty() || k.is_param) {
                let free = k.is_param.then(|| vec![k.effect.clone()]);
                if let Ok(r) = fit_with(&m, &d, k.add.clone(), free.as_deref(), 0.05) {
                    let f = |e: &Errors| {
                        format!(
                            "eq {:.2} win {:.2} ctl {:.2}",
                            e.equation_nrmse_pct.unwrap_or(f64::NAN),
                            e.window_sim_nrmse_pct.unwrap_or(f64::NAN),
                            e.controller_nrmse_pct.unwrap_or(f64::NAN)
                        )
                    };
                    println!("    fit: {} -> {}", f(&r.before), f(&r.after));
                }
            }
            if let Ok(a) = auto(&m, &d, 0.05, 4) {
                let added: Vec<String> = a
                    .steps
                    .iter()
                    .skip(1)
                    .flat_map(|s| s.added.clone())
                    .collect();
                let eq = a
                    .steps
                    .last()
                    .and_then(|s| s.errors.equation_nrmse_pct)
                    .unwrap_or(f64::NAN);
                let peer = dg.sparse_peer.equation_nrmse_pct;
                println!(
                    "    auto: [{}] eq {eq:.3} %; peer {peer:.3} % with [{}]{}",
                    added.join(", "),
                    dg.sparse_peer.terms.join(", "),
                    if eq > peer { "  PEER LOWER" } else { "" }
                );
            }
            let ok = verdict == "yes";
            let others: Vec<String> = dg
                .candidates
                .iter()
                .filter(|k| k.significant)
                .skip(1)
                .filter(|k| first.is_none_or(|f| !f.same_as.contains(&k.effect)))
                .map(|k| format!("{} ({:.0} %)", k.effect, k.error_reduction_pct))
                .collect();
            let others = if others.is_empty() {
                "-".to_string()
            } else {
                others.join(", ")
            };
            let peak = run.controller.iter().fold(0.0f64, |a, x| a.max(x.abs()));
            total += 1;
            if ok {
                hits += 1;
            }
            if c.expect.is_empty() && first.is_some() && c.kind.starts_with("none") {
                false_claims.push(format!("{} {} ({nl}): {named}", c.kind, c.level));
            }
            let row = format!(
                "| {} | {} | {} | {} | {} | {} | {:.1} | {:.1}+{:.1} s |",
                c.kind, c.level, nl, named, verdict, others, peak, tgen, tdiag
            );
            println!("{row}");
            println!("    verdict: {}", dg.verdict);
            rows.push(row);
        }
    }
    println!();
    println!("| kind | level | noise | first significant: class / ids (reduction) | match | other significant | peak u N m | gen+diag |");
    println!("|---|---|---|---|---|---|---|---|");
    for r in &rows {
        println!("{r}");
    }
    println!("{hits} of {total} match");
    // what the baseline already holds: nothing is named where nothing is hidden
    assert!(
        false_claims.is_empty(),
        "significant candidates without a hidden effect: {false_claims:?}"
    );
}
