//! The workbench on the shipped rotary axis (`examples/models/xc-c.toml` under the X-C cam job,
//! which turns the C axis one and a half turns one way): effects hidden in a copy of the model,
//! simulated with `feedloop sim`, diagnosed with the plain model.

use std::f64::consts::FRAC_PI_2;
use std::path::{Path, PathBuf};
use std::process::Command;

use feedloop_test_support::Scratch;
use serde_json::Value;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

/// Runs the cam job with `hidden` appended to the C axis' model and returns the diagnosis of
/// axis c against the shipped model (`diagnose --json`).
fn diagnose_hidden(dir: &Path, hidden: &str) -> Value {
    let plain = std::fs::read_to_string(repo("examples/models/xc-c.toml")).unwrap();
    std::fs::write(dir.join("c0.toml"), &plain).unwrap();
    std::fs::write(dir.join("c.toml"), format!("{plain}\n{hidden}\n")).unwrap();
    std::fs::copy(repo("examples/models/xc-x.toml"), dir.join("x.toml")).unwrap();
    let job = std::fs::read_to_string(repo("examples/jobs/xc-cam-coupled.toml"))
        .unwrap()
        .replace("../models/xc-c.toml", "c.toml")
        .replace("../models/xc-x.toml", "x.toml");
    std::fs::write(dir.join("job.toml"), job).unwrap();
    let out = dir.join("out");
    let o = Command::new(bin())
        .args(["sim", "--quiet", "--json"])
        .arg(dir.join("job.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = Command::new(bin())
        .args(["diagnose", "--axis", "c", "--json", "--trace"])
        .arg(out.join("trace.csv"))
        .arg("--model")
        .arg(dir.join("c0.toml"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

fn candidates(dg: &Value) -> &Vec<Value> {
    dg["candidates"].as_array().unwrap()
}

fn first_significant(dg: &Value) -> &Value {
    candidates(dg)
        .iter()
        .find(|c| c["significant"] == true)
        .unwrap_or_else(|| panic!("nothing significant: {}", dg["verdict"]))
}

#[test]
fn a_constant_torque_on_an_axis_turning_one_way_is_not_named_friction() {
    // turning one way, a friction level and a constant torque are one column on every moving
    // row: the constant torque is the name, and the friction says why it cannot be claimed
    for torque in [20.0, -8.0] {
        let dir = Scratch::new("rotary", &format!("const{torque}"));
        let dg = diagnose_hidden(
            &dir,
            &format!("[effects.constant_force]\ntorque_nm = {torque}"),
        );
        let top = first_significant(&dg);
        assert_eq!(top["effect"], "constant_force", "{}", dg["verdict"]);
        let got = top["params"]["torque_nm"].as_f64().unwrap();
        assert!((got / torque - 1.0).abs() < 0.1, "{got} N m for {torque}");
        for c in candidates(&dg).iter().filter(|c| c["class"] == "friction") {
            assert!(c["significant"] == false, "{}", c["evidence"]);
        }
        let coulomb = candidates(&dg)
            .iter()
            .find(|c| c["effect"] == "coulomb_friction")
            .unwrap();
        assert!(
            coulomb["evidence"]
                .as_str()
                .unwrap()
                .contains("one direction only"),
            "{}",
            coulomb["evidence"]
        );
    }
}

#[test]
fn an_unbalance_hidden_at_two_sizes_and_any_phase_is_named_first_with_its_size() {
    // the third hangs a quarter turn off zero: its torque is all in the cosine of the angle
    for (mgr, zero, constant) in [(5.0, 0.4, 0.0), (20.0, -1.0, 3.0), (8.0, FRAC_PI_2, 0.0)] {
        let dir = Scratch::new("rotary", &format!("unbalance{mgr}"));
        let dg = diagnose_hidden(
            &dir,
            &format!(
                "[effects.unbalance]\nmgr_nm = {mgr}\nzero_angle_rad = {zero}\nconstant_nm = {constant}"
            ),
        );
        let top = first_significant(&dg);
        assert_eq!(top["effect"], "unbalance", "{}", dg["verdict"]);
        let p = &top["params"];
        let got = p["mgr_nm"].as_f64().unwrap();
        assert!((got / mgr - 1.0).abs() < 0.1, "mgr {got} N m for {mgr}");
        let z = p["zero_angle_rad"].as_f64().unwrap();
        let period = p["period_rad"].as_f64().unwrap();
        assert!(
            (period / std::f64::consts::TAU - 1.0).abs() < 0.01,
            "period {period}"
        );
        // the same zero, modulo the period
        let dz = (z - zero).rem_euclid(period);
        assert!(dz.min(period - dz) < 0.05, "zero {z} rad for {zero}");
    }
}

#[test]
fn a_cogging_ripple_in_the_cosine_of_the_angle_is_named_first_with_its_size() {
    let dir = Scratch::new("rotary", "cogging");
    let dg = diagnose_hidden(
        &dir,
        "[effects.cogging]\namplitude_nm = 2.0\nperiods_per_rev = 24\nphase_rad = 1.5707963",
    );
    let top = first_significant(&dg);
    assert_eq!(top["effect"], "cogging", "{}", dg["verdict"]);
    let got = top["params"]["amplitude_nm"].as_f64().unwrap();
    assert!((got / 2.0 - 1.0).abs() < 0.1, "amplitude {got} N m for 2");
}
