//! The candidates of a diagnosis on the torque and deflection channels: one per base parameter
//! (refitted alone), one per effect of the library on the channel where it shows (refitted with
//! the base parameters and the model's own effects, see [`super::refit`]), each with its
//! evidence in words; an effect that cannot be tested goes to `untested` with its reason.

use std::collections::BTreeMap;

use super::base::BaseClass;
use super::data::AxisData;
use super::effects::{
    channel, constant_force_value, round_sig, Channel, Effect, EffectId, WbModel,
};
use super::lsq::Cv;
use super::refit::{
    backlash_hyper, best_effect, cv_cols, cv_cols_masked, default_side, deflection, flat,
    held_words, inertias_now, Refit, Released, Untestable, FOLDS,
};
use super::scoring::*;
use super::signal::{rms, std_dev};
use super::words::{class_of, constant_force_words, evidence, fmt, reversals};
use feedloop_model::model::AxisKind;
use feedloop_plant::effects::EffectParams;

/// Why a fit that cuts enough is still not significant: it wins in too few of the
/// cross-validation's blocks.
fn few_wins(wins: usize) -> String {
    format!("it lowers the cross-validated error in only {wins} of the record's {FOLDS} blocks ({MIN_FOLD_WINS} needed): not significant")
}

/// One candidate per base parameter, refitted alone.
pub(super) fn base_parameter_candidates(
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
        let new = old + delta;
        let mut params = BTreeMap::new();
        params.insert(k.to_string(), new);
        let contribution: Vec<f64> = decimate(col, a, b).iter().map(|x| x * delta).collect();
        // a change inside its own confidence interval is not a wrong value, and an inertia, a
        // damping or a stiffness below zero is no value at all
        let se = cv.theta_se[0];
        let outside = delta.abs() > CI_SIGMAS * se;
        let physical = if k.class() == BaseClass::Inertia {
            new > 0.0
        } else {
            new >= 0.0
        };
        let change = if old != 0.0 {
            format!("{:+.1} %", 100.0 * delta / old)
        } else {
            "the model has none".to_string()
        };
        let mut why = String::new();
        if !outside {
            why = ": inside its interval, not significant".into();
        } else if !physical {
            why = "; a value at or below zero is not physical: not significant".into();
        } else if red >= ch.min_pct && wins < MIN_FOLD_WINS {
            why = format!("; {}", few_wins(wins));
        }
        cands.push(Candidate {
            effect: k.to_string(),
            is_param: true,
            class: k.class().id().to_string(),
            significant: red >= ch.min_pct && wins >= MIN_FOLD_WINS && outside && physical,
            error_reduction_pct: red.clamp(-100.0, 100.0),
            evidence: format!(
                "refitting {k} alone moves it from {} to {} ({change}, +-{} at {CI_SIGMAS} standard errors){why}",
                fmt(old),
                fmt(new),
                fmt(CI_SIGMAS * se),
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
pub(super) fn effect_candidates(
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
    if let Some((rd, dcols)) = &defl {
        condition_deflection(cands, d, rd, dcols, &ch.bl);
    }
    untested
}

/// Forward selection on the deflection channel: once its best candidate (the largest cut of the
/// motor-minus-load misfit) is known, every other deflection candidate keeps its significance
/// only if it lowers the deflection's cross-validated error further, with the first one's
/// columns refitted beside it, by [`MIN_REDUCTION_PCT`] in [`MIN_FOLD_WINS`] blocks: a lead error
/// that only re-explains part of a gap's misfit is credited with its extra only.
fn condition_deflection(
    cands: &mut [Candidate],
    d: &AxisData,
    rd: &[f64],
    dcols: &[Vec<f64>],
    bl: &[(usize, usize)],
) {
    let Some(ti) = cands
        .iter()
        .enumerate()
        .filter(|(_, c)| c.channel == "deflection")
        .max_by(|a, b| a.1.error_reduction_pct.total_cmp(&b.1.error_reduction_pct))
        .map(|(i, _)| i)
    else {
        return;
    };
    let top_name = cands[ti].effect.clone();
    let top_cols: Vec<Vec<f64>> = cands[ti].add.iter().flat_map(|e| e.columns(d)).collect();
    let mut base: Vec<&[f64]> = dcols.iter().map(|c| c.as_slice()).collect();
    base.extend(top_cols.iter().map(|c| c.as_slice()));
    let reference = cv_cols(&base, &[], rd, bl);
    for (i, c) in cands.iter_mut().enumerate() {
        if i == ti || c.channel != "deflection" || !c.significant {
            continue;
        }
        let cols: Vec<Vec<f64>> = c.add.iter().flat_map(|e| e.columns(d)).collect();
        let refs: Vec<&[f64]> = cols.iter().map(|x| x.as_slice()).collect();
        let cv = cv_cols(&base, &refs, rd, bl);
        let extra =
            (100.0 * (reference.rms - cv.rms) / reference.rms.max(1e-300)).clamp(-100.0, 100.0);
        if extra < MIN_REDUCTION_PCT || fold_wins(&cv, &reference.fold_mse) < MIN_FOLD_WINS {
            c.significant = false;
            c.evidence = format!(
                "{}; beyond {top_name} it lowers the deflection's cross-validated error by only {extra:.1} % (not significant)",
                c.evidence
            );
        }
    }
}

/// `directional_friction` is Coulomb friction with levels and slopes of their own in each
/// direction: it is credited only with what it lowers the error by beyond `coulomb_friction`
/// (with its offset), and is significant only when that is material, so the simpler law is named
/// unless the data ask for the richer one. The same holds for `stribeck_friction` (see below).
pub(super) fn refine_of_coulomb(cands: &mut [Candidate], min_pct: f64) {
    let Some((coulomb, coulomb_named)) = cands
        .iter()
        .find(|c| c.effect == EffectId::CoulombFriction.id())
        .map(|c| (c.error_reduction_pct, c.significant))
    else {
        return;
    };
    for c in cands
        .iter_mut()
        .filter(|c| c.effect == EffectId::DirectionalFriction.id())
    {
        let extra = (c.error_reduction_pct - coulomb).clamp(-100.0, 100.0);
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
    // Stribeck friction is Coulomb friction with a rise at low speed: beside a Coulomb friction
    // the data name, it keeps its own cut where that rise lowers the error materially beyond
    // it (a rise the data show ranks it first), else it is credited with what it adds and not
    // named
    if !coulomb_named {
        return;
    }
    for c in cands
        .iter_mut()
        .filter(|c| c.effect == EffectId::StribeckFriction.id() && c.significant)
    {
        let extra = (c.error_reduction_pct - coulomb).clamp(-100.0, 100.0);
        if extra < min_pct {
            // credited, as directional friction is, with what it adds: it ranks below
            c.error_reduction_pct = extra;
            c.significant = false;
            c.evidence = format!(
                "{}; beyond coulomb_friction it lowers the cross-validated error by only {extra:.1} % (not significant)",
                c.evidence
            );
        }
    }
}

/// A candidate goes to the list, or its effect to `untested` with the reason it could not be
/// refitted: no effect disappears from a diagnosis.
pub(super) fn keep(
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

/// The accuracy of the best linear scales, um/m: a cumulative lead error below it is not named.
const SCALE_ACCURACY_UM_PER_M: f64 = 1.0;

/// `backlash` or `pitch_error` scored on the deflection channel (residual `rd`, base columns
/// `dcols`: compliance and zero offset).
pub(super) fn deflection_candidate(
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
    // a lead error is a periodic error of at least that size, or a cumulative one beyond the
    // accuracy of the best linear scales (1 um/m): a slope below that, however resolvable over
    // the travel, is a scale's own error or a misfit of another kind
    let lead_error = id != EffectId::PitchError
        || matches!(e.to_params(kind, d.r), EffectParams::PitchError(p)
            if p.amplitude_m >= DEFLECTION_FLOOR_M || p.slope_um_per_m.abs() >= SCALE_ACCURACY_UM_PER_M);
    let contribution = decimate(&e.contribution(d), a, b);
    let mut ev = if !resolvable {
        format!(
            "{}; below the 1 nm any feed-drive encoder resolves: not significant",
            evidence(&e, d)
        )
    } else if !lead_error {
        format!(
            "{}; its periodic part below 1 nm and its slope below the {SCALE_ACCURACY_UM_PER_M} um/m of the best linear scales: not significant",
            evidence(&e, d)
        )
    } else {
        evidence(&e, d)
    };
    let resolvable = resolvable && lead_error;
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
pub(super) fn viscous_candidate(d: &AxisData, ch: &TorqueChannel<'_>) -> Candidate {
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
    // a viscous friction below zero would feed energy into the motion: what it fits is a
    // model damping too high, which the damping parameters' own candidates name
    let physical = e.coef[0] >= 0.0;
    let mut ev = evidence(&e, d);
    if !physical {
        ev = format!("{ev}; a negative viscous friction is not physical (the model's damping is too high: see its damping parameters): not significant");
    } else if red >= ch.min_pct && wins < MIN_FOLD_WINS {
        ev = format!("{ev}; {}", few_wins(wins));
    }
    Candidate {
        effect: id.to_string(),
        is_param: false,
        class: "damping".into(),
        significant: red >= ch.min_pct && wins >= MIN_FOLD_WINS && physical,
        error_reduction_pct: red.clamp(-100.0, 100.0),
        evidence: ev,
        params,
        same_as: vec![],
        contribution: decimate(&e.contribution(d), a, b),
        add: vec![e],
        channel: "torque",
    }
}

/// Why a third-mass fit whose mass comes out zero or negative names no mode.
const NEGATIVE_MASS: &str =
    "its fitted mass is not positive, and no body on a spring has a negative mass";

/// Whether a third-mass fit carries a positive mass.
fn positive_mass(e: &Effect) -> bool {
    e.coef.first().is_some_and(|m| *m > 0.0)
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
pub(super) fn mode_candidate(
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
    // refitted on the torque channel, the mode must still carry a mass
    let physical = positive_mass(&e);
    let mut ev = format!(
        "{}; in the band up to {} Hz it lowers the error by {:.1} % beyond a refit of the base parameters",
        evidence(&e, d),
        fmt(wide_hz),
        wide.error_reduction_pct
    );
    // and cut what the torque balance counts: below it the wide band's structure is the
    // numerics of the derivatives (the true model of a clamped drive leaves it too). The whole
    // cut counts, as in its score: a mode the wide band singles out explains the inertia refit's
    // part too (a strongly excited mass behind the table cuts little beyond that refit alone)
    let material = red >= ch.min_pct;
    if !physical {
        ev = format!("{ev}; on the torque channel {NEGATIVE_MASS}: not significant");
    } else if !material && red < MIN_REDUCTION_PCT {
        ev = format!(
            "{ev}; on the torque channel it lowers the cross-validated error by only {red:.1} %: not significant"
        );
    }
    Ok(Candidate {
        effect: id.to_string(),
        is_param: false,
        class: class_of(id).into(),
        significant: physical && material,
        // a mode that the data single out ranks before the inertia refit it also explains
        error_reduction_pct: if physical { red } else { ch.cut_pct(&cv) }.clamp(-100.0, 100.0),
        evidence: ev,
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
pub(super) fn torque_effect_candidate(
    id: EffectId,
    model: &WbModel,
    d: &AxisData,
    ch: &TorqueChannel<'_>,
) -> Result<Candidate, Untestable> {
    let Some((reduced, old)) = model.without_superseded(id) else {
        return scored_candidate(id, model, d, ch, ch);
    };
    let rel = Released::of(&reduced, d, None);
    let ch_r = TorqueChannel::new(&reduced, d, &rel);
    scored_candidate(id, &reduced, d, &ch_r, ch).map(|mut c| {
        c.evidence = format!("{}; it replaces the model's {old}", c.evidence);
        c
    })
}

/// [`torque_effect_candidate`] refitted on channel `ch` (of `model`) and scored against
/// `reference` (the channel of the model it would change).
pub(super) fn scored_candidate(
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
        ev = format!("{ev}; {}", few_wins(wins));
    }
    let mut extra = extra;
    // its leading coefficient must lie outside its own confidence interval around zero
    let nb = ch.base_cols.len();
    if channel(id) == Channel::Torque {
        if let Some((_, se)) =
            leading_size(&e, &cv, nb, d).filter(|(c, se)| c.is_nan() || *c <= CI_SIGMAS * se)
        {
            significant = false;
            ev = format!("{ev}; its size is inside its own confidence interval (+-{} at {CI_SIGMAS} standard errors): not significant", fmt(CI_SIGMAS * se));
        }
    }
    if significant && id == EffectId::CoulombFriction && add.len() > 1 {
        // Coulomb friction is a step at reversals: it must earn its sign column beyond a
        // constant force, or the constant force alone is the name (gravity on an inclined axis)
        let one = vec![1.0; d.len()];
        let cv_off = cv_cols_masked(&ch.base_cols, &[&one], &ch.res, &ch.bl, mk);
        let beyond = (100.0 * (cv_off.rms - cv.rms) / ch.e0).clamp(-100.0, 100.0);
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
    if significant && id == EffectId::TorqueSaturation {
        if let Some(why) = tracks_beyond_limit(d, e.hyper[0]) {
            significant = false;
            ev = format!("{ev}; {why}: not significant");
        }
    }
    if id == EffectId::ThirdMass && !positive_mass(&e) {
        significant = false;
        ev = format!("{ev}; {NEGATIVE_MASS}: not significant");
    }
    if class_of(id) == "friction" {
        (significant, ev) = reversal_words(d, significant, ev);
    }
    let red = if significant {
        (100.0 * (reference.e0 - cv.rms) / reference.e0).max(extra)
    } else {
        extra
    };
    let contribution = contribution_of(&add, model, d, ch);
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

/// Why a drive clamp at `limit` on the recorded torque is no clamp: where the recorded torque
/// lies beyond the limit, the following error of the position the loop closes on (command less
/// position) spreads no wider about its mean than elsewhere. A drive clamped there gives less
/// torque than its loop asks and falls behind, further the longer the clamp binds; a record
/// that keeps its track while its torque sits beyond a supposed limit shows a load the model
/// lacks (a gravity that changes with the pose), not a clamp. The spread about the mean, not
/// the RMS: an offset between command and encoder says nothing about a clamp. `None` when the
/// clamp is not contradicted so, or too few samples lie on either side.
fn tracks_beyond_limit(d: &AxisData, limit: f64) -> Option<String> {
    let (a, b) = d.range;
    let rec = d.torque_raw.as_deref().or(d.torque.as_deref())?;
    if d.cmd.len() < b || rec.len() < b {
        return None;
    }
    // the position the loop closes on: of the load and the motor position, the one that
    // follows the command more closely over the record
    let load = d.load_in_motor_units();
    let spread = |x: &[f64], rows: &mut dyn Iterator<Item = usize>| {
        std_dev(&rows.map(|k| d.cmd[k] - x[k]).collect::<Vec<f64>>())
    };
    let x = match d.motor_raw.as_deref() {
        Some(m) if m.len() >= b && spread(m, &mut (a..b)) < spread(&load, &mut (a..b)) => m,
        _ => load.as_slice(),
    };
    let beyond = (a..b).filter(|&k| rec[k].abs() > limit).count();
    let enough = ((b - a) / 50).max(10);
    if beyond < enough || (b - a) - beyond < enough {
        return None;
    }
    let eb = spread(x, &mut (a..b).filter(|&k| rec[k].abs() > limit));
    let ew = spread(x, &mut (a..b).filter(|&k| rec[k].abs() <= limit));
    (eb <= ew).then(|| {
        format!(
            "where the recorded torque lies beyond it ({:.0} % of the samples) the position follows its command as closely as elsewhere (following error spread {} against {}, motor units): a clamped drive would fall behind",
            100.0 * beyond as f64 / (b - a) as f64,
            fmt(eb),
            fmt(ew)
        )
    })
}

/// A friction candidate's significance and evidence after the record's reversals are counted:
/// a friction law needs reversals to be told from an offset and a slope, and the
/// cross-validation needs them spread over its blocks (a block without one can only refit the
/// level it already saw). While the axis moves one way only, a friction level and a constant
/// torque are the same column on every row that is scored (standstills are not): the constant
/// force is the simpler name, and the friction cannot be claimed. Where too few reversals are
/// why a friction is not named, the evidence says so.
fn reversal_words(d: &AxisData, significant: bool, ev: String) -> (bool, String) {
    let turns = reversals(d);
    if turns == 0 {
        return (
            false,
            format!("{ev}; the axis moves in one direction only in this record (no reversal): a friction level cannot be told from a constant torque (constant_force carries it)"),
        );
    }
    if !significant && turns < FOLDS {
        return (
            false,
            format!("{ev}; too few reversals to judge friction ({turns} in this record, fewer than the {FOLDS} blocks of the cross-validation): record more moves in both directions"),
        );
    }
    (significant, ev)
}

/// What the effects `add` change in the torque balance of `model` on `d`: their contribution to
/// the torque needed, or the change of the applied torque for a torque-path effect.
pub(super) fn contribution_of(
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
pub(super) type WithOffset = (Vec<Effect>, Cv, BTreeMap<String, f64>, String);

/// Asymmetric Coulomb friction = Coulomb + a constant force while the axis moves: fitted
/// together and reported both, when that fits at least as well (within 2 %) as Coulomb alone
/// and the offset lies outside its confidence interval around zero.
pub(super) fn coulomb_with_offset(
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
    // interval), it is a torque a servo engineer would see (on a near noise-free record a
    // confidence interval excludes zero for a thousandth of a newton), and it does not worsen
    // the held-out error
    let off_t = cv2.theta[nb + 1].abs();
    if cv2.rms > cv.rms * 1.02 || off_t <= CI_SIGMAS * cv2.theta_se[nb + 1] || off_t < ch.material {
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
