//! `nl_pid_coupler`: nonlinear PID coupling controller for X-C cam grinding on the profile error
//! (seed 003, claims 1-10: profile error from both axes' tracking errors, nonlinear PID whose
//! gains vary with hyperbolic and exponential functions over the response, correction
//! distributed to both drives by the coupling gains).
//!
//! Geometry (as the `xc_cam` trajectory, [`feedloop_motion::cam`]): profile r(phi),
//! wheel radius R, S = sqrt(r^2 + r'^2); X = sqrt(r^2 + R^2 + 2 R r^2 / S) (m),
//! C = -phi + atan(R r' / (r (S + R))) (rad). Gx = (R + r^2/S) / X (m/m), Gc = r r'/S (m/rad)
//! are the profile error's derivatives by X and C (seed 003's coupling gains).
//!
//! Profile error (m, positive = material left), key `contact`:
//! - `"measured"` (default): at the contact angle phi_m of the measured C (Newton's method on
//!   C(phi) = C, [`XcGeometry::contact_of_c`], warm-started from the last cycle),
//!   eps = Gx(phi_m) (X - X(phi_m)) - eps*, where
//!   eps* = Gx(phi*) (X* - X(phi*)) is the command's own distance from the profile (phi* the
//!   contact angle of the commanded C; 0 while grinding, not on an approach move). Exact in the C
//!   error, first order in the X error (the wheel moves along the X line).
//! - `"commanded"`: the seed's linearisation about the command,
//!   eps = Gx(phi*) (X - X*) + Gc(phi*) (C - C*). When C lags by a quarter of a radian (a slow
//!   C loop at 1 rev/s) this is off by up to 208 um on the shipped cam, as large as the error
//!   the coupler is meant to remove.
//!
//! The rate is eps' = Gx vX + Gc vC - (Gx X*' + Gc C*') with the measured velocities (the
//! gains at the same contact angle; the command's rate taken at phi*).
//!
//! Nonlinear PID on eps (u in m/s), the gains scheduled on |eps|, i.e. on the region of the
//! response (large error: stiff and without integral; near zero: soft, integrating and damped):
//! - Kp(eps) = kp_min + (kp_max - kp_min) (1 - sech(|eps| / kp_width))   (hyperbolic, 1/s)
//! - Ki(eps) = ki_max sech(|eps| / ki_width)                              (hyperbolic, 1/s^2)
//! - Kd(eps) = kd_min + (kd_max - kd_min) exp(-|eps| / kd_width)          (exponential, 1)
//! - u = Kp eps + I + Kd eps',  I' = Ki(eps) eps (the gain applied to the increment, so a
//!   changing Ki never kicks the output), |I| and |u| limited to `max_correction_m_per_s`.
//!
//! Distribution by the coupling gains: vel_cmd_X -= Gx w / (Gx^2 + Gc^2),
//! vel_cmd_C -= Gc w / (Gx^2 + Gc^2) (converted to motor units), key `axis_loops`:
//! - `"tangential"` (default): w = u + (Gx V_X + Gc vC - (Gx X*' + Gc C*')), with V_X the X
//!   velocity command the stages before the coupler made and vC C's measured velocity. The
//!   bracket is the profile-error rate the axes' own loops would cause on top of the command's:
//!   X's loop chases X* while C lags, and with mismatched loops that alone makes the profile
//!   error (777 um on the shipped job). Removing it leaves the axes' loops acting along the
//!   profile only; normal to it X follows C as C really moves, and the coupler's PID is the
//!   position feedback (so its Kp must be >= 30 1/s, [`TANGENTIAL_MIN_KP_PER_S`]).
//! - `"full"`: w = u, the correction added to the axes' full loops (the two pull against each
//!   other: 264 um left on the shipped job with `contact = "commanded"`).
//!
//! With ideal drives and `"tangential"` the X-C motion then changes eps at the rate -u. Gc is a
//! few mm/rad while Gx is about 1, so X (the fast linear motor) does almost all of the
//! correcting.
//!
//! Keys: `wheel_radius_m`, `profile` and its keys exactly as in the `xc_cam` trajectory
//! (`eccentricity_m`, `disc_radius_m` | `base_radius_m`, `lift_m`, `rise_start_rad`, `rise_rad`,
//! `dwell_rad`, `fall_rad` | `radius_table_m`, `harmonics`); `kp_min_per_s` (default 60),
//! `kp_max_per_s` (150), `kp_width_m` (50e-6), `ki_max_per_s2` (2000), `ki_width_m` (50e-6),
//! `kd_min` (0), `kd_max` (0.3), `kd_width_m` (20e-6), `max_correction_m_per_s` (0.1),
//! `contact` (`"measured"` | `"commanded"`), `axis_loops` (`"tangential"` | `"full"`).
//! `x_bandwidth_share` (0.25): the largest Kp is at most this share of X's velocity-loop
//! bandwidth (X's velocity gain Kv, as its chain's velocity stage runs it, else its model's
//! `[controller]`, over the mass or inertia the motor moves; 0 = no limit); above it Kp is clamped and Ki slowed with it ([`NlPidGains::slowed_to`]):
//! the loop normal to the profile is a position loop around X's velocity loop, and with the
//! shipped schedule it went unstable on a 60 rad/s X velocity loop (rise-dwell cam: 938 um
//! independent, 1485 um coupled and growing; clamped to 15 1/s: 164 um, settling).
//!
//! Ranges: Kp <= 200 1/s (>= 30 with `"tangential"`, before the clamp for a slow X), Ki <= 2e4
//! 1/s^2, Kd <= 0.5 (a derivative gain g on the error rate scales the axes' velocity loop gain
//! by up to 1 + g: 0.5 keeps any velocity loop with 3.5 dB of gain margin stable).

use std::path::Path;

use feedloop_control::controller::{AxisContext, AxisSignals, Coupler, CycleContext};
use feedloop_model::key_choice;
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
    /// The schedule with Kp at most `kp_limit_per_s` (kp_min and kp_max clamped to it) and
    /// Ki times s^2, s = kp_limit / kp_min (when below 1), Kd unchanged: near zero error, where
    /// Ki acts, the loop normal to the profile keeps its damping (Kp^2 / Ki) and runs s times
    /// slower.
    pub fn slowed_to(self, kp_limit_per_s: f64) -> Self {
        // (a limit that is not a positive number leaves the schedule as it is)
        if kp_limit_per_s.is_nan() || kp_limit_per_s <= 0.0 {
            return self;
        }
        let s = (kp_limit_per_s / self.kp_min_per_s).min(1.0);
        Self {
            kp_min_per_s: self.kp_min_per_s.min(kp_limit_per_s),
            kp_max_per_s: self.kp_max_per_s.min(kp_limit_per_s),
            ki_max_per_s2: self.ki_max_per_s2 * s * s,
            ..self
        }
    }

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
    /// Where the profile error is linearised (`contact`).
    pub contact: Contact,
    /// What the axes' own loops still command (`axis_loops`).
    pub axis_loops: AxisLoops,
    /// Largest Kp as a share of X's velocity-loop bandwidth (`x_bandwidth_share`; 0 = no limit).
    pub x_bandwidth_share: f64,
}

/// Lowest Kp (1/s) of the schedule with [`AxisLoops::Tangential`]: the profile error then
/// settles only through the coupler; below about 30 1/s its slowest mode (Ki, Kd anywhere in
/// their ranges) was measured to shrink by less than 30 % per 0.1 s on the X-C cam job.
pub const TANGENTIAL_MIN_KP_PER_S: f64 = 30.0;

/// What the axes' own loops (the stages before the coupler) still command (key `axis_loops`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisLoops {
    /// `"tangential"` (default): their motion along the profile only. The coupler removes the
    /// profile-error rate their velocity commands would cause (X's command with C's measured
    /// motion) and commands the command's own rate minus its correction instead, so the profile
    /// error no longer depends on how differently the two axes lag.
    Tangential,
    /// `"full"`: their full velocity commands; the coupler's correction is added to them (the
    /// two loops then pull against each other whenever the axes lag differently).
    Full,
}

/// Where the coupler linearises the profile error (key `contact`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Contact {
    /// `"measured"` (default): at the contact angle of the measured C, eps = Gx (X - X(phi_C)).
    /// Exact in the C error, first order in the X error.
    Measured,
    /// `"commanded"`: at the commanded contact angle, eps = Gx (X - X*) + Gc (C - C*) (the
    /// seed's formula; first order in both errors, off by hundreds of um when C lags by 0.25 rad).
    Commanded,
}

key_choice!(AxisLoops, "axis_loops", default Tangential, ["tangential" => Tangential, "full" => Full]);
key_choice!(Contact, "contact", default Measured, ["measured" => Measured, "commanded" => Commanded]);

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
        let contact: Contact = f.choose("contact")?;
        let share = f.f64_or("x_bandwidth_share", Range::Within(0.0, 1.0), 0.25)?;
        let axis_loops: AxisLoops = f.choose("axis_loops")?;
        if axis_loops == AxisLoops::Tangential {
            // the coupler is then the only position feedback normal to the profile
            for (key, kp) in [
                ("kp_min_per_s", g.kp_min_per_s),
                ("kp_max_per_s", g.kp_max_per_s),
            ] {
                if kp < TANGENTIAL_MIN_KP_PER_S {
                    return Err(f.error(
                        key,
                        format!(
                            "must be at least {TANGENTIAL_MIN_KP_PER_S} 1/s with axis_loops = \"tangential\" (the default: the coupler is the only position feedback normal to the profile), got {kp}; axis_loops = \"full\" accepts 0 .. 200"
                        ),
                    ));
                }
            }
            if max <= 0.0 {
                return Err(f.error(
                    "max_correction_m_per_s",
                    "must be > 0 with axis_loops = \"tangential\" (the default: the coupler is the only position feedback normal to the profile)",
                ));
            }
        }
        let geometry = XcGeometry::checked(profile, wheel, &f)?;
        f.finish()?;
        Ok(Self {
            geometry,
            gains: g,
            max_correction_m_per_s: max,
            contact,
            axis_loops,
            x_bandwidth_share: share,
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
    /// Warm starts of the contact angles of the command and of the measured C.
    warm: [WarmStart; 2],
    /// Integral term, m/s.
    integral: f64,
    terms: CouplerTerms,
    /// The commanded contact of a cycle, solved ahead ([`Coupler::prepare`]): the cycle, the
    /// commanded C and warm-start guess it was solved for, and the solution.
    ahead: Option<(u64, f64, f64, Contact0)>,
}

/// A contact solution of [`XcGeometry::contact_of_c`]: angle, X on the profile, gains.
type Contact0 = (f64, f64, (f64, f64));

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
        let mut params = params;
        if params.x_bandwidth_share > 0.0 {
            params.gains = params
                .gains
                .slowed_to(x_velocity_bandwidth_per_s(x) * params.x_bandwidth_share);
        }
        Ok(Self {
            params,
            axes: [axes[0], axes[1]],
            scale: [x.plant.motor_per_load(), c.plant.motor_per_load()],
            warm: [WarmStart::COLD; 2],
            integral: 0.0,
            terms: CouplerTerms::default(),
            ahead: None,
        })
    }

    /// The gain schedule in use (slowed for a slow X velocity loop, [`NlPidGains::slowed_to`]).
    pub fn gains(&self) -> NlPidGains {
        self.params.gains
    }

    /// Terms of the last cycle.
    pub fn terms(&self) -> CouplerTerms {
        self.terms
    }

    fn reset(&mut self) {
        self.integral = 0.0;
        self.warm = [WarmStart::COLD; 2];
        self.terms = CouplerTerms::default();
    }
}

impl Coupler for NlPidCoupler {
    fn prepare(&mut self, ctx: &CycleContext, axes: &[AxisSignals]) {
        let ic = self.axes[1];
        let Some(sc) = axes.get(ic) else { return };
        let c_ref = sc.reference[0] / self.scale[1];
        let guess = self.warm[0].guess();
        self.ahead = Some((
            ctx.cycle,
            c_ref,
            guess,
            self.params.geometry.contact_of_c(c_ref, guess),
        ));
    }

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
        // commands and measurements in load units (m, rad; m/s, rad/s)
        let (x_ref, c_ref) = (sx.reference[0] / kx, sc.reference[0] / kc);
        let (vx_ref, vc_ref) = (sx.reference[1] / kx, sc.reference[1] / kc);
        let (x_m, c_m) = (sx.load_pos / kx, sc.load_pos / kc);
        let (vx, vc) = (sx.motor_vel / kx, sc.motor_vel / kc);
        let geometry = &self.params.geometry;
        // the commanded contact, solved ahead in the slack when it was for this very command
        // and guess (the same solve: the same result)
        let guess = self.warm[0].guess();
        let (phi_c, x_on_c, (gxc, gcc)) = match self.ahead.take() {
            Some((cycle, c, g, out))
                if cycle == ctx.cycle
                    && c.to_bits() == c_ref.to_bits()
                    && g.to_bits() == guess.to_bits() =>
            {
                out
            }
            _ => geometry.contact_of_c(c_ref, guess),
        };
        // the normal rate of the command (0 on the profile)
        let ref_rate = gxc * vx_ref + gcc * vc_ref;
        let (phi_m, gx, gc, eps) = match self.params.contact {
            Contact::Measured => {
                let (phi, x_on, (gx, gc)) = geometry.contact_of_c(c_m, self.warm[1].guess());
                // how far the wheel is off the profile minus how far the command is (0 when
                // grinding; not 0 on an approach move)
                (phi, gx, gc, gx * (x_m - x_on) - gxc * (x_ref - x_on_c))
            }
            Contact::Commanded => (phi_c, gxc, gcc, gxc * (x_m - x_ref) + gcc * (c_m - c_ref)),
        };
        let eps_rate = gx * vx + gc * vc - ref_rate;
        let g2 = gx * gx + gc * gc;
        if !(eps.is_finite() && eps_rate.is_finite() && g2.is_finite() && g2 > 0.0) {
            self.reset();
            return;
        }
        self.warm[0].update(phi_c);
        self.warm[1].update(phi_m);
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
        // the profile-error rate the upstream stages would cause beyond the command's, m/s
        let upstream = match self.params.axis_loops {
            AxisLoops::Tangential => gx * axes[ix].vel_cmd / kx + gc * vc - ref_rate,
            AxisLoops::Full => 0.0,
        };
        let total = u + upstream;
        axes[ix].vel_cmd -= kx * gx * total / g2;
        axes[ic].vel_cmd -= kc * gc * total / g2;
    }
}

/// X's velocity-loop bandwidth, 1/s: its velocity gain (the runtime hands couplers the gains the
/// chain runs with) over the inertia (or mass) the motor moves; infinite when none is known.
fn x_velocity_bandwidth_per_s(x: &AxisContext) -> f64 {
    match x.defaults.kv {
        Some(kv) if kv > 0.0 => kv / x.plant.total_inertia(),
        _ => f64::INFINITY,
    }
}

/// Warm start of a contact-angle solve: the last angle and its change over the last cycle.
#[derive(Debug, Clone, Copy)]
struct WarmStart {
    /// Last angle, rad; NaN before the first.
    phi: f64,
    /// Its change over the last cycle, rad.
    dphi: f64,
}

impl WarmStart {
    const COLD: Self = Self {
        phi: f64::NAN,
        dphi: 0.0,
    };

    /// The last angle extrapolated by a cycle (NaN when cold).
    fn guess(&self) -> f64 {
        self.phi + self.dphi
    }

    fn update(&mut self, phi: f64) {
        self.dphi = if self.phi.is_finite() {
            phi - self.phi
        } else {
            0.0
        };
        self.phi = phi;
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
            let (got, x, gains) = c.params.geometry.contact_of_c(cc, f64::NAN);
            assert!((got - phi).abs() < 1e-10, "{phi}: {got}");
            let (gx, gc) = c.params.geometry.gains(phi);
            assert!((x - c.params.geometry.axes_at(phi).0).abs() < 1e-12);
            assert!(
                (gains.0 - gx).abs() < 1e-7 && (gains.1 - gc).abs() < 1e-7,
                "{gains:?}"
            );
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

    #[test]
    fn measured_contact_gives_the_exact_profile_error_when_c_lags_a_quarter_radian() {
        // the wheel on the profile at a contact angle 0.25 rad behind the command, 30 um out
        let (phi_cmd, lag, out) = (2.0, 0.25, 30e-6);
        for (contact, within) in [("", 1e-9), ("contact = \"commanded\"", f64::INFINITY)] {
            let mut c = coupler(&format!("{contact}\nkd_max = 0\nki_max_per_s2 = 0"));
            let g = c.params.geometry.clone();
            let mut s = signals_at(&c, phi_cmd);
            let (x, cc) = g.axes_at(phi_cmd - lag);
            s[0].load_pos = x + out / g.gains(phi_cmd - lag).0;
            s[1].load_pos = cc;
            c.step(&CTX, &mut s);
            let exact = g.profile_error_m(s[0].load_pos, s[1].load_pos, phi_cmd - lag);
            let eps = c.terms().eps_m;
            assert!((exact - out).abs() < 1e-9, "{exact}");
            if within.is_finite() {
                assert!((eps - exact).abs() < within, "{eps} vs {exact}");
            } else {
                // the seed's linearisation about the command is far off
                assert!((eps - exact).abs() > 50e-6, "{eps} vs {exact}");
            }
        }
    }

    #[test]
    fn tangential_axis_loops_lose_the_profile_error_rate_they_would_cause() {
        let phi = 1.0;
        for (loops, kept) in [("", false), ("axis_loops = \"full\"", true)] {
            let mut c = coupler(&format!("{loops}\nkd_max = 0\nki_max_per_s2 = 0"));
            let mut s = signals_at(&c, phi);
            // the X loop asks for 1 mm/s, C's loop for 0.1 rad/s while C turns at 0.05 rad/s
            s[0].vel_cmd = 1e-3;
            s[1].vel_cmd = 0.1;
            s[1].motor_vel = 0.05;
            c.step(&CTX, &mut s);
            let (gx, gc) = c.terms().gains;
            assert!(c.terms().eps_m.abs() < 1e-12 && c.terms().p.abs() < 1e-9);
            let rate = gx * s[0].vel_cmd + gc * s[1].vel_cmd;
            if kept {
                assert!((rate - (gx * 1e-3 + gc * 0.1)).abs() < 1e-15, "{rate}");
            } else {
                // of the commands' profile-error rate only the part of C's loop catching up
                // with the 0.05 rad/s C lacks is left: X follows C as C really turns
                assert!((rate - gc * 0.05).abs() < 1e-15, "{rate} vs {}", gc * 0.05);
                assert!(s[0].vel_cmd.abs() > 1e-4, "X follows C: {}", s[0].vel_cmd);
            }
        }
    }

    #[test]
    fn tangential_axis_loops_need_a_coupler_kp_of_30_per_s() {
        for key in ["kp_min_per_s", "kp_max_per_s"] {
            let t: toml::Table = format!("wheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.005\ndisc_radius_m = 0.03\n{key} = 10.0").parse().unwrap();
            let e = NlPidCouplerParams::from_table(&t, Path::new("j")).unwrap_err();
            assert_eq!(e.key, key);
            assert!(e.reason.contains("axis_loops"), "{e}");
            let mut t = t;
            t.insert("axis_loops".into(), "full".into());
            assert!(NlPidCouplerParams::from_table(&t, Path::new("j")).is_ok());
        }
        let e = params_err("contact = \"nearest\"");
        assert_eq!(e.key, "contact");
        let e = params_err("axis_loops = \"normal\"");
        assert_eq!(e.key, "axis_loops");
        let e = params_err("max_correction_m_per_s = 0.0");
        assert_eq!(e.key, "max_correction_m_per_s");
    }

    #[test]
    fn a_slow_x_velocity_loop_slows_the_schedule_keeping_its_damping() {
        // test X: kv 8000 N s/m on 20 kg = 400 rad/s; a quarter is 100 1/s < kp_max 150
        let d = NlPidGains::default();
        let g = coupler("").gains();
        assert_eq!(
            g,
            NlPidGains {
                kp_max_per_s: 100.0,
                ..d
            }
        );
        // a tenth: 40 1/s, below kp_min as well
        let g = coupler("x_bandwidth_share = 0.1").gains();
        let s = 40.0 / 60.0;
        assert!(g.kp_min_per_s == 40.0 && g.kp_max_per_s == 40.0 && g.kd_max == 0.3);
        assert!((g.ki_max_per_s2 - 2000.0 * s * s).abs() < 1e-9);
        // Kp^2 / Ki, the damping of the loop normal to the profile near zero error, is kept
        let ratio = |g: NlPidGains| g.kp_min_per_s * g.kp_min_per_s / g.ki_max_per_s2;
        assert!((ratio(g) - ratio(d)).abs() < 1e-9);
        // off, or a share the gains stay under
        assert_eq!(coupler("x_bandwidth_share = 0").gains(), d);
        assert_eq!(coupler("x_bandwidth_share = 0.5").gains(), d);
    }

    fn params_err(extra: &str) -> ConfigError {
        let t: toml::Table = format!("wheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.005\ndisc_radius_m = 0.03\n{extra}").parse().unwrap();
        NlPidCouplerParams::from_table(&t, Path::new("j")).unwrap_err()
    }
}
