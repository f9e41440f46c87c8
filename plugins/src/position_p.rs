//! `position_p`: proportional position loop on the load position (seed 000, Fig. 1 / claim 1).
//!
//! V = Kp (th - thL)
//!
//! th is the commanded position, thL the measured load position (table scale), both in motor
//! units (rad for a ball-screw axis, m for a linear axis); V is the velocity command handed to
//! the velocity loop (motor units per s). Kp (`kp_per_s`, 1/s) sets the position bandwidth; at a
//! constant feed v the steady following error is v / Kp. Typical Kp: 20 .. 150 1/s.

use std::path::Path;

use feedloop_runtime::controller::{
    AxisContext, AxisSignals, Controller, ControllerState, CycleContext,
};
use feedloop_runtime::params::{ConfigError, Fields, Range};

/// Parameters of [`PositionP`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionPParams {
    /// Position loop gain, 1/s.
    pub kp_per_s: f64,
}

impl PositionPParams {
    /// Reads `kp_per_s` from `params`, defaulting to the model's `[controller]`.
    pub fn from_table(
        params: &toml::Table,
        axis: &AxisContext,
        file: &Path,
    ) -> Result<Self, ConfigError> {
        let mut f = Fields::new(params, file, "");
        let kp = f.opt_f64("kp_per_s", Range::Within(0.0, 1.0e5))?;
        f.finish()?;
        let kp_per_s = kp.or(axis.defaults.kp_per_s).ok_or_else(|| {
            ConfigError::new(
                file,
                "kp_per_s",
                format!(
                    "is required: give it in the plugin params or in the [controller] table of axis `{}`'s model",
                    axis.name
                ),
            )
        })?;
        Ok(Self { kp_per_s })
    }
}

/// The position P controller.
#[derive(Debug, Clone)]
pub struct PositionP {
    params: PositionPParams,
}

impl PositionP {
    /// Plugin id.
    pub const ID: &'static str = "position_p";

    /// Builds the controller.
    pub fn new(params: PositionPParams) -> Self {
        Self { params }
    }
}

impl Controller for PositionP {
    fn id(&self) -> &str {
        Self::ID
    }

    fn step(&mut self, _ctx: &CycleContext, io: &mut AxisSignals) {
        io.vel_cmd += self.params.kp_per_s * (io.reference[0] - io.load_pos);
    }

    fn snapshot(&self) -> ControllerState {
        ControllerState::EMPTY
    }

    fn restore(&mut self, _state: &ControllerState) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn velocity_command_is_gain_times_position_error() {
        let mut c = PositionP::new(PositionPParams { kp_per_s: 40.0 });
        let mut io = AxisSignals {
            load_pos: 1.0,
            ..Default::default()
        };
        io.reference[0] = 1.5;
        let ctx = CycleContext {
            period_s: 1e-4,
            cycle: 0,
            t_s: 0.0,
        };
        c.step(&ctx, &mut io);
        assert!((io.vel_cmd - 20.0).abs() < 1e-12);
    }
}
