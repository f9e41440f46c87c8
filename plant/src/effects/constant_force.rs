//! `constant_force`: a constant force on the load (gravity on a vertical axis, counterbalance
//! offset, a cable or hose pulling).
//!
//! Equation: the load feels `+force_n` (N, along +x) on a ball-screw table or a rigid mass, or
//! `+torque_nm` (N m) on a rotary load. Reflected to the motor of a ball screw it is
//! `force_n lead_m / (2 pi gear_ratio)` N m.
//!
//! Keys: `force_n` (ballscrew, rigid) or `torque_nm` (rotary); any finite sign (negative pulls
//! toward -x, e.g. gravity on an upward +z axis).
//!
//! Typical values: vertical axis with 50 kg: -490 N; counterbalance mismatch 10 .. 100 N; EMPS
//! about +3 N (the benchmark's published offset of -3.16 N is a term of the motor force: minus
//! this force).
//!
//! Signature: a torque offset at standstill equal to the reflected force (opposite sign), the
//! same in both directions of travel (unlike friction, which flips sign with velocity).
//!
//! Integration: a constant input of the exactly discretised linear part (exact).

use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::{one_table, read_one, Ctx, EffectTable};

/// `[effects.constant_force]`: the force on the load, N (`force_n`), or the torque on a rotary
/// axis, N m (`torque_nm`); positive along +x.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConstantForceParams {
    /// Force (N) or torque (N m) on the load.
    pub value: f64,
}

/// The key of the force on an axis of `kind`.
fn key(kind: AxisKind) -> &'static str {
    if kind == AxisKind::Rotary {
        "torque_nm"
    } else {
        "force_n"
    }
}

one_number_table!(ConstantForceParams, value, ctx => key(ctx.kind), Range::Finite);

impl ConstantForceParams {
    /// The load torque in motor units.
    pub(crate) fn motor(&self, ctx: &Ctx) -> f64 {
        self.value * ctx.load_units().torque_to_motor
    }
}
