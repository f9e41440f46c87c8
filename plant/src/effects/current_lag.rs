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
use nalgebra::DMatrix;

use super::{one_table, read_one, Ctx, EffectTable};

/// Mean over a period of the share of the distance to the held command still left:
/// `tau / period (1 - exp(-period / tau))` (the applied torque is its [`relax`] by this).
pub(crate) fn mean_factor(tau_s: f64, period_s: f64) -> f64 {
    tau_s / period_s * (1.0 - (-period_s / tau_s).exp())
}

/// The lagged torque relaxing from `x` toward the held command `u` by `factor` (the decay over
/// a period, or [`mean_factor`] for its mean over the period).
#[inline]
pub(crate) fn relax(u: f64, x: f64, factor: f64) -> f64 {
    u + (x - u) * factor
}

/// Adds the lag's state `il` to the continuous `(A, B)`: `tau T' = T_cmd - T`, `T` driving the
/// motor of inertia `jm`.
pub(crate) fn stamp(a: &mut DMatrix<f64>, b: &mut DMatrix<f64>, il: usize, tau: f64, jm: f64) {
    a[(1, il)] = 1.0 / jm;
    a[(il, il)] = -1.0 / tau;
    b[(il, 0)] = 1.0 / tau;
}

/// `[effects.current_lag]`: the current loop's time constant, s (`tau_s`, 1 ns .. 10 s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurrentLagParams {
    /// Time constant, s.
    pub tau_s: f64,
}

one_number_table!(CurrentLagParams, tau_s, _ctx => "tau_s", Range::Within(1e-9, 10.0));
