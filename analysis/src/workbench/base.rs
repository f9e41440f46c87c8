//! The plant's base parameters in the torque balance (masses, inertias, viscous damping), as one
//! closed set: each names its model-file key, its regressor column and its identifiability class.

use std::fmt;

use feedloop_model::model::{AxisKind, PlantParams};

use super::data::AxisData;

/// One base parameter of the torque balance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum BaseParam {
    /// `mass_kg`: the moving mass of a rigid axis.
    MassKg,
    /// `viscous_ns_per_m`: the viscous damping of a rigid axis.
    ViscousNsPerM,
    /// `jm_kgm2`: the motor-side inertia of a two-mass axis.
    JmKgm2,
    /// `jl_kgm2`: the load-side inertia of a two-mass axis.
    JlKgm2,
    /// `dm_nms_per_rad`: the motor-side viscous damping.
    DmNmsPerRad,
    /// `dl_nms_per_rad`: the load-side viscous damping.
    DlNmsPerRad,
}

/// What a base parameter is, for grouping candidates that the data cannot tell apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BaseClass {
    /// A mass or an inertia (must stay above zero).
    Inertia,
    /// A viscous damping (may be zero).
    Damping,
}

impl BaseClass {
    /// The class's name in a diagnosis (`inertia`, `damping`).
    pub fn id(self) -> &'static str {
        match self {
            BaseClass::Inertia => "inertia",
            BaseClass::Damping => "damping",
        }
    }
}

impl BaseParam {
    /// The base parameters of a rigid axis, in the order a model lists them.
    pub const RIGID: [BaseParam; 2] = [BaseParam::MassKg, BaseParam::ViscousNsPerM];
    /// The base parameters of a two-mass axis (ball screw or rotary), in the order a model lists
    /// them.
    pub const TWO_MASS: [BaseParam; 4] = [
        BaseParam::JmKgm2,
        BaseParam::JlKgm2,
        BaseParam::DmNmsPerRad,
        BaseParam::DlNmsPerRad,
    ];

    /// The model-file key.
    pub fn key(self) -> &'static str {
        match self {
            BaseParam::MassKg => "mass_kg",
            BaseParam::ViscousNsPerM => "viscous_ns_per_m",
            BaseParam::JmKgm2 => "jm_kgm2",
            BaseParam::JlKgm2 => "jl_kgm2",
            BaseParam::DmNmsPerRad => "dm_nms_per_rad",
            BaseParam::DlNmsPerRad => "dl_nms_per_rad",
        }
    }

    /// The base parameters of an axis of `kind`.
    pub fn of_kind(kind: AxisKind) -> &'static [BaseParam] {
        match kind {
            AxisKind::Rigid => &BaseParam::RIGID,
            AxisKind::BallScrew | AxisKind::Rotary => &BaseParam::TWO_MASS,
        }
    }

    /// The base parameter of an axis of `kind` with model-file key `key`.
    pub fn parse(kind: AxisKind, key: &str) -> Option<BaseParam> {
        BaseParam::of_kind(kind)
            .iter()
            .copied()
            .find(|p| p.key() == key)
    }

    /// Its identifiability class.
    pub fn class(self) -> BaseClass {
        match self {
            BaseParam::MassKg | BaseParam::JmKgm2 | BaseParam::JlKgm2 => BaseClass::Inertia,
            BaseParam::ViscousNsPerM | BaseParam::DmNmsPerRad | BaseParam::DlNmsPerRad => {
                BaseClass::Damping
            }
        }
    }

    /// Whether it acts on the load body of a two-mass axis (and so needs the load's motion).
    pub fn on_load(self) -> bool {
        match self {
            BaseParam::JlKgm2 | BaseParam::DlNmsPerRad => true,
            BaseParam::MassKg
            | BaseParam::ViscousNsPerM
            | BaseParam::JmKgm2
            | BaseParam::DmNmsPerRad => false,
        }
    }

    /// Its regressor column: the torque needed per unit of the parameter.
    pub fn column(self, d: &AxisData) -> &[f64] {
        match self {
            BaseParam::MassKg | BaseParam::JmKgm2 => &d.am,
            BaseParam::JlKgm2 => &d.al,
            BaseParam::ViscousNsPerM | BaseParam::DmNmsPerRad => &d.vm,
            BaseParam::DlNmsPerRad => &d.vl,
        }
    }

    /// Its value in `plant` (`None` on a plant of the other structure).
    pub fn get(self, plant: &PlantParams) -> Option<f64> {
        let mut p = *plant;
        self.slot(&mut p).map(|v| *v)
    }

    /// Sets its value in `plant` (no change on a plant of the other structure).
    pub fn set(self, plant: &mut PlantParams, v: f64) {
        if let Some(s) = self.slot(plant) {
            *s = v;
        }
    }

    /// Where it lives in `plant` (`None` on a plant of the other structure).
    fn slot(self, plant: &mut PlantParams) -> Option<&mut f64> {
        match plant {
            PlantParams::Rigid(p) => match self {
                BaseParam::MassKg => Some(&mut p.mass_kg),
                BaseParam::ViscousNsPerM => Some(&mut p.viscous_ns_per_m),
                BaseParam::JmKgm2
                | BaseParam::JlKgm2
                | BaseParam::DmNmsPerRad
                | BaseParam::DlNmsPerRad => None,
            },
            PlantParams::BallScrew { two_mass: t, .. }
            | PlantParams::Rotary { two_mass: t, .. } => match self {
                BaseParam::JmKgm2 => Some(&mut t.jm_kgm2),
                BaseParam::JlKgm2 => Some(&mut t.jl_kgm2),
                BaseParam::DmNmsPerRad => Some(&mut t.dm_nms_per_rad),
                BaseParam::DlNmsPerRad => Some(&mut t.dl_nms_per_rad),
                BaseParam::MassKg | BaseParam::ViscousNsPerM => None,
            },
        }
    }
}

impl fmt::Display for BaseParam {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.key())
    }
}

impl AsRef<str> for BaseParam {
    fn as_ref(&self) -> &str {
        self.key()
    }
}
