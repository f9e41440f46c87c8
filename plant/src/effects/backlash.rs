//! `backlash`: a dead zone of width `gap` between screw and nut (or in a gear train).
//!
//! Equation: with the motor-side deflection `d = thM + e_pitch - thL` (motor rad) and the
//! half gap `g/2`, the transmitted torque is
//! `T = KL (d - g/2) + CL (wM - wL)` for `d > g/2`, `T = KL (d + g/2) + CL (wM - wL)` for
//! `d < -g/2`, and `T = 0` inside the gap, where motor and load move independently.
//!
//! Keys: `gap_m` (ball screw: axial play between screw and nut, m, >= 0) or `gap_rad` (rotary
//! axis: angular play at the load, rad, >= 0). Not available on a rigid axis. A zero gap switches
//! the effect off.
//!
//! Typical values: preloaded ball nut 0 .. 5 um; worn screw 10 .. 50 um; gear train 1e-4 ..
//! 1e-3 rad.
//!
//! Signature: lost motion at reversals: the motor position (in load units) minus the load
//! position jumps by about the gap between the two directions of travel; the load stands still
//! for the time the motor needs to cross the gap, giving a following-error spike on the scale
//! and an impact when contact is regained.
//!
//! Integration: three exactly discretised linear modes (contact +, gap, contact -); contact
//! changes are located by bisection inside a period (to period/1024).

use feedloop_model::params::{ConfigError, Fields, Range};

use super::{check_keys, needs_transmission, put, Ctx, EffectTable};

/// Contact state at deflection `d` (motor units) with half gap `gap_half`: +1 driving in +, -1
/// driving in -, 0 inside the gap.
#[inline]
pub(crate) fn contact(d: f64, gap_half: f64) -> i8 {
    if d > gap_half {
        1
    } else if d < -gap_half {
        -1
    } else {
        0
    }
}

/// Whether deflection `d` is consistent with contact state `contact` (on or beyond its flank,
/// or inside the gap).
#[inline]
pub(crate) fn consistent(contact: i8, d: f64, gap_half: f64) -> bool {
    match contact {
        1 => d >= gap_half,
        -1 => d <= -gap_half,
        _ => d.abs() <= gap_half,
    }
}

/// The held spring torque on the load in contact state `contact`: the other held spring torque
/// `pt` less the spring's torque over the half gap (`KL gap/2`); 0 inside the gap.
#[inline]
pub(crate) fn held_spring(contact: i8, pt: f64, kl: f64, gap_half: f64) -> f64 {
    match contact {
        1 => pt - kl * gap_half,
        -1 => pt + kl * gap_half,
        _ => 0.0,
    }
}

/// The spring's stretch at deflection `d`: `d -+ gap/2` in contact, 0 inside the gap.
#[inline]
pub(crate) fn stretch(d: f64, gap_half: f64) -> f64 {
    if d > gap_half {
        d - gap_half
    } else if d < -gap_half {
        d + gap_half
    } else {
        0.0
    }
}

/// `[effects.backlash]`: the full gap at the load, m on a ball screw (`gap_m`), rad on a rotary
/// axis (`gap_rad`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BacklashParams {
    /// Full gap in load units, >= 0.
    pub gap: f64,
}

impl EffectTable for BacklashParams {
    /// Reads `[effects.backlash]`.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        needs_transmission(f, ctx, "backlash")?;
        let key = format!("gap_{}", ctx.load_units().pos);
        check_keys(f, &[&key])?;
        let gap = f.f64(&key, Range::NonNegative)?;
        Ok(Self { gap })
    }

    /// The model-file table.
    fn to_table(&self, ctx: &Ctx) -> toml::Table {
        let mut t = toml::Table::new();
        put(&mut t, format!("gap_{}", ctx.load_units().pos), self.gap);
        t
    }
}

impl BacklashParams {
    /// The full gap in motor rad (`None` for a zero gap: no backlash).
    pub(crate) fn motor(&self, ctx: &Ctx) -> Option<f64> {
        let gap_motor = self.gap * ctx.load_units().vel_to_motor;
        (gap_motor > 0.0).then_some(gap_motor)
    }
}
