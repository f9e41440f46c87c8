//! What no library effect explains: the torque residual against a small dictionary of terms
//! (the direction of travel, the velocity and its magnitude, the position, the acceleration,
//! the time, a delayed torque, and any trace column the user adds), so that a structured misfit
//! is described by what it follows, in words, with the cut each term gives, instead of "looks
//! like noise" or a wrong name. The same cross-validation and confidence rules as the effect
//! candidates decide which terms count.
//!
//! The dictionary is also what a generic identification tool regresses on: [`sparse_peer`] runs
//! a sequentially thresholded least squares over it (as pysindy's STLSQ does), the yardstick the
//! workbench's named, physical fit is compared with.

use std::f64::consts::PI;

use super::data::AxisData;
use super::effects::{dead_band, sgn};
use super::lsq::{blocks, contribution_size, cross_validate, normals, sizing_rows, Cv, CI_SIGMAS};
use super::refit::{cv_cols_masked, FOLDS};
use super::scoring::fold_wins;
use super::signal::{filtfilt_butter4, mean, nrmse_pct, quantile, rms, span};

/// Most terms the forward selection names.
pub const MAX_TERMS: usize = 3;

/// One term of the dictionary: a name, the words for what it follows, and its columns.
#[derive(Debug, Clone)]
pub struct Term {
    /// Short id (`direction`, `velocity`, `column:j3.load` ...).
    pub id: String,
    /// What the residual follows when this term explains it, in words.
    pub words: String,
    /// Its regressor columns (torque units per unit coefficient).
    pub cols: Vec<Vec<f64>>,
}

/// A term the residual follows, with the cut of the cross-validated error it gives beyond the
/// base refit and the terms named before it.
#[derive(Debug, Clone)]
pub struct TermCut {
    /// The term's id.
    pub term: String,
    /// What the residual follows, in words.
    pub words: String,
    /// Cut of the cross-validated error, % of the error before it.
    pub cut_pct: f64,
    /// Whether the cut counts (at least the channel's smallest cut, in 4 of 5 blocks, its
    /// contribution outside its own confidence interval).
    pub significant: bool,
}

/// The dictionary for the axis `d`: the default terms, then `extra` trace columns (name,
/// values at the axis' samples), filtered as the torque is. `needed` is the torque the model
/// needs for the recorded motion (for the delayed-torque term).
pub fn terms(d: &AxisData, needed: &[f64], extra: &[(String, Vec<f64>)]) -> Vec<Term> {
    let n = d.len();
    let (a, b) = d.range;
    let v = &d.vm;
    let eps = dead_band(d, v);
    let vmax = quantile(&v[a..b].iter().map(|x| x.abs()).collect::<Vec<_>>(), 0.99).max(1e-12);
    let filt = |c: Vec<f64>| -> Vec<f64> {
        if d.torque_filtered {
            filtfilt_butter4(&c, d.cutoff_hz, 1.0 / d.dt)
        } else {
            c
        }
    };
    let map = |f: &dyn Fn(f64) -> f64| v.iter().map(|x| f(*x)).collect::<Vec<f64>>();
    let sign = move |x: f64| sgn(x, eps);
    let mut out = vec![
        Term {
            id: "constant".into(),
            words: "a constant (an offset in both directions)".into(),
            cols: vec![vec![1.0; n]],
        },
        Term {
            id: "direction".into(),
            words: "the direction of travel (a step at each reversal)".into(),
            cols: vec![filt(map(&sign))],
        },
        Term {
            id: "direction_smooth".into(),
            words: "the direction of travel, smoothed over a twentieth of the top speed".into(),
            cols: vec![map(&|x| (x / (0.05 * vmax)).tanh())],
        },
        Term {
            id: "velocity".into(),
            words: "the velocity".into(),
            cols: vec![v.clone()],
        },
        Term {
            id: "speed".into(),
            words: "the speed |velocity| (the same in both directions)".into(),
            cols: vec![map(&f64::abs)],
        },
        Term {
            id: "velocity_squared".into(),
            words: "the velocity squared, with its sign (a drag)".into(),
            cols: vec![map(&|x| x.abs() * x)],
        },
        Term {
            id: "acceleration".into(),
            words: "the acceleration (an inertia the model lacks)".into(),
            cols: vec![d.am.clone()],
        },
    ];
    out.extend(position_terms(d, &filt));
    let t0 = mean(&d.t[a..b]);
    out.push(Term {
        id: "time".into(),
        words: "the time (a drift)".into(),
        cols: vec![d.t.iter().map(|t| t - t0).collect()],
    });
    out.push(Term {
        id: "delayed_torque".into(),
        words: "the change of the needed torque over one period (a delay the model lacks)".into(),
        // a drive that applies the recorded torque one period late moves now as the torque of
        // a period ago asks: the residual is the needed torque's change over one period. Built
        // from the motion only: the recorded torque's own change would carry its noise, which
        // the residual carries too, and a regression on it would "explain" that noise
        cols: vec![(0..n)
            .map(|k| {
                if k + 1 < n {
                    needed[k + 1] - needed[k]
                } else {
                    0.0
                }
            })
            .collect()],
    });
    for (name, c) in extra {
        if c.len() == n {
            out.push(Term {
                id: format!("column:{name}"),
                words: format!("the trace column `{name}`"),
                cols: vec![filt(c.clone())],
            });
        }
    }
    out
}

/// The position terms: periodic over one motor revolution (a ripple; not on a rigid axis) and
/// over twice the travel (a slow shape), each a sine and a cosine filtered by `filt`.
fn position_terms(d: &AxisData, filt: &dyn Fn(Vec<f64>) -> Vec<f64>) -> Vec<Term> {
    let (a, b) = d.range;
    let travel = span(&d.qm[a..b]);
    let mut periods = Vec::new();
    if d.kind != feedloop_model::model::AxisKind::Rigid {
        periods.push(("position_rev", 2.0 * PI, "one motor revolution"));
    }
    if travel > 0.0 {
        periods.push((
            "position_travel",
            2.0 * travel,
            "twice the travel (a slow shape of the position)",
        ));
    }
    periods
        .into_iter()
        .map(|(id, p, what)| {
            let w = 2.0 * PI / p;
            Term {
                id: id.into(),
                words: format!("the position, periodic over {what}"),
                cols: vec![
                    filt(d.qm.iter().map(|q| (w * q).sin()).collect()),
                    filt(d.qm.iter().map(|q| (w * q).cos()).collect()),
                ],
            }
        })
        .collect()
}

/// What the residual `res` follows beyond the `base` columns: forward selection of at most
/// [`MAX_TERMS`] terms, each scored by the blocked cross-validation against the fit before it
/// (the one that cuts most among those that count is taken);
/// a term counts when it cuts that error by `min_pct` % or more in `min_wins` of the blocks and
/// its contribution lies outside its own confidence interval ([`contribution_size`]). The
/// counted terms are returned, then the best one that did not count (so a user sees how close
/// the next one came).
#[allow(clippy::too_many_arguments)]
pub fn explain(
    terms: &[Term],
    base: &[&[f64]],
    res: &[f64],
    bl: &[(usize, usize)],
    mask: Option<&[f64]>,
    min_pct: f64,
    min_wins: usize,
) -> Vec<TermCut> {
    let mut chosen: Vec<usize> = Vec::new();
    let mut out = Vec::new();
    // sized on the rows the fit uses: those of its blocks, the mask's
    let span = (
        bl.first().map(|b| b.0).unwrap_or(0),
        bl.last().map(|b| b.1).unwrap_or(0),
    );
    let rows = sizing_rows(span, mask);
    let mut reference = cv_with(terms, &[], base, res, bl, mask);
    while chosen.len() < MAX_TERMS {
        let mut scored: Vec<(usize, Cv)> = (0..terms.len())
            .filter(|i| !chosen.contains(i))
            .map(|i| {
                let mut with = chosen.clone();
                with.push(i);
                (i, cv_with(terms, &with, base, res, bl, mask))
            })
            .collect();
        scored.sort_by(|x, y| x.1.rms.total_cmp(&y.1.rms));
        let first = base.len() + chosen.iter().map(|c| terms[*c].cols.len()).sum::<usize>();
        // the term that cuts most among those that count: its cut, in enough blocks, and its
        // contribution outside its own confidence interval (as an effect's size); else the
        // best one that does not count
        let cut_of = |i: usize, cv: &Cv| {
            let cut = 100.0 * (reference.rms - cv.rms) / reference.rms.max(1e-300);
            let wins = fold_wins(cv, &reference.fold_mse);
            let cols: Vec<&[f64]> = terms[i].cols.iter().map(|c| c.as_slice()).collect();
            let (size, se) = contribution_size(&cols, cv, first, &rows, false);
            (
                cut,
                cut >= min_pct && wins >= min_wins && size > CI_SIGMAS * se,
            )
        };
        if scored.is_empty() {
            break;
        }
        let k = scored
            .iter()
            .position(|(i, cv)| cut_of(*i, cv).1)
            .unwrap_or(0);
        let (i, cv) = scored.swap_remove(k);
        let (cut_pct, significant) = cut_of(i, &cv);
        out.push(TermCut {
            term: terms[i].id.clone(),
            words: terms[i].words.clone(),
            cut_pct,
            significant,
        });
        if !significant {
            break;
        }
        chosen.push(i);
        reference = cv;
    }
    out
}

fn cv_with(
    terms: &[Term],
    chosen: &[usize],
    base: &[&[f64]],
    res: &[f64],
    bl: &[(usize, usize)],
    mask: Option<&[f64]>,
) -> Cv {
    let extra: Vec<&[f64]> = chosen
        .iter()
        .flat_map(|i| terms[*i].cols.iter().map(|c| c.as_slice()))
        .collect();
    cv_cols_masked(base, &extra, res, bl, mask)
}

/// The generic peer: a sparse regression of the residual on the dictionary, as an
/// identification engineer would run pysindy's STLSQ.
#[derive(Debug, Clone)]
pub struct SparsePeer {
    /// The dictionary terms it keeps.
    pub terms: Vec<String>,
    /// The threshold it chose by cross-validation, as a share of the applied torque's spread.
    pub threshold: f64,
    /// Its equation error over the fit range: NRMSE of what remains against the applied torque,
    /// % (the workbench's own equation error, measured the same way).
    pub equation_nrmse_pct: f64,
}

/// Dictionary terms the peer does not regress on: the time is no term of the dictionary such
/// an engineer would build for an axis' torque (constant, sign and tanh of the velocity, |v|,
/// |v| v, sine and cosine of the position, a delayed torque); `diagnose` keeps it to say
/// when a residual drifts.
const PEER_LEAVES_OUT: [&str; 1] = ["time"];

/// Thresholds tried, as shares of the applied torque's standard deviation (a term whose
/// contribution is smaller than that is no finding: on a right model, all of them).
const THRESHOLDS: [f64; 7] = [0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1];

/// [`SparsePeer`] of residual `res` (applied torque `y_app`) on the dictionary `terms` alone:
/// least squares, then each column whose contribution's RMS is below the threshold times the
/// applied torque's spread is dropped and the rest refitted, ten times; the threshold with the
/// lowest blocked cross-validated error wins. Its velocity and acceleration terms are its refit
/// of a damping and an inertia, as an engineer's regression has them: one column each, not the
/// model's motor and load columns, whose difference a record that moves the two bodies together
/// does not determine (on a circle a free split of the two inertias fits the scale's noise, in
/// sample, to half the equation error of a right model).
pub fn sparse_peer(
    terms: &[Term],
    res: &[f64],
    y_app: &[f64],
    range: (usize, usize),
) -> SparsePeer {
    let (a, b) = range;
    let mut cols: Vec<&[f64]> = Vec::new();
    let mut owner: Vec<usize> = Vec::new();
    for (i, t) in terms
        .iter()
        .enumerate()
        .filter(|(_, t)| !PEER_LEAVES_OUT.contains(&t.id.as_str()))
    {
        for c in &t.cols {
            cols.push(c);
            owner.push(i);
        }
    }
    let scale: Vec<f64> = cols.iter().map(|c| rms(&c[a..b])).collect();
    let spread = super::signal::std_dev(&y_app[a..b]).max(1e-300);
    let bl = blocks(range, FOLDS);
    let all = normals(&cols, res, &blocks(range, 1)).remove(0);
    let folds = normals(&cols, res, &bl);
    // the columns kept at threshold `lam`
    let keep_at = |lam: f64| -> Vec<usize> {
        let mut keep: Vec<usize> = (0..cols.len()).collect();
        for _ in 0..10 {
            let th = all.select(&keep).solve();
            let next: Vec<usize> = keep
                .iter()
                .enumerate()
                .filter(|(k, i)| (th[*k] * scale[**i]).abs() >= lam * spread)
                .map(|(_, i)| *i)
                .collect();
            if next.len() == keep.len() {
                break;
            }
            keep = next;
        }
        keep
    };
    let (mut best_lam, mut best_cv) = (0.0, f64::INFINITY);
    for lam in THRESHOLDS {
        let keep = keep_at(lam);
        let sub: Vec<_> = folds.iter().map(|n| n.select(&keep)).collect();
        let cv = cross_validate(&sub).rms;
        if cv < best_cv * (1.0 - 1e-9) {
            (best_lam, best_cv) = (lam, cv);
        }
    }
    let keep = keep_at(best_lam);
    let th = all.select(&keep).solve();
    let mut after = res.to_vec();
    for (k, i) in keep.iter().enumerate() {
        for (x, c) in after.iter_mut().zip(cols[*i]) {
            *x -= th[k] * c;
        }
    }
    let mut names: Vec<String> = keep.iter().map(|i| terms[owner[*i]].id.clone()).collect();
    names.dedup();
    SparsePeer {
        terms: names,
        threshold: best_lam,
        equation_nrmse_pct: nrmse_pct(&y_app[a..b], &after[a..b]),
    }
}
