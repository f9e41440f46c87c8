//! `diagnose`: rank the candidate causes of the misfit.
//!
//! Candidates are every effect of the physics library plus a wrong value of each base
//! parameter. The residual is the recorded (applied) torque minus the torque the model needs for
//! the measured motion. Each candidate is refitted (linear least squares in its coefficients;
//! a 1-D grid search for its nonlinear parameter: Stribeck velocity, cogging period, mode
//! frequency, delay, lag, limit) and scored on data not used for the fit: blocked 5-fold
//! cross-validation, contiguous blocks, so neighbouring correlated samples never sit on both
//! sides. A base parameter is refitted alone. An effect is refitted together with all base
//! parameters; it is significant only when it lowers the cross-validated error beyond what a
//! base-parameter refit alone achieves, by at least 3 % of the model's error and in at least 4
//! of 5 blocks, so noise never earns an effect and a wrong parameter is not mistaken for one.
//! Scores are the cross-validated RMS reduction as a percentage of the model's RMS error: a
//! significant effect is credited with everything adding it achieves (it is what lets the base
//! parameters return to their true values), a non-significant one only with its extra.
//! `viscous_friction` has the damping parameter's column and is scored like it. Candidates whose fitted contributions are nearly
//! collinear (correlation above 0.95) cannot be told apart by the data and are reported together.
//! `backlash` and `pitch_error` are tested on the deflection (motor minus load position), which
//! needs both position columns.

use serde_json::{json, Value};

use super::beyond::{beyond_top, Top, TorqueFit};
use super::candidates::*;
use super::controller::ControllerChannel;
pub use super::controller_candidates::excitation_99_hz;
use super::controller_candidates::*;
use super::data::AxisData;
use super::dictionary::{self, SparsePeer, TermCut};
use super::effects::{Effect, EffectId, WbModel};
use super::gap_sizing::{score_floating_gap, WINDOW_SIZED};
use super::pair::name_hidden_pair;
use super::refit::{flat, inertias_now, Released};
use super::scoring::*;
pub use super::scoring::{
    material_cut, Candidate, CI_SIGMAS, DEFLECTION_FLOOR_M, MATERIAL_FRACTION, MIN_FOLD_WINS,
    MIN_REDUCTION_PCT,
};
use super::side::simulation_prefers;
use super::signal::autocorrelation;
use super::standstill::standstill_friction;
pub use super::verdict::Confirmed;
use super::verdict::*;
use super::words::evidence;

/// A diagnosis.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    /// Candidates sorted by error reduction (largest first).
    pub candidates: Vec<Candidate>,
    /// One-sentence verdict.
    pub verdict: String,
    /// Cross-validated RMS of the model's torque residual (nothing refitted).
    pub model_rms: f64,
    /// Cross-validated RMS after refitting the base parameters only.
    pub base_refit_rms: f64,
    /// Whether the residual after the base refit passed the whiteness test.
    pub whiteness_passed: bool,
    /// Effects that could not be tested on this trace, with the reason.
    pub untested: Vec<(String, String)>,
    /// The controller channel's figures (JSON), when the model has a controller law.
    pub controller: Option<Value>,
    /// What the torque residual follows beyond the base refit, from the dictionary of terms:
    /// the terms that count, then the best one that did not.
    pub residual_terms: Vec<TermCut>,
    /// The generic peer: a sparse regression of the residual on the same dictionary.
    pub sparse_peer: SparsePeer,
}

/// Options of [`diagnose`].
#[derive(Debug, Clone)]
pub struct DiagOptions {
    /// Effect ids to leave out (e.g. those already in the model are still tested).
    pub skip: Vec<String>,
    /// Length of the simulation windows of the fit that confirms a recommendation, s.
    pub window_s: f64,
    /// Trace columns (name, values at the axis' samples) added to the dictionary of terms the
    /// residual is described by (see [`super::dictionary`]), e.g. another joint's angle.
    pub extra_terms: Vec<(String, Vec<f64>)>,
}

impl Default for DiagOptions {
    fn default() -> Self {
        Self {
            skip: Vec::new(),
            window_s: 0.05,
            extra_terms: Vec::new(),
        }
    }
}

/// First candidates whose fit is tried before none is recommended (see [`confirm`]).
pub const MAX_CONFIRM: usize = 3;

/// Diagnoses `model` on `d` (which must carry torque), in named steps: the torque channel's
/// residual and its reference fits ([`TorqueChannel::new`]), a candidate per base parameter
/// ([`base_parameter_candidates`]), a candidate per effect of the library on the channel where
/// it shows ([`effect_candidates`]), forward selection beyond the first ([`condition_on_top`]),
/// candidates the data cannot tell apart ([`mark_indistinguishable`]), two candidates that hide
/// each other when none is significant alone (`pair::name_hidden_pair`), and the verdict with
/// the whiteness of what is left ([`residual_whiteness`], [`verdict`]).
pub fn diagnose(model: &WbModel, d: &AxisData, opts: &DiagOptions) -> Diagnosis {
    let rel = Released::of(model, d, None);
    let ch = TorqueChannel::new(model, d, &rel);
    let mut cands = base_parameter_candidates(model, d, &ch);
    let untested = effect_candidates(model, d, &ch, &mut cands);
    score_floating_gap(&mut cands, model, d, opts.window_s);
    standstill_friction(&mut cands, model, d, ch.mask.as_deref());
    let cc = ControllerChannel::new(model, d);
    if let Some(cc) = &cc {
        controller_candidates(model, d, cc, &mut cands);
    }
    refine_of_coulomb(&mut cands, ch.min_pct);
    note_immaterial(&mut cands, ch.min_pct);
    cands.sort_by(|x, y| y.error_reduction_pct.total_cmp(&x.error_reduction_pct));
    let now = inertias_now(model, &ch.free_keys);
    let tf = TorqueFit {
        min_pct: ch.min_pct,
        base_cols: &ch.base_cols,
        now: &now,
        res: &ch.res,
        bl: &ch.bl,
        mask: ch.mask.as_deref(),
    };
    let (mut cands, fitted, rejected) =
        select_and_confirm(cands, model, d, &tf, ch.e0, opts.window_s);
    let (white, ac) = residual_whiteness(d, &ch);
    // a misfit that is not noise, with no candidate significant alone: two that hide each
    // other (both named, or the leader alone; none whose fit was refused above)
    let refused: Vec<String> = rejected.iter().map(|(e, _)| e.clone()).collect();
    let fitted = match fitted {
        None if !white => {
            name_hidden_pair(&mut cands, &refused, model, d, &tf, ch.e0, opts.window_s)
        }
        f => f,
    };
    if let Some(e) = fitted.as_ref().and_then(|f| f.resized.clone()) {
        resize_candidate(&mut cands, e, d);
    }
    // the table reads top down: what is significant first, each part in the order of its cut
    // (a first candidate whose fit was refused no longer stands above the one named)
    cands.sort_by(|x, y| y.error_reduction_pct.total_cmp(&x.error_reduction_pct));
    cands.sort_by_key(|c| !c.significant);
    let (residual_terms, sparse_peer) = dictionary_of(model, d, &ch, &opts.extra_terms);
    let mut verdict = verdict(&cands, white, &ac, cc.as_ref(), d, fitted.as_ref());
    let follows: Vec<String> = residual_terms
        .iter()
        .filter(|t| t.significant)
        .map(|t| format!("{} (a cut of {:.1} %)", t.words, t.cut_pct))
        .collect();
    if !follows.is_empty() && !cands.iter().any(|c| c.significant) {
        verdict = format!(
            "{verdict}. What no effect of the library explains follows {}",
            follows.join(", then ")
        );
    }
    Diagnosis {
        candidates: cands,
        verdict,
        model_rms: ch.e0,
        base_refit_rms: ch.cvb.rms,
        whiteness_passed: white,
        untested,
        controller: cc.as_ref().map(|c| c.to_json(d)),
        residual_terms,
        sparse_peer,
    }
}

/// A torque-channel candidate that cuts the error by more than [`MIN_REDUCTION_PCT`] but less
/// than the channel's smallest cut that counts (the model's error already within
/// [`MATERIAL_FRACTION`] of the torque) says so: otherwise it would read as not significant with
/// no reason.
fn note_immaterial(cands: &mut [Candidate], min_pct: f64) {
    for c in cands.iter_mut().filter(|c| {
        c.channel == "torque"
            && !c.significant
            && c.error_reduction_pct >= MIN_REDUCTION_PCT
            && c.error_reduction_pct < min_pct
    }) {
        let counts = if min_pct > 100.0 {
            "no cut in the torque balance counts".to_string()
        } else {
            format!("a cut counts only from {min_pct:.0} % of it")
        };
        c.evidence = format!(
            "{}; the model's torque error is already below {} % of the recorded torque's RMS, so {counts}: not significant",
            c.evidence,
            100.0 * MATERIAL_FRACTION
        );
    }
}

/// The candidate whose effect its confirming fit sized on another channel takes that size:
/// what the verdict names is what `fit` writes.
fn resize_candidate(cands: &mut [Candidate], e: Effect, d: &AxisData) {
    let Some(c) = cands
        .iter_mut()
        .find(|c| c.add.iter().any(|a| a.id == e.id))
    else {
        return;
    };
    c.params = flat(&e.to_table(d.kind, d.r));
    c.evidence = match c.evidence.find(WINDOW_SIZED) {
        // scored on the windowed simulation already: the fit's size, the same account
        Some(at) => format!("{}{}", evidence(&e, d), &c.evidence[at..]),
        None => format!(
            "{}{WINDOW_SIZED} (the deflection's least squares: {})",
            evidence(&e, d),
            c.add
                .iter()
                .find(|a| a.id == e.id)
                .map(|a| evidence(a, d))
                .unwrap_or_default()
        ),
    };
    c.add = vec![e];
}

/// Candidates the data cannot tell apart (same channel, scores within 10 % of each other,
/// contributions correlated above 0.95) name each other in `same_as`, and share the class of
/// the first of them.
pub(super) fn mark_indistinguishable(cands: &mut [Candidate]) {
    for i in 0..cands.len() {
        let mut same = Vec::new();
        for j in 0..cands.len() {
            if i != j
                && cands[i].channel == cands[j].channel
                && cands[i].error_reduction_pct > 0.5
                && cands[j].error_reduction_pct > 0.5
                && (cands[i].error_reduction_pct - cands[j].error_reduction_pct).abs()
                    <= 0.1
                        * cands[i]
                            .error_reduction_pct
                            .abs()
                            .max(cands[j].error_reduction_pct.abs())
                && corr(&cands[i].contribution, &cands[j].contribution).abs() > 0.95
            {
                same.push(cands[j].effect.clone());
            }
        }
        for x in same {
            if !cands[i].same_as.contains(&x) {
                cands[i].same_as.push(x);
            }
        }
    }
    for i in 0..cands.len() {
        let cls = cands[i].class.clone();
        for other in cands[i].same_as.clone() {
            if let Some(j) = cands.iter().position(|c| c.effect == other) {
                if j > i && cands[j].class != cls {
                    cands[j].class = cls.clone();
                }
            }
        }
    }
}

/// Forward selection beyond the first candidate of `ranked`, whose recommendation is then
/// confirmed by its fit; a first candidate whose fit fails (or whose class-mate simulates the
/// record better) loses its significance and the selection is made again beyond the next one
/// (at most [`MAX_CONFIRM`] times). The candidates, the confirmed fit, and the candidates
/// passed over with why.
fn select_and_confirm(
    ranked: Vec<Candidate>,
    model: &WbModel,
    d: &AxisData,
    tf: &TorqueFit<'_>,
    e0: f64,
    window_s: f64,
) -> (Vec<Candidate>, Option<Confirmed>, Vec<(String, String)>) {
    let mut rejected: Vec<(String, String)> = Vec::new();
    let (cands, fitted) = loop {
        let mut cands = ranked.clone();
        for c in cands.iter_mut() {
            if let Some((_, why)) = rejected.iter().find(|(e, _)| *e == c.effect) {
                c.significant = false;
                c.evidence = format!("{}; {why}", c.evidence);
            }
        }
        condition_on_top(&mut cands, model, d, tf, e0);
        mark_indistinguishable(&mut cands);
        let top = cands
            .iter()
            .position(|c| c.significant && (c.is_param || !c.add.is_empty()));
        let Some(i) = top else { break (cands, None) };
        if rejected.len() + 1 < MAX_CONFIRM {
            if let Some(why) = classmate_simulates_better(&cands[i], &ranked, &rejected, model, d) {
                rejected.push((cands[i].effect.clone(), why));
                continue;
            }
        }
        match confirm(&cands[i], model, d, window_s) {
            Ok(f) => break (cands, Some(f)),
            Err(why) if rejected.len() + 1 < MAX_CONFIRM => {
                rejected.push((cands[i].effect.clone(), why));
            }
            Err(why) => {
                cands[i].significant = false;
                cands[i].evidence = format!("{}; {why}", cands[i].evidence);
                rejected.push((cands[i].effect.clone(), why));
                break (cands, None);
            }
        }
    };
    (cands, fitted, rejected)
}

/// A dead time and a first-order lag delay the applied torque alike, and on a smooth record
/// the torque balance cuts about as much with either. When the first candidate `top` is one of
/// them and the other (significant alone, not passed over before: `rejected`) cuts within
/// [`MIN_REDUCTION_PCT`] points of it alone (`ranked`), the one whose model simulates the
/// record better, window by window, is named: why `top` is passed over, or `None`. (On the
/// circle with a 5-cycle dead time, the lag cut 95.9 % and the dead time 95.2 %; the lag's
/// model simulated the record at 201.7 %, the dead time's at 124.8 %.)
fn classmate_simulates_better(
    top: &Candidate,
    ranked: &[Candidate],
    rejected: &[(String, String)],
    model: &WbModel,
    d: &AxisData,
) -> Option<String> {
    let delays = [EffectId::Delay.id(), EffectId::CurrentLag.id()];
    if !delays.contains(&top.effect.as_str()) || top.add.len() != 1 {
        return None;
    }
    let alone = ranked.iter().find(|c| c.effect == top.effect)?;
    let rival = ranked.iter().find(|c| {
        delays.contains(&c.effect.as_str())
            && c.effect != top.effect
            && c.significant
            && c.add.len() == 1
            && !rejected.iter().any(|(e, _)| *e == c.effect)
    })?;
    if rival.error_reduction_pct < alone.error_reduction_pct - MIN_REDUCTION_PCT {
        return None;
    }
    (simulation_prefers(&top.add[0], &rival.add[0], model, d) == Some(true)).then(|| {
        format!(
            "{} delays the torque as well (alone it cuts {:.1} %, this one {:.1} %) and the model with it simulates the record better, window by window: it is named instead",
            rival.effect, rival.error_reduction_pct, alone.error_reduction_pct
        )
    })
}

/// The residual's description by the dictionary and the sparse peer on it, on at most 200,000
/// evenly spread samples (a long trace is thinned: the terms are smooth or held).
pub(super) fn dictionary_of(
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
    extra: &[(String, Vec<f64>)],
) -> (Vec<TermCut>, SparsePeer) {
    let step = d.len().div_ceil(200_000).max(1);
    let run = |d: &AxisData, ch: &TorqueChannel<'_>, extra: &[(String, Vec<f64>)]| {
        let needed: Vec<f64> = ch.y_app.iter().zip(&ch.res).map(|(a, r)| a - r).collect();
        let terms = dictionary::terms(d, &needed, extra);
        let cuts = dictionary::explain(
            &terms,
            &ch.base_cols,
            &ch.res,
            &ch.bl,
            ch.mask.as_deref(),
            ch.min_pct,
            MIN_FOLD_WINS,
        );
        let peer = dictionary::sparse_peer(&terms, &ch.res, &ch.y_app, d.range);
        (cuts, peer)
    };
    if step == 1 {
        return run(d, ch, extra);
    }
    let dd = d.decimated(step);
    let rel = Released::of(model, &dd, None);
    let chd = TorqueChannel::new(model, &dd, &rel);
    let thin: Vec<(String, Vec<f64>)> = extra
        .iter()
        .map(|(n, c)| (n.clone(), c.iter().step_by(step).copied().collect()))
        .collect();
    run(&dd, &chd, &thin)
}

/// Whiteness of the torque residual after the base refit: whether at most one of its first 20
/// autocorrelation lags lies outside the 99 % band, and the lags. The residual is decimated to
/// the filter's correlation length first, so that filtering alone does not colour it.
pub(super) fn residual_whiteness(d: &AxisData, ch: &TorqueChannel<'_>) -> (bool, Vec<f64>) {
    let (a, b) = d.range;
    let mut rb = ch.res.clone();
    for (k, c) in ch.base_cols.iter().enumerate() {
        let th = ch.cvb.theta.get(k).copied().unwrap_or(0.0);
        for (x, v) in rb.iter_mut().zip(c.iter()) {
            *x -= th * v;
        }
    }
    let corr_len = (2.0 / (d.cutoff_hz * d.dt)).ceil() as usize;
    let step = ((b - a) / 20000).max(corr_len).max(1);
    let rb_d: Vec<f64> = rb[a..b].iter().step_by(step).copied().collect();
    let ac = autocorrelation(&rb_d, 20);
    let bound = 2.58 / (rb_d.len() as f64).sqrt();
    let white = ac.iter().filter(|x| x.abs() > bound).count() <= 1;
    (white, ac)
}

/// Forward selection: once the first candidate (an effect on the torque channel) is
/// significant, every other torque-channel effect must earn its significance beyond it: it is
/// refitted together with the base parameters and the first candidate, and keeps its
/// significance only if it lowers the cross-validated error further by [`MIN_REDUCTION_PCT`] in
/// [`MIN_FOLD_WINS`] blocks. A candidate that only re-explains part of the first one's misfit
/// (a clamp of the torque where friction steps, an offset the first one already carries) is
/// credited with its extra only; when the first candidate already includes its effect, it is
/// reported in the first one's class.
pub(super) fn condition_on_top(
    cands: &mut [Candidate],
    model: &WbModel,
    d: &AxisData,
    tf: &TorqueFit<'_>,
    e0: f64,
) {
    // the first significant candidate (one ranked above it lost its significance when its fit
    // failed and stays as it is)
    let Some(ti) = cands.iter().position(|c| c.significant) else {
        return;
    };
    let top = &cands[ti];
    if top.is_param || top.channel != "torque" {
        return;
    }
    let top = Top::of(top);
    let others: Vec<usize> = (ti + 1..cands.len())
        .filter(|i| {
            let c = &cands[*i];
            !c.is_param && c.channel == "torque" && !c.add.is_empty()
        })
        .collect();
    let refs: Vec<&Candidate> = others.iter().map(|i| &cands[*i]).collect();
    let results = beyond_top(&top, &refs, model, d, tf, e0);
    let mut included = Vec::new();
    for (i, r) in others.into_iter().zip(results) {
        if let Some(e) = top.judge(&mut cands[i], r.earns(), r.extra, r.rescored, d) {
            included.push(e);
        }
    }
    cands[ti].same_as.extend(included);
    cands.sort_by(|x, y| y.error_reduction_pct.total_cmp(&x.error_reduction_pct));
}

impl Diagnosis {
    /// The JSON printed by `diagnose --json`.
    pub fn to_json(&self) -> Value {
        let cands: Vec<Value> = self
            .candidates
            .iter()
            .map(|c| {
                json!({
                    "effect": c.effect,
                    "kind": if c.is_param { "parameter" } else { "effect" },
                    "class": c.class,
                    "significant": c.significant,
                    "error_reduction_pct": (c.error_reduction_pct * 100.0).round() / 100.0,
                    "params": c.params,
                    "evidence": c.evidence,
                    "same_class_as": c.same_as,
                    "channel": c.channel,
                })
            })
            .collect();
        json!({
            "candidates": cands,
            "verdict": self.verdict,
            "model_cv_rms": self.model_rms,
            "base_refit_cv_rms": self.base_refit_rms,
            "whiteness_passed": self.whiteness_passed,
            "controller": self.controller,
            "untested": self.untested.iter().map(|(k, r)| json!({"effect": k, "reason": r})).collect::<Vec<_>>(),
            "residual_terms": self.residual_terms.iter().map(|t| json!({
                "term": t.term,
                "follows": t.words,
                "cut_pct": (t.cut_pct * 100.0).round() / 100.0,
                "significant": t.significant,
            })).collect::<Vec<_>>(),
            "sparse_peer": {
                "terms": self.sparse_peer.terms,
                "threshold": self.sparse_peer.threshold,
                "equation_nrmse_pct": self.sparse_peer.equation_nrmse_pct,
            },
        })
    }
}
