//! `directional_friction`: dry and viscous friction whose level and slope differ between the two
//! directions of travel (a gear or a guide that runs differently forward and back, a seal, a
//! cable carrier that pulls one way).
//!
//! Equation: sliding at velocity `v` on its body, `T = -(fc_pos + c_pos v)` for `v > 0` and
//! `T = fc_neg + c_neg |v|` for `v < 0`: the friction opposes the motion with the level and the
//! slope of the direction the body moves in. It sticks below the level of the direction it would
//! break away in, as `coulomb_friction` does.
//!
//! Keys (on `side = "motor"` (default) or `"load"`, in that body's units): `fc_pos_nm` /
//! `fc_pos_n` and `fc_neg_nm` / `fc_neg_n` (>= 0, the levels for positive and negative velocity),
//! optional `c_pos_nms_per_rad` / `c_pos_ns_per_m` and `c_neg_nms_per_rad` / `c_neg_ns_per_m`
//! (>= 0, the viscous slopes, default 0). It is the body's dry and its viscous friction at once:
//! a body with `directional_friction` has no other friction effect.
//!
//! Typical values: levels differing by 5 .. 30 % between the directions; KUKA KR300 joint 1
//! (Weigand et al.): about 1.36 N m with a small direction-dependent offset.
//!
//! Signature: the torque residual steps at each reversal by the sum of the two levels, but the
//! steps are not centred: its mean over forward travel and over backward travel differ by more
//! than a constant force explains (a constant force shifts both by the same amount), and the
//! slope against speed differs between the directions.
//!
//! Integration: as `coulomb_friction` and `viscous_friction` with their `_neg` levels.

use feedloop_model::params::{ConfigError, Fields, Range};

use super::{check_keys, put, put_side, read_side, Ctx, DryFriction, EffectTable, Side, Viscous};

/// `[effects.directional_friction]` in the units of its body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectionalFrictionParams {
    /// Body it acts on (`side`).
    pub side: Side,
    /// Level for positive velocity (`fc_pos_nm` / `fc_pos_n`), >= 0.
    pub fc_pos: f64,
    /// Level for negative velocity (`fc_neg_nm` / `fc_neg_n`), >= 0.
    pub fc_neg: f64,
    /// Viscous slope for positive velocity (`c_pos_nms_per_rad` / `c_pos_ns_per_m`), >= 0.
    pub c_pos: f64,
    /// Viscous slope for negative velocity (`c_neg_nms_per_rad` / `c_neg_ns_per_m`), >= 0.
    pub c_neg: f64,
}

impl EffectTable for DirectionalFrictionParams {
    /// Reads one `[effects.directional_friction]` table.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        let (side, u) = read_side(f, ctx)?;
        let (k_fp, k_fn) = (
            format!("fc_pos_{}", u.torque),
            format!("fc_neg_{}", u.torque),
        );
        let (k_cp, k_cn) = (format!("c_pos_{}", u.visc), format!("c_neg_{}", u.visc));
        check_keys(f, &["side", &k_fp, &k_fn, &k_cp, &k_cn])?;
        Ok(Self {
            side,
            fc_pos: f.f64(&k_fp, Range::NonNegative)?,
            fc_neg: f.f64(&k_fn, Range::NonNegative)?,
            c_pos: f.f64_or(&k_cp, Range::NonNegative, 0.0)?,
            c_neg: f.f64_or(&k_cn, Range::NonNegative, 0.0)?,
        })
    }

    /// The model-file table.
    fn to_table(&self, ctx: &Ctx) -> toml::Table {
        let u = ctx.units(self.side);
        let mut t = toml::Table::new();
        put(&mut t, format!("fc_pos_{}", u.torque), self.fc_pos);
        put(&mut t, format!("fc_neg_{}", u.torque), self.fc_neg);
        put(&mut t, format!("c_pos_{}", u.visc), self.c_pos);
        put(&mut t, format!("c_neg_{}", u.visc), self.c_neg);
        put_side(&mut t, self.side, ctx);
        t
    }
}

impl DirectionalFrictionParams {
    /// Its dry and its viscous part, in motor units.
    pub(crate) fn motor(&self, ctx: &Ctx) -> (DryFriction, Viscous) {
        let u = ctx.units(self.side);
        let t = u.torque_to_motor;
        let scale = t / u.vel_to_motor;
        (
            DryFriction {
                fc: [self.fc_pos * t, self.fc_neg * t],
                fs: [self.fc_pos * t, self.fc_neg * t],
                vs: f64::INFINITY,
                exponent: 2.0,
            },
            Viscous {
                c: [self.c_pos * scale, self.c_neg * scale],
            },
        )
    }
}
