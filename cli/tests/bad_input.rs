//! Bad job and model files are refused before any process starts, with the file and key named.

use std::path::Path;
use std::process::Command;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

use feedloop_test_support::Scratch;

/// A fresh scratch folder for test `name` (removed when the test passes).
fn scratch(name: &str) -> Scratch {
    Scratch::new("cli", name)
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
fn refused(name: &str, cmd: &str, job: &str, model: &str) -> (Scratch, String) {
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

/// Runs `feedloop ARGS` and returns stderr after checking it failed.
fn fails(args: &[&std::ffi::OsStr]) -> String {
    let o = Command::new(bin()).args(args).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(
        !o.status.success(),
        "{args:?} succeeded: {}",
        String::from_utf8_lossy(&o.stdout)
    );
    err
}

#[test]
fn an_unknown_key_is_answered_with_the_accepted_keys_and_the_nearest_one() {
    // a job table whose only key is misspelled: the accepted keys are listed all the same
    let (_, err) = refused(
        "nearjob",
        "sim",
        &format!("{JOB}[run]\nmdoe = \"lockstep\"\n"),
        MODEL,
    );
    assert!(err.contains("`run.mdoe`"), "{err}");
    assert!(err.contains("did you mean `mode`?"), "{err}");
    assert!(
        err.contains("accepted here:") && err.contains("mode") && err.contains("wait"),
        "{err}"
    );
    // a model's controller key with a slip in its unit suffix
    let (_, err) = refused(
        "nearmodel",
        "sim",
        JOB,
        &MODEL.replace("kv_nms_per_rad", "kv_nms_per_rd"),
    );
    assert!(err.contains("`controller.kv_nms_per_rd`"), "{err}");
    assert!(err.contains("did you mean `kv_nms_per_rad`?"), "{err}");
    assert!(err.contains("torque_limit_nm"), "{err}");
    // a plugin's parameters (what `feedloop swap --params FILE` sends is read the same way)
    let job = format!(
        "{JOB}[[chain]]\naxis = \"x\"\nstage = \"velocity\"\nplugin = \"pi_velocity\"\nparams = {{ tv_ss = 0.005 }}\n"
    );
    let (_, err) = refused("nearplugin", "sim", &job, MODEL);
    assert!(err.contains("did you mean `tv_s`?"), "{err}");
    assert!(err.contains("kv_nms_per_rad"), "{err}");
    // an effect table of a model: its id, and a key inside it
    let (_, err) = refused(
        "neareffect",
        "sim",
        JOB,
        &format!("{MODEL}[effects.coulomb_fricton]\nfc_nm = 0.1\n"),
    );
    assert!(
        err.contains("`effects.coulomb_fricton`")
            && err.contains("did you mean `coulomb_friction`?"),
        "{err}"
    );
    let (_, err) = refused(
        "neareffectkey",
        "sim",
        JOB,
        &format!("{MODEL}[effects.coulomb_friction]\nfc_nmm = 0.1\n"),
    );
    assert!(
        err.contains("`effects.coulomb_friction.fc_nmm`")
            && err.contains("did you mean `fc_nm`")
            && err.contains("accepted here: side, fc_nm"),
        "{err}"
    );
}

#[test]
fn a_misspelled_required_key_is_named_not_only_reported_missing() {
    let (_, err) = refused(
        "slipjob",
        "sim",
        &JOB.replace("period_s = 0.001", "perod_s = 0.001"),
        MODEL,
    );
    assert!(
        err.contains("`period_s`") && err.contains("`perod_s`") && err.contains("misspelling"),
        "{err}"
    );
    let (_, err) = refused(
        "slipmodel",
        "sim",
        JOB,
        &MODEL.replace("jm_kgm2 = 2.0e-3", "jm_kgm = 2.0e-3"),
    );
    assert!(
        err.contains("`jm_kgm2`") && err.contains("`jm_kgm`") && err.contains("misspelling"),
        "{err}"
    );
}

#[test]
fn an_unknown_grid_parameter_is_answered_with_the_nearest_one() {
    let d = scratch("neargrid");
    std::fs::write(d.join("m.toml"), MODEL).unwrap();
    std::fs::write(d.join("job.toml"), JOB).unwrap();
    let job = d.join("job.toml");
    let err = fails(&[
        "tune".as_ref(),
        "--job".as_ref(),
        job.as_os_str(),
        "--grid".as_ref(),
        "kp_pers=20:120:3".as_ref(),
    ]);
    assert!(err.contains("did you mean `kp_per_s`?"), "{err}");
    assert!(
        err.contains("kp_per_s, kv_nms_per_rad, tv_s"),
        "the accepted parameters are listed: {err}"
    );
}

#[test]
fn trace_import_errors_name_the_source_file_and_its_line() {
    let d = scratch("importline");
    let src = d.join("export.csv");
    let out = d.join("imported.csv");
    let import = || {
        fails(&[
            "trace".as_ref(),
            "import".as_ref(),
            "--from".as_ref(),
            src.as_os_str(),
            "--map".as_ref(),
            "t=time_ms*0.001,x.cmd=pos_mm*0.001,x.load=pos_mm*0.001".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ])
    };
    // three comment lines, a header, then rows; the time steps back on line 8 of the source
    // (line 7 of the trace it would write)
    std::fs::write(
        &src,
        "# exported by a drive tool\n# units: ms, mm\n# axis X\ntime_ms,pos_mm\n0,0\n1,1\n2,2\n1.5,3\n4,4\n",
    )
    .unwrap();
    let err = import();
    assert!(
        err.contains(&format!("{}: line 8:", src.display())),
        "the source and its line: {err}"
    );
    assert!(err.contains("not strictly increasing"), "{err}");
    assert!(!err.contains("imported.csv"), "the output is named: {err}");
    // uneven sampling: the row whose step is off, on the source's line
    std::fs::write(&src, "time_ms;pos_mm\n\n0;0\n1;1\n2;2\n3;3\n5;4\n6;5\n").unwrap();
    let err = import();
    assert!(
        err.contains(&format!("{}: line 7:", src.display())) && err.contains("uneven"),
        "{err}"
    );
    assert!(!out.exists(), "a refused import wrote its output");
}

/// A file that does not exist: the message names it and says the cause once (the trace reader's
/// message already quotes its cause, and the cause was printed again after it).
#[test]
fn a_missing_file_is_named_with_its_cause_said_once() {
    let dir = scratch("missing_file");
    let missing = dir.join("no-such-trace.csv");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/xy-x.toml");
    let out = Command::new(bin())
        .arg("compare")
        .arg("--trace")
        .arg(&missing)
        .arg("--model")
        .arg(&model)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&missing.display().to_string()), "{err}");
    let cause = std::io::Error::from(std::io::ErrorKind::NotFound).to_string();
    let said = err.matches("os error 2").count();
    assert_eq!(said, 1, "the cause ({cause}) said {said} times: {err}");
}
