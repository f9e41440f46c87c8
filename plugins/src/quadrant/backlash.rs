//! Reversal compensation of a dead band: at each reversal of the commanded velocity the motor
//! must cross the backlash before the table moves again. The compensator plays a smooth motor
//! velocity pulse whose area is the gap (sine-squared over `backlash_s`), and the motor torque
//! that accelerates the motor alone through it (the load is free inside the gap). The position
//! loop closes on the table, so the step of the motor's offset stays. The table stands while the
//! motor crosses; started `lead_s` before the reversal (predicted from the reference), the
//! standstill falls where the command moves least: centred on the reversal (`lead_s` half the
//! crossing) the command leaves the standing table by a d^2 / 8 instead of a d^2 / 2 (a the
//! command's acceleration, d the crossing time).

use std::f64::consts::PI;

/// A backlash crossing, played at each reversal (the crossing in progress is the
/// compensator's state, snapshotted with the rest of it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BacklashPulse {
    /// Gap in motor units (rad).
    pub gap_motor: f64,
    /// Crossing time, s.
    pub duration_s: f64,
    /// Motor inertia, kg m^2.
    pub jm: f64,
    /// How long before the reversal the crossing starts, s (0: at the reversal).
    pub lead_s: f64,
}

impl BacklashPulse {
    /// Motor velocity (rad/s) and torque (N m) at `t_s` of the crossing that started at `t0`
    /// towards `sign` (+1 / -1, or a share of the gap with its sign); `None` once it is over.
    pub fn at(&self, t_s: f64, t0: f64, sign: f64) -> Option<(f64, f64)> {
        let (tau, d) = (t_s - t0, self.duration_s);
        if tau > d {
            return None;
        }
        if tau < 0.0 {
            return Some((0.0, 0.0));
        }
        let s = (PI * tau / d).sin();
        let w = sign * self.gap_motor * 2.0 / d * s * s;
        let a = sign * self.gap_motor * 2.0 * PI / (d * d) * (2.0 * PI * tau / d).sin();
        Some((w, self.jm * a))
    }
}

impl BacklashPulse {
    /// The share of the gap crossed at `t_s` by the crossing that started at `t0` (0 .. 1).
    pub fn share(&self, t_s: f64, t0: f64) -> f64 {
        let u = ((t_s - t0) / self.duration_s).clamp(0.0, 1.0);
        u - (2.0 * PI * u).sin() / (2.0 * PI)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_velocity_pulse_crosses_the_gap_and_ends() {
        let b = BacklashPulse {
            gap_motor: 0.01,
            duration_s: 0.002,
            jm: 1e-3,
            lead_s: 0.0,
        };
        let dt = 1e-6;
        let area: f64 = (0..2000)
            .map(|k| b.at(1.0 + k as f64 * dt, 1.0, -1.0).unwrap().0 * dt)
            .sum();
        assert!((area + 0.01).abs() < 1e-6, "{area}");
        assert_eq!(b.at(1.01, 1.0, -1.0), None);
    }
}
