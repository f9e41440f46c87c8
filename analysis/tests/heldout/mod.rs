//! Held-out trace generator: closed-loop traces of a ball-screw feed axis made without
//! feedloop's plant simulator (`feedloop-plant`) and without the workbench's effect forms, so
//! the workbench can be tried on traces it has never seen. Use from an integration test with
//! `mod heldout;`.
//!
//! # The axis (nominal model, the keys of docs/model-file.md)
//!
//! States, motor side in rad / rad/s, the table and the mass behind it in m / m/s:
//! `thM, wM` (motor), `thL, wL` (screw/nut angle; table position `xL = r thL`, `r = lead / 2 pi`
//! m/rad), `x3, v3` (mass behind the table, table frame, m), plus two book-keeping states (work
//! done by the drive, energy dissipated) for the energy audit.
//!
//! ```text
//! JM wM' = T - DM wM - KL (thM - thL) - CL (wM - wL)                         [N m]
//! JL wL' = KL (thM - thL) + CL (wM - wL) - DL wL + r F_table                 [N m]
//! F_table = F_fric + F_visc + F_const + F_3                                  [N]
//! m3 v3' = -F_3                                                              [N]
//! ```
//!
//! Integrated with classical Runge-Kutta 4 over [`SUBSTEPS`] sub-steps of each 250 us period
//! (4 kHz), the drive torque `T` held over the period (not the plant simulator's exact
//! zero-order-hold matrix exponential, and no stick/slip state machine).
//!
//! # Hidden effects (each optional, any combination; [`Hidden`])
//!
//! * Dry friction on the table, a smooth law of this file:
//!   `F_fric = -Fc tanh(vL / v_eps)` [N], `Fc` in N, `v_eps` in m/s (e.g. 5e-5 m/s: the step
//!   of `2 Fc` at a reversal is crossed within a few um/s). There is no breakaway level above
//!   `Fc` and no sticking: at rest the force is 0.
//! * Extra viscous friction on the table: `F_visc = -c vL` [N], `c` in N s/m (on top of the
//!   nominal `DL`).
//! * Constant load force (gravity on an inclined axis): `F_const = -m g sin(alpha)` given as one
//!   number in N along +x; no friction step comes with it.
//! * A mass behind the table on its own spring: `F_3 = k3 (x3 - xL) + c3 (v3 - vL)` [N] with
//!   `k3 = m3 (2 pi f3)^2` [N/m], `c3 = 2 zeta sqrt(k3 m3)` [N s/m]; `m3` kg, `f3` Hz in
//!   50..150 (the mode of the mass on a held table), `zeta` 1.
//! * Transport delay in the drive: `T_applied[k] = T_cmd[k - n]`, `n` periods (before the
//!   start the drive holds the initial torque).
//! * Torque saturation of the drive: `T = clamp(T_cmd, -L, L)` [N m], the drive's `L` below the
//!   controller's own limit (which the nominal model file states). The torque column records
//!   either the clamped torque (what the drive reports) or the unclamped command.
//! * An input added after the controller: rectangular torque pulses `p(t) = A` [N m] while
//!   `(t - t0) mod P < w` and `t >= t0`, else 0; the controller law ignores them; the torque
//!   column records controller output + pulses (as the EMPS validation record `emps_pulses.csv`).
//!
//! Drive chain: controller output `u` -> `+ p(t)` -> delay -> clamp -> motor.
//!
//! # Controller (the nominal model's `[controller]`)
//!
//! P position loop on the table scale, PI velocity loop on the motor, per period `dt`:
//! `V = Kp (x_cmd - x_scale) / r` [rad/s]; `e = V - w_meas`; `I += e dt` (rectangle rule; not
//! while the output is at the controller's limit and `e` drives it further);
//! `u = clamp(Kv (e + I / Tv), -Lc, Lc)` [N m] (or, with [`Axis::integrate_after_output`], the
//! output from the integrator before this period's update; with
//! [`Axis::velocity_from_encoder`], the velocity is the backward difference of the quantised
//! motor encoder instead of the velocity sensor). The loop starts in equilibrium (the integrator
//! holds the constant load force).
//!
//! # Sensors
//!
//! Motor encoder 2^20 counts/rev and a 10 nm linear scale, both truncated to the count below
//! (`floor(x / q) q`); motor velocity = true velocity at the sample + Gaussian noise of std
//! `vel_noise_rad_per_s` [rad/s] (xorshift64* + Box-Muller, seeded). The trace's columns are
//! `t, x.cmd, x.load, x.motor, x.motor_vel, x.torque` (docs/trace-format.md), the torque being
//! the command the drive received at that sample (held over the next period).

#![allow(dead_code)]

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use feedloop_trace::TraceWriter;

/// Sampling period, s (4 kHz).
pub const PERIOD_S: f64 = 2.5e-4;
/// Runge-Kutta sub-steps per period.
pub const SUBSTEPS: usize = 8;
/// Motor encoder counts per revolution (20 bit).
pub const MOTOR_COUNTS: u64 = 1 << 20;
/// Linear scale resolution, m.
pub const SCALE_M: f64 = 1e-8;

/// Nominal axis: plant and controller, SI units, motor side as in docs/model-file.md.
#[derive(Debug, Clone)]
pub struct Axis {
    pub jm: f64,
    pub dm: f64,
    pub kl: f64,
    pub cl: f64,
    pub jl: f64,
    pub dl: f64,
    pub lead_m: f64,
    pub kp: f64,
    pub kv: f64,
    pub tv: f64,
    pub limit_nm: f64,
    /// The drive's velocity loop updates its integrator after forming the output (`u_k` uses
    /// `I_(k-1)`); default false (before, as feedloop's).
    pub integrate_after_output: bool,
    /// The drive's velocity loop uses the backward difference of the quantised motor encoder
    /// (the `motor_vel` column still records the noisy velocity sensor); default false.
    pub velocity_from_encoder: bool,
    /// A velocity feed-forward the nominal model's `[controller]` does not have: this many
    /// N m per rad/s of commanded motor velocity added to the controller's output (inside its
    /// limit); default 0.
    pub velocity_ff_nms_per_rad: f64,
}

impl Default for Axis {
    fn default() -> Self {
        Self {
            jm: 2.0e-3,
            dm: 1.0e-3,
            kl: 3000.0,
            cl: 0.03,
            jl: 3.0e-3,
            dl: 2.0e-3,
            lead_m: 0.01,
            kp: 40.0,
            kv: 3.0,
            tv: 0.008,
            limit_nm: 30.0,
            integrate_after_output: false,
            velocity_from_encoder: false,
            velocity_ff_nms_per_rad: 0.0,
        }
    }
}

impl Axis {
    /// Table metres per screw radian.
    pub fn r(&self) -> f64 {
        self.lead_m / (2.0 * PI)
    }

    /// The nominal model file (TOML): base parameters, `[controller]` and `[sensor]`.
    pub fn model_toml(&self) -> String {
        format!(
            "# nominal model of the held-out generator (analysis/tests/heldout)\n\
             kind = \"ballscrew\"\n\
             jm_kgm2 = {:e}\ndm_nms_per_rad = {:e}\nkl_nm_per_rad = {:e}\ncl_nms_per_rad = {:e}\n\
             jl_kgm2 = {:e}\ndl_nms_per_rad = {:e}\nlead_m = {:e}\n\n\
             [controller]\nkp_per_s = {:e}\nkv_nms_per_rad = {:e}\ntv_s = {:e}\ntorque_limit_nm = {:e}\n\n\
             [sensor]\nmotor_counts_per_rev = {}\nload_resolution_m = {:e}\n",
            self.jm,
            self.dm,
            self.kl,
            self.cl,
            self.jl,
            self.dl,
            self.lead_m,
            self.kp,
            self.kv,
            self.tv,
            self.limit_nm,
            MOTOR_COUNTS,
            SCALE_M
        )
    }
}

/// What the drive's torque column records when it clamps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Record {
    /// The clamped torque (the drive reports what it applies).
    Clamped,
    /// The controller's unclamped command.
    Unclamped,
}

/// Drive torque saturation.
#[derive(Debug, Clone, Copy)]
pub struct Saturation {
    /// Drive limit, N m (> 0).
    pub limit_nm: f64,
    pub record: Record,
}

/// A mass behind the table on its own spring.
#[derive(Debug, Clone, Copy)]
pub struct ThirdMass {
    /// kg
    pub mass_kg: f64,
    /// Mode of the mass on a held table, Hz (50..150).
    pub freq_hz: f64,
    /// Damping ratio, 1.
    pub zeta: f64,
}

/// Dry friction on the table, `-fc tanh(v / v_eps)`.
#[derive(Debug, Clone, Copy)]
pub struct Friction {
    /// N
    pub fc_n: f64,
    /// m/s
    pub v_eps_m_per_s: f64,
}

/// Rectangular torque pulses added after the controller.
#[derive(Debug, Clone, Copy)]
pub struct Pulses {
    /// N m
    pub amplitude_nm: f64,
    /// First rising edge, s.
    pub start_s: f64,
    /// Repetition period, s.
    pub period_s: f64,
    /// Width of each pulse, s.
    pub width_s: f64,
}

impl Pulses {
    /// Pulse torque at time `t`, N m.
    pub fn at(&self, t: f64) -> f64 {
        if t < self.start_s {
            return 0.0;
        }
        let ph = (t - self.start_s) % self.period_s;
        if ph < self.width_s {
            self.amplitude_nm
        } else {
            0.0
        }
    }
}

/// The effects hidden from the nominal model.
#[derive(Debug, Clone, Default)]
pub struct Hidden {
    pub friction: Option<Friction>,
    /// Extra table viscous friction, N s/m.
    pub viscous_ns_per_m: f64,
    /// Constant force on the table along +x, N.
    pub constant_force_n: f64,
    pub third_mass: Option<ThirdMass>,
    /// Transport delay in the drive, periods.
    pub delay_cycles: usize,
    pub saturation: Option<Saturation>,
    pub pulses: Option<Pulses>,
}

/// Measurement noise.
#[derive(Debug, Clone, Copy)]
pub struct Noise {
    /// Std dev of the motor velocity noise, rad/s.
    pub vel_noise_rad_per_s: f64,
    /// Seed of the noise generator.
    pub seed: u64,
}

/// The moves a commissioning engineer runs: for each speed, forward / back / forward / back
/// strokes with dwells, then a back-and-forth sine (reversals without dwell), then a dwell.
#[derive(Debug, Clone)]
pub struct Moves {
    /// Stroke, m (shortened for slow speeds to keep the trace short).
    pub stroke_m: f64,
    /// Cruise speeds, m/s.
    pub speeds_m_per_s: Vec<f64>,
    /// Peak acceleration of the ramps, m/s^2.
    pub accel_m_per_s2: f64,
    /// Smooth ramps (acceleration `a sin^2(pi t / ta)`, little excitation above 1 / ta) or,
    /// when false, constant-acceleration ramps (acceleration steps that excite every mode).
    pub smooth: bool,
    /// Dwell between strokes, s.
    pub dwell_s: f64,
    /// Sine: amplitude m, frequency Hz, cycles.
    pub sine: (f64, f64, usize),
}

impl Default for Moves {
    fn default() -> Self {
        Self {
            stroke_m: 0.02,
            speeds_m_per_s: vec![0.01, 0.05, 0.15],
            accel_m_per_s2: 4.0,
            smooth: true,
            dwell_s: 0.15,
            sine: (0.004, 2.0, 3),
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum Seg {
    Dwell(f64),
    /// distance, top speed, ramp time, cruise time, smooth ramps
    Move(f64, f64, f64, f64, bool),
    /// half the peak-to-peak, frequency, duration
    Sine(f64, f64, f64),
}

impl Seg {
    fn duration(&self) -> f64 {
        match *self {
            Seg::Dwell(d) | Seg::Sine(_, _, d) => d,
            Seg::Move(_, _, ta, tc, _) => 2.0 * ta + tc,
        }
    }

    /// Displacement from the segment's start at time `s` into it.
    fn at(&self, s: f64) -> f64 {
        match *self {
            Seg::Dwell(_) => 0.0,
            Seg::Sine(a, f, _) => a * (1.0 - (2.0 * PI * f * s).cos()),
            Seg::Move(d, v, ta, tc, smooth) => {
                // accelerating ramp a(t) = a_pk sin^2(pi t / ta), or constant v / ta; its
                // distance is v ta / 2 either way
                let ramp = |t: f64| {
                    let cos = if smooth {
                        ta / (4.0 * PI * PI) * ((2.0 * PI * t / ta).cos() - 1.0)
                    } else {
                        0.0
                    };
                    v * (t * t / (2.0 * ta) + cos)
                };
                let sg = d.signum();
                let total = 2.0 * ta + tc;
                let s = s.clamp(0.0, total);
                let x = if s < ta {
                    ramp(s)
                } else if s < ta + tc {
                    v * ta / 2.0 + v * (s - ta)
                } else {
                    d.abs() - ramp(total - s)
                };
                sg * x
            }
        }
    }
}

impl Moves {
    fn stroke(&self, d: f64, v: f64) -> Seg {
        // mean acceleration over a ramp: a / 2 for the sin^2 ramp, a for a constant one
        let a = if self.smooth {
            self.accel_m_per_s2 / 2.0
        } else {
            self.accel_m_per_s2
        };
        let mut v = v;
        let mut ta = v / a;
        if v * ta > d.abs() {
            v = (d.abs() * a).sqrt();
            ta = v / a;
        }
        let tc = (d.abs() - v * ta) / v;
        Seg::Move(d, v, ta, tc.max(0.0), self.smooth)
    }

    fn segments(&self) -> Vec<Seg> {
        let mut segs = vec![Seg::Dwell(0.2)];
        for &v in &self.speeds_m_per_s {
            let d = self.stroke_m.min(v * 0.6);
            for dir in [1.0, -1.0, 1.0, -1.0] {
                segs.push(self.stroke(dir * d, v));
                segs.push(Seg::Dwell(self.dwell_s));
            }
        }
        let (a, f, n) = self.sine;
        segs.push(Seg::Sine(a, f, n as f64 / f));
        segs.push(Seg::Dwell(0.2));
        segs
    }

    /// Commanded table position at every sample, m.
    pub fn command(&self, dt: f64) -> Vec<f64> {
        let segs = self.segments();
        let total: f64 = segs.iter().map(Seg::duration).sum();
        let n = (total / dt).floor() as usize + 1;
        let mut out = Vec::with_capacity(n);
        let (mut i, mut t0, mut x0) = (0usize, 0.0f64, 0.0f64);
        for k in 0..n {
            let t = k as f64 * dt;
            while i + 1 < segs.len() && t >= t0 + segs[i].duration() {
                x0 += segs[i].at(segs[i].duration());
                t0 += segs[i].duration();
                i += 1;
            }
            out.push(x0 + segs[i].at(t - t0));
        }
        out
    }
}

/// xorshift64* with Box-Muller: deterministic standard normal numbers.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng((seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    pub fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * PI * b).cos()
    }
}

/// Everything one run produced: the trace's columns and the truths behind them.
#[derive(Debug, Clone)]
pub struct Run {
    /// Time, s.
    pub t: Vec<f64>,
    /// Commanded table position, m.
    pub cmd: Vec<f64>,
    /// Scale reading, m (quantised).
    pub load: Vec<f64>,
    /// Motor encoder reading, rad (quantised).
    pub motor: Vec<f64>,
    /// Measured motor velocity, rad/s.
    pub motor_vel: Vec<f64>,
    /// The torque column, N m.
    pub torque: Vec<f64>,
    /// Controller output (before pulses, delay and clamp), N m.
    pub controller: Vec<f64>,
    /// Pulse torque added after the controller, N m.
    pub pulses: Vec<f64>,
    /// Torque the motor received over the period following each sample, N m.
    pub applied: Vec<f64>,
    /// True motor velocity at each sample, rad/s.
    pub true_motor_vel: Vec<f64>,
    /// True table position at each sample, m.
    pub true_load: Vec<f64>,
    /// Work done by the motor torque, J.
    pub work_j: f64,
    /// Energy dissipated by all dampers and friction, J.
    pub dissipated_j: f64,
    /// Kinetic + spring + potential energy at the end minus at the start, J.
    pub stored_change_j: f64,
}

const NS: usize = 8;

/// Right-hand side: derivative of `[thM, wM, thL, wL, x3, v3, work, dissipated]`.
fn rhs(ax: &Axis, h: &Hidden, k3c3: (f64, f64, f64), s: &[f64; NS], tq: f64) -> [f64; NS] {
    let r = ax.r();
    let (th_m, w_m, th_l, w_l, x3, v3) = (s[0], s[1], s[2], s[3], s[4], s[5]);
    let vl = r * w_l;
    let xl = r * th_l;
    let spring = ax.kl * (th_m - th_l) + ax.cl * (w_m - w_l);
    let f_fric = h
        .friction
        .map_or(0.0, |f| -f.fc_n * (vl / f.v_eps_m_per_s).tanh());
    let f_visc = -h.viscous_ns_per_m * vl;
    let (k3, c3, m3) = k3c3;
    let f3 = if m3 > 0.0 {
        k3 * (x3 - xl) + c3 * (v3 - vl)
    } else {
        0.0
    };
    let f_table = f_fric + f_visc + h.constant_force_n + f3;
    let dw_m = (tq - ax.dm * w_m - spring) / ax.jm;
    let dw_l = (spring - ax.dl * w_l + r * f_table) / ax.jl;
    let dv3 = if m3 > 0.0 { -f3 / m3 } else { 0.0 };
    let diss = ax.dm * w_m * w_m + ax.cl * (w_m - w_l) * (w_m - w_l) + ax.dl * w_l * w_l
        - (f_fric + f_visc) * vl
        + if m3 > 0.0 {
            c3 * (v3 - vl) * (v3 - vl)
        } else {
            0.0
        };
    [w_m, dw_m, w_l, dw_l, v3, dv3, tq * w_m, diss]
}

fn stored(ax: &Axis, h: &Hidden, k3c3: (f64, f64, f64), s: &[f64; NS]) -> f64 {
    let r = ax.r();
    let (k3, _, m3) = k3c3;
    let d = s[0] - s[2];
    let xl = r * s[2];
    0.5 * ax.jm * s[1] * s[1]
        + 0.5 * ax.jl * s[3] * s[3]
        + 0.5 * ax.kl * d * d
        + 0.5 * m3 * s[5] * s[5]
        + 0.5 * k3 * (s[4] - xl) * (s[4] - xl)
        - h.constant_force_n * xl
}

/// Runs the closed loop over `moves` and returns the trace and its truths.
pub fn run(ax: &Axis, h: &Hidden, noise: &Noise, moves: &Moves) -> Run {
    if let Some(m) = h.third_mass {
        assert!(
            (50.0..=150.0).contains(&m.freq_hz) && m.mass_kg > 0.0,
            "third mass: mode must be 50..150 Hz and the mass > 0"
        );
    }
    if let Some(s) = h.saturation {
        assert!(s.limit_nm > 0.0 && s.limit_nm < ax.limit_nm);
    }
    let dt = PERIOD_S;
    let r = ax.r();
    let cmd = moves.command(dt);
    let n = cmd.len();
    let k3c3 = h.third_mass.map_or((0.0, 0.0, 0.0), |m| {
        let k3 = m.mass_kg * (2.0 * PI * m.freq_hz).powi(2);
        (k3, 2.0 * m.zeta * (k3 * m.mass_kg).sqrt(), m.mass_kg)
    });
    // equilibrium under the constant force (it acts on the table): u0 = -r F, spring
    // deflection u0 / KL
    let u0 = -r * h.constant_force_n;
    let mut s = [0.0; NS];
    s[0] = u0 / ax.kl;
    let e0 = stored(ax, h, k3c3, &s);
    let mut integ = u0 * ax.tv / ax.kv;
    let qm = 2.0 * PI / MOTOR_COUNTS as f64;
    let mut rng = Rng::new(noise.seed);
    let mut line = vec![u0; h.delay_cycles + 1];
    let mut th_prev = 0.0;
    let mut out = Run {
        t: Vec::with_capacity(n),
        cmd: cmd.clone(),
        load: Vec::with_capacity(n),
        motor: Vec::with_capacity(n),
        motor_vel: Vec::with_capacity(n),
        torque: Vec::with_capacity(n),
        controller: Vec::with_capacity(n),
        pulses: Vec::with_capacity(n),
        applied: Vec::with_capacity(n),
        true_motor_vel: Vec::with_capacity(n),
        true_load: Vec::with_capacity(n),
        work_j: 0.0,
        dissipated_j: 0.0,
        stored_change_j: 0.0,
    };
    let hs = dt / SUBSTEPS as f64;
    for (k, &c) in cmd.iter().enumerate() {
        let t = k as f64 * dt;
        // sensors
        let x_true = r * s[2];
        let x_meas = (x_true / SCALE_M).floor() * SCALE_M;
        let th_meas = (s[0] / qm).floor() * qm;
        let w_meas = s[1] + noise.vel_noise_rad_per_s * rng.normal();
        // controller
        let w_loop = if ax.velocity_from_encoder {
            let v = if k == 0 {
                0.0
            } else {
                (th_meas - th_prev) / dt
            };
            th_prev = th_meas;
            v
        } else {
            w_meas
        };
        let e = ax.kp * (c - x_meas) / r - w_loop;
        let u = if ax.integrate_after_output {
            let u = (ax.kv * (e + integ / ax.tv)).clamp(-ax.limit_nm, ax.limit_nm);
            let i_new = integ + e * dt;
            let raw = ax.kv * (e + i_new / ax.tv);
            if !(raw.abs() > ax.limit_nm && raw * e > 0.0) {
                integ = i_new;
            }
            u
        } else {
            let mut i_new = integ + e * dt;
            let raw = ax.kv * (e + i_new / ax.tv);
            if raw.abs() > ax.limit_nm && raw * e > 0.0 {
                i_new = integ;
            }
            integ = i_new;
            (ax.kv * (e + integ / ax.tv)).clamp(-ax.limit_nm, ax.limit_nm)
        };
        let u = if ax.velocity_ff_nms_per_rad != 0.0 {
            let v_cmd = if k == 0 {
                0.0
            } else {
                (c - cmd[k - 1]) / (r * dt)
            };
            (u + ax.velocity_ff_nms_per_rad * v_cmd).clamp(-ax.limit_nm, ax.limit_nm)
        } else {
            u
        };
        // drive: pulses, delay, clamp
        let p = h.pulses.map_or(0.0, |p| p.at(t));
        let cmd_drive = u + p;
        line.rotate_right(1);
        line[0] = cmd_drive;
        let delayed = line[h.delay_cycles];
        let (applied, recorded) = match h.saturation {
            Some(sat) => {
                let a = delayed.clamp(-sat.limit_nm, sat.limit_nm);
                match sat.record {
                    Record::Clamped => (a, cmd_drive.clamp(-sat.limit_nm, sat.limit_nm)),
                    Record::Unclamped => (a, cmd_drive),
                }
            }
            None => (delayed, cmd_drive),
        };
        out.t.push(t);
        out.load.push(x_meas);
        out.motor.push(th_meas);
        out.motor_vel.push(w_meas);
        out.torque.push(recorded);
        out.controller.push(u);
        out.pulses.push(p);
        out.applied.push(applied);
        out.true_motor_vel.push(s[1]);
        out.true_load.push(x_true);
        // plant: RK4 sub-steps, torque held over the period
        for _ in 0..SUBSTEPS {
            let k1 = rhs(ax, h, k3c3, &s, applied);
            let mut y = s;
            for j in 0..NS {
                y[j] = s[j] + 0.5 * hs * k1[j];
            }
            let k2 = rhs(ax, h, k3c3, &y, applied);
            for j in 0..NS {
                y[j] = s[j] + 0.5 * hs * k2[j];
            }
            let k3 = rhs(ax, h, k3c3, &y, applied);
            for j in 0..NS {
                y[j] = s[j] + hs * k3[j];
            }
            let k4 = rhs(ax, h, k3c3, &y, applied);
            for j in 0..NS {
                s[j] += hs / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
            }
        }
    }
    out.work_j = s[6];
    out.dissipated_j = s[7];
    out.stored_change_j = stored(ax, h, k3c3, &s) - e0;
    out
}

impl Run {
    /// Writes the trace (format v1) to `path`.
    pub fn write(&self, path: &Path, source: &str) -> std::io::Result<()> {
        let cols: Vec<String> = ["t", "x.cmd", "x.load", "x.motor", "x.motor_vel", "x.torque"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let meta = vec![
            ("period_s".to_string(), format!("{PERIOD_S}")),
            ("source".to_string(), source.to_string()),
        ];
        let mut w = TraceWriter::create(path, &meta, &cols)?;
        for k in 0..self.t.len() {
            w.write_row(&[
                self.t[k],
                self.cmd[k],
                self.load[k],
                self.motor[k],
                self.motor_vel[k],
                self.torque[k],
            ])?;
        }
        w.finish()?;
        Ok(())
    }
}

/// Generates one case into `dir`: `<name>.csv` (trace) and `<name>.toml` (nominal model).
pub fn generate(
    dir: &Path,
    name: &str,
    ax: &Axis,
    h: &Hidden,
    noise: &Noise,
    moves: &Moves,
) -> std::io::Result<(PathBuf, PathBuf, Run)> {
    std::fs::create_dir_all(dir)?;
    let run = run(ax, h, noise, moves);
    let trace = dir.join(format!("{name}.csv"));
    let model = dir.join(format!("{name}.toml"));
    run.write(
        &trace,
        &format!(
            "heldout generator (analysis/tests/heldout), case {name}, seed {}",
            noise.seed
        ),
    )?;
    std::fs::write(&model, ax.model_toml())?;
    Ok((trace, model, run))
}
