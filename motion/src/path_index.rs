//! An index of a trajectory's commanded path in the plane of two axes, for the distance from a
//! measured point to that path: the contour error of a general 2-D path (a part program).
//!
//! Newton's method on the time parameter, started at the current command, is not enough: the
//! measured point lags the command by the loop's following error (v / Kp, hundreds of um on a
//! plain P/PI cascade), and between the two the path may turn a corner (the squared distance is
//! then concave in time), rest at a dwell (zero velocity: no gradient at all) or reverse.
//!
//! The index samples the commanded path once (step control keeps every sample interval within
//! [`CHORD_TOL_M`] of its chord), and merges runs of samples that advance monotonically along a
//! straight line within [`CHORD_TOL_M`] into chords; rests collapse into a zero-length chord. A
//! query for the point `p` at time `t`:
//! 1. measures `p` against every chord that overlaps the time window
//!    `[t - WINDOW_BEHIND_S, t + WINDOW_AHEAD_S]` (point-to-segment distance);
//! 2. refines every chord within `3 CHORD_TOL_M` of the best (the path lies within about
//!    `1.25 CHORD_TOL_M` of its chords) on the exact trajectory: inside a
//!    chord the path advances monotonically along the chord's direction `u`, so
//!    `h(tau) = (c(tau) - p) . u` has one root in time (safeguarded Newton on a bracket), and
//!    Newton steps on the perpendicularity condition `(c - p) . c' = 0` then land on the foot
//!    of the perpendicular, accepted only while the distance falls.
//!
//! The result is the distance to the nearest point of the commanded path in the window, exact to
//! the trajectory's own rounding, signed positive to the left of the direction of travel. Where
//! the path passes the same place twice (a reversal along a line) the pass nearest in time to the
//! command gives the sign (feet within 1 nm of each other are a tie).

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::MAX_AXES;

use super::Trajectory;

/// Largest distance between the commanded path and a chord of the index, m.
pub const CHORD_TOL_M: f64 = 1e-6;
/// How far back in time from the current command the path is searched, s.
pub const WINDOW_BEHIND_S: f64 = 2.0;
/// How far ahead of the current command the path is searched, s.
pub const WINDOW_AHEAD_S: f64 = 0.5;
/// Longest sampling step, s.
const MAX_STEP_S: f64 = 1e-3;
/// Shortest sampling step, s.
const MIN_STEP_S: f64 = 1e-7;
/// Most samples merged into one chord (bounds the merge cost per sample).
const MAX_RUN: usize = 256;
/// The projection root is accepted within this distance along the chord, m.
const ROOT_TOL_M: f64 = 1e-13;
/// Feet whose distances differ by less than this are a tie, won by the one nearest in time to
/// the command: a reversal along a line passes the same place twice in opposite directions, and
/// a blend nearby can make the later pass nearer by a fraction of a nanometre, m.
const TIE_M: f64 = 1e-9;

/// The commanded path of two axes of a trajectory as time-stamped chords.
#[derive(Debug, Clone)]
pub struct PathIndex {
    axes: [usize; 2],
    /// Knot times, s (non-decreasing); chord `i` runs from knot `i` to knot `i + 1`.
    t: Vec<f64>,
    /// Knot points (the exact commanded positions at the knot times), m.
    p: Vec<[f64; 2]>,
}

/// Position, velocity and acceleration of the two axes at one time.
#[derive(Debug, Clone, Copy)]
struct PathPoint {
    pos: [f64; 2],
    vel: [f64; 2],
    acc: [f64; 2],
}

fn eval_point<T: Trajectory + ?Sized>(traj: &T, axes: [usize; 2], tau: f64) -> PathPoint {
    let n = traj.axes().len().min(MAX_AXES);
    let mut buf = [[0.0; REF_DERIVS]; MAX_AXES];
    traj.eval(tau, &mut buf[..n]);
    let (x, y) = (buf[axes[0]], buf[axes[1]]);
    PathPoint {
        pos: [x[0], y[0]],
        vel: [x[1], y[1]],
        acc: [x[2], y[2]],
    }
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

/// Distance from `p` to the segment `a`-`b` (m, or whatever unit the points are in).
pub(crate) fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let d = sub(b, a);
    let l2 = dot(d, d);
    let w = sub(p, a);
    let s = if l2 > 0.0 {
        (dot(w, d) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (w[0] - s * d[0]).hypot(w[1] - s * d[1])
}

/// Whether the samples `run[1..]` lie within `tol` of the chord `run[0]`-`last` and advance
/// monotonically along it.
fn fits(run: &[[f64; 2]], last: [f64; 2], tol: f64) -> bool {
    let a = run[0];
    let d = sub(last, a);
    let l2 = dot(d, d);
    if l2 == 0.0 {
        // A rest: only samples at the same point belong to it.
        return run.iter().all(|q| *q == a);
    }
    let len = l2.sqrt();
    let u = [d[0] / len, d[1] / len];
    let mut prev = 0.0;
    for q in &run[1..] {
        let w = sub(*q, a);
        let along = dot(w, u);
        let across = w[0] * u[1] - w[1] * u[0];
        if across.abs() > tol || along < prev - tol || along > len + tol {
            return false;
        }
        prev = prev.max(along);
    }
    true
}

impl PathIndex {
    /// Samples the commanded path of `axes` (job axis indices) of `traj` over its whole
    /// duration. The trajectory's [`Trajectory::breakpoints_s`] (motion starts and ends, blend
    /// limits) are always sampled, so a short blend or a rest is never stepped over.
    pub fn build<T: Trajectory + ?Sized>(traj: &T, axes: [usize; 2]) -> Self {
        let end = traj.duration_s().max(0.0);
        let mut bps: Vec<f64> = traj
            .breakpoints_s()
            .into_iter()
            .filter(|b| b.is_finite() && *b > 0.0 && *b < end)
            .collect();
        bps.sort_by(f64::total_cmp);
        let mut index = PathIndex {
            axes,
            t: Vec::new(),
            p: Vec::new(),
        };
        let mut run_t: Vec<f64> = Vec::with_capacity(MAX_RUN + 1);
        let mut run_p: Vec<[f64; 2]> = Vec::with_capacity(MAX_RUN + 1);
        let mut next_bp = 0;
        let mut tau = 0.0;
        let mut cur = eval_point(traj, axes, tau);
        index.t.push(tau);
        index.p.push(cur.pos);
        run_t.push(tau);
        run_p.push(cur.pos);
        while tau < end {
            while next_bp < bps.len() && bps[next_bp] <= tau {
                next_bp += 1;
            }
            let limit = bps.get(next_bp).copied().unwrap_or(end).min(end);
            // Step from the acceleration (the chord of a curve with normal acceleration a over
            // dt is off by at most a dt^2 / 8), then halve until the midpoint agrees.
            let a = cur.acc[0].hypot(cur.acc[1]);
            let mut dt = if a > 0.0 {
                (8.0 * CHORD_TOL_M / a).sqrt()
            } else {
                MAX_STEP_S
            }
            .clamp(MIN_STEP_S, MAX_STEP_S);
            let (next_tau, next) = loop {
                let cand = (tau + dt).min(limit);
                let next = eval_point(traj, axes, cand);
                if cand - tau <= MIN_STEP_S {
                    break (cand, next);
                }
                let mid = eval_point(traj, axes, 0.5 * (tau + cand));
                if segment_distance(mid.pos, cur.pos, next.pos) <= 0.25 * CHORD_TOL_M {
                    break (cand, next);
                }
                dt = 0.5 * (cand - tau);
            };
            tau = next_tau;
            cur = next;
            if run_p.len() < MAX_RUN && fits(&run_p, cur.pos, CHORD_TOL_M) {
                run_t.push(tau);
                run_p.push(cur.pos);
                continue;
            }
            // Close the chord at the last sample that fitted and start the next one there.
            let (kt, kp) = (run_t[run_t.len() - 1], run_p[run_p.len() - 1]);
            index.t.push(kt);
            index.p.push(kp);
            run_t.clear();
            run_p.clear();
            run_t.extend([kt, tau]);
            run_p.extend([kp, cur.pos]);
        }
        if run_t.len() > 1 {
            index.t.push(run_t[run_t.len() - 1]);
            index.p.push(run_p[run_p.len() - 1]);
        }
        index.t.shrink_to_fit();
        index.p.shrink_to_fit();
        index
    }

    /// Signed distance (m) from `p` to the commanded path between `t_s - WINDOW_BEHIND_S` and
    /// `t_s + WINDOW_AHEAD_S`, positive to the left of the direction of travel; `traj` must be
    /// the trajectory the index was built from. No allocation.
    pub fn distance_m<T: Trajectory + ?Sized>(&self, traj: &T, t_s: f64, p: [f64; 2]) -> f64 {
        let n = self.t.len();
        if n == 0 || !(p[0].is_finite() && p[1].is_finite()) {
            return f64::NAN;
        }
        if n == 1 {
            return (p[0] - self.p[0][0]).hypot(p[1] - self.p[0][1]);
        }
        let t = if t_s.is_finite() { t_s } else { 0.0 };
        let (lo, hi) = (t - WINDOW_BEHIND_S, t + WINDOW_AHEAD_S);
        // First chord whose end is at or after `lo`; the window always holds at least one chord
        // (the one nearest in time).
        let first = self
            .t
            .partition_point(|x| *x < lo)
            .saturating_sub(1)
            .min(n - 2);
        let chords = || (first..n - 1).take_while(move |&i| i == first || self.t[i] <= hi);
        let mut best = f64::INFINITY;
        for i in chords() {
            best = best.min(segment_distance(p, self.p[i], self.p[i + 1]));
        }
        // (distance, side, time of the foot); where the path passes the same place twice
        // (a reversal along a line) the pass nearest in time to the command wins the tie
        let mut result = (f64::INFINITY, 0.0f64, f64::INFINITY);
        for i in chords() {
            if segment_distance(p, self.p[i], self.p[i + 1]) <= best + 3.0 * CHORD_TOL_M {
                let (d, side, tau) = self.refine(traj, i, p, lo, hi);
                let tie = (d - result.0).abs() <= TIE_M;
                if (d < result.0 && !tie) || (tie && (tau - t).abs() < (result.2 - t).abs()) {
                    result = (d, side, tau);
                }
            }
        }
        if result.1 < 0.0 {
            -result.0
        } else {
            result.0
        }
    }

    /// Nearest point of the exact path inside chord `i` and the time window `[lo, hi]`:
    /// (distance, side, time of the foot), side > 0 when `p` is to the left of the direction of
    /// travel.
    fn refine<T: Trajectory + ?Sized>(
        &self,
        traj: &T,
        i: usize,
        p: [f64; 2],
        lo: f64,
        hi: f64,
    ) -> (f64, f64, f64) {
        let (mut ta, mut tb) = (self.t[i], self.t[i + 1]);
        let (mut a, mut b) = (self.p[i], self.p[i + 1]);
        let d = sub(b, a);
        let len = dot(d, d).sqrt();
        if len == 0.0 {
            // A rest: the distance to its point, the side from the nearest moving chord.
            let dist = (p[0] - a[0]).hypot(p[1] - a[1]);
            return (dist, self.side_near(i, p, a), ta.max(lo).min(hi));
        }
        let u = [d[0] / len, d[1] / len];
        // Only the part of the chord inside the window counts (the path still advances along
        // `u` there).
        if ta < lo && lo < tb {
            ta = lo;
            a = eval_point(traj, self.axes, ta).pos;
        }
        if tb > hi && hi > ta {
            tb = hi;
            b = eval_point(traj, self.axes, tb).pos;
        }
        let h = |q: [f64; 2]| dot(sub(q, p), u);
        let (ha, hb) = (h(a), h(b));
        let mut tau;
        let mut pt;
        if ha >= 0.0 {
            tau = ta;
            pt = eval_point(traj, self.axes, ta);
        } else if hb <= 0.0 {
            tau = tb;
            pt = eval_point(traj, self.axes, tb);
        } else {
            // h rises monotonically from ha < 0 to hb > 0: safeguarded Newton on [lo, hi].
            let (mut lo, mut hi) = (ta, tb);
            tau = ta + (tb - ta) * (-ha / (hb - ha));
            pt = eval_point(traj, self.axes, tau);
            for _ in 0..60 {
                let hv = h(pt.pos);
                if hv.abs() <= ROOT_TOL_M {
                    break;
                }
                if hv < 0.0 {
                    lo = tau;
                } else {
                    hi = tau;
                }
                let slope = dot(pt.vel, u);
                let newton = tau - hv / slope;
                let next = if slope > 0.0 && newton > lo && newton < hi {
                    newton
                } else {
                    0.5 * (lo + hi)
                };
                if next == tau {
                    break;
                }
                tau = next;
                pt = eval_point(traj, self.axes, tau);
            }
        }
        // Polish: Newton on (c - p) . c' = 0, accepted while the distance falls.
        let dist2 = |q: &PathPoint| {
            let w = sub(q.pos, p);
            dot(w, w)
        };
        let mut d2 = dist2(&pt);
        for _ in 0..4 {
            let w = sub(pt.pos, p);
            let g = dot(w, pt.vel);
            let g2 = dot(pt.vel, pt.vel) + dot(w, pt.acc);
            if g == 0.0 || g2 <= 0.0 || !g2.is_finite() {
                break;
            }
            let cand = (tau - g / g2).clamp(ta, tb);
            if cand == tau {
                break;
            }
            let q = eval_point(traj, self.axes, cand);
            let qd2 = dist2(&q);
            if qd2 >= d2 {
                break;
            }
            (tau, pt, d2) = (cand, q, qd2);
        }
        let speed2 = dot(pt.vel, pt.vel);
        let tangent = if speed2 > 0.0 { pt.vel } else { u };
        let w = sub(p, pt.pos);
        let side = tangent[0] * w[1] - tangent[1] * w[0];
        (d2.sqrt(), side, tau)
    }

    /// Side of `p` relative to the direction of travel near the rest at chord `i` (point `at`):
    /// from the nearest chord before it that moves, else the nearest after it.
    fn side_near(&self, i: usize, p: [f64; 2], at: [f64; 2]) -> f64 {
        let moving = |j: usize| self.p[j] != self.p[j + 1];
        let j = (0..i)
            .rev()
            .find(|&j| moving(j))
            .or_else(|| (i + 1..self.t.len() - 1).find(|&j| moving(j)));
        match j {
            Some(j) => {
                let d = sub(self.p[j + 1], self.p[j]);
                let w = sub(p, at);
                d[0] * w[1] - d[1] * w[0]
            }
            None => 0.0,
        }
    }
}
