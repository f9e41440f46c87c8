//! The words of a diagnosis: figures with significant digits, the evidence sentence of each
//! effect, its identifiability class, the units of an axis.

use feedloop_model::model::AxisKind;

use super::data::AxisData;
use super::effects::{round_sig, Effect, EffectId};
use super::signal::quantile;

pub(crate) fn fmt(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.3e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.4}")
    }
}

pub(crate) fn reversals(d: &AxisData) -> usize {
    let (a, b) = d.range;
    let vmax = quantile(
        &d.vm[a..b].iter().map(|x| x.abs()).collect::<Vec<_>>(),
        0.99,
    );
    let th = 0.02 * vmax;
    let mut last = 0.0;
    let mut n = 0;
    for &v in &d.vm[a..b] {
        let s = if v > th {
            1.0
        } else if v < -th {
            -1.0
        } else {
            0.0
        };
        if s != 0.0 {
            if last != 0.0 && s != last {
                n += 1;
            }
            last = s;
        }
    }
    n
}

pub(crate) fn units(kind: AxisKind) -> (&'static str, &'static str) {
    match kind {
        AxisKind::Rotary => ("N m", "rad"),
        AxisKind::BallScrew => ("N m", "rad"),
        AxisKind::Rigid => ("N", "m"),
    }
}

/// The mass (or, on a rotary axis, the inertia) a third-mass fit carries, in the model file's
/// units at the load, with its sign: a negative one is no mass.
pub(crate) fn third_mass_words(e: &Effect, d: &AxisData) -> String {
    let m = e.coef.first().copied().unwrap_or(0.0)
        * super::effect_params::third_mass_factor(d.kind, d.r);
    if d.kind == AxisKind::Rotary {
        format!("an inertia of {} kg m^2 at the load", fmt(m))
    } else {
        format!("a mass of {} kg", fmt(m))
    }
}

pub(crate) fn evidence(e: &Effect, d: &AxisData) -> String {
    let (tu, _) = units(d.kind);
    let kind = d.kind;
    let (fu, r) = if kind == AxisKind::BallScrew {
        ("N", d.r)
    } else {
        (tu, 1.0)
    };
    match e.id {
        EffectId::CoulombFriction => {
            let fc = e.coef[0] * r;
            format!(
                "the residual steps by about 2 Fc = {} {fu} at each of {} velocity reversals",
                fmt(2.0 * fc),
                reversals(d)
            )
        }
        EffectId::StribeckFriction => format!(
            "friction rises by {} {fu} above its sliding level {} {fu} below about {} of velocity",
            fmt(e.coef[1] * r),
            fmt(e.coef[0] * r),
            fmt(e.hyper[0] / r)
        ),
        EffectId::ViscousFriction => format!("the residual grows in proportion to velocity ({} per unit of velocity)", fmt(e.coef[0])),
        EffectId::ConstantForce => format!(
            "the residual is the same in both directions of travel: {}",
            constant_force_words(-e.coef[0] * r, kind)
        ),
        EffectId::Cogging => format!(
            "a ripple of {} {tu} repeating every {} {} of motor position",
            fmt(e.coef[0].hypot(e.coef[1])),
            fmt(e.hyper[0]),
            if kind == AxisKind::Rigid { "m" } else { "rad" }
        ),
        EffectId::ThirdMass => format!(
            "the residual follows a mode near {} Hz (damping ratio {}) carrying {}",
            fmt(e.hyper[0]),
            e.hyper[1],
            third_mass_words(e, d)
        ),
        EffectId::Delay => format!(
            "the recorded torque explains the motion best when shifted by {} cycles ({} ms)",
            e.hyper[0],
            fmt(e.hyper[0] * d.dt / d.sub as f64 * 1e3)
        ),
        EffectId::CurrentLag => format!("the recorded torque explains the motion best through a lag of {} ms", fmt(e.hyper[0] * 1e3)),
        EffectId::TorqueSaturation => format!(
            "where the recorded torque exceeds about {} {tu} the motion shows less torque than recorded",
            fmt(e.hyper[0])
        ),
        EffectId::Backlash => format!(
            "motor minus load position steps by about {} at each of {} reversals",
            match kind {
                AxisKind::BallScrew => format!("{} m", fmt(round_sig(e.backlash_params(kind, d.r).gap))),
                AxisKind::Rotary => format!("{} rad", fmt(round_sig(e.backlash_params(kind, d.r).gap))),
                AxisKind::Rigid => format!("{} rad", fmt(2.0 * e.coef[0])),
            },
            reversals(d)
        ),
        EffectId::LostMotion => {
            let p = e.lost_motion_params(kind, d.r);
            let u = if kind == AxisKind::BallScrew { "m" } else { "rad" };
            format!(
                "motor minus load position shifts by about {} {u} between the two directions of travel, following the direction of travel (lost motion), not the transmitted torque (backlash), over about {} {u} of travel",
                fmt(round_sig(p.lost)),
                fmt(p.transition)
            )
        }
        EffectId::PitchError => format!(
            "motor minus load position varies with load position, period {} m, amplitude {} m",
            fmt(e.hyper[0]),
            fmt(round_sig(e.pitch_params(d.r).amplitude_m))
        ),
        EffectId::DirectionalFriction => {
            let c = &e.coef;
            format!(
                "friction differs between the directions of travel: {} {fu} with a viscous slope of {} beyond the model's damping moving forward, {} {fu} with {} moving back (directional_friction; slopes in torque units per unit of velocity)",
                fmt(c[0] * r),
                fmt(c[2]),
                fmt(c[1] * r),
                fmt(c[3])
            )
        }
        EffectId::Unbalance => {
            let p = e.unbalance_params(d.r);
            format!(
                "the residual follows the load angle, the same in both directions of travel: an unbalance of m g r = {} N m at the load returning it to {} rad (period {} rad of the load column), plus a constant {} N m (unbalance.mgr_nm, zero_angle_rad, period_rad, constant_nm)",
                fmt(p.mgr_nm),
                fmt(p.zero_angle_rad),
                fmt(p.period_rad),
                fmt(p.constant_nm)
            )
        }
    }
}

/// A constant force (or torque on a rotary axis) in words, in the sign of the model file's
/// `constant_force` (the force acting on the axis, positive along +x; docs/workbench.md
/// "Signs"): `a constant force of +3.18 N on the axis (constant_force.force_n)`.
pub(crate) fn constant_force_words(force: f64, kind: AxisKind) -> String {
    let sign = if force > 0.0 { "+" } else { "" };
    match kind {
        AxisKind::Rotary => format!(
            "a constant torque of {sign}{} N m on the axis (constant_force.torque_nm)",
            fmt(force)
        ),
        _ => format!(
            "a constant force of {sign}{} N on the axis (constant_force.force_n)",
            fmt(force)
        ),
    }
}

/// Identifiability class of effect `id` (the name a diagnosis groups candidates under).
pub fn class_of(id: EffectId) -> &'static str {
    match id {
        EffectId::ViscousFriction => "damping",
        EffectId::CoulombFriction | EffectId::StribeckFriction => "friction",
        EffectId::ConstantForce => "offset",
        EffectId::Cogging => "cogging",
        EffectId::ThirdMass => "mode",
        EffectId::Delay | EffectId::CurrentLag => "delay",
        EffectId::TorqueSaturation => "saturation",
        EffectId::Backlash => "backlash",
        EffectId::LostMotion => "lost_motion",
        EffectId::PitchError => "pitch",
        EffectId::Unbalance => "gravity",
        EffectId::DirectionalFriction => "friction",
    }
}
