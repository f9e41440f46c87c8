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

use std::collections::BTreeMap;

use serde_json::{json, Value};

use super::base::BaseParam;
use super::controller::{at_limit, ControllerChannel};
use super::data::AxisData;
use super::dictionary::{self, SparsePeer, TermCut};
use super::effects::{
    channel, class_of, constant_force_value, constant_force_words, evidence, fmt, reversals,
    round_sig, Channel, Effect, EffectId, Side, WbModel,
};
use super::fit::{fit, fit_with, FitResult};
use super::lsq::{blocks, Cv};
use super::refit::{
    backlash_hyper, best_effect, cv_cols, cv_cols_masked, default_side, deflection, flat,
    held_words, inertias_now, moving_mask, Refit, Released, Untestable, FOLDS,
};
use super::signal::{autocorrelation, mean, quantile, rms};
use feedloop_model::model::AxisKind;
use feedloop_model::units::sig;

/// Smallest cross-validated error reduction that counts, % of the model's error.
pub const MIN_REDUCTION_PCT: f64 = 3.0;
/// Whether a fit that takes its channel's error from `before` to `after` (%) cuts it
/// materially: by at least [`MIN_REDUCTION_PCT`] % of it (a step that moves the error in its
/// second decimal is no finding, whatever its cross-validated score).
pub fn material_cut(before: f64, after: f64) -> bool {
    after < before * (1.0 - MIN_REDUCTION_PCT / 100.0)
}

/// Blocks (of [`FOLDS`]) in which a significant candidate must lower the error.
pub const MIN_FOLD_WINS: usize = 4;
/// Smallest error reduction that counts on the torque channel, as a fraction of the applied
/// torque's RMS (0.1 %: below it, a change of the model changes nothing a servo engineer sees,
/// and on an exact or noise-free record the remaining misfit is the numerics of the
/// derivatives, which a parameter refit can always shave).
pub const MATERIAL_FRACTION: f64 = 1e-3;

/// Smallest deflection effect that counts, m at the load (the finest linear scales of feed
/// drives resolve about 1 nm).
pub const DEFLECTION_FLOOR_M: f64 = 1e-9;

/// Motor units per metre at the load (the ball screw's `r`), 1 for other kinds (whose deflection
/// is already in their own units).
fn load_to_motor(d: &AxisData) -> f64 {
    if d.kind == AxisKind::BallScrew {
        d.r
    } else {
        1.0
    }
}

pub use super::lsq::CI_SIGMAS;

/// One candidate cause.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// Effect id, or a base-parameter key.
    pub effect: String,
    /// Whether it is a base parameter (not an effect).
    pub is_param: bool,
    /// Identifiability class.
    pub class: String,
    /// Significant under cross-validation.
    pub significant: bool,
    /// Cross-validated RMS reduction, % of the model's error (within -100 .. 100: a candidate
    /// that raises the error more than doubles it is shown at -100).
    pub error_reduction_pct: f64,
    /// Fitted parameters (model-file keys).
    pub params: BTreeMap<String, f64>,
    /// One sentence of evidence.
    pub evidence: String,
    /// Other candidates the data cannot tell apart from this one.
    pub same_as: Vec<String>,
    /// Effects to add when accepting it (with fitted nonlinear parameters).
    pub add: Vec<Effect>,
    /// Fitted contribution (for the collinearity check), decimated.
    contribution: Vec<f64>,
    /// Channel it was scored on.
    pub channel: &'static str,
}

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

fn corr(a: &[f64], b: &[f64]) -> f64 {
    let (ma, mb) = (mean(a), mean(b));
    let mut sab = 0.0;
    let mut saa = 0.0;
    let mut sbb = 0.0;
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa <= 0.0 || sbb <= 0.0 {
        return 0.0;
    }
    sab / (saa * sbb).sqrt()
}

fn fold_wins(a: &Cv, reference: &[f64]) -> usize {
    a.fold_mse
        .iter()
        .zip(reference)
        .filter(|(x, r)| **x < **r * 0.999)
        .count()
}

fn decimate(x: &[f64], a: usize, b: usize) -> Vec<f64> {
    let step = ((b - a) / 20000).max(1);
    x[a..b].iter().step_by(step).copied().collect()
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
/// candidates the data cannot tell apart ([`mark_indistinguishable`]), and the verdict with the
/// whiteness of what is left ([`residual_whiteness`], [`verdict`]).
pub fn diagnose(model: &WbModel, d: &AxisData, opts: &DiagOptions) -> Diagnosis {
    let rel = Released::of(model, d, None);
    let ch = TorqueChannel::new(model, d, &rel);
    let mut cands = base_parameter_candidates(model, d, &ch);
    let untested = effect_candidates(model, d, &ch, &mut cands);
    let cc = ControllerChannel::new(model, d);
    if let Some(cc) = &cc {
        controller_candidates(model, d, cc, &mut cands);
    }
    refine_of_coulomb(&mut cands, ch.min_pct);
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
    // forward selection beyond the first candidate, whose recommendation is then confirmed by
    // its fit; a first candidate whose fit fails loses its significance and the selection is
    // made again beyond the next one (at most MAX_CONFIRM times)
    let ranked = cands;
    let mut rejected: Vec<(String, String)> = Vec::new();
    let (cands, fitted) = loop {
        let mut cands = ranked.clone();
        for c in cands.iter_mut() {
            if let Some((_, why)) = rejected.iter().find(|(e, _)| *e == c.effect) {
                c.significant = false;
                c.evidence = format!("{}; {why}", c.evidence);
            }
        }
        condition_on_top(&mut cands, model, d, &tf, ch.e0);
        mark_indistinguishable(&mut cands);
        let top = cands
            .iter()
            .position(|c| c.significant && (c.is_param || !c.add.is_empty()));
        let Some(i) = top else { break (cands, None) };
        match confirm(&cands[i], model, d, opts.window_s) {
            Ok(f) => break (cands, Some(f)),
            Err(why) if rejected.len() + 1 < MAX_CONFIRM => {
                rejected.push((cands[i].effect.clone(), why));
            }
            Err(why) => {
                cands[i].significant = false;
                cands[i].evidence = format!("{}; {why}", cands[i].evidence);
                break (cands, None);
            }
        }
    };
    let (white, ac) = residual_whiteness(d, &ch);
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

/// The torque channel of a diagnosis: the residual (applied minus needed torque), the base
/// parameters that may be refitted with their columns, the cross-validation blocks and rows,
/// and the two reference fits every candidate is scored against.
struct TorqueChannel<'d> {
    /// Recorded torque as applied to the axis (delay, lag, limit of the model included).
    y_app: Vec<f64>,
    /// Applied minus needed torque.
    res: Vec<f64>,
    /// Cross-validation blocks.
    bl: Vec<(usize, usize)>,
    /// Base-parameter keys that can be refitted on this trace.
    free_keys: Vec<BaseParam>,
    /// Their regressor columns, then those of the model's own effects (see [`Released`]).
    base_cols: Vec<&'d [f64]>,
    /// The name of each of `base_cols`' parameters.
    names: Vec<String>,
    /// Rows that carry information (see [`moving_mask`]).
    mask: Option<Vec<f64>>,
    /// Cross-validation of the residual with nothing refitted.
    cv0: Cv,
    /// Its RMS (the model's error), never 0.
    e0: f64,
    /// Cross-validation with every base parameter refitted.
    cvb: Cv,
    /// Smallest reduction that counts on this channel, % of the model's error:
    /// [`MIN_REDUCTION_PCT`], or [`MATERIAL_FRACTION`] of the applied torque's RMS when that is
    /// more (a model whose error is already far below the torque has nothing left to name).
    min_pct: f64,
}

impl<'d> TorqueChannel<'d> {
    fn new(model: &WbModel, d: &'d AxisData, rel: &'d Released) -> Self {
        assert!(
            d.torque.is_some(),
            "diagnose needs the torque column (checked by the caller)"
        );
        let y_app = model.applied(d).expect("checked above");
        let needed = model.torque_needed(d);
        let res: Vec<f64> = y_app.iter().zip(&needed).map(|(a, b)| a - b).collect();
        let bl = blocks(d.range, FOLDS);
        // with one position column, motor and load columns coincide: keep one of each pair
        let free_keys: Vec<BaseParam> = BaseParam::of_kind(d.kind)
            .iter()
            .copied()
            .filter(|k| d.has_motor() || !k.on_load())
            .collect();
        let mut base_cols: Vec<&[f64]> = free_keys.iter().map(|k| k.column(d)).collect();
        base_cols.extend(rel.cols.iter().map(|c| c.as_slice()));
        let mut names: Vec<String> = free_keys.iter().map(|k| k.key().to_string()).collect();
        names.extend(rel.names(model));
        let mask = moving_mask(d);
        let cv0 = cv_cols_masked(&[], &[], &res, &bl, mask.as_deref());
        let e0 = cv0.rms.max(1e-300);
        let cvb = cv_cols_masked(&base_cols, &[], &res, &bl, mask.as_deref());
        let (a, b) = d.range;
        let material = MATERIAL_FRACTION * rms(&y_app[a..b]);
        let min_pct = MIN_REDUCTION_PCT.max(100.0 * material / e0);
        Self {
            min_pct,
            y_app,
            res,
            bl,
            free_keys,
            base_cols,
            names,
            mask,
            cv0,
            e0,
            cvb,
        }
    }
}

impl TorqueChannel<'_> {
    /// A candidate's cut beyond the base refit (the model with every parameter it has refitted,
    /// cross-validated), % of the larger of the model's error and that refit's: a refit that
    /// generalises worse than the model as it stands (its values fitted on this very record)
    /// credits no candidate with more than the whole error.
    fn cut_pct(&self, cv: &Cv) -> f64 {
        100.0 * (self.cvb.rms - cv.rms) / self.e0.max(self.cvb.rms)
    }
}

/// One candidate per base parameter, refitted alone.
fn base_parameter_candidates(
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
) -> Vec<Candidate> {
    let (a, b) = d.range;
    let mut cands = Vec::new();
    for k in &ch.free_keys {
        let col = k.column(d);
        let cv = cv_cols_masked(&[col], &[], &ch.res, &ch.bl, ch.mask.as_deref());
        let red = 100.0 * (ch.e0 - cv.rms) / ch.e0;
        let wins = fold_wins(&cv, &ch.cv0.fold_mse);
        let delta = cv.theta[0];
        let old = model.base_value(*k);
        let mut params = BTreeMap::new();
        params.insert(k.to_string(), old + delta);
        let contribution: Vec<f64> = decimate(col, a, b).iter().map(|x| x * delta).collect();
        // a change inside its own confidence interval is not a wrong value
        let se = cv.theta_se[0];
        let outside = delta.abs() > CI_SIGMAS * se;
        cands.push(Candidate {
            effect: k.to_string(),
            is_param: true,
            class: k.class().id().to_string(),
            significant: red >= ch.min_pct && wins >= MIN_FOLD_WINS && outside,
            error_reduction_pct: red.clamp(-100.0, 100.0),
            evidence: format!(
                "refitting {k} alone moves it from {} to {} ({:+.1} %, +-{} at {CI_SIGMAS} standard errors{})",
                fmt(old),
                fmt(old + delta),
                if old != 0.0 {
                    100.0 * delta / old
                } else {
                    f64::INFINITY
                },
                fmt(CI_SIGMAS * se),
                if outside { "" } else { ": inside its interval, not significant" }
            ),
            params,
            same_as: vec![],
            add: vec![],
            contribution,
            channel: "torque",
        });
    }
    cands
}

/// One candidate per effect of the library, each on the channel where it shows: the
/// deflection for `backlash` and `pitch_error`, the torque for the others. Returns the effects
/// that could not be tested on this trace, with the reason.
fn effect_candidates(
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
    cands: &mut Vec<Candidate>,
) -> Vec<(String, String)> {
    let kind = d.kind;
    let defl = deflection(model, d);
    let mut untested = Vec::new();
    for effect in EffectId::ALL {
        let id = effect;
        if !effect.repeatable() && model.effects.iter().any(|e| e.id == id) {
            untested.push((
                id.to_string(),
                "already in the model (it is not repeatable; refit it with `fit`)".to_string(),
            ));
            continue;
        }
        if id == EffectId::Unbalance && kind != AxisKind::Rotary {
            untested.push((
                id.to_string(),
                "rotary axes only (a load torque of the load angle; on a linear axis gravity is a constant_force)".to_string(),
            ));
            continue;
        }
        if channel(id) == Channel::Deflection {
            if kind == AxisKind::Rigid {
                untested.push((id.to_string(), "not defined on a rigid axis".to_string()));
                continue;
            }
            if kind == AxisKind::Rotary && id == EffectId::PitchError {
                untested.push((id.to_string(), "ball-screw axes only".to_string()));
                continue;
            }
            let Some((rd, dcols)) = &defl else {
                untested.push((
                    id.to_string(),
                    format!("needs both `{0}.motor` and `{0}.load` (it shows in the deflection between them)", d.axis),
                ));
                continue;
            };
            keep(
                deflection_candidate(id, model, d, rd, dcols, &ch.bl),
                id,
                cands,
                &mut untested,
            );
            continue;
        }
        if id == EffectId::ViscousFriction {
            cands.push(viscous_candidate(d, ch));
            continue;
        }
        if id == EffectId::ThirdMass {
            keep(mode_candidate(model, d, ch), id, cands, &mut untested);
            continue;
        }
        keep(
            torque_effect_candidate(id, model, d, ch),
            id,
            cands,
            &mut untested,
        );
    }
    untested
}

/// `directional_friction` is Coulomb friction with levels and slopes of their own in each
/// direction: it is credited only with what it lowers the error by beyond `coulomb_friction`
/// (with its offset), and is significant only when that is material, so the simpler law is named
/// unless the data ask for the richer one.
fn refine_of_coulomb(cands: &mut [Candidate], min_pct: f64) {
    let Some(coulomb) = cands
        .iter()
        .find(|c| c.effect == EffectId::CoulombFriction.id())
        .map(|c| c.error_reduction_pct)
    else {
        return;
    };
    for c in cands
        .iter_mut()
        .filter(|c| c.effect == EffectId::DirectionalFriction.id())
    {
        let extra = c.error_reduction_pct - coulomb;
        c.error_reduction_pct = extra;
        if extra < min_pct {
            c.significant = false;
        }
        c.evidence = format!(
            "{}; beyond coulomb_friction it lowers the cross-validated error by {extra:.1} %{}",
            c.evidence,
            if extra < min_pct {
                " (not significant)"
            } else {
                ""
            }
        );
    }
}

/// A candidate goes to the list, or its effect to `untested` with the reason it could not be
/// refitted: no effect disappears from a diagnosis.
fn keep(
    c: Result<Candidate, Untestable>,
    id: EffectId,
    cands: &mut Vec<Candidate>,
    untested: &mut Vec<(String, String)>,
) {
    match c {
        Ok(c) => cands.push(c),
        Err(why) => untested.push((id.to_string(), why)),
    }
}

/// `backlash` or `pitch_error` scored on the deflection channel (residual `rd`, base columns
/// `dcols`: compliance and zero offset).
fn deflection_candidate(
    id: EffectId,
    model: &WbModel,
    d: &AxisData,
    rd: &[f64],
    dcols: &[Vec<f64>],
    bl: &[(usize, usize)],
) -> Result<Candidate, Untestable> {
    let (a, b) = d.range;
    let kind = d.kind;
    // backlash says where the deflection is only while a flank transmits torque:
    // inside the gap (the transmitted torque within its dead band) the samples are
    // left out of its score (zero weight in the residual and every column)
    let mask: Option<Vec<f64>> = (id == EffectId::Backlash)
        .then(|| backlash_hyper(model, d))
        .flatten()
        .map(|h| {
            Effect::new(id, default_side(kind), h).columns(d)[0]
                .iter()
                .map(|x| x.abs())
                .collect()
        });
    let masked = |x: &[f64]| -> Vec<f64> {
        match &mask {
            Some(m) => x.iter().zip(m).map(|(v, w)| v * w).collect(),
            None => x.to_vec(),
        }
    };
    let rd = &masked(rd);
    let dcols: Vec<Vec<f64>> = dcols.iter().map(|c| masked(c)).collect();
    let dref: Vec<&[f64]> = dcols.iter().map(|c| c.as_slice()).collect();
    let dbase = cv_cols(&dref, &[], rd, bl);
    let Refit {
        effect: e,
        cv,
        doubtful,
        ..
    } = best_effect(id, model, d, &dref, &[], rd, bl, None)?;
    // % of the deflection's misfit after its base refit (compliance, zero offset)
    let red = 100.0 * (dbase.rms - cv.rms) / dbase.rms.max(1e-300);
    let wins = fold_wins(&cv, &dbase.fold_mse);
    // a deflection effect smaller than any feed-drive encoder resolves (1 nm at the load) is
    // numerical noise, however much of a residual at that level it explains
    let resolvable = rms(&e.contribution(d)[a..b]) >= DEFLECTION_FLOOR_M * load_to_motor(d);
    let params = flat(&e.to_table(kind, d.r));
    let contribution = decimate(&e.contribution(d), a, b);
    let mut ev = if resolvable {
        evidence(&e, d)
    } else {
        format!(
            "{}; below the 1 nm any feed-drive encoder resolves: not significant",
            evidence(&e, d)
        )
    };
    if let Some(why) = &doubtful {
        ev = format!("{ev}; {why}: doubtful, not significant");
    }
    Ok(Candidate {
        effect: id.to_string(),
        is_param: false,
        class: class_of(id).into(),
        significant: red >= MIN_REDUCTION_PCT
            && wins >= MIN_FOLD_WINS
            && resolvable
            && doubtful.is_none(),
        error_reduction_pct: red.clamp(-100.0, 100.0),
        evidence: ev,
        params,
        same_as: vec![],
        add: vec![e],
        contribution,
        channel: "deflection",
    })
}

/// `viscous_friction`: the same column as the damping parameter, scored the same way, one class.
fn viscous_candidate(d: &AxisData, ch: &TorqueChannel<'_>) -> Candidate {
    let (a, b) = d.range;
    let id = EffectId::ViscousFriction;
    let e = Effect::new(id, default_side(d.kind), vec![]);
    let cols = e.columns(d);
    let cv = cv_cols_masked(&[], &[&cols[0]], &ch.res, &ch.bl, ch.mask.as_deref());
    let mut e = e;
    e.coef = vec![cv.theta[0]];
    let red = 100.0 * (ch.e0 - cv.rms) / ch.e0;
    let wins = fold_wins(&cv, &ch.cv0.fold_mse);
    let params = flat(&e.to_table(d.kind, d.r));
    Candidate {
        effect: id.to_string(),
        is_param: false,
        class: "damping".into(),
        significant: red >= ch.min_pct && wins >= MIN_FOLD_WINS,
        error_reduction_pct: red.clamp(-100.0, 100.0),
        evidence: evidence(&e, d),
        params,
        same_as: vec![],
        contribution: decimate(&e.contribution(d), a, b),
        add: vec![e],
        channel: "torque",
    }
}

/// `third_mass`, searched where a mode shows: a structural mode of 50 to 150 Hz rings above
/// the 100 Hz the torque channel keeps, and below it a mass that follows the table is the same
/// as more load inertia. When the sampling allows a wider band than the channel's, the mode is
/// searched and judged on the data filtered at a tenth of the sampling rate (at most 1 kHz):
/// it must lower that band's cross-validated error beyond a refit of every base parameter by
/// the usual margin, and be a resonance (damping ratio below 0.3). A mode found there is then
/// fitted on the torque channel with the
/// frequency and damping found in the wide band, and credited with everything it achieves
/// there. Without a wider band it is an ordinary torque-channel candidate.
fn mode_candidate(
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
) -> Result<Candidate, Untestable> {
    let id = EffectId::ThirdMass;
    let wide_hz = (0.1 / d.dt).min(1000.0);
    if wide_hz < 1.5 * d.cutoff_hz {
        return torque_effect_candidate(id, model, d, ch);
    }
    let dw = d.with_cutoff(wide_hz);
    let relw = Released::of(model, &dw, None);
    let chw = TorqueChannel::new(model, &dw, &relw);
    let wide = torque_effect_candidate(id, model, &dw, &chw)?;
    // a structure's mode is a resonance: lightly damped (a damping ratio of 0.3 or more is a
    // broad-band correction of the high frequencies, not a peak the spectrum shows)
    let resonant = wide.add[0].hyper.get(1).is_some_and(|z| *z < 0.3);
    if !wide.significant || !resonant {
        // not a mode in the wide band: the narrow candidate may still say something, but it
        // cannot be significant
        return torque_effect_candidate(id, model, d, ch).map(|mut c| {
            if c.significant {
                c.significant = false;
                c.evidence = format!(
                    "{}; in the band up to {} Hz it {} (not significant)",
                    c.evidence,
                    fmt(wide_hz),
                    if resonant {
                        format!(
                            "lowers the error by only {:.1} % beyond a base refit",
                            wide.error_reduction_pct
                        )
                    } else {
                        "is no resonance (damping ratio 0.3 or more)".to_string()
                    }
                );
            }
            c
        });
    }
    // the mode of the wide band, its coefficient refitted on the torque channel
    let e = wide.add[0].clone();
    let cols = e.columns(d);
    let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let cv = cv_cols_masked(&ch.base_cols, &refs, &ch.res, &ch.bl, ch.mask.as_deref());
    let nb = ch.base_cols.len();
    let mut e = e;
    e.coef = vec![cv.theta.get(nb).copied().unwrap_or(0.0)];
    let params = flat(&e.to_table(d.kind, d.r));
    let (a, b) = d.range;
    let red = (100.0 * (ch.e0 - cv.rms) / ch.e0).max(ch.cut_pct(&cv));
    Ok(Candidate {
        effect: id.to_string(),
        is_param: false,
        class: class_of(id).into(),
        significant: true,
        // a mode that the data single out ranks before the inertia refit it also explains
        error_reduction_pct: red.clamp(-100.0, 100.0),
        evidence: format!(
            "{}; in the band up to {} Hz it lowers the error by {:.1} % beyond a refit of the base parameters",
            evidence(&e, d),
            fmt(wide_hz),
            wide.error_reduction_pct
        ),
        params,
        same_as: vec![],
        contribution: decimate(&e.contribution(d), a, b),
        add: vec![e],
        channel: "torque",
    })
}

/// An effect of the torque channel, refitted together with every base parameter. It is
/// credited with all it achieves (with the base refit) when it is significant beyond a base
/// refit, else only with what it adds to the base refit. An effect that contains one the model
/// has (directional or Stribeck friction and a Coulomb friction) replaces it: it is refitted on
/// the model without it and scored against the model with it, refitted.
fn torque_effect_candidate(
    id: EffectId,
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
) -> Result<Candidate, Untestable> {
    let Some(old) = id
        .supersedes()
        .filter(|s| model.effects.iter().any(|e| e.id == *s))
    else {
        return scored_candidate(id, model, d, ch, ch);
    };
    let mut reduced = model.clone();
    reduced.effects.retain(|e| e.id != old);
    let rel = Released::of(&reduced, d, None);
    let ch_r = TorqueChannel::new(&reduced, d, &rel);
    scored_candidate(id, &reduced, d, &ch_r, ch).map(|mut c| {
        c.evidence = format!("{}; it replaces the model's {old}", c.evidence);
        c
    })
}

/// [`torque_effect_candidate`] refitted on channel `ch` (of `model`) and scored against
/// `reference` (the channel of the model it would change).
fn scored_candidate(
    id: EffectId,
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
    reference: &TorqueChannel<'_>,
) -> Result<Candidate, Untestable> {
    let (a, b) = d.range;
    let mk = ch.mask.as_deref();
    let now = inertias_now(model, &ch.free_keys);
    let Refit {
        effect: e,
        cv,
        held,
        doubtful,
    } = best_effect(id, model, d, &ch.base_cols, &now, &ch.res, &ch.bl, mk)?;
    let mut add = vec![e.clone()];
    let mut cv = cv;
    let mut params = flat(&e.to_table(d.kind, d.r));
    let mut ev = evidence(&e, d);
    if !held.is_empty() {
        ev = format!("{ev}; {}", held_words(&held, &ch.names));
    }
    if id == EffectId::CoulombFriction {
        if let Some(with_offset) = coulomb_with_offset(&e, &cv, d, ch) {
            (add, cv, params, ev) = with_offset;
        }
    }
    let extra = reference.cut_pct(&cv);
    let wins = fold_wins(&cv, &reference.cvb.fold_mse);
    let mut significant = extra >= reference.min_pct && wins >= MIN_FOLD_WINS;
    if extra >= reference.min_pct && wins < MIN_FOLD_WINS {
        ev = format!(
            "{ev}; it lowers the cross-validated error in only {wins} of the record's {FOLDS} blocks ({MIN_FOLD_WINS} needed): not significant"
        );
    }
    let mut extra = extra;
    // its leading coefficient must lie outside its own confidence interval around zero
    let nb = ch.base_cols.len();
    if channel(id) == Channel::Torque && cv.theta.len() > nb {
        let (c, se) = (cv.theta[nb], cv.theta_se[nb]);
        if c.abs() <= CI_SIGMAS * se {
            significant = false;
            ev = format!("{ev}; its size is inside its own confidence interval (+-{} at {CI_SIGMAS} standard errors): not significant", fmt(CI_SIGMAS * se));
        }
    }
    if significant && id == EffectId::CoulombFriction && add.len() > 1 {
        // Coulomb friction is a step at reversals: it must earn its sign column beyond a
        // constant force, or the constant force alone is the name (gravity on an inclined axis)
        let one = vec![1.0; d.len()];
        let cv_off = cv_cols_masked(&ch.base_cols, &[&one], &ch.res, &ch.bl, mk);
        let beyond = 100.0 * (cv_off.rms - cv.rms) / ch.e0;
        if beyond < ch.min_pct || fold_wins(&cv, &cv_off.fold_mse) < MIN_FOLD_WINS {
            significant = false;
            extra = beyond;
            ev = format!(
                "{ev}; beyond a constant force it lowers the cross-validated error by only {beyond:.1} %: there is no friction step at the reversals"
            );
        }
    }
    if let Some(why) = &doubtful {
        significant = false;
        ev = format!("{ev}; {why}: doubtful, not significant");
    }
    let red = if significant {
        (100.0 * (reference.e0 - cv.rms) / reference.e0).max(extra)
    } else {
        extra
    };
    let contribution = contribution_of(&add, model, d, ch);
    // a friction law needs reversals to be told from an offset and a slope: say so where that
    // is why it is not named
    let turns = reversals(d);
    if !significant && class_of(id) == "friction" && turns < 2 {
        ev = format!(
            "{ev}; too few reversals to judge friction ({turns} in this record): record moves in both directions"
        );
    }
    Ok(Candidate {
        effect: id.to_string(),
        is_param: false,
        class: class_of(id).into(),
        significant,
        error_reduction_pct: red.clamp(-100.0, 100.0),
        evidence: ev,
        params,
        same_as: vec![],
        add,
        contribution: decimate(&contribution, a, b),
        channel: "torque",
    })
}

/// What the effects `add` change in the torque balance of `model` on `d`: their contribution to
/// the torque needed, or the change of the applied torque for a torque-path effect.
fn contribution_of(
    add: &[Effect],
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
) -> Vec<f64> {
    let mut contribution = vec![0.0; d.len()];
    for e in add {
        if channel(e.id) == Channel::TorquePath {
            let mut with = model.clone();
            with.effects.push(e.clone());
            let t = with.applied(d).unwrap_or_else(|| ch.y_app.clone());
            for (c, (x, z)) in contribution.iter_mut().zip(t.iter().zip(&ch.y_app)) {
                *c += x - z;
            }
        } else {
            for (c, x) in contribution.iter_mut().zip(e.contribution(d)) {
                *c += x;
            }
        }
    }
    contribution
}

/// What [`coulomb_with_offset`] returns: the effects to add, their cross-validation, the
/// fitted parameters and the evidence sentence.
type WithOffset = (Vec<Effect>, Cv, BTreeMap<String, f64>, String);

/// Asymmetric Coulomb friction = Coulomb + a constant force while the axis moves: fitted
/// together and reported both, when that fits at least as well (within 2 %) as Coulomb alone
/// and the offset lies outside its confidence interval around zero.
fn coulomb_with_offset(
    e: &Effect,
    cv: &Cv,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
) -> Option<WithOffset> {
    let kind = d.kind;
    let cols = e.columns(d);
    let one = vec![1.0; d.len()];
    let cv2 = cv_cols_masked(
        &ch.base_cols,
        &[&cols[0], &one],
        &ch.res,
        &ch.bl,
        ch.mask.as_deref(),
    );
    let nb = ch.base_cols.len();
    // the offset is kept only where the data say it is not zero (outside its own confidence
    // interval) and it does not worsen the held-out error
    if cv2.rms > cv.rms * 1.02 || cv2.theta[nb + 1].abs() <= CI_SIGMAS * cv2.theta_se[nb + 1] {
        return None;
    }
    let mut ec = e.clone();
    ec.coef = vec![cv2.theta[nb], 0.0];
    let mut cf = Effect::new(EffectId::ConstantForce, ec.side, vec![]);
    cf.coef = vec![cv2.theta[nb + 1]];
    let mut params = flat(&ec.to_table(kind, d.r));
    // the offset in the sign of the model file's constant_force (the force on the axis, see
    // docs/workbench.md "Signs"), i.e. minus the torque-balance coefficient
    let off = round_sig(constant_force_value(cf.coef[0], kind, d.r));
    let key = if kind == AxisKind::Rotary {
        "offset_nm"
    } else {
        "offset_n"
    };
    params.insert(key.into(), off);
    let ev = format!(
        "{}, with {} in both directions (asymmetric Coulomb friction and Coulomb plus constant_force are one class while the axis moves)",
        evidence(&ec, d),
        constant_force_words(off, kind)
    );
    Some((vec![ec, cf], cv2, params, ev))
}

/// Candidates the data cannot tell apart (same channel, scores within 10 % of each other,
/// contributions correlated above 0.95) name each other in `same_as`, and share the class of
/// the first of them.
fn mark_indistinguishable(cands: &mut [Candidate]) {
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

/// The residual's description by the dictionary and the sparse peer on it, on at most 200,000
/// evenly spread samples (a long trace is thinned: the terms are smooth or held).
fn dictionary_of(
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
    extra: &[(String, Vec<f64>)],
) -> (Vec<TermCut>, SparsePeer) {
    let step = d.len().div_ceil(200_000).max(1);
    let run = |d: &AxisData, ch: &TorqueChannel<'_>, extra: &[(String, Vec<f64>)]| {
        let terms = dictionary::terms(d, &ch.y_app, extra);
        let cuts = dictionary::explain(
            &terms,
            &ch.base_cols,
            &ch.res,
            &ch.bl,
            ch.mask.as_deref(),
            ch.min_pct,
            MIN_FOLD_WINS,
        );
        let peer = dictionary::sparse_peer(&terms, &ch.base_cols, &ch.res, &ch.y_app, d.range);
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
fn residual_whiteness(d: &AxisData, ch: &TorqueChannel<'_>) -> (bool, Vec<f64>) {
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

/// The one-sentence verdict: the first significant candidate with what to do about it, or why
/// nothing was found.
/// What the fit of the recommended candidate delivers, measured.
#[derive(Debug, Clone)]
pub struct Confirmed {
    /// The candidate's name.
    pub effect: String,
    /// The error in its channel before the fit, %.
    pub before_pct: f64,
    /// The error in its channel after the fit, %.
    pub after_pct: f64,
    /// The sentence the verdict ends with.
    pub words: String,
}

/// The error of `f` in the channel `channel` before and after, %, and the channel's words.
fn channel_errors(f: &FitResult, channel: &str) -> Option<(f64, f64, &'static str)> {
    let (b, a, name) = match channel {
        "deflection" => (
            f.before.window_sim_nrmse_pct,
            f.after.window_sim_nrmse_pct,
            "windowed simulation error",
        ),
        "controller" => (
            f.before.controller_nrmse_pct,
            f.after.controller_nrmse_pct,
            "controller channel's error",
        ),
        _ => (
            f.before.equation_nrmse_pct,
            f.after.equation_nrmse_pct,
            "equation error",
        ),
    };
    Some((b?, a?, name))
}

/// Fits candidate `c` as the verdict would tell the user to (`fit --free KEY` or `fit --add
/// IDS`) and measures the error of the channel it was scored on: what the fit delivers, or why it
/// is not recommended (its fit is refused or raises that error), in words for its evidence.
fn confirm(
    c: &Candidate,
    model: &WbModel,
    d: &AxisData,
    window_s: f64,
) -> Result<Confirmed, String> {
    let res = if c.is_param {
        let free = [c.effect.clone()];
        fit_with(model, d, vec![], Some(&free), window_s)
    } else {
        let mut ids: Vec<EffectId> = c.add.iter().map(|e| e.id).collect();
        ids.dedup();
        fit(model, d, &ids, None, window_s)
    };
    match res.as_ref().ok().and_then(|f| channel_errors(f, c.channel)) {
        Some((b, a, name)) if material_cut(b, a) => Ok(Confirmed {
            effect: c.effect.clone(),
            before_pct: b,
            after_pct: a,
            words: format!(
                "fitting it takes the {name} from {} % to {} % (a cut of {:.0} %)",
                sig(b),
                sig(a),
                100.0 * (b - a) / b.max(1e-300)
            ),
        }),
        Some((b, a, name)) if a >= b => Err(format!(
            "fitting it raises the {name} from {} % to {} %: not recommended",
            sig(b),
            sig(a)
        )),
        Some((b, a, name)) => Err(format!(
            "fitting it lowers the {name} only from {} % to {} % (less than {MIN_REDUCTION_PCT} % of it): not recommended",
            sig(b),
            sig(a)
        )),
        None => Err(format!(
            "its fit is refused ({})",
            match res {
                Err(e) => e.to_string(),
                Ok(_) => "its channel's error cannot be measured on this trace".into(),
            }
        )),
    }
}

/// The part of a candidate's evidence that says why it is not significant: from the clause of
/// the last of the reasons a diagnosis gives (a refused or weak fit, a confidence interval, too
/// few winning blocks, an estimate at an edge) to the end.
fn why_not_significant(evidence: &str) -> &str {
    let at = [
        "its fit is refused",
        "fitting it ",
        "inside its own confidence interval",
        "it lowers the cross-validated error in only",
        "edge of the range searched",
        "too few reversals",
        "not significant",
    ]
    .iter()
    .filter_map(|m| evidence.find(m))
    .min();
    let Some(at) = at else { return "" };
    let start = evidence[..at].rfind("; ").map(|i| i + 2).unwrap_or(0);
    evidence[start..]
        .trim_end_matches(": not significant")
        .trim_end_matches(" (not significant)")
}

fn verdict(
    cands: &[Candidate],
    white: bool,
    ac: &[f64],
    cc: Option<&ControllerChannel>,
    d: &AxisData,
    fitted: Option<&Confirmed>,
) -> String {
    let sig: Vec<&Candidate> = cands.iter().filter(|c| c.significant).collect();
    let cc_fails = cc.filter(|c| c.fails());
    match sig.first() {
        None if cc_fails.is_some() => {
            let c = cc_fails.expect("checked");
            format!(
                "the torque balance shows no missing effect, but the recorded torque departs from the controller law (controller channel NRMSE {:.1} %, {:.0} times its noise floor; largest at t = {} s): the drive does something the model's [controller] does not say",
                c.nrmse_pct,
                c.rms / c.noise_rms.max(1e-300),
                fmt(largest_at(c, d))
            )
        }
        None if white => "no missing effect found; the remaining misfit looks like noise (whiteness test passed)".to_string(),
        None => {
            let lag1 = ac.first().copied().unwrap_or(0.0);
            // the largest cut of a candidate that is not significant, measured, with why
            match cands
                .iter()
                .filter(|c| c.channel == "torque" && c.error_reduction_pct >= MIN_REDUCTION_PCT)
                .max_by(|a, b| a.error_reduction_pct.total_cmp(&b.error_reduction_pct))
            {
                Some(c) => format!(
                    "no missing effect found; the remaining misfit does not look like noise (whiteness test failed, lag-1 autocorrelation {lag1:.2}), and the largest cut, {:.1} % of the cross-validated error by {}, is not significant ({})",
                    c.error_reduction_pct,
                    c.effect,
                    why_not_significant(&c.evidence)
                ),
                None => format!(
                    "no missing effect found; the remaining misfit does not look like noise (whiteness test failed): its lag-1 autocorrelation is {lag1:.2}, but no candidate lowers the cross-validated error by {MIN_REDUCTION_PCT} % or more"
                ),
            }
        }
        Some(top) if top.channel == "controller" && top.add.is_empty() => format!(
            "the controller channel: {} (class {}) explains {:.0} % of the recorded torque's departure from the controller law ({}); {}",
            top.effect,
            top.class,
            top.error_reduction_pct,
            top.evidence,
            if top.effect == "added_input" {
                format!("declare it as a known input (`--added-input COLUMN`, or a trace column `{}.torque_add`) so that the equation and the simulation use it", d.axis)
            } else {
                "check the drive's gains and filters against the model's [controller]".to_string()
            }
        ),
        Some(top) => {
            let mut names = vec![top.effect.clone()];
            names.extend(top.same_as.iter().cloned());
            let what = if top.is_param { "a wrong base parameter" } else { "a missing effect" };
            let of = if top.channel == "controller" {
                "of the recorded torque's departure from the controller law"
            } else {
                "of the error"
            };
            // the figure is what fitting it delivers where that was measured, else the
            // cross-validated estimate, said as such
            let explains = match fitted.filter(|f| f.effect == top.effect) {
                Some(f) => f.words.clone(),
                None => format!(
                    "lowers the cross-validated error by {:.0} % {of}",
                    top.error_reduction_pct
                ),
            };
            format!(
                "{what}: {} (class {}): {explains} ({}); {}",
                names.join(" / "),
                top.class,
                top.evidence,
                if top.is_param && top.class == "inertia" {
                    format!(
                        "refit it with `feedloop fit --free {}`{}",
                        top.effect,
                        excitation_99_hz(d)
                            .map(|f| format!("; an inertia refit and a mass on its own spring whose mode these moves barely excite look the same (99 % of the commanded acceleration lies below {} Hz): to tell them apart, move with acceleration steps or a sweep", fmt(f)))
                            .unwrap_or_default()
                    )
                } else if top.is_param {
                    format!("refit it with `feedloop fit --free {}`", top.effect)
                } else {
                    let ids: Vec<&str> = top.add.iter().map(|e| e.id.id()).collect();
                    format!("add it with `feedloop fit --add {}`", ids.join(","))
                }
            )
        }
    }
}

/// What the torque channel's candidates are scored with: the base columns, the residual, the
/// cross-validation blocks and the rows used (see [`moving_mask`]).
struct TorqueFit<'a> {
    /// Smallest reduction that counts, % of the model's error (see [`TorqueChannel`]).
    min_pct: f64,
    base_cols: &'a [&'a [f64]],
    /// Current values of the inertias among the base parameters (see [`inertias_now`]).
    now: &'a [f64],
    res: &'a [f64],
    bl: &'a [(usize, usize)],
    mask: Option<&'a [f64]>,
}

/// Forward selection: once the first candidate (an effect on the torque channel) is
/// significant, every other torque-channel effect must earn its significance beyond it: it is
/// refitted together with the base parameters and the first candidate, and keeps its
/// significance only if it lowers the cross-validated error further by [`MIN_REDUCTION_PCT`] in
/// [`MIN_FOLD_WINS`] blocks. A candidate that only re-explains part of the first one's misfit
/// (a clamp of the torque where friction steps, an offset the first one already carries) is
/// credited with its extra only; when the first candidate already includes its effect, it is
/// reported in the first one's class.
fn condition_on_top(
    cands: &mut [Candidate],
    model: &WbModel,
    d: &AxisData,
    tf: &TorqueFit<'_>,
    e0: f64,
) {
    let (base_cols, res, bl, mk) = (tf.base_cols, tf.res, tf.bl, tf.mask);
    // the first significant candidate (one ranked above it lost its significance when its fit
    // failed and stays as it is)
    let Some(ti) = cands.iter().position(|c| c.significant) else {
        return;
    };
    let top = &cands[ti];
    if top.is_param || top.channel != "torque" {
        return;
    }
    let top_add = top.add.clone();
    let top_class = top.class.clone();
    let top_name = top.effect.clone();
    let needed = model.torque_needed(d);
    let mut with_top = model.clone();
    let mut top_cols: Vec<Vec<f64>> = Vec::new();
    for e in &top_add {
        match channel(e.id) {
            Channel::TorquePath => with_top.effects.push(e.clone()),
            Channel::Torque => top_cols.extend(e.columns(d)),
            Channel::Deflection => {}
        }
    }
    let target_of = |m: &WbModel| -> Vec<f64> {
        match m.applied(d) {
            Some(t) => t.iter().zip(&needed).map(|(a, b)| a - b).collect(),
            None => res.to_vec(),
        }
    };
    let t_ref = target_of(&with_top);
    let mut cols: Vec<&[f64]> = base_cols.to_vec();
    cols.extend(top_cols.iter().map(|c| c.as_slice()));
    let cv_ref = cv_cols_masked(&cols, &[], &t_ref, bl, mk);
    let mut now_ext = tf.now.to_vec();
    now_ext.resize(cols.len(), 0.0);
    let mut included = Vec::new();
    for c in cands.iter_mut().skip(ti + 1) {
        if c.is_param || c.channel != "torque" || c.add.is_empty() {
            continue;
        }
        let was_significant = c.significant;
        // a single effect is refitted beyond the first one (its nonlinear parameter chosen
        // again: the first one's misfit no longer hides it)
        let single = (c.add.len() == 1).then(|| c.add[0].id).filter(|id| {
            channel(*id) != Channel::Deflection
                && (id.repeatable() || !top_add.iter().any(|t| t.id == *id))
        });
        let rescored = single
            .and_then(|id| best_effect(id, &with_top, d, &cols, &now_ext, &t_ref, bl, mk).ok());
        let cv = match &rescored {
            Some(r) => r.cv.clone(),
            None => {
                let mut with = with_top.clone();
                let mut extra_cols: Vec<Vec<f64>> = Vec::new();
                for e in &c.add {
                    match channel(e.id) {
                        Channel::TorquePath => with.effects.push(e.clone()),
                        Channel::Torque => extra_cols.extend(e.columns(d)),
                        Channel::Deflection => {}
                    }
                }
                let t = if with.effects.len() > with_top.effects.len() {
                    target_of(&with)
                } else {
                    t_ref.clone()
                };
                let refs: Vec<&[f64]> = extra_cols.iter().map(|x| x.as_slice()).collect();
                cv_cols_masked(&cols, &refs, &t, bl, mk)
            }
        };
        let extra = 100.0 * (cv_ref.rms - cv.rms) / e0;
        let wins = fold_wins(&cv, &cv_ref.fold_mse);
        let nb = cols.len();
        let inside_ci = rescored.as_ref().is_some_and(|r| {
            channel(r.effect.id) == Channel::Torque
                && r.cv.theta.len() > nb
                && r.cv.theta[nb].abs() <= CI_SIGMAS * r.cv.theta_se[nb]
        });
        if extra >= tf.min_pct && wins >= MIN_FOLD_WINS && !inside_ci {
            if let Some(Refit { effect: e, .. }) = rescored {
                c.params = flat(&e.to_table(d.kind, d.r));
                c.evidence = evidence(&e, d);
                c.add = vec![e];
            }
            if !was_significant {
                c.significant = true;
                c.error_reduction_pct = extra;
            }
            c.evidence = format!(
                "{}; beyond {top_name} it lowers the cross-validated error by {extra:.1} %",
                c.evidence
            );
        } else {
            c.significant = false;
            c.error_reduction_pct = extra;
            if c.add.iter().all(|e| top_add.iter().any(|t| t.id == e.id)) {
                c.class = top_class.clone();
                if !c.same_as.contains(&top_name) {
                    c.same_as.push(top_name.clone());
                }
                included.push(c.effect.clone());
            }
            c.evidence = format!(
                "{}; beyond {top_name} it lowers the cross-validated error by only {extra:.1} % (not significant)",
                c.evidence
            );
        }
    }
    cands[0].same_as.extend(included);
    cands.sort_by(|x, y| y.error_reduction_pct.total_cmp(&x.error_reduction_pct));
}

/// The frequency below which 99 % of the commanded acceleration's energy lies, Hz: what the
/// moves excite (a mode they barely excite looks like inertia).
pub fn excitation_99_hz(d: &AxisData) -> Option<f64> {
    let n = d.cmd.len();
    if n < 64 {
        return None;
    }
    let dt2 = d.dt * d.dt;
    let acc: Vec<f64> = (1..n - 1)
        .map(|k| (d.cmd[k + 1] - 2.0 * d.cmd[k] + d.cmd[k - 1]) / dt2)
        .collect();
    let (f, a) = super::report::spectrum(&acc, d.dt);
    let total: f64 = a.iter().map(|x| x * x).sum();
    if total <= 0.0 {
        return None;
    }
    let mut cum = 0.0;
    for (fi, ai) in f.iter().zip(&a) {
        cum += ai * ai;
        if cum >= 0.99 * total {
            return Some(*fi);
        }
    }
    f.last().copied()
}

/// Time of the controller residual's largest magnitude, s.
fn largest_at(c: &ControllerChannel, d: &AxisData) -> f64 {
    let (a, b) = c.range;
    let k = (a..b)
        .max_by(|&i, &j| c.residual[i].abs().total_cmp(&c.residual[j].abs()))
        .unwrap_or(a);
    d.t[k]
}

/// Torque unit of the axis kind.
fn torque_unit(kind: AxisKind) -> &'static str {
    if kind == AxisKind::Rigid {
        "N"
    } else {
        "N m"
    }
}

/// Candidates of the controller channel, when the record departs from the law beyond its
/// noise: a clamp of the drive recorded after clamping (`torque_saturation`), then, on what is
/// left, an input added after the controller when the departure is concentrated in time
/// (`added_input`, reported as events), or else a law that differs (`controller_law`). A
/// torque-channel candidate of the same id that is not significant gives way to the controller
/// channel's. Scores are % of the controller residual's RMS.
fn controller_candidates(
    model: &WbModel,
    d: &AxisData,
    cc: &ControllerChannel,
    cands: &mut Vec<Candidate>,
) {
    if !cc.fails() {
        return;
    }
    let tu = torque_unit(d.kind);
    let (a, b) = cc.range;
    let mut rest = cc.clone();
    let noise2 = 9.0 * cc.noise_rms * cc.noise_rms;
    if let Some((l, after)) = cc.clamp_fit(d) {
        let red = 100.0 * (cc.rms - after) / cc.rms;
        if red >= MIN_REDUCTION_PCT && cc.rms * cc.rms - after * after > noise2 {
            let mut e = Effect::new(EffectId::TorqueSaturation, Side::Motor, vec![l]);
            e.coef.clear();
            let at_limit = (a..b).filter(|&k| at_limit(cc.recorded[k], l)).count();
            let lc = model.file.controller.torque_limit;
            let params = flat(&e.to_table(d.kind, d.r));
            cands.retain(|c| c.effect != "torque_saturation" || c.significant);
            cands.push(Candidate {
                effect: EffectId::TorqueSaturation.to_string(),
                is_param: false,
                class: class_of(EffectId::TorqueSaturation).into(),
                significant: true,
                error_reduction_pct: red.clamp(-100.0, 100.0),
                evidence: format!(
                    "the recorded torque sits at +-{} {tu} in {} samples ({:.1} % of the time) where the controller law asks for more{}: the drive clamps and records the clamped value",
                    fmt(l),
                    at_limit,
                    100.0 * at_limit as f64 / (b - a) as f64,
                    lc.map(|x| format!(" (the controller's own limit is {} {tu})", fmt(x)))
                        .unwrap_or_default()
                ),
                params,
                same_as: vec![],
                contribution: decimate(&cc.residual, a, b),
                add: vec![e],
                channel: "controller",
            });
            let mut with = model.clone();
            with.effects.push(Effect::new(
                EffectId::TorqueSaturation,
                Side::Motor,
                vec![l],
            ));
            if let Some(c2) = ControllerChannel::new(&with, d) {
                rest = c2;
            }
        }
    }
    if !rest.fails() {
        return;
    }
    let events = rest.events(d);
    let (share, time) = rest.event_shares(&events);
    // a departure that follows the motion (the acceleration by which a velocity estimate other
    // than the drive's lags or leads, or a feed-forward of velocity or acceleration the model's
    // [controller] does not have) is a law that differs, not an input added after it (the
    // law's output itself is no test: in a closed loop it reacts to any added input)
    let one = vec![1.0; d.len()];
    let kv = model.file.controller.kv.unwrap_or(1.0);
    let acc: Vec<f64> = d.am.iter().map(|x| kv * x).collect();
    let bl = blocks(rest.range, FOLDS);
    let follows = cv_cols(&[&acc, &d.vm], &[], &rest.residual, &bl);
    let law_like = follows.rms < (0.5f64).sqrt() * rest.rms;
    if !law_like && !events.is_empty() && share >= 50.0 && time <= 75.0 {
        let red = 100.0 * (1.0 - (1.0 - share / 100.0).max(0.0).sqrt());
        let starts: Vec<f64> = events.iter().map(|e| e.start_s).collect();
        let mut gaps: Vec<f64> = starts.windows(2).map(|w| w[1] - w[0]).collect();
        let spacing = if gaps.len() >= 2 {
            gaps.sort_by(f64::total_cmp);
            let med = gaps[gaps.len() / 2];
            let regular = gaps.iter().all(|g| (g - med).abs() <= 0.05 * med);
            regular.then_some(med)
        } else {
            None
        };
        let sizes: Vec<f64> = events.iter().map(|e| e.mean).collect();
        let size = quantile(&sizes.iter().map(|x| x.abs()).collect::<Vec<_>>(), 0.5);
        let first: Vec<String> = events
            .iter()
            .take(3)
            .map(|e| format!("{}..{} s", fmt(e.start_s), fmt(e.end_s)))
            .collect();
        let mut params = BTreeMap::new();
        params.insert("events".to_string(), events.len() as f64);
        params.insert("median_size".to_string(), size);
        params.insert("first_start_s".to_string(), events[0].start_s);
        if let Some(p) = spacing {
            params.insert("period_s".to_string(), p);
        }
        cands.push(Candidate {
            effect: "added_input".into(),
            is_param: false,
            class: "input".into(),
            significant: true,
            error_reduction_pct: red.clamp(-100.0, 100.0),
            evidence: format!(
                "the recorded torque departs from the controller law in {} stretches ({:.0} % of the time, {:.0} % of the departure), by about {} {tu} each, switching on and off at once: {}{}{}; the controller law ignores it, so something is added after the controller",
                events.len(),
                time,
                share,
                fmt(size),
                first.join(", "),
                if events.len() > 3 { ", ..." } else { "" },
                spacing
                    .map(|p| format!(", repeating every {} s", fmt(p)))
                    .unwrap_or_default()
            ),
            params,
            same_as: vec![],
            contribution: decimate(&rest.residual, a, b),
            add: vec![],
            channel: "controller",
        });
        return;
    }
    // a law that differs: the record as a gain on the law plus an offset
    let cv = cv_cols(&[&rest.law, &one], &[], &rest.residual, &bl);
    let red = 100.0 * (rest.rms - cv.rms) / rest.rms;
    let mut params = BTreeMap::new();
    params.insert("gain".to_string(), 1.0 + cv.theta[0]);
    params.insert("offset".to_string(), cv.theta[1]);
    cands.push(Candidate {
        effect: "controller_law".into(),
        is_param: false,
        class: "controller".into(),
        significant: red >= MIN_REDUCTION_PCT,
        error_reduction_pct: red.clamp(0.0, 100.0),
        evidence: format!(
            "the recorded torque departs from the controller law throughout (NRMSE {:.1} %); as a gain on the law it is {:.3} times the law plus {} {tu}",
            rest.nrmse_pct,
            1.0 + cv.theta[0],
            fmt(cv.theta[1])
        ),
        params,
        same_as: vec![],
        contribution: decimate(&rest.residual, a, b),
        add: vec![],
        channel: "controller",
    });
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
