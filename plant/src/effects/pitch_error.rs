//! `pitch_error`: lead error of the ball screw, periodic over one lead plus a cumulative part.
//!
//! Equation: the nut advance for a screw position `x = thM / r` (m, `r = 2 pi gear / lead`) is
//! `x + e(x)` with `e(x) = amplitude_m sin(2 pi x / period_m + phase_rad) + slope_um_per_m 1e-6 x`.
//! The error sits inside the transmission: the spring deflection becomes
//! `d = thM + r e(thM / r) - thL`, so with the table held by the scale loop the motor angle
//! carries the error, and the table (linear scale) is where it should be.
//!
//! Keys (ball-screw axes only): `amplitude_m` (>= 0), optional `period_m` (> 0, default the
//! model's `lead_m`), optional `phase_rad`, optional `slope_um_per_m` (cumulative lead error,
//! um per m of travel, any sign).
//!
//! Typical values: ground screw (class C3) 1 .. 3 um periodic, 5 .. 10 um/m cumulative; rolled
//! screw (C7) up to 10 um periodic, 50 um/m cumulative.
//!
//! Signature: motor position (converted to m) minus scale position varies periodically with
//! position, period = lead, amplitude = `amplitude_m`, plus a linear trend of `slope_um_per_m`; it
//! follows position, not time, so a slower move shows the same shape over a longer time.
//!
//! Integration: `e` is evaluated once per period at the mid-period motor angle (predicted from
//! the motor velocity) and held; the resulting spring torque enters as a held input.

use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::cogging::{PERIOD_M, PHASE_RAD};
use super::{check_keys, put, table_error, Ctx, EffectTable};

/// Pitch error parameters (load units, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PitchError {
    /// Periodic amplitude, m.
    pub amplitude_m: f64,
    /// Period, m.
    pub period_m: f64,
    /// Phase, rad.
    pub phase_rad: f64,
    /// Cumulative error, m per m.
    pub slope: f64,
}

impl PitchError {
    /// Error e(x) (m) and its slope de/dx (m/m) at screw position `x` (m).
    #[inline]
    pub fn eval(&self, x: f64) -> (f64, f64) {
        let k = 2.0 * std::f64::consts::PI / self.period_m;
        let (s, c) = (k * x + self.phase_rad).sin_cos();
        (
            self.amplitude_m * s + self.slope * x,
            self.amplitude_m * k * c + self.slope,
        )
    }

    /// At motor angle `th_m` (motor velocity `wm`): the deflection offset `r e(thM / r)` in motor
    /// units and the spring torque it adds, `KL r e + CL e' wM`. `scale` is (load units per motor
    /// unit, motor units per load unit), `spring` the transmission's (KL, CL).
    #[inline]
    pub fn held(&self, th_m: f64, wm: f64, scale: (f64, f64), spring: (f64, f64)) -> (f64, f64) {
        let (e, de) = self.eval(th_m * scale.0);
        let e_m = e * scale.1;
        (e_m, spring.0 * e_m + spring.1 * de * wm)
    }
}

/// `[effects.pitch_error]` as the model file gives it (m, rad, um per m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PitchErrorParams {
    /// Periodic amplitude, m (`amplitude_m`).
    pub amplitude_m: f64,
    /// Period, m (`period_m`; the screw's lead when not given).
    pub period_m: f64,
    /// Phase, rad (`phase_rad`, default 0).
    pub phase_rad: f64,
    /// Cumulative lead error, um per m of travel (`slope_um_per_m`, default 0).
    pub slope_um_per_m: f64,
}

impl EffectTable for PitchErrorParams {
    /// Reads `[effects.pitch_error]`.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        let (AxisKind::BallScrew, Some(lead_m)) = (ctx.kind, ctx.lead_m) else {
            return Err(table_error(
            f,
            "pitch_error needs a screw (kind = \"ballscrew\"); use cogging for angle-periodic torque",
        ));
        };
        check_keys(f, &["amplitude_m", PERIOD_M, PHASE_RAD, "slope_um_per_m"])?;
        let amplitude_m = f.f64("amplitude_m", Range::NonNegative)?;
        let period_m = f.f64_or(PERIOD_M, Range::Positive, lead_m)?;
        let phase_rad = f.f64_or(PHASE_RAD, Range::Finite, 0.0)?;
        let slope_um = f.f64_or("slope_um_per_m", Range::Within(-1e4, 1e4), 0.0)?;
        if amplitude_m * 2.0 * std::f64::consts::PI / period_m >= 0.5 {
            return Err(f.error(
                "amplitude_m",
                format!(
                "an error of {amplitude_m} m over a period of {period_m} m is not a pitch error \
                 (slope 2 pi amplitude / period must stay below 0.5)"
            ),
            ));
        }
        Ok(Self {
            amplitude_m,
            period_m,
            phase_rad,
            slope_um_per_m: slope_um,
        })
    }

    /// The model-file table.
    fn to_table(&self, _ctx: &Ctx) -> toml::Table {
        let mut t = toml::Table::new();
        put(&mut t, "amplitude_m", self.amplitude_m);
        put(&mut t, PERIOD_M, self.period_m);
        put(&mut t, PHASE_RAD, self.phase_rad);
        put(&mut t, "slope_um_per_m", self.slope_um_per_m);
        t
    }
}

impl PitchErrorParams {
    /// The law's parameters.
    pub(crate) fn motor(&self) -> PitchError {
        PitchError {
            amplitude_m: self.amplitude_m,
            period_m: self.period_m,
            phase_rad: self.phase_rad,
            slope: self.slope_um_per_m * 1e-6,
        }
    }
}
