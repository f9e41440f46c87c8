//! The effects `fit` adds, each searched for its best variant on the channel where it shows,
//! beside the base parameters, the model's own effects and the effects added before it; and
//! what those searches held, which the joint refit keeps held.

use super::base::BaseParam;
use super::controller::ControllerChannel;
use super::data::AxisData;
use super::effects::{channel, Channel, Effect, EffectId, Side, WbModel};
use super::lsq::blocks_of_rows;
use super::refit::{
    best_effect, deflection, held_words, inertias_now, moving_mask, Refit, Released, FOLDS,
};
use super::WorkbenchError;

/// The effects added by [`fit`], each refitted on its own beside the base parameters (and the
/// model's own effects' coefficients, [`Released`]), and what those refits held.
pub(super) struct Adder<'a> {
    model: &'a WbModel,
    d: &'a AxisData,
    free_keys: &'a [BaseParam],
    rel: &'a Released,
    /// The free base parameters' columns, then the released ones.
    base_cols: Vec<&'a [f64]>,
    /// Their names, in the same order.
    names: Vec<String>,
    bl: Vec<(usize, usize)>,
    moving: Option<Vec<f64>>,
    /// Base parameters an effect's refit held.
    pub(super) held_all: Vec<BaseParam>,
    /// The model's effects whose coefficients an effect's refit held.
    pub(super) held_effects: Vec<EffectId>,
}

/// One effect fitted by an [`Adder`], or why it is refused.
pub(super) type Fitted = Result<Effect, WorkbenchError>;

impl<'a> Adder<'a> {
    pub(super) fn new(
        model: &'a WbModel,
        d: &'a AxisData,
        free_keys: &'a [BaseParam],
        rel: &'a Released,
    ) -> Self {
        let mut base_cols: Vec<&[f64]> = free_keys.iter().map(|k| k.column(d)).collect();
        base_cols.extend(rel.cols.iter().map(|c| c.as_slice()));
        let mut names: Vec<String> = free_keys.iter().map(|k| k.key().to_string()).collect();
        names.extend(rel.names(model));
        let moving = moving_mask(d);
        Adder {
            model,
            d,
            free_keys,
            rel,
            base_cols,
            names,
            bl: blocks_of_rows(d.range, FOLDS, moving.as_deref()),
            moving,
            held_all: Vec::new(),
            held_effects: Vec::new(),
        }
    }

    /// Effect `id` at its best variant, on the channel where it shows (what was doubtful or
    /// held said in `warnings`), or why it is refused.
    pub(super) fn effect(&mut self, id: EffectId, warnings: &mut Vec<String>) -> Fitted {
        let (model, d) = (self.model, self.d);
        if !id.repeatable() && model.effects.iter().any(|e| e.id == id) {
            return Err(WorkbenchError::EffectRefused {
                effect: id.to_string(),
                reason: "it is already in the model, and a model gives it only once".into(),
                advice: format!(
                    "nothing was written; remove [effects.{id}] from the model to fit it anew, or leave it out of --add"
                ),
            });
        }
        match channel(id) {
            Channel::Deflection => {
                let (rd, dcols) = deflection(model, d).ok_or_else(|| {
                    missing_column(
                        d,
                        "motor",
                        format!("fitting `{id}` (it shows in motor minus load position)"),
                    )
                })?;
                let dref: Vec<&[f64]> = dcols.iter().map(|c| c.as_slice()).collect();
                let r = best_effect(id, model, d, &dref, &[], &rd, &self.bl, None)
                    .map_err(|why| refused(id, why))?;
                if let Some(why) = &r.doubtful {
                    warnings.push(format!("{id}: {why} (doubtful)"));
                }
                Ok(r.effect)
            }
            Channel::Torque | Channel::TorquePath => self.torque_effect(id, warnings),
        }
    }

    /// [`Adder::effect`] on the torque channel (or its path).
    fn torque_effect(&mut self, id: EffectId, warnings: &mut Vec<String>) -> Fitted {
        let (model, d) = (self.model, self.d);
        let y = d.torque.as_ref().ok_or_else(|| {
            missing_column(d, "torque", format!("fitting `{id}` by inverse dynamics"))
        })?;
        // a drive that records its clamped torque shows its limit in the controller
        // channel, not in the torque balance: take the limit from there when it
        // explains the record's departure from the law better than the balance
        if id == EffectId::TorqueSaturation {
            if let Some(l) = controller_clamp(model, d) {
                return Ok(Effect::new(id, Side::Motor, vec![l]));
            }
        }
        let res = residual(model, d, y);
        let now = inertias_now(model, self.free_keys);
        let Refit {
            effect: mut e,
            held,
            doubtful,
            ..
        } = best_effect(
            id,
            model,
            d,
            &self.base_cols,
            &now,
            &res,
            &self.bl,
            self.moving.as_deref(),
        )
        .map_err(|why| refused(id, why))?;
        // a Coulomb friction is added symmetric: its level alone spans no offset, so the
        // model's own effects it held are refitted beside it; any other effect keeps
        // them held (an offset beside a friction with a level per direction)
        let symmetric = e.id == EffectId::CoulombFriction;
        if symmetric {
            e.coef[1] = 0.0;
        }
        let nk = self.free_keys.len();
        if !symmetric {
            self.held_effects.extend(
                held.iter()
                    .filter(|i| **i >= nk)
                    .map(|i| model.effects[self.rel.slots[*i - nk].0].id),
            );
        }
        let held: Vec<usize> = held.into_iter().filter(|i| *i < nk || !symmetric).collect();
        if !held.is_empty() {
            warnings.push(format!("{id}: {}", held_words(&held, &self.names)));
            self.held_all
                .extend(held.iter().filter_map(|i| self.free_keys.get(*i).copied()));
        }
        if let Some(why) = &doubtful {
            warnings.push(format!("{id}: {why} (doubtful)"));
        }
        Ok(e)
    }
}

/// What the added effects' own refits held: base parameters, and the model's effects whose
/// coefficients they could not be told apart from.
#[derive(Default)]
pub(super) struct Held {
    pub(super) base: Vec<BaseParam>,
    pub(super) effects: Vec<EffectId>,
}

impl Held {
    /// The free parameters of the joint refit when the effects' refits held some (`None`: as
    /// given): the free base parameters and the model's effects (those `free_effects` lists,
    /// all when `None`) less those held.
    pub(super) fn narrowed(
        &self,
        model: &WbModel,
        free_keys: &[BaseParam],
        free_effects: Option<&[EffectId]>,
    ) -> Option<Vec<String>> {
        (!self.base.is_empty() || !self.effects.is_empty()).then(|| {
            let effects: Vec<EffectId> = free_effects
                .map(<[EffectId]>::to_vec)
                .unwrap_or_else(|| model.effects.iter().map(|e| e.id).collect())
                .into_iter()
                .filter(|id| !self.effects.contains(id))
                .collect();
            free_keys
                .iter()
                .filter(|k| !self.base.contains(k))
                .map(|k| k.key().to_string())
                .chain(effects.iter().map(|id| id.id().to_string()))
                .collect()
        })
    }
}

/// The drive's torque limit as the controller channel shows it: when the record departs from
/// the controller law beyond its noise and a clamp at the largest recorded magnitude removes at
/// least half of that departure.
fn controller_clamp(model: &WbModel, d: &AxisData) -> Option<f64> {
    let cc = ControllerChannel::new(model, d)?;
    if !cc.fails() {
        return None;
    }
    let (l, after, _) = cc.clamp_fit(d)?;
    (after < 0.5 * cc.rms).then_some(l)
}

fn residual(model: &WbModel, d: &AxisData, y: &[f64]) -> Vec<f64> {
    let _ = y;
    let y_app = model.applied(d).unwrap_or_default();
    let n = model.torque_needed(d);
    model.balance_residual(d, &y_app, &n)
}

/// The error of a fit that needs column `A.column` of the axis, which `d` lacks, for
/// `needed_for`.
pub(super) fn missing_column(d: &AxisData, column: &str, needed_for: String) -> WorkbenchError {
    WorkbenchError::MissingColumn {
        path: d.path.clone(),
        column: format!("{}.{column}", d.axis),
        needed_for,
        present: d.columns_present().join(", "),
    }
}

/// The error of `fit --add ID` when the effect cannot be fitted.
pub(super) fn refused(id: EffectId, why: String) -> WorkbenchError {
    WorkbenchError::EffectRefused {
        effect: id.to_string(),
        reason: why,
        advice: format!(
            "nothing was written; run `feedloop diagnose` to see what these data show, record \
             moves that excite `{id}` (reversals for friction, a range of speeds, travel for \
             position-dependent effects), or leave it out"
        ),
    }
}
