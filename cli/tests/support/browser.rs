//! The browser the browser tests use: the first of the usual Chromium names on PATH. Included by
//! the test files with `#[path = "support/browser.rs"] mod browser;`.

use std::path::PathBuf;

/// The browser, or `None` after saying the test `what` is skipped; on CI (`CI=true`) a missing
/// browser fails the test instead.
pub fn browser_or_skip(what: &str) -> Option<PathBuf> {
    let found = std::env::var_os("PATH").and_then(|path| {
        ["chromium", "chromium-browser", "google-chrome"]
            .iter()
            .flat_map(|b| std::env::split_paths(&path).map(move |d| d.join(b)))
            .find(|p| p.is_file())
    });
    if found.is_none() {
        let msg =
            format!("no browser (chromium, chromium-browser or google-chrome) on PATH: {what}");
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("{msg}");
        }
        eprintln!("skipped: {msg}");
    }
    found
}
