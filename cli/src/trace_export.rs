//! `feedloop trace export`: a trace in the formats other tools read.
//!
//! - MCAP (Foxglove, PlotJuggler): one channel per axis (topic `/A`, plus `/trace` for the
//!   columns of no axis), each with a JSON schema of its signals; one JSON message per sample
//!   holding `t` and the axis' signals (the `A.` prefix dropped), log time = sample time in ns.
//! - Parquet (pandas, polars, DuckDB, PlotJuggler): the trace's columns under their own names,
//!   as required float64 columns; the trace's metadata and period as key-value metadata.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use feedloop_trace::Trace;

/// The formats `trace export` writes.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// MCAP with JSON messages, one channel per axis.
    Mcap,
    /// Apache Parquet, one float64 column per trace column.
    Parquet,
}

impl ExportFormat {
    /// The name on the command line.
    pub fn id(self) -> &'static str {
        match self {
            ExportFormat::Mcap => "mcap",
            ExportFormat::Parquet => "parquet",
        }
    }
}

/// Writes `trace` to `out` in `format`.
pub fn export(trace: &Trace, format: ExportFormat, out: &Path) -> Result<()> {
    match format {
        ExportFormat::Mcap => write_mcap(trace, out),
        ExportFormat::Parquet => write_parquet(trace, out),
    }
}

/// The channel of column `name`: its axis (the part before the first `.`), or `trace` for a
/// column of no axis; `None` for the time column.
fn channel_of(name: &str) -> Option<(&str, &str)> {
    if name == "t" {
        return None;
    }
    Some(match name.split_once('.') {
        Some((axis, signal)) => (axis, signal),
        None => ("trace", name),
    })
}

/// A channel of the MCAP file: its name and its columns (index in the trace, field name).
struct Group<'a> {
    name: &'a str,
    fields: Vec<(usize, &'a str)>,
}

fn groups(trace: &Trace) -> Vec<Group<'_>> {
    let mut out: Vec<Group<'_>> = Vec::new();
    for (i, c) in trace.columns.iter().enumerate() {
        let Some((name, field)) = channel_of(c) else {
            continue;
        };
        match out.iter_mut().find(|g| g.name == name) {
            Some(g) => g.fields.push((i, field)),
            None => out.push(Group {
                name,
                fields: vec![(i, field)],
            }),
        }
    }
    out
}

/// The JSON schema of a channel's messages.
fn schema_of(g: &Group<'_>) -> String {
    let mut props = serde_json::Map::new();
    let mut required = vec![serde_json::json!("t")];
    props.insert(
        "t".into(),
        serde_json::json!({"type": "number", "description": "sample time, s"}),
    );
    for (_, f) in &g.fields {
        props.insert((*f).into(), serde_json::json!({"type": "number"}));
        required.push(serde_json::json!(f));
    }
    serde_json::json!({
        "title": format!("feedloop.{}", g.name),
        "type": "object",
        "properties": props,
        "required": required,
    })
    .to_string()
}

/// Appends `v` as a JSON number (shortest text that reads back to the same f64).
fn push_number(s: &mut String, buf: &mut ryu::Buffer, v: f64) {
    s.push_str(buf.format_finite(v));
}

fn write_mcap(trace: &Trace, out: &Path) -> Result<()> {
    let t = trace.t();
    if t[0] < 0.0 {
        bail!(
            "{}: the time column starts at {} s: MCAP log times count nanoseconds from 0, so a trace for MCAP must start at t >= 0",
            trace.path.display(),
            t[0]
        );
    }
    let file = File::create(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let io = |e: mcap::McapError| anyhow::anyhow!("{}: cannot write MCAP: {e}", out.display());
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .profile("")
        .create(BufWriter::new(file))
        .map_err(io)?;
    let mut meta: BTreeMap<String, String> = trace.meta.iter().cloned().collect();
    meta.insert("period_s".into(), trace.period_s().to_string());
    meta.insert("source_trace".into(), trace.path.display().to_string());
    w.write_metadata(&mcap::records::Metadata {
        name: "feedloop-trace".into(),
        metadata: meta,
    })
    .map_err(io)?;
    let gs = groups(trace);
    let mut ids = Vec::new();
    for g in &gs {
        let schema = schema_of(g);
        let sid = w
            .add_schema(
                &format!("feedloop.{}", g.name),
                "jsonschema",
                schema.as_bytes(),
            )
            .map_err(io)?;
        let cid = w
            .add_channel(sid, &format!("/{}", g.name), "json", &BTreeMap::new())
            .map_err(io)?;
        ids.push(cid);
    }
    let cols: Vec<&[f64]> = (0..trace.columns.len())
        .map(|i| trace.column_at(i).unwrap_or(&[]))
        .collect();
    let mut buf = ryu::Buffer::new();
    let mut msg = String::new();
    for (k, &tk) in t.iter().enumerate() {
        let log_time = (tk * 1e9).round() as u64;
        for (g, &cid) in gs.iter().zip(&ids) {
            msg.clear();
            msg.push_str("{\"t\":");
            push_number(&mut msg, &mut buf, tk);
            for &(i, f) in &g.fields {
                msg.push_str(",\"");
                msg.push_str(f);
                msg.push_str("\":");
                push_number(&mut msg, &mut buf, cols[i][k]);
            }
            msg.push('}');
            w.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: cid,
                    sequence: k as u32,
                    log_time,
                    publish_time: log_time,
                },
                msg.as_bytes(),
            )
            .map_err(io)?;
        }
    }
    w.finish().map_err(io)?;
    Ok(())
}

/// Rows per row group of the Parquet file.
const ROW_GROUP: usize = 1 << 20;

fn write_parquet(trace: &Trace, out: &Path) -> Result<()> {
    use parquet::basic::{Compression, Repetition, Type as Physical};
    use parquet::data_type::DoubleType;
    use parquet::file::metadata::KeyValue;
    use parquet::file::properties::WriterProperties;
    use parquet::file::writer::SerializedFileWriter;
    use parquet::schema::types::Type;

    let pq = |e: parquet::errors::ParquetError| {
        anyhow::anyhow!("{}: cannot write Parquet: {e}", out.display())
    };
    let fields = trace
        .columns
        .iter()
        .map(|c| {
            Type::primitive_type_builder(c, Physical::DOUBLE)
                .with_repetition(Repetition::REQUIRED)
                .build()
                .map(Arc::new)
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(pq)?;
    let schema = Arc::new(
        Type::group_type_builder("feedloop_trace")
            .with_fields(fields)
            .build()
            .map_err(pq)?,
    );
    let mut kv: Vec<KeyValue> = trace
        .meta
        .iter()
        .map(|(k, v)| KeyValue::new(k.clone(), v.clone()))
        .collect();
    if !trace.meta.iter().any(|(k, _)| k == "period_s") {
        kv.push(KeyValue::new(
            "period_s".to_string(),
            trace.period_s().to_string(),
        ));
    }
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_key_value_metadata(Some(kv))
        .set_created_by("feedloop trace export".to_string())
        .build();
    let file = File::create(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let mut w =
        SerializedFileWriter::new(BufWriter::new(file), schema, Arc::new(props)).map_err(pq)?;
    let n = trace.len();
    let mut start = 0;
    while start < n {
        let end = (start + ROW_GROUP).min(n);
        let mut rg = w.next_row_group().map_err(pq)?;
        let mut i = 0;
        while let Some(mut col) = rg.next_column().map_err(pq)? {
            let values = &trace.column_at(i).unwrap_or(&[])[start..end];
            col.typed::<DoubleType>()
                .write_batch(values, None, None)
                .map_err(pq)?;
            col.close().map_err(pq)?;
            i += 1;
        }
        rg.close().map_err(pq)?;
        start = end;
    }
    w.close().map_err(pq)?;
    Ok(())
}
