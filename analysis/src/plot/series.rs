//! What a plot draws: curves, their styles and colours, reference lines.

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
