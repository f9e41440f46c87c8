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

/// The command acting around sample `k` of a zero-order-held record `y`: the mean of commands
/// `k - 1` and `k` (a command recorded at sample k is held over the following period), `y[0]` at
/// the start. Indexed, so a long record is aligned without a copy.
#[inline]
pub fn zoh_mid(y: &[f64], k: usize) -> f64 {
    if k == 0 {
        y[0]
    } else {
        0.5 * (y[k - 1] + y[k])
    }
}

/// Means of `x` over consecutive blocks of `q` samples (`x.len() / q` values; a last,
/// incomplete block is left out). A block's mean stands for the value at its centre.
pub fn block_means(x: &[f64], q: usize) -> Vec<f64> {
    let q = q.max(1);
    x.chunks_exact(q)
        .map(|c| c.iter().sum::<f64>() / q as f64)
        .collect()
}

/// The sample at the centre of each block of `q` samples of `x` (index `k q + q / 2`), as many
/// as [`block_means`] gives.
pub fn block_centres(x: &[f64], q: usize) -> Vec<f64> {
    let q = q.max(1);
    x.chunks_exact(q).map(|c| c[q / 2]).collect()
}

/// For a smooth series `x` held at the centres of blocks of `q` recording periods, the mean of
/// `f` over each block: `f` is evaluated at the `q` instants of the block, `x` there
/// interpolated linearly between its neighbouring values. A nonlinearity of the held series
/// (a sign, a sine of the position) then has the mean it has over the recording's samples, up
/// to the interpolation: a velocity reversal inside a block counts for the part of the block
/// on each side, as in the block mean of the recorded torque.
pub fn sub_sample_means(x: &[f64], q: usize, f: impl Fn(f64) -> f64) -> Vec<f64> {
    let n = x.len();
    let q = q.max(1);
    let centre = (q as f64 - 1.0) / 2.0;
    // the slope between samples k - 1 and k (the first one at the start)
    let slope = |k: usize| match (k, n) {
        (_, 0 | 1) => 0.0,
        (0, _) => x[1] - x[0],
        _ => x[k] - x[k - 1],
    };
    (0..n)
        .map(|k| {
            let (before, after) = (slope(k), slope((k + 1).min(n - 1)));
            let mut acc = 0.0;
            for j in 0..q {
                // offset from the block's centre, held samples
                let s = (j as f64 - centre) / q as f64;
                acc += f(x[k] + s * if s < 0.0 { before } else { after });
            }
            acc / q as f64
        })
        .collect()
}

/// Derivative by the 7-point central stencil (the central difference, then one-sided, near the
/// ends), for series held at a tenth of their rate ([`block_means`]): at the filter's cut-off,
/// a tenth of the rate, the central difference of [`derivative`] loses 6.5 % of the amplitude
/// where this one loses 0.05 %, as the central difference does at the recording's rate.
pub fn derivative_fine(x: &[f64], dt: f64) -> Vec<f64> {
    let mut d = derivative(x, dt);
    let n = x.len();
    for i in 3..n.saturating_sub(3) {
        d[i] = (45.0 * (x[i + 1] - x[i - 1]) - 9.0 * (x[i + 2] - x[i - 2]) + (x[i + 3] - x[i - 3]))
            / (60.0 * dt);
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

/// Largest minus smallest value (the travel of a position column).
pub fn span(x: &[f64]) -> f64 {
    x.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - x.iter().cloned().fold(f64::INFINITY, f64::min)
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

/// Golden-section search for the minimum of `f` on `[lo, hi]`: `steps` narrowings of the
/// bracket, each with one new evaluation; returns the last bracket.
pub fn golden_section(lo: f64, hi: f64, steps: usize, mut f: impl FnMut(f64) -> f64) -> (f64, f64) {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut a, mut b) = (lo, hi);
    let (mut c, mut dd) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(dd));
    for _ in 0..steps {
        if fc < fd {
            b = dd;
            dd = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = dd;
            fc = fd;
            dd = a + g * (b - a);
            fd = f(dd);
        }
    }
    (a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Five seconds of a unit sine of `f_hz` sampled at 1 kHz, and the rate.
    fn sine_1khz(f_hz: f64) -> (Vec<f64>, f64) {
        let fs = 1000.0;
        let x = (0..5000)
            .map(|k| (2.0 * PI * f_hz * k as f64 / fs).sin())
            .collect();
        (x, fs)
    }

    #[test]
    fn zero_phase_filter_passes_a_slow_sine_without_lag() {
        let (x, fs) = sine_1khz(2.0);
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
        let (x, fs) = sine_1khz(300.0);
        let y = filtfilt_butter4(&x, 50.0, fs);
        assert!(rms(&y[500..4500]) < 1e-3, "{}", rms(&y));
    }

    #[test]
    fn derivative_of_a_parabola_is_exact_inside() {
        let x: Vec<f64> = (0..10).map(|k| (k as f64 * 0.1).powi(2)).collect();
        let d = derivative(&x, 0.1);
        assert!((d[5] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn block_means_and_centres_take_whole_blocks_only() {
        let x: Vec<f64> = (0..23).map(|i| i as f64).collect();
        assert_eq!(block_means(&x, 5), vec![2.0, 7.0, 12.0, 17.0]);
        assert_eq!(block_centres(&x, 5), vec![2.0, 7.0, 12.0, 17.0]);
        assert_eq!(block_centres(&x, 4), vec![2.0, 6.0, 10.0, 14.0, 18.0]);
        assert_eq!(block_means(&x, 1), x);
    }

    #[test]
    fn sub_sample_means_match_the_block_means_of_the_recording() {
        // a ramp recorded at 10 samples per block: its block means are the held series; a
        // linear function of it keeps them, and its sign counts the part of the block on
        // each side of the zero crossing
        let q = 10;
        let full: Vec<f64> = (0..200).map(|i| (i as f64 - 104.5) * 0.01).collect();
        let held = block_means(&full, q);
        let lin = sub_sample_means(&held, q, |v| 3.0 * v + 1.0);
        for (a, b) in lin.iter().zip(&held) {
            assert!((a - (3.0 * b + 1.0)).abs() < 1e-12);
        }
        let sign_full: Vec<f64> = full.iter().map(|v| v.signum()).collect();
        let want = block_means(&sign_full, q);
        let got = sub_sample_means(&held, q, f64::signum);
        for (a, b) in got.iter().zip(&want) {
            assert!((a - b).abs() < 1e-12, "{got:?} vs {want:?}");
        }
        assert!((got[10]).abs() < 1e-12);
        assert_eq!(sub_sample_means(&held, 1, |v| v), held);
    }

    #[test]
    fn the_fine_derivative_is_exact_on_polynomials_and_close_at_a_tenth_of_the_rate() {
        let dt = 0.5;
        let x: Vec<f64> = (0..40)
            .map(|i| {
                let t = i as f64 * dt;
                1.0 - 2.0 * t + 0.5 * t.powi(3) - 0.01 * t.powi(5)
            })
            .collect();
        let d = derivative_fine(&x, dt);
        for (i, v) in d.iter().enumerate().take(37).skip(3) {
            let t = i as f64 * dt;
            let want = -2.0 + 1.5 * t * t - 0.05 * t.powi(4);
            assert!(
                (v - want).abs() < 1e-9 * want.abs().max(1.0),
                "{i}: {v} vs {want}"
            );
        }
        // a sine at a tenth of the rate keeps its amplitude within 0.1 %
        let w = 2.0 * std::f64::consts::PI * 0.1;
        let s: Vec<f64> = (0..100).map(|i| (w * i as f64).sin()).collect();
        let d = derivative_fine(&s, 1.0);
        let peak = d[10..90].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((peak / w - 1.0).abs() < 1e-3, "{}", peak / w);
    }
}
