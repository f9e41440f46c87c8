//! The one SVG plotting module every feedloop plot is drawn with: the tune heat map, the Bode
//! plot of `identify stiffness`, the deviation plot of `identify inertia`, `latency.svg` and the
//! plots of the workbench reports.
//!
//! A [`Plot`] is a title, two [`Axis`] (label and unit, linear or log, ticks at 1-2-5 steps or
//! given ones), curves ([`Series`]: lines, dashed lines or dots), reference lines ([`Mark`]) and
//! shaded x intervals, with a legend naming every curve and reference line. [`stacked`] puts
//! panels over one another under one title (the Bode plot's magnitude and phase); [`HeatMap`]
//! draws a grid of values with a colour scale and an optional marked cell.
//!
//! Parts carry a `class` (`title`, `x-label`, `y-label`, `x-tick`, `y-tick`, `legend`,
//! `series`, `ref-line`, `colour-scale`, `marker`) so tests can check that a plot has them. No external
//! libraries; plain SVG 1.1 that browsers and converters render alike.

use std::fmt::Write as _;

use feedloop_model::units::{prefix_for, sig};

/// Units an axis may print with an SI prefix that fits its values (`Axis::si`).
const PREFIXABLE: [&str; 9] = ["m", "s", "rad", "N", "N m", "m/s", "rad/s", "A", "V"];

/// Colours for curves, in order (the usual ten-colour palette).
pub const PALETTE: [&str; 6] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b",
];

/// Escapes text for SVG/HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// One axis: what it shows, in which unit, on which scale.
#[derive(Debug, Clone)]
pub struct Axis {
    label: String,
    unit: String,
    log: bool,
    si: bool,
    ticks: Option<Vec<(f64, String)>>,
    range: Option<(f64, f64)>,
}

impl Axis {
    /// A linear axis; `unit` is printed after the label, e.g. `time (s)`.
    pub fn linear(label: &str, unit: &str) -> Self {
        Self {
            label: label.into(),
            unit: unit.into(),
            log: false,
            si: false,
            ticks: None,
            range: None,
        }
    }

    /// A log10 axis (values <= 0 are left out).
    pub fn log(label: &str, unit: &str) -> Self {
        Self {
            log: true,
            ..Self::linear(label, unit)
        }
    }

    /// Values are SI and the axis prints them with the prefix that fits (`deviation (um)` with
    /// ticks 0, 2, 4 for values up to 4e-6 m); only for units that take one (m, s, rad, N, ...).
    pub fn si(mut self) -> Self {
        self.si = PREFIXABLE.contains(&self.unit.as_str());
        self
    }

    /// Ticks at these values with these labels instead of the automatic ones.
    pub fn ticks(mut self, ticks: Vec<(f64, String)>) -> Self {
        self.ticks = Some(ticks);
        self
    }

    /// A fixed range instead of the data's.
    pub fn range(mut self, lo: f64, hi: f64) -> Self {
        self.range = Some((lo, hi));
        self
    }

    fn tf(&self, v: f64) -> f64 {
        if self.log {
            if v > 0.0 {
                v.log10()
            } else {
                f64::NAN
            }
        } else {
            v
        }
    }

    /// The axis title with its (possibly prefixed) unit, and the factor tick values are
    /// multiplied by; `max_abs` is the largest magnitude shown.
    fn title(&self, max_abs: f64) -> (String, f64) {
        let (scale, unit) = if self.si {
            prefix_for(max_abs, &self.unit)
        } else {
            (1.0, self.unit.clone())
        };
        let scale_note = if self.log { ", log scale" } else { "" };
        let text = match (unit.is_empty(), scale_note.is_empty()) {
            (true, true) => self.label.clone(),
            (true, false) => format!("{} (log scale)", self.label),
            _ => format!("{} ({unit}{scale_note})", self.label),
        };
        (text, scale)
    }

    /// Ticks (position in transformed units, label) for the transformed range `lo..hi`.
    fn tick_marks(&self, lo: f64, hi: f64) -> (Vec<(f64, String)>, String) {
        if let Some(t) = &self.ticks {
            let marks = t
                .iter()
                .map(|(v, l)| (self.tf(*v), l.clone()))
                .filter(|(v, _)| *v >= lo - 1e-9 && *v <= hi + 1e-9)
                .collect();
            return (marks, self.title(1.0).0);
        }
        if self.log {
            let ticks = log_ticks(10f64.powf(lo), 10f64.powf(hi));
            let max = ticks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let (title, scale) = self.title(max);
            let marks = ticks
                .iter()
                .map(|v| (v.log10(), log_label(v * scale)))
                .collect();
            return (marks, title);
        }
        let ticks = nice_ticks(lo, hi, 6);
        let step = if ticks.len() > 1 {
            ticks[1] - ticks[0]
        } else {
            1.0
        };
        let max = ticks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let (title, scale) = self.title(max);
        let marks = ticks
            .iter()
            .map(|v| (*v, tick_label(v * scale, step * scale)))
            .collect();
        (marks, title)
    }
}

/// Ticks at 1-2-5 steps inside `lo..hi`, about `n` of them and never fewer than three when the
/// range is not empty.
pub fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(hi > lo && lo.is_finite() && hi.is_finite()) {
        return vec![lo];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let steps: Vec<f64> = [0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .collect();
    // the first 1-2-5 step at least `raw`, or a finer one where that leaves fewer than three
    let first = steps
        .iter()
        .position(|s| *s >= raw)
        .unwrap_or(steps.len() - 1);
    let mut out = Vec::new();
    for &step in steps[..=first].iter().rev() {
        out.clear();
        let mut k = (lo / step).ceil();
        while k * step <= hi + 1e-9 * step {
            let t = k * step;
            out.push(if t.abs() < 1e-9 * step { 0.0 } else { t });
            k += 1.0;
        }
        if out.len() >= 3 {
            break;
        }
    }
    out
}

/// Ticks of a log axis over `lo..hi` (both > 0): decades, with 2 and 5 between them when that
/// gives too few, every integer multiple when still fewer than three, and 1-2-5 steps within
/// a span shorter than that.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return vec![];
    }
    let (d0, d1) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    if d1 - d0 > 8 {
        // many decades: every second, third, ... decade, about eight ticks
        let every = (d1 - d0 + 7) / 8;
        return (d0..=d1)
            .filter(|d| d.rem_euclid(every) == 0)
            .map(|d| 10f64.powi(d))
            .filter(|v| *v >= lo * (1.0 - 1e-9) && *v <= hi * (1.0 + 1e-9))
            .collect();
    }
    for mult in [
        &[1.0][..],
        &[1.0, 2.0, 5.0],
        &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0],
    ] {
        let t: Vec<f64> = (d0..=d1)
            .flat_map(|d| mult.iter().map(move |m| m * 10f64.powi(d)))
            .filter(|v| *v >= lo * (1.0 - 1e-9) && *v <= hi * (1.0 + 1e-9))
            .collect();
        if t.len() >= 3 {
            return t;
        }
    }
    // less than a decade: linear steps
    nice_ticks(lo, hi, 4)
}

/// A tick label on a log axis: plain digits from 1e-3 up to 1e6 (`10000`, not `1e4`),
/// exponent form outside.
fn log_label(v: f64) -> String {
    if (1e4..1e6).contains(&v.abs()) {
        format!("{}", v.round())
    } else {
        sig(v)
    }
}

/// A tick label for `v` on a grid of `step`: as many decimals as the step needs.
fn tick_label(v: f64, step: f64) -> String {
    let a = v.abs().max(step.abs());
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        return sig(v);
    }
    let decimals = (-(step.abs().log10().floor()) as i32).clamp(0, 6) as usize;
    let s = format!("{v:.decimals$}");
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        "0".into()
    } else {
        s
    }
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Style {
    /// A solid line.
    Line,
    /// A dashed line (reference curves).
    Dashed,
    /// Dots (scatter plots).
    Dots,
}

/// One curve: legend text, colour, points.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// CSS colour.
    pub color: String,
    /// x values.
    pub x: Vec<f64>,
    /// y values.
    pub y: Vec<f64>,
    /// How it is drawn.
    pub style: Style,
}

impl Series {
    /// `y` over `x` as a solid line.
    pub fn line(label: &str, color: &str, x: &[f64], y: &[f64]) -> Self {
        Self {
            label: label.into(),
            color: color.into(),
            x: x.to_vec(),
            y: y.to_vec(),
            style: Style::Line,
        }
    }

    /// `y` over `x` as a dashed line.
    pub fn dashed(label: &str, color: &str, x: &[f64], y: &[f64]) -> Self {
        Self {
            style: Style::Dashed,
            ..Self::line(label, color, x, y)
        }
    }

    /// `y` over `x` as dots.
    pub fn dots(label: &str, color: &str, x: &[f64], y: &[f64]) -> Self {
        Self {
            style: Style::Dots,
            ..Self::line(label, color, x, y)
        }
    }

    /// Points given as (x, y) pairs, as a solid line.
    pub fn points(label: &str, color: &str, p: &[(f64, f64)]) -> Self {
        let (x, y): (Vec<f64>, Vec<f64>) = p.iter().copied().unzip();
        Self::line(label, color, &x, &y)
    }
}

/// A reference line across the plot at one value, named in the legend.
#[derive(Debug, Clone)]
pub struct Mark {
    /// Legend text (with the value, as the caller wants it read).
    pub label: String,
    /// Where (data units of its axis).
    pub value: f64,
    /// CSS colour.
    pub color: String,
}

impl Mark {
    /// A reference line at `value` (an empty label leaves it out of the legend, e.g. when
    /// another panel names it).
    pub fn new(label: &str, value: f64, color: &str) -> Self {
        Self {
            label: label.into(),
            value,
            color: color.into(),
        }
    }
}

/// A plot: title, axes, curves, reference lines, shaded x intervals.
#[derive(Debug, Clone)]
pub struct Plot {
    title: String,
    x: Axis,
    y: Axis,
    series: Vec<Series>,
    vlines: Vec<Mark>,
    hlines: Vec<Mark>,
    shade: Vec<(f64, f64)>,
    shade_label: String,
    width: f64,
    height: f64,
}

/// Room around the plot area: left (tick labels, rotated y title), right, top (title, legend),
/// bottom (tick labels, x title).
const ML: f64 = 84.0;
const MR: f64 = 24.0;
const MT: f64 = 30.0;
const MB: f64 = 46.0;
/// Height of one legend row.
const LEGEND_ROW: f64 = 16.0;

impl Plot {
    /// An empty plot of 860 x 300 px.
    pub fn new(title: &str, x: Axis, y: Axis) -> Self {
        Self {
            title: title.into(),
            x,
            y,
            series: vec![],
            vlines: vec![],
            hlines: vec![],
            shade: vec![],
            shade_label: String::new(),
            width: 860.0,
            height: 300.0,
        }
    }

    /// Size in px.
    pub fn size(mut self, width: f64, height: f64) -> Self {
        self.width = width;
        self.height = height;
        self
    }

    /// Adds a curve.
    pub fn series(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }

    /// Adds a vertical reference line at an x value.
    pub fn vline(mut self, m: Mark) -> Self {
        self.vlines.push(m);
        self
    }

    /// Adds a horizontal reference line at a y value.
    pub fn hline(mut self, m: Mark) -> Self {
        self.hlines.push(m);
        self
    }

    /// Shades x intervals, named `label` in the legend.
    pub fn shade(mut self, label: &str, intervals: &[(f64, f64)]) -> Self {
        self.shade = intervals.to_vec();
        self.shade_label = label.into();
        self
    }

    /// Whether any curve has a finite point to draw.
    pub fn has_data(&self) -> bool {
        self.series.iter().any(|s| {
            s.x.iter()
                .zip(&s.y)
                .any(|(x, y)| self.x.tf(*x).is_finite() && self.y.tf(*y).is_finite())
        })
    }

    /// The legend entries: (text, colour, style; `None` = a shaded box).
    fn legend_entries(&self) -> Vec<(String, String, Option<Style>)> {
        let mut e: Vec<_> = self
            .series
            .iter()
            .map(|s| (s.label.clone(), s.color.clone(), Some(s.style)))
            .collect();
        for m in self.vlines.iter().chain(&self.hlines) {
            if !m.label.is_empty() {
                e.push((m.label.clone(), m.color.clone(), Some(Style::Dashed)));
            }
        }
        if !self.shade.is_empty() && !self.shade_label.is_empty() {
            e.push((self.shade_label.clone(), "#f4b6b6".into(), None));
        }
        e
    }

    /// The plot as a standalone SVG document.
    pub fn svg(&self) -> String {
        let h = self.height + self.legend_height();
        let mut s = svg_open(self.width, h);
        self.draw(&mut s, 0.0, 0.0, true);
        s.push_str("</svg>\n");
        s
    }

    /// Height the legend adds above the plot area.
    fn legend_height(&self) -> f64 {
        legend_rows(&self.legend_entries(), self.width - ML - MR) as f64 * LEGEND_ROW
    }

    /// Draws the plot with its top left corner at (ox, oy); `big_title` for a plot of its own
    /// (a panel of [`stacked`] has a smaller one).
    fn draw(&self, s: &mut String, ox: f64, oy: f64, big_title: bool) {
        let legend_h = self.legend_height();
        let (x0, x1) = (ox + ML, ox + self.width - MR);
        let (y0, y1) = (oy + MT + legend_h, oy + self.height + legend_h - MB);
        let _ = write!(
            s,
            r#"<text class="title" x="{x0}" y="{:.1}" font-weight="bold" font-size="{}">{}</text>"#,
            oy + 19.0,
            if big_title { 14 } else { 12 },
            esc(&self.title)
        );
        draw_legend(s, &self.legend_entries(), x0, oy + MT + 2.0, x1 - x0);
        let (xr, yr) = match (self.range(true), self.range(false)) {
            (Some(xr), Some(yr)) => (xr, yr),
            _ => {
                let _ = write!(
                    s,
                    r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">no data</text>"#,
                    (x0 + x1) / 2.0,
                    (y0 + y1) / 2.0
                );
                return;
            }
        };
        let px = |v: f64| x0 + (self.x.tf(v) - xr.0) / (xr.1 - xr.0) * (x1 - x0);
        let py = |v: f64| y1 - (self.y.tf(v) - yr.0) / (yr.1 - yr.0) * (y1 - y0);
        for &(a, b) in &self.shade {
            let (a, b) = (px(a).max(x0), px(b).min(x1));
            if b >= a {
                let _ = write!(
                    s,
                    r##"<rect x="{a:.1}" y="{y0:.1}" width="{:.1}" height="{:.1}" fill="#f4b6b6" opacity="0.6"/>"##,
                    (b - a).max(1.0),
                    y1 - y0
                );
            }
        }
        let (xt, xtitle) = self.x.tick_marks(xr.0, xr.1);
        let (yt, ytitle) = self.y.tick_marks(yr.0, yr.1);
        draw_axes(
            s,
            true,
            (x0, x1, y0, y1),
            xr,
            yr,
            &xt,
            &yt,
            &xtitle,
            &ytitle,
        );
        let clip = clip_id(&self.title, ox, oy);
        let _ = write!(
            s,
            r#"<clipPath id="{clip}"><rect x="{x0}" y="{y0:.1}" width="{:.1}" height="{:.1}"/></clipPath><g clip-path="url(#{clip})">"#,
            x1 - x0,
            y1 - y0
        );
        if !self.y.log && yr.0 < 0.0 && yr.1 > 0.0 {
            let _ = write!(
                s,
                r##"<line x1="{x0}" y1="{y:.1}" x2="{x1}" y2="{y:.1}" stroke="#999" stroke-width="0.8"/>"##,
                y = py(0.0)
            );
        }
        for se in &self.series {
            draw_series(s, se, &px, &py);
        }
        for m in &self.vlines {
            let x = px(m.value);
            if x.is_finite() {
                let _ = write!(
                    s,
                    r#"<line class="ref-line" x1="{x:.1}" y1="{y0:.1}" x2="{x:.1}" y2="{y1:.1}" stroke="{}" stroke-width="1.2" stroke-dasharray="5,3"/>"#,
                    m.color
                );
            }
        }
        for m in &self.hlines {
            let y = py(m.value);
            if y.is_finite() {
                let _ = write!(
                    s,
                    r#"<line class="ref-line" x1="{x0}" y1="{y:.1}" x2="{x1}" y2="{y:.1}" stroke="{}" stroke-width="1.2" stroke-dasharray="5,3"/>"#,
                    m.color
                );
            }
        }
        s.push_str("</g>");
    }

    /// The range along x (`along_x`) or y in transformed units: the axis's own, else the
    /// data's where the other coordinate is drawable, with the reference lines across it
    /// (vertical for x, horizontal for y); y gets 5 % added at each end.
    fn range(&self, along_x: bool) -> Option<(f64, f64)> {
        let (own, other, lines, pad) = if along_x {
            (&self.x, &self.y, &self.vlines, 0.0)
        } else {
            (&self.y, &self.x, &self.hlines, 0.05)
        };
        if let Some((a, b)) = own.range {
            return Some((own.tf(a), own.tf(b)));
        }
        let vals = self
            .series
            .iter()
            .flat_map(|s| {
                let (mine, theirs) = if along_x { (&s.x, &s.y) } else { (&s.y, &s.x) };
                mine.iter().zip(theirs)
            })
            .filter(|(_, o)| other.tf(**o).is_finite())
            .map(|(v, _)| own.tf(*v))
            .chain(lines.iter().map(|m| own.tf(m.value)));
        span(vals, pad)
    }
}

/// The finite range of `vals`, widened by `pad` of its length at each end (a unit or a tenth of
/// the value when all are equal); `None` without a finite value.
fn span(vals: impl Iterator<Item = f64>, pad: f64) -> Option<(f64, f64)> {
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
fn clip_id(title: &str, ox: f64, oy: f64) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in format!("{title}|{ox}|{oy}").bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!("clip{h:016x}")
}

fn svg_open(w: f64, h: f64) -> String {
    format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="11"><rect width="{w}" height="{h}" fill="white"/>"#
    )
}

/// Frame, grid lines (with `grid`), tick marks and labels and the two axis titles of the plot
/// area (x0, x1, y0, y1) with transformed ranges `xr`, `yr`.
#[allow(clippy::too_many_arguments)]
fn draw_axes(
    s: &mut String,
    grid: bool,
    (x0, x1, y0, y1): (f64, f64, f64, f64),
    xr: (f64, f64),
    yr: (f64, f64),
    xt: &[(f64, String)],
    yt: &[(f64, String)],
    xtitle: &str,
    ytitle: &str,
) {
    let grid_colour = if grid { "#e3e3e3" } else { "none" };
    for (v, label) in xt {
        let x = x0 + (v - xr.0) / (xr.1 - xr.0) * (x1 - x0);
        let _ = write!(
            s,
            r##"<g class="x-tick"><line x1="{x:.1}" y1="{y0:.1}" x2="{x:.1}" y2="{y1:.1}" stroke="{grid_colour}"/><line x1="{x:.1}" y1="{y1:.1}" x2="{x:.1}" y2="{:.1}" stroke="#555"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text></g>"##,
            y1 + 4.0,
            y1 + 16.0,
            esc(label)
        );
    }
    for (v, label) in yt {
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
        esc(xtitle)
    );
    let (lx, ly) = (x0 - 64.0, (y0 + y1) / 2.0);
    let _ = write!(
        s,
        r#"<text class="y-label" x="{lx:.1}" y="{ly:.1}" transform="rotate(-90 {lx:.1} {ly:.1})" text-anchor="middle">{}</text>"#,
        esc(ytitle)
    );
}

fn draw_series(s: &mut String, se: &Series, px: &dyn Fn(f64) -> f64, py: &dyn Fn(f64) -> f64) {
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
fn entry_width(t: &str) -> f64 {
    30.0 + 6.2 * t.chars().count() as f64
}

/// Rows the legend entries take in `width` px.
fn legend_rows(entries: &[(String, String, Option<Style>)], width: f64) -> usize {
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
fn draw_legend(
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

/// Panels over one another under one title, as one SVG (e.g. magnitude over phase).
pub fn stacked(title: &str, panels: &[Plot]) -> String {
    let width = panels.iter().fold(0.0f64, |w, p| w.max(p.width));
    let top = 30.0;
    let height = top
        + panels
            .iter()
            .map(|p| p.height + p.legend_height())
            .sum::<f64>();
    let mut s = svg_open(width, height);
    let _ = write!(
        s,
        r#"<text class="title" x="{ML}" y="20" font-weight="bold" font-size="14">{}</text>"#,
        esc(title)
    );
    let mut y = top;
    for p in panels {
        p.draw(&mut s, 0.0, y, false);
        y += p.height + p.legend_height();
    }
    s.push_str("</svg>\n");
    s
}

/// A grid of values (`values[row][col]` at `(xs[col], ys[row])`) in colour, with a colour scale;
/// NaN cells are drawn grey and named by `missing` in the legend; `marker` marks one cell.
#[derive(Debug, Clone)]
pub struct HeatMap {
    /// Title.
    pub title: String,
    /// The column axis.
    pub x: Axis,
    /// The row axis.
    pub y: Axis,
    /// Column values.
    pub xs: Vec<f64>,
    /// Row values.
    pub ys: Vec<f64>,
    /// Values, one row per `ys` entry.
    pub values: Vec<Vec<f64>>,
    /// What the colours mean, with the unit, e.g. `E, weighted RMS error`.
    pub value_label: String,
    /// Whether colours follow log10 of the values.
    pub log_colour: bool,
    /// Legend text of the grey cells.
    pub missing: String,
    /// A marked cell: (column, row, legend text).
    pub marker: Option<(usize, usize, String)>,
}

/// A perceptually ordered colour map (dark blue, teal, green, yellow) at `t` in 0..1.
fn colour(t: f64) -> String {
    const STOPS: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let t = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f64;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let m = |p: f64, q: f64| (p + (q - p) * f).round() as u8;
    format!("rgb({},{},{})", m(a.0, b.0), m(a.1, b.1), m(a.2, b.2))
}

/// Cell edges around grid values `v` (sorted): midway between neighbours, half a step beyond
/// the ends (a tenth of the value, or 1, for a single value).
fn edges(v: &[f64]) -> Vec<f64> {
    match v {
        [] => vec![0.0, 1.0],
        [a] => {
            let d = if *a == 0.0 { 1.0 } else { 0.1 * a.abs() };
            vec![a - d, a + d]
        }
        _ => {
            let mut e = vec![v[0] - (v[1] - v[0]) / 2.0];
            e.extend(v.windows(2).map(|w| (w[0] + w[1]) / 2.0));
            let n = v.len();
            e.push(v[n - 1] + (v[n - 1] - v[n - 2]) / 2.0);
            e
        }
    }
}

impl HeatMap {
    /// The heat map as a standalone SVG document.
    pub fn svg(&self) -> String {
        let (w, h) = (780.0, 560.0);
        let mut legend: Vec<(String, String, Option<Style>)> = vec![];
        if let Some((_, _, t)) = &self.marker {
            legend.push((t.clone(), "black".into(), Some(Style::Dots)));
        }
        let has_missing = self.values.iter().flatten().any(|v| !v.is_finite());
        if has_missing {
            legend.push((self.missing.clone(), "rgb(200,200,200)".into(), None));
        }
        let bar_w = 100.0;
        let (x0, x1) = (ML, w - MR - bar_w);
        let legend_h = legend_rows(&legend, x1 - x0) as f64 * LEGEND_ROW;
        let (y0, y1) = (MT + legend_h + 4.0, h - MB);
        let mut s = svg_open(w, h);
        let _ = write!(
            s,
            r#"<text class="title" x="{x0}" y="19" font-weight="bold" font-size="14">{}</text>"#,
            esc(&self.title)
        );
        draw_legend(&mut s, &legend, x0, MT + 2.0, x1 - x0);
        let tf = |v: f64| if self.log_colour { v.log10() } else { v };
        let finite: Vec<f64> = self
            .values
            .iter()
            .flatten()
            .map(|v| tf(*v))
            .filter(|v| v.is_finite())
            .collect();
        let lo = finite.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let (lo, hi) = if hi > lo {
            (lo, hi)
        } else {
            (lo - 0.5, lo + 0.5)
        };
        let (ex, ey) = (edges(&self.xs), edges(&self.ys));
        let xr = (self.x.tf(ex[0]), self.x.tf(ex[ex.len() - 1]));
        let yr = (self.y.tf(ey[0]), self.y.tf(ey[ey.len() - 1]));
        let px = |v: f64| x0 + (self.x.tf(v) - xr.0) / (xr.1 - xr.0) * (x1 - x0);
        let py = |v: f64| y1 - (self.y.tf(v) - yr.0) / (yr.1 - yr.0) * (y1 - y0);
        for (j, row) in self.values.iter().enumerate().take(ey.len() - 1) {
            for (i, v) in row.iter().enumerate().take(ex.len() - 1) {
                let c = tf(*v);
                let fill = if c.is_finite() {
                    colour((c - lo) / (hi - lo))
                } else {
                    "rgb(200,200,200)".into()
                };
                let (a, b) = (px(ex[i]), px(ex[i + 1]));
                let (top, bottom) = (py(ey[j + 1]), py(ey[j]));
                let _ = write!(
                    s,
                    r#"<rect x="{a:.1}" y="{top:.1}" width="{:.1}" height="{:.1}" fill="{fill}"><title>{}</title></rect>"#,
                    b - a + 0.5,
                    bottom - top + 0.5,
                    sig(*v)
                );
            }
        }
        let (xt, xtitle) = self.x.tick_marks(xr.0, xr.1);
        let (yt, ytitle) = self.y.tick_marks(yr.0, yr.1);
        draw_axes(
            &mut s,
            false,
            (x0, x1, y0, y1),
            xr,
            yr,
            &xt,
            &yt,
            &xtitle,
            &ytitle,
        );
        if let Some((i, j, _)) = &self.marker {
            if let (Some(x), Some(y)) = (self.xs.get(*i), self.ys.get(*j).or(self.ys.first())) {
                let (cx, cy) = (
                    px(*x),
                    if self.ys.is_empty() {
                        (y0 + y1) / 2.0
                    } else {
                        py(*y)
                    },
                );
                let _ = write!(
                    s,
                    r#"<g class="marker"><circle cx="{cx:.1}" cy="{cy:.1}" r="7" fill="none" stroke="white" stroke-width="3"/><circle cx="{cx:.1}" cy="{cy:.1}" r="7" fill="none" stroke="black" stroke-width="1.5"/><circle cx="{cx:.1}" cy="{cy:.1}" r="2.5" fill="black"/></g>"#
                );
            }
        }
        // the colour scale: a bar of 64 steps with ticks in the values' own units
        let (bx, bw) = (x1 + 18.0, 16.0);
        s.push_str(r#"<g class="colour-scale">"#);
        for k in 0..64 {
            let t0 = k as f64 / 64.0;
            let ya = y1 - (t0 + 1.0 / 64.0) * (y1 - y0);
            let _ = write!(
                s,
                r#"<rect x="{bx:.1}" y="{ya:.1}" width="{bw}" height="{:.2}" fill="{}"/>"#,
                (y1 - y0) / 64.0 + 0.3,
                colour(t0 + 0.5 / 64.0)
            );
        }
        let _ = write!(
            s,
            r##"<rect x="{bx:.1}" y="{y0:.1}" width="{bw}" height="{:.1}" fill="none" stroke="#555"/>"##,
            y1 - y0
        );
        let ticks: Vec<(f64, String)> = if self.log_colour {
            log_ticks(10f64.powf(lo), 10f64.powf(hi))
                .into_iter()
                .map(|v| (v.log10(), log_label(v)))
                .collect()
        } else {
            let t = nice_ticks(lo, hi, 5);
            let step = if t.len() > 1 { t[1] - t[0] } else { 1.0 };
            t.into_iter().map(|v| (v, tick_label(v, step))).collect()
        };
        for (v, label) in ticks {
            let y = y1 - (v - lo) / (hi - lo) * (y1 - y0);
            let _ = write!(
                s,
                r##"<line x1="{:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#555"/><text x="{:.1}" y="{:.1}">{label}</text>"##,
                bx + bw,
                bx + bw + 4.0,
                bx + bw + 6.0,
                y + 4.0
            );
        }
        let (lx, ly) = (bx + bw + 62.0, (y0 + y1) / 2.0);
        let _ = write!(
            s,
            r#"<text x="{lx:.1}" y="{ly:.1}" transform="rotate(-90 {lx:.1} {ly:.1})" text-anchor="middle">{}{}</text></g>"#,
            esc(&self.value_label),
            if self.log_colour { " (log scale)" } else { "" }
        );
        s.push_str("</svg>\n");
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_fall_on_1_2_5_steps_and_are_never_fewer_than_three() {
        assert_eq!(
            nice_ticks(0.0, 10.0, 5),
            vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
        );
        assert_eq!(nice_ticks(-180.0, 180.0, 4), vec![-100.0, 0.0, 100.0]);
        let t = nice_ticks(0.13, 0.31, 6);
        assert!(t.len() >= 3, "{t:?}");
        let t = nice_ticks(1.0, 1.9, 1);
        assert!(t.len() >= 3, "{t:?}");
        assert_eq!(log_ticks(1.0, 1000.0), vec![1.0, 10.0, 100.0, 1000.0]);
        assert_eq!(log_ticks(3.0, 40.0), vec![5.0, 10.0, 20.0]);
        assert_eq!(log_ticks(12.0, 30.0), vec![15.0, 20.0, 25.0, 30.0]);
    }

    #[test]
    fn an_si_axis_takes_the_prefix_of_its_values() {
        let p = Plot::new(
            "d",
            Axis::linear("time", "s"),
            Axis::linear("deviation", "m").si(),
        )
        .series(Series::line("a", "red", &[0.0, 1.0], &[0.0, 4e-6]));
        let s = p.svg();
        assert!(s.contains(">deviation (um)<"), "{s}");
        assert!(s.contains(">time (s)<"), "{s}");
        assert!(s.contains(">4<") && s.contains(">2<"), "{s}");
    }

    #[test]
    fn a_plot_has_its_title_axes_ticks_legend_and_reference_lines() {
        let x: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
        let y: Vec<f64> = x.iter().map(|v| v.sin()).collect();
        let s = Plot::new(
            "sine <test>",
            Axis::linear("time", "s"),
            Axis::linear("torque", "N m"),
        )
        .series(Series::line("sine", PALETTE[0], &x, &y))
        .hline(Mark::new("limit 0.5 N m", 0.5, "black"))
        .vline(Mark::new("t = 2 s", 2.0, "red"))
        .svg();
        assert!(s.contains(r#"class="title""#) && s.contains("sine &lt;test&gt;"));
        assert!(s.contains(">time (s)<") && s.contains(">torque (N m)<"));
        assert!(s.matches(r#"class="x-tick""#).count() > 2);
        assert!(s.matches(r#"class="y-tick""#).count() > 2);
        assert!(s.contains(r#"class="legend""#) && s.contains(">limit 0.5 N m<"));
        assert_eq!(s.matches(r#"class="ref-line""#).count(), 2);
    }

    #[test]
    fn a_heat_map_has_a_colour_scale_and_its_marker() {
        let m = HeatMap {
            title: "E".into(),
            x: Axis::linear("kp", "1/s"),
            y: Axis::linear("kv", "N m s/rad"),
            xs: vec![10.0, 20.0, 30.0],
            ys: vec![1.0, 2.0],
            values: vec![vec![1.0, 2.0, f64::NAN], vec![3.0, 0.5, 4.0]],
            value_label: "E (m)".into(),
            log_colour: true,
            missing: "rejected".into(),
            marker: Some((1, 1, "best".into())),
        };
        let s = m.svg();
        assert!(s.contains(r#"class="colour-scale""#) && s.contains(">E (m) (log scale)<"));
        assert!(s.contains(r#"class="marker""#) && s.contains(">best<"));
        assert!(s.contains(">rejected<"));
        assert!(s.matches(r#"class="x-tick""#).count() > 2);
    }
}
