//! The checks a pick pair is judged on.

use super::super::frf::Frf;
use super::options::{
    StiffnessChecks, StiffnessOptions, JM_FACTOR, MAX_BIN_ERROR, MIN_PICK_BINS, MIN_SEGMENTS,
};

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
pub(super) fn judge(
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
    check_segments(&mut c, opts);
    check_coherence(&mut c);
    check_separation(&mut c, band, picks, df);
    check_inertia(&mut c, opts, picks);
    c
}

/// Enough averaged segments for the coherence to mean something.
fn check_segments(c: &mut StiffnessChecks, opts: &StiffnessOptions) {
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
}

/// The response around each pick stands out of its noise.
fn check_coherence(c: &mut StiffnessChecks) {
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
        c.advice.push(format!(
            "excite the band with more amplitude or for longer, without reversals (a traverse \
             under the excitation: {})",
            super::direction::TRAVERSE_FLAGS
        ));
    }
}

/// The picks lie apart from each other and from the band's edges.
fn check_separation(c: &mut StiffnessChecks, band: [f64; 2], [fa, fr]: [f64; 2], df: f64) {
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
}

/// The given motor inertia agrees with what the response shows above the resonance (or, without
/// that band, the pair's total inertia with the response below the anti-resonance).
fn check_inertia(c: &mut StiffnessChecks, opts: &StiffnessOptions, [fa, fr]: [f64; 2]) {
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
}
