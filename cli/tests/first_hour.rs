//! What a new user met in the first hour (issue 34, items 1, 3, 4, 5, 6 and 9), through the real
//! binary: a realtime run that misses its period is warned about with advice and shows a live
//! line on a terminal; messages name the real column, flag and range; `tune` says when its best
//! is on the grid's edge; `excite` prints the `file` line a job needs; `identify inertia` says
//! when its record cannot see the load; `merge` says what its exit status means.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use feedloop_test_support::{found_or_skip, Scratch};
use feedloop_trace::log::{LogWriter, PlantRecord, REC_OVERRUN};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn scratch(name: &str) -> Scratch {
    Scratch::new("first", name)
}

fn run_in(dir: Option<&Path>, args: &[&str]) -> Output {
    let mut c = Command::new(bin());
    c.args(args);
    if let Some(d) = dir {
        c.current_dir(d);
    }
    c.output().unwrap()
}

fn run(args: &[&str]) -> Output {
    run_in(None, args)
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn describe(o: &Output) -> String {
    let (out, err) = text(o);
    format!("exit {:?}\nstdout: {out}\nstderr: {err}", o.status.code())
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A folder as a realtime run leaves it: plant.log with `cycles` records, the first
/// `overruns` of them plant overruns, and plant.json ending with `end`.
fn run_logs(dir: &Path, cycles: u64, overruns: u64, wait: &str, end: &str) {
    let recs: Vec<PlantRecord> = (0..cycles)
        .map(|k| PlantRecord {
            seq: k,
            flags: if k < overruns { REC_OVERRUN } else { 0 },
            ..Default::default()
        })
        .collect();
    let mut w = LogWriter::create(&dir.join("plant.log")).unwrap();
    for chunk in recs.chunks(64) {
        w.write_block(chunk).unwrap();
    }
    let plant = serde_json::json!({"pid": 1, "mode": "realtime", "wait": wait,
        "cycles": cycles, "planned_cycles": cycles,
        "end": {"reason": end, "cycle": cycles}});
    std::fs::write(dir.join("plant.json"), plant.to_string()).unwrap();
}

fn merge(dir: &Path, json: bool) -> Output {
    let job = repo("examples/jobs/single-axis-move.toml");
    let mut a = vec!["merge", s(dir), "--job", s(&job)];
    if json {
        a.push("--json");
    }
    run(&a)
}

/// Item 1: overruns in most cycles give a warning (text and `timing_warning`) that says the
/// share, the limit and what to change; a run within the limit gets none.
#[test]
fn a_realtime_run_that_overruns_most_cycles_is_warned_about_with_advice() {
    let d = scratch("overruns");
    run_logs(&d, 1000, 900, "block", "completed");
    let o = merge(&d, true);
    assert!(o.status.success(), "{}", describe(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let w = &v["timing_warning"];
    assert_eq!(w["exceeded"], serde_json::json!(["plant_overruns"]), "{v}");
    assert_eq!(w["share_limit"], 0.01, "{w}");
    assert_eq!(w["plant_overrun_share"], 0.9, "{w}");
    let advice = w["advice"].to_string();
    assert!(
        advice.contains("--wait busy") && advice.contains("--pin") && advice.contains("period_s"),
        "{advice}"
    );
    let o = merge(&d, false);
    let (out, _) = text(&o);
    assert!(
        out.contains("warning: plant overruns")
            && out.contains("90.0 % of the cycles (900 of 1000)")
            && out.contains("more than 1 %")
            && out.contains("--wait busy or --wait hybrid"),
        "{out}"
    );
    // within the limit: no warning
    let d = scratch("fewoverruns");
    run_logs(&d, 1000, 10, "block", "completed");
    let o = merge(&d, true);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["timing_warning"].is_null(), "{v}");
    assert!(!text(&merge(&d, false)).0.contains("warning"));
}

/// Item 1: `run` draws a live line (cycles, run time, overruns so far) when standard error is a
/// terminal, and none with `--quiet`.
#[test]
fn a_realtime_run_on_a_terminal_shows_a_live_line_and_quiet_hides_it() {
    let script = Path::new("/usr/bin/script");
    if found_or_skip(
        script.exists().then_some(()),
        "`script` (util-linux) for a terminal",
    )
    .is_none()
    {
        return;
    }
    let d = scratch("live");
    let job = repo("examples/jobs/xy-circle.toml");
    let line = |extra: &str| {
        let cmd = format!(
            "{} run {} --out {} --mode realtime --wait hybrid {extra}",
            bin(),
            s(&job),
            s(&d.join("out"))
        );
        // a realtime run on a shared machine can end early (a busy machine loses the
        // scheduler), which is not what is tested here: once more then
        let mut o = Command::new(script)
            .args(["-qec", &cmd, "/dev/null"])
            .output()
            .unwrap();
        if !o.status.success() {
            eprintln!("retried after: {}", describe(&o));
            o = Command::new(script)
                .args(["-qec", &cmd, "/dev/null"])
                .output()
                .unwrap();
        }
        assert!(o.status.success(), "{}", describe(&o));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let shown = line("");
    // the run lasts 3.97 s of wall time: the line is redrawn with cycles done before it ends
    let live: Vec<&str> = shown
        .split(['\r', '\n'])
        .filter(|l| l.contains("/39699 cycles, ") && l.contains("plant overruns"))
        .collect();
    assert!(
        live.iter().any(|l| !l.contains(" 0/39699")),
        "no live figure: {shown}"
    );
    assert!(shown.contains("of 3.97 s"), "{shown}");
    let quiet = line("--quiet");
    assert!(!quiet.contains("/39699 cycles, "), "{quiet}");
    assert!(quiet.contains("ended: completed"), "{quiet}");
}

/// Item 3: a lockstep run prints no wall-clock latency figures.
#[test]
fn a_lockstep_run_prints_no_latency() {
    let d = scratch("lockstep");
    let job = repo("examples/jobs/single-axis-move.toml");
    let o = run(&[
        "run",
        s(&job),
        "--out",
        s(&d),
        "--mode",
        "lockstep",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    let (out, _) = text(&o);
    assert!(
        out.contains("[lockstep]") && !out.contains("latency"),
        "{out}"
    );
}

/// Item 3: `compare` names the column an axis lacks (`x.load`, not `A.cmd`) and, for an axis
/// that is not there, the prefixes the trace has and what an axis needs.
#[test]
fn compare_names_the_missing_column_and_the_axes_there_are() {
    let d = scratch("compare");
    let mut t = String::from("# feedloop-trace v1\nt,x.cmd,x.motor\n");
    for k in 0..200 {
        t.push_str(&format!("{},{},{}\n", k as f64 * 1e-3, k as f64 * 1e-4, k));
    }
    let tr = d.join("t.csv");
    std::fs::write(&tr, t).unwrap();
    let model = repo("examples/models/xy-x.toml");
    let out = d.join("out");
    let base = [
        "compare",
        "--trace",
        s(&tr),
        "--model",
        s(&model),
        "--out",
        s(&out),
    ];
    for axis in [None, Some("x")] {
        let mut a = base.to_vec();
        if let Some(x) = axis {
            a.extend(["--axis", x]);
        }
        let o = run(&a);
        let (_, err) = text(&o);
        assert!(!o.status.success(), "{}", describe(&o));
        assert!(
            err.contains("missing column `x.load`") && !err.contains("A.cmd`,"),
            "{err}"
        );
    }
    let mut a = base.to_vec();
    a.extend(["--axis", "y"]);
    let (_, err) = text(&run(&a));
    assert!(
        err.contains("no axis `y`")
            && err.contains("column prefixes: x (no `x.load`)")
            && err.contains("`A.cmd` and `A.load`"),
        "{err}"
    );
}

/// Item 3: an unknown `swap --plugin` is refused under its flag with the closest id.
#[test]
fn swap_refuses_an_unknown_plugin_under_its_flag() {
    let o = run(&[
        "swap",
        "--instance",
        "nobody-here",
        "--axis",
        "x",
        "--stage",
        "velocity",
        "--plugin",
        "pi_velocty",
    ]);
    let (_, err) = text(&o);
    assert!(!o.status.success());
    assert!(
        err.contains("--plugin `pi_velocty`")
            && err.contains("did you mean `pi_velocity`?")
            && err.contains("position_p"),
        "{err}"
    );
    assert!(!err.contains("<swap --params>"), "{err}");
}

/// Item 3: a range is printed with significant digits, not rows of zeros.
#[test]
fn a_range_refusal_prints_its_bounds_readably() {
    let d = scratch("range");
    let job = std::fs::read_to_string(repo("examples/jobs/single-axis-move.toml"))
        .unwrap()
        .replace(
            "model = \"../models/xy-x.toml\"",
            &format!("model = {:?}", s(&repo("examples/models/xy-x.toml"))),
        )
        + "\n[[chain]]\naxis = \"x\"\nstage = \"velocity\"\nplugin = \"pi_velocity\"\n\
           params = { kv_nms_per_rad = 2e10 }\n";
    let j = d.join("j.toml");
    std::fs::write(&j, job).unwrap();
    let (_, err) = text(&run(&["sim", s(&j), "--out", s(&d.join("o")), "--quiet"]));
    assert!(
        err.contains("must be within [1e-12, 1e9], got 2e10"),
        "{err}"
    );
}

/// Item 4: a best value on the edge of its grid is warned about, naming the parameter, the edge
/// and a wider range (text and JSON); a best inside the grid is not.
#[test]
fn tune_warns_when_the_best_is_on_the_edge_of_the_grid() {
    let job = repo("examples/jobs/tune-ramp.toml");
    let grid = "kp_per_s=20:120:3,kv_nms_per_rad=4:8:3";
    let o = run(&["tune", "--job", s(&job), "--grid", grid, "--json"]);
    assert!(o.status.success(), "{}", describe(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let w = &v["edge_warnings"][0];
    assert_eq!(w["parameter"], "kp_per_s", "{v}");
    assert_eq!(w["edge"], "upper", "{v}");
    assert_eq!(w["widened"], "kp_per_s=20:220:3", "{v}");
    let (out, _) = text(&run(&["tune", "--job", s(&job), "--grid", grid]));
    assert!(
        out.contains("warning: the best kp_per_s is 120, the upper bound of its grid")
            && out.contains("--grid kp_per_s=20:220:3"),
        "{out}"
    );
    // kv 10 and 12 are rejected by the margins: the best kv 8 is inside, kp has one value
    let o = run(&[
        "tune",
        "--job",
        s(&job),
        "--grid",
        "kp_per_s=120:120:1,kv_nms_per_rad=4:12:5",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["edge_warnings"], serde_json::json!([]), "{v}");
}

/// Item 5: `excite` prints the `file` line a job in the output's folder (or in `--for-job`'s)
/// needs; a job that names its own folder twice is told the line to write, not to write the file
/// to the doubled path; `identify stiffness` on the default excitation names the flags of a
/// traverse.
#[test]
fn excite_prints_the_file_line_a_job_needs_and_the_traverse_flags_are_named() {
    let d = scratch("excite");
    std::fs::create_dir_all(d.join("jobs")).unwrap();
    let o = run_in(
        Some(&d),
        &[
            "excite",
            "--kind",
            "random-segments",
            "--out",
            "jobs/cmd.csv",
        ],
    );
    let (out, _) = text(&o);
    assert!(o.status.success(), "{}", describe(&o));
    assert!(
        out.contains("file = \"cmd.csv\" in a job in jobs/")
            && out.contains("read from the job's own folder"),
        "{out}"
    );
    let o = run_in(
        Some(&d),
        &[
            "excite",
            "--kind",
            "random-segments",
            "--out",
            "jobs/cmd.csv",
            "--for-job",
            "other/j.toml",
            "--json",
        ],
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["job_file"], "../jobs/cmd.csv", "{v}");
    // the job as the old message had it pasted: the folder twice
    let job = std::fs::read_to_string(repo("examples/jobs/identify-stiffness-trace.toml"))
        .unwrap()
        .replace(
            "model = \"../models/xy-x.toml\"",
            &format!("model = {:?}", s(&repo("examples/models/xy-x.toml"))),
        );
    let doubled = job.replace("file = \"cmd.csv\"", "file = \"jobs/cmd.csv\"");
    std::fs::write(d.join("jobs/doubled.toml"), doubled).unwrap();
    let (_, err) = text(&run_in(
        Some(&d),
        &["sim", "jobs/doubled.toml", "--out", "o", "--quiet"],
    ));
    assert!(
        err.contains("named twice: write file = \"cmd.csv\"") && !err.contains("--out jobs/jobs/"),
        "{err}"
    );
    // the default excitation, played and identified: the advice names the traverse flags
    std::fs::write(d.join("jobs/play.toml"), job).unwrap();
    let o = run_in(
        Some(&d),
        &["sim", "jobs/play.toml", "--out", "o", "--quiet"],
    );
    assert!(o.status.success(), "{}", describe(&o));
    let o = run_in(
        Some(&d),
        &[
            "identify",
            "stiffness",
            "--trace",
            "o/trace.csv",
            "--jm-kgm2",
            "2e-3",
        ],
    );
    let (out, err) = text(&o);
    assert!(
        (out.clone() + &err).contains("--set traverse_m_per_s=0.02 --set max_travel_m=0.1"),
        "{}",
        describe(&o)
    );
}

/// The inertia example's move on a machine with load inertia `jl`, its feedforward's params
/// `ff` (its own inertia from the machine's model unless `ff` pins one).
fn inertia_record(d: &Path, tag: &str, jl: f64, ff: &str) -> PathBuf {
    let model = std::fs::read_to_string(repo("examples/models/xy-x.toml"))
        .unwrap()
        .replace("jl_kgm2 = 3.0e-3", &format!("jl_kgm2 = {jl:e}"));
    let m = d.join(format!("{tag}.toml"));
    std::fs::write(&m, model).unwrap();
    let job = std::fs::read_to_string(repo("examples/jobs/identify-inertia-move.toml"))
        .unwrap()
        .replace(
            "model = \"../models/xy-x.toml\"",
            &format!("model = {:?}", s(&m)),
        )
        .replace(
            "params = { structure = \"split\" }",
            &format!("params = {{ {ff} }}"),
        );
    let j = d.join(format!("{tag}-job.toml"));
    std::fs::write(&j, job).unwrap();
    let out = d.join(tag);
    let o = run(&["sim", s(&j), "--out", s(&out), "--quiet"]);
    assert!(o.status.success(), "{}", describe(&o));
    out.join("trace.csv")
}

/// Item 6: a record whose feedforward followed the heavier load cannot show the load in the
/// command-load deviation: the estimate (the model job's feedforward inertia) comes with a
/// warning; a record whose feedforward kept the nominal inertia carries it and gets none.
#[test]
fn identify_inertia_warns_when_its_record_cannot_see_the_load() {
    let d = scratch("inertia");
    let job = repo("examples/jobs/identify-inertia-move.toml");
    let est = |trace: &Path| -> serde_json::Value {
        let o = run(&[
            "identify",
            "inertia",
            "--trace",
            s(trace),
            "--model",
            s(&job),
            "--at",
            "0.01",
            "--json",
        ]);
        assert!(o.status.success(), "{}", describe(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let blind = est(&inertia_record(
        &d,
        "follows",
        3.9e-3,
        "structure = \"split\"",
    ));
    let w = blind["warnings"].to_string();
    assert!(
        w.contains("does not tell the load from the feedforward")
            && w.contains("1 % change")
            && w.contains("--deviation motor-load"),
        "{blind}"
    );
    let seen = est(&inertia_record(
        &d,
        "nominal",
        3.9e-3,
        "structure = \"split\", jl_kgm2 = 3.0e-3",
    ));
    assert!((seen["jl_kgm2"].as_f64().unwrap() / 3.9e-3 - 1.0).abs() < 1e-3);
    assert_eq!(seen["warnings"], serde_json::json!([]), "{seen}");
    let o = run(&[
        "identify",
        "inertia",
        "--trace",
        s(&d.join("follows/trace.csv")),
        "--model",
        s(&job),
        "--at",
        "0.01",
    ]);
    assert!(text(&o)
        .0
        .contains("warning: the measured command-load deviation"));
}

/// Item 9: `merge` of a run that ended abnormally writes both files, exits 1 and says so; its
/// `--help` says what each exit status means.
#[test]
fn merge_says_what_its_exit_status_means() {
    let d = scratch("merge");
    run_logs(&d, 500, 0, "busy", "scheduler_lost");
    let o = merge(&d, false);
    assert_eq!(o.status.code(), Some(1), "{}", describe(&o));
    let (out, err) = text(&o);
    assert!(d.join("trace.csv").exists() && d.join("summary.json").exists());
    assert!(out.contains("wrote"), "{out}");
    assert!(
        err.contains("exit status 1: the export worked")
            && err.contains("ended abnormally (end: scheduler_lost"),
        "{err}"
    );
    let (help, _) = text(&run(&["merge", "--help"]));
    assert!(
        help.contains("Exit status: 0 when the run completed")
            && help.contains("1 when trace.csv and summary.json were written"),
        "{help}"
    );
}
