//! `summary.json` of a run: timing figures from the plant's log and tracking figures from the
//! trace rows. The same code serves `feedloop run` (both processes) and `feedloop sim`.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::log::{AxisRecord, PlantRecord, REC_OVERRUN, REC_STALL};

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
        if crate::log::is_deadline_miss(r.flags) {
            t.deadline_misses += 1;
        }
        if r.flags & REC_OVERRUN != 0 {
            t.plant_overruns += 1;
        }
        if r.flags & crate::log::REC_BAD_SEQ != 0 {
            t.bad_sequence += 1;
        }
        if r.flags & crate::log::REC_LATE_CMD != 0 {
            t.late_commands += 1;
        }
        if r.flags & crate::log::REC_DUP_CMD != 0 {
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

/// Streams trace rows and accumulates the tracking figures (constant memory). A run has contour
/// figures when its rows came with contour errors (see [`Tracking::push`]).
#[derive(Debug, Clone)]
pub struct Tracking {
    names: Vec<String>,
    /// Load unit of each axis ("m" or "rad"), when known.
    units: Vec<Option<&'static str>>,
    sum_sq: Vec<f64>,
    max_abs: Vec<f64>,
    rows: u64,
    contour_rows: u64,
    contour_sum_sq: f64,
    contour_max: f64,
}

impl Tracking {
    /// For axes `names` (job order), units unknown.
    pub fn new(names: &[String]) -> Self {
        Self {
            names: names.to_vec(),
            units: vec![None; names.len()],
            sum_sq: vec![0.0; names.len()],
            max_abs: vec![0.0; names.len()],
            rows: 0,
            contour_rows: 0,
            contour_sum_sq: 0.0,
            contour_max: 0.0,
        }
    }

    /// For the axes of `job` (job order, each with its load unit: m, or rad for a rotary axis).
    pub fn for_job(job: &feedloop_model::job::Job) -> Self {
        let mut t = Self::new(&job.axis_names());
        for (u, a) in t.units.iter_mut().zip(&job.axes) {
            *u = Some(match a.model.plant.kind() {
                feedloop_model::model::AxisKind::Rotary => "rad",
                _ => "m",
            });
        }
        t
    }

    /// Adds one cycle's rows; `contour_error` is the row's contour error (m) when the run has a
    /// contour (rows without one, or with a non-finite one, are left out of the contour figures).
    pub fn push(&mut self, axes: &[AxisRecord], contour_error: Option<f64>) {
        for (i, a) in axes.iter().enumerate().take(self.names.len()) {
            let e = a.cmd - a.load;
            self.sum_sq[i] += e * e;
            self.max_abs[i] = self.max_abs[i].max(e.abs());
        }
        if let Some(e) = contour_error.filter(|e| e.is_finite()) {
            self.contour_rows += 1;
            self.contour_sum_sq += e * e;
            self.contour_max = self.contour_max.max(e.abs());
        }
        self.rows += 1;
    }

    /// Per-axis figures in job order, with each axis's load unit when known.
    pub fn axes_in_order(&self) -> Vec<(String, AxisFigures, Option<&'static str>)> {
        let n = self.rows.max(1) as f64;
        (0..self.names.len())
            .map(|i| {
                let figures = AxisFigures {
                    max_following_error: self.max_abs[i],
                    rms_following_error: (self.sum_sq[i] / n).sqrt(),
                };
                (self.names[i].clone(), figures, self.units[i])
            })
            .collect()
    }

    /// Per-axis figures by axis name.
    pub fn axes(&self) -> BTreeMap<String, AxisFigures> {
        self.axes_in_order()
            .into_iter()
            .map(|(name, figures, _)| (name, figures))
            .collect()
    }

    /// Contour figures, when rows came with contour errors.
    pub fn contour(&self) -> Option<ContourFigures> {
        if self.contour_rows == 0 {
            return None;
        }
        Some(ContourFigures {
            max_error: self.contour_max,
            rms_error: (self.contour_sum_sq / self.contour_rows as f64).sqrt(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::log::REC_MISSED;

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
    fn tracking_streams_following_and_contour_figures_and_skips_rows_without_a_contour_error() {
        let names = vec!["x".to_string(), "y".to_string()];
        let row = |ex: f64, ey: f64| {
            [
                AxisRecord {
                    cmd: 1.0,
                    load: 1.0 - ex,
                    ..Default::default()
                },
                AxisRecord {
                    cmd: -2.0,
                    load: -2.0 - ey,
                    ..Default::default()
                },
            ]
        };
        let mut t = Tracking::new(&names);
        t.push(&row(3e-6, -4e-6), Some(-2e-6));
        t.push(&row(-1e-6, 0.0), None);
        t.push(&row(0.0, 0.0), Some(f64::NAN));
        t.push(&row(0.0, 2e-6), Some(1e-6));
        let c = t.contour().unwrap();
        assert_eq!(c.max_error, 2e-6);
        assert!(
            (c.rms_error - (2.5e-12f64).sqrt()).abs() < 1e-18,
            "{}",
            c.rms_error
        );
        let a = t.axes();
        assert!((a["x"].max_following_error - 3e-6).abs() < 1e-15);
        assert!((a["y"].max_following_error - 4e-6).abs() < 1e-15);
        assert!((a["x"].rms_following_error - (10e-12f64 / 4.0).sqrt()).abs() < 1e-15);
        let mut none = Tracking::new(&names);
        none.push(&row(1e-6, 1e-6), None);
        none.push(&row(1e-6, 1e-6), Some(f64::NAN));
        assert_eq!(
            none.contour(),
            None,
            "no contour without a finite contour error"
        );
    }
}
