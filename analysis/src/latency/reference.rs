//! Reference loops run on the benchmark's CPUs before the run, one thread per CPU: what the
//! machine gives a sleeping real-time loop and a bare spinning loop, measured in the same
//! command as the loop itself (the VM's behaviour changes from minute to minute).

use std::time::Duration;

use hdrhistogram::Histogram;

use super::{ns_histogram, LatencyError};

use feedloop_runtime::shared::clock::{now_ns, sleep_until_ns};
use feedloop_runtime::shared::rt::{apply, RtRequest};

/// Result of [`sleeping_loop`].
pub struct Sleeping {
    /// Wake-up lateness of every period on every CPU, ns.
    pub lateness: Histogram<u64>,
    /// Whether SCHED_FIFO was granted on every CPU.
    pub sched_fifo: bool,
}

/// A cyclictest-style loop on each CPU: sleep to an absolute deadline every `period_ns`
/// (SCHED_FIFO 80 when permitted, memory locked), record how late each wake-up is.
pub fn sleeping_loop(
    cpus: &[usize],
    period_ns: u64,
    time: Duration,
) -> Result<Sleeping, LatencyError> {
    let results: Vec<(Histogram<u64>, bool)> = std::thread::scope(|sc| {
        let handles: Vec<_> = cpus
            .iter()
            .map(|&cpu| {
                sc.spawn(move || -> Result<(Histogram<u64>, bool), LatencyError> {
                    let applied = apply(&RtRequest {
                        mlockall: true,
                        fifo_priority: Some(80),
                        cpu: Some(cpu),
                    });
                    let mut h = ns_histogram()?;
                    let start = now_ns() + 1_000_000;
                    let end = start + time.as_nanos() as u64;
                    let mut next = start;
                    while next < end {
                        sleep_until_ns(next);
                        h.saturating_record(now_ns().saturating_sub(next).max(1));
                        next += period_ns;
                    }
                    Ok((h, applied.sched_fifo))
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|t| t.join().unwrap_or(Err(LatencyError::ProbePanicked)))
            .collect::<Result<Vec<_>, LatencyError>>()
    })?;
    let mut lateness = ns_histogram()?;
    let mut fifo = !results.is_empty();
    for (h, f) in &results {
        lateness.add(h)?;
        fifo &= *f;
    }
    Ok(Sleeping {
        lateness,
        sched_fifo: fifo,
    })
}

/// Result of [`spinning_loop`].
pub struct Spinning {
    /// Stretches of at least the threshold between two clock readings, all CPUs.
    pub count: u64,
    /// Their total length, ns.
    pub lost_ns: u64,
    /// The longest, ns.
    pub max_ns: u64,
}

/// A bare spinning loop on each CPU (what a busy-polling process does, without any IPC):
/// counts the stretches of at least `threshold_ns` between two consecutive clock readings,
/// i.e. the times the OS or the hypervisor took the core away.
pub fn spinning_loop(
    cpus: &[usize],
    threshold_ns: u64,
    time: Duration,
) -> Result<Spinning, LatencyError> {
    let results: Vec<(u64, u64, u64)> = std::thread::scope(|sc| {
        let handles: Vec<_> = cpus
            .iter()
            .map(|&cpu| {
                sc.spawn(move || {
                    apply(&RtRequest {
                        mlockall: false,
                        fifo_priority: None,
                        cpu: Some(cpu),
                    });
                    let (mut count, mut lost, mut max) = (0u64, 0u64, 0u64);
                    let end = now_ns() + time.as_nanos() as u64;
                    let mut prev = now_ns();
                    while prev < end {
                        let now = now_ns();
                        let gap = now - prev;
                        if gap >= threshold_ns {
                            count += 1;
                            lost += gap;
                            max = max.max(gap);
                        }
                        prev = now;
                    }
                    (count, lost, max)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|t| t.join().unwrap_or((0, 0, 0)))
            .collect()
    });
    Ok(Spinning {
        count: results.iter().map(|r| r.0).sum(),
        lost_ns: results.iter().map(|r| r.1).sum(),
        max_ns: results.iter().map(|r| r.2).max().unwrap_or(0),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spinning_probe_sees_a_forced_gap_and_a_sleeping_probe_records_every_period() {
        // with a zero threshold every stretch between two clock readings counts, and together
        // they cover the whole window; with an unreachable threshold none does
        let all = spinning_loop(&[0], 0, Duration::from_millis(20)).unwrap();
        assert!(all.count > 1000, "{} stretches", all.count);
        assert!(all.lost_ns > 10_000_000 && all.lost_ns <= 40_000_000);
        let none = spinning_loop(&[0], u64::MAX, Duration::from_millis(20)).unwrap();
        assert_eq!((none.count, none.lost_ns, none.max_ns), (0, 0, 0));
        let s = sleeping_loop(&[0], 1_000_000, Duration::from_millis(50)).unwrap();
        assert_eq!(s.lateness.len(), 50);
    }
}
