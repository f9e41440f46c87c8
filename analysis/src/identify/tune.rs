//! Control-parameter optimisation by a ramp test (seed 001): run the job for each parameter set
//! of a grid (in parallel), score `E = l1 RMS(x err) + l2 RMS(v err) + l3 RMS(a err)` over the
//! steady-state part, reject sets that saturate the torque or whose loops (from the model, with
//! the control period's delay and zero-order hold) have less than 30 deg phase margin or 6 dB
//! gain margin.

use feedloop_model::job::Job;
use feedloop_model::units::sig;
use rayon::prelude::*;
use serde::Serialize;

use super::inertia::run_axis;
use super::IdentifyError;

pub use feedloop_control::loop_model::{
    loop_delay_s, margins, model_delay_cycles, Gains, MIN_GAIN_MARGIN_DB, MIN_PHASE_MARGIN_DEG,
};

/// Tunable parameters, in grid order.
pub const PARAMS: [&str; 3] = ["kp_per_s", "kv_nms_per_rad", "tv_s"];

/// One grid axis `name = lo:hi:n`.
#[derive(Debug, Clone)]
pub struct GridAxis {
    /// Parameter name (one of [`PARAMS`]).
    pub name: String,
    /// Values.
    pub values: Vec<f64>,
}

/// Parses `name=lo:hi:n,name=lo:hi:n,...`.
pub fn parse_grid(s: &str) -> Result<Vec<GridAxis>, IdentifyError> {
    let bad = |m: String| IdentifyError::Invalid(m);
    let mut out = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (name, range) = part
            .split_once('=')
            .ok_or_else(|| bad(format!("grid `{part}`: expected name=lo:hi:n")))?;
        if !PARAMS.contains(&name) {
            return Err(bad(format!(
                "grid `{part}`: `{name}`: {}",
                feedloop_model::params::unknown_name_reason("parameter", name, PARAMS)
            )));
        }
        let v: Vec<&str> = range.split(':').collect();
        let (lo, hi, n) = match v.as_slice() {
            [lo, hi, n] => (
                lo.parse::<f64>()
                    .map_err(|e| bad(format!("grid `{part}`: {e}")))?,
                hi.parse::<f64>()
                    .map_err(|e| bad(format!("grid `{part}`: {e}")))?,
                n.parse::<usize>()
                    .map_err(|e| bad(format!("grid `{part}`: {e}")))?,
            ),
            _ => return Err(bad(format!("grid `{part}`: expected name=lo:hi:n"))),
        };
        if n == 0 || !(lo.is_finite() && hi.is_finite()) || hi < lo || lo < 0.0 {
            return Err(bad(format!(
                "grid `{part}`: needs 0 <= lo <= hi and n >= 1 points (empty grid)"
            )));
        }
        let values = (0..n)
            .map(|k| {
                if n == 1 {
                    lo
                } else {
                    lo + (hi - lo) * k as f64 / (n - 1) as f64
                }
            })
            .collect();
        out.push(GridAxis {
            name: name.to_string(),
            values,
        });
    }
    if out.is_empty() {
        return Err(bad("empty grid: give e.g. kp_per_s=20:120:11".into()));
    }
    Ok(out)
}

/// The job's gains for axis `i` (chain params first, then the model's controller).
pub fn job_gains(job: &Job, i: usize) -> Gains {
    let c = &job.axes[i].model.controller;
    let mut g = Gains {
        kp_per_s: c.kp_per_s.unwrap_or(50.0),
        kv_nms_per_rad: c.kv.unwrap_or(5.0),
        tv_s: c.tv_s.unwrap_or(0.005),
    };
    for e in job.chain.iter().filter(|e| e.axis == i) {
        for k in PARAMS {
            if let Some(v) = e.params.get(k).and_then(|v| v.as_float()) {
                g.set(k, v);
            }
        }
    }
    g
}

/// A copy of `job` with the gains of axis `i` set.
pub fn job_with_gains(job: &Job, i: usize, g: Gains) -> Job {
    let mut j = job.clone();
    let c = &mut j.axes[i].model.controller;
    c.kp_per_s = Some(g.kp_per_s);
    c.kv = Some(g.kv_nms_per_rad);
    c.tv_s = Some(g.tv_s);
    for e in j.chain.iter_mut().filter(|e| e.axis == i) {
        for (k, v) in [
            ("kp_per_s", g.kp_per_s),
            ("kv_nms_per_rad", g.kv_nms_per_rad),
            ("tv_s", g.tv_s),
        ] {
            if e.params.contains_key(k) {
                e.params.insert(k.into(), toml::Value::Float(v));
            }
        }
    }
    j
}

/// Score of one evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct Evaluation {
    /// Gains.
    pub gains: Gains,
    /// E, or None when rejected.
    pub e: Option<f64>,
    /// Why rejected.
    pub rejected: Option<String>,
}

/// E of a run of axis `i`: RMS of position, velocity and acceleration errors (central
/// differences) over the steady-state part, i.e. where the command acceleration is ~0 and the
/// velocity is not, after the first 30 % of that part.
pub fn ramp_error(job: &Job, i: usize, weights: [f64; 3]) -> Result<(f64, f64), IdentifyError> {
    let rec = run_axis(job, i)?;
    let h = job.period_s;
    let n = rec.len();
    if n < 10 {
        return Err(IdentifyError::Invalid(
            "the run is too short for a ramp test".into(),
        ));
    }
    let cmd: Vec<f64> = rec.iter().map(|r| r.cmd).collect();
    let load: Vec<f64> = rec.iter().map(|r| r.load).collect();
    let tmax = rec.iter().map(|r| r.torque.abs()).fold(0.0, f64::max);
    let vmax = (1..n - 1)
        .map(|k| ((cmd[k + 1] - cmd[k - 1]) / (2.0 * h)).abs())
        .fold(0.0, f64::max);
    let steady: Vec<usize> = (2..n - 2)
        .filter(|&k| {
            let v = (cmd[k + 1] - cmd[k - 1]) / (2.0 * h);
            let a = (cmd[k + 2] - 2.0 * cmd[k] + cmd[k - 2]) / (4.0 * h * h);
            v.abs() > 0.5 * vmax && a.abs() < 1e-6 * vmax / h
        })
        .collect();
    if steady.len() < 10 {
        return Err(IdentifyError::Invalid(
            "the job's command has no constant-velocity (ramp) part to score".into(),
        ));
    }
    let part = &steady[(3 * steady.len()) / 10..];
    let (mut sx, mut sv, mut sa) = (0.0, 0.0, 0.0);
    for &k in part {
        let e = |j: usize| cmd[j] - load[j];
        sx += e(k).powi(2);
        sv += ((e(k + 1) - e(k - 1)) / (2.0 * h)).powi(2);
        sa += ((e(k + 1) - 2.0 * e(k) + e(k - 1)) / (h * h)).powi(2);
    }
    let m = part.len() as f64;
    let e =
        weights[0] * (sx / m).sqrt() + weights[1] * (sv / m).sqrt() + weights[2] * (sa / m).sqrt();
    Ok((e, tmax))
}

/// Evaluates one gain set; the margins include the zero-order hold and `delay_cycles` periods
/// of transport delay on top of the model's own.
pub fn evaluate(job: &Job, i: usize, g: Gains, weights: [f64; 3], delay_cycles: u32) -> Evaluation {
    let reject = |why: String| Evaluation {
        gains: g,
        e: None,
        rejected: Some(why),
    };
    let delay_s = loop_delay_s(job, i, delay_cycles);
    if let Some((pm, gm)) = margins(&job.axes[i].model.plant, g, job.period_s, delay_s) {
        if pm < MIN_PHASE_MARGIN_DEG || gm < MIN_GAIN_MARGIN_DB {
            return reject(format!(
                "margins {pm:.1} deg / {gm:.1} dB (with the {:.0} us sampling hold and {:.0} us delay)",
                0.5e6 * job.period_s,
                1e6 * delay_s
            ));
        }
    }
    let j = job_with_gains(job, i, g);
    match ramp_error(&j, i, weights) {
        Ok((e, tmax)) => {
            let lim = job.axes[i]
                .model
                .controller
                .torque_limit
                .unwrap_or(f64::INFINITY);
            if tmax >= 0.999 * lim {
                reject(format!("torque saturates ({tmax:.1} N m)"))
            } else if !e.is_finite() {
                reject("unstable".into())
            } else {
                Evaluation {
                    gains: g,
                    e: Some(e),
                    rejected: None,
                }
            }
        }
        Err(e) => reject(e.to_string()),
    }
}

/// Result of [`tune`].
#[derive(Debug, Clone, Serialize)]
pub struct TuneResult {
    /// Best gains.
    pub best: Gains,
    /// E of the best.
    pub e_best: f64,
    /// E of the job's own gains.
    pub e_default: f64,
    /// Sets evaluated.
    pub evaluated: usize,
    /// Sets rejected.
    pub rejected: usize,
    /// All evaluations, grid order (last axis fastest).
    #[serde(skip)]
    pub all: Vec<Evaluation>,
}

/// Runs the grid on axis `i` in parallel; `progress` is called from worker threads after each
/// set. `delay_cycles`: see [`evaluate`].
pub fn tune(
    job: &Job,
    i: usize,
    grid: &[GridAxis],
    weights: [f64; 3],
    delay_cycles: u32,
    refine: bool,
    progress: &(dyn Fn() + Sync),
) -> Result<TuneResult, IdentifyError> {
    let base = job_gains(job, i);
    let mut sets = vec![base];
    for ax in grid {
        sets = sets
            .iter()
            .flat_map(|g| {
                ax.values.iter().map(move |v| {
                    let mut g = *g;
                    g.set(&ax.name, *v);
                    g
                })
            })
            .collect();
    }
    if sets.is_empty() {
        return Err(IdentifyError::Invalid("empty grid".into()));
    }
    let all: Vec<Evaluation> = sets
        .par_iter()
        .map(|g| {
            let e = evaluate(job, i, *g, weights, delay_cycles);
            progress();
            e
        })
        .collect();
    let e_default = evaluate(job, i, base, weights, delay_cycles)
        .e
        .unwrap_or(f64::NAN);
    let best = all
        .iter()
        .filter_map(|e| e.e.map(|v| (v, e.gains)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .ok_or_else(|| {
            IdentifyError::Invalid(format!(
                "all {} parameter sets were rejected (first reason: {})",
                all.len(),
                all[0].rejected.clone().unwrap_or_default()
            ))
        })?;
    let (mut e_best, mut g_best) = best;
    if refine {
        // Coordinate search with shrinking relative steps.
        let mut step = 0.1;
        while step > 0.005 {
            let mut improved = false;
            for name in grid.iter().map(|a| a.name.clone()) {
                for s in [1.0 + step, 1.0 - step] {
                    let mut g = g_best;
                    let v = match name.as_str() {
                        "kp_per_s" => g.kp_per_s,
                        "kv_nms_per_rad" => g.kv_nms_per_rad,
                        _ => g.tv_s,
                    };
                    g.set(&name, v * s);
                    if let Some(e) = evaluate(job, i, g, weights, delay_cycles).e {
                        if e < e_best {
                            e_best = e;
                            g_best = g;
                            improved = true;
                        }
                    }
                }
            }
            if !improved {
                step *= 0.5;
            }
        }
    }
    let rejected = all.iter().filter(|e| e.e.is_none()).count();
    Ok(TuneResult {
        best: g_best,
        e_best,
        e_default,
        evaluated: all.len(),
        rejected,
        all,
    })
}
/// A best set on the edge of its grid: the search did not see the error rise past it, so the
/// best may lie beyond (a grid axis of one value has no edge; a lower bound of 0 is the
/// parameter's own end).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct EdgeWarning {
    /// The parameter (one of [`PARAMS`]).
    pub parameter: String,
    /// `upper` or `lower`.
    pub edge: &'static str,
    /// The grid's bound on that edge.
    pub bound: f64,
    /// The best set's value.
    pub best: f64,
    /// The same grid axis widened past that edge by its span (same number of points).
    pub widened: String,
}

/// The parameters whose best value lies on (or, refined, beyond) an edge of their grid axis.
pub fn edge_warnings(grid: &[GridAxis], best: Gains) -> Vec<EdgeWarning> {
    let mut out = vec![];
    for ax in grid.iter().filter(|a| a.values.len() >= 2) {
        let (lo, hi, n) = (
            ax.values[0],
            ax.values[ax.values.len() - 1],
            ax.values.len(),
        );
        let b = match ax.name.as_str() {
            "kp_per_s" => best.kp_per_s,
            "kv_nms_per_rad" => best.kv_nms_per_rad,
            _ => best.tv_s,
        };
        let span = hi - lo;
        let close = 1e-9 * span;
        let (edge, bound, widened) = if b >= hi - close {
            (
                "upper",
                hi,
                format!("{}={}:{}:{n}", ax.name, sig(lo), sig(hi + span)),
            )
        } else if b <= lo + close && lo > 0.0 {
            let wider = (lo - span).max(0.0);
            (
                "lower",
                lo,
                format!("{}={}:{}:{n}", ax.name, sig(wider), sig(hi)),
            )
        } else {
            continue;
        };
        out.push(EdgeWarning {
            parameter: ax.name.clone(),
            edge,
            bound,
            best: b,
            widened,
        });
    }
    out
}
