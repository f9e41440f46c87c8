//! Reversal compensation of a dead band: at each reversal of the commanded velocity the motor
//! must cross the backlash before the table moves again. The compensator plays a smooth motor
//! velocity pulse whose area is the gap (sine-squared over `backlash_s`), and the motor torque
//! that accelerates the motor alone through it (the load is free inside the gap). The position
//! loop closes on the table, so the step of the motor's offset stays.

use std::f64::consts::PI;

/// A backlash crossing, played at each reversal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BacklashPulse {
    /// Gap in motor units (rad).
    pub gap_motor: f64,
    /// Crossing time, s.
    pub duration_s: f64,
    /// Motor inertia, kg m^2.
    pub jm: f64,
    /// Reversal being played: (instant, sign of the new direction).
    pub active: Option<(f64, f64)>,
}

impl BacklashPulse {
    /// Starts a crossing at `t_s` towards `sign` (+1 / -1).
    pub fn start(&mut self, t_s: f64, sign: f64) {
        self.active = Some((t_s, sign));
    }

    /// Motor velocity (rad/s) and torque (N m) of the crossing at `t_s`.
    pub fn at(&mut self, t_s: f64) -> (f64, f64) {
        let Some((t0, sign)) = self.active else {
            return (0.0, 0.0);
        };
        let (tau, d) = (t_s - t0, self.duration_s);
        if tau > d {
            self.active = None;
            return (0.0, 0.0);
        }
        if tau < 0.0 {
            return (0.0, 0.0);
        }
        let s = (PI * tau / d).sin();
        let w = sign * self.gap_motor * 2.0 / d * s * s;
        let a = sign * self.gap_motor * 2.0 * PI / (d * d) * (2.0 * PI * tau / d).sin();
        (w, self.jm * a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_velocity_pulse_crosses_the_gap_and_ends() {
        let mut b = BacklashPulse {
            gap_motor: 0.01,
            duration_s: 0.002,
            jm: 1e-3,
            active: None,
        };
        b.start(1.0, -1.0);
        let dt = 1e-6;
        let area: f64 = (0..2100).map(|k| b.at(1.0 + k as f64 * dt).0 * dt).sum();
        assert!((area + 0.01).abs() < 1e-6, "{area}");
        assert_eq!(b.at(1.01), (0.0, 0.0));
        assert!(b.active.is_none());
    }
}
