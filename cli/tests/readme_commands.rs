//! Commands as the README and the examples give them leave the shipped files alone, and a shipped
//! job that needs a file made by another step says which command makes it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

use feedloop_test_support::Scratch;

/// A fresh scratch folder for test `name` (removed when the test passes).
fn scratch(name: &str) -> Scratch {
    Scratch::new("readme", name)
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// A shipped job copied to `dir/jobs/NAME` with its models read from the shipped folder, so that
/// a run can write next to it without touching the repository.
fn copy_job(dir: &Path, name: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let models = examples().join("models");
    let text = std::fs::read_to_string(examples().join("jobs").join(name)).unwrap();
    let text = text.replace("\"../models/", &format!("\"{}/", models.display()));
    std::fs::create_dir_all(dir.join("jobs")).unwrap();
    let p = dir.join("jobs").join(name);
    std::fs::write(&p, edit(text)).unwrap();
    p
}

fn learn(cwd: &Path, extra: &[&str]) -> Output {
    let o = Command::new(bin())
        .current_dir(cwd)
        .args([
            "learn",
            "quadrant",
            "--job",
            "jobs/xy-circle-quadrant.toml",
            "--passes",
            "1",
        ])
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    o
}

#[test]
fn learn_quadrant_as_the_readme_writes_it_leaves_the_jobs_table_alone() {
    let d = scratch("learn");
    // the shipped job and a copy of its shipped table, a shorter circle to keep the test quick
    copy_job(&d, "xy-circle-quadrant.toml", |t| {
        t.replace("turns = 2.0", "turns = 0.5")
    });
    std::fs::create_dir_all(d.join("tables")).unwrap();
    let shipped = std::fs::read(examples().join("tables/xy-circle-quadrant.toml")).unwrap();
    let job_table = d.join("tables/xy-circle-quadrant.toml");
    std::fs::write(&job_table, &shipped).unwrap();

    // the README's command: the table goes to the output folder, the job's table is untouched
    let o = learn(&d, &[]);
    assert!(
        std::fs::read(&job_table).unwrap() == shipped,
        "the job's table was overwritten"
    );
    let learned = d.join("out/learn-xy-circle-quadrant/xy-circle-quadrant.toml");
    let t = std::fs::read_to_string(&learned).unwrap();
    assert!(t.contains("[[axes.y."), "a learned table: {t}");
    let s = text(&o.stdout);
    assert!(
        s.contains(&learned.file_name().unwrap().to_string_lossy().to_string())
            && s.contains("unchanged"),
        "{s}"
    );

    // an output folder of one's own
    learn(&d, &["--out", "mine"]);
    assert!(d.join("mine/xy-circle-quadrant.toml").exists());
    assert!(
        std::fs::read(&job_table).unwrap() == shipped,
        "--out: the job's table was overwritten"
    );

    // told explicitly, it writes the job's table (relative to where it is run)
    learn(&d, &["--table", "tables/xy-circle-quadrant.toml"]);
    assert!(
        std::fs::read(&job_table).unwrap() != shipped,
        "--table: the job's table was not written"
    );
}

#[test]
fn the_trace_example_without_its_command_file_says_how_to_make_it() {
    let d = scratch("excite");
    let job = copy_job(&d, "identify-stiffness-trace.toml", |t| t);
    let cmd_csv = d.join("jobs/cmd.csv");
    let o = Command::new(bin())
        .args(["sim"])
        .arg(&job)
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    let err = text(&o.stderr);
    assert!(!o.status.success(), "ran without cmd.csv");
    let want = format!(
        "feedloop excite --kind random-segments --out {}",
        cmd_csv.display()
    );
    assert!(err.contains(&want), "{err}");
    // the command given is the one that makes the job run
    let quoted = err.split('`').nth(3).unwrap_or_default().to_string();
    assert_eq!(quoted, want, "{err}");
    let args: Vec<&str> = quoted.split_whitespace().skip(1).collect();
    let o = Command::new(bin()).args(&args).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = Command::new(bin())
        .args(["sim"])
        .arg(&job)
        .arg("--out")
        .arg(d.join("out"))
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// The commands of the README's fenced blocks that run feedloop (`cargo run --release -- ...` or
/// `feedloop ...`), as their arguments.
fn readme_commands() -> Vec<Vec<String>> {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .unwrap();
    let mut cmds = Vec::new();
    let mut in_block = false;
    for line in readme.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
            continue;
        }
        if !in_block {
            continue;
        }
        let l = line.trim();
        let rest = l
            .strip_prefix("cargo run --release --")
            .or_else(|| l.strip_prefix("feedloop "));
        if let Some(rest) = rest {
            cmds.push(rest.split_whitespace().map(str::to_string).collect());
        }
    }
    cmds
}

#[test]
fn every_feedloop_command_of_the_readme_runs_as_written() {
    let cmds = readme_commands();
    assert!(
        !cmds.is_empty(),
        "the README quotes no command that runs feedloop"
    );
    let d = scratch("tour");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for (i, args) in cmds.iter().enumerate() {
        // from the repository's root, as a new user runs it, its output in a scratch folder
        let mut args = args.clone();
        if let Some(k) = args.iter().position(|a| a == "--out") {
            args[k + 1] = d.join(format!("out{i}")).display().to_string();
        }
        let o = Command::new(bin())
            .current_dir(&root)
            .args(&args)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "`feedloop {}` failed: {}",
            args.join(" "),
            text(&o.stderr)
        );
        if args.first().is_some_and(|a| a == "run" || a == "sim") {
            let out = d.join(format!("out{i}"));
            for f in ["trace.csv", "summary.json"] {
                assert!(
                    out.join(f).exists(),
                    "`feedloop {}` wrote no {f}",
                    args.join(" ")
                );
            }
        }
    }
}
