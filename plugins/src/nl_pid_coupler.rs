//! `nl_pid_coupler`: nonlinear PID coupling controller for X-C cam grinding on the profile error
//! (seed 003, claims 1-10: profile error from both axes' tracking errors, nonlinear PID whose
//! gains vary with hyperbolic and exponential functions over the response, correction
//! distributed to both drives by the coupling gains).
//!
//! Geometry (as the `xc_cam` trajectory, [`feedloop_motion::cam`]): profile r(phi),
//! wheel radius R, S = sqrt(r^2 + r'^2); X = sqrt(r^2 + R^2 + 2 R r^2 / S) (m),
//! C = -phi + atan(R r' / (r (S + R))) (rad). The contact angle phi is found each cycle from the
//! commanded C by Newton's method (warm-started from the last cycle).
//!
//! Profile error (m, positive = material left), linearised about the command:
//! eps = Gx (X - X*) + Gc (C - C*), Gx = (R + r^2/S) / X (m/m), Gc = r r'/S (m/rad),
//! with X, C the measured load positions and X*, C* the commands; its rate uses the measured
//! motor velocities and the commanded velocities the same way.
//!
//! Nonlinear PID on eps (u in m/s), the gains scheduled on |eps|, i.e. on the region of the
//! response (large error: stiff and without integral; near zero: soft, integrating and damped):
//! - Kp(eps) = kp_min + (kp_max - kp_min) (1 - sech(|eps| / kp_width))   (hyperbolic, 1/s)
//! - Ki(eps) = ki_max sech(|eps| / ki_width)                              (hyperbolic, 1/s^2)
//! - Kd(eps) = kd_min + (kd_max - kd_min) exp(-|eps| / kd_width)          (exponential, 1)
//! - u = Kp eps + I + Kd eps',  I' = Ki(eps) eps (the gain applied to the increment, so a
//!   changing Ki never kicks the output), |I| and |u| limited to `max_correction_m_per_s`.
//!
//! Distribution: vel_cmd_X -= Gx u / (Gx^2 + Gc^2), vel_cmd_C -= Gc u / (Gx^2 + Gc^2) (converted
//! to motor units), so with ideal drives the correction changes eps' by exactly -u. Gc is a few
//! mm/rad while Gx is about 1, so X (the fast linear motor) does almost all of the correcting.
//!
//! Keys: `wheel_radius_m`, `profile` and its keys exactly as in the `xc_cam` trajectory
//! (`eccentricity_m`, `disc_radius_m` | `base_radius_m`, `lift_m`, `rise_start_rad`, `rise_rad`,
//! `dwell_rad`, `fall_rad` | `radius_table_m`, `harmonics`); `kp_min_per_s` (default 60),
//! `kp_max_per_s` (150), `kp_width_m` (50e-6), `ki_max_per_s2` (2000), `ki_width_m` (50e-6),
//! `kd_min` (0), `kd_max` (0.3), `kd_width_m` (20e-6), `max_correction_m_per_s` (0.1).
//! Ranges: Kp <= 200 1/s, Ki <= 2e4 1/s^2, Kd <= 0.5 (a derivative gain g on the error rate
//! scales the axes' velocity loop gain by up to 1 + g: 0.5 keeps any velocity loop with 3.5 dB
//! of gain margin stable).

use std::path::Path;

use feedloop_control::controller::{AxisContext, AxisSignals, Coupler, CycleContext};
use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};
use feedloop_motion::cam::XcGeometry;

/// The scheduled gains of the nonlinear PID.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NlPidGains {
    /// Kp at zero error, 1/s.
    pub kp_min_per_s: f64,
    /// Kp at large error, 1/s.
    pub kp_max_per_s: f64,
    /// |eps| scale of the Kp schedule, m.
    pub kp_width_m: f64,
    /// Ki at zero error, 1/s^2.
    pub ki_max_per_s2: f64,
    /// |eps| scale of the Ki schedule, m.
    pub ki_width_m: f64,
    /// Kd at large error.
    pub kd_min: f64,
    /// Kd at zero error.
    pub kd_max: f64,
    /// |eps| scale of the Kd schedule, m.
    pub kd_width_m: f64,
}

impl Default for NlPidGains {
    fn default() -> Self {
        Self {
            kp_min_per_s: 60.0,
            kp_max_per_s: 150.0,
            kp_width_m: 50e-6,
            ki_max_per_s2: 2000.0,
            ki_width_m: 50e-6,
            kd_min: 0.0,
            kd_max: 0.3,
            kd_width_m: 20e-6,
        }
    }
}

fn sech(x: f64) -> f64 {
    // 1 / cosh without overflow for large |x|
    let e = (-x.abs()).exp();
    2.0 * e / (1.0 + e * e)
}

impl NlPidGains {
    /// (Kp, Ki, Kd) at profile error `eps` (m).
    pub fn at(&self, eps: f64) -> (f64, f64, f64) {
        let a = eps.abs();
        let kp = self.kp_min_per_s
            + (self.kp_max_per_s - self.kp_min_per_s) * (1.0 - sech(a / self.kp_width_m));
        let ki = self.ki_max_per_s2 * sech(a / self.ki_width_m);
        let kd = self.kd_min + (self.kd_max - self.kd_min) * (-a / self.kd_width_m).exp();
        (kp, ki, kd)
    }
}

/// The terms of the last output, m/s, and the error they acted on.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CouplerTerms {
    /// Linearised profile error, m.
    pub eps_m: f64,
    /// Its rate, m/s.
    pub eps_rate_m_per_s: f64,
    /// Coupling gains (Gx, Gc).
    pub gains: (f64, f64),
    /// Proportional, integral, derivative terms, m/s.
    pub p: f64,
    /// Integral term.
    pub i: f64,
    /// Derivative term.
    pub d: f64,
    /// Whether the output was limited.
    pub limited: bool,
}

/// Parameters of [`NlPidCoupler`].
#[derive(Debug, Clone, PartialEq)]
pub struct NlPidCouplerParams {
    /// The grinding geometry.
    pub geometry: XcGeometry,
    /// The gain schedule.
    pub gains: NlPidGains,
    /// Output (and integral) limit, m/s.
    pub max_correction_m_per_s: f64,
}

impl NlPidCouplerParams {
    /// Reads the coupler keys (`file` for messages).
    pub fn from_table(params: &toml::Table, file: &Path) -> Result<Self, ConfigError> {
        let mut f = Fields::new(params, file, "");
        let wheel = f.f64("wheel_radius_m", Range::Positive)?;
        let profile = feedloop_motion::cam::read_profile(&mut f)?;
        let d = NlPidGains::default();
        let width = Range::Within(1e-12, 1.0);
        let g = NlPidGains {
            kp_min_per_s: f.f64_or("kp_min_per_s", Range::Within(0.0, 200.0), d.kp_min_per_s)?,
            kp_max_per_s: f.f64_or("kp_max_per_s", Range::Within(0.0, 200.0), d.kp_max_per_s)?,
            kp_width_m: f.f64_or("kp_width_m", width, d.kp_width_m)?,
            ki_max_per_s2: f.f64_or("ki_max_per_s2", Range::Within(0.0, 2e4), d.ki_max_per_s2)?,
            ki_width_m: f.f64_or("ki_width_m", width, d.ki_width_m)?,
            kd_min: f.f64_or("kd_min", Range::Within(0.0, 0.5), d.kd_min)?,
            kd_max: f.f64_or("kd_max", Range::Within(0.0, 0.5), d.kd_max)?,
            kd_width_m: f.f64_or("kd_width_m", width, d.kd_width_m)?,
        };
        let max = f.f64_or("max_correction_m_per_s", Range::Within(0.0, 10.0), 0.1)?;
        let geometry = XcGeometry::checked(profile, wheel, &f)?;
        f.finish()?;
        Ok(Self {
            geometry,
            gains: g,
            max_correction_m_per_s: max,
        })
    }
}

/// The X-C nonlinear PID coupler.
#[derive(Debug, Clone)]
pub struct NlPidCoupler {
    params: NlPidCouplerParams,
    /// [X, C] axis indices (job order).
    axes: [usize; 2],
    /// Motor units per load unit of X and C.
    scale: [f64; 2],
    /// Contact angle of the last cycle, rad (Newton warm start); NaN before the first.
    phi: f64,
    /// Change of the contact angle over the last cycle, rad (extrapolates the warm start).
    dphi: f64,
    /// Integral term, m/s.
    integral: f64,
    terms: CouplerTerms,
}

impl NlPidCoupler {
    /// Plugin id.
    pub const ID: &'static str = "nl_pid_coupler";

    /// Builds the coupler over `axes` = [X, C] (job order indices into `contexts`).
    pub fn new(
        params: NlPidCouplerParams,
        contexts: &[AxisContext],
        axes: &[usize],
        file: &Path,
    ) -> Result<Self, ConfigError> {
        let err = |r: String| ConfigError::new(file, "axes", r);
        if axes.len() != 2 {
            return Err(err(format!(
                "`{}` couples exactly two axes [X (linear), C (rotary)], got {}",
                Self::ID,
                axes.len()
            )));
        }
        let (x, c) = (&contexts[axes[0]], &contexts[axes[1]]);
        if x.plant.kind() == AxisKind::Rotary {
            return Err(err(format!(
                "the first axis is X, a linear axis (rigid or ballscrew); `{}` is rotary",
                x.name
            )));
        }
        if c.plant.kind() != AxisKind::Rotary {
            return Err(err(format!(
                "the second axis is C, a rotary axis; `{}` is {}",
                c.name,
                c.plant.kind().id()
            )));
        }
        Ok(Self {
            params,
            axes: [axes[0], axes[1]],
            scale: [x.plant.motor_per_load(), c.plant.motor_per_load()],
            phi: f64::NAN,
            dphi: 0.0,
            integral: 0.0,
            terms: CouplerTerms::default(),
        })
    }

    /// Terms of the last cycle.
    pub fn terms(&self) -> CouplerTerms {
        self.terms
    }

    /// Contact angle whose C command is `c_cmd`, by Newton's method from `guess`.
    ///
    /// Newton converges quadratically here (`c(phi)` is smooth and monotonic): once a step is
    /// below 1e-6 rad, the error left after taking it is of the order of the step squared
    /// (< 1e-11 rad, under 1e-12 m on the profile), so it is taken without a further check. With
    /// the warm start extrapolated from the last two cycles that is usually the first step.
    fn contact_angle(&self, c_cmd: f64, guess: f64) -> f64 {
        let g = &self.params.geometry;
        let mut phi = if guess.is_finite() { guess } else { -c_cmd };
        for _ in 0..6 {
            // value and first derivative are all Newton needs
            let (_, c) = g.axis_jets::<2>(&[phi, 1.0]);
            let dc = c[1];
            if !(dc.is_finite() && dc.abs() > 1e-6) {
                break;
            }
            let step = ((c[0] - c_cmd) / dc).clamp(-0.5, 0.5);
            phi -= step;
            if step.abs() < 1e-6 {
                break;
            }
        }
        phi
    }

    fn reset(&mut self) {
        self.integral = 0.0;
        self.phi = f64::NAN;
        self.dphi = 0.0;
        self.terms = CouplerTerms::default();
    }
}

impl Coupler for NlPidCoupler {
    fn id(&self) -> &str {
        Self::ID
    }

    fn axes(&self) -> &[usize] {
        &self.axes
    }

    fn step(&mut self, ctx: &CycleContext, axes: &mut [AxisSignals]) {
        let [ix, ic] = self.axes;
        if ix >= axes.len() || ic >= axes.len() {
            return;
        }
        let [kx, kc] = self.scale;
        let (sx, sc) = (&axes[ix], &axes[ic]);
        let c_cmd = sc.reference[0] / kc;
        let phi = self.contact_angle(c_cmd, self.phi + self.dphi);
        let (gx, gc) = self.params.geometry.gains(phi);
        // actual - command, load units
        let ex = (sx.load_pos - sx.reference[0]) / kx;
        let ec = (sc.load_pos - sc.reference[0]) / kc;
        let rx = (sx.motor_vel - sx.reference[1]) / kx;
        let rc = (sc.motor_vel - sc.reference[1]) / kc;
        let eps = gx * ex + gc * ec;
        let eps_rate = gx * rx + gc * rc;
        let g2 = gx * gx + gc * gc;
        if !(eps.is_finite() && eps_rate.is_finite() && g2.is_finite() && g2 > 0.0) {
            self.reset();
            return;
        }
        self.dphi = if self.phi.is_finite() {
            phi - self.phi
        } else {
            0.0
        };
        self.phi = phi;
        let lim = self.params.max_correction_m_per_s;
        let (kp, ki, kd) = self.params.gains.at(eps);
        self.integral = (self.integral + ctx.period_s * ki * eps).clamp(-lim, lim);
        let (p, d) = (kp * eps, kd * eps_rate);
        let raw = p + self.integral + d;
        let u = raw.clamp(-lim, lim);
        self.terms = CouplerTerms {
            eps_m: eps,
            eps_rate_m_per_s: eps_rate,
            gains: (gx, gc),
            p,
            i: self.integral,
            d,
            limited: u != raw,
        };
        axes[ix].vel_cmd -= kx * gx * u / g2;
        axes[ic].vel_cmd -= kc * gc * u / g2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use feedloop_model::model::{PlantParams, RigidParams};

    fn contexts() -> Vec<AxisContext> {
        let x = crate::test_util::rigid_axis(1e-4);
        let c = crate::test_util::rotary_c_axis(5e4, 1e-4);
        vec![x, c]
    }

    fn params(extra: &str) -> NlPidCouplerParams {
        let t: toml::Table = format!(
            "wheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.005\ndisc_radius_m = 0.03\n{extra}"
        )
        .parse()
        .unwrap();
        NlPidCouplerParams::from_table(&t, Path::new("j.toml")).unwrap()
    }

    fn coupler(extra: &str) -> NlPidCoupler {
        NlPidCoupler::new(params(extra), &contexts(), &[0, 1], Path::new("j.toml")).unwrap()
    }

    fn signals_at(c: &NlPidCoupler, phi: f64) -> Vec<AxisSignals> {
        let (x, cc) = c.params.geometry.axes_at(phi);
        let mut s = vec![AxisSignals::default(); 2];
        s[0].reference[0] = x;
        s[0].load_pos = x;
        s[1].reference[0] = cc;
        s[1].load_pos = cc;
        s
    }

    const CTX: CycleContext = CycleContext {
        period_s: 1e-4,
        cycle: 0,
        t_s: 0.0,
    };

    #[test]
    fn contact_angle_is_recovered_from_the_c_command_over_a_turn() {
        let c = coupler("");
        for i in 0..24 {
            let phi = std::f64::consts::TAU * i as f64 / 24.0 + 0.1;
            let (_, cc) = c.params.geometry.axes_at(phi);
            let got = c.contact_angle(cc, f64::NAN);
            assert!((got - phi).abs() < 1e-10, "{phi}: {got}");
        }
    }

    #[test]
    fn x_lagging_by_2_um_gives_gx_times_2_um_and_a_correction_pushing_x_on() {
        let mut c = coupler("kd_max = 0\nki_max_per_s2 = 0");
        let phi = 1.0;
        let mut s = signals_at(&c, phi);
        s[0].load_pos -= 2e-6; // X behind its command: wheel too close -> material removed
        c.step(&CTX, &mut s);
        let t = c.terms();
        let (gx, gc) = c.params.geometry.gains(phi);
        assert!((t.eps_m + gx * 2e-6).abs() < 1e-15, "{t:?}");
        assert!(s[0].vel_cmd > 0.0, "X is pushed on: {}", s[0].vel_cmd);
        // the correction moves eps back up: dEps = Gx dX + Gc dC > 0
        let deps = gx * s[0].vel_cmd + gc * s[1].vel_cmd;
        let kp = c.params.gains.at(t.eps_m).0;
        assert!((deps - kp * gx * 2e-6).abs() < 1e-12, "{deps}");
    }

    #[test]
    fn gain_schedule_is_stiff_at_large_error_and_integrating_near_zero() {
        let g = NlPidGains::default();
        let (kp0, ki0, kd0) = g.at(0.0);
        assert_eq!((kp0, ki0, kd0), (60.0, 2000.0, 0.3));
        let (kp1, ki1, kd1) = g.at(0.01);
        assert!((kp1 - 150.0).abs() < 1e-9 && ki1 < 1e-9 && kd1 < 1e-9);
        // hyperbolic: Kp at eps = width is kp_min + (kp_max - kp_min)(1 - sech 1)
        let (kp, ki, _) = g.at(-50e-6);
        assert!((kp - (60.0 + 90.0 * (1.0 - 1.0 / 1f64.cosh()))).abs() < 1e-9);
        assert!((ki - 2000.0 / 1f64.cosh()).abs() < 1e-9);
        // exponential: Kd at eps = width is kd_max / e
        let (_, _, kd) = g.at(20e-6);
        assert!((kd - 0.3 / std::f64::consts::E).abs() < 1e-12);
    }

    #[test]
    fn non_finite_measurement_adds_nothing_and_resets_the_integral() {
        let mut c = coupler("");
        let mut s = signals_at(&c, 0.5);
        s[0].load_pos -= 1e-6;
        for _ in 0..10 {
            c.step(&CTX, &mut s);
        }
        assert!(c.integral != 0.0);
        let mut s = signals_at(&c, 0.5);
        s[1].load_pos = f64::NAN;
        c.step(&CTX, &mut s);
        assert_eq!((s[0].vel_cmd, s[1].vel_cmd), (0.0, 0.0));
        assert_eq!(c.integral, 0.0);
    }

    #[test]
    fn output_is_limited_to_max_correction() {
        let mut c = coupler("max_correction_m_per_s = 0.001");
        let mut s = signals_at(&c, 0.5);
        s[0].load_pos -= 0.001;
        c.step(&CTX, &mut s);
        let t = c.terms();
        assert!(t.limited);
        let (gx, gc) = t.gains;
        let deps = gx * s[0].vel_cmd + gc * s[1].vel_cmd;
        assert!((deps - 0.001).abs() < 1e-12, "{deps}");
    }

    #[test]
    fn c_axis_must_be_rotary_and_x_linear() {
        let ctx = contexts();
        let e = NlPidCoupler::new(params(""), &ctx, &[1, 0], Path::new("j")).unwrap_err();
        assert_eq!(e.key, "axes");
        let e = NlPidCoupler::new(params(""), &ctx, &[0], Path::new("j")).unwrap_err();
        assert_eq!(e.key, "axes");
        let mut rigid_c = ctx.clone();
        rigid_c[1].plant = PlantParams::Rigid(RigidParams {
            mass_kg: 1.0,
            viscous_ns_per_m: 0.0,
        });
        assert!(NlPidCoupler::new(params(""), &rigid_c, &[0, 1], Path::new("j")).is_err());
    }

    #[test]
    fn kd_above_one_half_is_refused_naming_the_key() {
        let t: toml::Table = "wheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.005\ndisc_radius_m = 0.03\nkd_max = 0.8".parse().unwrap();
        let e = NlPidCouplerParams::from_table(&t, Path::new("j")).unwrap_err();
        assert_eq!(e.key, "kd_max");
    }
}
