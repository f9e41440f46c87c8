//! The workbench's own regressor form of the plant's base parameters and of every effect of the
//! physics library, and the conversion between those forms and model-file keys.
//!
//! Each effect is written as "torque the motor needs for the measured motion" =
//! `sum_i coef_i * column_i(hyper)`: linear in its coefficients once its nonlinear parameters
//! (`hyper`: Stribeck velocity, cogging period, mode frequency, delay, lag, limit, gap) are fixed.
//! Effects on the drive's torque path (`delay`, `current_lag`, `torque_saturation`) instead
//! transform the recorded torque into the applied one. `backlash` and `pitch_error` act inside
//! the transmission and are seen in the deflection (motor position minus load position), so they
//! need both position columns. These forms are deliberately simple and generic: the diagnosis
//! must not depend on the exact formula of any simulator.

use std::f64::consts::PI;
use std::path::Path;

use feedloop_model::model::{AxisKind, ModelFile, PlantParams};
use feedloop_model::params::read_toml_file;
use feedloop_plant::effects::read_effects;

use super::base::BaseParam;
use super::data::AxisData;
use super::signal::{sub_sample_means, zoh_mid};
use super::WorkbenchError;

pub use feedloop_model::{EffectId, Side};

/// One effect in regressor form.
#[derive(Debug, Clone, PartialEq)]
pub struct Effect {
    /// Which effect.
    pub id: EffectId,
    /// Body it acts on (friction effects).
    pub side: Side,
    /// Nonlinear parameters (see the module doc of each id in `columns`).
    pub hyper: Vec<f64>,
    /// Linear coefficients, motor units.
    pub coef: Vec<f64>,
}

/// Where an effect shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// In the torque balance (inverse dynamics).
    Torque,
    /// On the drive's torque path: it changes the applied torque.
    TorquePath,
    /// In the transmission: motor minus load position.
    Deflection,
}

/// Channel of effect `id`.
pub fn channel(id: EffectId) -> Channel {
    match id {
        EffectId::Delay | EffectId::CurrentLag | EffectId::TorqueSaturation => Channel::TorquePath,
        EffectId::Backlash | EffectId::PitchError | EffectId::LostMotion => Channel::Deflection,
        EffectId::ViscousFriction
        | EffectId::CoulombFriction
        | EffectId::StribeckFriction
        | EffectId::Cogging
        | EffectId::ConstantForce
        | EffectId::ThirdMass
        | EffectId::Unbalance
        | EffectId::DirectionalFriction => Channel::Torque,
    }
}

/// Velocity below which dry friction is taken as undetermined (sticking), motor units/s.
pub fn dead_band(d: &AxisData, v: &[f64]) -> f64 {
    let (a, b) = d.range;
    let vmax = super::signal::quantile(&v[a..b].iter().map(|x| x.abs()).collect::<Vec<_>>(), 0.99);
    1e-3 * vmax.max(1e-12)
}

/// The sign of `v` outside the dead band `eps`, 0 inside it.
pub(crate) fn sgn(v: f64, eps: f64) -> f64 {
    if v > eps {
        1.0
    } else if v < -eps {
        -1.0
    } else {
        0.0
    }
}

/// The regressor functions of `directional_friction` of the velocity, outside the dead band
/// `eps`: the level for positive velocity, the level for negative velocity (as the torque
/// needed: -1 there), the slope for positive and for negative velocity.
fn directional_columns(eps: f64) -> [Box<dyn Fn(f64) -> f64>; 4] {
    [
        Box::new(move |x| if x > eps { 1.0 } else { 0.0 }),
        Box::new(move |x| if x < -eps { -1.0 } else { 0.0 }),
        Box::new(|x: f64| x.max(0.0)),
        Box::new(|x: f64| x.min(0.0)),
    ]
}

/// The lost-motion state of a motor position series `q` (motor units), in units of half the lost
/// motion: it starts centred (0) and relaxes toward the sign of each step's travel by `1 -
/// exp(-|dq| / travel)`, so it holds at rest and flips over a travel of a few `travel`s, the law
/// the plant integrates (`plant/src/effects/lost_motion.rs`).
pub fn lost_motion_column(q: &[f64], travel: f64) -> Vec<f64> {
    let travel = travel.abs().max(1e-300);
    let mut z = 0.0f64;
    let mut out = Vec::with_capacity(q.len());
    let mut prev = q.first().copied().unwrap_or(0.0);
    for &x in q {
        let dq = x - prev;
        prev = x;
        if dq != 0.0 && dq.is_finite() {
            let target = dq.signum();
            z = target + (z - target) * (-dq.abs() / travel).exp();
        }
        out.push(z);
    }
    out
}

/// The block means of `sin(w x)` and `cos(w x)` for a position `x` held at the centres of blocks
/// of `sub` recorded instants and moving linearly through each block (by the central slope): a
/// sum of sines over evenly spaced phases is the sine at the centre times the Dirichlet kernel
/// `sin(theta / 2) / (sub sin(theta / (2 sub)))`, `theta = w` times the travel per held sample
/// (the ripple of a fast motion averages out within a block, as in the recorded torque).
fn held_ripple(x: &[f64], w: f64, sub: usize) -> Vec<Vec<f64>> {
    let n = x.len();
    let q = sub as f64;
    let (mut s, mut c) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for k in 0..n {
        let slope = match n {
            0 | 1 => 0.0,
            _ if k == 0 => x[1] - x[0],
            _ if k == n - 1 => x[k] - x[k - 1],
            _ => 0.5 * (x[k + 1] - x[k - 1]),
        };
        let theta = w * slope;
        let kernel = if (theta / q).abs() < 1e-9 {
            1.0
        } else {
            (0.5 * theta).sin() / (q * (0.5 * theta / q).sin())
        };
        let (sn, cs) = (w * x[k]).sin_cos();
        s.push(kernel * sn);
        c.push(kernel * cs);
    }
    vec![s, c]
}

impl Effect {
    /// A new effect with zero coefficients of the right count.
    pub fn new(id: EffectId, side: Side, hyper: Vec<f64>) -> Self {
        let n = match id {
            EffectId::ViscousFriction
            | EffectId::ConstantForce
            | EffectId::ThirdMass
            | EffectId::Backlash
            | EffectId::LostMotion => 1,
            EffectId::CoulombFriction | EffectId::StribeckFriction | EffectId::Cogging => 2,
            EffectId::PitchError | EffectId::Unbalance => 3,
            EffectId::DirectionalFriction => 4,
            EffectId::Delay | EffectId::CurrentLag | EffectId::TorqueSaturation => 0,
        };
        Self {
            id,
            side,
            hyper,
            coef: vec![0.0; n],
        }
    }

    /// Regressor columns (torque needed per unit coefficient, or deflection per unit for the
    /// deflection effects). Empty for the torque-path effects.
    ///
    /// - `viscous_friction`: `[v]`;
    /// - `coulomb_friction`: `[sign v, |sign v|]` (symmetric level, asymmetry);
    /// - `stribeck_friction` (hyper `[vs, exponent]`): `[sign v, sign v exp(-(|v|/vs)^e)]`;
    /// - `constant_force`: `[1]`;
    /// - `cogging` (hyper `[period]`, motor units): `[sin(2 pi q / P), cos(2 pi q / P)]`;
    /// - `third_mass` (hyper `[f_hz, zeta]`): `[x3'']` of a mass on a spring driven by the load;
    /// - `backlash` (hyper `[JM, DM, dead band]`, from the model): `[sign T]` in the deflection
    ///   (half gap), `T = torque - JM aM - DM vM` the torque the screw transmits, 0 within the
    ///   dead band; without hyper (or torque) `[sign vM]`;
    /// - `pitch_error` (hyper `[period_m]`): `[sin, cos, x]` in the deflection (which carries
    ///   minus the lead error: the motor angle makes up for it);
    /// - `lost_motion` (hyper `[s_t]`, motor units): `[z]` in the deflection (half the lost
    ///   motion), `z` relaxing toward the sign of the motor's travel over a travel `s_t` and
    ///   holding at rest (see [`lost_motion_column`]): it follows the direction of travel,
    ///   backlash the transmitted torque.
    pub fn columns(&self, d: &AxisData) -> Vec<Vec<f64>> {
        let cols = self.raw_columns(d);
        if d.torque_filtered
            && matches!(
                self.id,
                EffectId::CoulombFriction
                    | EffectId::StribeckFriction
                    | EffectId::Cogging
                    | EffectId::DirectionalFriction
            )
        {
            let fs = 1.0 / d.dt;
            cols.iter()
                .map(|c| super::signal::filtfilt_butter4(c, d.cutoff_hz, fs))
                .collect()
        } else {
            cols
        }
    }

    fn raw_columns(&self, d: &AxisData) -> Vec<Vec<f64>> {
        let v = self.side_velocity(d);
        if d.sub > 1 {
            if let Some(cols) = self.held_columns(d, v) {
                return cols;
            }
        }
        match self.id {
            EffectId::ViscousFriction => vec![v.to_vec()],
            EffectId::CoulombFriction => {
                let eps = dead_band(d, v);
                let s: Vec<f64> = v.iter().map(|x| sgn(*x, eps)).collect();
                let a: Vec<f64> = s.iter().map(|x| x.abs()).collect();
                vec![s, a]
            }
            EffectId::StribeckFriction => {
                let eps = dead_band(d, v);
                let (vs, e) = (self.hyper[0], self.hyper[1]);
                let s: Vec<f64> = v.iter().map(|x| sgn(*x, eps)).collect();
                let st: Vec<f64> = v
                    .iter()
                    .zip(&s)
                    .map(|(x, s)| s * (-(x.abs() / vs).powf(e)).exp())
                    .collect();
                vec![s, st]
            }
            EffectId::ConstantForce => vec![vec![1.0; d.len()]],
            EffectId::DirectionalFriction => {
                let eps = dead_band(d, v);
                let m = |f: &dyn Fn(f64) -> f64| v.iter().map(|x| f(*x)).collect::<Vec<f64>>();
                directional_columns(eps)
                    .iter()
                    .map(|f| m(f.as_ref()))
                    .collect()
            }
            EffectId::Cogging => {
                let w = 2.0 * PI / self.hyper[0];
                vec![
                    d.qm.iter().map(|x| (w * x).sin()).collect(),
                    d.qm.iter().map(|x| (w * x).cos()).collect(),
                ]
            }
            EffectId::ThirdMass => vec![third_mass_accel(d, self.hyper[0], self.hyper[1])],
            // the flank in contact follows the torque the screw transmits, not the direction of
            // travel (a load without friction is braked through the other flank); inside the
            // dead band of that torque the position in the gap is undetermined; without the
            // model's hyper (or a torque) the direction of travel stands in
            EffectId::Backlash => vec![if let ([jm, dm, eps, ..], Some(y)) =
                (self.hyper.as_slice(), &d.torque)
            {
                (0..d.len())
                    .map(|k| sgn(y[k] - jm * d.am[k] - dm * d.vm[k], *eps))
                    .collect()
            } else {
                let eps = dead_band(d, &d.vm);
                d.vm.iter().map(|x| sgn(*x, eps)).collect()
            }],
            EffectId::PitchError => {
                let w = 2.0 * PI / (self.hyper[0] * d.r);
                vec![
                    d.qm.iter().map(|x| (w * x).sin()).collect(),
                    d.qm.iter().map(|x| (w * x).cos()).collect(),
                    d.qm.clone(),
                ]
            }
            EffectId::Unbalance => {
                let w = 2.0 * PI / self.hyper[0];
                let th = |q: &f64| w * q / d.r;
                vec![
                    d.ql.iter().map(|q| th(q).sin()).collect(),
                    d.ql.iter().map(|q| th(q).cos()).collect(),
                    vec![1.0; d.len()],
                ]
            }
            EffectId::LostMotion => {
                vec![lost_motion_column(
                    &d.qm,
                    self.hyper.first().copied().unwrap_or(1.0),
                )]
            }
            // the torque-path effects transform the recorded torque instead
            EffectId::Delay | EffectId::CurrentLag | EffectId::TorqueSaturation => vec![],
        }
    }

    /// On an axis held in block means ([`AxisData::sub`] > 1), the columns that are a
    /// nonlinear function of the velocity or position (dry friction, cogging), as the means of
    /// that function over each block's recorded instants ([`sub_sample_means`]): the block mean
    /// of the recorded torque holds the friction step of a reversal inside a block in part, and
    /// so must its column. `None` for the other effects (linear in the held series, or not
    /// filtered).
    fn held_columns(&self, d: &AxisData, v: &[f64]) -> Option<Vec<Vec<f64>>> {
        let m = |x: &[f64], f: &dyn Fn(f64) -> f64| sub_sample_means(x, d.sub, f);
        Some(match self.id {
            EffectId::CoulombFriction => {
                let eps = dead_band(d, v);
                vec![m(v, &|x| sgn(x, eps)), m(v, &|x| sgn(x, eps).abs())]
            }
            EffectId::StribeckFriction => {
                let eps = dead_band(d, v);
                let (vs, e) = (self.hyper[0], self.hyper[1]);
                let hump = move |x: f64| {
                    let r = x.abs() / vs;
                    // the grid's exponents 1 and 2 without the general power
                    let p = if e == 1.0 {
                        r
                    } else if e == 2.0 {
                        r * r
                    } else {
                        r.powf(e)
                    };
                    sgn(x, eps) * (-p).exp()
                };
                vec![m(v, &|x| sgn(x, eps)), m(v, &hump)]
            }
            EffectId::Cogging => held_ripple(&d.qm, 2.0 * PI / self.hyper[0], d.sub),
            EffectId::DirectionalFriction => directional_columns(dead_band(d, v))
                .iter()
                .map(|f| m(v, f.as_ref()))
                .collect(),
            EffectId::ViscousFriction
            | EffectId::ConstantForce
            | EffectId::ThirdMass
            | EffectId::Backlash
            | EffectId::PitchError
            | EffectId::Delay
            | EffectId::CurrentLag
            | EffectId::TorqueSaturation
            | EffectId::Unbalance
            | EffectId::LostMotion => return None,
        })
    }

    /// How many of its coefficients a refit changes (the first that many of [`Effect::columns`]):
    /// all, but a symmetric Coulomb friction (no asymmetry fitted) keeps its symmetry.
    pub fn free_count(&self) -> usize {
        if self.id == EffectId::CoulombFriction && self.coef.get(1).copied().unwrap_or(0.0) == 0.0 {
            1
        } else {
            self.coef.len()
        }
    }

    /// Whether a refitted coefficient `j` may take the value `v`, from its current value: an
    /// offset, an unbalance's or a ripple's sine and cosine parts take any sign; a level, a
    /// slope or a mass keeps its sign (a friction that changes sign is no friction).
    pub fn coef_in_range(&self, j: usize, v: f64) -> bool {
        let now = self.coef.get(j).copied().unwrap_or(0.0);
        let signed = matches!(
            self.id,
            EffectId::ConstantForce | EffectId::Unbalance | EffectId::Cogging
        ) || (self.id == EffectId::CoulombFriction && j == 1);
        signed || now == 0.0 || v * now >= 0.0
    }

    /// A dry friction's torque at rest, as the torque needed (motor units): any value between
    /// the level it reaches just below zero velocity and the level just above (the breakaway
    /// levels of the two directions). `None` for an effect that holds nothing at rest.
    pub fn rest_band(&self) -> Option<(f64, f64)> {
        let c = |j: usize| self.coef.get(j).copied().unwrap_or(0.0);
        let (lo, hi) = match self.id {
            // columns sign(v), |sign(v)|
            EffectId::CoulombFriction => (c(1) - c(0), c(1) + c(0)),
            // columns sign(v), sign(v) exp(-(|v|/vs)^e): the hump is whole at rest
            EffectId::StribeckFriction => (-(c(0) + c(1)), c(0) + c(1)),
            // columns [v > eps], -[v < -eps], the slopes (zero at rest)
            EffectId::DirectionalFriction => (-c(1), c(0)),
            EffectId::ViscousFriction
            | EffectId::ConstantForce
            | EffectId::Cogging
            | EffectId::ThirdMass
            | EffectId::Backlash
            | EffectId::PitchError
            | EffectId::Delay
            | EffectId::CurrentLag
            | EffectId::TorqueSaturation
            | EffectId::Unbalance
            | EffectId::LostMotion => return None,
        };
        Some((lo.min(hi), lo.max(hi)))
    }

    /// The velocity of the body the effect acts on.
    pub fn side_velocity<'d>(&self, d: &'d AxisData) -> &'d [f64] {
        match self.side {
            Side::Motor => &d.vm,
            Side::Load => &d.vl,
        }
    }

    /// The contribution `sum coef_i column_i`.
    pub fn contribution(&self, d: &AxisData) -> Vec<f64> {
        let mut out = vec![0.0; d.len()];
        for (c, col) in self.coef.iter().zip(self.columns(d)) {
            for (o, x) in out.iter_mut().zip(&col) {
                *o += c * x;
            }
        }
        out
    }

    /// Applies a torque-path effect to the recorded torque `y` (identity for other effects).
    pub fn applied_torque(&self, y: &[f64], dt: f64) -> Vec<f64> {
        self.applied_torque_held(y, dt, 1)
    }

    /// [`Effect::applied_torque`] on a torque held in block means of `sub` recorded samples
    /// (period `dt` of the held samples): a delay of `k` recording periods shifts it by `k /
    /// sub` held samples (interpolated linearly).
    pub fn applied_torque_held(&self, y: &[f64], dt: f64, sub: usize) -> Vec<f64> {
        match self.id {
            EffectId::Delay if sub > 1 => {
                let shift = self.hyper[0].round().max(0.0) / sub as f64;
                let (k, f) = (shift.floor() as usize, shift.fract());
                let at = |i: usize, k: usize| if i >= k { y[i - k] } else { 0.0 };
                (0..y.len())
                    .map(|i| (1.0 - f) * at(i, k) + f * at(i, k + 1))
                    .collect()
            }
            EffectId::Delay => {
                let k = self.hyper[0].round().max(0.0) as usize;
                (0..y.len())
                    .map(|i| if i >= k { y[i - k] } else { 0.0 })
                    .collect()
            }
            EffectId::CurrentLag => {
                let a = (-dt / self.hyper[0].max(1e-12)).exp();
                let mut s = y.first().copied().unwrap_or(0.0);
                // the mean over each period of a first-order response to a held input
                y.iter()
                    .map(|&u| {
                        let start = s;
                        s = a * s + (1.0 - a) * u;
                        let tau = self.hyper[0];
                        u + (start - u) * tau / dt * (1.0 - a)
                    })
                    .collect()
            }
            EffectId::TorqueSaturation => {
                let l = self.hyper[0];
                y.iter().map(|x| x.clamp(-l, l)).collect()
            }
            EffectId::ViscousFriction
            | EffectId::CoulombFriction
            | EffectId::StribeckFriction
            | EffectId::Backlash
            | EffectId::PitchError
            | EffectId::Cogging
            | EffectId::ConstantForce
            | EffectId::ThirdMass
            | EffectId::Unbalance
            | EffectId::DirectionalFriction
            | EffectId::LostMotion => y.to_vec(),
        }
    }
}

/// The model file's `constant_force` (the force on the axis, N, or its torque on a rotary axis,
/// N m; positive along +x) of a torque-balance coefficient `coef` (motor units): minus it.
pub fn constant_force_value(coef: f64, kind: AxisKind, r: f64) -> f64 {
    match kind {
        AxisKind::BallScrew | AxisKind::Rotary => -coef * r,
        AxisKind::Rigid => -coef,
    }
}

/// Rounds to 7 significant digits (keeps written model files readable).
pub fn round_sig(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let mag = v.abs().log10().floor() as i32;
    let f = 10f64.powi(6 - mag);
    if !f.is_finite() || f == 0.0 {
        return v;
    }
    (v * f).round() / f
}

/// Acceleration of a third mass on a spring (natural frequency `f_hz`, damping ratio `zeta`)
/// driven by the measured load motion: `x3'' = w^2 (xL - x3) + 2 zeta w (vL - v3)`.
fn third_mass_accel(d: &AxisData, f_hz: f64, zeta: f64) -> Vec<f64> {
    third_mass_track(d, f_hz, zeta).2
}

/// Motion of a mass on a spring (natural frequency `f_hz`, damping ratio `zeta`) driven by the
/// measured load motion: (position, velocity, acceleration) at every sample, motor units. It
/// starts at rest relative to the load.
pub fn third_mass_track(d: &AxisData, f_hz: f64, zeta: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let w = 2.0 * PI * f_hz;
    let n = d.len();
    let sub = ((d.dt * w * 8.0).ceil() as usize).max(1);
    let h = d.dt / sub as f64;
    let mut x = d.ql.first().copied().unwrap_or(0.0);
    let mut v = d.vl.first().copied().unwrap_or(0.0);
    let mut out = Vec::with_capacity(n);
    let mut pos = Vec::with_capacity(n);
    let mut vel = Vec::with_capacity(n);
    for k in 0..n {
        let acc = |x: f64, v: f64, xl: f64, vl: f64| w * w * (xl - x) + 2.0 * zeta * w * (vl - v);
        out.push(acc(x, v, d.ql[k], d.vl[k]));
        pos.push(x);
        vel.push(v);
        if k + 1 < n {
            for s in 0..sub {
                let f = s as f64 / sub as f64;
                let xl = d.ql[k] + f * (d.ql[k + 1] - d.ql[k]);
                let vl = d.vl[k] + f * (d.vl[k + 1] - d.vl[k]);
                // semi-implicit Euler
                v += h * acc(x, v, xl, vl);
                x += h * v;
            }
        }
    }
    (pos, vel, out)
}

/// The model as the workbench uses it: base parameters by key, and effects in regressor form.
#[derive(Debug, Clone)]
pub struct WbModel {
    /// The parsed model file.
    pub file: ModelFile,
    /// The raw TOML table (kept to write a new file with everything else unchanged).
    pub table: toml::Table,
    /// Base parameters (and their values) that enter the torque balance.
    pub base: Vec<(BaseParam, f64)>,
    /// Effects in regressor form.
    pub effects: Vec<Effect>,
    /// The side of the dry friction taken out by [`WbModel::without_superseded`]: the effect
    /// that replaces it refines that friction's curve, on that side.
    pub replaced_side: Option<Side>,
}

/// The torque-path effects in the drive's order.
const TORQUE_PATH: [EffectId; 3] = [
    EffectId::Delay,
    EffectId::TorqueSaturation,
    EffectId::CurrentLag,
];

/// The torque-path effects that act on each held command, before the half-sample alignment.
const HELD_PATH: [EffectId; 2] = [EffectId::Delay, EffectId::TorqueSaturation];

impl WbModel {
    /// This model without the effect that effect `id` contains (see [`WbModel::superseded_by`]),
    /// the side of a dry friction taken out kept in [`WbModel::replaced_side`]; and that
    /// effect's id. `None` when the model has nothing `id` contains.
    pub fn without_superseded(&self, id: EffectId) -> Option<(WbModel, EffectId)> {
        let old = self.superseded_by(id)?;
        let mut reduced = self.clone();
        reduced.replaced_side = self.effects.iter().find(|e| e.id == old).map(|e| e.side);
        reduced.effects.retain(|e| e.id != old);
        Some((reduced, old))
    }

    /// The effect of this model that effect `id` contains and so replaces when added (see
    /// [`EffectId::supersedes`]): what `fit` takes out and `diagnose` scores it without.
    pub fn superseded_by(&self, id: EffectId) -> Option<EffectId> {
        id.supersedes()
            .filter(|s| self.effects.iter().any(|e| e.id == *s))
    }

    /// Loads a model file.
    pub fn load(path: &Path) -> Result<Self, WorkbenchError> {
        let file = ModelFile::load(path)?;
        let table = read_toml_file(path)?;
        Self::from_parts(file, table)
    }

    /// Builds from a parsed model file and its table.
    pub fn from_parts(file: ModelFile, table: toml::Table) -> Result<Self, WorkbenchError> {
        let kind = file.plant.kind();
        let base = BaseParam::of_kind(kind)
            .iter()
            .map(|p| (*p, p.get(&file.plant).unwrap_or(0.0)))
            .collect();
        let r = file.plant.motor_per_load();
        let effects = read_effects(&file)?
            .iter()
            .map(|p| Effect::from_params(p, kind, r))
            .collect();
        Ok(Self {
            file,
            table,
            base,
            effects,
            replaced_side: None,
        })
    }

    /// Axis kind.
    pub fn kind(&self) -> AxisKind {
        self.file.plant.kind()
    }

    /// Value of base parameter `p` (0 if the model's structure has no such parameter).
    pub fn base_value(&self, p: BaseParam) -> f64 {
        self.base
            .iter()
            .find(|(k, _)| *k == p)
            .map(|(_, v)| *v)
            .unwrap_or(0.0)
    }

    /// The drive's torque limit: the lowest of the model's `torque_saturation` effects, torque
    /// units (`None` without one).
    pub fn drive_limit(&self) -> Option<f64> {
        self.effects
            .iter()
            .filter(|e| e.id == EffectId::TorqueSaturation)
            .map(|e| e.hyper[0])
            .reduce(f64::min)
    }

    /// The applied torque: the recorded torque through the model's torque-path effects.
    ///
    /// A command recorded at sample k is held over the following period (zero-order hold), so
    /// the torque acting around sample k (where the central differences are centred) is the mean
    /// of the commands acting over periods k-1 and k. The drive delays and clamps each command it
    /// holds, so the delay and the clamp act on the recorded commands before that half-sample
    /// alignment (a clamp does not commute with the mean: aligning first put half a period of
    /// torque beyond the limit at every entry into the clamp and every exit, where a mode then
    /// fitted); the lag, linear and time-invariant, acts after it as before.
    pub fn applied_torque(&self, y: &[f64], dt: f64) -> Vec<f64> {
        let held = self.path_effects(y.to_vec(), dt, 1, &HELD_PATH);
        let aligned: Vec<f64> = (0..held.len()).map(|k| zoh_mid(&held, k)).collect();
        self.path_effects(aligned, dt, 1, &[EffectId::CurrentLag])
    }

    /// The torque-path effects among `ids` on the torque `out`, in the drive's order (`ids`
    /// lists them in it: delay, saturation, lag; `sub`: see [`Effect::applied_torque_held`]).
    fn path_effects(&self, mut out: Vec<f64>, dt: f64, sub: usize, ids: &[EffectId]) -> Vec<f64> {
        for id in ids {
            for e in self.effects.iter().filter(|e| e.id == *id) {
                out = e.applied_torque_held(&out, dt, sub);
            }
        }
        out
    }

    /// The applied torque of the trace `d`: the recorded torque (as recorded, so that clamps and
    /// delays act on the real signal) through the half-sample alignment and the torque-path
    /// effects, then the same zero-phase filter as the positions when `d` filters its torque.
    pub fn applied(&self, d: &AxisData) -> Option<Vec<f64>> {
        let raw = d.torque_raw.as_ref()?;
        // an axis held in block means holds the torque already aligned (see `load_axis_held`)
        let out = if d.sub > 1 {
            self.path_effects(raw.clone(), d.dt, d.sub, &TORQUE_PATH)
        } else {
            self.applied_torque(raw, d.dt)
        };
        Some(if d.torque_filtered {
            super::signal::filtfilt_butter4(&out, d.cutoff_hz, 1.0 / d.dt)
        } else {
            out
        })
    }

    /// The torque balance's residual, `applied` minus `needed` (the model's
    /// [`WbModel::torque_needed`]), with the model's dry friction sticking at rest
    /// ([`WbModel::held_at_rest`]): the residual `compare` reports and `diagnose` scores.
    pub fn balance_residual(&self, d: &AxisData, applied: &[f64], needed: &[f64]) -> Vec<f64> {
        let mut r: Vec<f64> = applied.iter().zip(needed).map(|(a, b)| a - b).collect();
        self.held_at_rest(d, &mut r);
        r
    }

    /// The torque balance's residual `residual` (applied minus needed) with the model's dry
    /// friction sticking where its body is at rest (inside the friction's dead band): there the
    /// friction holds whatever torque the rest of the balance leaves, up to its breakaway level
    /// in each direction, and only what exceeds that level is misfit. A model without dry
    /// friction leaves the residual as it is.
    fn held_at_rest(&self, d: &AxisData, residual: &mut [f64]) {
        let n = residual.len().min(d.len());
        // per row: the sliding contribution to take back, and the band the friction spans
        let mut rest: Vec<Option<(f64, f64, f64)>> = vec![None; n];
        for e in self
            .effects
            .iter()
            .filter(|e| channel(e.id) == Channel::Torque)
        {
            let Some((lo, hi)) = e.rest_band() else {
                continue;
            };
            let v = e.side_velocity(d);
            let eps = dead_band(d, v);
            let c = e.contribution(d);
            for k in 0..n {
                if v[k].abs() <= eps {
                    let (s, l, h) = rest[k].unwrap_or((0.0, 0.0, 0.0));
                    rest[k] = Some((s + c[k], l + lo, h + hi));
                }
            }
        }
        for (r, held) in residual.iter_mut().zip(&rest) {
            if let Some((sliding, lo, hi)) = held {
                let free = *r + sliding;
                *r = free - free.clamp(*lo, *hi);
            }
        }
    }

    /// Torque the model needs for the measured motion (inverse dynamics).
    pub fn torque_needed(&self, d: &AxisData) -> Vec<f64> {
        let mut out = vec![0.0; d.len()];
        for (k, v) in &self.base {
            for (o, x) in out.iter_mut().zip(k.column(d)) {
                *o += v * x;
            }
        }
        for e in self
            .effects
            .iter()
            .filter(|e| channel(e.id) == Channel::Torque)
        {
            for (o, x) in out.iter_mut().zip(e.contribution(d)) {
                *o += x;
            }
        }
        out
    }

    /// The `[effects]` table of the current effects, under the model file's keys (a repeated
    /// effect becomes an array of tables).
    pub fn effects_table(&self) -> toml::Table {
        let kind = self.kind();
        let r = self.file.plant.motor_per_load();
        let mut eff = toml::Table::new();
        for e in &self.effects {
            let et = e.to_table(kind, r);
            match eff.get_mut(e.id.id()) {
                None => {
                    eff.insert(e.id.id().to_string(), toml::Value::Table(et));
                }
                Some(toml::Value::Table(prev)) => {
                    let prev = prev.clone();
                    eff.insert(
                        e.id.id().to_string(),
                        toml::Value::Array(vec![toml::Value::Table(prev), toml::Value::Table(et)]),
                    );
                }
                Some(toml::Value::Array(a)) => a.push(toml::Value::Table(et)),
                Some(_) => {}
            }
        }
        eff
    }

    /// The model as the plant simulator reads it: the current base values and effects, no
    /// sensor model (the simulation is compared with the measurement, noise and all).
    pub fn sim_file(&self) -> ModelFile {
        let mut f = self.file.clone();
        self.base_into(&mut f.plant);
        f.effects = self.effects_table();
        f.sensor = toml::Table::new();
        f
    }

    /// Writes the current base values into `plant`. The one place the workbench's base
    /// parameters go back into the typed model.
    pub fn base_into(&self, plant: &mut PlantParams) {
        for (p, v) in &self.base {
            p.set(plant, *v);
        }
    }

    /// Writes the model with the current base values and effects to `path`.
    pub fn write(&self, path: &Path) -> Result<(), WorkbenchError> {
        std::fs::write(path, self.text()).map_err(|e| WorkbenchError::io(path, e))
    }

    /// The model file's text with the current base values and effects (what [`Self::write`]
    /// writes).
    pub fn text(&self) -> String {
        let mut t = self.table.clone();
        for (k, v) in &self.base {
            t.insert(k.key().to_string(), toml::Value::Float(round_sig(*v)));
        }
        let eff = self.effects_table();
        if eff.is_empty() {
            t.remove("effects");
        } else {
            t.insert("effects".into(), toml::Value::Table(eff));
        }
        format!(
            "# written by `feedloop fit` (feedloop model workbench)\n{}",
            toml::to_string_pretty(&t).unwrap_or_default()
        )
    }
}
// What `diagnose` says of each effect: its class and its evidence sentence, beside the
// regressor so that the workbench's per-effect tables stand in one file.

#[cfg(test)]
mod tests {
    use super::*;
    use crate::workbench::signal::{block_means, sub_sample_means};

    #[test]
    fn held_ripple_is_the_block_mean_of_the_ripple_over_the_recorded_instants() {
        // a position moving at constant speed, recorded at 10 instants per block: the closed
        // form equals the sum over the instants, for a slow and for a fast ripple
        let q = 10;
        let full: Vec<f64> = (0..400).map(|i| 0.3 + 0.004 * i as f64).collect();
        let held = block_means(&full, q);
        for w in [2.0, 90.0] {
            let got = held_ripple(&held, w, q);
            let want_s = block_means(&full.iter().map(|x| (w * x).sin()).collect::<Vec<_>>(), q);
            let want_c = block_means(&full.iter().map(|x| (w * x).cos()).collect::<Vec<_>>(), q);
            let by_instants = sub_sample_means(&held, q, |x| (w * x).sin());
            for k in 0..held.len() {
                assert!((got[0][k] - want_s[k]).abs() < 1e-9, "w {w} k {k}");
                assert!((got[1][k] - want_c[k]).abs() < 1e-9, "w {w} k {k}");
                assert!((got[0][k] - by_instants[k]).abs() < 1e-9, "w {w} k {k}");
            }
        }
    }
}
