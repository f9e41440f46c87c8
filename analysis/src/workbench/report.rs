//! `report.html`: hand-written SVG plots a servo engineer reads at a glance.
//!
//! Measurement versus model, residual over time with the worst segments shaded, residual
//! against velocity, load position and motor angle, the residual spectrum, and the windowed
//! simulation. No external libraries: every plot is a small inline SVG.

use std::fmt::Write as _;

use rustfft::{num_complex::Complex, FftPlanner};

use super::compare::Comparison;
use super::data::AxisData;

const W: f64 = 860.0;
const H: f64 = 260.0;
const ML: f64 = 70.0;
const MR: f64 = 20.0;
const MT: f64 = 28.0;
const MB: f64 = 40.0;

/// A series of a plot.
pub struct Series<'a> {
    /// Legend text.
    pub name: &'a str,
    /// Colour (CSS).
    pub color: &'a str,
    /// x values.
    pub x: &'a [f64],
    /// y values.
    pub y: &'a [f64],
    /// Draw as dots instead of a line.
    pub dots: bool,
}

impl<'a> Series<'a> {
    /// `y` over `x` drawn as a line.
    pub fn line(name: &'a str, color: &'a str, x: &'a [f64], y: &'a [f64]) -> Self {
        Self {
            name,
            color,
            x,
            y,
            dots: false,
        }
    }

    /// `y` over `x` drawn as dots.
    pub fn dots(name: &'a str, color: &'a str, x: &'a [f64], y: &'a [f64]) -> Self {
        Self {
            dots: true,
            ..Self::line(name, color, x, y)
        }
    }
}

fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return vec![lo];
    }
    let raw = (hi - lo) / n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let mut t = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while t <= hi + 1e-9 * step {
        out.push(if t.abs() < 1e-12 * step { 0.0 } else { t });
        t += step;
    }
    out
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// Draws an SVG plot; `shade` are x intervals to shade; `logy` plots log10 of y.
/// Kept as one function (about 160 lines): one SVG from frame to legend (axes, ticks, shading,
/// lines, labels), each part a few lines that share the same scales.
pub fn plot(
    title: &str,
    xlabel: &str,
    ylabel: &str,
    series: &[Series<'_>],
    shade: &[(f64, f64)],
    logy: bool,
) -> String {
    let tf = |v: f64| if logy { v.max(1e-300).log10() } else { v };
    let mut xlo = f64::INFINITY;
    let mut xhi = f64::NEG_INFINITY;
    let mut ylo = f64::INFINITY;
    let mut yhi = f64::NEG_INFINITY;
    for s in series {
        for (&x, &y) in s.x.iter().zip(s.y) {
            let y = tf(y);
            if x.is_finite() && y.is_finite() {
                xlo = xlo.min(x);
                xhi = xhi.max(x);
                ylo = ylo.min(y);
                yhi = yhi.max(y);
            }
        }
    }
    if !xlo.is_finite() {
        return format!("<p>{}: no data</p>", esc(title));
    }
    if xhi <= xlo {
        xhi = xlo + 1.0;
    }
    if yhi <= ylo {
        yhi = ylo + 1.0;
        ylo -= 1.0;
    }
    let pad = 0.05 * (yhi - ylo);
    ylo -= pad;
    yhi += pad;
    let px = |x: f64| ML + (x - xlo) / (xhi - xlo) * (W - ML - MR);
    let py = |y: f64| MT + (1.0 - (y - ylo) / (yhi - ylo)) * (H - MT - MB);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="11">"#
    );
    let _ = write!(
        s,
        r#"<rect x="0" y="0" width="{W}" height="{H}" fill="white"/>"#
    );
    for &(a, b) in shade {
        let (x0, x1) = (px(a.max(xlo)), px(b.min(xhi)));
        let _ = write!(
            s,
            r##"<rect x="{x0:.1}" y="{MT}" width="{:.1}" height="{:.1}" fill="#f4b6b6" opacity="0.6"/>"##,
            (x1 - x0).max(1.0),
            H - MT - MB
        );
    }
    for t in nice_ticks(xlo, xhi, 8) {
        let x = px(t);
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" y1="{MT}" x2="{x:.1}" y2="{:.1}" stroke="#e3e3e3"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"##,
            H - MB,
            H - MB + 14.0,
            fmt_tick(t)
        );
    }
    for t in nice_ticks(ylo, yhi, 5) {
        let y = py(t);
        let label = if logy {
            format!("1e{}", t)
        } else {
            fmt_tick(t)
        };
        let _ = write!(
            s,
            r##"<line x1="{ML}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#e3e3e3"/><text x="{:.1}" y="{:.1}" text-anchor="end">{label}</text>"##,
            W - MR,
            ML - 4.0,
            y + 4.0
        );
    }
    let _ = write!(
        s,
        r##"<rect x="{ML}" y="{MT}" width="{:.1}" height="{:.1}" fill="none" stroke="#888"/>"##,
        W - ML - MR,
        H - MT - MB
    );
    let _ = write!(
        s,
        r#"<text x="{ML}" y="16" font-weight="bold" font-size="13">{}</text>"#,
        esc(title)
    );
    let _ = write!(
        s,
        r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
        (W + ML) / 2.0,
        H - 6.0,
        esc(xlabel)
    );
    let _ = write!(
        s,
        r#"<text x="14" y="{:.1}" transform="rotate(-90 14 {:.1})" text-anchor="middle">{}</text>"#,
        (H - MB + MT) / 2.0,
        (H - MB + MT) / 2.0,
        esc(ylabel)
    );
    let mut lx = W - MR - 10.0;
    for se in series.iter().rev() {
        let w = 8.0 + 6.5 * se.name.len() as f64;
        lx -= w + 18.0;
        let _ = write!(
            s,
            r#"<rect x="{lx:.1}" y="8" width="12" height="4" fill="{}"/><text x="{:.1}" y="14">{}</text>"#,
            se.color,
            lx + 16.0,
            esc(se.name)
        );
    }
    for se in series {
        if se.dots {
            for (&x, &y) in se.x.iter().zip(se.y) {
                let y = tf(y);
                if x.is_finite() && y.is_finite() {
                    let _ = write!(
                        s,
                        r#"<circle cx="{:.1}" cy="{:.1}" r="1.2" fill="{}" fill-opacity="0.35"/>"#,
                        px(x),
                        py(y),
                        se.color
                    );
                }
            }
        } else {
            let mut path = String::new();
            for (i, (&x, &y)) in se.x.iter().zip(se.y).enumerate() {
                let y = tf(y);
                if !(x.is_finite() && y.is_finite()) {
                    continue;
                }
                let _ = write!(
                    path,
                    "{}{:.1},{:.1}",
                    if i == 0 { "M" } else { "L" },
                    px(x),
                    py(y)
                );
            }
            let _ = write!(
                s,
                r#"<path d="{path}" fill="none" stroke="{}" stroke-width="1"/>"#,
                se.color
            );
        }
    }
    s.push_str("</svg>");
    s
}

fn fmt_tick(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.1e}")
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// Min/max envelope decimation of `y` over `x` to about `m` points (keeps spikes visible).
pub fn envelope(x: &[f64], y: &[f64], m: usize) -> (Vec<f64>, Vec<f64>) {
    let n = x.len().min(y.len());
    if n <= m {
        return (x[..n].to_vec(), y[..n].to_vec());
    }
    let b = (n * 2).div_ceil(m);
    let mut xo = Vec::with_capacity(m + 2);
    let mut yo = Vec::with_capacity(m + 2);
    let mut i = 0;
    while i < n {
        let j = (i + b).min(n);
        let (mut imin, mut imax) = (i, i);
        for k in i..j {
            if y[k] < y[imin] {
                imin = k;
            }
            if y[k] > y[imax] {
                imax = k;
            }
        }
        let (a, c) = if imin < imax {
            (imin, imax)
        } else {
            (imax, imin)
        };
        xo.push(x[a]);
        yo.push(y[a]);
        xo.push(x[c]);
        yo.push(y[c]);
        i = j;
    }
    (xo, yo)
}

/// Every `step`-th sample (for scatter plots).
fn thin(x: &[f64], m: usize) -> Vec<f64> {
    let step = (x.len() / m).max(1);
    x.iter().step_by(step).copied().collect()
}

/// Averaged amplitude spectrum (Welch, Hann window, 50 % overlap) of `x`: (Hz, amplitude).
pub fn spectrum(x: &[f64], dt: f64) -> (Vec<f64>, Vec<f64>) {
    let nfft = 4096.min(x.len().next_power_of_two() / 2).max(16);
    let mut planner = FftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(nfft);
    let win: Vec<f64> = (0..nfft)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / nfft as f64).cos())
        .collect();
    let mut acc = vec![0.0; nfft / 2];
    let mut count = 0;
    let mut start = 0;
    let mut buf = vec![Complex::new(0.0, 0.0); nfft];
    while start + nfft <= x.len() && count < 400 {
        for i in 0..nfft {
            buf[i] = Complex::new(x[start + i] * win[i], 0.0);
        }
        fft.process(&mut buf);
        for i in 0..nfft / 2 {
            acc[i] += buf[i].norm_sqr();
        }
        count += 1;
        start += nfft / 2;
    }
    let norm = 2.0 / win.iter().sum::<f64>();
    let f: Vec<f64> = (1..nfft / 2)
        .map(|i| i as f64 / (nfft as f64 * dt))
        .collect();
    let a: Vec<f64> = (1..nfft / 2)
        .map(|i| (acc[i] / count.max(1) as f64).sqrt() * norm)
        .collect();
    (f, a)
}

/// Writes the HTML report of a comparison (and, when given, a diagnosis table and an error
/// history) as a string.
/// Kept as one function (about 160 lines): the report page from top to bottom, each section a
/// figure and its plot in the order the reader meets them.
pub fn html(d: &AxisData, c: &Comparison, title: &str, extra_html: &str) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>{}</title><style>body{{font-family:sans-serif;max-width:900px;margin:auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}th{{background:#eee}}</style></head><body><h1>{}</h1>",
        esc(title),
        esc(title)
    );
    let _ = write!(h, "<p>trace <code>{}</code>, axis <b>{}</b>, {} samples at {} s; positions filtered zero-phase at {:.0} Hz before differentiation.</p>", esc(&d.path.display().to_string()), esc(&d.axis), d.len(), d.dt, d.cutoff_hz);
    h.push_str("<h2>Figures</h2><table><tr><th>channel</th><th>method</th><th>NRMSE %</th><th>residual RMS</th></tr>");
    if let Some(e) = &c.eq {
        let _ = write!(h, "<tr><td>torque</td><td>equation error (inverse dynamics)</td><td>{:.2}</td><td>{:.4}</td></tr>", e.nrmse_pct, e.rms);
    }
    if let Some(cc) = &c.controller {
        let _ = write!(h, "<tr><td>controller</td><td>recorded torque against the controller law on the recorded signals (velocity: {}; noise floor {:.3e}{})</td><td>{:.2}</td><td>{:.4e}</td></tr>", esc(cc.velocity), cc.noise_rms, if cc.fails() { ", <b>departs</b>" } else { "" }, cc.nrmse_pct, cc.rms);
    }
    for ch in &c.sim.channels {
        let _ = write!(h, "<tr><td>{}</td><td>{} simulation, {:.0} ms windows from measured state</td><td>{:.2}</td><td>{:.4e}</td></tr>", ch.name, c.sim.mode, c.sim.window_s * 1e3, ch.window_nrmse_pct, ch.window_rms);
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{} simulation, free run</td><td>{:.2}</td><td></td></tr>",
            ch.name, c.sim.mode, ch.free_nrmse_pct
        );
    }
    h.push_str("</table>");
    h.push_str("<h2>Where the residual lives</h2><table><tr><th>motion</th><th>share of residual %</th><th>share of time %</th><th>RMS</th></tr>");
    for s in &c.by_kind {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.1}</td><td>{:.1}</td><td>{:.4}</td></tr>",
            s.name, s.share_pct, s.time_pct, s.rms
        );
    }
    h.push_str("</table><p>Worst segments:</p><table><tr><th>kind</th><th>from s</th><th>to s</th><th>share %</th><th>RMS</th></tr>");
    for s in c.segments.iter().take(10) {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.1}</td><td>{:.4}</td></tr>",
            s.kind.id(),
            d.t[s.start],
            d.t[s.end - 1],
            s.share_pct,
            s.rms
        );
    }
    h.push_str("</table>");
    h.push_str(extra_html);
    let (residual, meas, model, ylabel) = match &c.eq {
        Some(e) => (&e.residual, &e.measured, &e.model, "torque (N m or N)"),
        None => (
            &c.sim.residual,
            &c.sim.measured,
            &c.sim.simulated,
            c.sim
                .channels
                .first()
                .map(|x| x.name.as_str())
                .unwrap_or(""),
        ),
    };
    h.push_str("<h2>Plots</h2>");
    if !meas.is_empty() {
        let (tx, my) = envelope(&d.t, meas, 1600);
        let (tx2, sy) = envelope(&d.t, model, 1600);
        h.push_str(&plot(
            "Measurement vs model",
            "time (s)",
            ylabel,
            &[
                Series::line("measured", "#1f77b4", &tx, &my),
                Series::line("model", "#d62728", &tx2, &sy),
            ],
            &[],
            false,
        ));
    }
    if let Some(cc) = &c.controller {
        let ev = cc.events(d);
        let ev_shade: Vec<(f64, f64)> = ev.iter().take(200).map(|e| (e.start_s, e.end_s)).collect();
        let (tx, ry) = envelope(&d.t, &cc.residual, 1600);
        h.push_str(&plot(
            &format!(
                "Controller channel: recorded torque minus controller law ({} stretches where it departs, shaded)",
                ev.len()
            ),
            "time (s)",
            "recorded - law (N m or N)",
            &[Series::line("recorded - law", "#9467bd", &tx, &ry)],
            &ev_shade,
            false,
        ));
    }
    let shade: Vec<(f64, f64)> = c
        .segments
        .iter()
        .take(10)
        .map(|s| (d.t[s.start], d.t[s.end - 1]))
        .collect();
    let (tx, ry) = envelope(&d.t, residual, 1600);
    h.push_str(&plot(
        "Residual over time (worst 10 segments shaded)",
        "time (s)",
        "residual",
        &[Series::line("residual", "#333", &tx, &ry)],
        &shade,
        false,
    ));
    let rs = thin(residual, 4000);
    let v = thin(&d.vm, 4000);
    h.push_str(&plot(
        "Residual against motor velocity",
        "motor velocity (motor units/s)",
        "residual",
        &[Series::dots("residual", "#2ca02c", &v, &rs)],
        &[],
        false,
    ));
    let p = thin(&d.load_raw, 4000);
    h.push_str(&plot(
        "Residual against load position",
        "load position (m or rad)",
        "residual",
        &[Series::dots("residual", "#9467bd", &p, &rs)],
        &[],
        false,
    ));
    let ang: Vec<f64> = thin(&d.qm, 4000)
        .iter()
        .map(|q| {
            if d.kind == feedloop_model::model::AxisKind::Rigid {
                *q
            } else {
                q.rem_euclid(2.0 * std::f64::consts::PI)
            }
        })
        .collect();
    h.push_str(&plot(
        "Residual against motor angle (mod one revolution; position for a linear motor)",
        "motor angle (rad) / position (m)",
        "residual",
        &[Series::dots("residual", "#8c564b", &ang, &rs)],
        &[],
        false,
    ));
    let (a, b) = d.range;
    let (f, amp) = spectrum(&residual[a..b], d.dt);
    h.push_str(&plot(
        "Residual spectrum (Welch, Hann)",
        "frequency (Hz)",
        "amplitude (log10)",
        &[Series::line("residual", "#ff7f0e", &f, &amp)],
        &[],
        true,
    ));
    if c.eq.is_some() && !c.sim.measured.is_empty() {
        let (tx, my) = envelope(&d.t, &c.sim.measured, 1600);
        let (tx2, sy) = envelope(&d.t, &c.sim.simulated, 1600);
        let name = c
            .sim
            .channels
            .first()
            .map(|x| x.name.clone())
            .unwrap_or_default();
        h.push_str(&plot(
            &format!(
                "Windowed simulation ({}, {:.0} ms windows): {name}",
                c.sim.mode,
                c.sim.window_s * 1e3
            ),
            "time (s)",
            &name,
            &[
                Series::line("measured", "#1f77b4", &tx, &my),
                Series::line("simulated", "#d62728", &tx2, &sy),
            ],
            &[],
            false,
        ));
    }
    h.push_str("</body></html>\n");
    h
}
