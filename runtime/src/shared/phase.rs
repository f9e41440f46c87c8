//! Where in the period the host leaves the core alone.
//!
//! A virtual machine (and a kernel whose tick cannot be switched off) takes the core away at a
//! fixed rhythm: on the machine these figures were taken on, every 4 ms timer tick costs a
//! spinning thread 10-60 us, on both cores at once. When the loop's period divides that rhythm
//! (100 us into 4 ms), the interruption falls at the same point of every 40th cycle for the whole
//! run. If that point is the round trip, one cycle in 40 is 10-60 us late and the p99 of the round
//! trip is the interruption's length; a few microseconds later in the period, it costs nothing.
//! Which of the two a run gets used to be decided by the instant the loop happened to close.
//!
//! [`probe`] spins on the clock for a short while and keeps every stretch the core was away.
//! [`Probe::quiet_phase`] then names the phase of the period (`CLOCK_MONOTONIC` modulo the
//! period) at which a window around a cycle's start lost the least time to those stretches, and
//! [`next_at_phase`] the first instant at that phase: the plant starts its schedule there, and
//! keeps the phase when it re-anchors after a stall.
//!
//! When nothing interrupted the probe, or the interruptions do not keep a phase (their rhythm
//! does not divide into the period), every phase costs about the same and the choice changes
//! nothing.

use super::clock::now_ns;

/// A stretch between two clock reads longer than this is the core being away (a spinning read
/// takes 20-50 ns).
pub const AWAY_NS: u64 = 1_000;

/// At most this many phase bins (bins are at least [`MIN_BIN_NS`] wide).
const MAX_BINS: u64 = 4_096;
/// Narrowest phase bin, ns.
const MIN_BIN_NS: u64 = 250;
/// At most this many stretches away are kept (a probe of 0.5 s on a noisy host sees 100-1,600).
const MAX_AWAY: usize = 1 << 13;

/// What a probe saw: the stretches the core was away.
#[derive(Debug, Clone, PartialEq)]
pub struct Probe {
    /// Period the phases are taken modulo, ns.
    pub period_ns: u64,
    /// How long the probe watched, ns.
    pub span_ns: u64,
    /// Stretches away `[from, to)` on `CLOCK_MONOTONIC`, ns.
    away: Vec<(u64, u64)>,
}

/// The phase chosen and what it is worth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuietPhase {
    /// Phase of the period's start, ns after a multiple of the period on `CLOCK_MONOTONIC`.
    pub phase_ns: u64,
    /// Share of the probe's periods whose window at that phase was interrupted (0..1).
    pub hit_share: f64,
    /// Time those interruptions lasted, per period, ns.
    pub delay_ns: f64,
    /// Share of periods interrupted at the worst phase: what an unlucky start would have cost.
    pub worst_hit_share: f64,
    /// Time lost per period at the worst phase, ns.
    pub worst_delay_ns: f64,
}

impl Probe {
    /// An empty probe of `period_ns` (no time watched yet).
    pub fn new(period_ns: u64) -> Probe {
        Probe {
            period_ns: period_ns.max(1),
            span_ns: 0,
            away: Vec::with_capacity(MAX_AWAY),
        }
    }

    /// Adds a stretch away from the core, `[from_ns, to_ns)` on `CLOCK_MONOTONIC`.
    pub fn add_away(&mut self, from_ns: u64, to_ns: u64) {
        if to_ns > from_ns && self.away.len() < MAX_AWAY {
            self.away.push((from_ns, to_ns));
        }
    }

    /// Stretches away seen.
    pub fn interruptions(&self) -> usize {
        self.away.len()
    }

    /// Longest stretch away, ns.
    pub fn longest_ns(&self) -> u64 {
        self.away.iter().map(|&(a, b)| b - a).max().unwrap_or(0)
    }

    /// Per phase of the period's start (bins of `period / bins`): how many of the probe's
    /// stretches away shorter than a period overlapped the window
    /// `[start - window/4, start + 3 window/4)` of a period starting at that phase, and how long
    /// they were in all, ns.
    pub fn hits(&self, window_ns: u64) -> Vec<(u64, u64)> {
        let t = self.period_ns;
        let n = (t / MIN_BIN_NS).clamp(1, MAX_BINS);
        let bin = t as f64 / n as f64;
        let n = n as usize;
        let before = window_ns / 4;
        let after = window_ns - before;
        // difference arrays over the bins (circular ranges split in two)
        let mut count = vec![0i64; n + 1];
        let mut delay = vec![0i64; n + 1];
        let (mut all_count, mut all_delay) = (0i64, 0i64);
        // a stretch of a period or more hits every phase alike: it says nothing of where to
        // start, and is left out
        for &(a, b) in self.away.iter().filter(|&&(a, b)| b - a < t) {
            let w = (b - a) as i64;
            // period starts s with the window overlapping [a, b): a - after < s < b + before
            let lo = a.saturating_sub(after) + 1;
            let len = (b + before).saturating_sub(lo);
            let whole = (len / t) as i64;
            all_count += whole;
            all_delay += whole * w;
            let rem = len % t;
            if rem == 0 {
                continue;
            }
            let i0 = ((lo % t) as f64 / bin) as usize % n;
            let i1 = (((lo % t) + rem - 1) as f64 / bin) as usize; // may pass n: wraps
            let mut add = |from: usize, to: usize| {
                count[from] += 1;
                count[to] -= 1;
                delay[from] += w;
                delay[to] -= w;
            };
            if i1 < n {
                add(i0, i1 + 1);
            } else {
                add(i0, n);
                add(0, (i1 - n + 1).min(n));
            }
        }
        let (mut c, mut d) = (all_count, all_delay);
        (0..n)
            .map(|i| {
                c += count[i];
                d += delay[i];
                (c.max(0) as u64, d.max(0) as u64)
            })
            .collect()
    }

    /// The phase at which a window of `window_ns` (the period's start, `window_ns / 4` before
    /// it to `3 window_ns / 4` after it) lost the least time to interruptions, in the middle of
    /// the widest stretch of phases that are about as good; `None` when the probe saw no
    /// interruption or watched less than a period.
    pub fn quiet_phase(&self, window_ns: u64) -> Option<QuietPhase> {
        if self.away.is_empty() || self.span_ns < self.period_ns {
            return None;
        }
        let hits = self.hits(window_ns);
        let cost: Vec<u64> = hits.iter().map(|h| h.1).collect();
        let n = cost.len();
        let min = *cost.iter().min()?;
        let worst = (0..n).max_by_key(|&i| cost[i])?;
        let max = cost[worst];
        let good = |c: u64| c <= min + (max - min) / 20;
        // the widest circular run of good bins, and its middle
        let mut best_mid = cost.iter().position(|&c| c == min)?;
        if let Some(start) = (0..n).find(|&i| !good(cost[i])) {
            let (mut run, mut best_len) = (0usize, 0usize);
            for step in 1..=n {
                let i = (start + step) % n;
                if good(cost[i]) {
                    run += 1;
                    if run > best_len {
                        best_len = run;
                        best_mid = (i + n + 1 - run.div_ceil(2)) % n;
                    }
                } else {
                    run = 0;
                }
            }
        }
        let periods = self.span_ns as f64 / self.period_ns as f64;
        let bin = self.period_ns as f64 / n as f64;
        Some(QuietPhase {
            phase_ns: (((best_mid as f64 + 0.5) * bin) as u64).min(self.period_ns - 1),
            hit_share: (hits[best_mid].0 as f64 / periods).min(1.0),
            delay_ns: hits[best_mid].1 as f64 / periods,
            worst_hit_share: (hits[worst].0 as f64 / periods).min(1.0),
            worst_delay_ns: hits[worst].1 as f64 / periods,
        })
    }
}

/// What a run's start-up probe found and chose (`plant.json`'s `phase`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhaseChoice {
    /// How long the probe watched, s.
    pub probe_s: f64,
    /// Stretches away from the core it saw.
    pub interruptions: usize,
    /// The longest, ns.
    pub longest_ns: u64,
    /// Window the phase was chosen for, ns.
    pub window_ns: u64,
    /// The phase chosen, if the probe saw anything to avoid.
    pub quiet: Option<QuietPhase>,
}

/// The window a period's start is kept clear for: a fifth of the period, within 2..50 us (a
/// round trip takes 1-3 us; the plant wakes a little before the deadline).
pub fn window_ns(period_ns: u64) -> u64 {
    (period_ns / 5).clamp(2_000, 50_000).min(period_ns)
}

/// Probes for `probe_s` (on the calling thread) and chooses the phase for `period_ns`.
pub fn choose(period_ns: u64, probe_s: f64) -> PhaseChoice {
    let p = probe(period_ns, (probe_s.max(0.0) * 1e9) as u64);
    let window_ns = window_ns(period_ns);
    PhaseChoice {
        probe_s: p.span_ns as f64 * 1e-9,
        interruptions: p.interruptions(),
        longest_ns: p.longest_ns(),
        window_ns,
        quiet: p.quiet_phase(window_ns),
    }
}

/// Spins on the clock for `span_ns` and records where in `period_ns` the core was away.
/// Call it on the thread (and CPU) that will run the loop.
pub fn probe(period_ns: u64, span_ns: u64) -> Probe {
    let mut p = Probe::new(period_ns);
    let start = now_ns();
    let end = start.saturating_add(span_ns);
    let mut last = start;
    loop {
        let t = now_ns();
        if t - last > AWAY_NS {
            p.add_away(last, t);
        }
        last = t;
        if t >= end {
            break;
        }
    }
    p.span_ns = last - start;
    p
}

/// The first instant at or after `now_ns` whose phase in `period_ns` is `phase_ns`.
pub fn next_at_phase(now_ns: u64, period_ns: u64, phase_ns: u64) -> u64 {
    let period_ns = period_ns.max(1);
    let phase_ns = phase_ns % period_ns;
    let base = now_ns - now_ns % period_ns + phase_ns;
    if base >= now_ns {
        base
    } else {
        base + period_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A host that takes the core every `every` periods at `at_ns` into the period for `len_ns`.
    fn rhythmic(period: u64, periods: u64, every: u64, at_ns: u64, len_ns: u64) -> Probe {
        let mut p = Probe::new(period);
        let t0 = 7 * period; // any multiple: phases are taken on the absolute clock
        let mut k = 0;
        while k < periods {
            let s = t0 + k * period + at_ns;
            p.add_away(s, s + len_ns);
            k += every;
        }
        p.span_ns = periods * period;
        p
    }

    #[test]
    fn the_chosen_phase_keeps_the_window_clear_of_a_rhythmic_interruption() {
        // 100 us period, 40 us away every 40th period starting 98 us into it (this machine's
        // tick): lost phases 98..100 and 0..38 us
        let p = rhythmic(100_000, 4_000, 40, 98_000, 40_000);
        let q = p.quiet_phase(20_000).expect("interruptions were seen");
        // window [phase - 5 us, phase + 15 us] inside the clear 38..98 us
        assert!(
            q.phase_ns >= 43_000 && q.phase_ns <= 83_000,
            "phase {} ns",
            q.phase_ns
        );
        // in the middle of the clear stretch, not at its edge
        assert!((q.phase_ns as i64 - 63_000).abs() <= 3_000, "{q:?}");
        assert_eq!(q.hit_share, 0.0);
        assert_eq!(q.delay_ns, 0.0);
        // the worst phase is hit by every interruption: one period in 40
        assert!((q.worst_hit_share - 1.0 / 40.0).abs() < 0.005, "{q:?}");
    }

    #[test]
    fn an_interruption_across_the_period_boundary_is_found_on_both_sides() {
        // away from 90 us to 30 us of the next period (wraps); window 10 us: 2.5 us before
        // the start, 7.5 us after
        let p = rhythmic(100_000, 1_000, 10, 90_000, 40_000);
        let hits = p.hits(10_000);
        let bin = 100_000 / hits.len() as u64;
        let at = |us: u64| hits[(us * 1_000 / bin) as usize].0;
        // hit: starts from 82.5 us (window reaches 90) round to 32.5 us (window starts at 30)
        for us in [83, 90, 99, 0, 10, 32] {
            assert_eq!(at(us), 100, "start at {us} us");
        }
        for us in [34, 50, 81] {
            assert_eq!(at(us), 0, "start at {us} us");
        }
        let q = p.quiet_phase(10_000).unwrap();
        assert!((q.phase_ns as i64 - 57_500).abs() <= 1_000, "{q:?}");
        assert!((q.worst_hit_share - 0.1).abs() < 1e-9, "{q:?}");
        // every 10th period loses 40 us in the worst window: 4 us per period on average
        assert!((q.worst_delay_ns - 4_000.0).abs() < 1e-6, "{q:?}");
        assert_eq!(q.delay_ns, 0.0);
    }

    #[test]
    fn a_stretch_of_a_period_or_more_says_nothing_of_the_phase() {
        let mut p = rhythmic(100_000, 4_000, 40, 98_000, 40_000);
        let before = p.hits(20_000);
        p.add_away(1_000_000, 1_000_000 + 250_000);
        p.add_away(3_000_000, 3_000_000 + 100_000);
        assert_eq!(p.hits(20_000), before);
        assert_eq!(p.longest_ns(), 250_000);
        assert_eq!(p.interruptions(), 102);
    }

    #[test]
    fn a_stretch_just_short_of_a_period_hits_nearly_every_phase_once() {
        let mut p = Probe::new(100_000);
        p.add_away(1_000_000, 1_000_000 + 90_000);
        let hits = p.hits(20_000);
        // 90 us + the 20 us window: a start in any phase but none overlaps it once or twice
        assert!(
            hits.iter()
                .all(|&(c, d)| c == d / 90_000 && (1..=2).contains(&c)),
            "{hits:?}"
        );
        assert_eq!(hits.iter().filter(|h| h.0 == 2).count(), hits.len() / 10);
    }

    #[test]
    fn short_scattered_interruptions_do_not_outweigh_a_long_rhythmic_one() {
        // 40 us at 98 us every 40th period, and a 1.5 us one every 3rd period, walking through
        // the phases (37 us further each time)
        let mut p = rhythmic(100_000, 4_000, 40, 98_000, 40_000);
        for k in (0..4_000u64).step_by(3) {
            let s = 700_000 + k * 100_000 + (k * 37_000) % 100_000;
            p.add_away(s, s + 1_500);
        }
        let q = p.quiet_phase(20_000).unwrap();
        assert!(q.phase_ns >= 43_000 && q.phase_ns <= 83_000, "{q:?}");
        // the short ones still hit the window often; the long one never
        assert!(q.hit_share > 0.05 && q.delay_ns < 200.0, "{q:?}");
        assert!(q.worst_delay_ns > 900.0, "{q:?}");
    }

    #[test]
    fn no_interruption_or_too_short_a_look_chooses_nothing() {
        let mut p = Probe::new(100_000);
        p.span_ns = 1_000_000;
        assert_eq!(p.quiet_phase(20_000), None);
        let mut short = rhythmic(100_000, 1, 1, 50_000, 5_000);
        short.span_ns = 50_000;
        assert_eq!(short.quiet_phase(20_000), None);
    }

    #[test]
    fn next_at_phase_is_the_first_instant_at_that_phase() {
        assert_eq!(next_at_phase(1_000_000, 100_000, 60_000), 1_060_000);
        assert_eq!(next_at_phase(1_070_000, 100_000, 60_000), 1_160_000);
        assert_eq!(next_at_phase(1_060_000, 100_000, 60_000), 1_060_000);
        assert_eq!(next_at_phase(1_060_000, 100_000, 160_000), 1_060_000);
        for now in [0u64, 1, 99_999, 123_456_789] {
            let t = next_at_phase(now, 100_000, 42_000);
            assert!(t >= now && t - now < 100_000 && t % 100_000 == 42_000);
        }
    }

    #[test]
    fn a_real_probe_watches_as_long_as_asked() {
        let p = probe(100_000, 2_000_000);
        assert!(p.span_ns >= 2_000_000, "{}", p.span_ns);
        let away: u64 = p.away.iter().map(|&(a, b)| b - a).sum();
        assert!(away <= p.span_ns);
        assert!(p.away.iter().all(|&(a, b)| b - a > AWAY_NS));
    }
}
