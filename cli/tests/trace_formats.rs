//! `trace export` writes MCAP and Parquet files that hold the trace; `trace import` reads
//! LinuxCNC's halsampler and halscope captures, and refuses a bad one naming the file and line.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use feedloop_test_support::Scratch;
use feedloop_trace::Trace;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn run(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The fields of a flat JSON object of numbers, each number read by Rust's exact parser (so that a
/// value compares to the bit).
fn fields(json: &str) -> std::collections::BTreeMap<String, f64> {
    let inner = json
        .trim()
        .strip_prefix('{')
        .unwrap()
        .strip_suffix('}')
        .unwrap();
    inner
        .split(',')
        .map(|kv| {
            let (k, v) = kv.split_once(':').unwrap();
            (k.trim_matches('"').to_string(), v.parse::<f64>().unwrap())
        })
        .collect()
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A two-axis trace with a column of no axis, 1 kHz, 500 samples.
fn sample_trace(dir: &Path) -> PathBuf {
    let mut s = String::from(
        "# feedloop-trace v1\n# period_s=0.001\nt,x.cmd,x.load,x.torque,y.cmd,y.load,contour_err\n",
    );
    for k in 0..500 {
        let t = k as f64 * 1e-3;
        let (a, b) = ((3.0 * t).sin() * 0.01, (3.0 * t).cos() * 0.01);
        s.push_str(&format!(
            "{t},{a},{},{},{b},{},{}\n",
            a * 0.999,
            0.1 + t,
            b * 0.998,
            1e-6 * t
        ));
    }
    let path = dir.join("in.csv");
    std::fs::write(&path, s).unwrap();
    path
}

#[test]
fn mcap_export_has_a_channel_per_axis_and_a_message_per_sample() {
    let dir = Scratch::new("tfmt", "mcap");
    let input = sample_trace(&dir);
    let out = dir.join("t.mcap");
    let o = run(&[
        "trace",
        "export",
        p(&input),
        "--format",
        "mcap",
        "--out",
        p(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let tr = Trace::read(&input).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    type Msgs = Vec<(u64, std::collections::BTreeMap<String, f64>)>;
    let mut per_topic: std::collections::BTreeMap<String, Msgs> = Default::default();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        assert_eq!(m.channel.message_encoding, "json");
        let schema = m.channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, "jsonschema");
        // valid JSON, and its fields
        serde_json::from_slice::<serde_json::Value>(&m.data).unwrap();
        let v = fields(std::str::from_utf8(&m.data).unwrap());
        per_topic
            .entry(m.channel.topic.clone())
            .or_default()
            .push((m.log_time, v));
    }
    assert_eq!(
        per_topic.keys().cloned().collect::<Vec<_>>(),
        ["/trace", "/x", "/y"]
    );
    for (topic, msgs) in &per_topic {
        assert_eq!(msgs.len(), tr.len(), "{topic}");
        for (k, (log_time, v)) in msgs.iter().enumerate() {
            assert_eq!(*log_time, (tr.t()[k] * 1e9).round() as u64);
            assert_eq!(v["t"], tr.t()[k]);
        }
    }
    let x = &per_topic["/x"];
    for (k, (_, v)) in x.iter().enumerate() {
        for s in ["cmd", "load", "torque"] {
            assert_eq!(v[s], tr.column(&format!("x.{s}")).unwrap()[k]);
        }
    }
    assert_eq!(
        per_topic["/trace"][7].1["contour_err"],
        tr.column("contour_err").unwrap()[7]
    );
}

#[test]
fn parquet_export_has_the_trace_columns_as_doubles() {
    use parquet::file::reader::{FileReader, SerializedFileReader};
    let dir = Scratch::new("tfmt", "parquet");
    let input = sample_trace(&dir);
    let out = dir.join("t.parquet");
    let o = run(&[
        "trace",
        "export",
        p(&input),
        "--format",
        "parquet",
        "--out",
        p(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let tr = Trace::read(&input).unwrap();
    let r = SerializedFileReader::new(std::fs::File::open(&out).unwrap()).unwrap();
    let meta = r.metadata().file_metadata();
    assert_eq!(meta.num_rows() as usize, tr.len());
    let names: Vec<String> = meta
        .schema_descr()
        .columns()
        .iter()
        .map(|c| c.name().to_string())
        .collect();
    assert_eq!(names, tr.columns);
    assert!(meta
        .schema_descr()
        .columns()
        .iter()
        .all(|c| c.physical_type() == parquet::basic::Type::DOUBLE));
    let kv = meta.key_value_metadata().unwrap();
    assert!(kv
        .iter()
        .any(|e| e.key == "period_s" && e.value.as_deref() == Some("0.001")));
    // every value, row by row
    for (k, row) in r.get_row_iter(None).unwrap().enumerate() {
        let row = row.unwrap();
        for (i, (_, field)) in row.get_column_iter().enumerate() {
            match field {
                parquet::record::Field::Double(v) => {
                    assert_eq!(*v, tr.column_at(i).unwrap()[k])
                }
                other => panic!("not a double: {other:?}"),
            }
        }
    }
}

#[test]
fn an_unknown_export_format_lists_the_formats() {
    let dir = Scratch::new("tfmt", "badformat");
    let input = sample_trace(&dir);
    let o = run(&[
        "trace",
        "export",
        p(&input),
        "--format",
        "hdf5",
        "--out",
        "x",
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("mcap") && e.contains("parquet"), "{e}");
}

#[test]
fn halsampler_output_is_imported_by_field_position() {
    let dir = Scratch::new("tfmt", "halsampler");
    let src = dir.join("cap.txt");
    std::fs::write(
        &src,
        "0.000000 0.000000 0.1\n1.000000 0.500000 0.2\n2.000000 1.500000 0.3\n",
    )
    .unwrap();
    let out = dir.join("cap.csv");
    let o = run(&[
        "trace",
        "import",
        "--format",
        "halsampler",
        "--from",
        p(&src),
        "--period-s",
        "0.001",
        "--map",
        "x.cmd=1*0.001,x.load=2*0.001,x.torque=3",
        "--out",
        p(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let tr = Trace::read(&out).unwrap();
    assert_eq!(tr.columns, ["t", "x.cmd", "x.load", "x.torque"]);
    assert_eq!(tr.t(), [0.0, 0.001, 0.002]);
    assert_eq!(tr.column("x.load").unwrap(), [0.0, 0.0005, 0.0015]);
    assert_eq!(tr.column("x.torque").unwrap(), [0.1, 0.2, 0.3]);

    // no time: refused, saying how to give it
    let o = run(&[
        "trace",
        "import",
        "--format",
        "halsampler",
        "--from",
        p(&src),
        "--map",
        "x.cmd=1,x.load=2",
        "--out",
        p(&out),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--period-s"), "{}", stderr(&o));

    // a short line: the file and its line
    std::fs::write(&src, "1 2 3\n4 5 6\n7 8\n").unwrap();
    let o = run(&[
        "trace",
        "import",
        "--format",
        "halsampler",
        "--from",
        p(&src),
        "--period-s",
        "0.001",
        "--map",
        "x.cmd=1,x.load=2",
        "--out",
        p(&out),
    ]);
    let e = stderr(&o);
    assert!(
        e.contains(&format!("{}: line 3: 2 values", src.display())),
        "{e}"
    );
}

#[test]
fn halscope_log_is_imported_by_hal_name_with_its_period() {
    let dir = Scratch::new("tfmt", "halscope");
    let src = dir.join("scope.log");
    std::fs::write(
        &src,
        "# Sampling period is 250000 ns\njoint.0.pos-cmd;joint.0.pos-fb\n# Position: 0.5;0.5\n# Scale: 0;0\n0.00000000000000;0.00000000000000\n1.00000000000000;0.50000000000000\n2.00000000000000;1.50000000000000\n",
    )
    .unwrap();
    let out = dir.join("scope.csv");
    let args = |map: &'static str| {
        vec![
            "trace".to_string(),
            "import".into(),
            "--format".into(),
            "halscope".into(),
            "--from".into(),
            p(&src).into(),
            "--map".into(),
            map.into(),
            "--out".into(),
            p(&out).into(),
        ]
    };
    let o = Command::new(bin())
        .args(args(
            "x.cmd=joint.0.pos-cmd*0.001,x.load=joint.0.pos-fb*0.001",
        ))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let tr = Trace::read(&out).unwrap();
    assert_eq!(tr.t(), [0.0, 0.00025, 0.0005]);
    assert_eq!(tr.column("x.cmd").unwrap(), [0.0, 0.001, 0.002]);

    // a channel the log does not have: the channels it has
    let o = Command::new(bin())
        .args(args("x.cmd=joint.0.pos-cmd,x.load=joint.1.pos-fb"))
        .output()
        .unwrap();
    let e = stderr(&o);
    assert!(
        e.contains("no field `joint.1.pos-fb`") && e.contains("joint.0.pos-cmd, joint.0.pos-fb"),
        "{e}"
    );

    // a cell that is not a number: file, line, channel
    let text = std::fs::read_to_string(&src)
        .unwrap()
        .replace("1.50000000000000", "1.5e");
    std::fs::write(&src, text).unwrap();
    let o = Command::new(bin())
        .args(args("x.cmd=joint.0.pos-cmd,x.load=joint.0.pos-fb"))
        .output()
        .unwrap();
    let e = stderr(&o);
    assert!(
        e.contains(&format!(
            "{}: line 7: field `joint.0.pos-fb`: \"1.5e\" is not a number",
            src.display()
        )),
        "{e}"
    );

    // not a halscope log: says what it expected
    std::fs::write(&src, "a;b\n1;2\n").unwrap();
    let o = Command::new(bin())
        .args(args("x.cmd=a,x.load=b"))
        .output()
        .unwrap();
    assert!(
        stderr(&o).contains("line 1: expected the line `# Sampling period is N ns`"),
        "{}",
        stderr(&o)
    );
}
