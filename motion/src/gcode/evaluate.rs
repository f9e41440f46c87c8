//! Evaluating a planned program: each motion's arc-length profile through its line or arc
//! geometry as jets, summed over the blends, and the [`Trajectory`] face (contour, breakpoints).

use feedloop_control::controller::REF_DERIVS;

use crate::jet::{self, Jet};
use crate::path_index::PathIndex;
use crate::poly::{taylor_at, SMOOTHSTEP_INTEGRAL};
use crate::{Contour, ContourShape, RefState, Trajectory};

use super::plan::{Geom, Motion, ProgramTrajectory};

impl Geom {
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

impl Motion {
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

impl ProgramTrajectory {
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
    axes_and_duration!(self => self.duration_s);

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcode::tests::{build_program, write_job_dir, PART};
    use crate::test_util::*;

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
        // Long: one sweep against a brute-force reference whose closures share the dense path.
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
}
