//! `summary.json` of a run: timing figures from the plant's log and tracking figures from the
//! trace rows. The same code serves `feedloop run` (both processes) and `feedloop sim`.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::record::{AxisRecord, PlantRecord, REC_OVERRUN, REC_STALL};

/// Latency percentiles, microseconds.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct Percentiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// 99.9th percentile.
    pub p999: f64,
    /// Maximum.
    pub max: f64,
}

/// Percentiles (us) of nanosecond values; `None` when empty. Sorts `values` in place.
pub fn percentiles_us(values: &mut [u64]) -> Option<Percentiles> {
    if values.is_empty() {
        return None;
    }
    values.sort_unstable();
    let at = |q: f64| {
        let i = ((values.len() as f64 * q).ceil() as usize).clamp(1, values.len()) - 1;
        values[i] as f64 / 1000.0
    };
    Some(Percentiles {
        p50: at(0.5),
        p99: at(0.99),
        p999: at(0.999),
        max: values[values.len() - 1] as f64 / 1000.0,
    })
}

/// Stall episodes: runs of consecutive cycles in which the plant woke more than 1 ms late.
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Default)]
pub struct Stalls {
    /// Number of episodes.
    pub count: u64,
    /// Longest lateness seen in any episode, ms.
    pub max_ms: f64,
}

/// Timing figures of a run.
#[derive(Debug, Clone, Serialize, PartialEq, Default)]
pub struct Timing {
    /// Commands that missed their deadline while the plant itself was on time.
    pub deadline_misses: u64,
    /// Cycles in which the plant woke more than half a period late.
    pub plant_overruns: u64,
    /// Stall episodes.
    pub stalls: Stalls,
    /// Sample published -> command received, us.
    pub latency_us: Option<Percentiles>,
    /// Commands with an unexpected sequence number the plant dropped.
    pub bad_sequence: u64,
    /// Cycles in which an answer to an earlier cycle arrived after its deadline (dropped).
    pub late_commands: u64,
    /// Cycles in which a second command for an already answered cycle was seen (dropped).
    pub duplicate_commands: u64,
}

/// Computes timing figures from the plant's records.
pub fn timing(records: &[PlantRecord]) -> Timing {
    let mut t = Timing::default();
    let mut lat: Vec<u64> = Vec::with_capacity(records.len());
    let mut in_stall = false;
    for r in records {
        if crate::record::is_deadline_miss(r.flags) {
            t.deadline_misses += 1;
        }
        if r.flags & REC_OVERRUN != 0 {
            t.plant_overruns += 1;
        }
        if r.flags & crate::record::REC_BAD_SEQ != 0 {
            t.bad_sequence += 1;
        }
        if r.flags & crate::record::REC_LATE_CMD != 0 {
            t.late_commands += 1;
        }
        if r.flags & crate::record::REC_DUP_CMD != 0 {
            t.duplicate_commands += 1;
        }
        if r.flags & REC_STALL != 0 {
            if !in_stall {
                t.stalls.count += 1;
            }
            in_stall = true;
            t.stalls.max_ms = t.stalls.max_ms.max(r.wake_late_ns as f64 * 1e-6);
        } else {
            in_stall = false;
        }
        if r.latency_ns != u64::MAX {
            lat.push(r.latency_ns);
        }
    }
    t.latency_us = percentiles_us(&mut lat);
    t
}

/// Following-error figures of one axis (load units: m or rad).
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Default)]
pub struct AxisFigures {
    /// max |cmd - load|.
    pub max_following_error: f64,
    /// RMS of cmd - load.
    pub rms_following_error: f64,
}

/// Contour-error figures (distance of the measured point from the commanded path).
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Default)]
pub struct ContourFigures {
    /// Largest distance, m.
    pub max_error: f64,
    /// RMS distance, m.
    pub rms_error: f64,
}

/// How the contour error of a run is judged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ContourMode {
    /// No contour (single-axis jobs).
    None,
    /// The trajectory knows its contour (circle, path, X-C profile) and the caller passes each
    /// row's error to [`Tracking::push`].
    Given,
    /// Distance from the measured point to the commanded polyline of these two axes.
    Polyline(usize, usize),
}

/// Streams trace rows and accumulates the tracking figures.
#[derive(Debug, Clone)]
pub struct Tracking {
    names: Vec<String>,
    sum_sq: Vec<f64>,
    max_abs: Vec<f64>,
    rows: u64,
    mode: ContourMode,
    path: Vec<[f64; 4]>,
    given: Vec<f64>,
}

impl Tracking {
    /// For axes `names` (job order), judging the contour as `mode` says.
    pub fn new(names: &[String], mode: ContourMode) -> Self {
        Self {
            names: names.to_vec(),
            sum_sq: vec![0.0; names.len()],
            max_abs: vec![0.0; names.len()],
            rows: 0,
            mode,
            path: Vec::new(),
            given: Vec::new(),
        }
    }

    /// Adds one cycle's rows; `contour_error` is the row's contour error in [`ContourMode::Given`].
    pub fn push(&mut self, axes: &[AxisRecord], contour_error: Option<f64>) {
        for (i, a) in axes.iter().enumerate().take(self.names.len()) {
            let e = a.cmd - a.load;
            self.sum_sq[i] += e * e;
            self.max_abs[i] = self.max_abs[i].max(e.abs());
        }
        match self.mode {
            ContourMode::Polyline(x, y) => {
                self.path
                    .push([axes[x].cmd, axes[y].cmd, axes[x].load, axes[y].load]);
            }
            ContourMode::Given => {
                if let Some(e) = contour_error {
                    self.given.push(e.abs());
                }
            }
            ContourMode::None => {}
        }
        self.rows += 1;
    }

    /// Per-axis figures.
    pub fn axes(&self) -> BTreeMap<String, AxisFigures> {
        let n = self.rows.max(1) as f64;
        self.names
            .iter()
            .enumerate()
            .map(|(i, name)| {
                (
                    name.clone(),
                    AxisFigures {
                        max_following_error: self.max_abs[i],
                        rms_following_error: (self.sum_sq[i] / n).sqrt(),
                    },
                )
            })
            .collect()
    }

    /// Contour figures, when two axes were named.
    pub fn contour(&self) -> Option<ContourFigures> {
        let d = match self.mode {
            ContourMode::None => return None,
            ContourMode::Given => self.given.clone(),
            ContourMode::Polyline(..) => contour_distances(&self.path),
        };
        if d.is_empty() {
            return None;
        }
        let max = d.iter().fold(0.0f64, |m, v| m.max(*v));
        let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
        Some(ContourFigures {
            max_error: max,
            rms_error: rms,
        })
    }
}

/// Distance of each measured point `[_, _, x, y]` from the commanded polyline `[x, y, _, _]`.
///
/// The nearest segment is tracked forward in time (the measured point lags the command), with a
/// local search window, so the cost is linear in the number of samples.
pub fn contour_distances(path: &[[f64; 4]]) -> Vec<f64> {
    let n = path.len();
    let mut out = Vec::with_capacity(n);
    if n < 2 {
        return out;
    }
    let seg_dist = |j: usize, px: f64, py: f64| -> f64 {
        let (ax, ay) = (path[j][0], path[j][1]);
        let (bx, by) = (path[j + 1][0], path[j + 1][1]);
        let (dx, dy) = (bx - ax, by - ay);
        let l2 = dx * dx + dy * dy;
        let t = if l2 > 0.0 {
            (((px - ax) * dx + (py - ay) * dy) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (cx, cy) = (ax + t * dx - px, ay + t * dy - py);
        (cx * cx + cy * cy).sqrt()
    };
    // Walk the nearest segment forward while it improves (the command moves on by about one
    // segment per sample), then look a few segments either side to step over flat spots.
    let mut j = 0usize;
    const LOCAL: usize = 8;
    for (k, p) in path.iter().enumerate() {
        let (px, py) = (p[2], p[3]);
        let hi = k.min(n - 2);
        let mut best_j = j.min(hi);
        let mut best = seg_dist(best_j, px, py);
        while best_j < hi {
            let d = seg_dist(best_j + 1, px, py);
            if d > best {
                break;
            }
            best = d;
            best_j += 1;
        }
        for i in best_j.saturating_sub(LOCAL)..=(best_j + LOCAL).min(hi) {
            let d = seg_dist(i, px, py);
            if d < best {
                best = d;
                best_j = i;
            }
        }
        j = best_j;
        out.push(best);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::REC_MISSED;

    #[test]
    fn percentiles_pick_the_right_ranks() {
        let mut v: Vec<u64> = (1..=1000).map(|i| i * 1000).collect();
        let p = percentiles_us(&mut v).unwrap();
        assert_eq!(p.p50, 500.0);
        assert_eq!(p.p99, 990.0);
        assert_eq!(p.p999, 999.0);
        assert_eq!(p.max, 1000.0);
    }

    #[test]
    fn stall_episodes_count_runs_not_cycles() {
        let mk = |flags, late| PlantRecord {
            flags,
            wake_late_ns: late,
            latency_ns: 1000,
            ..Default::default()
        };
        let recs = [
            mk(0, 0),
            mk(REC_STALL | REC_OVERRUN, 5_000_000),
            mk(REC_STALL | REC_OVERRUN, 4_000_000),
            mk(0, 0),
            mk(REC_MISSED, 0),
            mk(REC_STALL | REC_OVERRUN | REC_MISSED, 2_000_000),
        ];
        let t = timing(&recs);
        assert_eq!(t.stalls.count, 2);
        assert_eq!(t.stalls.max_ms, 5.0);
        assert_eq!(t.deadline_misses, 1);
        assert_eq!(t.plant_overruns, 3);
    }

    #[test]
    fn contour_error_of_a_lagging_point_on_a_circle_is_its_radial_error() {
        // commanded circle r = 10 mm; the measured point lags 200 samples and sits 5 um inside
        let n = 20_000;
        let r = 0.01;
        let path: Vec<[f64; 4]> = (0..n)
            .map(|k| {
                let a = k as f64 * 2e-4;
                let b = (k as f64 - 200.0).max(0.0) * 2e-4;
                [
                    r * a.cos(),
                    r * a.sin(),
                    (r - 5e-6) * b.cos(),
                    (r - 5e-6) * b.sin(),
                ]
            })
            .collect();
        let d = contour_distances(&path);
        for v in &d[300..] {
            assert!((v - 5e-6).abs() < 2e-9, "{v}");
        }
    }
}
