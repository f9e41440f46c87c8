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

use crate::shared::clock::now_ns;

/// How long the writer waits for a kick before it looks at the ring anyway: without a phase
/// (a lockstep run, a test), and as a fallback with one.
const WRITER_PERIOD: Duration = Duration::from_millis(2);
/// The same with a phase: the loop kicks the writer (see [`Recorder::push`]), so this only
/// matters when the loop has stopped pushing.
const WRITER_IDLE: Duration = Duration::from_millis(100);
/// Most records the writer encodes into one block (one `write`) before it looks at the clock:
/// a wake of the writer costs the loop more than the records it writes, so each writes many.
const WRITER_CHUNK: usize = 256;
/// With a phase, the loop kicks the writer about this often (a power of two of cycles, see
/// [`Phase::every`]): each wake takes the core from a spinning loop and leaves its caches cold
/// for the next round trip, so fewer, fuller wakes touch fewer cycles.
const WRITER_EVERY_S: f64 = 0.03;
/// Fraction of the period after a cycle's start by which the writer lets the core go again,
/// leaving the loop's next wake-up and round trip to it.
const WRITER_PHASE_END: f64 = 0.75;

/// Where the loop's control periods lie: anchor (a cycle's start on
/// [`crate::shared::clock::now_ns`]) and period, ns; period 0 = unknown (no budget).
#[derive(Debug)]
struct Phase {
    anchor_ns: AtomicU64,
    period_ns: AtomicU64,
    /// Records between two kicks of the writer.
    every: AtomicU64,
}

impl Default for Phase {
    fn default() -> Self {
        Self {
            anchor_ns: AtomicU64::new(0),
            period_ns: AtomicU64::new(0),
            every: AtomicU64::new(WRITER_CHUNK as u64),
        }
    }
}

impl Phase {
    /// Cycles between two kicks at `period_ns`: a power of two of about [`WRITER_EVERY_S`]
    /// (1 to 1024), never more than a block holds.
    fn every(period_ns: u64) -> u64 {
        let n = (WRITER_EVERY_S * 1e9 / period_ns.max(1) as f64).clamp(1.0, 1024.0) as u64;
        (1u64 << n.ilog2()).min(WRITER_CHUNK as u64)
    }

    /// When a writer kicked at `now_ns` must stop: `WRITER_PHASE_END` into the period `now_ns`
    /// falls in; `None` without a phase.
    fn budget_end(&self, now_ns: u64) -> Option<u64> {
        let period = self.period_ns.load(Ordering::Relaxed);
        if period == 0 {
            return None;
        }
        let anchor = self.anchor_ns.load(Ordering::Relaxed);
        let start = anchor + now_ns.saturating_sub(anchor) / period * period;
        Some(start + (period as f64 * WRITER_PHASE_END) as u64)
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
    /// The writer thread, to kick.
    writer: std::thread::Thread,
    /// Records pushed (kicks fall on multiples of the phase's `every`).
    pushed: u64,
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
                // how long the last block took to write, ns
                let mut chunk_ns = 0u64;
                loop {
                    let finishing = stop2.load(Ordering::Acquire);
                    let budget_end = if finishing {
                        None
                    } else {
                        phase2.budget_end(now_ns())
                    };
                    // write blocks until the ring is empty or this period's budget is spent: a
                    // further block starts only when the last one's time still fits (the first
                    // needs only to start in time: an estimate that never fits must not stop
                    // the writing)
                    let mut chunks = 0u32;
                    loop {
                        if let Some(end) = budget_end {
                            let need = if chunks == 0 { 0 } else { chunk_ns };
                            if now_ns().saturating_add(need) >= end {
                                break;
                            }
                        }
                        chunks += 1;
                        while block.len() < WRITER_CHUNK {
                            match consumer.pop() {
                                Ok(r) => block.push(r),
                                Err(_) => break,
                            }
                        }
                        if block.is_empty() {
                            break;
                        }
                        let t0 = now_ns();
                        writer.write_block(&block)?;
                        if let Some(t) = tap.as_mut() {
                            t(&block, dropped2.load(Ordering::Relaxed));
                        }
                        written += block.len() as u64;
                        block.clear();
                        chunk_ns = now_ns().saturating_sub(t0);
                    }
                    let backlog = consumer.slots();
                    if backlog == 0 && finishing {
                        return Ok(written);
                    }
                    // On a small machine this thread preempts a spinning loop whenever it runs:
                    // a loop preempted for more than a period misses its deadline, and the round
                    // trip after a wake finds its caches cold; a timer wakes it tens of
                    // microseconds late on a VM, often into the next cycle. So the loop kicks it,
                    // in its slack right after a cycle, every `every` records (about 30 ms, on
                    // the same cycles in both processes), and it writes for at most part of
                    // that period. A backlog near the ring's size is written without pausing,
                    // so that nothing is dropped.
                    if finishing || backlog > capacity / 8 {
                        continue;
                    }
                    let phased = phase2.period_ns.load(Ordering::Relaxed) > 0;
                    std::thread::park_timeout(if phased { WRITER_IDLE } else { WRITER_PERIOD });
                }
            })?;
        let writer = thread.thread().clone();
        Ok(Self {
            producer,
            phase,
            writer,
            pushed: 0,
            dropped,
            stop,
            thread: Some(thread),
            path: path.to_path_buf(),
        })
    }

    /// Hands one record to the writer (wait-free). A full ring counts a dropped record. Every
    /// so many records (about 30 ms of a realtime loop's cycles) it kicks the writer, which then
    /// writes in the rest of this period: called after a cycle's work, so the writer runs in
    /// its slack. A kick is an atomic swap, and a futex wake when the writer sleeps.
    #[inline]
    pub fn push(&mut self, r: T) {
        if self.producer.push(r).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
        self.pushed += 1;
        if self
            .pushed
            .is_multiple_of(self.phase.every.load(Ordering::Relaxed).max(1))
        {
            self.writer.unpark();
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
        self.phase
            .every
            .store(Phase::every(period_ns), Ordering::Relaxed);
    }

    /// Records dropped because the ring was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Flushes everything and stops the writer thread; returns the number of records written.
    pub fn finish(mut self) -> std::io::Result<u64> {
        self.stop.store(true, Ordering::Release);
        self.writer.unpark();
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
    fn the_writer_is_kicked_every_power_of_two_cycles_and_stops_by_three_quarters_of_the_period() {
        assert_eq!(Phase::every(100_000), 256); // 10 kHz: 25.6 ms
        assert_eq!(Phase::every(1_000_000), 16); // 1 kHz: 16 ms
        assert_eq!(Phase::every(10_000_000_000), 1); // a 10 s period: every cycle
                                                     // both processes count records from their cycle 0, so kicks at multiples of `every`
                                                     // fall on the same cycles in both
        assert!(1024 % Phase::every(250_000) == 0);
        let p = Phase::default();
        assert_eq!(p.budget_end(123), None);
        p.anchor_ns.store(5_000, Ordering::Relaxed);
        p.period_ns.store(1_000, Ordering::Relaxed);
        // kicked 30 ns into the period that starts at 9_000: done by 9_750
        assert_eq!(p.budget_end(9_030), Some(9_750));
        assert_eq!(p.budget_end(9_999), Some(9_750));
        assert_eq!(p.budget_end(10_000), Some(10_750));
        assert_eq!(p.budget_end(4_000), Some(5_750));
    }

    #[test]
    fn a_kicked_writer_keeps_every_record_of_a_paced_loop() {
        let p = tmp("kicked.log");
        let period = 100_000u64;
        let mut r = Recorder::<PlantRecord>::start(&p, 1 << 12).unwrap();
        let t0 = now_ns();
        r.set_phase(t0, period);
        for i in 0..5_000u64 {
            crate::shared::clock::spin_until_ns(t0 + i * period);
            r.push(PlantRecord {
                seq: i,
                ..Default::default()
            });
        }
        assert_eq!(r.dropped(), 0);
        assert_eq!(r.finish().unwrap(), 5_000);
        let log = read_log::<PlantRecord>(&p).unwrap();
        assert!(log
            .records
            .iter()
            .enumerate()
            .all(|(i, r)| r.seq == i as u64));
        assert_eq!(log.records.len(), 5_000);
        let _ = std::fs::remove_file(&p);
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
        let _ = std::fs::remove_file(&p);
    }
}
