//! The workbench on the shipped circle (`examples/jobs/xy-circle.toml`, and once on the single-axis
//! move): effects hidden in a copy
//! of the X axis' model (with a sensor model), simulated with `feedloop sim`, and `diagnose
//! --auto` run with the shipped model. On a circle the motor and the table accelerate together
//! (the screw barely deflects): the torque balance sees only the sum of the two inertias, and a
//! refit that splits a change between them at random reads the screw's deflection wrong, where
//! it then finds a lead error or a mode that is not there.

use std::path::{Path, PathBuf};
use std::process::Command;

use feedloop_test_support::Scratch;
use serde_json::Value;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

const SENSOR: &str = "
[sensor]
motor_counts_per_rev = 1048576
load_resolution_m = 1.0e-8
load_pos_noise_m = 1.5e-8
motor_vel_noise_rad_per_s = 0.004
seed = 23
";

/// Simulates the circle with `hidden` in the X axis' model and runs `diagnose --auto --json`
/// of axis x with the shipped model (and the same sensor).
fn auto_hidden(dir: &Path, hidden: &str) -> Value {
    auto_machine(dir, hidden, |m| m.to_string())
}

/// Simulates the circle with `hidden` in the X axis' model, the machine's model also changed
/// by `edit` (the plain model, with the sensor, written as `x0.toml`); the output folder.
fn sim_machine(dir: &Path, hidden: &str, edit: impl Fn(&str) -> String) -> PathBuf {
    sim_job(dir, "xy-circle", hidden, edit)
}

/// [`sim_machine`] on the shipped job `job` (an X-Y job of `examples/jobs`).
fn sim_job(dir: &Path, job: &str, hidden: &str, edit: impl Fn(&str) -> String) -> PathBuf {
    let plain = std::fs::read_to_string(repo("examples/models/xy-x.toml")).unwrap();
    std::fs::write(dir.join("x0.toml"), format!("{plain}\n{SENSOR}")).unwrap();
    let machine = edit(&plain);
    std::fs::write(dir.join("x.toml"), format!("{machine}\n{hidden}\n{SENSOR}")).unwrap();
    std::fs::copy(repo("examples/models/xy-y.toml"), dir.join("y.toml")).unwrap();
    let job = std::fs::read_to_string(repo(&format!("examples/jobs/{job}.toml")))
        .unwrap()
        .replace("../models/xy-x.toml", "x.toml")
        .replace("../models/xy-y.toml", "y.toml");
    std::fs::write(dir.join("job.toml"), job).unwrap();
    let out = dir.join("out");
    let o = Command::new(bin())
        .args(["sim", "--quiet"])
        .arg(dir.join("job.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// As [`auto_hidden`], the machine's model also changed by `edit` (the plain model kept).
fn auto_machine(dir: &Path, hidden: &str, edit: impl Fn(&str) -> String) -> Value {
    let out = sim_machine(dir, hidden, edit);
    auto_on(dir, &out)
}

/// `diagnose --auto --out DIR/auto` on the simulated trace in `out` with the plain model of
/// `dir`: its JSON.
fn auto_on(dir: &Path, out: &Path) -> Value {
    let auto = dir.join("auto");
    plain_json(
        &["diagnose", "--auto", "--out", auto.to_str().unwrap()],
        dir,
        out,
    )
}

/// `feedloop ARGS --axis x --json` on the simulated trace in `out` with the plain model of
/// `dir` (`x0.toml`): its JSON.
fn plain_json(args: &[&str], dir: &Path, out: &Path) -> Value {
    let o = Command::new(bin())
        .args(args)
        .args(["--axis", "x", "--json", "--trace"])
        .arg(out.join("trace.csv"))
        .arg("--model")
        .arg(dir.join("x0.toml"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// What each step of the guided loop added.
fn added(a: &Value) -> Vec<String> {
    a["steps"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|s| s["added"].as_array().unwrap().clone())
        .map(|v| v.as_str().unwrap().to_string())
        .collect()
}

/// The final model written by `diagnose --auto --out`.
fn final_model(dir: &Path) -> toml::Table {
    let text = std::fs::read_to_string(dir.join("auto").join("model.toml")).unwrap();
    text.parse().unwrap()
}

/// A base parameter of the final model.
fn final_param(dir: &Path, key: &str) -> f64 {
    final_model(dir)[key].as_float().unwrap()
}

/// [`auto_hidden`], asserting that the guided loop added exactly `expect`: its JSON.
fn auto_adds(dir: &Path, hidden: &str, expect: &[&str]) -> Value {
    let a = auto_hidden(dir, hidden);
    let got = added(&a);
    println!("added {got:?}; {}", a["verdict"]);
    assert_eq!(got, expect, "{}", a["verdict"]);
    a
}

/// Asserts that `v` lies within `tol` (relative) of `truth` (the hidden or the model's value).
fn near(what: &str, v: f64, truth: f64, tol: f64) {
    assert!(
        (v / truth - 1.0).abs() < tol,
        "{what} = {v}, expected {truth}"
    );
}

fn check(tag: &str, hidden: &str, expect: &[&str]) {
    let dir = Scratch::new("workbench_circle", tag);
    auto_adds(&dir, hidden, expect);
    // the two inertias stay where they were: the record cannot split them
    for (key, truth) in [("jm_kgm2", 2.0e-3), ("jl_kgm2", 3.0e-3)] {
        near(
            &format!("{tag}: {key}"),
            final_param(&dir, key),
            truth,
            0.02,
        );
    }
}

/// Hides `hidden` on the circle (scratch folder `tag`), asserts that the guided loop adds
/// `effect` alone, and that each of its `(key, truth, tol)` in the final model lies within `tol`
/// (relative) of `truth`.
fn adds_alone_sized(tag: &str, hidden: &str, effect: &str, sizes: &[(&str, f64, f64)]) {
    let dir = Scratch::new("workbench_circle", tag);
    auto_adds(&dir, hidden, &[effect]);
    let t = final_model(&dir);
    let e = t["effects"][effect].as_table().unwrap();
    for (key, truth, tol) in sizes {
        let got = e
            .get(*key)
            .and_then(|v| v.as_float())
            .unwrap_or_else(|| panic!("{tag}: {effect} has no `{key}`: {e:?}"));
        near(&format!("{tag}: {key}"), got, *truth, *tol);
    }
}

/// The generic peer refits one inertia and one damping through its dictionary's acceleration and
/// velocity terms, not through the model's motor and load columns: on the circle the two bodies
/// move together, and a free split of the two inertias fits the scale's noise in sample (to half
/// the right model's equation error before it regressed on its dictionary alone).
#[test]
fn the_generic_peer_finds_nothing_beyond_a_right_model_on_the_circle() {
    let dir = Scratch::new("workbench_circle", "peer");
    let out = sim_machine(&dir, "", |m| m.to_string());
    let json = |args: &[&str]| plain_json(args, &dir, &out);
    let peer = json(&["diagnose"])["sparse_peer"].clone();
    let cmp_out = dir.join("cmp");
    let model = json(&["compare", "--out", cmp_out.to_str().unwrap()])["equation_nrmse_pct"]
        .as_f64()
        .unwrap();
    println!("peer {peer}; the model's equation error {model} %");
    assert_eq!(peer["terms"], serde_json::json!([]), "{peer}");
    let p = peer["equation_nrmse_pct"].as_f64().unwrap();
    assert!(
        (p / model - 1.0).abs() < 0.01,
        "peer {p} %, model {model} %"
    );
}

#[test]
fn a_constant_force_on_the_circle_is_added_alone_and_keeps_the_inertias() {
    check(
        "constant_force",
        "[effects.constant_force]\nforce_n = -120.0\n",
        &["constant_force"],
    );
}

#[test]
fn cogging_on_the_circle_is_added_alone_and_keeps_the_inertias() {
    check(
        "cogging",
        "[[effects.cogging]]\namplitude_nm = 0.05\nperiods_per_rev = 36\n",
        &["cogging"],
    );
}

#[test]
fn a_heavier_table_on_the_circle_is_refitted_as_the_load_inertia_alone() {
    let dir = Scratch::new("workbench_circle", "heavier");
    let a = auto_machine(&dir, "", |m| {
        assert!(
            m.contains("jl_kgm2 = 3.0e-3"),
            "the shipped model's load inertia moved"
        );
        m.replace("jl_kgm2 = 3.0e-3", "jl_kgm2 = 3.6e-3")
    });
    let got = added(&a);
    println!("heavier: added {got:?}; {}", a["verdict"]);
    // the step names what it moved: the motor's inertia is held, the load's takes the change
    assert_eq!(got, ["refit jl_kgm2"]);
    for (key, truth) in [("jm_kgm2", 2.0e-3), ("jl_kgm2", 3.6e-3)] {
        near(key, final_param(&dir, key), truth, 0.02);
    }
}

/// The side the guided loop put its one dry friction on, and its level there (`fc_nm` on the
/// motor, `fc_n` on the table), read from the final model.
fn friction_side(dir: &Path) -> (String, f64) {
    let t = final_model(dir);
    let f = t["effects"]["coulomb_friction"]
        .as_table()
        .unwrap_or_else(|| panic!("one coulomb_friction table expected: {t}"));
    let side = f["side"].as_str().unwrap().to_string();
    let level = f
        .get("fc_nm")
        .or_else(|| f.get("fc_n"))
        .and_then(|v| v.as_float())
        .unwrap();
    (side, level)
}

/// A dry friction on the motor and one on the table give the same torque balance but for the
/// instants around a reversal; the motion after them tells the sides apart. Each hidden friction
/// is added on its own side with its level (before, every friction of a ball screw went on the
/// table: a motor's 0.1 N m was written as 62.8 N there and its windowed simulation error was
/// two to nine times the right model's).
#[test]
fn a_dry_friction_on_the_circle_is_added_on_the_side_it_acts_on() {
    for (tag, hidden, side, truth) in [
        (
            "motor_friction",
            "[effects.coulomb_friction]\nside = \"motor\"\nfc_nm = 0.12\n",
            "motor",
            0.12,
        ),
        (
            "table_friction",
            "[effects.coulomb_friction]\nside = \"load\"\nfc_n = 45.0\n",
            "load",
            45.0,
        ),
    ] {
        let dir = Scratch::new("workbench_circle", tag);
        auto_adds(&dir, hidden, &["coulomb_friction"]);
        let (s, level) = friction_side(&dir);
        assert_eq!(s, side, "{tag}: friction put on the {s} side");
        near(&format!("{tag}: level"), level, truth, 0.02);
    }
}

/// A Stribeck friction whose rise spans a third of the circle's top speed: the best Stribeck
/// velocity lies at the upper edge of the range first searched (30 % of the top speed), so the
/// search goes on beyond it. The guided loop then ends with the Stribeck friction alone, its
/// levels and its velocity within 10 % (before, the velocity at the edge made the hump doubtful:
/// a Coulomb friction and a refit of the two dampings were added instead).
#[test]
fn a_stribeck_rise_over_a_third_of_the_top_speed_is_found_beyond_the_first_range() {
    let hidden = "[[effects.stribeck_friction]]\nside = \"load\"\nfc_n = 55.0\nfs_n = 85.0\nvs_m_per_s = 0.011\n";
    adds_alone_sized(
        "stribeck",
        hidden,
        "stribeck_friction",
        &[
            ("fc_n", 55.0, 0.1),
            ("fs_n", 85.0, 0.1),
            ("vs_m_per_s", 0.011, 0.1),
        ],
    );
}

/// A Stribeck velocity and a lost motion's transition travel lie between the points of their
/// grids: the refit refines them between the best point's neighbours, as it does a time
/// constant. Before, the grid's step alone sized a Stribeck velocity of 1 rad/s at 0.912 rad/s
/// (its breakaway level 3 % high) and a transition of 10 um at 17.1 um.
#[test]
fn a_stribeck_velocity_and_a_lost_motion_transition_between_grid_points_are_sized_closely() {
    let hidden = "[effects.stribeck_friction]\nfc_nm = 0.1\nfs_nm = 0.2\nvs_rad_per_s = 1.0\n";
    adds_alone_sized(
        "stribeck-refined",
        hidden,
        "stribeck_friction",
        &[
            ("fc_nm", 0.1, 0.01),
            ("fs_nm", 0.2, 0.01),
            ("vs_rad_per_s", 1.0, 0.03),
        ],
    );
    adds_alone_sized(
        "lost-refined",
        "[effects.lost_motion]\nlost_motion_m = 1.0e-5\n",
        "lost_motion",
        &[
            ("lost_motion_m", 1.0e-5, 0.01),
            ("transition_m", 1.0e-5, 0.1),
        ],
    );
}

/// A dead time of five periods on the circle: a first-order lag cuts the torque balance about as
/// much (95.9 % against 95.2 %), but the model with it simulates the record far worse; the
/// guided loop names the dead time, with its length (before, the lag was named).
#[test]
fn a_dead_time_on_the_circle_is_named_a_delay_not_a_lag() {
    let dir = Scratch::new("workbench_circle", "delay");
    auto_adds(&dir, "[effects.delay]\ndelay_cycles = 5\n", &["delay"]);
    let t = final_model(&dir);
    let n = t["effects"]["delay"]["delay_cycles"].as_integer().unwrap();
    assert_eq!(n, 5);
}

/// A friction whose levels and slopes differ between the two directions: the guided loop first
/// sees unequal levels as a Coulomb friction and a constant force (one torque balance while
/// moving), then the slopes' difference as the directional friction. It ends with the directional
/// friction alone, the constant folded into its levels, which come out within 10 % (before, the
/// constant force stayed beside it: an effect that is not there).
#[test]
fn a_directional_friction_on_the_circle_ends_alone_with_the_constant_folded_into_its_levels() {
    let dir = Scratch::new("workbench_circle", "directional");
    let hidden = "[effects.directional_friction]\nside = \"motor\"\nfc_pos_nm = 0.26\nfc_neg_nm = 0.13\nc_pos_nms_per_rad = 1.5e-3\n";
    let a = auto_hidden(&dir, hidden);
    let got = added(&a);
    println!("added {got:?}; {}", a["verdict"]);
    let t = final_model(&dir);
    let effects = t["effects"].as_table().unwrap();
    let names: Vec<&String> = effects.keys().collect();
    assert_eq!(names, ["directional_friction"], "{}", a["verdict"]);
    let f = effects["directional_friction"].as_table().unwrap();
    for (key, truth) in [("fc_pos_nm", 0.26), ("fc_neg_nm", 0.13)] {
        near(key, f[key].as_float().unwrap(), truth, 0.1);
    }
    // the slopes carry the model's two dampings (1e-3 and 2e-3 N m s/rad) the fit freed
    let (pos, neg) = (
        f["c_pos_nms_per_rad"].as_float().unwrap(),
        f["c_neg_nms_per_rad"].as_float().unwrap(),
    );
    assert!(
        ((pos - neg) / 1.5e-3 - 1.0).abs() < 0.2,
        "slopes {pos} and {neg}: their difference is the hidden 1.5e-3"
    );
}

/// A motor's friction beside a play between screw and table: the table reverses later than the
/// motor, and the torque balance itself tells the sides apart (the friction on the table leaves
/// about four times the error). The windowed simulation cannot, both sides ringing in the play
/// alike (130.3 % and 130.8 %); before, that left the friction on the default side, the table.
/// Now it goes on the motor with its level, and the play is added after it.
#[test]
fn a_motor_friction_beside_a_play_is_put_on_the_motor_by_the_torque_balance() {
    let dir = Scratch::new("workbench_circle", "friction_play");
    let hidden = "[effects.coulomb_friction]\nside = \"motor\"\nfc_nm = 0.12\n\n[effects.backlash]\ngap_m = 1.5e-5\n";
    auto_adds(&dir, hidden, &["coulomb_friction", "backlash"]);
    let (side, level) = friction_side(&dir);
    assert_eq!(side, "motor");
    near("level", level, 0.12, 0.05);
    let gap = final_model(&dir)["effects"]["backlash"]["gap_m"]
        .as_float()
        .unwrap();
    near("gap", gap, 1.5e-5, 0.1);
}

/// A gap wide enough that the frictionless table floats across it, rattling between the flanks:
/// the transmitted torque's sign no longer says which flank is in contact, and the deflection's
/// least squares sized it at a fifth and cut nothing; `diagnose` said "no missing effect" beside
/// a windowed simulation error above 100 %. Now the gap the flanks' medians see is sized on the
/// windowed simulation, as `fit` sizes it: named first within 10 %, and the guided loop adds it
/// alone and at least halves the windowed simulation error.
#[test]
fn a_gap_the_table_floats_across_is_named_and_sized_on_the_windowed_simulation() {
    let dir = Scratch::new("workbench_circle", "floating_gap");
    let truth = 2.5e-5;
    let out = sim_machine(
        &dir,
        &format!("[effects.backlash]\ngap_m = {truth:e}\n"),
        |m| m.to_string(),
    );
    let d = plain_json(&["diagnose"], &dir, &out);
    let first = &d["candidates"][0];
    assert_eq!(first["effect"], "backlash", "{}", d["verdict"]);
    assert_eq!(first["significant"], true, "{}", first["evidence"]);
    near(
        "gap",
        first["params"]["gap_m"].as_f64().unwrap(),
        truth,
        0.1,
    );
    // named by the windowed simulation, not by the deflection's least squares
    let why = first["evidence"].as_str().unwrap();
    assert!(why.contains("the load floats across the gap"), "{why}");
    let a = auto_on(&dir, &out);
    assert_eq!(added(&a), ["backlash"], "{}", a["verdict"]);
    let steps = a["steps"].as_array().unwrap();
    let w = |s: &Value| s["window_sim_nrmse_pct"].as_f64().unwrap();
    let (before, after) = (w(&steps[0]), w(steps.last().unwrap()));
    assert!(
        after < 0.5 * before,
        "windowed simulation {before} -> {after} %"
    );
}

/// A drive that clamps its torque on the single-axis move (limit 3.4 N m): the drive clamps
/// each command it holds, and the torque balance must clamp before the half-sample alignment,
/// not after. Aligned first, the clamp left half a period of torque beyond the limit at every
/// entry and exit (0.057 % against the true model's 0.032 %), and a third mass near 400 Hz
/// fitted it in the wide band: the guided loop added the clamp and that mode. Now it adds the
/// clamp alone, within 1 % of the limit; the mode, whose cut on the torque channel does not
/// count, is not significant.
#[test]
fn a_clamped_drive_on_the_single_axis_move_is_the_clamp_alone() {
    let dir = Scratch::new("workbench_circle", "clamp_move");
    let out = sim_job(
        &dir,
        "single-axis-move",
        "[effects.torque_saturation]\nlimit_nm = 3.4\n",
        |m| m.to_string(),
    );
    let a = auto_on(&dir, &out);
    assert_eq!(added(&a), ["torque_saturation"], "{}", a["verdict"]);
    let limit = final_model(&dir)["effects"]["torque_saturation"]["limit_nm"]
        .as_float()
        .unwrap();
    near("limit", limit, 3.4, 0.01);
}
