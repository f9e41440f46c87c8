//! `cogging`: detent torque of the motor, periodic in motor angle (or position for a linear motor).
//!
//! Equation: `T = amplitude_nm sin(periods_per_rev thM + phase_rad)` on the motor (rad), or on a
//! rigid axis (linear motor) `F = amplitude_n sin(2 pi x / period_m + phase_rad)`.
//! Several harmonics may be given as `[[effects.cogging]]` (at most 8).
//!
//! Keys: `amplitude_nm` (>= 0, N m) and `periods_per_rev` (positive integer: a torque that is
//! periodic in the angle repeats a whole number of times per revolution) for ballscrew/rotary;
//! `amplitude_n` (>= 0, N) and `period_m` (> 0, magnet pitch) for rigid; optional `phase_rad`.
//!
//! Typical values: 0.5 .. 2 % of rated torque (0.01 .. 0.1 N m for a 1 kW servo); orders
//! `periods_per_rev` = lcm(poles, slots), e.g. 12, 36, 72; linear motors 20 .. 60 mm pitch.
//!
//! Signature: a spectral line in motor torque and velocity at `periods_per_rev` times the
//! rotation frequency (moving with speed, unlike a mechanical resonance), and a ripple of the
//! standstill torque with position.
//!
//! Integration: evaluated once per period at the mid-period angle predicted from the motor
//! velocity, and held.

use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::{check_keys, put, Ctx, EffectTable};

/// The key of a period along the travel, m (also a pitch error's period).
pub const PERIOD_M: &str = "period_m";
/// The key of a phase, rad (also a pitch error's phase).
pub const PHASE_RAD: &str = "phase_rad";

/// One cogging harmonic in motor units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CoggingHarmonic {
    /// Amplitude, N m (N on a rigid axis).
    pub amplitude: f64,
    /// Spatial frequency, rad of phase per motor unit (N per rad, or 2 pi / period_m per m).
    pub wavenumber: f64,
    /// Phase, rad.
    pub phase_rad: f64,
}

impl CoggingHarmonic {
    /// A harmonic of zero amplitude.
    pub const ZERO: CoggingHarmonic = CoggingHarmonic {
        amplitude: 0.0,
        wavenumber: 0.0,
        phase_rad: 0.0,
    };

    /// Torque on the motor at motor position `th`.
    #[inline]
    pub fn torque(&self, th: f64) -> f64 {
        self.amplitude * (self.wavenumber * th + self.phase_rad).sin()
    }
}

/// How often a cogging harmonic repeats.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CoggingPeriod {
    /// Periods per motor revolution (`periods_per_rev`, rotary motors).
    PerRev(i64),
    /// Period along the travel, m (`period_m`, a rigid linear axis).
    Metres(f64),
}

/// One `[effects.cogging]` harmonic as the model file gives it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoggingParams {
    /// Amplitude, N m (`amplitude_nm`) or N on a rigid axis (`amplitude_n`).
    pub amplitude: f64,
    /// Its period.
    pub period: CoggingPeriod,
    /// Phase, rad (`phase_rad`, default 0).
    pub phase_rad: f64,
}

impl EffectTable for CoggingParams {
    /// Reads one `[effects.cogging]` table.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        if ctx.kind == AxisKind::Rigid {
            check_keys(f, &["amplitude_n", PERIOD_M, PHASE_RAD])?;
            let amplitude = f.f64("amplitude_n", Range::NonNegative)?;
            let period_m = f.f64(PERIOD_M, Range::Positive)?;
            let phase_rad = f.f64_or(PHASE_RAD, Range::Finite, 0.0)?;
            return Ok(Self {
                amplitude,
                period: CoggingPeriod::Metres(period_m),
                phase_rad,
            });
        }
        check_keys(f, &["amplitude_nm", "periods_per_rev", PHASE_RAD])?;
        let amplitude = f.f64("amplitude_nm", Range::NonNegative)?;
        let n = f.opt_i64("periods_per_rev", 1, 100_000)?.ok_or_else(|| {
            f.error(
                "periods_per_rev",
                "is required but missing (a positive integer)",
            )
        })?;
        let phase_rad = f.f64_or(PHASE_RAD, Range::Finite, 0.0)?;
        Ok(Self {
            amplitude,
            period: CoggingPeriod::PerRev(n),
            phase_rad,
        })
    }

    /// The model-file table.
    fn to_table(&self, _ctx: &Ctx) -> toml::Table {
        let mut t = toml::Table::new();
        match self.period {
            CoggingPeriod::Metres(p) => {
                put(&mut t, "amplitude_n", self.amplitude);
                put(&mut t, PERIOD_M, p);
            }
            CoggingPeriod::PerRev(n) => {
                put(&mut t, "amplitude_nm", self.amplitude);
                t.insert("periods_per_rev".into(), toml::Value::Integer(n));
            }
        }
        put(&mut t, PHASE_RAD, self.phase_rad);
        t
    }
}

impl CoggingParams {
    /// The harmonic in motor units.
    pub(crate) fn motor(&self) -> CoggingHarmonic {
        CoggingHarmonic {
            amplitude: self.amplitude,
            wavenumber: match self.period {
                CoggingPeriod::Metres(p) => 2.0 * std::f64::consts::PI / p,
                CoggingPeriod::PerRev(n) => n as f64,
            },
            phase_rad: self.phase_rad,
        }
    }
}
