//! `diagnose --auto`: the guided loop. Add the most significant candidate, refit, diagnose
//! again, until nothing significant remains; record the error after each step.
//!
//! The rule, in one sentence: add the first significant candidate (significant = it lowers the
//! cross-validated error of the channel where it shows by a margin noise cannot give) as long
//! as it is not already in the model and adding it lowers that channel's error, else stop.
//! Candidates that cannot be added to a model (an input added after the controller, a
//! controller law that differs) end the loop and are named in its verdict.

use serde_json::{json, Value};

use super::data::AxisData;
use super::diagnose::{diagnose, material_cut, Candidate, DiagOptions, Diagnosis};
use super::effects::EffectId;
use super::effects::WbModel;
use super::fit::{fit, fit_with, Errors, FitResult};
use super::WorkbenchError;
use crate::plot::{Axis, Plot, Series, PALETTE};

/// One step of the loop.
#[derive(Debug, Clone)]
pub struct Step {
    /// What was added (effect ids or `refit <param>`); empty for the starting model.
    pub added: Vec<String>,
    /// Errors after the step.
    pub errors: Errors,
}

/// Result of the loop.
#[derive(Debug, Clone)]
pub struct AutoResult {
    /// The steps, the starting model first.
    pub steps: Vec<Step>,
    /// The final model.
    pub model: WbModel,
    /// The last diagnosis (nothing significant, or the step limit).
    pub last: Diagnosis,
}

/// Runs the guided loop for at most `max_steps` additions.
pub fn auto(
    model: &WbModel,
    d: &AxisData,
    window_s: f64,
    max_steps: usize,
) -> Result<AutoResult, WorkbenchError> {
    let mut m = model.clone();
    let mut steps = vec![Step {
        added: vec![],
        errors: Errors::of(&m, d, window_s),
    }];
    let mut last = diagnose(&m, d, &DiagOptions::default());
    for _ in 0..max_steps {
        let Some(top) = last.candidates.iter().find(|c| c.significant).cloned() else {
            break;
        };
        // what cannot be added to a model (an input after the controller, a law that differs)
        // is reported, not fitted; an effect already in the model is never added again
        if !top.is_param && top.add.is_empty() {
            break;
        }
        if !top.is_param
            && top
                .add
                .iter()
                .all(|e| m.effects.iter().any(|x| x.id == e.id) && !e.id.repeatable())
        {
            break;
        }
        let res = fit_step(&m, d, &top, &last, window_s);
        let mut res = match res {
            Ok(r) => r,
            Err(e) => {
                last.verdict = format!(
                    "{}; the guided loop stopped: fitting {} was refused ({e})",
                    last.verdict, top.effect
                );
                break;
            }
        };
        // an effect of the transmission (backlash, lead error) barely shows in the torque
        // balance: it must lower the windowed simulation error instead
        let (b, a) = match top.channel {
            "deflection" => (
                res.before.window_sim_nrmse_pct,
                res.after.window_sim_nrmse_pct,
            ),
            "controller" => (
                res.before.controller_nrmse_pct,
                res.after.controller_nrmse_pct,
            ),
            _ => (res.before.equation_nrmse_pct, res.after.equation_nrmse_pct),
        };
        let better = match (b, a) {
            (Some(b), Some(a)) => material_cut(b, a),
            _ => true,
        };
        if !better {
            break;
        }
        let added = if top.is_param {
            moved_params(&m, &res, &top)
        } else {
            added_effects(&mut res, model, d, window_s)
        };
        m = res.model;
        steps.push(Step {
            added,
            errors: res.after,
        });
        last = diagnose(&m, d, &DiagOptions::default());
    }
    Ok(AutoResult {
        steps,
        model: m,
        last,
    })
}

/// What a step that refitted base parameters added: the parameters the refit moved (of those
/// freed with the candidate, the one the data cannot tell from the other may have been held).
fn moved_params(m: &WbModel, res: &FitResult, top: &Candidate) -> Vec<String> {
    let moved: Vec<String> = m
        .base
        .iter()
        .filter(|(k, v)| res.model.base_value(*k) != *v)
        .map(|(k, _)| format!("refit {}", k.key()))
        .collect();
    if moved.is_empty() {
        vec![format!("refit {}", top.effect)]
    } else {
        moved
    }
}

/// What a step that added effects added, with what they replace; a constant force the loop
/// added before is folded into a directional friction beside it here (see
/// [`fold_constant_into_directional`]; kept unless the fold simulates the record materially
/// worse).
fn added_effects(res: &mut FitResult, start: &WbModel, d: &AxisData, window_s: f64) -> Vec<String> {
    let mut replaced = res.replaced.clone();
    if let Some(folded) = fold_constant_into_directional(&res.model, start) {
        let errors = Errors::of(&folded, d, window_s);
        // judged on the windowed simulation, which sticks at rest and at reversals as the
        // plant does: the equation error's dead band around a reversal charges the two forms
        // a little differently (a constant beside the friction fills it), not the motion
        let judged = |e: &Errors| e.window_sim_nrmse_pct.or(e.equation_nrmse_pct);
        if let (Some(kept), Some(f)) = (judged(&res.after), judged(&errors)) {
            if !material_cut(f, kept) {
                replaced.push(EffectId::ConstantForce.id().to_string());
                res.model = folded;
                res.after = errors;
            }
        }
    }
    if replaced.is_empty() {
        res.added.clone()
    } else {
        let r = replaced.join(", ");
        res.added
            .iter()
            .map(|a| format!("{a} (replaces {r})"))
            .collect()
    }
}

/// Folds a constant force the loop added (not in the starting model `start`) into a directional
/// friction beside it: while moving the constant adds to one direction's level and takes from
/// the other's, and at rest it shifts the band the friction holds by as much, so the two are one
/// torque balance and the directional friction alone says it with fewer parameters (a constant
/// found beside a symmetric Coulomb friction is how the loop first sees unequal levels). Done
/// only when both levels stay levels (not negative): the model folded, or `None`.
fn fold_constant_into_directional(m: &WbModel, start: &WbModel) -> Option<WbModel> {
    let has = |w: &WbModel, id: EffectId| w.effects.iter().any(|e| e.id == id);
    if has(start, EffectId::ConstantForce) || has(start, EffectId::DirectionalFriction) {
        return None;
    }
    let find = |id: EffectId| m.effects.iter().position(|e| e.id == id);
    let (c, f) = (
        find(EffectId::ConstantForce)?,
        find(EffectId::DirectionalFriction)?,
    );
    let k = m.effects[c].coef[0];
    // columns [v > eps] and -[v < -eps]: moving forward c0 + k, backward -(c1 - k)
    let (pos, neg) = (m.effects[f].coef[0] + k, m.effects[f].coef[1] - k);
    if pos < 0.0 || neg < 0.0 {
        return None;
    }
    let mut folded = m.clone();
    folded.effects[f].coef[0] = pos;
    folded.effects[f].coef[1] = neg;
    folded.effects.remove(c);
    Some(folded)
}

/// The fit of one step: a base parameter refitted (with those the diagnosis cannot tell from
/// it), or the effects added through the fit the diagnosis confirmed its recommendation with
/// (`fit --add IDS`: it replaces what the effect contains and carries the base parameters it
/// spans).
fn fit_step(
    m: &WbModel,
    d: &AxisData,
    top: &Candidate,
    last: &Diagnosis,
    window_s: f64,
) -> Result<FitResult, WorkbenchError> {
    if top.is_param {
        let mut free = vec![top.effect.clone()];
        for o in &top.same_as {
            if last.candidates.iter().any(|c| &c.effect == o && c.is_param) {
                free.push(o.clone());
            }
        }
        return fit_with(m, d, vec![], Some(&free), window_s);
    }
    let mut ids: Vec<EffectId> = top.add.iter().map(|e| e.id).collect();
    ids.dedup();
    fit(m, d, &ids, None, window_s)
}

impl AutoResult {
    /// JSON of the loop.
    pub fn to_json(&self) -> Value {
        json!({
            "steps": self.steps.iter().enumerate().map(|(i, s)| json!({
                "step": i,
                "added": s.added,
                "equation_nrmse_pct": s.errors.equation_nrmse_pct,
                "relative_error_pct": s.errors.relative_error_pct,
                "window_sim_nrmse_pct": s.errors.window_sim_nrmse_pct,
                "controller_nrmse_pct": s.errors.controller_nrmse_pct,
            })).collect::<Vec<_>>(),
            "verdict": self.last.verdict,
            "candidates": self.last.to_json()["candidates"].clone(),
        })
    }

    /// HTML table and plot of the error after each step ("watch the error fall").
    pub fn html(&self) -> String {
        let mut h = String::from("<h2>Watch the error fall</h2><table><tr><th>step</th><th>added</th><th>equation NRMSE %</th><th>windowed sim NRMSE %</th></tr>");
        for (i, s) in self.steps.iter().enumerate() {
            h.push_str(&format!(
                "<tr><td>{i}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                if s.added.is_empty() {
                    "(nominal model)".to_string()
                } else {
                    s.added.join(", ")
                },
                s.errors
                    .equation_nrmse_pct
                    .map(|v| format!("{v:.2}"))
                    .unwrap_or_default(),
                s.errors
                    .window_sim_nrmse_pct
                    .map(|v| format!("{v:.2}"))
                    .unwrap_or_default()
            ));
        }
        h.push_str("</table>");
        let x: Vec<f64> = (0..self.steps.len()).map(|i| i as f64).collect();
        let eq: Vec<f64> = self
            .steps
            .iter()
            .map(|s| s.errors.equation_nrmse_pct.unwrap_or(f64::NAN))
            .collect();
        let ws: Vec<f64> = self
            .steps
            .iter()
            .map(|s| s.errors.window_sim_nrmse_pct.unwrap_or(f64::NAN))
            .collect();
        h.push_str(
            &Plot::new(
                "Error after each step",
                Axis::linear("step", "effects added").ticks(
                    (0..self.steps.len())
                        .map(|i| (i as f64, i.to_string()))
                        .collect(),
                ),
                Axis::linear("NRMSE", "%"),
            )
            .series(Series::line("equation error", PALETTE[0], &x, &eq))
            .series(Series::line("windowed simulation", PALETTE[1], &x, &ws))
            .svg(),
        );
        h.push_str(&format!(
            "<p><b>Verdict:</b> {}</p>",
            self.last.verdict.replace('<', "&lt;")
        ));
        h
    }
}

/// HTML table of a diagnosis.
pub fn diagnosis_html(d: &Diagnosis) -> String {
    let mut h = String::from("<h2>Diagnosis</h2><table><tr><th>candidate</th><th>class</th><th>significant</th><th>error reduction %</th><th>evidence</th></tr>");
    for c in &d.candidates {
        h.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{:.1}</td><td style=\"text-align:left\">{}</td></tr>",
            c.effect,
            c.class,
            if c.significant { "yes" } else { "no" },
            c.error_reduction_pct,
            c.evidence.replace('<', "&lt;")
        ));
    }
    h.push_str("</table>");
    h.push_str(&format!(
        "<p><b>Verdict:</b> {}</p>",
        d.verdict.replace('<', "&lt;")
    ));
    h
}
