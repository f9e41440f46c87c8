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

use feedloop_model::params::{ConfigError, Fields, Range};

use super::{check_keys, read_side, Ctx, DryFriction, Side};

/// Parses one `[effects.coulomb_friction]` table.
pub(crate) fn parse(
    f: &mut Fields<'_>,
    table: &toml::Table,
    ctx: &Ctx,
) -> Result<(Side, DryFriction), ConfigError> {
    let side = read_side(f)?;
    let u = ctx.units(side);
    let key = format!("fc_{}", u.torque);
    let key_neg = format!("fc_neg_{}", u.torque);
    check_keys(f, table, &["side", &key, &key_neg])?;
    let fc = f.f64(&key, Range::NonNegative)?;
    let fc_neg = f.f64_or(&key_neg, Range::NonNegative, fc)?;
    let t = u.torque_to_motor;
    Ok((
        side,
        DryFriction {
            fc: [fc * t, fc_neg * t],
            fs: [fc * t, fc_neg * t],
            vs: f64::INFINITY,
            exponent: 2.0,
        },
    ))
}
