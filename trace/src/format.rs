//! Trace format v1 (see `docs/trace-format.md`): writing and reading, with validation.
//!
//! A trace is a CSV file: optional leading `#` comment lines (metadata as `# key=value`), one
//! header row, then one row per sample. Column `t` is time in seconds, strictly increasing and
//! uniformly sampled: every step `dt_i = t_i - t_{i-1}` must satisfy
//! `|dt_i - median(dt)| <= 0.01 * median(dt)`. Per axis `A` the columns are `A.cmd`, `A.load`
//! (m or rad) and optionally `A.motor`, `A.motor_vel`, `A.torque`; any other column is kept.
//!
//! - [`TraceWriter`] streams rows: each `f64` is printed with `ryu` (shortest text that parses
//!   back to the same bits), so identical values give byte-identical files.
//! - [`Trace`] reads a whole file into column-major `f64` vectors and refuses every defect with
//!   the file name, the 1-based line number and what is wrong ([`TraceError`]).
//!
//! # Examples
//! ```
//! use feedloop_trace::{Trace, TraceWriter};
//! use std::path::Path;
//!
//! let cols: Vec<String> = ["t", "x.cmd", "x.load"].iter().map(|s| s.to_string()).collect();
//! let mut w = TraceWriter::new(Vec::new(), &cols).unwrap();
//! for k in 0..4 {
//!     let t = k as f64 * 1e-4;
//!     w.write_row(&[t, 1e-3 * t, 0.9e-3 * t]).unwrap();
//! }
//! let bytes = w.finish().unwrap();
//! let text = String::from_utf8(bytes).unwrap();
//! let trace = Trace::parse(Path::new("mem.csv"), &text).unwrap();
//! assert_eq!(trace.len(), 4);
//! assert_eq!(trace.axes(), vec!["x".to_string()]);
//! assert!((trace.period_s() - 1e-4).abs() < 1e-12);
//! ```

use std::fmt;
use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

/// First line of every trace written by feedloop.
pub const VERSION_LINE: &str = "# feedloop-trace v1";

/// Largest allowed deviation of one time step from the median step, as a fraction (1 %).
pub const SAMPLING_TOLERANCE: f64 = 0.01;

/// Longest cell text quoted in an error message, characters.
const QUOTE_MAX: usize = 40;

// ---------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------

/// Why a trace could not be read (or built); every variant names the file, and those about one
/// place in the file name the 1-based line.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// The file could not be opened or read.
    #[error("{}: cannot read trace: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error.
        source: io::Error,
    },
    /// A line is not valid UTF-8.
    #[error("{}: line {line}: not valid UTF-8 text", path.display())]
    NotUtf8 {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
    },
    /// No header row (the file is empty, holds only comments, or starts with data).
    #[error("{}: line {line}: missing header row: {reason}", path.display())]
    MissingHeader {
        /// The file.
        path: PathBuf,
        /// 1-based line where the header was expected (last line + 1 at end of file).
        line: usize,
        /// What was found instead.
        reason: String,
    },
    /// The header has no `t` column.
    #[error("{}: line {line}: header has no `t` (time, s) column; columns: {present}", path.display())]
    MissingTime {
        /// The file.
        path: PathBuf,
        /// Line of the header.
        line: usize,
        /// The columns that are there, comma-separated.
        present: String,
    },
    /// A column name appears twice in the header.
    #[error("{}: line {line}: column `{column}` appears twice (columns {first} and {second})", path.display())]
    DuplicateColumn {
        /// The file.
        path: PathBuf,
        /// Line of the header.
        line: usize,
        /// The repeated name.
        column: String,
        /// 1-based position of the first occurrence.
        first: usize,
        /// 1-based position of the second occurrence.
        second: usize,
    },
    /// A column name uses characters outside `A-Z a-z 0-9 _ . -` or is empty.
    #[error("{}: line {line}: bad column name \"{column}\" (column {position}): {reason}", path.display())]
    BadColumnName {
        /// The file.
        path: PathBuf,
        /// Line of the header.
        line: usize,
        /// The name as written.
        column: String,
        /// 1-based position in the header.
        position: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A metadata comment is malformed, repeated, or contradicts the data.
    #[error("{}: line {line}: metadata: {reason}", path.display())]
    BadMeta {
        /// The file.
        path: PathBuf,
        /// Line of the comment.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A `#` comment line after the header (comments are only allowed before it).
    #[error("{}: line {line}: comment line after the header (comments are only allowed before the header row)", path.display())]
    MisplacedComment {
        /// The file.
        path: PathBuf,
        /// Line of the comment.
        line: usize,
    },
    /// An empty line between data rows.
    #[error("{}: line {line}: empty line between data rows", path.display())]
    BlankLine {
        /// The file.
        path: PathBuf,
        /// Line of the empty line.
        line: usize,
    },
    /// A cell that does not parse as a number.
    #[error("{}: line {line}: column `{column}`: \"{cell}\" is not a number", path.display())]
    NotANumber {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// Column of the cell.
        column: String,
        /// The cell text (cut to 40 characters).
        cell: String,
    },
    /// A cell holding NaN or an infinity.
    #[error("{}: line {line}: column `{column}`: \"{cell}\" is not finite (NaN and inf are not allowed)", path.display())]
    NotFinite {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// Column of the cell.
        column: String,
        /// The cell text.
        cell: String,
    },
    /// A row with a different number of cells than the header.
    #[error("{}: line {line}: {found} cells, but the header has {expected} columns", path.display())]
    CellCount {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// Cells found.
        found: usize,
        /// Columns in the header.
        expected: usize,
    },
    /// Time equal to or before the previous row's.
    #[error("{}: line {line}: time is not strictly increasing: t = {t} s after t = {previous} s", path.display())]
    TimeNotIncreasing {
        /// The file.
        path: PathBuf,
        /// 1-based line of the offending row.
        line: usize,
        /// Its time, s.
        t: f64,
        /// The previous row's time, s.
        previous: f64,
    },
    /// A time step more than 1 % away from the median step.
    #[error("{}: line {line}: uneven sampling: step {step_s} s differs from the median step {median_s} s by more than 1 %", path.display())]
    UnevenSampling {
        /// The file.
        path: PathBuf,
        /// 1-based line of the first row whose step is off.
        line: usize,
        /// That step, s.
        step_s: f64,
        /// Median step, s.
        median_s: f64,
    },
    /// A header but no data rows.
    #[error("{}: empty trace: header but no data rows", path.display())]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// A single data row: no sampling period can be derived.
    #[error("{}: line {line}: only one data row; a trace needs at least 2 rows to define its sampling period", path.display())]
    TooFewRows {
        /// The file.
        path: PathBuf,
        /// Line of the only row.
        line: usize,
    },
    /// Column data of unequal lengths given to [`Trace::from_columns`].
    #[error("{}: column `{column}` has {found} values, `t` has {expected}", path.display())]
    ColumnLength {
        /// The (nominal) file.
        path: PathBuf,
        /// The column.
        column: String,
        /// Its length.
        found: usize,
        /// Length of `t`.
        expected: usize,
    },
    /// A column a tool needs is absent.
    #[error("{}: missing column `{column}` (columns present: {present})", path.display())]
    MissingColumn {
        /// The file.
        path: PathBuf,
        /// The column that was asked for.
        column: String,
        /// The columns that are there, comma-separated.
        present: String,
    },
}

impl TraceError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            TraceError::Io { path, .. }
            | TraceError::NotUtf8 { path, .. }
            | TraceError::MissingHeader { path, .. }
            | TraceError::MissingTime { path, .. }
            | TraceError::DuplicateColumn { path, .. }
            | TraceError::BadColumnName { path, .. }
            | TraceError::BadMeta { path, .. }
            | TraceError::MisplacedComment { path, .. }
            | TraceError::BlankLine { path, .. }
            | TraceError::NotANumber { path, .. }
            | TraceError::NotFinite { path, .. }
            | TraceError::CellCount { path, .. }
            | TraceError::TimeNotIncreasing { path, .. }
            | TraceError::UnevenSampling { path, .. }
            | TraceError::Empty { path }
            | TraceError::TooFewRows { path, .. }
            | TraceError::ColumnLength { path, .. }
            | TraceError::MissingColumn { path, .. } => path,
        }
    }

    /// The 1-based line the error is about, when it is about one line.
    pub fn line(&self) -> Option<usize> {
        match self {
            TraceError::NotUtf8 { line, .. }
            | TraceError::MissingHeader { line, .. }
            | TraceError::MissingTime { line, .. }
            | TraceError::DuplicateColumn { line, .. }
            | TraceError::BadColumnName { line, .. }
            | TraceError::BadMeta { line, .. }
            | TraceError::MisplacedComment { line, .. }
            | TraceError::BlankLine { line, .. }
            | TraceError::NotANumber { line, .. }
            | TraceError::NotFinite { line, .. }
            | TraceError::CellCount { line, .. }
            | TraceError::TimeNotIncreasing { line, .. }
            | TraceError::UnevenSampling { line, .. }
            | TraceError::TooFewRows { line, .. } => Some(*line),
            TraceError::Io { .. }
            | TraceError::Empty { .. }
            | TraceError::ColumnLength { .. }
            | TraceError::MissingColumn { .. } => None,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Names
// ---------------------------------------------------------------------------------------------

/// Checks every header name and refuses duplicates (`line` is the header's line number).
fn check_header<S: AsRef<str>>(path: &Path, line: usize, names: &[S]) -> Result<(), TraceError> {
    for (i, c) in names.iter().map(AsRef::as_ref).enumerate() {
        check_column_name(c).map_err(|reason| TraceError::BadColumnName {
            path: path.to_path_buf(),
            line,
            column: quote(c),
            position: i + 1,
            reason,
        })?;
        if let Some(j) = names[..i].iter().position(|d| d.as_ref() == c) {
            return Err(TraceError::DuplicateColumn {
                path: path.to_path_buf(),
                line,
                column: c.to_string(),
                first: j + 1,
                second: i + 1,
            });
        }
    }
    Ok(())
}

/// Checks a column name: non-empty, ASCII letters, digits, `_`, `.`, `-`, not starting or ending
/// with `.` and without an empty `..` part. Returns what is wrong.
pub fn check_column_name(name: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err("empty name (two separators in a row, or one at the end?)".into());
    }
    if name.len() > 128 {
        return Err(format!("longer than 128 characters ({})", name.len()));
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-')))
    {
        return Err(match c {
            '"' | '\'' => "quotes are not used in trace headers".to_string(),
            c if c.is_whitespace() => "contains white space".to_string(),
            c => format!("character {c:?} is not allowed (use letters, digits, `_`, `.`, `-`)"),
        });
    }
    if name.starts_with('.') || name.ends_with('.') || name.contains("..") {
        return Err("`.` separates an axis name from a signal name; no empty parts".into());
    }
    Ok(())
}

/// Whether `name` is a valid axis name (lowercase letters, digits, `_`).
fn is_axis_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
}

fn quote(cell: &str) -> String {
    if cell.chars().count() <= QUOTE_MAX {
        cell.to_string()
    } else {
        let cut: String = cell.chars().take(QUOTE_MAX).collect();
        format!("{cut}...")
    }
}

fn check_meta_key(key: &str) -> Result<(), String> {
    if key.is_empty() {
        return Err("empty metadata key".into());
    }
    if key
        .chars()
        .any(|c| c.is_whitespace() || c == '=' || c.is_control())
    {
        return Err(format!(
            "metadata key {key:?} must not contain white space or `=`"
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Writer
// ---------------------------------------------------------------------------------------------

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
        })
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
        let t = values[self.t_index];
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
            self.line
                .extend_from_slice(buf.format_finite(*v).as_bytes());
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

// ---------------------------------------------------------------------------------------------
// Reader
// ---------------------------------------------------------------------------------------------

/// A validated trace held column-major in memory (one `Vec<f64>` per column).
#[derive(Debug, Clone, PartialEq)]
pub struct Trace {
    /// Where it came from (used in messages).
    pub path: PathBuf,
    /// `# key=value` metadata, in file order (keys unique).
    pub meta: Vec<(String, String)>,
    /// Other leading comment lines (without the `#`), including the version line.
    pub comments: Vec<String>,
    /// Column names, in file order.
    pub columns: Vec<String>,
    data: Vec<Vec<f64>>,
    t_index: usize,
    period_s: f64,
}

/// Iterates the lines of a reader as `(1-based number, bytes without the line break)` through
/// one reused buffer.
struct Lines<R: BufRead> {
    r: R,
    buf: Vec<u8>,
    number: usize,
}

impl<R: BufRead> Lines<R> {
    fn next_line(&mut self, path: &Path) -> Result<Option<(usize, &str)>, TraceError> {
        self.buf.clear();
        let n = self
            .r
            .read_until(b'\n', &mut self.buf)
            .map_err(|source| TraceError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        if n == 0 {
            return Ok(None);
        }
        self.number += 1;
        let mut end = self.buf.len();
        if end > 0 && self.buf[end - 1] == b'\n' {
            end -= 1;
        }
        if end > 0 && self.buf[end - 1] == b'\r' {
            end -= 1;
        }
        std::str::from_utf8(&self.buf[..end])
            .map(|s| Some((self.number, s)))
            .map_err(|_| TraceError::NotUtf8 {
                path: path.to_path_buf(),
                line: self.number,
            })
    }
}

impl Trace {
    /// Reads and validates the trace file at `path`.
    pub fn read(path: &Path) -> Result<Trace, TraceError> {
        let f = File::open(path).map_err(|source| TraceError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let size = f.metadata().map(|m| m.len()).ok();
        Self::from_reader_sized(path, BufReader::with_capacity(1 << 16, f), size)
    }

    /// Parses trace text; `path` is only used in messages.
    pub fn parse(path: &Path, text: &str) -> Result<Trace, TraceError> {
        Self::from_reader(path, text.as_bytes())
    }

    /// Parses a trace streamed from `r`, line by line; `path` is only used in messages.
    pub fn from_reader<R: BufRead>(path: &Path, r: R) -> Result<Trace, TraceError> {
        Self::from_reader_sized(path, r, None)
    }

    /// `from_reader` with the total size in bytes when known: after the first row the columns
    /// reserve about `size / row length` values, so a large file is not copied while growing.
    fn from_reader_sized<R: BufRead>(
        path: &Path,
        r: R,
        size_bytes: Option<u64>,
    ) -> Result<Trace, TraceError> {
        let p = || path.to_path_buf();
        let mut lines = Lines {
            r,
            buf: Vec::with_capacity(256),
            number: 0,
        };
        let mut meta: Vec<(String, String)> = Vec::new();
        let mut meta_lines: Vec<usize> = Vec::new();
        let mut comments = Vec::new();

        // Leading comments and the header.
        let (header_line, columns) = loop {
            let Some((n, line)) = lines.next_line(path)? else {
                return Err(TraceError::MissingHeader {
                    path: p(),
                    line: lines.number + 1,
                    reason: if lines.number == 0 {
                        "the file is empty".into()
                    } else {
                        "end of file reached after the comment lines".into()
                    },
                });
            };
            let trimmed = line.trim();
            if trimmed.is_empty() {
                continue;
            }
            if let Some(c) = trimmed.strip_prefix('#') {
                let c = c.trim();
                if let Some(rest) = c.strip_prefix("feedloop-trace") {
                    let v = rest.trim();
                    if v != "v1" {
                        return Err(TraceError::BadMeta {
                            path: p(),
                            line: n,
                            reason: format!(
                                "unsupported trace version `{v}` (this reader reads v1)"
                            ),
                        });
                    }
                    comments.push(c.to_string());
                } else if let Some((k, v)) = c.split_once('=') {
                    let k = k.trim();
                    if check_meta_key(k).is_ok() {
                        if let Some(i) = meta.iter().position(|(mk, _)| mk == k) {
                            return Err(TraceError::BadMeta {
                                path: p(),
                                line: n,
                                reason: format!(
                                    "key `{k}` given twice (lines {} and {n})",
                                    meta_lines[i]
                                ),
                            });
                        }
                        meta.push((k.to_string(), v.trim().to_string()));
                        meta_lines.push(n);
                    } else {
                        comments.push(c.to_string());
                    }
                } else {
                    comments.push(c.to_string());
                }
                continue;
            }
            let names: Vec<&str> = line.split(',').map(str::trim).collect();
            if names.iter().all(|c| c.parse::<f64>().is_ok()) {
                return Err(TraceError::MissingHeader {
                    path: p(),
                    line: n,
                    reason:
                        "this line holds numbers; the first non-comment line must name the columns"
                            .into(),
                });
            }
            check_header(path, n, &names)?;
            let columns: Vec<String> = names.iter().map(|s| s.to_string()).collect();
            break (n, columns);
        };
        let t_index =
            columns
                .iter()
                .position(|c| c == "t")
                .ok_or_else(|| TraceError::MissingTime {
                    path: p(),
                    line: header_line,
                    present: columns.join(", "),
                })?;

        // Rows.
        let ncol = columns.len();
        let mut data: Vec<Vec<f64>> = vec![Vec::new(); ncol];
        let mut blank: Option<usize> = None;
        let mut prev_t = f64::NEG_INFINITY;
        let mut rows = 0usize;
        while let Some((n, line)) = lines.next_line(path)? {
            let body = line.trim();
            if body.is_empty() {
                blank.get_or_insert(n);
                continue;
            }
            if let Some(b) = blank {
                return Err(TraceError::BlankLine { path: p(), line: b });
            }
            if body.starts_with('#') {
                return Err(TraceError::MisplacedComment { path: p(), line: n });
            }
            let mut found = 0usize;
            for (i, cell) in body.split(',').enumerate() {
                found = i + 1;
                if i >= ncol {
                    continue;
                }
                let cell = cell.trim();
                let v: f64 = cell.parse().map_err(|_| TraceError::NotANumber {
                    path: p(),
                    line: n,
                    column: columns[i].clone(),
                    cell: quote(cell),
                })?;
                if !v.is_finite() {
                    return Err(TraceError::NotFinite {
                        path: p(),
                        line: n,
                        column: columns[i].clone(),
                        cell: quote(cell),
                    });
                }
                data[i].push(v);
            }
            if found != ncol {
                return Err(TraceError::CellCount {
                    path: p(),
                    line: n,
                    found,
                    expected: ncol,
                });
            }
            let t = data[t_index][rows];
            if t <= prev_t {
                return Err(TraceError::TimeNotIncreasing {
                    path: p(),
                    line: n,
                    t,
                    previous: prev_t,
                });
            }
            prev_t = t;
            rows += 1;
            if rows == 1 {
                if let Some(size) = size_bytes {
                    // Rows of a trace have similar lengths; 10 % spare, capped at 2^27 rows.
                    let est = (size as f64 / (line.len() + 1) as f64 * 1.1) as usize;
                    let est = est.min(1 << 27);
                    for c in &mut data {
                        c.reserve(est);
                    }
                }
            }
        }
        if rows == 0 {
            return Err(TraceError::Empty { path: p() });
        }
        if rows == 1 {
            return Err(TraceError::TooFewRows {
                path: p(),
                line: header_line + 1,
            });
        }
        for c in &mut data {
            c.shrink_to_fit();
        }
        let first_row_line = header_line + 1;
        let period_s = check_sampling(path, &data[t_index], first_row_line)?;
        if let Some(i) = meta.iter().position(|(k, _)| k == "period_s") {
            check_meta_period(path, meta_lines[i], &meta[i].1, period_s)?;
        }
        Ok(Trace {
            path: p(),
            meta,
            comments,
            columns,
            data,
            t_index,
            period_s,
        })
    }

    /// Builds a trace from column data, with the same checks as reading a file. Line numbers in
    /// errors are those the rows would have in the file [`Trace::write_to`] produces.
    pub fn from_columns(
        path: &Path,
        meta: Vec<(String, String)>,
        columns: Vec<String>,
        data: Vec<Vec<f64>>,
    ) -> Result<Trace, TraceError> {
        let p = || path.to_path_buf();
        let header_line = 2 + meta.len();
        for (i, (k, _)) in meta.iter().enumerate() {
            check_meta_key(k).map_err(|reason| TraceError::BadMeta {
                path: p(),
                line: 2 + i,
                reason,
            })?;
        }
        check_header(path, header_line, &columns)?;
        let t_index =
            columns
                .iter()
                .position(|c| c == "t")
                .ok_or_else(|| TraceError::MissingTime {
                    path: p(),
                    line: header_line,
                    present: columns.join(", "),
                })?;
        if data.len() != columns.len() {
            return Err(TraceError::CellCount {
                path: p(),
                line: header_line,
                found: data.len(),
                expected: columns.len(),
            });
        }
        let rows = data[t_index].len();
        for (c, d) in columns.iter().zip(&data) {
            if d.len() != rows {
                return Err(TraceError::ColumnLength {
                    path: p(),
                    column: c.clone(),
                    found: d.len(),
                    expected: rows,
                });
            }
            if let Some(r) = d.iter().position(|v| !v.is_finite()) {
                return Err(TraceError::NotFinite {
                    path: p(),
                    line: header_line + 1 + r,
                    column: c.clone(),
                    cell: format!("{}", d[r]),
                });
            }
        }
        if rows == 0 {
            return Err(TraceError::Empty { path: p() });
        }
        if rows == 1 {
            return Err(TraceError::TooFewRows {
                path: p(),
                line: header_line + 1,
            });
        }
        let t = &data[t_index];
        for r in 1..rows {
            if t[r] <= t[r - 1] {
                return Err(TraceError::TimeNotIncreasing {
                    path: p(),
                    line: header_line + 1 + r,
                    t: t[r],
                    previous: t[r - 1],
                });
            }
        }
        let period_s = check_sampling(path, t, header_line + 1)?;
        if let Some(i) = meta.iter().position(|(k, _)| k == "period_s") {
            check_meta_period(path, 2 + i, &meta[i].1, period_s)?;
        }
        Ok(Trace {
            path: p(),
            meta,
            comments: vec![VERSION_LINE.trim_start_matches('#').trim().to_string()],
            columns,
            data,
            t_index,
            period_s,
        })
    }

    /// Number of rows (samples).
    pub fn len(&self) -> usize {
        self.data[self.t_index].len()
    }

    /// Always false: a valid trace has at least 2 rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Sampling period: the median time step, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Time span from the first to the last row, s.
    pub fn span_s(&self) -> f64 {
        let t = self.t();
        t[t.len() - 1] - t[0]
    }

    /// The time column, s.
    pub fn t(&self) -> &[f64] {
        &self.data[self.t_index]
    }

    /// Index of column `name`.
    pub fn column_index(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }

    /// Whether column `name` exists.
    pub fn has(&self, name: &str) -> bool {
        self.column_index(name).is_some()
    }

    /// The values of column `name`.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.column_index(name).map(|i| self.data[i].as_slice())
    }

    /// The values of the column at `index` (in [`Trace::columns`] order).
    pub fn column_at(&self, index: usize) -> Option<&[f64]> {
        self.data.get(index).map(Vec::as_slice)
    }

    /// The values of column `name`, or an error naming the file, the column and the columns
    /// that are present.
    pub fn require(&self, name: &str) -> Result<&[f64], TraceError> {
        self.column(name).ok_or_else(|| TraceError::MissingColumn {
            path: self.path.clone(),
            column: name.to_string(),
            present: self.columns.join(", "),
        })
    }

    /// Axis names `A` that have both `A.cmd` and `A.load`, in column order.
    pub fn axes(&self) -> Vec<String> {
        let mut out = Vec::new();
        for c in &self.columns {
            if let Some(a) = c.strip_suffix(".cmd") {
                if is_axis_name(a) && self.has(&format!("{a}.load")) && !out.iter().any(|o| o == a)
                {
                    out.push(a.to_string());
                }
            }
        }
        out
    }

    /// The value of metadata key `key`.
    pub fn meta_value(&self, key: &str) -> Option<&str> {
        self.meta
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

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

impl fmt::Display for Trace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {} rows x {} columns, period {} s",
            self.path.display(),
            self.len(),
            self.columns.len(),
            self.period_s
        )
    }
}

/// Median of the steps of `t` (len >= 2); refuses the first step more than 1 % off it.
fn check_sampling(path: &Path, t: &[f64], first_row_line: usize) -> Result<f64, TraceError> {
    let mut steps: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let mid = steps.len() / 2;
    let median = if steps.len() % 2 == 1 {
        *steps.select_nth_unstable_by(mid, f64::total_cmp).1
    } else {
        let hi = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
        let lo = steps[..mid]
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lo + hi)
    };
    drop(steps);
    let tol = SAMPLING_TOLERANCE * median;
    for (i, w) in t.windows(2).enumerate() {
        let step = w[1] - w[0];
        if (step - median).abs() > tol {
            return Err(TraceError::UnevenSampling {
                path: path.to_path_buf(),
                line: first_row_line + i + 1,
                step_s: step,
                median_s: median,
            });
        }
    }
    Ok(median)
}

fn check_meta_period(path: &Path, line: usize, text: &str, median: f64) -> Result<(), TraceError> {
    let bad = |reason: String| TraceError::BadMeta {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let v: f64 = text
        .parse()
        .map_err(|_| bad(format!("period_s=\"{}\" is not a number", quote(text))))?;
    if !(v.is_finite() && v > 0.0) {
        return Err(bad(format!("period_s={v} must be a positive number")));
    }
    if (v - median).abs() > SAMPLING_TOLERANCE * median {
        return Err(bad(format!(
            "period_s={v} disagrees with the time column's median step {median} s by more than 1 %"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn parse(text: &str) -> Result<Trace, TraceError> {
        Trace::parse(Path::new("rig.csv"), text)
    }

    fn cols(names: &[&str]) -> Vec<String> {
        names.iter().map(|s| s.to_string()).collect()
    }

    const GOOD: &str = "# feedloop-trace v1\n# period_s=0.001\n# source=test rig\nt,x.cmd,x.load,x.torque\n0,0,0,0.5\n0.001,1e-6,0.9e-6,0.25\n0.002,2e-6,1.9e-6,-0.125\n";

    #[test]
    fn a_good_trace_is_read_with_meta_columns_and_axes() {
        let tr = parse(GOOD).unwrap();
        assert_eq!(tr.len(), 3);
        assert_eq!(tr.columns, cols(&["t", "x.cmd", "x.load", "x.torque"]));
        assert_eq!(tr.meta_value("source"), Some("test rig"));
        assert_eq!(tr.meta_value("period_s"), Some("0.001"));
        assert!((tr.period_s() - 0.001).abs() < 1e-15);
        assert_eq!(tr.axes(), vec!["x".to_string()]);
        assert_eq!(tr.column("x.torque").unwrap(), &[0.5, 0.25, -0.125]);
        assert!(tr.has("x.load") && !tr.has("x.motor"));
        assert_eq!(tr.t(), &[0.0, 0.001, 0.002]);
    }

    #[test]
    fn require_names_the_file_the_missing_column_and_those_present() {
        let tr = parse(GOOD).unwrap();
        let e = tr.require("x.motor_vel").unwrap_err().to_string();
        assert!(
            e.starts_with("rig.csv: missing column `x.motor_vel`"),
            "{e}"
        );
        assert!(e.contains("t, x.cmd, x.load, x.torque"), "{e}");
    }

    #[test]
    fn axes_need_both_cmd_and_load() {
        let tr = parse("t,x.cmd,x.load,y.cmd,z.load\n0,0,0,0,0\n1,0,0,0,0\n").unwrap();
        assert_eq!(tr.axes(), vec!["x".to_string()]);
    }

    #[test]
    fn an_empty_file_has_no_header() {
        let e = parse("").unwrap_err();
        assert!(
            matches!(e, TraceError::MissingHeader { line: 1, .. }),
            "{e}"
        );
        assert!(e
            .to_string()
            .starts_with("rig.csv: line 1: missing header row"));
    }

    #[test]
    fn a_file_of_comments_only_has_no_header() {
        let e = parse("# feedloop-trace v1\n# a=b\n").unwrap_err();
        assert!(
            matches!(e, TraceError::MissingHeader { line: 3, .. }),
            "{e}"
        );
    }

    #[test]
    fn data_without_a_header_is_refused_at_its_first_line() {
        let e = parse("# c\n0,1,2\n0.1,1,2\n").unwrap_err();
        assert!(
            matches!(e, TraceError::MissingHeader { line: 2, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("holds numbers"), "{e}");
    }

    #[test]
    fn a_header_without_t_is_refused_listing_the_columns() {
        let e = parse("time,x.cmd\n0,0\n1,1\n").unwrap_err();
        assert!(matches!(e, TraceError::MissingTime { line: 1, .. }), "{e}");
        assert!(e.to_string().contains("time, x.cmd"), "{e}");
    }

    #[test]
    fn a_duplicate_column_is_refused_with_both_positions() {
        let e = parse("t,x.cmd,x.load,x.cmd\n0,0,0,0\n").unwrap_err();
        match e {
            TraceError::DuplicateColumn {
                line,
                column,
                first,
                second,
                ..
            } => {
                assert_eq!((line, column.as_str(), first, second), (1, "x.cmd", 2, 4));
            }
            other => panic!("{other}"),
        }
    }

    #[test]
    fn bad_column_names_are_refused_with_the_reason() {
        for (header, reason) in [
            ("t,x cmd\n", "white space"),
            ("t,\"x.cmd\"\n", "quotes"),
            ("t,x.cmd,\n", "empty name"),
            ("t,x..cmd\n", "empty parts"),
            ("t,x/cmd\n", "not allowed"),
        ] {
            let e = parse(&format!("{header}0,0\n")).unwrap_err();
            assert!(
                matches!(e, TraceError::BadColumnName { line: 1, .. }),
                "{e}"
            );
            assert!(e.to_string().contains(reason), "{header:?}: {e}");
        }
    }

    #[test]
    fn a_non_numeric_cell_is_quoted_with_its_line_and_column() {
        let e = parse("t,x.cmd\n0,0\n0.1,abc\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "rig.csv: line 3: column `x.cmd`: \"abc\" is not a number"
        );
        assert_eq!(e.line(), Some(3));
    }

    #[test]
    fn an_empty_cell_is_not_a_number() {
        let e = parse("t,x.cmd\n0,0\n0.1,\n").unwrap_err();
        assert!(matches!(e, TraceError::NotANumber { line: 3, .. }), "{e}");
    }

    #[test]
    fn nan_and_inf_cells_are_refused() {
        for cell in ["NaN", "nan", "inf", "-inf", "infinity"] {
            let e = parse(&format!("t,x.cmd\n0,0\n0.1,{cell}\n")).unwrap_err();
            assert!(matches!(e, TraceError::NotFinite { line: 3, .. }), "{e}");
            assert!(e.to_string().contains(cell), "{e}");
        }
    }

    #[test]
    fn a_row_with_the_wrong_number_of_cells_is_refused() {
        let e = parse("t,x.cmd,x.load\n0,0,0\n0.1,0\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "rig.csv: line 3: 2 cells, but the header has 3 columns"
        );
        let e = parse("t,x.cmd\n0,0\n0.1,0,7\n").unwrap_err();
        assert!(matches!(e, TraceError::CellCount { found: 3, .. }), "{e}");
    }

    #[test]
    fn time_going_backwards_or_repeating_is_refused() {
        let e = parse("t,x.cmd\n0,0\n0.1,0\n0.05,0\n").unwrap_err();
        assert!(
            matches!(e, TraceError::TimeNotIncreasing { line: 4, .. }),
            "{e}"
        );
        let e = parse("t,x.cmd\n0,0\n0.1,0\n0.1,0\n").unwrap_err();
        assert!(
            matches!(e, TraceError::TimeNotIncreasing { line: 4, .. }),
            "{e}"
        );
    }

    #[test]
    fn uneven_sampling_names_the_first_offending_line() {
        // Steps 1 ms except the 4th row's, 1.5 ms.
        let e =
            parse("t,x.cmd\n0,0\n0.001,0\n0.002,0\n0.0035,0\n0.0045,0\n0.0055,0\n").unwrap_err();
        match e {
            TraceError::UnevenSampling {
                line,
                step_s,
                median_s,
                ..
            } => {
                assert_eq!(line, 5);
                assert!((step_s - 0.0015).abs() < 1e-12);
                assert!((median_s - 0.001).abs() < 1e-12);
            }
            other => panic!("{other}"),
        }
    }

    #[test]
    fn jitter_below_one_percent_is_accepted() {
        let mut text = String::from("t,x.cmd\n");
        for k in 0..100 {
            let t = k as f64 * 1e-3 + if k % 2 == 0 { 4e-6 } else { 0.0 };
            text.push_str(&format!("{t},0\n"));
        }
        let tr = parse(&text).unwrap();
        assert!((tr.period_s() - 1e-3).abs() < 1e-5);
    }

    #[test]
    fn a_header_without_rows_is_an_empty_trace() {
        let e = parse("# feedloop-trace v1\nt,x.cmd\n").unwrap_err();
        assert!(matches!(e, TraceError::Empty { .. }), "{e}");
        assert_eq!(
            e.to_string(),
            "rig.csv: empty trace: header but no data rows"
        );
    }

    #[test]
    fn a_single_row_cannot_define_a_period() {
        let e = parse("t,x.cmd\n0,0\n").unwrap_err();
        assert!(matches!(e, TraceError::TooFewRows { line: 2, .. }), "{e}");
    }

    #[test]
    fn a_comment_after_the_header_is_refused() {
        let e = parse("t,x.cmd\n0,0\n# late\n0.1,0\n").unwrap_err();
        assert!(
            matches!(e, TraceError::MisplacedComment { line: 3, .. }),
            "{e}"
        );
    }

    #[test]
    fn an_empty_line_between_rows_is_refused_but_trailing_ones_are_not() {
        let e = parse("t,x.cmd\n0,0\n\n0.1,0\n").unwrap_err();
        assert!(matches!(e, TraceError::BlankLine { line: 3, .. }), "{e}");
        assert_eq!(parse("t,x.cmd\n0,0\n0.1,0\n\n\n").unwrap().len(), 2);
    }

    #[test]
    fn crlf_line_ends_and_spaces_around_cells_are_accepted() {
        let tr = parse("t, x.cmd\r\n0, 1.5\r\n0.1 ,2.5\r\n").unwrap();
        assert_eq!(tr.column("x.cmd").unwrap(), &[1.5, 2.5]);
    }

    #[test]
    fn a_period_in_the_metadata_that_disagrees_with_the_time_column_is_refused() {
        let e = parse("# period_s=0.002\nt,x.cmd\n0,0\n0.001,0\n0.002,0\n").unwrap_err();
        assert!(matches!(e, TraceError::BadMeta { line: 1, .. }), "{e}");
        let e = parse("# period_s=fast\nt,x.cmd\n0,0\n0.001,0\n").unwrap_err();
        assert!(e.to_string().contains("not a number"), "{e}");
    }

    #[test]
    fn a_repeated_metadata_key_is_refused() {
        let e = parse("# a=1\n# a=2\nt,x.cmd\n0,0\n1,0\n").unwrap_err();
        assert!(matches!(e, TraceError::BadMeta { line: 2, .. }), "{e}");
    }

    #[test]
    fn another_trace_version_is_refused() {
        let e = parse("# feedloop-trace v2\nt,x.cmd\n0,0\n1,0\n").unwrap_err();
        assert!(
            e.to_string().contains("unsupported trace version `v2`"),
            "{e}"
        );
    }

    #[test]
    fn invalid_utf8_is_refused_with_the_line() {
        let bytes: &[u8] = b"t,x.cmd\n0,0\n0.1,\xff\n";
        let e = Trace::from_reader(Path::new("b.csv"), bytes).unwrap_err();
        assert!(matches!(e, TraceError::NotUtf8 { line: 3, .. }), "{e}");
    }

    #[test]
    fn a_missing_file_is_an_io_error_naming_it() {
        let e = Trace::read(Path::new("/nonexistent/feedloop/x.csv")).unwrap_err();
        assert!(e
            .to_string()
            .starts_with("/nonexistent/feedloop/x.csv: cannot read"));
    }

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
    fn from_columns_applies_the_same_checks_as_reading() {
        let c = cols(&["t", "x.cmd"]);
        let ok = Trace::from_columns(
            Path::new("mem"),
            vec![],
            c.clone(),
            vec![vec![0.0, 0.5, 1.0], vec![1.0, 2.0, 3.0]],
        )
        .unwrap();
        assert!((ok.period_s() - 0.5).abs() < 1e-15);
        let e = Trace::from_columns(
            Path::new("mem"),
            vec![],
            c.clone(),
            vec![vec![0.0, 0.5, 1.0], vec![1.0, 2.0]],
        )
        .unwrap_err();
        assert!(
            matches!(e, TraceError::ColumnLength { found: 2, .. }),
            "{e}"
        );
        let e = Trace::from_columns(
            Path::new("mem"),
            vec![],
            c,
            vec![vec![0.0, 0.5, 0.4], vec![1.0, 2.0, 3.0]],
        )
        .unwrap_err();
        assert!(
            matches!(e, TraceError::TimeNotIncreasing { line: 5, .. }),
            "{e}"
        );
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
    /// feedloop-runtime trace_throughput -- --ignored --nocapture`.
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
        fn random_text_never_panics_the_parser(s in "\\PC{0,200}") {
            let _ = parse(&s);
        }

        #[test]
        fn random_csv_like_text_never_panics_the_parser(
            s in "(#[ a-z=0-9.]{0,12}\n){0,2}(t|x\\.cmd|,|[0-9.e+-]{1,6}|nan|inf|\n|\r| ){0,80}"
        ) {
            let _ = parse(&s);
        }

        #[test]
        fn random_bytes_never_panic_the_reader(b in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = Trace::from_reader(Path::new("b.csv"), b.as_slice());
        }

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
