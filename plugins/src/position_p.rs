//! `position_p`: proportional position loop on the load position (seed 000, Fig. 1 / claim 1).
//!
//! V = Kp (th - thL)
//!
//! th is the commanded position, thL the measured load position (table scale), both in motor
//! units (rad for a ball-screw axis, m for a linear axis); V is the velocity command handed to
//! the velocity loop (motor units per s). Kp (`kp_per_s`, 1/s) sets the position bandwidth; at a
//! constant feed v the steady following error is v / Kp. Typical Kp: 20 .. 150 1/s.
//!
//! Optional `vel_filter_hz` (Hz, 0 or absent = off): a first-order low-pass on this stage's own
//! velocity command, V = LP(Kp (th - thL)), discretised bilinearly with prewarp at the corner
//! (see [`crate::filters`]); feedforward stages added after it are not filtered. Must be below
//! 0.45 / period. Its state is the snapshot.
//!
//! The drive's own feed-forwards, as every CNC drive has them (defaults from the model's
//! `[controller]`, 0 when absent): `velocity_ff` adds that share of the commanded velocity to V
//! (`V += velocity_ff dth/dt`), and `torque_ff_kgm2` (`force_ff_kg` on a rigid axis) adds that
//! inertia times the commanded acceleration to the torque feed-forward the velocity loop adds to
//! its output. Neither is filtered.

use std::path::Path;

use feedloop_control::controller::{
    AxisContext, AxisSignals, Controller, ControllerState, CycleContext, Stage,
};
use feedloop_model::params::{ConfigError, Fields, Range};

use crate::filters::LowPass1;
use crate::keys::{key_for, read_hz, read_kp};
use crate::plugin::{axis_plugin, AxisPlugin, PluginParams};

/// Parameters of [`PositionP`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionPParams {
    /// Position loop gain, 1/s.
    pub kp_per_s: f64,
    /// Low-pass corner on the output velocity command, Hz (`vel_filter_hz`); `None` = off.
    pub vel_filter_hz: Option<f64>,
    /// Sampling period the filter is discretised for, s.
    pub period_s: f64,
    /// Share of the commanded velocity fed forward (`velocity_ff`), 0 = off.
    pub velocity_ff: f64,
    /// Inertia the commanded acceleration is fed forward with (`torque_ff_kgm2` /
    /// `force_ff_kg`), 0 = off.
    pub torque_ff: f64,
}

impl PluginParams for PositionPParams {
    /// Reads `kp_per_s` from `f`, defaulting to the model's `[controller]`.
    fn read(mut f: Fields<'_>, axis: &AxisContext, file: &Path) -> Result<Self, ConfigError> {
        let kp = read_kp(&mut f)?;
        let vel_filter_hz = read_hz(&mut f, "vel_filter_hz", axis.period_s)?.flatten();
        let ff_key = key_for(axis.plant.kind(), "force_ff_kg", "torque_ff_kgm2");
        let velocity_ff = f
            .opt_f64("velocity_ff", Range::Within(0.0, 1.5))?
            .or(axis.defaults.velocity_ff)
            .unwrap_or(0.0);
        let torque_ff = f
            .opt_f64(ff_key, Range::NonNegative)?
            .or(axis.defaults.torque_ff)
            .unwrap_or(0.0);
        f.finish()?;
        let kp_per_s = axis.param_or_model(kp, axis.defaults.kp_per_s, "kp_per_s", file)?;
        Ok(Self {
            kp_per_s,
            vel_filter_hz,
            period_s: axis.period_s,
            velocity_ff,
            torque_ff,
        })
    }
}

/// The position P controller.
#[derive(Debug, Clone)]
pub struct PositionP {
    params: PositionPParams,
    filter: Option<LowPass1>,
}

axis_plugin!(PositionP, PositionPParams, "position_p", Stage::Position);

impl PositionP {
    /// Builds the controller.
    pub fn new(params: PositionPParams) -> Self {
        Self {
            filter: params
                .vel_filter_hz
                .map(|hz| LowPass1::new(hz, params.period_s)),
            params,
        }
    }
}

impl Controller for PositionP {
    fn id(&self) -> &str {
        Self::ID
    }

    fn loop_gains(&self) -> feedloop_control::loop_model::LoopGains {
        feedloop_control::loop_model::LoopGains {
            kp_per_s: Some(self.params.kp_per_s),
            ..Default::default()
        }
    }

    fn step(&mut self, _ctx: &CycleContext, io: &mut AxisSignals) {
        let v = self.params.kp_per_s * (io.reference[0] - io.load_pos);
        let v = match &mut self.filter {
            Some(f) => {
                let y = f.process(v);
                if y.is_finite() {
                    y
                } else {
                    f.settle(0.0);
                    0.0
                }
            }
            None if v.is_finite() => v,
            None => 0.0,
        };
        io.vel_cmd += v;
        // the drive's feed-forwards (not filtered; 0 when the model gives none)
        let vff = self.params.velocity_ff * io.reference[1];
        if vff.is_finite() {
            io.vel_cmd += vff;
        }
        let tff = self.params.torque_ff * io.reference[2];
        if tff.is_finite() {
            io.torque_ff += tff;
        }
    }

    fn snapshot(&self) -> ControllerState {
        match &self.filter {
            Some(f) => ControllerState::from_slice(&[f.state()]),
            None => ControllerState::EMPTY,
        }
    }

    fn restore(&mut self, state: &ControllerState) {
        if let Some(f) = &mut self.filter {
            f.set_state(state.finite_or_zero(0));
        }
    }

    fn initialize_from(&mut self, last: &AxisSignals) {
        if let Some(f) = &mut self.filter {
            let v = self.params.kp_per_s * (last.reference[0] - last.load_pos);
            f.settle(if v.is_finite() { v } else { 0.0 });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn velocity_command_is_gain_times_position_error() {
        let mut c = PositionP::new(PositionPParams {
            velocity_ff: 0.0,
            torque_ff: 0.0,
            kp_per_s: 40.0,
            vel_filter_hz: None,
            period_s: 1e-4,
        });
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

    #[test]
    fn the_drives_feed_forwards_come_from_the_model_and_add_to_both_commands() {
        let mut axis = crate::test_util::ballscrew_axis(1e-4);
        axis.defaults.velocity_ff = Some(0.8);
        axis.defaults.torque_ff = Some(4e-3);
        let p =
            PositionPParams::from_table(&toml::Table::new(), &axis, Path::new("j.toml")).unwrap();
        assert_eq!((p.velocity_ff, p.torque_ff), (0.8, 4e-3));
        // a job's plugin parameters override the model's
        let t: toml::Table = "velocity_ff = 0.5".parse().unwrap();
        let q = PositionPParams::from_table(&t, &axis, Path::new("j.toml")).unwrap();
        assert_eq!(q.velocity_ff, 0.5);
        let mut c = PositionP::new(p);
        let mut io = AxisSignals {
            reference: [0.0, 10.0, 2000.0, 0.0, 0.0, 0.0],
            ..Default::default()
        };
        let ctx = CycleContext {
            period_s: 1e-4,
            cycle: 0,
            t_s: 0.0,
        };
        c.step(&ctx, &mut io);
        assert!((io.vel_cmd - 8.0).abs() < 1e-12, "{}", io.vel_cmd);
        assert!((io.torque_ff - 8.0).abs() < 1e-12, "{}", io.torque_ff);
        // out of range is refused with the key
        let bad: toml::Table = "velocity_ff = 3.0".parse().unwrap();
        let e = PositionPParams::from_table(&bad, &axis, Path::new("j.toml")).unwrap_err();
        assert!(e.to_string().contains("velocity_ff"), "{e}");
    }

    #[test]
    fn filtered_velocity_command_reaches_63_percent_after_one_time_constant() {
        let t: toml::Table = "vel_filter_hz = 100".parse().unwrap();
        let axis = crate::test_util::ballscrew_axis(1e-4);
        let p = PositionPParams::from_table(&t, &axis, Path::new("j.toml")).unwrap();
        assert_eq!(p.kp_per_s, 50.0);
        let mut c = PositionP::new(p);
        let ctx = CycleContext {
            period_s: 1e-4,
            cycle: 0,
            t_s: 0.0,
        };
        // tau = 1 / (2 pi 100) = 1.59 ms = 15.9 cycles
        let mut v = 0.0;
        for _ in 0..16 {
            let mut io = AxisSignals::default();
            io.reference[0] = 0.02;
            c.step(&ctx, &mut io);
            v = io.vel_cmd;
        }
        let frac = v / (50.0 * 0.02);
        assert!((frac - 0.63).abs() < 0.02, "{frac}");
        assert_eq!(c.snapshot().len, 1);
    }

    #[test]
    fn nan_load_position_gives_a_zero_velocity_command() {
        let t: toml::Table = "vel_filter_hz = 100".parse().unwrap();
        let axis = crate::test_util::ballscrew_axis(1e-4);
        let mut c = PositionP::new(PositionPParams::from_table(&t, &axis, Path::new("j")).unwrap());
        let ctx = CycleContext {
            period_s: 1e-4,
            cycle: 0,
            t_s: 0.0,
        };
        let mut io = AxisSignals {
            load_pos: f64::NAN,
            ..Default::default()
        };
        c.step(&ctx, &mut io);
        assert_eq!(io.vel_cmd, 0.0);
        io.load_pos = 0.0;
        io.reference[0] = 1.0;
        c.step(&ctx, &mut io);
        assert!(io.vel_cmd.is_finite() && io.vel_cmd > 0.0);
    }
}
