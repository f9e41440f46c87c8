//! The candidates of the controller channel: a clamp (with its anti-windup form), an input added
//! after the controller, a law that differs, each named from the recorded torque against the
//! model's controller law.

use std::collections::BTreeMap;

use super::controller::{at_limit, ControllerChannel, Event};
use super::data::AxisData;
use super::effects::{Effect, EffectId, Side, WbModel};
use super::lsq::blocks;
use super::refit::{cv_cols, flat, FOLDS};
use super::scoring::*;
use super::signal::quantile;
use super::words::{class_of, fmt};
use feedloop_model::model::AxisKind;

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
pub(super) fn largest_at(c: &ControllerChannel, d: &AxisData) -> f64 {
    let (a, b) = c.range;
    let k = (a..b)
        .max_by(|&i, &j| c.residual[i].abs().total_cmp(&c.residual[j].abs()))
        .unwrap_or(a);
    d.t[k]
}

/// Torque unit of the axis kind.
pub(super) fn torque_unit(kind: AxisKind) -> &'static str {
    if kind == AxisKind::Rigid {
        "N"
    } else {
        "N m"
    }
}

/// Candidates of the controller channel, when the record departs from the law beyond its
/// noise: a clamp of the drive recorded after clamping (`torque_saturation`, see
/// [`clamp_candidate`]), then, on what is left, an input added after the controller when the
/// departure is concentrated in time (`added_input`, reported as events, see
/// [`added_input_candidate`]), or else a law that differs (`controller_law`, see
/// [`law_candidate`]). A torque-channel candidate of the same id that is not significant gives
/// way to the controller channel's. Scores are % of the controller residual's RMS.
pub(super) fn controller_candidates(
    model: &WbModel,
    d: &AxisData,
    cc: &ControllerChannel,
    cands: &mut Vec<Candidate>,
) {
    if !cc.fails() {
        return;
    }
    let rest = clamp_candidate(model, d, cc, cands).unwrap_or_else(|| cc.clone());
    if !rest.fails() {
        return;
    }
    let events = rest.events(d);
    let (share, time) = rest.event_shares(&events);
    // a departure that follows the motion (the acceleration by which a velocity estimate other
    // than the drive's lags or leads, or a feed-forward of velocity or acceleration the model's
    // [controller] does not have) is a law that differs, not an input added after it (the
    // law's output itself is no test: in a closed loop it reacts to any added input)
    let kv = model.file.controller.kv.unwrap_or(1.0);
    let acc: Vec<f64> = d.am.iter().map(|x| kv * x).collect();
    let bl = blocks(rest.range, FOLDS);
    let follows = cv_cols(&[&acc, &d.vm], &[], &rest.residual, &bl);
    let law_like = follows.rms < (0.5f64).sqrt() * rest.rms;
    if !law_like && !events.is_empty() && share >= 50.0 && time <= 75.0 {
        cands.push(added_input_candidate(d, cc, &rest, &events, share, time));
        return;
    }
    cands.push(law_candidate(d, cc, &rest, &bl));
}

/// The clamp candidate, pushed onto `cands` when a clamp at the largest recorded magnitude
/// (with its anti-windup form) lowers the departure materially beyond the noise; then the
/// channel with the clamp inside the law, what is left for the other candidates (`None`: the
/// channel as it was).
fn clamp_candidate(
    model: &WbModel,
    d: &AxisData,
    cc: &ControllerChannel,
    cands: &mut Vec<Candidate>,
) -> Option<ControllerChannel> {
    let tu = torque_unit(d.kind);
    let (a, b) = cc.range;
    let noise2 = 9.0 * cc.noise_rms * cc.noise_rms;
    let (l, after, aw) = cc.clamp_fit(d)?;
    let red = 100.0 * (cc.rms - after) / cc.rms;
    if !(red >= MIN_REDUCTION_PCT && cc.rms * cc.rms - after * after > noise2) {
        return None;
    }
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
            "the recorded torque sits at +-{} {tu} in {} samples ({:.1} % of the time) where the controller law asks for more{}: the drive clamps and records the clamped value, {}",
            fmt(l),
            at_limit,
            100.0 * at_limit as f64 / (b - a) as f64,
            lc.map(|x| format!(" (the controller's own limit is {} {tu})", fmt(x)))
                .unwrap_or_default(),
            aw.map(|aw| format!("with {}", aw.words())).unwrap_or_else(|| "the law otherwise unchanged".into())
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
    ControllerChannel::with_anti_windup(&with, d, aw)
}

/// The candidate of an input added after the controller, from the stretches `events` where
/// what is left (`rest`) departs (`share` % of the departure in `time` % of the time): their
/// count, median size, first start and spacing when regular.
fn added_input_candidate(
    d: &AxisData,
    cc: &ControllerChannel,
    rest: &ControllerChannel,
    events: &[Event],
    share: f64,
    time: f64,
) -> Candidate {
    let tu = torque_unit(d.kind);
    let (a, b) = cc.range;
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
    Candidate {
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
    }
}

/// The candidate of a law that differs: the record as a gain on the law plus an offset,
/// cross-validated over blocks `bl`.
fn law_candidate(
    d: &AxisData,
    cc: &ControllerChannel,
    rest: &ControllerChannel,
    bl: &[(usize, usize)],
) -> Candidate {
    let tu = torque_unit(d.kind);
    let (a, b) = cc.range;
    let one = vec![1.0; d.len()];
    let cv = cv_cols(&[&rest.law, &one], &[], &rest.residual, bl);
    let red = 100.0 * (rest.rms - cv.rms) / rest.rms;
    let mut params = BTreeMap::new();
    params.insert("gain".to_string(), 1.0 + cv.theta[0]);
    params.insert("offset".to_string(), cv.theta[1]);
    Candidate {
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
    }
}
