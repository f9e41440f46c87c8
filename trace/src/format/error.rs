//! Why a trace could not be read or built: [`TraceError`], naming the file and, where it is
//! about one place, the line.

use std::io;
use std::path::{Path, PathBuf};

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

/// The file and the line (when it is about one) of a `TraceError` behind a shared or a mutable
/// reference: one list of the variants for [`TraceError::path`], [`TraceError::line`] and
/// [`TraceError::relocated`].
macro_rules! place {
    ($error:expr) => {
        match $error {
            TraceError::NotUtf8 { path, line }
            | TraceError::MissingHeader { path, line, .. }
            | TraceError::MissingTime { path, line, .. }
            | TraceError::DuplicateColumn { path, line, .. }
            | TraceError::BadColumnName { path, line, .. }
            | TraceError::BadMeta { path, line, .. }
            | TraceError::MisplacedComment { path, line }
            | TraceError::BlankLine { path, line }
            | TraceError::NotANumber { path, line, .. }
            | TraceError::NotFinite { path, line, .. }
            | TraceError::CellCount { path, line, .. }
            | TraceError::TimeNotIncreasing { path, line, .. }
            | TraceError::UnevenSampling { path, line, .. }
            | TraceError::TooFewRows { path, line } => (path, Some(line)),
            TraceError::Io { path, .. }
            | TraceError::Empty { path }
            | TraceError::ColumnLength { path, .. }
            | TraceError::MissingColumn { path, .. } => (path, None),
        }
    };
}

impl TraceError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        self.place().0
    }

    /// The 1-based line the error is about, when it is about one line.
    pub fn line(&self) -> Option<usize> {
        self.place().1.copied()
    }

    /// The same error about another file: `path`, with each line number `l` replaced by
    /// `line(l)`. For a trace built from another file's rows (e.g. an import), so the error
    /// names the file and line the user can open.
    pub fn relocated(mut self, path: &Path, line: impl Fn(usize) -> usize) -> TraceError {
        let (p, l) = self.place_mut();
        *p = path.to_path_buf();
        if let Some(l) = l {
            *l = line(*l);
        }
        self
    }

    /// The file and the line (when it is about one) of the error.
    fn place(&self) -> (&PathBuf, Option<&usize>) {
        place!(self)
    }

    fn place_mut(&mut self) -> (&mut PathBuf, Option<&mut usize>) {
        place!(self)
    }
}
