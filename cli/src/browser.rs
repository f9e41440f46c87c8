//! The browser that draws a page headless (`bench scope`, and the tests that render in one):
//! the first of the usual Chromium names on PATH.

use std::path::PathBuf;

/// What is said when [`on_path`] finds none.
pub const NOT_FOUND: &str = "no browser on PATH (chromium, chromium-browser or google-chrome)";

/// The first of `chromium`, `chromium-browser` and `google-chrome` on PATH.
pub fn on_path() -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .flat_map(|b| std::env::split_paths(&path).map(move |d| d.join(b)))
        .find(|p| p.is_file())
}

/// The flags every headless run of it takes here: no sandbox, GPU, QUIC, first-run page or
/// background traffic, a 1400 x 1000 window, and a DevTools port chosen by the browser.
pub const HEADLESS_FLAGS: [&str; 10] = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1400,1000",
    "--remote-debugging-port=0",
];
