//! Signal tools of the workbench: zero-phase Butterworth filtering, central differences and
//! the error figures (RMS, NRMSE).

use std::f64::consts::PI;

/// One second-order section `y = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2) x`.
#[derive(Debug, Clone, Copy)]
struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
}

impl Biquad {
    /// Low-pass section of quality `q` at `fc` Hz for sampling rate `fs` Hz (bilinear transform
    /// with prewarping, so the -3 dB point of the cascade lands at `fc`).
    fn lowpass(fc: f64, fs: f64, q: f64) -> Self {
        let k = (PI * fc / fs).tan();
        let norm = 1.0 / (1.0 + k / q + k * k);
        let b0 = k * k * norm;
        Self {
            b: [b0, 2.0 * b0, b0],
            a: [2.0 * (k * k - 1.0) * norm, (1.0 - k / q + k * k) * norm],
        }
    }

    /// Filters `x` in place, starting from the steady state for the first value.
    fn run(&self, x: &mut [f64]) {
        let Some(&x0) = x.first() else { return };
        // direct form II transposed, initialised at the DC steady state of x0
        let gain = (self.b[0] + self.b[1] + self.b[2]) / (1.0 + self.a[0] + self.a[1]);
        let y0 = gain * x0;
        let mut z1 = y0 - self.b[0] * x0;
        let mut z2 = self.b[2] * x0 - self.a[1] * y0;
        for v in x.iter_mut() {
            let xi = *v;
            let yi = self.b[0] * xi + z1;
            z1 = self.b[1] * xi - self.a[0] * yi + z2;
            z2 = self.b[2] * xi - self.a[1] * yi;
            // a state decaying towards zero (a signal that stopped, e.g. a friction column at a
            // long standstill) would enter the subnormal range, where arithmetic is many times
            // slower: flush it (the error is below 1e-200)
            if z1.abs() < 1e-200 {
                z1 = 0.0;
            }
            if z2.abs() < 1e-200 {
                z2 = 0.0;
            }
            *v = yi;
        }
    }
}

/// Zero-phase low-pass: a 4th-order Butterworth at `fc` Hz run forward and backward, as
/// MATLAB's `filtfilt(butter(4, ..))` (so the magnitude is squared and the phase is zero).
///
/// The ends are padded by odd reflection so that ramps pass without transients. When `fc` is at
/// or above 0.45 `fs` the signal is returned unchanged.
pub fn filtfilt_butter4(x: &[f64], fc: f64, fs: f64) -> Vec<f64> {
    let n = x.len();
    if n < 4 || fc >= 0.45 * fs || fc <= 0.0 {
        return x.to_vec();
    }
    let sections = [
        Biquad::lowpass(fc, fs, 0.541_196_100_146_197),
        Biquad::lowpass(fc, fs, 1.306_562_964_876_376_5),
    ];
    let pad = ((3.0 * fs / fc).ceil() as usize).clamp(1, n - 1);
    let mut buf = Vec::with_capacity(n + 2 * pad);
    let (first, last) = (x[0], x[n - 1]);
    for i in (1..=pad).rev() {
        buf.push(2.0 * first - x[i]);
    }
    buf.extend_from_slice(x);
    for i in 1..=pad {
        buf.push(2.0 * last - x[n - 1 - i]);
    }
    for s in &sections {
        s.run(&mut buf);
    }
    buf.reverse();
    for s in &sections {
        s.run(&mut buf);
    }
    buf.reverse();
    buf.drain(..pad);
    buf.truncate(n);
    buf
}

/// Central-difference derivative (one-sided at the ends), `dt` the sampling period.
pub fn derivative(x: &[f64], dt: f64) -> Vec<f64> {
    let n = x.len();
    let mut d = vec![0.0; n];
    if n < 2 {
        return d;
    }
    d[0] = (x[1] - x[0]) / dt;
    d[n - 1] = (x[n - 1] - x[n - 2]) / dt;
    for i in 1..n - 1 {
        d[i] = (x[i + 1] - x[i - 1]) / (2.0 * dt);
    }
    d
}

/// Root mean square.
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

/// Mean.
pub fn mean(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    x.iter().sum::<f64>() / x.len() as f64
}

/// Standard deviation (population).
pub fn std_dev(x: &[f64]) -> f64 {
    let m = mean(x);
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / x.len() as f64).sqrt()
}

/// NRMSE in percent, the system-identification convention: `100 ||y - y_model|| / ||y - mean(y)||`
/// (`fit % = 100 - NRMSE %`). `err` is `y - y_model`.
pub fn nrmse_pct(y: &[f64], err: &[f64]) -> f64 {
    let s = std_dev(y);
    if s <= 0.0 {
        return if rms(err) == 0.0 { 0.0 } else { f64::INFINITY };
    }
    100.0 * rms(err) / s
}

/// Relative error in percent: `100 ||err|| / ||y||` (the EMPS benchmark's "relative force error").
pub fn relative_error_pct(y: &[f64], err: &[f64]) -> f64 {
    let s = rms(y);
    if s <= 0.0 {
        return 0.0;
    }
    100.0 * rms(err) / s
}

/// The `p`-quantile (0..1) of `x` (by sorting a copy; NaN-free input).
pub fn quantile(x: &[f64], p: f64) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    let mut v = x.to_vec();
    let k = ((v.len() - 1) as f64 * p.clamp(0.0, 1.0)).round() as usize;
    let (_, m, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    *m
}

/// Robust centre and spread of `x` that tolerate up to three quarters of the samples being
/// elsewhere (steps, pulses, clamps): the shortest interval holding a quarter of the samples,
/// its median as the centre and its width over 0.637 as the spread (for Gaussian noise that
/// interval is +-0.3186 sigma). NaN-free input; (0, 0) when empty.
pub fn densest_quarter(x: &[f64]) -> (f64, f64) {
    if x.is_empty() {
        return (0.0, 0.0);
    }
    let mut v = x.to_vec();
    v.sort_unstable_by(f64::total_cmp);
    let w = (v.len() / 4).max(1).min(v.len() - 1);
    let mut best = (f64::INFINITY, 0);
    for i in 0..v.len() - w {
        let width = v[i + w] - v[i];
        if width < best.0 {
            best = (width, i);
        }
    }
    if !best.0.is_finite() {
        return (v[0], 0.0);
    }
    (v[best.1 + w / 2], best.0 / 0.637)
}

/// Lag-`k` autocorrelation coefficients 1..=`max_lag` of `x` (mean removed).
pub fn autocorrelation(x: &[f64], max_lag: usize) -> Vec<f64> {
    let m = mean(x);
    let c0: f64 = x.iter().map(|v| (v - m) * (v - m)).sum();
    (1..=max_lag)
        .map(|k| {
            if c0 <= 0.0 || k >= x.len() {
                return 0.0;
            }
            x.iter()
                .zip(&x[k..])
                .map(|(a, b)| (a - m) * (b - m))
                .sum::<f64>()
                / c0
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_phase_filter_passes_a_slow_sine_without_lag() {
        let fs = 1000.0;
        let x: Vec<f64> = (0..5000)
            .map(|k| (2.0 * PI * 2.0 * k as f64 / fs).sin())
            .collect();
        let y = filtfilt_butter4(&x, 100.0, fs);
        let err = x
            .iter()
            .zip(&y)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-3, "{err}");
    }

    #[test]
    fn zero_phase_filter_removes_a_tone_far_above_the_cutoff() {
        let fs = 1000.0;
        let x: Vec<f64> = (0..5000)
            .map(|k| (2.0 * PI * 300.0 * k as f64 / fs).sin())
            .collect();
        let y = filtfilt_butter4(&x, 50.0, fs);
        assert!(rms(&y[500..4500]) < 1e-3, "{}", rms(&y));
    }

    #[test]
    fn derivative_of_a_parabola_is_exact_inside() {
        let x: Vec<f64> = (0..10).map(|k| (k as f64 * 0.1).powi(2)).collect();
        let d = derivative(&x, 0.1);
        assert!((d[5] - 1.0).abs() < 1e-12);
    }
}
