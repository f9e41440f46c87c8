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
use feedloop_model::model::{AxisKind, ModelFile};
use feedloop_model::params::ConfigError;

mod body;
mod step;
mod structure;

use crate::effects::delay::DelayLine;
use crate::effects::{
    self, backlash, current_lag, torque_saturation, CoggingHarmonic, LostMotion, PitchError, Side,
    Unbalance, MAX_COGGING_HARMONICS,
};
use crate::linear::{Bank, State, MAX_N};
use crate::sensor::{self, Sensor};

use body::{bodies, Body};
use structure::Structure;

/// Bisection depth below the base sub-step: events are located to `sub-step / 2^FINE_LEVELS`.
const FINE_LEVELS: u32 = 10;
/// Largest number of bisection halvings per period (bounds the worst-case step time).
const MAX_BISECTIONS: u32 = 96;
/// Most base sub-steps per period: `2^MAX_BASE_LEVEL`.
const MAX_BASE_LEVEL: u32 = 6;
/// Commands are clamped to this magnitude (N m or N) before anything else.
pub const TORQUE_BOUND: f64 = 1e9;

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
        let st = Structure::of(&model.plant, &fx);
        let (bodies, nbodies) = bodies(&st, &fx);
        let backlash = fx.backlash_gap.is_some();
        let events = backlash || bodies.iter().any(|b| b.dry);
        let base_level = if events { base_level(&st, period_s) } else { 0 };
        let bank = mode_bank(&st, &bodies, nbodies, backlash, period_s, base_level);
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

    #[inline]
    fn measure(&mut self) {
        let (mp, mv, lp, _) = self.true_state();
        self.meas = self
            .sensor
            .measure([mp, mv, lp, self.applied], self.period_s);
    }
}

/// Sub-step level of an axis with events: halved until the fastest mode turns by at most
/// pi / 4 per sub-step (at most `2^MAX_BASE_LEVEL` sub-steps).
fn base_level(st: &Structure, period_s: f64) -> u32 {
    let mut base_level = 0;
    let w = st.omega_max();
    while base_level < MAX_BASE_LEVEL && period_s / f64::from(1u32 << base_level) * w > PI / 4.0 {
        base_level += 1;
    }
    base_level
}

/// The exact discrete matrices of every mode the axis can be in: bit 0 the motor stuck, bit 1
/// the load stuck, bit 2 the backlash open (spring off); a stuck body's rows are frozen.
fn mode_bank(
    st: &Structure,
    bodies: &[Body; 2],
    nbodies: usize,
    backlash: bool,
    period_s: f64,
    base_level: u32,
) -> Bank {
    let modes: Vec<usize> = (0..8)
        .filter(|m| {
            (m & 1 == 0 || bodies[0].dry)
                && (m & 2 == 0 || (nbodies > 1 && bodies[1].dry))
                && (m & 4 == 0 || backlash)
        })
        .collect();
    Bank::new(
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
    )
}
