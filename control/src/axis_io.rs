//! What the plant measures on one axis and what the scheduler asks of it, per cycle: the
//! per-axis parts of the wire messages (`feedloop_runtime::shared::wire`), plain `#[repr(C)]`
//! data with no IPC attached, so that the physics and offline tools can use them alone.

use serde::{Deserialize, Serialize};

/// What the plant measured on one axis at the start of a cycle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[repr(C)]
pub struct AxisSensor {
    /// Motor position: rad for a rotary motor, m for a linear motor.
    pub motor_pos: f64,
    /// Motor velocity: rad/s or m/s.
    pub motor_vel: f64,
    /// Load position (linear scale / table encoder): m for a linear axis, rad for a rotary axis.
    pub load_pos: f64,
    /// Torque (N m) or force (N) the plant applied during the previous period.
    pub applied_torque: f64,
}

/// What the scheduler asks of one axis for the coming period.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[repr(C)]
pub struct AxisCommand {
    /// Torque (N m, rotary motor) or force (N, linear motor) to apply for one period (zero-order hold).
    pub torque: f64,
    /// Commanded load position at this cycle (m or rad); logged by the plant, not used by physics.
    pub reference: f64,
}
