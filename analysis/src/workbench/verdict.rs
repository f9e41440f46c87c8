//! The verdict of a diagnosis: the recommendation confirmed by running the fit it recommends
//! (the figures quoted are the measured ones), and the sentence that says what to do, or why
//! nothing was found.

use super::controller::ControllerChannel;
use super::controller_candidates::*;
use super::data::AxisData;
use super::effects::{Effect, EffectId, WbModel};
use super::fit::{fit, fit_with, FitResult};
use super::scoring::*;
use super::words::fmt;
use feedloop_model::units::sig;

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
    /// The candidate's effect as the fit sized it, where the fit sizes it on another channel
    /// than the candidate's score (a backlash gap sized on the windowed simulation).
    pub resized: Option<Effect>,
}

/// The backlash of fit `f` when candidate `c` adds one and the fit sized it otherwise.
fn resized_gap(c: &Candidate, f: &FitResult) -> Option<Effect> {
    let before = c.add.iter().find(|e| e.id == EffectId::Backlash)?;
    let after = f
        .model
        .effects
        .iter()
        .find(|e| e.id == EffectId::Backlash)?;
    (after.coef != before.coef).then(|| after.clone())
}

/// The error of `f` in the channel `channel` before and after, %, and the channel's words.
pub(super) fn channel_errors(f: &FitResult, channel: &str) -> Option<(f64, f64, &'static str)> {
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
pub(super) fn confirm(
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
            resized: res.as_ref().ok().and_then(|f| resized_gap(c, f)),
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

/// The words of an estimate at an edge of its search, in a candidate's evidence (see
/// `refit::at_edge`).
pub(super) const AT_EDGE: &str = "edge of the range searched";

/// The words of a candidate whose fit leaves its physical range or contradicts the motion (a
/// negative damping or inertia, a clamp the motion does not show): no later refit beyond
/// another candidate or in a pair makes it significant.
const VETOES: [&str; 2] = ["is not physical", "a clamped drive would fall behind"];

/// Whether a candidate's evidence carries a veto ([`VETOES`]).
pub(super) fn vetoed(evidence: &str) -> bool {
    VETOES.iter().any(|v| evidence.contains(v))
}

/// Where the reasons a candidate's evidence gives for not being significant begin: at the
/// clause of the first of them (a refused or weak fit, a confidence interval, too few winning
/// blocks, an estimate at an edge, too few reversals, a mass that is not positive). `None` when
/// it gives none.
pub(super) fn reasons_start(evidence: &str) -> Option<usize> {
    let at = [
        "its fit is refused",
        "fitting it ",
        "inside its own confidence interval",
        "it lowers the cross-validated error in only",
        AT_EDGE,
        "too few reversals",
        "its fitted mass is not positive",
        "not significant",
    ]
    .iter()
    .filter_map(|m| evidence.find(m))
    .min()?;
    Some(evidence[..at].rfind("; ").map(|i| i + 2).unwrap_or(0))
}

/// The part of a candidate's evidence that says why it is not significant: from the clause of
/// the first of the reasons a diagnosis gives ([`reasons_start`]) to the end.
pub(super) fn why_not_significant(evidence: &str) -> &str {
    let Some(start) = reasons_start(evidence) else {
        return "";
    };
    evidence[start..]
        .trim_end_matches(": not significant")
        .trim_end_matches(" (not significant)")
}

pub(super) fn verdict(
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reasons_a_candidate_is_not_significant_are_found_at_the_clause_of_the_first() {
        let ev = "steps by 2 N m; held x; it lowers the cross-validated error in only 3 of the record's 5 blocks (4 needed): not significant; its size is inside its own confidence interval (+-1 at 3 standard errors): not significant";
        let at = reasons_start(ev).unwrap();
        assert_eq!(&ev[..at], "steps by 2 N m; held x; ");
        assert!(
            why_not_significant(ev).starts_with("it lowers the cross-validated error in only 3")
        );
        let edge = "a lag of 80 ms; its time constant (0.08) is at the upper edge of the range searched (0.001 to 0.08): the best value may lie beyond: doubtful, not significant";
        assert_eq!(&edge[..reasons_start(edge).unwrap()], "a lag of 80 ms; ");
        assert_eq!(reasons_start("a step of 2 N m at each reversal"), None);
        assert_eq!(why_not_significant("a step of 2 N m at each reversal"), "");
    }
}
