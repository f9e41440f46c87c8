//! What the procedure may know of the axis without measuring it: the data-sheet facts, and the
//! jobs its experiments are written as.

use feedloop_control::loop_model::Gains;
use feedloop_model::model::{ModelFile, PlantParams};
use serde::Serialize;

use super::device::{Bounds, Experiment};

/// The data-sheet facts of one axis.
#[derive(Debug, Clone, Serialize)]
pub struct Facts {
    /// Motor inertia (given on the command line), kg m^2.
    pub jm_kgm2: f64,
    /// Screw lead, m per revolution.
    pub lead_m: f64,
    /// Motor revolutions per screw revolution.
    pub gear_ratio: f64,
    /// Drive torque limit, N m.
    pub torque_limit_nm: f64,
    /// Travel either side of the start, m.
    pub travel_m: f64,
    /// Motor encoder counts per revolution (`None`: not given).
    pub counts_per_rev: Option<f64>,
    /// How the drive measures the motor velocity (`exact` or `difference`).
    pub velocity_estimate: String,
    /// The drive's starting gains.
    pub start: Gains,
    /// Control period, s.
    pub period_s: f64,
}

impl Facts {
    /// The facts a data sheet gives of the axis of `model`, with the user's `jm_kgm2` and
    /// `travel_m`; a model without a lead (not a ball screw) is refused.
    pub fn from_model(m: &ModelFile, jm_kgm2: f64, travel_m: f64) -> Result<Self, String> {
        let PlantParams::BallScrew {
            lead_m, gear_ratio, ..
        } = m.plant
        else {
            return Err(format!(
                "{}: commissioning needs a ball-screw axis (kind = \"ballscrew\"), this one is \"{}\"",
                m.path.display(),
                m.plant.kind().id()
            ));
        };
        if !(jm_kgm2.is_finite() && jm_kgm2 > 0.0) {
            return Err(format!(
                "--jm-kgm2 must be a motor inertia > 0 kg m^2, got {jm_kgm2}"
            ));
        }
        if !(travel_m.is_finite() && travel_m > 0.0) {
            return Err(format!("--travel-m must be > 0 m, got {travel_m}"));
        }
        let c = &m.controller;
        let counts = m
            .sensor
            .get("motor_counts_per_rev")
            .and_then(|v| v.as_integer().map(|i| i as f64).or_else(|| v.as_float()));
        let velocity_estimate = m
            .sensor
            .get("velocity_estimate")
            .and_then(|v| v.as_str())
            .unwrap_or("exact")
            .to_string();
        Ok(Self {
            jm_kgm2,
            lead_m,
            gear_ratio,
            torque_limit_nm: c.torque_limit.unwrap_or(30.0),
            travel_m,
            counts_per_rev: counts,
            velocity_estimate,
            start: Gains {
                kp_per_s: c.kp_per_s.unwrap_or(50.0),
                kv_nms_per_rad: c.kv.unwrap_or(5.0),
                tv_s: c.tv_s.unwrap_or(0.005),
            },
            period_s: 1e-4,
        })
    }

    /// Motor radians per metre of table travel.
    pub fn ratio(&self) -> f64 {
        2.0 * std::f64::consts::PI * self.gear_ratio / self.lead_m
    }

    /// The bounds every experiment keeps: the travel less 5 %, 80 % of the torque limit, and
    /// a following error of `following_m`.
    pub fn bounds(&self, following_m: f64) -> Bounds {
        Bounds {
            following_m,
            torque_nm: 0.8 * self.torque_limit_nm,
            travel_m: 0.95 * self.travel_m,
        }
    }
}

/// A chain entry table.
pub fn entry(axis: &str, stage: &str, plugin: &str, params: toml::Table) -> toml::Value {
    let mut e = toml::Table::new();
    e.insert("axis".into(), axis.into());
    e.insert("stage".into(), stage.into());
    e.insert("plugin".into(), plugin.into());
    if !params.is_empty() {
        e.insert("params".into(), toml::Value::Table(params));
    }
    toml::Value::Table(e)
}

/// A table of float keys.
pub fn floats(kv: &[(&str, f64)]) -> toml::Table {
    kv.iter()
        .map(|(k, v)| (k.to_string(), toml::Value::Float(*v)))
        .collect()
}

/// The P/PI cascade of `axis` with gains `g` (given explicitly: the device's own defaults are
/// not read).
pub fn cascade(axis: &str, g: Gains) -> Vec<toml::Value> {
    vec![
        entry(
            axis,
            "position",
            "position_p",
            floats(&[("kp_per_s", g.kp_per_s)]),
        ),
        entry(
            axis,
            "velocity",
            "pi_velocity",
            floats(&[("kv_nms_per_rad", g.kv_nms_per_rad), ("tv_s", g.tv_s)]),
        ),
    ]
}

/// An experiment on `axes` with the chain `chain` and the trajectory `traj`.
pub fn experiment(
    name: &str,
    facts: &Facts,
    axes: &[&str],
    chain: Vec<toml::Value>,
    traj: toml::Table,
    bounds: Bounds,
) -> Experiment {
    let mut job = toml::Table::new();
    job.insert("name".into(), name.replace(['/', '.'], "-").into());
    job.insert("period_s".into(), toml::Value::Float(facts.period_s));
    let mut at = toml::Table::new();
    for a in axes {
        at.insert(a.to_string(), toml::Value::Table(toml::Table::new()));
    }
    job.insert("axes".into(), toml::Value::Table(at));
    job.insert("chain".into(), toml::Value::Array(chain));
    job.insert("trajectory".into(), toml::Value::Table(traj));
    Experiment {
        name: name.replace(['/', '.'], "-"),
        job,
        bounds,
    }
}

/// `{ axis = value }`.
pub fn per_axis(axis: &str, v: f64) -> toml::Value {
    let mut t = toml::Table::new();
    t.insert(axis.into(), toml::Value::Float(v));
    toml::Value::Table(t)
}
