//! Axis contexts for unit tests.

use feedloop_control::controller::AxisContext;
use feedloop_model::model::{ControllerParams, PlantParams, RigidParams, TwoMassParams};

/// The brief's reference ball-screw axis (JM 2e-3, JL 3e-3, KL 3000, 10 mm lead, Kp 50, Kv 5,
/// Tv 5 ms) sampled every `period_s`.
pub fn ballscrew_axis(period_s: f64) -> AxisContext {
    AxisContext {
        name: "x".into(),
        plant: PlantParams::BallScrew {
            two_mass: TwoMassParams {
                jm_kgm2: 2e-3,
                dm_nms_per_rad: 0.0,
                kl_nm_per_rad: 3000.0,
                cl_nms_per_rad: 0.0,
                jl_kgm2: 3e-3,
                dl_nms_per_rad: 0.0,
            },
            lead_m: 0.01,
            gear_ratio: 1.0,
        },
        defaults: ControllerParams {
            kp_per_s: Some(50.0),
            kv: Some(5.0),
            tv_s: Some(0.005),
            torque_limit: Some(30.0),
        },
        period_s,
    }
}

/// A 20 kg linear-motor axis (rigid), Kp 60, Kv 8000 N s/m, Tv 5 ms.
pub fn rigid_axis(period_s: f64) -> AxisContext {
    AxisContext {
        name: "x".into(),
        plant: PlantParams::Rigid(RigidParams {
            mass_kg: 20.0,
            viscous_ns_per_m: 0.0,
        }),
        defaults: ControllerParams {
            kp_per_s: Some(60.0),
            kv: Some(8000.0),
            tv_s: Some(0.005),
            torque_limit: Some(5000.0),
        },
        period_s,
    }
}
