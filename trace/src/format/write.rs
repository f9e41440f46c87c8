//! Writing a trace: [`TraceWriter`] streams rows with the shortest round-trip text of each
//! value (and, for [`TraceWriter::write_cycle`], the time as the exact decimal of cycle x
//! period); [`Trace::write_to`] writes a trace held in memory.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use super::{check_column_name, check_meta_key, Trace, VERSION_LINE};

/// Streams a trace: the version line, optional `# key=value` metadata, the header, then rows.
///
/// Rows are formatted into one reused buffer and written through a `BufWriter`, so writing a
/// row does not allocate. Call [`TraceWriter::finish`] to flush and see write errors (dropping
/// the writer flushes too, but ignores errors).
pub struct TraceWriter<W: Write> {
    out: BufWriter<W>,
    line: Vec<u8>,
    columns: Vec<String>,
    t_index: usize,
    last_t: f64,
    rows: u64,
    /// The period as an exact decimal, once [`TraceWriter::with_period`] set it.
    period: Option<DecimalPeriod>,
    last_cycle: Option<u64>,
}

/// A period as the decimal it was written as (`0.0003` = 3 x 10^-4), so that the time of cycle
/// `k` can be printed as the exact decimal `k x 3 x 10^-4` instead of the float product (which
/// prints as `0.00030000000000000003` for k = 1 and period 1e-4 x 3).
#[derive(Debug, Clone, Copy, PartialEq)]
struct DecimalPeriod {
    seconds: f64,
    digits: u64,
    exp10: i32,
}

impl DecimalPeriod {
    /// The shortest decimal that reads back as `seconds` (what `ryu` prints), split into
    /// integer digits and a power of ten.
    fn of(seconds: f64) -> Option<Self> {
        if !(seconds.is_finite() && seconds > 0.0) {
            return None;
        }
        let mut buf = ryu::Buffer::new();
        let text = buf.format_finite(seconds);
        let (mantissa, exp) = match text.split_once('e') {
            Some((m, e)) => (m, e.parse::<i32>().ok()?),
            None => (text, 0),
        };
        let (int, frac) = mantissa.split_once('.').unwrap_or((mantissa, ""));
        let mut digits: u64 = format!("{int}{frac}").parse().ok()?;
        let mut exp10 = exp - frac.len() as i32;
        while digits > 0 && digits.is_multiple_of(10) {
            digits /= 10;
            exp10 += 1;
        }
        Some(Self {
            seconds,
            digits,
            exp10,
        })
    }

    /// Appends the exact decimal of `cycle` periods to `out` (`0.0`, `0.0003`, `12.5`, `40.0`),
    /// without allocating.
    fn write_time(&self, cycle: u64, out: &mut Vec<u8>) {
        let mut n = u128::from(cycle) * u128::from(self.digits);
        // the integer's digits, least significant first
        let mut rev = [0u8; 40];
        let mut len = 0;
        loop {
            rev[len] = b'0' + (n % 10) as u8;
            len += 1;
            n /= 10;
            if n == 0 {
                break;
            }
        }
        let frac = (-self.exp10).max(0) as usize;
        let zeros_after = self.exp10.max(0) as usize;
        // integer part: the digits above `frac`, then the power's zeros
        if len > frac {
            out.extend(rev[frac..len].iter().rev());
            out.extend(std::iter::repeat_n(b'0', zeros_after));
        } else {
            out.push(b'0');
        }
        out.push(b'.');
        // fraction: `frac` digits (leading zeros where the integer is shorter), trailing zeros
        // dropped but one digit kept
        let fraction = (0..frac).rev().map(|i| if i < len { rev[i] } else { b'0' });
        let start = out.len();
        out.extend(fraction);
        while out.len() > start + 1 && out.last() == Some(&b'0') {
            out.pop();
        }
        if out.len() == start {
            out.push(b'0');
        }
    }
}

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

impl<W: Write> TraceWriter<W> {
    /// Starts a trace on `w` with `columns` (must contain `t`; names as for the reader).
    pub fn new(w: W, columns: &[String]) -> io::Result<Self> {
        Self::with_meta(w, &[], columns)
    }

    /// Starts a trace whose version line is followed by one `# key=value` line per `meta` entry.
    /// Keys must not contain white space or `=`; values must not contain line breaks.
    pub fn with_meta(w: W, meta: &[(String, String)], columns: &[String]) -> io::Result<Self> {
        for (i, c) in columns.iter().enumerate() {
            check_column_name(c).map_err(|r| invalid(format!("column {:?}: {r}", c)))?;
            if let Some(j) = columns[..i].iter().position(|d| d == c) {
                return Err(invalid(format!(
                    "column `{c}` appears twice (columns {} and {})",
                    j + 1,
                    i + 1
                )));
            }
        }
        let t_index = columns
            .iter()
            .position(|c| c == "t")
            .ok_or_else(|| invalid("a trace needs a `t` (time, s) column".into()))?;
        let mut out = BufWriter::with_capacity(1 << 16, w);
        out.write_all(VERSION_LINE.as_bytes())?;
        out.write_all(b"\n")?;
        for (k, v) in meta {
            check_meta_key(k).map_err(invalid)?;
            if v.contains(['\n', '\r']) {
                return Err(invalid(format!(
                    "metadata `{k}`: value must not contain line breaks"
                )));
            }
            writeln!(out, "# {k}={v}")?;
        }
        out.write_all(columns.join(",").as_bytes())?;
        out.write_all(b"\n")?;
        Ok(Self {
            out,
            line: Vec::with_capacity(32 * columns.len() + 8),
            columns: columns.to_vec(),
            t_index,
            last_t: f64::NEG_INFINITY,
            rows: 0,
            period: None,
            last_cycle: None,
        })
    }

    /// Sets the period rows are written at with [`TraceWriter::write_cycle`]: their time is the
    /// exact decimal of cycle x period as the period is written (`0.0003` for cycle 3 at
    /// `1e-4`, where the float product prints `0.00030000000000000003`). The file stays format
    /// v1: any reader parses these numbers.
    pub fn with_period(mut self, period_s: f64) -> io::Result<Self> {
        self.period = Some(
            DecimalPeriod::of(period_s)
                .ok_or_else(|| invalid(format!("period must be > 0 s, got {period_s}")))?,
        );
        Ok(self)
    }

    /// The columns, in order.
    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    /// Rows written so far.
    pub fn rows_written(&self) -> u64 {
        self.rows
    }

    /// Writes one row (`values.len()` must equal the column count). NaN/inf values and a time
    /// not after the previous row's are refused (`InvalidInput`), since the file could not be
    /// read back; nothing is written then.
    pub fn write_row(&mut self, values: &[f64]) -> io::Result<()> {
        self.write_values(values, None)
    }

    /// Writes the row of cycle `cycle` (`values` as for [`TraceWriter::write_row`]; the value in
    /// the `t` column is not used): its time is cycle x period, printed exactly (see
    /// [`TraceWriter::with_period`], which must have set the period). Cycles must increase.
    pub fn write_cycle(&mut self, cycle: u64, values: &[f64]) -> io::Result<()> {
        let Some(p) = self.period else {
            return Err(invalid(
                "write_cycle needs the period: start the writer with with_period".into(),
            ));
        };
        if self.last_cycle.is_some_and(|c| cycle <= c) {
            return Err(invalid(format!(
                "cycle {cycle} is not after the previous row's {}",
                self.last_cycle.unwrap_or(0)
            )));
        }
        self.write_values(values, Some((cycle, p)))?;
        self.last_cycle = Some(cycle);
        Ok(())
    }

    /// Checks and writes one row; with `cycle`, the time cell is that cycle's exact time.
    fn write_values(
        &mut self,
        values: &[f64],
        cycle: Option<(u64, DecimalPeriod)>,
    ) -> io::Result<()> {
        if values.len() != self.columns.len() {
            return Err(invalid(format!(
                "row has {} values, the trace has {} columns",
                values.len(),
                self.columns.len()
            )));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(invalid(format!(
                "column `{}`: value {} cannot be written (trace format v1 refuses NaN and inf)",
                self.columns[i], values[i]
            )));
        }
        let t = match cycle {
            Some((k, p)) => k as f64 * p.seconds,
            None => values[self.t_index],
        };
        if t <= self.last_t {
            return Err(invalid(format!(
                "time {t} s is not after the previous row's {} s",
                self.last_t
            )));
        }
        self.last_t = t;
        self.line.clear();
        let mut buf = ryu::Buffer::new();
        for (i, v) in values.iter().enumerate() {
            if i > 0 {
                self.line.push(b',');
            }
            match cycle {
                Some((k, p)) if i == self.t_index => p.write_time(k, &mut self.line),
                _ => self
                    .line
                    .extend_from_slice(buf.format_finite(*v).as_bytes()),
            }
        }
        self.line.push(b'\n');
        self.out.write_all(&self.line)?;
        self.rows += 1;
        Ok(())
    }

    /// Flushes buffered rows to the underlying writer.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }

    /// Flushes and returns the underlying writer.
    pub fn finish(self) -> io::Result<W> {
        self.out.into_inner().map_err(|e| e.into_error())
    }
}

impl TraceWriter<File> {
    /// Creates (truncates) `path` and starts a trace there.
    pub fn create(
        path: &Path,
        meta: &[(String, String)],
        columns: &[String],
    ) -> io::Result<TraceWriter<File>> {
        let f = File::create(path)?;
        TraceWriter::with_meta(f, meta, columns)
    }
}

impl Trace {
    /// Writes the trace (version line, metadata, header, rows) to `w`.
    pub fn write_to<W: Write>(&self, w: W) -> io::Result<W> {
        let mut tw = TraceWriter::with_meta(w, &self.meta, &self.columns)?;
        let mut row = vec![0.0; self.columns.len()];
        for r in 0..self.len() {
            for (v, c) in row.iter_mut().zip(&self.data) {
                *v = c[r];
            }
            tw.write_row(&row)?;
        }
        tw.finish()
    }

    /// Writes the trace to the file `path` (created or truncated).
    pub fn write(&self, path: &Path) -> io::Result<()> {
        let f = File::create(path)?;
        let mut f = self.write_to(f)?;
        f.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::tests::{cols, parse, GOOD};
    use proptest::prelude::*;

    #[test]
    fn the_writer_produces_the_version_line_meta_and_shortest_numbers() {
        let meta = vec![("period_s".to_string(), "0.25".to_string())];
        let mut w =
            TraceWriter::with_meta(Vec::new(), &meta, &cols(&["t", "x.cmd", "x.load"])).unwrap();
        w.write_row(&[0.0, 0.1, -2.5e-9]).unwrap();
        w.write_row(&[0.25, 1.0, 3.0]).unwrap();
        let text = String::from_utf8(w.finish().unwrap()).unwrap();
        assert_eq!(
            text,
            "# feedloop-trace v1\n# period_s=0.25\nt,x.cmd,x.load\n0.0,0.1,-2.5e-9\n0.25,1.0,3.0\n"
        );
    }

    /// The time cells of `text` (first column after the header).
    fn times(text: &str) -> Vec<String> {
        text.lines()
            .filter(|l| !l.starts_with('#'))
            .skip(1)
            .map(|l| l.split(',').next().unwrap().to_string())
            .collect()
    }

    #[test]
    fn rows_written_by_cycle_have_exact_decimal_times() {
        let c = cols(&["t", "x.cmd"]);
        let mut w = TraceWriter::new(Vec::new(), &c)
            .unwrap()
            .with_period(1e-4)
            .unwrap();
        for k in [0u64, 1, 3, 7, 10, 12_345, 10_000_000_001] {
            // the t value given is ignored: the cycle's time is written
            w.write_cycle(k, &[k as f64 * 1e-4, 0.5]).unwrap();
        }
        let text = String::from_utf8(w.finish().unwrap()).unwrap();
        assert_eq!(
            times(&text),
            [
                "0.0",
                "0.0001",
                "0.0003",
                "0.0007",
                "0.001",
                "1.2345",
                "1000000.0001"
            ]
        );
        // 3 x 1e-4 as a float product would print 0.00030000000000000003
        assert_ne!(ryu::Buffer::new().format(3.0 * 1e-4), "0.0003");
        // and such a file reads as before (format v1)
        let mut w = TraceWriter::new(Vec::new(), &c)
            .unwrap()
            .with_period(1e-4)
            .unwrap();
        for k in 0..20 {
            w.write_cycle(k, &[0.0, 0.5]).unwrap();
        }
        let tr = parse(&String::from_utf8(w.finish().unwrap()).unwrap()).unwrap();
        assert_eq!(tr.column("t").unwrap()[3], 0.0003);
        assert!((tr.period_s() - 1e-4).abs() < 1e-15);

        for (period, k, want) in [
            (0.00025, 3, "0.00075"),
            (2.5e-7, 4, "0.000001"),
            (0.02, 3, "0.06"),
            (1.5, 4, "6.0"),
            (20.0, 3, "60.0"),
            // a period that is itself a float product is taken as it is written
            (1e-4 * 3.0, 3, "0.00090000000000000009"),
        ] {
            let mut w = TraceWriter::new(Vec::new(), &c)
                .unwrap()
                .with_period(period)
                .unwrap();
            w.write_cycle(k, &[0.0, 1.0]).unwrap();
            let text = String::from_utf8(w.finish().unwrap()).unwrap();
            assert_eq!(times(&text), [want], "period {period}, cycle {k}");
        }
    }

    #[test]
    fn writing_by_cycle_needs_a_period_and_increasing_cycles() {
        let c = cols(&["t", "x.cmd"]);
        assert!(TraceWriter::new(Vec::new(), &c)
            .unwrap()
            .write_cycle(0, &[0.0, 1.0])
            .is_err());
        assert!(TraceWriter::new(Vec::new(), &c)
            .unwrap()
            .with_period(0.0)
            .is_err());
        let mut w = TraceWriter::new(Vec::new(), &c)
            .unwrap()
            .with_period(1e-3)
            .unwrap();
        w.write_cycle(5, &[0.0, 1.0]).unwrap();
        assert!(w.write_cycle(5, &[0.0, 1.0]).is_err());
        assert!(w.write_cycle(4, &[0.0, 1.0]).is_err());
        w.write_cycle(6, &[0.0, 1.0]).unwrap();
        assert_eq!(w.rows_written(), 2);
    }

    #[test]
    fn the_writer_refuses_what_could_not_be_read_back() {
        let c = cols(&["t", "x.cmd"]);
        assert!(TraceWriter::new(Vec::new(), &cols(&["x.cmd"])).is_err());
        assert!(TraceWriter::new(Vec::new(), &cols(&["t", "t"])).is_err());
        assert!(TraceWriter::new(Vec::new(), &cols(&["t", "x cmd"])).is_err());
        let bad_meta = vec![("a b".to_string(), "1".to_string())];
        assert!(TraceWriter::with_meta(Vec::new(), &bad_meta, &c).is_err());
        let mut w = TraceWriter::new(Vec::new(), &c).unwrap();
        assert!(w.write_row(&[0.0]).is_err());
        let e = w.write_row(&[0.0, f64::NAN]).unwrap_err();
        assert!(e.to_string().contains("`x.cmd`"), "{e}");
        w.write_row(&[0.0, 1.0]).unwrap();
        assert!(w.write_row(&[0.0, 1.0]).is_err());
        assert_eq!(w.rows_written(), 1);
    }

    #[test]
    fn two_hundred_thousand_rows_round_trip_bit_for_bit() {
        let names = [
            "t",
            "x.cmd",
            "x.load",
            "x.motor",
            "x.motor_vel",
            "x.torque",
            "y.cmd",
            "y.load",
            "y.motor",
            "y.motor_vel",
            "y.torque",
        ];
        let c = cols(&names);
        let rows = 200_000usize;
        let mut w = TraceWriter::new(Vec::with_capacity(rows * 200), &c).unwrap();
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut expect: Vec<Vec<f64>> = vec![Vec::with_capacity(rows); names.len()];
        let mut row = [0.0f64; 11];
        for k in 0..rows {
            row[0] = k as f64 * 1e-4;
            for v in row.iter_mut().skip(1) {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                *v = (state as i64 as f64) * 1e-21;
            }
            for (e, v) in expect.iter_mut().zip(row.iter()) {
                e.push(*v);
            }
            w.write_row(&row).unwrap();
        }
        let text = String::from_utf8(w.finish().unwrap()).unwrap();
        let tr = parse(&text).unwrap();
        assert_eq!(tr.len(), rows);
        for (i, name) in names.iter().enumerate() {
            let got = tr.column(name).unwrap();
            assert!(
                got.iter()
                    .zip(&expect[i])
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "column {name} differs"
            );
        }
        // Writing the read trace again gives the same bytes.
        let again = String::from_utf8(tr.write_to(Vec::new()).unwrap()).unwrap();
        assert_eq!(again, text);
    }

    #[test]
    fn a_trace_written_to_disk_reads_back_equal() {
        let dir = std::env::temp_dir().join(format!("feedloop-trace-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.csv");
        let tr = parse(GOOD).unwrap();
        tr.write(&path).unwrap();
        let back = Trace::read(&path).unwrap();
        assert_eq!(back.columns, tr.columns);
        assert_eq!(back.meta, tr.meta);
        for c in &tr.columns {
            assert_eq!(back.column(c), tr.column(c));
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Measures (does not assert) write and read speed: `cargo test --release -p
    /// feedloop-trace trace_throughput -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn trace_throughput_is_measured_for_a_million_rows_of_eleven_columns() {
        let names: Vec<String> = std::iter::once("t".to_string())
            .chain((0..2).flat_map(|a| {
                ["cmd", "load", "motor", "motor_vel", "torque"]
                    .iter()
                    .map(move |s| format!("a{a}.{s}"))
            }))
            .collect();
        let path = std::env::temp_dir().join(format!("feedloop-tp-{}.csv", std::process::id()));
        let rows = 1_000_000usize;
        // Wall time and this thread's CPU time (the machine may be shared).
        let cpu = || {
            let mut ts = libc::timespec {
                tv_sec: 0,
                tv_nsec: 0,
            };
            // SAFETY: clock_gettime writes into the timespec we own.
            unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
            ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
        };
        let clock = || (std::time::Instant::now(), cpu());
        let since = |(w, c): (std::time::Instant, f64)| (w.elapsed().as_secs_f64(), cpu() - c);
        let start = clock();
        let mut w = TraceWriter::create(&path, &[], &names).unwrap();
        let mut row = [0.0f64; 11];
        for k in 0..rows {
            let t = k as f64 * 1e-4;
            row[0] = t;
            for (j, v) in row.iter_mut().enumerate().skip(1) {
                // Cheap varied values with full-length mantissas (as measured signals have).
                *v = (k as f64 * 1.000_000_3 + j as f64) * 1.234_567e-7;
            }
            w.write_row(&row).unwrap();
        }
        w.finish().unwrap();
        let write = since(start);
        let start = clock();
        let mut sink = TraceWriter::new(io::sink(), &names).unwrap();
        for k in 0..rows {
            row[0] = k as f64 * 1e-4;
            sink.write_row(&row).unwrap();
        }
        let format = since(start);
        let bytes = std::fs::metadata(&path).unwrap().len();
        let start = clock();
        let tr = Trace::read(&path).unwrap();
        let read = since(start);
        assert_eq!(tr.len(), rows);
        let m = |s: f64| rows as f64 / s / 1e6;
        println!(
            "file {} MB; M rows/s by wall / CPU time: write to file {:.2} / {:.2}, format only {:.2} / {:.2}, read {:.2} / {:.2}",
            bytes / 1_000_000,
            m(write.0),
            m(write.1),
            m(format.0),
            m(format.1),
            m(read.0),
            m(read.1)
        );
        std::fs::remove_file(&path).ok();
    }

    proptest! {
        #[test]
        fn any_finite_values_round_trip_exactly(vals in proptest::collection::vec(
            any::<f64>().prop_filter("finite", |v| v.is_finite()), 2..40)) {
            let c = cols(&["t", "v"]);
            let mut w = TraceWriter::new(Vec::new(), &c).unwrap();
            for (k, v) in vals.iter().enumerate() {
                w.write_row(&[k as f64, *v]).unwrap();
            }
            let text = String::from_utf8(w.finish().unwrap()).unwrap();
            let tr = parse(&text).unwrap();
            let got = tr.column("v").unwrap();
            for (a, b) in got.iter().zip(&vals) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
        }
    }
}
