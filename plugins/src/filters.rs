//! Discrete filters used by the loop plugins: first-order low-pass and notch, both discretised
//! with the bilinear (Tustin) transform prewarped at their characteristic frequency.
//!
//! Analog prototypes (w0 = 2 pi f0, rad/s):
//! - low-pass: H(s) = w0 / (s + w0) (corner `f0` Hz, -3 dB there, DC gain 1);
//! - notch: H(s) = (s^2 + 2 d zeta w0 s + w0^2) / (s^2 + 2 zeta w0 s + w0^2) with zeta = 1 / (2 Q):
//!   gain `d` (the depth, 0 = full notch, 1 = no notch) at f0, 1 at DC and far above; Q sets the
//!   width (-3 dB band about f0 / Q wide for a full notch).
//!
//! Discretisation: s = c (z - 1) / (z + 1) with c = w0 / tan(w0 T / 2), so the digital filter has
//! exactly the analog gain and phase at f0 (plain Tustin, c = 2 / T, would shift a 1 kHz notch
//! at 10 kHz by about 3 %). A stable analog prototype gives a stable digital filter for any
//! f0 < 1 / (2 T); the plugins refuse f0 above 0.45 / T so the prewarp stays well conditioned.
//!
//! Both run in transposed direct form II (one state per order), whose state for a constant input
//! is known in closed form: [`LowPass1::settle`] / [`Biquad::settle`] put a filter at rest at a
//! given input, which is what a bumpless controller switch needs.

use std::f64::consts::PI;

/// Largest characteristic frequency accepted, as a fraction of the sampling rate.
pub const MAX_FRACTION_OF_RATE: f64 = 0.45;

/// Prewarped bilinear constant c = w0 / tan(w0 T / 2), 1/s.
fn prewarp(f0_hz: f64, period_s: f64) -> f64 {
    let w0 = 2.0 * PI * f0_hz;
    w0 / (w0 * period_s / 2.0).tan()
}

/// First-order low-pass y = w0 / (s + w0) x, Tustin with prewarp at the corner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowPass1 {
    b0: f64,
    a1: f64,
    /// Transposed-DF-II state.
    s: f64,
}

impl LowPass1 {
    /// A low-pass with corner `f0_hz` sampled every `period_s`, at rest at 0.
    pub fn new(f0_hz: f64, period_s: f64) -> Self {
        let w0 = 2.0 * PI * f0_hz;
        let c = prewarp(f0_hz, period_s);
        Self {
            b0: w0 / (c + w0),
            a1: (w0 - c) / (c + w0),
            s: 0.0,
        }
    }

    /// Filters one sample.
    #[inline]
    pub fn process(&mut self, x: f64) -> f64 {
        let y = self.b0 * x + self.s;
        self.s = self.b0 * x - self.a1 * y;
        y
    }

    /// Puts the filter at rest at input (= output) `x`.
    pub fn settle(&mut self, x: f64) {
        self.s = x - self.b0 * x;
    }

    /// The state value (for snapshots).
    pub fn state(&self) -> f64 {
        self.s
    }

    /// Restores the state value.
    pub fn set_state(&mut self, s: f64) {
        self.s = s;
    }

    /// Gain magnitude at `f_hz` for sampling period `period_s`.
    pub fn gain_at(&self, f_hz: f64, period_s: f64) -> f64 {
        let th = 2.0 * PI * f_hz * period_s;
        let (c, s) = (th.cos(), -th.sin());
        let (nr, ni) = (self.b0 * (1.0 + c), self.b0 * s);
        let (dr, di) = (1.0 + self.a1 * c, self.a1 * s);
        ((nr * nr + ni * ni) / (dr * dr + di * di)).sqrt()
    }
}

/// A second-order section in transposed direct form II, normalised (a0 = 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
    s: [f64; 2],
}

impl Biquad {
    /// A notch at `f0_hz` with quality `q` and centre gain `depth` (0..1), sampled every `period_s`.
    pub fn notch(f0_hz: f64, q: f64, depth: f64, period_s: f64) -> Self {
        let w = 2.0 * PI * f0_hz;
        let c = prewarp(f0_hz, period_s);
        let zeta = 1.0 / (2.0 * q);
        let (c2, w2) = (c * c, w * w);
        let nz = 2.0 * depth * zeta * w * c;
        let np = 2.0 * zeta * w * c;
        let a0 = c2 + np + w2;
        Self {
            b: [
                (c2 + nz + w2) / a0,
                2.0 * (w2 - c2) / a0,
                (c2 - nz + w2) / a0,
            ],
            a: [2.0 * (w2 - c2) / a0, (c2 - np + w2) / a0],
            s: [0.0; 2],
        }
    }

    /// Filters one sample.
    #[inline]
    pub fn process(&mut self, x: f64) -> f64 {
        let y = self.b[0] * x + self.s[0];
        self.s[0] = self.b[1] * x - self.a[0] * y + self.s[1];
        self.s[1] = self.b[2] * x - self.a[1] * y;
        y
    }

    /// DC gain (b0 + b1 + b2) / (1 + a1 + a2).
    pub fn dc_gain(&self) -> f64 {
        (self.b[0] + self.b[1] + self.b[2]) / (1.0 + self.a[0] + self.a[1])
    }

    /// Puts the filter at rest at input `x` (output = DC gain times `x`).
    pub fn settle(&mut self, x: f64) {
        let y = self.dc_gain() * x;
        self.s[1] = self.b[2] * x - self.a[1] * y;
        self.s[0] = y - self.b[0] * x;
    }

    /// The two state values (for snapshots).
    pub fn state(&self) -> [f64; 2] {
        self.s
    }

    /// Restores the state values.
    pub fn set_state(&mut self, s: [f64; 2]) {
        self.s = s;
    }

    /// Gain magnitude at `f_hz` for sampling period `period_s`.
    pub fn gain_at(&self, f_hz: f64, period_s: f64) -> f64 {
        let th = 2.0 * PI * f_hz * period_s;
        // H(e^{j th}) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)
        let (c1, s1) = (th.cos(), -th.sin());
        let (c2, s2) = ((2.0 * th).cos(), -(2.0 * th).sin());
        let nr = self.b[0] + self.b[1] * c1 + self.b[2] * c2;
        let ni = self.b[1] * s1 + self.b[2] * s2;
        let dr = 1.0 + self.a[0] * c1 + self.a[1] * c2;
        let di = self.a[0] * s1 + self.a[1] * s2;
        ((nr * nr + ni * ni) / (dr * dr + di * di)).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steady-state amplitude of the filter's response to a sine of `f` Hz.
    fn measured_gain(mut step: impl FnMut(f64) -> f64, f: f64, t: f64) -> f64 {
        let n = (2.0 / (f * t)).ceil() as usize * 20;
        let mut peak: f64 = 0.0;
        for k in 0..n {
            let y = step((2.0 * PI * f * k as f64 * t).sin());
            if k > n / 2 {
                peak = peak.max(y.abs());
            }
        }
        peak
    }

    #[test]
    fn low_pass_is_exactly_3_db_down_at_its_corner_thanks_to_the_prewarp() {
        let t = 1e-4;
        let lp = LowPass1::new(2000.0, t);
        let g = lp.gain_at(2000.0, t);
        assert!((g - 0.5f64.sqrt()).abs() < 1e-12, "gain {g}");
        // plain Tustin (c = 2 / T) would give 0.65 there
        let mut m = LowPass1::new(200.0, t);
        let g = measured_gain(|x| m.process(x), 200.0, t);
        assert!((g - 0.5f64.sqrt()).abs() < 2e-3, "gain {g}");
    }

    #[test]
    fn low_pass_passes_dc_with_unit_gain() {
        let mut lp = LowPass1::new(100.0, 1e-4);
        let mut y = 0.0;
        for _ in 0..20_000 {
            y = lp.process(3.0);
        }
        assert!((y - 3.0).abs() < 1e-12);
    }

    #[test]
    fn full_notch_removes_its_centre_frequency_and_passes_a_decade_away() {
        let t = 1e-4;
        let n = Biquad::notch(800.0, 2.0, 0.0, t);
        assert!(n.gain_at(800.0, t) < 1e-9);
        assert!((n.gain_at(80.0, t) - 1.0).abs() < 0.01);
        assert!((n.dc_gain() - 1.0).abs() < 1e-12);
        let mut m = n;
        let g = measured_gain(|x| m.process(x), 800.0, t);
        assert!(g < 1e-3, "{g}");
    }

    #[test]
    fn partial_notch_has_its_depth_as_gain_at_the_centre() {
        let t = 1e-4;
        let n = Biquad::notch(1500.0, 1.0, 0.25, t);
        assert!((n.gain_at(1500.0, t) - 0.25).abs() < 1e-9);
    }

    #[test]
    fn settled_filters_hold_a_constant_input_without_a_transient() {
        let t = 1e-4;
        let mut n = Biquad::notch(500.0, 0.7, 0.1, t);
        n.settle(2.5);
        let mut lp = LowPass1::new(300.0, t);
        lp.settle(2.5);
        for _ in 0..10 {
            assert!((n.process(2.5) - 2.5).abs() < 1e-12);
            assert!((lp.process(2.5) - 2.5).abs() < 1e-12);
        }
    }
}
