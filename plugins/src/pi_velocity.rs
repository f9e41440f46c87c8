//! `pi_velocity`: PI velocity loop on the motor velocity with torque limit and anti-windup
//! (seed 000, the inner loop of the cascade).
//!
//! tau = Kv (1 + 1/(Tv s)) (V - wM) + tau_ff, clamped to +-`torque_limit`.
//!
//! Discrete form (period T): e_k = V_k - wM_k, I_k = I_{k-1} + T e_k (rectangle rule, as in the
//! seed), tau_k = Kv (e_k + I_k / Tv) + tau_ff. Anti-windup by conditional integration: while the
//! output is clamped and the error pushes further into the limit, the integrator step is undone,
//! so the loop recovers from saturation without overshoot from a wound-up integral.
//!
//! Keys: `kv_nms_per_rad` (N m s/rad; `kv_ns_per_m` in N s/m for a linear axis), `tv_s` (s,
//! 0 = proportional only), `torque_limit_nm` (N m; `force_limit_n` in N for a linear axis).
//! Typical for a 2e-3 kg m^2 motor with a 3e-3 kg m^2 load: Kv = 5, Tv = 5 ms.

use std::path::Path;

use feedloop_runtime::controller::{
    AxisContext, AxisSignals, Controller, ControllerState, CycleContext,
};
use feedloop_runtime::model::AxisKind;
use feedloop_runtime::params::{ConfigError, Fields, Range};

/// Parameters of [`PiVelocity`] (motor units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PiVelocityParams {
    /// Proportional gain Kv: N m s/rad (rotary) or N s/m (linear).
    pub kv: f64,
    /// Integral time Tv, s; 0 disables the integral term.
    pub tv_s: f64,
    /// Output limit: N m or N.
    pub torque_limit: f64,
}

/// Parameter key names for an axis kind: (kv, limit).
pub fn key_names(kind: AxisKind) -> (&'static str, &'static str) {
    match kind {
        AxisKind::Rigid => ("kv_ns_per_m", "force_limit_n"),
        _ => ("kv_nms_per_rad", "torque_limit_nm"),
    }
}

impl PiVelocityParams {
    /// Reads the plugin keys from `params`, defaulting to the model's `[controller]`;
    /// `base` (when given) supplies values for keys `params` omits (used by retunes).
    pub fn from_table(
        params: &toml::Table,
        axis: &AxisContext,
        file: &Path,
        base: Option<&PiVelocityParams>,
    ) -> Result<Self, ConfigError> {
        let (kv_key, lim_key) = key_names(axis.plant.kind());
        let mut f = Fields::new(params, file, "");
        let kv = f.opt_f64(kv_key, Range::Within(1e-12, 1e9))?;
        let tv = f.opt_f64("tv_s", Range::Within(0.0, 1e3))?;
        let lim = f.opt_f64(lim_key, Range::Within(1e-9, 1e9))?;
        f.finish()?;
        let d = &axis.defaults;
        let missing = |key: &str| {
            ConfigError::new(
                file,
                key,
                format!(
                    "is required: give it in the plugin params or in the [controller] table of axis `{}`'s model",
                    axis.name
                ),
            )
        };
        Ok(Self {
            kv: kv
                .or(base.map(|b| b.kv))
                .or(d.kv)
                .ok_or_else(|| missing(kv_key))?,
            tv_s: tv.or(base.map(|b| b.tv_s)).or(d.tv_s).unwrap_or(0.0),
            torque_limit: lim
                .or(base.map(|b| b.torque_limit))
                .or(d.torque_limit)
                .ok_or_else(|| missing(lim_key))?,
        })
    }
}

/// Terms of the last output, as a tuner wants to see them.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PiTerms {
    /// Proportional term Kv e, N m.
    pub p: f64,
    /// Integral term Kv I / Tv, N m.
    pub i: f64,
    /// Whether the output was clamped.
    pub saturated: bool,
}

/// The PI velocity controller.
#[derive(Debug, Clone)]
pub struct PiVelocity {
    params: PiVelocityParams,
    /// Integral of the velocity error, motor units (rad or m).
    integral: f64,
    terms: PiTerms,
}

impl PiVelocity {
    /// Plugin id.
    pub const ID: &'static str = "pi_velocity";

    /// Builds the controller with a zero integrator.
    pub fn new(params: PiVelocityParams) -> Self {
        Self {
            params,
            integral: 0.0,
            terms: PiTerms::default(),
        }
    }

    /// Current parameters.
    pub fn params(&self) -> &PiVelocityParams {
        &self.params
    }

    /// Terms of the last step.
    pub fn terms(&self) -> PiTerms {
        self.terms
    }
}

impl Controller for PiVelocity {
    fn id(&self) -> &str {
        Self::ID
    }

    fn step(&mut self, ctx: &CycleContext, io: &mut AxisSignals) {
        let p = &self.params;
        let e = io.vel_cmd - io.motor_vel;
        let prev = self.integral;
        let use_i = p.tv_s > 0.0;
        if use_i {
            self.integral += ctx.period_s * e;
        }
        let i_term = if use_i {
            p.kv * self.integral / p.tv_s
        } else {
            0.0
        };
        let raw = p.kv * e + i_term + io.torque_ff;
        let lim = p.torque_limit;
        let out = raw.clamp(-lim, lim);
        let saturated = out != raw;
        if saturated && use_i && e * raw > 0.0 {
            self.integral = prev;
        }
        if !self.integral.is_finite() {
            self.integral = 0.0;
        }
        self.terms = PiTerms {
            p: p.kv * e,
            i: if use_i {
                p.kv * self.integral / p.tv_s
            } else {
                0.0
            },
            saturated,
        };
        io.torque = if out.is_nan() { 0.0 } else { out };
    }

    fn snapshot(&self) -> ControllerState {
        ControllerState::from_slice(&[self.integral])
    }

    fn restore(&mut self, state: &ControllerState) {
        self.integral = state.as_slice().first().copied().unwrap_or(0.0);
    }

    fn initialize_from(&mut self, last: &AxisSignals) {
        // Choose the integrator so that last cycle's inputs would have produced last cycle's
        // torque: then the first output of this controller continues from it.
        let p = &self.params;
        if p.tv_s > 0.0 && last.torque.is_finite() {
            let e = last.vel_cmd - last.motor_vel;
            let i = ((last.torque - last.torque_ff) / p.kv - e) * p.tv_s;
            self.integral = if i.is_finite() { i } else { 0.0 };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx() -> CycleContext {
        CycleContext {
            period_s: 1e-3,
            cycle: 0,
            t_s: 0.0,
        }
    }

    fn pi(kv: f64, tv: f64, lim: f64) -> PiVelocity {
        PiVelocity::new(PiVelocityParams {
            kv,
            tv_s: tv,
            torque_limit: lim,
        })
    }

    #[test]
    fn integral_term_ramps_by_kv_t_over_tv_per_cycle() {
        let mut c = pi(2.0, 0.01, 100.0);
        let mut io = AxisSignals {
            vel_cmd: 1.0,
            ..Default::default()
        };
        c.step(&ctx(), &mut io);
        // Kv (e + T e / Tv) = 2 (1 + 0.1) = 2.2
        assert!((io.torque - 2.2).abs() < 1e-12, "{}", io.torque);
        c.step(&ctx(), &mut io);
        assert!((io.torque - 2.4).abs() < 1e-12, "{}", io.torque);
    }

    #[test]
    fn output_is_clamped_and_integrator_does_not_wind_up() {
        let mut c = pi(2.0, 0.01, 1.0);
        let mut io = AxisSignals {
            vel_cmd: 10.0,
            ..Default::default()
        };
        for _ in 0..1000 {
            c.step(&ctx(), &mut io);
            assert!(io.torque <= 1.0);
        }
        // the error reverses: a wound-up integrator would keep the output at +limit
        io.vel_cmd = -0.1;
        c.step(&ctx(), &mut io);
        assert!(io.torque < 0.0, "recovered immediately: {}", io.torque);
    }

    #[test]
    fn nan_input_never_produces_nan_torque() {
        let mut c = pi(2.0, 0.01, 1.0);
        let mut io = AxisSignals {
            vel_cmd: f64::NAN,
            ..Default::default()
        };
        c.step(&ctx(), &mut io);
        assert!(io.torque.is_finite());
        io.vel_cmd = 0.5;
        c.step(&ctx(), &mut io);
        assert!(io.torque.is_finite());
    }

    #[test]
    fn initialising_from_previous_output_is_bumpless() {
        let mut c = pi(3.0, 0.005, 50.0);
        let last = AxisSignals {
            vel_cmd: 2.0,
            motor_vel: 1.5,
            torque: 7.0,
            ..Default::default()
        };
        c.initialize_from(&last);
        let mut io = last;
        c.step(&ctx(), &mut io);
        // same error: output moves only by one integration step Kv T e / Tv = 3*1e-3*0.5/0.005
        assert!((io.torque - 7.0 - 0.3).abs() < 1e-9, "{}", io.torque);
    }
}
