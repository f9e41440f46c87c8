//! Per-cycle records and the compact binary log both processes stream to disk.
//!
//! The control cycle pushes a fixed-size record into a wait-free ring ([`Recorder`]); a writer
//! thread drains it, encodes blocks of records with bincode and appends them to a log file.
//! Each block is `magic u32 | payload length u32 | crc32 u32 | payload`; a reader stops at the
//! first torn or corrupt block (e.g. after a crash) instead of half-parsing it.

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::clock::{now_ns, sleep_until_ns};
use crate::wire::MAX_AXES;

/// One axis' row of a trace: exactly the trace-format columns (SI, load units for positions
/// of the load, motor units for the motor).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct AxisRecord {
    /// Commanded load position (m or rad).
    pub cmd: f64,
    /// Measured load position (m or rad).
    pub load: f64,
    /// Measured motor position (rad or m).
    pub motor: f64,
    /// Measured motor velocity (rad/s or m/s).
    pub motor_vel: f64,
    /// Torque (N m) / force (N) applied for this cycle.
    pub torque: f64,
}

/// How often the writer thread looks at the ring when it has caught up.
const WRITER_PERIOD: Duration = Duration::from_millis(2);
/// Most records the writer encodes and writes in one go before it lets the core go again.
const WRITER_CHUNK: usize = 64;
/// Pause between two chunks while a small backlog is left.
const WRITER_GAP: Duration = Duration::from_micros(100);

/// `PlantRecord::flags`: the command for this cycle did not arrive in time (held the last one).
pub const REC_MISSED: u8 = 1;
/// `PlantRecord::flags`: the plant itself woke late (more than half a period).
pub const REC_OVERRUN: u8 = 2;
/// `PlantRecord::flags`: the plant woke more than 1 ms late (machine-wide stall).
pub const REC_STALL: u8 = 4;
/// `PlantRecord::flags`: a command with an unexpected sequence number was seen and dropped.
pub const REC_BAD_SEQ: u8 = 8;
/// `PlantRecord::flags`: a command for an earlier cycle arrived late (after its deadline) and
/// was dropped.
pub const REC_LATE_CMD: u8 = 16;
/// `PlantRecord::flags`: a second command for a cycle already answered (a duplicate) was seen
/// and dropped.
pub const REC_DUP_CMD: u8 = 32;
/// `PlantRecord::flags`: while waiting for this cycle's command the plant itself lost its core
/// for at least half a period (realtime runs; a spinning plant polls every few hundred ns), so
/// a miss of this cycle may be the plant's own lateness in looking.
pub const REC_WAIT_INTERRUPTED: u8 = 64;

/// Whether a cycle's `flags` make it a deadline miss: no command arrived in time while the plant
/// itself was on time (a late plant is an overrun, not a miss). The one definition used by the
/// plant's running count, the summary and the swap-window statistics.
#[inline]
pub fn is_deadline_miss(flags: u8) -> bool {
    flags & REC_MISSED != 0 && flags & REC_OVERRUN == 0
}

/// What the plant logs each cycle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PlantRecord {
    /// Cycle number.
    pub seq: u64,
    /// How late the plant woke for this cycle, ns (0 in lockstep).
    pub wake_late_ns: u64,
    /// Sample published -> command received, ns; `u64::MAX` when no command arrived.
    pub latency_ns: u64,
    /// CPU time of the physics step (and sensing), ns.
    pub compute_ns: u32,
    /// `REC_*` flags.
    pub flags: u8,
    /// Per-axis rows.
    pub axes: [AxisRecord; MAX_AXES],
}

/// What the scheduler logs each cycle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SchedRecord {
    /// Cycle number answered.
    pub seq: u64,
    /// CPU time of the trajectory and controller chain, ns.
    pub compute_ns: u32,
    /// Samples skipped because a newer one was already there (realtime catch-up).
    pub skipped: u32,
    /// Longest stretch without progress around this cycle, ns (saturating): from the end of the
    /// previous cycle to the first poll, between two polls while spinning for this sample, from
    /// the last poll to the start of the computation, and the publication of the command. A few
    /// hundred ns normally; tens of microseconds or more when the OS or the hypervisor took the
    /// scheduler's core away. Time blocked in a wait on purpose is not counted.
    pub poll_gap_ns: u32,
    /// Per-axis torque commanded and reference, (N m or N, m or rad).
    pub axes: [(f64, f64); MAX_AXES],
}

const MAGIC: u32 = 0xFEED_100F;

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard().with_fixed_int_encoding()
}

/// Appends blocks of records to a log file.
pub struct LogWriter {
    out: BufWriter<File>,
    buf: Vec<u8>,
}

impl LogWriter {
    /// Creates (truncates) `path`.
    pub fn create(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            out: BufWriter::with_capacity(1 << 20, File::create(path)?),
            buf: Vec::with_capacity(1 << 20),
        })
    }

    /// Writes one block holding `records`, and flushes it to the OS.
    pub fn write_block<T: Serialize>(&mut self, records: &[T]) -> std::io::Result<()> {
        if records.is_empty() {
            return Ok(());
        }
        self.buf.clear();
        bincode::serde::encode_into_std_write(records, &mut self.buf, bincode_config())
            .map_err(std::io::Error::other)?;
        let crc = crc32fast::hash(&self.buf);
        self.out.write_all(&MAGIC.to_le_bytes())?;
        self.out.write_all(&(self.buf.len() as u32).to_le_bytes())?;
        self.out.write_all(&crc.to_le_bytes())?;
        self.out.write_all(&self.buf)?;
        self.out.flush()
    }
}

/// Result of reading a log: the records of all intact blocks, and whether a torn tail was dropped.
#[derive(Debug, Clone)]
pub struct LogContents<T> {
    /// Records of the intact blocks, in order.
    pub records: Vec<T>,
    /// Bytes at the end that did not form an intact block (a crash mid-write), dropped.
    pub torn_bytes: usize,
}

/// Reads every intact block of a log file.
pub fn read_log<T: DeserializeOwned>(path: &Path) -> std::io::Result<LogContents<T>> {
    let mut bytes = Vec::new();
    File::open(path)?.read_to_end(&mut bytes)?;
    let mut records = Vec::new();
    let mut pos = 0usize;
    while bytes.len() - pos >= 12 {
        let word = |o: usize| u32::from_le_bytes(bytes[pos + o..pos + o + 4].try_into().unwrap());
        if word(0) != MAGIC {
            break;
        }
        let len = word(4) as usize;
        let crc = word(8);
        let start = pos + 12;
        if bytes.len() - start < len {
            break;
        }
        let payload = &bytes[start..start + len];
        if crc32fast::hash(payload) != crc {
            break;
        }
        let (mut block, _): (Vec<T>, usize) =
            match bincode::serde::decode_from_slice(payload, bincode_config()) {
                Ok(v) => v,
                Err(_) => break,
            };
        records.append(&mut block);
        pos = start + len;
    }
    Ok(LogContents {
        records,
        torn_bytes: bytes.len() - pos,
    })
}

/// Where in the control period the writer should run: anchor (a cycle's start on
/// [`crate::clock::now_ns`]) and period, ns; period 0 = anywhere.
#[derive(Debug, Default)]
struct Phase {
    anchor_ns: AtomicU64,
    period_ns: AtomicU64,
}

/// Fraction of the period after a cycle's start at which the writer wakes: past the round trip
/// (a few microseconds) and the wake-up jitter of the loop, with most of the period left to
/// write before the next cycle starts.
const WRITER_PHASE: f64 = 0.3;

impl Phase {
    /// The first time at or after `earliest_ns` that sits `WRITER_PHASE` into a period.
    fn next_slot(&self, earliest_ns: u64) -> Option<u64> {
        let period = self.period_ns.load(Ordering::Relaxed);
        if period == 0 {
            return None;
        }
        let first = self.anchor_ns.load(Ordering::Relaxed) + (period as f64 * WRITER_PHASE) as u64;
        let k = earliest_ns.saturating_sub(first).div_ceil(period);
        Some(first + k * period)
    }
}

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
        let (producer, mut consumer) = rtrb::RingBuffer::<T>::new(capacity);
        let mut writer = LogWriter::create(path)?;
        let stop = Arc::new(AtomicBool::new(false));
        let dropped = Arc::new(AtomicU64::new(0));
        let stop2 = stop.clone();
        let phase = Arc::new(Phase::default());
        let phase2 = phase.clone();
        let thread = std::thread::Builder::new()
            .name("feedloop-recorder".into())
            .spawn(move || -> std::io::Result<u64> {
                // Wake when asked, not up to 50 us later (the default timer slack), so that the
                // phase below holds.
                // SAFETY: plain prctl on the calling thread.
                unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1000, 0, 0, 0) };
                let mut block: Vec<T> = Vec::with_capacity(WRITER_CHUNK);
                let mut written = 0u64;
                loop {
                    let finishing = stop2.load(Ordering::Acquire);
                    while block.len() < WRITER_CHUNK {
                        match consumer.pop() {
                            Ok(r) => block.push(r),
                            Err(_) => break,
                        }
                    }
                    if !block.is_empty() {
                        writer.write_block(&block)?;
                        written += block.len() as u64;
                        block.clear();
                    }
                    let backlog = consumer.slots();
                    if backlog == 0 && finishing {
                        return Ok(written);
                    }
                    // On a small machine this thread preempts a spinning loop whenever it runs,
                    // and a loop preempted for more than a period misses its deadline. So it
                    // writes short chunks (tens of microseconds each) and lets the core go in
                    // between, unless the backlog grows (a lockstep run goes as fast as it can):
                    // then it writes without pausing, so that nothing is dropped.
                    if finishing || backlog > capacity / 8 {
                        continue;
                    }
                    let pause = if backlog >= WRITER_CHUNK {
                        WRITER_GAP
                    } else {
                        WRITER_PERIOD
                    };
                    // With a phase (a realtime loop), wake in the slack after a cycle's round
                    // trip, not at a random moment that may fall on the next one.
                    let earliest = now_ns() + pause.as_nanos() as u64;
                    match phase2.next_slot(earliest) {
                        Some(t) => sleep_until_ns(t),
                        None => std::thread::sleep(pause),
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
    /// [`crate::clock::now_ns`], every `period_ns`), so that it writes in the slack after a
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

    #[test]
    fn a_torn_final_block_is_dropped_not_half_parsed() {
        let p = tmp("torn.log");
        let mut w = LogWriter::create(&p).unwrap();
        let recs: Vec<SchedRecord> = (0..100)
            .map(|i| SchedRecord {
                seq: i,
                ..Default::default()
            })
            .collect();
        w.write_block(&recs[..60]).unwrap();
        w.write_block(&recs[60..]).unwrap();
        drop(w);
        let full = std::fs::read(&p).unwrap();
        std::fs::write(&p, &full[..full.len() - 7]).unwrap();
        let log = read_log::<SchedRecord>(&p).unwrap();
        assert_eq!(log.records.len(), 60);
        assert!(log.torn_bytes > 0);
    }
}
