//! Robustness to the mathematical form of an effect: traces made by small generators written
//! here (not the plant simulator, not the workbench's own effect forms), a rigid axis under a
//! P position / PI velocity loop: a smooth `tanh` friction law with a Stribeck-like hump, and a
//! trace without hidden effect but with coloured (low-pass) force noise and quantised position.
//! The diagnosis must name the class first and the fit must cut the equation error.

use std::f64::consts::PI;
use std::path::Path;

use feedloop_analysis::workbench::{
    data::{load_axis, Prep},
    diagnose::{diagnose, DiagOptions},
    effects::WbModel,
    fit::fit_with,
};
use feedloop_runtime::model::ModelFile;
use feedloop_runtime::trace::Trace;

const DT: f64 = 1e-3;
const M: f64 = 20.0;
const C: f64 = 60.0;
const KP: f64 = 40.0;
const KV: f64 = 3000.0;
const TV: f64 = 0.02;
const LIMIT: f64 = 1500.0;

const NOMINAL: &str = r#"
kind = "rigid"
mass_kg = 20.0
viscous_ns_per_m = 60.0
[controller]
kp_per_s = 40.0
kv_ns_per_m = 3000.0
tv_s = 0.02
force_limit_n = 1500.0
"#;

/// Moves with reversals, a slow crawl, holds and a sine, position in m.
fn command() -> Vec<f64> {
    let mut x = Vec::new();
    let mut pos = 0.0;
    let hold = |x: &mut Vec<f64>, pos: f64, s: f64| {
        for _ in 0..(s / DT) as usize {
            x.push(pos);
        }
    };
    let mv = |x: &mut Vec<f64>, pos: &mut f64, dist: f64, t: f64| {
        let n = (t / DT) as usize;
        for k in 1..=n {
            let u = k as f64 / n as f64;
            x.push(*pos + dist * (u - (2.0 * PI * u).sin() / (2.0 * PI)));
        }
        *pos += dist;
    };
    hold(&mut x, pos, 0.1);
    for (d, t) in [
        (0.1, 0.6),
        (-0.15, 0.8),
        (0.05, 0.4),
        (-0.03, 0.3),
        (0.2, 1.0),
    ] {
        mv(&mut x, &mut pos, d, t);
        hold(&mut x, pos, 0.1);
    }
    mv(&mut x, &mut pos, 0.005, 1.5);
    mv(&mut x, &mut pos, -0.005, 1.5);
    let n = (4.0 / DT) as usize;
    let mut ph = 0.0;
    for k in 0..n {
        let f = 0.5 + 4.0 * k as f64 / n as f64;
        ph += 2.0 * PI * f * DT;
        x.push(pos + 0.01 * ph.sin());
    }
    hold(&mut x, pos, 0.2);
    x
}

/// A small deterministic generator of standard normal numbers (xorshift + Box-Muller).
struct Noise(u64);

impl Noise {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * PI * b).cos()
    }
}

/// Closed loop of a rigid mass with the extra force `friction(v)` (N, opposing), coloured
/// force noise of std `noise_n` (first-order low-pass at 20 Hz) and the load position quantised
/// to `q` m.
fn simulate(friction: &dyn Fn(f64) -> f64, noise_n: f64, q: f64) -> Trace {
    let cmd = command();
    let n = cmd.len();
    let sub = 20;
    let h = DT / sub as f64;
    let (mut x, mut v, mut integ) = (0.0, 0.0, 0.0);
    let mut rng = Noise(0x9E37_79B9_7F4A_7C15);
    let mut coloured = 0.0;
    let a = (-2.0 * PI * 20.0 * DT).exp();
    let mut cols: Vec<Vec<f64>> = (0..4).map(|_| Vec::with_capacity(n)).collect();
    for (k, &c) in cmd.iter().enumerate() {
        let xm = (x / q).floor() * q;
        let e = KP * (c - xm) - v;
        let prev = integ;
        integ += DT * e;
        let raw = KV * (e + integ / TV);
        let u = raw.clamp(-LIMIT, LIMIT);
        if u != raw && e * raw > 0.0 {
            integ = prev;
        }
        for (j, val) in [k as f64 * DT, c, xm, u].into_iter().enumerate() {
            cols[j].push(val);
        }
        coloured = a * coloured + (1.0 - a) * rng.normal() * noise_n * 7.0;
        for _ in 0..sub {
            let f = u + coloured - C * v - friction(v);
            v += h * f / M;
            x += h * v;
        }
    }
    let names = ["t", "x.cmd", "x.load", "x.torque"]
        .map(String::from)
        .to_vec();
    Trace::from_columns(Path::new("forms.csv"), vec![], names, cols).unwrap()
}

fn nominal() -> WbModel {
    let t: toml::Table = NOMINAL.parse().unwrap();
    WbModel::from_parts(
        ModelFile::from_table(&t, Path::new("nominal.toml")).unwrap(),
        t,
    )
    .unwrap()
}

#[test]
fn a_smooth_tanh_friction_law_with_a_hump_is_named_friction_and_its_fit_cuts_the_error() {
    // another friction law: tanh(v / 2 mm/s) with a hump decaying as 1 / (1 + (v/vs)^2)
    let fric = |v: f64| (40.0 + 25.0 / (1.0 + (v / 0.004).powi(2))) * (v / 0.002).tanh();
    let tr = simulate(&fric, 0.5, 1e-7);
    let m = nominal();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    let dg = diagnose(&m, &d, &DiagOptions::default());
    let top = &dg.candidates[0];
    assert_eq!(top.class, "friction", "{}", dg.verdict);
    assert!(top.significant, "{}", dg.verdict);
    let r = fit_with(&m, &d, top.add.clone(), None, 0.05).unwrap();
    let (b, a) = (
        r.before.equation_nrmse_pct.unwrap(),
        r.after.equation_nrmse_pct.unwrap(),
    );
    println!(
        "tanh friction: top {} equation NRMSE {b:.2} -> {a:.2}; window {:?} -> {:?}",
        top.effect, r.before.window_sim_nrmse_pct, r.after.window_sim_nrmse_pct
    );
    assert!(a < 0.3 * b, "equation NRMSE {b} -> {a}; {:?}", r.params);
    // the windowed closed-loop simulation (rigid axis, sticking friction) agrees
    let (wb, wa) = (
        r.before.window_sim_nrmse_pct.unwrap(),
        r.after.window_sim_nrmse_pct.unwrap(),
    );
    assert!(wa < 0.3 * wb, "windowed simulation NRMSE {wb} -> {wa}");
}

#[test]
fn coloured_noise_and_quantisation_without_hidden_effect_give_no_significant_effect() {
    let tr = simulate(&|_| 0.0, 2.0, 1e-6);
    let m = nominal();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    let dg = diagnose(&m, &d, &DiagOptions::default());
    let sig: Vec<String> = dg
        .candidates
        .iter()
        .filter(|c| c.significant)
        .map(|c| format!("{} {:.1} %", c.effect, c.error_reduction_pct))
        .collect();
    assert!(sig.is_empty(), "significant: {sig:?}; {}", dg.verdict);
    assert!(
        dg.verdict
            .starts_with("no missing effect found; the remaining misfit"),
        "{}",
        dg.verdict
    );
}
