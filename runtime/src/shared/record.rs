//! The recorder both processes use: the control cycle pushes a fixed-size record into a
//! wait-free ring ([`Recorder`]); a writer thread drains it and appends blocks to a log file in
//! the format of [`feedloop_trace::log`].

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use serde::Serialize;

use feedloop_trace::log::LogWriter;

use crate::shared::clock::{now_ns, sleep_until_ns};

/// How often the writer thread looks at the ring when it has caught up and knows no phase.
const WRITER_PERIOD: Duration = Duration::from_millis(2);
/// Most records the writer encodes and writes in one go before it looks at the clock.
const WRITER_CHUNK: usize = 16;
/// Pause between two chunks while a small backlog is left (no phase).
const WRITER_GAP: Duration = Duration::from_micros(100);
/// With a phase, the writer wakes about this often (a power of two of cycles, see
/// [`Phase::every`]): each wake takes a core from a spinning loop and leaves its caches cold
/// for the next round trip, so fewer, fuller wakes touch fewer cycles.
const WRITER_EVERY_S: f64 = 0.03;

/// Where in the control period the writer should run: anchor (a cycle's start on
/// [`crate::shared::clock::now_ns`]) and period, ns; period 0 = anywhere.
#[derive(Debug, Default)]
struct Phase {
    anchor_ns: AtomicU64,
    period_ns: AtomicU64,
}

/// Fraction of the period after a cycle's start at which the writer wakes: past the round trip
/// (a few microseconds) and the wake-up jitter of the loop, with most of the period left to
/// write before the next cycle starts.
const WRITER_PHASE: f64 = 0.3;
/// Fraction of the period after a cycle's start by which the writer lets the core go again,
/// leaving the loop's next wake-up and round trip to it.
const WRITER_PHASE_END: f64 = 0.75;

impl Phase {
    /// The writer's wake-ups fall on the cycles whose number is a multiple of this: a power of
    /// two of about [`WRITER_EVERY_S`] (at most 1024, which both processes' anchors are
    /// multiples of), so that the plant's and the scheduler's writers wake in the same cycles.
    fn every(period_ns: u64) -> u64 {
        let n = (WRITER_EVERY_S * 1e9 / period_ns.max(1) as f64).clamp(1.0, 1024.0) as u64;
        1 << n.ilog2()
    }

    /// The first slot at or after `earliest_ns` that sits `WRITER_PHASE` into a period whose
    /// cycle is a multiple of `every` cycles after the anchor.
    fn next_slot_every(&self, earliest_ns: u64, every: u64) -> Option<u64> {
        let period = self.period_ns.load(Ordering::Relaxed);
        if period == 0 {
            return None;
        }
        let step = period * every.max(1);
        let first = self.anchor_ns.load(Ordering::Relaxed) + (period as f64 * WRITER_PHASE) as u64;
        let k = earliest_ns.saturating_sub(first).div_ceil(step);
        Some(first + k * step)
    }

    /// The first slot at or after `earliest_ns` that sits `WRITER_PHASE` into a period.
    fn next_slot(&self, earliest_ns: u64) -> Option<u64> {
        self.next_slot_every(earliest_ns, 1)
    }

    /// The next slot of the writer's wake-up grid (every [`Phase::every`] cycles).
    fn next_grid_slot(&self, earliest_ns: u64) -> Option<u64> {
        let period = self.period_ns.load(Ordering::Relaxed);
        self.next_slot_every(earliest_ns, Self::every(period))
    }

    /// When the writer, woken at `slot_ns`, must stop: `WRITER_PHASE_END` into that period.
    fn budget_end(&self, slot_ns: u64) -> Option<u64> {
        let period = self.period_ns.load(Ordering::Relaxed);
        (period > 0).then(|| slot_ns + (period as f64 * (WRITER_PHASE_END - WRITER_PHASE)) as u64)
    }
}

/// A reader of every block the writer thread writes (e.g. the scope feed), called on the
/// writer thread after the block reached the log, never on the cycle's thread; with the
/// records the ring has dropped so far.
pub type Tap<T> = Box<dyn FnMut(&[T], u64)>;
/// Makes a [`Tap`] on the writer thread (iceoryx2 ports stay on the thread that made them);
/// `None` when it could not be made (the log is written all the same).
pub type TapFactory<T> = Box<dyn FnOnce() -> Option<Tap<T>> + Send>;

/// The cycle's side of a recorder: a wait-free push that never blocks or allocates.
pub struct Recorder<T: Copy + Send + 'static> {
    producer: rtrb::Producer<T>,
    phase: Arc<Phase>,
    dropped: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<std::io::Result<u64>>>,
    path: PathBuf,
}

impl<T: Copy + Send + Serialize + 'static> Recorder<T> {
    /// Starts a writer thread that appends blocks to `path`; `capacity` records are buffered.
    pub fn start(path: &Path, capacity: usize) -> std::io::Result<Self> {
        Self::start_with_tap(path, capacity, None)
    }

    /// [`Recorder::start`], and hands every written block to the tap `tap` makes.
    pub fn start_with_tap(
        path: &Path,
        capacity: usize,
        tap: Option<TapFactory<T>>,
    ) -> std::io::Result<Self> {
        let (producer, mut consumer) = rtrb::RingBuffer::<T>::new(capacity);
        let mut writer = LogWriter::create(path)?;
        let stop = Arc::new(AtomicBool::new(false));
        let dropped = Arc::new(AtomicU64::new(0));
        let stop2 = stop.clone();
        let dropped2 = dropped.clone();
        let phase = Arc::new(Phase::default());
        let phase2 = phase.clone();
        let thread = std::thread::Builder::new()
            .name("feedloop-recorder".into())
            .spawn(move || -> std::io::Result<u64> {
                // Wake when asked, not up to 50 us later (the default timer slack), so that the
                // phase below holds.
                // SAFETY: plain prctl on the calling thread.
                unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1000, 0, 0, 0) };
                let mut tap = tap.and_then(|make| make());
                let mut block: Vec<T> = Vec::with_capacity(WRITER_CHUNK);
                let mut written = 0u64;
                // the slot this wake was meant for (with a phase), for its time budget
                let mut slot: Option<u64> = None;
                loop {
                    let finishing = stop2.load(Ordering::Acquire);
                    let budget_end = slot.and_then(|s| phase2.budget_end(s));
                    // write chunks until the ring is empty or this period's budget is spent
                    loop {
                        while block.len() < WRITER_CHUNK {
                            match consumer.pop() {
                                Ok(r) => block.push(r),
                                Err(_) => break,
                            }
                        }
                        if block.is_empty() {
                            break;
                        }
                        writer.write_block(&block)?;
                        if let Some(t) = tap.as_mut() {
                            t(&block, dropped2.load(Ordering::Relaxed));
                        }
                        written += block.len() as u64;
                        block.clear();
                        match budget_end {
                            Some(end) if !finishing && now_ns() < end => {}
                            Some(_) => break,
                            // no phase: one chunk per wake, as before
                            None if finishing => {}
                            None => break,
                        }
                    }
                    let backlog = consumer.slots();
                    if backlog == 0 && finishing {
                        return Ok(written);
                    }
                    // On a small machine this thread preempts a spinning loop whenever it runs:
                    // a loop preempted for more than a period misses its deadline, and the round
                    // trip after a wake finds its caches cold. So with a phase (a realtime loop)
                    // it wakes rarely, on the same cycles in both processes, in the slack after
                    // a round trip, writes for at most part of that period, and comes back in
                    // the next period's slack while a backlog is left. Without one (a lockstep
                    // run goes as fast as it can) it writes short chunks and lets the core go in
                    // between. A backlog near the ring's size is written without pausing, so
                    // that nothing is dropped.
                    if finishing || backlog > capacity / 8 {
                        slot = None;
                        continue;
                    }
                    let now = now_ns();
                    slot = if backlog > 0 {
                        phase2.next_slot(now + 1)
                    } else {
                        phase2.next_grid_slot(now + 1)
                    };
                    match slot {
                        Some(t) => sleep_until_ns(t),
                        None => std::thread::sleep(if backlog >= WRITER_CHUNK {
                            WRITER_GAP
                        } else {
                            WRITER_PERIOD
                        }),
                    }
                }
            })?;
        Ok(Self {
            producer,
            phase,
            dropped,
            stop,
            thread: Some(thread),
            path: path.to_path_buf(),
        })
    }

    /// Hands one record to the writer (wait-free). A full ring counts a dropped record.
    #[inline]
    pub fn push(&mut self, r: T) {
        if self.producer.push(r).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Tells the writer where the loop's cycles start (`anchor_ns` on
    /// [`crate::shared::clock::now_ns`], every `period_ns`), so that it writes in the slack after a
    /// cycle instead of preempting the loop at a random moment. Two atomic stores: callable
    /// from the cycle (e.g. when a realtime loop re-anchors its schedule after a stall).
    #[inline]
    pub fn set_phase(&self, anchor_ns: u64, period_ns: u64) {
        self.phase.anchor_ns.store(anchor_ns, Ordering::Relaxed);
        self.phase.period_ns.store(period_ns, Ordering::Relaxed);
    }

    /// Records dropped because the ring was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Flushes everything and stops the writer thread; returns the number of records written.
    pub fn finish(mut self) -> std::io::Result<u64> {
        self.stop.store(true, Ordering::Release);
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| {
                std::io::Error::other(format!(
                    "recorder thread for {} panicked",
                    self.path.display()
                ))
            })?,
            None => Ok(0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use feedloop_trace::log::{read_log, PlantRecord};

    fn tmp(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("feedloop-rec-{}-{name}", std::process::id()))
    }

    #[test]
    fn the_writer_slot_sits_three_tenths_into_the_first_period_not_before_the_earliest() {
        let p = Phase::default();
        assert_eq!(p.next_slot(5), None);
        p.anchor_ns.store(1_000, Ordering::Relaxed);
        p.period_ns.store(100, Ordering::Relaxed);
        assert_eq!(p.next_slot(0), Some(1_030));
        assert_eq!(p.next_slot(1_030), Some(1_030));
        assert_eq!(p.next_slot(1_031), Some(1_130));
        assert_eq!(p.next_slot(10_000), Some(10_030));
        for e in [0u64, 999, 1_234, 987_654] {
            let t = p.next_slot(e).unwrap();
            assert!(
                t >= e && t < e.max(1_030) + 100 && (t - 1_030) % 100 == 0,
                "{e} -> {t}"
            );
        }
    }

    #[test]
    fn the_writer_wakes_on_the_same_cycles_from_any_anchor_that_is_a_multiple_of_1024_cycles() {
        let period = 100_000u64; // 10 kHz
        let every = Phase::every(period);
        assert!(every.is_power_of_two() && 1024 % every == 0);
        assert_eq!(every, 256); // 25.6 ms, about WRITER_EVERY_S
        assert_eq!(Phase::every(1_000_000), 16); // 1 kHz
        assert_eq!(Phase::every(10_000_000_000), 1); // a 10 s period: every cycle
                                                     // the plant anchors at cycle 0, the scheduler at a cycle it answered that is a
                                                     // multiple of 1024 (a little later: the sample's way to it)
        let plant = Phase::default();
        plant.anchor_ns.store(5_000_000, Ordering::Relaxed);
        plant.period_ns.store(period, Ordering::Relaxed);
        let sched = Phase::default();
        sched
            .anchor_ns
            .store(5_000_000 + 3 * 1024 * period + 900, Ordering::Relaxed);
        sched.period_ns.store(period, Ordering::Relaxed);
        let cycle_of = |t: u64| (t - 5_000_000) / period;
        for earliest in [5_400_000_000u64, 5_400_012_345, 6_000_000_000] {
            let (p, s) = (
                plant.next_grid_slot(earliest).unwrap(),
                sched.next_grid_slot(earliest).unwrap(),
            );
            assert_eq!(cycle_of(p), cycle_of(s), "{earliest}");
            assert_eq!(cycle_of(p) % every, 0);
            assert!(p >= earliest && p < earliest + every * period);
            // 0.3 into its period, done by 0.75 of it
            assert_eq!((p - 5_000_000) % period, 30_000);
            assert_eq!(plant.budget_end(p), Some(p + 45_000));
        }
    }

    #[test]
    fn recorder_writes_every_record_in_order() {
        let p = tmp("order.log");
        let mut r = Recorder::<PlantRecord>::start(&p, 1024).unwrap();
        for i in 0..10_000u64 {
            r.push(PlantRecord {
                seq: i,
                ..Default::default()
            });
            if i % 500 == 0 {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        let dropped = r.dropped();
        let n = r.finish().unwrap();
        let log = read_log::<PlantRecord>(&p).unwrap();
        assert_eq!(n + dropped, 10_000);
        assert_eq!(log.records.len() as u64, n);
        assert!(log.records.windows(2).all(|w| w[1].seq > w[0].seq));
        assert_eq!(log.torn_bytes, 0);
    }
}
