//! A scratch folder for one test, removed when the test passes (kept for a look when it fails),
//! so the suite leaves nothing behind in the temp folder. Test files of other crates include
//! this file with `#[path = "../../tests/src/scratch.rs"] mod scratch;`.

use std::path::{Path, PathBuf};

/// A fresh folder in the temp folder, removed on drop unless the thread is panicking.
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
