//! `coulomb_friction`: dry friction of constant magnitude opposing motion, with true sticking.
//!
//! Equation (body velocity `v`, net other torque `T_net` on the body):
//! sliding (`v != 0`): `T = -fc sign(v)` (`fc_neg` for `v < 0`);
//! sticking (`v = 0`): `T = -T_net` as long as `-fc_neg <= T_net <= fc`, so the body stays
//! exactly at rest; it breaks away when `T_net` leaves that interval. The static level equals the
//! Coulomb level (use `stribeck_friction` for a higher breakaway).
//!
//! Keys: `side = "motor" | "load"` (default motor), `fc_nm` (rotary side, N m) or `fc_n`
//! (ball-screw table or rigid mass, N), >= 0; optional `fc_neg_nm` / `fc_neg_n` for negative
//! velocity (asymmetric friction, e.g. gravity-loaded guides).
//!
//! Typical values: motor + screw 0.05 .. 0.5 N m; table guides 10 .. 100 N (EMPS: about 20 N).
//!
//! Signature: a torque step of `2 fc` at every velocity reversal; in closed loop a following-error
//! spike right after each reversal (quadrant glitch), about 2 um per N m of motor-side `fc` with
//! Kv = 5 N m s/rad and a 10 mm lead, which the integrator then removes. At rest under a torque
//! below `fc` the velocity is exactly zero.
//!
//! Integration: stick/slip state machine. In slip the friction torque is held over a sub-step;
//! a velocity zero crossing inside a sub-step is located by bisection (to period/1024), where the
//! body either sticks (velocity set to exactly 0, position frozen) or slides on in the direction
//! of the net torque. Sticking is a constrained linear mode, discretised exactly.

use feedloop_model::params::{ConfigError, Fields};

use super::{level_pair_table, read_level_pair, stribeck_friction, Ctx, EffectTable, Side};

/// Dry friction of one body, motor units (`coulomb_friction`, or `stribeck_friction` with a
/// higher breakaway level).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DryFriction {
    /// Coulomb (sliding) level for positive / negative velocity, N m (or N), >= 0.
    pub fc: [f64; 2],
    /// Static (breakaway) level for positive / negative direction, >= fc.
    pub fs: [f64; 2],
    /// Stribeck velocity, motor units per s (infinite for pure Coulomb).
    pub vs: f64,
    /// Stribeck exponent (dimensionless).
    pub exponent: f64,
}

/// The dry-friction law of one body, with what the integrator precomputes from [`DryFriction`].
#[derive(Debug, Clone, Copy)]
pub(crate) struct DryLaw {
    /// Coulomb level for positive / negative velocity.
    pub fc: [f64; 2],
    /// Breakaway level for positive / negative direction.
    pub fs: [f64; 2],
    /// 1 / Stribeck velocity (0 for pure Coulomb).
    pub inv_vs: f64,
    /// Stribeck exponent.
    pub exponent: f64,
    /// Whether the level rises above `fc` at low speed.
    pub stribeck: bool,
    /// Beyond this |v|/vs the Stribeck term is below 1e-17 of (fs - fc) and is skipped.
    pub r_cut: f64,
}

impl DryLaw {
    /// No dry friction.
    pub const NONE: DryLaw = DryLaw {
        fc: [0.0; 2],
        fs: [0.0; 2],
        inv_vs: 0.0,
        exponent: 2.0,
        stribeck: false,
        r_cut: 0.0,
    };

    /// The law of `d`.
    pub fn new(d: DryFriction) -> Self {
        Self {
            fc: d.fc,
            fs: d.fs,
            stribeck: d.vs.is_finite() && (d.fs[0] > d.fc[0] || d.fs[1] > d.fc[1]),
            inv_vs: if d.vs.is_finite() { 1.0 / d.vs } else { 0.0 },
            exponent: d.exponent,
            r_cut: 40.0f64.powf(1.0 / d.exponent),
        }
    }

    /// Magnitude of the friction while sliding at speed `av = |v|` in direction `dir` (+-1):
    /// `fc`, plus the Stribeck hump `(fs - fc) g(|v| / vs)`.
    #[inline]
    pub fn sliding_level(&self, dir: f64, av: f64) -> f64 {
        let i = usize::from(dir < 0.0);
        let mut mag = self.fc[i];
        let r = av * self.inv_vs;
        if self.stribeck && r < self.r_cut {
            mag += (self.fs[i] - self.fc[i]) * stribeck_friction::hump(r, self.exponent);
        }
        mag
    }

    /// Whether a body at rest stays stuck under the net other torque `net`.
    #[inline]
    pub fn holds(&self, net: f64) -> bool {
        net <= self.fs[0] && net >= -self.fs[1]
    }
}

/// `[effects.coulomb_friction]` in the units of its body (N m or N).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoulombFrictionParams {
    /// Body it acts on (`side`).
    pub side: Side,
    /// Level for positive velocity (`fc_nm` / `fc_n`), >= 0.
    pub fc: f64,
    /// Level for negative velocity (`fc_neg_*`; `fc` when not given), >= 0.
    pub fc_neg: f64,
}

impl EffectTable for CoulombFrictionParams {
    /// Reads one `[effects.coulomb_friction]` table.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        let (side, fc, fc_neg) = read_level_pair(f, ctx, "fc", |u| u.torque)?;
        Ok(Self { side, fc, fc_neg })
    }

    /// The model-file table (`fc_neg_*` only where it differs).
    fn to_table(&self, ctx: &Ctx) -> toml::Table {
        level_pair_table(ctx, self.side, "fc", |u| u.torque, (self.fc, self.fc_neg))
    }
}

impl CoulombFrictionParams {
    /// In motor units.
    pub(crate) fn motor(&self, ctx: &Ctx) -> DryFriction {
        let t = ctx.units(self.side).torque_to_motor;
        DryFriction {
            fc: [self.fc * t, self.fc_neg * t],
            fs: [self.fc * t, self.fc_neg * t],
            vs: f64::INFINITY,
            exponent: 2.0,
        }
    }
}
