//! `torque_saturation`: the drive clamps the torque (current) command.
//!
//! Equation: `T = clamp(T_cmd, -limit, +limit)`, applied after `delay` and before
//! `current_lag`.
//!
//! Keys: `limit_nm` (> 0, N m; ballscrew, rotary) or `limit_n` (> 0, N; rigid).
//!
//! Typical values: 3 .. 4 x the rated torque (a 1 kW servo: 10 .. 15 N m peak).
//!
//! Signature: the applied torque flattens at `+-limit` while the command goes beyond; in closed
//! loop, larger following error and integrator wind-up overshoot on fast moves.
//!
//! Integration: exact (the held torque is clamped).

use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::{one_table, read_one, Ctx, EffectTable};

/// The applied command: `u` clamped to `+-limit`.
#[inline]
pub(crate) fn clamp(u: f64, limit: f64) -> f64 {
    u.clamp(-limit, limit)
}

/// `[effects.torque_saturation]`: the drive's torque limit, N m (`limit_nm`), or its force limit
/// on a rigid axis, N (`limit_n`), in motor units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TorqueSaturationParams {
    /// The limit, > 0.
    pub limit: f64,
}

/// The key of the limit on an axis of `kind`.
fn key(kind: AxisKind) -> &'static str {
    if kind == AxisKind::Rigid {
        "limit_n"
    } else {
        "limit_nm"
    }
}

one_number_table!(TorqueSaturationParams, limit, ctx => key(ctx.kind), Range::Positive);
