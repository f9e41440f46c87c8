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

/// The [`EffectTable`] of an effect whose table holds one number, the field `$field`:
/// `one_number_table!(Params, field, ctx => key, range)`, `key` naming it on the axis `ctx`.
macro_rules! one_number_table {
    ($params:ty, $field:ident, $ctx:ident => $key:expr, $range:expr) => {
        impl EffectTable for $params {
            fn read(f: &mut Fields<'_>, $ctx: &Ctx) -> Result<Self, ConfigError> {
                let $field = read_one(f, $key, $range)?;
                Ok(Self { $field })
            }

            fn to_table(&self, $ctx: &Ctx) -> toml::Table {
                one_table($key, self.$field)
            }
        }
    };
}

pub mod backlash;
pub mod cogging;
pub mod constant_force;
pub mod coulomb_friction;
pub mod current_lag;
pub mod delay;
pub mod directional_friction;
pub mod lost_motion;
pub mod pitch_error;
pub mod stribeck_friction;
pub mod third_mass;
pub mod torque_saturation;
pub mod unbalance;
pub mod viscous_friction;

use feedloop_model::model::{AxisKind, ModelFile, PlantParams};
use feedloop_model::params::{nearest, ConfigError, ConfigErrorKind, Fields, Range};
pub use feedloop_model::{EffectId, Side};

pub use backlash::BacklashParams;
pub use cogging::{CoggingParams, CoggingPeriod};
pub use constant_force::ConstantForceParams;
pub use coulomb_friction::CoulombFrictionParams;
pub use current_lag::CurrentLagParams;
pub use delay::DelayParams;
pub use directional_friction::DirectionalFrictionParams;
pub use lost_motion::LostMotionParams;
pub use pitch_error::PitchErrorParams;
pub use stribeck_friction::StribeckFrictionParams;
pub use third_mass::ThirdMassParams;
pub use torque_saturation::TorqueSaturationParams;
pub use unbalance::UnbalanceParams;
pub use viscous_friction::ViscousFrictionParams;

pub(crate) use cogging::CoggingHarmonic;
pub(crate) use coulomb_friction::DryFriction;
pub(crate) use lost_motion::LostMotion;
pub(crate) use pitch_error::PitchError;
pub(crate) use third_mass::ThirdMass;
pub(crate) use unbalance::Unbalance;
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

    /// The load of a geared rotary axis: rotary keys, converted through the gear.
    fn geared(gear_ratio: f64) -> Units {
        Units {
            torque_to_motor: 1.0 / gear_ratio,
            vel_to_motor: gear_ratio,
            ..Units::ROTARY
        }
    }

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

/// What an effect's parameters need to know about the axis: its kind, the ratio between motor and
/// load units, and the screw's lead (the default period of a pitch error).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ctx {
    /// Axis kind.
    pub kind: AxisKind,
    /// Motor units per load unit (rad/m for a ball screw, else 1).
    pub motor_per_load: f64,
    /// Screw lead, m (ball screw only).
    pub lead_m: Option<f64>,
}

impl Ctx {
    /// The context of the axis a model file describes.
    pub fn of(model: &ModelFile) -> Self {
        let lead_m = match model.plant {
            PlantParams::BallScrew { lead_m, .. } => Some(lead_m),
            PlantParams::Rotary { .. } | PlantParams::Rigid(_) => None,
        };
        let motor_per_load = model.plant.motor_per_load();
        Ctx {
            kind: model.plant.kind(),
            motor_per_load,
            lead_m,
        }
    }

    /// Units of the body a side acts on.
    pub(crate) fn units(&self, side: Side) -> Units {
        match (self.kind, side) {
            (AxisKind::Rigid, _) => Units::linear(1.0),
            (AxisKind::BallScrew, Side::Load) => Units::linear(self.motor_per_load),
            (AxisKind::Rotary, Side::Load) => Units::geared(self.motor_per_load),
            _ => Units::ROTARY,
        }
    }

    /// Units of the load body.
    pub(crate) fn load_units(&self) -> Units {
        self.units(Side::Load)
    }
}

/// Refuses keys not in `known`: the error suggests the nearest known key (the shared rule of
/// [`feedloop_model::params::nearest`]; else one with the same stem, as the axis/side fixes the
/// unit suffix) and lists the keys this table accepts.
pub(crate) fn check_keys(f: &Fields<'_>, known: &[&str]) -> Result<(), ConfigError> {
    for key in f.table().keys() {
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
/// The error of an effect of the transmission (`what`) on a rigid axis, which has none; `Ok` on
/// a ball-screw or rotary axis.
pub(crate) fn needs_transmission(f: &Fields<'_>, ctx: &Ctx, what: &str) -> Result<(), ConfigError> {
    if ctx.kind == AxisKind::Rigid {
        return Err(table_error(
            f,
            format!(
                "{what} needs a transmission (kind = \"ballscrew\" or \"rotary\"); a rigid axis has none"
            ),
        ));
    }
    Ok(())
}

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

/// Writes `value` under `key` (a float in the model file's units).
pub(crate) fn put(t: &mut toml::Table, key: impl Into<String>, value: f64) {
    t.insert(key.into(), toml::Value::Float(value));
}

/// Reads a table of one number, `key` (its only key), within `range`.
pub(crate) fn read_one(f: &mut Fields<'_>, key: &str, range: Range) -> Result<f64, ConfigError> {
    check_keys(f, &[key])?;
    f.f64(key, range)
}

/// The model-file table of one number, `key`.
pub(crate) fn one_table(key: &str, value: f64) -> toml::Table {
    let mut t = toml::Table::new();
    put(&mut t, key, value);
    t
}

/// Reads a friction table of one level per direction on the body its `side` names:
/// `{stem}_{unit}` for positive velocity and `{stem}_neg_{unit}` for negative (default: the
/// positive one), both >= 0, and no other key. Returns the side and the two levels.
pub(crate) fn read_level_pair(
    f: &mut Fields<'_>,
    ctx: &Ctx,
    stem: &str,
    unit: fn(&Units) -> &'static str,
) -> Result<(Side, f64, f64), ConfigError> {
    let (side, u) = read_side(f, ctx)?;
    let key = format!("{stem}_{}", unit(&u));
    let key_neg = format!("{stem}_neg_{}", unit(&u));
    check_keys(f, &["side", &key, &key_neg])?;
    let pos = f.f64(&key, Range::NonNegative)?;
    let neg = f.f64_or(&key_neg, Range::NonNegative, pos)?;
    Ok((side, pos, neg))
}

/// The table [`read_level_pair`] reads: the negative-direction key only where it differs.
pub(crate) fn level_pair_table(
    ctx: &Ctx,
    side: Side,
    stem: &str,
    unit: fn(&Units) -> &'static str,
    (pos, neg): (f64, f64),
) -> toml::Table {
    let u = ctx.units(side);
    let mut t = toml::Table::new();
    put(&mut t, format!("{stem}_{}", unit(&u)), pos);
    if neg != pos {
        put(&mut t, format!("{stem}_neg_{}", unit(&u)), neg);
    }
    put_side(&mut t, side, ctx);
    t
}

/// Writes the `side` key of a friction table (a rigid axis has one body and no side).
pub(crate) fn put_side(t: &mut toml::Table, side: Side, ctx: &Ctx) {
    if ctx.kind != AxisKind::Rigid {
        t.insert("side".into(), toml::Value::String(side.id().into()));
    }
}

/// The typed form of one `[effects.<id>]` table: the parameters as the model file gives them,
/// in the units of the body they act on (the units their keys name). Each effect's file
/// implements it for its parameters, so that its keys are spelled there only.
pub trait EffectTable: Sized {
    /// Reads one table (every key checked, errors naming the dotted key).
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError>;

    /// The model-file table (the keys [`EffectTable::read`] reads, floats unrounded).
    fn to_table(&self, ctx: &Ctx) -> toml::Table;
}

/// Declares [`EffectParams`], a variant per effect named as its [`EffectId`] and holding the
/// effect's [`EffectTable`], with the dispatch of reading and writing: an effect is one line of
/// the list below, and the match over [`EffectId`] it generates is exhaustive.
macro_rules! effect_params {
    ($($(#[$doc:meta])* $variant:ident($params:ty),)*) => {
        /// One `[effects.<id>]` table in typed form (see [`EffectTable`]). The plant converts
        /// these to motor units ([`EffectSet`]), the workbench to its regressor form.
        #[derive(Debug, Clone, Copy, PartialEq)]
        pub enum EffectParams {
            $($(#[$doc])* $variant($params),)*
        }

        impl EffectParams {
            /// Which effect.
            pub fn id(&self) -> EffectId {
                match self {
                    $(EffectParams::$variant(_) => EffectId::$variant,)*
                }
            }

            /// Reads one table of effect `id` (every key checked, errors naming the dotted key).
            fn read(id: EffectId, f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
                Ok(match id {
                    $(EffectId::$variant => EffectParams::$variant(<$params>::read(f, ctx)?),)*
                })
            }

            /// The model-file table of these parameters (the keys the plant reads, floats
            /// unrounded).
            pub fn to_table(&self, ctx: &Ctx) -> toml::Table {
                match self {
                    $(EffectParams::$variant(p) => p.to_table(ctx),)*
                }
            }
        }
    };
}

effect_params! {
    /// `viscous_friction`.
    ViscousFriction(ViscousFrictionParams),
    /// `coulomb_friction`.
    CoulombFriction(CoulombFrictionParams),
    /// `stribeck_friction`.
    StribeckFriction(StribeckFrictionParams),
    /// `backlash`.
    Backlash(BacklashParams),
    /// `pitch_error`.
    PitchError(PitchErrorParams),
    /// `cogging` (one harmonic).
    Cogging(CoggingParams),
    /// `constant_force`.
    ConstantForce(ConstantForceParams),
    /// `third_mass`.
    ThirdMass(ThirdMassParams),
    /// `delay`.
    Delay(DelayParams),
    /// `current_lag`.
    CurrentLag(CurrentLagParams),
    /// `torque_saturation`.
    TorqueSaturation(TorqueSaturationParams),
    /// `unbalance`.
    Unbalance(UnbalanceParams),
    /// `directional_friction`.
    DirectionalFriction(DirectionalFrictionParams),
    /// `lost_motion`.
    LostMotion(LostMotionParams),
}

impl EffectParams {
    /// The body a friction effect acts on (`None` for the other effects).
    pub fn side(&self) -> Option<Side> {
        match self {
            EffectParams::ViscousFriction(p) => Some(p.side),
            EffectParams::CoulombFriction(p) => Some(p.side),
            EffectParams::StribeckFriction(p) => Some(p.side),
            EffectParams::DirectionalFriction(p) => Some(p.side),
            EffectParams::Backlash(_)
            | EffectParams::PitchError(_)
            | EffectParams::Cogging(_)
            | EffectParams::ConstantForce(_)
            | EffectParams::ThirdMass(_)
            | EffectParams::Delay(_)
            | EffectParams::CurrentLag(_)
            | EffectParams::TorqueSaturation(_)
            | EffectParams::Unbalance(_)
            | EffectParams::LostMotion(_) => None,
        }
    }
}

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
    /// Load torque of the load angle.
    pub unbalance: Option<Unbalance>,
    /// Motor-to-load offset of the direction of travel.
    pub lost_motion: Option<LostMotion>,
}

impl EffectSet {
    /// Adds one effect, converted to motor units ([`read_effects`] has checked that no body gets
    /// two laws of one kind).
    fn add(&mut self, p: &EffectParams, ctx: &Ctx) {
        match p {
            EffectParams::ViscousFriction(p) => {
                self.viscous[p.side.body(ctx.kind)] = Some(p.motor(ctx));
            }
            EffectParams::CoulombFriction(p) => {
                self.dry[p.side.body(ctx.kind)] = Some(p.motor(ctx))
            }
            EffectParams::StribeckFriction(p) => {
                self.dry[p.side.body(ctx.kind)] = Some(p.motor(ctx));
            }
            EffectParams::Backlash(p) => self.backlash_gap = p.motor(ctx),
            EffectParams::PitchError(p) => self.pitch = Some(p.motor()),
            EffectParams::Cogging(p) => self.cogging.push(p.motor()),
            EffectParams::ConstantForce(p) => self.load_torque = Some(p.motor(ctx)),
            EffectParams::ThirdMass(p) => self.third_mass = Some(p.motor(ctx)),
            EffectParams::Delay(p) => self.delay_cycles = p.motor(),
            EffectParams::CurrentLag(p) => self.lag_tau_s = Some(p.tau_s),
            EffectParams::TorqueSaturation(p) => self.limit = Some(p.limit),
            EffectParams::Unbalance(p) => self.unbalance = Some(p.motor(ctx)),
            EffectParams::DirectionalFriction(p) => {
                let b = p.side.body(ctx.kind);
                let (dry, visc) = p.motor(ctx);
                self.dry[b] = Some(dry);
                self.viscous[b] = Some(visc);
            }
            EffectParams::LostMotion(p) => self.lost_motion = p.motor(ctx),
        }
    }
}

/// Parses and validates the `[effects]` table of a model file into motor units.
pub(crate) fn parse(model: &ModelFile) -> Result<EffectSet, ConfigError> {
    let ctx = Ctx::of(model);
    let mut set = EffectSet::default();
    for p in read_effects(model)? {
        set.add(&p, &ctx);
    }
    Ok(set)
}

/// The tables of effect `id` under `value` (`[effects.<id>]`, or `[[effects.<id>]]` for an
/// effect that may repeat), each with its dotted key.
fn effect_tables<'a>(
    model: &ModelFile,
    id: &str,
    effect: EffectId,
    value: &'a toml::Value,
) -> Result<Vec<(String, &'a toml::Table)>, ConfigError> {
    let key = format!("effects.{id}");
    match value {
        toml::Value::Table(t) => Ok(vec![(key, t)]),
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
            Ok(v)
        }
        toml::Value::Array(_) => Err(ConfigError::new(
            &model.path,
            &key,
            format!(
                "`{id}` may be given only once ([effects.{id}]); only {} may repeat",
                EffectId::list(EffectId::repeatable)
            ),
        )),
        other => Err(ConfigError::new(
            &model.path,
            &key,
            format!("must be a table, got {}", other.type_str()),
        )),
    }
}

/// Reads every `[effects.<id>]` table of a model file in typed form, in file order, with the
/// checks that span effects: unknown ids, repeats, one dry and one viscous friction law per
/// body, at most [`MAX_COGGING_HARMONICS`] cogging harmonics. Errors name the model file and the
/// dotted key.
pub fn read_effects(model: &ModelFile) -> Result<Vec<EffectParams>, ConfigError> {
    let ctx = Ctx::of(model);
    let mut out = Vec::new();
    let mut dry_from: [Option<String>; 2] = [None, None];
    let mut visc_from: [Option<String>; 2] = [None, None];
    let mut harmonics = 0;
    for (id, value) in &model.effects {
        let Some(effect) = EffectId::parse(id) else {
            return Err(ConfigError::new(
                &model.path,
                format!("effects.{id}"),
                format!(
                    "unknown effect `{id}`{} (known effects: {})",
                    EffectId::did_you_mean(id),
                    EffectId::list(|_| true)
                ),
            ));
        };
        for (prefix, table) in effect_tables(model, id, effect, value)? {
            let mut f = Fields::new(table, &model.path, &prefix);
            if effect == EffectId::Cogging {
                if harmonics >= MAX_COGGING_HARMONICS {
                    return Err(ConfigError::new(
                        &model.path,
                        &prefix,
                        format!("at most {MAX_COGGING_HARMONICS} cogging harmonics"),
                    ));
                }
                harmonics += 1;
            }
            let p = EffectParams::read(effect, &mut f, &ctx)?;
            // the friction laws a body may carry once each: one dry, one viscous
            let (dry, visc) = match effect {
                EffectId::ViscousFriction => (false, true),
                EffectId::CoulombFriction | EffectId::StribeckFriction => (true, false),
                EffectId::DirectionalFriction => (true, true),
                EffectId::Backlash
                | EffectId::PitchError
                | EffectId::Cogging
                | EffectId::ConstantForce
                | EffectId::ThirdMass
                | EffectId::Delay
                | EffectId::CurrentLag
                | EffectId::TorqueSaturation
                | EffectId::Unbalance
                | EffectId::LostMotion => (false, false),
            };
            if let Some(side) = p.side() {
                let b = side.body(ctx.kind);
                for (taken, seen) in [(dry, &mut dry_from), (visc, &mut visc_from)] {
                    if !taken {
                        continue;
                    }
                    if let Some(prev) = &seen[b] {
                        return Err(duplicate_side(&f, &prefix, prev, side, ctx.kind));
                    }
                    seen[b] = Some(prefix.clone());
                }
            }
            f.finish()?;
            out.push(p);
        }
    }
    Ok(out)
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
             Coulomb level, directional_friction is a dry and a viscous friction; give one dry and \
             one viscous friction per side)"
        ),
    )
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    /// The model `head` (plant keys) with the effect tables `effects` written back in.
    fn model(head: &str, effects: &toml::Table) -> ModelFile {
        let mut t: toml::Table = head.parse().expect("test model");
        t.insert("effects".into(), toml::Value::Table(effects.clone()));
        ModelFile::from_table(&t, Path::new("m.toml")).expect("valid model")
    }

    /// Every effect's table, written from its typed form, reads back to the same typed form,
    /// on the three kinds of axis and on both sides of a two-mass axis.
    #[test]
    fn typed_effects_round_trip_through_their_tables() {
        let two_mass = "jm_kgm2 = 2e-3\nkl_nm_per_rad = 3000.0\njl_kgm2 = 3e-3\n";
        let heads = [
            format!("kind = \"ballscrew\"\n{two_mass}lead_m = 0.01\n"),
            format!("kind = \"rotary\"\n{two_mass}gear_ratio = 120.0\n"),
            "kind = \"rigid\"\nmass_kg = 50.0\n".to_string(),
        ];
        for head in &heads {
            let probe = model(head, &toml::Table::new());
            let ctx = Ctx::of(&probe);
            let side = |s| match ctx.kind {
                AxisKind::Rigid => Side::Motor,
                AxisKind::BallScrew | AxisKind::Rotary => s,
            };
            let mut all = vec![
                EffectParams::ViscousFriction(ViscousFrictionParams {
                    side: side(Side::Load),
                    c: 2.5,
                    c_neg: 3.5,
                }),
                EffectParams::StribeckFriction(StribeckFrictionParams {
                    side: Side::Motor,
                    fc: 0.1,
                    fs: 0.25,
                    fc_neg: 0.12,
                    fs_neg: 0.2,
                    vs: 0.7,
                    exponent: 1.0,
                }),
                EffectParams::Cogging(CoggingParams {
                    amplitude: 0.05,
                    period: match ctx.kind {
                        AxisKind::Rigid => CoggingPeriod::Metres(0.032),
                        AxisKind::BallScrew | AxisKind::Rotary => CoggingPeriod::PerRev(12),
                    },
                    phase_rad: -0.4,
                }),
                EffectParams::ConstantForce(ConstantForceParams { value: -49.0 }),
                EffectParams::ThirdMass(ThirdMassParams {
                    mass: 5.0,
                    stiffness: 5e6,
                    damping: 20.0,
                }),
                EffectParams::Delay(DelayParams { cycles: 3 }),
                EffectParams::CurrentLag(CurrentLagParams { tau_s: 2e-4 }),
                EffectParams::TorqueSaturation(TorqueSaturationParams { limit: 12.0 }),
            ];
            if ctx.kind != AxisKind::Rigid {
                all.push(EffectParams::CoulombFriction(CoulombFrictionParams {
                    side: Side::Load,
                    fc: 30.0,
                    fc_neg: 30.0,
                }));
                all.push(EffectParams::Backlash(BacklashParams { gap: 1e-5 }));
                all.push(EffectParams::LostMotion(LostMotionParams {
                    lost: 2e-5,
                    transition: 3e-3,
                }));
            }
            if ctx.kind == AxisKind::Rotary {
                all.push(EffectParams::Unbalance(UnbalanceParams {
                    mgr_nm: 98.0,
                    zero_angle_rad: -0.2,
                    constant_nm: 3.5,
                    period_rad: 1680.0,
                }));
            }
            if ctx.kind == AxisKind::BallScrew {
                all.push(EffectParams::PitchError(PitchErrorParams {
                    amplitude_m: 2e-6,
                    period_m: 0.01,
                    phase_rad: 0.3,
                    slope_um_per_m: 10.0,
                }));
            }
            let mut tables = toml::Table::new();
            for p in &all {
                tables.insert(p.id().id().into(), toml::Value::Table(p.to_table(&ctx)));
            }
            let back = read_effects(&model(head, &tables)).expect("tables it wrote");
            assert_eq!(back.len(), all.len(), "{head}");
            for p in &all {
                assert!(
                    back.contains(p),
                    "{head}: {p:?} not read back from {tables}"
                );
            }
        }
    }
}

#[cfg(test)]
mod directional_tests {
    use std::path::Path;

    use super::*;

    #[test]
    fn directional_friction_round_trips_and_takes_both_friction_slots_of_its_body() {
        let head = "kind = \"ballscrew\"\njm_kgm2 = 2e-3\nkl_nm_per_rad = 3000.0\njl_kgm2 = 3e-3\nlead_m = 0.01\n";
        let model = |effects: &str| {
            let t: toml::Table = format!("{head}{effects}").parse().unwrap();
            ModelFile::from_table(&t, Path::new("m.toml")).unwrap()
        };
        let m = model(
            "[effects.directional_friction]\nside = \"load\"\nfc_pos_n = 40.0\nfc_neg_n = 30.0\nc_pos_ns_per_m = 500.0\n",
        );
        let p = read_effects(&m).unwrap();
        let EffectParams::DirectionalFriction(d) = p[0] else {
            panic!("{p:?}")
        };
        assert_eq!(
            (d.fc_pos, d.fc_neg, d.c_pos, d.c_neg),
            (40.0, 30.0, 500.0, 0.0)
        );
        let mut eff = toml::Table::new();
        eff.insert(
            "directional_friction".into(),
            toml::Value::Table(p[0].to_table(&Ctx::of(&m))),
        );
        let mut t: toml::Table = head.parse().unwrap();
        t.insert("effects".into(), toml::Value::Table(eff));
        let back = read_effects(&ModelFile::from_table(&t, Path::new("m.toml")).unwrap()).unwrap();
        assert_eq!(back, p);
        // it is the load's dry and viscous friction: a second one on that body is refused
        for other in [
            "[effects.coulomb_friction]\nside = \"load\"\nfc_n = 1.0\n",
            "[effects.viscous_friction]\nside = \"load\"\nc_ns_per_m = 1.0\n",
        ] {
            let m = model(&format!(
                "[effects.directional_friction]\nside = \"load\"\nfc_pos_n = 4.0\nfc_neg_n = 3.0\n{other}"
            ));
            let e = read_effects(&m).unwrap_err();
            assert!(
                e.reason.contains("already has this kind of friction"),
                "{e}"
            );
        }
        // on the other body it is fine
        let m = model(
            "[effects.directional_friction]\nside = \"load\"\nfc_pos_n = 4.0\nfc_neg_n = 3.0\n[effects.coulomb_friction]\nfc_nm = 0.1\n",
        );
        assert_eq!(read_effects(&m).unwrap().len(), 2);
    }
}
