//! Phase 2: every effect leaves its signature, in numbers, mostly in closed loop with the
//! brief's cascade (Kp = 50/s, Kv = 5 N m s/rad, Tv = 5 ms, JM = 2e-3, JL = 3e-3, KL = 3000,
//! 10 mm lead, 10 kHz).

mod common;

use std::f64::consts::PI;

use common::*;
use feedloop_plant::{AxisPlant, Side};

const H: f64 = 1e-4;
const R: f64 = 2.0 * PI / 0.01; // rad per m

fn closed_loop(extra_toml: &str) -> (AxisPlant, Cascade) {
    (ballscrew_with(extra_toml, H), Cascade::brief(H, R))
}

fn mean(x: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = x.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    s / n as f64
}

/// Lost motion: mean of (motor in m - load) in the constant-speed middle of + moves minus the
/// same in - moves (trapezoidal moves of 2 mm at 10 mm/s).
fn lost_motion_um(extra: &str) -> f64 {
    let (mut ax, mut c) = closed_loop(extra);
    let (dist, v, ta, td) = (0.002, 0.01, 0.02, 0.1);
    let tm = dist / v + ta;
    let recs = run_loop(
        &mut ax,
        &mut c,
        20_000,
        |t| trapezoid(t, dist, v, ta, td),
        |_| 0.0,
    );
    let cycle = 2.0 * (tm + td);
    let diff = |r: &Rec| (r.m.motor_pos / R - r.m.load_pos) * 1e6;
    let window = |start: f64| {
        let recs = &recs;
        mean(
            recs.iter()
                .filter(move |r| {
                    r.t > cycle
                        && (start + 0.3 * tm..start + 0.7 * tm).contains(&r.t.rem_euclid(cycle))
                })
                .map(diff),
        )
    };
    window(td) - window(2.0 * td + tm)
}

#[test]
fn backlash_of_20_um_shows_20_um_of_lost_motion_at_reversals() {
    // Table guides with 100 N of Coulomb friction keep the nut on its driving flank (with
    // much less friction the lightly damped nut contact bounces for seconds after a reversal).
    let fric = "[effects.coulomb_friction]\nside = \"load\"\nfc_n = 100\n";
    let with = lost_motion_um(&format!("{fric}[effects.backlash]\ngap_m = 20e-6\n"));
    let without = lost_motion_um(fric);
    println!("lost motion: {with:.3} um with a 20 um gap, {without:.4} um without");
    assert!((with - 20.0).abs() < 2.0, "{with}");
    assert!(without.abs() < 0.5, "{without}");
}

fn spectral_peak_hz(x: &[f64], h: f64, min_hz: f64) -> (f64, f64) {
    let (df, mags) = spectrum(x, h);
    let i0 = (min_hz / df) as usize;
    let (i, m) = mags
        .iter()
        .enumerate()
        .skip(i0)
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map(|(i, m)| (i, *m))
        .unwrap();
    (parabolic(&mags, i) * df, m)
}

fn constant_speed_torque(extra: &str, v: f64) -> Vec<f64> {
    let (mut ax, mut c) = closed_loop(extra);
    let recs = run_loop(&mut ax, &mut c, 12_000, |t| (v * t, v), |_| 0.0);
    recs[2000..].iter().map(|r| r.u).collect()
}

#[test]
fn cogging_of_12_periods_per_rev_shows_a_line_at_12_times_the_rotation_frequency() {
    // 50 mm/s on a 10 mm lead = 5 rev/s: the cogging line is at 60 Hz.
    let u = constant_speed_torque(
        "[effects.cogging]\namplitude_nm = 0.05\nperiods_per_rev = 12\n",
        0.05,
    );
    let (f, amp) = spectral_peak_hz(&u, H, 5.0);
    let u0 = constant_speed_torque("", 0.05);
    let (_, amp0) = spectral_peak_hz(&u0, H, 5.0);
    println!("cogging line at {f:.2} Hz, torque amplitude {amp:.4} N m (no cogging: {amp0:.2e})");
    assert!((f - 60.0).abs() < 0.5, "{f}");
    assert!(amp > 0.02 && amp < 0.08, "{amp}");
    assert!(amp0 < 1e-3 * amp);
}

fn circle_error(extra: &str) -> Vec<(f64, f64)> {
    // x = A sin(w t): reversals at t = 0.25 s, 0.75 s, ... (A = 5 mm, 1 Hz).
    let (a, w) = (0.005, 2.0 * PI);
    let (mut ax, mut c) = closed_loop(extra);
    let recs = run_loop(
        &mut ax,
        &mut c,
        20_000,
        |t| (a * (w * t).sin(), a * w * (w * t).cos()),
        |_| 0.0,
    );
    recs.iter().map(|r| (r.t, r.r - r.m.load_pos)).collect()
}

#[test]
fn coulomb_friction_gives_a_following_error_spike_of_about_2_um_per_n_m_at_reversals() {
    let base = circle_error("");
    for fc in [0.25, 0.5, 1.0] {
        let fr = circle_error(&format!("[effects.coulomb_friction]\nfc_nm = {fc}\n"));
        // Spike after the reversal at t = 1.25 s (velocity + -> -).
        let spike = fr
            .iter()
            .zip(&base)
            .filter(|(a, _)| (1.25..1.35).contains(&a.0))
            .map(|(a, b)| (a.1 - b.1).abs())
            .fold(0.0, f64::max);
        let per_nm = spike * 1e6 / fc;
        println!(
            "fc {fc} N m: reversal spike {:.3} um = {per_nm:.2} um per N m",
            spike * 1e6
        );
        assert!((1.5..2.7).contains(&per_nm), "{per_nm}");
    }
}

/// Welch H1 estimate of torque -> motor velocity from a closed-loop run with a random torque.
fn closed_loop_frf(extra: &str) -> (f64, Vec<f64>) {
    use rand::{rngs::SmallRng, Rng, SeedableRng};
    let (mut ax, mut c) = closed_loop(extra);
    let mut rng = SmallRng::seed_from_u64(7);
    let noise: Vec<f64> = (0..1 << 17).map(|_| rng.random_range(-0.5..0.5)).collect();
    let recs = run_loop(&mut ax, &mut c, noise.len(), |_| (0.0, 0.0), |k| noise[k]);
    let seg = 4096;
    let mut syu = vec![rustfft::num_complex::Complex::new(0.0, 0.0); seg / 2];
    let mut suu = vec![0.0; seg / 2];
    let win: Vec<f64> = (0..seg)
        .map(|i| 0.5 - 0.5 * (2.0 * PI * i as f64 / seg as f64).cos())
        .collect();
    let mut start = 0;
    while start + seg < recs.len() {
        // The torque of cycle k acts on the velocity sampled at k + 1.
        let u: Vec<f64> = (0..seg).map(|i| recs[start + i].u * win[i]).collect();
        let y: Vec<f64> = (0..seg)
            .map(|i| recs[start + i + 1].m.motor_vel * win[i])
            .collect();
        let (fu, fy) = (fft(&u), fft(&y));
        for k in 0..seg / 2 {
            syu[k] += fy[k] * fu[k].conj();
            suu[k] += fu[k].norm_sqr();
        }
        start += seg / 2;
    }
    let mag = (0..seg / 2).map(|k| (syu[k] / suu[k]).norm()).collect();
    (1.0 / (seg as f64 * H), mag)
}

fn local_max_near(mag: &[f64], df: f64, f: f64) -> Option<f64> {
    let i0 = ((f * 0.9) / df) as usize;
    let i1 = ((f * 1.1) / df) as usize;
    let i = (i0..=i1).max_by(|&a, &b| mag[a].total_cmp(&mag[b]))?;
    (i > i0 && i < i1 && mag[i] > 2.0 * mag[i0].min(mag[i1])).then_some(i as f64 * df)
}

/// 200 kg on 7.9e7 N/m (100 Hz alone), 2 % damping, behind the table: the model lines and the
/// two modes (Hz) of the free-free chain JM -KL- JL -K3- J3 (motor units, w^4 - b w^2 + c = 0).
fn third_mass_200_kg() -> (String, f64, f64) {
    let (m3, k3, c3) = (200.0, THIRD_MASS_K_N_PER_M, 5000.0);
    let extra = format!(
        "[effects.third_mass]\nmass_kg = {m3}\nstiffness_n_per_m = {k3}\ndamping_ns_per_m = {c3}\n"
    );
    let (j1, j2, j3) = (2e-3, 3e-3, m3 / (R * R));
    let (k1, k2) = (3000.0, k3 / (R * R));
    let b = k1 / j1 + k1 / j2 + k2 / j2 + k2 / j3;
    let cc = k1 * k2 * (j1 + j2 + j3) / (j1 * j2 * j3);
    let disc = (b * b - 4.0 * cc).sqrt();
    let mode = |w2: f64| w2.sqrt() / (2.0 * PI);
    (extra, mode((b - disc) / 2.0), mode((b + disc) / 2.0))
}

/// The third mass's spring: 100 Hz for 200 kg alone.
const THIRD_MASS_K_N_PER_M: f64 = 200.0 * (2.0 * PI * 100.0) * (2.0 * PI * 100.0);

#[test]
fn third_mass_adds_a_second_resonance_where_the_3_mass_chain_predicts_it() {
    let (extra, f_lo, f_hi) = third_mass_200_kg();
    let f_2mass = (3000.0f64 * 5e-3 / 6e-6).sqrt() / (2.0 * PI);
    let (df, mag) = closed_loop_frf(&extra);
    let (df0, mag0) = closed_loop_frf("");
    let lo = local_max_near(&mag, df, f_lo);
    let hi = local_max_near(&mag, df, f_hi);
    let base_lo = local_max_near(&mag0, df0, f_lo);
    let base_2 = local_max_near(&mag0, df0, f_2mass);
    println!("predicted {f_lo:.1} Hz and {f_hi:.1} Hz; measured {lo:?} and {hi:?}; 2-mass only: {base_2:?} (pred {f_2mass:.1}), near {f_lo:.0} Hz: {base_lo:?}");
    let lo = lo.expect("first resonance");
    let hi = hi.expect("second resonance");
    assert!((lo / f_lo - 1.0).abs() < 0.03);
    assert!((hi / f_hi - 1.0).abs() < 0.03);
    assert!(base_lo.is_none());
    assert!((base_2.expect("2-mass resonance") / f_2mass - 1.0).abs() < 0.03);
}

/// Local extrema of `x` (sign changes of its first difference).
fn extrema(x: &[f64]) -> usize {
    x.windows(3)
        .filter(|w| (w[1] - w[0]) * (w[2] - w[1]) < 0.0)
        .count()
}

#[test]
fn third_mass_rings_after_a_fast_move_at_the_frequency_of_the_chain() {
    // The 200 kg third mass; a 10 mm move at 100 mm/s with 10 ms ramps, then 0.2 s at rest.
    let (extra, f_lo, _) = third_mass_200_kg();
    let (dist, v, t_acc, t_dwell) = (0.01, 0.1, 0.01, 0.2);
    let traj = |t: f64| trapezoid(t, dist, v, t_acc, t_dwell);
    let run = |extra: &str| {
        let (mut ax, mut c) = closed_loop(extra);
        run_loop(&mut ax, &mut c, 5000, traj, |_| 0.0)
    };
    let (with, without) = (run(&extra), run(""));
    // The dwell after the stop, from 5 ms to 105 ms after the end of the move.
    let stop = t_dwell + dist / v + t_acc;
    let window = |recs: &[Rec]| -> Vec<f64> {
        recs.iter()
            .filter(|r| r.t >= stop + 0.005 && r.t < stop + 0.105)
            .map(|r| r.r - r.m.load_pos)
            .collect()
    };
    let (e3, e0) = (window(&with), window(&without));
    // The ringing: the difference the third mass makes, mean removed; its frequency from the
    // zero crossings (interpolated).
    let d: Vec<f64> = e3.iter().zip(&e0).map(|(a, b)| a - b).collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let crossings: Vec<f64> = d
        .windows(2)
        .enumerate()
        .filter(|(_, w)| (w[0] - mean) * (w[1] - mean) < 0.0)
        .map(|(k, w)| (k as f64 + (w[0] - mean) / (w[0] - w[1])) * H)
        .collect();
    let f_ring =
        (crossings.len() - 1) as f64 / (2.0 * (crossings[crossings.len() - 1] - crossings[0]));
    // The chain with the table held by the loop rings between the third mass on a fixed table
    // (100 Hz) and the free-free chain's first mode.
    let f_alone = (THIRD_MASS_K_N_PER_M / 200.0).sqrt() / (2.0 * PI);
    let amp = |x: &[f64], from: usize, to: usize| {
        x[from..to]
            .iter()
            .fold(0.0f64, |m, v| m.max((v - mean).abs()))
    };
    let (first, last) = (amp(&d, 0, 200), amp(&d, 800, 1000));
    println!(
        "ringing at {f_ring:.1} Hz (third mass alone {f_alone:.1} Hz, free chain {f_lo:.1} Hz), \
         {} extrema in 100 ms with the third mass, {} without; amplitude {:.2} um -> {:.2} um \
         over 80 ms",
        extrema(&e3),
        extrema(&e0),
        first * 1e6,
        last * 1e6
    );
    assert!(
        f_ring > 0.97 * f_alone && f_ring < 1.03 * f_lo,
        "{f_ring} Hz outside {f_alone}..{f_lo}"
    );
    assert!(extrema(&e3) >= 15, "it rings: {}", extrema(&e3));
    assert!(
        extrema(&e0) <= 2,
        "without it the loop settles: {}",
        extrema(&e0)
    );
    // The mode's own 2 % damping (plus what the loop adds through the table) makes it decay.
    assert!(first > 1e-6 && last < 0.6 * first, "{first} -> {last}");
}

#[test]
fn torque_saturation_grows_the_following_error_during_the_fastest_accelerations() {
    // A 20 mm move at 150 mm/s with 30 ms raised-cosine ramps (peak 7.9 m/s^2) needs up to
    // 26 N m at the motor; the drive clamps at 20 N m.
    let limit = 20.0;
    let (dist, v, t_acc, t_dwell) = (0.02, 0.15, 0.03, 0.05);
    let traj = |t: f64| trapezoid(t, dist, v, t_acc, t_dwell);
    let run = |extra: &str| {
        let (mut ax, mut c) = closed_loop(extra);
        run_loop(&mut ax, &mut c, 4000, traj, |_| 0.0)
    };
    let free = run("");
    let sat = run(&format!(
        "[effects.torque_saturation]\nlimit_nm = {limit}\n"
    ));
    let err = |r: &Rec| r.r - r.m.load_pos;
    let peak_demand = free.iter().map(|r| r.u.abs()).fold(0.0, f64::max);
    assert!(peak_demand > 1.2 * limit, "{peak_demand}");
    assert!(sat.iter().all(|r| r.m.applied_torque.abs() <= limit));
    // Identical until the drive first clamps (sample k reports the torque applied over the
    // period before it, so the first sample showing the limit already moved differently).
    let first = sat
        .iter()
        .position(|r| r.m.applied_torque.abs() >= limit)
        .expect("the drive clamps");
    assert!(first > 100);
    assert!(free[..first]
        .iter()
        .zip(&sat[..first])
        .all(|(a, b)| err(a) == err(b)));
    assert!(err(&free[first]) != err(&sat[first]));
    // The error the clamp adds peaks inside an acceleration ramp (or within 5 ms of its end)...
    let ramps = [
        (t_dwell, t_dwell + t_acc),
        (t_dwell + dist / v, t_dwell + dist / v + t_acc),
    ];
    let excess: Vec<(f64, f64)> = free
        .iter()
        .zip(&sat)
        .map(|(a, b)| (a.t, (err(b) - err(a)).abs()))
        .collect();
    let (t_peak, peak) = excess
        .iter()
        .filter(|(t, _)| *t < 2.0 * t_dwell + dist / v + t_acc)
        .fold((0.0, 0.0), |m, &(t, e)| if e > m.1 { (t, e) } else { m });
    let in_ramp = ramps
        .iter()
        .any(|&(a, b)| t_peak >= a && t_peak <= b + 0.005);
    // ... and has died away by the end of the constant-speed part.
    let cruise_end = excess
        .iter()
        .filter(|(t, _)| *t > ramps[1].0 - 0.02 && *t < ramps[1].0)
        .fold(0.0f64, |m, e| m.max(e.1));
    let free_max = free.iter().map(|r| err(r).abs()).fold(0.0, f64::max);
    println!(
        "demand {peak_demand:.1} N m, limit {limit} N m: clamped from t = {:.4} s; added error \
         peaks at {:.1} um at t = {t_peak:.4} s (ramps {ramps:?}); {:.2} um left at the end of \
         the cruise; unlimited max error {:.1} um",
        sat[first].t,
        peak * 1e6,
        cruise_end * 1e6,
        free_max * 1e6
    );
    assert!(in_ramp, "peak at {t_peak}");
    assert!(peak > 3.0 * free_max, "{peak} vs {free_max}");
    assert!(cruise_end < 0.05 * peak, "{cruise_end} vs {peak}");
}

fn delay_peak_lag(extra: &str) -> usize {
    use rand::{rngs::SmallRng, Rng, SeedableRng};
    let (mut ax, mut c) = closed_loop(extra);
    let mut rng = SmallRng::seed_from_u64(3);
    let prbs: Vec<f64> = (0..40_000)
        .map(|_| if rng.random::<bool>() { 0.2 } else { -0.2 })
        .collect();
    let recs = run_loop(&mut ax, &mut c, prbs.len(), |_| (0.0, 0.0), |k| prbs[k]);
    // Velocity increment over period k (from sample k to k + 1) against the PRBS of cycle k - lag.
    let dw: Vec<f64> = recs
        .windows(2)
        .map(|w| w[1].m.motor_vel - w[0].m.motor_vel)
        .collect();
    let xc = |lag: usize| -> f64 { (lag..dw.len()).map(|k| dw[k] * prbs[k - lag]).sum::<f64>() };
    let cors: Vec<f64> = (0..10).map(xc).collect();
    let peak = cors.iter().copied().fold(f64::MIN, f64::max);
    let rel: Vec<String> = cors.iter().map(|c| format!("{:.2}", c / peak)).collect();
    println!(
        "{extra:?}: cross-correlation by lag 0..9 (relative) {}",
        rel.join(" ")
    );
    (0..10)
        .max_by(|&a, &b| cors[a].total_cmp(&cors[b]))
        .unwrap()
}

#[test]
fn delay_of_3_cycles_moves_the_torque_response_cross_correlation_peak_by_3() {
    assert_eq!(delay_peak_lag(""), 0);
    assert_eq!(delay_peak_lag("[effects.delay]\ndelay_cycles = 3\n"), 3);
}

#[test]
fn pitch_error_is_periodic_in_position_with_the_lead_and_has_the_cumulative_slope() {
    let (amp, slope) = (5e-6, 20.0);
    let (mut ax, mut c) = closed_loop(&format!(
        "[effects.pitch_error]\namplitude_m = {amp}\nslope_um_per_m = {slope}\nphase_rad = 0.3\n"
    ));
    // 10 mm/s over 50 mm (five leads) after a short start.
    let v = 0.01;
    let recs = run_loop(&mut ax, &mut c, 52_000, |t| (v * t, v), |_| 0.0);
    // Least squares: d(x) = a sin(kx) + b cos(kx) + s x + c0 on the settled part.
    let k = 2.0 * PI / 0.01;
    let pts: Vec<(f64, f64)> = recs[2000..]
        .iter()
        .map(|r| (r.m.load_pos, r.m.motor_pos / R - r.m.load_pos))
        .collect();
    let basis = |x: f64| [(k * x).sin(), (k * x).cos(), x, 1.0];
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    let mut atb = nalgebra::Vector4::<f64>::zeros();
    for &(x, d) in &pts {
        let phi = nalgebra::Vector4::from(basis(x));
        ata += phi * phi.transpose();
        atb += phi * d;
    }
    let sol = ata.lu().solve(&atb).unwrap();
    let fitted_amp = (sol[0] * sol[0] + sol[1] * sol[1]).sqrt();
    let resid = pts
        .iter()
        .map(|&(x, d)| (d - nalgebra::Vector4::from(basis(x)).dot(&sol)).abs())
        .fold(0.0, f64::max);
    println!("pitch: amplitude {:.4} um (set 5), slope {:.3} um/m (set 20, seen negated on the motor), residual {:.2e} um", fitted_amp * 1e6, -sol[2] * 1e6, resid * 1e6);
    assert!((fitted_amp / amp - 1.0).abs() < 0.02);
    assert!((-sol[2] * 1e6 / slope - 1.0).abs() < 0.02);
    assert!(resid < 0.05 * amp);
}

#[test]
fn constant_force_of_200_n_shows_a_standstill_torque_of_minus_f_lead_over_2_pi() {
    let (mut ax, mut c) = closed_loop("[effects.constant_force]\nforce_n = 200.0\n");
    let recs = run_loop(&mut ax, &mut c, 10_000, |_| (0.0, 0.0), |_| 0.0);
    let t = mean(recs[8000..].iter().map(|r| r.u));
    let exact = -200.0 * 0.01 / (2.0 * PI); // -0.3183 N m
    println!("standstill torque {t:.6} N m (exact {exact:.6})");
    assert!((t / exact - 1.0).abs() < 1e-3);
    // At standstill the table sits at the commanded position.
    assert!(recs.last().unwrap().m.load_pos.abs() < 1e-9);
}

#[test]
fn friction_and_backlash_never_create_energy() {
    use rand::{rngs::SmallRng, Rng, SeedableRng};
    let mut ax = ballscrew_with(
        "[[effects.coulomb_friction]]\nfc_nm = 0.2\nfc_neg_nm = 0.15\n[[effects.stribeck_friction]]\nside = \"load\"\nfc_n = 40\nfs_n = 60\nvs_m_per_s = 0.002\n[effects.backlash]\ngap_m = 5e-6\n[effects.viscous_friction]\nc_nms_per_rad = 0.002\nc_neg_nms_per_rad = 0.001\n",
        H,
    );
    let mut rng = SmallRng::seed_from_u64(11);
    let mut u = 0.0;
    let (mut total_in, mut worst): (f64, f64) = (0.0, 0.0);
    let e_start = ax.energy_j();
    for k in 0..200_000 {
        if k % 50 == 0 {
            u = rng.random_range(-1.0..1.0);
        }
        let (th0, e0) = (ax.true_state().0, ax.energy_j());
        ax.step_axis(u);
        let w_in = u * (ax.true_state().0 - th0);
        total_in += w_in;
        let dissipated = w_in - (ax.energy_j() - e0);
        worst = worst.min(dissipated);
    }
    let total_diss = total_in - (ax.energy_j() - e_start);
    println!("input work {total_in:.4e} J, dissipated {total_diss:.4e} J, most negative step dissipation {worst:.2e} J");
    assert!(total_diss > 0.0);
    assert!(worst > -1e-12, "{worst}");
}

#[test]
fn stuck_motor_velocity_stays_exactly_zero_under_torque_below_static_friction() {
    let mut ax = ballscrew_with(
        "[effects.stribeck_friction]\nfc_nm = 0.4\nfs_nm = 0.6\nvs_rad_per_s = 1.0\n",
        H,
    );
    for k in 0..20_000 {
        // Up to 0.55 N m, alternating, below the static 0.6 N m.
        let u = 0.55 * (k as f64 * 0.01).sin();
        ax.step_axis(u);
        let (_, wm, _, _) = ax.true_state();
        assert_eq!(wm, 0.0, "cycle {k}");
        assert_eq!(ax.sense_axis().motor_vel, 0.0);
        assert!(ax.is_stuck(Side::Motor));
    }
    // 0.65 N m breaks it away.
    for _ in 0..100 {
        ax.step_axis(0.65);
    }
    assert!(!ax.is_stuck(Side::Motor));
    assert!(ax.true_state().1 > 0.0);
}

#[test]
fn stribeck_breakaway_happens_at_the_static_level_and_sliding_continues_above_coulomb() {
    let mut ax = ballscrew_with(
        "[effects.stribeck_friction]\nfc_nm = 0.4\nfs_nm = 0.6\nvs_rad_per_s = 1.0\n",
        H,
    );
    // Ramp at 1 N m/s (1e-4 N m per cycle).
    let mut breakaway = None;
    for k in 0..10_000 {
        let u = k as f64 * 1e-4;
        ax.step_axis(u);
        if breakaway.is_none() && ax.true_state().1 != 0.0 {
            breakaway = Some(u);
            break;
        }
    }
    let b = breakaway.unwrap();
    println!("breakaway at {b:.4} N m (static 0.6)");
    assert!((b - 0.6).abs() < 2e-3);
    // Once sliding faster than a few vs, friction has dropped to Coulomb: 0.5 N m (between
    // Coulomb 0.4 and static 0.6) keeps it sliding and accelerating.
    for _ in 0..500 {
        ax.step_axis(1.0);
    }
    let w0 = ax.true_state().1;
    assert!(w0 > 3.0, "{w0}");
    for _ in 0..2000 {
        ax.step_axis(0.5);
    }
    let w1 = ax.true_state().1;
    println!("speed {w0:.4} -> {w1:.4} rad/s at 0.5 N m");
    assert!(w1 > w0 + 1.0);
}

#[test]
fn asymmetric_coulomb_friction_on_a_rigid_axis_holds_up_to_each_level() {
    let mut ax = axis(
        "kind = \"rigid\"\nmass_kg = 10\n[effects.coulomb_friction]\nfc_n = 20\nfc_neg_n = 30\n",
        1e-3,
    );
    for _ in 0..100 {
        ax.step_axis(-29.0);
    }
    assert_eq!(ax.true_state().1, 0.0);
    for _ in 0..100 {
        ax.step_axis(21.0);
    }
    // 21 N against 20 N: a = 0.1 m/s^2 for 0.1 s.
    println!("rigid: v = {} m/s (exact 0.01)", ax.true_state().1);
    assert!((ax.true_state().1 - 0.01).abs() < 1e-9);
}

#[test]
fn asymmetric_viscous_friction_gives_steady_speeds_f_over_c_by_direction() {
    let mut ax = axis("kind = \"rigid\"\nmass_kg = 1\n[effects.viscous_friction]\nc_ns_per_m = 100\nc_neg_ns_per_m = 50\n", 1e-3);
    for _ in 0..2000 {
        ax.step_axis(100.0);
    }
    let vp = ax.true_state().1;
    for _ in 0..2000 {
        ax.step_axis(-100.0);
    }
    let vn = ax.true_state().1;
    println!("steady speeds {vp:.6} and {vn:.6} m/s (exact 1 and -2)");
    assert!((vp - 1.0).abs() < 1e-3);
    assert!((vn + 2.0).abs() < 2e-3);
}

#[test]
fn current_lag_matches_the_exact_first_order_response() {
    let (m, tau) = (2.0, 1e-3);
    let mut ax = axis(
        &format!("kind = \"rigid\"\nmass_kg = {m}\n[effects.current_lag]\ntau_s = {tau}\n"),
        H,
    );
    for k in 1..=30 {
        ax.step_axis(1.0);
        let t = k as f64 * H;
        let v_exact = (t - tau * (1.0 - (-t / tau).exp())) / m;
        let mean_exact = 1.0 - tau / H * (1.0 - (-H / tau).exp()) * (-(t - H) / tau).exp();
        assert!((ax.true_state().1 - v_exact).abs() < 1e-12, "k {k}");
        assert!((ax.applied_torque() - mean_exact).abs() < 1e-12, "k {k}");
    }
    println!("lag: applied torque after 10 tau/H periods 63 %: ok");
}

#[test]
fn torque_saturation_clamps_the_applied_torque_to_the_limit() {
    let mut ax = axis(
        "kind = \"rigid\"\nmass_kg = 2\n[effects.torque_saturation]\nlimit_n = 10\n",
        1e-3,
    );
    for _ in 0..100 {
        ax.step_axis(50.0);
    }
    assert_eq!(ax.applied_torque(), 10.0);
    assert_eq!(ax.sense_axis().applied_torque, 10.0);
    assert!((ax.true_state().1 - 10.0 * 0.1 / 2.0).abs() < 1e-12);
    ax.step_axis(-1e6);
    assert_eq!(ax.applied_torque(), -10.0);
}

#[test]
fn friction_on_both_sides_is_given_as_an_array_of_tables() {
    let mut ax = ballscrew_with(
        "[[effects.coulomb_friction]]\nside = \"motor\"\nfc_nm = 0.1\n[[effects.coulomb_friction]]\nside = \"load\"\nfc_n = 50\n",
        H,
    );
    // Load friction 50 N = 0.0796 N m at the motor; total 0.1796 N m holds 0.17 N m.
    for _ in 0..1000 {
        ax.step_axis(0.17);
    }
    assert!(ax.is_stuck(Side::Motor) && ax.is_stuck(Side::Load));
    assert_eq!(ax.true_state().3, 0.0);
}

#[test]
fn sensor_quantises_to_the_encoder_grid_and_adds_noise_of_the_given_deviation() {
    let mut ax = ballscrew_with(
        "[sensor]\nmotor_counts_per_rev = 4096\nload_resolution_m = 1e-6\nmotor_vel_noise_rad_per_s = 0.1\ntorque_noise_nm = 0.01\nseed = 5\n",
        H,
    );
    ax.set_initial_position(0.0123456);
    let q = 2.0 * PI / 4096.0;
    let (mut s1, mut s2, n) = (0.0, 0.0, 20_000);
    for _ in 0..n {
        ax.step_axis(0.0);
        let m = ax.sense_axis();
        let counts = m.motor_pos / q;
        assert!((counts - counts.round()).abs() < 1e-6);
        let lc = m.load_pos / 1e-6;
        assert!((lc - lc.round()).abs() < 1e-6);
        assert!(m.load_pos <= 0.0123456 && m.load_pos > 0.0123456 - 1e-6);
        s1 += m.motor_vel;
        s2 += m.motor_vel * m.motor_vel;
    }
    let sd = (s2 / n as f64 - (s1 / n as f64).powi(2)).sqrt();
    println!("velocity noise sd {sd:.5} rad/s (set 0.1)");
    assert!((sd / 0.1 - 1.0).abs() < 0.03);
}

#[test]
fn difference_velocity_is_the_quantised_position_step_over_the_period() {
    let mut ax = axis("kind = \"rigid\"\nmass_kg = 1\n[sensor]\nmotor_resolution_m = 1e-6\nvelocity_estimate = \"difference\"\n", 1e-3);
    let mut prev = ax.sense_axis().motor_pos;
    for _ in 0..200 {
        ax.step_axis(1.0);
        let m = ax.sense_axis();
        assert!((m.motor_vel - (m.motor_pos - prev) / 1e-3).abs() < 1e-9);
        prev = m.motor_pos;
    }
}

#[test]
fn all_effects_combined_stay_finite_and_track_a_move_within_20_um() {
    let (mut ax, mut c) = closed_loop(
        r#"
[[effects.viscous_friction]]
c_nms_per_rad = 0.001
c_neg_nms_per_rad = 0.002
[[effects.viscous_friction]]
side = "load"
c_ns_per_m = 300
[effects.coulomb_friction]
fc_nm = 0.1
[effects.stribeck_friction]
side = "load"
fc_n = 100
fs_n = 130
vs_m_per_s = 0.001
[effects.backlash]
gap_m = 5e-6
[effects.pitch_error]
amplitude_m = 2e-6
slope_um_per_m = 10
[[effects.cogging]]
amplitude_nm = 0.02
periods_per_rev = 36
[[effects.cogging]]
amplitude_nm = 0.01
periods_per_rev = 72
[effects.constant_force]
force_n = -100
[effects.third_mass]
mass_kg = 100
stiffness_n_per_m = 5e7
damping_ns_per_m = 2000
[effects.delay]
delay_cycles = 1
[effects.current_lag]
tau_s = 2e-4
[effects.torque_saturation]
limit_nm = 20
[sensor]
motor_counts_per_rev = 1048576
load_resolution_m = 1e-8
load_pos_noise_m = 1e-8
motor_vel_noise_rad_per_s = 0.001
"#,
    );
    // 10 mm at 20 mm/s with 50 ms ramps, back and forth, 3 s.
    let traj = |t: f64| trapezoid(t, 0.01, 0.02, 0.05, 0.2);
    let recs = run_loop(&mut ax, &mut c, 30_000, traj, |_| 0.0);
    let (mut ax0, mut c0) = closed_loop("");
    let base = run_loop(&mut ax0, &mut c0, 30_000, traj, |_| 0.0);
    let worst = |rs: &[Rec]| {
        rs.iter()
            .map(|r| (r.r - r.m.load_pos).abs())
            .fold(0.0, f64::max)
    };
    let (w, w0) = (worst(&recs), worst(&base));
    println!(
        "all effects: worst following error {:.2} um (no effects {:.3} um)",
        w * 1e6,
        w0 * 1e6
    );
    assert!(w < 20e-6, "{w}");
    assert!(w > 2.0 * w0);
    assert!(recs
        .iter()
        .all(|r| r.u.is_finite() && r.m.motor_pos.is_finite()));
}
