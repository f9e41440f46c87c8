//! An axis of a plot: label, unit, scale and its ticks.

use feedloop_model::units::{prefix_for, sig};

/// Units an axis may print with an SI prefix that fits its values (`Axis::si`).
const PREFIXABLE: [&str; 9] = ["m", "s", "rad", "N", "N m", "m/s", "rad/s", "A", "V"];

/// One axis: what it shows, in which unit, on which scale.
#[derive(Debug, Clone)]
pub struct Axis {
    label: String,
    unit: String,
    pub(super) log: bool,
    si: bool,
    ticks: Option<Vec<(f64, String)>>,
    pub(super) range: Option<(f64, f64)>,
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

    pub(super) fn tf(&self, v: f64) -> f64 {
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
    pub(super) fn tick_marks(&self, lo: f64, hi: f64) -> (Vec<(f64, String)>, String) {
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
pub(super) fn log_label(v: f64) -> String {
    if (1e4..1e6).contains(&v.abs()) {
        format!("{}", v.round())
    } else {
        sig(v)
    }
}

/// A tick label for `v` on a grid of `step`: as many decimals as the step needs.
pub(super) fn tick_label(v: f64, step: f64) -> String {
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
