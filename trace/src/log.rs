//! The per-cycle records both processes log, and the binary log format they are stored in.
//!
//! Each block is `magic u32 | payload length u32 | crc32 u32 | payload` (bincode records; the
//! per-axis arrays of a record hold only their used prefix, see [`used_prefix`]); a reader stops at the first torn or corrupt block (e.g. after a crash) instead of half-parsing
//! it. The ring and writer thread that produce such logs live in the runtime
//! (`feedloop_runtime::shared::record::Recorder`).

use std::fs::File;
use std::io::{Read, Write};
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
    #[serde(with = "used_prefix")]
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
    /// ... when the sample was held and the cycle's work began (the catch-up when needed, the
    /// control plane's look, the chain), ns.
    pub started_ns: u64,
    /// ... when the command was ready (chain and vetting done), ns.
    pub computed_ns: u64,
    /// ... when the command's publication returned, ns.
    pub sent_ns: u64,
    /// Per-axis torque commanded and reference, (N m or N, m or rad).
    #[serde(with = "used_prefix")]
    pub axes: [(f64, f64); MAX_AXES],
    /// Per-axis stage outputs: the velocity command the velocity stage followed (position stage
    /// plus feedforward, motor units/s) and the torque feedforward added to its output
    /// (feedforward and compensator stages, N m or N).
    #[serde(with = "used_prefix")]
    pub stages: [(f64, f64); MAX_AXES],
}

/// An entry of a per-axis array whose bits are all zero (an axis the job does not have).
pub trait Blank {
    /// Whether every field is +0.0 (bit for bit, so that leaving it out loses nothing).
    fn is_blank(&self) -> bool;
}

impl Blank for AxisRecord {
    fn is_blank(&self) -> bool {
        [self.cmd, self.load, self.motor, self.motor_vel, self.torque]
            .iter()
            .all(|v| v.to_bits() == 0)
    }
}

impl Blank for (f64, f64) {
    fn is_blank(&self) -> bool {
        self.0.to_bits() == 0 && self.1.to_bits() == 0
    }
}

/// Serde of a per-axis array as its used prefix: a length, then the entries up to the last one
/// that is not [`Blank`]; read back into the whole array with blank entries after it. A job with
/// two axes writes two entries instead of eight, which makes a record about three times smaller
/// and its encoding, on the recorder's thread in the loop's slack, as much faster. Lossless: the
/// entries left out are exactly the array's defaults.
pub mod used_prefix {
    use super::Blank;
    use serde::de::{Deserializer, Error, SeqAccess, Visitor};
    use serde::{Deserialize, Serialize, Serializer};
    use std::marker::PhantomData;

    /// Writes the used prefix of `a`.
    pub fn serialize<S: Serializer, T: Serialize + Blank, const N: usize>(
        a: &[T; N],
        s: S,
    ) -> Result<S::Ok, S::Error> {
        let n = a.iter().rposition(|x| !x.is_blank()).map_or(0, |i| i + 1);
        s.collect_seq(&a[..n])
    }

    struct Prefix<T, const N: usize>(PhantomData<T>);

    impl<'de, T: Deserialize<'de> + Default + Copy, const N: usize> Visitor<'de> for Prefix<T, N> {
        type Value = [T; N];

        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(f, "at most {N} per-axis entries")
        }

        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
            let mut out = [T::default(); N];
            let mut i = 0;
            while let Some(x) = seq.next_element()? {
                if i == N {
                    return Err(A::Error::invalid_length(i + 1, &self));
                }
                out[i] = x;
                i += 1;
            }
            Ok(out)
        }
    }

    /// Reads a used prefix back into the whole array.
    pub fn deserialize<
        'de,
        D: Deserializer<'de>,
        T: Deserialize<'de> + Default + Copy,
        const N: usize,
    >(
        d: D,
    ) -> Result<[T; N], D::Error> {
        d.deserialize_seq(Prefix::<T, N>(PhantomData))
    }
}

/// Log file magic; bumped with every record layout change (0xFEED_100F before the round-trip
/// timestamps of issue 18, 0xFEED_1010 before the stage outputs of issue 16, 0xFEED_1011 before
/// the used-prefix per-axis arrays), so an older log is refused instead of misread.
const MAGIC: u32 = 0xFEED_1012;
const OLDER_MAGICS: [(u32, &str); 3] = [
    (0xFEED_100F, "records without the round-trip timestamps"),
    (0xFEED_1010, "scheduler records without the stage outputs"),
    (0xFEED_1011, "records with all eight axes written out"),
];

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard().with_fixed_int_encoding()
}

/// Appends blocks of records to a log file.
pub struct LogWriter {
    out: File,
    /// A block being built: 12 header bytes, then the encoded records.
    buf: Vec<u8>,
}

impl LogWriter {
    /// Creates (truncates) `path`.
    pub fn create(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            out: File::create(path)?,
            buf: vec![0; 1 << 16],
        })
    }

    /// Writes one block holding `records` to the OS: encoded in place behind the block's
    /// header, one `write` for the whole block (a recorder writes in a control period's slack).
    pub fn write_block<T: Serialize>(&mut self, records: &[T]) -> std::io::Result<()> {
        if records.is_empty() {
            return Ok(());
        }
        let len = loop {
            match bincode::serde::encode_into_slice(records, &mut self.buf[12..], bincode_config())
            {
                Ok(n) => break n,
                Err(bincode::error::EncodeError::UnexpectedEnd) => {
                    let grown = self.buf.len() * 2;
                    self.buf.resize(grown, 0);
                }
                Err(e) => return Err(std::io::Error::other(e)),
            }
        };
        let crc = crc32fast::hash(&self.buf[12..12 + len]);
        self.buf[0..4].copy_from_slice(&MAGIC.to_le_bytes());
        self.buf[4..8].copy_from_slice(&(len as u32).to_le_bytes());
        self.buf[8..12].copy_from_slice(&crc.to_le_bytes());
        self.out.write_all(&self.buf[..12 + len])
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

/// Decodes the intact blocks at the start of `bytes` into `records`; returns the bytes they
/// took (the rest is a torn or corrupt block, or one not yet written whole).
fn parse_blocks<T: DeserializeOwned>(bytes: &[u8], records: &mut Vec<T>) -> usize {
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
    pos
}

/// Reads every intact block of a log file.
pub fn read_log<T: DeserializeOwned>(path: &Path) -> std::io::Result<LogContents<T>> {
    let mut bytes = Vec::new();
    File::open(path)?.read_to_end(&mut bytes)?;
    if bytes.len() >= 4 {
        let first = u32::from_le_bytes(bytes[0..4].try_into().unwrap());
        if let Some((_, what)) = OLDER_MAGICS.iter().find(|(m, _)| first == *m) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "{}: a log of an older feedloop ({what}); read it with the version \
                     that wrote it",
                    path.display()
                ),
            ));
        }
    }
    let mut records = Vec::new();
    let pos = parse_blocks(&bytes, &mut records);
    Ok(LogContents {
        records,
        torn_bytes: bytes.len() - pos,
    })
}

/// Bytes a [`LogTail`] holds back waiting for a block to be completed: far more than any
/// recorder block.
const MAX_PENDING: usize = 1 << 24;

/// Follows a log while its process writes it: each [`LogTail::read_new`] returns the records of
/// the blocks written whole since the last call (a block still being written waits for the
/// next). For a live figure next to a running loop: it reads the file the recorder thread
/// writes anyway, and asks nothing of the loop.
pub struct LogTail {
    path: std::path::PathBuf,
    file: Option<File>,
    /// Bytes read that do not form a whole block yet.
    pending: Vec<u8>,
}

impl LogTail {
    /// A tail of `path` (which need not exist yet).
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            file: None,
            pending: Vec::new(),
        }
    }

    /// The records of the blocks completed since the last call (none while the file is not
    /// there).
    pub fn read_new<T: DeserializeOwned>(&mut self) -> Vec<T> {
        if self.file.is_none() {
            self.file = File::open(&self.path).ok();
        }
        let mut records = Vec::new();
        if let Some(f) = self.file.as_mut() {
            if f.read_to_end(&mut self.pending).is_ok() {
                let used = parse_blocks(&self.pending, &mut records);
                self.pending.drain(..used);
                if self.pending.len() > MAX_PENDING {
                    // a corrupt block, not one being written: skip it (a live figure only)
                    self.pending.clear();
                }
            }
        }
        records
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> std::path::PathBuf {
        std::env::temp_dir().join(format!("feedloop-log-{}-{name}", std::process::id()))
    }

    #[test]
    fn a_tail_returns_each_block_once_and_waits_for_a_half_written_one() {
        let p = tmp("tail.log");
        let recs = |from: u64, n: u64| -> Vec<PlantRecord> {
            (from..from + n)
                .map(|k| PlantRecord {
                    seq: k,
                    flags: (k % 3) as u8,
                    ..Default::default()
                })
                .collect()
        };
        let mut tail = LogTail::new(&p);
        assert!(tail.read_new::<PlantRecord>().is_empty(), "no file yet");
        let mut w = LogWriter::create(&p).unwrap();
        w.write_block(&recs(0, 10)).unwrap();
        w.write_block(&recs(10, 5)).unwrap();
        let got: Vec<PlantRecord> = tail.read_new();
        assert_eq!(got, recs(0, 15));
        assert!(tail.read_new::<PlantRecord>().is_empty());
        // a third block, written in two parts: nothing until it is whole
        let other = tmp("tail-block.log");
        LogWriter::create(&other)
            .unwrap()
            .write_block(&recs(15, 7))
            .unwrap();
        let block = std::fs::read(&other).unwrap();
        let mut f = std::fs::OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(&block[..block.len() / 2]).unwrap();
        assert!(tail.read_new::<PlantRecord>().is_empty());
        f.write_all(&block[block.len() / 2..]).unwrap();
        assert_eq!(tail.read_new::<PlantRecord>(), recs(15, 7));
        let _ = std::fs::remove_file(&p);
        let _ = std::fs::remove_file(&other);
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

    #[test]
    fn records_keep_every_bit_of_their_used_axes_and_take_the_space_of_those_only() {
        let mut a = PlantRecord {
            seq: 7,
            latency_ns: u64::MAX,
            flags: REC_MISSED,
            ..Default::default()
        };
        a.axes[0].cmd = 1.5;
        a.axes[1].torque = -0.0; // not +0.0: must survive
        a.axes[1].load = f64::NAN;
        let mut b = a;
        b.axes[4].motor_vel = 3.0; // a gap of blank axes before a used one is kept
        let mut s = SchedRecord {
            seq: 9,
            ..Default::default()
        };
        s.axes[0] = (2.0, 3.0);
        s.stages[2] = (0.0, 5e-300);
        let mut buf = vec![0u8; 4096];
        let n_ab = encode_records(&[a, b], &mut buf).unwrap();
        let back: Vec<PlantRecord> = decode_records(&buf[..n_ab]).unwrap();
        assert_eq!(back.len(), 2);
        for (x, y) in back.iter().zip([a, b]) {
            assert_eq!(x.seq, y.seq);
            assert_eq!((x.latency_ns, x.flags), (y.latency_ns, y.flags));
            for (p, q) in x.axes.iter().zip(&y.axes) {
                let bits = |r: &AxisRecord| {
                    [r.cmd, r.load, r.motor, r.motor_vel, r.torque].map(f64::to_bits)
                };
                assert_eq!(bits(p), bits(q));
            }
        }
        let n_s = encode_records(&[s], &mut buf).unwrap();
        assert_eq!(decode_records::<SchedRecord>(&buf[..n_s]).unwrap(), vec![s]);
        // two used axes cost two entries: a record of all eight takes four times their room
        let full = PlantRecord {
            axes: [AxisRecord {
                cmd: 1.0,
                ..Default::default()
            }; MAX_AXES],
            ..Default::default()
        };
        let n_full = encode_records(&[full], &mut buf).unwrap();
        let n_a = encode_records(&[a], &mut buf).unwrap();
        let entry = 5 * 8;
        assert_eq!(n_full - n_a, (MAX_AXES - 2) * entry);
        // more entries than the array holds is an error, not a panic
        let mut long = buf[..n_full].to_vec();
        let len_at = n_full - MAX_AXES * entry - 8;
        long[len_at..len_at + 8].copy_from_slice(&(MAX_AXES as u64 + 1).to_le_bytes());
        long.extend(std::iter::repeat_n(0u8, entry));
        assert!(decode_records::<PlantRecord>(&long).is_none());
    }
}
