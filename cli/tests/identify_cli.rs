//! `feedloop excite`, `identify inertia|stiffness` and `tune` end to end on the shipped
//! examples, through the real binary: JSON on stdout (parsed whole: nothing else may be
//! there), plots written, figures against the example model's truth (examples/models/xy-x.toml:
//! JM 2e-3, JL 3e-3 kg m^2, KL 3000 N m/rad, 10 mm lead), and the issue's bad inputs refused
//! with a clear message and a non-zero exit, never a panic.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

use feedloop_test_support::Scratch;

/// A fresh scratch folder for test `name` (removed when the test passes).
fn scratch(name: &str) -> Scratch {
    Scratch::new("idcli", name)
}

/// A command line: the words of `line`, then `option path` for each of `paths`.
fn cli(line: &str, paths: &[(&str, &Path)]) -> Vec<String> {
    let mut a: Vec<String> = line.split_whitespace().map(String::from).collect();
    for (option, path) in paths {
        a.push(option.to_string());
        a.push(path.display().to_string());
    }
    a
}

fn run<S: AsRef<str>>(args: &[S]) -> Output {
    Command::new(bin())
        .args(args.iter().map(AsRef::as_ref))
        .output()
        .unwrap()
}

fn describe<S: AsRef<str>>(args: &[S], o: &Output) -> String {
    format!(
        "feedloop {}\nexit {:?}\nstdout: {}\nstderr: {}",
        args.iter().map(AsRef::as_ref).collect::<Vec<_>>().join(" "),
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Runs with `--json`; the command must succeed and its whole stdout must be one JSON value.
fn json<S: AsRef<str>>(args: &[S]) -> serde_json::Value {
    let mut a: Vec<&str> = args.iter().map(AsRef::as_ref).collect();
    a.push("--json");
    let o = run(&a);
    assert!(o.status.success(), "{}", describe(&a, &o));
    let out = String::from_utf8(o.stdout.clone()).unwrap();
    serde_json::from_str(out.trim_end())
        .unwrap_or_else(|e| panic!("stdout is not pure JSON ({e}): {}", describe(&a, &o)))
}

/// The command must fail with a message (no panic, nothing on stdout); returns stderr.
fn refused<S: AsRef<str>>(args: &[S]) -> String {
    let o = run(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "accepted: {}", describe(args, &o));
    assert!(
        !err.contains("panicked") && !err.is_empty(),
        "{}",
        describe(args, &o)
    );
    assert!(o.stdout.is_empty(), "{}", describe(args, &o));
    err
}

/// The texts of the elements of class `class` in `svg`: a `<text>`'s own, a group's first.
fn texts_of(svg: &str, class: &str) -> Vec<String> {
    svg.match_indices(&format!(r#"class="{class}""#))
        .map(|(i, _)| {
            let rest = &svg[i..];
            let t = if svg[..i].ends_with("<g ") {
                &rest[rest.find("<text").unwrap()..]
            } else {
                rest
            };
            let t = &t[t.find('>').unwrap() + 1..];
            t[..t.find("</text>").unwrap()].to_string()
        })
        .collect()
}

/// All texts of the legends of `svg`, joined by ` | `.
fn legend_of(svg: &str) -> String {
    svg.split(r#"class="legend""#)
        .skip(1)
        .flat_map(|rest| {
            let group = &rest[..rest.find("</g>").unwrap()];
            group
                .split("<text")
                .skip(1)
                .map(|t| t[t.find('>').unwrap() + 1..t.find("</text>").unwrap()].to_string())
                .collect::<Vec<_>>()
        })
        .collect::<Vec<_>>()
        .join(" | ")
}

/// Reads a plot and checks what every plot has: a title, axis titles that carry a unit in
/// parentheses, more than two ticks on each axis of each panel, a legend.
fn check_plot(path: &Path, panels: usize) -> String {
    let s = std::fs::read_to_string(path).unwrap();
    assert!(s.starts_with("<svg") && s.trim_end().ends_with("</svg>"));
    assert!(!texts_of(&s, "title")[0].is_empty(), "no title");
    for axis in ["x-label", "y-label"] {
        let labels = texts_of(&s, axis);
        assert_eq!(labels.len(), panels, "{axis}: {labels:?}");
        for l in labels {
            assert!(
                l.contains(" (") && l.ends_with(')'),
                "{axis} `{l}` has no unit"
            );
        }
    }
    for tick in ["x-tick", "y-tick"] {
        assert!(
            texts_of(&s, tick).len() > 2 * panels,
            "{tick}: {:?}",
            texts_of(&s, tick)
        );
    }
    assert!(s.contains(r#"class="legend""#), "no legend");
    s
}

fn num(v: &serde_json::Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("`{key}` missing or not a number in {v}"))
}

fn sim(job: &Path, out: &Path) -> PathBuf {
    let args = [
        "sim",
        job.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    let o = run(&args);
    assert!(o.status.success(), "{}", describe(&args, &o));
    out.join("trace.csv")
}

/// The "machine": the inertia example's move on the X axis with load inertia `jl` while the
/// feedforward keeps the nominal 3e-3 (`params` of the feedforward as given).
fn machine_trace(d: &Path, tag: &str, jl: f64, ff_params: &str) -> PathBuf {
    let model = std::fs::read_to_string(repo("examples/models/xy-x.toml")).unwrap();
    assert!(model.contains("jl_kgm2 = 3.0e-3"));
    let model = model.replace("jl_kgm2 = 3.0e-3", &format!("jl_kgm2 = {jl:e}"));
    let m = d.join(format!("machine-{tag}.toml"));
    std::fs::write(&m, model).unwrap();
    let j = inertia_job(
        d,
        &format!("machine-{tag}-job.toml"),
        &m,
        Some(&format!("{ff_params}, jl_kgm2 = 3.0e-3")),
        None,
    );
    sim(&j, &d.join(format!("run-{tag}")))
}

/// `examples/jobs/identify-inertia-move.toml` written to `d/name` with the axis model `model`,
/// the feedforward's params `ff_params` when given (else the shipped split structure) and the
/// move's `duration_s` when given.
fn inertia_job(
    d: &Path,
    name: &str,
    model: &Path,
    ff_params: Option<&str>,
    duration_s: Option<&str>,
) -> PathBuf {
    let job = std::fs::read_to_string(repo("examples/jobs/identify-inertia-move.toml")).unwrap();
    assert!(job.contains("model = \"../models/xy-x.toml\""));
    assert!(job.contains("params = { structure = \"split\" }"));
    assert!(job.contains("duration_s = 0.3"));
    let mut job = job.replace(
        "model = \"../models/xy-x.toml\"",
        &format!("model = {:?}", model.display().to_string()),
    );
    if let Some(ff) = ff_params {
        job = job.replace(
            "params = { structure = \"split\" }",
            &format!("params = {{ {ff} }}"),
        );
    }
    if let Some(t) = duration_s {
        job = job.replace("duration_s = 0.3", &format!("duration_s = {t}"));
    }
    let p = d.join(name);
    std::fs::write(&p, job).unwrap();
    p
}

#[test]
fn excite_writes_a_playable_command_for_each_kind() {
    let d = scratch("excite");
    for (kind, set) in [
        ("random-segments", "duration_s=2.0"),
        ("prbs", "periods=1"),
        ("multisine", "periods=1"),
    ] {
        let out = d.join(format!("{kind}.csv"));
        let v = json(&cli(
            &format!("excite --kind {kind} --set {set}"),
            &[("--out", &out)],
        ));
        println!("{kind}: {v}");
        assert_eq!(v["kind"], kind);
        assert_eq!(v["out"], out.display().to_string());
        let (dur, rows) = (num(&v, "duration_s"), num(&v, "rows"));
        assert!(dur > 0.5 && dur < 20.0, "{v}");
        assert!((rows - (dur / 1e-4 + 1.0)).abs() <= 2.0, "{v}");
        let text = std::fs::read_to_string(&out).unwrap();
        let header = text
            .lines()
            .find(|l| !l.starts_with('#'))
            .expect("a header line");
        assert_eq!(header, "t,x.cmd,x.cmd_vel,x.cmd_acc");
        let data = text.lines().filter(|l| !l.starts_with('#')).count() - 1;
        assert!((data as f64 - rows).abs() <= 2.0, "{data} rows vs {rows}");
    }
    // A quantity in another unit replaces the default one: a position multisine, and a
    // rotary axis's velocity levels.
    for (kind, axis, set) in [
        ("multisine", "x", "amplitude_m=1e-4"),
        ("prbs", "x", "amplitude_m=5e-5"),
        ("random-segments", "c", "velocity_rad_per_s=0.5"),
    ] {
        let out = d.join(format!("{kind}-{axis}-other-unit.csv"));
        let extra = if kind == "random-segments" {
            "max_travel_rad=1.0"
        } else {
            "periods=1"
        };
        let v = json(&cli(
            &format!("excite --kind {kind} --axis {axis} --set {set} --set {extra}"),
            &[("--out", &out)],
        ));
        let text = std::fs::read_to_string(&out).unwrap();
        let peak = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .skip(1)
            .map(|l| {
                let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
                if set.starts_with("amplitude_m=") {
                    c[1].abs()
                } else {
                    c[2].abs()
                }
            })
            .fold(0.0f64, f64::max);
        let want: f64 = set.split('=').nth(1).unwrap().parse().unwrap();
        println!("{kind} {set}: {v}, peak {peak}");
        assert!(
            peak <= want * (1.0 + 1e-9) && peak > 0.5 * want,
            "{peak} vs {want}"
        );
    }
    let e = refused(&cli("excite --kind sweep", &[("--out", &d.join("x.csv"))]));
    assert!(e.contains("sweep") && e.contains("random-segments"), "{e}");
}

#[test]
fn identify_stiffness_on_the_shipped_excitation_finds_kl_and_jl_and_draws_the_bode_plot() {
    let d = scratch("stiffness");
    let trace = sim(
        &repo("examples/jobs/identify-stiffness.toml"),
        &d.join("run"),
    );
    let svg = d.join("bode.svg");
    let v = json(&cli(
        "identify stiffness --jm-kgm2 2e-3",
        &[("--trace", &trace), ("--svg", &svg)],
    ));
    println!("{v}");
    // Truth: wa = sqrt(KL / JL) = 159.15 Hz, wr = sqrt(KL (JM + JL) / (JM JL)) = 251.64 Hz.
    let wa = (3000.0f64 / 3e-3).sqrt() / (2.0 * std::f64::consts::PI);
    let wr = (3000.0f64 * 5e-3 / 6e-6).sqrt() / (2.0 * std::f64::consts::PI);
    assert!(
        (num(&v, "kl_nm_per_rad") / 3000.0 - 1.0).abs() < 0.01,
        "{v}"
    );
    assert!((num(&v, "jl_kgm2") / 3e-3 - 1.0).abs() < 0.01, "{v}");
    assert!((num(&v, "antiresonance_hz") / wa - 1.0).abs() < 0.01, "{v}");
    assert!((num(&v, "resonance_hz") / wr - 1.0).abs() < 0.01, "{v}");
    let c = num(&v, "coherence_min");
    assert!(c > 0.8 && c <= 1.0, "{v}");
    // magnitude, phase and coherence, the resonance pair marked in each
    let plot = check_plot(&svg, 3);
    assert!(texts_of(&plot, "y-label").contains(&"phase (deg)".to_string()));
    assert_eq!(plot.matches(r#"class="ref-line""#).count(), 2 * 3);
    let legend = legend_of(&plot);
    assert!(
        legend.contains("anti-resonance") && legend.contains(" Hz"),
        "{legend}"
    );

    // A band without a resonance (below the anti-resonance) names the band.
    let e = refused(&cli(
        "identify stiffness --jm-kgm2 2e-3 --f-max-hz 100",
        &[("--trace", &trace)],
    ));
    assert!(e.contains("between 5.0 and 100.0 Hz"), "{e}");
    // The closed-loop command -> table FRF is refused with the reason.
    let e = refused(&cli(
        "identify stiffness --jm-kgm2 2e-3 --frf command-table",
        &[("--trace", &trace)],
    ));
    assert!(e.contains("negative"), "{e}");
}

#[test]
fn identify_inertia_sim_match_and_linear_find_a_30_percent_workpiece_and_apply_writes_the_model() {
    let d = scratch("inertia");
    let truth = 3.9e-3;
    let measured = machine_trace(&d, "w30", truth, "structure = \"split\"");
    let job = repo("examples/jobs/identify-inertia-move.toml");
    let applied = d.join("applied.toml");
    let svg = d.join("deviation.svg");
    let v = json(&cli(
        "identify inertia --method sim-match --at 0.01",
        &[
            ("--trace", &measured),
            ("--model", &job),
            ("--apply", &applied),
            ("--svg", &svg),
        ],
    ));
    println!("sim-match: {v}");
    let plot = check_plot(&svg, 1);
    assert!(plot.contains("--at 0.01"));
    assert_eq!(
        plot.matches(r#"class="series""#).count(),
        2,
        "measured and model curves"
    );
    assert_eq!(plot.matches(r#"class="ref-line""#).count(), 1, "the probe");
    assert!(texts_of(&plot, "y-label")[0].starts_with("deviation ("));
    assert_eq!(v["method"], "sim-match");
    assert_eq!(v["deviation"], "command-load");
    assert!((num(&v, "jl_kgm2") / truth - 1.0).abs() < 0.02, "{v}");
    let it = num(&v, "iterations");
    assert!((2.0..=20.0).contains(&it), "{v}");
    let (dm, dd) = (
        num(&v, "deviation_measured_m"),
        num(&v, "deviation_model_m"),
    );
    // +30 % against a feedforward at 3e-3 leaves well under a micrometre at 10 mm, not zero.
    assert!(dm.abs() > 1e-8 && dm.abs() < 1e-5, "{v}");
    assert!((dm - dd).abs() <= 1e-3 * dm.abs(), "{v}");
    assert!(v["literal_bias_percent"].is_null(), "{v}");
    // The applied model carries the estimate; the job runs with it.
    let text = std::fs::read_to_string(&applied).unwrap();
    let t: toml::Table = text.parse().unwrap();
    let jl = t["jl_kgm2"].as_float().unwrap();
    assert!((jl - num(&v, "jl_kgm2")).abs() < 1e-12, "{text}");
    assert!(text.starts_with('#') && text.contains("a3..a5"), "{text}");

    // The motor-load deviation (screw twist) gives the same inertia.
    let v2 = json(&cli(
        "identify inertia --at 0.01 --deviation motor-load",
        &[("--trace", &measured), ("--model", &job)],
    ));
    println!("sim-match, motor-load: {v2}");
    assert!((num(&v2, "jl_kgm2") / truth - 1.0).abs() < 0.02, "{v2}");

    // Method 2 between the no-load run (3e-3) and a known +20 % run (3.6e-3).
    let svg = d.join("linear.svg");
    let no_load = machine_trace(&d, "w0", 3.0e-3, "structure = \"split\"");
    let loaded = machine_trace(&d, "w20", 3.6e-3, "structure = \"split\"");
    let v3 = json(&cli(
        "identify inertia --method linear --loaded-jl-kgm2 3.6e-3 --no-load-jl-kgm2 3.0e-3 --at 0.01",
        &[
            ("--no-load", &no_load),
            ("--loaded", &loaded),
            ("--model", &job),
            ("--trace", &measured),
            ("--svg", &svg),
        ],
    ));
    println!("linear: {v3}");
    let plot = check_plot(&svg, 1);
    assert_eq!(plot.matches(r#"class="series""#).count(), 3, "three traces");
    assert_eq!(v3["method"], "linear");
    assert!((num(&v3, "jl_kgm2") / truth - 1.0).abs() < 0.02, "{v3}");

    // Bad input: a position outside the move names the travel.
    let e = refused(&cli(
        "identify inertia --at 0.2",
        &[("--trace", &measured), ("--model", &job)],
    ));
    assert!(e.contains("outside the move"), "{e}");
}

#[test]
fn the_brief_literal_structure_reports_its_bias_through_the_command_line() {
    let d = scratch("literal");
    let ff = "structure = \"literal\", lag_discretisation = \"backward_euler\"";
    let measured = machine_trace(&d, "lit", 3.0e-3, ff);
    // The model job: the shipped example with the same literal feedforward.
    let job = std::fs::read_to_string(repo("examples/jobs/identify-inertia-move.toml"))
        .unwrap()
        .replace(
            "model = \"../models/xy-x.toml\"",
            &format!(
                "model = {:?}",
                repo("examples/models/xy-x.toml").display().to_string()
            ),
        )
        .replace(
            "params = { structure = \"split\" }",
            &format!("params = {{ {ff} }}"),
        );
    let j = d.join("model-job.toml");
    std::fs::write(&j, job).unwrap();
    let v = json(&cli(
        "identify inertia --at 0.03",
        &[("--trace", &measured), ("--model", &j)],
    ));
    println!("{v}");
    assert!((num(&v, "jl_kgm2") / 3e-3 - 1.0).abs() < 0.005, "{v}");
    // The brief: ~0.6 um residual against ~8..10 um per +100 % of JL: -7.5 .. -6 %.
    let b = num(&v, "literal_bias_percent");
    assert!((-8.5..=-5.0).contains(&b), "{v}");
    let jc = num(&v, "jl_continuous_model_kgm2");
    assert!(
        (jc / num(&v, "jl_kgm2") - 1.0 - b / 100.0).abs() < 1e-9,
        "{v}"
    );
}

#[test]
fn a_trace_without_the_needed_columns_is_refused_naming_the_column() {
    let d = scratch("columns");
    let cmd = d.join("cmd.csv");
    json(&cli(
        "excite --kind prbs --set periods=1",
        &[("--out", &cmd)],
    ));
    let job = repo("examples/jobs/identify-inertia-move.toml");
    let e = refused(&cli(
        "identify inertia --at 0.01",
        &[("--trace", &cmd), ("--model", &job)],
    ));
    assert!(e.contains("x.load"), "{e}");
    let e = refused(&cli(
        "identify stiffness --jm-kgm2 2e-3",
        &[("--trace", &cmd)],
    ));
    assert!(e.contains("x.torque") || e.contains("x.motor_vel"), "{e}");
    let e = refused(&cli(
        "identify stiffness --jm-kgm2 2e-3",
        &[("--trace", &d.join("missing.csv"))],
    ));
    assert!(e.contains("missing.csv"), "{e}");
}

#[test]
fn tune_on_the_shipped_ramp_beats_the_defaults_writes_the_heat_map_and_the_tuned_job() {
    let d = scratch("tune");
    let svg = d.join("heat.svg");
    let tuned = d.join("tuned.toml");
    let job = repo("examples/jobs/tune-ramp.toml");
    let grid = "kp_per_s=20:120:3,kv_nms_per_rad=2:10:3,tv_s=0.005:0.005:1";
    let t0 = std::time::Instant::now();
    let v = json(&cli(
        &format!("tune --grid {grid}"),
        &[("--job", &job), ("--svg", &svg), ("--apply", &tuned)],
    ));
    println!("{v} ({:.2} s)", t0.elapsed().as_secs_f64());
    for k in ["kp_per_s", "kv_nms_per_rad", "tv_s"] {
        assert!(v["best"][k].is_number(), "{v}");
    }
    assert_eq!(num(&v, "evaluated"), 9.0);
    assert!(num(&v, "rejected") <= 9.0);
    let (eb, ed) = (num(&v, "e_best"), num(&v, "e_default"));
    // Defaults kp 50: the ramp's following error alone is v / kp = 0.1 / 50 = 2 mm.
    assert!((ed / 2.0e-3 - 1.0).abs() < 0.05, "{v}");
    assert!(eb < ed, "{v}");
    assert_eq!(v["axis"], "x");
    let plot = check_plot(&svg, 1);
    assert_eq!(texts_of(&plot, "x-label"), ["kp_per_s (1/s)"]);
    assert_eq!(texts_of(&plot, "y-label"), ["kv_nms_per_rad (N m s/rad)"]);
    assert!(plot.contains(r#"class="colour-scale""#), "no colour scale");
    assert!(plot.contains(r#"class="marker""#), "no best-point marker");
    let best = format!("best: kp_per_s {}", v["best"]["kp_per_s"].as_f64().unwrap());
    let legend = legend_of(&plot);
    assert!(legend.starts_with(&best), "{best}: {legend}");
    // The tuned job, run afresh, has the lower E: its following error is v / kp.
    let t: toml::Table = std::fs::read_to_string(&tuned).unwrap().parse().unwrap();
    let kp = t["chain"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["plugin"].as_str() == Some("position_p"))
        .and_then(|e| e["params"]["kp_per_s"].as_float())
        .unwrap();
    assert_eq!(kp, num(&v["best"], "kp_per_s"));
    let run = sim(&tuned, &d.join("fresh"));
    let text = std::fs::read_to_string(&run).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let (ic, il) = (
        header.iter().position(|h| *h == "x.cmd").unwrap(),
        header.iter().position(|h| *h == "x.load").unwrap(),
    );
    let fe_mid = lines
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (c[0], c[ic] - c[il])
        })
        .filter(|(t, _)| (0.5..0.8).contains(t))
        .map(|(_, e)| e.abs())
        .fold(0.0, f64::max);
    println!("tuned job afresh: following error {fe_mid:.4e} m at constant velocity");
    assert!(fe_mid < 2.0e-3 * 0.9 && (fe_mid - 0.1 / kp).abs() < 0.05 * 0.1 / kp);

    // Bad input: an empty grid.
    for g in ["", "kp_per_s=20:120:0", "kp_per_s=120:20:3"] {
        let e = refused(&["tune", "--job", job.to_str().unwrap(), "--grid", g]);
        assert!(e.contains("grid"), "`{g}`: {e}");
    }
    let e = refused(&cli(
        &format!("tune --grid {grid} --axis z"),
        &[("--job", &job)],
    ));
    assert!(e.contains("`z`"), "{e}");
}

#[test]
fn a_simulated_trace_has_exact_decimal_times() {
    let d = scratch("exact-t");
    // period 1e-4 s: cycle k is at k / 10^4 s exactly, e.g. 0.0003 for k = 3 (the float
    // product 3 x 1e-4 prints 0.00030000000000000003)
    let text = std::fs::read_to_string(sim(&repo("examples/jobs/tune-ramp.toml"), &d)).unwrap();
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .collect();
    assert!(rows.len() > 9000, "{} rows", rows.len());
    for (k, row) in rows.iter().enumerate() {
        let t = row.split(',').next().unwrap();
        let frac = format!("{:04}", k % 10_000);
        let frac = frac.trim_end_matches('0');
        let want = format!(
            "{}.{}",
            k / 10_000,
            if frac.is_empty() { "0" } else { frac }
        );
        assert_eq!(t, want, "row {k}");
    }
}

#[test]
fn tune_prints_its_figures_with_four_significant_digits() {
    let job = repo("examples/jobs/tune-ramp.toml");
    // the grid's top tv_s is 0.002 + (0.02 - 0.002) = 0.020000000000000004 in f64; the lower
    // one is rejected, so that is the best set
    let args = cli(
        "tune --grid kp_per_s=120:120:1,kv_nms_per_rad=9:9:1,tv_s=0.002:0.02:2",
        &[("--job", &job)],
    );
    let o = run(&args);
    assert!(o.status.success(), "{}", describe(&args, &o));
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(
        text.contains("best kp_per_s 120 kv_nms_per_rad 9 tv_s 0.02: E "),
        "{text}"
    );
    let numbers: Vec<&str> = text
        .split(|c: char| c.is_whitespace() || ",;:()".contains(c))
        .filter(|w| w.parse::<f64>().is_ok())
        .collect();
    assert!(numbers.len() >= 7, "{text}");
    for w in numbers {
        let mantissa = w.split('e').next().unwrap();
        let digits = mantissa
            .chars()
            .filter(char::is_ascii_digit)
            .collect::<String>();
        let significant = digits.trim_start_matches('0').len();
        assert!(significant <= 4, "`{w}` in {text}");
    }
}

/// `tune --svg` and `--apply` into folders that do not exist yet: made before the grid is
/// computed (it computed the whole grid, then failed with exit 2 on the missing folder).
#[test]
fn tune_makes_the_folders_of_its_outputs() {
    let dir = scratch("tune_folders");
    let job = repo("examples/jobs/tune-ramp.toml");
    let svg = dir.join("plots/tune/heat.svg");
    let applied = dir.join("jobs/tuned/job.toml");
    let args = cli(
        "tune --grid kp_per_s=120:120:1,kv_nms_per_rad=9:9:1,tv_s=0.002:0.02:2",
        &[("--job", &job), ("--svg", &svg), ("--apply", &applied)],
    );
    let o = run(&args);
    assert!(o.status.success(), "{}", describe(&args, &o));
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
    assert!(std::fs::metadata(&applied).unwrap().len() > 0);
}

#[test]
fn tune_without_axis_tunes_every_axis_of_the_xy_ramp_in_turn() {
    let d = scratch("tune-xy");
    let svg = d.join("heat.svg");
    let job = repo("examples/jobs/tune-ramp-xy.toml");
    let v = json(&cli(
        "tune --grid kp_per_s=20:120:3,kv_nms_per_rad=2:10:2",
        &[("--job", &job), ("--svg", &svg)],
    ));
    println!("{v}");
    assert_eq!(v["axes"], serde_json::json!(["x", "y"]));
    assert_eq!(num(&v, "evaluated"), 12.0);
    for a in ["x", "y"] {
        assert!(v["best"][a]["kp_per_s"].is_number(), "{v}");
        assert!(num(&v["e_best"], a) < num(&v["e_default"], a), "{v}");
        assert!(d.join(format!("heat-{a}.svg")).exists());
    }
    // Y runs at half X's velocity: its E at the same gains is about half.
    let r = num(&v["e_default"], "y") / num(&v["e_default"], "x");
    assert!((r - 0.5).abs() < 0.05, "{v}");
    // --axis picks one.
    let v = json(&cli(
        "tune --grid kp_per_s=20:120:3 --axis y",
        &[("--job", &job)],
    ));
    assert_eq!(v["axis"], "y");
    assert_eq!(num(&v, "evaluated"), 3.0);
}

/// Issue 15 item 8: a stiffness result is judged before it is reported: a trace without
/// excitation (one Welch segment, coherence 1 by construction, two picks a bin apart) and a
/// motor inertia the response contradicts are refused with the reason and what to change;
/// `--force` reports them flagged.
#[test]
fn identify_stiffness_refuses_results_it_cannot_vouch_for() {
    let d = scratch("stiffchecks");
    let circle = sim(&repo("examples/jobs/xy-circle.toml"), &d.join("circle"));
    let e = refused(&cli(
        "identify stiffness --jm-kgm2 2e-3",
        &[("--trace", &circle)],
    ));
    assert!(
        e.contains("1 averaged segment") && e.contains("to do:") && e.contains("--force"),
        "{e}"
    );
    let v = json(&cli(
        "identify stiffness --jm-kgm2 2e-3 --force",
        &[("--trace", &circle)],
    ));
    assert_eq!(
        (&v["credible"], &v["refused"]),
        (&false.into(), &false.into()),
        "{v}"
    );
    assert!(
        !v["checks"]["problems"].as_array().unwrap().is_empty(),
        "{v}"
    );
    assert_eq!(v["checks"]["segments"], 1, "{v}");

    let exc = sim(
        &repo("examples/jobs/identify-stiffness.toml"),
        &d.join("excitation"),
    );
    let e = refused(&cli(
        "identify stiffness --jm-kgm2 1e9",
        &[("--trace", &exc)],
    ));
    assert!(e.contains("the given JM") && e.contains("--jm-kgm2"), "{e}");
    // A band that ends below 1.5 times the resonance: JM is judged on the total inertia below
    // the anti-resonance instead.
    let e = refused(&cli(
        "identify stiffness --jm-kgm2 1e9 --f-max-hz 300",
        &[("--trace", &exc)],
    ));
    assert!(e.contains("total inertia"), "{e}");
    let v = json(&cli(
        "identify stiffness --jm-kgm2 2e-3 --f-max-hz 300",
        &[("--trace", &exc)],
    ));
    assert_eq!(v["credible"], true, "{v}");
    assert!(v["checks"]["jm_from_response_kgm2"].is_null(), "{v}");
    let total = num(&v["checks"], "total_from_response_kgm2");
    assert!((total / 5e-3 - 1.0).abs() < 0.5, "{v}");
    let v = json(&cli(
        "identify stiffness --jm-kgm2 2e-3",
        &[("--trace", &exc)],
    ));
    assert_eq!(v["credible"], true, "{v}");
    let c = &v["checks"];
    assert!(num(c, "segments") >= 4.0, "{v}");
    assert!(num(c, "coherence_resonance") > 0.5, "{v}");
    assert!(num(c, "prominence_resonance_db") >= 6.0, "{v}");
    let jm = num(c, "jm_from_response_kgm2");
    assert!((jm / 2e-3 - 1.0).abs() < 0.5, "{v}");
    // The shipped excitation rides on a traverse: only one-direction windows are read, both
    // directions, and the turns are cut out.
    assert_eq!(num(c, "reversals"), 0.0, "{v}");
    assert!(num(c, "reversals_cut") >= 2.0, "{v}");
    assert!(
        num(c, "windows_positive") >= 1.0 && num(c, "windows_negative") >= 1.0,
        "{v}"
    );
    assert_eq!(
        num(c, "segments_positive") + num(c, "segments_negative"),
        num(c, "segments"),
        "{v}"
    );
}

/// Issue 15 item 9: the linear inertia method checks the recorded runs for torque saturation
/// as sim-match checks its model.
#[test]
fn identify_inertia_linear_refuses_a_run_that_saturates_the_torque() {
    let d = scratch("inertiasat");
    let job = repo("examples/jobs/identify-inertia-move.toml");
    let no_load = machine_trace(&d, "w0", 3.0e-3, "structure = \"split\"");
    // Ten times the load inertia: the move needs more than the 30 N m the drive has.
    let loaded = machine_trace(&d, "w900", 3.0e-2, "structure = \"split\"");
    let measured = machine_trace(&d, "w30", 3.9e-3, "structure = \"split\"");
    let e = refused(&cli(
        "identify inertia --method linear --loaded-jl-kgm2 3.0e-2 --no-load-jl-kgm2 3.0e-3 --at 0.01",
        &[
            ("--no-load", &no_load),
            ("--loaded", &loaded),
            ("--model", &job),
            ("--trace", &measured),
        ],
    ));
    assert!(
        e.contains("the loaded run") && e.contains("limit 30") && e.contains("gentler move"),
        "{e}"
    );
}

/// Issue 15 item 9: the linear method's known inertias are checked, and an estimate far
/// outside its characteristic is refused rather than extrapolated.
#[test]
fn identify_inertia_linear_refuses_absurd_inertias_and_far_extrapolations() {
    let d = scratch("inertiaabsurd");
    let job = repo("examples/jobs/identify-inertia-move.toml");
    let no_load = machine_trace(&d, "w0", 3.0e-3, "structure = \"split\"");
    let loaded = machine_trace(&d, "w20", 3.6e-3, "structure = \"split\"");
    let measured = machine_trace(&d, "w30", 3.9e-3, "structure = \"split\"");
    let runs = [
        ("--no-load", no_load.as_path()),
        ("--loaded", loaded.as_path()),
        ("--model", job.as_path()),
        ("--trace", measured.as_path()),
    ];
    let e = refused(&cli(
        "identify inertia --method linear --loaded-jl-kgm2=-1 --no-load-jl-kgm2 3.0e-3 --at 0.01",
        &runs,
    ));
    assert!(e.contains("--loaded-jl-kgm2 must be"), "{e}");
    // Two runs of the same load give no characteristic; a known load only 1 % above the
    // no-load run puts the +30 % machine about 30 spans beyond the runs.
    let e = refused(&cli(
        "identify inertia --method linear --loaded-jl-kgm2 3.000001e-3 --no-load-jl-kgm2 3.0e-3 --at 0.01",
        &[
            ("--no-load", no_load.as_path()),
            ("--loaded", no_load.as_path()),
            ("--model", job.as_path()),
            ("--trace", measured.as_path()),
        ],
    ));
    assert!(e.contains("same deviation"), "{e}");
    let near = machine_trace(&d, "w1", 3.03e-3, "structure = \"split\"");
    let e = refused(&cli(
        "identify inertia --method linear --loaded-jl-kgm2 3.03e-3 --no-load-jl-kgm2 3.0e-3 --at 0.01",
        &[
            ("--no-load", no_load.as_path()),
            ("--loaded", near.as_path()),
            ("--model", job.as_path()),
            ("--trace", measured.as_path()),
        ],
    ));
    assert!(e.contains("spans") && e.contains("extrapolation"), "{e}");
}

/// The shipped stiffness job with only its model file changed (written here, not shipped):
/// `(tag, model text, JM, KL, JL)`.
fn stiffness_axis(d: &Path, tag: &str, model: &str) -> PathBuf {
    stiffness_axis_at(d, tag, model, None)
}

/// [`stiffness_axis`] with another excitation amplitude (m/s) when given.
fn stiffness_axis_at(d: &Path, tag: &str, model: &str, amplitude: Option<f64>) -> PathBuf {
    let dir = d.join(tag);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("model.toml"), model).unwrap();
    let job = std::fs::read_to_string(repo("examples/jobs/identify-stiffness.toml")).unwrap();
    assert!(job.contains("\"../models/xy-x.toml\""));
    let mut job = job.replace("\"../models/xy-x.toml\"", "\"model.toml\"");
    if let Some(a) = amplitude {
        assert!(job.contains("velocity_m_per_s = { x = 2.0e-4 }"));
        job = job.replace(
            "velocity_m_per_s = { x = 2.0e-4 }",
            &format!("velocity_m_per_s = {{ x = {a:e} }}"),
        );
    }
    std::fs::write(dir.join("job.toml"), job).unwrap();
    sim(&dir.join("job.toml"), &dir.join("out"))
}

#[test]
fn the_shipped_stiffness_job_survives_backlash_friction_and_noise_or_refuses() {
    let d = scratch("stiffeffects");
    let nominal = std::fs::read_to_string(repo("examples/models/xy-x.toml")).unwrap();
    let effects = std::fs::read_to_string(repo("examples/models/xy-x-effects.toml")).unwrap();
    // Another axis: lighter motor, stiffer screw, heavier table, Stribeck friction on the table,
    // Coulomb on the motor, 18 um of play, a 10 nm scale and more velocity noise.
    let other = "kind = \"ballscrew\"\njm_kgm2 = 1.2e-3\ndm_nms_per_rad = 1.0e-3\n\
                 kl_nm_per_rad = 4500.0\ncl_nms_per_rad = 0.03\njl_kgm2 = 3.6e-3\n\
                 dl_nms_per_rad = 2.0e-3\nlead_m = 0.01\ngear_ratio = 1.0\n\
                 [controller]\nkp_per_s = 45.0\nkv_nms_per_rad = 5.0\ntv_s = 0.006\n\
                 torque_limit_nm = 30.0\n\
                 [effects.stribeck_friction]\nside = \"load\"\nfc_n = 35.0\nfs_n = 60.0\n\
                 vs_m_per_s = 0.002\n\
                 [[effects.coulomb_friction]]\nside = \"motor\"\nfc_nm = 0.08\n\
                 [effects.backlash]\ngap_m = 1.8e-5\n\
                 [sensor]\nmotor_counts_per_rev = 1048576\nload_resolution_m = 1.0e-8\n\
                 motor_vel_noise_rad_per_s = 0.015\nseed = 11\n";
    let cases = [
        // backlash alone: nothing holds the nut on one flank but the table's damping
        (
            "backlash",
            format!("{nominal}\n[effects.backlash]\ngap_m = 1.2e-5\n"),
            2e-3,
            3000.0,
            3e-3,
            true,
        ),
        // friction on both sides, 10 um of play, 20-bit encoder, 50 nm scale, velocity noise
        ("effects", effects, 2e-3, 3000.0, 3e-3, true),
        ("other", other.to_string(), 1.2e-3, 4500.0, 3.6e-3, false),
    ];
    for (tag, model, jm, kl, jl, must_answer) in cases {
        let trace = stiffness_axis(&d, tag, &model);
        let v = json(&cli(
            &format!("identify stiffness --jm-kgm2 {jm} --force"),
            &[("--trace", &trace)],
        ));
        let (kl_err, jl_err) = (
            num(&v, "kl_nm_per_rad") / kl - 1.0,
            num(&v, "jl_kgm2") / jl - 1.0,
        );
        let credible = v["credible"] == true;
        eprintln!(
            "{tag}: KL {:+.2} %, JL {:+.2} %, credible {credible}, problems {}",
            100.0 * kl_err,
            100.0 * jl_err,
            v["checks"]["problems"]
        );
        // What is called credible is within 1 %; what is not says what to change.
        if credible {
            assert!(kl_err.abs() < 0.01 && jl_err.abs() < 0.01, "{tag}: {v}");
            for key in ["kl_ci_pct", "jl_ci_pct"] {
                assert!(num(&v["checks"], key) < 1.0, "{tag}: {v}");
            }
        } else {
            // refused: it says what to change
            assert!(
                !v["checks"]["advice"].as_array().unwrap().is_empty(),
                "{tag}: {v}"
            );
        }
        if must_answer {
            assert!(credible, "{tag}: {v}");
        }
        // The effects the reversals show, named with their size whatever the verdict.
        let e = &v["reversal_effects"];
        let gap = [("backlash", 12e-6), ("effects", 10e-6), ("other", 18e-6)]
            .iter()
            .find(|(t, _)| *t == tag)
            .unwrap()
            .1;
        assert_eq!(e["backlash_seen"], true, "{tag}: {e}");
        assert!((num(e, "backlash_m") / gap - 1.0).abs() < 0.1, "{tag}: {e}");
        // a Coulomb step where the model has one, none on the axis with damping alone
        assert_eq!(e["friction_seen"], tag != "backlash", "{tag}: {e}");
        assert_eq!(e["flank_lifted"], false, "{tag}: {e}");
    }
    // Five times the shipped amplitude lifts the nut off its flank on `xy-x-effects`: the fit
    // still looks tight, the result is wrong (KL about -11 %), and it is refused for that.
    let effects = std::fs::read_to_string(repo("examples/models/xy-x-effects.toml")).unwrap();
    let trace = stiffness_axis_at(&d, "lifted", &effects, Some(1e-3));
    let v = json(&cli(
        "identify stiffness --jm-kgm2 2e-3 --force",
        &[("--trace", &trace)],
    ));
    assert_eq!(v["credible"], false, "{v}");
    assert_eq!(v["reversal_effects"]["flank_lifted"], true, "{v}");
    assert!(
        v["checks"]["problems"]
            .to_string()
            .contains("lifts the nut off its flank"),
        "{v}"
    );
}

#[test]
fn sim_match_finds_workpieces_on_an_axis_with_friction_backlash_and_noise_within_1_percent() {
    // The machine: `xy-x-effects` (Coulomb friction on both sides, 10 um backlash, 20-bit
    // encoder, 50 nm scale, velocity noise) with a workpiece; the user's model: the same axis
    // with the nominal inertia and a sensor seed of its own (nobody knows the machine's noise).
    let d = scratch("inertia-effects");
    let effects = std::fs::read_to_string(repo("examples/models/xy-x-effects.toml")).unwrap();
    assert!(effects.contains("jl_kgm2 = 3.0e-3") && effects.contains("seed = 1 "));
    let user = d.join("user.toml");
    std::fs::write(&user, effects.replace("seed = 1 ", "seed = 8 ")).unwrap();
    let user_job = |duration: &str| {
        inertia_job(
            &d,
            &format!("user-{duration}.toml"),
            &user,
            None,
            Some(duration),
        )
    };
    // +100 % saturates the 30 N m drive on the 0.3 s move: it runs the move in 0.6 s
    for (factor, duration) in [(1.3, "0.3"), (1.3, "0.6"), (2.0, "0.6")] {
        let truth = 3e-3 * factor;
        let m = d.join(format!("machine-{factor}-{duration}.toml"));
        std::fs::write(
            &m,
            effects.replace("jl_kgm2 = 3.0e-3", &format!("jl_kgm2 = {truth:e}")),
        )
        .unwrap();
        let mj = inertia_job(
            &d,
            &format!("machine-{factor}-{duration}-job.toml"),
            &m,
            Some("structure = \"split\", jl_kgm2 = 3.0e-3"),
            Some(duration),
        );
        let trace = sim(&mj, &d.join(format!("run-{factor}-{duration}")));
        let v = json(&cli(
            "identify inertia --method sim-match --at 0.01",
            &[("--trace", &trace), ("--model", &user_job(duration))],
        ));
        let err = num(&v, "jl_kgm2") / truth - 1.0;
        eprintln!(
            "+{:.0} % over {duration} s: JL {:+.2} %",
            100.0 * (factor - 1.0),
            100.0 * err
        );
        assert!(err.abs() < 0.01, "+{factor} / {duration} s: {v}");
    }
}
