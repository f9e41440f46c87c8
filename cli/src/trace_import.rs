//! `feedloop trace import --format halsampler|halscope`: LinuxCNC captures into trace format v1.
//!
//! - halsampler prints one line per sample, its values separated by spaces (with `-t`, the sample
//!   number first) and no header: its fields are named by their position, `1`, `2`, ... in the
//!   `--map` (with `-t`, field `1` is the sample number). It records no time: give `--period-s`
//!   (the sampler thread's period times its decimation) or map `t`.
//! - halscope's "save log" writes `# Sampling period is N ns`, a header row of the channels' HAL
//!   names separated by `;`, optional `# Position:` / `# Scale:` lines, then one row per sample;
//!   older versions wrote the period line without `#`. Channels are named in the `--map` by
//!   their HAL names (e.g. `x.cmd=joint.0.pos-cmd*0.001`); time comes from the period line.
//!
//! The mapping (`target=source*factor+offset`) is that of the CSV import.

use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use feedloop_analysis::workbench::import::MapEntry;
use feedloop_trace::Trace;

/// The source formats of `trace import`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImportFormat {
    /// CSV with a header row (`,`, `;` or tab separated).
    Csv,
    /// LinuxCNC halsampler output (space-separated values, no header; fields named 1, 2, ...).
    Halsampler,
    /// LinuxCNC halscope log file (period line, `;`-separated header of HAL names, rows).
    Halscope,
}

/// A table read from a HAL capture: field names, values by column, the source line of each row
/// and the sampling period the file states.
struct Table {
    names: Vec<String>,
    cols: Vec<Vec<f64>>,
    lines: Vec<usize>,
    period_s: Option<f64>,
    header_line: usize,
}

impl Table {
    /// Appends the row of source line `ln` (as many cells as names, checked by the caller).
    fn push_row(&mut self, from: &Path, ln: usize, cells: &[&str]) -> Result<()> {
        for (k, c) in cells.iter().enumerate() {
            self.cols[k].push(number(from, ln, &self.names[k], c)?);
        }
        self.lines.push(ln);
        Ok(())
    }
}

fn err(from: &Path, line: usize, what: String) -> anyhow::Error {
    anyhow!("{}: line {line}: {what}", from.display())
}

/// The value of cell `cell` (field `name`) on line `line`.
fn number(from: &Path, line: usize, name: &str, cell: &str) -> Result<f64> {
    let v: f64 = cell.trim().parse().map_err(|_| {
        err(
            from,
            line,
            format!("field `{name}`: \"{}\" is not a number", cell.trim()),
        )
    })?;
    if !v.is_finite() {
        return Err(err(
            from,
            line,
            format!("field `{name}`: \"{}\" is not finite", cell.trim()),
        ));
    }
    Ok(v)
}

fn read_halsampler(from: &Path, text: &str) -> Result<Table> {
    let mut t = Table {
        names: Vec::new(),
        cols: Vec::new(),
        lines: Vec::new(),
        period_s: None,
        header_line: 0,
    };
    for (i, line) in text.lines().enumerate() {
        let ln = i + 1;
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = l.split_whitespace().collect();
        if t.names.is_empty() {
            t.names = (1..=cells.len()).map(|k| k.to_string()).collect();
            t.cols = vec![Vec::new(); cells.len()];
        } else if cells.len() != t.names.len() {
            bail!(err(
                from,
                ln,
                format!(
                    "{} values, but the first sample has {} (halsampler prints every channel on every line)",
                    cells.len(),
                    t.names.len()
                )
            ));
        }
        t.push_row(from, ln, &cells)?;
    }
    if t.lines.is_empty() {
        bail!(
            "{}: no samples: halsampler output has one line of space-separated values per sample",
            from.display()
        );
    }
    Ok(t)
}

/// The period of a halscope line `[# ]Sampling period is N ns`.
fn halscope_period(line: &str) -> Option<Option<f64>> {
    let l = line.trim().trim_start_matches('#').trim();
    let rest = l.strip_prefix("Sampling period is")?;
    let ns = rest.trim().strip_suffix("ns")?.trim();
    Some(
        ns.parse::<f64>()
            .ok()
            .filter(|v| *v > 0.0)
            .map(|v| v * 1e-9),
    )
}

fn read_halscope(from: &Path, text: &str) -> Result<Table> {
    let mut t = Table {
        names: Vec::new(),
        cols: Vec::new(),
        lines: Vec::new(),
        period_s: None,
        header_line: 0,
    };
    let mut sep = ';';
    for (i, line) in text.lines().enumerate() {
        let ln = i + 1;
        let l = line.trim();
        if l.is_empty() {
            continue;
        }
        if let Some(p) = halscope_period(l) {
            t.period_s = Some(p.ok_or_else(|| {
                err(
                    from,
                    ln,
                    format!("\"{l}\": the sampling period must be a number of nanoseconds > 0"),
                )
            })?);
            continue;
        }
        if l.starts_with('#') {
            continue;
        }
        if t.names.is_empty() {
            if t.period_s.is_none() {
                bail!(err(
                    from,
                    ln,
                    "expected the line `# Sampling period is N ns` before the header of channel names (is this a halscope log file?)".into()
                ));
            }
            sep = [';', '\t', ',']
                .into_iter()
                .max_by_key(|c| l.matches(*c).count())
                .unwrap_or(';');
            t.names = l
                .split(sep)
                .map(|s| s.trim().to_string())
                .filter(|s| !s.is_empty())
                .collect();
            t.cols = vec![Vec::new(); t.names.len()];
            t.header_line = ln;
            continue;
        }
        let cells: Vec<&str> = l
            .split(sep)
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .collect();
        if cells.len() != t.names.len() {
            bail!(err(
                from,
                ln,
                format!(
                    "{} values, but the header (line {}) names {} channels",
                    cells.len(),
                    t.header_line,
                    t.names.len()
                )
            ));
        }
        t.push_row(from, ln, &cells)?;
    }
    if t.names.is_empty() {
        bail!(
            "{}: no header of channel names: a halscope log file has `# Sampling period is N ns`, then the channels' HAL names separated by `;`, then one row per sample",
            from.display()
        );
    }
    if t.lines.is_empty() {
        bail!("{}: no samples after the header", from.display());
    }
    Ok(t)
}

/// Imports a HAL capture `from` in `format` (not CSV) into a trace with the mapped columns,
/// written to `out`.
pub fn import_hal(
    from: &Path,
    format: ImportFormat,
    map: &[MapEntry],
    period_s: Option<f64>,
    out: &Path,
) -> Result<Trace> {
    let text = std::fs::read_to_string(from)
        .with_context(|| format!("{}: cannot read", from.display()))?;
    let table = match format {
        ImportFormat::Halsampler => read_halsampler(from, &text)?,
        ImportFormat::Halscope => read_halscope(from, &text)?,
        ImportFormat::Csv => bail!("a CSV source is read by the CSV import"),
    };
    if let Some(p) = period_s {
        if !(p.is_finite() && p > 0.0) {
            bail!("--period-s {p}: must be a finite period > 0 s");
        }
    }
    let mut columns = Vec::new();
    let mut data = Vec::new();
    for e in map {
        let i = table
            .names
            .iter()
            .position(|n| *n == e.source)
            .ok_or_else(|| {
                anyhow!(
                    "--map {}={}: {} has no field `{}` (fields: {})",
                    e.target,
                    e.source,
                    from.display(),
                    e.source,
                    table.names.join(", ")
                )
            })?;
        columns.push(e.target.clone());
        data.push(
            table.cols[i]
                .iter()
                .map(|v| v * e.scale + e.offset)
                .collect::<Vec<f64>>(),
        );
    }
    if !columns.iter().any(|c| c == "t") {
        let p = period_s.or(table.period_s).ok_or_else(|| {
            anyhow!(
                "{}: no time: halsampler records none; give --period-s (the sampler thread's period times its decimation) or map a field to `t`",
                from.display()
            )
        })?;
        columns.insert(0, "t".into());
        data.insert(0, (0..table.lines.len()).map(|k| k as f64 * p).collect());
    }
    let meta = vec![(
        "source".to_string(),
        format!(
            "feedloop trace import of {} ({})",
            from.display(),
            match format {
                ImportFormat::Halsampler => "halsampler",
                _ => "halscope",
            }
        ),
    )];
    let header_line = Trace::written_header_line(meta.len());
    let lines = table.lines;
    let hl = table.header_line.max(1);
    let trace = Trace::from_columns(out, meta, columns, data).map_err(|e| {
        // rows are the source's rows: name the source file and line
        e.relocated(from, |l| match l.checked_sub(header_line + 1) {
            Some(r) => lines.get(r).copied().unwrap_or(l),
            None => hl,
        })
    })?;
    trace
        .write(out)
        .with_context(|| format!("{}: cannot write", out.display()))?;
    Ok(trace)
}
