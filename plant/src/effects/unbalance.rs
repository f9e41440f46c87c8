//! `unbalance`: a load torque that depends on the axis' own angle: gravity on an unbalanced
//! rotary load (a swivel head, a tilting table, a robot joint), plus a constant part.
//!
//! Equation: with the load angle `thL` (rad, at the load), the torque acting on the load is
//! `T = constant_nm - mgr_nm sin(2 pi (thL - zero_angle_rad) / period_rad)`: an unbalanced mass
//! `m` at radius `r` under gravity `g` pulls the load back toward `zero_angle_rad`, the angle at
//! which it hangs straight down (`mgr_nm` = m g r). The period is one load revolution (2 pi) on
//! a load measured in its own radians; a record whose load column is referred to the motor
//! (link angle times the gear ratio, as robot controllers log it) repeats over 2 pi times that
//! ratio. On the motor the torque acts through the gear as `T / gear_ratio`.
//!
//! Keys (rotary axes only): `mgr_nm` (>= 0, N m at the load), optional `zero_angle_rad` (the
//! load angle of zero torque that the load returns to, default 0), optional `constant_nm` (a
//! constant torque at the load along +thL, any sign, default 0), optional `period_rad` (> 0,
//! the load angle over which it repeats, default 2 pi).
//!
//! Typical values: a swivel head of 200 kg with its centre of mass 50 mm off the axis: 98 N m; a
//! counterbalanced robot arm: a few hundred N m at the link.
//!
//! Signature: the torque residual follows the load angle, not the time or the direction of
//! travel: one period per load revolution, the same in both directions (friction flips with the
//! direction, this does not).
//!
//! Integration: evaluated once per period at the predicted mid-period load angle and held, as
//! the other position-dependent torques.

use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::{check_keys, put, table_error, Ctx, EffectTable};

/// `[effects.unbalance]` as the model file gives it (at the load).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnbalanceParams {
    /// Amplitude `m g r`, N m at the load, >= 0 (`mgr_nm`).
    pub mgr_nm: f64,
    /// Load angle of zero torque that the load returns to, rad (`zero_angle_rad`).
    pub zero_angle_rad: f64,
    /// Constant torque at the load along +thL, N m (`constant_nm`).
    pub constant_nm: f64,
    /// Load angle over which it repeats, rad (`period_rad`, 2 pi: one revolution).
    pub period_rad: f64,
}

impl EffectTable for UnbalanceParams {
    /// Reads `[effects.unbalance]`.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        if ctx.kind != AxisKind::Rotary {
            return Err(table_error(
                f,
                "unbalance needs a rotary load (kind = \"rotary\"); a linear axis under gravity has a constant_force",
            ));
        }
        check_keys(
            f,
            &["mgr_nm", "zero_angle_rad", "constant_nm", "period_rad"],
        )?;
        let mgr_nm = f.f64("mgr_nm", Range::NonNegative)?;
        let zero_angle_rad = f.f64_or("zero_angle_rad", Range::Finite, 0.0)?;
        let constant_nm = f.f64_or("constant_nm", Range::Finite, 0.0)?;
        let period_rad = f.f64_or("period_rad", Range::Positive, 2.0 * std::f64::consts::PI)?;
        Ok(Self {
            mgr_nm,
            zero_angle_rad,
            constant_nm,
            period_rad,
        })
    }

    /// The model-file table.
    fn to_table(&self, _ctx: &Ctx) -> toml::Table {
        let mut t = toml::Table::new();
        put(&mut t, "mgr_nm", self.mgr_nm);
        put(&mut t, "zero_angle_rad", self.zero_angle_rad);
        put(&mut t, "constant_nm", self.constant_nm);
        put(&mut t, "period_rad", self.period_rad);
        t
    }
}

impl UnbalanceParams {
    /// The law, on the motor.
    pub(crate) fn motor(&self, ctx: &Ctx) -> Unbalance {
        Unbalance {
            params: *self,
            wavenumber: 2.0 * std::f64::consts::PI / self.period_rad,
            torque_to_motor: ctx.load_units().torque_to_motor,
        }
    }
}

/// The unbalance law as the integrator evaluates it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Unbalance {
    params: UnbalanceParams,
    /// `2 pi / period_rad`, rad of phase per rad of load angle.
    wavenumber: f64,
    /// Load torque to motor torque (1 / gear ratio).
    torque_to_motor: f64,
}

impl Unbalance {
    /// Torque on the motor (motor units) at load angle `th_load` (rad at the load).
    #[inline]
    pub fn torque(&self, th_load: f64) -> f64 {
        let p = &self.params;
        (p.constant_nm - p.mgr_nm * (self.wavenumber * (th_load - p.zero_angle_rad)).sin())
            * self.torque_to_motor
    }
}
