//! The grids of nonlinear parameters an effect's refit searches (a Stribeck velocity, a mode's
//! frequency, a time constant, a period), sized from the trace.

use feedloop_model::model::AxisKind;

use super::data::AxisData;
use super::effects::EffectId;
use super::signal::{quantile, span};

/// The top speed of the load (99th percentile of |vL|, motor units), which the Stribeck
/// velocities searched are shares of.
fn top_speed(d: &AxisData) -> f64 {
    let (a, b) = d.range;
    quantile(
        &d.vl[a..b].iter().map(|x| x.abs()).collect::<Vec<_>>(),
        0.99,
    )
    .max(1e-12)
}

/// Where the best point `best` (its first parameter) of effect `id`'s grid `grid` lay at the
/// grid's upper or lower edge (within 2 %): the points beyond that edge to search next, the first parameter continued on the grid's own
/// logarithmic step up to a physical limit, each with the other parameters' variants of the
/// grid. A Stribeck velocity goes on to the top speed (beyond it a hump is a viscous slope) and
/// down to a fifty-thousandth of it. Empty for the other effects and when the grid is already
/// at the limit: their edges are bounds, shapes or the record's own range, and a current lag
/// longer than the grid's 20 periods is a low-pass that smooths the recorded torque's own
/// noise (a coloured torque noise is "explained" by a lag of tens of periods), so it stays
/// doubtful there.
pub fn widened_grid(id: EffectId, d: &AxisData, grid: &[Vec<f64>], best: f64) -> Vec<Vec<f64>> {
    let (lo_cap, hi_cap) = match id {
        EffectId::StribeckFriction => {
            let vmax = top_speed(d);
            (vmax * 2e-5, vmax)
        }
        EffectId::CurrentLag
        | EffectId::Delay
        | EffectId::ThirdMass
        | EffectId::Cogging
        | EffectId::TorqueSaturation
        | EffectId::PitchError
        | EffectId::Unbalance
        | EffectId::LostMotion
        | EffectId::ViscousFriction
        | EffectId::CoulombFriction
        | EffectId::ConstantForce
        | EffectId::Backlash
        | EffectId::DirectionalFriction => return vec![],
    };
    let mut firsts: Vec<f64> = grid.iter().filter_map(|h| h.first().copied()).collect();
    firsts.sort_by(f64::total_cmp);
    firsts.dedup();
    let (Some(&lo), Some(&hi)) = (firsts.first(), firsts.last()) else {
        return vec![];
    };
    if firsts.len() < 2 || lo <= 0.0 {
        return vec![];
    }
    let step = (hi / lo).powf(1.0 / (firsts.len() - 1) as f64);
    let upper = best >= hi / 1.02;
    if !upper && best > lo * 1.02 {
        return vec![];
    }
    let edge = if upper { hi } else { lo };
    let shapes: Vec<Vec<f64>> = grid
        .iter()
        .filter(|h| h.first() == Some(&edge))
        .map(|h| h[1..].to_vec())
        .collect();
    let mut out = Vec::new();
    let mut x = edge;
    for _ in 0..12 {
        x = if upper { x * step } else { x / step };
        if x > hi_cap * (1.0 + 1e-9) || x < lo_cap * (1.0 - 1e-9) {
            break;
        }
        for s in &shapes {
            let mut h = vec![x];
            h.extend_from_slice(s);
            out.push(h);
        }
    }
    out
}

/// The grid of nonlinear parameters tried for effect `id`.
pub fn hyper_grid(id: EffectId, d: &AxisData) -> Vec<Vec<f64>> {
    let (a, b) = d.range;
    let vmax = top_speed(d);
    let fs = 1.0 / d.dt;
    match id {
        EffectId::StribeckFriction => {
            let mut g = Vec::new();
            for vs in logspace(vmax * 2e-3, vmax * 0.3, 14) {
                for e in [1.0, 2.0] {
                    g.push(vec![vs, e]);
                }
            }
            g
        }
        EffectId::Cogging => match d.kind {
            AxisKind::Rigid => logspace(1e-3, 0.1, 120)
                .into_iter()
                .map(|p| vec![p])
                .collect(),
            AxisKind::BallScrew | AxisKind::Rotary => (1..=120)
                .map(|n| vec![2.0 * std::f64::consts::PI / n as f64])
                .collect(),
        },
        EffectId::ThirdMass => {
            let mut g = Vec::new();
            for f in logspace(5.0, (fs / 5.0).min(2000.0), 24) {
                for z in [0.02, 0.1, 0.3] {
                    g.push(vec![f, z]);
                }
            }
            g
        }
        EffectId::Delay => (1..=10).map(|k| vec![k as f64]).collect(),
        // time constants of the recording's period (that of the samples held on a long trace
        // held in block means)
        EffectId::CurrentLag => logspace(d.dt / d.sub as f64 * 0.3, d.dt / d.sub as f64 * 20.0, 16)
            .into_iter()
            .map(|t| vec![t])
            .collect(),
        EffectId::TorqueSaturation => {
            let Some(y) = &d.torque_raw else {
                return vec![];
            };
            let ay: Vec<f64> = y[a..b].iter().map(|x| x.abs()).collect();
            let (lo, hi) = (quantile(&ay, 0.3), quantile(&ay, 1.0));
            (0..40)
                .map(|i| vec![lo + (hi - lo) * i as f64 / 40.0])
                .collect()
        }
        EffectId::PitchError => {
            let lead = d.r.recip() * 2.0 * std::f64::consts::PI;
            vec![vec![lead]]
        }
        // linear in their coefficients: nothing to search (backlash takes its dead band from
        // the model where it is fitted)
        EffectId::ViscousFriction
        | EffectId::CoulombFriction
        | EffectId::ConstantForce
        | EffectId::Backlash
        | EffectId::DirectionalFriction => vec![vec![]],
        // the motor travel over which the offset flips: from a millionth of the travel
        // recorded (a step) to a hundredth of it
        EffectId::LostMotion => {
            let travel = span(&d.qm[a..b]).max(1e-12);
            logspace(travel * 1e-6, travel * 1e-2, 16)
                .into_iter()
                .map(|w| vec![w])
                .collect()
        }
        // one load revolution first (a tie keeps it), then the periods a load column referred
        // through a gear shows: from the travel (a record that travels less than one revolution
        // shows at most one period of its gravity; a shorter period is a ripple, not a weight)
        // to a thousand times it
        EffectId::Unbalance => {
            let travel = span(&d.ql[a..b]) / d.r;
            let mut g = vec![vec![2.0 * std::f64::consts::PI]];
            if travel > 0.0 {
                g.extend(
                    logspace(travel, 1000.0 * travel, 40)
                        .into_iter()
                        .map(|p| vec![p]),
                );
            }
            g
        }
    }
}

/// `n` values from `lo` to `hi`, evenly spaced on a log scale.
pub(super) fn logspace(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}
