//! Model files: one feed-drive axis (plant parameters, default controller, effects, sensor).
//!
//! Keys are fixed and SI (see `docs/model-file.md`). Plant keys sit at the top level, the
//! controller that drives the axis under `[controller]`, physical effects under
//! `[effects.<id>]` (validated by the plant library) and the sensor/noise model under `[sensor]`.
//!
//! ```toml
//! kind = "ballscrew"
//! jm_kgm2 = 2.0e-3
//! dm_nms_per_rad = 1.0e-3
//! kl_nm_per_rad = 3000.0
//! cl_nms_per_rad = 0.05
//! jl_kgm2 = 3.0e-3
//! dl_nms_per_rad = 2.0e-3
//! lead_m = 0.01
//! gear_ratio = 1.0
//! [controller]
//! kp_per_s = 50.0
//! kv_nms_per_rad = 5.0
//! tv_s = 0.005
//! torque_limit_nm = 30.0
//! velocity_ff = 1.0         # optional: share of the command velocity fed forward
//! torque_ff_kgm2 = 5.0e-3   # optional: inertia times command acceleration fed forward
//! ```

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use crate::params::{read_toml_file, ConfigError, Fields, Range};

/// The physical structure of an axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AxisKind {
    /// Rotary motor -> ball screw -> table: 2-mass model in motor-side rad; load position in m.
    BallScrew,
    /// Rotary motor -> elastic shaft -> rotary load (e.g. a direct-drive C axis): load in rad.
    Rotary,
    /// A single rigid mass driven by a force (linear motor, or a load-side model such as EMPS): m, N.
    Rigid,
}

impl AxisKind {
    /// The id used in model files.
    pub fn id(self) -> &'static str {
        match self {
            AxisKind::BallScrew => "ballscrew",
            AxisKind::Rotary => "rotary",
            AxisKind::Rigid => "rigid",
        }
    }
}

/// Parameters of the 2-mass model of seed 000, all on the motor side (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwoMassParams {
    /// Motor (rotor + coupling) inertia JM, kg m^2. Typical 1e-4 .. 1e-2.
    pub jm_kgm2: f64,
    /// Motor-side viscous damping DM, N m s/rad. Typical 1e-4 .. 1e-2.
    pub dm_nms_per_rad: f64,
    /// Screw/coupling torsional stiffness KL seen from the motor, N m/rad. Typical 1e3 .. 1e4.
    pub kl_nm_per_rad: f64,
    /// Damping of that spring CL, N m s/rad. Typical 0 .. 0.5.
    pub cl_nms_per_rad: f64,
    /// Load (table + workpiece) inertia reflected to the motor JL, kg m^2.
    pub jl_kgm2: f64,
    /// Load-side viscous damping DL, N m s/rad.
    pub dl_nms_per_rad: f64,
}

/// Parameters of a rigid mass driven by a force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidParams {
    /// Moving mass, kg.
    pub mass_kg: f64,
    /// Viscous friction, N s/m.
    pub viscous_ns_per_m: f64,
}

/// The plant part of a model file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PlantParams {
    /// `kind = "ballscrew"`.
    BallScrew {
        /// The 2-mass parameters.
        two_mass: TwoMassParams,
        /// Screw lead, m per screw revolution. Typical 0.005 .. 0.02.
        lead_m: f64,
        /// Motor revolutions per screw revolution (1 for direct coupling).
        gear_ratio: f64,
    },
    /// `kind = "rotary"`.
    Rotary {
        /// The 2-mass parameters.
        two_mass: TwoMassParams,
        /// Motor revolutions per load revolution (1 for a direct drive).
        gear_ratio: f64,
    },
    /// `kind = "rigid"`.
    Rigid(RigidParams),
}

impl PlantParams {
    /// Axis kind.
    pub fn kind(&self) -> AxisKind {
        match self {
            PlantParams::BallScrew { .. } => AxisKind::BallScrew,
            PlantParams::Rotary { .. } => AxisKind::Rotary,
            PlantParams::Rigid(_) => AxisKind::Rigid,
        }
    }

    /// Motor units per load unit: rad per m for a ball screw (2 pi gear / lead), the gear ratio
    /// (motor rad per load rad) for a rotary axis, 1 for a rigid one.
    pub fn motor_per_load(&self) -> f64 {
        match self {
            PlantParams::BallScrew {
                lead_m, gear_ratio, ..
            } => 2.0 * PI * gear_ratio / lead_m,
            PlantParams::Rotary { gear_ratio, .. } => *gear_ratio,
            PlantParams::Rigid(_) => 1.0,
        }
    }

    /// The 2-mass parameters, if the axis has them.
    pub fn two_mass(&self) -> Option<&TwoMassParams> {
        match self {
            PlantParams::BallScrew { two_mass, .. } | PlantParams::Rotary { two_mass, .. } => {
                Some(two_mass)
            }
            PlantParams::Rigid(_) => None,
        }
    }

    /// Total inertia (kg m^2) or mass (kg) that the motor accelerates, in motor units.
    pub fn total_inertia(&self) -> f64 {
        match self {
            PlantParams::BallScrew { two_mass, .. } | PlantParams::Rotary { two_mass, .. } => {
                two_mass.jm_kgm2 + two_mass.jl_kgm2
            }
            PlantParams::Rigid(r) => r.mass_kg,
        }
    }
}

/// The controller the model's axis runs under (defaults for the job's chain).
///
/// Gains are in motor units: for a ball-screw axis rad, rad/s, N m; for a rigid axis m, m/s, N.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ControllerParams {
    /// Position loop gain Kp, 1/s (V = Kp (th - thL)). Typical 20 .. 150.
    pub kp_per_s: Option<f64>,
    /// Velocity loop gain Kv: N m s/rad (`kv_nms_per_rad`) or N s/m (`kv_ns_per_m`).
    pub kv: Option<f64>,
    /// Velocity loop integral time Tv, s (0 = proportional only). Typical 0.002 .. 0.02.
    pub tv_s: Option<f64>,
    /// Output limit: N m (`torque_limit_nm`) or N (`force_limit_n`).
    pub torque_limit: Option<f64>,
    /// Velocity feed-forward (`velocity_ff`): the share of the commanded velocity added to the
    /// velocity command, V = Kp (th - thL) + velocity_ff dth/dt. 0 (absent) .. 1 (full); every
    /// CNC drive has it.
    pub velocity_ff: Option<f64>,
    /// Torque feed-forward: the inertia the commanded acceleration is multiplied by and added to
    /// the velocity loop's output, kg m^2 (`torque_ff_kgm2`, motor side) or kg (`force_ff_kg`).
    pub torque_ff: Option<f64>,
}

/// One parsed model file.
#[derive(Debug, Clone)]
pub struct ModelFile {
    /// Where it was read from (for messages and relative paths).
    pub path: PathBuf,
    /// The plant's base parameters.
    pub plant: PlantParams,
    /// The controller defaults.
    pub controller: ControllerParams,
    /// `[effects.<id>]` tables, validated by the plant library.
    pub effects: toml::Table,
    /// `[sensor]` table (noise model), validated by the plant library.
    pub sensor: toml::Table,
}

impl ModelFile {
    /// Reads and validates a model file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let table = read_toml_file(path)?;
        Self::from_table(&table, path)
    }

    /// Validates a parsed model table (`path` is used in messages).
    pub fn from_table(table: &toml::Table, path: &Path) -> Result<Self, ConfigError> {
        let mut f = Fields::new(table, path, "");
        let kind = f.str("kind")?;
        let plant = match kind {
            "ballscrew" => PlantParams::BallScrew {
                two_mass: two_mass(&mut f)?,
                lead_m: f.f64("lead_m", Range::Positive)?,
                gear_ratio: f.f64_or("gear_ratio", Range::Positive, 1.0)?,
            },
            "rotary" => PlantParams::Rotary {
                two_mass: two_mass(&mut f)?,
                gear_ratio: f.f64_or("gear_ratio", Range::Positive, 1.0)?,
            },
            "rigid" => PlantParams::Rigid(RigidParams {
                mass_kg: f.f64("mass_kg", Range::Positive)?,
                viscous_ns_per_m: f.f64_or("viscous_ns_per_m", Range::NonNegative, 0.0)?,
            }),
            other => {
                return Err(f.error(
                    "kind",
                    format!("unknown axis kind `{other}` (expected ballscrew, rotary or rigid)"),
                ))
            }
        };
        let controller = match f.opt_table("controller")? {
            Some(t) => controller_params(t, path, plant.kind())?,
            None => ControllerParams::default(),
        };
        let effects = f.opt_table("effects")?.cloned().unwrap_or_default();
        let sensor = f.opt_table("sensor")?.cloned().unwrap_or_default();
        f.finish()?;
        Ok(Self {
            path: path.to_path_buf(),
            plant,
            controller,
            effects,
            sensor,
        })
    }
}

fn two_mass(f: &mut Fields<'_>) -> Result<TwoMassParams, ConfigError> {
    Ok(TwoMassParams {
        jm_kgm2: f.f64("jm_kgm2", Range::Positive)?,
        dm_nms_per_rad: f.f64_or("dm_nms_per_rad", Range::NonNegative, 0.0)?,
        kl_nm_per_rad: f.f64("kl_nm_per_rad", Range::Positive)?,
        cl_nms_per_rad: f.f64_or("cl_nms_per_rad", Range::NonNegative, 0.0)?,
        jl_kgm2: f.f64("jl_kgm2", Range::Positive)?,
        dl_nms_per_rad: f.f64_or("dl_nms_per_rad", Range::NonNegative, 0.0)?,
    })
}

fn controller_params(
    t: &toml::Table,
    path: &Path,
    kind: AxisKind,
) -> Result<ControllerParams, ConfigError> {
    let mut f = Fields::new(t, path, "controller");
    let (kv_key, lim_key, ff_key) = match kind {
        AxisKind::Rigid => ("kv_ns_per_m", "force_limit_n", "force_ff_kg"),
        _ => ("kv_nms_per_rad", "torque_limit_nm", "torque_ff_kgm2"),
    };
    let p = ControllerParams {
        kp_per_s: f.opt_f64("kp_per_s", Range::NonNegative)?,
        kv: f.opt_f64(kv_key, Range::Positive)?,
        tv_s: f.opt_f64("tv_s", Range::NonNegative)?,
        torque_limit: f.opt_f64(lim_key, Range::Positive)?,
        velocity_ff: f.opt_f64("velocity_ff", Range::Within(0.0, 1.5))?,
        torque_ff: f.opt_f64(ff_key, Range::NonNegative)?,
    };
    f.finish()?;
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
kind = "ballscrew"
jm_kgm2 = 2.0e-3
kl_nm_per_rad = 3000.0
jl_kgm2 = 3.0e-3
lead_m = 0.01
[controller]
kp_per_s = 50
kv_nms_per_rad = 5.0
tv_s = 0.005
torque_limit_nm = 30
"#;

    fn parse(s: &str) -> Result<ModelFile, ConfigError> {
        let t: toml::Table = s.parse().unwrap();
        ModelFile::from_table(&t, Path::new("m.toml"))
    }

    #[test]
    fn ballscrew_model_reads_with_defaults() {
        let m = parse(GOOD).unwrap();
        assert!((m.plant.motor_per_load() - 2.0 * PI / 0.01).abs() < 1e-9);
        assert_eq!(m.controller.kp_per_s, Some(50.0));
        assert_eq!(m.plant.two_mass().unwrap().cl_nms_per_rad, 0.0);
    }

    #[test]
    fn negative_load_inertia_is_refused_naming_the_key() {
        let e = parse(&GOOD.replace("jl_kgm2 = 3.0e-3", "jl_kgm2 = -3.0e-3")).unwrap_err();
        assert_eq!(e.key, "jl_kgm2");
    }

    #[test]
    fn rigid_axis_refuses_rotary_controller_keys() {
        let e = parse("kind = \"rigid\"\nmass_kg = 95\n[controller]\nkv_nms_per_rad = 3\n")
            .unwrap_err();
        assert_eq!(e.key, "controller.kv_nms_per_rad");
    }

    #[test]
    fn unknown_kind_is_refused() {
        let e = parse("kind = \"hydraulic\"\n").unwrap_err();
        assert_eq!(e.key, "kind");
    }
}
