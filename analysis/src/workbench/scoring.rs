//! What every candidate of a diagnosis is scored with: the torque channel (the residual, the
//! columns refitted beside a candidate, the cross-validation blocks and the two reference fits),
//! the thresholds of significance, and the candidate itself. The candidates
//! (`candidates.rs`, `controller_candidates.rs`), the verdict (`verdict.rs`) and the diagnosis
//! that orders them (`diagnose.rs`) all build on it.

use std::collections::BTreeMap;

use super::base::BaseParam;
use super::data::AxisData;
use super::effects::{Effect, WbModel};
use super::lsq::blocks_of_rows;
use super::lsq::{contribution_size, sizing_rows, Cv};
use super::refit::{cv_cols_masked, moving_mask, Released, FOLDS};
use super::signal::{mean, rms};
use feedloop_model::model::AxisKind;
use feedloop_model::EffectId;

pub use super::lsq::{material_cut, MIN_REDUCTION_PCT};

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
pub(super) fn load_to_motor(d: &AxisData) -> f64 {
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
    pub(super) contribution: Vec<f64>,
    /// Channel it was scored on.
    pub channel: &'static str,
}

pub(super) fn corr(a: &[f64], b: &[f64]) -> f64 {
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

pub(super) fn fold_wins(a: &Cv, reference: &[f64]) -> usize {
    blocks_lower(&a.fold_mse, reference)
}

/// The blocks in which the mean square `mse` lies below `reference` (by more than 0.1 %).
pub(super) fn blocks_lower(mse: &[f64], reference: &[f64]) -> usize {
    mse.iter()
        .zip(reference)
        .filter(|(x, r)| **x < **r * 0.999)
        .count()
}

pub(super) fn decimate(x: &[f64], a: usize, b: usize) -> Vec<f64> {
    let step = ((b - a) / 20000).max(1);
    x[a..b].iter().step_by(step).copied().collect()
}

/// The torque channel of a diagnosis: the residual (applied minus needed torque), the base
/// parameters that may be refitted with their columns, the cross-validation blocks and rows,
/// and the two reference fits every candidate is scored against.
pub(super) struct TorqueChannel<'d> {
    /// Recorded torque as applied to the axis (delay, lag, limit of the model included).
    pub(super) y_app: Vec<f64>,
    /// Applied minus needed torque.
    pub(super) res: Vec<f64>,
    /// Cross-validation blocks.
    pub(super) bl: Vec<(usize, usize)>,
    /// Base-parameter keys that can be refitted on this trace.
    pub(super) free_keys: Vec<BaseParam>,
    /// Their regressor columns, then those of the model's own effects (see [`Released`]).
    pub(super) base_cols: Vec<&'d [f64]>,
    /// The name of each of `base_cols`' parameters.
    pub(super) names: Vec<String>,
    /// Rows that carry information (see [`moving_mask`]).
    pub(super) mask: Option<Vec<f64>>,
    /// Cross-validation of the residual with nothing refitted.
    pub(super) cv0: Cv,
    /// Its RMS (the model's error), never 0.
    pub(super) e0: f64,
    /// Cross-validation with every base parameter refitted.
    pub(super) cvb: Cv,
    /// Smallest torque that counts on this channel: [`MATERIAL_FRACTION`] of the applied
    /// torque's RMS, torque units.
    pub(super) material: f64,
    /// Smallest reduction that counts on this channel, % of the model's error:
    /// [`MIN_REDUCTION_PCT`], or [`MATERIAL_FRACTION`] of the applied torque's RMS when that is
    /// more (a model whose error is already far below the torque has nothing left to name).
    pub(super) min_pct: f64,
}

impl<'d> TorqueChannel<'d> {
    pub(super) fn new(model: &WbModel, d: &'d AxisData, rel: &'d Released) -> Self {
        assert!(
            d.torque.is_some(),
            "diagnose needs the torque column (checked by the caller)"
        );
        let y_app = model.applied(d).expect("checked above");
        let needed = model.torque_needed(d);
        let res = model.balance_residual(d, &y_app, &needed);
        let mask = moving_mask(d);
        let bl = blocks_of_rows(d.range, FOLDS, mask.as_deref());
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
        let cv0 = cv_cols_masked(&[], &[], &res, &bl, mask.as_deref());
        let e0 = cv0.rms.max(1e-300);
        let cvb = cv_cols_masked(&base_cols, &[], &res, &bl, mask.as_deref());
        let (a, b) = d.range;
        let material = MATERIAL_FRACTION * rms(&y_app[a..b]);
        let min_pct = MIN_REDUCTION_PCT.max(100.0 * material / e0);
        Self {
            min_pct,
            material,
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
    pub(super) fn cut_pct(&self, cv: &Cv) -> f64 {
        100.0 * (self.cvb.rms - cv.rms) / self.e0.max(self.cvb.rms)
    }
}

/// The size of an effect's leading term in the refit `cv` (its coefficients after the `nb` base
/// ones) and that size's standard error, `None` when the refit has no coefficient of its own.
/// One coefficient for most effects; for a cogging ripple, whose leading pair is the sine and
/// the cosine of one angle, the amplitude of the pair, with the standard error in its direction
/// (delta method): a phase that puts the term in the cosine must not read as no term at all. An
/// unbalance is sized by the torque it varies by over the positions recorded
/// ([`varying_torque_size`]): over an arc much shorter than its period its amplitude and phase
/// trade off with its constant part, while the torque it adds along the arc does not.
pub(super) fn leading_size(e: &Effect, cv: &Cv, nb: usize, d: &AxisData) -> Option<(f64, f64)> {
    let (t, s) = (&cv.theta, &cv.theta_se);
    if t.len() <= nb {
        return None;
    }
    if e.id == EffectId::Unbalance && t.len() > nb + 1 {
        return varying_torque_size(e, cv, nb, d);
    }
    if e.id != EffectId::Cogging || t.len() <= nb + 1 {
        return Some((t[nb].abs(), s[nb]));
    }
    let (a, b) = (t[nb], t[nb + 1]);
    let amp = a.hypot(b);
    if amp == 0.0 {
        return Some((0.0, s[nb].max(s[nb + 1])));
    }
    let se = ((a * s[nb]).powi(2) + (b * s[nb + 1]).powi(2)).sqrt() / amp;
    Some((amp, se))
}

/// The RMS over the fit range of the part of effect `e`'s torque that varies with the position
/// (its sine and cosine columns, their mean removed: a constant is carried by its own column),
/// fitted by `cv`, and its standard error ([`contribution_size`]).
fn varying_torque_size(e: &Effect, cv: &Cv, nb: usize, d: &AxisData) -> Option<(f64, f64)> {
    let cols = e.columns(d);
    if cols.len() < 2 {
        return None;
    }
    let rows = sizing_rows(d.range, None);
    let refs = [cols[0].as_slice(), cols[1].as_slice()];
    Some(contribution_size(&refs, cv, nb, &rows, true))
}
