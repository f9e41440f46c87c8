//! Shared helpers of the plant tests: model builders, a cascade controller, spectra.
#![allow(dead_code)]

use std::path::Path;

use feedloop_control::axis_io::AxisSensor;
use feedloop_model::model::ModelFile;
use feedloop_model::params::ConfigError;
use feedloop_plant::AxisPlant;

/// The brief's ball-screw axis: JM = 2e-3, JL = 3e-3 kg m^2, KL = 3000 N m/rad, 10 mm lead.
pub const BALLSCREW: &str = r#"
kind = "ballscrew"
jm_kgm2 = 2.0e-3
dm_nms_per_rad = 1.0e-3
kl_nm_per_rad = 3000.0
cl_nms_per_rad = 0.05
jl_kgm2 = 3.0e-3
dl_nms_per_rad = 2.0e-3
lead_m = 0.01
"#;

/// Parses a model file text (named `test.toml` in messages).
pub fn parse(text: &str) -> Result<ModelFile, ConfigError> {
    let t: toml::Table = text.parse().expect("test model is valid TOML");
    ModelFile::from_table(&t, Path::new("test.toml"))
}

/// Builds an axis, panicking with the message on a config error.
pub fn axis(text: &str, period_s: f64) -> AxisPlant {
    let m = parse(text).unwrap_or_else(|e| panic!("{e}"));
    AxisPlant::new(&m, period_s).unwrap_or_else(|e| panic!("{e}"))
}

/// The ball-screw axis with extra TOML appended (effects, sensor).
pub fn ballscrew_with(extra: &str, period_s: f64) -> AxisPlant {
    axis(&format!("{BALLSCREW}\n{extra}"), period_s)
}

/// Error of building a model text.
pub fn build_error(text: &str) -> ConfigError {
    match parse(text) {
        Err(e) => e,
        Ok(m) => match AxisPlant::new(&m, 1e-4) {
            Err(e) => e,
            Ok(_) => panic!("model was accepted:\n{text}"),
        },
    }
}

/// P position loop on the load measurement + PI velocity loop on the motor velocity (seed 000):
/// `V = Kp (th - thL) + vff`, `T = Kv (e + (1/Tv) int e dt)` with `e = V - wM` (motor units).
#[derive(Debug, Clone)]
pub struct Cascade {
    /// Position gain, 1/s.
    pub kp: f64,
    /// Velocity gain, N m s/rad.
    pub kv: f64,
    /// Integral time, s.
    pub tv: f64,
    /// Period, s.
    pub h: f64,
    /// Motor units per load unit.
    pub r: f64,
    integ: f64,
}

impl Cascade {
    /// The brief's gains: Kp = 50/s, Kv = 5 N m s/rad, Tv = 5 ms.
    pub fn brief(h: f64, r: f64) -> Self {
        Self {
            kp: 50.0,
            kv: 5.0,
            tv: 0.005,
            h,
            r,
            integ: 0.0,
        }
    }

    /// Torque for a load reference `pos` (load units) with velocity feedforward `vel` (load
    /// units per s).
    pub fn torque(&mut self, pos: f64, vel: f64, m: &AxisSensor) -> f64 {
        let v = self.kp * (pos - m.load_pos) * self.r + vel * self.r;
        let e = v - m.motor_vel;
        self.integ += e * self.h;
        self.kv * (e + self.integ / self.tv)
    }
}

/// One closed-loop cycle record.
#[derive(Debug, Clone, Copy)]
pub struct Rec {
    /// Time at the sample, s.
    pub t: f64,
    /// Load reference, load units.
    pub r: f64,
    /// Measurement.
    pub m: AxisSensor,
    /// Commanded torque.
    pub u: f64,
}

/// Runs `n` cycles in closed loop with reference `traj(t) -> (pos, vel)`; `extra(k)` adds a
/// torque to the controller output.
pub fn run_loop(
    ax: &mut AxisPlant,
    ctl: &mut Cascade,
    n: usize,
    traj: impl Fn(f64) -> (f64, f64),
    extra: impl Fn(usize) -> f64,
) -> Vec<Rec> {
    let h = ax.period_s();
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let t = k as f64 * h;
        let m = ax.sense_axis();
        let (p, v) = traj(t);
        let u = ctl.torque(p, v, &m) + extra(k);
        out.push(Rec { t, r: p, m, u });
        ax.step_axis(u);
    }
    out
}

/// Smooth back-and-forth move: dwell, +`dist` in `t_move`, dwell, back, ... (cycloidal
/// velocity profile, so the reference has continuous acceleration). Returns (pos, vel).
pub fn back_and_forth(t: f64, dist: f64, t_move: f64, t_dwell: f64) -> (f64, f64) {
    let cycle = 2.0 * (t_move + t_dwell);
    let tc = t.rem_euclid(cycle);
    let seg = |s: f64| {
        let a = (s / t_move).clamp(0.0, 1.0);
        let p = a - (2.0 * std::f64::consts::PI * a).sin() / (2.0 * std::f64::consts::PI);
        let v = if (0.0..1.0).contains(&a) {
            (1.0 - (2.0 * std::f64::consts::PI * a).cos()) / t_move
        } else {
            0.0
        };
        (p, v)
    };
    if tc < t_dwell {
        (0.0, 0.0)
    } else if tc < t_dwell + t_move {
        let (p, v) = seg(tc - t_dwell);
        (dist * p, dist * v)
    } else if tc < 2.0 * t_dwell + t_move {
        (dist, 0.0)
    } else {
        let (p, v) = seg(tc - 2.0 * t_dwell - t_move);
        (dist * (1.0 - p), -dist * v)
    }
}

/// Magnitude spectrum (single-sided, amplitude-normalised) of a real signal, mean removed,
/// with a Hann window. Returns (frequency resolution Hz, magnitudes).
pub fn spectrum(x: &[f64], h: f64) -> (f64, Vec<f64>) {
    use rustfft::{num_complex::Complex, FftPlanner};
    let n = x.len();
    let mean = x.iter().sum::<f64>() / n as f64;
    let mut buf: Vec<Complex<f64>> = x
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let w = 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / n as f64).cos();
            Complex::new((v - mean) * w, 0.0)
        })
        .collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buf);
    let mags = buf[..n / 2]
        .iter()
        .map(|c| 4.0 * c.norm() / n as f64)
        .collect();
    (1.0 / (n as f64 * h), mags)
}

/// Complex FFT of a real signal (no window).
pub fn fft(x: &[f64]) -> Vec<rustfft::num_complex::Complex<f64>> {
    use rustfft::{num_complex::Complex, FftPlanner};
    let mut buf: Vec<Complex<f64>> = x.iter().map(|&v| Complex::new(v, 0.0)).collect();
    FftPlanner::new()
        .plan_fft_forward(x.len())
        .process(&mut buf);
    buf
}

/// Refines the extremum at bin `i` of `y` by a parabola through its neighbours (returns the
/// fractional bin).
pub fn parabolic(y: &[f64], i: usize) -> f64 {
    if i == 0 || i + 1 >= y.len() {
        return i as f64;
    }
    let (a, b, c) = (y[i - 1], y[i], y[i + 1]);
    let den = a - 2.0 * b + c;
    if den == 0.0 {
        i as f64
    } else {
        i as f64 + 0.5 * (a - c) / den
    }
}

/// Back-and-forth trapezoidal move: dwell `t_dwell`, +`dist` at speed `v` with raised-cosine
/// velocity ramps of `t_acc`, dwell, back. Returns (pos, vel).
pub fn trapezoid(t: f64, dist: f64, v: f64, t_acc: f64, t_dwell: f64) -> (f64, f64) {
    let t_move = dist / v + t_acc;
    let cycle = 2.0 * (t_move + t_dwell);
    let tc = t.rem_euclid(cycle);
    let pi = std::f64::consts::PI;
    // Position and velocity of a move of length `dist` at time s in [0, t_move].
    let seg = |s: f64| -> (f64, f64) {
        let s = s.clamp(0.0, t_move);
        let up = |s: f64| v * (s / 2.0 - t_acc / (2.0 * pi) * (pi * s / t_acc).sin());
        if s < t_acc {
            (up(s), v * (1.0 - (pi * s / t_acc).cos()) / 2.0)
        } else if s < t_move - t_acc {
            (up(t_acc) + v * (s - t_acc), v)
        } else {
            let r = t_move - s;
            (dist - up(r), v * (1.0 - (pi * r / t_acc).cos()) / 2.0)
        }
    };
    if tc < t_dwell {
        (0.0, 0.0)
    } else if tc < t_dwell + t_move {
        seg(tc - t_dwell)
    } else if tc < 2.0 * t_dwell + t_move {
        (dist, 0.0)
    } else {
        let (p, vv) = seg(tc - 2.0 * t_dwell - t_move);
        (dist - p, -vv)
    }
}
