//! The per-cycle records both processes log, and the binary log format they are stored in.
//!
//! Each block is `magic u32 | payload length u32 | crc32 u32 | payload` (bincode records); a
//! reader stops at the first torn or corrupt block (e.g. after a crash) instead of half-parsing
//! it. The ring and writer thread that produce such logs live in the runtime
//! (`feedloop_runtime::shared::record::Recorder`).

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use feedloop_control::axis_io::{AxisCommand, AxisSensor};
use feedloop_model::MAX_AXES;

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

impl AxisRecord {
    /// The row of one axis in one cycle: what was measured at its start (`s`) and what was
    /// commanded and applied for it (`c`). The one place a cycle becomes a trace row, in the
    /// plant process and in the simulation alike.
    #[inline]
    pub fn of(s: &AxisSensor, c: &AxisCommand) -> Self {
        Self {
            cmd: c.reference,
            load: s.load_pos,
            motor: s.motor_pos,
            motor_vel: s.motor_vel,
            torque: c.torque,
        }
    }
}

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
/// `PlantRecord::flags`: the plant is bringing the axes to a safe stop in this cycle (a limit,
/// a plugin fault or an operator stop); the first such cycle is where the stop began.
pub const REC_STOPPING: u8 = 128;

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
    /// Monotonic clock (CLOCK_MONOTONIC, shared by the processes) just before the sample was
    /// published, ns: with `latency_ns` and the scheduler's times it splits the round trip.
    pub published_ns: u64,
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
    /// Monotonic clock (shared with the plant) at the poll that found the sample, ns.
    pub received_ns: u64,
    /// ... when the cycle's computation began (after the control plane's look), ns.
    pub started_ns: u64,
    /// ... when the command was ready (chain and vetting done), ns.
    pub computed_ns: u64,
    /// ... when the command's publication returned, ns.
    pub sent_ns: u64,
    /// Per-axis torque commanded and reference, (N m or N, m or rad).
    pub axes: [(f64, f64); MAX_AXES],
    /// Per-axis stage outputs: the velocity command the velocity stage followed (position stage
    /// plus feedforward, motor units/s) and the torque feedforward added to its output
    /// (feedforward and compensator stages, N m or N).
    pub stages: [(f64, f64); MAX_AXES],
}

/// Log file magic; bumped with every record layout change (0xFEED_100F before the round-trip
/// timestamps of issue 18, 0xFEED_1010 before the stage outputs of issue 16), so an older log
/// is refused instead of misread.
const MAGIC: u32 = 0xFEED_1011;
const OLDER_MAGICS: [(u32, &str); 2] = [
    (0xFEED_100F, "records without the round-trip timestamps"),
    (0xFEED_1010, "scheduler records without the stage outputs"),
];

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

/// Encodes `records` into `out` in the log's record encoding (what a log block's payload holds);
/// returns the bytes used, or `None` when they do not fit.
pub fn encode_records<T: Serialize>(records: &[T], out: &mut [u8]) -> Option<usize> {
    bincode::serde::encode_into_slice(records, out, bincode_config()).ok()
}

/// Decodes records written by [`encode_records`].
pub fn decode_records<T: DeserializeOwned>(bytes: &[u8]) -> Option<Vec<T>> {
    bincode::serde::decode_from_slice(bytes, bincode_config())
        .ok()
        .map(|(v, _)| v)
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
            if let Some((_, what)) = OLDER_MAGICS.iter().find(|(m, _)| pos == 0 && word(0) == *m) {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!(
                        "{}: a log of an older feedloop ({what}); read it with the version \
                         that wrote it",
                        path.display()
                    ),
                ));
            }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> std::path::PathBuf {
        std::env::temp_dir().join(format!("feedloop-log-{}-{name}", std::process::id()))
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
