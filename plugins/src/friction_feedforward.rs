//! `friction_feedforward`: plain Coulomb friction feedforward, the baseline a learned quadrant
//! compensation is compared with (seed 004's background: the fixed compensation it improves on).
//!
//! torque_ff += Fc sign(th'), th' the commanded velocity (`reference[1]`); nothing while the
//! command is at rest (th' = 0).
//!
//! Keys: `fc_nm` (N m, motor torque; rotary-motor axes) or `fc_n` (N, force; rigid axes), and on a
//! ball-screw axis optionally `fc_load_n` (N, friction of the table guides, converted to motor
//! torque F lead / (2 pi gear_ratio)). Both default to 0; they add. With the friction known
//! exactly it removes about 99 % of the reversal spike (brief); with a wrong Fc, the
//! remainder scales with the mismatch.

use std::path::Path;

use feedloop_control::controller::{AxisContext, AxisSignals, Controller, CycleContext, Stage};
use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use crate::keys::key_for;
use crate::plugin::{reference_only_plugin, AxisPlugin};

/// The friction feedforward.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrictionFeedforward {
    /// Coulomb level in motor units, N m (N).
    pub fc: f64,
}

impl AxisPlugin for FrictionFeedforward {
    const ID: &'static str = "friction_feedforward";
    const STAGE: Stage = Stage::Compensator;

    /// Reads `fc_nm` / `fc_n` / `fc_load_n`.
    fn build(params: &toml::Table, axis: &AxisContext, file: &Path) -> Result<Self, ConfigError> {
        let mut f = Fields::new(params, file, "");
        let kind = axis.plant.kind();
        let motor_key = key_for(kind, "fc_n", "fc_nm");
        let mut fc = f.f64_or(motor_key, Range::Within(0.0, 1e6), 0.0)?;
        if kind == AxisKind::BallScrew {
            fc +=
                f.f64_or("fc_load_n", Range::Within(0.0, 1e6), 0.0)? / axis.plant.motor_per_load();
        }
        f.finish()?;
        Ok(Self { fc })
    }
}

impl Controller for FrictionFeedforward {
    reference_only_plugin!();

    fn step(&mut self, _ctx: &CycleContext, io: &mut AxisSignals) {
        let v = io.reference[1];
        if v > 0.0 {
            io.torque_ff += self.fc;
        } else if v < 0.0 {
            io.torque_ff -= self.fc;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn load_side_friction_of_62_8_n_on_a_10_mm_screw_is_0_1_n_m() {
        let t: toml::Table = "fc_load_n = 62.83185307179586\nfc_nm = 0.05"
            .parse()
            .unwrap();
        let f =
            FrictionFeedforward::build(&t, &crate::test_util::ballscrew_axis(1e-4), Path::new("j"))
                .unwrap();
        assert!((f.fc - 0.15).abs() < 1e-12, "{}", f.fc);
    }

    #[test]
    fn torque_follows_the_sign_of_the_commanded_velocity_and_nan_adds_nothing() {
        let mut f = FrictionFeedforward { fc: 0.2 };
        let ctx = CycleContext {
            period_s: 1e-4,
            cycle: 0,
            t_s: 0.0,
        };
        for (v, want) in [(1.0, 0.2), (-1e-9, -0.2), (0.0, 0.0), (f64::NAN, 0.0)] {
            let mut io = AxisSignals::default();
            io.reference[1] = v;
            f.step(&ctx, &mut io);
            assert_eq!(io.torque_ff, want, "v {v}");
        }
    }

    #[test]
    fn rigid_axis_takes_fc_n_and_refuses_fc_nm() {
        let a = crate::test_util::rigid_axis(1e-4);
        let t: toml::Table = "fc_nm = 1".parse().unwrap();
        assert_eq!(
            FrictionFeedforward::build(&t, &a, Path::new("j"))
                .unwrap_err()
                .key,
            "fc_nm"
        );
        let t: toml::Table = "fc_n = 12".parse().unwrap();
        assert_eq!(
            FrictionFeedforward::build(&t, &a, Path::new("j"))
                .unwrap()
                .fc,
            12.0
        );
    }
}
