//! What the plant loop needs of a plant: the simulated physics (`feedloop-plant`) or a driver
//! for real hardware. Both work on the per-axis parts of the wire messages, so a device needs
//! no IPC: the plant process's loop (`feedloop_runtime::plant`) fills and reads the messages
//! around it.

use crate::axis_io::{AxisCommand, AxisSensor};

/// A plant the plant process can drive, one period at a time.
pub trait PlantDevice {
    /// Number of axes.
    fn axis_count(&self) -> usize;
    /// Writes the current measurement of axis `i` into `out[i]`, for the first
    /// `min(axis_count, out.len())` axes.
    fn sense(&mut self, out: &mut [AxisSensor]);
    /// Applies `cmd[i].torque` to axis `i` for one period (zero-order hold).
    fn step(&mut self, cmd: &[AxisCommand]);
}
