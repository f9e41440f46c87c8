//! `inverse_feedforward`: inverse-model feedforward of the 2-mass feed drive (seed 000, the
//! inverse characteristic model added to the cascade, Figs. 1-2 and the transfer function of VH).
//!
//! Plant (motor side, rad / N m; a rigid axis is the same with JL = 0, in m / N):
//! JM thM'' = tau - DM thM' - KL (thM - thL) - CL (thM' - thL'),
//! JL thL'' = KL (thM - thL) + CL (thM' - thL') - DL thL'.
//! Cascade: V = Kp (th - thL), tau = Kv (1 + 1/(Tv s)) (V + VH - wM).
//!
//! Asking for thL = th exactly gives the motor motion and torque the model needs:
//! thM = th + d with KL d + CL d' = JL th'' + DL th' (the twist of the screw), and
//! tau = JM thM'' + DM thM' + JL th'' + DL th'.
//!
//! Two structures (`structure`):
//! - `"literal"`: the patent's VH added to the velocity command, which the PI then integrates:
//!   VH = (b1 s + b2 s^2 + b3 s^3 + b4 s^4 + b5 s^5) th / (Kv (1 + Tv s) (1 + (CL/KL) s)),
//!   with a1 = Kv, a2 = Tv (DM + DL) + Kv (Tv + DL/KL),
//!   a3 = Tv (JM + JL + DM DL/KL) + Kv (Tv DL + JL)/KL,
//!   a4 = Tv (JM DL + DM JL)/KL + Kv Tv JL/KL, a5 = Tv JM JL/KL and b1 = a1, b2 = a2 + CL Kv/KL,
//!   b3 = a3 + CL Tv (DL + DM + Kv)/KL, b4 = a4 + CL Tv (JM + JL)/KL, b5 = a5 (CL = 0: b = a
//!   and the second lag vanishes). The lags are discretised with Tustin. For a
//!   proportional-only velocity loop (Tv = 0) VH = thM' + tau / Kv. The PI sums the sampled VH
//!   with the rectangle rule; with the Tustin lags this leaves 0.011 um on the brief's 50 mm /
//!   0.3 s move. `lag_discretisation = "backward_euler"` discretises the lags as the brief did
//!   (y_k = (tau y_{k-1} + T x_k) / (tau + T)): the lag and the PI's rectangle rule then cancel
//!   into a rectangle-rule integral of the numerator, which leads the continuous one by half a
//!   sample and leaves 0.85 um (the brief's ~0.6 um).
//! - `"split"` (default): the same inverse split at the PI: the motor's velocity reference thM'
//!   is added to the velocity command and the model torque tau directly to `torque_ff`, so the PI
//!   sees zero error when the plant follows the model. The torque is evaluated half a sample
//!   ahead (tau(t + T/2) by a first-order Taylor step, `torque_advance_s`): a zero-order-held
//!   torque then has the right mean over the period. 0.007 um on the same move (the rest is
//!   the zero-order hold's position lead, about T^2 tau / (12 J)).
//!
//! The twist uses the first two terms of d = (f - (CL/KL) f' + ...)/KL, f = JL th'' + DL th';
//! (CL/KL) w is below 1e-3 for any frequency a feed trajectory carries.
//!
//! Derivatives th', ..., th^(5) come analytically from the trajectory (`AxisSignals::reference`),
//! never from differencing the sampled command. The motor-velocity reference must be defined as
//! the plant measures motor velocity (`velocity_estimate`, as the plant's `[sensor]` key):
//! `"exact"` (the velocity at the sample instant, default) or `"difference"` (encoder position difference over the last period, i.e.
//! the mean velocity over [t - T, t] = thM'(t) - T/2 thM'' + T^2/6 thM''').
//!
//! Keys (model keys default to the axis model, loop keys to its `[controller]`):
//! `structure`; `jm_kgm2`, `dm_nms_per_rad`, `kl_nm_per_rad`, `cl_nms_per_rad`, `jl_kgm2`,
//! `dl_nms_per_rad` (ball-screw and rotary axes) or `mass_kg`, `viscous_ns_per_m` (rigid axes);
//! `kv_nms_per_rad` / `kv_ns_per_m` and `tv_s` (the PI being inverted; `literal` only);
//! `torque_advance_s` (s, default period / 2; `split` only); `velocity_estimate`;
//! `lag_discretisation` (`tustin`, default, or `backward_euler`; `literal` only).
//! `jl_kgm2` is the key inertia identification updates (a3..a5 depend on it).

use std::path::Path;

use feedloop_control::controller::{
    AxisContext, AxisSignals, Controller, ControllerState, CycleContext, Stage,
};
use feedloop_model::key_choice;
use feedloop_model::model::PlantParams;
use feedloop_model::params::{ConfigError, Fields, Range};

use crate::keys::{read_pi_gains, PiGains};
use crate::plugin::{axis_plugin, reference_only_plugin, PluginParams};

/// The 2-mass model the feedforward inverts (motor units; a rigid axis has `jl = 0`, `kl = inf`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwoMassModel {
    /// Motor inertia JM, kg m^2 (rigid axis: the mass, kg).
    pub jm: f64,
    /// Motor-side viscous damping DM, N m s/rad (rigid: N s/m).
    pub dm: f64,
    /// Spring stiffness KL, N m/rad (`f64::INFINITY` for a rigid axis).
    pub kl: f64,
    /// Spring damping CL, N m s/rad.
    pub cl: f64,
    /// Load inertia JL, kg m^2 (0 for a rigid axis).
    pub jl: f64,
    /// Load-side viscous damping DL, N m s/rad.
    pub dl: f64,
}

impl TwoMassModel {
    /// The model of an axis' plant parameters.
    pub fn of_plant(p: &PlantParams) -> Self {
        match p {
            PlantParams::BallScrew { two_mass: t, .. }
            | PlantParams::Rotary { two_mass: t, .. } => Self {
                jm: t.jm_kgm2,
                dm: t.dm_nms_per_rad,
                kl: t.kl_nm_per_rad,
                cl: t.cl_nms_per_rad,
                jl: t.jl_kgm2,
                dl: t.dl_nms_per_rad,
            },
            PlantParams::Rigid(r) => Self {
                jm: r.mass_kg,
                dm: r.viscous_ns_per_m,
                kl: f64::INFINITY,
                cl: 0.0,
                jl: 0.0,
                dl: 0.0,
            },
        }
    }

    /// Compliance 1/KL (0 for a rigid axis).
    pub fn compliance(&self) -> f64 {
        if self.kl.is_finite() {
            1.0 / self.kl
        } else {
            0.0
        }
    }

    /// The patent's coefficients a1..a5 (CL = 0) for a PI with gain `kv` and integral time `tv`.
    pub fn coefficients_a(&self, kv: f64, tv: f64) -> [f64; 5] {
        let c = self.compliance();
        let Self { jm, dm, jl, dl, .. } = *self;
        [
            kv,
            tv * (dm + dl) + kv * (tv + dl * c),
            tv * (jm + jl + dm * dl * c) + kv * (tv * dl + jl) * c,
            tv * (jm * dl + dm * jl) * c + kv * tv * jl * c,
            tv * jm * jl * c,
        ]
    }

    /// The numerator b1..b5 of the exact ratio form with spring damping CL (denominator
    /// 1 + (CL/KL) s); equal to a1..a5 when CL = 0.
    pub fn coefficients_b(&self, kv: f64, tv: f64) -> [f64; 5] {
        let a = self.coefficients_a(kv, tv);
        let c = self.compliance();
        let Self {
            jm, dm, cl, jl, dl, ..
        } = *self;
        [
            a[0],
            a[1] + cl * kv * c,
            a[2] + cl * tv * (dl + dm + kv) * c,
            a[3] + cl * tv * (jm + jl) * c,
            a[4],
        ]
    }

    /// Spring time constant CL/KL, s.
    pub fn spring_tau_s(&self) -> f64 {
        self.cl * self.compliance()
    }

    /// Motor position offset (twist) d and its derivatives 1..3 for the reference `r`
    /// (position, velocity, ... 5th derivative) and an estimate `d6` of the 6th derivative
    /// (only d''' uses it): d, d', d'', d'''.
    pub fn twist(&self, r: &[f64; 6], d6: f64) -> [f64; 4] {
        let c = self.compliance();
        let tc = self.spring_tau_s();
        let f = |i: usize| self.jl * r[i + 2] + self.dl * r[i + 1];
        let f4 = self.jl * d6 + self.dl * r[5];
        let f3 = f(3);
        [
            c * (f(0) - tc * f(1)),
            c * (f(1) - tc * f(2)),
            c * (f(2) - tc * f3),
            c * (f3 - tc * f4),
        ]
    }

    /// Motor velocity, acceleration and jerk references and the model torque and its rate for the
    /// reference `r` and 6th-derivative estimate `d6` (see [`TwoMassModel::twist`]):
    /// (thM', thM'', thM''', tau, tau').
    pub fn inverse(&self, r: &[f64; 6], d6: f64) -> InverseState {
        let d = self.twist(r, d6);
        let w = r[1] + d[1];
        let a = r[2] + d[2];
        let j = r[3] + d[3];
        InverseState {
            motor_vel: w,
            motor_acc: a,
            motor_jerk: j,
            torque: self.jm * a + self.dm * w + self.jl * r[2] + self.dl * r[1],
            torque_rate: self.jm * j + self.dm * a + self.jl * r[3] + self.dl * r[2],
        }
    }
}

/// What the inverse model asks of the motor at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverseState {
    /// Motor velocity thM', rad/s (m/s).
    pub motor_vel: f64,
    /// Motor acceleration thM'', rad/s^2.
    pub motor_acc: f64,
    /// Motor jerk thM''', rad/s^3.
    pub motor_jerk: f64,
    /// Torque tau, N m (N).
    pub torque: f64,
    /// Torque rate tau', N m/s.
    pub torque_rate: f64,
}

/// How the feedforward enters the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Structure {
    /// The patent's VH on the velocity command.
    Literal,
    /// Motor velocity reference on the velocity command, model torque on `torque_ff`.
    Split,
}

/// How the literal structure's lags 1/(1 + tau s) are discretised (`lag_discretisation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LagDiscretisation {
    /// Bilinear (Tustin), s = 2 (z - 1) / (T (z + 1)).
    Tustin,
    /// Backward Euler, s = (z - 1) / (T z): the brief's literal implementation.
    BackwardEuler,
}

/// How the plant's motor velocity is measured (what the velocity reference must match).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotorVelMeasure {
    /// Velocity at the sample instant.
    Sampled,
    /// Position difference over the last period / period.
    Difference,
}

key_choice!(Structure, "structure", default Split, ["split" => Split, "literal" => Literal]);
key_choice!(LagDiscretisation, "lag discretisation", default Tustin,
    ["tustin" => Tustin, "backward_euler" => BackwardEuler]);
key_choice!(MotorVelMeasure, "velocity estimate", default Sampled,
    ["exact" => Sampled, "difference" => Difference]);

/// Parameters of [`InverseFeedforward`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverseFeedforwardParams {
    /// Structure (`structure`).
    pub structure: Structure,
    /// The model inverted.
    pub model: TwoMassModel,
    /// Velocity loop gain Kv of the PI being inverted (literal only), N m s/rad or N s/m.
    pub kv: f64,
    /// Its integral time Tv, s (0 = proportional velocity loop).
    pub tv_s: f64,
    /// Torque evaluation advance, s (split only); default half the period.
    pub torque_advance_s: f64,
    /// Motor velocity measurement (`velocity_estimate`).
    pub motor_vel: MotorVelMeasure,
    /// Control period, s.
    pub period_s: f64,
    /// Discretisation of the literal structure's lags.
    pub lag: LagDiscretisation,
}

impl PluginParams for InverseFeedforwardParams {
    /// Reads the plugin keys, defaulting to the axis model and its `[controller]`.
    fn read(mut f: Fields<'_>, axis: &AxisContext, file: &Path) -> Result<Self, ConfigError> {
        let structure: Structure = f.choose("structure")?;
        let mut model = TwoMassModel::of_plant(&axis.plant);
        let pos = Range::Within(1e-12, 1e9);
        let nonneg = Range::Within(0.0, 1e9);
        if axis.plant.two_mass().is_some() {
            model.jm = f.f64_or("jm_kgm2", pos, model.jm)?;
            model.dm = f.f64_or("dm_nms_per_rad", nonneg, model.dm)?;
            model.kl = f.f64_or("kl_nm_per_rad", pos, model.kl)?;
            model.cl = f.f64_or("cl_nms_per_rad", nonneg, model.cl)?;
            model.jl = f.f64_or("jl_kgm2", nonneg, model.jl)?;
            model.dl = f.f64_or("dl_nms_per_rad", nonneg, model.dl)?;
        } else {
            model.jm = f.f64_or("mass_kg", pos, model.jm)?;
            model.dm = f.f64_or("viscous_ns_per_m", nonneg, model.dm)?;
        }
        let PiGains { kv_key, kv, tv } = read_pi_gains(&mut f, axis.plant.kind())?;
        let adv = f.opt_f64(
            "torque_advance_s",
            Range::Within(-axis.period_s * 10.0, axis.period_s * 10.0),
        )?;
        let motor_vel: MotorVelMeasure = f.choose("velocity_estimate")?;
        let lag: LagDiscretisation = f.choose("lag_discretisation")?;
        f.finish()?;
        let kv = kv.or(axis.defaults.kv);
        let kv = match (structure, kv) {
            (_, Some(k)) => k,
            (Structure::Split, None) => 0.0,
            (Structure::Literal, None) => {
                return Err(ConfigError::new(
                    file,
                    kv_key,
                    format!(
                        "is required by `structure = \"literal\"`: give it in the plugin params or in the [controller] table of axis `{}`'s model",
                        axis.name
                    ),
                ))
            }
        };
        Ok(Self {
            structure,
            model,
            kv,
            tv_s: tv.or(axis.defaults.tv_s).unwrap_or(0.0),
            torque_advance_s: adv.unwrap_or(axis.period_s / 2.0),
            motor_vel,
            period_s: axis.period_s,
            lag,
        })
    }
}

/// First-order lag 1/(1 + tau s), `y_k = b0 x_k + s`, `s = b1 x_k - a1 y_k`: Tustin (c = 2/T,
/// b1 = b0) or backward Euler (b1 = 0); `tau = 0` passes through.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Lag {
    b0: f64,
    b1: f64,
    a1: f64,
    s: f64,
}

impl Lag {
    fn new(tau: f64, period: f64, how: LagDiscretisation) -> Self {
        match how {
            LagDiscretisation::Tustin => {
                let c = 2.0 / period;
                let b0 = 1.0 / (1.0 + c * tau);
                Self {
                    b0,
                    b1: b0,
                    a1: (1.0 - c * tau) / (1.0 + c * tau),
                    s: 0.0,
                }
            }
            LagDiscretisation::BackwardEuler => Self {
                b0: period / (tau + period),
                b1: 0.0,
                a1: -tau / (tau + period),
                s: 0.0,
            },
        }
    }
    #[inline]
    fn process(&mut self, x: f64) -> f64 {
        let y = self.b0 * x + self.s;
        self.s = self.b1 * x - self.a1 * y;
        y
    }
    fn settle(&mut self, x: f64) {
        self.s = x - self.b0 * x;
    }
}

/// The inverse-model feedforward.
#[derive(Debug, Clone)]
pub struct InverseFeedforward {
    params: InverseFeedforwardParams,
    /// Last cycle's 5th derivative (crackle), if valid: the 6th derivative the torque rate
    /// needs (JM JL/KL th^(6)) is its backward difference.
    last_crackle: Option<f64>,
    /// b1..b5 / Kv (literal structure).
    coef: [f64; 5],
    lag_tv: Lag,
    lag_spring: Lag,
}

axis_plugin!(
    InverseFeedforward,
    InverseFeedforwardParams,
    "inverse_feedforward",
    Stage::Feedforward
);

impl InverseFeedforward {
    /// Builds the feedforward at rest.
    pub fn new(params: InverseFeedforwardParams) -> Self {
        let mut me = Self {
            params,
            last_crackle: None,
            coef: [0.0; 5],
            lag_tv: Lag::new(0.0, params.period_s, params.lag),
            lag_spring: Lag::new(0.0, params.period_s, params.lag),
        };
        me.set_model(params.model);
        me
    }

    /// Current parameters.
    pub fn params(&self) -> &InverseFeedforwardParams {
        &self.params
    }

    /// Replaces the model (e.g. after inertia identification); keeps the lag states.
    pub fn set_model(&mut self, model: TwoMassModel) {
        self.params.model = model;
        let p = &self.params;
        let b = model.coefficients_b(p.kv, p.tv_s);
        self.coef = if p.kv > 0.0 {
            b.map(|x| x / p.kv)
        } else {
            [0.0; 5]
        };
        let (s1, s2) = (self.lag_tv.s, self.lag_spring.s);
        self.lag_tv = Lag::new(p.tv_s, p.period_s, p.lag);
        self.lag_spring = Lag::new(model.spring_tau_s(), p.period_s, p.lag);
        self.lag_tv.s = s1;
        self.lag_spring.s = s2;
    }

    /// The literal VH before the lags: sum b_i th^(i) / Kv (motor units/s).
    fn literal_numerator(&self, r: &[f64; 6]) -> f64 {
        self.coef
            .iter()
            .zip(&r[1..])
            .map(|(c, d)| c * d)
            .sum::<f64>()
    }

    /// The motor velocity reference matching the measurement.
    fn motor_vel_ref(&self, inv: &InverseState) -> f64 {
        match self.params.motor_vel {
            MotorVelMeasure::Sampled => inv.motor_vel,
            MotorVelMeasure::Difference => {
                let t = self.params.period_s;
                inv.motor_vel - 0.5 * t * inv.motor_acc + t * t / 6.0 * inv.motor_jerk
            }
        }
    }

    /// (velocity addition, torque addition) for reference `r`, updating the lags.
    fn compute(&mut self, r: &[f64; 6]) -> (f64, f64) {
        let d6 = match self.last_crackle {
            Some(c) => (r[5] - c) / self.params.period_s,
            None => 0.0,
        };
        self.last_crackle = r[5].is_finite().then_some(r[5]);
        let p = &self.params;
        match p.structure {
            Structure::Split => {
                let inv = p.model.inverse(r, d6);
                (
                    self.motor_vel_ref(&inv),
                    inv.torque + p.torque_advance_s * inv.torque_rate,
                )
            }
            Structure::Literal if p.tv_s > 0.0 => {
                let n = self.literal_numerator(r);
                let v = self.lag_tv.process(n);
                (self.lag_spring.process(v), 0.0)
            }
            Structure::Literal => {
                let inv = p.model.inverse(r, d6);
                let vh = self.motor_vel_ref(&inv) + inv.torque / p.kv;
                (vh, 0.0)
            }
        }
    }
}

impl Controller for InverseFeedforward {
    reference_only_plugin!();

    fn step(&mut self, _ctx: &CycleContext, io: &mut AxisSignals) {
        let (v, tau) = self.compute(&io.reference);
        if v.is_finite() && tau.is_finite() {
            io.vel_cmd += v;
            io.torque_ff += tau;
        } else {
            // A non-finite reference or model: add nothing this cycle and restart the lags.
            self.lag_tv.settle(0.0);
            self.lag_spring.settle(0.0);
        }
    }

    /// Snapshot layout: [Tv lag state, spring lag state (literal structure; zeros for split),
    /// last crackle, 1 if it is valid].
    fn snapshot(&self) -> ControllerState {
        ControllerState::from_slice(&[
            self.lag_tv.s,
            self.lag_spring.s,
            self.last_crackle.unwrap_or(0.0),
            self.last_crackle.is_some() as u8 as f64,
        ])
    }

    fn restore(&mut self, state: &ControllerState) {
        let at = |i: usize| state.finite_or_zero(i);
        self.lag_tv.s = at(0);
        self.lag_spring.s = at(1);
        self.last_crackle = (at(3) != 0.0).then(|| at(2));
    }

    /// Starts the literal structure's lags at rest at the last reference's numerator, as if the
    /// feedforward had been running through a slow motion.
    fn initialize_from(&mut self, last: &AxisSignals) {
        let n = self.literal_numerator(&last.reference);
        let n = if n.is_finite() { n } else { 0.0 };
        self.lag_tv.settle(n);
        self.lag_spring.settle(n);
        self.last_crackle = last.reference[5].is_finite().then_some(last.reference[5]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Minimal complex arithmetic for frequency-domain checks.
    #[derive(Clone, Copy, Debug)]
    struct C(f64, f64);
    impl std::ops::Add for C {
        type Output = C;
        fn add(self, o: C) -> C {
            C(self.0 + o.0, self.1 + o.1)
        }
    }
    impl std::ops::Mul for C {
        type Output = C;
        fn mul(self, o: C) -> C {
            C(self.0 * o.0 - self.1 * o.1, self.0 * o.1 + self.1 * o.0)
        }
    }
    impl std::ops::Div for C {
        type Output = C;
        fn div(self, o: C) -> C {
            let d = o.0 * o.0 + o.1 * o.1;
            C(
                (self.0 * o.0 + self.1 * o.1) / d,
                (self.1 * o.0 - self.0 * o.1) / d,
            )
        }
    }
    fn re(x: f64) -> C {
        C(x, 0.0)
    }

    fn model() -> TwoMassModel {
        TwoMassModel {
            jm: 2e-3,
            dm: 1e-3,
            kl: 3000.0,
            cl: 0.05,
            jl: 3e-3,
            dl: 2e-3,
        }
    }

    #[test]
    fn ratio_form_equals_the_exact_inverse_at_every_frequency() {
        let m = model();
        let (kv, tv) = (5.0, 0.005);
        let b = m.coefficients_b(kv, tv);
        for f in [1.0, 30.0, 300.0, 3000.0] {
            let s = C(0.0, 2.0 * std::f64::consts::PI * f);
            // exact: Kv (1 + Tv s) s M + Tv s T with M = thM/th, T = tau/th
            let mm = re(1.0) + (re(m.jl) * s * s + re(m.dl) * s) / (re(m.kl) + re(m.cl) * s);
            let tt = (re(m.jm) * s * s + re(m.dm) * s) * mm + re(m.jl) * s * s + re(m.dl) * s;
            let exact = re(kv) * (re(1.0) + re(tv) * s) * s * mm + re(tv) * s * tt;
            let mut num = re(0.0);
            let mut sp = s;
            for bi in b {
                num = num + re(bi) * sp;
                sp = sp * s;
            }
            let ratio = num / (re(1.0) + re(m.cl / m.kl) * s);
            let err = ((ratio.0 - exact.0).powi(2) + (ratio.1 - exact.1).powi(2)).sqrt();
            let mag = (exact.0.powi(2) + exact.1.powi(2)).sqrt();
            assert!(err < 1e-9 * mag, "f {f}: {err} vs {mag}");
        }
    }

    #[test]
    fn a5_is_tv_jm_jl_over_kl_and_b_equals_a_without_spring_damping() {
        let mut m = model();
        m.cl = 0.0;
        let a = m.coefficients_a(5.0, 0.005);
        assert!((a[4] - 0.005 * 2e-3 * 3e-3 / 3000.0).abs() < 1e-20);
        assert_eq!(a, m.coefficients_b(5.0, 0.005));
    }

    #[test]
    fn split_torque_at_constant_acceleration_is_total_inertia_times_acceleration() {
        let mut m = model();
        m.dm = 0.0;
        m.dl = 0.0;
        let inv = m.inverse(&[0.0, 0.0, 100.0, 0.0, 0.0, 0.0], 0.0);
        assert!((inv.torque - 5e-3 * 100.0).abs() < 1e-12);
        // twist JL a / KL appears as motor position, not velocity, at constant acceleration
        assert!(
            (m.twist(&[0.0, 0.0, 100.0, 0.0, 0.0, 0.0], 0.0)[0] - 3e-3 * 100.0 / 3000.0).abs()
                < 1e-9
        );
    }

    fn axis() -> AxisContext {
        crate::test_util::ballscrew_axis(1e-4)
    }

    #[test]
    fn literal_structure_needs_a_velocity_gain_only_when_none_is_in_the_model() {
        let mut a = axis();
        a.defaults.kv = None;
        let t: toml::Table = "structure = \"literal\"".parse().unwrap();
        let e = InverseFeedforwardParams::from_table(&t, &a, Path::new("j")).unwrap_err();
        assert_eq!(e.key, "kv_nms_per_rad");
        let t: toml::Table = "structure = \"split\"".parse().unwrap();
        assert!(InverseFeedforwardParams::from_table(&t, &a, Path::new("j")).is_ok());
    }

    #[test]
    fn rigid_axis_refuses_two_mass_keys_and_accepts_mass() {
        let a = crate::test_util::rigid_axis(1e-4);
        let t: toml::Table = "jl_kgm2 = 1e-3".parse().unwrap();
        let e = InverseFeedforwardParams::from_table(&t, &a, Path::new("j")).unwrap_err();
        assert_eq!(e.key, "jl_kgm2");
        let t: toml::Table = "mass_kg = 25".parse().unwrap();
        let p = InverseFeedforwardParams::from_table(&t, &a, Path::new("j")).unwrap();
        assert_eq!(p.model.jm, 25.0);
        let inv = p.model.inverse(&[0.0, 0.1, 2.0, 0.0, 0.0, 0.0], 0.0);
        assert!((inv.torque - 50.0).abs() < 1e-12);
        assert_eq!(inv.motor_vel, 0.1);
    }

    #[test]
    fn unknown_structure_is_refused_naming_structure() {
        let t: toml::Table = "structure = \"inverse\"".parse().unwrap();
        let e = InverseFeedforwardParams::from_table(&t, &axis(), Path::new("j")).unwrap_err();
        assert_eq!(e.key, "structure");
    }

    #[test]
    fn backward_euler_lag_steps_by_t_over_tau_plus_t_and_unknown_names_are_refused() {
        let t: toml::Table = "structure = \"literal\"\nlag_discretisation = \"backward_euler\""
            .parse()
            .unwrap();
        let p = InverseFeedforwardParams::from_table(&t, &axis(), Path::new("j")).unwrap();
        assert_eq!(p.lag, LagDiscretisation::BackwardEuler);
        // y_k = (tau y_{k-1} + T x_k) / (tau + T) on a unit step, tau = 4 T.
        let mut lag = Lag::new(4e-4, 1e-4, LagDiscretisation::BackwardEuler);
        let (y1, y2) = (lag.process(1.0), lag.process(1.0));
        assert!((y1 - 0.2).abs() < 1e-12 && (y2 - (0.8 * 0.2 + 0.2)).abs() < 1e-12);
        let t: toml::Table = "lag_discretisation = \"euler\"".parse().unwrap();
        let e = InverseFeedforwardParams::from_table(&t, &axis(), Path::new("j")).unwrap_err();
        assert_eq!(e.key, "lag_discretisation");
    }

    #[test]
    fn split_adds_the_half_sample_advanced_torque_and_the_motor_velocity() {
        let t: toml::Table = "".parse().unwrap();
        let p = InverseFeedforwardParams::from_table(&t, &axis(), Path::new("j")).unwrap();
        assert_eq!(p.torque_advance_s, 5e-5);
        let mut c = InverseFeedforward::new(p);
        let mut io = AxisSignals {
            reference: [0.0, 10.0, 100.0, 1000.0, 0.0, 0.0],
            ..Default::default()
        };
        c.step(&FIRST_CYCLE, &mut io);
        // thM' = v + JL jerk / KL = 10 + 3e-3 * 1000 / 3000 = 10.001
        assert!((io.vel_cmd - 10.001).abs() < 1e-12, "{}", io.vel_cmd);
        // tau = (JM + JL) a = 0.5; tau' = (JM + JL) jerk = 5 -> + 5e-5 * 5
        assert!(
            (io.torque_ff - (0.5 + 2.5e-4)).abs() < 1e-12,
            "{}",
            io.torque_ff
        );
    }

    /// The first cycle at 10 kHz.
    const FIRST_CYCLE: CycleContext = CycleContext {
        period_s: 1e-4,
        cycle: 0,
        t_s: 0.0,
    };

    /// The literal structure on the test axis.
    fn literal() -> InverseFeedforward {
        let t: toml::Table = "structure = \"literal\"".parse().unwrap();
        let p = InverseFeedforwardParams::from_table(&t, &axis(), Path::new("j")).unwrap();
        InverseFeedforward::new(p)
    }

    #[test]
    fn literal_at_constant_velocity_settles_to_velocity_plus_damping_terms() {
        let mut c = literal();
        let ctx = FIRST_CYCLE;
        let mut v = 0.0;
        for _ in 0..5000 {
            let mut io = AxisSignals {
                reference: [0.0, 10.0, 0.0, 0.0, 0.0, 0.0],
                ..Default::default()
            };
            c.step(&ctx, &mut io);
            v = io.vel_cmd;
        }
        // no damping in this model: a1 v / Kv = v
        assert!((v - 10.0).abs() < 1e-9, "{v}");
    }

    #[test]
    fn non_finite_reference_adds_nothing() {
        let mut c = literal();
        let ctx = FIRST_CYCLE;
        let mut io = AxisSignals {
            reference: [0.0, f64::NAN, 0.0, 0.0, f64::INFINITY, 0.0],
            vel_cmd: 1.0,
            ..Default::default()
        };
        c.step(&ctx, &mut io);
        assert_eq!((io.vel_cmd, io.torque_ff), (1.0, 0.0));
        io.reference = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
        c.step(&ctx, &mut io);
        assert!(io.vel_cmd.is_finite());
    }
}
