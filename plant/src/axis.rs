//! One feed-drive axis: state, exact linear part, effects, sensor.
//!
//! The state is, in motor units, `[thM, wM, thL, wL, (th3, w3), (T_lag)]` for a 2-mass axis
//! (ballscrew, rotary) and `[x, v, (x3, v3), (T_lag)]` for a rigid axis. Each period the held
//! torque command goes through `delay`, `torque_saturation` and `current_lag`; position-dependent
//! torques (cogging, pitch error) are evaluated once at the predicted mid-period position and
//! held; then the period is integrated with exact discrete matrices, in `2^base_level` sub-steps
//! when the axis has events (dry friction, backlash). An event (velocity zero crossing, breakaway,
//! backlash contact change) inside a sub-step is located by bisection to `period / 2^(base+10)`
//! with precomputed matrices, and the mode switches there.

use std::f64::consts::PI;

use feedloop_control::axis_io::AxisSensor;
use feedloop_model::model::{AxisKind, ModelFile, PlantParams};
use feedloop_model::params::ConfigError;
use nalgebra::DMatrix;

use crate::effects::coulomb_friction::DryLaw;
use crate::effects::delay::DelayLine;
use crate::effects::{
    self, backlash, current_lag, third_mass, torque_saturation, viscous_friction, CoggingHarmonic,
    LostMotion, PitchError, Side, Unbalance, Viscous, MAX_COGGING_HARMONICS,
};
use crate::linear::{dot8, Bank, State, MAX_N, NU};
use crate::sensor::{self, Sensor};

/// Bisection depth below the base sub-step: events are located to `sub-step / 2^FINE_LEVELS`.
const FINE_LEVELS: u32 = 10;
/// Largest number of bisection halvings per period (bounds the worst-case step time).
const MAX_BISECTIONS: u32 = 96;
/// Most base sub-steps per period: `2^MAX_BASE_LEVEL`.
const MAX_BASE_LEVEL: u32 = 6;
/// Commands are clamped to this magnitude (N m or N) before anything else.
pub const TORQUE_BOUND: f64 = 1e9;

/// One body that may carry friction (the motor or the load).
#[derive(Debug, Clone, Copy)]
struct Body {
    pos: usize,
    vel: usize,
    dry: bool,
    law: DryLaw,
    /// Explicit direction-dependent viscous part: torque = -c_half |v|.
    c_half: f64,
    stuck: bool,
    dir: f64,
    /// Net torque on the body (without its own friction) = row . x + u_row . u, for spring
    /// [off, on]; the body's own velocity coefficient is zero.
    net_row: [[f64; MAX_N]; 2],
    net_u: [[f64; NU]; 2],
}

impl Body {
    fn inert(pos: usize, vel: usize) -> Self {
        Self {
            pos,
            vel,
            dry: false,
            law: DryLaw::NONE,
            c_half: 0.0,
            stuck: false,
            dir: 1.0,
            net_row: [[0.0; MAX_N]; 2],
            net_u: [[0.0; NU]; 2],
        }
    }

    /// Friction torque while sliding at velocity `v` (held over a sub-step).
    #[inline]
    fn friction(&self, v: f64) -> f64 {
        let av = v.abs();
        let mut t = viscous_friction::asymmetric_torque(self.c_half, av);
        if self.dry && !self.stuck {
            t -= self.dir * self.law.sliding_level(self.dir, av);
        }
        t
    }

    #[inline]
    fn net(&self, x: &State, spring: usize, u: &[f64; NU]) -> f64 {
        let ur = &self.net_u[spring & 1];
        dot8(&self.net_row[spring & 1], x) + ((ur[0] * u[0] + ur[1] * u[1]) + ur[2] * u[2])
    }

    #[inline]
    fn holds(&self, net: f64) -> bool {
        self.law.holds(net)
    }
}

/// Linear structure of an axis in motor units (what the matrices are built from).
#[derive(Debug, Clone, Copy)]
struct Structure {
    two_mass: bool,
    n: usize,
    /// Motor inertia (kg m^2) or rigid mass (kg).
    jm: f64,
    dm: f64,
    kl: f64,
    cl: f64,
    jl: f64,
    dl: f64,
    /// Third mass: (index of its position, inertia, stiffness, damping).
    third: Option<(usize, f64, f64, f64)>,
    /// Current lag: (state index, tau_s).
    lag: Option<(usize, f64)>,
}

impl Structure {
    fn load_idx(&self) -> (usize, usize) {
        if self.two_mass {
            (2, 3)
        } else {
            (0, 1)
        }
    }

    /// Continuous `(A, B)` with the transmission spring engaged or not.
    fn continuous(&self, spring_on: bool) -> (DMatrix<f64>, DMatrix<f64>) {
        let n = self.n;
        let mut a = DMatrix::<f64>::zeros(n, n);
        let mut b = DMatrix::<f64>::zeros(n, NU);
        let (lp, lv) = self.load_idx();
        let jload = if self.two_mass { self.jl } else { self.jm };
        a[(0, 1)] = 1.0;
        a[(1, 1)] = -self.dm / self.jm;
        b[(1, 1)] = 1.0 / self.jm;
        if self.two_mass {
            a[(2, 3)] = 1.0;
            a[(3, 3)] = -self.dl / self.jl;
            b[(3, 2)] = 1.0 / self.jl;
            if spring_on {
                let (k, c) = (self.kl, self.cl);
                a[(1, 0)] -= k / self.jm;
                a[(1, 2)] += k / self.jm;
                a[(1, 1)] -= c / self.jm;
                a[(1, 3)] += c / self.jm;
                a[(3, 0)] += k / self.jl;
                a[(3, 2)] -= k / self.jl;
                a[(3, 1)] += c / self.jl;
                a[(3, 3)] -= c / self.jl;
            }
        } else {
            b[(1, 2)] = 1.0 / self.jm;
        }
        if let Some(t) = self.third {
            third_mass::stamp(&mut a, (lp, lv), jload, t);
        }
        match self.lag {
            Some((il, tau)) => current_lag::stamp(&mut a, &mut b, il, tau, self.jm),
            None => b[(1, 0)] = 1.0 / self.jm,
        }
        (a, b)
    }

    /// Upper bound of the highest undamped natural frequency, rad/s (Gershgorin bound of the
    /// mass-normalised stiffness matrix).
    fn omega_max(&self) -> f64 {
        let mut masses = Vec::new();
        let mut springs = Vec::new();
        if self.two_mass {
            masses.extend([self.jm, self.jl]);
            springs.push((0, 1, self.kl));
        } else {
            masses.push(self.jm);
        }
        if let Some((_, j3, k3, _)) = self.third {
            let attach = masses.len() - 1;
            masses.push(j3);
            springs.push((attach, attach + 1, k3));
        }
        let m = masses.len();
        let mut k = vec![0.0; m * m];
        for &(i, j, s) in &springs {
            k[i * m + i] += s;
            k[j * m + j] += s;
            k[i * m + j] -= s;
            k[j * m + i] -= s;
        }
        let mut w2: f64 = 0.0;
        for i in 0..m {
            let row: f64 = (0..m)
                .map(|j| k[i * m + j].abs() / (masses[i] * masses[j]).sqrt())
                .sum();
            w2 = w2.max(row);
        }
        w2.sqrt()
    }
}

/// One axis of the plant: 2-mass (ballscrew, rotary) or rigid, with its effects and sensor.
///
/// Units: motor side rad, rad/s, N m (a rigid axis: m, m/s, N); load side m (ballscrew) or rad
/// (rotary). [`AxisPlant::step_axis`] and [`AxisPlant::sense_axis`] allocate nothing, take no
/// lock and never panic; a non-finite torque is treated as 0 and finite torques are clamped to
/// +-[`TORQUE_BOUND`].
#[derive(Debug, Clone)]
pub struct AxisPlant {
    kind: AxisKind,
    period_s: f64,
    motor_per_load: f64,
    load_per_motor: f64,
    st: Structure,
    x: State,
    bank: Bank,
    base_level: u32,
    events: bool,
    bodies: [Body; 2],
    nbodies: usize,
    backlash: bool,
    gap_half: f64,
    contact: i8,
    pitch: Option<PitchError>,
    /// Motor-to-load offset of the direction of travel (`lost_motion`), if any.
    lost_motion: Option<LostMotion>,
    /// Its current offset of the spring's rest point, motor units.
    lost_e: f64,
    e_m: f64,
    cogging: [CoggingHarmonic; MAX_COGGING_HARMONICS],
    ncog: usize,
    load_torque: f64,
    /// Load torque of the load angle (`unbalance`), if any.
    unbalance: Option<Unbalance>,
    lag_mean: f64,
    delay: DelayLine,
    limit: f64,
    sensor: Sensor,
    meas: AxisSensor,
    applied: f64,
    /// 1.0 at the state entries that are positions (shifted by the origin each step), else 0.0.
    pos_mask: State,
}

fn check_period(model: &ModelFile, period_s: f64) -> Result<(), ConfigError> {
    if !(period_s.is_finite() && period_s > 0.0 && period_s <= 1.0) {
        return Err(ConfigError::new(
            &model.path,
            "period_s",
            format!("the plant period must be within (0, 1] s, got {period_s}"),
        ));
    }
    Ok(())
}

impl AxisPlant {
    /// Builds an axis from its model file for a control period `period_s` (s), validating the
    /// `[effects.*]` and `[sensor]` tables. Errors name the model file and the dotted key.
    pub fn new(model: &ModelFile, period_s: f64) -> Result<Self, ConfigError> {
        Self::new_indexed(model, period_s, 0)
    }

    /// As [`AxisPlant::new`] for axis number `axis_index` of a plant: the index is mixed into
    /// the sensor noise seed so that axes sharing a model file get independent noise.
    /// Kept as one function (about 150 lines): every parameter of the model file and of its
    /// effects is converted to the integrator's units and state in one place.
    pub fn new_indexed(
        model: &ModelFile,
        period_s: f64,
        axis_index: usize,
    ) -> Result<Self, ConfigError> {
        check_period(model, period_s)?;
        let fx = effects::parse(model)?;
        let sp = sensor::parse(model)?;
        let kind = model.plant.kind();
        let motor_per_load = model.plant.motor_per_load();
        let mut st = match model.plant {
            PlantParams::BallScrew { two_mass, .. } | PlantParams::Rotary { two_mass, .. } => {
                Structure {
                    two_mass: true,
                    n: 4,
                    jm: two_mass.jm_kgm2,
                    dm: two_mass.dm_nms_per_rad + Viscous::mean(fx.viscous[0]),
                    kl: two_mass.kl_nm_per_rad,
                    cl: two_mass.cl_nms_per_rad,
                    jl: two_mass.jl_kgm2,
                    dl: two_mass.dl_nms_per_rad + Viscous::mean(fx.viscous[1]),
                    third: None,
                    lag: None,
                }
            }
            PlantParams::Rigid(r) => Structure {
                two_mass: false,
                n: 2,
                jm: r.mass_kg,
                dm: r.viscous_ns_per_m + Viscous::mean(fx.viscous[0]),
                kl: 0.0,
                cl: 0.0,
                jl: 0.0,
                dl: 0.0,
                third: None,
                lag: None,
            },
        };
        if let Some(t) = fx.third_mass {
            st.third = Some((st.n, t.inertia, t.stiffness, t.damping));
            st.n += 2;
        }
        if let Some(tau) = fx.lag_tau_s {
            st.lag = Some((st.n, tau));
            st.n += 1;
        }
        let nbodies = if st.two_mass { 2 } else { 1 };
        let (lp, lv) = st.load_idx();
        let mut bodies = [Body::inert(0, 1), Body::inert(lp, lv)];
        for (b, body) in bodies.iter_mut().enumerate().take(nbodies) {
            body.c_half = Viscous::half(fx.viscous[b]);
            if let Some(d) = fx.dry[b] {
                body.dry = true;
                body.law = DryLaw::new(d);
            }
            let inertia = if b == 0 { st.jm } else { st.jl };
            for spring in 0..2 {
                let (a, bm) = st.continuous(spring == 1);
                for c in 0..st.n {
                    body.net_row[spring][c] = if c == body.vel {
                        0.0
                    } else {
                        inertia * a[(body.vel, c)]
                    };
                }
                for c in 0..NU {
                    body.net_u[spring][c] = inertia * bm[(body.vel, c)];
                }
            }
        }
        let backlash = fx.backlash_gap.is_some();
        let events = backlash || bodies.iter().any(|b| b.dry);
        let mut base_level = 0;
        if events {
            let w = st.omega_max();
            while base_level < MAX_BASE_LEVEL
                && period_s / f64::from(1u32 << base_level) * w > PI / 4.0
            {
                base_level += 1;
            }
        }
        let modes: Vec<usize> = (0..8)
            .filter(|m| {
                (m & 1 == 0 || bodies[0].dry)
                    && (m & 2 == 0 || (nbodies > 1 && bodies[1].dry))
                    && (m & 4 == 0 || backlash)
            })
            .collect();
        let bank = Bank::new(
            st.n,
            period_s,
            base_level,
            FINE_LEVELS as usize + 1,
            &modes,
            |mode| {
                let (mut a, mut b) = st.continuous(mode & 4 == 0);
                let mut frozen = Vec::new();
                for (bit, body) in [(1, &bodies[0]), (2, &bodies[1])] {
                    if mode & bit != 0 {
                        frozen.extend([body.pos, body.vel]);
                    }
                }
                for &r in &frozen {
                    a.row_mut(r).fill(0.0);
                    b.row_mut(r).fill(0.0);
                }
                (a, b, frozen)
            },
        );
        let mut cogging = [CoggingHarmonic::ZERO; MAX_COGGING_HARMONICS];
        let ncog = fx.cogging.len().min(MAX_COGGING_HARMONICS);
        cogging[..ncog].copy_from_slice(&fx.cogging[..ncog]);
        let lag_mean = match fx.lag_tau_s {
            Some(tau) => current_lag::mean_factor(tau, period_s),
            None => 0.0,
        };
        let mut axis = Self {
            kind,
            period_s,
            motor_per_load,
            load_per_motor: 1.0 / motor_per_load,
            st,
            x: [0.0; MAX_N],
            bank,
            base_level,
            events,
            bodies,
            nbodies,
            backlash,
            gap_half: fx.backlash_gap.unwrap_or(0.0) * 0.5,
            contact: 0,
            pitch: fx.pitch,
            lost_motion: fx.lost_motion,
            lost_e: 0.0,
            e_m: 0.0,
            cogging,
            ncog,
            load_torque: fx.load_torque.unwrap_or(0.0),
            unbalance: fx.unbalance,
            lag_mean,
            delay: DelayLine::new(fx.delay_cycles),
            limit: fx.limit.unwrap_or(TORQUE_BOUND),
            sensor: Sensor::new(sp, axis_index),
            meas: AxisSensor::default(),
            applied: 0.0,
            pos_mask: [0.0; MAX_N],
        };
        axis.pos_mask[0] = 1.0;
        if st.two_mass {
            axis.pos_mask[2] = 1.0;
        }
        if let Some((i3, ..)) = st.third {
            axis.pos_mask[i3] = 1.0;
        }
        axis.set_initial_position(0.0);
        Ok(axis)
    }

    /// Axis kind.
    pub fn kind(&self) -> AxisKind {
        self.kind
    }

    /// Control period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Motor units per load unit: rad per m for a ball screw (2 pi gear / lead), else 1.
    pub fn motor_per_load(&self) -> f64 {
        self.motor_per_load
    }

    /// Number of states of the linear part (4 for 2-mass, 2 for rigid, +2 third mass, +1 lag).
    pub fn state_dim(&self) -> usize {
        self.st.n
    }

    /// Sub-steps per period used when the axis has events (1 without dry friction or backlash).
    pub fn substeps_per_period(&self) -> u32 {
        1 << self.base_level
    }

    /// Puts the axis at rest with the load at `load_pos` (m for ballscrew/rigid, rad for rotary),
    /// springs relaxed (backlash centred in its gap), dry friction sticking, the current lag and
    /// the delay line emptied. A non-finite position is taken as 0.
    pub fn set_initial_position(&mut self, load_pos: f64) {
        let lp = if load_pos.is_finite() { load_pos } else { 0.0 };
        self.x = [0.0; MAX_N];
        let th_l = lp * self.motor_per_load;
        let mut th_m = th_l;
        self.e_m = 0.0;
        self.lost_e = 0.0;
        if let Some(p) = self.pitch {
            for _ in 0..8 {
                self.e_m = p.eval(th_m / self.motor_per_load).0 * self.motor_per_load;
                th_m = th_l - self.e_m;
            }
            self.e_m = th_l - th_m;
        }
        self.x[0] = th_m;
        if self.st.two_mass {
            self.x[2] = th_l;
        }
        if let Some((i3, ..)) = self.st.third {
            self.x[i3] = th_l;
        }
        for b in &mut self.bodies {
            b.stuck = b.dry;
            b.dir = 1.0;
        }
        self.contact = 0;
        self.delay.clear();
        self.applied = 0.0;
        self.sensor.reset_position(self.x[0]);
        self.measure();
    }

    /// Puts the axis in a given state, for a simulation restarted from a measured state (the
    /// workbench's windowed simulation): motor position and velocity (rad, rad/s; m, m/s on a
    /// rigid axis), load position and velocity (m, m/s on a ball screw, rad, rad/s on a rotary
    /// axis; ignored on a rigid axis). `past_torque` holds the torque commands of the periods
    /// before, oldest first: the latest fill the delay line (missing ones count as the oldest
    /// given, or 0), the current lag's state is its response to the commands that left the
    /// delay line in the periods before (over the last 20 time constants), and without a lag
    /// the last one is the applied torque.
    ///
    /// A third mass starts at rest relative to the load with its spring relaxed; dry friction
    /// sticks on a body whose velocity is exactly 0 and slides in the direction of its velocity
    /// otherwise; the backlash contact follows from the deflection. Non-finite values are taken
    /// as 0.
    pub fn set_state(&mut self, motor: (f64, f64), load: (f64, f64), past_torque: &[f64]) {
        let fin = |v: f64| if v.is_finite() { v } else { 0.0 };
        let (mp, mv) = (fin(motor.0), fin(motor.1));
        let (lp, lv) = if self.st.two_mass {
            (
                fin(load.0) * self.motor_per_load,
                fin(load.1) * self.motor_per_load,
            )
        } else {
            (mp, mv)
        };
        self.x = [0.0; MAX_N];
        self.x[0] = mp;
        self.x[1] = mv;
        if self.st.two_mass {
            self.x[2] = lp;
            self.x[3] = lv;
        }
        if let Some((i3, ..)) = self.st.third {
            self.x[i3] = lp;
            self.x[i3 + 1] = lv;
        }
        let last = past_torque.last().copied().map(fin).unwrap_or(0.0);
        let mut applied = last;
        if let Some((il, tau)) = self.st.lag {
            // the lag's state is its response to the commands that left the delay line and the
            // limit in the past periods: run it over the last 20 time constants (before them
            // the oldest command given is taken as held)
            let m = past_torque.len();
            let dlen = self.delay.len();
            let back = ((20.0 * tau / self.period_s).ceil() as usize).min(m);
            let input = |j: usize| -> f64 {
                let v = if j >= dlen {
                    past_torque[j - dlen]
                } else {
                    past_torque.first().copied().unwrap_or(0.0)
                };
                torque_saturation::clamp(fin(v), self.limit)
            };
            let decay = (-self.period_s / tau).exp();
            let mut x = if m > 0 { input(m - back) } else { 0.0 };
            for j in m - back..m {
                let u = input(j);
                applied = current_lag::relax(u, x, self.lag_mean);
                x = current_lag::relax(u, x, decay);
            }
            self.x[il] = x;
        }
        self.delay.restore(past_torque, fin);
        self.e_m = 0.0;
        if let Some(p) = self.pitch {
            self.e_m = p.eval(mp * self.load_per_motor).0 * self.motor_per_load;
        }
        self.lost_e = 0.0;
        if let Some(l) = &self.lost_motion {
            self.lost_e = l.settled(mv);
            self.e_m += self.lost_e;
        }
        self.contact = 0;
        if self.backlash && self.st.two_mass {
            let d = self.x[0] + self.e_m - self.x[2];
            self.contact = backlash::contact(d, self.gap_half);
        }
        for b in &mut self.bodies[..self.nbodies] {
            let v = self.x[b.vel];
            b.stuck = b.dry && v == 0.0;
            b.dir = if v < 0.0 { -1.0 } else { 1.0 };
        }
        self.applied = applied;
        self.sensor.reset_position(self.x[0]);
        self.measure();
    }

    /// True state `(motor_pos, motor_vel, load_pos, load_vel)`: motor rad, rad/s (m, m/s on a
    /// rigid axis); load m, m/s (ballscrew, rigid) or rad, rad/s (rotary).
    pub fn true_state(&self) -> (f64, f64, f64, f64) {
        if self.st.two_mass {
            (
                self.x[0],
                self.x[1],
                self.x[2] * self.load_per_motor,
                self.x[3] * self.load_per_motor,
            )
        } else {
            (self.x[0], self.x[1], self.x[0], self.x[1])
        }
    }

    /// Third mass position and velocity in load units (m, m/s or rad, rad/s), if present.
    pub fn third_mass_state(&self) -> Option<(f64, f64)> {
        self.st.third.map(|(i, ..)| {
            let r = if self.st.two_mass {
                self.motor_per_load
            } else {
                1.0
            };
            (self.x[i] / r, self.x[i + 1] / r)
        })
    }

    /// The lost-motion offsets of the spring's rest point (motor units) that the recorded motor
    /// positions `motor` (motor units, one per period, oldest first) lead to from a centred
    /// start; `None` without lost motion. A window restarted from measured positions takes its
    /// offset from here ([`AxisPlant::set_lost_motion_offset`]).
    pub fn lost_motion_series(&self, motor: &[f64]) -> Option<Vec<f64>> {
        self.lost_motion.as_ref().map(|l| l.series(motor))
    }

    /// Sets the lost-motion offset (motor units, e.g. from [`AxisPlant::lost_motion_series`])
    /// after [`AxisPlant::set_state`]; no effect without lost motion or for a non-finite value.
    pub fn set_lost_motion_offset(&mut self, e: f64) {
        if self.lost_motion.is_none() || !e.is_finite() {
            return;
        }
        self.e_m += e - self.lost_e;
        self.lost_e = e;
        if self.backlash && self.st.two_mass {
            let d = self.x[0] + self.e_m - self.x[2];
            self.contact = backlash::contact(d, self.gap_half);
        }
    }

    /// Puts the third mass (if present) at position `pos` and velocity `vel` in load units
    /// (as [`AxisPlant::third_mass_state`] reports them), e.g. after [`AxisPlant::set_state`]
    /// when its motion was estimated from the measured load motion. Non-finite values leave it
    /// where it was.
    pub fn set_third_mass_state(&mut self, pos: f64, vel: f64) {
        if !(pos.is_finite() && vel.is_finite()) {
            return;
        }
        if let Some((i, ..)) = self.st.third {
            let r = if self.st.two_mass {
                self.motor_per_load
            } else {
                1.0
            };
            self.x[i] = pos * r;
            self.x[i + 1] = vel * r;
        }
    }

    /// Torque (N m) or force (N) applied to the motor during the previous period, before sensor
    /// noise (the mean over the period when a current lag is present).
    pub fn applied_torque(&self) -> f64 {
        self.applied
    }

    /// Whether dry friction on `side` is sticking now (false without dry friction there).
    /// On a rigid axis both sides name the single mass.
    pub fn is_stuck(&self, side: Side) -> bool {
        let b = side.body(self.kind);
        b < self.nbodies && self.bodies[b].dry && self.bodies[b].stuck
    }

    /// Backlash contact: +1 driving in +, -1 driving in -, 0 inside the gap (0 without backlash).
    pub fn backlash_contact(&self) -> i8 {
        if self.backlash {
            self.contact
        } else {
            0
        }
    }

    /// Stored mechanical energy, J: kinetic energy of all masses plus the elastic energy of the
    /// transmission spring (dead zone included) and of the third-mass spring. Gravity
    /// (`constant_force`) and cogging potentials are not included.
    pub fn energy_j(&self) -> f64 {
        let x = &self.x;
        let st = &self.st;
        let mut e = 0.5 * st.jm * x[1] * x[1];
        if st.two_mass {
            e += 0.5 * st.jl * x[3] * x[3];
            let d = x[0] + self.e_m - x[2];
            let dz = if self.backlash {
                backlash::stretch(d, self.gap_half)
            } else {
                d
            };
            e += 0.5 * st.kl * dz * dz;
        }
        if let Some((i3, j3, k3, _)) = st.third {
            let (lp, _) = st.load_idx();
            let s = x[lp] - x[i3];
            e += 0.5 * j3 * x[i3 + 1] * x[i3 + 1] + 0.5 * k3 * s * s;
        }
        e
    }

    /// The measurement of the current time (sensor model applied): motor_pos, motor_vel,
    /// load_pos, applied_torque. It is formed once per period (at construction, at
    /// [`AxisPlant::set_initial_position`] and at the end of each step), so calling this twice
    /// returns the same sample.
    #[inline]
    pub fn sense_axis(&self) -> AxisSensor {
        self.meas
    }

    /// Advances one period with `torque` (N m, or N on a rigid axis) held constant.
    #[inline]
    pub fn step_axis(&mut self, torque: f64) {
        let mut u = if torque.is_finite() {
            torque.clamp(-TORQUE_BOUND, TORQUE_BOUND)
        } else {
            0.0
        };
        u = self.delay.push(u);
        u = torque_saturation::clamp(u, self.limit);
        self.applied = match self.st.lag {
            Some((il, _)) => current_lag::relax(u, self.x[il], self.lag_mean),
            None => u,
        };
        let before = self.x;
        let (bm, bl, pt) = self.held_torques();
        // Integrate in coordinates relative to the motor position at the period start: the
        // dynamics only see position differences, and this keeps an axis at rest far from the
        // origin exactly at rest and the spring deflection free of cancellation error.
        let origin = self.x[0];
        // x - origin * 1 = x - origin and x - origin * 0 = x exactly (origin is finite: a
        // non-finite state never survives a step), and the whole-array form has no branches.
        for (v, m) in self.x.iter_mut().zip(&self.pos_mask) {
            *v -= origin * m;
        }
        if self.events {
            self.integrate(u, bm, bl, pt);
        } else {
            // No events: one exact step with the held inputs (and the explicit asymmetric
            // viscous part, if any).
            let fm = self.bodies[0].friction(self.x[1]);
            let fl = self.bodies[1].friction(self.x[self.bodies[1].vel]);
            let (um, ul) = self.spring_inputs(bm, bl, pt);
            let fl = if self.nbodies > 1 { fl } else { 0.0 };
            self.x = self.bank.step(0, 0, &self.x, &[u, um + fm, ul + fl]);
        }
        // A NaN or an infinity anywhere makes the pairwise sum non-finite (a finite sum of
        // finite entries needs no check of its own: every entry is far below f64::MAX / 8).
        // It runs on the relative state as the integrator stored it (whole-array stores), before
        // the scalar stores below: loading just-stored scalars as vectors would stall.
        let x = &self.x;
        let sum = ((x[0] + x[1]) + (x[2] + x[3])) + ((x[4] + x[5]) + (x[6] + x[7]));
        let finite = (sum + origin).is_finite();
        for (v, m) in self.x.iter_mut().zip(&self.pos_mask) {
            *v += origin * m;
        }
        if !finite {
            self.recover(before);
        }
        self.measure();
    }

    fn recover(&mut self, before: State) {
        self.x = if before.iter().all(|v| v.is_finite()) {
            before
        } else {
            [0.0; MAX_N]
        };
        for b in &self.bodies {
            self.x[b.vel] = 0.0;
        }
        if let Some((i3, ..)) = self.st.third {
            self.x[i3 + 1] = 0.0;
        }
        if let Some((il, _)) = self.st.lag {
            self.x[il] = 0.0;
        }
    }

    #[inline]
    fn measure(&mut self) {
        let (mp, mv, lp, _) = self.true_state();
        self.meas = self
            .sensor
            .measure([mp, mv, lp, self.applied], self.period_s);
    }

    /// Cogging torque on the motor, the load torque (constant and of the load angle), and the
    /// pitch-error spring torque, evaluated at the predicted mid-period position and held over
    /// the period.
    #[inline]
    fn held_torques(&mut self) -> (f64, f64, f64) {
        let th_mid = self.x[0] + 0.5 * self.period_s * self.x[1];
        let mut tm = 0.0;
        for c in &self.cogging[..self.ncog] {
            tm += c.torque(th_mid);
        }
        let mut pt = 0.0;
        if let Some(p) = &self.pitch {
            (self.e_m, pt) = p.held(
                th_mid,
                self.x[1],
                (self.load_per_motor, self.motor_per_load),
                (self.st.kl, self.st.cl),
            );
        }
        if let Some(l) = &self.lost_motion {
            self.lost_e = l.advance(self.lost_e, self.x[1], self.period_s);
            let e = self.lost_e;
            self.e_m = if self.pitch.is_some() {
                self.e_m + e
            } else {
                e
            };
            pt += self.st.kl * e;
        }
        let mut lt = self.load_torque;
        if let Some(u) = &self.unbalance {
            let (lp, lv) = self.st.load_idx();
            let th_l_mid = self.x[lp] + 0.5 * self.period_s * self.x[lv];
            lt += u.torque(th_l_mid * self.load_per_motor);
        }
        (tm, lt, pt)
    }

    #[inline]
    fn spring_on(&self) -> bool {
        !self.backlash || self.contact != 0
    }

    /// Motor- and load-side held torques (without friction) for the current contact state.
    #[inline]
    fn spring_inputs(&self, bm: f64, bl: f64, pt: f64) -> (f64, f64) {
        let rem = if !self.backlash {
            pt
        } else {
            backlash::held_spring(self.contact, pt, self.st.kl, self.gap_half)
        };
        (bm - rem, bl + rem)
    }

    #[inline]
    fn mode(&self) -> usize {
        usize::from(self.bodies[0].stuck)
            | usize::from(self.bodies[1].stuck) << 1
            | usize::from(self.backlash && self.contact == 0) << 2
    }

    /// Whether the state `y`, reached in the current mode, is consistent with that mode.
    #[inline]
    fn consistent(&self, y: &State, u: &[f64; NU]) -> bool {
        let spring = usize::from(self.spring_on());
        for b in &self.bodies[..self.nbodies] {
            if !b.dry {
                continue;
            }
            if b.stuck {
                if !b.holds(b.net(y, spring, u)) {
                    return false;
                }
            } else if b.dir * y[b.vel] < 0.0 {
                return false;
            }
        }
        if self.backlash {
            let d = y[0] + self.e_m - y[2];
            if !backlash::consistent(self.contact, d, self.gap_half) {
                return false;
            }
        }
        true
    }

    /// Whether the period start needs a stick/slip decision or a contact re-classification:
    /// a sticking body (the new torque may break it away), a sliding body at exactly zero
    /// velocity, or a pitch error (it moves the backlash flanks with position).
    #[inline]
    fn needs_settle(&self) -> bool {
        let settle = |b: &Body| b.dry && (b.stuck || self.x[b.vel] == 0.0);
        self.pitch.is_some()
            || (self.lost_motion.is_some() && self.backlash)
            || settle(&self.bodies[0])
            || (self.nbodies > 1 && settle(&self.bodies[1]))
    }

    /// Re-classifies backlash contact and decides stick/slip of every dry body at the current
    /// state.
    fn transition(&mut self, u: f64, bm: f64, bl: f64, pt: f64) {
        if self.backlash {
            let d = self.x[0] + self.e_m - self.x[2];
            self.contact = backlash::contact(d, self.gap_half);
        }
        let (um, ul) = self.spring_inputs(bm, bl, pt);
        let uu = [u, um, ul];
        let spring = usize::from(self.spring_on());
        for i in 0..self.nbodies {
            let b = self.bodies[i];
            if !b.dry {
                continue;
            }
            if b.stuck {
                let net = b.net(&self.x, spring, &uu);
                if !b.holds(net) {
                    self.bodies[i].stuck = false;
                    self.bodies[i].dir = if net > 0.0 { 1.0 } else { -1.0 };
                }
            } else if b.dir * self.x[b.vel] <= 0.0 {
                self.x[b.vel] = 0.0;
                let net = b.net(&self.x, spring, &uu);
                if b.holds(net) {
                    self.bodies[i].stuck = true;
                } else {
                    self.bodies[i].dir = if net > 0.0 { 1.0 } else { -1.0 };
                }
            }
        }
    }

    /// Integrates one period with held inputs, locating events by bisection.
    #[inline]
    fn integrate(&mut self, u: f64, bm: f64, bl: f64, pt: f64) {
        let base_piece: u32 = 1 << FINE_LEVELS;
        let mut remaining: u32 = base_piece << self.base_level;
        let mut piece = base_piece;
        let mut budget = MAX_BISECTIONS;
        if self.events && self.needs_settle() {
            self.transition(u, bm, bl, pt);
        }
        let (mut um, mut ul) = self.spring_inputs(bm, bl, pt);
        while remaining > 0 {
            let fm = self.bodies[0].friction(self.x[1]);
            let fl = if self.nbodies > 1 {
                self.bodies[1].friction(self.x[self.bodies[1].vel])
            } else {
                0.0
            };
            let inputs = [u, um + fm, ul + fl];
            let level = (FINE_LEVELS - piece.trailing_zeros()) as usize;
            let y = self.bank.step(self.mode(), level, &self.x, &inputs);
            let ok = !self.events || self.consistent(&y, &[u, um, ul]);
            if ok || piece <= 1 || budget == 0 {
                self.x = y;
                remaining = remaining.saturating_sub(piece);
                if !ok {
                    self.transition(u, bm, bl, pt);
                    (um, ul) = self.spring_inputs(bm, bl, pt);
                }
                if remaining > 0 {
                    piece = (1u32 << remaining.trailing_zeros()).min(base_piece);
                }
            } else {
                piece >>= 1;
                budget -= 1;
            }
        }
    }
}
