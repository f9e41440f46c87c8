//! Planning a parsed program: motions with their feeds lowered by look-ahead (corner tolerance,
//! arc limits, blends that fit) and their blend and cruise times (see the module docs).

use std::sync::OnceLock;

use crate::path_index::PathIndex;
use crate::poly::SMOOTHSTEP_PEAK_SLOPE;

use super::parse::{dist3, PathSegment, Program};

/// Peak of `|s''(u)|` of the C5 smoothstep (`s'' = 13860 u^4 (1-u)^4 (1-2u)`).
pub const SMOOTHSTEP_PEAK_CURVATURE: f64 = 11.266_575_215_925;
/// `h(1/2) = int_0^(1/2) s`: the corner is cut by `H_HALF B dv` at mid-blend.
pub const H_HALF: f64 = 0.056_396_484_375;

/// Planner limits (path quantities, m and s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanLimits {
    /// Largest path speed (also the G0 speed), m/s.
    pub max_velocity_m_per_s: f64,
    /// Acceleration budget, m/s^2.
    pub max_accel_m_per_s2: f64,
    /// Jerk budget, m/s^3.
    pub max_jerk_m_per_s3: f64,
    /// Largest corner cut at a blend, m.
    pub corner_tolerance_m: f64,
    /// Shortest blend, s.
    pub min_blend_s: f64,
}

/// Geometry of one planned motion, unit-speed in its arc length.
#[derive(Debug, Clone, Copy)]
pub(super) enum Geom {
    Line {
        p0: [f64; 3],
        u: [f64; 3],
    },
    Arc {
        c: [f64; 2],
        r: f64,
        a0: f64,
        dir: f64,
        z: f64,
    },
}

impl Geom {
    /// Unit tangent at arc length `s`.
    fn tangent(&self, s: f64) -> [f64; 3] {
        match *self {
            Geom::Line { u, .. } => u,
            Geom::Arc { r, a0, dir, .. } => {
                let a = a0 + dir * s / r;
                [-dir * a.sin(), dir * a.cos(), 0.0]
            }
        }
    }

    /// Centripetal acceleration per speed^2 (curvature vector) at `s`.
    fn curvature(&self, s: f64) -> [f64; 3] {
        match *self {
            Geom::Line { .. } => [0.0; 3],
            Geom::Arc { r, a0, dir, .. } => {
                let a = a0 + dir * s / r;
                [-a.cos() / r, -a.sin() / r, 0.0]
            }
        }
    }

    pub(super) fn radius(&self) -> f64 {
        match *self {
            Geom::Line { .. } => f64::INFINITY,
            Geom::Arc { r, .. } => r,
        }
    }
}

/// One planned motion segment: geometry, feed and timing.
#[derive(Debug, Clone, Copy)]
pub(super) struct Motion {
    pub(super) geom: Geom,
    pub(super) len: f64,
    pub(super) feed: f64,
    /// Start time, s.
    pub(super) start: f64,
    /// Acceleration, cruise and deceleration times, s.
    pub(super) acc: f64,
    pub(super) cruise: f64,
    pub(super) dec: f64,
    /// Programmed start point (program coordinates, m).
    pub(super) q0: [f64; 3],
    /// Programmed end point.
    pub(super) q1: [f64; 3],
}

impl Motion {
    pub(super) fn end(&self) -> f64 {
        self.start + self.acc + self.cruise + self.dec
    }
}

/// Largest velocity change at a corner whose cut stays within `tol` (bisection).
fn max_corner_dv(lim: &PlanLimits, a: f64, j: f64) -> f64 {
    let cut = |dv: f64| blend_time(lim, dv, 0.0, a, j) * H_HALF * dv;
    let (mut lo, mut hi) = (0.0, 2.0 * lim.max_velocity_m_per_s);
    if cut(hi) <= lim.corner_tolerance_m {
        return hi;
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if cut(mid) <= lim.corner_tolerance_m {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// Blend time for a velocity change `dv` and centripetal change `da`.
fn blend_time(lim: &PlanLimits, dv: f64, da: f64, a: f64, j: f64) -> f64 {
    (SMOOTHSTEP_PEAK_SLOPE * dv / a)
        .max((SMOOTHSTEP_PEAK_CURVATURE * dv / j).sqrt())
        .max(SMOOTHSTEP_PEAK_SLOPE * da / j)
        .max(lim.min_blend_s)
}

fn norm3(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The part of the velocity change at the corner `a` -> `b` across the mean direction of travel
/// (what cuts the corner; a collinear speed change cuts nothing), m/s.
fn perpendicular_dv(a: &Motion, b: &Motion) -> f64 {
    let ta = a.geom.tangent(a.len);
    let tb = b.geom.tangent(0.0);
    let dv = [0, 1, 2].map(|k| b.feed * tb[k] - a.feed * ta[k]);
    let mean = [0, 1, 2].map(|k| ta[k] + tb[k]);
    let ml = norm3(mean);
    if ml < 1e-9 {
        return norm3(dv);
    }
    let along = (0..3).map(|k| dv[k] * mean[k] / ml).sum::<f64>();
    let perp = [0, 1, 2].map(|k| dv[k] - along * mean[k] / ml);
    norm3(perp)
}

/// The speed at the corner between `a` and `b` (same speed on both sides) whose cut stays within
/// the tolerance, capped by both feeds.
fn corner_speed(lim: &PlanLimits, a: &Motion, b: &Motion) -> f64 {
    let ta = a.geom.tangent(a.len);
    let tb = b.geom.tangent(0.0);
    let du = norm3([0, 1, 2].map(|k| tb[k] - ta[k]));
    let arc = a.geom.radius().is_finite() || b.geom.radius().is_finite();
    let (acc, jerk) = if arc {
        (0.5 * lim.max_accel_m_per_s2, 0.5 * lim.max_jerk_m_per_s3)
    } else {
        (lim.max_accel_m_per_s2, lim.max_jerk_m_per_s3)
    };
    let cap = a.feed.min(b.feed);
    if du < 1e-12 {
        return cap;
    }
    (max_corner_dv(lim, acc, jerk) / du).min(cap)
}

/// The part of line motion `m` from arc length `s0` to `s1`, at `feed`.
fn sub_line(m: &Motion, s0: f64, s1: f64, feed: f64) -> Motion {
    let Geom::Line { p0, u } = m.geom else {
        return *m;
    };
    let a = [0, 1, 2].map(|k| p0[k] + u[k] * s0);
    let b = [0, 1, 2].map(|k| p0[k] + u[k] * s1);
    Motion {
        geom: Geom::Line { p0: a, u },
        len: s1 - s0,
        feed,
        q0: a,
        q1: b,
        ..*m
    }
}

fn split_for_corners(
    motions: Vec<Motion>,
    gaps: Vec<f64>,
    lim: &PlanLimits,
) -> (Vec<Motion>, Vec<f64>) {
    let n = motions.len();
    let joined = |i: usize| i + 1 < n && gaps[i + 1] == 0.0;
    let mut out = Vec::with_capacity(n);
    let mut out_gaps = Vec::with_capacity(n);
    for (i, m) in motions.iter().enumerate() {
        let is_line = matches!(m.geom, Geom::Line { .. });
        let v_in = (i > 0 && joined(i - 1)).then(|| corner_speed(lim, &motions[i - 1], m));
        let v_out = joined(i).then(|| corner_speed(lim, m, &motions[i + 1]));
        let slow = |v: Option<f64>| v.filter(|v| *v < 0.95 * m.feed);
        let (v_in, v_out) = (slow(v_in), slow(v_out));
        if !is_line || (v_in.is_none() && v_out.is_none()) {
            out.push(*m);
            out_gaps.push(gaps[i]);
            continue;
        }
        // Length of an end piece at corner speed v: half the collinear blend from the feed plus
        // half the corner blend, with 10 % to spare.
        let piece = |v: f64| {
            let coll = blend_time(
                lim,
                m.feed - v,
                0.0,
                lim.max_accel_m_per_s2,
                lim.max_jerk_m_per_s3,
            );
            let corner = blend_time(
                lim,
                max_corner_dv(lim, lim.max_accel_m_per_s2, lim.max_jerk_m_per_s3),
                0.0,
                0.5 * lim.max_accel_m_per_s2,
                0.5 * lim.max_jerk_m_per_s3,
            );
            1.1 * 0.5 * v * (coll + corner)
        };
        let body_blend = |v: Option<f64>| {
            v.map_or(0.0, |v| {
                blend_time(
                    lim,
                    m.feed - v,
                    0.0,
                    lim.max_accel_m_per_s2,
                    lim.max_jerk_m_per_s3,
                )
            })
        };
        let l_in = v_in.map_or(0.0, piece);
        let l_out = v_out.map_or(0.0, piece);
        let body = m.len - l_in - l_out;
        let body_need = m.feed * 0.5 * (body_blend(v_in) + body_blend(v_out));
        if body <= body_need {
            out.push(*m);
            out_gaps.push(gaps[i]);
            continue;
        }
        let mut gap = gaps[i];
        if let Some(v) = v_in {
            out.push(sub_line(m, 0.0, l_in, v));
            out_gaps.push(gap);
            gap = 0.0;
        }
        out.push(sub_line(m, l_in, m.len - l_out, m.feed));
        out_gaps.push(gap);
        if let Some(v) = v_out {
            out.push(sub_line(m, m.len - l_out, m.len, v));
            out_gaps.push(0.0);
        }
    }
    (out, out_gaps)
}

/// The program's motions at their programmed feeds (capped by the velocity limit and, on arcs,
/// by `F^2 / R <= a/2` and `F^3 / R^2 <= j/2`), not yet timed; the dwell before each motion;
/// and the dwell after the last one.
fn unplanned_motions(program: &Program, lim: &PlanLimits) -> (Vec<Motion>, Vec<f64>, f64) {
    // Motions and chain breaks (dwells) in order.
    let mut motions: Vec<Motion> = Vec::new();
    let mut gaps: Vec<f64> = Vec::new(); // dwell before motion i
    let mut pending = 0.0;
    let mut trailing = 0.0;
    for s in &program.segments {
        let (geom, q0, q1, feed) = match *s {
            PathSegment::Dwell { duration_s, .. } => {
                pending += duration_s;
                continue;
            }
            PathSegment::Line {
                from_m,
                to_m,
                feed_m_per_s,
                ..
            } => {
                let l = dist3(&from_m, &to_m);
                let u = [0, 1, 2].map(|k| (to_m[k] - from_m[k]) / l);
                (Geom::Line { p0: from_m, u }, from_m, to_m, feed_m_per_s)
            }
            PathSegment::Arc {
                center_m,
                radius_m,
                start_angle_rad,
                sweep_rad,
                z_m,
                feed_m_per_s,
                ..
            } => {
                let e = start_angle_rad + sweep_rad;
                (
                    Geom::Arc {
                        c: center_m,
                        r: radius_m,
                        a0: start_angle_rad,
                        dir: sweep_rad.signum(),
                        z: z_m,
                    },
                    [
                        center_m[0] + radius_m * start_angle_rad.cos(),
                        center_m[1] + radius_m * start_angle_rad.sin(),
                        z_m,
                    ],
                    [
                        center_m[0] + radius_m * e.cos(),
                        center_m[1] + radius_m * e.sin(),
                        z_m,
                    ],
                    feed_m_per_s,
                )
            }
        };
        let mut f = feed.min(lim.max_velocity_m_per_s);
        let r = geom.radius();
        if r.is_finite() {
            f = f
                .min((0.5 * lim.max_accel_m_per_s2 * r).sqrt())
                .min((0.5 * lim.max_jerk_m_per_s3 * r * r).cbrt());
        }
        gaps.push(pending);
        pending = 0.0;
        motions.push(Motion {
            geom,
            len: s.length_m(),
            feed: f,
            start: 0.0,
            acc: 0.0,
            cruise: 0.0,
            dec: 0.0,
            q0,
            q1,
        });
    }
    trailing += pending;
    (motions, gaps, trailing)
}

/// The motions of a program being planned: which corners join two motions and which motions
/// are arcs (both fixed once the lines are split for their corners).
struct Chain {
    lim: PlanLimits,
    n: usize,
    /// Corner i (between motion i and i+1) is a blend; false at a chain break (dwell).
    joined: Vec<bool>,
    is_arc: Vec<bool>,
}

impl Chain {
    fn new(motions: &[Motion], gaps: &[f64], lim: PlanLimits) -> Self {
        let n = motions.len();
        // Corner i is between motion i and i+1 (None at a chain break).
        let joined: Vec<bool> = (0..n.saturating_sub(1))
            .map(|i| gaps[i + 1] == 0.0)
            .collect();
        let is_arc: Vec<bool> = motions
            .iter()
            .map(|m| m.geom.radius().is_finite())
            .collect();
        Self {
            lim,
            n,
            joined,
            is_arc,
        }
    }

    /// Acceleration and jerk budgets at corner `i`.
    fn budgets(&self, i: usize) -> (f64, f64) {
        let (lim, n) = (&self.lim, self.n);
        // Halve the budgets where an arc takes part.
        let arc = |k: usize| k < n && self.is_arc[k];
        if arc(i) || arc(i + 1) {
            (0.5 * lim.max_accel_m_per_s2, 0.5 * lim.max_jerk_m_per_s3)
        } else {
            (lim.max_accel_m_per_s2, lim.max_jerk_m_per_s3)
        }
    }

    /// Velocity change and centripetal acceleration change at corner `i`.
    fn corner(m: &[Motion], i: usize) -> (f64, f64) {
        let (a, b) = (&m[i], &m[i + 1]);
        let ta = a.geom.tangent(a.len);
        let tb = b.geom.tangent(0.0);
        let ka = a.geom.curvature(a.len);
        let kb = b.geom.curvature(0.0);
        let dv = norm3([0, 1, 2].map(|k| b.feed * tb[k] - a.feed * ta[k]));
        let da = norm3([0, 1, 2].map(|k| b.feed * b.feed * kb[k] - a.feed * a.feed * ka[k]));
        (dv, da)
    }

    /// Ramp time from or to rest of motion `m`.
    fn ramp(&self, m: &Motion, arc_budget: bool) -> f64 {
        let lim = &self.lim;
        let (a, j) = if arc_budget {
            (0.5 * lim.max_accel_m_per_s2, 0.5 * lim.max_jerk_m_per_s3)
        } else {
            (lim.max_accel_m_per_s2, lim.max_jerk_m_per_s3)
        };
        let da = m.feed * m.feed / m.geom.radius();
        blend_time(lim, m.feed, da, a, j)
    }

    /// Blend times from the current feeds; sets acc/dec/cruise; returns the segments whose
    /// blends do not fit in them (with the length they would need).
    fn assign(&self, motions: &mut [Motion]) -> Vec<(usize, f64)> {
        let (lim, n, joined) = (&self.lim, self.n, &self.joined);
        let arc = |m: &Motion| m.geom.radius().is_finite();
        let blends: Vec<f64> = (0..n.saturating_sub(1))
            .map(|i| {
                if joined[i] {
                    let (a, j) = self.budgets(i);
                    let (dv, da) = Self::corner(motions, i);
                    blend_time(lim, dv, da, a, j)
                } else {
                    0.0
                }
            })
            .collect();
        let mut bad = Vec::new();
        for i in 0..n {
            let acc = if i == 0 || !joined[i - 1] {
                self.ramp(&motions[i], arc(&motions[i]))
            } else {
                blends[i - 1]
            };
            let dec = if i == n - 1 || !joined[i] {
                self.ramp(&motions[i], arc(&motions[i]))
            } else {
                blends[i]
            };
            let m = &mut motions[i];
            m.acc = acc;
            m.dec = dec;
            let need = m.feed * 0.5 * (acc + dec);
            m.cruise = ((m.len - need) / m.feed).max(0.0);
            if need > m.len * (1.0 + 1e-12) {
                bad.push((i, need));
            }
        }
        bad
    }

    /// Look-ahead: lowers feeds until every corner is within tolerance and every segment holds
    /// its blends (feeds only decrease, so this terminates), and sets the blend times.
    fn look_ahead(&self, motions: &mut [Motion]) {
        let (lim, n, joined) = (&self.lim, self.n, &self.joined);
        for _ in 0..2000 {
            let mut changed = false;
            for i in 0..n.saturating_sub(1) {
                if !joined[i] {
                    continue;
                }
                let (a, j) = self.budgets(i);
                let (dv, da) = Self::corner(motions, i);
                let cut = blend_time(lim, dv, da, a, j)
                    * H_HALF
                    * perpendicular_dv(&motions[i], &motions[i + 1]);
                if cut > lim.corner_tolerance_m * (1.0 + 1e-9) {
                    let k = (lim.corner_tolerance_m / cut).sqrt().min(0.999);
                    motions[i].feed *= k;
                    motions[i + 1].feed *= k;
                    changed = true;
                }
            }
            for (i, need) in self.assign(motions) {
                let m = &mut motions[i];
                m.feed *= 0.9f64.max((m.len / need).sqrt()).min(0.99);
                changed = true;
            }
            if !changed {
                break;
            }
        }
        // Should the iteration limit be hit, squeeze the cruise out of what does not fit.
        for (i, _) in self.assign(motions) {
            let m = &mut motions[i];
            m.feed = m.len / (0.5 * (m.acc + m.dec));
            m.cruise = 0.0;
        }
    }

    /// Sets the start times (a chain starts after its dwell; a blended motion starts when the
    /// one before begins to decelerate); returns the end of the last motion.
    fn timing(&self, motions: &mut [Motion], gaps: &[f64], delay_s: f64) -> f64 {
        let joined = &self.joined;
        let mut t = delay_s;
        for i in 0..self.n {
            if i == 0 || !joined[i - 1] {
                t += gaps[i];
                motions[i].start = t;
            } else {
                motions[i].start = motions[i - 1].end() - motions[i - 1].dec;
            }
            t = motions[i].end();
        }
        t
    }
}

/// A planned program (kind `program`).
pub struct ProgramTrajectory {
    pub(super) axes: Vec<String>,
    /// Job axis index of program X, Y, Z.
    pub(super) map: [Option<usize>; 3],
    /// Machine position of program zero, per job axis.
    pub(super) origin: Vec<f64>,
    pub(super) motions: Vec<Motion>,
    pub(super) ends: Vec<f64>,
    pub(super) duration_s: f64,
    pub(super) program: Program,
    pub(super) delay_s: f64,
    /// The commanded X-Y path as chords, built on the first contour query.
    pub(super) path_index: OnceLock<PathIndex>,
}

impl ProgramTrajectory {
    /// Plans `program` with `limits`. `map[k]` is the job axis of program X, Y, Z; `origin` the
    /// machine position (per job axis, m) of program zero; motion starts after `delay_s` and the
    /// end is held `after_s` more.
    pub fn plan(
        program: Program,
        axes: &[String],
        map: [Option<usize>; 3],
        origin: Vec<f64>,
        limits: PlanLimits,
        delay_s: f64,
        after_s: f64,
    ) -> Self {
        let lim = limits;
        let (motions, gaps, trailing) = unplanned_motions(&program, &lim);
        let n = motions.len();
        if n == 0 {
            return ProgramTrajectory {
                axes: axes.to_vec(),
                map,
                origin,
                motions,
                ends: Vec::new(),
                duration_s: delay_s + trailing + after_s,
                program,
                delay_s,
                path_index: OnceLock::new(),
            };
        }
        // Split lines whose feed is above what their corners allow into a body at the feed and
        // short collinear end pieces at the corner speed: a collinear blend changes the speed
        // without leaving the line, so a long line slows down only near its corners.
        let (motions, gaps) = split_for_corners(motions, gaps, &lim);
        let mut motions = motions;
        let chain = Chain::new(&motions, &gaps, lim);
        chain.look_ahead(&mut motions);
        let t = chain.timing(&mut motions, &gaps, delay_s);
        let ends: Vec<f64> = motions.iter().map(Motion::end).collect();
        let duration_s = t + trailing + after_s;
        ProgramTrajectory {
            axes: axes.to_vec(),
            map,
            origin,
            motions,
            ends,
            duration_s,
            program,
            delay_s,
            path_index: OnceLock::new(),
        }
    }

    /// The parsed program (programmed geometry, program coordinates).
    pub fn program(&self) -> &Program {
        &self.program
    }

    /// Planned cruise feed of each motion segment, m/s (after look-ahead).
    pub fn planned_feeds_m_per_s(&self) -> Vec<f64> {
        self.motions.iter().map(|m| m.feed).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcode::tests::{build_program, parse, write_job_dir, PART};
    use crate::poly::{taylor_at, SMOOTHSTEP_INTEGRAL};
    use crate::test_util::*;

    #[test]
    fn the_smoothstep_constants_are_its_peak_curvature_and_half_integral() {
        let n = 100_000;
        let peak = (0..=n)
            .map(|i| crate::poly::smoothstep(i as f64 / n as f64)[2].abs())
            .fold(0.0, f64::max);
        assert!((peak - SMOOTHSTEP_PEAK_CURVATURE).abs() < 1e-6);
        assert!((taylor_at(&SMOOTHSTEP_INTEGRAL, 0.5)[0] - H_HALF).abs() < 1e-15);
    }

    #[test]
    fn a_planned_program_stays_within_its_limits_and_tolerance() {
        let dir = write_job_dir("limits", PART);
        let tr = build_program(&dir, "corner_tolerance_m = 2e-5\n", &["x", "y"]).unwrap();
        let prog = {
            let t = std::fs::read_to_string(dir.join("part.nc")).unwrap();
            parse(&t).unwrap()
        };
        let (mut vmax, mut amax, mut jmax, mut dev): (f64, f64, f64, f64) = (0.0, 0.0, 0.0, 0.0);
        let n = 40_000;
        for k in 0..=n {
            let t = tr.duration_s() * k as f64 / n as f64;
            let s = at(tr.as_ref(), t);
            vmax = vmax.max(s[0][1].hypot(s[1][1]));
            amax = amax.max(s[0][2].hypot(s[1][2]));
            jmax = jmax.max(s[0][3].hypot(s[1][3]));
            dev = dev.max(prog.distance_xy_m([s[0][0], s[1][0]]));
        }
        eprintln!("vmax {vmax} amax {amax} jmax {jmax} deviation {dev}");
        assert!(vmax <= 0.03 + 1e-9, "F1800 = 0.03 m/s: {vmax}");
        assert!(vmax > 0.029, "reaches the feed on the long lines: {vmax}");
        assert!(amax <= 1.0 * 1.05, "{amax}");
        assert!(jmax <= 100.0 * 1.1, "{jmax}");
        assert!(dev <= 2e-5 * 1.05, "corner cut {dev}");
        // Ends exactly at the last programmed point and holds.
        let end = at(tr.as_ref(), tr.duration_s() + 1.0);
        assert!((end[0][0] - 0.01).abs() < 1e-12 && end[1][0].abs() < 1e-12);
        check_final_hold(tr.as_ref());
        std::fs::remove_dir_all(&dir).ok();
    }
}
