//! The refit of one candidate: an effect's best variant fitted together with the base
//! parameters, shared by `diagnose` (which ranks candidates by it) and `fit` (which adds what was
//! asked for), so that the cut a diagnosis announces is the cut a fit delivers.

use std::collections::BTreeMap;

use rayon::prelude::*;

use feedloop_model::model::AxisKind;

use super::base::{BaseClass, BaseParam};
use super::data::AxisData;
use super::effects::{channel, Channel, Effect, EffectId, Side, WbModel};
use super::grids::{hyper_grid, logspace, widened_grid};
use super::lsq::{
    blocks, blocks_of_rows, cross_validate, material_cut, normals_masked, Cv, CI_SIGMAS,
};
use super::pinned::held_at_controller_limit;
use super::side::{other_side, simulation_prefers, taken};
use super::signal::{golden_section, quantile};
use feedloop_model::units::sig;

/// Folds of the blocked cross-validation.
pub const FOLDS: usize = 5;

/// Samples from which a trace counts as long: the grids of column effects are then searched on
/// a decimated copy (see [`best_effect`]).
pub const LONG_TRACE: usize = 500_000;

/// Cross-validates `extra` columns together with `base` columns on target `y`.
pub fn cv_cols(base: &[&[f64]], extra: &[&[f64]], y: &[f64], bl: &[(usize, usize)]) -> Cv {
    cv_cols_masked(base, extra, y, bl, None)
}

/// [`cv_cols`] over the rows where `mask` (when given) is not 0.
pub fn cv_cols_masked(
    base: &[&[f64]],
    extra: &[&[f64]],
    y: &[f64],
    bl: &[(usize, usize)],
    mask: Option<&[f64]>,
) -> Cv {
    let mut cols: Vec<&[f64]> = base.to_vec();
    cols.extend_from_slice(extra);
    cross_validate(&normals_masked(&cols, y, bl, mask))
}

/// Rows of the torque channel that carry information about the candidates: all but the
/// standstills (below 2 % of the top speed for more than 20 ms, as `compare` classifies them).
/// At a standstill dry friction takes whatever torque the loop applies below its breakaway level
/// (a hunting velocity loop moves it about while nothing moves), which no velocity-driven law
/// describes and a torque clamp would wrongly claim. `None` when fewer than a fifth of the rows
/// move (or all do).
pub fn moving_mask(d: &AxisData) -> Option<Vec<f64>> {
    let kinds = super::compare::classify(d);
    let (a, b) = d.range;
    let mask: Vec<f64> = kinds
        .iter()
        .map(|k| {
            if *k == super::compare::SegKind::Standstill {
                0.0
            } else {
                1.0
            }
        })
        .collect();
    let moving = mask[a..b].iter().filter(|w| **w != 0.0).count();
    (moving < b - a && 5 * moving >= b - a).then_some(mask)
}

pub(crate) fn default_side(kind: AxisKind) -> Side {
    if kind == AxisKind::BallScrew {
        Side::Load
    } else {
        Side::Motor
    }
}

/// Nonlinear parameters of the backlash column: the model's `JM`, `DM` (to form the torque the
/// screw transmits) and a dead band of 5 % of that torque's range, inside which the flank in
/// contact is undetermined. `None` without a 2-mass model or a torque column.
pub fn backlash_hyper(model: &WbModel, d: &AxisData) -> Option<Vec<f64>> {
    let t = model.file.plant.two_mass()?;
    let y = d.torque.as_ref()?;
    let (a, b) = d.range;
    let tr: Vec<f64> = (a..b)
        .map(|k| (y[k] - t.jm_kgm2 * d.am[k] - t.dm_nms_per_rad * d.vm[k]).abs())
        .collect();
    Some(vec![
        t.jm_kgm2,
        t.dm_nms_per_rad,
        0.05 * quantile(&tr, 0.99),
    ])
}

/// The current values of the inertias (and the mass) among `keys`, 0 for the other keys: what
/// [`best_effect`] keeps physical.
pub fn inertias_now(model: &WbModel, keys: &[BaseParam]) -> Vec<f64> {
    keys.iter()
        .map(|k| match k.class() {
            BaseClass::Inertia => model.base_value(*k),
            BaseClass::Damping => 0.0,
        })
        .collect()
}

/// The coefficients of the effects already in a model, refitted beside the base parameters:
/// whatever a diagnosis or a fit adds competes with the model refitted whole (its offsets and
/// friction levels cross-validated too), not with values fitted once on all the samples.
#[derive(Debug, Clone, Default)]
pub struct Released {
    /// Their regressor columns (torque needed per unit change of each coefficient).
    pub cols: Vec<Vec<f64>>,
    /// For each column: the index of the effect in the model and of the coefficient.
    pub slots: Vec<(usize, usize)>,
}

impl Released {
    /// The torque-channel effects of `model` whose ids `only` lists (all when `None`).
    pub fn of(model: &WbModel, d: &AxisData, only: Option<&[EffectId]>) -> Self {
        let mut r = Released::default();
        for (i, e) in model.effects.iter().enumerate() {
            if channel(e.id) != Channel::Torque || only.is_some_and(|o| !o.contains(&e.id)) {
                continue;
            }
            for (j, c) in e.columns(d).into_iter().take(e.free_count()).enumerate() {
                r.cols.push(c);
                r.slots.push((i, j));
            }
        }
        r
    }

    /// The name of each column's parameter in a sentence (`constant_force`).
    pub fn names(&self, model: &WbModel) -> Vec<String> {
        self.slots
            .iter()
            .map(|(i, _)| model.effects[*i].id.id().to_string())
            .collect()
    }

    /// Whether change `delta` of column `k` keeps its coefficient in range (see
    /// [`Effect::coef_in_range`]).
    pub fn in_range(&self, model: &WbModel, k: usize, delta: f64) -> bool {
        let (i, j) = self.slots[k];
        let e = &model.effects[i];
        e.coef_in_range(j, e.coef[j] + delta)
    }

    /// `model` with each coefficient changed by its `delta`.
    pub fn apply(&self, model: &mut WbModel, delta: &[f64]) {
        for ((i, j), dv) in self.slots.iter().zip(delta) {
            model.effects[*i].coef[*j] += dv;
        }
    }
}

/// The best variant of one effect refitted with the base parameters: the effect with its
/// fitted coefficients, the cross-validation of the joint fit, and the base parameters held at
/// their values because the data cannot determine them together with the effect.
#[derive(Debug, Clone)]
pub struct Refit {
    /// The effect, coefficients fitted.
    pub effect: Effect,
    /// Cross-validation of the joint fit; `theta`, `theta_se` and each of `loo_theta` list every
    /// base column (0 for a held one) followed by the effect's coefficients.
    pub cv: Cv,
    /// Indices of the base columns held at their values.
    pub held: Vec<usize>,
    /// Why its nonlinear parameter is doubtful: it lies at an edge of the range searched that is
    /// no physical bound, so the best value may lie beyond (`None`: inside the range).
    pub doubtful: Option<String>,
}

/// Why an effect could not be refitted on a trace (a sentence for `untested` and for the error
/// of `fit --add`).
pub type Untestable = String;

/// Best-scoring variant of effect `id` on `y` with `base` columns free (see [`Refit`]).
/// `base_now` holds the current values of the base parameters whose columns are `base` (0 for
/// those not checked, empty when those columns are not base parameters; see [`inertias_now`]):
/// a joint fit that would take one of them to less than a tenth of its value (an inertia or a
/// mass that the effect makes vanish) cannot tell the two apart, so that parameter is held at
/// its value and the effect refitted without it. An effect that no variant fits physically is
/// [`Untestable`], with the reason. In steps: the grid ([`search_grid`]), its decimated
/// pre-search on a long trace ([`presearch_decimated`]), every point scored by the joint fit
/// ([`Scorer::eval`], [`Scorer::best_on`]) and a continuous parameter refined
/// ([`Scorer::refine`]).
#[allow(clippy::too_many_arguments)]
pub fn best_effect(
    id: EffectId,
    model: &WbModel,
    d: &AxisData,
    base: &[&[f64]],
    base_now: &[f64],
    y: &[f64],
    bl: &[(usize, usize)],
    mask: Option<&[f64]>,
) -> Result<Refit, Untestable> {
    let p = Problem {
        model,
        d,
        base,
        base_now,
        y,
        bl,
        mask,
    };
    let side = default_side(d.kind);
    let Some(other) = other_side(id, model, d, side) else {
        return best_on_side(id, side, p);
    };
    // a friction that replaces one refines that one's curve, on its side; a side that carries
    // a dry friction already takes no second one, so the other side is the one left
    match (model.replaced_side, taken(model, side), taken(model, other)) {
        (Some(s), ..) => best_on_side(id, s, p),
        (None, true, false) => best_on_side(id, other, p),
        (None, false, true) => best_on_side(id, side, p),
        (None, true, true) | (None, false, false) => {
            match (best_on_side(id, side, p), best_on_side(id, other, p)) {
                // the side whose model simulates the record better (see [`super::side`]); where
                // neither does (a play between motor and load rings alike with both), the side
                // whose torque balance fits materially better (the play makes the load reverse
                // later, which the balance sees); else the default side
                (Ok(a), Ok(b)) => {
                    let second = simulation_prefers(&a.effect, &b.effect, model, d)
                        .unwrap_or_else(|| material_cut(a.cv.rms, b.cv.rms));
                    Ok(if second { b } else { a })
                }
                (Err(_), Ok(b)) => Ok(b),
                (first, _) => first,
            }
        }
    }
}

/// [`best_effect`] with the effect on `side`.
fn best_on_side(id: EffectId, side: Side, p: Problem<'_>) -> Result<Refit, Untestable> {
    let (model, d) = (p.model, p.d);
    let mut grid = search_grid(id, model, d)?;
    let mut searched = grid.clone();
    if let Some(h) = presearch_decimated(id, side, &p, grid.len()) {
        grid = vec![h];
    }
    let scorer = Scorer {
        id,
        side,
        needed: (channel(id) == Channel::TorquePath).then(|| model.torque_needed(d)),
        // a base column that the effect's own columns span (the damping beside a friction with
        // viscous slopes) cannot be refitted beside it: held from the start
        collinear: held_from_start(id, model, d, p.base, p.base_now),
        p,
    };
    let (mut best, reason) = scorer.best_on(&grid);
    // a continuous parameter (a time constant, a limit, a mode's frequency, a Stribeck velocity,
    // a lost motion's transition): refined between the grid's neighbours of the best point (the
    // grid's step alone sized a Stribeck velocity of 1 rad/s at 0.912 rad/s)
    if let Some(b) = best.as_ref().filter(|_| refines_first(id)) {
        if let Some(r) = scorer.refine(&grid, &b.effect.hyper) {
            if r.cv.rms < b.cv.rms {
                best = Some(r);
            }
        }
    }
    let mut best =
        best.ok_or_else(|| reason.unwrap_or_else(|| "no variant could be fitted".into()))?;
    // a best point at an edge of the range searched: the search goes on beyond that edge, as
    // far as the effect's physics allows; what still lies at the new edge is doubtful
    if let (Some(_), Some(&first)) = (
        at_edge(id, &searched, &best.effect.hyper),
        best.effect.hyper.first(),
    ) {
        let wider = widened_grid(id, d, &searched, first);
        if !wider.is_empty() {
            if let (Some(w), _) = scorer.best_on(&wider) {
                if w.cv.rms < best.cv.rms {
                    best = w;
                }
            }
            searched.extend(wider);
        }
    }
    best.doubtful = at_edge(id, &searched, &best.effect.hyper);
    Ok(best)
}

/// Whether effect `id`'s first nonlinear parameter varies continuously and is refined after
/// the grid: a time constant, a limit, a mode's frequency, a Stribeck velocity, a lost motion's
/// transition. The others are integers (a delay, a cogging's periods per revolution), the
/// record's own (a backlash's dead band, a pitch's lead) or searched over a span (an
/// unbalance's period). The second parameters stay on their grids: a Stribeck exponent is a
/// shape, a mode's damping ratio a class (lightly damped, or a broad-band correction from 0.3
/// on, which a refined value would blur).
fn refines_first(id: EffectId) -> bool {
    match id {
        EffectId::CurrentLag
        | EffectId::TorqueSaturation
        | EffectId::StribeckFriction
        | EffectId::LostMotion
        | EffectId::ThirdMass => true,
        EffectId::Delay
        | EffectId::Cogging
        | EffectId::PitchError
        | EffectId::Unbalance
        | EffectId::Backlash
        | EffectId::ViscousFriction
        | EffectId::CoulombFriction
        | EffectId::ConstantForce
        | EffectId::DirectionalFriction => false,
    }
}

/// The nonlinear parameters searched for effect `id` (a backlash's from the model when it has
/// one), or why there is nothing to search on this trace.
fn search_grid(id: EffectId, model: &WbModel, d: &AxisData) -> Result<Vec<Vec<f64>>, Untestable> {
    let mut grid = hyper_grid(id, d);
    if id == EffectId::Backlash {
        if let Some(h) = backlash_hyper(model, d) {
            grid = vec![h];
        }
    }
    if id == EffectId::TorqueSaturation && held_at_controller_limit(model, d) {
        // a drive that clamps far below what its controller asks for keeps the recorded torque
        // at the controller's limit most of the time: no quantile of the record bounds the
        // drive's limit from below, so the search starts at a hundredth of the peak
        if let Some(hi) = grid
            .iter()
            .filter_map(|h| h.first().copied())
            .reduce(f64::max)
        {
            grid = logspace(hi / 100.0, hi, 40)
                .into_iter()
                .map(|l| vec![l])
                .collect();
        }
    }
    if grid.is_empty() {
        return Err(match channel(id) {
            Channel::TorquePath => format!(
                "needs the recorded torque `{}.torque` (it changes the applied torque)",
                d.axis
            ),
            Channel::Torque | Channel::Deflection => "nothing to search on this trace".into(),
        });
    }
    Ok(grid)
}

/// On a long trace, the grid (of `points` points) of an effect with regressor columns is
/// searched on a decimated copy (the filtered signals are band-limited to the cut-off) and only
/// its best point is scored on all samples: that point, when the pre-search found one.
fn presearch_decimated(
    id: EffectId,
    side: Side,
    p: &Problem<'_>,
    points: usize,
) -> Option<Vec<f64>> {
    let d = p.d;
    let q = ((1.0 / (d.dt * 10.0 * d.cutoff_hz)).floor() as usize).max(1);
    if !(channel(id) == Channel::Torque && points > 1 && q > 1 && d.len() >= LONG_TRACE) {
        return None;
    }
    let dd = d.decimated(q);
    let dec = |x: &[f64]| x.iter().step_by(q).copied().collect::<Vec<f64>>();
    let base_d: Vec<Vec<f64>> = p.base.iter().map(|c| dec(c)).collect();
    let base_r: Vec<&[f64]> = base_d.iter().map(|c| c.as_slice()).collect();
    let y_d = dec(p.y);
    let mask_d = p.mask.map(dec);
    let bl_d = blocks_of_rows(dd.range, p.bl.len(), mask_d.as_deref());
    let pd = Problem {
        model: p.model,
        d: &dd,
        base: &base_r,
        base_now: p.base_now,
        y: &y_d,
        bl: &bl_d,
        mask: mask_d.as_deref(),
    };
    best_on_side(id, side, pd).ok().map(|r| r.effect.hyper)
}

/// The base columns an effect is refitted without from the start: those its own columns span
/// ([`spanned_base`]), and for a torque saturation on a record held at the controller's limit
/// the inertias: where the clamp binds, the applied torque's scale and the inertia trade off
/// exactly (a tenth of the limit fits as well with a tenth of the inertia), so the clamp is
/// found against the inertias as they are.
fn held_from_start(
    id: EffectId,
    model: &WbModel,
    d: &AxisData,
    base: &[&[f64]],
    base_now: &[f64],
) -> Vec<usize> {
    let mut held = spanned_base(id, d, base);
    if id == EffectId::TorqueSaturation && held_at_controller_limit(model, d) {
        held.extend((0..base.len()).filter(|i| base_now.get(*i).is_some_and(|v| *v > 0.0)));
        held.sort_unstable();
        held.dedup();
    }
    held
}

/// What an effect is refitted on (the arguments of [`best_effect`]).
#[derive(Clone, Copy)]
struct Problem<'a> {
    model: &'a WbModel,
    d: &'a AxisData,
    base: &'a [&'a [f64]],
    base_now: &'a [f64],
    y: &'a [f64],
    bl: &'a [(usize, usize)],
    mask: Option<&'a [f64]>,
}

/// What one point of an effect's grid is scored with (see [`best_effect`]).
struct Scorer<'a> {
    id: EffectId,
    side: Side,
    p: Problem<'a>,
    /// The torque the model needs, for an effect on the torque path (it changes the target).
    needed: Option<Vec<f64>>,
    /// Base columns held from the start (see [`spanned_base`]).
    collinear: Vec<usize>,
}

impl Scorer<'_> {
    /// The effect at nonlinear parameters `h` refitted with the base parameters, or why it does
    /// not fit physically there.
    fn eval(&self, h: Vec<f64>) -> Result<Refit, Untestable> {
        let (id, d, nb) = (self.id, self.p.d, self.p.base.len());
        let e = Effect::new(id, self.side, h);
        let target: Option<Vec<f64>> = match &self.needed {
            Some(needed) => {
                let mut with = self.p.model.clone();
                with.effects.push(e.clone());
                let t = with
                    .applied(d)
                    .ok_or_else(|| format!("needs the recorded torque `{}.torque`", d.axis))?;
                // the balance's residual as the channel's own (the model's dry friction sticking
                // at rest), so that the cut is measured against the same target as the
                // reference refit and the equation error `fit` reports
                Some(with.balance_residual(d, &t, needed))
            }
            None => None,
        };
        let cols = match &self.needed {
            Some(_) => vec![],
            None => e.columns(d),
        };
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        let y = target.as_deref().unwrap_or(self.p.y);
        let (cv, held) = self.joint_fit(&refs, y);
        physical(id, &e, &cv, nb)?;
        let mut e = e;
        for (i, c) in e.coef.iter_mut().enumerate() {
            *c = cv.theta.get(nb + i).copied().unwrap_or(0.0);
        }
        Ok(Refit {
            effect: e,
            cv,
            held,
            doubtful: None,
        })
    }

    /// The cross-validated fit of the effect's columns `refs` with the base columns on `y`, the
    /// base columns held at their values where the joint fit would make them vanish; and those
    /// held.
    fn joint_fit(&self, refs: &[&[f64]], y: &[f64]) -> (Cv, Vec<usize>) {
        let nb = self.p.base.len();
        let mut held: Vec<usize> = self.collinear.clone();
        let cv = loop {
            let free: Vec<&[f64]> = (0..nb)
                .filter(|i| !held.contains(i))
                .map(|i| self.p.base[i])
                .collect();
            let cv = expand(
                cv_cols_masked(&free, refs, y, self.p.bl, self.p.mask),
                nb,
                &held,
            );
            let vanishing: Vec<usize> = self
                .p
                .base_now
                .iter()
                .enumerate()
                .filter(|(i, v)| {
                    !held.contains(i)
                        && **v > 0.0
                        && *v + cv.theta.get(*i).copied().unwrap_or(0.0) < 0.1 * *v
                })
                .map(|(i, _)| i)
                .collect();
            if vanishing.is_empty() {
                break cv;
            }
            held.extend(vanishing);
            held.sort_unstable();
        };
        (cv, held)
    }

    /// The best of the grid's points (the first on a tie, so the result does not depend on the
    /// thread count: the points are independent and scored in parallel) and the first reason a
    /// point did not fit.
    fn best_on(&self, grid: &[Vec<f64>]) -> (Option<Refit>, Option<Untestable>) {
        let scored: Vec<Result<Refit, Untestable>> =
            grid.par_iter().map(|h| self.eval(h.clone())).collect();
        let mut best: Option<Refit> = None;
        let mut reason: Option<Untestable> = None;
        for r in scored {
            match r {
                Ok(r) => {
                    if best.as_ref().map(|b| r.cv.rms < b.cv.rms).unwrap_or(true) {
                        best = Some(r);
                    }
                }
                Err(why) => {
                    reason.get_or_insert(why);
                }
            }
        }
        (best, reason)
    }

    /// The refit at the minimum of a golden-section search on the logarithm of the first
    /// parameter between the grid's values next to the point `best` (its other parameters
    /// held): `None` when the grid has no other positive value of it.
    fn refine(&self, grid: &[Vec<f64>], best: &[f64]) -> Option<Refit> {
        let x0 = *best.first()?;
        if x0 <= 0.0 {
            return None;
        }
        let values = || grid.iter().filter_map(|h| h.first().copied());
        let lo = values()
            .filter(|v| *v > 0.0 && *v < x0)
            .reduce(f64::max)
            .unwrap_or(x0);
        let hi = values().filter(|v| *v > x0).reduce(f64::min).unwrap_or(x0);
        if lo >= hi {
            return None;
        }
        let at = |x: f64| {
            let mut h = best.to_vec();
            h[0] = x;
            h
        };
        let score = |x: f64| {
            self.eval(at(x.exp()))
                .map(|r| r.cv.rms)
                .unwrap_or(f64::INFINITY)
        };
        let (a, b) = golden_section(lo.ln(), hi.ln(), 12, score);
        self.eval(at((0.5 * (a + b)).exp())).ok()
    }
}

/// Why effect `e` (fitted by `cv`, its coefficients after the `nb` base columns) is not
/// physical, for the effects that have such a bound.
fn physical(id: EffectId, e: &Effect, cv: &Cv, nb: usize) -> Result<(), Untestable> {
    // a Stribeck hump must be a rise of friction at low speed (fs >= fc), and one the data
    // tell from none: a hump inside its own confidence interval is a Coulomb friction, whose
    // fit would then be credited to the Stribeck effect
    if id == EffectId::StribeckFriction {
        let hump = cv.theta.get(nb + 1).copied().unwrap_or(0.0);
        let se = cv.theta_se.get(nb + 1).copied().unwrap_or(0.0);
        if hump < 0.0 {
            return Err(
                "its breakaway level fits below its sliding level (fs < fc) at every \
                    Stribeck velocity searched: these data show no rise of friction at low \
                    speed"
                    .into(),
            );
        }
        if hump <= CI_SIGMAS * se {
            return Err(
                "its rise of friction at low speed (fs - fc) lies inside its own confidence \
                    interval at every Stribeck velocity searched: the friction these data show \
                    is a Coulomb friction"
                    .into(),
            );
        }
    }
    // a third mass has a positive mass (a negative one is coloured noise fitted by a mode)
    if id == EffectId::ThirdMass && cv.theta.get(nb).copied().unwrap_or(0.0) <= 0.0 {
        return Err(
            "its mass fits negative at every frequency searched (coloured noise, \
                    not a mass on a spring)"
                .into(),
        );
    }
    // lost motion is a play the motor crosses by travelling it: not negative, and not
    // crossed in less travel than its own size (a negative stiffness of the spring)
    if id == EffectId::LostMotion {
        let half = cv.theta.get(nb).copied().unwrap_or(0.0);
        if half < 0.0 {
            return Err("its offset fits the wrong way (the load ahead of the motor in the direction of travel) at every transition searched".into());
        }
        if e.hyper.first().is_some_and(|t| *t < 2.0 * half) {
            return Err("it fits only with a transition shorter than the play itself, which no transmission has".into());
        }
    }
    Ok(())
}

/// The words for a nonlinear parameter `hyper` of effect `id` that lies at an edge of the range
/// `grid` searched (within 2 %, the refinement of a continuous parameter included), when that
/// edge is no physical bound: the shortest delay (one period) and one cogging period per
/// revolution are bounds; a mode's damping ratio and a Stribeck exponent are shapes, not
/// searched ranges; an unbalance's one-revolution period is the physical default, not an edge.
fn at_edge(id: EffectId, grid: &[Vec<f64>], hyper: &[f64]) -> Option<String> {
    // (the parameter's name, whether the lowest value searched is a bound, whether the grid's
    // first point is a default outside the range)
    let (name, low_is_bound, skip_first) = match id {
        EffectId::StribeckFriction => ("Stribeck velocity", false, false),
        EffectId::Cogging => ("period", false, false),
        EffectId::ThirdMass => ("frequency", false, false),
        EffectId::Delay => ("delay", true, false),
        EffectId::CurrentLag => ("time constant", false, false),
        EffectId::TorqueSaturation => ("limit", false, false),
        EffectId::Unbalance => ("period", false, true),
        EffectId::LostMotion => ("transition travel", true, false),
        EffectId::ViscousFriction
        | EffectId::CoulombFriction
        | EffectId::ConstantForce
        | EffectId::Backlash
        | EffectId::PitchError
        | EffectId::DirectionalFriction => return None,
    };
    let mut values: Vec<f64> = grid
        .iter()
        .skip(usize::from(skip_first))
        .filter_map(|h| h.first().copied())
        .collect();
    values.sort_by(f64::total_cmp);
    values.dedup();
    let v = *hyper.first()?;
    let (&lo, &hi) = (values.first()?, values.last()?);
    if values.len() < 3 {
        return None;
    }
    // a cogging period on a rotary motor is 2 pi / n: its largest value (n = 1) is the bound
    let high_is_bound = id == EffectId::Cogging && (hi - std::f64::consts::TAU).abs() < 1e-12;
    let near = |edge: f64| (v - edge).abs() <= 0.02 * edge.abs().max(1e-300);
    let edge = if near(lo) && !low_is_bound {
        "lower"
    } else if near(hi) && !high_is_bound {
        "upper"
    } else {
        return None;
    };
    Some(format!(
        "its {name} ({}) is at the {edge} edge of the range searched ({} to {}): the best value may lie beyond",
        sig(v),
        sig(lo),
        sig(hi)
    ))
}

/// The base columns among `base` that the columns of effect `id` (on its default side, at the
/// first point of its grid) span: a torque-channel effect whose columns hold a base parameter's
/// (the damping beside a friction with viscous slopes) carries that parameter.
pub fn spanned_base(id: EffectId, d: &AxisData, base: &[&[f64]]) -> Vec<usize> {
    if channel(id) != Channel::Torque {
        return Vec::new();
    }
    let Some(h) = hyper_grid(id, d).into_iter().next() else {
        return Vec::new();
    };
    let cols = Effect::new(id, default_side(d.kind), h).columns(d);
    let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    // over the rows the torque channel uses (an offset is a friction asymmetry while moving)
    let mask = moving_mask(d);
    (0..base.len())
        .filter(|i| spanned(base[*i], &refs, d.range, mask.as_deref()))
        .collect()
}

/// Whether column `b` lies in the span of `cols` over `range` (the rows where `mask`, when
/// given, is not 0): a least-squares fit of it leaves less than 1 % of its energy (a variance
/// inflation of 100: the regression cannot share it out; an offset against a filtered friction
/// asymmetry differs only in the filter's tails at the reversals).
pub(super) fn spanned(
    b: &[f64],
    cols: &[&[f64]],
    range: (usize, usize),
    mask: Option<&[f64]>,
) -> bool {
    if cols.is_empty() {
        return false;
    }
    let ne = normals_masked(cols, b, &blocks(range, 1), mask);
    let Some(n) = ne.first() else { return false };
    let th = n.solve();
    n.yty > 0.0 && n.sse(&th) < 1e-2 * n.yty
}

/// `cv` of a fit without the base columns `held` (sorted), with a 0 coefficient (and standard
/// error) inserted for each of them so that it lists all `nb` base columns.
fn expand(mut cv: Cv, nb: usize, held: &[usize]) -> Cv {
    if held.is_empty() {
        return cv;
    }
    let widen = |v: &nalgebra::DVector<f64>| {
        let mut out = Vec::with_capacity(v.len() + held.len());
        let mut src = v.iter();
        for i in 0..v.len() + held.len() {
            if i < nb && held.contains(&i) {
                out.push(0.0);
            } else {
                out.push(src.next().copied().unwrap_or(0.0));
            }
        }
        nalgebra::DVector::from_vec(out)
    };
    cv.theta = widen(&cv.theta);
    cv.theta_se = widen(&cv.theta_se);
    cv.loo_theta = cv.loo_theta.iter().map(widen).collect();
    cv
}

/// Deflection channel: (residual, base columns) when both positions are measured.
///
/// The spring transmits what the motor does not keep: `KL (thM - thL) = T - JM aM - DM vM`
/// (motor-side effects included), with `T` the applied torque when recorded (so load-side
/// friction, which also deflects the spring, is not mistaken for a gap), else the load's
/// model torque `JL aL + DL vL`. The residual is the measured deflection minus that over `KL`;
/// the base columns (the transmitted torque and a constant) correct `1 / KL` and a zero offset.
pub fn deflection(model: &WbModel, d: &AxisData) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
    let t = model.file.plant.two_mass()?;
    let _m = d.motor_raw.as_ref()?;
    let transmitted: Vec<f64> = match &d.torque {
        Some(y) => {
            let _ = y;
            let ya = model.applied(d).unwrap_or_default();
            let mut motor_side = vec![0.0; d.len()];
            for e in model
                .effects
                .iter()
                .filter(|e| channel(e.id) == Channel::Torque && e.side == Side::Motor)
            {
                for (x, c) in motor_side.iter_mut().zip(e.contribution(d)) {
                    *x += c;
                }
            }
            (0..d.len())
                .map(|k| ya[k] - t.jm_kgm2 * d.am[k] - t.dm_nms_per_rad * d.vm[k] - motor_side[k])
                .collect()
        }
        None => {
            d.al.iter()
                .zip(&d.vl)
                .map(|(a, v)| t.jl_kgm2 * a + t.dl_nms_per_rad * v)
                .collect()
        }
    };
    let mut rd: Vec<f64> = (0..d.len())
        .map(|k| (d.qm[k] - d.ql[k]) - transmitted[k] / t.kl_nm_per_rad)
        .collect();
    for e in model
        .effects
        .iter()
        .filter(|e| channel(e.id) == Channel::Deflection)
    {
        for (x, c) in rd.iter_mut().zip(e.contribution(d)) {
            *x -= c;
        }
    }
    let one = vec![1.0; d.len()];
    Some((rd, vec![transmitted, one]))
}

/// Numeric entries of an effect table, flat.
pub fn flat(t: &toml::Table) -> BTreeMap<String, f64> {
    t.iter()
        .filter_map(|(k, v)| match v {
            toml::Value::Float(f) => Some((k.clone(), *f)),
            toml::Value::Integer(i) => Some((k.clone(), *i as f64)),
            _ => None,
        })
        .collect()
}

/// `jm_kgm2 held at its value (the data cannot tell it apart from this effect ...)`, for the base
/// parameters `held` (indices into `keys`).
pub fn held_words<S: AsRef<str>>(held: &[usize], keys: &[S]) -> String {
    let names: Vec<&str> = held
        .iter()
        .filter_map(|i| keys.get(*i).map(|k| k.as_ref()))
        .collect();
    format!(
        "{} held at {} value (the data cannot tell {} apart from this effect: a joint refit would take an inertia below a tenth of its value, or the effect's own columns hold it)",
        names.join(", "),
        if names.len() == 1 { "its" } else { "their" },
        if names.len() == 1 { "it" } else { "them" },
    )
}
