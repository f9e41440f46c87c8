//! Reading a trace: leading comments and metadata, the header, the rows, and the checks of
//! time and sampling; the same checks for a trace built from columns.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use super::{
    check_header, check_meta_key, quote, Trace, TraceError, SAMPLING_TOLERANCE, VERSION_LINE,
};

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
        Self::read_kept(path, None)
    }

    /// Reads and validates the trace file at `path` like [`Trace::read`] (every cell of every
    /// column is checked), but keeps only the time column and the columns for which `keep`
    /// is true: a long trace of many axes read for one of them takes that axis' memory only.
    pub fn read_columns(path: &Path, keep: &dyn Fn(&str) -> bool) -> Result<Trace, TraceError> {
        Self::read_kept(path, Some(keep))
    }

    /// The column names of the trace file at `path` (its header only is read and checked).
    pub fn read_header(path: &Path) -> Result<Vec<String>, TraceError> {
        let mut lines = Lines {
            r: BufReader::new(open(path)?),
            buf: Vec::with_capacity(256),
            number: 0,
        };
        let head = read_head(path, &mut lines)?;
        time_column(path, head.header_line, &head.columns)?;
        Ok(head.columns)
    }

    /// The file at `path`, keeping the columns `keep` accepts (all when `None`).
    fn read_kept(path: &Path, keep: Option<&dyn Fn(&str) -> bool>) -> Result<Trace, TraceError> {
        let f = open(path)?;
        let size = f.metadata().map(|m| m.len()).ok();
        Self::from_reader_kept(path, BufReader::with_capacity(1 << 16, f), size, keep)
    }

    /// Parses trace text; `path` is only used in messages.
    pub fn parse(path: &Path, text: &str) -> Result<Trace, TraceError> {
        Self::from_reader(path, text.as_bytes())
    }

    /// Parses a trace streamed from `r`, line by line; `path` is only used in messages.
    pub fn from_reader<R: BufRead>(path: &Path, r: R) -> Result<Trace, TraceError> {
        Self::from_reader_kept(path, r, None, None)
    }

    /// Parses a trace streamed from `r`, keeping the time column and the columns `keep`
    /// accepts (all when `None`). With the total size in bytes when known, after the first row
    /// the columns reserve about `size / row length` values, so a large file is not copied
    /// while growing.
    fn from_reader_kept<R: BufRead>(
        path: &Path,
        r: R,
        size_bytes: Option<u64>,
        keep: Option<&dyn Fn(&str) -> bool>,
    ) -> Result<Trace, TraceError> {
        let p = || path.to_path_buf();
        let mut lines = Lines {
            r,
            buf: Vec::with_capacity(256),
            number: 0,
        };
        let Head {
            meta,
            meta_lines,
            comments,
            header_line,
            columns,
        } = read_head(path, &mut lines)?;
        let t_index = time_column(path, header_line, &columns)?;
        let kept: Vec<bool> = columns
            .iter()
            .enumerate()
            .map(|(i, c)| i == t_index || keep.is_none_or(|k| k(c)))
            .collect();
        let (data, rows) = read_rows(path, &mut lines, &columns, t_index, size_bytes, &kept)?;
        let mut data: Vec<Vec<f64>> = data
            .into_iter()
            .zip(&kept)
            .filter_map(|(c, k)| k.then_some(c))
            .collect();
        let t_index = kept[..t_index].iter().filter(|k| **k).count();
        let columns: Vec<String> = columns
            .into_iter()
            .zip(&kept)
            .filter_map(|(c, k)| k.then_some(c))
            .collect();
        check_row_count(path, header_line, rows)?;
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
    /// The line of the header row in the file [`Trace::write_to`] writes for a trace with
    /// `meta_entries` metadata entries (the version line, one line per entry, then the header;
    /// data row `r`, from 0, is on the line after it plus `r`).
    pub fn written_header_line(meta_entries: usize) -> usize {
        2 + meta_entries
    }

    /// Builds a trace from column data, with the same checks as reading a file. Line numbers in
    /// errors are those the rows would have in the file [`Trace::write_to`] produces (see
    /// [`Trace::written_header_line`]).
    pub fn from_columns(
        path: &Path,
        meta: Vec<(String, String)>,
        columns: Vec<String>,
        data: Vec<Vec<f64>>,
    ) -> Result<Trace, TraceError> {
        let p = || path.to_path_buf();
        let header_line = Self::written_header_line(meta.len());
        for (i, (k, _)) in meta.iter().enumerate() {
            check_meta_key(k).map_err(|reason| TraceError::BadMeta {
                path: p(),
                line: 2 + i,
                reason,
            })?;
        }
        check_header(path, header_line, &columns)?;
        let t_index = time_column(path, header_line, &columns)?;
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
        check_row_count(path, header_line, rows)?;
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
}

/// What comes before the rows.
struct Head {
    /// `# key=value` metadata, in file order.
    meta: Vec<(String, String)>,
    /// The line of each metadata entry.
    meta_lines: Vec<usize>,
    /// Other comment lines (without the `#`).
    comments: Vec<String>,
    /// Line of the header.
    header_line: usize,
    /// Column names.
    columns: Vec<String>,
}

/// Reads the leading comments, metadata and the header.
fn read_head<R: BufRead>(path: &Path, lines: &mut Lines<R>) -> Result<Head, TraceError> {
    let p = || path.to_path_buf();
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
                        reason: format!("unsupported trace version `{v}` (this reader reads v1)"),
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
                reason: "this line holds numbers; the first non-comment line must name the columns"
                    .into(),
            });
        }
        check_header(path, n, &names)?;
        let columns: Vec<String> = names.iter().map(|s| s.to_string()).collect();
        break (n, columns);
    };
    Ok(Head {
        meta,
        meta_lines,
        comments,
        header_line,
        columns,
    })
}

/// Opens the file at `path`, the error naming it.
fn open(path: &Path) -> Result<File, TraceError> {
    File::open(path).map_err(|source| TraceError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads the rows after the header: the columns' values and the row count. With the file size
/// known, the columns reserve room for all rows after the first.
fn read_rows<R: BufRead>(
    path: &Path,
    lines: &mut Lines<R>,
    columns: &[String],
    t_index: usize,
    size_bytes: Option<u64>,
    kept: &[bool],
) -> Result<(Vec<Vec<f64>>, usize), TraceError> {
    let p = || path.to_path_buf();
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
            if kept[i] {
                data[i].push(v);
            }
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
                for (c, k) in data.iter_mut().zip(kept) {
                    if *k {
                        c.reserve(est);
                    }
                }
            }
        }
    }
    Ok((data, rows))
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

/// Index of the `t` column, or the error naming the header line and the columns present.
fn time_column(path: &Path, header_line: usize, columns: &[String]) -> Result<usize, TraceError> {
    columns
        .iter()
        .position(|c| c == "t")
        .ok_or_else(|| TraceError::MissingTime {
            path: path.to_path_buf(),
            line: header_line,
            present: columns.join(", "),
        })
}

/// A trace needs two rows at least to define its period: none is an empty trace, one is too
/// few (`header_line` is the header's line in the file).
fn check_row_count(path: &Path, header_line: usize, rows: usize) -> Result<(), TraceError> {
    match rows {
        0 => Err(TraceError::Empty {
            path: path.to_path_buf(),
        }),
        1 => Err(TraceError::TooFewRows {
            path: path.to_path_buf(),
            line: header_line + 1,
        }),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::tests::{cols, parse};
    use proptest::prelude::*;

    /// Parses `text`, which must be refused with a `TraceError::$variant` matching the fields
    /// that follow; gives the error.
    macro_rules! refused {
        ($text:expr, $variant:ident $($fields:tt)*) => {{
            let e = parse($text).unwrap_err();
            assert!(matches!(e, TraceError::$variant $($fields)*), "{e}");
            e
        }};
    }

    /// Parses `text`, which must be refused with exactly `message`; gives the error.
    fn refused_saying(text: &str, message: &str) -> TraceError {
        let e = parse(text).unwrap_err();
        assert_eq!(e.to_string(), message);
        e
    }

    #[test]
    fn reading_selected_columns_keeps_time_and_those_and_still_checks_every_cell() {
        let dir = std::env::temp_dir().join(format!("feedloop-trace-sel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("two.csv");
        std::fs::write(
            &p,
            "x.cmd,t,x.load,y.cmd,y.load\n0,0,1,2,3\n0.5,0.001,1.5,2.5,3.5\n1,0.002,2,3,4\n",
        )
        .unwrap();
        assert_eq!(
            Trace::read_header(&p).unwrap(),
            vec!["x.cmd", "t", "x.load", "y.cmd", "y.load"]
        );
        let tr = Trace::read_columns(&p, &|c: &str| c.starts_with("y.")).unwrap();
        assert_eq!(tr.columns, vec!["t", "y.cmd", "y.load"]);
        assert_eq!(tr.t(), &[0.0, 0.001, 0.002]);
        assert_eq!(tr.column("y.load").unwrap(), &[3.0, 3.5, 4.0]);
        assert!(tr.column("x.cmd").is_none());
        // a bad cell in a column that is not kept is still refused, with its line and column
        std::fs::write(
            &p,
            "t,x.cmd,x.load,y.cmd,y.load\n0,0,1,2,3\n0.001,oops,1.5,2.5,3.5\n",
        )
        .unwrap();
        let e = Trace::read_columns(&p, &|c: &str| c.starts_with("y.")).unwrap_err();
        assert!(
            matches!(&e, TraceError::NotANumber { line: 3, column, .. } if column == "x.cmd"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn an_empty_file_has_no_header() {
        let e = refused!("", MissingHeader { line: 1, .. });
        assert!(e
            .to_string()
            .starts_with("rig.csv: line 1: missing header row"));
    }

    #[test]
    fn a_file_of_comments_only_has_no_header() {
        refused!(
            "# feedloop-trace v1\n# a=b\n",
            MissingHeader { line: 3, .. }
        );
    }

    #[test]
    fn data_without_a_header_is_refused_at_its_first_line() {
        let e = refused!("# c\n0,1,2\n0.1,1,2\n", MissingHeader { line: 2, .. });
        assert!(e.to_string().contains("holds numbers"), "{e}");
    }

    #[test]
    fn a_header_without_t_is_refused_listing_the_columns() {
        let e = refused!("time,x.cmd\n0,0\n1,1\n", MissingTime { line: 1, .. });
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
            let e = refused!(&format!("{header}0,0\n"), BadColumnName { line: 1, .. });
            assert!(e.to_string().contains(reason), "{header:?}: {e}");
        }
    }

    #[test]
    fn a_non_numeric_cell_is_quoted_with_its_line_and_column() {
        let e = refused_saying(
            "t,x.cmd\n0,0\n0.1,abc\n",
            "rig.csv: line 3: column `x.cmd`: \"abc\" is not a number",
        );
        assert_eq!(e.line(), Some(3));
    }

    #[test]
    fn an_empty_cell_is_not_a_number() {
        refused!("t,x.cmd\n0,0\n0.1,\n", NotANumber { line: 3, .. });
    }

    #[test]
    fn nan_and_inf_cells_are_refused() {
        for cell in ["NaN", "nan", "inf", "-inf", "infinity"] {
            let e = refused!(
                &format!("t,x.cmd\n0,0\n0.1,{cell}\n"),
                NotFinite { line: 3, .. }
            );
            assert!(e.to_string().contains(cell), "{e}");
        }
    }

    #[test]
    fn a_row_with_the_wrong_number_of_cells_is_refused() {
        refused_saying(
            "t,x.cmd,x.load\n0,0,0\n0.1,0\n",
            "rig.csv: line 3: 2 cells, but the header has 3 columns",
        );
        refused!("t,x.cmd\n0,0\n0.1,0,7\n", CellCount { found: 3, .. });
    }

    #[test]
    fn time_going_backwards_or_repeating_is_refused() {
        for last in ["0.05", "0.1"] {
            let text = format!("t,x.cmd\n0,0\n0.1,0\n{last},0\n");
            refused!(&text, TimeNotIncreasing { line: 4, .. });
        }
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
        let e = refused_saying(
            "# feedloop-trace v1\nt,x.cmd\n",
            "rig.csv: empty trace: header but no data rows",
        );
        assert!(matches!(e, TraceError::Empty { .. }), "{e}");
    }

    #[test]
    fn a_single_row_cannot_define_a_period() {
        refused!("t,x.cmd\n0,0\n", TooFewRows { line: 2, .. });
    }

    #[test]
    fn a_comment_after_the_header_is_refused() {
        refused!(
            "t,x.cmd\n0,0\n# late\n0.1,0\n",
            MisplacedComment { line: 3, .. }
        );
    }

    #[test]
    fn an_empty_line_between_rows_is_refused_but_trailing_ones_are_not() {
        refused!("t,x.cmd\n0,0\n\n0.1,0\n", BlankLine { line: 3, .. });
        assert_eq!(parse("t,x.cmd\n0,0\n0.1,0\n\n\n").unwrap().len(), 2);
    }

    #[test]
    fn crlf_line_ends_and_spaces_around_cells_are_accepted() {
        let tr = parse("t, x.cmd\r\n0, 1.5\r\n0.1 ,2.5\r\n").unwrap();
        assert_eq!(tr.column("x.cmd").unwrap(), &[1.5, 2.5]);
    }

    #[test]
    fn a_period_in_the_metadata_that_disagrees_with_the_time_column_is_refused() {
        refused!(
            "# period_s=0.002\nt,x.cmd\n0,0\n0.001,0\n0.002,0\n",
            BadMeta { line: 1, .. }
        );
        let e = parse("# period_s=fast\nt,x.cmd\n0,0\n0.001,0\n").unwrap_err();
        assert!(e.to_string().contains("not a number"), "{e}");
    }

    #[test]
    fn a_repeated_metadata_key_is_refused() {
        refused!("# a=1\n# a=2\nt,x.cmd\n0,0\n1,0\n", BadMeta { line: 2, .. });
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
    }
}
