//! The effect library: physical imperfections switched on with `[effects.<id>]` tables.
//!
//! Each effect lives in its own module whose doc comment gives the equation, the units, typical
//! values and the signature the effect leaves in a trace. This module reads and validates the
//! tables (with [`Fields`], so errors name the model file and the dotted key) and converts every
//! parameter to motor units: on a ball-screw axis a force `F` (N) on the table becomes the torque
//! `F / r` (N m) with `r = 2 pi gear_ratio / lead_m` rad per m, a velocity `v` (m/s) becomes
//! `v r` (rad/s) and a viscous coefficient `c` (N s/m) becomes `c / r^2` (N m s/rad).
//!
//! Friction effects and `cogging` may be given several times as an array of tables
//! (`[[effects.coulomb_friction]]`), e.g. once on the motor side and once on the load side;
//! every other effect at most once.

pub mod backlash;
pub mod cogging;
pub mod constant_force;
pub mod coulomb_friction;
pub mod current_lag;
pub mod delay;
pub mod pitch_error;
pub mod stribeck_friction;
pub mod third_mass;
pub mod torque_saturation;
pub mod viscous_friction;

use feedloop_model::model::{AxisKind, ModelFile, PlantParams};
use feedloop_model::params::{nearest, ConfigError, ConfigErrorKind, Fields};
pub use feedloop_model::{EffectId, Side};

pub(crate) use cogging::CoggingHarmonic;
pub(crate) use coulomb_friction::DryFriction;
pub(crate) use pitch_error::PitchError;
pub(crate) use third_mass::ThirdMass;
pub(crate) use viscous_friction::Viscous;

/// The unit family of one body: suffixes of its keys and the factors to motor units.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Units {
    /// Suffix of a torque/force key: `nm` or `n`.
    pub torque: &'static str,
    /// Suffix of a velocity key: `rad_per_s` or `m_per_s`.
    pub vel: &'static str,
    /// Suffix of a viscous-coefficient key: `nms_per_rad` or `ns_per_m`.
    pub visc: &'static str,
    /// Suffix of an angle/position: `rad` or `m`.
    pub pos: &'static str,
    /// Multiply a torque/force in these units by this to get motor-unit torque.
    pub torque_to_motor: f64,
    /// Multiply a velocity in these units by this to get motor-unit velocity.
    pub vel_to_motor: f64,
}

impl Units {
    const ROTARY: Units = Units {
        torque: "nm",
        vel: "rad_per_s",
        visc: "nms_per_rad",
        pos: "rad",
        torque_to_motor: 1.0,
        vel_to_motor: 1.0,
    };

    fn linear(motor_per_load: f64) -> Units {
        Units {
            torque: "n",
            vel: "m_per_s",
            visc: "ns_per_m",
            pos: "m",
            torque_to_motor: 1.0 / motor_per_load,
            vel_to_motor: motor_per_load,
        }
    }
}

/// What an effect parser knows about the axis.
pub(crate) struct Ctx {
    /// Axis kind.
    pub kind: AxisKind,
    /// Motor units per load unit (rad/m for a ball screw, else 1).
    pub motor_per_load: f64,
    /// Screw lead, m (ball screw only).
    pub lead_m: Option<f64>,
}

impl Ctx {
    /// Units of the body a side acts on.
    pub fn units(&self, side: Side) -> Units {
        match (self.kind, side) {
            (AxisKind::Rigid, _) => Units::linear(1.0),
            (AxisKind::BallScrew, Side::Load) => Units::linear(self.motor_per_load),
            _ => Units::ROTARY,
        }
    }

    /// Units of the load body.
    pub fn load_units(&self) -> Units {
        self.units(Side::Load)
    }
}

/// Refuses keys not in `known`: the error suggests the nearest known key (the shared rule of
/// [`feedloop_model::params::nearest`]; else one with the same stem, as the axis/side fixes the
/// unit suffix) and lists the keys this table accepts.
pub(crate) fn check_keys(
    f: &Fields<'_>,
    table: &toml::Table,
    known: &[&str],
) -> Result<(), ConfigError> {
    for key in table.keys() {
        if !known.contains(&key.as_str()) {
            let stem = |k: &str| k.split('_').next().unwrap_or("").to_string();
            let same_stem = |k: &&str| !stem(key).is_empty() && stem(k) == stem(key);
            let suggestion = nearest(key, known.iter().copied())
                .or_else(|| known.iter().copied().find(same_stem));
            let hint = match suggestion {
                Some(k) if same_stem(&k) => {
                    format!("; did you mean `{k}` (this axis/side uses these units)?")
                }
                Some(k) => format!("; did you mean `{k}`?"),
                None => String::new(),
            };
            return Err(f.error_of(
                ConfigErrorKind::UnknownKey,
                key,
                format!("unknown key{hint} (accepted here: {})", known.join(", ")),
            ));
        }
    }
    Ok(())
}

/// An error about the whole table `f` reads (key = the table's dotted path).
pub(crate) fn table_error(f: &Fields<'_>, reason: impl Into<String>) -> ConfigError {
    let mut e = f.error("", reason);
    if e.key.ends_with('.') {
        e.key.pop();
    }
    e
}

/// Reads the optional `side` key (default motor) and returns it with the units of the body it
/// names (the units of the table's other keys).
pub(crate) fn read_side(f: &mut Fields<'_>, ctx: &Ctx) -> Result<(Side, Units), ConfigError> {
    let side = match f.opt_str("side")? {
        None => Side::Motor,
        Some(s) => Side::parse(s).ok_or_else(|| {
            f.error(
                "side",
                format!("unknown side `{s}` (expected \"motor\" or \"load\")"),
            )
        })?,
    };
    Ok((side, ctx.units(side)))
}

/// Largest number of cogging harmonics per axis.
pub const MAX_COGGING_HARMONICS: usize = 8;

/// All effects of one axis, validated and converted to motor units.
#[derive(Debug, Clone, Default)]
pub(crate) struct EffectSet {
    /// Viscous friction per body (0 motor, 1 load).
    pub viscous: [Option<Viscous>; 2],
    /// Dry friction per body.
    pub dry: [Option<DryFriction>; 2],
    /// Backlash: full gap width, motor rad (ballscrew/rotary).
    pub backlash_gap: Option<f64>,
    /// Pitch error.
    pub pitch: Option<PitchError>,
    /// Cogging harmonics.
    pub cogging: Vec<CoggingHarmonic>,
    /// Constant torque on the load, motor units.
    pub load_torque: Option<f64>,
    /// Third mass (inertia, stiffness, damping) in motor units.
    pub third_mass: Option<ThirdMass>,
    /// Transport delay, cycles.
    pub delay_cycles: usize,
    /// Current-loop lag time constant, s.
    pub lag_tau_s: Option<f64>,
    /// Torque limit, motor units.
    pub limit: Option<f64>,
}

/// Parses and validates the `[effects]` table of a model file.
/// Kept as one function (about 110 lines): the one dispatch over `EffectId`, with the checks
/// that span effects (one friction law per body and side, unknown ids, repeats).
pub(crate) fn parse(model: &ModelFile) -> Result<EffectSet, ConfigError> {
    let (motor_per_load, lead_m) = match model.plant {
        PlantParams::BallScrew { lead_m, .. } => (model.plant.motor_per_load(), Some(lead_m)),
        _ => (1.0, None),
    };
    let ctx = Ctx {
        kind: model.plant.kind(),
        motor_per_load,
        lead_m,
    };
    let mut set = EffectSet::default();
    let mut dry_from: [Option<String>; 2] = [None, None];
    let mut visc_from: [Option<String>; 2] = [None, None];
    for (id, value) in &model.effects {
        let key = format!("effects.{id}");
        let Some(effect) = EffectId::parse(id) else {
            return Err(ConfigError::new(
                &model.path,
                &key,
                format!(
                    "unknown effect `{id}`{} (known effects: {})",
                    EffectId::did_you_mean(id),
                    EffectId::list(|_| true)
                ),
            ));
        };
        let tables: Vec<(String, &toml::Table)> = match value {
            toml::Value::Table(t) => vec![(key.clone(), t)],
            toml::Value::Array(arr) if effect.repeatable() => {
                if arr.is_empty() {
                    return Err(ConfigError::new(&model.path, &key, "empty array of tables"));
                }
                let mut v = Vec::new();
                for (i, e) in arr.iter().enumerate() {
                    let k = format!("{key}[{i}]");
                    let t = e
                        .as_table()
                        .ok_or_else(|| ConfigError::new(&model.path, &k, "must be a table"))?;
                    v.push((k, t));
                }
                v
            }
            toml::Value::Array(_) => {
                return Err(ConfigError::new(
                    &model.path,
                    &key,
                    format!(
                        "`{id}` may be given only once ([effects.{id}]); only {} may repeat",
                        EffectId::list(EffectId::repeatable)
                    ),
                ))
            }
            other => {
                return Err(ConfigError::new(
                    &model.path,
                    &key,
                    format!("must be a table, got {}", other.type_str()),
                ))
            }
        };
        for (prefix, table) in tables {
            let mut f = Fields::new(table, &model.path, &prefix);
            match effect {
                EffectId::ViscousFriction => {
                    let (side, v) = viscous_friction::parse(&mut f, table, &ctx)?;
                    let b = side.body(ctx.kind);
                    if let Some(prev) = &visc_from[b] {
                        return Err(duplicate_side(&f, &prefix, prev, side, ctx.kind));
                    }
                    visc_from[b] = Some(prefix.clone());
                    set.viscous[b] = Some(v);
                }
                EffectId::CoulombFriction | EffectId::StribeckFriction => {
                    let (side, d) = if effect == EffectId::CoulombFriction {
                        coulomb_friction::parse(&mut f, table, &ctx)?
                    } else {
                        stribeck_friction::parse(&mut f, table, &ctx)?
                    };
                    let b = side.body(ctx.kind);
                    if let Some(prev) = &dry_from[b] {
                        return Err(duplicate_side(&f, &prefix, prev, side, ctx.kind));
                    }
                    dry_from[b] = Some(prefix.clone());
                    set.dry[b] = Some(d);
                }
                EffectId::Backlash => set.backlash_gap = backlash::parse(&mut f, table, &ctx)?,
                EffectId::PitchError => set.pitch = Some(pitch_error::parse(&mut f, table, &ctx)?),
                EffectId::Cogging => {
                    if set.cogging.len() >= MAX_COGGING_HARMONICS {
                        return Err(ConfigError::new(
                            &model.path,
                            &prefix,
                            format!("at most {MAX_COGGING_HARMONICS} cogging harmonics"),
                        ));
                    }
                    set.cogging.push(cogging::parse(&mut f, table, &ctx)?);
                }
                EffectId::ConstantForce => {
                    set.load_torque = Some(constant_force::parse(&mut f, table, &ctx)?)
                }
                EffectId::ThirdMass => {
                    set.third_mass = Some(third_mass::parse(&mut f, table, &ctx)?)
                }
                EffectId::Delay => set.delay_cycles = delay::parse(&mut f, table)?,
                EffectId::CurrentLag => set.lag_tau_s = Some(current_lag::parse(&mut f, table)?),
                EffectId::TorqueSaturation => {
                    set.limit = Some(torque_saturation::parse(&mut f, table, &ctx)?)
                }
            }
            f.finish()?;
        }
    }
    Ok(set)
}

fn duplicate_side(
    f: &Fields<'_>,
    prefix: &str,
    prev: &str,
    side: Side,
    kind: AxisKind,
) -> ConfigError {
    let what = if kind == AxisKind::Rigid {
        "the single mass of this rigid axis".to_string()
    } else {
        format!("the {} side", side.id())
    };
    ConfigError::new(
        f.file(),
        prefix,
        format!(
            "{what} already has this kind of friction from `{prev}` (stribeck_friction includes the \
             Coulomb level; give one dry and one viscous friction per side)"
        ),
    )
}
