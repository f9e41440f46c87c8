//! A backlash gap sized on the windowed simulation.
//!
//! The deflection channel sizes a gap by least squares: motor minus load position against the
//! flank that the transmitted torque presses on. That torque's sign says which flank is in
//! contact only while a flank carries load; while the motor crosses the gap the load floats on
//! its own inertia, and the least squares size comes out low (7.5 um for a 10 um gap on the
//! frictionless table of a shipped circle). The windowed simulation integrates the gap itself,
//! and its error is sharp in the gap's size (on that circle 110 % at 7.5 um, 16 % at 10 um,
//! 29 % at 12 um): a gap that the least squares named is therefore resized to the value whose
//! windowed simulation fits the record best, searched from half to twice the least-squares
//! size and from half to twice the size the two flanks' median deflections give (which the
//! impacts of a load bouncing between the flanks do not pull down). Where no windowed
//! simulation can be run (no loop gains, no torque), or none of the sizes tried beats the
//! least-squares one, that one stays.

use super::data::AxisData;
use super::effects::{EffectId, WbModel};
use super::lsq::{blocks, MIN_REDUCTION_PCT};
use super::refit::{deflection, flat, FOLDS};
use super::scoring::{
    blocks_lower, decimate, load_to_motor, Candidate, DEFLECTION_FLOOR_M, MIN_FOLD_WINS,
};
use super::signal::{golden_section, quantile};
use super::window::{windowed_only, WindowSim};
use super::words::evidence;

/// The factors of the least-squares gap tried first (half to twice it, about 12 % apart).
const COARSE: [f64; 13] = [
    0.5, 0.561, 0.63, 0.707, 0.794, 0.891, 1.0, 1.122, 1.26, 1.414, 1.587, 1.782, 2.0,
];

/// Golden-section steps after the coarse search (the bracket shrinks to about 2 % of it).
const GOLDEN_STEPS: usize = 8;

/// The gap's half (the coefficient of effect `i` of `model`, motor units) as the two flanks'
/// median deflections put it: the deflection residual of the model without the gap, where
/// the transmitted torque presses on one flank, against where it presses on the other.
/// Samples in the gap (either flank's torque within its dead band) and the impacts that
/// bounce the load between the flanks carry no weight in a median, as they do in a least
/// squares fit. `None` with fewer than 20 samples on either flank.
fn median_half_gap(model: &WbModel, i: usize, d: &AxisData) -> Option<f64> {
    let flank = model.effects[i].columns(d).into_iter().next()?;
    let mut without = model.clone();
    without.effects.remove(i);
    let (rd, _) = deflection(&without, d)?;
    let (a, b) = d.range;
    let side = |s: f64| -> Vec<f64> { (a..b).filter(|k| flank[*k] == s).map(|k| rd[k]).collect() };
    let (pos, neg) = (side(1.0), side(-1.0));
    if pos.len() < 20 || neg.len() < 20 {
        return None;
    }
    let h = 0.5 * (quantile(&pos, 0.5) - quantile(&neg, 0.5));
    (h.is_finite() && h > 0.0).then_some(h)
}

/// Resizes the `backlash` effect of `model` to the gap whose windowed simulation on `d` fits
/// best (see the module's note); a model without one, or without a windowed simulation, is
/// left as it is.
pub(super) fn size_gaps_on_window(model: &mut WbModel, d: &AxisData, window_s: f64) {
    let Some(i) = model
        .effects
        .iter()
        .position(|e| e.id == EffectId::Backlash)
    else {
        return;
    };
    // a least squares that sized no gap (a load floating across it): the flanks' medians seed
    // the search
    let mut g0 = model.effects[i].coef[0];
    if !(g0.is_finite() && g0 > 0.0) {
        match median_half_gap(model, i, d) {
            Some(m) => {
                model.effects[i].coef[0] = m;
                g0 = m;
            }
            None => return,
        }
    }
    let error_at = |g: f64| -> Option<f64> {
        let mut trial = model.clone();
        trial.effects[i].coef[0] = g;
        windowed_only(&trial, d, window_s)
            .headline_nrmse_pct()
            .filter(|e| e.is_finite())
    };
    let Some(e0) = error_at(g0) else { return };
    // (factor of the least-squares gap, its windowed simulation error)
    let mut best = (1.0, e0);
    let mut factors: Vec<f64> = COARSE.iter().copied().filter(|f| *f != 1.0).collect();
    if let Some(m) = median_half_gap(model, i, d).filter(|m| (m / g0 - 1.0).abs() > 0.05) {
        factors.extend(COARSE.iter().map(|f| f * m / g0));
    }
    for f in factors {
        if let Some(e) = error_at(g0 * f).filter(|e| *e < best.1) {
            best = (f, e);
        }
    }
    // golden section on the log of the factor, within one coarse step each side, keeping the
    // best point it evaluates
    let step = 1.122f64.ln();
    golden_section(best.0.ln() - step, best.0.ln() + step, GOLDEN_STEPS, |x| {
        let e = error_at(g0 * x.exp()).unwrap_or(f64::INFINITY);
        if e < best.1 {
            best = (x.exp(), e);
        }
        e
    });
    if best.0 != 1.0 {
        model.effects[i].coef[0] = g0 * best.0;
    }
}

/// The words of a candidate whose gap the windowed simulation sized.
pub(super) const WINDOW_SIZED: &str =
    "; sized on the windowed simulation, which integrates the gap";

/// How much wider than the least squares the flanks' medians must put a gap before the windowed
/// simulation is asked: a load that floats across its gap drags the least-squares size down by
/// far more than this (a fifth of the medians' size on a 30 um gap of a shipped circle), while on
/// a load that stays on its flanks the two agree within the noise.
const FLOATING_RATIO: f64 = 1.5;

/// Mean square of `x` over each block.
fn block_mse(x: &[f64], bl: &[(usize, usize)]) -> Vec<f64> {
    bl.iter()
        .map(|(a, b)| x[*a..*b].iter().map(|v| v * v).sum::<f64>() / (b - a).max(1) as f64)
        .collect()
}

/// A `backlash` candidate the deflection's least squares left not significant, scored where a
/// wide gap shows: the transmitted torque's sign says which flank is in contact only while one
/// is; a load with little friction floats across a wide gap, rattling between the flanks, and
/// the least squares then sizes the gap low and cuts nothing (a 30 um gap on the frictionless
/// table of a shipped circle: 5.1 um, -0.5 %), while the flanks' medians still see it. When the
/// medians put the gap [`FLOATING_RATIO`] times wider than the least squares, the gap is sized
/// on the windowed simulation as `fit` sizes it, and the candidate takes the cut of that
/// simulation's error; it is significant when that cut reaches [`MIN_REDUCTION_PCT`] and the
/// error falls in [`MIN_FOLD_WINS`] of [`FOLDS`] blocks of the record. Only where the plant
/// simulator runs the model (the one-body approximation has no gap).
pub(super) fn score_floating_gap(
    cands: &mut [Candidate],
    model: &WbModel,
    d: &AxisData,
    window_s: f64,
) {
    let Some(c) = cands
        .iter_mut()
        .find(|c| c.effect == EffectId::Backlash.id() && !c.significant && c.add.len() == 1)
    else {
        return;
    };
    let mut trial = model.clone();
    trial.effects.push(c.add[0].clone());
    let i = trial.effects.len() - 1;
    let g0 = trial.effects[i].coef[0];
    let Some(m) = median_half_gap(&trial, i, d) else {
        return;
    };
    if m < FLOATING_RATIO * g0.max(0.0) || 2.0 * m < DEFLECTION_FLOOR_M * load_to_motor(d) {
        return;
    }
    let without = windowed_only(model, d, window_s);
    if !without.on_plant() || without.headline_nrmse_pct().is_none() {
        return;
    }
    size_gaps_on_window(&mut trial, d, window_s);
    let with = windowed_only(&trial, d, window_s);
    if !with.on_plant() {
        return;
    }
    let Some((red, wins)) = window_cut(&without, &with, d) else {
        return;
    };
    let e = trial.effects[i].clone();
    let (lsq, lsq_cut) = (evidence(&c.add[0], d), c.error_reduction_pct);
    let (a, b) = d.range;
    if red >= MIN_REDUCTION_PCT && wins >= MIN_FOLD_WINS {
        c.significant = true;
        c.error_reduction_pct = red.min(100.0);
        c.params = flat(&e.to_table(d.kind, d.r));
        c.contribution = decimate(&e.contribution(d), a, b);
        c.evidence = format!(
            "{}{WINDOW_SIZED}: it cuts that error by {red:.1} % and lowers it in {wins} of {FOLDS} blocks (the deflection's least squares, {lsq}, cut {lsq_cut:.1} % and was not significant: the load floats across the gap, where the transmitted torque's sign does not say which flank it is on)",
            evidence(&e, d)
        );
        c.add = vec![e];
    } else {
        c.evidence = format!(
            "{}; sized on the windowed simulation ({}) it cuts that error by only {red:.1} %, in {wins} of {FOLDS} blocks",
            c.evidence,
            evidence(&e, d)
        );
    }
}

/// The cut of the headline windowed simulation error from `without` to `with`, %, and the
/// number of [`FOLDS`] blocks of the record in which it falls.
fn window_cut(without: &WindowSim, with: &WindowSim, d: &AxisData) -> Option<(f64, usize)> {
    let (e0, e1) = (
        without.channels.first()?.window_rms,
        with.channels.first()?.window_rms,
    );
    if !(e0.is_finite() && e1.is_finite() && e0 > 0.0) {
        return None;
    }
    let bl = blocks(d.range, FOLDS);
    let (m0, m1) = (
        block_mse(&without.residual, &bl),
        block_mse(&with.residual, &bl),
    );
    let wins = blocks_lower(&m1, &m0);
    Some(((100.0 * (e0 - e1) / e0).clamp(-100.0, 100.0), wins))
}
