//! The effects real axes have (issue 30), each hidden in a record made here by a plain explicit
//! integration (not the plant simulator): the workbench names it and `fit --add` recovers its
//! physical parameters.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use feedloop_analysis::workbench::{
    data::{load_axis, AxisData, Prep},
    diagnose::{diagnose, DiagOptions, Diagnosis},
    effects::WbModel,
    fit::fit,
};
use feedloop_model::model::ModelFile;
use feedloop_model::EffectId;
use feedloop_trace::Trace;

/// A deterministic uniform noise on -0.5 .. 0.5 (xorshift), the same sequence in every run.
fn uniform_noise() -> impl FnMut() -> f64 {
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }
}

/// Whether the dictionary of what no effect explains counts term `id`, and whether the sparse
/// peer keeps it.
fn term_counted_and_kept(dg: &Diagnosis, id: &str) -> (bool, bool) {
    (
        dg.residual_terms
            .iter()
            .any(|t| t.term == id && t.significant),
        dg.sparse_peer.terms.iter().any(|t| t == id),
    )
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("feedloop-new-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A rigid body (inertia `j`, motor units) driven open loop by a sum of sines, with `load` the
/// torque it meets at position and velocity `(q, v)`; a trace at 1 kHz over `secs`.
fn record(
    dir: &Path,
    j: f64,
    secs: f64,
    drive: impl Fn(f64) -> f64,
    load: impl Fn(f64, f64) -> f64,
) -> PathBuf {
    let dt = 1e-3;
    let sub = 20;
    let h = dt / sub as f64;
    let (mut q, mut v) = (0.0f64, 0.0f64);
    let mut text = String::from("# feedloop-trace v1\n# period_s=0.001\nt,x.cmd,x.load,x.torque\n");
    for k in 0..(secs / dt) as usize {
        let t = k as f64 * dt;
        let u = drive(t);
        text.push_str(&format!("{t},{q},{q},{u}\n"));
        for _ in 0..sub {
            let a = (u - load(q, v)) / j;
            v += a * h;
            q += v * h;
        }
    }
    let p = dir.join("t.csv");
    std::fs::write(&p, text).unwrap();
    p
}

fn setup(trace: &Path, model: &str, dir: &Path) -> (WbModel, AxisData) {
    let table: toml::Table = model.parse().unwrap();
    let file = ModelFile::from_table(&table, &dir.join("m.toml")).unwrap();
    let m = WbModel::from_parts(file, table).unwrap();
    let tr = Trace::read(trace).unwrap();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    (m, d)
}

/// A copy of the recorded `trace` at `out` whose torque column (`x.torque`) carries `extra(t)`
/// that the body did not meet, with a column `x.NAME` holding `column(t)` appended when given.
fn torque_added(
    trace: &Path,
    out: &Path,
    mut extra: impl FnMut(f64) -> f64,
    column: Option<(&str, &dyn Fn(f64) -> f64)>,
) -> PathBuf {
    let text = std::fs::read_to_string(trace).unwrap();
    let mut body = String::new();
    for line in text.lines() {
        if line.starts_with('#') {
            body.push_str(line);
        } else if line.starts_with("t,") {
            body.push_str(line);
            if let Some((name, _)) = column {
                body.push_str(&format!(",x.{name}"));
            }
        } else {
            let mut cells: Vec<String> = line.split(',').map(String::from).collect();
            let t: f64 = cells[0].parse().unwrap();
            let f: f64 = cells[3].parse().unwrap();
            cells[3] = format!("{}", f + extra(t));
            body.push_str(&cells.join(","));
            if let Some((_, c)) = column {
                body.push_str(&format!(",{}", c(t)));
            }
        }
        body.push('\n');
    }
    std::fs::write(out, body).unwrap();
    out.to_path_buf()
}

#[test]
fn directional_friction_is_named_and_fitted_with_both_levels_and_slopes() {
    let dir = scratch("directional");
    let (fp, fn_, cp, cn) = (30.0, 18.0, 90.0, 40.0);
    let trace = record(
        &dir,
        20.0,
        12.0,
        |t| 700.0 * (2.0 * PI * 0.4 * t).sin() + 250.0 * (2.0 * PI * 1.3 * t).sin(),
        |_, v| {
            if v > 1e-6 {
                fp + cp * v
            } else if v < -1e-6 {
                -fn_ + cn * v
            } else {
                0.0
            }
        },
    );
    let (m, d) = setup(&trace, "kind = \"rigid\"\nmass_kg = 20.0\n", &dir);
    let dg = diagnose(&m, &d, &DiagOptions::default());
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    assert_eq!(top.class, "friction", "{}", dg.verdict);
    let r = fit(&m, &d, &[EffectId::DirectionalFriction], None, 0.05).unwrap();
    let p = &r.params;
    for (key, want, tol) in [
        ("fc_pos_n", fp, 0.1),
        ("fc_neg_n", fn_, 0.1),
        ("c_pos_ns_per_m", cp, 0.15),
        ("c_neg_ns_per_m", cn, 0.15),
    ] {
        assert!(
            (p[key] / want - 1.0).abs() < tol,
            "{key}: {} for {want}",
            p[key]
        );
    }
    let (b, a) = (
        r.before.equation_nrmse_pct.unwrap(),
        r.after.equation_nrmse_pct.unwrap(),
    );
    assert!(a < 0.3 * b, "equation error {b} % -> {a} %");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn an_unbalanced_rotary_load_is_named_and_fitted() {
    let dir = scratch("unbalance");
    let (mgr, zero, c0) = (40.0, 0.6, 5.0);
    // the load swings through about 3 rad; a rotary axis with gear 1 (motor = load)
    let trace = record(
        &dir,
        2.0,
        12.0,
        |t| 60.0 * (2.0 * PI * 0.25 * t).sin() + 20.0 * (2.0 * PI * 0.9 * t).sin(),
        |q, v| -(c0 - mgr * (q - zero).sin()) + 3.0 * v,
    );
    let (m, d) = setup(
        &trace,
        "kind = \"rotary\"\njm_kgm2 = 1.0\njl_kgm2 = 1.0\nkl_nm_per_rad = 1e6\ndm_nms_per_rad = 3.0\n",
        &dir,
    );
    let dg = diagnose(&m, &d, &DiagOptions::default());
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    assert_eq!(top.effect, "unbalance", "{}", dg.verdict);
    let r = fit(&m, &d, &[EffectId::Unbalance], None, 0.05).unwrap();
    let p = &r.params;
    assert!((p["mgr_nm"] / mgr - 1.0).abs() < 0.05, "{p:?}");
    assert!((p["zero_angle_rad"] - zero).abs() < 0.05, "{p:?}");
    assert!((p["constant_nm"] / c0 - 1.0).abs() < 0.1, "{p:?}");
    assert!((p["period_rad"] - 2.0 * PI).abs() < 1e-6, "{p:?}");
    std::fs::remove_dir_all(dir).ok();
}

/// What no library effect explains is described by what it follows: a quadratic drag (no
/// effect of the library has it) is named as the velocity squared with its sign; a torque that
/// follows another signal of the machine is named by that column once the user adds it to the
/// dictionary; on a right model no term counts and the sparse peer keeps no term.
#[test]
fn a_misfit_outside_the_library_is_described_by_the_terms_it_follows() {
    let dir = scratch("dictionary");
    let drive = |t: f64| 500.0 * (2.0 * PI * 0.3 * t).sin() + 200.0 * (2.0 * PI * 1.1 * t).sin();
    // a drag of 40 N s^2/m^2 |v| v on a 20 kg mass
    let trace = record(&dir, 20.0, 12.0, drive, |_, v| 40.0 * v.abs() * v);
    let (m, d) = setup(&trace, "kind = \"rigid\"\nmass_kg = 20.0\n", &dir);
    let dg = diagnose(&m, &d, &DiagOptions::default());
    let first = &dg.residual_terms[0];
    assert_eq!(first.term, "velocity_squared", "{:?}", dg.residual_terms);
    assert!(first.significant && first.cut_pct > 70.0, "{first:?}");
    assert!(dg
        .sparse_peer
        .terms
        .contains(&"velocity_squared".to_string()));

    // a torque of 30 N times another signal of the machine (an unrelated slow sine)
    let other = |t: f64| (2.0 * PI * 0.07 * t + 1.0).sin();
    let trace = record(&dir, 20.0, 12.0, drive, |_, _| 0.0);
    // the recorded force carries the other signal's torque the model does not know
    let path = torque_added(
        &trace,
        &dir.join("other.csv"),
        |t| 30.0 * other(t),
        Some(("other", &other)),
    );
    let (m, d) = setup(&path, "kind = \"rigid\"\nmass_kg = 20.0\n", &dir);
    let col = Trace::read(&path)
        .unwrap()
        .column("x.other")
        .unwrap()
        .to_vec();
    let plain = diagnose(&m, &d, &DiagOptions::default());
    let with = diagnose(
        &m,
        &d,
        &DiagOptions {
            extra_terms: vec![("x.other".into(), col)],
            ..DiagOptions::default()
        },
    );
    assert_eq!(
        with.residual_terms[0].term, "column:x.other",
        "{:?}",
        with.residual_terms
    );
    assert!(with.residual_terms[0].significant);
    assert!(
        !plain
            .residual_terms
            .iter()
            .any(|t| t.term == "column:x.other"),
        "{:?}",
        plain.residual_terms
    );

    // a right model: nothing follows, the peer keeps nothing
    let trace = record(&dir, 20.0, 12.0, drive, |_, _| 0.0);
    let (m, d) = setup(&trace, "kind = \"rigid\"\nmass_kg = 20.0\n", &dir);
    let dg = diagnose(&m, &d, &DiagOptions::default());
    assert!(
        dg.residual_terms.iter().all(|t| !t.significant),
        "{:?}",
        dg.residual_terms
    );
    assert!(dg.sparse_peer.terms.is_empty(), "{:?}", dg.sparse_peer);
    std::fs::remove_dir_all(dir).ok();
}

/// A recorded torque that drifts with the time (a warming current sensor: 2 N more every second
/// than the body meets) is among what the dictionary names ("the time"), but the generic peer does not
/// regress on the time: its dictionary is the one an identification engineer builds for an
/// axis' torque (constant, sign and tanh of the velocity, |v|, |v| v, the position's sine and
/// cosine, a delayed torque).
#[test]
fn a_drift_is_named_by_the_dictionary_and_is_no_term_of_the_peer() {
    let dir = scratch("drift");
    let drive = |t: f64| 500.0 * (2.0 * PI * 0.3 * t).sin() + 200.0 * (2.0 * PI * 1.1 * t).sin();
    let trace = record(&dir, 20.0, 12.0, drive, |_, _| 0.0);
    let trace = torque_added(&trace, &dir.join("drift.csv"), |t| 2.0 * t, None);
    let (m, d) = setup(&trace, "kind = \"rigid\"\nmass_kg = 20.0\n", &dir);
    let dg = diagnose(&m, &d, &DiagOptions::default());
    // (the open-loop body wanders, so slow shapes of its position stand beside the time)
    assert_eq!(
        term_counted_and_kept(&dg, "time"),
        (true, false),
        "{:?} {:?}",
        dg.residual_terms,
        dg.sparse_peer
    );
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn noise_on_the_recorded_torque_is_not_read_as_a_delay() {
    // a right model whose recorded torque carries white noise of 5 % of the drive (a current
    // ripple the motion does not follow): the dictionary's delay term is built from the motion,
    // so neither the forward selection nor the sparse peer "explains" that noise with it
    let dir = scratch("torque-noise");
    let drive = |t: f64| 500.0 * (2.0 * PI * 0.3 * t).sin() + 200.0 * (2.0 * PI * 1.1 * t).sin();
    let trace = record(&dir, 20.0, 12.0, drive, |_, _| 0.0);
    let mut uniform = uniform_noise();
    // uniform on +-60 N: an RMS of about 17 N beside the drive's 380 N
    let path = torque_added(&trace, &dir.join("noisy.csv"), |_| 120.0 * uniform(), None);
    let (m, d) = setup(&path, "kind = \"rigid\"\nmass_kg = 20.0\n", &dir);
    let dg = diagnose(&m, &d, &DiagOptions::default());
    assert_eq!(
        term_counted_and_kept(&dg, "delayed_torque"),
        (false, false),
        "{:?} {:?}",
        dg.residual_terms,
        dg.sparse_peer
    );
    std::fs::remove_dir_all(dir).ok();
}

/// A swivel axis over a short arc (about 60 degrees of the link, recorded on the motor side of a
/// 50:1 gear, as a robot joint logs it) with gravity and friction: the guided loop ends with
/// both, the friction at the level hidden. Before, the unbalance took a period shorter than the
/// travel (a ripple that fits part of the friction's steps along this path) and the friction
/// was never added.
#[test]
fn gravity_and_friction_of_a_short_swing_are_both_added() {
    let dir = scratch("hidden-pair");
    // motor-side inertia, damping, Coulomb level, gravity and constant torque (N m), gear
    let (j, d_v, fc, g, zero, c0, u) = (0.05, 0.02, 2.0, 12.0, 1.1, 4.0, 50.0);
    let (amp, f) = (0.45, 0.125);
    let w = 2.0 * PI * f;
    let mut text = String::from("# feedloop-trace v1\n# period_s=0.004\nt,x.cmd,x.load,x.torque\n");
    // a deterministic, coloured torque noise (the drive's current ripple and quantisation)
    let mut white = uniform_noise();
    let mut coloured = 0.0;
    for k in 0..3_000 {
        let t = k as f64 * 4e-3;
        let (s1, c1, s3, c3) = (
            (w * t).sin(),
            (w * t).cos(),
            (3.1 * w * t).sin(),
            (3.1 * w * t).cos(),
        );
        let q = amp * s1 + 0.08 * s3;
        let v = amp * w * c1 + 0.08 * 3.1 * w * c3;
        let a = -amp * w * w * s1 - 0.08 * (3.1 * w).powi(2) * s3;
        coloured = 0.9 * coloured + 0.4 * white();
        let tq = j * u * a + d_v * u * v + fc * v.signum() + c0 - g * (q - zero).sin() + coloured;
        text.push_str(&format!("{t},{},{},{tq}\n", u * q, u * q));
    }
    let trace = dir.join("t.csv");
    std::fs::write(&trace, text).unwrap();
    let (m, d) = setup(
        &trace,
        "kind = \"rotary\"\njm_kgm2 = 0.025\njl_kgm2 = 0.025\nkl_nm_per_rad = 1e6\ndm_nms_per_rad = 0.02\n",
        &dir,
    );
    let r = feedloop_analysis::workbench::auto::auto(&m, &d, 0.05, 6).unwrap();
    let names: Vec<String> = r.steps.iter().flat_map(|s| s.added.clone()).collect();
    let fc_fitted = r
        .model
        .effects
        .iter()
        .find(|e| e.id == EffectId::CoulombFriction)
        .map(|e| e.coef[0].abs());
    for want in ["unbalance", "coulomb_friction"] {
        assert!(
            names.iter().any(|n| n.starts_with(want)),
            "{want} not added: {names:?}: {}",
            r.last.verdict
        );
    }
    let fc_fitted = fc_fitted.unwrap();
    assert!(
        (fc_fitted / fc - 1.0).abs() < 0.1,
        "Fc {fc_fitted} for {fc}"
    );
    std::fs::remove_dir_all(dir).ok();
}
