//! A plot of curves over two axes, alone or stacked in panels.

use std::fmt::Write as _;

use super::axis::Axis;
use super::draw::{
    clip_id, draw_axes, draw_legend, draw_series, legend_rows, span, svg_open, LEGEND_ROW, MB, ML,
    MR, MT,
};
use super::series::{esc, Mark, Series, Style};

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
        draw_axes(s, true, (x0, x1, y0, y1), (&self.x, xr), (&self.y, yr));
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
