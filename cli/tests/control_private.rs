//! The control service of a running loop stays private to the user who runs it (issue 31):
//! another Unix user (`nobody`) cannot swap a controller of the loop, nor read its status, and the
//! loop's shared-memory files are mode 0600. Needs root to act as `nobody` (`runuser`); without
//! it, or without that user, the test says so and is skipped, except on CI (`CI=true`), where it
//! fails.

mod scope_common;

use std::ffi::CString;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use scope_common::{bin, long_job, scratch, start_run, status, stop};

const OTHER: &str = "nobody";

/// `runuser`, when this process is root and the other user exists.
fn runuser() -> Option<PathBuf> {
    // SAFETY: geteuid cannot fail.
    if unsafe { libc::geteuid() } != 0 {
        return None;
    }
    let name = CString::new(OTHER).unwrap();
    // SAFETY: a NUL-terminated name; the result is only compared with null.
    if unsafe { libc::getpwnam(name.as_ptr()) }.is_null() {
        return None;
    }
    ["/usr/sbin/runuser", "/sbin/runuser", "/usr/bin/runuser"]
        .into_iter()
        .map(PathBuf::from)
        .find(|p| p.exists())
}

/// `feedloop ARGS` as the other user, from a copy of the binary that user may run.
fn as_other(runuser: &Path, exe: &Path, args: &[&str]) -> Output {
    Command::new(runuser)
        .args(["-u", OTHER, "--"])
        .arg(exe)
        .args(args)
        .current_dir("/")
        .output()
        .unwrap()
}

/// The binary, copied where any user may run it (the build folder need not be open to them).
fn open_copy(dir: &Path) -> PathBuf {
    let exe = dir.join("feedloop");
    std::fs::copy(bin(), &exe).unwrap();
    std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o755)).unwrap();
    exe
}

/// The mode bits of feedloop's iceoryx2 files in `/dev/shm` (its prefix `feedloop_`), but for
/// iceoryx2's node counter (`*.global_mgmt`, 16 bytes): every user's nodes count in it, by
/// iceoryx2's design, and it holds nothing of any loop.
fn shared_memory_modes() -> Vec<(String, u32)> {
    std::fs::read_dir("/dev/shm")
        .map(|rd| {
            rd.filter_map(Result::ok)
                .filter(|e| {
                    let n = e.file_name().to_string_lossy().into_owned();
                    n.starts_with("feedloop_") && !n.ends_with(".global_mgmt")
                })
                .filter_map(|e| {
                    let mode = e.metadata().ok()?.permissions().mode() & 0o777;
                    Some((e.file_name().to_string_lossy().into_owned(), mode))
                })
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn another_unix_user_cannot_swap_on_the_loop() {
    let missing = format!("another user's swap not tested: needs root, user `{OTHER}` and runuser");
    let Some(runuser) = feedloop_test_support::found_or_skip(runuser(), missing) else {
        return;
    };
    let d = scratch("control-private");
    let exe = open_copy(&d);
    let instance = format!("private{}", std::process::id());
    let job = long_job(&d, 3.0);
    let mut run = start_run(&job, &d.join("run"), &instance);
    status(&instance, 30.0);

    // the other user can run feedloop at all (so a refusal below is the loop's privacy)
    let o = as_other(&runuser, &exe, &["--version"]);
    assert!(o.status.success(), "{OTHER} cannot run feedloop: {o:?}");

    let params = d.join("kv.toml");
    std::fs::write(&params, "kv_nms_per_rad = 4.5\n").unwrap();
    std::fs::set_permissions(&params, std::fs::Permissions::from_mode(0o644)).unwrap();
    let swap = as_other(
        &runuser,
        &exe,
        &[
            "swap",
            "--instance",
            &instance,
            "--axis",
            "x",
            "--stage",
            "velocity",
            "--plugin",
            "pi_velocity",
            "--params",
            params.to_str().unwrap(),
            "--timeout-s",
            "3",
        ],
    );
    let said = String::from_utf8_lossy(&swap.stderr).into_owned();
    assert!(!swap.status.success(), "{OTHER} swapped: {swap:?}");
    assert!(
        said.contains("iceoryx2") || said.contains("control service"),
        "{said}"
    );
    let look = as_other(
        &runuser,
        &exe,
        &["status", "--instance", &instance, "--timeout-s", "3"],
    );
    assert!(!look.status.success(), "{OTHER} read the status: {look:?}");

    // the loop's owner sees no swap, and its shared memory is its own
    let st = status(&instance, 5.0);
    assert_eq!(st["swaps"], 0, "{st}");
    let modes = shared_memory_modes();
    assert!(
        modes.len() > 4,
        "the loop's shared memory is not in /dev/shm: {modes:?}"
    );
    let open: Vec<_> = modes.iter().filter(|(_, m)| m & 0o077 != 0).collect();
    assert!(open.is_empty(), "shared memory open to others: {open:?}");
    // the nodes' and services' descriptions are in a folder others cannot enter
    let root = std::fs::metadata("/tmp/iceoryx2")
        .unwrap()
        .permissions()
        .mode();
    assert_eq!(root & 0o007, 0, "/tmp/iceoryx2 is mode {root:o}");

    stop(&mut run);
    let sum = std::fs::read_to_string(d.join("run/summary.json")).unwrap();
    let sum: serde_json::Value = serde_json::from_str(&sum).unwrap();
    assert_eq!(sum["swaps"], serde_json::json!([]), "{sum}");
    let _ = std::fs::remove_dir_all(&d);
}
