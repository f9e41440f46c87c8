//! The sensor model of an axis (`[sensor]` in a model file): encoder quantisation, Gaussian
//! noise with a fixed seed, and how the motor velocity is obtained.
//!
//! Keys (all optional; without a `[sensor]` table the plant reports its true state):
//! - `motor_counts_per_rev` (integer >= 1; ballscrew/rotary) or `motor_resolution_m` (> 0, m;
//!   rigid): motor encoder quantisation. Positions are truncated to the count below
//!   (`floor(pos / q) q`), like an incremental encoder.
//! - `load_resolution_m` (> 0, m; ballscrew, rigid) or `load_counts_per_rev` (integer; rotary):
//!   load-side scale quantisation.
//! - `motor_pos_noise_rad` / `motor_pos_noise_m`, `motor_vel_noise_rad_per_s` /
//!   `motor_vel_noise_m_per_s`, `load_pos_noise_m` / `load_pos_noise_rad`, `torque_noise_nm` /
//!   `force_noise_n`: standard deviations of additive white Gaussian noise (>= 0), added before
//!   quantisation.
//! - `velocity_estimate = "exact" | "difference"`: motor velocity is the true velocity plus
//!   noise (default), or the backward difference of the measured (noisy, quantised) motor
//!   position over one period, as most drives compute it.
//! - `seed` (integer >= 0, default 0): the noise generator's seed; each axis of a plant mixes its
//!   index into it, so two axes with the same model file get independent noise.

use std::f64::consts::PI;

use feedloop_control::axis_io::AxisSensor;
use feedloop_model::model::{AxisKind, ModelFile};
use feedloop_model::params::{ConfigError, Fields, Range};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::effects::check_keys;

/// Validated sensor parameters, motor/load units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SensorParams {
    /// Motor position quantum (rad or m), 0 = none.
    pub q_motor: f64,
    /// Load position quantum (m or rad), 0 = none.
    pub q_load: f64,
    /// Noise standard deviations: motor pos, motor vel, load pos, torque.
    pub sigma: [f64; 4],
    /// Motor velocity from position differences.
    pub difference: bool,
    /// Seed.
    pub seed: u64,
}

/// Parses the `[sensor]` table.
pub(crate) fn parse(model: &ModelFile) -> Result<SensorParams, ConfigError> {
    let kind = model.plant.kind();
    let mut f = Fields::new(&model.sensor, &model.path, "sensor");
    let (k_qm, k_ql, k_mp, k_mv, k_lp, k_t) = match kind {
        AxisKind::BallScrew => (
            "motor_counts_per_rev",
            "load_resolution_m",
            "motor_pos_noise_rad",
            "motor_vel_noise_rad_per_s",
            "load_pos_noise_m",
            "torque_noise_nm",
        ),
        AxisKind::Rotary => (
            "motor_counts_per_rev",
            "load_counts_per_rev",
            "motor_pos_noise_rad",
            "motor_vel_noise_rad_per_s",
            "load_pos_noise_rad",
            "torque_noise_nm",
        ),
        AxisKind::Rigid => (
            "motor_resolution_m",
            "load_resolution_m",
            "motor_pos_noise_m",
            "motor_vel_noise_m_per_s",
            "load_pos_noise_m",
            "force_noise_n",
        ),
    };
    check_keys(
        &f,
        &[
            k_qm,
            k_ql,
            k_mp,
            k_mv,
            k_lp,
            k_t,
            "velocity_estimate",
            "seed",
        ],
    )?;
    let counts = |f: &mut Fields<'_>, key: &str| -> Result<f64, ConfigError> {
        Ok(match f.opt_i64(key, 1, 1 << 40)? {
            Some(n) => 2.0 * PI / n as f64,
            None => 0.0,
        })
    };
    let q_motor = if k_qm.ends_with("_m") {
        f.f64_or(k_qm, Range::Positive, 0.0)?
    } else {
        counts(&mut f, k_qm)?
    };
    let q_load = if k_ql.ends_with("_m") {
        f.f64_or(k_ql, Range::Positive, 0.0)?
    } else {
        counts(&mut f, k_ql)?
    };
    let mut sigma = [0.0; 4];
    for (s, k) in sigma.iter_mut().zip([k_mp, k_mv, k_lp, k_t]) {
        *s = f.f64_or(k, Range::NonNegative, 0.0)?;
    }
    let difference = match f.opt_str("velocity_estimate")? {
        None | Some("exact") => false,
        Some("difference") => true,
        Some(other) => {
            return Err(f.error(
                "velocity_estimate",
                format!(
                    "unknown velocity estimate `{other}` (expected \"exact\" or \"difference\")"
                ),
            ))
        }
    };
    let seed = f.opt_i64("seed", 0, i64::MAX)?.unwrap_or(0) as u64;
    f.finish()?;
    Ok(SensorParams {
        q_motor,
        q_load,
        sigma,
        difference,
        seed,
    })
}

/// Run-time sensor state of one axis.
#[derive(Debug, Clone)]
pub(crate) struct Sensor {
    p: SensorParams,
    inv_q_motor: f64,
    inv_q_load: f64,
    noisy: bool,
    rng: SmallRng,
    prev_motor_pos: f64,
}

/// `floor(x / q) q` (x unchanged for q = 0). The floor avoids a libm call on baseline x86-64.
#[inline]
fn quantise(x: f64, q: f64, inv_q: f64) -> f64 {
    if q > 0.0 {
        fast_floor(x * inv_q) * q
    } else {
        x
    }
}

#[inline]
fn fast_floor(v: f64) -> f64 {
    // Beyond 2^52 every f64 is an integer (and NaN/inf pass through).
    if v.abs() < 4_503_599_627_370_496.0 {
        // SAFETY: |v| < 2^52 (which NaN fails) fits i64, so the unchecked conversion is exact
        // and skips the saturation fix-ups of `as`.
        let t = unsafe { v.to_int_unchecked::<i64>() } as f64;
        if t > v {
            t - 1.0
        } else {
            t
        }
    } else {
        v
    }
}

impl Sensor {
    /// A sensor for axis number `axis_index` of a plant.
    pub fn new(p: SensorParams, axis_index: usize) -> Self {
        let mix = p.seed ^ (axis_index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let inv = |q: f64| if q > 0.0 { 1.0 / q } else { 0.0 };
        Self {
            inv_q_motor: inv(p.q_motor),
            inv_q_load: inv(p.q_load),
            noisy: p.sigma.iter().any(|&s| s > 0.0),
            rng: SmallRng::seed_from_u64(mix),
            prev_motor_pos: 0.0,
            p,
        }
    }

    #[inline]
    fn noise(&mut self, i: usize) -> f64 {
        let s = self.p.sigma[i];
        if s > 0.0 {
            let z: f64 = self.rng.sample(StandardNormal);
            s * z
        } else {
            0.0
        }
    }

    /// Forms one measurement from the true values (motor pos, motor vel, load pos, torque).
    #[inline]
    pub fn measure(&mut self, truth: [f64; 4], period_s: f64) -> AxisSensor {
        let [mp, mv, lp, t] = truth;
        if !self.noisy && self.p.q_motor == 0.0 && self.p.q_load == 0.0 && !self.p.difference {
            return AxisSensor {
                motor_pos: mp,
                motor_vel: mv,
                load_pos: lp,
                applied_torque: t,
            };
        }
        let motor_pos = quantise(mp + self.noise(0), self.p.q_motor, self.inv_q_motor);
        let motor_vel = if self.p.difference {
            (motor_pos - self.prev_motor_pos) / period_s
        } else {
            mv + self.noise(1)
        };
        self.prev_motor_pos = motor_pos;
        let load_pos = quantise(lp + self.noise(2), self.p.q_load, self.inv_q_load);
        let applied_torque = t + self.noise(3);
        AxisSensor {
            motor_pos,
            motor_vel,
            load_pos,
            applied_torque,
        }
    }

    /// Forgets the previous motor position (next difference velocity is taken against `pos`).
    pub fn reset_position(&mut self, motor_pos: f64) {
        self.prev_motor_pos = quantise(motor_pos, self.p.q_motor, self.inv_q_motor);
    }
}
