//! Learning the `quadrant_compensator` table from recorded runs (seed 004, steps (1)-(8)).
//!
//! 1. Reversals are found in the commanded velocity with the compensator's own
//!    [`ReversalDetector`]; around each one the following error e = th - thL (load units) is
//!    resampled on tau = -L, ..., 0, T, 2T, ... about the interpolated reversal instant (the
//!    approach, `lead_s` = L before it, and `window_s` after it), its value at tau = -L
//!    subtracted (the error in steady motion, before the friction's Stribeck rise), and the
//!    curves of all reversals of one direction averaged. The spike is the largest |e(tau) -
//!    e(-L)| of any single reversal. (Measured from e(0) instead, the approach error at the
//!    reversal, -66 nm on the shipped circle, reappears as +62 nm at the end of every window,
//!    where no pulse after the reversal can reach it.)
//! 2. In a region of that curve the maximum |e| is the "max point"; the start point is the last
//!    sample before it, and the end point the first after it, where |e| falls to `threshold` of
//!    the maximum (or changes sign); otherwise the region's bounds.
//! 3. Two acceleration-planned models (see [`feedloop_plugins::quadrant`]) span start->max and
//!    max->end; their rise/fall splits are chosen by bisection on the sign of the least-squares
//!    residual's slope, with the amplitude at the measured maximum, and kept so that every
//!    acceleration phase lasts at least `min_phase_s`; the common amplitude is then the
//!    least-squares fit of both models to the curve.
//! 4. Pass 1 fits the spike after the reversal (against e(0), its start point tried at the
//!    threshold and at the reversal, kept per axis as it ran better) and the approach, the lobe
//!    of what is left through the reversal, played from the predicted reversal instant. The
//!    pulses are written to the table, the job is run again with them, and later passes fit one
//!    pulse to each lobe of the residual (one sign between zero crossings, so each pulse leaves
//!    and returns to zero where its lobe does), until the spike is below `accept` or the pass
//!    count is reached.
//!
//! [`learn_quadrant`] runs that loop. It does not know how to run a job: the caller passes a
//! closure (the CLI's `feedloop learn quadrant` passes the in-process simulation), so the
//! learning loop stays independent of how a job is run.

use std::path::{Path, PathBuf};

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::job::Job;
use feedloop_model::params::ConfigError;
use feedloop_trace::log::AxisRecord;

use feedloop_plugins::quadrant::{
    AxisPulses, Direction, Profile, Pulse, QuadrantCompensator, QuadrantTable, ReversalDetector,
    MAX_PULSES,
};

/// Records of one run, per axis (`records[axis][cycle]`, job axis order, load units).
pub type RunRecords = Vec<Vec<AxisRecord>>;

/// How [`learn_quadrant`] runs a job: returns its records or a message.
pub type RunJob<'a> = dyn FnMut(&Job) -> Result<RunRecords, String> + 'a;

/// Options of the learning loop.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnOptions {
    /// Error window after each reversal, s (also cut at the next reversal). Default 0.08.
    pub window_s: f64,
    /// Error window before each reversal (the approach), s; pulses may start that early, played
    /// from the reversal instant the compensator predicts. Default 0.08.
    pub lead_s: f64,
    /// Start/end points: where |e| falls to this fraction of the maximum. Default 0.01.
    pub threshold: f64,
    /// Stop when every axis' spike is at or below this, load units (m or rad). Default 0.
    pub accept: f64,
    /// Write the table here instead of the path in the job's `table` key.
    pub table: Option<PathBuf>,
    /// Without `table`: write the table into this folder, under the file name of the job's
    /// `table` (the job's own table file is then left as it is).
    pub out_dir: Option<PathBuf>,
    /// Learning gain of the first pass: the fitted amplitude is scaled by it. Default 1.
    pub gain: f64,
    /// Learning gain of the later passes (which fit smaller, faster residuals, where the plant
    /// answers a compensation less faithfully). Default 0.5.
    pub refine_gain: f64,
    /// Later passes fit residual lobes at least this fraction of the largest. Default 0.3.
    pub lobe_fraction: f64,
    /// Shape of the learned pulses. Default [`Profile::SineAcceleration`].
    pub profile: Profile,
    /// Shortest acceleration or deceleration phase of a learned pulse, s: the splits are kept
    /// so, and a lobe too short for two phases gets no pulse. Default 1 ms.
    pub min_phase_s: f64,
}

impl Default for LearnOptions {
    fn default() -> Self {
        Self {
            window_s: 0.08,
            lead_s: 0.08,
            threshold: 0.01,
            accept: 0.0,
            table: None,
            out_dir: None,
            gain: 1.0,
            refine_gain: 0.5,
            lobe_fraction: 0.3,
            profile: Profile::SineAcceleration,
            min_phase_s: 0.001,
        }
    }
}

/// Errors of [`learn_quadrant`].
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    /// No stage to learn for.
    #[error("the job has no `quadrant_compensator` stage: add one (with a `table` path) to the axes to learn")]
    NoCompensator,
    /// Stages point at different tables.
    #[error("the quadrant_compensator stages name different tables ({0} and {1}): learn one table at a time")]
    SeveralTables(PathBuf, PathBuf),
    /// Invalid job or parameters.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Writing the table failed.
    #[error("writing the table {path}: {source}")]
    Write {
        /// Table file.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The run closure failed.
    #[error("running the job: {0}")]
    Run(String),
    /// The run returned a wrong shape.
    #[error("the run returned {got} axes of records, the job has {want}")]
    RecordShape {
        /// Axes returned.
        got: usize,
        /// Axes of the job.
        want: usize,
    },
}

/// One axis after one pass.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisSpike {
    /// Axis name.
    pub axis: String,
    /// Largest |e(tau) - e(0)| over all reversal windows, load units (m or rad).
    pub spike: f64,
    /// Reversals seen.
    pub reversals: usize,
    /// Pulses in the table that produced this run.
    pub pulses: usize,
}

/// One pass (0 = the run before learning).
#[derive(Debug, Clone, PartialEq)]
pub struct PassReport {
    /// Pass number.
    pub pass: usize,
    /// Per learned axis, as run with the table of this pass.
    pub axes: Vec<AxisSpike>,
    /// Runs this pass took (more than 1 when an axis' new pulses had to be scaled back).
    pub runs: usize,
}

/// Times a pass' new pulses of an axis are halved before they are dropped (each costs a run).
pub const MAX_BACKTRACKS: usize = 3;

/// What [`learn_quadrant`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnReport {
    /// Where the table was written.
    pub table_path: PathBuf,
    /// The table file the job's stages name (the same as `table_path` unless the table was
    /// written elsewhere).
    pub job_table: PathBuf,
    /// Pass 0 (no compensation) and every learning pass run.
    pub passes: Vec<PassReport>,
    /// The final table.
    pub table: QuadrantTable,
}

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
    let rise_sse = |split: f64| -> f64 {
        if m <= s {
            return 0.0;
        }
        let span = t(m) - t(s);
        (s..=m)
            .map(|j| {
                let g = profile.rise((t(j) - t(s)) / span, split)[0];
                (curve[j] - peak * g).powi(2)
            })
            .sum()
    };
    let fall_sse = |split: f64| -> f64 {
        if e <= m {
            return 0.0;
        }
        let span = t(e) - t(m);
        (m..=e)
            .map(|j| {
                let g = profile.rise((t(j) - t(m)) / span, split)[0];
                (curve[j] - peak * (1.0 - g)).powi(2)
            })
            .sum()
    };
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

/// A quadrant_compensator stage of the job: (axis index, table axis name, table path).
fn compensated_axes(job: &Job) -> Result<(Vec<(usize, String)>, PathBuf), LearnError> {
    let dir = job.path.parent().unwrap_or(Path::new("."));
    let mut out = Vec::new();
    let mut path: Option<PathBuf> = None;
    for c in job
        .chain
        .iter()
        .filter(|c| c.plugin == QuadrantCompensator::ID)
    {
        let key = format!("{}.params.table", c.key);
        let rel = c
            .params
            .get("table")
            .and_then(|v| v.as_str())
            .ok_or_else(|| {
                ConfigError::new(&job.path, &key, "is required: the table to learn into")
            })?;
        let p = dir.join(rel);
        if let Some(q) = &path {
            if *q != p {
                return Err(LearnError::SeveralTables(q.clone(), p));
            }
        }
        path = Some(p);
        let name = c
            .params
            .get("axis")
            .and_then(|v| v.as_str())
            .unwrap_or(&job.axes[c.axis].name)
            .to_string();
        out.push((c.axis, name));
    }
    match path {
        Some(p) => Ok((out, p)),
        None => Err(LearnError::NoCompensator),
    }
}

/// Commanded velocity (load units/s) of every job axis at cycles 0..n.
fn commanded_velocities(job: &Job, n: usize) -> Result<Vec<Vec<f64>>, ConfigError> {
    let names = job.axis_names();
    let traj = feedloop_motion::build(&job.trajectory, &job.path, &names, job.period_s)?;
    let map: Vec<Option<usize>> = names
        .iter()
        .map(|a| traj.axes().iter().position(|t| t == a))
        .collect();
    let mut out = vec![vec![0.0; n]; names.len()];
    let mut buf = vec![[0.0; REF_DERIVS]; traj.axes().len()];
    for k in 0..n {
        traj.eval(k as f64 * job.period_s, &mut buf);
        for (o, m) in out.iter_mut().zip(&map) {
            if let Some(j) = m {
                o[k] = buf[*j][1];
            }
        }
    }
    Ok(out)
}

/// Learns the quadrant table of `job` in up to `passes` passes.
///
/// `run` runs the job (reading the table file as it stands) and returns its records per axis
/// (`records[axis][cycle]`, job axis order, load units). The table is written before every run:
/// empty before pass 0, then with the pulses of passes 1..=p. Returns the spike of every run.
pub fn learn_quadrant(
    job: &Job,
    passes: usize,
    options: &LearnOptions,
    run: &mut RunJob<'_>,
) -> Result<LearnReport, LearnError> {
    let (axes, job_table) = compensated_axes(job)?;
    let elsewhere = match (&options.table, &options.out_dir) {
        (Some(t), _) => Some(t.clone()),
        (None, Some(dir)) => Some(dir.join(job_table.file_name().unwrap_or_default())),
        (None, None) => None,
    };
    let job_table_path = job_table.clone();
    let (table_path, job) = match elsewhere {
        // the stages resolve a relative `table` against the job's folder: give them the path
        // as seen from here
        Some(p) => {
            let p = std::path::absolute(&p).map_err(|source| LearnError::Write {
                path: p.clone(),
                source,
            })?;
            let j = retarget(job, &p);
            (p, j)
        }
        None => (job_table, job.clone()),
    };
    let mut table = QuadrantTable::default();
    for (_, name) in &axes {
        table.axes.insert(name.clone(), AxisPulses::default());
    }
    let mut velocities: Option<Vec<Vec<f64>>> = None;
    // Writes `t`, runs the job, and measures every learned axis.
    let mut evaluate =
        |t: &QuadrantTable| -> Result<(Vec<AxisSpike>, Vec<ReversalCurves>), LearnError> {
            t.save(&table_path).map_err(|source| LearnError::Write {
                path: table_path.clone(),
                source,
            })?;
            let records = run(&job).map_err(LearnError::Run)?;
            if records.len() != job.axes.len() {
                return Err(LearnError::RecordShape {
                    got: records.len(),
                    want: job.axes.len(),
                });
            }
            let n = records.iter().map(Vec::len).min().unwrap_or(0);
            if velocities.as_ref().map(|v| v[0].len()) != Some(n) {
                velocities = Some(commanded_velocities(&job, n)?);
            }
            let vel = velocities.as_ref().expect("just computed");
            Ok(measure(&job, &axes, &records, vel, t, options))
        };
    let (mut spikes, mut curves) = evaluate(&table)?;
    let mut reports = vec![PassReport {
        pass: 0,
        axes: spikes.clone(),
        runs: 1,
    }];
    // Span of the first pass' pulse (grid indices), per learned axis and direction.
    let mut spans: Vec<[Option<(usize, usize)>; 2]> = axes.iter().map(|_| [None, None]).collect();
    for pass in 1..=passes {
        if spikes.iter().all(|a| a.spike <= options.accept) {
            break;
        }
        let before = spans.clone();
        let mut fitted = fit_axes(&curves, pass, &mut spans, options, SpikeStart::Threshold);
        let mut tried = 0;
        if pass == 1 {
            // Where the spike's pulse starts is tried both ways (at the threshold point and at
            // the reversal, where the friction flips), and kept per axis as it ran better.
            let other = fit_axes(
                &curves,
                pass,
                &mut before.clone(),
                options,
                SpikeStart::Reversal,
            );
            let ones = vec![1.0; axes.len()];
            let (s_a, _) = evaluate(&candidate(&table, &axes, &fitted, &ones))?;
            let (s_b, _) = evaluate(&candidate(&table, &axes, &other, &ones))?;
            tried = 2;
            for (i, o) in other.into_iter().enumerate() {
                if s_b[i].spike < s_a[i].spike {
                    fitted[i] = o;
                }
            }
        }
        // Step (6) with a guard: an axis whose spike grows gets its new pulses halved (twice),
        // then dropped, so a pass never leaves an axis worse than the pass before.
        let mut scale = vec![1.0; axes.len()];
        for attempt in 0..=MAX_BACKTRACKS {
            let cand = candidate(&table, &axes, &fitted, &scale);
            let (s_new, c_new) = evaluate(&cand)?;
            let worse: Vec<usize> = (0..axes.len())
                .filter(|&i| scale[i] > 0.0 && s_new[i].spike > spikes[i].spike)
                .collect();
            if worse.is_empty() || attempt == MAX_BACKTRACKS {
                table = cand;
                spikes = s_new;
                curves = c_new;
                reports.push(PassReport {
                    pass,
                    axes: spikes.clone(),
                    runs: tried + attempt + 1,
                });
                break;
            }
            for i in worse {
                scale[i] = if attempt + 1 < MAX_BACKTRACKS {
                    scale[i] * 0.5
                } else {
                    0.0
                };
            }
        }
    }
    Ok(LearnReport {
        table_path,
        job_table: job_table_path,
        passes: reports,
        table,
    })
}

/// The spike and mean reversal curves of every learned axis (`axes`: job axis index, table
/// axis name) in `records`, as run with table `t`; `vel` is the commanded velocity per job axis.
fn measure(
    job: &Job,
    axes: &[(usize, String)],
    records: &RunRecords,
    vel: &[Vec<f64>],
    t: &QuadrantTable,
    options: &LearnOptions,
) -> (Vec<AxisSpike>, Vec<ReversalCurves>) {
    let mut spikes = Vec::new();
    let mut curves = Vec::new();
    for (ax, name) in axes {
        let rec = &records[*ax];
        let cmd: Vec<f64> = rec.iter().map(|r| r.cmd).collect();
        let load: Vec<f64> = rec.iter().map(|r| r.load).collect();
        let c = reversal_curves(
            &cmd,
            &load,
            &vel[*ax],
            job.period_s,
            (options.lead_s, options.window_s),
        );
        spikes.push(AxisSpike {
            axis: job.axes[*ax].name.clone(),
            spike: c.spike,
            reversals: c.events[0] + c.events[1],
            pulses: t
                .axes
                .get(name)
                .map_or(0, |p| p.to_positive.len() + p.to_negative.len()),
        });
        curves.push(c);
    }
    (spikes, curves)
}

/// The pass' pulses per learned axis and direction, fitted to `curves`; updates `spans` (the
/// first pass' pulse span per axis and direction).
fn fit_axes(
    curves: &[ReversalCurves],
    pass: usize,
    spans: &mut [[Option<(usize, usize)>; 2]],
    options: &LearnOptions,
    start: SpikeStart,
) -> Vec<[Vec<Pulse>; 2]> {
    let mut fitted: Vec<[Vec<Pulse>; 2]> = Vec::new();
    for (i, c) in curves.iter().enumerate() {
        let mut per_dir: [Vec<Pulse>; 2] = [Vec::new(), Vec::new()];
        for dir in Direction::ALL {
            let d = dir.index();
            let (pulses, span) = fit_pass(
                &c.curves[d],
                (c.period_s, c.lead),
                (pass as u32, start),
                spans[i][d],
                options,
            );
            spans[i][d] = span;
            per_dir[d] = pulses;
        }
        fitted.push(per_dir);
    }
    fitted
}

/// `table` with the `fitted` pulses of every learned axis added, their amplitudes times the
/// axis' `scale` (an axis at scale 0 gets none), up to [`MAX_PULSES`] per direction.
fn candidate(
    table: &QuadrantTable,
    axes: &[(usize, String)],
    fitted: &[[Vec<Pulse>; 2]],
    scale: &[f64],
) -> QuadrantTable {
    let mut cand = table.clone();
    for (i, (_, name)) in axes.iter().enumerate() {
        if scale[i] == 0.0 {
            continue;
        }
        let entry = cand.axes.entry(name.clone()).or_default();
        for dir in Direction::ALL {
            let list = entry.get_mut(dir);
            let room = MAX_PULSES.saturating_sub(list.len());
            list.extend(fitted[i][dir.index()].iter().take(room).map(|p| Pulse {
                amplitude: p.amplitude * scale[i],
                ..*p
            }));
        }
    }
    cand
}

/// `job` with every quadrant_compensator stage reading `table`.
fn retarget(job: &Job, table: &Path) -> Job {
    let mut j = job.clone();
    for c in j
        .chain
        .iter_mut()
        .filter(|c| c.plugin == QuadrantCompensator::ID)
    {
        c.params.insert(
            "table".into(),
            toml::Value::String(table.to_string_lossy().into_owned()),
        );
    }
    j
}

#[cfg(test)]
mod tests {
    use super::*;

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
