//! Frequency response by Welch averaging: Hann windows, 50 % overlap, H1 estimate and
//! coherence, or the indirect estimate with an instrument (the command when the loop is closed).

use rustfft::num_complex::Complex64;
use rustfft::FftPlanner;

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
    let mut suu = vec![0.0; nf];
    let mut syy = vec![0.0; nf];
    let mut suy = vec![Complex64::new(0.0, 0.0); nf];
    let mut sru = vec![Complex64::new(0.0, 0.0); nf];
    let mut sry = vec![Complex64::new(0.0, 0.0); nf];
    let mut srr = vec![0.0; nf];
    let mut segments = 0;
    let seg_fft = |x: &[f64]| -> Vec<Complex64> {
        let mean = x.iter().sum::<f64>() / x.len() as f64;
        let mut buf: Vec<Complex64> = x
            .iter()
            .zip(&window)
            .map(|(v, w)| Complex64::new((v - mean) * w, 0.0))
            .collect();
        fft.process(&mut buf);
        buf
    };
    let mut per_window = Vec::with_capacity(windows.len());
    for &(w0, w1) in windows {
        let w1 = w1.min(n);
        let before = segments;
        let mut start = w0;
        while start + nseg <= w1 {
            let fu = seg_fft(&u[start..start + nseg]);
            let fy = seg_fft(&y[start..start + nseg]);
            let fr = r.map(|r| seg_fft(&r[start..start + nseg]));
            for k in 0..nf {
                suu[k] += fu[k].norm_sqr();
                syy[k] += fy[k].norm_sqr();
                suy[k] += fu[k].conj() * fy[k];
                if let Some(fr) = &fr {
                    sru[k] += fr[k].conj() * fu[k];
                    sry[k] += fr[k].conj() * fy[k];
                    srr[k] += fr[k].norm_sqr();
                }
            }
            segments += 1;
            start += hop;
        }
        per_window.push(segments - before);
    }
    let df = 1.0 / (nseg as f64 * dt);
    let mut f_hz = Vec::with_capacity(nf);
    let mut h = Vec::with_capacity(nf);
    let mut coherence = Vec::with_capacity(nf);
    let mut coherence_instrument = Vec::new();
    for k in 0..nf {
        if r.is_some() {
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
        let hk = if r.is_some() {
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
    Ok((
        Frf {
            f_hz,
            h,
            coherence,
            segments,
            coherence_instrument,
        },
        per_window,
    ))
}
