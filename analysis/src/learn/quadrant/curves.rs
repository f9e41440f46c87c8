//! The reversal curves of a run and the pulses fitted to them.

use feedloop_plugins::quadrant::{Profile, Pulse, ReversalDetector};

use super::options::LearnOptions;

/// Averaged reversal error curves of one axis.
#[derive(Debug, Clone, PartialEq)]
pub struct ReversalCurves {
    /// Grid step, s.
    pub period_s: f64,
    /// Samples before the reversal at the start of every curve: `curves[d][j]` is at
    /// tau = (j - lead) T.
    pub lead: usize,
    /// Mean curve e(tau) - e(-lead T) per direction (`Direction::index`): the error against
    /// the error before the approach; empty without reversals.
    pub curves: [Vec<f64>; 2],
    /// Reversals per direction.
    pub events: [usize; 2],
    /// Largest |e(tau) - e(-lead T)| of any single reversal, approach included.
    pub spike: f64,
}

impl ReversalCurves {
    /// Time after the reversal of grid index `j`, s.
    pub fn tau(&self, j: usize) -> f64 {
        (j as f64 - self.lead as f64) * self.period_s
    }
}

/// Finds the reversals in `vel` (commanded velocity, one sample per period from t = 0) and
/// averages the error `cmd - load` around them: from `lead_s` before each reversal (the
/// approach, cut to half the time since the previous reversal) to `window_s` after it (cut at
/// the next one), against the error where the approach window starts.
pub fn reversal_curves(
    cmd: &[f64],
    load: &[f64],
    vel: &[f64],
    period_s: f64,
    (lead_s, window_s): (f64, f64),
) -> ReversalCurves {
    let n = cmd.len().min(load.len()).min(vel.len());
    let mut det = ReversalDetector::new();
    let mut revs = Vec::new();
    for (k, &v) in vel.iter().enumerate().take(n) {
        if let Some(r) = det.update(k as f64 * period_s, v) {
            revs.push((k, r));
        }
    }
    let e = |k: usize| cmd[k] - load[k];
    let max_len = (window_s / period_s).floor() as usize + 1;
    let lead = (lead_s.max(0.0) / period_s).floor() as usize;
    let mut sums: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let mut counts: [Vec<usize>; 2] = [Vec::new(), Vec::new()];
    let mut events = [0usize; 2];
    let mut spike: f64 = 0.0;
    for (i, &(k, r)) in revs.iter().enumerate() {
        // r.t_s lies in [t_{k-1}, t_k]: e(t_r + j T) interpolates samples k-1+j and k+j.
        let f = if k == 0 {
            1.0
        } else {
            ((r.t_s - (k - 1) as f64 * period_s) / period_s).clamp(0.0, 1.0)
        };
        let next_k = revs.get(i + 1).map(|x| x.0).unwrap_or(n);
        let len = max_len.min(next_k.saturating_sub(k)).min(n - k);
        if len < 2 {
            continue;
        }
        let prev_k = if i > 0 { revs[i - 1].0 } else { 0 };
        // samples before the reversal this event has (the rest of the lead is not averaged)
        let pre = lead.min((k - prev_k) / 2).min(k.saturating_sub(1));
        let at = |j: isize| {
            let kk = (k as isize + j) as usize;
            let hi = e(kk);
            let lo = if kk >= 1 { e(kk - 1) } else { hi };
            (1.0 - f) * lo + f * hi
        };
        let base = at(-(pre as isize));
        let d = r.direction.index();
        events[d] += 1;
        if sums[d].len() < lead + len {
            sums[d].resize(lead + len, 0.0);
            counts[d].resize(lead + len, 0);
        }
        for j in (lead - pre)..(lead + len) {
            let x = at(j as isize - lead as isize) - base;
            if x.is_finite() {
                spike = spike.max(x.abs());
                sums[d][j] += x;
                counts[d][j] += 1;
            }
        }
    }
    let curves = [0, 1].map(|d| {
        sums[d]
            .iter()
            .zip(&counts[d])
            .map(|(s, &c)| if c > 0 { s / c as f64 } else { 0.0 })
            .collect()
    });
    ReversalCurves {
        period_s,
        lead,
        curves,
        events,
        spike,
    }
}

/// Start, max and end indices of the spike whose maximum |curve| lies in `curve[a..=b]`: the
/// start and end are searched from the maximum outwards over the whole curve, so a spike that
/// straddles the region's bounds is modelled whole (see the module docs).
pub fn spike_points(
    curve: &[f64],
    a: usize,
    b: usize,
    threshold: f64,
) -> Option<(usize, usize, usize)> {
    let b = b.min(curve.len().checked_sub(1)?);
    if a > b {
        return None;
    }
    let m = (a..=b).max_by(|&i, &j| curve[i].abs().total_cmp(&curve[j].abs()))?;
    let p = curve[m];
    if p == 0.0 || !p.is_finite() {
        return None;
    }
    let quiet = |j: usize| curve[j].abs() <= threshold * p.abs() || curve[j] * p < 0.0;
    let last = curve.len() - 1;
    let s = (0..m).rev().find(|&j| quiet(j)).unwrap_or(0);
    let e = (m + 1..=last).find(|&j| quiet(j)).unwrap_or(last);
    Some((s, m, e))
}

/// Bisection for the split in [lo, hi] minimising `sse` (assumed unimodal): halves the
/// interval on the sign of the slope, 40 times.
fn bisect_split(sse: impl Fn(f64) -> f64, (mut lo, mut hi): (f64, f64)) -> f64 {
    let h = 1e-5;
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if sse(mid + h) < sse(mid - h) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Fits one pulse (two acceleration-planned models) to `curve[a..=b]` sampled every `period_s`.
/// Returns it with its (start, max, end) indices.
pub fn fit_pulse(
    curve: &[f64],
    period_s: f64,
    (a, b): (usize, usize),
    threshold: f64,
    pass: u32,
    (profile, min_phase_s): (Profile, f64),
) -> Option<(Pulse, (usize, usize, usize))> {
    let (s, m, e) = spike_points(curve, a, b, threshold)?;
    fit_pulse_at(curve, period_s, (s, m, e), pass, (profile, min_phase_s)).map(|p| (p, (s, m, e)))
}

/// Fits one pulse to `curve` with given start, max and end indices.
pub fn fit_pulse_at(
    curve: &[f64],
    period_s: f64,
    (s, m, e): (usize, usize, usize),
    pass: u32,
    (profile, min_phase_s): (Profile, f64),
) -> Option<Pulse> {
    if e <= s || e >= curve.len() || m < s || m > e {
        return None;
    }
    // Splits that keep both phases of a model at least `min_phase_s` long (the whole range
    // when the model is too short for that; such a pulse is refused below).
    let bounds = |span: f64| {
        let f = (min_phase_s / span).max(0.01);
        if f <= 0.5 {
            (f, 1.0 - f)
        } else {
            (0.01, 0.99)
        }
    };
    let peak = curve[m];
    let t = |j: usize| j as f64 * period_s;
    // a model shorter than two phases cannot be played smoothly enough: no pulse
    if t(m) - t(s) < 2.0 * min_phase_s || t(e) - t(m) < 2.0 * min_phase_s {
        return None;
    }
    // the squared misfit of the phase from sample `a` to `b` with `split`: the rise toward the
    // peak, or the fall from it
    let phase_sse = |a: usize, b: usize, fall: bool, split: f64| -> f64 {
        if b <= a {
            return 0.0;
        }
        let span = t(b) - t(a);
        (a..=b)
            .map(|j| {
                let g = profile.rise((t(j) - t(a)) / span, split)[0];
                let shape = if fall { 1.0 - g } else { g };
                (curve[j] - peak * shape).powi(2)
            })
            .sum()
    };
    let rise_sse = |split: f64| phase_sse(s, m, false, split);
    let fall_sse = |split: f64| phase_sse(m, e, true, split);
    let mut pulse = Pulse {
        pass,
        start_s: t(s),
        peak_s: t(m),
        end_s: t(e),
        rise_split: bisect_split(rise_sse, bounds(t(m) - t(s))),
        fall_split: bisect_split(fall_sse, bounds(t(e) - t(m))),
        amplitude: 1.0,
        profile,
    };
    // Least-squares amplitude of both models together.
    let (mut num, mut den) = (0.0, 0.0);
    for (j, c) in curve.iter().enumerate().take(e + 1).skip(s) {
        let g = if j == m { 1.0 } else { pulse.shape(t(j))[0] };
        num += c * g;
        den += g * g;
    }
    pulse.amplitude = if den > 0.0 { num / den } else { peak };
    pulse.amplitude.is_finite().then_some(pulse)
}

/// The lobes of `curve[a..=b]`: runs of one sign between zero crossings whose largest |value|
/// is at least `threshold` of the largest |value| there, as (start, max, end) indices (start
/// and end are the last sample before and the first after the run, where the curve has
/// crossed zero, or the bounds), largest first. A pulse fitted from start to end then leaves
/// and returns to zero where the lobe does.
pub fn lobes(curve: &[f64], a: usize, b: usize, threshold: f64) -> Vec<(usize, usize, usize)> {
    let b = b.min(curve.len().saturating_sub(1));
    if curve.is_empty() || a > b {
        return Vec::new();
    }
    let big = (a..=b).map(|j| curve[j].abs()).fold(0.0, f64::max);
    if !(big > 0.0 && big.is_finite()) {
        return Vec::new();
    }
    let sign = |j: usize| {
        if curve[j] > 0.0 {
            1
        } else if curve[j] < 0.0 {
            -1
        } else {
            0
        }
    };
    let mut out = Vec::new();
    let mut j = a;
    while j <= b {
        let sg = sign(j);
        if sg == 0 {
            j += 1;
            continue;
        }
        let first = j;
        while j <= b && sign(j) == sg {
            j += 1;
        }
        let last = j - 1;
        let m = (first..=last)
            .max_by(|&x, &y| curve[x].abs().total_cmp(&curve[y].abs()))
            .unwrap_or(first);
        if curve[m].abs() >= threshold * big {
            out.push((first.saturating_sub(1).max(a), m, (last + 1).min(b)));
        }
    }
    out.sort_by(|x, y| curve[y.1].abs().total_cmp(&curve[x.1].abs()));
    out
}

/// Where pass 1 starts the pulse of the spike after the reversal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpikeStart {
    /// Where the error (against its value at the reversal) last stays within `threshold` of
    /// the maximum (the seed's start point).
    Threshold,
    /// At the reversal, where the friction flips, if that is earlier.
    Reversal,
}

/// The pulses of one learning pass for one axis and direction, fitted to the mean error `curve`
/// (grid step `period_s`, `curve[j]` at tau = (j - lead) T; pulse times are in tau).
///
/// Pass 1 (`span` None) fits one pulse to the spike after the reversal (the error against its
/// value at the reversal; its start point as `start` says), then, to what that pulse leaves, one pulse to each lobe at least
/// `lobe_fraction` of the largest: the approach (the error before the reversal, which stays
/// while the spike is played) and what the spike's pulse missed. Later passes fit one pulse to
/// each lobe of the residual in `span` (the whole curve) at least `lobe_fraction` of the largest
/// (the residual of a compensated spike changes sign, and one pulse cannot model both signs).
/// Each fitted pulse is taken off before the next is fitted. Amplitudes are scaled by the
/// pass' learning gain. Returns the pulses and the span for the next pass.
pub fn fit_pass(
    curve: &[f64],
    (period_s, lead): (f64, usize),
    (pass, start): (u32, SpikeStart),
    span: Option<(usize, usize)>,
    options: &LearnOptions,
) -> (Vec<Pulse>, Option<(usize, usize)>) {
    if curve.is_empty() {
        return (Vec::new(), span);
    }
    let last = curve.len() - 1;
    let shape = (options.profile, options.min_phase_s);
    // Pulses are fitted on the grid's own clock (index j at j T) and shifted to tau at the end.
    let minus = |c: &[f64], p: Option<&Pulse>| -> Vec<f64> {
        c.iter()
            .enumerate()
            .map(|(j, v)| v - p.map_or(0.0, |p| p.eval(j as f64 * period_s)[0]))
            .collect()
    };
    let mut fitted: Vec<Pulse> = Vec::new();
    match span {
        None => {
            // The spike after the reversal and the approach through it overlap: fitted in turn,
            // each to the curve less the other. The first spike fit takes the error after the
            // reversal against its value there (the approach error at the reversal).
            let e0 = curve.get(lead).copied().unwrap_or(0.0);
            let mut approach: Option<Pulse> = None;
            let mut spike: Option<Pulse> = None;
            for round in 0..1 {
                let rest = minus(curve, approach.as_ref());
                let target: Vec<f64> = (0..=last)
                    .map(|j| match (j < lead, round) {
                        (true, _) => 0.0,
                        (false, 0) => rest[j] - e0,
                        (false, _) => rest[j],
                    })
                    .collect();
                spike = spike_points(&target, lead, usize::MAX, options.threshold).and_then(
                    |(s, m, e)| {
                        let s = match start {
                            SpikeStart::Threshold => s,
                            SpikeStart::Reversal => s.min(lead),
                        };
                        fit_pulse_at(&target, period_s, (s, m, e), pass, shape)
                    },
                );
                let Some(sp) = spike else {
                    return (Vec::new(), None);
                };
                let rest = minus(curve, Some(&sp));
                approach = lobes(&rest, 0, last, 0.0)
                    .into_iter()
                    .find(|&(s, _, e)| s < lead && lead < e)
                    .and_then(|pts| fit_pulse_at(&rest, period_s, pts, pass, shape));
            }
            fitted.extend(spike.into_iter().chain(approach).map(|p| Pulse {
                amplitude: p.amplitude * options.gain,
                ..p
            }));
        }
        Some((a, b)) => {
            let mut work = curve.to_vec();
            for pts in lobes(curve, a, b, options.lobe_fraction) {
                if let Some(mut p) = fit_pulse_at(&work, period_s, pts, pass, shape) {
                    p.amplitude *= options.refine_gain;
                    work = minus(&work, Some(&p));
                    fitted.push(p);
                }
            }
        }
    }
    let shift = lead as f64 * period_s;
    let out = fitted
        .into_iter()
        .map(|p| Pulse {
            start_s: p.start_s - shift,
            peak_s: p.peak_s - shift,
            end_s: p.end_s - shift,
            ..p
        })
        .collect();
    (out, Some((0, last)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use feedloop_plugins::quadrant::Direction;

    /// A friction-like spike: fast rise, slow decay.
    fn spike(t: f64) -> f64 {
        if t <= 0.0 {
            0.0
        } else {
            3e-6 * (1.0 - (-t / 0.002).exp()) * (-t / 0.008).exp() * 2.4
        }
    }

    #[test]
    fn spike_points_bracket_the_maximum_at_the_threshold() {
        let c: Vec<f64> = (0..800).map(|j| spike(j as f64 * 1e-4)).collect();
        let (s, m, e) = spike_points(&c, 0, usize::MAX, 0.05).unwrap();
        assert_eq!(s, 0);
        // peak of (1 - exp(-t/2ms)) exp(-t/8ms): 2 ms ln 5 = 3.22 ms
        assert_eq!(m, 32);
        assert!(c[e] <= 0.05 * c[m] && c[e - 1] > 0.05 * c[m]);
    }

    #[test]
    fn fitted_pulse_leaves_less_than_a_fifth_of_a_friction_like_spike() {
        let t = 1e-4;
        let c: Vec<f64> = (0..800).map(|j| spike(j as f64 * t)).collect();
        let (p, _) = fit_pulse(
            &c,
            t,
            (0, usize::MAX),
            0.05,
            1,
            (Profile::SineAcceleration, 0.0),
        )
        .unwrap();
        let peak = c.iter().cloned().fold(0.0, f64::max);
        let resid = c
            .iter()
            .enumerate()
            .map(|(j, v)| (v - p.eval(j as f64 * t)[0]).abs())
            .fold(0.0, f64::max);
        assert!(resid < 0.2 * peak, "residual {resid} of {peak}: {p:?}");
        assert!(p.rise_split > 0.01 && p.rise_split < 0.99);
    }

    #[test]
    fn bisection_finds_the_split_of_an_exact_model() {
        let t = 1e-4;
        let truth = Pulse {
            pass: 1,
            start_s: 0.0,
            peak_s: 0.005,
            end_s: 0.02,
            rise_split: 0.3,
            fall_split: 0.7,
            amplitude: -4e-6,
            profile: Profile::ConstantAcceleration,
        };
        let c: Vec<f64> = (0..=200).map(|j| truth.eval(j as f64 * t)[0]).collect();
        let (p, _) = fit_pulse(
            &c,
            t,
            (0, 200),
            0.0,
            1,
            (Profile::ConstantAcceleration, 0.0),
        )
        .unwrap();
        assert!((p.rise_split - 0.3).abs() < 1e-3, "{p:?}");
        assert!((p.fall_split - 0.7).abs() < 1e-3, "{p:?}");
        assert!((p.amplitude + 4e-6).abs() < 1e-10, "{p:?}");
    }

    #[test]
    fn reversal_curves_average_both_directions_and_report_the_largest_spike() {
        // velocity sin(2 pi t): reversals at 0.5 s (to negative) and 1.0 s (to positive)
        let t = 1e-3;
        let n = 1400;
        let vel: Vec<f64> = (0..n)
            .map(|k| (2.0 * std::f64::consts::PI * k as f64 * t).sin())
            .collect();
        let cmd = vec![0.0; n];
        let load: Vec<f64> = (0..n)
            .map(|k| {
                let tk = k as f64 * t;
                if tk > 0.5 && tk < 0.9 {
                    -spike(tk - 0.5)
                } else if tk > 1.0 {
                    2.0 * spike(tk - 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        let c = reversal_curves(&cmd, &load, &vel, t, (0.0, 0.08));
        assert_eq!(c.events, [1, 1]);
        let peak = (0..800).map(|j| spike(j as f64 * 1e-4)).fold(0.0, f64::max);
        assert!(
            (c.spike - 2.0 * peak).abs() < 0.05 * peak,
            "{} vs {}",
            c.spike,
            2.0 * peak
        );
        assert!(c.curves[Direction::ToNegative.index()]
            .iter()
            .all(|&x| x >= 0.0));
        assert!(c.curves[Direction::ToPositive.index()]
            .iter()
            .all(|&x| x <= 0.0));
    }
}
