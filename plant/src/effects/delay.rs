//! `delay`: pure transport delay between the torque command and the applied torque.
//!
//! Equation: `T_applied[k] = T_cmd[k - delay_cycles]` (commands before the start count as 0).
//! It comes on top of the loop's own one-cycle delay (a command computed from the sample of
//! cycle k is applied during period k).
//!
//! Keys: `delay_cycles` (integer, 0 .. 10000).
//!
//! Typical values: 1 .. 3 cycles (fieldbus, drive PWM update, computation).
//!
//! Signature: the cross-correlation between the torque command and the motor acceleration
//! (velocity increments) peaks `delay_cycles` later than without the effect; in closed loop, a
//! phase loss of `omega delay_cycles period` and a lower stability margin.
//!
//! Integration: a ring buffer allocated when the model is built.

use feedloop_model::params::{ConfigError, Fields};

use super::check_keys;

/// Parses `[effects.delay]`.
pub(crate) fn parse(f: &mut Fields<'_>, table: &toml::Table) -> Result<usize, ConfigError> {
    check_keys(f, table, &["delay_cycles"])?;
    let n = f.opt_i64("delay_cycles", 0, 10_000)?.ok_or_else(|| {
        f.error(
            "delay_cycles",
            "is required but missing (a whole number of cycles)",
        )
    })?;
    Ok(n as usize)
}
