//! `report.html`: hand-written SVG plots a servo engineer reads at a glance.
//!
//! Measurement versus model, residual over time with the worst segments shaded, residual
//! against velocity, load position and motor angle, the residual spectrum, and the windowed
//! simulation. No external libraries: every plot is a small inline SVG.

use std::fmt::Write as _;

use rustfft::{num_complex::Complex, FftPlanner};

use feedloop_model::model::AxisKind;
use feedloop_model::units::{si, sig};

use super::compare::Comparison;
use super::data::AxisData;
use crate::plot::{esc, Axis, Plot, Series, PALETTE};

/// The units of an axis's signals in the model's motor units: (motor position, motor velocity,
/// torque or force, load position).
fn units(kind: AxisKind) -> (&'static str, &'static str, &'static str, &'static str) {
    match kind {
        AxisKind::Rigid => ("m", "m/s", "N", "m"),
        AxisKind::BallScrew => ("rad", "rad/s", "N m", "m"),
        AxisKind::Rotary => ("rad", "rad/s", "N m", "rad"),
    }
}

/// The unit of a windowed-simulation channel.
fn channel_unit(name: &str, kind: AxisKind) -> &'static str {
    let (pos, vel, torque, _) = units(kind);
    match name {
        "torque" => torque,
        "velocity" => vel,
        _ => pos,
    }
}

/// A plot of the report, inline (a short note instead when it has nothing to draw).
fn figure(p: Plot) -> String {
    if p.has_data() {
        p.svg()
    } else {
        "<p>(no data to plot)</p>".into()
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

/// The channel the report's headline plots show: the torque's equation error when recorded,
/// else the windowed simulation's first channel.
struct Shown<'a> {
    residual: &'a [f64],
    measured: &'a [f64],
    model: &'a [f64],
    /// Its name on the value axis (`force`, `torque`, `velocity`, ...).
    label: String,
    unit: &'static str,
}

impl<'a> Shown<'a> {
    fn of(d: &AxisData, c: &'a Comparison) -> Self {
        let (_, _, torque_unit, _) = units(d.kind);
        match &c.eq {
            Some(e) => Shown {
                residual: &e.residual,
                measured: &e.measured,
                model: &e.model,
                label: if torque_unit == "N" {
                    "force"
                } else {
                    "torque"
                }
                .to_string(),
                unit: torque_unit,
            },
            None => {
                let name = c
                    .sim
                    .channels
                    .first()
                    .map(|x| x.name.as_str())
                    .unwrap_or("");
                Shown {
                    residual: &c.sim.residual,
                    measured: &c.sim.measured,
                    model: &c.sim.simulated,
                    label: name.replace('_', " "),
                    unit: channel_unit(name, d.kind),
                }
            }
        }
    }
}

/// A time axis.
fn time() -> Axis {
    Axis::linear("time", "s")
}

/// A value axis in SI prefixes.
fn value(label: &str, unit: &str) -> Axis {
    Axis::linear(label, unit).si()
}

/// Writes the HTML report of a comparison (and, when given, a diagnosis table and an error
/// history) as a string: the page's head, the figures, where the residual lives, then the plots
/// in the order the reader meets them.
pub fn html(d: &AxisData, c: &Comparison, title: &str, extra_html: &str) -> String {
    let mut h = String::new();
    head(&mut h, d, title);
    let shown = Shown::of(d, c);
    figures_table(&mut h, d, c);
    residual_tables(&mut h, d, c, shown.unit);
    h.push_str(extra_html);
    h.push_str("<h2>Plots</h2>");
    time_plots(&mut h, d, c, &shown);
    scatter_plots(&mut h, d, &shown);
    windowed_plot(&mut h, d, c);
    h.push_str("</body></html>\n");
    h
}

/// The page's head, title and the trace it reads.
fn head(h: &mut String, d: &AxisData, title: &str) {
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>{}</title><style>body{{font-family:sans-serif;max-width:900px;margin:auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}th{{background:#eee}}</style></head><body><h1>{}</h1>",
        esc(title),
        esc(title)
    );
    let _ = write!(h, "<p>trace <code>{}</code>, axis <b>{}</b>, {} samples at {}; positions filtered zero-phase at {} Hz before differentiation.</p>", esc(&d.path.display().to_string()), esc(&d.axis), d.len(), si(d.dt, "s"), sig(d.cutoff_hz));
}

/// The table of figures: each channel's NRMSE and residual RMS.
fn figures_table(h: &mut String, d: &AxisData, c: &Comparison) {
    let (_, _, torque_unit, _) = units(d.kind);
    h.push_str("<h2>Figures</h2><table><tr><th>channel</th><th>method</th><th>NRMSE %</th><th>residual RMS</th></tr>");
    if let Some(e) = &c.eq {
        let _ = write!(h, "<tr><td>torque</td><td>equation error (inverse dynamics)</td><td>{:.2}</td><td>{}</td></tr>", e.nrmse_pct, si(e.rms, torque_unit));
    }
    if let Some(cc) = &c.controller {
        let _ = write!(h, "<tr><td>controller</td><td>recorded torque against the controller law on the recorded signals (velocity: {}; noise floor {}{})</td><td>{:.2}</td><td>{}</td></tr>", esc(cc.velocity), si(cc.noise_rms, torque_unit), if cc.fails() { ", <b>departs</b>" } else { "" }, cc.nrmse_pct, si(cc.rms, torque_unit));
    }
    for ch in &c.sim.channels {
        let _ = write!(h, "<tr><td>{}</td><td>{} simulation, {:.0} ms windows from measured state</td><td>{:.2}</td><td>{}</td></tr>", ch.name, c.sim.mode, c.sim.window_s * 1e3, ch.window_nrmse_pct, si(ch.window_rms, channel_unit(&ch.name, d.kind)));
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{} simulation, free run</td><td>{:.2}</td><td></td></tr>",
            ch.name, c.sim.mode, ch.free_nrmse_pct
        );
    }
    h.push_str("</table>");
}

/// Where the residual lives: its share by kind of motion, then the worst segments.
fn residual_tables(h: &mut String, d: &AxisData, c: &Comparison, unit: &str) {
    h.push_str("<h2>Where the residual lives</h2><table><tr><th>motion</th><th>share of residual %</th><th>share of time %</th><th>RMS</th></tr>");
    for s in &c.by_kind {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.1}</td><td>{:.1}</td><td>{}</td></tr>",
            s.name,
            s.share_pct,
            s.time_pct,
            si(s.rms, unit)
        );
    }
    h.push_str("</table><p>Worst segments:</p><table><tr><th>kind</th><th>from s</th><th>to s</th><th>share %</th><th>RMS</th></tr>");
    for s in c.segments.iter().take(10) {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.1}</td><td>{}</td></tr>",
            s.kind.id(),
            d.t[s.start],
            d.t[s.end - 1],
            s.share_pct,
            si(s.rms, unit)
        );
    }
    h.push_str("</table>");
}

/// The plots over time: measurement against model, the controller channel where it departs,
/// and the residual with the worst segments shaded.
fn time_plots(h: &mut String, d: &AxisData, c: &Comparison, shown: &Shown<'_>) {
    let (_, _, torque_unit, _) = units(d.kind);
    let unit = shown.unit;
    if !shown.measured.is_empty() {
        let (tx, my) = envelope(&d.t, shown.measured, 1600);
        let (tx2, sy) = envelope(&d.t, shown.model, 1600);
        h.push_str(&figure(
            Plot::new("Measurement vs model", time(), value(&shown.label, unit))
                .series(Series::line("measured", PALETTE[0], &tx, &my))
                .series(Series::line("model", PALETTE[1], &tx2, &sy)),
        ));
    }
    if let Some(cc) = &c.controller {
        let ev = cc.events(d);
        let ev_shade: Vec<(f64, f64)> = ev.iter().take(200).map(|e| (e.start_s, e.end_s)).collect();
        let (tx, ry) = envelope(&d.t, &cc.residual, 1600);
        h.push_str(&figure(
            Plot::new(
                &format!(
                    "Controller channel: recorded torque minus controller law ({} stretches where it departs)",
                    ev.len()
                ),
                time(),
                value("recorded - law", torque_unit),
            )
            .series(Series::line("recorded - law", PALETTE[3], &tx, &ry))
            .shade("where it departs beyond its noise", &ev_shade),
        ));
    }
    let shade: Vec<(f64, f64)> = c
        .segments
        .iter()
        .take(10)
        .map(|s| (d.t[s.start], d.t[s.end - 1]))
        .collect();
    let (tx, ry) = envelope(&d.t, shown.residual, 1600);
    h.push_str(&figure(
        Plot::new("Residual over time", time(), value("residual", unit))
            .series(Series::line(
                "residual (measured - model)",
                "#333",
                &tx,
                &ry,
            ))
            .shade("worst 10 segments", &shade),
    ));
}

/// The residual against motor velocity, load position and motor angle, and its spectrum.
fn scatter_plots(h: &mut String, d: &AxisData, shown: &Shown<'_>) {
    let (pos_unit, vel_unit, _, load_unit) = units(d.kind);
    let (residual, unit) = (shown.residual, shown.unit);
    let rs = thin(residual, 4000);
    let v = thin(&d.vm, 4000);
    h.push_str(&figure(
        Plot::new(
            "Residual against motor velocity",
            value("motor velocity", vel_unit),
            value("residual", unit),
        )
        .series(Series::dots("residual", PALETTE[2], &v, &rs)),
    ));
    let p = thin(&d.load_raw, 4000);
    h.push_str(&figure(
        Plot::new(
            "Residual against load position",
            value("load position", load_unit),
            value("residual", unit),
        )
        .series(Series::dots("residual", PALETTE[3], &p, &rs)),
    ));
    let ang: Vec<f64> = thin(&d.qm, 4000)
        .iter()
        .map(|q| {
            if d.kind == AxisKind::Rigid {
                *q
            } else {
                q.rem_euclid(2.0 * std::f64::consts::PI)
            }
        })
        .collect();
    let (angle_title, angle_label) = if d.kind == AxisKind::Rigid {
        ("Residual against motor position", "motor position")
    } else {
        (
            "Residual against motor angle (mod one revolution)",
            "motor angle",
        )
    };
    h.push_str(&figure(
        Plot::new(
            angle_title,
            value(angle_label, pos_unit),
            value("residual", unit),
        )
        .series(Series::dots("residual", PALETTE[5], &ang, &rs)),
    ));
    let (a, b) = d.range;
    let (f, amp) = spectrum(&residual[a..b], d.dt);
    h.push_str(&figure(
        Plot::new(
            "Residual spectrum (Welch, Hann)",
            Axis::linear("frequency", "Hz"),
            Axis::log("amplitude", unit),
        )
        .series(Series::line("residual", PALETTE[4], &f, &amp)),
    ));
}

/// The windowed simulation against the measurement, when the headline plots showed the torque.
fn windowed_plot(h: &mut String, d: &AxisData, c: &Comparison) {
    if c.eq.is_none() || c.sim.measured.is_empty() {
        return;
    }
    let (tx, my) = envelope(&d.t, &c.sim.measured, 1600);
    let (tx2, sy) = envelope(&d.t, &c.sim.simulated, 1600);
    let name = c
        .sim
        .channels
        .first()
        .map(|x| x.name.clone())
        .unwrap_or_default();
    h.push_str(&figure(
        Plot::new(
            &format!(
                "Windowed simulation ({}, {:.0} ms windows): {}",
                c.sim.mode,
                c.sim.window_s * 1e3,
                name.replace('_', " ")
            ),
            time(),
            value(&name.replace('_', " "), channel_unit(&name, d.kind)),
        )
        .series(Series::line("measured", PALETTE[0], &tx, &my))
        .series(Series::line("simulated", PALETTE[1], &tx2, &sy)),
    ));
}
