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

/// The loop's round trip in parts (issue 18), ns, from the processes' shared monotonic clock:
/// for each answered cycle, the plant's publication time and the scheduler's four times.
pub struct Breakdown {
    /// Sample published by the plant -> found by the scheduler's poll (transport out).
    pub to_scheduler: Histogram<u64>,
    /// Found -> held: the poll that found the sample (iceoryx2's receive, the copy of the used
    /// axes).
    pub before_compute: Histogram<u64>,
    /// The catch-up when needed, the control plane's look, the chain and the vetting of its
    /// command.
    pub chain: Histogram<u64>,
    /// The command's publication.
    pub publish: Histogram<u64>,
    /// Publication returned -> the plant holds the command (transport back).
    pub to_plant: Histogram<u64>,
    /// Cycles split.
    pub cycles: u64,
}

impl Breakdown {
    /// Joins the plant's and the scheduler's records by cycle (each in cycle order; cycles the
    /// plant did not get an answer for, or the scheduler did not log, are left out).
    pub fn from_records(
        plant: &[PlantRecord],
        sched: &[feedloop_trace::log::SchedRecord],
    ) -> Result<Self, LatencyError> {
        let mut b = Breakdown {
            to_scheduler: super::ns_histogram()?,
            before_compute: super::ns_histogram()?,
            chain: super::ns_histogram()?,
            publish: super::ns_histogram()?,
            to_plant: super::ns_histogram()?,
            cycles: 0,
        };
        let mut j = 0usize;
        for p in plant {
            if p.latency_ns == u64::MAX || p.published_ns == 0 {
                continue;
            }
            while j < sched.len() && sched[j].seq < p.seq {
                j += 1;
            }
            let Some(s) = sched.get(j).filter(|s| s.seq == p.seq && s.sent_ns != 0) else {
                continue;
            };
            let held = p.published_ns + p.latency_ns;
            let rec = |h: &mut Histogram<u64>, a: u64, b: u64| {
                h.saturating_record(b.saturating_sub(a).max(1));
            };
            rec(&mut b.to_scheduler, p.published_ns, s.received_ns);
            rec(&mut b.before_compute, s.received_ns, s.started_ns);
            rec(&mut b.chain, s.started_ns, s.computed_ns);
            rec(&mut b.publish, s.computed_ns, s.sent_ns);
            rec(&mut b.to_plant, s.sent_ns, held);
            b.cycles += 1;
        }
        Ok(b)
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
