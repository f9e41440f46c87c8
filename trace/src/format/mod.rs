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
//!
//! # Layout
//! `error` holds [`TraceError`]; `read` the reader ([`Trace::read`], [`Trace::from_columns`])
//! and its checks; `write` the writer ([`TraceWriter`], [`Trace::write_to`]). This file holds
//! what both sides share: the version line, the name rules and the in-memory [`Trace`].

mod error;
mod read;
mod write;

pub use error::TraceError;
pub use write::TraceWriter;

use std::fmt;
use std::path::{Path, PathBuf};

/// First line of every trace written by feedloop.
pub const VERSION_LINE: &str = "# feedloop-trace v1";

/// Largest allowed deviation of one time step from the median step, as a fraction (1 %).
pub const SAMPLING_TOLERANCE: f64 = 0.01;

/// Longest cell text quoted in an error message, characters.
const QUOTE_MAX: usize = 40;

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

impl Trace {
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

    /// The column names and their values, taken out of the trace (no copy: a long trace's
    /// columns can be reduced one by one, each freed when done).
    pub fn into_columns(self) -> Vec<(String, Vec<f64>)> {
        self.columns.into_iter().zip(self.data).collect()
    }

    /// Axis names `A` that have both `A.cmd` and `A.load`, in column order.
    pub fn axes(&self) -> Vec<String> {
        axes_of(&self.columns)
    }

    /// The value of metadata key `key`.
    pub fn meta_value(&self, key: &str) -> Option<&str> {
        self.meta
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
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

/// Axis names `A` among trace column names `columns` that have both `A.cmd` and `A.load`, in
/// column order (what [`Trace::axes`] gives, from a header alone).
pub fn axes_of(columns: &[String]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for c in columns {
        if let Some(a) = c.strip_suffix(".cmd") {
            if is_axis_name(a)
                && columns.iter().any(|x| *x == format!("{a}.load"))
                && !out.iter().any(|o| o == a)
            {
                out.push(a.to_string());
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn parse(text: &str) -> Result<Trace, TraceError> {
        Trace::parse(Path::new("rig.csv"), text)
    }

    pub(super) fn cols(names: &[&str]) -> Vec<String> {
        names.iter().map(|s| s.to_string()).collect()
    }

    pub(super) const GOOD: &str = "# feedloop-trace v1\n# period_s=0.001\n# source=test rig\nt,x.cmd,x.load,x.torque\n0,0,0,0.5\n0.001,1e-6,0.9e-6,0.25\n0.002,2e-6,1.9e-6,-0.125\n";

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
    fn into_columns_gives_every_column_with_the_values_read() {
        let tr = parse(GOOD).unwrap();
        let want: Vec<(String, Vec<f64>)> = tr
            .columns
            .iter()
            .map(|c| (c.clone(), tr.column(c).unwrap().to_vec()))
            .collect();
        assert_eq!(tr.into_columns(), want);
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
}
