//! `trace import` (another tool's CSV export into trace format v1, with explicit scaling) and
//! `model init` (a nominal starting model from a trace: base parameters by least squares).

use std::path::Path;

use feedloop_model::model::{AxisKind, ModelFile, PlantParams};
use feedloop_trace::{check_column_name, Trace};

use super::data::{load_axis, pick_axis, AxisData, Prep};
use super::effects::{round_sig, WbModel};
use super::lsq::{blocks, cross_validate, normals};
use super::signal::span;
use super::WorkbenchError;

/// One `target=expression` entry of `--map`.
#[derive(Debug, Clone, PartialEq)]
pub struct MapEntry {
    /// Column of the new trace (e.g. `x.cmd`).
    pub target: String,
    /// Source column.
    pub source: String,
    /// Factor applied to the source value.
    pub scale: f64,
    /// Offset added after scaling.
    pub offset: f64,
}

/// Parses `--map "x.cmd=col_a*0.001,x.load=col_b/1000,x.torque=-col_c*2.5+0.1"`.
///
/// Each expression is a source column name, optionally negated, followed by any number of
/// `*number`, `/number` and a final `+number` / `-number` offset.
pub fn parse_map(map: &str) -> Result<Vec<MapEntry>, WorkbenchError> {
    let bad = |item: &str, reason: String| WorkbenchError::BadArgument {
        arg: format!("--map {item}"),
        reason,
    };
    let mut out: Vec<MapEntry> = Vec::new();
    for item in map.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (target, expr) = item
            .split_once('=')
            .ok_or_else(|| bad(item, "expected `target=source_column[*factor]`".into()))?;
        let target = target.trim().to_string();
        check_column_name(&target)
            .map_err(|r| bad(item, format!("target column `{target}`: {r}")))?;
        if out.iter().any(|e| e.target == target) {
            return Err(bad(
                item,
                format!("target column `{target}` is mapped twice"),
            ));
        }
        let mut s = expr.trim();
        let mut scale = 1.0;
        if let Some(rest) = s.strip_prefix('-') {
            scale = -1.0;
            s = rest.trim_start();
        }
        let end = s.find(['*', '/', '+']).unwrap_or(s.len());
        // a '-' after the name starts an offset (names may contain '-' only before any operator)
        let (name, mut rest) = s.split_at(end);
        let name = name.trim();
        if name.is_empty() {
            return Err(bad(item, "no source column named".into()));
        }
        let mut offset = 0.0;
        while !rest.is_empty() {
            let op = rest.as_bytes()[0] as char;
            let tail = &rest[1..];
            let stop = tail[1.min(tail.len())..]
                .find(['*', '/', '+'])
                .map(|i| i + 1.min(tail.len()))
                .unwrap_or(tail.len());
            let (num, next) = tail.split_at(stop);
            let v: f64 = num
                .trim()
                .parse()
                .map_err(|_| bad(item, format!("`{}` is not a number", num.trim())))?;
            if !v.is_finite() {
                return Err(bad(
                    item,
                    format!("`{}` is not a finite number", num.trim()),
                ));
            }
            match op {
                '*' => scale *= v,
                '/' if v != 0.0 => scale /= v,
                '/' => return Err(bad(item, "division by zero".into())),
                _ => offset += v,
            }
            rest = next;
        }
        out.push(MapEntry {
            target,
            source: name.to_string(),
            scale,
            offset,
        });
    }
    if out.is_empty() {
        return Err(bad(map, "empty map".into()));
    }
    Ok(out)
}

/// Imports `from` (CSV with a header row; `,`, `;` or tab separated; `#` comment lines allowed)
/// into a trace with the mapped columns. Time comes from a `t=...` entry, else from a source
/// column named `t`, else from `period_s` (then `t = k * period_s`). In one pass over the
/// source, each step feeding the next: the header ([`Source::read`]), the column map
/// ([`mapped_columns`], [`time_column`]), the rows ([`Source::rows`]), then the trace written.
pub fn import(
    from: &Path,
    map: &[MapEntry],
    period_s: Option<f64>,
    out: &Path,
) -> Result<Trace, WorkbenchError> {
    let text = std::fs::read_to_string(from).map_err(|e| WorkbenchError::io(from, e))?;
    let src = Source::read(from, &text)?;
    let idx = mapped_columns(&src, map)?;
    let t_src = time_column(&src, map, period_s)?;
    let Rows { cols, t, src_lines } = src.rows(map, &idx, t_src)?;
    let n = cols[0].len();
    let mut columns = Vec::new();
    let mut data = Vec::new();
    if !map.iter().any(|e| e.target == "t") {
        columns.push("t".to_string());
        data.push(if t_src.is_some() {
            t
        } else {
            let p = period_s.unwrap_or(1.0);
            (0..n).map(|k| k as f64 * p).collect()
        });
    }
    for (e, c) in map.iter().zip(cols) {
        columns.push(e.target.clone());
        data.push(c);
    }
    let meta = vec![(
        "source".to_string(),
        format!("feedloop trace import of {}", from.display()),
    )];
    let header_line = Trace::written_header_line(meta.len());
    let trace = Trace::from_columns(out, meta, columns, data).map_err(|e| {
        // its rows are the source's rows: name the source file and line (the time column after
        // the --map scaling); the header and metadata lines become the source's header line
        let e = e.relocated(from, |l| match l.checked_sub(header_line + 1) {
            Some(r) => src_lines.get(r).copied().unwrap_or(l),
            None => src.hline + 1,
        });
        WorkbenchError::Trace(e)
    })?;
    trace.write(out).map_err(|e| WorkbenchError::io(out, e))?;
    Ok(trace)
}

/// The error of line `line` (1-based) of source file `from`.
fn line_err(from: &Path, line: usize, reason: String) -> WorkbenchError {
    WorkbenchError::Data {
        path: from.to_path_buf(),
        reason: format!("line {line}: {reason}"),
    }
}

/// A source file of `trace import`: its header and its data lines.
struct Source<'a> {
    from: &'a Path,
    /// Index (0-based) of the header line.
    hline: usize,
    /// The separator, the one the header holds most of.
    sep: char,
    /// The header's column names.
    names: Vec<String>,
    /// The data lines with their indices (0-based), comments and blank lines left out.
    lines: Vec<(usize, &'a str)>,
}

impl<'a> Source<'a> {
    /// The header (the first line that is neither a comment nor blank) and the data lines of
    /// `text`, read from `from`.
    fn read(from: &'a Path, text: &'a str) -> Result<Self, WorkbenchError> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim_start().starts_with('#') && !l.trim().is_empty());
        let (hline, header) = lines
            .next()
            .ok_or_else(|| line_err(from, 1, "no header row".into()))?;
        let sep = [',', ';', '\t']
            .into_iter()
            .max_by_key(|c| header.matches(*c).count())
            .unwrap_or(',');
        let names: Vec<String> = header
            .split(sep)
            .map(|s| s.trim().trim_matches('"').to_string())
            .collect();
        Ok(Source {
            from,
            hline,
            sep,
            names,
            lines: lines.collect(),
        })
    }

    /// The mapped columns (scaled and offset), the time column `t_src` when read from the
    /// source, and the source line of every row, so that the checks of the built trace name the
    /// source.
    fn rows(
        &self,
        map: &[MapEntry],
        idx: &[usize],
        t_src: Option<usize>,
    ) -> Result<Rows, WorkbenchError> {
        let (from, names) = (self.from, &self.names);
        let mut cols: Vec<Vec<f64>> = vec![Vec::new(); map.len()];
        let mut t = Vec::new();
        let mut src_lines: Vec<usize> = Vec::new();
        for &(ln, line) in &self.lines {
            src_lines.push(ln + 1);
            let cells: Vec<&str> = line.split(self.sep).collect();
            if cells.len() != names.len() {
                return Err(line_err(
                    from,
                    ln + 1,
                    format!(
                        "{} cells, but the header has {} columns",
                        cells.len(),
                        names.len()
                    ),
                ));
            }
            let num = |i: usize| -> Result<f64, WorkbenchError> {
                let c = cells[i].trim().trim_matches('"');
                let v: f64 = c.parse().map_err(|_| {
                    line_err(
                        from,
                        ln + 1,
                        format!("column `{}`: \"{c}\" is not a number", names[i]),
                    )
                })?;
                if !v.is_finite() {
                    return Err(line_err(
                        from,
                        ln + 1,
                        format!("column `{}`: \"{c}\" is not finite", names[i]),
                    ));
                }
                Ok(v)
            };
            for (j, (e, &i)) in map.iter().zip(idx).enumerate() {
                cols[j].push(num(i)? * e.scale + e.offset);
            }
            if let Some(i) = t_src {
                t.push(num(i)?);
            }
        }
        Ok(Rows { cols, t, src_lines })
    }
}

/// What [`Source::rows`] reads.
struct Rows {
    /// The mapped columns, in the order of the map.
    cols: Vec<Vec<f64>>,
    /// The source's time column, when read from it.
    t: Vec<f64>,
    /// The source line (1-based) of every row.
    src_lines: Vec<usize>,
}

/// The index in the source of every mapped column, or an error naming the one it lacks.
fn mapped_columns(src: &Source<'_>, map: &[MapEntry]) -> Result<Vec<usize>, WorkbenchError> {
    let names = &src.names;
    let mut idx = Vec::new();
    for e in map {
        let i = names.iter().position(|n| *n == e.source).ok_or_else(|| {
            WorkbenchError::BadArgument {
                arg: format!("--map {}={}", e.target, e.source),
                reason: format!(
                    "{}: line {}: no column `{}` (columns: {})",
                    src.from.display(),
                    src.hline + 1,
                    e.source,
                    names.join(", ")
                ),
            }
        })?;
        idx.push(i);
    }
    Ok(idx)
}

/// The source column `t`, when time is not mapped and the source has it; an error when time
/// comes from nowhere (not mapped, no `t` column, no period).
fn time_column(
    src: &Source<'_>,
    map: &[MapEntry],
    period_s: Option<f64>,
) -> Result<Option<usize>, WorkbenchError> {
    let t_src = if map.iter().any(|e| e.target == "t") {
        None
    } else {
        src.names.iter().position(|n| n == "t")
    };
    if !map.iter().any(|e| e.target == "t") && t_src.is_none() && period_s.is_none() {
        return Err(WorkbenchError::BadArgument {
            arg: "--map".into(),
            reason: format!(
                "{}: no time: map a column to `t` (e.g. t=time_ms*0.001), or give --period-s",
                src.from.display()
            ),
        });
    }
    Ok(t_src)
}

/// Builds a nominal model of `spec.kind` for axis `axis` of `trace` by least squares on its
/// torque (no effects, no controller), and writes it to `out`. A ball screw's lead and a rotary
/// axis's gear ratio come from `spec`, else from the motor/load travel ratio when the trace has a
/// motor column. In steps: a provisional model that reads the trace in the kind's units
/// ([`provisional`]), the least squares for the kind ([`fitted_table`]), the written file.
pub fn model_init(
    trace: &Trace,
    spec: &InitSpec,
    axis: Option<&str>,
    out: &Path,
) -> Result<WbModel, WorkbenchError> {
    let axis = pick_axis(trace, out, axis)?;
    let file = provisional(trace, spec, &axis, out)?;
    let d = load_axis(trace, &file, &axis, &Prep::default())?;
    let y = d.require_torque("model init (least squares on the torque)", trace)?;
    let mut notes = Vec::new();
    let t = fitted_table(&d, y, spec.kind, &file, &mut notes);
    let file = ModelFile::from_table(&t, out)?;
    let m = WbModel::from_parts(file, t.clone())?;
    let text = format!(
        "# nominal model from `feedloop model init` on {} (axis {axis}): base parameters by least squares, no effects\n{}{}",
        trace.path.display(),
        notes.iter().map(|n| format!("# {n}\n")).collect::<String>(),
        toml::to_string_pretty(&t).unwrap_or_default()
    );
    std::fs::write(out, text).map_err(|e| WorkbenchError::io(out, e))?;
    Ok(m)
}

/// A model of `spec.kind` with unit base parameters and the ratio between motor and load units
/// (from `spec`, else from the motor/load travel ratio of axis `axis` of `trace`): what reads
/// the trace in the kind's units.
fn provisional(
    trace: &Trace,
    spec: &InitSpec,
    axis: &str,
    out: &Path,
) -> Result<ModelFile, WorkbenchError> {
    let kind = spec.kind;
    // motor units per load unit from the motor/load travel ratio (when the trace has a motor
    // column): a lead for a ball screw, a gear ratio for a rotary axis
    let travels = |flag: &str, what: &str| -> Result<(f64, f64), WorkbenchError> {
        let m = trace.column(&format!("{axis}.motor")).ok_or_else(|| WorkbenchError::BadArgument {
            arg: flag.into(),
            reason: format!(
                "{}: a {} model needs the {what}: give {flag}, or a trace with `{axis}.motor` to estimate it",
                trace.path.display(),
                kind.id()
            ),
        })?;
        let l = trace.require(&format!("{axis}.load"))?;
        Ok((span(m), span(l)))
    };
    let provisional = match kind {
        AxisKind::BallScrew => {
            let lead = match spec.lead_m {
                Some(l) => l,
                None => {
                    let (m, l) = travels("--lead-m", "screw lead")?;
                    2.0 * std::f64::consts::PI * l / m.max(1e-300)
                }
            };
            format!("kind = \"ballscrew\"\njm_kgm2 = 1.0\nkl_nm_per_rad = 1.0\njl_kgm2 = 1.0\nlead_m = {lead}\n")
        }
        AxisKind::Rotary => {
            let gear = match (spec.gear_ratio, trace.column(&format!("{axis}.motor"))) {
                (Some(g), _) => g,
                (None, Some(_)) => {
                    let (m, l) = travels("--gear-ratio", "gear ratio")?;
                    gear_of_travel(m / l.max(1e-300))
                }
                // one encoder: the load column is the motor's, expressed at the load
                (None, None) => 1.0,
            };
            format!("kind = \"rotary\"\njm_kgm2 = 1.0\nkl_nm_per_rad = 1.0\njl_kgm2 = 1.0\ngear_ratio = {gear}\n")
        }
        AxisKind::Rigid => "kind = \"rigid\"\nmass_kg = 1.0\n".to_string(),
    };
    let table: toml::Table = provisional
        .parse()
        .map_err(|e| WorkbenchError::BadArgument {
            arg: "--lead-m / --gear-ratio".into(),
            reason: format!("{e}"),
        })?;
    Ok(ModelFile::from_table(&table, out)?)
}

/// The model file's table of a `kind` model fitted by least squares on torque `y` of `d` (read
/// with the provisional `file`), what the fit leaves out said in `notes`.
fn fitted_table(
    d: &AxisData,
    y: &[f64],
    kind: AxisKind,
    file: &ModelFile,
    notes: &mut Vec<String>,
) -> toml::Table {
    let bl = blocks(d.range, 1);
    let mut t = toml::Table::new();
    t.insert("kind".into(), toml::Value::String(kind.id().into()));
    let pos = |v: f64, floor: f64| round_sig(v.max(floor));
    match kind {
        AxisKind::Rigid => {
            let th = cross_validate(&normals(&[&d.am, &d.vm], y, &bl)).theta;
            t.insert("mass_kg".into(), toml::Value::Float(pos(th[0], 1e-6)));
            t.insert(
                "viscous_ns_per_m".into(),
                toml::Value::Float(pos(th[1], 0.0)),
            );
        }
        AxisKind::BallScrew | AxisKind::Rotary => {
            let (j, dmp) = if d.has_motor() {
                let th = cross_validate(&normals(&[&d.am, &d.al, &d.vm, &d.vl], y, &bl)).theta;
                ((th[0], th[1]), (th[2], th[3]))
            } else {
                let th = cross_validate(&normals(&[&d.am, &d.vm], y, &bl)).theta;
                ((0.4 * th[0], 0.6 * th[0]), (0.5 * th[1], 0.5 * th[1]))
            };
            let jm = pos(j.0, 1e-9);
            let jl = pos(j.1, 1e-9);
            let kl = if kind == AxisKind::Rotary {
                rotary_stiffness(d, y, jm, &bl, notes)
            } else {
                ballscrew_stiffness(d, jm, jl, dmp.1.max(0.0), &bl)
            };
            t.insert("jm_kgm2".into(), toml::Value::Float(jm));
            t.insert("dm_nms_per_rad".into(), toml::Value::Float(pos(dmp.0, 0.0)));
            t.insert("kl_nm_per_rad".into(), toml::Value::Float(round_sig(kl)));
            t.insert("cl_nms_per_rad".into(), toml::Value::Float(0.0));
            t.insert("jl_kgm2".into(), toml::Value::Float(jl));
            t.insert("dl_nms_per_rad".into(), toml::Value::Float(pos(dmp.1, 0.0)));
            match &file.plant {
                PlantParams::BallScrew { lead_m, .. } => {
                    t.insert("lead_m".into(), toml::Value::Float(round_sig(*lead_m)));
                    t.insert("gear_ratio".into(), toml::Value::Float(1.0));
                }
                PlantParams::Rotary { gear_ratio, .. } => {
                    t.insert(
                        "gear_ratio".into(),
                        toml::Value::Float(round_sig(*gear_ratio)),
                    );
                }
                PlantParams::Rigid(_) => {}
            }
        }
    }
    t
}

/// What `model init` builds: the axis kind and, where the trace cannot tell, the ratio between
/// motor and load units.
#[derive(Debug, Clone, Copy)]
pub struct InitSpec {
    /// Axis kind.
    pub kind: AxisKind,
    /// Screw lead of a ball screw, m (default: from the motor/load travel ratio).
    pub lead_m: Option<f64>,
    /// Gear ratio of a rotary axis, motor rad per load rad (default: from the motor/load travel
    /// ratio, 1 with one encoder).
    pub gear_ratio: Option<f64>,
}

/// The gear ratio of a rotary axis from its motor/load travel ratio: 1 when the two columns
/// travel alike within 1 % (the load column is already on the motor side, as a recorder that
/// refers the load encoder through the gear writes it), else the ratio to 6 significant digits.
fn gear_of_travel(ratio: f64) -> f64 {
    if (ratio - 1.0).abs() < 0.01 {
        1.0
    } else {
        round_sig(ratio)
    }
}

/// A ball screw's stiffness from the deflection when both positions are measured (the load's
/// torque against motor minus load position), else a mode at 150 Hz.
fn ballscrew_stiffness(d: &AxisData, jm: f64, jl: f64, dl: f64, bl: &[(usize, usize)]) -> f64 {
    let mut kl = jl * (2.0 * std::f64::consts::PI * 150.0f64).powi(2) * (jm / (jm + jl));
    if d.has_motor() {
        let lt: Vec<f64> =
            d.al.iter()
                .zip(&d.vl)
                .map(|(a, v)| jl * a + dl * v)
                .collect();
        let defl: Vec<f64> = d.qm.iter().zip(&d.ql).map(|(m, l)| m - l).collect();
        let one = vec![1.0; d.len()];
        let th = cross_validate(&normals(&[&defl, &one], &lt, bl)).theta;
        if th[0] > 0.0 && th[0].is_finite() {
            kl = th[0];
        }
    }
    kl
}

/// A geared rotary axis's stiffness, motor side: with both encoders, the deflection (motor minus
/// load position) against the motor's torque, with the
/// encoders' zero offset and a lost motion that follows the direction of travel as columns of
/// their own; with one encoder, a stiff coupling (mode at twice the sampling rate: the model is
/// rigid in the band the trace sees).
fn rotary_stiffness(
    d: &AxisData,
    y: &[f64],
    jm: f64,
    bl: &[(usize, usize)],
    notes: &mut Vec<String>,
) -> f64 {
    let rigid = {
        let w = 2.0 * std::f64::consts::PI * 2.0 / d.dt;
        jm * w * w
    };
    if !d.has_motor() {
        notes.push(
            "one encoder: the coupling is stiff (its mode at twice the sampling rate), a rigid \
             rotary model"
                .into(),
        );
        return rigid;
    }
    // the torque the gear transmits, taken as the motor's torque: with two encoders that
    // travel together the least squares cannot split the inertia between motor and load, and
    // the rotor's share is small beside a geared load's
    let trans = y;
    let defl: Vec<f64> = d.qm.iter().zip(&d.ql).map(|(m, l)| m - l).collect();
    let one = vec![1.0; d.len()];
    let eps = 0.02 * d.vm.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let dir: Vec<f64> =
        d.vm.iter()
            .map(|v| if v.abs() > eps { v.signum() } else { 0.0 })
            .collect();
    let th = cross_validate(&normals(&[trans, &one, &dir], &defl, bl)).theta;
    // (the reading has already removed an offset it found: it is added back to say the whole)
    notes.push(format!(
        "encoders' zero offset {:.4e} rad (motor side), lost motion {:.4e} rad between the \
         directions of travel: both left out of the stiffness",
        th[1] + d.encoder_offset.unwrap_or(0.0),
        2.0 * th[2]
    ));
    if th[0] > 0.0 && th[0].is_finite() {
        1.0 / th[0]
    } else {
        notes.push("the deflection does not follow the transmitted torque: stiff coupling".into());
        rigid
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_expressions_parse_scale_sign_and_offset() {
        let m = parse_map("x.cmd=pos_mm*0.001, x.load=-enc/1000, x.torque=i_a*2.5+0.1").unwrap();
        assert_eq!(m[0].source, "pos_mm");
        assert!((m[0].scale - 0.001).abs() < 1e-15);
        assert!((m[1].scale + 0.001).abs() < 1e-15);
        assert!((m[2].offset - 0.1).abs() < 1e-15 && (m[2].scale - 2.5).abs() < 1e-15);
    }

    #[test]
    fn a_map_entry_without_equals_sign_is_refused_naming_it() {
        let e = parse_map("x.cmd").unwrap_err();
        assert!(e.to_string().contains("--map x.cmd"), "{e}");
    }
}
