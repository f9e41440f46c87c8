//! `stribeck_friction`: dry friction whose breakaway (static) level exceeds the sliding level.
//!
//! Equation (sliding, body velocity `v`, direction `s = sign(v)`):
//! `T = -s (fc + (fs - fc) exp(-(|v| / vs)^exponent))`;
//! sticking (`v = 0`): the body stays exactly at rest while the net other torque lies within
//! `[-fs_neg, fs]`, and breaks away beyond. `fs >= fc` is required.
//!
//! Keys: `side = "motor" | "load"` (default motor); `fc_nm` and `fs_nm` (rotary side, N m) or
//! `fc_n` and `fs_n` (ball-screw table or rigid mass, N); `vs_rad_per_s` or `vs_m_per_s` (> 0);
//! optional `exponent` (dimensionless, default 2, within [0.5, 4]); optional `fc_neg_*`,
//! `fs_neg_*` for negative velocity.
//!
//! Typical values: motor `fs` 1.2 .. 2 x `fc`, `vs` 0.5 .. 5 rad/s; table `vs` 0.1 .. 2 mm/s.
//!
//! Signature: a breakaway torque peak of `fs` before motion starts, then a drop to `fc` within a
//! few `vs`; at low speed in closed loop stick-slip (a sawtooth in position with the velocity
//! resting at exactly zero between slips); at reversals a spike somewhat larger than with Coulomb
//! friction alone.
//!
//! Integration: as `coulomb_friction` (stick/slip state machine with located zero crossings);
//! the velocity-dependent level is held over a sub-step at the sub-step's start velocity.

use feedloop_model::params::{ConfigError, Fields, Range};

use super::{check_keys, put, put_side, read_side, Ctx, DryFriction, EffectTable, Side};

/// The Stribeck curve `g(r) = exp(-r^exponent)` at `r = |v| / vs`: the share of `fs - fc` added to
/// the sliding level (see `coulomb_friction::DryLaw::sliding_level`).
#[inline]
pub(crate) fn hump(r: f64, exponent: f64) -> f64 {
    if exponent == 2.0 {
        (-r * r).exp()
    } else if exponent == 1.0 {
        (-r).exp()
    } else {
        (-r.powf(exponent)).exp()
    }
}

/// `[effects.stribeck_friction]` in the units of its body (N m and rad/s, or N and m/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StribeckFrictionParams {
    /// Body it acts on (`side`).
    pub side: Side,
    /// Sliding (Coulomb) level for positive velocity (`fc_nm` / `fc_n`).
    pub fc: f64,
    /// Breakaway level for positive velocity (`fs_*`), >= `fc`.
    pub fs: f64,
    /// Sliding level for negative velocity (`fc_neg_*`; `fc` when not given).
    pub fc_neg: f64,
    /// Breakaway level for negative velocity (`fs_neg_*`; `fs` when not given).
    pub fs_neg: f64,
    /// Stribeck velocity (`vs_rad_per_s` / `vs_m_per_s`), > 0.
    pub vs: f64,
    /// Shape exponent (`exponent`, 0.5 .. 4, default 2).
    pub exponent: f64,
}

impl EffectTable for StribeckFrictionParams {
    /// Reads one `[effects.stribeck_friction]` table.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        let (side, u) = read_side(f, ctx)?;
        let k_fc = format!("fc_{}", u.torque);
        let k_fs = format!("fs_{}", u.torque);
        let k_fc_neg = format!("fc_neg_{}", u.torque);
        let k_fs_neg = format!("fs_neg_{}", u.torque);
        let k_vs = format!("vs_{}", u.vel);
        check_keys(
            f,
            &[
                "side", &k_fc, &k_fs, &k_fc_neg, &k_fs_neg, &k_vs, "exponent",
            ],
        )?;
        let fc = f.f64(&k_fc, Range::NonNegative)?;
        let fs = f.f64(&k_fs, Range::NonNegative)?;
        if fs < fc {
            return Err(f.error(
                &k_fs,
                format!("static friction must be >= Coulomb friction {k_fc} = {fc}, got {fs}"),
            ));
        }
        let fc_neg = f.f64_or(&k_fc_neg, Range::NonNegative, fc)?;
        let fs_neg = f.f64_or(&k_fs_neg, Range::NonNegative, fs)?;
        if fs_neg < fc_neg {
            return Err(f.error(
                &k_fs_neg,
                format!("static friction must be >= Coulomb friction {fc_neg}, got {fs_neg}"),
            ));
        }
        let vs = f.f64(&k_vs, Range::Positive)?;
        let exponent = f.f64_or("exponent", Range::Within(0.5, 4.0), 2.0)?;
        Ok(Self {
            side,
            fc,
            fs,
            fc_neg,
            fs_neg,
            vs,
            exponent,
        })
    }

    /// The model-file table (the negative-direction levels only where they differ).
    fn to_table(&self, ctx: &Ctx) -> toml::Table {
        let u = ctx.units(self.side);
        let mut t = toml::Table::new();
        put(&mut t, format!("fc_{}", u.torque), self.fc);
        put(&mut t, format!("fs_{}", u.torque), self.fs);
        if self.fc_neg != self.fc {
            put(&mut t, format!("fc_neg_{}", u.torque), self.fc_neg);
        }
        if self.fs_neg != self.fs {
            put(&mut t, format!("fs_neg_{}", u.torque), self.fs_neg);
        }
        put(&mut t, format!("vs_{}", u.vel), self.vs);
        put(&mut t, "exponent", self.exponent);
        put_side(&mut t, self.side, ctx);
        t
    }
}

impl StribeckFrictionParams {
    /// In motor units.
    pub(crate) fn motor(&self, ctx: &Ctx) -> DryFriction {
        let u = ctx.units(self.side);
        let t = u.torque_to_motor;
        DryFriction {
            fc: [self.fc * t, self.fc_neg * t],
            fs: [self.fs * t, self.fs_neg * t],
            vs: self.vs * u.vel_to_motor,
            exponent: self.exponent,
        }
    }
}
