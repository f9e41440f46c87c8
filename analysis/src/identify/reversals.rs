//! What the traverse's reversals show about the axis (issue 20): the stiffness identification
//! cuts each reversal out of its data, but the windows on both sides of it tell two effects a
//! commissioning engineer wants named even when the stiffness can still be measured.
//!
//! - **Friction**: the mean torque on a window of positive velocity less the mean on one of
//!   negative velocity is the step the drive sees at a reversal, twice the velocity-dependent
//!   torque at the traverse speed (Coulomb and damping together; one traverse speed cannot tell
//!   them apart). A constant load (gravity) cancels in the difference.
//! - **Backlash**: the motor position less the load position (in motor units) shifts at each
//!   reversal by the lost motion: the dead band plus the spring's change of deflection, which is
//!   at most the torque step over the stiffness. A lost motion beyond that bound is a dead band.
//!
//! Each figure comes with its 95 % interval from the scatter over the reversals; an effect is
//! named only when the interval excludes its absence.

use serde::Serialize;

use crate::workbench::signal::{mean, quantile};

/// Effects seen at the reversals of a traverse.
#[derive(Debug, Clone, Serialize, Default)]
pub struct ReversalEffects {
    /// Reversals (pairs of adjacent one-direction windows of opposite sign) read.
    pub reversals: usize,
    /// Half the torque step between the directions: Coulomb friction plus damping at the
    /// traverse speed, motor side, N m.
    pub friction_nm: f64,
    /// Its 95 % half-width, N m.
    pub friction_ci_nm: f64,
    /// Coulomb friction (the part of the step that flips with the velocity's sign, not in
    /// proportion to it), N m, from the torque through each reversal: the torque, the velocity,
    /// its sign and the acceleration times the total inertia, all averaged over 20 ms (the
    /// excitation averages out, the reversal stays), fitted as `J a + Fc sign(v) + d v + c`.
    pub coulomb_nm: Option<f64>,
    /// Its 95 % half-width, N m (samples counted once per averaging length).
    pub coulomb_ci_nm: Option<f64>,
    /// The velocity-proportional part `d`, N m s/rad.
    pub damping_nms_per_rad: Option<f64>,
    /// Whether a Coulomb step is told apart from damping alone (its interval excludes 0).
    pub friction_seen: bool,
    /// Motor units per load unit read from the data (rad/m for a ball screw), when the trace has
    /// the load position.
    pub ratio: Option<f64>,
    /// Lost motion at a reversal, load units (m), when the trace has both positions.
    pub lost_motion_m: Option<f64>,
    /// Its 95 % half-width, m.
    pub lost_motion_ci_m: Option<f64>,
    /// The most the spring's deflection explains (torque step / KL), m.
    pub elastic_m: Option<f64>,
    /// Whether a dead band is told apart from the spring (lost motion less its interval above
    /// the elastic bound).
    pub backlash_seen: bool,
    /// Estimated dead band (lost motion less the spring's share, at least 0), m.
    pub backlash_m: Option<f64>,
    /// How far the deflection (motor less load position, load units, averaged over 1 ms)
    /// swings within a one-direction window (median over the windows of the range holding
    /// 99 % of its samples, the window's middle half), m. With the nut on one flank it is the
    /// spring's elastic swing; when the excitation lifts the nut off its flank it grows towards
    /// the dead band.
    pub flank_swing_m: Option<f64>,
    /// How one-sided that swing is: the longer side of the range about the median over the
    /// shorter (median over the windows; 1 for a symmetric elastic swing).
    pub flank_lopsided: Option<f64>,
    /// Whether the excitation lifted the nut off its flank: the swing is lopsided beyond
    /// [`MAX_LOPSIDED`], or larger than half the dead band read at the reversals. The response
    /// then mixes contact and free flight, and a two-mass fit to it can look tight and be wrong
    /// (on `xy-x-effects` with +-1 mm/s: KL -11 %, fit +-1 %).
    pub flank_lifted: bool,
    /// The smallest dead band the load measurement tells apart: twice its quantum, at least
    /// [`MIN_DEAD_BAND_M`], m.
    pub resolution_m: Option<f64>,
}

/// Largest lopsidedness of the deflection's swing within a direction that still counts as the
/// spring's own (symmetric) swing: lifted off its flank, the nut moves the deflection one way
/// only, half as far again as the other way at least (measured 1.02..1.03 in contact, 2.2 on an
/// axis whose nut lifted).
pub const MAX_LOPSIDED: f64 = 1.5;

/// Below a nanometre no lost motion is called a dead band (far below any scale's resolution and
/// any real backlash, above the rounding of positions in metres).
pub const MIN_DEAD_BAND_M: f64 = 1e-9;

/// Mean and 95 % half-width (1.96 standard errors) of `x`.
fn mean_ci(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    if x.len() < 2 {
        return (m, f64::INFINITY);
    }
    let var = x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, 1.96 * (var / n).sqrt())
}

/// Reads friction and backlash at the reversals between the one-direction `windows`
/// (`(start, end, sign)` sample ranges, settling already cut) of torque `u`, with the motor
/// position `motor` and the load position `load` when recorded, for a spring of `kl` N m/rad
/// (motor side). `None` with fewer than two reversals.
#[allow(clippy::too_many_arguments)]
pub fn reversal_effects(
    u: &[f64],
    v: &[f64],
    dt: f64,
    j_total: f64,
    motor: Option<&[f64]>,
    load: Option<&[f64]>,
    windows: &[(usize, usize, i8)],
    kl: f64,
) -> Option<ReversalEffects> {
    let pairs: Vec<(usize, usize)> = (1..windows.len())
        .filter(|&i| windows[i].2 != windows[i - 1].2)
        .map(|i| (i - 1, i))
        .collect();
    if pairs.len() < 2 {
        return None;
    }
    let wmean = |x: &[f64], (a, b, _): (usize, usize, i8)| mean(&x[a..b]);
    // the torque step, as (positive - negative) / 2 for each reversal
    let steps: Vec<f64> = pairs
        .iter()
        .map(|&(i, j)| {
            let (ui, uj) = (wmean(u, windows[i]), wmean(u, windows[j]));
            0.5 * f64::from(windows[i].2) * (ui - uj)
        })
        .collect();
    let (friction, friction_ci) = mean_ci(&steps);
    let mut e = ReversalEffects {
        reversals: pairs.len(),
        friction_nm: friction,
        friction_ci_nm: friction_ci,
        ..Default::default()
    };
    if let Some((fc, ci, d)) = coulomb_through_reversals(u, v, dt, j_total, windows, &pairs) {
        e.coulomb_nm = Some(fc);
        e.coulomb_ci_nm = Some(ci);
        e.damping_nms_per_rad = Some(d);
        e.friction_seen = fc - ci > 0.0;
    }
    let (Some(m), Some(l)) = (motor, load) else {
        return Some(e);
    };
    let Some(r) = travel_ratio(m, l, windows) else {
        return Some(e);
    };
    let lost = lost_motions(m, l, r, windows, &pairs);
    let (lm, lm_ci) = mean_ci(&lost);
    let (swings, lopsided) = flank_swings(m, l, r, dt, windows);
    if !swings.is_empty() {
        e.flank_swing_m = Some(quantile(&swings, 0.5));
        e.flank_lopsided = Some(quantile(&lopsided, 0.5));
    }
    let elastic = if kl > 0.0 {
        2.0 * friction.abs() / kl / r.abs()
    } else {
        f64::INFINITY
    };
    e.ratio = Some(r);
    e.lost_motion_m = Some(lm);
    e.lost_motion_ci_m = Some(lm_ci);
    e.elastic_m = Some(elastic);
    let floor = load_resolution(l);
    e.resolution_m = Some(floor);
    e.backlash_seen = lm - lm_ci > elastic + floor;
    e.backlash_m = Some((lm - elastic).max(0.0));
    e.flank_lifted = e.flank_lopsided.is_some_and(|x| x > MAX_LOPSIDED)
        || (e.backlash_seen
            && e.flank_swing_m
                .zip(e.backlash_m)
                .is_some_and(|(sw, gap)| sw > 0.5 * gap));
    Some(e)
}

/// Motor units per load unit: the travel of each window, motor over load (least squares);
/// `None` without load travel.
fn travel_ratio(m: &[f64], l: &[f64], windows: &[(usize, usize, i8)]) -> Option<f64> {
    let (mut sml, mut sll) = (0.0, 0.0);
    for &(a, b, _) in windows {
        let (dm, dl) = (m[b - 1] - m[a], l[b - 1] - l[a]);
        sml += dm * dl;
        sll += dl * dl;
    }
    if sll.is_nan() || sll <= 0.0 {
        return None;
    }
    Some(sml / sll)
}

/// The lost motion at each reversal of `pairs`, load units: the shift of the deflection (motor
/// less `r` times load) near each side of the reversal, the last quarter of the window before
/// against the first quarter of the one after.
fn lost_motions(
    m: &[f64],
    l: &[f64],
    r: f64,
    windows: &[(usize, usize, i8)],
    pairs: &[(usize, usize)],
) -> Vec<f64> {
    pairs
        .iter()
        .map(|&(i, j)| {
            let (a0, b0, _) = windows[i];
            let (a1, b1, _) = windows[j];
            let before = (b0 - (b0 - a0) / 4)..b0;
            let after = a1..(a1 + (b1 - a1) / 4);
            let defl = |k: std::ops::Range<usize>| {
                let n = k.len().max(1) as f64;
                k.map(|k| m[k] - r * l[k]).sum::<f64>() / n
            };
            (defl(before) - defl(after)).abs() / r.abs()
        })
        .collect()
}

/// The deflection's swing within each window's middle half (range holding 99 % of it, averaged
/// over 1 ms) and how lopsided it is about its median; windows too short are left out.
fn flank_swings(
    m: &[f64],
    l: &[f64],
    r: f64,
    dt: f64,
    windows: &[(usize, usize, i8)],
) -> (Vec<f64>, Vec<f64>) {
    let len = ((0.001 / dt).round() as usize).max(1);
    windows
        .iter()
        .filter_map(|&(a, b, _)| {
            let (a, b) = (a + (b - a) / 4, b - (b - a) / 4);
            let defl: Vec<f64> = (a..b).map(|k| (m[k] - r * l[k]) / r).collect();
            let d = moving_average(&defl, len);
            if d.len() < 100 {
                return None;
            }
            let (lo, mid, hi) = (quantile(&d, 0.005), quantile(&d, 0.5), quantile(&d, 0.995));
            // lifting off the flank moves the deflection one way only: towards the gap's middle
            let lopsided = (hi - mid).max(mid - lo) / (hi - mid).min(mid - lo).max(1e-15);
            Some((hi - lo, lopsided))
        })
        .unzip()
}

/// What the load measurement resolves: twice its quantum (the smallest gap between the
/// distinct values it recorded), and never below [`MIN_DEAD_BAND_M`].
fn load_resolution(l: &[f64]) -> f64 {
    let mut levels: Vec<f64> = l.iter().copied().filter(|x| x.is_finite()).collect();
    levels.sort_by(f64::total_cmp);
    let quantum = levels
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    (2.0 * quantum).clamp(MIN_DEAD_BAND_M, f64::MAX)
}

/// Moving average over `n` samples (centred; the ends average what they have).
fn moving_average(x: &[f64], n: usize) -> Vec<f64> {
    let mut c = Vec::with_capacity(x.len() + 1);
    c.push(0.0);
    for v in x {
        c.push(c.last().copied().unwrap_or(0.0) + v);
    }
    let h = n / 2;
    (0..x.len())
        .map(|k| {
            let (a, b) = (k.saturating_sub(h), (k + h + 1).min(x.len()));
            (c[b] - c[a]) / (b - a) as f64
        })
        .collect()
}

/// Coulomb friction, its 95 % half-width and the damping from the torque through the reversals
/// (see [`ReversalEffects::coulomb_nm`]): each reversal's stretch runs from the last quarter of
/// the window before to the first quarter of the one after.
fn coulomb_through_reversals(
    u: &[f64],
    v: &[f64],
    dt: f64,
    j_total: f64,
    windows: &[(usize, usize, i8)],
    pairs: &[(usize, usize)],
) -> Option<(f64, f64, f64)> {
    use nalgebra::{DMatrix, DVector};
    let len = ((0.02 / dt).round() as usize).max(3);
    let uf = moving_average(u, len);
    let vf = moving_average(v, len);
    let sign: Vec<f64> = v.iter().map(|x| x.signum()).collect();
    let sf = moving_average(&sign, len);
    let mut rows: Vec<[f64; 4]> = Vec::new();
    let mut y = Vec::new();
    for &(i, j) in pairs {
        let (a0, b0, _) = windows[i];
        let (a1, b1, _) = windows[j];
        let (s, e) = (b0 - (b0 - a0) / 4, a1 + (b1 - a1) / 4);
        for k in (s.max(1) + len..e.min(u.len() - 1).saturating_sub(len)).step_by(len / 3 + 1) {
            let a = (vf[k + 1] - vf[k - 1]) / (2.0 * dt);
            rows.push([sf[k], vf[k], 1.0, 0.0]);
            y.push(uf[k] - j_total * a);
        }
    }
    let n = rows.len();
    if n < 20 {
        return None;
    }
    let x = DMatrix::from_fn(n, 3, |r, c| rows[r][c]);
    let yv = DVector::from_vec(y);
    let xtx = x.transpose() * &x;
    let inv = xtx.clone().try_inverse()?;
    let beta = &inv * (x.transpose() * &yv);
    let res = &yv - &x * &beta;
    // samples a third of the averaging length apart: about 3 per independent one
    let eff = (n as f64 / 3.0 - 3.0).max(1.0);
    let s2 = res.norm_squared() / eff;
    let ci = 1.96 * (inv[(0, 0)] * s2 * 3.0).max(0.0).sqrt();
    Some((beta[0], ci, beta[1]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A traverse at +-1 with a dead band `gap` (load units) and a friction step: the motor leads
    /// the load by half the gap in each direction, plus the spring's share.
    #[allow(clippy::type_complexity)]
    fn traverse(
        gap: f64,
        friction: f64,
        kl: f64,
        r: f64,
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let (mut u, mut v, mut m, mut l) = (vec![], vec![], vec![], vec![]);
        let mut x: f64 = 0.0;
        for k in 0..8000 {
            let dir = if (k / 1000) % 2 == 0 { 1.0 } else { -1.0 };
            x += dir * 1e-4;
            let noise = 1e-3 * ((k * 7919 % 13) as f64 - 6.0);
            let tq = dir * friction + noise;
            u.push(tq);
            v.push(dir * 0.1);
            l.push(x);
            m.push(r * (x + dir * 0.5 * gap) + tq / kl);
        }
        (u, v, m, l)
    }

    fn windows() -> Vec<(usize, usize, i8)> {
        (0..8)
            .map(|i| {
                (
                    i * 1000 + 100,
                    i * 1000 + 900,
                    if i % 2 == 0 { 1 } else { -1 },
                )
            })
            .collect()
    }

    #[test]
    fn a_dead_band_and_a_friction_step_are_read_with_their_size() {
        let (u, v, m, l) = traverse(12e-6, 0.15, 3000.0, 628.3);
        let e =
            reversal_effects(&u, &v, 1e-3, 0.0, Some(&m), Some(&l), &windows(), 3000.0).unwrap();
        assert_eq!(e.reversals, 7);
        assert!(
            e.friction_seen && (e.friction_nm - 0.15).abs() < 1e-3,
            "{e:?}"
        );
        assert!((e.ratio.unwrap() / 628.3 - 1.0).abs() < 1e-3, "{e:?}");
        assert!(e.backlash_seen, "{e:?}");
        let lost = e.lost_motion_m.unwrap();
        // 12 um of play plus the spring's 2 x 0.15 / 3000 / 628.3 = 0.16 um
        assert!((lost - 12.16e-6).abs() < 0.1e-6, "{e:?}");
    }

    #[test]
    fn a_spring_alone_is_no_backlash_and_no_torque_step_no_friction() {
        let (u, v, m, l) = traverse(0.0, 0.15, 3000.0, 628.3);
        let e =
            reversal_effects(&u, &v, 1e-3, 0.0, Some(&m), Some(&l), &windows(), 3000.0).unwrap();
        assert!(e.friction_seen && !e.backlash_seen, "{e:?}");
        let (u, v, m, l) = traverse(0.0, 0.0, 3000.0, 628.3);
        let e =
            reversal_effects(&u, &v, 1e-3, 0.0, Some(&m), Some(&l), &windows(), 3000.0).unwrap();
        assert!(!e.friction_seen && !e.backlash_seen, "{e:?}");
        assert!(reversal_effects(&u, &v, 1e-3, 0.0, None, None, &windows()[..2], 3000.0).is_none());
    }
}
