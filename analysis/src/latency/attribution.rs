//! Which deadline misses fell while the plant or the scheduler had lost its core: such a miss
//! is the machine's (the OS or the hypervisor took the CPU away), not the loop's.

use feedloop_trace::log::{PlantRecord, SchedRecord, REC_MISSED, REC_STALL, REC_WAIT_INTERRUPTED};

/// Deadline misses split by whether a process had lost its core when they happened.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Attribution {
    /// Answered cycles around which the scheduler went at least half a period without progress.
    pub scheduler_losses: u64,
    /// Longest such stretch, ns.
    pub scheduler_max_ns: u64,
    /// Missed cycles during whose wait the plant itself lost its core for half a period.
    pub plant_losses: u64,
    /// Misses (outside plant stalls) covered by a core loss of either process.
    pub explained: u64,
    /// Misses outside plant stalls and outside core losses.
    pub unexplained: u64,
}

/// A miss of cycle `s` is covered when the plant lost its core while waiting for it
/// (`REC_WAIT_INTERRUPTED`), or when the first cycle the scheduler answered at or after `s` came
/// after a stretch without progress (or a computation) of at least half a period that reaches
/// back to `s`'s period: the scheduler could not have answered `s` in time.
pub fn attribute_misses(
    plant: &[PlantRecord],
    sched: &[SchedRecord],
    period_ns: u64,
) -> Attribution {
    let half = period_ns / 2;
    let mut a = Attribution::default();
    let lost = |r: &SchedRecord| u64::from(r.poll_gap_ns).max(u64::from(r.compute_ns));
    for r in sched {
        if lost(r) >= half {
            a.scheduler_losses += 1;
            a.scheduler_max_ns = a.scheduler_max_ns.max(lost(r));
        }
    }
    let mut j = 0usize;
    for p in plant {
        if p.flags & REC_MISSED == 0 {
            continue;
        }
        let plant_lost = p.flags & REC_WAIT_INTERRUPTED != 0;
        if plant_lost {
            a.plant_losses += 1;
        }
        if p.flags & REC_STALL != 0 {
            continue;
        }
        // scheduler records are in cycle order: advance to the first at or after this cycle
        while j < sched.len() && sched[j].seq < p.seq {
            j += 1;
        }
        let covered = plant_lost
            || sched.get(j).is_some_and(|r| {
                let g = lost(r);
                g >= half && (r.seq - p.seq) * period_ns <= g + period_ns
            });
        if covered {
            a.explained += 1;
        } else {
            a.unexplained += 1;
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plant(seq: u64, flags: u8) -> PlantRecord {
        PlantRecord {
            seq,
            flags,
            ..Default::default()
        }
    }

    fn sched(seq: u64, poll_gap_us: u32) -> SchedRecord {
        SchedRecord {
            seq,
            compute_ns: 300,
            poll_gap_ns: poll_gap_us * 1000,
            ..Default::default()
        }
    }

    #[test]
    fn misses_are_explained_only_by_a_core_loss_that_reaches_back_to_them() {
        let period = 100_000;
        // cycles 10..=12 missed; the scheduler answered 13 after 350 us without a poll: all three
        // are covered. Cycle 20 missed, but 21 was answered after only 2 us: not covered. Cycle 30
        // missed during a plant stall: neither. Cycle 40 missed and the next answer (45) came
        // after a 120 us loss that cannot reach back five periods: not covered.
        let mut p: Vec<PlantRecord> = (0..50).map(|k| plant(k, 0)).collect();
        for k in [10, 11, 12, 20, 40] {
            p[k].flags = REC_MISSED;
        }
        p[30].flags = REC_MISSED | REC_STALL;
        let mut s: Vec<SchedRecord> = (0..50)
            .filter(|k| ![10, 11, 12, 20, 30, 40, 41, 42, 43, 44].contains(k))
            .map(|k| sched(k, 1))
            .collect();
        for r in s.iter_mut() {
            match r.seq {
                13 => r.poll_gap_ns = 350_000,
                21 => r.poll_gap_ns = 2_000,
                45 => r.poll_gap_ns = 120_000,
                _ => {}
            }
        }
        let a = attribute_misses(&p, &s, period);
        assert_eq!(a.scheduler_losses, 2);
        assert_eq!(a.scheduler_max_ns, 350_000);
        assert_eq!(a.explained, 3);
        assert_eq!(a.unexplained, 2);
        // a long computation counts like a long stretch without a poll
        s.iter_mut().find(|r| r.seq == 21).unwrap().compute_ns = 90_000;
        let b = attribute_misses(&p, &s, period);
        assert_eq!((b.explained, b.unexplained, b.scheduler_losses), (4, 1, 3));
        // and so does the plant losing its core while it waited for cycle 40
        p[40].flags |= REC_WAIT_INTERRUPTED;
        let c = attribute_misses(&p, &s, period);
        assert_eq!((c.explained, c.unexplained, c.plant_losses), (5, 0, 1));
    }
}
