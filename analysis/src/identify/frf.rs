//! Frequency response by Welch averaging: Hann windows, 50 % overlap, H1 estimate and
//! coherence, or the indirect estimate with an instrument (the command when the loop is closed).

use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

use super::IdentifyError;

/// A frequency response on a uniform frequency grid.
#[derive(Debug, Clone)]
pub struct Frf {
    /// Frequencies, Hz.
    pub f_hz: Vec<f64>,
    /// Complex response output / input.
    pub h: Vec<Complex64>,
    /// Ordinary coherence between input and output, 0..1.
    pub coherence: Vec<f64>,
    /// Number of averaged segments.
    pub segments: usize,
    /// With an instrument `r`: the coherences of `r` with the input and with the output
    /// (`|S_ru|^2 / (S_rr S_uu)`, `|S_ry|^2 / (S_rr S_yy)`), the shares of each that the
    /// instrument explains; they set the variance of `S_ry / S_ru`. Empty without instrument.
    pub coherence_instrument: Vec<(f64, f64)>,
}

impl Frf {
    /// How much of the estimate at bin `k` is signal, 0..1, as a coherence: the ordinary
    /// coherence for H1; with an instrument `1 / (1 + v)`, `v = (1 - g_u) / g_u + (1 - g_y) / g_y`
    /// the relative variance of `S_ry / S_ru` from the instrument's coherences with input and
    /// output (feedback noise that the ordinary coherence counts as signal counts as noise).
    pub fn quality(&self, k: usize) -> f64 {
        match self.coherence_instrument.get(k) {
            Some(&(gu, gy)) => {
                let (gu, gy) = (gu.clamp(1e-12, 1.0), gy.clamp(1e-12, 1.0));
                1.0 / (1.0 + (1.0 - gu) / gu + (1.0 - gy) / gy)
            }
            None => self.coherence.get(k).copied().unwrap_or(0.0),
        }
    }
}

/// Welch cross spectra of `u` (input), `y` (output) and optionally `r` (instrument).
/// `nseg` is the segment length (samples), `dt` the sample time. With `r`, the response is
/// `S_ry / S_ru` (unbiased by noise on `u` and by feedback); without, `S_uy / S_uu` (H1).
pub fn welch_frf(
    u: &[f64],
    y: &[f64],
    r: Option<&[f64]>,
    dt: f64,
    nseg: usize,
) -> Result<Frf, IdentifyError> {
    let n = u.len().min(y.len());
    welch_frf_windows(u, y, r, dt, nseg, &[(0, n)]).map(|(f, _)| f)
}

/// [`welch_frf`] averaged over the segments that lie wholly inside one of `windows` (sample
/// ranges `start..end`; no segment straddles two). Also returns the segments per window.
pub fn welch_frf_windows(
    u: &[f64],
    y: &[f64],
    r: Option<&[f64]>,
    dt: f64,
    nseg: usize,
    windows: &[(usize, usize)],
) -> Result<(Frf, Vec<usize>), IdentifyError> {
    let n = u.len().min(y.len());
    let longest = windows
        .iter()
        .map(|(a, b)| b.min(&n).saturating_sub(*a))
        .max()
        .unwrap_or(0);
    if nseg < 16 || longest < nseg {
        return Err(IdentifyError::Invalid(format!(
            "the record (its longest analysed window) holds {longest} samples, fewer than one FFT \
             segment of {nseg}; record longer or lower the resolution"
        )));
    }
    let hop = nseg / 2;
    let window: Vec<f64> = (0..nseg)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / nseg as f64).cos())
        .collect();
    let fft = FftPlanner::<f64>::new().plan_fft_forward(nseg);
    let nf = nseg / 2 + 1;
    let mut sums = Spectra::new(nf);
    let mut per_window = Vec::with_capacity(windows.len());
    for &(w0, w1) in windows {
        let w1 = w1.min(n);
        let before = sums.segments;
        let mut start = w0;
        while start + nseg <= w1 {
            let seg = |x: &[f64]| segment_fft(&x[start..start + nseg], &window, fft.as_ref());
            let fu = seg(u);
            let fy = seg(y);
            let fr = r.map(seg);
            sums.add(&fu, &fy, fr.as_deref());
            start += hop;
        }
        per_window.push(sums.segments - before);
    }
    let df = 1.0 / (nseg as f64 * dt);
    Ok((sums.frf(df, r.is_some()), per_window))
}

/// The spectrum of one segment `x`, its mean removed, through `window`.
fn segment_fft(x: &[f64], window: &[f64], fft: &dyn Fft<f64>) -> Vec<Complex64> {
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let mut buf: Vec<Complex64> = x
        .iter()
        .zip(window)
        .map(|(v, w)| Complex64::new((v - mean) * w, 0.0))
        .collect();
    fft.process(&mut buf);
    buf
}

/// Auto and cross spectra of torque `u`, response `y` and instrument `r`, summed over segments.
struct Spectra {
    suu: Vec<f64>,
    syy: Vec<f64>,
    suy: Vec<Complex64>,
    sru: Vec<Complex64>,
    sry: Vec<Complex64>,
    srr: Vec<f64>,
    segments: usize,
}

impl Spectra {
    fn new(nf: usize) -> Self {
        Spectra {
            suu: vec![0.0; nf],
            syy: vec![0.0; nf],
            suy: vec![Complex64::new(0.0, 0.0); nf],
            sru: vec![Complex64::new(0.0, 0.0); nf],
            sry: vec![Complex64::new(0.0, 0.0); nf],
            srr: vec![0.0; nf],
            segments: 0,
        }
    }

    /// Adds one segment's spectra.
    fn add(&mut self, fu: &[Complex64], fy: &[Complex64], fr: Option<&[Complex64]>) {
        for k in 0..self.suu.len() {
            self.suu[k] += fu[k].norm_sqr();
            self.syy[k] += fy[k].norm_sqr();
            self.suy[k] += fu[k].conj() * fy[k];
            if let Some(fr) = fr {
                self.sru[k] += fr[k].conj() * fu[k];
                self.sry[k] += fr[k].conj() * fy[k];
                self.srr[k] += fr[k].norm_sqr();
            }
        }
        self.segments += 1;
    }

    /// The response on bins `df` Hz apart: `sry / sru` with an instrument, else `suy / suu`.
    fn frf(self, df: f64, instrument: bool) -> Frf {
        let Spectra {
            suu,
            syy,
            suy,
            sru,
            sry,
            srr,
            segments,
        } = self;
        let nf = suu.len();
        let mut f_hz = Vec::with_capacity(nf);
        let mut h = Vec::with_capacity(nf);
        let mut coherence = Vec::with_capacity(nf);
        let mut coherence_instrument = Vec::new();
        for k in 0..nf {
            if instrument {
                let c = |s: Complex64, p: f64| {
                    if srr[k] > 0.0 && p > 0.0 {
                        s.norm_sqr() / (srr[k] * p)
                    } else {
                        0.0
                    }
                };
                coherence_instrument.push((c(sru[k], suu[k]), c(sry[k], syy[k])));
            }
            f_hz.push(k as f64 * df);
            let hk = if instrument {
                if sru[k].norm() > 0.0 {
                    sry[k] / sru[k]
                } else {
                    Complex64::new(0.0, 0.0)
                }
            } else if suu[k] > 0.0 {
                suy[k] / suu[k]
            } else {
                Complex64::new(0.0, 0.0)
            };
            h.push(hk);
            let c = if suu[k] > 0.0 && syy[k] > 0.0 {
                suy[k].norm_sqr() / (suu[k] * syy[k])
            } else {
                0.0
            };
            coherence.push(c);
        }
        Frf {
            f_hz,
            h,
            coherence,
            segments,
            coherence_instrument,
        }
    }
}
