//! A grid of values in colour with a colour scale.

use std::fmt::Write as _;

use feedloop_model::units::sig;

use super::axis::{log_label, log_ticks, nice_ticks, tick_label, Axis};
use super::draw::{draw_axes, draw_legend, legend_rows, svg_open, LEGEND_ROW, MB, ML, MR, MT};
use super::series::{esc, Style};

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

/// Grey of a cell without a finite value.
const MISSING_GREY: &str = "rgb(200,200,200)";

impl HeatMap {
    /// The heat map as a standalone SVG document.
    pub fn svg(&self) -> String {
        let (w, h) = (780.0, 560.0);
        let legend = self.legend();
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
        let (lo, hi) = self.colour_range();
        let (ex, ey) = (edges(&self.xs), edges(&self.ys));
        let xr = (self.x.tf(ex[0]), self.x.tf(ex[ex.len() - 1]));
        let yr = (self.y.tf(ey[0]), self.y.tf(ey[ey.len() - 1]));
        let px = |v: f64| x0 + (self.x.tf(v) - xr.0) / (xr.1 - xr.0) * (x1 - x0);
        let py = |v: f64| y1 - (self.y.tf(v) - yr.0) / (yr.1 - yr.0) * (y1 - y0);
        self.draw_cells(&mut s, (&ex, &ey), (lo, hi), &px, &py);
        draw_axes(
            &mut s,
            false,
            (x0, x1, y0, y1),
            (&self.x, xr),
            (&self.y, yr),
        );
        self.draw_marker(&mut s, (y0, y1), &px, &py);
        self.draw_colour_scale(&mut s, x1 + 18.0, (y0, y1), (lo, hi));
        s.push_str("</svg>\n");
        s
    }

    /// The legend entries: the marked cell and the grey of missing values, where there are any.
    fn legend(&self) -> Vec<(String, String, Option<Style>)> {
        let mut legend: Vec<(String, String, Option<Style>)> = vec![];
        if let Some((_, _, t)) = &self.marker {
            legend.push((t.clone(), "black".into(), Some(Style::Dots)));
        }
        let has_missing = self.values.iter().flatten().any(|v| !v.is_finite());
        if has_missing {
            legend.push((self.missing.clone(), MISSING_GREY.into(), None));
        }
        legend
    }

    /// A value on the colour scale (its log10 with `log_colour`).
    fn tf(&self, v: f64) -> f64 {
        if self.log_colour {
            v.log10()
        } else {
            v
        }
    }

    /// The colour scale's range: that of the finite values on it (a unit wide when they are
    /// all equal).
    fn colour_range(&self) -> (f64, f64) {
        let finite: Vec<f64> = self
            .values
            .iter()
            .flatten()
            .map(|v| self.tf(*v))
            .filter(|v| v.is_finite())
            .collect();
        let lo = finite.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if hi > lo {
            (lo, hi)
        } else {
            (lo - 0.5, lo + 0.5)
        }
    }

    /// One rectangle per cell between the edges `ex`, `ey`, coloured over `lo..hi`.
    fn draw_cells(
        &self,
        s: &mut String,
        (ex, ey): (&[f64], &[f64]),
        (lo, hi): (f64, f64),
        px: &dyn Fn(f64) -> f64,
        py: &dyn Fn(f64) -> f64,
    ) {
        for (j, row) in self.values.iter().enumerate().take(ey.len() - 1) {
            for (i, v) in row.iter().enumerate().take(ex.len() - 1) {
                let c = self.tf(*v);
                let fill = if c.is_finite() {
                    colour((c - lo) / (hi - lo))
                } else {
                    MISSING_GREY.into()
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
    }

    /// The marked cell's ring (mid-height when there are no rows).
    fn draw_marker(
        &self,
        s: &mut String,
        (y0, y1): (f64, f64),
        px: &dyn Fn(f64) -> f64,
        py: &dyn Fn(f64) -> f64,
    ) {
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
    }

    /// The colour scale at `bx`: a bar of 64 steps with ticks in the values' own units.
    fn draw_colour_scale(
        &self,
        s: &mut String,
        bx: f64,
        (y0, y1): (f64, f64),
        (lo, hi): (f64, f64),
    ) {
        let bw = 16.0;
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
    }
}
