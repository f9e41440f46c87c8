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
//!
//! A measured velocity-dependent curve (what `feedloop commission` writes), motor side:
//! `fs_nm` (static level, default `fc_nm`), `vs_rad_per_s` (Stribeck velocity), the shape exponent
//! (`stribeck_exponent`, default 2), `fc_neg_nm` / `fs_neg_nm` (levels for negative velocity, default the positive
//! ones), `c_nms_per_rad` (viscous, default 0): torque_ff += sign(w) (fc + (fs - fc)
//! exp(-(|w| / vs)^exponent) + c |w|) at the commanded motor velocity w. [`FrictionCurve`] is
//! shared with `quadrant_compensator`, which plays it under its learned pulses.

use std::path::Path;

use feedloop_control::controller::{AxisContext, AxisSignals, Controller, CycleContext, Stage};
use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use crate::keys::key_for;
use crate::plugin::{reference_only_plugin, AxisPlugin};

/// The friction feedforward.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrictionFeedforward {
    /// The friction played, motor units: a Coulomb level alone ([`FrictionCurve::coulomb`])
    /// unless the curve's keys are given.
    pub curve: FrictionCurve,
}

/// A measured friction curve per direction, motor side: `T(w) = fc + (fs - fc) exp(-(|w| /
/// vs)^e) + c |w|` for each sign of w.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrictionCurve {
    /// Coulomb levels, positive and negative velocity, N m.
    pub fc: [f64; 2],
    /// Static levels, N m.
    pub fs: [f64; 2],
    /// Stribeck velocity, rad/s.
    pub vs: f64,
    /// Shape exponent.
    pub exponent: f64,
    /// Viscous coefficient, N m s/rad.
    pub c: f64,
}

impl FrictionCurve {
    /// Reads the curve's keys (none given: `None`); `fc` is the Coulomb level read already.
    pub fn read(f: &mut Fields<'_>, fc: f64) -> Result<Option<Self>, ConfigError> {
        let level = Range::Within(0.0, 1e6);
        let fs = f.opt_f64("fs_nm", level)?;
        let vs = f.opt_f64("vs_rad_per_s", Range::Within(1e-9, 1e9))?;
        let exponent = f.f64_or("stribeck_exponent", Range::Within(0.5, 4.0), 2.0)?;
        let fc_neg = f.opt_f64("fc_neg_nm", level)?;
        let fs_neg = f.opt_f64("fs_neg_nm", level)?;
        let c = f.f64_or("c_nms_per_rad", Range::Within(0.0, 1e6), 0.0)?;
        if fs.is_none() && vs.is_none() && fc_neg.is_none() && fs_neg.is_none() && c == 0.0 {
            return Ok(None);
        }
        let fs = fs.unwrap_or(fc).max(fc);
        let fc_neg = fc_neg.unwrap_or(fc);
        Ok(Some(Self {
            fc: [fc, fc_neg],
            fs: [fs, fs_neg.unwrap_or(fs).max(fc_neg)],
            vs: vs.unwrap_or(1.0),
            exponent,
            c,
        }))
    }

    /// A Coulomb level alone, the same in both directions.
    pub fn coulomb(fc: f64) -> Self {
        Self {
            fc: [fc; 2],
            fs: [fc; 2],
            vs: 1.0,
            exponent: 2.0,
            c: 0.0,
        }
    }

    /// The friction torque at motor velocity `w` (0 at rest), N m.
    #[inline]
    pub fn torque(&self, w: f64) -> f64 {
        if !(w != 0.0 && w.is_finite()) {
            return 0.0;
        }
        let d = usize::from(w < 0.0);
        let a = w.abs();
        let rise = self.fs[d] - self.fc[d];
        let stribeck = if rise > 0.0 {
            rise * (-(a / self.vs).powf(self.exponent)).exp()
        } else {
            0.0
        };
        w.signum() * (self.fc[d] + stribeck + self.c * a)
    }
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
        let curve = if kind == AxisKind::Rigid {
            None
        } else {
            FrictionCurve::read(&mut f, fc)?
        };
        f.finish()?;
        Ok(Self {
            curve: curve.unwrap_or(FrictionCurve::coulomb(fc)),
        })
    }
}

impl Controller for FrictionFeedforward {
    reference_only_plugin!();

    fn step(&mut self, _ctx: &CycleContext, io: &mut AxisSignals) {
        io.torque_ff += self.curve.torque(io.reference[1]);
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
        assert!((f.curve.fc[0] - 0.15).abs() < 1e-12, "{:?}", f.curve);
        assert_eq!(f.curve, FrictionCurve::coulomb(f.curve.fc[0]));
    }

    #[test]
    fn torque_follows_the_sign_of_the_commanded_velocity_and_nan_adds_nothing() {
        let mut f = FrictionFeedforward {
            curve: FrictionCurve::coulomb(0.2),
        };
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
    fn a_stribeck_curve_gives_the_static_level_at_slow_speed_and_coulomb_plus_viscous_fast() {
        let t: toml::Table =
            "fc_nm = 0.1\nfs_nm = 0.2\nvs_rad_per_s = 1.0\nfc_neg_nm = 0.12\nc_nms_per_rad = 0.01"
                .parse()
                .unwrap();
        let f =
            FrictionFeedforward::build(&t, &crate::test_util::ballscrew_axis(1e-4), Path::new("j"))
                .unwrap();
        let c = f.curve;
        assert!((c.torque(1e-6) - 0.2).abs() < 1e-6);
        assert!((c.torque(100.0) - 1.1).abs() < 1e-9);
        assert!((c.torque(-100.0) + 1.12).abs() < 1e-9);
        assert!((c.torque(-1e-6) + 0.2).abs() < 1e-6, "{}", c.torque(-1e-6));
        assert_eq!(c.torque(0.0), 0.0);
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
                .curve
                .fc,
            [12.0; 2]
        );
    }
}
