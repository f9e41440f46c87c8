//! Simulation error: the model driven as the machine was, over the whole trace (free run) and
//! over short windows restarted from the measured state.
//!
//! Closed loop from the command when the model file has a controller (`[controller]` with
//! `kp_per_s` and a velocity gain): position P on the load position, velocity PI on the motor
//! velocity, output limit; the integrator of each window starts so that the first output equals
//! the recorded torque (bumpless). Open loop from the recorded torque otherwise.
//!
//! The simulated plant is the plant simulator's axis (`feedloop-plant`) built from the model with
//! its effects (no sensor model): the 2-mass chain with its spring, backlash, pitch error, a third
//! mass, sticking dry friction, the drive's delay, lag and limit. Each window restarts it from the
//! measured state: motor and load positions and velocities (a velocity inside the friction dead
//! band counts as standstill), the delay line and current lag from the recorded torque, a third
//! mass at rest relative to the load. When the simulator refuses the model (e.g. a fitted
//! coefficient outside the library's range), the model seen from the motor as one rigid inertia
//! with the torque-balance effects is simulated instead, and [`WindowSim::plant`] says so. A free
//! run of a system with backlash or stick-slip drifts in phase even when the model is right;
//! windows (50 ms by default) restart from the measured state and measure the local fit.

use feedloop_plant::AxisPlant;

use super::base::BaseClass;
use super::controller::AT_LIMIT_TOL;
use super::data::AxisData;
use super::effects::{dead_band, third_mass_track, EffectId, WbModel};
use super::signal::{filtfilt_butter4, nrmse_pct, rms};

/// Error of one simulated channel.
#[derive(Debug, Clone)]
pub struct SimChannel {
    /// Channel name (`torque`, `following_error`, `velocity`).
    pub name: String,
    /// NRMSE of the windowed simulation, %.
    pub window_nrmse_pct: f64,
    /// RMS of the windowed simulation's error.
    pub window_rms: f64,
    /// NRMSE of the free run over the whole trace, %.
    pub free_nrmse_pct: f64,
}

/// Result of the simulations.
#[derive(Debug, Clone)]
pub struct WindowSim {
    /// `closed_loop`, `open_loop`, or `none` (no torque and no controller: nothing to drive).
    pub mode: &'static str,
    /// Window length, s.
    pub window_s: f64,
    /// Channels (the first is the headline).
    pub channels: Vec<SimChannel>,
    /// Measured headline channel.
    pub measured: Vec<f64>,
    /// Windowed simulation of the headline channel.
    pub simulated: Vec<f64>,
    /// `measured - simulated` of the headline channel.
    pub residual: Vec<f64>,
    /// What was simulated: `plant` (the plant simulator's axis with the model's effects) or
    /// `rigid_body: REASON` (the one-body approximation, and why the simulator was not used).
    pub plant: String,
}

/// [`WindowSim::plant`] when the plant simulator ran the model.
const PLANT: &str = "plant";

impl WindowSim {
    /// Whether the plant simulator ran the model (not the one-body approximation).
    pub fn on_plant(&self) -> bool {
        self.plant == PLANT
    }

    /// NRMSE of the headline channel's windowed simulation, % (None when not simulated).
    pub fn headline_nrmse_pct(&self) -> Option<f64> {
        self.channels.first().map(|c| c.window_nrmse_pct)
    }

    /// NRMSE of the headline channel's free run, %.
    pub fn headline_free_nrmse_pct(&self) -> Option<f64> {
        self.channels.first().map(|c| c.free_nrmse_pct)
    }
}

/// The model as one rigid body seen from the motor.
struct Body {
    inertia: f64,
    damping: f64,
    /// dry friction: symmetric level, asymmetry, Stribeck extra, Stribeck velocity, exponent
    fc: f64,
    fasym: f64,
    fs_extra: f64,
    vs: f64,
    ex: f64,
    offset: f64,
    cog: Vec<(f64, f64, f64)>,
    /// the direction-dependent part of the viscous friction, times |v|
    dasym: f64,
    /// unbalance: coefficients of sin and cos of the load angle, and the load's motor units per
    /// radian of that angle
    unb: (f64, f64, f64),
    eps: f64,
    limit: f64,
}

impl Body {
    fn new(model: &WbModel, d: &AxisData) -> Self {
        let mut b = Body {
            inertia: 0.0,
            damping: 0.0,
            fc: 0.0,
            fasym: 0.0,
            fs_extra: 0.0,
            vs: 1.0,
            ex: 2.0,
            offset: 0.0,
            cog: vec![],
            dasym: 0.0,
            unb: (0.0, 0.0, d.r),
            eps: dead_band(d, &d.vm),
            limit: f64::INFINITY,
        };
        for (k, v) in &model.base {
            match k.class() {
                BaseClass::Inertia => b.inertia += v,
                BaseClass::Damping => b.damping += v,
            }
        }
        for e in &model.effects {
            match e.id {
                EffectId::ViscousFriction => b.damping += e.coef[0],
                EffectId::CoulombFriction => {
                    b.fc += e.coef[0];
                    b.fasym += e.coef[1];
                }
                EffectId::StribeckFriction => {
                    b.fc += e.coef[0];
                    b.fs_extra += e.coef[1];
                    b.vs = e.hyper[0];
                    b.ex = e.hyper[1];
                }
                EffectId::ConstantForce => b.offset += e.coef[0],
                EffectId::Cogging => b.cog.push((
                    2.0 * std::f64::consts::PI / e.hyper[0],
                    e.coef[0],
                    e.coef[1],
                )),
                EffectId::ThirdMass => b.inertia += e.coef[0].max(0.0),
                EffectId::DirectionalFriction => {
                    let c = &e.coef;
                    b.fc += 0.5 * (c[0] + c[1]);
                    b.fasym += 0.5 * (c[0] - c[1]);
                    b.damping += 0.5 * (c[2] + c[3]);
                    b.dasym += 0.5 * (c[2] - c[3]);
                }
                EffectId::Unbalance => {
                    b.unb.2 = d.r * e.hyper[0] / (2.0 * std::f64::consts::PI);
                    b.unb.0 += e.coef[0];
                    b.unb.1 += e.coef[1];
                    b.offset += e.coef[2];
                }
                EffectId::TorqueSaturation => b.limit = b.limit.min(e.hyper[0]),
                // in the transmission or on the torque path: not part of the load balance
                EffectId::Backlash
                | EffectId::PitchError
                | EffectId::LostMotion
                | EffectId::Delay
                | EffectId::CurrentLag => {}
            }
        }
        b.inertia = b.inertia.max(1e-300);
        b
    }

    /// Torque needed apart from inertia and dry friction.
    fn smooth(&self, q: f64, v: f64) -> f64 {
        let mut t = self.damping * v + self.dasym * v.abs() + self.offset;
        for (w, a, c) in &self.cog {
            t += a * (w * q).sin() + c * (w * q).cos();
        }
        let (a, c, r) = self.unb;
        if a != 0.0 || c != 0.0 {
            t += a * (q / r).sin() + c * (q / r).cos();
        }
        t
    }

    fn dry(&self, v: f64) -> f64 {
        let s = v.signum();
        s * (self.fc + self.fs_extra * (-(v.abs() / self.vs).powf(self.ex)).exp()) + self.fasym
    }

    fn breakaway(&self) -> f64 {
        (self.fc + self.fs_extra).abs() + self.fasym.abs()
    }

    /// Advances (q, v) by `h` under applied torque `u`.
    fn step(&self, q: &mut f64, v: &mut f64, u: f64, h: f64) {
        let u = u.clamp(-self.limit, self.limit);
        let other = u - self.smooth(*q, *v);
        let has_dry = self.breakaway() > 0.0;
        if has_dry && v.abs() <= self.eps && other.abs() <= self.breakaway() {
            *v = 0.0;
            return;
        }
        let vdir = if v.abs() > self.eps { *v } else { other };
        let a = (other - self.dry(vdir)) / self.inertia;
        let vn = *v + h * a;
        if has_dry && v.abs() > self.eps && vn * *v < 0.0 {
            *v = 0.0;
        } else {
            *v = vn;
        }
        *q += h * *v;
    }
}

/// The plant's states that no encoder measures, per sample, for restarting a window there.
struct Hidden {
    /// The third mass's position and velocity (motor units), from the load's motion through
    /// its own spring (as in its regressor).
    third: Option<(Vec<f64>, Vec<f64>)>,
    /// The lost-motion offset (motor units), replayed from the motor's travel.
    lost: Option<Vec<f64>>,
}

/// The simulated axis: the plant simulator's, or the one-body approximation.
enum Sim {
    /// The simulator's axis, the friction dead bands of motor and load velocity, and the states
    /// no encoder measures, estimated from the measured motion (see [`Hidden`]).
    Plant(Box<AxisPlant>, f64, f64, Hidden),
    Body {
        body: Body,
        q: f64,
        v: f64,
    },
}

impl Sim {
    /// The plant simulator's axis for `model` at the trace's period, or the rigid body (with the
    /// reason) when the simulator refuses the model.
    fn new(model: &WbModel, d: &AxisData) -> (Self, String) {
        match AxisPlant::new(&model.sim_file(), d.dt) {
            Ok(p) => {
                // a third mass is not measured: its motion follows from the load's, through
                // its own spring (as in its regressor), so each window restarts it there
                let third = model
                    .effects
                    .iter()
                    .find(|e| e.id == EffectId::ThirdMass && e.hyper.len() >= 2)
                    .map(|e| {
                        let (x, v, _) = third_mass_track(d, e.hyper[0], e.hyper[1]);
                        (x, v)
                    });
                let lost = p.lost_motion_series(&d.qm);
                (
                    Sim::Plant(
                        Box::new(p),
                        dead_band(d, &d.vm),
                        dead_band(d, &d.vl),
                        Hidden { third, lost },
                    ),
                    PLANT.to_string(),
                )
            }
            Err(e) => (
                Sim::Body {
                    body: Body::new(model, d),
                    q: 0.0,
                    v: 0.0,
                },
                format!("rigid_body: the plant simulator refused the model ({e})"),
            ),
        }
    }

    /// Whether the drive's torque path (delay) is simulated inside.
    fn has_torque_path(&self) -> bool {
        matches!(self, Sim::Plant(..))
    }

    /// Restarts from the measured state at sample `k`; `past` holds the torque commands
    /// recorded before it, `load_ref` whether the body's position is the load's (closed loop).
    fn restart(&mut self, d: &AxisData, k: usize, past: &[f64], load_ref: bool) {
        let still = |v: f64, eps: f64| if v.abs() <= eps { 0.0 } else { v };
        match self {
            Sim::Plant(p, em, el, hidden) => {
                p.set_state(
                    (d.qm[k], still(d.vm[k], *em)),
                    (d.ql[k] / d.r, still(d.vl[k], *el) / d.r),
                    past,
                );
                if let Some(e) = &hidden.lost {
                    p.set_lost_motion_offset(e[k]);
                }
                if let Some((x, v)) = &hidden.third {
                    let f = if p.kind() == feedloop_model::model::AxisKind::Rigid {
                        1.0
                    } else {
                        d.r
                    };
                    p.set_third_mass_state(x[k] / f, v[k] / f);
                }
            }
            Sim::Body { q, v, .. } => {
                *q = if load_ref { d.ql[k] } else { d.qm[k] };
                *v = d.vm[k];
            }
        }
    }

    /// (motor position, motor velocity, load position), motor units.
    fn state(&self, r: f64) -> (f64, f64, f64) {
        match self {
            Sim::Plant(p, ..) => {
                let (mp, mv, lp, _) = p.true_state();
                if p.kind() == feedloop_model::model::AxisKind::Rigid {
                    (mp, mv, mp)
                } else {
                    (mp, mv, lp * r)
                }
            }
            Sim::Body { q, v, .. } => (*q, *v, *q),
        }
    }

    /// Advances one period of `dt` under torque `u`.
    fn step(&mut self, u: f64, dt: f64) {
        match self {
            Sim::Plant(p, ..) => p.step_axis(u),
            Sim::Body { body, q, v } => {
                let sub = 4;
                let h = dt / sub as f64;
                for _ in 0..sub {
                    body.step(q, v, u, h);
                }
            }
        }
    }
}

/// Runs the windowed and free-run simulations.
pub fn window_sim(model: &WbModel, d: &AxisData, window_s: f64) -> WindowSim {
    window_sim_of(model, d, window_s, true)
}

/// The windowed simulation alone (the free run's figures are those of an all-zero simulation):
/// for comparing two variants of a model at half the cost.
pub fn windowed_only(model: &WbModel, d: &AxisData, window_s: f64) -> WindowSim {
    window_sim_of(model, d, window_s, false)
}

/// [`window_sim`], with the free run only when `free`.
fn window_sim_of(model: &WbModel, d: &AxisData, window_s: f64, free: bool) -> WindowSim {
    let c = &model.file.controller;
    let closed = c.kp_per_s.is_some() && c.kv.is_some();
    let n = d.len();
    let (mut sim, plant) = Sim::new(model, d);
    let none = WindowSim {
        mode: "none",
        window_s,
        channels: vec![],
        measured: vec![],
        simulated: vec![],
        residual: vec![0.0; n],
        plant: plant.clone(),
    };
    let wlen = ((window_s / d.dt).round() as usize).clamp(2, n);
    if closed {
        let Some(y) = d.torque.as_ref() else {
            // closed loop without a recorded torque: compare the following error only
            let (fe_w, _) = run_closed(model, &mut sim, d, wlen, None);
            let (fe_f, _) = if free {
                run_closed(model, &mut sim, d, n, None)
            } else {
                (vec![0.0; n], vec![])
            };
            let meas: Vec<f64> = d.cmd.iter().zip(&d.ql).map(|(c, l)| c - l).collect();
            return finish(
                "closed_loop",
                window_s,
                d,
                plant,
                vec![("following_error", meas, fe_w, fe_f)],
            );
        };
        let (fe_w, u_w) = run_closed(model, &mut sim, d, wlen, Some(y));
        let (fe_f, u_f) = if free {
            run_closed(model, &mut sim, d, n, Some(y))
        } else {
            (vec![0.0; n], vec![0.0; n])
        };
        // the measured torque went through the zero-phase filter (parallel filtering): so do
        // the simulated ones, so that the comparison is like with like
        let (u_w, u_f) = if d.torque_filtered {
            let fs = 1.0 / d.dt;
            (
                filtfilt_butter4(&u_w, d.cutoff_hz, fs),
                filtfilt_butter4(&u_f, d.cutoff_hz, fs),
            )
        } else {
            (u_w, u_f)
        };
        let meas_fe: Vec<f64> = d.cmd.iter().zip(&d.ql).map(|(c, l)| c - l).collect();
        return finish(
            "closed_loop",
            window_s,
            d,
            plant,
            vec![
                ("torque", y.clone(), u_w, u_f),
                ("following_error", meas_fe, fe_w, fe_f),
            ],
        );
    }
    let Some(y) = d.torque.as_ref() else {
        return none;
    };
    // the simulator applies the model's torque path itself; the one-body approximation gets
    // the applied torque
    let u: Vec<f64> = if sim.has_torque_path() {
        d.torque_raw.clone().unwrap_or_else(|| y.clone())
    } else {
        model.applied(d).unwrap_or_else(|| y.clone())
    };
    let v_w = run_open(&mut sim, d, &u, wlen);
    let v_f = if free {
        run_open(&mut sim, d, &u, n)
    } else {
        vec![0.0; n]
    };
    finish(
        "open_loop",
        window_s,
        d,
        plant,
        vec![("velocity", d.vm.clone(), v_w, v_f)],
    )
}

/// (channel name, measured, windowed simulation, free run).
type SimSeries<'a> = (&'a str, Vec<f64>, Vec<f64>, Vec<f64>);

fn finish(
    mode: &'static str,
    window_s: f64,
    d: &AxisData,
    plant: String,
    ch: Vec<SimSeries<'_>>,
) -> WindowSim {
    let (a, b) = d.range;
    let mut channels = Vec::new();
    let mut head: Option<(Vec<f64>, Vec<f64>, Vec<f64>)> = None;
    for (name, meas, w, f) in ch {
        let ew: Vec<f64> = meas.iter().zip(&w).map(|(m, s)| m - s).collect();
        let ef: Vec<f64> = meas.iter().zip(&f).map(|(m, s)| m - s).collect();
        channels.push(SimChannel {
            name: name.to_string(),
            window_nrmse_pct: nrmse_pct(&meas[a..b], &ew[a..b]),
            window_rms: rms(&ew[a..b]),
            free_nrmse_pct: nrmse_pct(&meas[a..b], &ef[a..b]),
        });
        if head.is_none() {
            head = Some((meas, w, ew));
        }
    }
    let (measured, simulated, residual) = head.unwrap_or_default();
    WindowSim {
        mode,
        window_s,
        channels,
        measured,
        simulated,
        residual,
        plant,
    }
}

/// Open loop: motor velocity of the model driven by the torque `u`, restarted every `wlen`
/// samples.
fn run_open(sim: &mut Sim, d: &AxisData, u: &[f64], wlen: usize) -> Vec<f64> {
    let n = d.len();
    let mut out = vec![0.0; n];
    for k in 0..n {
        if k % wlen == 0 {
            sim.restart(d, k, &u[..k], false);
        }
        out[k] = sim.state(d.r).1;
        sim.step(u[k], d.dt);
    }
    out
}

/// The velocity-loop error of the recorded loop at sample `k`, from the measured state.
fn e_meas(d: &AxisData, k: usize, kp: f64) -> f64 {
    kp * (d.cmd[k] - d.ql[k]) - d.vm[k]
}

/// The recorded loop's integrator state at every sample (the value after that sample's update),
/// for restarting windows. Where the recorded torque is inside the output limit it follows from
/// the output (`u / kv - e) tv`, the bumpless value); where the loop sat at its limit the output
/// says nothing about it, so it is carried by the controller's own law (integration of the
/// measured error, held while the clamped output and the error point the same way) from the last
/// sample where it was known. `y` is the torque compared with the model (filtered with the
/// positions when the torque column is), `raw` the column as recorded (it tells saturation).
#[allow(clippy::too_many_arguments)]
fn integrator_track(
    d: &AxisData,
    y: &[f64],
    raw: &[f64],
    kp: f64,
    kv: f64,
    tv: f64,
    lim: f64,
    rec_lim: f64,
) -> Vec<f64> {
    let n = d.len();
    let mut out = vec![0.0; n];
    if tv <= 0.0 || kv == 0.0 {
        return out;
    }
    // a recorded output within 0.5 % of the limit it was recorded at counts as clamped
    let clamped = |u: f64| rec_lim.is_finite() && u.abs() >= (1.0 - AT_LIMIT_TOL) * rec_lim;
    let mut integ = 0.0;
    let mut known = false;
    for k in 0..n {
        let e = e_meas(d, k, kp);
        let u_rec = raw.get(k).copied().unwrap_or(y[k]);
        if !clamped(u_rec) || !known {
            integ = (y[k] / kv - e) * tv;
            known = !clamped(u_rec);
        } else {
            let prev = integ;
            integ += d.dt * e;
            let out_raw = kv * (e + integ / tv);
            if out_raw.abs() > lim && e * out_raw > 0.0 {
                integ = prev;
            }
        }
        out[k] = integ;
    }
    out
}

/// Closed loop: (following error, torque) of the model under its controller, restarted every
/// `wlen` samples from the measured state.
fn run_closed(
    model: &WbModel,
    sim: &mut Sim,
    d: &AxisData,
    wlen: usize,
    y: Option<&Vec<f64>>,
) -> (Vec<f64>, Vec<f64>) {
    let c = &model.file.controller;
    let kp = c.kp_per_s.unwrap_or(0.0);
    let kv = c.kv.unwrap_or(0.0);
    let tv = c.tv_s.unwrap_or(0.0);
    let lim = c.torque_limit.unwrap_or(f64::INFINITY);
    let n = d.len();
    let mut fe = vec![0.0; n];
    let mut tq = vec![0.0; n];
    let mut integ = 0.0;
    // torque-path delay of the model, in cycles, when the one-body approximation runs (the
    // simulator has its own delay line)
    let delay = if sim.has_torque_path() {
        0
    } else {
        model
            .effects
            .iter()
            .filter(|e| e.id == EffectId::Delay)
            .map(|e| e.hyper[0].round().max(0.0) as usize)
            .sum::<usize>()
    };
    let past: &[f64] = d.torque_raw.as_deref().unwrap_or(&[]);
    // a declared input added after the controller: applied with the controller's output, and
    // taken out of the recorded torque where that tells the controller's state
    let add: Vec<f64> = super::controller::ControllerChannel::new(model, d)
        .and_then(|c| c.scaled_input(d))
        .unwrap_or_else(|| vec![0.0; n]);
    let y_law: Option<Vec<f64>> = y.map(|y| {
        if add.iter().all(|x| *x == 0.0) {
            y.clone()
        } else if d.torque_filtered {
            let fa = filtfilt_butter4(&add, d.cutoff_hz, 1.0 / d.dt);
            y.iter().zip(&fa).map(|(a, b)| a - b).collect()
        } else {
            y.iter().zip(&add).map(|(a, b)| a - b).collect()
        }
    });
    let raw_law: Vec<f64> = past.iter().zip(&add).map(|(a, b)| a - b).collect();
    // a drive limit below the controller's (the model's torque_saturation): a record that
    // never exceeds it was recorded after the clamp, and the simulated record is clamped too
    let drive_lim = model.drive_limit().unwrap_or(f64::INFINITY);
    let rec_clamped = drive_lim < lim
        && past
            .iter()
            .all(|x| x.abs() <= (1.0 + AT_LIMIT_TOL) * drive_lim);
    let rec_lim = if rec_clamped { drive_lim } else { lim };
    let integ_meas = y_law
        .as_ref()
        .map(|y| integrator_track(d, y, &raw_law, kp, kv, tv, lim, rec_lim));
    let mut hist: Vec<f64> = Vec::new();
    for k in 0..n {
        let restart = k % wlen == 0;
        if restart {
            sim.restart(d, k, &past[..k.min(past.len())], true);
            hist.clear();
        }
        let (_, v, q) = sim.state(d.r);
        let e = kp * (d.cmd[k] - q) - v;
        if restart {
            // bumpless: the first output equals the recorded torque (and where the recorded
            // loop was at its limit, the integrator tracked through the clamped stretch)
            integ = match &integ_meas {
                Some(im) if tv > 0.0 => im[k] + (e_meas(d, k, kp) - e) * tv,
                _ => 0.0,
            };
        }
        let prev = integ;
        if !restart && tv > 0.0 {
            integ += d.dt * e;
        }
        let raw = kv * (e + if tv > 0.0 { integ / tv } else { 0.0 });
        let u = raw.clamp(-lim, lim);
        // anti-windup by conditional integration (as the velocity loop does): while the output
        // is clamped and the error pushes further into the limit, the integrator step is undone
        if u != raw && e * raw > 0.0 {
            integ = prev;
        }
        fe[k] = d.cmd[k] - q;
        tq[k] = if rec_clamped {
            u.clamp(-drive_lim, drive_lim)
        } else {
            u
        } + add[k];
        hist.push(u + add[k]);
        let applied = if hist.len() > delay {
            hist[hist.len() - 1 - delay]
        } else {
            y.map(|y| y[k.saturating_sub(delay)]).unwrap_or(0.0)
        };
        sim.step(applied, d.dt);
    }
    (fe, tq)
}
