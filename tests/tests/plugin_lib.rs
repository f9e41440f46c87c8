//! Third-party plugins as shared libraries: the out-of-tree example in
//! `examples/plugins/pi-velocity-c/` is built here, loaded into a running loop and swapped in and
//! out alternately with the built-in PI; a library of another ABI version and a library without the
//! plugin symbols are refused with a reason.

use std::path::Path;
use std::time::Duration;

use feedloop_tests::{
    process_lock, read_json, repo_file, scratch, signal, start_realtime_run, swap_x_velocity,
    write_long_circle_job,
};

#[test]
fn a_shared_library_plugin_swaps_in_and_out_of_a_running_loop_and_bad_libraries_are_refused() {
    let _g = process_lock();
    let dir = scratch("plugin-lib");
    let good = feedloop_tests::build_example_plugin(&dir.join("t-good"), false);
    let wrong = feedloop_tests::build_example_plugin(&dir.join("t-wrong"), true);
    let job = write_long_circle_job(&dir, "lib");
    let params = dir.join("p.toml");
    // softer than the job's 5.0: at 2 kHz the job's own loop has only 3.4 dB gain margin, and a
    // stiffer retune would be refused as marginal
    std::fs::write(&params, "kv_nms_per_rad = 4.5\n").unwrap();
    let (mut run, inst, out) = start_realtime_run(&dir, &job, "lib", Duration::from_millis(300));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let swap = |extra: &[String]| swap_x_velocity(&inst, extra);
    let lib_args = vec![
        "--plugin".to_string(),
        "pi_velocity_c".into(),
        "--lib".into(),
        s(&good),
    ];
    let builtin_args = vec![
        "--plugin".to_string(),
        "pi_velocity".into(),
        "--params".into(),
        s(&params),
    ];
    for i in 0..10 {
        let o = swap(if i % 2 == 0 { &lib_args } else { &builtin_args });
        assert!(
            o.status.success(),
            "swap {i}: {}",
            String::from_utf8_lossy(&o.stdout)
        );
    }
    // The refusals below must not disturb the loop: the plant's deadline-miss count, as the
    // status service reports it, is the same before and after.
    let before = feedloop_tests::status(&inst);
    let bad_params = dir.join("bad.toml");
    std::fs::write(
        &bad_params,
        "kv_nms_per_rad = -5.5
",
    )
    .unwrap();
    let o = swap(&[
        "--plugin".into(),
        "pi_velocity".into(),
        "--params".into(),
        s(&bad_params),
    ]);
    assert!(!o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("kv_nms_per_rad"), "{text}");
    let o = swap(&[
        "--plugin".into(),
        "pi_velocity_c".into(),
        "--lib".into(),
        s(&wrong),
    ]);
    assert!(!o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("ABI version 999"), "{text}");
    let libm = [
        "/lib/x86_64-linux-gnu/libm.so.6",
        "/usr/lib/x86_64-linux-gnu/libm.so.6",
        "/lib64/libm.so.6",
    ]
    .into_iter()
    .find(|p| Path::new(p).exists());
    if let Some(libm) = libm {
        let o = swap(&["--plugin".into(), "x".into(), "--lib".into(), libm.into()]);
        assert!(!o.status.success());
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(
            text.contains("lacks the symbol `feedloop_plugin_abi_version`"),
            "{text}"
        );
    }
    let after = feedloop_tests::status(&inst);
    assert!(after["cycle"].as_u64() > before["cycle"].as_u64());
    // Deadline misses are not compared: on a busy host they come from the host, not the
    // requests. What a refused request could disturb is the loop's state: its stages and swaps.
    for key in ["swaps", "nonfinite_faults"] {
        assert_eq!(
            after[key], before[key],
            "refused requests changed `{key}`: {before} -> {after}"
        );
    }
    for (a, b) in after["axes"]
        .as_array()
        .unwrap()
        .iter()
        .zip(before["axes"].as_array().unwrap())
    {
        assert_eq!(
            a["stages"], b["stages"],
            "refused requests changed the stages"
        );
    }
    assert_eq!(
        after["rejected_requests"].as_u64().unwrap(),
        before["rejected_requests"].as_u64().unwrap() + if libm.is_some() { 3 } else { 2 }
    );
    signal(run.id(), "TERM");
    assert!(run.wait().unwrap().success());
    let sum = read_json(&out.join("summary.json"));
    let swaps = sum["swaps"].as_array().unwrap();
    assert_eq!(swaps.len(), 10, "{sum}");
    for (i, w) in swaps.iter().enumerate() {
        assert_eq!(w["rolled_back"], false, "swap {i}: {w}");
        let (step, allowed) = (
            w["torque_step"].as_f64().unwrap(),
            w["allowed_step"].as_f64().unwrap(),
        );
        assert!(step <= allowed, "swap {i}: {step} > {allowed}: {w}");
        assert_eq!(
            w["to"],
            if i % 2 == 0 {
                "pi_velocity_c"
            } else {
                "pi_velocity"
            }
        );
    }
}

#[test]
fn the_example_plugin_depends_on_feedloop_control_alone_and_not_on_the_ipc_stack() {
    // `cargo tree` resolves the example's dependency graph from its own manifest and lock file
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let o = std::process::Command::new(cargo)
        .current_dir(repo_file("examples/plugins/pi-velocity-c"))
        .args(["tree", "--edges", "normal", "--prefix", "none"])
        .output()
        .expect("running cargo tree");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let tree = String::from_utf8_lossy(&o.stdout);
    assert!(tree.contains("feedloop-control"), "{tree}");
    for absent in ["iceoryx2", "libloading", "feedloop-runtime", "rtrb"] {
        assert!(
            !tree.contains(absent),
            "{absent} in the plugin's tree:\n{tree}"
        );
    }
}

/// The example plugin is built with `--offline` by these tests: every crate its lock file names
/// must be one the workspace's lock file already pins, or a fresh machine that fetched only the
/// workspace's crates cannot build it.
#[test]
fn the_example_plugin_locks_only_crate_versions_the_workspace_locks() {
    fn packages(path: &Path) -> Vec<(String, String)> {
        let text = std::fs::read_to_string(path).expect("reading a Cargo.lock");
        let lock: toml::Table = text.parse().expect("a Cargo.lock is TOML");
        let list = lock["package"].as_array().expect("[[package]] entries");
        list.iter()
            .filter(|p| p.get("source").is_some())
            .map(|p| {
                let name = p["name"].as_str().expect("name").to_string();
                (name, p["version"].as_str().expect("version").to_string())
            })
            .collect()
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let workspace = packages(&root.join("Cargo.lock"));
    let plugin = packages(&root.join("examples/plugins/pi-velocity-c/Cargo.lock"));
    assert!(
        !plugin.is_empty(),
        "the plugin's lock names no registry crate"
    );
    let foreign: Vec<_> = plugin.iter().filter(|p| !workspace.contains(p)).collect();
    assert!(
        foreign.is_empty(),
        "the example plugin locks versions the workspace does not: {foreign:?}; \
         copy the workspace's Cargo.lock into examples/plugins/pi-velocity-c/"
    );
}

/// The fuzz campaign builds `fuzz/` with `--locked`: its lock file must still resolve after the
/// workspace's dependencies change (a crate added to the cli reaches the fuzz targets too). Not
/// `--offline`: on a fresh machine the fuzz crates (afl) are not yet in the local registry
/// cache, and an offline resolution fails for that alone.
#[test]
fn the_fuzz_crates_lock_file_is_up_to_date_with_the_workspace() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let o = std::process::Command::new(cargo)
        .args(["metadata", "--locked", "--format-version", "1"])
        .arg("--manifest-path")
        .arg(root.join("fuzz/Cargo.toml"))
        .output()
        .expect("running cargo metadata");
    assert!(
        o.status.success(),
        "fuzz/Cargo.lock is out of date: run `cargo metadata` in fuzz/ and commit it: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}
