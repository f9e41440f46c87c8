//! Piecewise polynomials in normalised time, the C5 smoothstep and the jerk-limited profile.
//!
//! Each piece `i` covers `[t_i, t_i + T_i)` and holds, per axis, a polynomial of degree <= 12 in
//! `tau = (t - t_i) / T_i`. The `d`-th time derivative is `p^(d)(tau) / T_i^d`.
//!
//! The C5 smoothstep (order-5 "smootherstep", degree 11) is the unique polynomial with
//! `s(0) = 0`, `s(1) = 1` and `s^(k)(0) = s^(k)(1) = 0` for `k = 1..5`:
//!
//! `s(tau) = 462 tau^6 - 1980 tau^7 + 3465 tau^8 - 3080 tau^9 + 1386 tau^10 - 252 tau^11`,
//! `s'(tau) = 2772 tau^5 (1 - tau)^5` (peak `2772 / 1024 = 2.707` at `tau = 1/2`).
//!
//! Its integral `h(tau) = int_0^tau s = 66 tau^7 - 247.5 tau^8 + 385 tau^9 - 308 tau^10 +
//! 126 tau^11 - 21 tau^12` (`h(1) = 1/2`) shapes a smooth velocity change: a velocity step `dv`
//! spread over `T` adds `dv T h(tau)` to the position.
//!
//! A piece built by [`Builder::piece`] is, per axis,
//! `p(tau) = p0 + v0 T tau + a0 T^2 tau^2 / 2 + j T^3 tau^3 / 6 + D s(tau) + dv T h(tau)`,
//! so moves (`D`), smooth velocity changes (`dv`) and constant-jerk pieces (`j`) chain with
//! continuous position, velocity and acceleration.

use feedloop_control::controller::REF_DERIVS;

use super::RefState;

/// Number of coefficients of a piece polynomial (degree 12).
pub const NC: usize = 13;

/// Polynomial coefficients in ascending powers of `tau`.
pub type Coeffs = [f64; NC];

/// The C5 smoothstep `s(tau)`.
pub const SMOOTHSTEP: Coeffs = [
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 462.0, -1980.0, 3465.0, -3080.0, 1386.0, -252.0, 0.0,
];

/// Integral of the C5 smoothstep, `h(tau) = int_0^tau s(u) du`.
pub const SMOOTHSTEP_INTEGRAL: Coeffs = [
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 66.0, -247.5, 385.0, -308.0, 126.0, -21.0,
];

/// Peak of `s'(tau)` (at `tau = 1/2`): `2772 / 1024`.
pub const SMOOTHSTEP_PEAK_SLOPE: f64 = 2772.0 / 1024.0;

/// Factorials 0!..5!.
pub const FACT: [f64; REF_DERIVS] = [1.0, 1.0, 2.0, 6.0, 24.0, 120.0];

/// Taylor coefficients `p^(d)(tau) / d!` for `d = 0..5` (repeated synthetic division).
pub fn taylor_at(c: &Coeffs, tau: f64) -> [f64; REF_DERIVS] {
    let mut b = *c;
    let mut out = [0.0; REF_DERIVS];
    for (d, o) in out.iter_mut().enumerate() {
        for k in (d..NC - 1).rev() {
            b[k] += tau * b[k + 1];
        }
        *o = b[d];
    }
    out
}

/// All Taylor coefficients `p^(d)(tau) / d!`, `d = 0..12` (the polynomial shifted to `tau`).
pub fn taylor_all(c: &Coeffs, tau: f64) -> Coeffs {
    let mut b = *c;
    for d in 0..NC {
        for k in (d..NC - 1).rev() {
            b[k] += tau * b[k + 1];
        }
    }
    b
}

/// Value and derivatives 1..5 of the smoothstep at `tau`, clamped outside `[0, 1]`.
pub fn smoothstep(tau: f64) -> RefState {
    if tau <= 0.0 {
        return [0.0; REF_DERIVS];
    }
    if tau >= 1.0 {
        let mut r = [0.0; REF_DERIVS];
        r[0] = 1.0;
        return r;
    }
    let mut r = taylor_at(&SMOOTHSTEP, tau);
    for (v, f) in r.iter_mut().zip(FACT) {
        *v *= f;
    }
    r
}

/// A multi-axis piecewise polynomial; holds the first piece's start before it and the end
/// position (zero derivatives) after it.
#[derive(Debug, Clone)]
pub struct PiecewisePoly {
    n_axes: usize,
    starts: Vec<f64>,
    durs: Vec<f64>,
    coeffs: Vec<Coeffs>,
    start_pos: Vec<f64>,
    end_pos: Vec<f64>,
    end_s: f64,
}

impl PiecewisePoly {
    /// Number of axes.
    pub fn n_axes(&self) -> usize {
        self.n_axes
    }

    /// End time, s.
    pub fn end_s(&self) -> f64 {
        self.end_s
    }

    /// Number of pieces.
    pub fn pieces(&self) -> usize {
        self.starts.len()
    }

    /// Start time of every piece, s (ascending).
    pub fn piece_starts(&self) -> &[f64] {
        &self.starts
    }

    /// Evaluates all axes at `t_s` (no allocation). `out` may be shorter than `n_axes`.
    pub fn eval(&self, t_s: f64, out: &mut [RefState]) {
        let n = self.n_axes.min(out.len());
        if self.starts.is_empty() || t_s >= self.end_s || t_s < self.starts[0] || t_s.is_nan() {
            let hold = if self.starts.is_empty() || t_s >= self.end_s || t_s.is_nan() {
                &self.end_pos
            } else {
                &self.start_pos
            };
            for (o, p) in out[..n].iter_mut().zip(hold) {
                *o = [0.0; REF_DERIVS];
                o[0] = *p;
            }
            return;
        }
        let i = self.starts.partition_point(|s| *s <= t_s).saturating_sub(1);
        let dur = self.durs[i];
        let tau = ((t_s - self.starts[i]) / dur).clamp(0.0, 1.0);
        let inv = 1.0 / dur;
        for (a, o) in out[..n].iter_mut().enumerate() {
            let tc = taylor_at(&self.coeffs[i * self.n_axes + a], tau);
            let mut scale = 1.0;
            for d in 0..REF_DERIVS {
                o[d] = tc[d] * FACT[d] * scale;
                scale *= inv;
            }
        }
    }

    /// Evaluates one axis at `t_s` (zeros for an axis index out of range).
    pub fn eval_axis(&self, t_s: f64, axis: usize) -> RefState {
        let mut buf = [[0.0; REF_DERIVS]; feedloop_model::MAX_AXES];
        let n = self.n_axes.min(buf.len());
        self.eval(t_s, &mut buf[..n]);
        buf.get(axis).copied().unwrap_or_default()
    }
}

/// Appends pieces while tracking each axis' position, velocity and acceleration at the end.
#[derive(Debug, Clone)]
pub struct Builder {
    n: usize,
    t: f64,
    pos: Vec<f64>,
    vel: Vec<f64>,
    acc: Vec<f64>,
    starts: Vec<f64>,
    durs: Vec<f64>,
    coeffs: Vec<Coeffs>,
    start_pos: Vec<f64>,
    windows: Vec<[f64; 2]>,
}

impl Builder {
    /// Starts at rest at `start` (one position per axis) at time 0.
    pub fn new(start: &[f64]) -> Self {
        Self {
            n: start.len(),
            t: 0.0,
            pos: start.to_vec(),
            vel: vec![0.0; start.len()],
            acc: vec![0.0; start.len()],
            starts: Vec::new(),
            durs: Vec::new(),
            coeffs: Vec::new(),
            start_pos: start.to_vec(),
            windows: Vec::new(),
        }
    }

    /// Current end time, s.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Current end position of each axis.
    pub fn position(&self) -> &[f64] {
        &self.pos
    }

    /// Current end velocity of each axis.
    pub fn velocity(&self) -> &[f64] {
        &self.vel
    }

    /// Whether every axis is at rest (velocity and acceleration below `1e-12` relative).
    pub fn at_rest(&self) -> bool {
        self.vel.iter().chain(&self.acc).all(|v| v.abs() < 1e-12)
    }

    /// Appends one piece of duration `dur` (s): per axis a smooth displacement `delta[a]`, a
    /// smooth velocity change `dv[a]` and a constant jerk `jerk[a]` on top of the current
    /// motion. Empty slices mean zeros. `dur <= 0` appends nothing.
    pub fn piece(&mut self, dur: f64, delta: &[f64], dv: &[f64], jerk: &[f64]) {
        if dur <= 0.0 || !dur.is_finite() {
            return;
        }
        let get = |s: &[f64], a: usize| s.get(a).copied().unwrap_or(0.0);
        for a in 0..self.n {
            let (d, w, j) = (get(delta, a), get(dv, a), get(jerk, a));
            let (p0, v0, a0) = (self.pos[a], self.vel[a], self.acc[a]);
            let mut c = [0.0; NC];
            c[0] = p0;
            c[1] = v0 * dur;
            c[2] = 0.5 * a0 * dur * dur;
            c[3] = j * dur * dur * dur / 6.0;
            for k in 0..NC {
                c[k] += d * SMOOTHSTEP[k] + w * dur * SMOOTHSTEP_INTEGRAL[k];
            }
            self.coeffs.push(c);
            self.pos[a] = p0
                + v0 * dur
                + 0.5 * a0 * dur * dur
                + j * dur * dur * dur / 6.0
                + d
                + 0.5 * w * dur;
            self.vel[a] = v0 + a0 * dur + 0.5 * j * dur * dur + w;
            self.acc[a] = a0 + j * dur;
        }
        self.starts.push(self.t);
        self.durs.push(dur);
        self.t += dur;
    }

    /// Holds the current motion (a dwell when at rest) for `dur` s.
    pub fn hold(&mut self, dur: f64) {
        self.piece(dur, &[], &[], &[]);
    }

    /// Constant velocity for `dur` s, recorded as a steady window.
    pub fn cruise(&mut self, dur: f64) {
        if dur > 0.0 {
            self.windows.push([self.t, self.t + dur]);
        }
        self.hold(dur);
    }

    /// A C5 move by `delta` (per axis) in `dur` s.
    pub fn smooth_move(&mut self, dur: f64, delta: &[f64]) {
        self.piece(dur, delta, &[], &[]);
    }

    /// A C5 velocity change by `dv` (per axis, load units/s) spread over `dur` s.
    pub fn smooth_velocity_change(&mut self, dur: f64, dv: &[f64]) {
        self.piece(dur, &[], dv, &[]);
    }

    /// A rest-to-rest jerk-limited (7-phase S-curve) straight move by `delta` with limits on
    /// the path (Euclidean over the axes): velocity `v_max`, acceleration `a_max`, jerk `j_max`.
    pub fn jerk_limited_move(&mut self, delta: &[f64], v_max: f64, a_max: f64, j_max: f64) {
        let dist = delta.iter().map(|d| d * d).sum::<f64>().sqrt();
        if dist <= 0.0 {
            return;
        }
        let p = ScurvePlan::new(dist, v_max, a_max, j_max);
        let target: Vec<f64> = self.pos.iter().zip(delta).map(|(p, d)| p + d).collect();
        let dir: Vec<f64> = delta.iter().map(|d| d / dist).collect();
        let jerk = |sign: f64| -> Vec<f64> { dir.iter().map(|u| sign * p.jerk * u).collect() };
        let (jp, jn, j0) = (jerk(1.0), jerk(-1.0), jerk(0.0));
        self.piece(p.tj, &[], &[], &jp);
        self.piece(p.tca, &[], &[], &j0);
        self.piece(p.tj, &[], &[], &jn);
        if p.tv > 0.0 {
            self.windows.push([self.t, self.t + p.tv]);
        }
        self.piece(p.tv, &[], &[], &j0);
        self.piece(p.tj, &[], &[], &jn);
        self.piece(p.tca, &[], &[], &j0);
        self.piece(p.tj, &[], &[], &jp);
        // Remove rounding residue (~1e-16 relative) so the next piece starts exactly at rest.
        self.pos = target;
        self.vel.iter_mut().for_each(|v| *v = 0.0);
        self.acc.iter_mut().for_each(|v| *v = 0.0);
    }

    /// The constant-velocity windows recorded so far, s.
    pub fn windows(&self) -> &[[f64; 2]] {
        &self.windows
    }

    /// Finishes: after the last piece the end position is held with zero derivatives.
    pub fn finish(self) -> (PiecewisePoly, Vec<[f64; 2]>) {
        (
            PiecewisePoly {
                n_axes: self.n,
                end_s: self.t,
                starts: self.starts,
                durs: self.durs,
                coeffs: self.coeffs,
                start_pos: self.start_pos,
                end_pos: self.pos,
            },
            self.windows,
        )
    }
}

/// Phase times of a rest-to-rest 7-phase S-curve over a distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScurvePlan {
    /// Duration of each constant-jerk phase, s.
    pub tj: f64,
    /// Duration of each constant-acceleration phase, s.
    pub tca: f64,
    /// Duration of the constant-velocity phase, s.
    pub tv: f64,
    /// Jerk magnitude used, units/s^3.
    pub jerk: f64,
    /// Peak velocity reached, units/s.
    pub v_peak: f64,
    /// Peak acceleration reached, units/s^2.
    pub a_peak: f64,
}

impl ScurvePlan {
    /// Plans `dist > 0` with limits `v`, `a`, `j` (all > 0), minimum time.
    pub fn new(dist: f64, v: f64, a: f64, j: f64) -> Self {
        let accel_phase = |v: f64| -> (f64, f64) {
            if v * j >= a * a {
                (a / j, v / a - a / j)
            } else {
                ((v / j).sqrt(), 0.0)
            }
        };
        let (mut tj, mut tca) = accel_phase(v);
        let d_acc = v * (2.0 * tj + tca) / 2.0;
        let mut v_peak = v;
        let mut tv = 0.0;
        if 2.0 * d_acc <= dist {
            tv = (dist - 2.0 * d_acc) / v;
        } else {
            let va = 0.5 * a * (-a / j + (a * a / (j * j) + 4.0 * dist / a).sqrt());
            v_peak = if va * j >= a * a {
                va
            } else {
                (dist * j.sqrt() / 2.0).powf(2.0 / 3.0)
            };
            (tj, tca) = accel_phase(v_peak);
        }
        ScurvePlan {
            tj,
            tca,
            tv,
            jerk: j,
            v_peak,
            a_peak: j * tj,
        }
    }

    /// Total duration, s.
    pub fn duration_s(&self) -> f64 {
        4.0 * self.tj + 2.0 * self.tca + self.tv
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothstep_has_zero_derivatives_one_to_five_at_both_ends() {
        let d0 = taylor_at(&SMOOTHSTEP, 0.0);
        let d1 = taylor_at(&SMOOTHSTEP, 1.0);
        assert_eq!(d0[0], 0.0);
        assert!((d1[0] - 1.0).abs() < 1e-12);
        for k in 1..REF_DERIVS {
            assert_eq!(d0[k], 0.0);
            assert!(d1[k].abs() < 1e-9, "derivative {k} at 1: {}", d1[k]);
        }
        let mid = smoothstep(0.5);
        assert!((mid[0] - 0.5).abs() < 1e-14);
        assert!((mid[1] - SMOOTHSTEP_PEAK_SLOPE).abs() < 1e-12);
    }

    #[test]
    fn smoothstep_integral_is_one_half_and_its_derivative_is_the_smoothstep() {
        let h = taylor_at(&SMOOTHSTEP_INTEGRAL, 1.0);
        assert!((h[0] - 0.5).abs() < 1e-12);
        for tau in [0.1, 0.37, 0.5, 0.9] {
            let hd = taylor_at(&SMOOTHSTEP_INTEGRAL, tau);
            let s = taylor_at(&SMOOTHSTEP, tau);
            assert!((hd[1] - s[0]).abs() < 1e-12);
        }
    }

    #[test]
    fn s_curve_respects_its_limits_and_covers_the_distance() {
        for (dist, v, a, j) in [
            (0.05, 0.2, 2.0, 50.0),
            (0.001, 0.2, 2.0, 50.0),
            (0.01, 0.2, 20.0, 50.0),
            (1.0, 0.1, 1.0, 1000.0),
        ] {
            let p = ScurvePlan::new(dist, v, a, j);
            assert!(p.v_peak <= v * (1.0 + 1e-12));
            assert!(p.a_peak <= a * (1.0 + 1e-12));
            let mut b = Builder::new(&[0.0]);
            b.jerk_limited_move(&[dist], v, a, j);
            let (pp, _) = b.finish();
            // Integrate the polynomial's end state at the last piece's end.
            let before = pp.eval_axis(pp.end_s() * (1.0 - 1e-12), 0);
            assert!(
                (before[0] - dist).abs() < 1e-9 * dist.max(1.0),
                "{before:?}"
            );
            assert!(before[1].abs() < 1e-6 && before[2].abs() < 1e-3);
            assert!((p.duration_s() - pp.end_s()).abs() < 1e-12);
        }
    }
}
