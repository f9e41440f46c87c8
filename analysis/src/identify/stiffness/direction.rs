//! The record's one-direction windows and the identification over them, each direction alone
//! and the reversals between them.

use feedloop_trace::Trace;

use super::super::reversals::reversal_effects;
use super::super::IdentifyError;
use super::options::{
    Estimator, FrfKind, StiffnessOptions, StiffnessResult, MAX_DIRECTION_SPREAD, MIN_SEGMENTS,
};
use super::picks::{identify_stiffness_from, identify_stiffness_windows};

/// The `feedloop excite` flags that put a traverse under the excitation (what the advice to
/// excite on a traverse asks for; `feedloop excite`'s defaults have none).
pub(super) const TRAVERSE_FLAGS: &str = "`feedloop excite ... --set traverse_m_per_s=0.02 --set \
    max_travel_m=0.1` with the excitation below the traverse (`--set velocity_m_per_s=2e-4` \
    for random-segments, `--set amplitude_m_per_s=2e-4` for prbs and multisine; the `_rad` \
    keys on a rotary axis)";

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
    let r = instrument(trace, axis, opts)?;
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
    let possible = possible_segments(windows.iter().map(|(a, b, _)| (*a, *b)), nseg);
    let all_reversals = count_reversals(y);
    let signals = Signals {
        u,
        y,
        r: r.as_deref(),
        dt,
        opts,
    };
    if possible >= MIN_SEGMENTS && all_reversals > 0 {
        return signals.on_traverse(trace, axis, &windows, nseg, all_reversals);
    }
    let mut result = identify_stiffness_from(u, y, r.as_deref(), dt, opts)?;
    result.checks.reversals = all_reversals;
    if result.checks.reversals > 0 {
        result.checks.advice.push(format!(
            "the axis reversed {} times in the record: backlash and friction then mix into the \
             response; excite on top of a constant traverse: {TRAVERSE_FLAGS}",
            result.checks.reversals
        ));
    }
    Ok(result)
}

/// The instrument: the command's increments (`A.cmd`) where the estimator takes one and the
/// command moves.
fn instrument(
    trace: &Trace,
    axis: &str,
    opts: &StiffnessOptions,
) -> Result<Option<Vec<f64>>, IdentifyError> {
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
    Ok(r)
}

/// Welch segments of `nseg` samples (half overlapping) that fit inside the sample ranges.
fn possible_segments(ranges: impl Iterator<Item = (usize, usize)>, nseg: usize) -> usize {
    ranges
        .map(|(a, b)| (b - a - nseg) / (nseg / 2).max(1) + 1)
        .sum()
}

/// The signals identified on: torque `u`, motor velocity `y`, instrument `r`, period `dt`.
struct Signals<'a> {
    u: &'a [f64],
    y: &'a [f64],
    r: Option<&'a [f64]>,
    dt: f64,
    opts: &'a StiffnessOptions,
}

impl Signals<'_> {
    /// The identification on a traverse's one-direction windows (`(start, end, sign)`), each
    /// direction alone and the reversals between them.
    fn on_traverse(
        &self,
        trace: &Trace,
        axis: &str,
        windows: &[(usize, usize, i8)],
        nseg: usize,
        all_reversals: usize,
    ) -> Result<StiffnessResult, IdentifyError> {
        let (u, y, dt, opts) = (self.u, self.y, self.dt, self.opts);
        // One-direction windows only: no segment holds a reversal or its settling.
        let ranges: Vec<(usize, usize)> = windows.iter().map(|(a, b, _)| (*a, *b)).collect();
        let mut result = identify_stiffness_windows(u, y, self.r, dt, opts, &ranges)?;
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
        self.check_directions(&mut result, windows, nseg);
        result.credible = result.checks.credible();
        result.reversal_effects = reversal_effects(
            u,
            y,
            dt,
            opts.jm_kgm2 + result.jl_kgm2,
            trace.column(&format!("{axis}.motor")),
            trace.column(&format!("{axis}.load")),
            windows,
            result.kl_nm_per_rad,
        );
        check_flank(&mut result);
        Ok(result)
    }

    /// Each direction alone must give the same pair: backlash, friction or noise that the
    /// average hides show as a disagreement.
    fn check_directions(
        &self,
        result: &mut StiffnessResult,
        windows: &[(usize, usize, i8)],
        nseg: usize,
    ) {
        let mut kl_dir = [None, None];
        for (i, dir) in [1i8, -1].into_iter().enumerate() {
            let own: Vec<(usize, usize)> = windows
                .iter()
                .filter(|w| w.2 == dir)
                .map(|(a, b, _)| (*a, *b))
                .collect();
            let n = possible_segments(own.iter().copied(), nseg);
            if n < MIN_SEGMENTS {
                continue;
            }
            let name = if dir > 0 { "positive" } else { "negative" };
            match identify_stiffness_windows(self.u, self.y, self.r, self.dt, self.opts, &own) {
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
    }
}

/// The flank check: an excitation that lifts the nut off its flank mixes contact and free
/// flight, so the result is not credible.
fn check_flank(result: &mut StiffnessResult) {
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
}
