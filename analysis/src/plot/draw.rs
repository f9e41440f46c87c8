//! The SVG pieces plots and heat maps share: the document, frame and ticks, curves, legend.

use std::fmt::Write as _;

use super::axis::Axis;
use super::series::{esc, Series, Style};

/// Room around the plot area: left (tick labels, rotated y title), right, top (title, legend),
/// bottom (tick labels, x title).
pub(super) const ML: f64 = 84.0;
pub(super) const MR: f64 = 24.0;
pub(super) const MT: f64 = 30.0;
pub(super) const MB: f64 = 46.0;
/// Height of one legend row.
pub(super) const LEGEND_ROW: f64 = 16.0;

/// The finite range of `vals`, widened by `pad` of its length at each end (a unit or a tenth of
/// the value when all are equal); `None` without a finite value.
pub(super) fn span(vals: impl Iterator<Item = f64>, pad: f64) -> Option<(f64, f64)> {
    let (lo, hi) = vals
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return None;
    }
    if hi <= lo {
        let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
        return Some((lo - d, hi + d));
    }
    let p = pad * (hi - lo);
    Some((lo - p, hi + p))
}

/// A clip-path id unique within one HTML page (several plots share its id space), and the
/// same for the same plot, so files stay byte-identical from run to run.
pub(super) fn clip_id(title: &str, ox: f64, oy: f64) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in format!("{title}|{ox}|{oy}").bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!("clip{h:016x}")
}

pub(super) fn svg_open(w: f64, h: f64) -> String {
    format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="11"><rect width="{w}" height="{h}" fill="white"/>"#
    )
}

/// Frame, grid lines (with `grid`), tick marks and labels and the two axis titles of the plot
/// area (x0, x1, y0, y1) for each axis with its transformed range (`xr`, `yr`).
pub(super) fn draw_axes(
    s: &mut String,
    grid: bool,
    (x0, x1, y0, y1): (f64, f64, f64, f64),
    (x_axis, xr): (&Axis, (f64, f64)),
    (y_axis, yr): (&Axis, (f64, f64)),
) {
    let (xt, xtitle) = x_axis.tick_marks(xr.0, xr.1);
    let (yt, ytitle) = y_axis.tick_marks(yr.0, yr.1);
    let grid_colour = if grid { "#e3e3e3" } else { "none" };
    for (v, label) in &xt {
        let x = x0 + (v - xr.0) / (xr.1 - xr.0) * (x1 - x0);
        let _ = write!(
            s,
            r##"<g class="x-tick"><line x1="{x:.1}" y1="{y0:.1}" x2="{x:.1}" y2="{y1:.1}" stroke="{grid_colour}"/><line x1="{x:.1}" y1="{y1:.1}" x2="{x:.1}" y2="{:.1}" stroke="#555"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text></g>"##,
            y1 + 4.0,
            y1 + 16.0,
            esc(label)
        );
    }
    for (v, label) in &yt {
        let y = y1 - (v - yr.0) / (yr.1 - yr.0) * (y1 - y0);
        let _ = write!(
            s,
            r##"<g class="y-tick"><line x1="{x0}" y1="{y:.1}" x2="{x1}" y2="{y:.1}" stroke="{grid_colour}"/><line x1="{:.1}" y1="{y:.1}" x2="{x0}" y2="{y:.1}" stroke="#555"/><text x="{:.1}" y="{:.1}" text-anchor="end">{}</text></g>"##,
            x0 - 4.0,
            x0 - 6.0,
            y + 4.0,
            esc(label)
        );
    }
    let _ = write!(
        s,
        r##"<rect x="{x0}" y="{y0:.1}" width="{:.1}" height="{:.1}" fill="none" stroke="#555"/>"##,
        x1 - x0,
        y1 - y0
    );
    let _ = write!(
        s,
        r#"<text class="x-label" x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
        (x0 + x1) / 2.0,
        y1 + 36.0,
        esc(&xtitle)
    );
    let (lx, ly) = (x0 - 64.0, (y0 + y1) / 2.0);
    let _ = write!(
        s,
        r#"<text class="y-label" x="{lx:.1}" y="{ly:.1}" transform="rotate(-90 {lx:.1} {ly:.1})" text-anchor="middle">{}</text>"#,
        esc(&ytitle)
    );
}

pub(super) fn draw_series(
    s: &mut String,
    se: &Series,
    px: &dyn Fn(f64) -> f64,
    py: &dyn Fn(f64) -> f64,
) {
    let pts =
        se.x.iter()
            .zip(&se.y)
            .map(|(x, y)| (px(*x), py(*y)))
            .filter(|(x, y)| x.is_finite() && y.is_finite());
    if se.style == Style::Dots {
        s.push_str(r#"<g class="series">"#);
        for (x, y) in pts {
            let _ = write!(
                s,
                r#"<circle cx="{x:.1}" cy="{y:.1}" r="1.4" fill="{}" fill-opacity="0.45"/>"#,
                se.color
            );
        }
        s.push_str("</g>");
        return;
    }
    let mut d = String::new();
    let mut pen_up = true;
    for (x, y) in se.x.iter().zip(&se.y).map(|(x, y)| (px(*x), py(*y))) {
        if !(x.is_finite() && y.is_finite()) {
            pen_up = true;
            continue;
        }
        let _ = write!(d, "{}{x:.1},{y:.1}", if pen_up { "M" } else { "L" });
        pen_up = false;
    }
    let dash = if se.style == Style::Dashed {
        r#" stroke-dasharray="6,3""#
    } else {
        ""
    };
    let _ = write!(
        s,
        r#"<path class="series" d="{d}" fill="none" stroke="{}" stroke-width="1.4"{dash}/>"#,
        se.color
    );
}

/// Width of a legend entry with text `t`, px (swatch, gap, text at about 6.2 px a character).
pub(super) fn entry_width(t: &str) -> f64 {
    30.0 + 6.2 * t.chars().count() as f64
}

/// Rows the legend entries take in `width` px.
pub(super) fn legend_rows(entries: &[(String, String, Option<Style>)], width: f64) -> usize {
    if entries.is_empty() {
        return 0;
    }
    let mut rows = 1;
    let mut x = 0.0;
    for (t, _, _) in entries {
        let w = entry_width(t);
        if x > 0.0 && x + w > width {
            rows += 1;
            x = 0.0;
        }
        x += w;
    }
    rows
}

/// The legend: a swatch and a text per entry, left to right, wrapping at `width`.
pub(super) fn draw_legend(
    s: &mut String,
    entries: &[(String, String, Option<Style>)],
    x0: f64,
    y0: f64,
    width: f64,
) {
    if entries.is_empty() {
        return;
    }
    s.push_str(r#"<g class="legend">"#);
    let (mut x, mut y) = (0.0, y0);
    for (t, c, style) in entries {
        let w = entry_width(t);
        if x > 0.0 && x + w > width {
            x = 0.0;
            y += LEGEND_ROW;
        }
        let sx = x0 + x;
        let _ = match style {
            Some(Style::Dots) => write!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{c}"/>"#,
                sx + 10.0,
                y + 6.0
            ),
            Some(st) => write!(
                s,
                r#"<line x1="{sx:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{c}" stroke-width="2"{}/>"#,
                y + 6.0,
                sx + 22.0,
                y + 6.0,
                if *st == Style::Dashed {
                    r#" stroke-dasharray="5,3""#
                } else {
                    ""
                }
            ),
            None => write!(
                s,
                r#"<rect x="{sx:.1}" y="{:.1}" width="22" height="10" fill="{c}"/>"#,
                y + 1.0
            ),
        };
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}">{}</text>"#,
            sx + 26.0,
            y + 10.0,
            esc(t)
        );
        x += w;
    }
    s.push_str("</g>");
}
