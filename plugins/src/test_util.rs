//! Axis contexts for the plugins' tests: the unit tests (`crate::test_util`) and the
//! integration tests in `tests/` (each includes this file as `mod test_util`).

use feedloop_control::controller::AxisContext;
use feedloop_model::model::{ControllerParams, PlantParams, RigidParams, TwoMassParams};

/// The brief's reference ball-screw axis (JM 2e-3, JL 3e-3, KL 3000, 10 mm lead, Kp 50, Kv 5,
/// Tv 5 ms) sampled every `period_s`.
pub fn ballscrew_axis(period_s: f64) -> AxisContext {
    ballscrew_axis_with(false, 3e-3, 5.0, 0.005, 30.0, period_s)
}

/// The reference ball-screw axis with load inertia `jl_kgm2` and the velocity-loop defaults
/// `kv`, `tv_s`, `torque_limit` (Kp 50); `damped` adds the damping of
/// `examples/models/xy-x.toml` (DM 1e-3, CL 0.02, DL 2e-3 N m s/rad), else there is none.
pub fn ballscrew_axis_with(
    damped: bool,
    jl_kgm2: f64,
    kv: f64,
    tv_s: f64,
    torque_limit: f64,
    period_s: f64,
) -> AxisContext {
    let d = |v: f64| if damped { v } else { 0.0 };
    AxisContext {
        name: "x".into(),
        plant: PlantParams::BallScrew {
            two_mass: TwoMassParams {
                jm_kgm2: 2e-3,
                dm_nms_per_rad: d(1e-3),
                kl_nm_per_rad: 3000.0,
                cl_nms_per_rad: d(0.02),
                jl_kgm2,
                dl_nms_per_rad: d(2e-3),
            },
            lead_m: 0.01,
            gear_ratio: 1.0,
        },
        defaults: ControllerParams {
            kp_per_s: Some(50.0),
            kv: Some(kv),
            tv_s: Some(tv_s),
            torque_limit: Some(torque_limit),
            ..ControllerParams::default()
        },
        period_s,
    }
}

/// A rotary C axis (JM 0.05, JL 0.1 kg m^2 on `kl_nm_per_rad`, undamped) without controller
/// defaults.
pub fn rotary_c_axis(kl_nm_per_rad: f64, period_s: f64) -> AxisContext {
    AxisContext {
        name: "c".into(),
        plant: PlantParams::Rotary {
            two_mass: TwoMassParams {
                jm_kgm2: 0.05,
                dm_nms_per_rad: 0.0,
                kl_nm_per_rad,
                cl_nms_per_rad: 0.0,
                jl_kgm2: 0.1,
                dl_nms_per_rad: 0.0,
            },
            gear_ratio: 1.0,
        },
        defaults: ControllerParams::default(),
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
            ..ControllerParams::default()
        },
        period_s,
    }
}
