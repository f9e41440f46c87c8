//! The workbench (compare, diagnose, fit) refuses options outside their range, warns when the
//! model needs columns the trace lacks, and says what its figures mean without a torque column.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

use feedloop_test_support::Scratch;

/// A fresh scratch folder for test `name` (removed when the test passes).
fn scratch(name: &str) -> Scratch {
    Scratch::new("wbin", name)
}

const RIGID: &str = "kind = \"rigid\"\nmass_kg = 50.0\nviscous_ns_per_m = 100.0\n[controller]\nkp_per_s = 50.0\nkv_ns_per_m = 5000.0\ntv_s = 0.01\nforce_limit_n = 1000.0\n";

const BALLSCREW: &str = "kind = \"ballscrew\"\njm_kgm2 = 2.0e-3\nkl_nm_per_rad = 3000.0\njl_kgm2 = 3.0e-3\nlead_m = 0.01\n[controller]\nkp_per_s = 50.0\nkv_nms_per_rad = 5.0\ntv_s = 0.005\ntorque_limit_nm = 30.0\n";

/// A 1 kHz trace of a 50 kg mass on a sine, 2 s, the load 2 ms behind the command; with the
/// force column when `torque`, with a motor column (a 10 mm lead: 2 pi / 0.01 rad per m) when
/// `motor`.
fn trace(dir: &Path, name: &str, torque: bool, motor: bool) -> PathBuf {
    let mut s = String::from("# feedloop-trace v1\nt,x.cmd,x.load");
    s.push_str(if motor { ",x.motor" } else { "" });
    s.push_str(if torque { ",x.torque\n" } else { "\n" });
    let w = 2.0 * std::f64::consts::PI * 0.5;
    for k in 0..2000 {
        let t = k as f64 * 1e-3;
        let cmd = 0.05 * (w * t).sin();
        let tl = t - 0.002;
        let (x, v, a) = (
            0.05 * (w * tl).sin(),
            0.05 * w * (w * tl).cos(),
            -0.05 * w * w * (w * tl).sin(),
        );
        s.push_str(&format!("{t},{cmd},{x}"));
        if motor {
            s.push_str(&format!(",{}", x * 2.0 * std::f64::consts::PI / 0.01));
        }
        if torque {
            s.push_str(&format!(",{}", 50.0 * a + 100.0 * v + 10.0 * v.signum()));
        }
        s.push('\n');
    }
    let p = dir.join(name);
    std::fs::write(&p, s).unwrap();
    p
}

fn model(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// `feedloop CMD --trace TRACE --model MODEL REST...`.
fn wb(cmd: &str, trace: &Path, model: &Path, rest: &[&std::ffi::OsStr]) -> Output {
    Command::new(bin())
        .args([cmd.as_ref(), "--trace".as_ref(), trace.as_os_str()])
        .args(["--model".as_ref(), model.as_os_str()])
        .args(rest)
        .output()
        .unwrap()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn a_window_or_cutoff_outside_its_range_is_refused_naming_the_flag() {
    let d = scratch("range");
    let tr = trace(&d, "t.csv", true, false);
    let m = model(&d, "m.toml", RIGID);
    let out = d.join("out");
    for (flag, value, why) in [
        ("--window-s", "0", "> 0"),
        ("--window-s", "-0.05", "> 0"),
        ("--window-s", "NaN", "finite"),
        ("--window-s", "0.0015", "two sample periods"),
        ("--cutoff-hz", "0", "> 0"),
        ("--cutoff-hz", "NaN", "finite"),
        ("--cutoff-hz", "500", "Nyquist"),
        ("--cutoff-hz", "2000", "Nyquist"),
    ] {
        for cmd in ["compare", "fit", "diagnose"] {
            let o = wb(
                cmd,
                &tr,
                &m,
                &[
                    "--out".as_ref(),
                    out.as_os_str(),
                    flag.as_ref(),
                    value.as_ref(),
                ],
            );
            let err = text(&o.stderr);
            assert!(!o.status.success(), "{cmd} {flag} {value} was accepted");
            assert!(
                err.contains(&format!("{flag} {value}")) && err.contains(why),
                "{cmd} {flag} {value}: {err}"
            );
            assert!(!out.exists(), "{cmd} {flag} {value} wrote its output");
        }
    }
    // the Nyquist limit is the trace's: 0.5 / 1 ms
    let o = wb(
        "compare",
        &tr,
        &m,
        &[
            "--out".as_ref(),
            out.as_os_str(),
            "--cutoff-hz".as_ref(),
            "600".as_ref(),
        ],
    );
    assert!(text(&o.stderr).contains("500 Hz"), "{}", text(&o.stderr));
    // in range, the same command runs
    let o = wb(
        "compare",
        &tr,
        &m,
        &[
            "--out".as_ref(),
            out.as_os_str(),
            "--cutoff-hz".as_ref(),
            "50".as_ref(),
            "--window-s".as_ref(),
            "0.002".as_ref(),
        ],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
}

#[test]
fn a_two_body_model_against_a_one_position_trace_is_warned_about() {
    let d = scratch("kinds");
    let one = trace(&d, "one.csv", true, false);
    let two = trace(&d, "two.csv", true, true);
    let m = model(&d, "bs.toml", BALLSCREW);
    let go = |tr: &Path, cmd: &str| {
        let out = d.join(format!("out-{cmd}"));
        let mut args: Vec<&std::ffi::OsStr> = vec!["--json".as_ref()];
        let f = d.join("fit.toml");
        if cmd == "fit" {
            args.extend(["--out".as_ref(), f.as_os_str()]);
        } else {
            args.extend(["--out".as_ref(), out.as_os_str()]);
        }
        let o = wb(cmd, tr, &m, &args);
        assert!(o.status.success(), "{cmd}: {}", text(&o.stderr));
        // the warning goes to standard error (standard output stays pure JSON) and into the
        // JSON's `warnings`
        let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        (text(&o.stderr), j["warnings"].clone())
    };
    for cmd in ["compare", "fit", "diagnose"] {
        let (err, w) = go(&one, cmd);
        assert!(
            err.contains("warning")
                && err.contains("ballscrew")
                && err.contains("no `x.motor` column")
                && err.contains("kl_nm_per_rad"),
            "{cmd}: {err}"
        );
        assert!(
            w[0].as_str()
                .is_some_and(|w| w.contains("no `x.motor` column")),
            "{cmd}: {w}"
        );
        // (with both positions a fit may still say what it held: not this warning)
        let (err, w) = go(&two, cmd);
        assert!(
            !err.contains("no `x.motor` column"),
            "{cmd} with x.motor: {err}"
        );
        assert!(
            w.as_array()
                .unwrap()
                .iter()
                .all(|w| !w.as_str().unwrap().contains("no `x.motor` column")),
            "{cmd} with x.motor: {w}"
        );
    }
}

#[test]
fn compare_without_a_torque_column_says_what_its_headline_figure_is() {
    let d = scratch("notorque");
    let m = model(&d, "m.toml", RIGID);
    let compare = |tr: &Path, json: bool| {
        let out = d.join("out");
        let mut args: Vec<&std::ffi::OsStr> = vec!["--out".as_ref(), out.as_os_str()];
        if json {
            args.push("--json".as_ref());
        }
        let o = wb("compare", tr, &m, &args);
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
    };
    let without = trace(&d, "without.csv", false, false);
    let s = compare(&without, false);
    assert!(
        s.contains("windowed simulation NRMSE (following_error)"),
        "{s}"
    );
    assert!(
        s.contains("no `x.torque` column")
            && s.contains("following error")
            && s.contains("not of the torque"),
        "{s}"
    );
    let j: serde_json::Value = serde_json::from_str(&compare(&without, true)).unwrap();
    assert_eq!(j["headline_channel"], "following_error", "{j}");
    assert!(
        j["note"].as_str().unwrap().contains("no `x.torque` column"),
        "{j}"
    );
    // with the torque column the headline is the torque and there is nothing to note
    let with = trace(&d, "with.csv", true, false);
    let s = compare(&with, false);
    assert!(s.contains("windowed simulation NRMSE (torque)"), "{s}");
    assert!(!s.contains("note:"), "{s}");
    let j: serde_json::Value = serde_json::from_str(&compare(&with, true)).unwrap();
    assert_eq!(j["headline_channel"], "torque", "{j}");
    assert!(j["note"].is_null(), "{j}");
}

#[test]
fn fit_without_a_torque_column_lists_the_columns_it_has() {
    let d = scratch("fitcols");
    let tr = trace(&d, "without.csv", false, false);
    let m = model(&d, "m.toml", RIGID);
    let out = d.join("fit.toml");
    let o = wb(
        "fit",
        &tr,
        &m,
        &[
            "--add".as_ref(),
            "coulomb_friction".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ],
    );
    let err = text(&o.stderr);
    assert!(!o.status.success(), "fit without torque succeeded");
    assert!(
        err.contains("missing column `x.torque`")
            && err.contains("columns present: x.cmd, x.load)"),
        "{err}"
    );
}

/// The EMPS estimation record shipped in `examples/data/emps/` (see its README).
fn emps() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/data/emps/emps_estimation.csv");
    assert!(p.exists(), "the shipped record {} is missing", p.display());
    Some(p)
}

#[test]
fn diagnose_and_fit_give_the_emps_offset_with_one_sign() {
    let Some(tr) = emps() else {
        eprintln!("EMPS data not found: skipped");
        return;
    };
    let m = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/emps-nominal.toml");
    let d = scratch("emps-sign");
    let o = wb("diagnose", &tr, &m, &["--json".as_ref()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let top = &j["candidates"][0];
    assert_eq!(top["effect"], "coulomb_friction", "{j}");
    let diag_offset = top["params"]["offset_n"].as_f64().unwrap();
    let evidence = top["evidence"].as_str().unwrap().to_string();
    let fitted = d.join("fitted.toml");
    let o = wb(
        "fit",
        &tr,
        &m,
        &[
            "--add".as_ref(),
            "coulomb_friction,constant_force".as_ref(),
            "--out".as_ref(),
            fitted.as_os_str(),
            "--json".as_ref(),
        ],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let f: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let force_n = f["params"]["force_n"].as_f64().unwrap();
    // the two name the same force with the same sign, and the written model file carries it
    assert!(
        (diag_offset - force_n).abs() < 0.3,
        "diagnose offset_n {diag_offset}, fit force_n {force_n}"
    );
    let written: toml::Table = std::fs::read_to_string(&fitted).unwrap().parse().unwrap();
    let in_file = written["effects"]["constant_force"]["force_n"]
        .as_float()
        .unwrap();
    assert!((in_file - force_n).abs() < 1e-3, "{in_file} {force_n}");
    // and the diagnosis' words give that signed value as the force on the axis
    let words = format!("constant force of {:+.1} N on the axis", diag_offset);
    assert!(evidence.contains(&words), "{words:?} not in {evidence:?}");
}

/// A third mass under the shipped circle (200 kg on 1e7 N/m behind the table of a copy of
/// `examples/models/xy-x.toml`, no sensor noise), whose mode the circle barely excites: it reads
/// as the load inertia it adds, and the guided loop, after refitting that, adds no lead error (it
/// added one of 0.24 nm with a 0.3 um/m slope, below what any linear scale resolves).
#[test]
fn a_weakly_excited_third_mass_brings_no_lead_error_with_it() {
    let dir = scratch("third_mass_circle");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let x = std::fs::read_to_string(root.join("examples/models/xy-x.toml")).unwrap();
    let hidden = "\n[effects.third_mass]\nmass_kg = 200.0\nstiffness_n_per_m = 1.0e7\ndamping_ns_per_m = 1800.0\n";
    std::fs::write(dir.join("x.toml"), format!("{x}{hidden}")).unwrap();
    std::fs::write(dir.join("x0.toml"), &x).unwrap();
    let y = root.join("examples/models/xy-y.toml");
    let job = std::fs::read_to_string(root.join("examples/jobs/xy-circle.toml"))
        .unwrap()
        .replace("../models/xy-x.toml", "x.toml")
        .replace("../models/xy-y.toml", &y.display().to_string());
    std::fs::write(dir.join("job.toml"), job).unwrap();
    let sim = Command::new(bin())
        .arg("sim")
        .arg(dir.join("job.toml"))
        .arg("--out")
        .arg(dir.join("sim"))
        .output()
        .unwrap();
    assert!(sim.status.success(), "{}", text(&sim.stderr));
    let out = Command::new(bin())
        .args(["diagnose", "--auto", "--axis", "x", "--json", "--trace"])
        .arg(dir.join("sim/trace.csv"))
        .arg("--model")
        .arg(dir.join("x0.toml"))
        .arg("--out")
        .arg(dir.join("auto"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let added: Vec<String> = j["steps"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|s| s["added"].as_array().unwrap().clone())
        .map(|a| a.as_str().unwrap().to_string())
        .collect();
    println!("added {added:?}");
    assert!(
        !added.is_empty(),
        "the added inertia is not named: {}",
        j["verdict"]
    );
    assert!(
        !added.iter().any(|e| e.starts_with("pitch_error")),
        "{added:?}: {}",
        j["verdict"]
    );
}

#[test]
fn a_right_model_under_up_to_five_times_the_shipped_sensor_noise_names_nothing() {
    let dir = scratch("right_model_noise");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let x = std::fs::read_to_string(root.join("examples/models/xy-x.toml")).unwrap();
    let y = root.join("examples/models/xy-y.toml");
    let job = std::fs::read_to_string(root.join("examples/jobs/xy-circle.toml"))
        .unwrap()
        .replace("../models/xy-x.toml", "x.toml")
        .replace("../models/xy-y.toml", &y.display().to_string());
    // the shipped models' noise: 0.01 rad/s on the motor velocity, 5 nm on the scale
    for times in [1.0, 3.0, 5.0] {
        let d = dir.join(format!("n{times}"));
        std::fs::create_dir_all(&d).unwrap();
        let sensor = format!(
            "\n[sensor]\nmotor_counts_per_rev = 1048576\nload_resolution_m = 5.0e-8\nmotor_vel_noise_rad_per_s = {}\nload_pos_noise_m = {}\nseed = 11\n",
            0.01 * times,
            5e-9 * times
        );
        std::fs::write(d.join("x.toml"), format!("{x}{sensor}")).unwrap();
        std::fs::write(d.join("job.toml"), &job).unwrap();
        let sim = Command::new(bin())
            .arg("sim")
            .arg(d.join("job.toml"))
            .arg("--out")
            .arg(d.join("sim"))
            .output()
            .unwrap();
        assert!(sim.status.success(), "{}", text(&sim.stderr));
        let out = wb(
            "diagnose",
            &d.join("sim/trace.csv"),
            &d.join("x.toml"),
            &["--axis".as_ref(), "x".as_ref(), "--json".as_ref()],
        );
        assert!(out.status.success(), "{}", text(&out.stderr));
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let named: Vec<String> = j["candidates"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| c["significant"] == true)
            .map(|c| c["effect"].as_str().unwrap().to_string())
            .collect();
        assert!(
            named.is_empty(),
            "{times} x the noise: {named:?} named on the right model: {}",
            j["verdict"]
        );
    }
}
