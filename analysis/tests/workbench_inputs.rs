//! Bad input gives clear errors naming file, line or key; import, model init and the report work
//! end to end on a small generated trace.

use std::path::{Path, PathBuf};

use feedloop_analysis::workbench::{
    compare::compare,
    data::{load_axis, pick_axis, Prep},
    effects::WbModel,
    fit::{fit, parse_effects},
    import::{import, model_init, parse_map},
    report,
};
use feedloop_model::EffectId;
use feedloop_trace::Trace;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("feedloop-wb-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A rigid mass (50 kg, 100 N s/m, 10 N Coulomb) following a sine, as another tool would export
/// it: time in ms, positions in mm, force in N, `;` separated.
fn foreign_csv(path: &Path) {
    let mut s = String::from("time_ms;ref_mm;pos_mm;force_n\n");
    let dt = 1e-3;
    for k in 0..4000 {
        let t = k as f64 * dt;
        let w = 2.0 * std::f64::consts::PI * 0.5;
        let x = 0.05 * (w * t).sin();
        let v = 0.05 * w * (w * t).cos();
        let a = -0.05 * w * w * (w * t).sin();
        let f = 50.0 * a + 100.0 * v + 10.0 * v.signum();
        s.push_str(&format!("{};{};{};{}\n", t * 1e3, x * 1e3, x * 1e3, f));
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn an_imported_foreign_export_gets_a_nominal_model_close_to_the_truth_and_a_report() {
    let d = dir("import");
    let src = d.join("export.csv");
    foreign_csv(&src);
    let map = parse_map("t=time_ms*0.001,x.cmd=ref_mm*0.001,x.load=pos_mm/1000,x.torque=force_n")
        .unwrap();
    let tr = import(&src, &map, None, &d.join("t.csv")).unwrap();
    assert_eq!(tr.len(), 4000);
    assert!((tr.period_s() - 1e-3).abs() < 1e-12);
    let tr = Trace::read(&d.join("t.csv")).unwrap();
    let m = model_init(
        &tr,
        &feedloop_analysis::workbench::import::InitSpec {
            kind: feedloop_model::model::AxisKind::Rigid,
            lead_m: None,
            gear_ratio: None,
        },
        None,
        &d.join("m.toml"),
    )
    .unwrap();
    // without Coulomb friction the viscous term absorbs it; the mass is close
    assert!(
        (m.base_value(feedloop_analysis::workbench::base::BaseParam::MassKg) - 50.0).abs() < 2.5,
        "{:?}",
        m.base
    );
    let m = WbModel::load(&d.join("m.toml")).unwrap();
    let ax = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    let r = fit(&m, &ax, &[EffectId::CoulombFriction], None, 0.05).unwrap();
    assert!((r.params["fc_n"] - 10.0).abs() < 1.0, "{:?}", r.params);
    assert!(
        (r.params["viscous_ns_per_m"] - 100.0).abs() < 10.0,
        "{:?}",
        r.params
    );
    let c = compare(&r.model, &ax, 0.05);
    let html = report::html(&ax, &c, "test", "");
    assert!(
        html.contains("<svg") && html.matches("<svg").count() >= 6,
        "plots missing"
    );
    // every plot: a title, axis titles with their unit, more than two ticks an axis, a legend;
    // a linear (rigid) axis is in N, not "N m or N"
    assert!(!html.contains("N m or N"));
    for svg in html.split("<svg").skip(1) {
        let svg = &svg[..svg.find("</svg>").unwrap()];
        let first = |class: &str| {
            let i = svg
                .find(&format!(r#"class="{class}""#))
                .unwrap_or_else(|| panic!("no {class} in {svg}"));
            let t = &svg[i..];
            t[t.find('>').unwrap() + 1..t.find("</text>").unwrap()].to_string()
        };
        assert!(!first("title").is_empty());
        for axis in ["x-label", "y-label"] {
            let l = first(axis);
            assert!(
                l.contains(" (") && l.ends_with(')'),
                "{axis} `{l}` has no unit"
            );
        }
        assert!(
            svg.matches(r#"class="x-tick""#).count() > 2,
            "{}",
            first("title")
        );
        assert!(
            svg.matches(r#"class="y-tick""#).count() > 2,
            "{}",
            first("title")
        );
        assert!(svg.contains(r#"class="legend""#), "{}", first("title"));
    }
    assert!(html.contains(">force (N)<"), "the measured force's axis");
    // the figures table gives the residual RMS with its unit, e.g. `<td>1.234 N</td>`
    let rms = c.eq.as_ref().unwrap().rms;
    assert!(
        html.contains(&format!("<td>{}</td>", feedloop_model::units::si(rms, "N"))),
        "residual RMS {rms} N not in the table"
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_map_naming_a_missing_column_is_refused_naming_the_column_and_file() {
    let d = dir("map");
    let src = d.join("export.csv");
    foreign_csv(&src);
    let map = parse_map("t=time_ms*0.001,x.cmd=nope*0.001,x.load=pos_mm").unwrap();
    let e = import(&src, &map, None, &d.join("t.csv"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("nope") && e.contains("export.csv") && e.contains("line 1"),
        "{e}"
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_nan_cell_in_a_foreign_export_is_refused_with_its_line() {
    let d = dir("nan");
    let src = d.join("export.csv");
    std::fs::write(&src, "t,a\n0,1\n0.001,NaN\n").unwrap();
    let map = parse_map("x.cmd=a,x.load=a").unwrap();
    let e = import(&src, &map, None, &d.join("t.csv"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 3") && e.contains("`a`"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_trace_without_torque_is_refused_naming_the_missing_column() {
    let tr = Trace::parse(
        Path::new("no-torque.csv"),
        &(String::from("t,x.cmd,x.load\n")
            + &(0..100)
                .map(|k| format!("{},{},{}\n", k as f64 * 1e-3, k, k))
                .collect::<String>()),
    )
    .unwrap();
    let t: toml::Table = "kind = \"rigid\"\nmass_kg = 1.0\n".parse().unwrap();
    let mf = feedloop_model::model::ModelFile::from_table(&t, Path::new("m.toml")).unwrap();
    let d = load_axis(&tr, &mf, "x", &Prep::default()).unwrap();
    let e = d.require_torque("diagnose", &tr).unwrap_err().to_string();
    assert!(
        e.contains("no-torque.csv") && e.contains("`x.torque`"),
        "{e}"
    );
}

#[test]
fn a_model_for_another_axis_or_another_screw_is_refused() {
    let rows: String = (0..100)
        .map(|k| {
            format!(
                "{},{},{},{}\n",
                k as f64 * 1e-3,
                k as f64 * 1e-4,
                k as f64 * 1e-4,
                k as f64 * 1e-4 * 628.3 * 2.0
            )
        })
        .collect();
    let tr = Trace::parse(
        Path::new("tr.csv"),
        &(String::from("t,x.cmd,x.load,x.motor\n") + &rows),
    )
    .unwrap();
    let e = pick_axis(&tr, Path::new("m.toml"), Some("y"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("no axis `y`"), "{e}");
    // the motor turns twice as far per metre as a 10 mm lead implies
    let t: toml::Table = "kind = \"ballscrew\"\njm_kgm2 = 1e-3\nkl_nm_per_rad = 1e3\njl_kgm2 = 1e-3\nlead_m = 0.01\n".parse().unwrap();
    let mf = feedloop_model::model::ModelFile::from_table(&t, Path::new("m.toml")).unwrap();
    let e = load_axis(&tr, &mf, "x", &Prep::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("lead_m") && e.contains("tr.csv"), "{e}");
}

#[test]
fn an_unknown_effect_id_is_refused_listing_the_library() {
    let e = parse_effects(&["coulomb".to_string()])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("--add coulomb") && e.contains("coulomb_friction"),
        "{e}"
    );
}
