//! Kind `program`: a small G-code subset planned into a C5-blended trajectory with look-ahead.
//!
//! # Language
//! `G0` rapid, `G1` line, `G2`/`G3` cw/ccw arc in the X-Y plane with centre offsets `I`, `J`
//! (incremental from the arc's start; end point = start gives a full circle), `G4 P<s>` dwell
//! (seconds), `G17` (X-Y plane, the only one), `G21` (mm, the only unit), `G90`/`G91`
//! absolute/incremental, `F` feed in mm/min, `X Y Z` in mm, `N` line numbers (ignored), `M2`/`M30`
//! end of program, comments in `( )` and after `;`, `%` lines ignored. Anything else is refused
//! with the file, the line and the word.
//!
//! # Planning (velocity blending)
//! Each motion segment `i` (length `L_i`, unit-speed path `P_i(sigma)`) is traversed by an
//! arc-length profile `sigma_i(t)`: speed `F_i s(u)` over `A_i`, `F_i` for `C_i`, `F_i (1 - s(u))`
//! over `D_i`, so `L_i = F_i (A_i/2 + C_i + D_i/2)`. The deceleration of segment `i` and the
//! acceleration of segment `i+1` run at the same time (`D_i = A_(i+1) = B_i`); the command is the
//! sum of the segments' displacements:
//!
//! `p(t) = Q_i + [P_i(sigma_i(t)) - P_i(0)] + [P_(i+1)(sigma_(i+1)(t)) - P_(i+1)(0)]`
//!
//! where `Q_i` is the programmed start of the earliest unfinished segment. In a blend the velocity
//! moves from `F_i T_i` to `F_(i+1) T_(i+1)` along `s(u)`: collinear segments join at exactly the
//! feed, corners are rounded. Every term is C5, so position and derivatives 1..5 are continuous;
//! derivatives come from jets ([`super::jet`]) of `sigma_i` through the line or arc geometry.
//!
//! With the velocity change `dv = |F_(i+1) T_(i+1) - F_i T_i|` at a corner, the blend time is
//! `B >= max(2.707 dv / a, sqrt(11.27 dv / j), 2.707 da / j, 4 periods)` (`a`, `j` the
//! acceleration and jerk budgets, `da` the change of centripetal acceleration), and the corner
//! is cut by `0.0564 B dv` (the path at mid-blend). Look-ahead lowers the feeds on both sides of a
//! corner until that deviation is within `corner_tolerance_m`, lowers the feed on arcs to
//! `F^2 / R <= a/2` and `F^3 / R^2 <= j/2`, and lowers a segment's feed until its blends fit in
//! it (`C_i >= 0`). Where an arc meets a blend the tangential budget is halved. A dwell (or the
//! program's start and end) brings the path to rest.
//!
//! The commanded path (the blended one) is a [`ContourShape::Path`]: contour error = distance from
//! the measured point to it, searched over the path around the current command
//! ([`super::path_index`]); the programmed geometry is [`Program::segments`].

use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::jet::{self, Jet};
use super::path_index::{segment_distance, PathIndex};
use super::poly::{taylor_at, SMOOTHSTEP_INTEGRAL, SMOOTHSTEP_PEAK_SLOPE};
use super::{per_axis, Contour, ContourShape, Ctx, RefState, Trajectory};

/// Peak of `|s''(u)|` of the C5 smoothstep (`s'' = 13860 u^4 (1-u)^4 (1-2u)`).
pub const SMOOTHSTEP_PEAK_CURVATURE: f64 = 11.266_575_215_925;
/// `h(1/2) = int_0^(1/2) s`: the corner is cut by `H_HALF B dv` at mid-blend.
pub const H_HALF: f64 = 0.056_396_484_375;

/// A G-code error: file, 1-based line and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: line {line}: {reason}", path.display())]
pub struct GcodeError {
    /// The program file.
    pub path: PathBuf,
    /// 1-based line number.
    pub line: usize,
    /// What is wrong.
    pub reason: String,
}

/// One programmed segment, in metres and seconds (program coordinates).
#[derive(Debug, Clone, PartialEq)]
pub enum PathSegment {
    /// A straight line (G0/G1).
    Line {
        /// Start `[x, y, z]`, m.
        from_m: [f64; 3],
        /// End `[x, y, z]`, m.
        to_m: [f64; 3],
        /// Programmed feed, m/s (`inf` for G0: the planner's velocity limit).
        feed_m_per_s: f64,
        /// Source line.
        line: usize,
    },
    /// A circular arc in the X-Y plane at constant Z (G2/G3).
    Arc {
        /// Centre `[x, y]`, m.
        center_m: [f64; 2],
        /// Radius, m.
        radius_m: f64,
        /// Angle of the start point, rad.
        start_angle_rad: f64,
        /// Signed sweep, rad (positive ccw/G3, negative cw/G2).
        sweep_rad: f64,
        /// Z, m.
        z_m: f64,
        /// Programmed feed, m/s.
        feed_m_per_s: f64,
        /// Source line.
        line: usize,
    },
    /// A dwell (G4), s.
    Dwell {
        /// Duration, s.
        duration_s: f64,
        /// Source line.
        line: usize,
    },
}

impl PathSegment {
    /// Path length, m (0 for a dwell).
    pub fn length_m(&self) -> f64 {
        match self {
            PathSegment::Line { from_m, to_m, .. } => dist3(from_m, to_m),
            PathSegment::Arc {
                radius_m,
                sweep_rad,
                ..
            } => radius_m * sweep_rad.abs(),
            PathSegment::Dwell { .. } => 0.0,
        }
    }

    /// Distance (m) from `p = [x, y]` to the segment's X-Y projection.
    pub fn distance_xy_m(&self, p: [f64; 2]) -> f64 {
        match self {
            PathSegment::Line { from_m, to_m, .. } => {
                segment_distance(p, [from_m[0], from_m[1]], [to_m[0], to_m[1]])
            }
            PathSegment::Arc {
                center_m,
                radius_m,
                start_angle_rad,
                sweep_rad,
                ..
            } => {
                let ang = (p[1] - center_m[1]).atan2(p[0] - center_m[0]);
                // Is the angle within the swept range?
                let rel = (ang - start_angle_rad) * sweep_rad.signum();
                let rel = rel.rem_euclid(2.0 * PI);
                if rel <= sweep_rad.abs() {
                    ((p[0] - center_m[0]).hypot(p[1] - center_m[1]) - radius_m).abs()
                } else {
                    let end = start_angle_rad + sweep_rad;
                    let a = [
                        center_m[0] + radius_m * start_angle_rad.cos(),
                        center_m[1] + radius_m * start_angle_rad.sin(),
                    ];
                    let b = [
                        center_m[0] + radius_m * end.cos(),
                        center_m[1] + radius_m * end.sin(),
                    ];
                    (p[0] - a[0])
                        .hypot(p[1] - a[1])
                        .min((p[0] - b[0]).hypot(p[1] - b[1]))
                }
            }
            PathSegment::Dwell { .. } => f64::INFINITY,
        }
    }
}

fn dist3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2)).sqrt()
}

/// A parsed program.
#[derive(Debug, Clone, PartialEq)]
pub struct Program {
    /// Where it came from.
    pub path: PathBuf,
    /// Segments in order (zero-length moves dropped).
    pub segments: Vec<PathSegment>,
    /// Which of X, Y, Z the program uses.
    pub uses: [bool; 3],
}

impl Program {
    /// Distance (m) from `p = [x, y]` (program coordinates) to the nearest programmed segment's
    /// X-Y projection.
    pub fn distance_xy_m(&self, p: [f64; 2]) -> f64 {
        self.segments
            .iter()
            .map(|s| s.distance_xy_m(p))
            .fold(f64::INFINITY, f64::min)
    }
}

/// Parses G-code `text` (from `path`, for messages) into segments in metres.
pub fn parse_program(path: &Path, text: &str) -> Result<Program, GcodeError> {
    let err = |line: usize, reason: String| GcodeError {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let mut pos = [0.0f64; 3];
    let mut absolute = true;
    let mut motion: Option<u32> = None;
    let mut feed: Option<f64> = None;
    let mut segments = Vec::new();
    let mut uses = [false; 3];
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        // Strip comments.
        let mut body = String::with_capacity(raw.len());
        let mut in_paren = false;
        for c in raw.chars() {
            match c {
                '(' if !in_paren => in_paren = true,
                ')' if in_paren => in_paren = false,
                ';' if !in_paren => break,
                c if !in_paren => body.push(c.to_ascii_uppercase()),
                _ => {}
            }
        }
        if in_paren {
            return Err(err(ln, "comment `(` is not closed on this line".into()));
        }
        let body = body.trim();
        if body.is_empty() || body == "%" {
            continue;
        }
        // Words: letter + number.
        let bytes = body.as_bytes();
        let mut k = 0;
        let mut words: Vec<(char, f64, String)> = Vec::new();
        while k < bytes.len() {
            let c = bytes[k] as char;
            if c.is_ascii_whitespace() {
                k += 1;
                continue;
            }
            if !c.is_ascii_alphabetic() {
                return Err(err(ln, format!("unexpected `{c}` (expected a letter)")));
            }
            k += 1;
            while k < bytes.len() && bytes[k].is_ascii_whitespace() {
                k += 1;
            }
            let start = k;
            while k < bytes.len()
                && (bytes[k].is_ascii_digit() || matches!(bytes[k], b'.' | b'-' | b'+'))
            {
                k += 1;
            }
            let num = &body[start..k];
            let v: f64 = num
                .parse()
                .map_err(|_| err(ln, format!("word `{c}` needs a number, got \"{num}\"")))?;
            if !v.is_finite() {
                return Err(err(ln, format!("word `{c}{num}` is not finite")));
            }
            words.push((c, v, format!("{c}{num}")));
        }
        let mut g_motion: Option<u32> = None;
        let mut dwell = false;
        let mut coords: [Option<f64>; 3] = [None; 3];
        let (mut ci, mut cj) = (None, None);
        let mut p_word = None;
        let mut end = false;
        let mut seen: Vec<char> = Vec::new();
        for (c, v, text) in &words {
            if *c != 'G' && *c != 'M' {
                if seen.contains(c) {
                    return Err(err(ln, format!("word `{c}` appears twice")));
                }
                seen.push(*c);
            }
            match c {
                'G' => {
                    let code = if v.fract() == 0.0 && *v >= 0.0 {
                        Some(*v as u32)
                    } else {
                        None
                    };
                    match code {
                        Some(m @ 0..=3) => {
                            if g_motion.is_some() {
                                return Err(err(ln, "two motion G-codes on one line".into()));
                            }
                            g_motion = Some(m);
                        }
                        Some(4) => dwell = true,
                        Some(17) | Some(21) => {}
                        Some(90) => absolute = true,
                        Some(91) => absolute = false,
                        Some(18) | Some(19) => {
                            return Err(err(ln, format!("{text}: only the X-Y plane (G17) is supported")))
                        }
                        Some(20) => {
                            return Err(err(ln, "G20: inch units are not supported (use G21, mm)".into()))
                        }
                        _ => {
                            return Err(err(
                                ln,
                                format!("unsupported G-code {text} (supported: G0 G1 G2 G3 G4 G17 G21 G90 G91)"),
                            ))
                        }
                    }
                }
                'M' => match *v as i64 {
                    2 | 30 if v.fract() == 0.0 => end = true,
                    _ => {
                        return Err(err(
                            ln,
                            format!("unsupported M-code {text} (supported: M2, M30)"),
                        ))
                    }
                },
                'X' => coords[0] = Some(*v),
                'Y' => coords[1] = Some(*v),
                'Z' => coords[2] = Some(*v),
                'I' => ci = Some(*v),
                'J' => cj = Some(*v),
                'P' => p_word = Some(*v),
                'F' => {
                    if *v <= 0.0 {
                        return Err(err(ln, format!("feed {text} must be > 0 mm/min")));
                    }
                    feed = Some(*v / 60_000.0);
                }
                'N' => {}
                'R' => {
                    return Err(err(
                        ln,
                        "arcs by radius (R) are not supported: give the centre with I and J".into(),
                    ))
                }
                'K' => {
                    return Err(err(
                        ln,
                        "K: only X-Y plane arcs (I, J) are supported".into(),
                    ))
                }
                other => {
                    return Err(err(
                        ln,
                        format!("unsupported word `{text}` (letter {other})"),
                    ))
                }
            }
        }
        if dwell {
            if g_motion.is_some() || coords.iter().any(Option::is_some) {
                return Err(err(
                    ln,
                    "G4 (dwell) must be alone on its line with P".into(),
                ));
            }
            let p = p_word.ok_or_else(|| err(ln, "G4 needs P<seconds>".into()))?;
            if p < 0.0 {
                return Err(err(ln, format!("dwell P{p} must be >= 0 s")));
            }
            if p > 0.0 {
                segments.push(PathSegment::Dwell {
                    duration_s: p,
                    line: ln,
                });
            }
            if end {
                break;
            }
            continue;
        }
        if p_word.is_some() {
            return Err(err(ln, "P is only used with G4".into()));
        }
        if let Some(m) = g_motion {
            motion = Some(m);
        }
        let has_xyz = coords.iter().any(Option::is_some);
        if !has_xyz && ci.is_none() && cj.is_none() {
            if end {
                break;
            }
            continue;
        }
        let m = motion.ok_or_else(|| {
            err(
                ln,
                "coordinates without a motion mode (G0, G1, G2, G3)".into(),
            )
        })?;
        let mut target = pos;
        for a in 0..3 {
            if let Some(v) = coords[a] {
                uses[a] = true;
                let v = v * 1e-3;
                target[a] = if absolute { v } else { pos[a] + v };
            }
        }
        match m {
            0 | 1 => {
                if ci.is_some() || cj.is_some() {
                    return Err(err(ln, "I and J are only used with G2/G3".into()));
                }
                let f = if m == 0 {
                    f64::INFINITY
                } else {
                    feed.ok_or_else(|| {
                        err(
                            ln,
                            "no feed rate (F, mm/min) programmed before this G1 move".into(),
                        )
                    })?
                };
                if dist3(&pos, &target) > 1e-12 {
                    segments.push(PathSegment::Line {
                        from_m: pos,
                        to_m: target,
                        feed_m_per_s: f,
                        line: ln,
                    });
                }
            }
            _ => {
                if coords[2].is_some() && (target[2] - pos[2]).abs() > 1e-12 {
                    return Err(err(
                        ln,
                        "helical arcs (Z change in G2/G3) are not supported".into(),
                    ));
                }
                let f = feed.ok_or_else(|| {
                    err(
                        ln,
                        format!("no feed rate (F, mm/min) programmed before this G{m} arc"),
                    )
                })?;
                if ci.is_none() && cj.is_none() {
                    return Err(err(ln, format!("G{m} needs the centre offsets I and/or J")));
                }
                uses[0] = true;
                uses[1] = true;
                let c = [
                    pos[0] + ci.unwrap_or(0.0) * 1e-3,
                    pos[1] + cj.unwrap_or(0.0) * 1e-3,
                ];
                let r0 = (pos[0] - c[0]).hypot(pos[1] - c[1]);
                let r1 = (target[0] - c[0]).hypot(target[1] - c[1]);
                if r0 <= 1e-9 {
                    return Err(err(ln, "arc radius is zero (I = J = 0)".into()));
                }
                if (r1 - r0).abs() > 1e-6 + 1e-4 * r0 {
                    return Err(err(
                        ln,
                        format!(
                            "arc end point is not on the circle: radius {:.4} mm at the start, {:.4} mm at the end",
                            r0 * 1e3,
                            r1 * 1e3
                        ),
                    ));
                }
                let a0 = (pos[1] - c[1]).atan2(pos[0] - c[0]);
                let a1 = (target[1] - c[1]).atan2(target[0] - c[0]);
                let ccw = m == 3;
                let mut sweep = if ccw {
                    (a1 - a0).rem_euclid(2.0 * PI)
                } else {
                    -(a0 - a1).rem_euclid(2.0 * PI)
                };
                if sweep.abs() < 1e-12 || dist3(&pos, &target) < 1e-12 {
                    sweep = if ccw { 2.0 * PI } else { -2.0 * PI };
                }
                // Land exactly on the circle through the start (r0).
                target[0] = c[0] + r0 * (a0 + sweep).cos();
                target[1] = c[1] + r0 * (a0 + sweep).sin();
                segments.push(PathSegment::Arc {
                    center_m: c,
                    radius_m: r0,
                    start_angle_rad: a0,
                    sweep_rad: sweep,
                    z_m: pos[2],
                    feed_m_per_s: f,
                    line: ln,
                });
            }
        }
        pos = target;
        if end {
            break;
        }
    }
    if !segments
        .iter()
        .any(|s| !matches!(s, PathSegment::Dwell { .. }))
    {
        return Err(GcodeError {
            path: path.to_path_buf(),
            line: text.lines().count().max(1),
            reason: "the program has no motion".into(),
        });
    }
    Ok(Program {
        path: path.to_path_buf(),
        segments,
        uses,
    })
}

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
enum Geom {
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

    fn radius(&self) -> f64 {
        match *self {
            Geom::Line { .. } => f64::INFINITY,
            Geom::Arc { r, .. } => r,
        }
    }

    /// Jets of x, y, z for the arc-length jet `sigma`.
    fn jets(&self, sigma: &Jet) -> [Jet; 3] {
        match *self {
            Geom::Line { p0, u } => {
                [0, 1, 2].map(|k| jet::add_const(&jet::scale(sigma, u[k]), p0[k]))
            }
            Geom::Arc { c, r, a0, dir, z } => {
                let ang = jet::add_const(&jet::scale(sigma, dir / r), a0);
                let (s, co) = jet::sin_cos(&ang);
                [
                    jet::add_const(&jet::scale(&co, r), c[0]),
                    jet::add_const(&jet::scale(&s, r), c[1]),
                    jet::constant(z),
                ]
            }
        }
    }
}

/// One planned motion segment: geometry, feed and timing.
#[derive(Debug, Clone, Copy)]
struct Motion {
    geom: Geom,
    len: f64,
    feed: f64,
    /// Start time, s.
    start: f64,
    /// Acceleration, cruise and deceleration times, s.
    acc: f64,
    cruise: f64,
    dec: f64,
    /// Programmed start point (program coordinates, m).
    q0: [f64; 3],
    /// Programmed end point.
    q1: [f64; 3],
}

impl Motion {
    fn end(&self) -> f64 {
        self.start + self.acc + self.cruise + self.dec
    }

    /// Arc-length value and time derivatives 1..5 at `t`.
    fn sigma(&self, t: f64) -> RefState {
        let u = t - self.start;
        let f = self.feed;
        let mut out = [0.0; REF_DERIVS];
        if u <= 0.0 {
            return out;
        }
        if u >= self.acc + self.cruise + self.dec {
            out[0] = self.len;
            return out;
        }
        let fact = [1.0, 1.0, 2.0, 6.0, 24.0, 120.0];
        if u < self.acc {
            let h = taylor_at(&SMOOTHSTEP_INTEGRAL, u / self.acc);
            let mut sc = f * self.acc;
            for k in 0..REF_DERIVS {
                out[k] = sc * h[k] * fact[k];
                sc /= self.acc;
            }
        } else if u < self.acc + self.cruise {
            out[0] = f * (0.5 * self.acc + (u - self.acc));
            out[1] = f;
        } else {
            let w = u - self.acc - self.cruise;
            let h = taylor_at(&SMOOTHSTEP_INTEGRAL, w / self.dec);
            let base = f * (0.5 * self.acc + self.cruise);
            let mut sc = f * self.dec;
            for k in 0..REF_DERIVS {
                out[k] = -sc * h[k] * fact[k];
                sc /= self.dec;
            }
            out[0] += base + f * w;
            out[1] += f;
        }
        out
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

/// A planned program (kind `program`).
pub struct ProgramTrajectory {
    axes: Vec<String>,
    /// Job axis index of program X, Y, Z.
    map: [Option<usize>; 3],
    /// Machine position of program zero, per job axis.
    origin: Vec<f64>,
    motions: Vec<Motion>,
    ends: Vec<f64>,
    duration_s: f64,
    program: Program,
    delay_s: f64,
    /// The commanded X-Y path as chords, built on the first contour query.
    path_index: OnceLock<PathIndex>,
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
        let n = motions.len();
        let mut motions = motions;
        // Corner i is between motion i and i+1 (None at a chain break).
        let joined: Vec<bool> = (0..n.saturating_sub(1))
            .map(|i| gaps[i + 1] == 0.0)
            .collect();
        let is_arc: Vec<bool> = motions
            .iter()
            .map(|m| m.geom.radius().is_finite())
            .collect();
        let budgets = |i: usize| -> (f64, f64) {
            // Halve the budgets where an arc takes part.
            let arc = |k: usize| k < n && is_arc[k];
            if arc(i) || arc(i + 1) {
                (0.5 * lim.max_accel_m_per_s2, 0.5 * lim.max_jerk_m_per_s3)
            } else {
                (lim.max_accel_m_per_s2, lim.max_jerk_m_per_s3)
            }
        };
        let corner = |m: &[Motion], i: usize| -> (f64, f64) {
            let (a, b) = (&m[i], &m[i + 1]);
            let ta = a.geom.tangent(a.len);
            let tb = b.geom.tangent(0.0);
            let ka = a.geom.curvature(a.len);
            let kb = b.geom.curvature(0.0);
            let dv = norm3([0, 1, 2].map(|k| b.feed * tb[k] - a.feed * ta[k]));
            let da = norm3([0, 1, 2].map(|k| b.feed * b.feed * kb[k] - a.feed * a.feed * ka[k]));
            (dv, da)
        };
        let ramp = |m: &Motion, arc_budget: bool| -> f64 {
            let (a, j) = if arc_budget {
                (0.5 * lim.max_accel_m_per_s2, 0.5 * lim.max_jerk_m_per_s3)
            } else {
                (lim.max_accel_m_per_s2, lim.max_jerk_m_per_s3)
            };
            let da = m.feed * m.feed / m.geom.radius();
            blend_time(&lim, m.feed, da, a, j)
        };
        // Blend times from the current feeds; sets acc/dec/cruise; returns the segments whose
        // blends do not fit in them (with the length they would need).
        let assign = |motions: &mut [Motion]| -> Vec<(usize, f64)> {
            let arc = |m: &Motion| m.geom.radius().is_finite();
            let blends: Vec<f64> = (0..n.saturating_sub(1))
                .map(|i| {
                    if joined[i] {
                        let (a, j) = budgets(i);
                        let (dv, da) = corner(motions, i);
                        blend_time(&lim, dv, da, a, j)
                    } else {
                        0.0
                    }
                })
                .collect();
            let mut bad = Vec::new();
            for i in 0..n {
                let acc = if i == 0 || !joined[i - 1] {
                    ramp(&motions[i], arc(&motions[i]))
                } else {
                    blends[i - 1]
                };
                let dec = if i == n - 1 || !joined[i] {
                    ramp(&motions[i], arc(&motions[i]))
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
        };
        // Look-ahead: lower feeds until every corner is within tolerance and every segment
        // holds its blends (feeds only decrease, so this terminates).
        for _ in 0..2000 {
            let mut changed = false;
            for i in 0..n.saturating_sub(1) {
                if !joined[i] {
                    continue;
                }
                let (a, j) = budgets(i);
                let (dv, da) = corner(&motions, i);
                let cut = blend_time(&lim, dv, da, a, j)
                    * H_HALF
                    * perpendicular_dv(&motions[i], &motions[i + 1]);
                if cut > lim.corner_tolerance_m * (1.0 + 1e-9) {
                    let k = (lim.corner_tolerance_m / cut).sqrt().min(0.999);
                    motions[i].feed *= k;
                    motions[i + 1].feed *= k;
                    changed = true;
                }
            }
            for (i, need) in assign(&mut motions) {
                let m = &mut motions[i];
                m.feed *= 0.9f64.max((m.len / need).sqrt()).min(0.99);
                changed = true;
            }
            if !changed {
                break;
            }
        }
        // Should the iteration limit be hit, squeeze the cruise out of what does not fit.
        for (i, _) in assign(&mut motions) {
            let m = &mut motions[i];
            m.feed = m.len / (0.5 * (m.acc + m.dec));
            m.cruise = 0.0;
        }
        // Timing.
        let mut t = delay_s;
        for i in 0..n {
            if i == 0 || !joined[i - 1] {
                t += gaps[i];
                motions[i].start = t;
            } else {
                motions[i].start = motions[i - 1].end() - motions[i - 1].dec;
            }
            t = motions[i].end();
        }
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

    /// Program-coordinate jets of X, Y, Z at `t`.
    fn program_jets(&self, t: f64) -> [Jet; 3] {
        let n = self.motions.len();
        let i = self.ends.partition_point(|e| *e <= t);
        if i >= n {
            let q = self.motions[n - 1].q1;
            return q.map(jet::constant);
        }
        let m = &self.motions[i];
        let mut out = m.q0.map(jet::constant);
        if t <= m.start {
            return out;
        }
        let mut add = |mo: &Motion| {
            let sig = jet::from_derivs(&mo.sigma(t));
            let p = mo.geom.jets(&sig);
            for k in 0..3 {
                out[k] = jet::add(&out[k], &jet::add_const(&p[k], -mo.q0[k]));
            }
        };
        add(m);
        if let Some(next) = self.motions.get(i + 1) {
            if next.start < t {
                add(next);
            }
        }
        out
    }
}

impl Trajectory for ProgramTrajectory {
    fn axes(&self) -> &[String] {
        &self.axes
    }

    fn duration_s(&self) -> f64 {
        self.duration_s
    }

    fn eval(&self, t_s: f64, out: &mut [RefState]) {
        for (o, p) in out.iter_mut().zip(&self.origin) {
            *o = [0.0; REF_DERIVS];
            o[0] = *p;
        }
        if self.motions.is_empty() {
            return;
        }
        let held = t_s.is_nan() || t_s >= self.duration_s;
        let t = if held { f64::INFINITY } else { t_s };
        let jets = self.program_jets(t);
        for (k, idx) in self.map.iter().enumerate() {
            if let Some(o) = idx.and_then(|i| out.get_mut(i)) {
                let d = jet::to_derivs(&jets[k]);
                o[0] += d[0];
                if !held {
                    o[1..].copy_from_slice(&d[1..]);
                }
            }
        }
    }

    fn kind(&self) -> &str {
        "program"
    }

    fn contour(&self) -> Option<Contour> {
        match (self.map[0], self.map[1]) {
            (Some(x), Some(y)) if self.program.uses[0] && self.program.uses[1] => Some(Contour {
                axes: [x, y],
                shape: ContourShape::Path,
            }),
            _ => None,
        }
    }

    /// The signed distance from the measured X-Y point to the commanded (blended) path within
    /// [`super::path_index::WINDOW_BEHIND_S`] before and
    /// [`super::path_index::WINDOW_AHEAD_S`] after the command at `t_s` (see [`PathIndex`]).
    /// The first call builds the path index (it allocates once).
    fn contour_error_m(&self, t_s: f64, actual: &[f64]) -> Option<f64> {
        let c = self.contour()?;
        let p = [*actual.get(c.axes[0])?, *actual.get(c.axes[1])?];
        let index = self
            .path_index
            .get_or_init(|| PathIndex::build(self, c.axes));
        Some(index.distance_m(self, t_s, p))
    }

    /// Each motion's start, the ends of its acceleration and cruise, and its end.
    fn breakpoints_s(&self) -> Vec<f64> {
        self.motions
            .iter()
            .flat_map(|m| {
                [
                    m.start,
                    m.start + m.acc,
                    m.start + m.acc + m.cruise,
                    m.end(),
                ]
            })
            .collect()
    }

    fn steady_windows_s(&self) -> Vec<[f64; 2]> {
        self.motions
            .iter()
            .filter(|m| m.cruise > 0.0 && m.geom.radius().is_infinite())
            .map(|m| [m.start + m.acc, m.start + m.acc + m.cruise])
            .filter(|w| w[0] >= self.delay_s)
            .collect()
    }
}

/// `kind = "program"`.
pub(crate) fn build(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let rel = f.str("file")?;
    let path = f.file().parent().unwrap_or(Path::new(".")).join(rel);
    let v = f.f64("max_velocity_m_per_s", Range::Positive)?;
    let a = f.f64("max_accel_m_per_s2", Range::Positive)?;
    let j = f.f64("max_jerk_m_per_s3", Range::Positive)?;
    let tol = f.f64_or("corner_tolerance_m", Range::Positive, 1e-5)?;
    let mut map: [Option<usize>; 3] = [0, 1, 2].map(|k| {
        let letter = ["x", "y", "z"][k];
        ctx.axes.iter().position(|a| a == letter)
    });
    if let Some(t) = f.opt_table("axes")? {
        map = [None; 3];
        for (letter, name) in t {
            let key = format!("axes.{letter}");
            let k = ["x", "y", "z"]
                .iter()
                .position(|l| l == letter)
                .ok_or_else(|| f.error(&key, "program axes are x, y and z"))?;
            let name = name.as_str().ok_or_else(|| {
                f.error(
                    &key,
                    format!("must be a job axis name, got {}", name.type_str()),
                )
            })?;
            map[k] = Some(ctx.axis_index(&f, &key, name)?);
        }
    }
    let origin: Vec<f64> = per_axis(&mut f, "origin_m", "origin_rad", ctx.axes, Range::Finite)?
        .into_iter()
        .map(|v| v.unwrap_or(0.0))
        .collect();
    let before = f.f64_or("dwell_before_s", Range::NonNegative, 0.0)?;
    let after = f.f64_or("dwell_after_s", Range::NonNegative, 0.0)?;
    let file = f.file();
    let k_file = f.path("file");
    f.finish()?;
    let text = std::fs::read_to_string(&path).map_err(|e| {
        ConfigError::new(
            file,
            &k_file,
            format!("cannot read {}: {e}", path.display()),
        )
    })?;
    let program =
        parse_program(&path, &text).map_err(|e| ConfigError::new(file, &k_file, e.to_string()))?;
    for (k, used) in program.uses.iter().enumerate() {
        if *used && map[k].is_none() {
            let letter = ["X", "Y", "Z"][k];
            return Err(ConfigError::new(
                file,
                &k_file,
                format!(
                    "{} uses {letter}, which is not mapped to a job axis (axes: {}); map it with axes = {{ {} = \"...\" }}",
                    path.display(),
                    ctx.axes.join(", "),
                    letter.to_ascii_lowercase()
                ),
            ));
        }
    }
    let limits = PlanLimits {
        max_velocity_m_per_s: v,
        max_accel_m_per_s2: a,
        max_jerk_m_per_s3: j,
        corner_tolerance_m: tol,
        min_blend_s: 4.0 * ctx.period_s,
    };
    Ok(Box::new(ProgramTrajectory::plan(
        program, ctx.axes, map, origin, limits, before, after,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::*;

    fn parse(text: &str) -> Result<Program, GcodeError> {
        parse_program(Path::new("part.nc"), text)
    }

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
    fn a_program_parses_into_lines_arcs_and_dwells_in_metres() {
        let p = parse(
            "% \n(square with a round corner)\nN10 G21 G17 G90\nG0 X0 Y0\nG1 X10 F600 ; 10 mm/s\nG3 X20 Y10 I0 J10\nG4 P0.5\nG91 G1 Y-10\nM30\nG1 X99\n",
        )
        .unwrap();
        assert_eq!(p.segments.len(), 4, "{:?}", p.segments);
        match &p.segments[0] {
            PathSegment::Line {
                to_m,
                feed_m_per_s,
                line,
                ..
            } => {
                assert_eq!(*to_m, [0.01, 0.0, 0.0]);
                assert!((feed_m_per_s - 0.01).abs() < 1e-15);
                assert_eq!(*line, 5);
            }
            other => panic!("{other:?}"),
        }
        match &p.segments[1] {
            PathSegment::Arc {
                center_m,
                radius_m,
                sweep_rad,
                ..
            } => {
                assert!((center_m[0] - 0.01).abs() < 1e-15 && (center_m[1] - 0.01).abs() < 1e-15);
                assert!((radius_m - 0.01).abs() < 1e-15);
                assert!((sweep_rad - PI / 2.0).abs() < 1e-12);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(
            p.segments[2],
            PathSegment::Dwell {
                duration_s: 0.5,
                line: 7
            }
        );
        match &p.segments[3] {
            PathSegment::Line { from_m, to_m, .. } => {
                assert!((from_m[0] - 0.02).abs() < 1e-15 && (from_m[1] - 0.01).abs() < 1e-15);
                assert!((to_m[1]).abs() < 1e-15, "incremental Y-10 from 10");
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(p.uses, [true, true, false]);
    }

    #[test]
    fn bad_programs_are_refused_with_file_and_line() {
        for (text, line, what) in [
            ("G1 X10\n", 1, "no feed rate"),
            ("G1 F100 X1\nG20\n", 2, "inch"),
            ("G1 F100 X1\nG41 X2\n", 2, "unsupported G-code G41"),
            ("F100\nG2 X10 Y0 I4 J1\n", 2, "not on the circle"),
            ("G1 F100 X1 X2\n", 1, "appears twice"),
            ("G1 F100 X1\nT1\n", 2, "unsupported word `T1`"),
            ("G1 F100 X1 (open\n", 1, "not closed"),
            ("G1 F100 Xabc\n", 1, "needs a number"),
            ("G2 F100 X1 R5\n", 1, "R"),
            ("G4\n", 1, "P<seconds>"),
            ("(nothing)\n", 1, "no motion"),
            ("G1 F100 X1\nG3 X0 Y0 Z1 I1 J0\n", 2, "helical"),
        ] {
            let e = parse(text).unwrap_err();
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(
                e.to_string()
                    .starts_with(&format!("part.nc: line {line}: ")),
                "{e}"
            );
            assert!(e.reason.contains(what), "{text:?}: {e}");
        }
    }

    fn write_job_dir(tag: &str, program: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("feedloop-gcode-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("part.nc"), program).unwrap();
        d
    }

    fn build_program(
        dir: &Path,
        extra: &str,
        axes: &[&str],
    ) -> Result<Box<dyn Trajectory>, ConfigError> {
        let text = format!(
            "kind = \"program\"\nfile = \"part.nc\"\nmax_velocity_m_per_s = 0.05\nmax_accel_m_per_s2 = 1.0\nmax_jerk_m_per_s3 = 100.0\n{extra}"
        );
        let t: toml::Table = text.parse().unwrap();
        let axes: Vec<String> = axes.iter().map(|s| s.to_string()).collect();
        crate::build(&t, &dir.join("job.toml"), &axes, 1e-4)
    }

    const PART: &str = "G21 G90 G17\nG1 X20 F1800\nG1 X20 Y10\nG3 X10 Y20 I-10 J0\nG1 X0 Y20\nG1 X0 Y0\nG4 P0.2\nG1 X5 Y0\nG1 X10 Y0\n";

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

    #[test]
    fn program_derivatives_match_central_differences_and_collinear_segments_keep_the_feed() {
        let dir = write_job_dir("fd", PART);
        let tr = build_program(&dir, "", &["x", "y", "c"]).unwrap();
        let worst = check_derivatives(tr.as_ref(), 600, 1e-7, &[]);
        assert!(worst < 1e-4, "{worst}");
        // The two collinear moves after the dwell (X0->X5->X10) join at full speed: the speed
        // never dips between them.
        let w = tr.steady_windows_s();
        let last = w[w.len() - 1];
        let s = at(tr.as_ref(), 0.5 * (last[0] + last[1]));
        assert!((s[0][1] - 0.03).abs() < 1e-12, "{:?}", s[0]);
        assert_eq!(at(tr.as_ref(), 1.0)[2], [0.0; 6], "unmapped axis c at rest");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn the_path_contour_error_is_the_distance_to_the_commanded_path() {
        let dir = write_job_dir("contour", PART);
        let tr = build_program(&dir, "", &["x", "y"]).unwrap();
        let c = tr.contour().unwrap();
        assert_eq!(c.shape, ContourShape::Path);
        // On the first line (+x), a point 3 um to the left (+y) of the command lagging by 1 ms.
        let t = 0.3;
        let s = at(tr.as_ref(), t - 1e-3);
        assert!(s[1][0].abs() < 1e-15 && s[0][1] > 0.02);
        let e = tr.contour_error_m(t, &[s[0][0], 3e-6]).unwrap();
        assert!((e - 3e-6).abs() < 1e-12, "{e}");
        let e = tr.contour_error_m(t, &[s[0][0], -2e-6]).unwrap();
        assert!((e + 2e-6).abs() < 1e-12, "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A 90 degree corner, an arc, a dwell, a 180 degree reversal, a full circle and a line
    /// crossing it: every place where the measured point and the command can sit on different
    /// pieces of the path.
    const TURNS: &str = "G21 G90 G17\nG1 X10 F1200\nG1 Y5\nG3 X5 Y10 I-5 J0\nG4 P0.1\nG1 X0 Y10\nG1 X5 Y10\nG2 X5 Y10 I0 J-2\nG1 X5 Y3 F600\n";

    #[test]
    fn a_point_lagging_the_command_round_corners_dwells_and_reversals_gets_its_distance_to_the_path(
    ) {
        use crate::path_index::{WINDOW_AHEAD_S, WINDOW_BEHIND_S};
        let dir = write_job_dir("turns", TURNS);
        let tr = build_program(&dir, "", &["x", "y"]).unwrap();
        let dur = tr.duration_s();
        // Reference: the commanded path sampled every 100 us, searched by brute force (chord
        // error below a h^2 / 8 = 1.3e-9 m at the planner's 1 m/s^2).
        let h = 1e-4;
        let dense: Vec<[f64; 2]> = (0..=(dur / h).ceil() as usize)
            .map(|k| {
                let s = at(tr.as_ref(), (k as f64 * h).min(dur));
                [s[0][0], s[1][0]]
            })
            .collect();
        // (distance, time of the foot, side, direction) of p from the dense segment k
        let seg = |p: [f64; 2], k: usize| {
            let (a, b) = (dense[k], dense[k + 1]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let l2 = dx * dx + dy * dy;
            let s = if l2 > 0.0 {
                (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (wx, wy) = (p[0] - a[0] - s * dx, p[1] - a[1] - s * dy);
            (
                wx.hypot(wy),
                (k as f64 + s) * h,
                dx * wy - dy * wx,
                [dx, dy],
            )
        };
        // Nearest point in [from, to]: (distance, foot time, side, distance of the nearest
        // point of another pass: more than 0.05 s away from that foot, or travelling the
        // other way).
        let brute = |from: f64, to: f64, p: [f64; 2]| {
            let lo = ((from / h).floor().max(0.0) as usize).min(dense.len() - 2);
            let hi = ((to / h).ceil().max(0.0) as usize).clamp(lo + 1, dense.len() - 1);
            let best =
                (lo..hi)
                    .map(|k| seg(p, k))
                    .fold((f64::INFINITY, 0.0, 0.0, [0.0; 2]), |b, c| {
                        if c.0 < b.0 {
                            c
                        } else {
                            b
                        }
                    });
            let other = (lo..hi)
                .map(|k| seg(p, k))
                .filter(|c| {
                    (c.1 - best.1).abs() > 0.05 || c.3[0] * best.3[0] + c.3[1] * best.3[1] < 0.0
                })
                .fold(f64::INFINITY, |m, c| m.min(c.0));
            (best.0, best.1, best.2, other)
        };
        let (mut worst, mut queries, mut far, mut signs) = (0.0f64, 0, 0, 0);
        let steps = 250;
        for k in 0..=steps {
            let t = -0.1 + (dur + 0.3) * k as f64 / steps as f64;
            for lag in [0.0, 0.01, 0.03, 0.08] {
                let c = at(tr.as_ref(), t - lag);
                let (vx, vy) = (c[0][1], c[1][1]);
                let v = vx.hypot(vy);
                // normal to the left of travel (any direction at rest)
                let n = if v > 0.0 {
                    [-vy / v, vx / v]
                } else {
                    [0.6, 0.8]
                };
                for off in [3e-6, -2e-5] {
                    let p = [c[0][0] + off * n[0], c[1][0] + off * n[1]];
                    let e = tr.contour_error_m(t, &p).unwrap();
                    let (d, _, side, other) = brute(t - WINDOW_BEHIND_S, t + WINDOW_AHEAD_S, p);
                    assert!(
                        (e.abs() - d).abs() <= 3e-9,
                        "t {t} lag {lag} off {off}: index {e}, brute force {d}"
                    );
                    worst = worst.max((e.abs() - d).abs());
                    // the side, where one pass of the path is clearly the nearest
                    if other - d > 1e-8 && d > 1e-8 && side != 0.0 {
                        assert_eq!(e.signum(), side.signum(), "t {t} lag {lag} off {off}: {e}");
                        signs += 1;
                    }
                    let now = at(tr.as_ref(), t);
                    if e.abs() < 0.5 * (c[0][0] - now[0][0]).hypot(c[1][0] - now[1][0]) {
                        far += 1;
                    }
                    queries += 1;
                }
            }
        }
        eprintln!(
            "{queries} queries, largest difference from brute force {worst:e} m, {signs} signs \
             checked, {far} points nearer the path than half their lag"
        );
        assert!(
            far > 500,
            "the sweep must include points that lag far behind the command"
        );
        assert!(signs > 1000, "{signs}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn an_unmapped_program_axis_and_a_bad_line_are_reported() {
        let dir = write_job_dir("map", "G1 F100 X1 Z2\n");
        let e = build_program(&dir, "", &["x", "y"]).err().unwrap();
        assert_eq!(e.key, "trajectory.file");
        assert!(e.reason.contains("uses Z"), "{e}");
        std::fs::write(dir.join("part.nc"), "G1 F100 X1\nG1 Q7\n").unwrap();
        let e = build_program(&dir, "", &["x", "y"]).err().unwrap();
        assert!(
            e.reason.contains("part.nc: line 2: unsupported word `Q7`"),
            "{e}"
        );
        let e = build_program(&dir, "axes = { w = \"x\" }\n", &["x", "y"])
            .err()
            .unwrap();
        assert_eq!(e.key, "trajectory.axes.w");
        std::fs::remove_dir_all(&dir).ok();
    }
}
