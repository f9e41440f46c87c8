//! Figures of one realtime run from the plant's log: the round-trip and jitter histograms and
//! the miss, overrun and stall counts (`latency.json`).

use hdrhistogram::Histogram;
use serde_json::{json, Value};

use feedloop_trace::log::{PlantRecord, REC_MISSED, REC_OVERRUN, REC_STALL};

use super::{ns_histogram, LatencyError};

/// What the plant's records of one run say about its timing.
pub struct RunFigures {
    /// Sample published -> command received, ns, for every answered cycle.
    pub latency: Histogram<u64>,
    /// How late the plant woke for each cycle, ns.
    pub jitter: Histogram<u64>,
    /// Cycles whose command did not arrive in time.
    pub misses: u64,
    /// Of these, the ones outside plant stalls.
    pub misses_outside_stalls: u64,
    /// Cycles in which the plant woke more than half a period late.
    pub overruns: u64,
    /// Episodes in which the plant woke more than 1 ms late.
    pub stalls: u64,
    /// The worst lateness in a stall, ms.
    pub stall_max_ms: f64,
}

impl RunFigures {
    /// Counts and histograms over `records` (cycle order).
    pub fn from_records(records: &[PlantRecord]) -> Result<Self, LatencyError> {
        let mut f = RunFigures {
            latency: ns_histogram()?,
            jitter: ns_histogram()?,
            misses: 0,
            misses_outside_stalls: 0,
            overruns: 0,
            stalls: 0,
            stall_max_ms: 0.0,
        };
        let mut in_stall = false;
        for r in records {
            if r.latency_ns != u64::MAX {
                f.latency.saturating_record(r.latency_ns.max(1));
            }
            f.jitter.saturating_record(r.wake_late_ns.max(1));
            let stalled = r.flags & REC_STALL != 0;
            if r.flags & REC_MISSED != 0 {
                f.misses += 1;
                if !stalled {
                    f.misses_outside_stalls += 1;
                }
            }
            if r.flags & REC_OVERRUN != 0 {
                f.overruns += 1;
            }
            if stalled {
                if !in_stall {
                    f.stalls += 1;
                }
                f.stall_max_ms = f.stall_max_ms.max(r.wake_late_ns as f64 * 1e-6);
            }
            in_stall = stalled;
        }
        Ok(f)
    }
}

/// A histogram of `values` (ns), as the run's figures are kept.
pub fn ns_histogram_of(values: &[u64]) -> Result<Histogram<u64>, LatencyError> {
    let mut h = super::ns_histogram()?;
    for v in values {
        h.saturating_record((*v).max(1));
    }
    Ok(h)
}

/// p50, p99, p99.9 and max of a histogram of ns values, in us, with the count.
pub fn hist_json(h: &Histogram<u64>) -> Value {
    let us = |v: u64| v as f64 / 1000.0;
    json!({
        "p50": us(h.value_at_quantile(0.5)),
        "p99": us(h.value_at_quantile(0.99)),
        "p999": us(h.value_at_quantile(0.999)),
        "max": us(h.max()),
        "count": h.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn misses_overruns_and_stall_episodes_are_counted_from_the_flags() {
        let mut recs: Vec<PlantRecord> = (0..10)
            .map(|seq| PlantRecord {
                seq,
                latency_ns: 3_000,
                wake_late_ns: 100,
                ..Default::default()
            })
            .collect();
        recs[2].flags = REC_MISSED;
        recs[2].latency_ns = u64::MAX;
        recs[4].flags = REC_OVERRUN;
        // one stall episode of two cycles (the second 2.5 ms late) with a miss in it, and another
        for (k, late) in [(6, 1_500_000), (7, 2_500_000), (9, 1_200_000)] {
            recs[k].flags = REC_STALL | REC_OVERRUN;
            recs[k].wake_late_ns = late;
        }
        recs[7].flags |= REC_MISSED;
        let f = RunFigures::from_records(&recs).unwrap();
        assert_eq!((f.misses, f.misses_outside_stalls), (2, 1));
        assert_eq!(f.overruns, 4);
        assert_eq!(f.stalls, 2);
        assert!((f.stall_max_ms - 2.5).abs() < 1e-12);
        assert_eq!(f.latency.len(), 9);
        assert_eq!(f.jitter.len(), 10);
        let j = hist_json(&f.latency);
        assert_eq!(j["count"], 9);
        assert!((j["p50"].as_f64().unwrap() - 3.0).abs() < 0.01);
    }
}
