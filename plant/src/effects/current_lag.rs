//! `current_lag`: first-order lag of the current (torque) loop.
//!
//! Equation: `tau_s dT/dt = T_cmd - T`, with `T_cmd` held over each period (after `delay` and
//! `torque_saturation`). The applied torque reported by the sensor is the mean of `T` over the
//! previous period.
//!
//! Keys: `tau_s` (> 0, s).
//!
//! Typical values: 1e-4 .. 1e-3 s (current-loop bandwidth 150 .. 1500 Hz).
//!
//! Signature: a torque step reaches 63 % after `tau_s`; in the frequency response a phase loss of
//! `atan(omega tau_s)` and a magnitude roll-off above `1 / (2 pi tau_s)` Hz.
//!
//! Integration: one more state of the exactly discretised linear part (exact).

use feedloop_model::params::{ConfigError, Fields, Range};

use super::check_keys;

/// Parses `[effects.current_lag]`.
pub(crate) fn parse(f: &mut Fields<'_>, table: &toml::Table) -> Result<f64, ConfigError> {
    check_keys(f, table, &["tau_s"])?;
    f.f64("tau_s", Range::Within(1e-9, 10.0))
}
