//! `viscous_friction`: friction proportional to velocity, optionally different by direction.
//!
//! Equation (on the chosen body, velocity `v`):
//! `T = -c_pos v` for `v >= 0`, `T = -c_neg v` for `v < 0`; `c_neg` defaults to `c_pos`.
//! It adds to the model's `dm_nms_per_rad` / `dl_nms_per_rad` (or `viscous_ns_per_m`).
//!
//! Keys (units follow the side, see `docs/effects.md`):
//! - `side = "motor" | "load"` (default `"motor"`; ignored on a rigid axis, which has one mass);
//! - `c_nms_per_rad` (rotary side) or `c_ns_per_m` (ball-screw table or rigid mass), >= 0;
//! - optional `c_neg_nms_per_rad` / `c_neg_ns_per_m` for negative velocity.
//!
//! Typical values: motor 1e-4 .. 1e-2 N m s/rad; ball-screw table 100 .. 2000 N s/m (EMPS:
//! about 200 N s/m).
//!
//! Signature: a torque component proportional to speed; at constant speed the torque offset
//! grows linearly with speed and reverses with it (no jump at reversal). The direction-dependent
//! part shows as a speed-proportional asymmetry between forward and backward torque.
//!
//! Integration: the mean `(c_pos + c_neg)/2` enters the exactly discretised linear part; the
//! half difference, `-(c_pos - c_neg)/2 |v|`, is applied as a held torque per sub-step.

use feedloop_model::params::{ConfigError, Fields};

use super::{level_pair_table, read_level_pair, Ctx, EffectTable, Side};

/// Viscous friction of one body, motor units: coefficient for positive / negative velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Viscous {
    /// N m s/rad (or N s/m) for positive and negative velocity.
    pub c: [f64; 2],
}

impl Viscous {
    /// The mean coefficient `(c_pos + c_neg)/2` (0 without the effect): it enters the linear part.
    pub fn mean(v: Option<Viscous>) -> f64 {
        v.map_or(0.0, |v| 0.5 * (v.c[0] + v.c[1]))
    }

    /// The half difference `(c_pos - c_neg)/2` (0 without the effect), see [`asymmetric_torque`].
    pub fn half(v: Option<Viscous>) -> f64 {
        v.map_or(0.0, |v| 0.5 * (v.c[0] - v.c[1]))
    }
}

/// The direction-dependent part of the law at speed `av = |v|`: `-c_half |v|`, held per sub-step.
#[inline]
pub(crate) fn asymmetric_torque(c_half: f64, av: f64) -> f64 {
    -c_half * av
}

/// `[effects.viscous_friction]` in the units of its body (N m s/rad or N s/m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViscousFrictionParams {
    /// Body it acts on (`side`).
    pub side: Side,
    /// Coefficient for positive velocity (`c_nms_per_rad` / `c_ns_per_m`).
    pub c: f64,
    /// Coefficient for negative velocity (`c_neg_*`; `c` when not given).
    pub c_neg: f64,
}

impl EffectTable for ViscousFrictionParams {
    /// Reads one `[effects.viscous_friction]` table.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        let (side, c, c_neg) = read_level_pair(f, ctx, "c", |u| u.visc)?;
        Ok(Self { side, c, c_neg })
    }

    /// The model-file table (`c_neg_*` only where it differs).
    fn to_table(&self, ctx: &Ctx) -> toml::Table {
        level_pair_table(ctx, self.side, "c", |u| u.visc, (self.c, self.c_neg))
    }
}

impl ViscousFrictionParams {
    /// In motor units.
    pub(crate) fn motor(&self, ctx: &Ctx) -> Viscous {
        let u = ctx.units(self.side);
        let scale = u.torque_to_motor / u.vel_to_motor;
        Viscous {
            c: [self.c * scale, self.c_neg * scale],
        }
    }
}
