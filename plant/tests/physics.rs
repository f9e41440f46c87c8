//! Phase 1: the base physics against analytic results.

mod common;

use std::f64::consts::PI;

use common::*;
use feedloop_control::axis_io::{AxisCommand, AxisSensor};
use feedloop_plant::{AxisPlant, EffectId, Plant};

const UNDAMPED: &str = r#"
kind = "ballscrew"
jm_kgm2 = 2.0e-3
kl_nm_per_rad = 3000.0
jl_kgm2 = 3.0e-3
lead_m = 0.01
"#;

/// Frequencies (Hz) of the anti-resonance (min) and resonance (max) of the torque -> motor
/// velocity FRF estimated from a simulated impulse response.
fn frf_extrema(model: &str, h: f64, log2n: u32) -> (f64, f64) {
    let mut ax = axis(model, h);
    let n = 1usize << log2n;
    let mut w = Vec::with_capacity(n);
    for k in 0..n {
        ax.step_axis(if k == 0 { 1.0 } else { 0.0 });
        w.push(ax.true_state().1);
    }
    let spec = fft(&w);
    let df = 1.0 / (n as f64 * h);
    let mag: Vec<f64> = spec[..n / 2].iter().map(|c| c.norm().ln()).collect();
    let band = |lo: f64, hi: f64| ((lo / df) as usize, (hi / df) as usize);
    let (a0, a1) = band(100.0, 220.0);
    let imin = (a0..a1).min_by(|&i, &j| mag[i].total_cmp(&mag[j])).unwrap();
    let (r0, r1) = band(200.0, 400.0);
    let imax = (r0..r1).max_by(|&i, &j| mag[i].total_cmp(&mag[j])).unwrap();
    (parabolic(&mag, imin) * df, parabolic(&mag, imax) * df)
}

#[test]
fn ballscrew_frf_shows_anti_resonance_and_resonance_within_half_a_percent_at_10_khz() {
    // Light damping so the response dies out inside the record.
    let model = UNDAMPED.to_string()
        + "dm_nms_per_rad = 5e-3\ndl_nms_per_rad = 5e-3\ncl_nms_per_rad = 0.02\n";
    let (fa, fr) = frf_extrema(&model, 1e-4, 18);
    let fa_exact = (3000.0f64 / 3e-3).sqrt() / (2.0 * PI); // 159.15 Hz
    let fr_exact = (3000.0f64 * 5e-3 / (2e-3 * 3e-3)).sqrt() / (2.0 * PI); // 251.65 Hz
    println!("anti-resonance {fa:.3} Hz (exact {fa_exact:.3}), resonance {fr:.3} Hz (exact {fr_exact:.3})");
    assert!((fa / fa_exact - 1.0).abs() < 0.005, "fa = {fa}");
    assert!((fr / fr_exact - 1.0).abs() < 0.005, "fr = {fr}");
}

#[test]
fn stiff_2_khz_resonance_is_exact_at_a_1_khz_loop() {
    // KL raised so the resonance (2 kHz) lies far above the 500 Hz Nyquist frequency: the
    // discrete response still equals the analytic one at every sample.
    let (jm, jl) = (2e-3, 3e-3);
    let wr = 2.0 * PI * 2000.0;
    let kl = wr * wr * (jm * jl) / (jm + jl);
    let mut ax = axis(&UNDAMPED.replace("3000.0", &format!("{kl}")), 1e-3);
    // Response of wM to a 1 N m step from rest: t/J + JL/(JM J) sin(wr t)/wr; a 1 ms pulse is
    // the difference of two steps.
    let step = |t: f64| t / (jm + jl) + jl / (jm * (jm + jl)) * (wr * t).sin() / wr;
    ax.step_axis(1.0);
    let mut max_err: f64 = 0.0;
    for k in 1..2000 {
        ax.step_axis(0.0);
        let t = (k + 1) as f64 * 1e-3;
        let exact = step(t) - step(t - 1e-3);
        max_err = max_err.max((ax.true_state().1 - exact).abs());
    }
    let amp = jl / (jm * (jm + jl)) / wr;
    println!("2 kHz resonance at 1 kHz: max |wM error| {max_err:.3e} rad/s (oscillation amplitude {amp:.3e})");
    assert!(max_err < 1e-9 * amp.max(1.0), "{max_err}");
}

#[test]
fn free_oscillation_period_matches_the_resonance_within_1e_4() {
    let mut ax = axis(UNDAMPED, 1e-4);
    ax.step_axis(1.0);
    let w_mean = 1.0 * 1e-4 / 5e-3;
    let h = 1e-4;
    let mut prev = ax.true_state().1 - w_mean;
    let (mut first, mut last, mut count) = (None, 0.0, 0usize);
    for k in 2..200_000 {
        ax.step_axis(0.0);
        let cur = ax.true_state().1 - w_mean;
        if prev < 0.0 && cur >= 0.0 {
            let t = (k as f64 - 1.0 + prev / (prev - cur)) * h;
            if first.is_none() {
                first = Some(t);
            } else {
                count += 1;
            }
            last = t;
        }
        prev = cur;
    }
    let period = (last - first.unwrap()) / count as f64;
    let wr = 2.0 * PI / period;
    let exact = (3000.0f64 * 5e-3 / 6e-6).sqrt();
    println!("resonance from {count} periods: {wr:.4} rad/s (exact {exact:.4})");
    assert!((wr / exact - 1.0).abs() < 1e-4);
}

#[test]
fn undamped_energy_equals_input_work_and_then_stays_constant_to_1e_9() {
    let mut ax = axis(UNDAMPED, 1e-4);
    let mut work = 0.0;
    for k in 0..50 {
        let u = 0.5 * (1.0 + (k as f64 * 0.3).sin());
        let th0 = ax.true_state().0;
        ax.step_axis(u);
        work += u * (ax.true_state().0 - th0);
    }
    let e0 = ax.energy_j();
    println!("energy after pulse {e0:.6e} J, input work {work:.6e} J");
    assert!((e0 / work - 1.0).abs() < 1e-9);
    let mut worst: f64 = 0.0;
    for _ in 0..100_000 {
        ax.step_axis(0.0);
        worst = worst.max((ax.energy_j() / e0 - 1.0).abs());
    }
    println!("max relative energy drift over 10 s: {worst:.2e}");
    assert!(worst < 1e-9);
}

#[test]
fn rigid_mass_under_constant_force_moves_f_t2_over_2m() {
    let mut ax = axis("kind = \"rigid\"\nmass_kg = 2.0\n", 1e-3);
    for _ in 0..1000 {
        ax.step_axis(10.0);
    }
    let (x, v, ..) = ax.true_state();
    println!("rigid: x(1 s) = {x}, v = {v} (exact 2.5, 5)");
    assert!((x - 10.0 * 1.0 / (2.0 * 2.0)).abs() < 1e-12);
    assert!((v - 5.0).abs() < 1e-12);
}

#[test]
fn rigid_mass_with_viscous_friction_follows_the_exponential_solution() {
    let (m, c, f) = (2.0, 4.0, 10.0);
    let mut ax = axis(
        &format!("kind = \"rigid\"\nmass_kg = {m}\nviscous_ns_per_m = {c}\n"),
        1e-3,
    );
    let tau = m / c;
    for k in 1..=3000 {
        ax.step_axis(f);
        if k % 500 == 0 {
            let t = k as f64 * 1e-3;
            let (x, v, ..) = ax.true_state();
            let xe = f / c * (t - tau * (1.0 - (-t / tau).exp()));
            let ve = f / c * (1.0 - (-t / tau).exp());
            assert!((x - xe).abs() < 1e-12 * xe.max(1.0), "t {t}: x {x} vs {xe}");
            assert!((v - ve).abs() < 1e-12 * ve.max(1.0), "t {t}: v {v} vs {ve}");
        }
    }
    // Steady velocity F/c = 2.5 m/s after 6 s (12 tau).
    for _ in 0..3000 {
        ax.step_axis(f);
    }
    assert!((ax.true_state().1 - 2.5).abs() < 1e-4);
}

#[test]
fn ballscrew_under_constant_torque_reaches_speed_t_over_dm_plus_dl_and_deflection_dl_w_over_kl() {
    let mut ax = axis(BALLSCREW, 1e-3);
    for _ in 0..50_000 {
        ax.step_axis(0.1);
    }
    let (thm, wm, xl, vl) = ax.true_state();
    let w = 0.1 / 3e-3; // 33.33 rad/s
    let r = 2.0 * PI / 0.01;
    let defl = thm - xl * r;
    println!(
        "steady: wM {wm} (exact {w}), load {} rad/s, deflection {defl:.6e} rad (exact {:.6e})",
        vl * r,
        2e-3 * w / 3000.0
    );
    assert!((wm / w - 1.0).abs() < 1e-6);
    assert!((vl * r / w - 1.0).abs() < 1e-6);
    assert!((defl / (2e-3 * w / 3000.0) - 1.0).abs() < 1e-4);
}

#[test]
fn initial_position_is_reported_in_load_units_with_motor_in_rad() {
    let mut ax = axis(BALLSCREW, 1e-4);
    ax.set_initial_position(0.05);
    let m = ax.sense_axis();
    assert!((m.load_pos - 0.05).abs() < 1e-15);
    assert!((m.motor_pos - 0.05 * 2.0 * PI / 0.01).abs() < 1e-12); // 31.416 rad
    assert_eq!(m.motor_vel, 0.0);
    // At rest with springs relaxed: no motion without torque.
    for _ in 0..1000 {
        ax.step_axis(0.0);
    }
    assert_eq!(ax.sense_axis().load_pos, m.load_pos);

    let mut rot = axis(
        &BALLSCREW
            .replace("ballscrew", "rotary")
            .replace("lead_m = 0.01", ""),
        1e-4,
    );
    rot.set_initial_position(1.0);
    let m = rot.sense_axis();
    assert_eq!((m.motor_pos, m.load_pos), (1.0, 1.0));
}

#[test]
fn gear_ratio_scales_the_load_position() {
    let mut ax = axis(&format!("{BALLSCREW}\ngear_ratio = 2.0\n"), 1e-4);
    ax.set_initial_position(0.01);
    assert!((ax.sense_axis().motor_pos - 4.0 * PI).abs() < 1e-12);
}

#[test]
fn unknown_effect_id_is_refused_listing_the_known_ids() {
    let e = build_error(&format!(
        "{BALLSCREW}\n[effects.magic_friction]\nfc_nm = 1\n"
    ));
    println!("{e}");
    assert_eq!(e.key, "effects.magic_friction");
    for id in EffectId::ALL {
        assert!(e.reason.contains(id.id()), "{e}");
    }
    assert!(e
        .to_string()
        .starts_with("test.toml: key `effects.magic_friction`"));
}

#[test]
fn unknown_sensor_key_is_refused_naming_it() {
    let e = build_error(&format!("{BALLSCREW}\n[sensor]\nmotor_counts = 1000\n"));
    assert_eq!(e.key, "sensor.motor_counts");
}

#[test]
fn nan_and_infinite_torques_count_as_zero_and_do_not_poison_the_state() {
    let mut ax = ballscrew_with(
        "[effects.coulomb_friction]\nfc_nm = 0.1\n[effects.backlash]\ngap_m = 1e-5\n",
        1e-4,
    );
    for k in 0..1000 {
        ax.step_axis(if k % 2 == 0 { 1.0 } else { -0.5 });
    }
    let before = ax.true_state();
    let mut twin = ax.clone();
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        ax.step_axis(bad);
        twin.step_axis(0.0);
    }
    assert_eq!(ax.true_state(), twin.true_state());
    assert!(before.0.is_finite());
    // Huge finite torques are clamped and keep the state finite.
    for _ in 0..100 {
        ax.step_axis(f64::MAX);
    }
    let s = ax.true_state();
    assert!(s.0.is_finite() && s.1.is_finite() && s.2.is_finite() && s.3.is_finite());
}

#[test]
fn same_inputs_give_bit_identical_outputs_including_noise() {
    let model = parse(&format!(
        "{BALLSCREW}\n[effects.coulomb_friction]\nfc_nm = 0.1\n[sensor]\nmotor_counts_per_rev = 8192\nload_resolution_m = 1e-7\nmotor_pos_noise_rad = 1e-4\nmotor_vel_noise_rad_per_s = 0.01\nload_pos_noise_m = 1e-7\nseed = 42\n"
    ))
    .unwrap();
    let run = || {
        let mut p = Plant::from_models(&[&model, &model], 1e-4).unwrap();
        let mut s = [AxisSensor::default(); 2];
        let mut c = [AxisCommand::default(); 2];
        let mut out = Vec::new();
        for k in 0..5000 {
            p.sense(&mut s);
            out.push(s);
            c[0].torque = (k as f64 * 0.01).sin();
            c[1].torque = (k as f64 * 0.013).cos();
            p.step(&c);
        }
        out
    };
    let (a, b) = (run(), run());
    assert!(a == b);
    // The two axes share a model file but get independent noise.
    assert_ne!(a[10][0].motor_vel - a[10][1].motor_vel, 0.0);
}

#[test]
fn plant_new_builds_all_axes_and_refuses_a_bad_period() {
    let m = parse(BALLSCREW).unwrap();
    let p = Plant::from_models(&[&m, &m, &m], 1e-4).unwrap();
    assert_eq!(p.axis_count(), 3);
    let e = Plant::from_models(&[&m], 0.0).unwrap_err();
    assert_eq!(e.key, "period_s");
    let _ = AxisPlant::new(&m, 1e-3).unwrap();
}

#[test]
fn plant_new_reads_the_axes_of_a_job_in_file_order() {
    let dir = std::env::temp_dir().join(format!("feedloop-plant-job-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("bs.toml"), BALLSCREW).unwrap();
    std::fs::write(dir.join("lin.toml"), "kind = \"rigid\"\nmass_kg = 10\n").unwrap();
    std::fs::write(
        dir.join("job.toml"),
        "period_s = 0.001\n[axes.x]\nmodel = \"bs.toml\"\n[axes.y]\nmodel = \"lin.toml\"\n[trajectory]\nkind = \"dwell\"\n",
    )
    .unwrap();
    let job = feedloop_model::job::Job::load(&dir.join("job.toml")).unwrap();
    let mut p = Plant::new(&job).unwrap();
    assert_eq!(p.axis_count(), 2);
    assert_eq!(p.period_s(), 0.001);
    p.set_initial_positions(&[0.01, 0.2]);
    let mut s = [AxisSensor::default(); 2];
    p.sense(&mut s);
    assert!((s[0].motor_pos - 2.0 * PI).abs() < 1e-12);
    assert_eq!(s[1].load_pos, 0.2);
    let mut c = [AxisCommand::default(); 2];
    c[1].torque = 10.0;
    p.step(&c);
    p.sense(&mut s);
    // 10 N on 10 kg for 1 ms: v = 1 mm/s, x = 0.2 + 0.5 um.
    assert!((s[1].motor_vel - 1e-3).abs() < 1e-15);
    assert!((s[1].load_pos - 0.2000005).abs() < 1e-12);
    assert_eq!(s[1].applied_torque, 10.0);
    let _ = std::fs::remove_dir_all(&dir);
}
