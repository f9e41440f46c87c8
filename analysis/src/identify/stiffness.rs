//! Stiffness identification (seed 001): FRF torque -> motor velocity, first anti-resonance and
//! resonance by peak picking with parabolic interpolation, then (motor side)
//! `KL = JL wa^2` and `JL = JM (wr^2 / wa^2 - 1)`.
//!
//! Peaks are picked on the torque -> motor *acceleration* magnitude `|H| w`, which is flat
//! (`1 / (JM + JL)` below, `1 / JM` above) apart from the notch and the peak, so the 1/s slope
//! does not shift them. Extrema count only when they stand out by `prominence_db` from the
//! response within +-20 % of their frequency.

use feedloop_trace::Trace;
use serde::Serialize;

use super::frf::{welch_frf, Frf};
use super::IdentifyError;

/// Which frequency response to read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrfKind {
    /// Torque -> motor velocity (the plant alone; the one the formulas hold for).
    TorqueToVelocity,
    /// Command -> table position of the closed loop: refused (no anti-resonance, its peak is a
    /// closed-loop pole; the formulas then give a negative inertia).
    CommandToTable,
}

/// How the torque -> velocity response is estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Estimator {
    /// `S_ry / S_ru` with the command `r` as instrument when the trace has a moving command,
    /// else H1.
    Auto,
    /// H1 = `S_uy / S_uu` (biased by torque noise and feedback in a closed loop).
    H1,
    /// The command as instrument (required: a moving `A.cmd`).
    Instrument,
}

/// Options of [`identify_stiffness`].
#[derive(Debug, Clone)]
pub struct StiffnessOptions {
    /// Motor inertia JM from the data sheet, kg m^2 (> 0).
    pub jm_kgm2: f64,
    /// Band searched, Hz.
    pub f_min_hz: f64,
    /// Band end, Hz (default: 0.4 times the sample rate).
    pub f_max_hz: Option<f64>,
    /// Frequency resolution, Hz (Welch segment = 1 / resolution).
    pub resolution_hz: f64,
    /// Minimum prominence of an extremum, dB.
    pub prominence_db: f64,
    /// Estimator.
    pub estimator: Estimator,
    /// Which FRF (only torque -> velocity is accepted).
    pub frf: FrfKind,
}

impl StiffnessOptions {
    /// Defaults for a motor inertia: band 5 Hz .. 0.4 fs, 0.3 Hz resolution, 6 dB, auto.
    pub fn new(jm_kgm2: f64) -> Self {
        Self {
            jm_kgm2,
            f_min_hz: 5.0,
            f_max_hz: None,
            resolution_hz: 0.3,
            prominence_db: 6.0,
            estimator: Estimator::Auto,
            frf: FrfKind::TorqueToVelocity,
        }
    }
}

/// One anti-resonance / resonance pair with what it implies.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ModePair {
    /// Anti-resonance, Hz.
    pub antiresonance_hz: f64,
    /// Resonance, Hz.
    pub resonance_hz: f64,
}

/// Result of [`identify_stiffness`].
#[derive(Debug, Clone, Serialize)]
pub struct StiffnessResult {
    /// Equivalent stiffness seen from the motor, N m/rad.
    pub kl_nm_per_rad: f64,
    /// Load inertia seen from the motor, kg m^2.
    pub jl_kgm2: f64,
    /// First anti-resonance, Hz.
    pub antiresonance_hz: f64,
    /// First resonance, Hz.
    pub resonance_hz: f64,
    /// Smallest torque -> velocity coherence between 0.8 wa and 1.2 wr (the notch excluded).
    pub coherence_min: f64,
    /// The next pair above the first, when there is one (e.g. a third mass).
    pub second: Option<ModePair>,
    /// `instrument` or `h1`.
    pub estimator: &'static str,
    /// Averaged Welch segments.
    pub segments: usize,
    /// The FRF (not serialised).
    #[serde(skip)]
    pub frf: Option<Frf>,
}

/// Identifies KL and JL from a trace of axis `axis` (columns `A.torque`, `A.motor_vel`, and
/// `A.cmd` for the instrument).
pub fn identify_stiffness(
    trace: &Trace,
    axis: &str,
    opts: &StiffnessOptions,
) -> Result<StiffnessResult, IdentifyError> {
    if opts.frf == FrfKind::CommandToTable {
        return Err(IdentifyError::Invalid(
            "refusing the closed-loop command -> table FRF: it has no anti-resonance and its peak \
             is a closed-loop pole, so JL = JM (wr^2/wa^2 - 1) and KL = JL wa^2 would come out \
             wrong (a negative inertia on the reference plant); use torque -> motor velocity"
                .into(),
        ));
    }
    let u = trace.require(&format!("{axis}.torque"))?;
    let y = trace.require(&format!("{axis}.motor_vel"))?;
    let cmd = match opts.estimator {
        Estimator::H1 => None,
        Estimator::Instrument => Some(trace.require(&format!("{axis}.cmd"))?),
        Estimator::Auto => trace.column(&format!("{axis}.cmd")),
    };
    let r: Option<Vec<f64>> = cmd.and_then(|c| {
        let d: Vec<f64> = c.windows(2).map(|w| w[1] - w[0]).collect();
        let moving = d.iter().any(|v| *v != 0.0);
        moving.then(|| {
            let mut d = d;
            d.insert(0, 0.0);
            d
        })
    });
    if opts.estimator == Estimator::Instrument && r.is_none() {
        return Err(IdentifyError::Invalid(format!(
            "`{axis}.cmd` never moves: no instrument; excite through the command or use --estimator h1"
        )));
    }
    identify_stiffness_from(u, y, r.as_deref(), trace.period_s(), opts)
}

/// [`identify_stiffness`] on plain signals: torque `u`, motor velocity `y`, instrument `r`.
/// Kept as one function (about 130 lines): the method reads in its own order (frequency
/// response, extrema with their prominence, interpolation, the two-mass formulas, coherence over
/// the picked band), its steps sharing the frequency grid and its closures.
pub fn identify_stiffness_from(
    u: &[f64],
    y: &[f64],
    r: Option<&[f64]>,
    dt: f64,
    opts: &StiffnessOptions,
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
    let frf = welch_frf(u, y, r, dt, nseg)?;
    let fs = 1.0 / dt;
    let f_hi = opts.f_max_hz.unwrap_or(0.4 * fs).min(0.5 * fs);
    let f_lo = opts.f_min_hz.max(frf.f_hz[1]);
    if f_hi <= f_lo {
        return Err(IdentifyError::Invalid(format!(
            "empty band {f_lo} .. {f_hi} Hz"
        )));
    }
    // log magnitude of torque -> acceleration.
    let la: Vec<f64> = frf
        .h
        .iter()
        .zip(&frf.f_hz)
        .map(|(h, f)| (h.norm() * 2.0 * std::f64::consts::PI * f).max(1e-300).ln())
        .collect();
    let band: Vec<usize> = (0..frf.f_hz.len())
        .filter(|&k| frf.f_hz[k] >= f_lo && frf.f_hz[k] <= f_hi && k >= 1 && k + 1 < la.len())
        .collect();
    let prom = opts.prominence_db / 20.0 * std::f64::consts::LN_10;
    let df = frf.f_hz[1];
    let extremum = |k: usize, min: bool| -> bool {
        let w = ((0.2 * frf.f_hz[k] / df).round() as usize).max(2);
        let lo = k.saturating_sub(w).max(1);
        let hi = (k + w).min(la.len() - 1);
        let s = if min { 1.0 } else { -1.0 };
        let v = s * la[k];
        if !(lo..=hi).all(|j| s * la[j] >= v) {
            return false;
        }
        let left = (lo..k).map(|j| s * la[j]).fold(f64::NEG_INFINITY, f64::max);
        let right = (k + 1..=hi)
            .map(|j| s * la[j])
            .fold(f64::NEG_INFINITY, f64::max);
        left - v >= prom && right - v >= prom
    };
    let interp = |k: usize| -> f64 {
        let (a, b, c) = (la[k - 1], la[k], la[k + 1]);
        let den = a - 2.0 * b + c;
        let d = if den.abs() > 1e-300 {
            (0.5 * (a - c) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        (k as f64 + d) * df
    };
    let minima: Vec<usize> = band
        .iter()
        .copied()
        .filter(|&k| extremum(k, true))
        .collect();
    let maxima: Vec<usize> = band
        .iter()
        .copied()
        .filter(|&k| extremum(k, false))
        .collect();
    let Some(&ka) = minima.first() else {
        return Err(IdentifyError::NoResonance {
            what: "anti-resonance",
            f_lo_hz: f_lo,
            f_hi_hz: f_hi,
            why: format!(
                "no notch {} dB deep in torque -> motor acceleration; widen the band or excite more",
                opts.prominence_db
            ),
        });
    };
    let Some(&kr) = maxima.iter().find(|&&k| k > ka) else {
        return Err(IdentifyError::NoResonance {
            what: "resonance",
            f_lo_hz: f_lo,
            f_hi_hz: f_hi,
            why: format!(
                "an anti-resonance at {:.1} Hz but no peak above it; widen the band",
                interp(ka)
            ),
        });
    };
    let fa = interp(ka);
    let fr = interp(kr);
    let second = minima.iter().find(|&&k| k > kr).and_then(|&k2| {
        maxima.iter().find(|&&m| m > k2).map(|&m2| ModePair {
            antiresonance_hz: interp(k2),
            resonance_hz: interp(m2),
        })
    });
    let wa = 2.0 * std::f64::consts::PI * fa;
    let wr = 2.0 * std::f64::consts::PI * fr;
    let jl = opts.jm_kgm2 * (wr * wr / (wa * wa) - 1.0);
    let kl = jl * wa * wa;
    let c_lo = 0.8 * fa;
    let c_hi = 1.2 * fr;
    let coherence_min = frf
        .f_hz
        .iter()
        .zip(&frf.coherence)
        .filter(|(f, _)| **f >= c_lo && **f <= c_hi && (**f - fa).abs() > 0.05 * fa)
        .map(|(_, c)| *c)
        .fold(1.0, f64::min);
    Ok(StiffnessResult {
        kl_nm_per_rad: kl,
        jl_kgm2: jl,
        antiresonance_hz: fa,
        resonance_hz: fr,
        coherence_min,
        second,
        estimator: if r.is_some() { "instrument" } else { "h1" },
        segments: frf.segments,
        frf: Some(frf),
    })
}
