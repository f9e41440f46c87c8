//! Two effects that hide each other. Each candidate is tested beyond the base refit alone,
//! where every other effect's misfit is still in the residual: a friction step at a few
//! reversals beside an unmodelled gravity that changes with the pose is judged against a
//! residual that is mostly that gravity, and its confidence interval (from the spread of the
//! block-wise fits) takes in zero, although its cross-validated cut reaches the smallest cut
//! that counts.
//!
//! When no candidate is significant and the misfit is not noise, each of the two leading
//! single torque-channel effects (by that cut; none whose fit was refused, none at an edge of
//! its search alone) is refitted beside every other single torque-channel effect of another
//! class. The partner must lower the cross-validated error beyond the leader by the smallest
//! cut that counts (a share of the model's error, as any candidate beyond a first one), in
//! [`MIN_FOLD_WINS`] of the blocks; the leader, refitted beside it, must then pass every rule of
//! a candidate (that cut, those blocks, its size outside its own confidence interval, its
//! nonlinear parameter not at an edge of its search). When the partner passes them too, beside
//! the leader, both are named; when its size stays inside its confidence interval or its
//! parameter at an edge, the leader alone is named and the partner's evidence says why it is
//! not. Either way the fit `fit --add` makes of what is named must lower the error materially.

use super::beyond::{beyond_top, Earned, Top, TorqueFit};
use super::data::AxisData;
use super::effects::{channel, Channel, EffectId, WbModel};
use super::refit::{flat, Refit};
use super::scoring::{Candidate, CI_SIGMAS, MIN_FOLD_WINS};
use super::verdict::{confirm, reasons_start, vetoed, Confirmed, AT_EDGE};
use super::words::{class_of, evidence, fmt, reversals};

/// Leading candidates (by their cut alone) each tried with every other one.
const LEADERS: usize = 2;

/// The effect of candidate `c` when it is a single torque-channel effect a pair may hold: a
/// friction needs at least one reversal (`turns` in the record; else a constant torque carries
/// it).
fn single_effect(c: &Candidate, turns: usize) -> Option<EffectId> {
    if c.is_param || c.channel != "torque" || c.add.len() != 1 {
        return None;
    }
    let id = c.add[0].id;
    if channel(id) != Channel::Torque || (class_of(id) == "friction" && turns == 0) {
        return None;
    }
    Some(id)
}

/// A pair found: the leader and its partner (indices into the candidates), each refitted beside
/// the other, and what each gives beside the other.
struct Pair {
    leader: usize,
    partner: usize,
    leader_fit: Refit,
    partner_fit: Refit,
    /// The leader's cut of the error left beside the partner, %, and its size with its
    /// standard error.
    leader_share: f64,
    leader_size: Option<(f64, f64)>,
    /// The partner's cut beside the leader: of the error the leader leaves, %, and of the
    /// model's error, % (the figure a candidate beyond a first one is credited with).
    partner_share: f64,
    partner_extra: f64,
    /// Why the partner is not named beside the leader (`None`: it is).
    partner_not: Option<String>,
}

/// The best pair of candidates that hide each other, when no candidate is significant alone:
/// one that names both before one that names the leader only, then the lowest cross-validated
/// error of the two refitted together.
fn best_pair(
    cands: &[Candidate],
    rejected: &[String],
    model: &WbModel,
    d: &AxisData,
    tf: &TorqueFit<'_>,
    e0: f64,
) -> Option<Pair> {
    if cands.iter().any(|c| c.significant) {
        return None;
    }
    let turns = reversals(d);
    let mut leaders: Vec<(usize, EffectId)> = (0..cands.len())
        .filter_map(|i| {
            let c = &cands[i];
            let id = single_effect(c, turns)?;
            let leads = c.error_reduction_pct >= tf.min_pct
                && !rejected.contains(&c.effect)
                && !c.evidence.contains(AT_EDGE)
                && !vetoed(&c.evidence);
            leads.then_some((i, id))
        })
        .collect();
    leaders.sort_by(|a, b| {
        cands[b.0]
            .error_reduction_pct
            .total_cmp(&cands[a.0].error_reduction_pct)
    });
    leaders.truncate(LEADERS);
    let mut best: Option<((bool, f64), Pair)> = None;
    for (li, lid) in leaders {
        let partners: Vec<usize> = (0..cands.len())
            .filter(|j| {
                single_effect(&cands[*j], turns)
                    .is_some_and(|id| id != lid && class_of(id) != class_of(lid))
            })
            .collect();
        let refs: Vec<&Candidate> = partners.iter().map(|j| &cands[*j]).collect();
        let top = Top::of(&cands[li]);
        for (pj, r) in partners
            .iter()
            .zip(beyond_top(&top, &refs, model, d, tf, e0))
        {
            if !r.cuts {
                continue;
            }
            let partner_not = r.held_back();
            let (partner_share, partner_extra) = (r.share, r.extra);
            let Some(partner_fit) = r.rescored else {
                continue;
            };
            let mut ptop = Top::of(&cands[*pj]);
            ptop.add = vec![partner_fit.effect.clone()];
            let back = beyond_top(&ptop, &[&cands[li]], model, d, tf, e0);
            // the leader, beside the partner, must be named by every rule
            let Some(Earned {
                rescored: Some(leader_fit),
                share: leader_share,
                size: leader_size,
                ..
            }) = back
                .into_iter()
                .next()
                .filter(|b| b.cuts && b.held_back().is_none())
            else {
                continue;
            };
            // a pair that names both first, then the lower error
            let key = (partner_not.is_some(), leader_fit.cv.rms);
            if best.as_ref().is_none_or(|(b, _)| key < *b) {
                best = Some((
                    key,
                    Pair {
                        leader: li,
                        partner: *pj,
                        leader_fit,
                        partner_fit,
                        leader_share,
                        leader_size,
                        partner_share,
                        partner_extra,
                        partner_not,
                    },
                ));
            }
        }
    }
    best.map(|(_, p)| p)
}

/// When no candidate is significant alone, the best pair of candidates that hide each other
/// (see the module's words; none of `rejected`, whose fits were refused) is confirmed by its fit
/// and named: the leader carries what `fit --add` is told to add (both effects, or itself alone
/// when the partner is not named) and the cut of what is added, the partner its cut beyond the
/// leader. A pair whose fit does not lower the error materially is left out, and the leader
/// says so.
pub(super) fn name_hidden_pair(
    cands: &mut [Candidate],
    rejected: &[String],
    model: &WbModel,
    d: &AxisData,
    tf: &TorqueFit<'_>,
    e0: f64,
    window_s: f64,
) -> Option<Confirmed> {
    let p = best_pair(cands, rejected, model, d, tf, e0)?;
    let (ln, pn) = (
        cands[p.leader].effect.clone(),
        cands[p.partner].effect.clone(),
    );
    let joint = (100.0 * (e0 - p.leader_fit.cv.rms) / e0).clamp(-100.0, 100.0);
    let ci = p
        .leader_size
        .map(|(_, se)| {
            format!(
                " (+-{} at {CI_SIGMAS} standard errors)",
                fmt(CI_SIGMAS * se)
            )
        })
        .unwrap_or_default();
    let mut trial = cands[p.leader].clone();
    let words = match &p.partner_not {
        None => {
            trial.add = vec![p.leader_fit.effect.clone(), p.partner_fit.effect.clone()];
            format!(
                "alone, each is hidden by the other's misfit; refitted together they lower the cross-validated error by {joint:.1} %: it cuts what {pn} leaves by {:.1} %, and {pn} what it leaves by {:.1} %, each in at least {MIN_FOLD_WINS} blocks with its size outside its own confidence interval",
                p.leader_share, p.partner_share
            )
        }
        Some(why) => format!(
            "refitted beside {pn} (which cuts what it leaves by a further {:.1} %, but is not named: {why}), it cuts what {pn} leaves by {:.1} % in at least {MIN_FOLD_WINS} blocks, and its size lies outside its own confidence interval{ci}: alone, {pn}'s misfit hid it",
            p.partner_share, p.leader_share
        ),
    };
    let outcome = confirm(&trial, model, d, window_s);
    let l = &mut cands[p.leader];
    let Ok(f) = outcome else {
        let why = outcome.err().unwrap_or_default();
        let what = if p.partner_not.is_none() {
            format!("fitting both ({ln} and {pn}) was tried: {why}")
        } else {
            why
        };
        l.evidence = format!("{}; {words}, but {what}", l.evidence);
        return None;
    };
    l.significant = true;
    let kept = reasons_start(&l.evidence).unwrap_or(l.evidence.len());
    let before = l.evidence[..kept].trim_end_matches("; ").to_string();
    if let Some(why) = &p.partner_not {
        l.evidence = format!("{before}; {words}");
        let q = &mut cands[p.partner];
        q.evidence = format!(
            "{}; beside {ln} it cuts what {ln} leaves by {:.1} % (not significant: {why}; {ln} is named beside it)",
            q.evidence, p.partner_share
        );
        return Some(f);
    }
    l.params = flat(&p.leader_fit.effect.to_table(d.kind, d.r));
    l.params
        .extend(flat(&p.partner_fit.effect.to_table(d.kind, d.r)));
    l.evidence = format!(
        "{} and {}; {words}",
        evidence(&p.leader_fit.effect, d),
        evidence(&p.partner_fit.effect, d)
    );
    l.add = trial.add;
    l.error_reduction_pct = joint;
    let q = &mut cands[p.partner];
    q.significant = true;
    // its cut beyond the leader, as any candidate beyond a first one: the leader, which carries
    // both, stays first
    q.error_reduction_pct = p.partner_extra.min(joint);
    q.evidence = format!(
        "{}; beside {ln} it cuts what {ln} leaves by {:.1} %: named together with it (see {ln})",
        evidence(&p.partner_fit.effect, d),
        p.partner_share
    );
    q.add = vec![p.partner_fit.effect];
    Some(f)
}
