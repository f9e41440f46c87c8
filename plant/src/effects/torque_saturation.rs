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

use super::{check_keys, Ctx};

/// The applied command: `u` clamped to `+-limit`.
#[inline]
pub(crate) fn clamp(u: f64, limit: f64) -> f64 {
    u.clamp(-limit, limit)
}

/// Parses `[effects.torque_saturation]`.
pub(crate) fn parse(
    f: &mut Fields<'_>,
    table: &toml::Table,
    ctx: &Ctx,
) -> Result<f64, ConfigError> {
    let key = if ctx.kind == AxisKind::Rigid {
        "limit_n"
    } else {
        "limit_nm"
    };
    check_keys(f, table, &[key])?;
    f.f64(key, Range::Positive)
}
