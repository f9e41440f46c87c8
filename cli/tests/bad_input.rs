//! Bad job and model files are refused before any process starts, with the file and key named.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("feedloop-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const MODEL: &str = r#"kind = "ballscrew"
jm_kgm2 = 2.0e-3
kl_nm_per_rad = 3000.0
jl_kgm2 = 3.0e-3
lead_m = 0.01
[controller]
kp_per_s = 50.0
kv_nms_per_rad = 5.0
tv_s = 0.005
torque_limit_nm = 30.0
"#;

const JOB: &str = r#"period_s = 0.001
[axes.x]
model = "m.toml"
[trajectory]
kind = "dwell"
duration_s = 0.1
"#;

/// Writes the job and model, runs `feedloop <cmd> job.toml --out DIR`, and returns stderr
/// after checking the exit code is non-zero and that nothing was started (no output folder).
fn refused(name: &str, cmd: &str, job: &str, model: &str) -> (PathBuf, String) {
    let d = scratch(name);
    std::fs::write(d.join("m.toml"), model).unwrap();
    std::fs::write(d.join("job.toml"), job).unwrap();
    let out = d.join("out");
    let o = Command::new(bin())
        .arg(cmd)
        .arg(d.join("job.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "{cmd} accepted a bad file: {err}");
    assert!(
        !Path::new(&out).exists(),
        "{cmd} created its output before validating"
    );
    (d, err)
}

#[test]
fn unknown_job_key_is_named_with_the_file() {
    for cmd in ["run", "sim"] {
        let (d, err) = refused("unknown", cmd, &format!("speed = 3\n{JOB}"), MODEL);
        assert!(
            err.contains(&d.join("job.toml").display().to_string()),
            "{err}"
        );
        assert!(
            err.contains("`speed`") && err.contains("unknown key"),
            "{err}"
        );
    }
}

#[test]
fn negative_load_inertia_is_named_with_the_model_file() {
    let (d, err) = refused(
        "negjl",
        "run",
        JOB,
        &MODEL.replace("jl_kgm2 = 3.0e-3", "jl_kgm2 = -3.0e-3"),
    );
    assert!(
        err.contains(&d.join("m.toml").display().to_string()),
        "{err}"
    );
    assert!(err.contains("`jl_kgm2`") && err.contains("> 0"), "{err}");
}

#[test]
fn zero_period_is_refused() {
    let (_, err) = refused(
        "zeroperiod",
        "run",
        &JOB.replace("period_s = 0.001", "period_s = 0"),
        MODEL,
    );
    assert!(err.contains("`period_s`") && err.contains("> 0"), "{err}");
}

#[test]
fn chain_axis_that_does_not_exist_is_refused() {
    let job =
        format!("{JOB}[[chain]]\naxis = \"z\"\nstage = \"velocity\"\nplugin = \"pi_velocity\"\n");
    let (_, err) = refused("chainaxis", "run", &job, MODEL);
    assert!(
        err.contains("chain[0].axis") && err.contains("`z` does not exist"),
        "{err}"
    );
}

#[test]
fn unknown_plugin_and_bad_plugin_parameter_are_refused() {
    let job =
        format!("{JOB}[[chain]]\naxis = \"x\"\nstage = \"velocity\"\nplugin = \"pid_magic\"\n");
    let (_, err) = refused("plugin", "run", &job, MODEL);
    assert!(err.contains("unknown plugin `pid_magic`"), "{err}");
    let job = format!(
        "{JOB}[[chain]]\naxis = \"x\"\nstage = \"velocity\"\nplugin = \"pi_velocity\"\nparams = {{ tv_s = -1.0 }}\n"
    );
    let (_, err) = refused("plugin2", "run", &job, MODEL);
    assert!(err.contains("chain[0].params.tv_s"), "{err}");
}

#[test]
fn missing_job_file_is_named() {
    let d = scratch("missing");
    let o = Command::new(bin())
        .args(["sim"])
        .arg(d.join("nope.toml"))
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("nope.toml") && err.contains("cannot read"),
        "{err}"
    );
}
