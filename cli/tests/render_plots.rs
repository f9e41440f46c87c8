//! The plots render in a browser: headless Chromium turns the tune heat map and a Bode plot into
//! PNGs of the SVG's own size with real content. Without a browser the test says so and is
//! skipped, except on CI (`CI=true`), where it fails. `scripts/render-plots` renders every plot
//! kind for a person to look at.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

/// The browser, or `None` after saying the test `what` is skipped (on CI a missing one fails).
fn browser_or_skip(what: &str) -> Option<PathBuf> {
    let missing = format!("{}: {what}", feedloop_cli::browser::NOT_FOUND);
    feedloop_test_support::found_or_skip(feedloop_cli::browser::on_path(), missing)
}

/// The SVG's `width` and `height` attributes, px.
fn svg_size(svg: &str) -> (u32, u32) {
    let attr = |name: &str| -> u32 {
        let i = svg.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
        svg[i..i + svg[i..].find('"').unwrap()]
            .parse::<f64>()
            .unwrap()
            .round() as u32
    };
    (attr("width"), attr("height"))
}

/// Renders `svg` to `png` at its own size and returns the PNG's size (from its header) and
/// length in bytes.
fn render(browser: &Path, svg: &Path, png: &Path) -> ((u32, u32), usize) {
    let (w, h) = svg_size(&std::fs::read_to_string(svg).unwrap());
    let o = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            &format!("--screenshot={}", png.display()),
            &format!("--window-size={w},{h}"),
            &format!("file://{}", svg.display()),
        ])
        .output()
        .unwrap();
    let bytes = std::fs::read(png).unwrap_or_else(|e| {
        panic!(
            "{} wrote no PNG ({e}): {}",
            browser.display(),
            String::from_utf8_lossy(&o.stderr)
        )
    });
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG");
    let be = |i: usize| u32::from_be_bytes(bytes[i..i + 4].try_into().unwrap());
    ((be(16), be(20)), bytes.len())
}

#[test]
fn the_heat_map_and_the_bode_plot_render_to_pngs_of_their_size() {
    let Some(browser) = browser_or_skip("plots not rendered") else {
        return;
    };
    let d = std::env::temp_dir().join(format!("feedloop-render-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let run = |args: &[&str]| {
        let o = Command::new(bin()).args(args).output().unwrap();
        assert!(
            o.status.success(),
            "feedloop {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let heat = d.join("tune.svg");
    run(&[
        "tune",
        "--job",
        &s(&repo("examples/jobs/tune-ramp.toml")),
        "--grid",
        "kp_per_s=20:120:5,kv_nms_per_rad=2:10:3",
        "--svg",
        &s(&heat),
        "--json",
    ]);
    run(&[
        "sim",
        &s(&repo("examples/jobs/identify-stiffness.toml")),
        "--out",
        &s(&d.join("stiff")),
        "--quiet",
    ]);
    let bode = d.join("bode.svg");
    run(&[
        "identify",
        "stiffness",
        "--trace",
        &s(&d.join("stiff/trace.csv")),
        "--jm-kgm2",
        "2e-3",
        "--svg",
        &s(&bode),
        "--json",
    ]);
    for svg in [heat, bode] {
        let png = svg.with_extension("png");
        let (size, len) = render(&browser, &svg, &png);
        let want = svg_size(&std::fs::read_to_string(&svg).unwrap());
        println!("{}: {size:?}, {len} bytes", png.display());
        assert_eq!(size, want, "{}", png.display());
        // a white page of that size with one line of text is 3.5 kB; axes, ticks, a legend and
        // curves or cells are several times that
        assert!(len > 12_000, "{}: {len} bytes", png.display());
    }
    std::fs::remove_dir_all(&d).ok();
}
