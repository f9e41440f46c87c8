//! The identified axis as a model file, and the tuned chain with its feedforwards.

use std::fmt::Write;

use feedloop_control::loop_model::Gains;

use super::excitation::Identified;
use super::facts::{entry, floats, Facts};
use super::friction::{FrictionSide, Survey};

/// The model file of the identified axis (`jl` the load inertia to write): two-mass
/// parameters, the measured friction on the motor side (Stribeck per direction, the viscous
/// part as DM), the backlash read at the reversals, the tuned gains. No sensor noise: the file
/// is the mechanics.
pub fn model_text(f: &Facts, s: &Survey, id: &Identified, jl: f64, g: Gains) -> String {
    model_text_viscous(f, s, id, jl, g, false)
}

/// [`model_text`] with the measured viscous friction on the table's side (`dl_nms_per_rad`)
/// instead of the motor's when `on_load` (the traverses measure the two together).
pub fn model_text_viscous(
    f: &Facts,
    s: &Survey,
    id: &Identified,
    jl: f64,
    g: Gains,
    on_load: bool,
) -> String {
    let fr = &s.friction;
    let (p, n) = (&fr.positive, &fr.negative);
    let viscous = 0.5 * (p.viscous_nms_per_rad + n.viscous_nms_per_rad).max(0.0);
    let mut t = String::new();
    let _ = writeln!(t, "# Axis identified by feedloop commission: every value below was measured, except jm_kgm2, lead_m,\n# gear_ratio and torque_limit_nm (data sheet).");
    let _ = writeln!(t, "kind = \"ballscrew\"");
    let _ = writeln!(t, "jm_kgm2 = {:e}", f.jm_kgm2);
    if on_load {
        let _ = writeln!(t, "dm_nms_per_rad = 0.0\ndl_nms_per_rad = {viscous:e}");
    } else {
        let _ = writeln!(t, "dm_nms_per_rad = {viscous:e}");
    }
    let _ = writeln!(t, "kl_nm_per_rad = {:.6e}", id.kl_nm_per_rad);
    let _ = writeln!(t, "jl_kgm2 = {jl:.6e}");
    let _ = writeln!(
        t,
        "lead_m = {:e}\ngear_ratio = {:e}",
        f.lead_m, f.gear_ratio
    );
    let _ = writeln!(
        t,
        "\n[controller]\nkp_per_s = {:.6e}\nkv_nms_per_rad = {:.6e}\ntv_s = {:.6e}\ntorque_limit_nm = {:e}",
        g.kp_per_s, g.kv_nms_per_rad, g.tv_s, f.torque_limit_nm
    );
    let _ = writeln!(t, "\n[effects.stribeck_friction]\nside = \"motor\"");
    let _ = writeln!(
        t,
        "fc_nm = {:.6e}\nfs_nm = {:.6e}",
        p.coulomb_nm,
        p.static_nm.max(p.coulomb_nm)
    );
    let _ = writeln!(
        t,
        "fc_neg_nm = {:.6e}\nfs_neg_nm = {:.6e}",
        n.coulomb_nm,
        n.static_nm.max(n.coulomb_nm)
    );
    let _ = writeln!(
        t,
        "vs_rad_per_s = {:.6e}\nexponent = {}",
        0.5 * (p.stribeck_rad_per_s + n.stribeck_rad_per_s),
        p.exponent
    );
    if let Some(b) = id.backlash_m.filter(|b| *b > 0.0) {
        let _ = writeln!(t, "\n[effects.backlash]\ngap_m = {b:.6e}");
    }
    t
}

/// The inverse-model feedforward's parameters with the identified JL and KL.
pub fn feedforward_params(f: &Facts, s: &Survey, id: &Identified, jl: f64) -> toml::Table {
    let fr = &s.friction;
    let dm = 0.5 * (fr.positive.viscous_nms_per_rad + fr.negative.viscous_nms_per_rad).max(0.0);
    let mut t = floats(&[
        ("jm_kgm2", f.jm_kgm2),
        ("dm_nms_per_rad", dm),
        ("kl_nm_per_rad", id.kl_nm_per_rad),
        ("cl_nms_per_rad", 0.0),
        ("jl_kgm2", jl),
        ("dl_nms_per_rad", 0.0),
    ]);
    t.insert("structure".into(), "split".into());
    t.insert(
        "velocity_estimate".into(),
        f.velocity_estimate.clone().into(),
    );
    t
}

/// The friction feedforward's parameters: the measured curve of each direction (the viscous
/// part is left to the inverse model's DM).
pub fn friction_params(s: &Survey) -> toml::Table {
    let side = |x: &FrictionSide| (x.coulomb_nm, x.static_nm.max(x.coulomb_nm));
    let (pc, ps) = side(&s.friction.positive);
    let (nc, ns) = side(&s.friction.negative);
    floats(&[
        ("fc_nm", pc),
        ("fs_nm", ps),
        ("fc_neg_nm", nc),
        ("fs_neg_nm", ns),
        (
            "vs_rad_per_s",
            0.5 * (s.friction.positive.stribeck_rad_per_s + s.friction.negative.stribeck_rad_per_s),
        ),
        ("stribeck_exponent", s.friction.positive.exponent),
    ])
}

/// What the motor travels at a reversal before the table follows, m: the measured lost motion
/// (the gap plus the screw's change of twist under the load-side friction; the backlash alone
/// leaves the motor that much short of the far flank, and the table waits while the loop closes
/// the rest), the backlash when the lost motion was not measured; `None` without a dead band.
pub fn crossed_m(id: &Identified) -> Option<f64> {
    let b = id.backlash_m.filter(|b| *b > 0.0)?;
    Some(id.lost_motion_m.filter(|l| *l >= b).unwrap_or(b))
}

/// What the tuned chain holds besides the cascade.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Compensation {
    /// The inverse-model feedforward.
    pub inverse: bool,
    /// The friction feedforward.
    pub friction: bool,
    /// The learned quadrant compensator (its table file), with the friction feedforward under
    /// its pulses when `friction` is set.
    pub quadrant: Option<String>,
}

/// The chain of `axis`: the cascade with gains `g` and the compensations asked for.
pub fn chain(
    axis: &str,
    g: Gains,
    c: &Compensation,
    f: &Facts,
    s: &Survey,
    id: &Identified,
    jl: f64,
) -> Vec<toml::Value> {
    let mut out = vec![entry(
        axis,
        "position",
        "position_p",
        floats(&[("kp_per_s", g.kp_per_s)]),
    )];
    if c.inverse {
        let mut p = feedforward_params(f, s, id, jl);
        p.insert(
            "kv_nms_per_rad".into(),
            toml::Value::Float(g.kv_nms_per_rad),
        );
        p.insert("tv_s".into(), toml::Value::Float(g.tv_s));
        out.push(entry(axis, "feedforward", "inverse_feedforward", p));
    }
    if let Some(table) = &c.quadrant {
        let mut p = floats(&[
            ("kp_per_s", g.kp_per_s),
            ("inertia_kgm2", f.jm_kgm2 + jl),
            ("jl_kgm2", jl),
            ("kl_nm_per_rad", id.kl_nm_per_rad),
        ]);
        p.insert("table".into(), table.as_str().into());
        if c.friction {
            p.extend(friction_params(s));
        }
        if let Some(b) = crossed_m(id) {
            // Crossing time: the motor's peak torque through the gap at a tenth of the limit.
            let peak = 2.0 * std::f64::consts::PI * b * f.ratio() * f.jm_kgm2;
            let d = (peak / (0.1 * f.torque_limit_nm)).sqrt().max(0.002);
            p.insert("backlash_m".into(), toml::Value::Float(b));
            p.insert("backlash_s".into(), toml::Value::Float(d));
            // The table stands while the motor crosses: centred on the reversal, where the
            // command moves least.
            p.insert("backlash_lead_s".into(), toml::Value::Float(0.5 * d));
        }
        out.push(entry(axis, "compensator", "quadrant_compensator", p));
    } else if c.friction {
        out.push(entry(
            axis,
            "compensator",
            "friction_feedforward",
            friction_params(s),
        ));
    }
    out.push(entry(
        axis,
        "velocity",
        "pi_velocity",
        floats(&[("kv_nms_per_rad", g.kv_nms_per_rad), ("tv_s", g.tv_s)]),
    ));
    out
}
