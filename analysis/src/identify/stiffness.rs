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

use rustfft::num_complex::Complex64;

use super::frf::{welch_frf_windows, Frf};
use super::reversals::{reversal_effects, ReversalEffects};
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
    /// Time cut after each reversal (and before the next) from the one-direction windows, s.
    pub settle_s: f64,
}

impl StiffnessOptions {
    /// Defaults for a motor inertia: band 5 Hz .. 0.4 fs, 0.3 Hz resolution, 6 dB, auto,
    /// 0.2 s settling after a reversal.
    pub fn new(jm_kgm2: f64) -> Self {
        Self {
            jm_kgm2,
            f_min_hz: 5.0,
            f_max_hz: None,
            resolution_hz: 0.3,
            prominence_db: 6.0,
            estimator: Estimator::Auto,
            frf: FrfKind::TorqueToVelocity,
            settle_s: 0.2,
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
    /// Whether every check of `checks` passed.
    pub credible: bool,
    /// How far the result can be trusted: the figures it is judged on and what fails.
    pub checks: StiffnessChecks,
    /// Friction and backlash read at the traverse's reversals (null without reversals between
    /// one-direction windows).
    pub reversal_effects: Option<ReversalEffects>,
    /// The FRF (not serialised).
    #[serde(skip)]
    pub frf: Option<Frf>,
}

/// Least averaged Welch segments for a coherence that means something (with one segment it is
/// 1 whatever the data).
pub const MIN_SEGMENTS: usize = 4;
/// Largest relative standard error of the averaged response around each pick,
/// `sqrt((1 - g) / (2 N g))` for the median coherence `g` over `N` segments: 0.25 is about
/// 2 dB, a third of the prominence an extremum needs ([`StiffnessOptions::prominence_db`]'s
/// default), so that the picks stand out of the scatter.
pub const MAX_BIN_ERROR: f64 = 0.25;
/// Least distance between the two picks, and of each pick from the band's edges, in bins.
pub const MIN_PICK_BINS: f64 = 3.0;
/// Largest relative difference between the KL of the two directions of a traverse (each then
/// lies within 1 % of their mean).
pub const MAX_DIRECTION_SPREAD: f64 = 0.02;
/// Largest 95 % confidence half-width of KL and JL from the two-mass fit, % (the accuracy a
/// commissioning result is asked for).
pub const MAX_CI_PCT: f64 = 1.0;
/// Largest factor between the given JM and the one the response shows above the resonance.
pub const JM_FACTOR: f64 = 2.0;

/// What [`identify_stiffness`] judges its own result on (reported beside the picks).
#[derive(Debug, Clone, Serialize, Default)]
pub struct StiffnessChecks {
    /// Averaged Welch segments (at least [`MIN_SEGMENTS`]).
    pub segments: usize,
    /// Median coherence of the estimate within +-20 % of the anti-resonance (its notch, +-5 %,
    /// left out): torque -> velocity for H1; with the command as instrument, what the
    /// instrument's coherences with torque and velocity leave (see `Frf::quality`).
    pub coherence_antiresonance: f64,
    /// The same within +-20 % of the resonance.
    pub coherence_resonance: f64,
    /// How far the anti-resonance stands below the response around it (+-20 %), dB.
    pub prominence_antiresonance_db: f64,
    /// How far the resonance stands above the response around it, dB.
    pub prominence_resonance_db: f64,
    /// Distance of the resonance from the anti-resonance, frequency bins.
    pub separation_bins: f64,
    /// The motor inertia the response shows above the resonance (1 / |H w| between 1.5 and 3
    /// times the resonance), kg m^2; null when the band does not reach there.
    pub jm_from_response_kgm2: Option<f64>,
    /// The total inertia the response shows below the anti-resonance (1 / |H w| between the band's
    /// start and half the anti-resonance), kg m^2; the pair and JM say JM (wr / wa)^2; null when
    /// the band does not reach there.
    pub total_from_response_kgm2: Option<f64>,
    /// Velocity reversals in the analysed data (the nut crossing its backlash, friction
    /// changing sign: each mixes another plant into the response).
    pub reversals: usize,
    /// Reversals cut out of the record with their settling (0 when the whole record is read).
    pub reversals_cut: usize,
    /// One-direction windows (positive velocity) whose segments were averaged.
    pub windows_positive: usize,
    /// One-direction windows (negative velocity) whose segments were averaged.
    pub windows_negative: usize,
    /// Averaged segments from windows of positive velocity.
    pub segments_positive: usize,
    /// Averaged segments from windows of negative velocity.
    pub segments_negative: usize,
    /// Averaged segments per analysed window (not serialised).
    #[serde(skip)]
    pub per_window: Vec<usize>,
    /// KL from the windows of positive velocity alone (when they hold enough segments).
    pub kl_positive_nm_per_rad: Option<f64>,
    /// KL from the windows of negative velocity alone.
    pub kl_negative_nm_per_rad: Option<f64>,
    /// 95 % confidence half-width of KL from the two-mass fit to the response around the
    /// picks, % of KL (null when the fit failed and the picks alone give the result).
    pub kl_ci_pct: Option<f64>,
    /// 95 % confidence half-width of JL, %.
    pub jl_ci_pct: Option<f64>,
    /// Frequency bins the two-mass model was fitted to.
    pub fit_bins: usize,
    /// What is not credible, with the figures; empty when the result passes.
    pub problems: Vec<String>,
    /// What to change for a credible result.
    pub advice: Vec<String>,
}

impl StiffnessChecks {
    /// Whether every check passed.
    pub fn credible(&self) -> bool {
        self.problems.is_empty()
    }
}

/// Sign changes of `v` with a hysteresis of 2 % of its largest magnitude (noise about zero
/// does not count).
pub fn count_reversals(v: &[f64]) -> usize {
    let peak = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let band = 0.02 * peak;
    let mut sign = 0i8;
    let mut n = 0;
    for &x in v {
        let s = if x > band {
            1
        } else if x < -band {
            -1
        } else {
            continue;
        };
        if sign != 0 && s != sign {
            n += 1;
        }
        sign = s;
    }
    n
}

/// One-direction windows of `v`: sample ranges where `v` keeps one sign beyond a band of 2 % of
/// its largest magnitude, less `settle` samples at both ends (the reversal or stop and its
/// settling), as `(start, end, sign)`.
pub fn one_direction_windows(v: &[f64], settle: usize) -> Vec<(usize, usize, i8)> {
    let peak = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let band = 0.02 * peak;
    let sign = |x: f64| -> i8 {
        if x > band {
            1
        } else if x < -band {
            -1
        } else {
            0
        }
    };
    let mut out = Vec::new();
    let mut k = 0;
    while k < v.len() {
        let s = sign(v[k]);
        let mut e = k + 1;
        while e < v.len() && sign(v[e]) == s {
            e += 1;
        }
        if s != 0 && e - k > 2 * settle {
            out.push((k + settle, e - settle, s));
        }
        k = e;
    }
    out
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
    let dt = trace.period_s();
    let nseg = (1.0 / (opts.resolution_hz * dt)).round() as usize;
    let settle = if opts.settle_s.is_finite() && opts.settle_s >= 0.0 {
        (opts.settle_s / dt).round() as usize
    } else {
        return Err(IdentifyError::Invalid(format!(
            "the settling time after a reversal (--settle-s, settle_s) must be >= 0 s, got {}",
            opts.settle_s
        )));
    };
    let windows: Vec<(usize, usize, i8)> = one_direction_windows(y, settle)
        .into_iter()
        .filter(|(a, b, _)| b - a >= nseg.max(1))
        .collect();
    let possible: usize = windows
        .iter()
        .map(|(a, b, _)| (b - a - nseg) / (nseg / 2).max(1) + 1)
        .sum();
    let all_reversals = count_reversals(y);
    if possible >= MIN_SEGMENTS && all_reversals > 0 {
        // One-direction windows only: no segment holds a reversal or its settling.
        let ranges: Vec<(usize, usize)> = windows.iter().map(|(a, b, _)| (*a, *b)).collect();
        let mut result = identify_stiffness_windows(u, y, r.as_deref(), dt, opts, &ranges)?;
        let (per_window, c) = (result.checks.per_window.clone(), &mut result.checks);
        for ((_, _, s), n) in windows.iter().zip(&per_window) {
            if *n == 0 {
                continue;
            }
            if *s > 0 {
                c.windows_positive += 1;
                c.segments_positive += n;
            } else {
                c.windows_negative += 1;
                c.segments_negative += n;
            }
        }
        c.reversals_cut = all_reversals;
        c.reversals = 0;
        // Each direction alone must give the same pair: backlash, friction or noise that the
        // average hides show as a disagreement.
        let mut kl_dir = [None, None];
        for (i, dir) in [1i8, -1].into_iter().enumerate() {
            let own: Vec<(usize, usize)> = windows
                .iter()
                .filter(|w| w.2 == dir)
                .map(|(a, b, _)| (*a, *b))
                .collect();
            let n: usize = own
                .iter()
                .map(|(a, b)| (b - a - nseg) / (nseg / 2).max(1) + 1)
                .sum();
            if n < MIN_SEGMENTS {
                continue;
            }
            let name = if dir > 0 { "positive" } else { "negative" };
            match identify_stiffness_windows(u, y, r.as_deref(), dt, opts, &own) {
                Ok(one) => kl_dir[i] = Some(one.kl_nm_per_rad),
                Err(e) => result.checks.problems.push(format!(
                    "the {name} direction alone gives no pair ({e}): the average of both is not \
                     reproducible"
                )),
            }
        }
        let c = &mut result.checks;
        c.kl_positive_nm_per_rad = kl_dir[0];
        c.kl_negative_nm_per_rad = kl_dir[1];
        if let [Some(kp), Some(kn)] = kl_dir {
            let apart = (kp - kn).abs() / (0.5 * (kp + kn)).abs();
            if apart > MAX_DIRECTION_SPREAD {
                c.problems.push(format!(
                    "the positive direction gives KL {kp:.1} N m/rad, the negative {kn:.1} \
                     ({:.1} % apart, at most {:.0} %): the response depends on more than the \
                     two-mass plant (backlash opening, friction) or on noise",
                    100.0 * apart,
                    100.0 * MAX_DIRECTION_SPREAD
                ));
                c.advice.push(
                    "lower the excitation amplitude (keeps the nut on one flank) and record \
                     longer (averages the noise)"
                        .into(),
                );
            }
        }
        result.credible = result.checks.credible();
        result.reversal_effects = reversal_effects(
            u,
            y,
            dt,
            opts.jm_kgm2 + result.jl_kgm2,
            trace.column(&format!("{axis}.motor")),
            trace.column(&format!("{axis}.load")),
            &windows,
            result.kl_nm_per_rad,
        );
        if let Some(e) = result.reversal_effects.as_ref().filter(|e| e.flank_lifted) {
            result.checks.problems.push(format!(
                "the excitation lifts the nut off its flank: the deflection swings {:.3} um within \
                 a direction, {:.2} times further one way than the other (the dead band is \
                 {:.3} um): the response mixes contact and free flight",
                e.flank_swing_m.unwrap_or(f64::NAN) * 1e6,
                e.flank_lopsided.unwrap_or(f64::NAN),
                e.backlash_m.unwrap_or(0.0) * 1e6
            ));
            result.checks.advice.push(
                "lower the excitation's amplitude (velocity_m_per_s) until the load's inertia \
                 force stays below the friction that holds the nut on one flank"
                    .into(),
            );
            result.credible = false;
        }
        return Ok(result);
    }
    let mut result = identify_stiffness_from(u, y, r.as_deref(), dt, opts)?;
    result.checks.reversals = all_reversals;
    if result.checks.reversals > 0 {
        result.checks.advice.push(format!(
            "the axis reversed {} times in the record: backlash and friction then mix into the \
             response; excite on top of a constant traverse",
            result.checks.reversals
        ));
    }
    Ok(result)
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
    // prominence: how far the extremum stands out from the response within +-20 %
    let prominence_db = |k: usize, min: bool| -> f64 {
        let w = ((0.2 * frf.f_hz[k] / df).round() as usize).max(2);
        let lo = k.saturating_sub(w).max(1);
        let hi = (k + w).min(la.len() - 1);
        let s = if min { 1.0 } else { -1.0 };
        let left = (lo..k).map(|j| s * la[j]).fold(f64::NEG_INFINITY, f64::max);
        let right = (k + 1..=hi)
            .map(|j| s * la[j])
            .fold(f64::NEG_INFINITY, f64::max);
        (left.min(right) - s * la[k]) * 20.0 / std::f64::consts::LN_10
    };
    let second = minima.iter().find(|&&k| k > kr).and_then(|&k2| {
        maxima.iter().find(|&&m| m > k2).map(|&m2| ModePair {
            antiresonance_hz: interp(k2),
            resonance_hz: interp(m2),
        })
    });
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
    let c_lo = 0.8 * fa;
    let c_hi = 1.2 * fr;
    let coherence_min = frf
        .f_hz
        .iter()
        .zip(&frf.coherence)
        .filter(|(f, _)| **f >= c_lo && **f <= c_hi && (**f - fa).abs() > 0.05 * fa)
        .map(|(_, c)| *c)
        .fold(1.0, f64::min);
    let mut checks = judge(
        &frf,
        &la,
        opts,
        [f_lo, f_hi],
        [fa, fr],
        [prominence_db(ka, true), prominence_db(kr, false)],
    );
    checks.per_window = per_window;
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
fn fit_two_mass(frf: &Frf, jm: f64, picks: [f64; 2], band: [f64; 2]) -> Option<TwoMassFit> {
    use nalgebra::{DMatrix, DVector, Vector4};
    let [fa, fr] = picks;
    let tau = 2.0 * std::f64::consts::PI;
    let (lo, hi) = ((0.5 * fa).max(band[0]), (2.0 * fr).min(band[1]));
    // (w, measured torque -> acceleration, weight)
    let bins: Vec<(f64, Complex64, f64)> = frf
        .f_hz
        .iter()
        .enumerate()
        .filter(|(_, f)| **f >= lo && **f <= hi)
        .map(|(k, f)| {
            let g = frf.quality(k).clamp(1e-9, 0.999);
            let w = tau * f;
            (w, frf.h[k] * Complex64::new(0.0, w), (g / (1.0 - g)).sqrt())
        })
        .filter(|b| b.1.norm().is_finite() && b.1.norm() > 0.0)
        .collect();
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
    let residuals = |p: &Vector4<f64>| -> DVector<f64> {
        let (jl, kl, cl, d) = (p[0].exp(), p[1].exp(), p[2].exp(), p[3]);
        let mut r = DVector::zeros(2 * bins.len());
        for (i, (w, h, wt)) in bins.iter().enumerate() {
            let e = h / two_mass_accel(jm, jl, kl, cl, d, *w) - 1.0;
            r[2 * i] = wt * e.re;
            r[2 * i + 1] = wt * e.im;
        }
        r
    };
    let jacobian = |p: &Vector4<f64>| -> DMatrix<f64> {
        let mut j = DMatrix::zeros(2 * bins.len(), 4);
        for i in 0..4 {
            let h = if i == 3 { 1e-9 } else { 1e-6 };
            let (mut a, mut b) = (*p, *p);
            a[i] += h;
            b[i] -= h;
            let d = (residuals(&a) - residuals(&b)) / (2.0 * h);
            j.set_column(i, &d);
        }
        j
    };
    // the delay's start: the mean phase lag of the measured over the undelayed model
    let lag: f64 = bins
        .iter()
        .map(|(w, h, _)| -(h / two_mass_accel(jm, jl0, kl0, cl0, 0.0, *w)).arg() / w)
        .sum::<f64>()
        / bins.len() as f64;
    let mut p = Vector4::new(jl0.ln(), kl0.ln(), cl0.ln(), lag);
    let mut c = residuals(&p).norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..100 {
        let j = jacobian(&p);
        let jtj = j.transpose() * &j;
        let jtr = j.transpose() * residuals(&p);
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
            let cq = residuals(&q).norm_squared();
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
    let (jl, kl) = (p[0].exp(), p[1].exp());
    let fa_fit = (kl / jl).sqrt() / tau;
    let fr_fit = (kl * (jm + jl) / (jm * jl)).sqrt() / tau;
    if !(jl.is_finite() && kl.is_finite() && fa_fit >= lo && fr_fit <= hi && fa_fit < fr_fit) {
        return None;
    }
    // Confidence: the covariance of the parameters, (J'J)^-1 times the residual variance per
    // degree of freedom, each bin counted as 1 / 1.5 of an independent one (a Hann window's
    // equivalent noise bandwidth is 1.5 bins); 95 % = 1.96 standard deviations.
    let j = jacobian(&p);
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

/// The two-mass model fitted to the response around the picks ([`fit_two_mass`]).
#[derive(Debug, Clone, Copy)]
struct TwoMassFit {
    jl_kgm2: f64,
    kl_nm_per_rad: f64,
    /// 95 % confidence half-widths, % of the value.
    jl_ci_pct: f64,
    kl_ci_pct: f64,
    /// Bins fitted.
    bins: usize,
}

/// Median of the estimate's quality ([`Frf::quality`]: the coherence, or with an instrument
/// what its coherences leave of it) over `lo..=hi` Hz, leaving out `notch` (+-5 % about it) when given.
fn median_coherence(frf: &Frf, lo: f64, hi: f64, notch: Option<f64>) -> f64 {
    let mut c: Vec<f64> = frf
        .f_hz
        .iter()
        .enumerate()
        .filter(|(_, f)| **f >= lo && **f <= hi && notch.is_none_or(|n| (**f - n).abs() > 0.05 * n))
        .map(|(k, _)| frf.quality(k))
        .collect();
    if c.is_empty() {
        return 0.0;
    }
    c.sort_by(f64::total_cmp);
    c[c.len() / 2]
}

/// The checks of a pick pair (`picks` = [anti-resonance, resonance] Hz, `prominence` in dB)
/// on the response `la` (log |H w|) within `band` Hz; reversals are counted by the caller.
fn judge(
    frf: &Frf,
    la: &[f64],
    opts: &StiffnessOptions,
    band: [f64; 2],
    picks: [f64; 2],
    prominence: [f64; 2],
) -> StiffnessChecks {
    let [fa, fr] = picks;
    let df = frf.f_hz[1];
    let mut c = StiffnessChecks {
        segments: frf.segments,
        coherence_antiresonance: median_coherence(frf, 0.8 * fa, 1.2 * fa, Some(fa)),
        coherence_resonance: median_coherence(frf, 0.8 * fr, 1.2 * fr, None),
        prominence_antiresonance_db: prominence[0],
        prominence_resonance_db: prominence[1],
        separation_bins: (fr - fa) / df,
        ..Default::default()
    };
    // 1 / |H w| above the resonance is the motor inertia alone.
    let hf: Vec<f64> = frf
        .f_hz
        .iter()
        .enumerate()
        .filter(|(_, f)| **f >= 1.5 * fr && **f <= (3.0 * fr).min(band[1]))
        .map(|(k, _)| la[k])
        .collect();
    let median_inertia = |mut v: Vec<f64>| -> Option<f64> {
        (v.len() >= 3).then(|| {
            v.sort_by(f64::total_cmp);
            (-v[v.len() / 2]).exp()
        })
    };
    c.jm_from_response_kgm2 = median_inertia(hf);
    let lf: Vec<f64> = frf
        .f_hz
        .iter()
        .enumerate()
        .filter(|(_, f)| **f >= band[0] && **f <= 0.5 * fa)
        .map(|(k, _)| la[k])
        .collect();
    c.total_from_response_kgm2 = median_inertia(lf);
    if c.segments < MIN_SEGMENTS {
        c.problems.push(format!(
            "{} averaged segment(s), at least {MIN_SEGMENTS} needed (with one the coherence is 1 \
             whatever the data)",
            c.segments
        ));
        c.advice.push(format!(
            "record at least {:.0} s of excitation, or ask for a coarser --resolution-hz",
            (MIN_SEGMENTS as f64 + 1.0) / (2.0 * opts.resolution_hz)
        ));
    }
    let bin_error = |g: f64| ((1.0 - g) / (2.0 * c.segments.max(1) as f64 * g.max(1e-12))).sqrt();
    let mut noisy = false;
    for (what, coh) in [
        ("anti-resonance", c.coherence_antiresonance),
        ("resonance", c.coherence_resonance),
    ] {
        let e = bin_error(coh);
        if e > MAX_BIN_ERROR {
            noisy = true;
            c.problems.push(format!(
                "median coherence {coh:.2} around the {what} over {} segments leaves each bin \
                 uncertain by {:.0} % (at most {:.0} %): the response there is mostly noise or \
                 another input",
                c.segments,
                100.0 * e,
                100.0 * MAX_BIN_ERROR
            ));
        }
    }
    if noisy {
        c.advice.push(
            "excite the band with more amplitude or for longer, without reversals (a traverse \
             under the excitation)"
                .into(),
        );
    }
    if c.separation_bins < MIN_PICK_BINS {
        c.problems.push(format!(
            "the resonance ({fr:.1} Hz) is only {:.1} bins above the anti-resonance ({fa:.1} Hz): \
             one feature, not a two-mass pair",
            c.separation_bins
        ));
    }
    let edge = MIN_PICK_BINS * df;
    if fa - band[0] < edge || band[1] - fr < edge {
        c.problems.push(format!(
            "a pick lies at the edge of the searched band {:.1} .. {:.1} Hz",
            band[0], band[1]
        ));
        c.advice
            .push("widen the band (--f-min-hz, --f-max-hz)".into());
    }
    if let Some(jm) = c.jm_from_response_kgm2 {
        let ratio = opts.jm_kgm2 / jm;
        if !(1.0 / JM_FACTOR..=JM_FACTOR).contains(&ratio) {
            c.problems.push(format!(
                "the given JM {:.4e} kg m^2 is {ratio:.3} times what the response shows above the \
                 resonance ({jm:.4e} kg m^2): the pair does not fit this motor",
                opts.jm_kgm2
            ));
            c.advice
                .push("check --jm-kgm2 (motor plus coupling, in kg m^2) and the axis".into());
        }
    } else if let Some(total) = c.total_from_response_kgm2 {
        // no band above the resonance: the pair's total inertia against the response below
        let implied = opts.jm_kgm2 * (fr / fa).powi(2);
        let ratio = implied / total;
        if !(1.0 / JM_FACTOR..=JM_FACTOR).contains(&ratio) {
            c.problems.push(format!(
                "JM {:.4e} kg m^2 and the pair imply a total inertia of {implied:.4e} kg m^2, {ratio:.3} \
                 times what the response shows below the anti-resonance ({total:.4e} kg m^2)",
                opts.jm_kgm2
            ));
            c.advice
                .push("check --jm-kgm2 (motor plus coupling, in kg m^2) and the axis".into());
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::super::frf::welch_frf_windows;
    use super::*;

    #[test]
    fn one_direction_windows_cut_the_reversals_and_their_settling() {
        // +1 for 1000 samples, a reversal through zero, -1 for 1000, noise below the band.
        let mut v: Vec<f64> = (0..1000)
            .map(|k| 1.0 + 0.01 * ((k % 7) as f64 - 3.0))
            .collect();
        v.extend((0..20).map(|k| 1.0 - k as f64 / 10.0));
        v.extend((0..1000).map(|k| -1.0 + 0.01 * ((k % 5) as f64 - 2.0)));
        let w = one_direction_windows(&v, 100);
        assert_eq!(w.len(), 2, "{w:?}");
        assert_eq!((w[0].0, w[0].2), (100, 1));
        assert_eq!(w[1].2, -1);
        // Every kept sample keeps its window's sign, at least `settle` from the reversal.
        for (a, b, s) in &w {
            assert!(v[*a..*b].iter().all(|x| x.signum() == f64::from(*s)));
        }
        let zero = v.iter().position(|x| *x <= 0.0).unwrap();
        assert!(w[0].1 + 100 <= zero && zero + 100 <= w[1].0, "{w:?} {zero}");
        assert_eq!(count_reversals(&v), 1);
    }

    #[test]
    fn welch_segments_stay_inside_their_windows() {
        let n = 3000;
        let u: Vec<f64> = (0..n).map(|k| ((k * 7919) % 101) as f64 - 50.0).collect();
        let y: Vec<f64> = u.iter().map(|x| 2.0 * x).collect();
        // 1000 samples hold 9 segments of 200 (hop 100); 300 hold 2; 150 none.
        let (frf, per) = welch_frf_windows(
            &u,
            &y,
            None,
            1e-3,
            200,
            &[(0, 1000), (1200, 1500), (1500, 1650)],
        )
        .unwrap();
        assert_eq!(per, vec![9, 2, 0]);
        assert_eq!(frf.segments, 11);
        assert!(
            frf.h[10].re > 1.99 && frf.h[10].re < 2.01,
            "{:?}",
            frf.h[10]
        );
        assert!(welch_frf_windows(&u, &y, None, 1e-3, 200, &[(0, 150)]).is_err());
    }
}
