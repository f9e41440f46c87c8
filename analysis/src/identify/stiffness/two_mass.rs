//! The two-mass model fitted to the complex response around the picks.

use nalgebra::{DMatrix, DVector, Vector4};
use rustfft::num_complex::Complex64;

use super::super::frf::Frf;

/// Torque -> motor acceleration of the two-mass plant (motor inertia `jm`, load inertia `jl`,
/// spring `kl` with damping `cl`) at `w` rad/s, behind a pure delay `delay_s` (the drive's
/// torque path and the velocity measurement).
fn two_mass_accel(jm: f64, jl: f64, kl: f64, cl: f64, delay_s: f64, w: f64) -> Complex64 {
    let s = Complex64::new(0.0, w);
    let z = s * cl + kl;
    let num = s * s * jl + z;
    let den = s * s * (jm * jl) + z * (jm + jl);
    num / den * Complex64::from_polar(1.0, -w * delay_s)
}

/// Fits the load inertia, the spring and its damping of the two-mass plant (the motor inertia
/// `jm` given), and a delay, to the complex response torque -> motor acceleration between half
/// the anti-resonance and twice the resonance (`picks`, Hz; within `band`). Each bin's
/// residual is its relative error `H / model - 1`, weighted by the inverse of the estimate's
/// relative standard deviation from [`Frf::quality`] (the complex estimate is unbiased where its
/// magnitude alone is biased upwards by noise). Levenberg-Marquardt on the logarithms of the
/// three plant parameters, started at the picks. `None` when too few bins or the fit does not
/// converge to a pair inside the band.
pub(super) fn fit_two_mass(
    frf: &Frf,
    jm: f64,
    picks: [f64; 2],
    band: [f64; 2],
) -> Option<TwoMassFit> {
    let [fa, fr] = picks;
    let tau = 2.0 * std::f64::consts::PI;
    let (lo, hi) = ((0.5 * fa).max(band[0]), (2.0 * fr).min(band[1]));
    let bins = fit_bins(frf, lo, hi);
    if bins.len() < 12 {
        return None;
    }
    let (wa, wr) = (tau * fa, tau * fr);
    let jl0 = jm * (wr * wr / (wa * wa) - 1.0);
    if jl0.is_nan() || jl0 <= 0.0 {
        return None;
    }
    let kl0 = jl0 * wa * wa;
    // damping ratio 0.05 of the spring between the two inertias as the start
    let cl0 = 0.1 * (kl0 * jm * jl0 / (jm + jl0)).sqrt();
    let problem = Problem { bins: &bins, jm };
    // the delay's start: the mean phase lag of the measured over the undelayed model
    let lag: f64 = bins
        .iter()
        .map(|(w, h, _)| -(h / two_mass_accel(jm, jl0, kl0, cl0, 0.0, *w)).arg() / w)
        .sum::<f64>()
        / bins.len() as f64;
    let (p, c) = problem.solve(Vector4::new(jl0.ln(), kl0.ln(), cl0.ln(), lag));
    let (jl, kl) = (p[0].exp(), p[1].exp());
    let fa_fit = (kl / jl).sqrt() / tau;
    let fr_fit = (kl * (jm + jl) / (jm * jl)).sqrt() / tau;
    if !(jl.is_finite() && kl.is_finite() && fa_fit >= lo && fr_fit <= hi && fa_fit < fr_fit) {
        return None;
    }
    // Confidence: the covariance of the parameters, (J'J)^-1 times the residual variance per
    // degree of freedom, each bin counted as 1 / 1.5 of an independent one (a Hann window's
    // equivalent noise bandwidth is 1.5 bins); 95 % = 1.96 standard deviations.
    let j = problem.jacobian(&p);
    let dof = (2.0 * bins.len() as f64 / 1.5 - 4.0).max(1.0);
    let s2 = c / dof / 1.5;
    let cov = (j.transpose() * j).try_inverse()? * s2;
    let ci = |i: usize| 100.0 * 1.96 * cov[(i, i)].max(0.0).sqrt();
    Some(TwoMassFit {
        jl_kgm2: jl,
        kl_nm_per_rad: kl,
        jl_ci_pct: ci(0),
        kl_ci_pct: ci(1),
        bins: bins.len(),
    })
}

/// The bins from `lo` to `hi` Hz as (w, measured torque -> acceleration, weight), those with a
/// finite non-zero response.
fn fit_bins(frf: &Frf, lo: f64, hi: f64) -> Vec<(f64, Complex64, f64)> {
    let tau = 2.0 * std::f64::consts::PI;
    frf.f_hz
        .iter()
        .enumerate()
        .filter(|(_, f)| **f >= lo && **f <= hi)
        .map(|(k, f)| {
            let g = frf.quality(k).clamp(1e-9, 0.999);
            let w = tau * f;
            (w, frf.h[k] * Complex64::new(0.0, w), (g / (1.0 - g)).sqrt())
        })
        .filter(|b| b.1.norm().is_finite() && b.1.norm() > 0.0)
        .collect()
}

/// The least-squares problem: the bins fitted and the given motor inertia; the parameters are
/// the logarithms of JL, KL and CL, and the delay.
struct Problem<'a> {
    bins: &'a [(f64, Complex64, f64)],
    jm: f64,
}

impl Problem<'_> {
    fn residuals(&self, p: &Vector4<f64>) -> DVector<f64> {
        let (jl, kl, cl, d) = (p[0].exp(), p[1].exp(), p[2].exp(), p[3]);
        let mut r = DVector::zeros(2 * self.bins.len());
        for (i, (w, h, wt)) in self.bins.iter().enumerate() {
            let e = h / two_mass_accel(self.jm, jl, kl, cl, d, *w) - 1.0;
            r[2 * i] = wt * e.re;
            r[2 * i + 1] = wt * e.im;
        }
        r
    }

    fn jacobian(&self, p: &Vector4<f64>) -> DMatrix<f64> {
        let mut j = DMatrix::zeros(2 * self.bins.len(), 4);
        for i in 0..4 {
            let h = if i == 3 { 1e-9 } else { 1e-6 };
            let (mut a, mut b) = (*p, *p);
            a[i] += h;
            b[i] -= h;
            let d = (self.residuals(&a) - self.residuals(&b)) / (2.0 * h);
            j.set_column(i, &d);
        }
        j
    }

    /// Levenberg-Marquardt from `p`: the parameters and their sum of squared residuals.
    fn solve(&self, mut p: Vector4<f64>) -> (Vector4<f64>, f64) {
        let mut c = self.residuals(&p).norm_squared();
        let mut lambda = 1e-3;
        for _ in 0..100 {
            let j = self.jacobian(&p);
            let jtj = j.transpose() * &j;
            let jtr = j.transpose() * self.residuals(&p);
            let mut improved = false;
            for _ in 0..20 {
                let mut m = jtj.clone();
                for i in 0..4 {
                    m[(i, i)] *= 1.0 + lambda;
                }
                let Some(step) = m.lu().solve(&(-&jtr)) else {
                    lambda *= 10.0;
                    continue;
                };
                let q = p + Vector4::from_column_slice(step.as_slice());
                let cq = self.residuals(&q).norm_squared();
                if cq < c {
                    let done = (c - cq) < 1e-10 * c.max(1e-300);
                    p = q;
                    c = cq;
                    lambda = (lambda / 3.0).max(1e-9);
                    improved = !done;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        (p, c)
    }
}

/// The two-mass model fitted to the response around the picks ([`fit_two_mass`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct TwoMassFit {
    pub(super) jl_kgm2: f64,
    pub(super) kl_nm_per_rad: f64,
    /// 95 % confidence half-widths, % of the value.
    pub(super) jl_ci_pct: f64,
    pub(super) kl_ci_pct: f64,
    /// Bins fitted.
    pub(super) bins: usize,
}
