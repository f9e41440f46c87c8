//! Minimal SVG plots: a Bode plot with marked points, and a heat map.

use std::fmt::Write;

use super::frf::Frf;

/// A Bode plot (magnitude in dB and phase in degrees over log frequency) of `frf` between
/// `f_lo` and `f_hi`, with vertical markers at `marks` (label, Hz).
pub fn bode_svg(frf: &Frf, f_lo: f64, f_hi: f64, marks: &[(&str, f64)]) -> String {
    let (w, h) = (800.0, 560.0);
    let (x0, x1) = (70.0, 780.0);
    let pts: Vec<(f64, f64, f64)> = frf
        .f_hz
        .iter()
        .zip(&frf.h)
        .filter(|(f, _)| **f >= f_lo && **f <= f_hi && **f > 0.0)
        .map(|(f, h)| {
            (
                *f,
                20.0 * h.norm().max(1e-300).log10(),
                h.arg().to_degrees(),
            )
        })
        .collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    if pts.is_empty() {
        s.push_str("</svg>\n");
        return s;
    }
    let lx = |f: f64| x0 + (f.log10() - f_lo.log10()) / (f_hi.log10() - f_lo.log10()) * (x1 - x0);
    let (mlo, mhi) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
    let panels = [
        (
            "magnitude, dB",
            20.0,
            260.0,
            mlo,
            mhi.max(mlo + 1.0),
            1usize,
        ),
        ("phase, deg", 300.0, 540.0, -180.0, 180.0, 2usize),
    ];
    for (title, y0, y1, lo, hi, idx) in panels {
        let _ = writeln!(
            s,
            r#"<rect x="{x0}" y="{y0}" width="{}" height="{}" fill="none" stroke="black"/><text x="{}" y="{}">{title}</text>"#,
            x1 - x0,
            y1 - y0,
            x0 + 5.0,
            y0 + 14.0
        );
        let ly = |v: f64| y1 - (v - lo) / (hi - lo) * (y1 - y0);
        let mut path = String::new();
        for p in &pts {
            let v = if idx == 1 { p.1 } else { p.2 };
            let _ = write!(path, "{:.1},{:.1} ", lx(p.0), ly(v));
        }
        let _ = writeln!(
            s,
            r#"<polyline points="{path}" fill="none" stroke="steelblue" stroke-width="1"/>"#
        );
        let _ = writeln!(
            s,
            r#"<text x="5" y="{:.1}">{hi:.0}</text><text x="5" y="{:.1}">{lo:.0}</text>"#,
            y0 + 10.0,
            y1
        );
    }
    for (label, f) in marks {
        let x = lx(*f);
        let _ = writeln!(
            s,
            r#"<line x1="{x:.1}" y1="20" x2="{x:.1}" y2="540" stroke="red" stroke-dasharray="4,3"/><circle cx="{x:.1}" cy="30" r="4" fill="red"/><text x="{:.1}" y="34" fill="red">{label} {f:.2} Hz</text>"#,
            x + 6.0
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="{x0}" y="556">frequency, Hz ({f_lo:.1} .. {f_hi:.1}, log)</text>"#
    );
    s.push_str("</svg>\n");
    s
}

/// A heat map of `values[row][col]` (NaN = rejected, drawn grey) with axis labels.
pub fn heatmap_svg(
    title: &str,
    x_label: &str,
    x: &[f64],
    y_label: &str,
    y: &[f64],
    values: &[Vec<f64>],
) -> String {
    let (w, h) = (720.0, 560.0);
    let (x0, y0, pw, ph) = (80.0, 30.0, 600.0, 460.0);
    let finite: Vec<f64> = values
        .iter()
        .flatten()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let lo = finite.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="{w}" height="{h}" fill="white"/><text x="{x0}" y="18">{title} (log color, grey = rejected; min {lo:.3e}, max {hi:.3e})</text>"#
    );
    let nx = x.len().max(1) as f64;
    let ny = y.len().max(1) as f64;
    for (j, row) in values.iter().enumerate() {
        for (i, v) in row.iter().enumerate() {
            let color = if v.is_finite() && hi > lo {
                let t = ((v.ln() - lo.ln()) / (hi.ln() - lo.ln())).clamp(0.0, 1.0);
                format!(
                    "rgb({},{},{})",
                    (255.0 * t) as u8,
                    (80.0 + 100.0 * (1.0 - t)) as u8,
                    (255.0 * (1.0 - t)) as u8
                )
            } else if v.is_finite() {
                "rgb(0,80,255)".to_string()
            } else {
                "rgb(200,200,200)".to_string()
            };
            let _ = writeln!(
                s,
                r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{color}"><title>{v:.4e}</title></rect>"#,
                x0 + i as f64 * pw / nx,
                y0 + ph - (j + 1) as f64 * ph / ny,
                pw / nx + 0.5,
                ph / ny + 0.5
            );
        }
    }
    let fmt = |v: &[f64]| match (v.first(), v.last()) {
        (Some(a), Some(b)) => format!("{a} .. {b}"),
        _ => String::new(),
    };
    let _ = writeln!(
        s,
        r#"<text x="{x0}" y="{}">{x_label}: {}</text><text x="5" y="{}" >{y_label}: {}</text></svg>"#,
        y0 + ph + 25.0,
        fmt(x),
        y0 + ph + 45.0,
        fmt(y)
    );
    s
}
