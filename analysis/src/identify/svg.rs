//! Minimal SVG plots: a Bode plot with marked points, a heat map, and curves over a linear axis.

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

/// One curve of [`lines_svg`]: label, colour, points (x, y).
pub struct Series<'a> {
    /// Legend text.
    pub label: &'a str,
    /// SVG colour.
    pub color: &'a str,
    /// Points.
    pub points: &'a [(f64, f64)],
}

/// Curves over a linear x axis with vertical markers at `marks` (label, x); labels carry the
/// units.
/// Kept as one function (about 100 lines): one SVG from frame to legend (axes, ticks, zero
/// line, curves, markers, labels), each part a few lines that share the same scales.
pub fn lines_svg(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    marks: &[(&str, f64)],
) -> String {
    let (w, h) = (800.0, 480.0);
    let (x0, x1, y0, y1) = (90.0, 780.0, 40.0, 430.0);
    let all = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|p| p.0.is_finite() && p.1.is_finite());
    let (mut xlo, mut xhi, mut ylo, mut yhi) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in all {
        xlo = xlo.min(p.0);
        xhi = xhi.max(p.0);
        ylo = ylo.min(p.1);
        yhi = yhi.max(p.1);
    }
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="{w}" height="{h}" fill="white"/><text x="{x0}" y="20">{title}</text>"#
    );
    if !(xlo.is_finite() && xhi.is_finite()) {
        s.push_str("</svg>\n");
        return s;
    }
    if xhi <= xlo {
        xhi = xlo + 1.0;
    }
    if yhi <= ylo {
        yhi = ylo + 1e-12_f64.max(ylo.abs() * 1e-3);
    }
    let pad = 0.05 * (yhi - ylo);
    let (ylo, yhi) = (ylo - pad, yhi + pad);
    let lx = |x: f64| x0 + (x - xlo) / (xhi - xlo) * (x1 - x0);
    let ly = |y: f64| y1 - (y - ylo) / (yhi - ylo) * (y1 - y0);
    let _ = writeln!(
        s,
        r#"<rect x="{x0}" y="{y0}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        x1 - x0,
        y1 - y0
    );
    if ylo < 0.0 && yhi > 0.0 {
        let _ = writeln!(
            s,
            r#"<line x1="{x0}" y1="{y:.1}" x2="{x1}" y2="{y:.1}" stroke="grey" stroke-width="0.5"/>"#,
            y = ly(0.0)
        );
    }
    for (k, se) in series.iter().enumerate() {
        let mut path = String::new();
        for p in se
            .points
            .iter()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
        {
            let _ = write!(path, "{:.1},{:.1} ", lx(p.0), ly(p.1));
        }
        let _ = writeln!(
            s,
            r#"<polyline points="{path}" fill="none" stroke="{c}" stroke-width="1.2"/><text x="{:.1}" y="{:.1}" fill="{c}">{}</text>"#,
            x0 + 10.0,
            y0 + 16.0 + 15.0 * k as f64,
            se.label,
            c = se.color
        );
    }
    for (label, x) in marks {
        let px = lx(*x);
        let _ = writeln!(
            s,
            r#"<line x1="{px:.1}" y1="{y0}" x2="{px:.1}" y2="{y1}" stroke="red" stroke-dasharray="4,3"/><text x="{:.1}" y="{:.1}" fill="red">{label}</text>"#,
            px + 4.0,
            y1 - 6.0
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="5" y="{:.1}">{yhi:.3e}</text><text x="5" y="{y1}">{ylo:.3e}</text><text x="5" y="{:.1}">{y_label}</text>"#,
        y0 + 10.0,
        (y0 + y1) / 2.0
    );
    let _ = writeln!(
        s,
        r#"<text x="{x0}" y="{:.1}">{xlo:.4}</text><text x="{:.1}" y="{:.1}">{xhi:.4}</text><text x="{:.1}" y="{:.1}">{x_label}</text>"#,
        y1 + 16.0,
        x1 - 50.0,
        y1 + 16.0,
        (x0 + x1) / 2.0 - 60.0,
        y1 + 36.0
    );
    s.push_str("</svg>\n");
    s
}
