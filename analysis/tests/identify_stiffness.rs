//! Stiffness identification (seed 001) on simulated closed-loop data.

use std::path::Path;

use feedloop_analysis::identify::stiffness::{
    identify_stiffness, Estimator, FrfKind, StiffnessOptions, MIN_SEGMENTS,
};
use feedloop_analysis::identify::IdentifyError;
use feedloop_analysis::sim::simulate;
use feedloop_model::job::Job;
use feedloop_plugins::Builtins;
use feedloop_trace::Trace;

mod controllers_util;

use controllers_util::{temp_dir, xy_x_model};

/// After the reference axis's `[controller]` keys.
const MODEL_TAIL: &str = r#"torque_limit_nm = 30.0
[sensor]
motor_counts_per_rev = 1048576
velocity_estimate = "difference"
torque_noise_nm = 0.02
load_resolution_m = 1e-8
seed = 3
"#;

const JOB: &str = r#"
name = "identify-stiffness"
period_s = 1.0e-4
[axes.x]
model = "model.toml"
[trajectory]
kind = "random_segments"
velocity_m_per_s = { x = 0.02 }
max_travel_m = { x = 0.01 }
min_segment_s = 0.001
max_segment_s = 0.003
transition_s = 0.0005
duration_s = 12.0
seed = 7
"#;

/// An axis that is not in the repository (JM 1.2e-3, JL 2.6e-3 kg m^2, KL 4200 N m/rad, 8 mm
/// lead) with Stribeck friction on the motor, Coulomb friction on the table, 12 um backlash, a
/// 20-bit encoder and velocity noise.
const REAL_AXIS: &str = r#"
kind = "ballscrew"
jm_kgm2 = 1.2e-3
dm_nms_per_rad = 8.0e-4
kl_nm_per_rad = 4200.0
cl_nms_per_rad = 0.03
jl_kgm2 = 2.6e-3
dl_nms_per_rad = 1.5e-3
lead_m = 0.008
[controller]
kp_per_s = 50.0
kv_nms_per_rad = 4.0
tv_s = 0.005
torque_limit_nm = 30.0
[effects.stribeck_friction]
side = "motor"
fc_nm = 0.12
fs_nm = 0.2
vs_rad_per_s = 1.0
[effects.coulomb_friction]
side = "load"
fc_n = 25.0
[effects.backlash]
gap_m = 1.2e-5
[sensor]
motor_counts_per_rev = 1048576
motor_vel_noise_rad_per_s = 0.002
seed = 5
"#;

/// The model: the reference X axis with a 20-bit encoder.
fn model() -> String {
    xy_x_model(MODEL_TAIL)
}

/// Simulates the excitation job on `model` and reads the trace back.
fn excite(tag: &str, model: &str) -> Trace {
    excite_with(tag, model, JOB)
}

/// Simulates `job` (its model file `model.toml`) on `model` and reads the trace back.
fn excite_with(tag: &str, model: &str, job: &str) -> Trace {
    let dir = temp_dir(&format!("id-{tag}"));
    std::fs::write(dir.join("model.toml"), model).unwrap();
    std::fs::write(dir.join("job.toml"), job).unwrap();
    let job = Job::load(&dir.join("job.toml")).unwrap_or_else(|e| panic!("{e}"));
    let path = dir.join("trace.csv");
    simulate(&job, &Builtins, Some(&path), &mut |_, _| {}).unwrap();
    Trace::read(Path::new(&path)).unwrap()
}

#[test]
fn closed_loop_data_with_a_20_bit_encoder_gives_kl_3000_and_jl_3e_3_within_1_percent() {
    let trace = excite("two-mass", &model());
    let r = identify_stiffness(&trace, "x", &StiffnessOptions::new(2.0e-3)).unwrap();
    let e_kl = r.kl_nm_per_rad / 3000.0 - 1.0;
    let e_jl = r.jl_kgm2 / 3.0e-3 - 1.0;
    println!(
        "wa {:.2} Hz (159.15), wr {:.2} Hz (251.64), KL {:.1} ({:+.3} %), JL {:.4e} ({:+.3} %), coherence_min {:.3}, {} segments, {}",
        r.antiresonance_hz,
        r.resonance_hz,
        r.kl_nm_per_rad,
        100.0 * e_kl,
        r.jl_kgm2,
        100.0 * e_jl,
        r.coherence_min,
        r.segments,
        r.estimator
    );
    assert_eq!(r.estimator, "instrument");
    assert!(e_kl.abs() < 0.01, "KL error {e_kl}");
    assert!(e_jl.abs() < 0.01, "JL error {e_jl}");
    println!(
        "second pair (noise above the velocity loop): {:?}",
        r.second
    );
}

#[test]
fn with_a_third_mass_the_first_pair_is_picked_and_the_second_reported() {
    // 100 kg on 5e7 N/m behind the table: reflected 2.53e-4 kg m^2 on 126.7 N m/rad.
    let model = model().replace(
        "[sensor]",
        "[effects.third_mass]\nmass_kg = 100.0\nstiffness_n_per_m = 1.0e9\ndamping_ns_per_m = 200.0\n[sensor]",
    );
    let trace = excite("three-mass", &model);
    let mut opts = StiffnessOptions::new(2.0e-3);
    opts.f_max_hz = Some(3000.0);
    let r = identify_stiffness(&trace, "x", &opts).unwrap();
    println!(
        "picked {:.2} / {:.2} Hz, second {:?}",
        r.antiresonance_hz, r.resonance_hz, r.second
    );
    let (fa, fr) = three_mass_pairs();
    println!(
        "predicted first pair {:.2} / {:.2} Hz, second {:.2} / {:.2} Hz",
        fa[0], fr[0], fa[1], fr[1]
    );
    assert!((r.antiresonance_hz / fa[0] - 1.0).abs() < 0.01);
    assert!((r.resonance_hz / fr[0] - 1.0).abs() < 0.01);
    let s = r.second.expect("the second pair is reported");
    assert!((s.antiresonance_hz / fa[1] - 1.0).abs() < 0.02, "{s:?}");
    assert!((s.resonance_hz / fr[1] - 1.0).abs() < 0.02, "{s:?}");
}

/// Undamped anti-resonances (motor held) and resonances (free) of the 3-mass chain, Hz.
fn three_mass_pairs() -> ([f64; 2], [f64; 2]) {
    let r2 = (0.01 / (2.0 * std::f64::consts::PI)).powi(2);
    let (jm, kl, jl, j3, k3) = (2.0e-3, 3000.0, 3.0e-3, 100.0 * r2, 1.0e9 * r2);
    let eig = |m: Vec<f64>, k: nalgebra::DMatrix<f64>| -> Vec<f64> {
        let n = m.len();
        let s = nalgebra::DMatrix::from_fn(n, n, |i, j| k[(i, j)] / (m[i] * m[j]).sqrt());
        let mut e: Vec<f64> = s.symmetric_eigen().eigenvalues.iter().copied().collect();
        e.sort_by(|a, b| a.partial_cmp(b).unwrap());
        e.iter()
            .filter(|v| **v > 1.0)
            .map(|v| v.sqrt() / (2.0 * std::f64::consts::PI))
            .collect()
    };
    let held = eig(
        vec![jl, j3],
        nalgebra::DMatrix::from_row_slice(2, 2, &[kl + k3, -k3, -k3, k3]),
    );
    let free = eig(
        vec![jm, jl, j3],
        nalgebra::DMatrix::from_row_slice(3, 3, &[kl, -kl, 0.0, -kl, kl + k3, -k3, 0.0, -k3, k3]),
    );
    ([held[0], held[1]], [free[0], free[1]])
}

#[test]
fn the_closed_loop_command_to_table_frf_is_refused_with_the_reason() {
    let trace = excite("refuse", &model());
    let mut opts = StiffnessOptions::new(2.0e-3);
    opts.frf = FrfKind::CommandToTable;
    let e = identify_stiffness(&trace, "x", &opts).unwrap_err();
    assert!(e.to_string().contains("negative inertia"), "{e}");
}

#[test]
fn a_band_without_a_resonance_and_a_missing_column_are_clear_errors() {
    let trace = excite("band", &model());
    let mut opts = StiffnessOptions::new(2.0e-3);
    opts.f_min_hz = 5.0;
    opts.f_max_hz = Some(100.0);
    let e = identify_stiffness(&trace, "x", &opts).unwrap_err();
    assert!(matches!(e, IdentifyError::NoResonance { .. }), "{e}");
    println!("{e}");
    opts.f_max_hz = None;
    opts.estimator = Estimator::H1;
    let e = identify_stiffness(&trace, "y", &opts).unwrap_err();
    assert!(e.to_string().contains("y.torque"), "{e}");
}

#[test]
fn on_a_traverse_an_axis_with_friction_and_backlash_gives_kl_and_jl_within_a_few_percent() {
    // The shipped stiffness job with this model file.
    let shipped = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/jobs/identify-stiffness.toml"),
    )
    .unwrap()
    .replace("../models/xy-x.toml", "model.toml");
    assert!(shipped.contains("traverse_m_per_s"), "{shipped}");
    let trace = excite_with("real-axis", REAL_AXIS, &shipped);
    let r = identify_stiffness(&trace, "x", &StiffnessOptions::new(1.2e-3)).unwrap();
    let (e_kl, e_jl) = (r.kl_nm_per_rad / 4200.0 - 1.0, r.jl_kgm2 / 2.6e-3 - 1.0);
    let c = &r.checks;
    println!(
        "KL {:.1} ({:+.2} %), JL {:.4e} ({:+.2} %), {} + {} segments, {} reversals cut, \
         directions {:?} / {:?}, problems {:?}",
        r.kl_nm_per_rad,
        100.0 * e_kl,
        r.jl_kgm2,
        100.0 * e_jl,
        c.segments_positive,
        c.segments_negative,
        c.reversals_cut,
        c.kl_positive_nm_per_rad,
        c.kl_negative_nm_per_rad,
        c.problems
    );
    assert!(r.credible, "{:?}", c.problems);
    assert_eq!(c.reversals, 0);
    assert!(c.reversals_cut >= 2);
    assert!(c.segments_positive >= MIN_SEGMENTS && c.segments_negative >= MIN_SEGMENTS);
    assert!(e_kl.abs() < 0.03, "KL error {e_kl}");
    assert!(e_jl.abs() < 0.03, "JL error {e_jl}");

    // The same axis under the reversing excitation (no traverse) is not read as a result.
    let trace = excite_with("real-axis-reversing", REAL_AXIS, JOB);
    match identify_stiffness(&trace, "x", &StiffnessOptions::new(1.2e-3)) {
        Ok(r) => {
            println!(
                "reversing: KL {:+.1} %, problems {:?}",
                100.0 * (r.kl_nm_per_rad / 4200.0 - 1.0),
                r.checks.problems
            );
            assert!(r.checks.reversals > 10);
            assert!(
                !r.credible || (r.kl_nm_per_rad / 4200.0 - 1.0).abs() < 0.03,
                "a wrong result passed as credible"
            );
        }
        Err(e) => println!("reversing: refused: {e}"),
    }
}
