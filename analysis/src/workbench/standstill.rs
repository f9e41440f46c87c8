//! A dry friction told from a constant torque by the standstills of a record that moves one way.
//!
//! While an axis moves one way only, a friction level and a constant torque are the same column
//! on every row the candidates are scored on (standstills are not), and the constant torque is
//! the simpler name. At a standstill they part: a constant torque (gravity on the axis, a
//! spring) keeps acting, and the drive must hold it; a dry friction sticks and takes whatever
//! torque the drive leaves it, down to none. Where the drive does not hold the constant torque
//! at rest, the torque balance at rest misses by about that torque with `constant_force` and by
//! little with a friction that sticks: the friction is the name (a rotary axis turning one way
//! with a 6 N m friction on its motor, stopping in between: the constant torque left 34.8 % of
//! equation error over the whole record, the friction 3.83 %, as the true model). Where the
//! drive holds it, both explain the standstills and the constant torque stays.

use super::data::AxisData;
use super::effects::{Effect, EffectId, WbModel};
use super::refit::flat;
use super::scoring::{decimate, Candidate};
use super::signal::{quantile, rms};
use super::words::{evidence, fmt, reversals};

/// The friction is named when the balance at rest misses by less than this fraction of what it
/// misses by with the constant torque: a drive that holds the constant torque leaves the two
/// about equal (the friction, sticking, takes what the drive gives), one that does not leaves
/// the constant torque's miss at its full size.
const HOLD_RATIO: f64 = 0.5;

/// The constant torque's miss at rest must also exceed its miss while moving this many times: a
/// drive that holds the constant torque leaves it missing at rest by the noise only, which the
/// friction (taking whatever lies within its level) always absorbs.
const REST_OVER_MOVING: f64 = 3.0;

/// Fewest standstill rows, and fewest per thousand rows of the record, that can tell the two.
const MIN_REST_ROWS: usize = 50;
const MIN_REST_PER_MILLE: usize = 20;

/// On a record without a reversal (`d`), with the standstill rows those outside `moving` (the
/// candidates' mask): when `constant_force` is significant and `coulomb_friction` with the
/// same torque while moving (a friction opposing the motion) explains the standstills where the
/// constant torque does not ([`HOLD_RATIO`], [`REST_OVER_MOVING`]), the friction takes the constant torque's score
/// and significance, and the constant torque loses it; both say why.
pub(super) fn standstill_friction(
    cands: &mut [Candidate],
    model: &WbModel,
    d: &AxisData,
    moving: Option<&[f64]>,
) {
    let Some(moving) = moving else { return };
    if reversals(d) != 0 {
        return;
    }
    let found = |id: EffectId, cands: &[Candidate]| {
        cands
            .iter()
            .position(|c| c.effect == id.id() && !c.add.is_empty())
    };
    let (Some(ic), Some(jf)) = (
        found(EffectId::ConstantForce, cands),
        found(EffectId::CoulombFriction, cands),
    ) else {
        return;
    };
    if !cands[ic].significant || cands[ic].add.len() != 1 {
        return;
    }
    let (a, b) = d.range;
    let rest: Vec<usize> = (a..b).filter(|k| moving[*k] == 0.0).collect();
    if rest.len() < MIN_REST_ROWS.max((b - a) * MIN_REST_PER_MILLE / 1000) {
        return;
    }
    let constant = cands[ic].add[0].clone();
    let Some(friction) = friction_like(&cands[jf].add[0], &constant, d, moving) else {
        return;
    };
    let on: Vec<usize> = (a..b).filter(|k| moving[*k] != 0.0).collect();
    // the RMS of the balance residual of the model with `e`, at rest and while moving
    let misses = |e: &Effect| -> Option<(f64, f64)> {
        let mut m = model.clone();
        m.effects.push(e.clone());
        let applied = m.applied(d)?;
        let needed = m.torque_needed(d);
        let r = m.balance_residual(d, &applied, &needed);
        let of = |rows: &[usize]| rms(&rows.iter().map(|k| r[*k]).collect::<Vec<_>>());
        Some((of(&rest), of(&on)))
    };
    let (Some((rc, moving_c)), Some((rf, _))) = (misses(&constant), misses(&friction)) else {
        return;
    };
    if rf.is_nan() || rc.is_nan() || rf >= HOLD_RATIO * rc || rc <= REST_OVER_MOVING * moving_c {
        return;
    }
    let share = 100.0 * rest.len() as f64 / (b - a) as f64;
    let score = cands[ic].error_reduction_pct;
    let f = &mut cands[jf];
    f.significant = true;
    f.error_reduction_pct = score;
    f.params = flat(&friction.to_table(d.kind, d.r));
    f.contribution = decimate(&friction.contribution(d), a, b);
    f.evidence = format!(
        "{}; at standstill ({share:.0} % of the record) the drive does not hold a constant torque: the torque balance at rest misses by {} with constant_force, by {} with this friction, which sticks there: a friction, not a constant torque (the axis moves one way only, so its level is the torque it takes while moving)",
        evidence(&friction, d),
        fmt(rc),
        fmt(rf)
    );
    f.add = vec![friction];
    let c = &mut cands[ic];
    c.significant = false;
    c.evidence = format!(
        "{}; at standstill the drive does not hold it (the torque balance at rest misses by {} with it, by {} with coulomb_friction, which sticks): coulomb_friction is named instead",
        c.evidence,
        fmt(rc),
        fmt(rf)
    );
}

/// The Coulomb friction (of `coulomb`'s side) that takes the torque of `constant` on the rows
/// that move: `None` when that torque drives the motion instead of opposing it (no friction).
fn friction_like(
    coulomb: &Effect,
    constant: &Effect,
    d: &AxisData,
    moving: &[f64],
) -> Option<Effect> {
    let mut f = coulomb.clone();
    f.coef = vec![1.0, 0.0];
    let unit = f.contribution(d);
    let (a, b) = d.range;
    let on: Vec<f64> = (a..b)
        .filter(|k| moving[*k] != 0.0)
        .map(|k| unit[k])
        .collect();
    // the direction of travel as the friction's column sees it (a filtered sign on a filtered
    // channel)
    let s = quantile(&on, 0.5);
    if s.is_nan() || s.abs() <= 0.5 {
        return None;
    }
    let level = constant.coef.first().copied()? / s;
    (level.is_finite() && level > 0.0).then(|| {
        f.coef = vec![level, 0.0];
        f
    })
}
