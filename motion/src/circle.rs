//! Kind `circle`: a circular contour in the plane of two axes with a C5 feed ramp.
//!
//! `x(t) = c_x + R cos(phi(t))`, `y(t) = c_y + R sin(phi(t))`, `phi(t) = phi_0 + d sigma(t) / R`
//! with `d = +1` (ccw) or `-1` (cw). The arc length `sigma(t)` accelerates with the C5 velocity
//! profile `F s(tau)` over `ramp_s`, runs at the feed `F`, and decelerates the same way, so the
//! path speed `|p'| = sigma'(t)` has no step and the total arc is `2 pi R turns`:
//! `2 pi R turns = F (ramp_s + cruise_s)`.
//!
//! Derivatives up to the 5th follow from Faa di Bruno's formula on `cos(phi(t))`, `sin(phi(t))`,
//! computed with truncated Taylor series ([`super::jet`]). The radius is exact at every instant
//! (to rounding), and the centripetal acceleration in the steady part is `F^2 / R`.

use std::f64::consts::PI;

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::jet;
use super::poly::{Builder, PiecewisePoly};
use super::{Contour, ContourShape, Ctx, RefState, Trajectory};

/// A circle trajectory (see the module documentation).
pub struct Circle {
    axes: Vec<String>,
    plane: [usize; 2],
    center_m: [f64; 2],
    radius_m: f64,
    /// `+1` ccw, `-1` cw (of the first pass, for `ccw_cw` / `cw_ccw`).
    direction: f64,
    start_angle_rad: f64,
    /// Arc length `sigma(t)`, m.
    arc: PiecewisePoly,
    windows: Vec<[f64; 2]>,
    /// The cruises at constant feed: `(t0, t1, sigma(t0), feed)` (two for a circle run both
    /// ways, the second with a negative feed); evaluated in closed form.
    cruise: Vec<(f64, f64, f64, f64)>,
}

impl Trajectory for Circle {
    axes_and_duration!(self => self.arc.end_s());

    fn eval(&self, t_s: f64, out: &mut [RefState]) {
        for &(t0, t1, sigma0, feed) in &self.cruise {
            if t_s >= t0 && t_s < t1 {
                // Constant angular speed w: the derivatives of cos/sin are powers of w.
                let k = self.direction / self.radius_m;
                let w = k * feed;
                let phi = self.start_angle_rad + k * (sigma0 + feed * (t_s - t0));
                let (sn, cs) = super::trig::sin_cos(phi);
                let r = self.radius_m;
                let (w2, w3) = (w * w, w * w * w);
                let (w4, w5) = (w2 * w2, w2 * w3);
                let x = [cs, -w * sn, -w2 * cs, w3 * sn, w4 * cs, -w5 * sn];
                let y = [sn, w * cs, -w2 * sn, -w3 * cs, w4 * sn, w5 * cs];
                for (i, o) in out.iter_mut().enumerate() {
                    let (v, c) = if i == self.plane[0] {
                        (&x, self.center_m[0])
                    } else if i == self.plane[1] {
                        (&y, self.center_m[1])
                    } else {
                        *o = [0.0; REF_DERIVS];
                        continue;
                    };
                    *o = std::array::from_fn(|d| r * v[d]);
                    o[0] += c;
                }
                return;
            }
        }
        for o in out.iter_mut() {
            *o = [0.0; REF_DERIVS];
        }
        let sigma = self.arc.eval_axis(t_s, 0);
        let k = self.direction / self.radius_m;
        let mut phi = jet::from_derivs(&sigma);
        for v in phi.iter_mut() {
            *v *= k;
        }
        phi[0] += self.start_angle_rad;
        let (s, c) = jet::sin_cos(&phi);
        let x = jet::to_derivs(&jet::scale(&c, self.radius_m));
        let y = jet::to_derivs(&jet::scale(&s, self.radius_m));
        if let Some(o) = out.get_mut(self.plane[0]) {
            *o = x;
            o[0] += self.center_m[0];
        }
        if let Some(o) = out.get_mut(self.plane[1]) {
            *o = y;
            o[0] += self.center_m[1];
        }
        if t_s >= self.arc.end_s() {
            // Exactly zero derivatives while holding (the jets give ~1e-20 residues).
            for i in self.plane {
                if let Some(o) = out.get_mut(i) {
                    o[1..].iter_mut().for_each(|v| *v = 0.0);
                }
            }
        }
    }

    fn kind(&self) -> &str {
        "circle"
    }

    fn contour(&self) -> Option<Contour> {
        Some(Contour {
            axes: self.plane,
            shape: ContourShape::Circle {
                center_m: self.center_m,
                radius_m: self.radius_m,
            },
        })
    }

    fn steady_windows_s(&self) -> Vec<[f64; 2]> {
        self.windows.clone()
    }

    fn breakpoints_s(&self) -> Vec<f64> {
        self.arc.piece_starts().to_vec()
    }
}

/// `kind = "circle"`.
pub(crate) fn build(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let plane = plane(&mut f, ctx)?;
    let center = f
        .opt_f64_array("center_m")?
        .ok_or_else(|| f.error("center_m", "is required: [x, y] of the centre, m"))?;
    if center.len() != 2 {
        return Err(f.error(
            "center_m",
            format!("must hold two numbers [x, y], got {}", center.len()),
        ));
    }
    let radius_m = f.f64("radius_m", Range::Positive)?;
    let feed = f.f64("feed_m_per_s", Range::Positive)?;
    let turns = f.f64_or("turns", Range::Positive, 1.0)?;
    // (direction of the first pass, whether it turns back the other way afterwards)
    let (direction, both_ways) = direction(&mut f)?;
    let start_angle_rad = f.f64_or("start_angle_rad", Range::Finite, 0.0)?;
    let ramp_s = f.f64_or("ramp_s", Range::Positive, 0.1)?;
    ctx.at_least_periods(&f, "ramp_s", ramp_s, 2.0)?;
    let before = f.f64_or("dwell_before_s", Range::NonNegative, 0.0)?;
    let after = f.f64_or("dwell_after_s", Range::NonNegative, 0.0)?;
    let between = f.f64_or("dwell_between_s", Range::NonNegative, 0.0)?;
    if !both_ways && f.has("dwell_between_s") {
        return Err(f.error(
            "dwell_between_s",
            "only used with direction = \"ccw_cw\" or \"cw_ccw\" (a rest between the two ways)",
        ));
    }
    let arc_m = 2.0 * PI * radius_m * turns;
    let cruise_s = arc_m / feed - ramp_s;
    if cruise_s < 0.0 {
        return Err(f.error(
            "ramp_s",
            format!(
                "the feed ramps alone cover {:.6} m, more than the {arc_m:.6} m of arc: shorten ramp_s or add turns",
                feed * ramp_s
            ),
        ));
    }
    f.finish()?;
    let (arc, windows) = arc_profile(feed, ramp_s, cruise_s, both_ways, [before, between, after]);
    let cruise = windows
        .iter()
        .zip([feed, -feed])
        .map(|(w, v)| (w[0], w[1], arc.eval_axis(w[0], 0)[0], v))
        .collect();
    Ok(Box::new(Circle {
        axes: ctx.axes.to_vec(),
        plane,
        center_m: [center[0], center[1]],
        radius_m,
        direction,
        start_angle_rad,
        arc,
        windows,
        cruise,
    }))
}

/// The plane's two axes (`axes`, or the job's own two).
fn plane(f: &mut Fields, ctx: &Ctx) -> Result<[usize; 2], ConfigError> {
    Ok(match f.opt_str_array("axes")? {
        Some(names) => {
            if names.len() != 2 {
                return Err(f.error(
                    "axes",
                    format!("must name exactly two axes, got {}", names.len()),
                ));
            }
            let a = ctx.axis_index(f, "axes", &names[0])?;
            let b = ctx.axis_index(f, "axes", &names[1])?;
            if a == b {
                return Err(f.error("axes", "must name two different axes"));
            }
            [a, b]
        }
        None if ctx.axes.len() == 2 => [0, 1],
        None => {
            return Err(f.error(
                "axes",
                format!(
                    "is required when the job does not have exactly two axes (axes: {})",
                    ctx.axes.join(", ")
                ),
            ))
        }
    })
}

/// `direction`: the sign of the first pass, and whether it turns back the other way afterwards.
fn direction(f: &mut Fields) -> Result<(f64, bool), ConfigError> {
    Ok(match f.opt_str("direction")?.unwrap_or("ccw") {
        "ccw" => (1.0, false),
        "cw" => (-1.0, false),
        "ccw_cw" => (1.0, true),
        "cw_ccw" => (-1.0, true),
        other => {
            return Err(f.error(
                "direction",
                format!("unknown direction `{other}` (ccw, cw, ccw_cw, cw_ccw)"),
            ))
        }
    })
}

/// The arc length's profile: dwell, smooth ramp to `feed`, cruise, ramp down (and back the
/// other way with `both_ways`), dwell; with its cruise windows.
fn arc_profile(
    feed: f64,
    ramp_s: f64,
    cruise_s: f64,
    both_ways: bool,
    [before, between, after]: [f64; 3],
) -> (PiecewisePoly, Vec<[f64; 2]>) {
    let mut b = Builder::new(&[0.0]);
    b.hold(before);
    b.smooth_velocity_change(ramp_s, &[feed]);
    b.cruise(cruise_s);
    b.smooth_velocity_change(ramp_s, &[-feed]);
    if both_ways {
        // At rest, then the same arc back the other way, to the start.
        b.hold(between);
        b.smooth_velocity_change(ramp_s, &[-feed]);
        b.cruise(cruise_s);
        b.smooth_velocity_change(ramp_s, &[feed]);
    }
    b.hold(after);
    b.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::*;

    /// The shipped example: R = 10 mm, 2 m/min, two turns.
    const EXAMPLE: &str = r#"
kind = "circle"
axes = ["x", "y"]
center_m = [-0.01, 0.0]
radius_m = 0.01
feed_m_per_s = 0.0333333333333
turns = 2
ramp_s = 0.1
dwell_after_s = 0.05
"#;

    /// The shipped example built for its two axes.
    fn example() -> Box<dyn Trajectory> {
        built(EXAMPLE, &["x", "y"])
    }

    #[test]
    fn the_example_circle_takes_about_four_seconds() {
        let tr = example();
        let arc = 2.0 * PI * 0.01 * 2.0;
        let expect = arc / 0.0333333333333 + 0.1 + 0.05;
        assert!((tr.duration_s() - expect).abs() < 1e-9);
        assert!((tr.duration_s() - 3.92).abs() < 0.01, "{}", tr.duration_s());
        // Starts at the origin (centre + R at angle 0).
        let s = at(tr.as_ref(), 0.0);
        assert!(s[0][0].abs() < 1e-15 && s[1][0].abs() < 1e-15);
    }

    #[test]
    fn the_radius_is_exact_and_the_speed_equals_the_feed_in_the_steady_part() {
        let tr = example();
        let c = tr.contour().unwrap();
        let w = tr.steady_windows_s();
        assert_eq!(w.len(), 1);
        assert!((w[0][0] - 0.1).abs() < 1e-12);
        let feed = 0.0333333333333;
        let n = 4000;
        for k in 0..=n {
            let t = tr.duration_s() * k as f64 / n as f64;
            let s = at(tr.as_ref(), t);
            let err = c.radial_error_m([s[0][0], s[1][0]]).unwrap();
            assert!(err.abs() < 1e-15, "radius off by {err} at {t}");
            if t > w[0][0] && t < w[0][1] {
                let speed = s[0][1].hypot(s[1][1]);
                assert!((speed - feed).abs() < 1e-14, "{speed}");
                let acc = s[0][2].hypot(s[1][2]);
                assert!((acc - feed * feed / 0.01).abs() < 1e-12, "{acc}");
                // Velocity is tangent: p' . (p - c) = 0.
                let radial = s[0][1] * (s[0][0] + 0.01) + s[1][1] * s[1][0];
                assert!(radial.abs() < 1e-16);
            }
        }
    }

    #[test]
    fn circle_derivatives_match_central_differences() {
        let tr = example();
        let worst = check_derivatives(tr.as_ref(), 400, 1e-5, &[]);
        assert!(worst < 1e-5, "{worst}");
    }

    #[test]
    fn a_clockwise_circle_ends_where_it_started_after_whole_turns() {
        let tr = refused(
            "kind = \"circle\"\ncenter_m = [0.1, 0.2]\nradius_m = 0.005\nfeed_m_per_s = 0.02\nturns = 1.25\ndirection = \"cw\"\nstart_angle_rad = 1.0\nramp_s = 0.05",
            &["y", "x", "z"],
        );
        assert_eq!(tr.key, "trajectory.axes", "three axes need `axes`");
        let tr = built(
            "kind = \"circle\"\naxes = [\"x\", \"y\"]\ncenter_m = [0.1, 0.2]\nradius_m = 0.005\nfeed_m_per_s = 0.02\nturns = 1.25\ndirection = \"cw\"\nstart_angle_rad = 1.0\nramp_s = 0.05",
            &["z", "x", "y"],
        );
        let start = at(tr.as_ref(), 0.0);
        assert!((start[1][0] - (0.1 + 0.005 * 1f64.cos())).abs() < 1e-15);
        let end = at(tr.as_ref(), tr.duration_s() + 1.0);
        let angle = 1.0 - 1.25 * 2.0 * PI;
        assert!((end[1][0] - (0.1 + 0.005 * angle.cos())).abs() < 1e-12);
        assert!((end[2][0] - (0.2 + 0.005 * angle.sin())).abs() < 1e-12);
        assert_eq!(end[0], [0.0; 6], "the third axis stays at rest");
        // Clockwise: angular momentum (x' y'' ...) sign: x y' - y x' < 0 about the centre.
        let m = at(tr.as_ref(), 0.5);
        let (dx, dy) = (m[1][0] - 0.1, m[2][0] - 0.2);
        assert!(dx * m[2][1] - dy * m[1][1] < 0.0);
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn a_circle_run_both_ways_turns_back_to_its_start_at_the_same_feed() {
        // The reversal study of a ballbar test: 1.5 turns ccw, 0.2 s at rest, 1.5 turns cw.
        let text = "kind = \"circle\"\ncenter_m = [-0.01, 0.0]\nradius_m = 0.01\nfeed_m_per_s = 0.03\nturns = 1.5\ndirection = \"ccw_cw\"\ndwell_between_s = 0.2\nramp_s = 0.1\n";
        let tr = built(text, &["x", "y"]);
        let one_way = 2.0 * PI * 0.01 * 1.5 / 0.03 + 0.1;
        assert!((tr.duration_s() - (2.0 * one_way + 0.2)).abs() < 1e-9);
        let w = tr.steady_windows_s();
        assert_eq!(w.len(), 2);
        let c = tr.contour().unwrap();
        let n = 6000;
        let mut turned = 0.0;
        let mut prev_angle = 0.0f64;
        for k in 0..=n {
            let t = tr.duration_s() * k as f64 / n as f64;
            let s = at(tr.as_ref(), t);
            let err = c.radial_error_m([s[0][0], s[1][0]]).unwrap();
            assert!(err.abs() < 1e-15, "radius off by {err} at {t}");
            // angular momentum about the centre: + ccw in the first pass, - cw in the second
            let (dx, dy) = (s[0][0] + 0.01, s[1][0]);
            let l = dx * s[1][1] - dy * s[0][1];
            let speed = s[0][1].hypot(s[1][1]);
            if t > w[0][0] && t < w[0][1] {
                assert!(l > 0.0 && (speed - 0.03).abs() < 1e-12, "{t}: {l} {speed}");
            }
            if t > w[1][0] && t < w[1][1] {
                assert!(l < 0.0 && (speed - 0.03).abs() < 1e-12, "{t}: {l} {speed}");
            }
            if t > one_way + 0.01 && t < one_way + 0.19 {
                assert_eq!(speed, 0.0, "at rest between the two ways ({t})");
            }
            let angle = dy.atan2(dx);
            if k > 0 {
                let mut d = angle - prev_angle;
                d -= (d / (2.0 * PI)).round() * 2.0 * PI;
                turned += d;
            }
            prev_angle = angle;
        }
        assert!(
            turned.abs() < 1e-9,
            "back where it started: turned {turned} rad"
        );
        let end = at(tr.as_ref(), tr.duration_s() + 1.0);
        assert!(end[0][0].abs() < 1e-12 && end[1][0].abs() < 1e-12);
        let worst = check_derivatives(tr.as_ref(), 400, 1e-6, &[]);
        assert!(worst < 1e-4, "derivatives vs central differences: {worst}");
        check_final_hold(tr.as_ref());
        // the rest between the ways only exists for a circle run both ways
        refused_at(
            &text.replace("ccw_cw", "ccw"),
            &["x", "y"],
            "trajectory.dwell_between_s",
        );
        // cw first: the first pass turns clockwise
        let tr = built(&text.replace("ccw_cw", "cw_ccw"), &["x", "y"]);
        let s = at(tr.as_ref(), 0.5 * (w[0][0] + w[0][1]));
        assert!((s[0][0] + 0.01) * s[1][1] - s[1][0] * s[0][1] < 0.0);
    }

    #[test]
    fn ramps_longer_than_the_arc_are_refused() {
        refused_at(
            "kind = \"circle\"\ncenter_m = [0, 0]\nradius_m = 0.001\nfeed_m_per_s = 0.1\nturns = 1\nramp_s = 0.5",
            &["x", "y"],
            "trajectory.ramp_s",
        );
    }

    #[test]
    fn circle_keys_are_validated_by_name() {
        for (extra, key) in [
            ("radius_m = -1\n", "trajectory.radius_m"),
            ("direction = \"up\"\n", "trajectory.direction"),
            ("feed_mm_per_min = 2000\n", "trajectory.feed_mm_per_min"),
        ] {
            let mut text =
                String::from("kind = \"circle\"\ncenter_m = [0, 0]\nfeed_m_per_s = 0.01\n");
            if !extra.starts_with("radius_m") {
                text.push_str("radius_m = 0.01\n");
            }
            text.push_str(extra);
            refused_at(&text, &["x", "y"], key);
        }
    }

    #[test]
    fn the_path_error_equals_minus_the_radial_error_for_a_ccw_circle() {
        let tr = example();
        let c = tr.contour().unwrap();
        // The distance to the commanded path, as part programs measure it, on a curved path.
        let index = crate::path_index::PathIndex::build(tr.as_ref(), c.axes);
        for (t, dr, lag) in [(1.0, 2e-6, 0.0), (2.0, -3e-6, 1e-3), (3.3, 1e-7, 5e-3)] {
            // A point lagging the command by `lag` seconds and off the circle by `dr`.
            let s = at(tr.as_ref(), t - lag);
            let (ux, uy) = (s[0][0] + 0.01, s[1][0]);
            let r = ux.hypot(uy);
            let p = [-0.01 + ux * (r + dr) / r, uy * (r + dr) / r];
            let radial = c.radial_error_m(p).unwrap();
            assert!((radial - dr).abs() < 1e-15);
            let path = index.distance_m(tr.as_ref(), t, p);
            assert!(
                (path + dr).abs() < 1e-12,
                "t={t}: path error {path}, radial {dr}"
            );
            assert_eq!(tr.contour_error_m(t, &p), Some(radial));
        }
    }
}
