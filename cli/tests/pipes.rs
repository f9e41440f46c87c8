//! A reader that goes away (`feedloop ... | head -1`) ends a command quietly: no panic, no
//! "failed printing to stdout", no exit code 101.

use std::io::Read;
use std::process::{Command, Stdio};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

/// Runs `feedloop ARGS` with its stdout's reader gone before the first write (what `| head -1`
/// does to every write after the first line).
fn closed_pipe(args: &[&str]) -> (std::process::ExitStatus, String) {
    let mut child = Command::new(bin())
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    (child.wait().unwrap(), err)
}

#[test]
fn commands_writing_into_a_closed_pipe_end_quietly() {
    let dir = std::env::temp_dir().join(format!("feedloop-pipes-{}", std::process::id()));
    let job = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/jobs/xy-circle.toml"
    );
    let out = dir.join("sim");
    let lockstep = dir.join("run");
    let cases: [&[&str]; 2] = [
        &["sim", job, "--out", out.to_str().unwrap(), "--json"],
        &[
            "run",
            job,
            "--out",
            lockstep.to_str().unwrap(),
            "--mode",
            "lockstep",
        ],
    ];
    for args in cases {
        let (st, err) = closed_pipe(args);
        assert_ne!(st.code(), Some(101), "{args:?}: {st}\n{err}");
        assert!(
            !err.contains("panicked") && !err.contains("failed printing"),
            "{args:?}: {err}"
        );
    }
}
