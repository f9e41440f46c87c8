//! Helpers shared by the test files of several crates (a dev-dependency, never a dependency of
//! the shipped code): a scratch folder per test, and the rule for a test that needs a program
//! the machine may lack.

use std::fmt::Display;
use std::path::{Path, PathBuf};

/// A fresh folder in the temp folder, removed on drop unless the thread is panicking: the suite
/// leaves nothing behind in the temp folder, and a failed test's folder is kept for a look.
pub struct Scratch(PathBuf);

impl Scratch {
    /// `feedloop-PREFIX-PID-NAME` in the temp folder, emptied first.
    pub fn new(prefix: &str, name: &str) -> Self {
        let d =
            std::env::temp_dir().join(format!("feedloop-{prefix}-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d)
            .unwrap_or_else(|e| panic!("creating the scratch folder {}: {e}", d.display()));
        Self(d)
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// What a test needs from the machine (e.g. a browser), or `None` after saying `missing` and
/// that the test is skipped; on CI (`CI=true`) a missing one fails the test instead.
pub fn found_or_skip<T>(found: Option<T>, missing: impl Display) -> Option<T> {
    if found.is_none() {
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("{missing}");
        }
        eprintln!("skipped: {missing}");
    }
    found
}

/// The files of `fuzz/<kind>/<target>` in the repository (`kind`: `seeds` or `regressions`),
/// sorted. Panics when the folder cannot be read: a test fed from it must not pass on nothing.
pub fn fuzz_inputs(kind: &str, target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz")
        .join(kind)
        .join(target);
    let mut out: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    out.sort();
    out
}
