//! The workbench on real data: the EMPS benchmark's estimation record (a rigid mass with viscous
//! friction misses its Coulomb friction and offset). Skipped, with a message, when the data file
//! is absent.

use std::path::{Path, PathBuf};

use feedloop_analysis::workbench::{
    compare::compare,
    data::{load_axis, Prep},
    diagnose::{diagnose, DiagOptions},
    effects::WbModel,
    fit::fit,
};
use feedloop_model::EffectId;
use feedloop_trace::Trace;

fn data_file() -> Option<PathBuf> {
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/emps/emps_estimation.csv");
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipped: {} is absent", p.display());
        None
    }
}

fn setup() -> Option<(WbModel, feedloop_analysis::workbench::data::AxisData)> {
    let path = data_file()?;
    let tr = Trace::read(&path).unwrap();
    let model_path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/emps-nominal.toml");
    let m = WbModel::load(&model_path).unwrap();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    Some((m, d))
}

#[test]
fn emps_misfit_of_the_nominal_model_is_concentrated_at_velocity_reversals() {
    let Some((m, d)) = setup() else { return };
    let c = compare(&m, &d, 0.05);
    let eq = c.eq.as_ref().unwrap();
    assert!(
        eq.nrmse_pct > 15.0 && eq.nrmse_pct < 21.0,
        "{}",
        eq.nrmse_pct
    );
    let conc = |name: &str| {
        let s = c.by_kind.iter().find(|s| s.name == name).unwrap();
        s.share_pct / s.time_pct.max(1e-9)
    };
    let rev = conc("reversal");
    assert!(
        rev > 1.5,
        "residual per unit time at reversals is only {rev:.2}x the average"
    );
    assert!(
        rev > conc("constant_velocity") && rev > conc("acceleration"),
        "{rev}"
    );
}

#[test]
fn emps_diagnosis_names_coulomb_friction_with_its_offset_first() {
    let Some((m, d)) = setup() else { return };
    let dg = diagnose(&m, &d, &DiagOptions::default());
    for c in &dg.candidates {
        println!(
            "{} ({}) {:.2} % significant {} {:?} same {:?}",
            c.effect, c.class, c.error_reduction_pct, c.significant, c.params, c.same_as
        );
    }
    let top = &dg.candidates[0];
    assert_eq!(top.effect, "coulomb_friction", "{}", dg.verdict);
    assert!(top.significant);
    assert_eq!(top.class, "friction");
    assert!(
        top.error_reduction_pct > 60.0,
        "{}",
        top.error_reduction_pct
    );
    let fc = top.params["fc_n"];
    assert!((fc - 20.3935).abs() < 1.0, "fc_n = {fc}");
    let off = top.params["offset_n"];
    assert!((off + 3.1648).abs() < 0.5, "offset = {off}");
    assert!(dg.verdict.contains("coulomb_friction"), "{}", dg.verdict);
    // Coulomb friction and its offset are the only things named: the offset alone
    // (`constant_force`) is reported in the friction class, and nothing else (a torque clamp
    // re-explaining part of the friction steps, say) is significant beyond them
    let others: Vec<String> = dg
        .candidates
        .iter()
        .skip(1)
        .filter(|c| c.significant)
        .map(|c| format!("{} {:.1} %", c.effect, c.error_reduction_pct))
        .collect();
    assert!(others.is_empty(), "also significant: {others:?}");
    let cf = dg
        .candidates
        .iter()
        .find(|c| c.effect == "constant_force")
        .unwrap();
    assert_eq!(cf.class, "friction", "{}", cf.evidence);
}

#[test]
fn emps_fit_with_coulomb_and_offset_reproduces_the_published_estimates() {
    let Some((m, d)) = setup() else { return };
    let add = [EffectId::CoulombFriction, EffectId::ConstantForce];
    let r = fit(&m, &d, &add, None, 0.05).unwrap();
    let p = &r.params;
    let rel = |v: f64, want: f64| ((v - want) / want).abs();
    assert!(rel(p["mass_kg"], 95.1089) < 0.05, "M = {}", p["mass_kg"]);
    assert!(
        rel(p["viscous_ns_per_m"], 203.5034) < 0.05,
        "Fv = {}",
        p["viscous_ns_per_m"]
    );
    assert!(rel(p["fc_n"], 20.3935) < 0.05, "Fc = {}", p["fc_n"]);
    // the published offset is the force the model needs: minus the constant force on the load
    let offset = -p["force_n"];
    assert!((offset + 3.1648).abs() < 0.5, "offset = {offset}");
    let e = r.after.relative_error_pct.unwrap();
    assert!(
        e > 3.5 && e < 5.0,
        "relative force error {e} % (published 4.08 %)"
    );
    let before = r.before.relative_error_pct.unwrap();
    assert!(before > 15.0, "{before}");
    // the windowed closed-loop simulation agrees
    let (wb, wa) = (
        r.before.window_sim_nrmse_pct.unwrap(),
        r.after.window_sim_nrmse_pct.unwrap(),
    );
    println!("EMPS windowed simulation NRMSE {wb:.2} % -> {wa:.2} %, relative force error {before:.2} % -> {e:.2} %");
    assert!(wa < 0.4 * wb, "windowed simulation NRMSE {wb} -> {wa}");
}
