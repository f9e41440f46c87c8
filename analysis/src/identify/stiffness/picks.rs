//! The picks: anti-resonance and resonance on the frequency response, refined by the two-mass
//! fit.

use super::super::frf::{welch_frf_windows, Frf};
use super::super::IdentifyError;
use super::checks::judge;
use super::options::{ModePair, StiffnessChecks, StiffnessOptions, StiffnessResult, MAX_CI_PCT};
use super::two_mass::{fit_two_mass, TwoMassFit};

/// [`identify_stiffness`](crate::identify::stiffness::identify_stiffness) on plain signals: torque `u`, motor velocity `y`, instrument `r`.
pub fn identify_stiffness_from(
    u: &[f64],
    y: &[f64],
    r: Option<&[f64]>,
    dt: f64,
    opts: &StiffnessOptions,
) -> Result<StiffnessResult, IdentifyError> {
    let n = u.len().min(y.len());
    identify_stiffness_windows(u, y, r, dt, opts, &[(0, n)])
}

/// [`identify_stiffness_from`] on the Welch segments that lie inside `windows` (sample ranges
/// `start..end`; e.g. the one-direction windows of a record on a traverse).
pub fn identify_stiffness_windows(
    u: &[f64],
    y: &[f64],
    r: Option<&[f64]>,
    dt: f64,
    opts: &StiffnessOptions,
    windows: &[(usize, usize)],
) -> Result<StiffnessResult, IdentifyError> {
    if !(opts.jm_kgm2.is_finite() && opts.jm_kgm2 > 0.0) {
        return Err(IdentifyError::Invalid(format!(
            "the motor inertia must be > 0 kg m^2, got {}",
            opts.jm_kgm2
        )));
    }
    if !(dt.is_finite() && dt > 0.0) {
        return Err(IdentifyError::Invalid(format!(
            "the trace's period must be > 0 s, got {dt}"
        )));
    }
    let nseg = (1.0 / (opts.resolution_hz * dt)).round() as usize;
    let (frf, per_window) = welch_frf_windows(u, y, r, dt, nseg, windows)?;
    let fs = 1.0 / dt;
    let f_hi = opts.f_max_hz.unwrap_or(0.4 * fs).min(0.5 * fs);
    let f_lo = opts.f_min_hz.max(frf.f_hz[1]);
    if f_hi <= f_lo {
        return Err(IdentifyError::Invalid(format!(
            "empty band {f_lo} .. {f_hi} Hz"
        )));
    }
    let shape = Shape::new(&frf);
    let extrema = Extrema::find(&shape, [f_lo, f_hi], opts.prominence_db);
    let (ka, kr) = extrema.first_pair(&shape, [f_lo, f_hi], opts.prominence_db)?;
    let fa = shape.interp(ka);
    let fr = shape.interp(kr);
    let second = extrema.second_pair(&shape, kr);
    let wa = 2.0 * std::f64::consts::PI * fa;
    let wr = 2.0 * std::f64::consts::PI * fr;
    let jl_pick = opts.jm_kgm2 * (wr * wr / (wa * wa) - 1.0);
    // The picks read two bins; the two-mass model fitted to every bin around them reads the
    // whole shape, so noise that fills the notch or tops the peak moves it far less.
    let fit = fit_two_mass(&frf, opts.jm_kgm2, [fa, fr], [f_lo, f_hi]);
    let (jl, kl) = fit.map_or((jl_pick, jl_pick * wa * wa), |f| {
        (f.jl_kgm2, f.kl_nm_per_rad)
    });
    let fa = (kl / jl).sqrt() / (2.0 * std::f64::consts::PI);
    let fr = (kl * (opts.jm_kgm2 + jl) / (opts.jm_kgm2 * jl)).sqrt() / (2.0 * std::f64::consts::PI);
    let coherence_min = coherence_about(&frf, fa, fr);
    let mut checks = judge(
        &frf,
        &shape.la,
        opts,
        [f_lo, f_hi],
        [fa, fr],
        [
            shape.prominence_db(ka, true),
            shape.prominence_db(kr, false),
        ],
    );
    checks.per_window = per_window;
    check_fit(&mut checks, fit);
    Ok(StiffnessResult {
        kl_nm_per_rad: kl,
        jl_kgm2: jl,
        antiresonance_hz: fa,
        resonance_hz: fr,
        coherence_min,
        second,
        estimator: if r.is_some() { "instrument" } else { "h1" },
        segments: frf.segments,
        credible: checks.credible(),
        checks,
        reversal_effects: None,
        frf: Some(frf),
    })
}

/// The response's shape: log magnitude of torque -> acceleration on its frequency grid.
struct Shape<'a> {
    f_hz: &'a [f64],
    la: Vec<f64>,
    df: f64,
}

impl<'a> Shape<'a> {
    fn new(frf: &'a Frf) -> Self {
        // log magnitude of torque -> acceleration.
        let la: Vec<f64> = frf
            .h
            .iter()
            .zip(&frf.f_hz)
            .map(|(h, f)| (h.norm() * 2.0 * std::f64::consts::PI * f).max(1e-300).ln())
            .collect();
        Shape {
            f_hz: &frf.f_hz,
            la,
            df: frf.f_hz[1],
        }
    }

    /// The bins within +-20 % of bin `k`'s frequency (at least two either side).
    fn reach(&self, k: usize) -> (usize, usize) {
        let w = ((0.2 * self.f_hz[k] / self.df).round() as usize).max(2);
        let lo = k.saturating_sub(w).max(1);
        let hi = (k + w).min(self.la.len() - 1);
        (lo, hi)
    }

    /// The sign that turns the response at a minimum (`min`) or a maximum into a minimum, and
    /// the highest signed response within [`Shape::reach`] left and right of bin `k`.
    fn sides(&self, k: usize, min: bool) -> (f64, f64, f64) {
        let la = &self.la;
        let (lo, hi) = self.reach(k);
        let s = if min { 1.0 } else { -1.0 };
        let left = (lo..k).map(|j| s * la[j]).fold(f64::NEG_INFINITY, f64::max);
        let right = (k + 1..=hi)
            .map(|j| s * la[j])
            .fold(f64::NEG_INFINITY, f64::max);
        (s, left, right)
    }

    /// Whether bin `k` is the lowest (`min`) or highest within +-20 % of its frequency and
    /// stands out by `prom` (natural log) on both sides.
    fn is_extremum(&self, k: usize, min: bool, prom: f64) -> bool {
        let la = &self.la;
        let (lo, hi) = self.reach(k);
        let (s, left, right) = self.sides(k, min);
        let v = s * la[k];
        if !(lo..=hi).all(|j| s * la[j] >= v) {
            return false;
        }
        left - v >= prom && right - v >= prom
    }

    /// The frequency of bin `k` refined by a parabola through it and its neighbours, Hz.
    fn interp(&self, k: usize) -> f64 {
        let la = &self.la;
        let (a, b, c) = (la[k - 1], la[k], la[k + 1]);
        let den = a - 2.0 * b + c;
        let d = if den.abs() > 1e-300 {
            (0.5 * (a - c) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        (k as f64 + d) * self.df
    }

    /// Prominence: how far the extremum stands out from the response within +-20 %, dB.
    fn prominence_db(&self, k: usize, min: bool) -> f64 {
        let (s, left, right) = self.sides(k, min);
        (left.min(right) - s * self.la[k]) * 20.0 / std::f64::consts::LN_10
    }
}

/// The prominent minima and maxima of the response within the band, as bins in rising order.
struct Extrema {
    minima: Vec<usize>,
    maxima: Vec<usize>,
}

impl Extrema {
    fn find(shape: &Shape<'_>, [f_lo, f_hi]: [f64; 2], prominence_db: f64) -> Self {
        let (f, la) = (shape.f_hz, &shape.la);
        let band: Vec<usize> = (0..f.len())
            .filter(|&k| f[k] >= f_lo && f[k] <= f_hi && k >= 1 && k + 1 < la.len())
            .collect();
        let prom = prominence_db / 20.0 * std::f64::consts::LN_10;
        let minima: Vec<usize> = band
            .iter()
            .copied()
            .filter(|&k| shape.is_extremum(k, true, prom))
            .collect();
        let maxima: Vec<usize> = band
            .iter()
            .copied()
            .filter(|&k| shape.is_extremum(k, false, prom))
            .collect();
        Extrema { minima, maxima }
    }

    /// The first anti-resonance and the first resonance above it (bins).
    fn first_pair(
        &self,
        shape: &Shape<'_>,
        [f_lo, f_hi]: [f64; 2],
        prominence_db: f64,
    ) -> Result<(usize, usize), IdentifyError> {
        let Some(&ka) = self.minima.first() else {
            return Err(IdentifyError::NoResonance {
                what: "anti-resonance",
                f_lo_hz: f_lo,
                f_hi_hz: f_hi,
                why: format!(
                    "no notch {prominence_db} dB deep in torque -> motor acceleration; widen the band or excite more",
                ),
            });
        };
        let Some(&kr) = self.maxima.iter().find(|&&k| k > ka) else {
            return Err(IdentifyError::NoResonance {
                what: "resonance",
                f_lo_hz: f_lo,
                f_hi_hz: f_hi,
                why: format!(
                    "an anti-resonance at {:.1} Hz but no peak above it; widen the band",
                    shape.interp(ka)
                ),
            });
        };
        Ok((ka, kr))
    }

    /// The next pair above the resonance `kr`, if there is one.
    fn second_pair(&self, shape: &Shape<'_>, kr: usize) -> Option<ModePair> {
        self.minima.iter().find(|&&k| k > kr).and_then(|&k2| {
            self.maxima.iter().find(|&&m| m > k2).map(|&m2| ModePair {
                antiresonance_hz: shape.interp(k2),
                resonance_hz: shape.interp(m2),
            })
        })
    }
}

/// The lowest coherence from 0.8 `fa` to 1.2 `fr` Hz, the notch (+-5 % about `fa`) left out.
fn coherence_about(frf: &Frf, fa: f64, fr: f64) -> f64 {
    let c_lo = 0.8 * fa;
    let c_hi = 1.2 * fr;
    frf.f_hz
        .iter()
        .zip(&frf.coherence)
        .filter(|(f, _)| **f >= c_lo && **f <= c_hi && (**f - fa).abs() > 0.05 * fa)
        .map(|(_, c)| *c)
        .fold(1.0, f64::min)
}

/// The two-mass fit's checks: its confidence, or that it found no pair.
fn check_fit(checks: &mut StiffnessChecks, fit: Option<TwoMassFit>) {
    match fit {
        Some(f) => {
            checks.kl_ci_pct = Some(f.kl_ci_pct);
            checks.jl_ci_pct = Some(f.jl_ci_pct);
            checks.fit_bins = f.bins;
            let worst = f.kl_ci_pct.max(f.jl_ci_pct);
            if worst > MAX_CI_PCT {
                checks.problems.push(format!(
                    "the two-mass fit leaves KL uncertain by +-{:.2} % and JL by +-{:.2} % (95 %; \
                     at most {MAX_CI_PCT} %): the data are too noisy or the plant is not two-mass \
                     here",
                    f.kl_ci_pct, f.jl_ci_pct
                ));
                checks.advice.push(
                    "record longer or excite more (staying below the traverse), or a coarser \
                     --resolution-hz"
                        .into(),
                );
            }
        }
        None => checks.problems.push(
            "the two-mass model does not fit the response around the picks (no pair inside the \
             band): the picks alone are not a result"
                .into(),
        ),
    }
}
