//! Kind `xc_cam`: X-C cam grinding (seed 003) with the exact contact geometry.
//!
//! The workpiece turns on the C axis; the X axis moves the grinding wheel (radius `R`) along a
//! fixed line through the rotation axis. The profile is `r(phi)` in the workpiece frame. With
//! `S = sqrt(r^2 + r'^2)` the outward normal at the contact point `P = r e_r` is
//! `N = (r e_r - r' e_theta) / S` and the wheel centre is `W = P + R N`, so the commands that put
//! the wheel on the contact point `phi` are
//!
//! `X = |W| = sqrt(r^2 + R^2 + 2 R r^2 / S)`,
//! `C = -phi + atan(R r' / (r (S + R)))` (C turns the workpiece so that `W` lies on the X line).
//!
//! `phi(t)` ramps C5-smoothly to `speed_rad_per_s`, runs, and ramps down; the time derivatives of
//! X and C up to the 5th come from jets of `phi(t)` through `r`, `r'` and the formulas above.
//!
//! Profile error (positive = material left on the part): with the measured `(X_a, C_a)` the wheel
//! centre in the workpiece frame is `W_a = X_a (cos C_a, -sin C_a)`, and
//! `eps = min_phi |W_a - P(phi)| - R` ([`XcGeometry::profile_error_m`], Newton on `phi`). Its
//! linearisation around the command is `eps ~ Gx e_x + Gc e_c` with
//! `Gx = dEps/dX = (R + r^2 / S) / X` and `Gc = dEps/dC = r r' / S` (m per rad)
//! ([`XcGeometry::gains`]).

use std::f64::consts::PI;

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::jet;
use super::poly::{taylor_all, Builder, PiecewisePoly, SMOOTHSTEP};
use super::{Contour, ContourShape, Ctx, RefState, Trajectory};

/// A cam profile `r(phi)` (m), periodic in `phi` (rad).
#[derive(Debug, Clone, PartialEq)]
pub enum CamProfile {
    /// A disc of radius `disc_radius_m` whose centre is `eccentricity_m` from the rotation axis
    /// (at `phi = 0`): `r = e cos(phi) + sqrt(rho^2 - e^2 sin^2(phi))`.
    Eccentric {
        /// `e`, m.
        eccentricity_m: f64,
        /// `rho`, m (> `e`).
        disc_radius_m: f64,
    },
    /// Base circle with one C5 rise, a top dwell and a C5 fall:
    /// `r = r0 + h s((psi) / rise)`, `r0 + h`, `r0 + h (1 - s(...))`, `r0`, `psi = phi - start`.
    RiseDwell {
        /// `r0`, m.
        base_radius_m: f64,
        /// `h`, m.
        lift_m: f64,
        /// Where the rise starts, rad.
        rise_start_rad: f64,
        /// Rise angle, rad.
        rise_rad: f64,
        /// Top dwell angle, rad.
        dwell_rad: f64,
        /// Fall angle, rad.
        fall_rad: f64,
    },
    /// A Fourier series `r = a0 + sum_k (a_k cos(k phi) + b_k sin(k phi))`, e.g. fitted to a
    /// table of radii.
    Fourier {
        /// `a0`, m.
        mean_m: f64,
        /// `a_k`, k = 1.., m.
        cos_m: Vec<f64>,
        /// `b_k`, k = 1.., m.
        sin_m: Vec<f64>,
    },
}

impl CamProfile {
    /// A Fourier profile through `radii_m` sampled at `phi = 2 pi i / n` (trigonometric
    /// interpolation truncated to `harmonics`).
    pub fn from_table(radii_m: &[f64], harmonics: usize) -> CamProfile {
        let n = radii_m.len();
        let nf = n as f64;
        let mean = radii_m.iter().sum::<f64>() / nf;
        let kmax = harmonics.min((n.saturating_sub(1)) / 2);
        let mut cos_m = Vec::with_capacity(kmax);
        let mut sin_m = Vec::with_capacity(kmax);
        for k in 1..=kmax {
            let (mut a, mut b) = (0.0, 0.0);
            for (i, r) in radii_m.iter().enumerate() {
                let (s, c) = (2.0 * PI * (k * i) as f64 / nf).sin_cos();
                a += r * c;
                b += r * s;
            }
            cos_m.push(2.0 * a / nf);
            sin_m.push(2.0 * b / nf);
        }
        CamProfile::Fourier {
            mean_m: mean,
            cos_m,
            sin_m,
        }
    }

    /// Jets of `r(phi)` and `r'(phi) = dr/dphi` for the jet `phi` (any length `L`, see
    /// [`jet`]; `L` at most 6).
    pub fn jets<const L: usize>(&self, phi: &[f64; L]) -> ([f64; L], [f64; L]) {
        match self {
            CamProfile::Eccentric {
                eccentricity_m: e,
                disc_radius_m: rho,
            } => {
                let (s, c) = jet::sin_cos(phi);
                let root = jet::sqrt(&jet::add_const(
                    &jet::scale(&jet::mul(&s, &s), -e * e),
                    rho * rho,
                ));
                let r = jet::add(&jet::scale(&c, *e), &root);
                let dr = jet::sub(
                    &jet::scale(&s, -e),
                    &jet::scale(&jet::div(&jet::mul(&s, &c), &root), e * e),
                );
                (r, dr)
            }
            CamProfile::RiseDwell {
                base_radius_m,
                lift_m,
                rise_start_rad,
                rise_rad,
                dwell_rad,
                fall_rad,
            } => {
                let phi0 = phi.first().copied().unwrap_or(0.0);
                let psi = (phi0 - rise_start_rad).rem_euclid(2.0 * PI);
                let delta = jet::add_const(phi, -phi0);
                // Jets of s(u0 + delta / beta) and of ds/dphi.
                let smooth = |u0: f64, beta: f64| -> ([f64; L], [f64; L]) {
                    let t = taylor_all(&SMOOTHSTEP, u0);
                    let coef = |d: usize| t.get(d).copied().unwrap_or(0.0);
                    let mut c = [0.0; REF_DERIVS];
                    let mut dc = [0.0; REF_DERIVS];
                    let mut k = 1.0;
                    for d in 0..REF_DERIVS {
                        c[d] = coef(d) * k;
                        dc[d] = (d + 1) as f64 * coef(d + 1) * k / beta;
                        k /= beta;
                    }
                    (
                        jet::compose_taylor(&c, &delta),
                        jet::compose_taylor(&dc, &delta),
                    )
                };
                let (r0, h) = (*base_radius_m, *lift_m);
                if psi < *rise_rad {
                    let (s, ds) = smooth(psi / rise_rad, *rise_rad);
                    (jet::add_const(&jet::scale(&s, h), r0), jet::scale(&ds, h))
                } else if psi < rise_rad + dwell_rad {
                    (jet::constant(r0 + h), [0.0; L])
                } else if psi < rise_rad + dwell_rad + fall_rad {
                    let (s, ds) = smooth((psi - rise_rad - dwell_rad) / fall_rad, *fall_rad);
                    (
                        jet::add_const(&jet::scale(&s, -h), r0 + h),
                        jet::scale(&ds, -h),
                    )
                } else {
                    (jet::constant(r0), [0.0; L])
                }
            }
            CamProfile::Fourier {
                mean_m,
                cos_m,
                sin_m,
            } => {
                let mut r = jet::constant(*mean_m);
                let mut dr = [0.0; L];
                let (s1, c1) = jet::sin_cos(phi);
                let (mut sk, mut ck) = (s1, c1);
                for (k, (a, b)) in cos_m.iter().zip(sin_m).enumerate() {
                    let kf = (k + 1) as f64;
                    r = jet::add(&r, &jet::add(&jet::scale(&ck, *a), &jet::scale(&sk, *b)));
                    dr = jet::add(
                        &dr,
                        &jet::add(&jet::scale(&sk, -kf * a), &jet::scale(&ck, kf * b)),
                    );
                    // (c + i s)_(k+1) = (c + i s)_k (c1 + i s1).
                    let nc = jet::sub(&jet::mul(&ck, &c1), &jet::mul(&sk, &s1));
                    let ns = jet::add(&jet::mul(&sk, &c1), &jet::mul(&ck, &s1));
                    (ck, sk) = (nc, ns);
                }
                (r, dr)
            }
        }
    }

    /// `r`, `r'`, `r''` at `phi` (m, m/rad, m/rad^2).
    pub fn derivatives(&self, phi: f64) -> [f64; 3] {
        let (r, dr) = self.jets::<3>(&jet::variable(phi));
        [r[0], dr[0], 2.0 * r[2]]
    }
}

/// The X-C grinding geometry: a profile and a wheel radius.
#[derive(Debug, Clone, PartialEq)]
pub struct XcGeometry {
    /// The profile.
    pub profile: CamProfile,
    /// Grinding wheel radius `R`, m.
    pub wheel_radius_m: f64,
}

impl XcGeometry {
    /// Jets of the X (m) and C (rad) commands for the contact-angle jet `phi` (any length `L`
    /// up to 6: 6 for the references, 2 for a Newton step on the contact angle).
    pub fn axis_jets<const L: usize>(&self, phi: &[f64; L]) -> ([f64; L], [f64; L]) {
        let (x, c, _) = self.axis_jets_and_gains(phi);
        (x, c)
    }

    /// [`XcGeometry::axis_jets`] and the coupling gains at `phi[0]` ([`XcGeometry::gains`])
    /// from the same evaluation of the profile.
    pub fn axis_jets_and_gains<const L: usize>(
        &self,
        phi: &[f64; L],
    ) -> ([f64; L], [f64; L], (f64, f64)) {
        let rw = self.wheel_radius_m;
        let (r, dr) = self.profile.jets(phi);
        let r2 = jet::mul(&r, &r);
        let s = jet::sqrt(&jet::add(&r2, &jet::mul(&dr, &dr)));
        let x2 = jet::add_const(
            &jet::add(&r2, &jet::scale(&jet::div(&r2, &s), 2.0 * rw)),
            rw * rw,
        );
        let x = jet::sqrt(&x2);
        let num = jet::scale(&dr, rw);
        let den = jet::mul(&r, &jet::add_const(&s, rw));
        let c = jet::sub(&jet::atan2(&num, &den), phi);
        let gains = ((rw + r2[0] / s[0]) / x[0], r[0] * dr[0] / s[0]);
        (x, c, gains)
    }

    /// The contact angle whose C command is `c_rad` (rad), the X command there (m) and the
    /// coupling gains (Gx, Gc) there: where the wheel touches when C stands at `c_rad` and X is
    /// on the profile. Newton's method from `guess_rad` (from `-c_rad` when it is NaN), steps
    /// clamped to 0.5 rad, at most 8 evaluations; no allocation.
    ///
    /// Newton converges quadratically here (`c(phi)` is smooth and monotonic): once a step is
    /// below 1e-5 rad, the error left after taking it is of the order of C''/C' times the step
    /// squared (< 1e-10 rad, under 1e-12 m on the profile), so it is taken without a further
    /// check. Warm-started from the last control cycle that is usually the first step. X is
    /// carried through the last step to first order (an error of the step squared times X'',
    /// < 1e-12 m); the gains are those before it (relative error about the step, 1e-5).
    #[inline]
    pub fn contact_of_c(&self, c_rad: f64, guess_rad: f64) -> (f64, f64, (f64, f64)) {
        let mut phi = if guess_rad.is_finite() {
            guess_rad
        } else {
            -c_rad
        };
        let (mut x_m, mut gains) = (f64::NAN, (f64::NAN, f64::NAN));
        for _ in 0..8 {
            // value and first derivative are all Newton needs
            let (x, c, g) = self.axis_jets_and_gains::<2>(&[phi, 1.0]);
            gains = g;
            let dc = c[1];
            if !(dc.is_finite() && dc.abs() > 1e-6) {
                x_m = x[0];
                break;
            }
            let step = ((c[0] - c_rad) / dc).clamp(-0.5, 0.5);
            phi -= step;
            x_m = x[0] - x[1] * step;
            if step.abs() < 1e-5 {
                break;
            }
        }
        (phi, x_m, gains)
    }

    /// X (m) and C (rad) that put the wheel on contact angle `phi_rad`.
    pub fn axes_at(&self, phi_rad: f64) -> (f64, f64) {
        let ([x], [c]) = self.axis_jets::<1>(&[phi_rad]);
        (x, c)
    }

    /// Linearised coupling gains at `phi_rad`: `Gx = (R + r^2/S) / X` (m of profile error per m
    /// of X error) and `Gc = r r' / S` (m per rad of C error).
    pub fn gains(&self, phi_rad: f64) -> (f64, f64) {
        let ([r], [dr]) = self.profile.jets::<1>(&[phi_rad]);
        let s = r.hypot(dr);
        // X as `axis_jets` forms it (the same operations in the same order)
        let rw = self.wheel_radius_m;
        let r2 = r * r;
        let x = ((r2 + 2.0 * rw * (r2 / (r2 + dr * dr).sqrt())) + rw * rw).sqrt();
        ((rw + r2 / s) / x, r * dr / s)
    }

    /// Exact profile error (m, positive = material left) for the measured `x_m`, `c_rad`:
    /// the distance from the wheel centre to the profile minus `R`, with the nearest contact
    /// angle found by Newton's method from `phi_guess_rad`. No allocation.
    pub fn profile_error_m(&self, x_m: f64, c_rad: f64, phi_guess_rad: f64) -> f64 {
        let w = [x_m * c_rad.cos(), -x_m * c_rad.sin()];
        let point = |phi: f64| {
            let [r, dr, ddr] = self.profile.derivatives(phi);
            let (s, c) = phi.sin_cos();
            let p = [r * c, r * s];
            let dp = [dr * c - r * s, dr * s + r * c];
            let ddp = [(ddr - r) * c - 2.0 * dr * s, (ddr - r) * s + 2.0 * dr * c];
            (p, dp, ddp)
        };
        let mut phi = phi_guess_rad;
        for _ in 0..30 {
            let (p, dp, ddp) = point(phi);
            let e = [p[0] - w[0], p[1] - w[1]];
            let g1 = e[0] * dp[0] + e[1] * dp[1];
            let g2 = dp[0] * dp[0] + dp[1] * dp[1] + e[0] * ddp[0] + e[1] * ddp[1];
            if g2 <= 0.0 || !g2.is_finite() {
                break;
            }
            let step = (-g1 / g2).clamp(-0.2, 0.2);
            phi += step;
            if step.abs() < 1e-15 {
                break;
            }
        }
        let (p, _, _) = point(phi);
        (p[0] - w[0]).hypot(p[1] - w[1]) - self.wheel_radius_m
    }

    /// The geometry of `profile` ground with a wheel of radius `wheel_radius_m`, checked
    /// ([`XcGeometry::check`]); what is wrong is an error on key `profile` of the table `f` reads.
    pub fn checked(
        profile: CamProfile,
        wheel_radius_m: f64,
        f: &Fields<'_>,
    ) -> Result<Self, ConfigError> {
        let geometry = XcGeometry {
            profile,
            wheel_radius_m,
        };
        geometry
            .check()
            .map_err(|r| f.error("profile", r.to_string()))?;
        Ok(geometry)
    }

    /// Checks the profile can be ground with this wheel: `r > 0` everywhere and, where the
    /// profile is concave, its radius of curvature exceeds `R`. Returns what is wrong.
    pub fn check(&self) -> Result<(), GeometryError> {
        let n = 3600;
        for i in 0..n {
            let phi = 2.0 * PI * i as f64 / n as f64;
            let [r, dr, ddr] = self.profile.derivatives(phi);
            if !r.is_finite() || r <= 0.0 {
                return Err(GeometryError::NonPositiveRadius { r, phi });
            }
            let s = r.hypot(dr);
            let curvature = (r * r + 2.0 * dr * dr - r * ddr) / (s * s * s);
            if curvature < 0.0 && 1.0 / -curvature <= self.wheel_radius_m {
                return Err(GeometryError::WheelTooLarge {
                    phi,
                    radius: 1.0 / -curvature,
                    wheel: self.wheel_radius_m,
                });
            }
        }
        Ok(())
    }
}

/// Why a cam profile cannot be ground with a wheel ([`XcGeometry::check`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    /// The profile radius is not positive (or not finite) somewhere.
    #[error("the profile radius is {r} m at phi = {phi:.4} rad (must be > 0)")]
    NonPositiveRadius {
        /// The radius there, m.
        r: f64,
        /// Where, rad.
        phi: f64,
    },
    /// A concave part is tighter than the wheel.
    #[error("the profile is concave at phi = {phi:.4} rad with a radius of curvature of {radius:.6} m, not more than the wheel radius {wheel} m")]
    WheelTooLarge {
        /// Where, rad.
        phi: f64,
        /// The profile's radius of curvature there, m.
        radius: f64,
        /// The wheel radius, m.
        wheel: f64,
    },
}

/// An X-C cam grinding trajectory (kind `xc_cam`).
pub struct XcCam {
    axes: Vec<String>,
    ix: usize,
    ic: usize,
    geometry: XcGeometry,
    /// Contact angle `phi(t)` minus its start, rad (1 axis).
    phi: PiecewisePoly,
    phi0: f64,
    /// Approach move of X and C (2 axes), ending where `phi` starts.
    approach: PiecewisePoly,
    t_rotate: f64,
    duration_s: f64,
    /// Constant-speed window of `phi`, s (trajectory time).
    windows: Vec<[f64; 2]>,
}

impl XcCam {
    /// The geometry.
    pub fn geometry(&self) -> &XcGeometry {
        &self.geometry
    }

    /// Contact angle commanded at `t_s`, rad.
    pub fn contact_angle_rad(&self, t_s: f64) -> f64 {
        self.phi0 + self.phi.eval_axis(t_s - self.t_rotate, 0)[0]
    }
}

impl Trajectory for XcCam {
    axes_and_duration!(self => self.duration_s);

    fn eval(&self, t_s: f64, out: &mut [RefState]) {
        for o in out.iter_mut() {
            *o = [0.0; REF_DERIVS];
        }
        if t_s < self.t_rotate {
            let mut two = [[0.0; REF_DERIVS]; 2];
            self.approach.eval(t_s, &mut two);
            if let Some(o) = out.get_mut(self.ix) {
                *o = two[0];
            }
            if let Some(o) = out.get_mut(self.ic) {
                *o = two[1];
            }
            return;
        }
        let mut phi = jet::from_derivs(&self.phi.eval_axis(t_s - self.t_rotate, 0));
        phi[0] += self.phi0;
        let (x, c) = self.geometry.axis_jets(&phi);
        let held = t_s >= self.duration_s;
        for (i, j) in [(self.ix, x), (self.ic, c)] {
            if let Some(o) = out.get_mut(i) {
                *o = jet::to_derivs(&j);
                if held {
                    o[1..].iter_mut().for_each(|v| *v = 0.0);
                }
            }
        }
    }

    fn kind(&self) -> &str {
        "xc_cam"
    }

    fn contour(&self) -> Option<Contour> {
        Some(Contour {
            axes: [self.ix, self.ic],
            shape: ContourShape::Profile,
        })
    }

    fn contour_error_m(&self, t_s: f64, actual: &[f64]) -> Option<f64> {
        let x = *actual.get(self.ix)?;
        let c = *actual.get(self.ic)?;
        // Newton on the distance starts where the wheel is, at the contact angle of the measured
        // C: from the commanded angle it can end on another branch when C lags by a radian
        let (guess, _, _) = self.geometry.contact_of_c(c, self.contact_angle_rad(t_s));
        Some(self.geometry.profile_error_m(x, c, guess))
    }

    fn steady_windows_s(&self) -> Vec<[f64; 2]> {
        self.windows.clone()
    }
}

/// Reads the cam profile keys (`profile` and its own keys) of a table; shared by the `xc_cam`
/// trajectory and the `nl_pid_coupler` plugin so both read the same geometry.
pub fn read_profile(f: &mut Fields) -> Result<CamProfile, ConfigError> {
    let p = match f.str("profile")? {
        "eccentric" => {
            let e = f.f64("eccentricity_m", Range::NonNegative)?;
            let rho = f.f64("disc_radius_m", Range::Positive)?;
            if e >= rho {
                return Err(f.error(
                    "eccentricity_m",
                    format!("must be < disc_radius_m ({rho} m), got {e}"),
                ));
            }
            CamProfile::Eccentric {
                eccentricity_m: e,
                disc_radius_m: rho,
            }
        }
        "rise_dwell" => {
            let rise = f.f64("rise_rad", Range::Positive)?;
            let dwell = f.f64_or("dwell_rad", Range::NonNegative, 0.0)?;
            let fall = f.f64("fall_rad", Range::Positive)?;
            if rise + dwell + fall > 2.0 * PI {
                return Err(f.error(
                    "fall_rad",
                    format!(
                        "rise_rad + dwell_rad + fall_rad = {} rad is more than a turn",
                        rise + dwell + fall
                    ),
                ));
            }
            CamProfile::RiseDwell {
                base_radius_m: f.f64("base_radius_m", Range::Positive)?,
                lift_m: f.f64("lift_m", Range::Finite)?,
                rise_start_rad: f.f64_or("rise_start_rad", Range::Finite, 0.0)?,
                rise_rad: rise,
                dwell_rad: dwell,
                fall_rad: fall,
            }
        }
        "table" => {
            let radii = f.opt_f64_array("radius_table_m")?.ok_or_else(|| {
                f.error(
                    "radius_table_m",
                    "is required: radii (m) at equally spaced angles over one turn from phi = 0",
                )
            })?;
            if radii.len() < 8 {
                return Err(f.error(
                    "radius_table_m",
                    format!("needs at least 8 radii, got {}", radii.len()),
                ));
            }
            let h = f.opt_i64("harmonics", 1, 1000)?.unwrap_or(32) as usize;
            CamProfile::from_table(&radii, h)
        }
        other => {
            return Err(f.error(
                "profile",
                format!("unknown profile `{other}` (eccentric, rise_dwell, table)"),
            ))
        }
    };
    Ok(p)
}

/// `kind = "xc_cam"`.
pub(crate) fn build(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let (ix, ic) =
        match f.opt_str_array("axes")? {
            Some(names) if names.len() == 2 => (
                ctx.axis_index(&f, "axes", &names[0])?,
                ctx.axis_index(&f, "axes", &names[1])?,
            ),
            Some(names) => {
                return Err(f.error(
                    "axes",
                    format!("must name two axes [X, C], got {}", names.len()),
                ))
            }
            None if ctx.axes.len() == 2 => (0, 1),
            None => return Err(f.error(
                "axes",
                "is required when the job does not have exactly two axes: [X (linear), C (rotary)]",
            )),
        };
    if ix == ic {
        return Err(f.error("axes", "X and C must be two different axes"));
    }
    let wheel = f.f64("wheel_radius_m", Range::Positive)?;
    let profile = read_profile(&mut f)?;
    let speed = f.f64("speed_rad_per_s", Range::Positive)?;
    let turns = f.f64_or("turns", Range::Positive, 1.0)?;
    let ramp_s = f.f64_or("ramp_s", Range::Positive, 0.2)?;
    ctx.at_least_periods(&f, "ramp_s", ramp_s, 2.0)?;
    let phi0 = f.f64_or("start_angle_rad", Range::Finite, 0.0)?;
    let approach_s = f.f64_or("approach_s", Range::NonNegative, 0.0)?;
    let x_start = f.f64_or("x_start_m", Range::Finite, 0.0)?;
    let c_start = f.f64_or("c_start_rad", Range::Finite, 0.0)?;
    if approach_s == 0.0 && (f.has("x_start_m") || f.has("c_start_rad")) {
        return Err(f.error(
            "approach_s",
            "is required (> 0) when x_start_m or c_start_rad is given",
        ));
    }
    if approach_s > 0.0 {
        ctx.at_least_periods(&f, "approach_s", approach_s, 2.0)?;
    }
    let before = f.f64_or("dwell_before_s", Range::NonNegative, 0.0)?;
    let after = f.f64_or("dwell_after_s", Range::NonNegative, 0.0)?;
    let total = 2.0 * PI * turns;
    let cruise = total / speed - ramp_s;
    if cruise < 0.0 {
        return Err(f.error(
            "ramp_s",
            format!(
                "the speed ramps alone turn {:.4} rad, more than the {total:.4} rad asked for: shorten ramp_s or add turns",
                speed * ramp_s
            ),
        ));
    }
    let geometry = XcGeometry::checked(profile, wheel, &f)?;
    f.finish()?;

    let (x0, c0) = geometry.axes_at(phi0);
    let mut ap = Builder::new(&[x_start, c_start]);
    if approach_s > 0.0 {
        ap.smooth_move(approach_s, &[x0 - x_start, c0 - c_start]);
    } else {
        ap = Builder::new(&[x0, c0]);
    }
    ap.hold(before);
    let t_rotate = ap.time();
    let (approach, _) = ap.finish();
    let mut b = Builder::new(&[0.0]);
    b.smooth_velocity_change(ramp_s, &[speed]);
    b.cruise(cruise);
    b.smooth_velocity_change(ramp_s, &[-speed]);
    b.hold(after);
    let (phi, windows) = b.finish();
    let windows = windows
        .iter()
        .map(|w| [w[0] + t_rotate, w[1] + t_rotate])
        .collect();
    let duration_s = t_rotate + phi.end_s();
    Ok(Box::new(XcCam {
        axes: ctx.axes.to_vec(),
        ix,
        ic,
        geometry,
        phi,
        phi0,
        approach,
        t_rotate,
        duration_s,
        windows,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::*;

    fn geometries() -> Vec<XcGeometry> {
        let table: Vec<f64> = (0..72)
            .map(|i| {
                let p = 2.0 * PI * i as f64 / 72.0;
                0.03 + 0.002 * p.cos() + 0.0005 * (2.0 * p).sin()
            })
            .collect();
        vec![
            XcGeometry {
                profile: CamProfile::Eccentric {
                    eccentricity_m: 0.005,
                    disc_radius_m: 0.03,
                },
                wheel_radius_m: 0.2,
            },
            XcGeometry {
                profile: CamProfile::RiseDwell {
                    base_radius_m: 0.025,
                    lift_m: 0.006,
                    rise_start_rad: 0.3,
                    rise_rad: 1.6,
                    dwell_rad: 0.4,
                    fall_rad: 1.6,
                },
                wheel_radius_m: 0.15,
            },
            XcGeometry {
                profile: CamProfile::from_table(&table, 32),
                wheel_radius_m: 0.1,
            },
        ]
    }

    #[test]
    fn the_commanded_axes_put_the_wheel_exactly_on_the_profile() {
        for g in geometries() {
            for i in 0..50 {
                let phi = 0.1 + 2.0 * PI * i as f64 / 50.0;
                let (x, c) = g.axes_at(phi);
                let e = g.profile_error_m(x, c, phi + 0.01);
                assert!(e.abs() < 1e-12, "{:?} at {phi}: {e}", g.profile);
                // The wheel centre W = X (cos C, -sin C) is R from the contact point along the
                // normal.
                let [r, dr, _] = g.profile.derivatives(phi);
                let s = r.hypot(dr);
                let (sp, cp) = phi.sin_cos();
                let n = [(r * cp + dr * sp) / s, (r * sp - dr * cp) / s];
                let w = [x * c.cos(), -x * c.sin()];
                assert!((w[0] - (r * cp + g.wheel_radius_m * n[0])).abs() < 1e-12);
                assert!((w[1] - (r * sp + g.wheel_radius_m * n[1])).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn the_coupling_gains_match_the_exact_geometry_by_perturbation() {
        for g in geometries() {
            let mut worst: f64 = 0.0;
            let (mut gx_err, mut gc_err): (f64, f64) = (0.0, 0.0);
            for i in 0..40 {
                let phi = 0.05 + 2.0 * PI * i as f64 / 40.0;
                let (x, c) = g.axes_at(phi);
                let (gx, gc) = g.gains(phi);
                let d = 1e-7;
                let ex = (g.profile_error_m(x + d, c, phi) - g.profile_error_m(x - d, c, phi))
                    / (2.0 * d);
                let ec = (g.profile_error_m(x, c + d, phi) - g.profile_error_m(x, c - d, phi))
                    / (2.0 * d);
                gx_err = gx_err.max((ex - gx).abs());
                gc_err = gc_err.max((ec - gc).abs());
                assert!(
                    (ex - gx).abs() < 1e-6,
                    "{:?} phi {phi}: dEps/dX {ex} vs Gx {gx}",
                    g.profile
                );
                assert!(
                    (ec - gc).abs() < 1e-6 * (1.0 + gc.abs()),
                    "phi {phi}: dEps/dC {ec} vs Gc {gc}"
                );
                // Combined small errors: eps ~ Gx ex + Gc ec to second order.
                let (dx, dc) = (3e-6, -2e-5);
                let exact = g.profile_error_m(x + dx, c + dc, phi);
                let lin = gx * dx + gc * dc;
                worst = worst.max((exact - lin).abs());
            }
            eprintln!(
                "Gx, Gc vs perturbation: max |dEps/dX - Gx| = {gx_err:.1e}, max |dEps/dC - Gc| = {gc_err:.1e} m/rad, linearisation error {worst:.1e} m"
            );
            assert!(
                worst < 1e-9,
                "{:?}: linearisation off by {worst} m for 3 um / 20 urad",
                g.profile
            );
        }
    }

    #[test]
    fn gx_is_one_and_gc_is_zero_on_a_round_part() {
        let g = XcGeometry {
            profile: CamProfile::Eccentric {
                eccentricity_m: 0.0,
                disc_radius_m: 0.02,
            },
            wheel_radius_m: 0.1,
        };
        let (x, c) = g.axes_at(1.0);
        assert!((x - 0.12).abs() < 1e-15 && (c + 1.0).abs() < 1e-15);
        let (gx, gc) = g.gains(1.0);
        assert!((gx - 1.0).abs() < 1e-15 && gc.abs() < 1e-15);
    }

    const CAM: &str = r#"
kind = "xc_cam"
axes = ["x", "c"]
wheel_radius_m = 0.2
profile = "eccentric"
eccentricity_m = 0.005
disc_radius_m = 0.03
speed_rad_per_s = 6.0
turns = 2
ramp_s = 0.2
approach_s = 0.3
x_start_m = 0.24
dwell_after_s = 0.1
"#;

    #[test]
    fn cam_commands_have_analytic_derivatives_and_a_zero_error_when_tracked() {
        let tr = built(CAM, &["x", "c"]);
        let expect = 0.3 + 4.0 * PI / 6.0 + 0.2 + 0.1;
        assert!((tr.duration_s() - expect).abs() < 1e-9);
        let start = at(tr.as_ref(), 0.0);
        assert!((start[0][0] - 0.24).abs() < 1e-15 && start[1][0] == 0.0);
        let worst = check_derivatives(tr.as_ref(), 500, 1e-6, &[]);
        assert!(worst < 1e-4, "{worst}");
        for k in 0..200 {
            let t = 0.3 + 2.0 * k as f64 / 200.0;
            let s = at(tr.as_ref(), t);
            let e = tr.contour_error_m(t, &[s[0][0], s[1][0]]).unwrap();
            assert!(e.abs() < 1e-12, "{t}: {e}");
            // 1 um of X error on the command shows as Gx um of profile error.
            let e = tr.contour_error_m(t, &[s[0][0] + 1e-6, s[1][0]]).unwrap();
            assert!(e > 0.9e-6 && e < 1.1e-6, "{e}");
        }
        // In the steady part C turns at about -speed on average over a turn.
        let w = tr.steady_windows_s();
        assert_eq!(w.len(), 1);
        assert!((w[0][0] - 0.5).abs() < 1e-12);
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn profile_error_is_exact_when_c_lags_by_more_than_a_radian() {
        let tr = built(CAM, &["x", "c"]);
        let g = XcGeometry {
            profile: CamProfile::Eccentric {
                eccentricity_m: 0.005,
                disc_radius_m: 0.03,
            },
            wheel_radius_m: 0.2,
        };
        let mut from_command: f64 = 0.0;
        for k in 0..40 {
            let t = 0.6 + 1.5 * k as f64 / 40.0;
            let s = at(tr.as_ref(), t);
            let (phi_cmd, _, _) = g.contact_of_c(s[1][0], f64::NAN);
            for lag in [0.25, 0.7, 1.0, 1.3, 1.6] {
                // the wheel 10 um off the profile where C stands, `lag` behind the command
                let phi = phi_cmd - lag;
                let (x, c) = g.axes_at(phi);
                let x = x + 10e-6 / g.gains(phi).0;
                let e = tr.contour_error_m(t, &[x, c]).unwrap();
                assert!((e - 10e-6).abs() < 1e-9, "t {t} lag {lag}: {e}");
                from_command = from_command.max((g.profile_error_m(x, c, phi_cmd) - 10e-6).abs());
            }
        }
        // Newton on the distance started at the commanded angle finds another branch
        assert!(from_command > 1e-3, "{from_command}");
    }

    #[test]
    fn a_profile_the_wheel_cannot_grind_is_refused() {
        let e = refused_at("kind = \"xc_cam\"\nwheel_radius_m = 0.2\nprofile = \"table\"\nradius_table_m = [0.03, 0.03, 0.03, 0.01, 0.03, 0.03, 0.03, 0.03, 0.03, 0.03, 0.03, 0.03]\nspeed_rad_per_s = 1", &["x", "c"], "trajectory.profile");
        assert!(e.reason.contains("concave"), "{e}");
        refused_at("kind = \"xc_cam\"\nwheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.05\ndisc_radius_m = 0.03\nspeed_rad_per_s = 1", &["x", "c"], "trajectory.eccentricity_m");
        refused_at("kind = \"xc_cam\"\nwheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.005\ndisc_radius_m = 0.03\nspeed_rad_per_s = 1\nx_start_m = 0.3", &["x", "c"], "trajectory.approach_s");
    }

    #[test]
    fn a_table_profile_reproduces_its_samples() {
        let radii: Vec<f64> = (0..64)
            .map(|i| 0.03 + 0.001 * (2.0 * PI * 3.0 * i as f64 / 64.0).cos())
            .collect();
        let p = CamProfile::from_table(&radii, 31);
        for (i, r) in radii.iter().enumerate() {
            let got = p.derivatives(2.0 * PI * i as f64 / 64.0)[0];
            assert!((got - r).abs() < 1e-15, "{i}");
        }
        // r' of a pure 3rd harmonic.
        let d = p.derivatives(0.4)[1];
        assert!((d - (-0.003 * (3.0f64 * 0.4).sin())).abs() < 1e-14);
    }
}
