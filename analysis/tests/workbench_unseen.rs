//! The workbench on traces it has never seen (issue 14): closed-loop traces of a ball-screw axis
//! from the independent generator of `heldout/` (RK4 two-mass axis with its own effect forms,
//! 4 kHz, 20-bit encoder, 10 nm scale, velocity noise), with other parameters, seeds and noise
//! levels than the baseline report of `workbench_heldout.rs`.
//!
//! For every trace: the hidden effect's class is the first significant candidate (nothing is
//! significant on a right model); adding the first candidate cuts the error of the channel
//! where it shows (equation, controller or windowed simulation) by at least 70 % and raises
//! no other channel; the guided loop ends with exactly the hidden effects' classes. An input
//! added after the controller is named and dated, not fitted; declared as a known input it
//! closes the controller channel and brings the windowed simulation within 2x of its figure
//! without the input.

mod heldout;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use feedloop_analysis::workbench::{
    auto::auto,
    base::BaseParam,
    data::{load_axis, AxisData, Prep},
    diagnose::{diagnose, DiagOptions, Diagnosis},
    effects::{EffectId, WbModel},
    fit::{fit_with, Errors},
    window::window_sim,
    words::class_of,
};
use feedloop_trace::Trace;
use heldout::*;

use feedloop_test_support::Scratch;

/// A fresh scratch folder for test `name` (removed when the test passes).
fn tmp(name: &str) -> Scratch {
    Scratch::new("unseen", name)
}

fn noise(v: f64, seed: u64) -> Noise {
    Noise {
        vel_noise_rad_per_s: v,
        seed,
    }
}

/// Generates, reads and diagnoses one trace.
fn case(
    name: &str,
    h: &Hidden,
    nz: Noise,
    smooth: bool,
) -> (WbModel, AxisData, Diagnosis, Run, CaseTrace) {
    case_on(&Axis::default(), name, h, nz, smooth)
}

/// [`case`] on axis `ax`.
fn case_on(
    ax: &Axis,
    name: &str,
    h: &Hidden,
    nz: Noise,
    smooth: bool,
) -> (WbModel, AxisData, Diagnosis, Run, CaseTrace) {
    let dir = tmp(name);
    let mv = Moves {
        smooth,
        ..Moves::default()
    };
    let (trace, model, run) = generate(&dir, name, ax, h, &nz, &mv).unwrap();
    let tr = Trace::read(&trace).unwrap();
    let m = WbModel::load(&model).unwrap();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    let dg = diagnose(&m, &d, &DiagOptions::default());
    (
        m,
        d,
        dg,
        run,
        CaseTrace {
            path: trace,
            _dir: dir,
        },
    )
}

/// A case's trace file, and its folder kept as long as the caller holds it.
struct CaseTrace {
    path: PathBuf,
    _dir: Scratch,
}

impl std::ops::Deref for CaseTrace {
    type Target = std::path::Path;
    fn deref(&self) -> &std::path::Path {
        &self.path
    }
}

fn table(dg: &Diagnosis) -> String {
    dg.candidates
        .iter()
        .filter(|c| c.significant)
        .map(|c| {
            format!(
                "{} ({}, {}) {:.1} %",
                c.effect, c.class, c.channel, c.error_reduction_pct
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
        + " | "
        + &dg.verdict
}

/// The class of a guided-loop step label (`refit KEY`, `ID`, `ID (replaces ...)`).
fn step_class(label: &str) -> String {
    match label.strip_prefix("refit ") {
        Some(k) => [BaseParam::RIGID.as_slice(), &BaseParam::TWO_MASS]
            .concat()
            .into_iter()
            .find(|p| p.key() == k)
            .expect("a base parameter's key")
            .class()
            .id()
            .to_string(),
        None => {
            let id = label.split_whitespace().next().unwrap();
            class_of(EffectId::parse(id).unwrap()).to_string()
        }
    }
}

/// The guided loop (at most 5 additions): its result, the step labels and their classes.
fn guided(
    m: &WbModel,
    d: &AxisData,
) -> (
    feedloop_analysis::workbench::auto::AutoResult,
    Vec<String>,
    BTreeSet<String>,
) {
    let a = auto(m, d, 0.05, 5).unwrap();
    let added: Vec<String> = a
        .steps
        .iter()
        .skip(1)
        .flat_map(|s| s.added.clone())
        .collect();
    let classes = added.iter().map(|l| step_class(l)).collect();
    (a, added, classes)
}

fn err_of(e: &Errors, channel: &str) -> f64 {
    match channel {
        "controller" => e.controller_nrmse_pct,
        "deflection" => e.window_sim_nrmse_pct,
        _ => e.equation_nrmse_pct,
    }
    .unwrap()
}

/// The checks of the module doc for a trace whose hidden effects have the classes `expect`
/// (the first significant candidate is in `expect[0]`'s class or, for two hidden effects, in
/// either).
fn check(name: &str, h: Hidden, nz: Noise, smooth: bool, expect: &[&str]) {
    let (m, d, dg, _, _case) = case(name, &h, nz, smooth);
    let first = dg.candidates.iter().find(|c| c.significant);
    let Some(top) = first else {
        panic!("{name}: nothing significant; {}", table(&dg));
    };
    assert!(
        expect.contains(&top.class.as_str()),
        "{name}: first significant is {} (class {}), hidden {expect:?}; {}",
        top.effect,
        top.class,
        table(&dg)
    );
    // adding the first candidate cuts its channel's error and raises no other
    let free = top.is_param.then(|| vec![top.effect.clone()]);
    let r = fit_with(&m, &d, top.add.clone(), free.as_deref(), 0.05).unwrap();
    let (b, a) = (
        err_of(&r.before, top.channel),
        err_of(&r.after, top.channel),
    );
    println!(
        "{name}: {} on {}: {b:.3} -> {a:.3} %; before {:?}; after {:?}",
        top.effect, top.channel, r.before, r.after
    );
    assert!(
        a <= 0.3 * b,
        "{name}: adding {} cuts its channel ({}) only from {b:.3} to {a:.3} %",
        top.effect,
        top.channel
    );
    for (what, x, y) in [
        (
            "equation",
            r.before.equation_nrmse_pct,
            r.after.equation_nrmse_pct,
        ),
        (
            "windowed simulation",
            r.before.window_sim_nrmse_pct,
            r.after.window_sim_nrmse_pct,
        ),
        (
            "controller",
            r.before.controller_nrmse_pct,
            r.after.controller_nrmse_pct,
        ),
    ] {
        let (x, y) = (x.unwrap(), y.unwrap());
        assert!(
            y <= 1.1 * x + 0.5,
            "{name}: adding {} raises the {what} error from {x:.3} to {y:.3} %",
            top.effect
        );
    }
    // the guided loop ends with exactly the hidden classes
    let (a, added, classes) = guided(&m, &d);
    let want: BTreeSet<String> = expect.iter().map(|s| s.to_string()).collect();
    assert_eq!(
        classes, want,
        "{name}: the guided loop added {added:?}; {}",
        a.last.verdict
    );
}

/// Nothing significant, and the verdict does not claim an effect.
fn check_right(name: &str, nz: Noise) {
    let (_, _, dg, _, _case) = case(name, &Hidden::default(), nz, true);
    assert!(
        dg.candidates.iter().all(|c| !c.significant),
        "{name}: {}",
        table(&dg)
    );
    assert!(
        dg.verdict.starts_with("no missing effect found"),
        "{name}: {}",
        dg.verdict
    );
}

#[test]
fn a_right_model_at_three_noise_levels_has_no_significant_candidate() {
    check_right("right-quiet", noise(5e-4, 41));
    check_right("right-mid", noise(0.02, 42));
    check_right("right-loud", noise(0.1, 43));
}

#[test]
fn a_drive_clamp_recorded_after_clamping_is_named_from_the_controller_channel() {
    let sat = |l: f64| Hidden {
        saturation: Some(Saturation {
            limit_nm: l,
            record: Record::Clamped,
        }),
        ..Hidden::default()
    };
    check(
        "clamped-6",
        sat(6.0),
        noise(0.02, 51),
        true,
        &["saturation"],
    );
    check(
        "clamped-4",
        sat(4.0),
        noise(0.005, 52),
        false,
        &["saturation"],
    );
    // the limit is the one the drive had
    let (_, _, dg, _, _case) = case("clamped-4b", &sat(4.0), noise(0.005, 53), true);
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    let l = top.params["limit_nm"];
    assert!((l - 4.0).abs() < 0.04, "limit {l}; {}", table(&dg));
    assert_eq!(top.channel, "controller");
}

#[test]
fn a_drive_clamp_recorded_before_clamping_is_named_from_the_torque_balance() {
    let h = Hidden {
        saturation: Some(Saturation {
            limit_nm: 6.5,
            record: Record::Unclamped,
        }),
        ..Hidden::default()
    };
    check("unclamped-6.5", h, noise(0.01, 54), true, &["saturation"]);
}

#[test]
fn a_constant_force_without_a_friction_step_is_named_constant_force() {
    let f = |n: f64| Hidden {
        constant_force_n: n,
        ..Hidden::default()
    };
    check("force+250", f(250.0), noise(0.01, 61), true, &["offset"]);
    check("force-60", f(-60.0), noise(0.08, 62), false, &["offset"]);
}

#[test]
fn smooth_dry_friction_and_extra_damping_are_named_in_their_classes() {
    let fric = Hidden {
        friction: Some(Friction {
            fc_n: 60.0,
            v_eps_m_per_s: 2e-4,
        }),
        ..Hidden::default()
    };
    check("tanh-60", fric, noise(0.03, 71), true, &["friction"]);
    let visc = Hidden {
        viscous_ns_per_m: 800.0,
        ..Hidden::default()
    };
    check("viscous-800", visc, noise(0.01, 72), true, &["damping"]);
}

#[test]
fn a_strongly_excited_mass_behind_the_table_is_named_a_mode() {
    let h = Hidden {
        third_mass: Some(ThirdMass {
            mass_kg: 250.0,
            freq_hz: 90.0,
            zeta: 0.03,
        }),
        ..Hidden::default()
    };
    check("mode-250-90", h, noise(0.02, 81), false, &["mode"]);
}

#[test]
fn a_one_period_drive_delay_with_friction_gives_both_classes_and_nothing_else() {
    delay_beside_friction("delay+friction", 50.0, 1e-4, noise(0.02, 91));
}

/// A 1-cycle drive delay beside a tanh friction of `fc_n` (transition `v_eps`): the guided loop
/// ends with both classes ([`check`]).
fn delay_beside_friction(name: &str, fc_n: f64, v_eps_m_per_s: f64, nz: Noise) {
    let h = Hidden {
        delay_cycles: 1,
        friction: Some(Friction {
            fc_n,
            v_eps_m_per_s,
        }),
        ..Hidden::default()
    };
    check(name, h, nz, true, &["friction", "delay"]);
}

/// A strong friction beside the delay: once the friction is in the model, the delay's refit
/// is scored against the same balance residual as the model (the friction holding the torque
/// at rest); against the raw one it raised the cross-validated error and the loop stopped
/// with the friction alone at five times the error of the true model.
#[test]
fn a_one_period_drive_delay_beside_a_strong_friction_is_added_after_it() {
    delay_beside_friction("delay+strong-friction", 120.0, 5e-5, noise(0.01, 17));
}

fn pulses() -> Pulses {
    Pulses {
        amplitude_nm: 1.2,
        start_s: 0.45,
        period_s: 0.7,
        width_s: 0.2,
    }
}

#[test]
fn an_input_added_after_the_controller_is_named_and_dated_and_declaring_it_closes_the_loop() {
    let h = Hidden {
        pulses: Some(pulses()),
        ..Hidden::default()
    };
    let (m, d, dg, run, trace) = case("pulses", &h, noise(0.02, 101), true);
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    assert_eq!(top.effect, "added_input", "{}", table(&dg));
    assert_eq!(top.channel, "controller");
    // the events are the pulses: their count, first start, period and size
    let p = pulses();
    let t_end = *run.t.last().unwrap();
    let expected = ((t_end - p.start_s) / p.period_s).ceil();
    assert!(
        (top.params["events"] - expected).abs() <= 1.0,
        "{:?} (expected about {expected} events)",
        top.params
    );
    assert!(
        (top.params["first_start_s"] - p.start_s).abs() <= 2.0 * PERIOD_S,
        "{:?}",
        top.params
    );
    assert!(
        (top.params["period_s"] - p.period_s).abs() <= 2.0 * PERIOD_S,
        "{:?}",
        top.params
    );
    assert!(
        (top.params["median_size"] - p.amplitude_nm).abs() < 0.02 * p.amplitude_nm,
        "{:?}",
        top.params
    );
    // the guided loop adds nothing for it and says what to do
    let a = auto(&m, &d, 0.05, 3).unwrap();
    assert_eq!(a.steps.len(), 1, "{}", a.last.verdict);
    assert!(a.last.verdict.contains("torque_add"), "{}", a.last.verdict);
    // declared as a known input (a column `x.torque_add`), the controller channel closes and
    // the windowed closed-loop simulation falls by 70 % or more
    let tr = Trace::read(&trace).unwrap();
    let mut names = tr.columns.clone();
    let mut cols: Vec<Vec<f64>> = names
        .iter()
        .map(|c| tr.column(c).unwrap().to_vec())
        .collect();
    names.push("x.torque_add".into());
    cols.push(tr.t().iter().map(|t| p.at(*t)).collect());
    let tr2 = Trace::from_columns(Path::new("pulses-declared.csv"), vec![], names, cols).unwrap();
    let d2 = load_axis(&tr2, &m.file, "x", &Prep::default()).unwrap();
    let (w1, w2) = (
        window_sim(&m, &d, 0.05).headline_nrmse_pct().unwrap(),
        window_sim(&m, &d2, 0.05).headline_nrmse_pct().unwrap(),
    );
    // the windowed simulation of the right model on the same moves, seed and noise without
    // pulses: the floor that noise leaves
    let (m0, d0, _, _, _case) = case("pulses-none", &Hidden::default(), noise(0.02, 101), true);
    let w0 = window_sim(&m0, &d0, 0.05).headline_nrmse_pct().unwrap();
    println!(
        "windowed simulation: {w1:.3} % undeclared, {w2:.3} % declared, {w0:.3} % without pulses"
    );
    // (the measure for the EMPS pulses record: within 2x of the figure without the
    // added input; the pulses' steps ring the screw's spring mode, which windows restarted from
    // the measured state cannot know)
    assert!(
        w2 <= 2.0 * w0 && w2 < w1,
        "windowed simulation {w1:.2} -> {w2:.2} % (without pulses {w0:.2} %)"
    );
    let dg2 = diagnose(&m, &d2, &DiagOptions::default());
    assert!(
        dg2.candidates.iter().all(|c| !c.significant),
        "{}",
        table(&dg2)
    );
    let c = dg2.controller.as_ref().unwrap();
    assert_eq!(c["fails"], false, "{c}");
    assert!(
        (c["added_input_gain"].as_f64().unwrap() - 1.0).abs() < 0.01,
        "{c}"
    );
}

#[test]
fn a_drive_that_discretises_its_loop_otherwise_is_read_right() {
    // the integrator updated after the output, the velocity from the encoder's backward
    // difference (the motor_vel column is the velocity sensor): a right model stays right,
    // and a clamp recorded after clamping is still named from the controller channel
    let ax = Axis {
        integrate_after_output: true,
        velocity_from_encoder: true,
        ..Axis::default()
    };
    let (_, _, dg, _, _) = case_on(
        &ax,
        "drive-right",
        &Hidden::default(),
        noise(0.02, 111),
        true,
    );
    assert!(
        dg.candidates.iter().all(|c| !c.significant),
        "{}",
        table(&dg)
    );
    let c = dg.controller.as_ref().unwrap();
    assert_eq!(c["fails"], false, "{c}");
    assert_eq!(
        c["discretisation"], "integrator updated after the output",
        "{c}"
    );
    let h = Hidden {
        saturation: Some(Saturation {
            limit_nm: 5.5,
            record: Record::Clamped,
        }),
        ..Hidden::default()
    };
    let (_, _, dg, _, _) = case_on(&ax, "drive-clamped", &h, noise(0.02, 112), false);
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    assert_eq!(top.class, "saturation", "{}", table(&dg));
    assert!(
        (top.params["limit_nm"] - 5.5).abs() < 0.06,
        "{:?}",
        top.params
    );
}

#[test]
fn two_hidden_effects_give_both_classes_and_nothing_else() {
    let h = Hidden {
        delay_cycles: 1,
        constant_force_n: -300.0,
        ..Hidden::default()
    };
    check(
        "delay+force",
        h,
        noise(0.01, 121),
        true,
        &["delay", "offset"],
    );
    // a damping is a base parameter: the guided loop refits it with the effect it adds (here
    // the delay class), so the final model's load damping must be the true one
    let h = Hidden {
        delay_cycles: 1,
        viscous_ns_per_m: 900.0,
        ..Hidden::default()
    };
    let (m, d, dg, _, _case) = case("delay+viscous", &h, noise(0.03, 122), true);
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    assert!(
        ["delay", "damping"].contains(&top.class.as_str()),
        "{}",
        table(&dg)
    );
    let (a, added, classes) = guided(&m, &d);
    assert!(classes.contains("delay"), "{added:?}");
    assert!(
        classes.iter().all(|c| c == "delay" || c == "damping"),
        "{added:?}"
    );
    // motor and load move together through the stiff screw: the data see their sum
    let ax = Axis::default();
    let d_true = ax.dm + ax.dl + 900.0 * ax.r() * ax.r();
    let d_fit =
        a.model.base_value(BaseParam::DmNmsPerRad) + a.model.base_value(BaseParam::DlNmsPerRad);
    assert!(
        (d_fit / d_true - 1.0).abs() < 0.1,
        "dm + dl {d_fit} for {d_true} after {added:?}"
    );
    let h = Hidden {
        saturation: Some(Saturation {
            limit_nm: 6.0,
            record: Record::Clamped,
        }),
        constant_force_n: 200.0,
        ..Hidden::default()
    };
    check(
        "clamp+force",
        h,
        noise(0.02, 123),
        false,
        &["saturation", "offset"],
    );
}

#[test]
fn a_weakly_excited_mode_is_inertia_on_these_moves_and_the_verdict_says_how_to_tell() {
    // smooth ramps barely excite a 130 Hz mode: what the data show is its mass moving with the
    // table; the verdict names the load inertia (the mass's m r^2 on top of JL) and says which
    // moves would tell a mode from it
    let h = Hidden {
        third_mass: Some(ThirdMass {
            mass_kg: 60.0,
            freq_hz: 130.0,
            zeta: 0.02,
        }),
        ..Hidden::default()
    };
    let (m, _, dg, _, _case) = case("weak-mode", &h, noise(0.01, 131), true);
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    assert!(
        ["inertia", "mode"].contains(&top.class.as_str()),
        "{}",
        table(&dg)
    );
    if top.class == "mode" {
        // named as a mode: then at its own frequency
        let get = |prefix: &str| {
            top.params
                .iter()
                .find(|(k, _)| k.starts_with(prefix))
                .map(|(_, v)| *v)
                .unwrap()
        };
        let f = (get("stiffness") / get("mass")).sqrt() / (2.0 * std::f64::consts::PI);
        assert!(
            (f / 130.0 - 1.0).abs() < 0.1,
            "mode at {f} Hz; {:?}",
            top.params
        );
    } else {
        assert!(
            dg.verdict.contains("acceleration steps or a sweep"),
            "{}",
            dg.verdict
        );
        let ax = Axis::default();
        let extra = 60.0 * ax.r() * ax.r();
        let k = top.effect.as_str();
        let p = BaseParam::parse(m.kind(), k).expect("a base parameter of the model");
        let moved = top.params[k] - m.base_value(p);
        assert!(
            (moved / extra - 1.0).abs() < 0.05,
            "{k} moves by {moved}, the mass adds {extra}"
        );
    }
}

#[test]
fn a_long_trace_is_searched_on_a_decimated_copy_and_named_the_same() {
    // 125 s at 4 kHz (500,000 samples, a long trace): the grids of column effects are searched
    // every 4th sample and only their best point is scored on all samples
    let h = Hidden {
        friction: Some(Friction {
            fc_n: 45.0,
            v_eps_m_per_s: 1e-4,
        }),
        ..Hidden::default()
    };
    let dir = tmp("long");
    let mv = Moves {
        sine: (0.004, 2.0, 240),
        ..Moves::default()
    };
    let (trace, model, _) =
        generate(&dir, "long", &Axis::default(), &h, &noise(0.02, 141), &mv).unwrap();
    let tr = Trace::read(&trace).unwrap();
    assert!(tr.len() >= feedloop_analysis::workbench::refit::LONG_TRACE);
    let m = WbModel::load(&model).unwrap();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    let dg = diagnose(&m, &d, &DiagOptions::default());
    let top = dg.candidates.iter().find(|c| c.significant).unwrap();
    assert_eq!(top.class, "friction", "{}", table(&dg));
    let fc = top.params["fc_n"];
    assert!((fc / 45.0 - 1.0).abs() < 0.1, "fc {fc}; {}", table(&dg));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_feed_forward_the_model_does_not_know_is_a_law_that_differs_not_an_added_input() {
    let ax = Axis {
        velocity_ff_nms_per_rad: 0.004,
        ..Axis::default()
    };
    let (_, _, dg, _, _) = case_on(
        &ax,
        "velocity-ff",
        &Hidden::default(),
        noise(0.01, 151),
        true,
    );
    let c = dg.controller.as_ref().unwrap();
    assert_eq!(c["fails"], true, "{c}");
    assert!(
        dg.candidates
            .iter()
            .all(|c| !(c.significant && c.effect == "added_input")),
        "{}",
        table(&dg)
    );
    assert!(dg.verdict.contains("controller"), "{}", dg.verdict);
}
