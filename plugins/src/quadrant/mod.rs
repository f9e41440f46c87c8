//! `quadrant_compensator`: learned reversal (quadrant-crossing) compensation by dynamic pulse
//! models (seed 004, steps (2)-(3) and claims 2-3: compensation sequences generated with
//! acceleration planning, the rise/fall split of each model allocated freely).
//!
//! At a reversal of the commanded velocity the axis lags: friction flips sign and the loop needs
//! time to rebuild the torque. The following error e = th - thL (load units, m or rad) then shows
//! a spike: it leaves zero at a start point, reaches a maximum and returns at an end point (and
//! with Stribeck friction it already drifts during the approach, as the speed falls). Each
//! learned pulse is a position offset delta(tau) (load units) over tau = t - t_r, the time since
//! the reversal, made of two acceleration-planned models:
//!
//! - start -> max (rise, split a): delta = A s(u; a), u = (tau - t_s) / (t_m - t_s);
//! - max -> end (fall, split b): delta = A (1 - s(u; b)), u = (tau - t_m) / (t_e - t_m);
//! - `profile = "constant_acceleration"` ([`planned_rise`]): s(u; a) = u^2 / a for u <= a,
//!   1 - (1 - u)^2 / (1 - a) above: a velocity that rises with constant acceleration until the
//!   split, then falls with constant deceleration to zero;
//! - `profile = "sine_acceleration"` ([`sine_rise`], what the learner writes): the velocity
//!   rises to its peak at the split with acceleration (4/a) sin^2(pi u / a) and falls the same
//!   way, so acceleration and jerk are continuous.
//!
//! The offset is fed forward like an extra reference the load must follow, through the axis'
//! 2-mass inverse (as `inverse_feedforward`'s split structure plays the trajectory): the motor
//! leads the load by the twist (JL/KL) delta'', so the velocity command gets
//! w = g (Kp delta + delta' + (JL/KL) delta''') and the torque g (J delta'' + JM (JL/KL) delta'''')
//! (J = JM + JL, or the mass; converted to motor units). With the loop following its references
//! exactly the learned error is cancelled exactly (a linear plant; friction makes it only
//! approximately so, hence the passes). Played as a rigid body instead, the steps of a
//! constant-acceleration pulse wind up the screw and the table rings against the motor (on the
//! X-Y table's screw, 159 Hz, up to 174 nm after a 761 nm pulse); a constant-acceleration pulse
//! has zero jerk between its joints, so old tables play exactly as they did.
//! With `inject = "torque"` the velocity part is turned into the torque the PI velocity loop
//! would have produced from it, torque_ff += Kv (w + (1/Tv) int w dt).
//! Pulses of every learning pass add up (see `feedloop_analysis::learn::quadrant`, which finds
//! the points and fits the models by least squares, the splits by bisection; learning runs
//! offline, never in the scheduler).
//!
//! Trigger: the sign change of the commanded velocity (`reference[1]`, |v| <= 1 nm/s counting as
//! rest); the reversal instant t_r is interpolated between the two samples (`ReversalDetector`,
//! shared with the learner so both use the same clock). A reversal to positive velocity plays
//! the table's `to_positive` pulses, one to negative the `to_negative` pulses. Pulses with
//! `start_s < 0` (the approach) start before the crossing: while no reversal plays, t_r is
//! predicted from the reference velocity, acceleration and jerk ([`time_to_reversal`]) once it
//! is at most the earliest `-start_s` away; the detected crossing then takes over. A predicted
//! reversal that has not come two periods after its instant (the axis stopped) is dropped.
//!
//! Keys: `table` (path of the learned table, relative to the job file; required), `gain`
//! (dimensionless, default 1), `kp_per_s` (1/s, default the model's), `inject` (`"velocity"`
//! default, or `"torque"` with `kv_nms_per_rad` / `kv_ns_per_m` and `tv_s` defaulting to the
//! model's `[controller]`), `inertia_kgm2` (`mass_kg` on a rigid axis; default the model's
//! JM + JL or mass), `jl_kgm2` and `kl_nm_per_rad` (the twist JL/KL; default the model's, 0 on a
//! rigid axis), `axis` (which axis entry of the table to play, default this axis' name).
//! The table's file format is in [`table`].
pub mod table;

pub use table::{AxisPulses, QuadrantTable, MAX_PULSES, TABLE_FORMAT};

use std::path::{Path, PathBuf};

use feedloop_control::controller::{
    AxisContext, AxisSignals, Controller, ControllerState, CycleContext, Stage,
};
use feedloop_model::params::{ConfigError, Fields, Range};

pub mod backlash;

use crate::friction_feedforward::FrictionCurve;
use crate::keys::{key_for, read_kp, read_pi_gains, PiGains};
use crate::plugin::{axis_plugin, reference_only_plugin, AxisPlugin, PluginParams};
use backlash::BacklashPulse;

/// Commanded velocities at or below this magnitude count as rest, load units/s (1 nm/s).
pub const REST_VELOCITY: f64 = 1e-9;

/// Direction of the commanded velocity after a reversal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Direction {
    /// Negative -> positive.
    ToPositive,
    /// Positive -> negative.
    ToNegative,
}

impl Direction {
    /// Both directions.
    pub const ALL: [Direction; 2] = [Direction::ToPositive, Direction::ToNegative];

    /// Name in table files.
    pub fn id(self) -> &'static str {
        match self {
            Direction::ToPositive => "to_positive",
            Direction::ToNegative => "to_negative",
        }
    }

    /// 0 for `ToPositive`, 1 for `ToNegative`.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// A detected reversal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reversal {
    /// Interpolated instant of the zero crossing, s.
    pub t_s: f64,
    /// New direction.
    pub direction: Direction,
}

/// Finds sign changes of a sampled commanded velocity (load units/s). Samples with
/// |v| <= [`REST_VELOCITY`] count as zero and keep the previous sign (so rounding noise of a
/// command at rest is no reversal); a run that starts from rest has no reversal until the
/// velocity changes sign.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ReversalDetector {
    sign: i8,
    last_v: f64,
    last_t: f64,
}

impl ReversalDetector {
    /// A detector that has seen nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// A detector whose last sample was `v` at `t_s`.
    pub fn at(t_s: f64, v: f64) -> Self {
        let mut d = Self::new();
        d.update(t_s, v);
        d
    }

    /// Feeds the sample `v` (velocity) at `t_s`; returns the reversal it completes, if any.
    #[inline]
    pub fn update(&mut self, t_s: f64, v: f64) -> Option<Reversal> {
        if !(v.is_finite() && t_s.is_finite()) {
            return None;
        }
        let s: i8 = if v > REST_VELOCITY {
            1
        } else if v < -REST_VELOCITY {
            -1
        } else {
            0
        };
        let mut out = None;
        if s != 0 {
            if self.sign != 0 && s != self.sign {
                let dv = self.last_v - v;
                let frac = if dv != 0.0 {
                    (self.last_v / dv).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let t_r = if self.last_t.is_finite() {
                    self.last_t + frac * (t_s - self.last_t)
                } else {
                    t_s
                };
                out = Some(Reversal {
                    t_s: t_r,
                    direction: if s > 0 {
                        Direction::ToPositive
                    } else {
                        Direction::ToNegative
                    },
                });
            }
            self.sign = s;
        }
        self.last_v = v;
        self.last_t = t_s;
        out
    }
}

/// Time until the commanded velocity `v` (acceleration `a`, jerk `j`; load units) crosses zero,
/// s, and the direction it will then have; `None` unless it is moving and decelerating. The root
/// of v + a t + j t^2 / 2 nearest to -v/a (two Newton steps from there).
#[inline]
pub fn time_to_reversal(v: f64, a: f64, j: f64) -> Option<(f64, usize)> {
    if !(v.abs() > REST_VELOCITY && a.is_finite() && j.is_finite()) || v * a >= 0.0 {
        return None;
    }
    let mut t = -v / a;
    for _ in 0..2 {
        let slope = a + j * t;
        if slope * a <= 0.0 {
            break;
        }
        t -= (v + a * t + 0.5 * j * t * t) / slope;
    }
    let d = if v > 0.0 {
        Direction::ToNegative
    } else {
        Direction::ToPositive
    };
    (t.is_finite() && t >= 0.0).then_some((t, d.index()))
}

/// Normalised acceleration-planned rise s(u; split) on u in [0, 1], its slope ds/du and its
/// curvature d2s/du2 (constant acceleration 2/split, then constant deceleration): the
/// [`Profile::ConstantAcceleration`] rise.
#[inline]
pub fn planned_rise(u: f64, split: f64) -> (f64, f64, f64) {
    let u = u.clamp(0.0, 1.0);
    if u <= split {
        (u * u / split, 2.0 * u / split, 2.0 / split)
    } else {
        let w = 1.0 - u;
        (
            1.0 - w * w / (1.0 - split),
            2.0 * w / (1.0 - split),
            -2.0 / (1.0 - split),
        )
    }
}

/// Normalised rise with sine-squared acceleration on u in [0, 1] and its first four derivatives
/// (the [`Profile::SineAcceleration`] rise): the velocity ds/du rises from 0 to its peak 2 at
/// `split` with acceleration (4/a) sin^2(pi u / a), a = split, then falls back to 0 at u = 1 the
/// same way over 1 - a. Velocity, acceleration and jerk are continuous everywhere (zero at both
/// ends and at the split), so the pulse can be played through the 2-mass inverse (its twist
/// needs the jerk, its torque the fourth derivative).
#[inline]
pub fn sine_rise(u: f64, split: f64) -> [f64; 5] {
    use std::f64::consts::TAU;
    let u = u.clamp(0.0, 1.0);
    if u <= split {
        let a = split;
        let p = TAU / a;
        let (sn, cs) = (p * u).sin_cos();
        let k = 2.0 / a;
        [
            k * (0.5 * u * u - (1.0 - cs) / (p * p)),
            k * (u - sn / p),
            k * (1.0 - cs),
            k * p * sn,
            k * p * p * cs,
        ]
    } else {
        let b = 1.0 - split;
        let w = 1.0 - u;
        let q = TAU / b;
        let (sn, cs) = (q * w).sin_cos();
        let k = 2.0 / b;
        [
            1.0 - k * (0.5 * w * w - (1.0 - cs) / (q * q)),
            k * (w - sn / q),
            -k * (1.0 - cs),
            k * q * sn,
            -k * q * q * cs,
        ]
    }
}

/// How a pulse's rise and fall models move between 0 and 1 (both acceleration-planned: the
/// velocity peaks at the model's split).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Profile {
    /// Constant acceleration up to the split, constant deceleration after ([`planned_rise`]).
    /// Its acceleration jumps, so the spring of a 2-mass axis rings after every joint; tables
    /// written before 2026-11-25 hold only this profile (the default when `profile` is absent).
    #[default]
    ConstantAcceleration,
    /// Sine-squared acceleration and deceleration ([`sine_rise`]): continuous acceleration and
    /// jerk, so the compensator can play the pulse through the 2-mass inverse.
    SineAcceleration,
}

impl Profile {
    /// Both profiles.
    pub const ALL: [Profile; 2] = [Profile::ConstantAcceleration, Profile::SineAcceleration];

    /// Name in table files.
    pub fn id(self) -> &'static str {
        match self {
            Profile::ConstantAcceleration => "constant_acceleration",
            Profile::SineAcceleration => "sine_acceleration",
        }
    }

    /// The profile named `id`.
    pub fn from_id(id: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.id() == id)
    }

    /// Normalised rise s(u; split) and its first four derivatives by u (for the constant
    /// acceleration the third and fourth are zero between the joints).
    #[inline]
    pub fn rise(self, u: f64, split: f64) -> [f64; 5] {
        match self {
            Profile::ConstantAcceleration => {
                let (s, ds, dds) = planned_rise(u, split);
                [s, ds, dds, 0.0, 0.0]
            }
            Profile::SineAcceleration => sine_rise(u, split),
        }
    }
}

/// One learned compensation pulse: a rise model and a fall model (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pulse {
    /// Learning pass that added it (1-based).
    pub pass: u32,
    /// Start of the rise model, s after the reversal.
    pub start_s: f64,
    /// Peak: end of the rise, start of the fall, s.
    pub peak_s: f64,
    /// End of the fall model, s.
    pub end_s: f64,
    /// Velocity-peak position of the rise model, fraction of its span (0..1).
    pub rise_split: f64,
    /// Velocity-peak position of the fall model, fraction of its span (0..1).
    pub fall_split: f64,
    /// Offset at the peak, load units (m or rad).
    pub amplitude: f64,
    /// Shape of the rise and fall models.
    pub profile: Profile,
}

impl Pulse {
    /// Shape (offset / amplitude) and its first four time derivatives at `tau` s after the
    /// reversal.
    #[inline]
    pub fn shape(&self, tau: f64) -> [f64; 5] {
        if tau <= self.start_s || tau >= self.end_s {
            return [0.0; 5];
        }
        let scaled = |r: [f64; 5], span: f64, sign: f64| {
            let mut out = [0.0; 5];
            let mut f = 1.0;
            for (o, x) in out.iter_mut().zip(r) {
                *o = sign * x * f;
                f /= span;
            }
            out
        };
        if tau < self.peak_s {
            let span = self.peak_s - self.start_s;
            let r = self
                .profile
                .rise((tau - self.start_s) / span, self.rise_split);
            scaled(r, span, 1.0)
        } else {
            let span = self.end_s - self.peak_s;
            if span <= 0.0 {
                return [0.0; 5];
            }
            let r = self
                .profile
                .rise((tau - self.peak_s) / span, self.fall_split);
            let mut out = scaled(r, span, -1.0);
            out[0] += 1.0;
            out
        }
    }

    /// Offset (load units) and its first four time derivatives (load units/s, /s^2, /s^3,
    /// /s^4) at `tau` s after the reversal.
    #[inline]
    pub fn eval(&self, tau: f64) -> [f64; 5] {
        self.shape(tau).map(|x| self.amplitude * x)
    }
}

/// How the compensation enters the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Injection {
    /// Added to the velocity command.
    Velocity,
    /// Added to `torque_ff` as the PI velocity loop (gain `kv`, integral time `tv_s`) would turn
    /// the same velocity into torque.
    Torque {
        /// Velocity loop gain, N m s/rad (N s/m).
        kv: f64,
        /// Integral time, s (0 = proportional).
        tv_s: f64,
    },
}

/// Parameters of [`QuadrantCompensator`].
#[derive(Debug, Clone, PartialEq)]
pub struct QuadrantParams {
    /// The table file (resolved against the job file's folder).
    pub table_path: PathBuf,
    /// The pulses played on this axis.
    pub pulses: AxisPulses,
    /// Injection gain, dimensionless.
    pub gain: f64,
    /// Position loop gain used to turn an offset into a velocity, 1/s.
    pub kp_per_s: f64,
    /// Motor units per load unit.
    pub motor_per_load: f64,
    /// Where it is injected.
    pub inject: Injection,
    /// Inertia (kg m^2) or mass (kg) the motor accelerates, for the torque J delta''.
    pub inertia: f64,
    /// Load-side inertia over the screw stiffness, JL / KL, s^2 (0 on a rigid axis): the motor
    /// leads the load by the twist (JL/KL) delta'' (about 1e-6 s^2 on the X-Y table).
    pub twist_s2: f64,
    /// Load-side inertia JL, kg m^2 (0 on a rigid axis).
    pub load_inertia: f64,
    /// A measured friction curve played under the pulses (the keys of `friction_feedforward`'s
    /// curve, `fc_nm` first), when given.
    pub friction: Option<FrictionCurve>,
    /// The backlash crossed at each reversal (`backlash_m`, load units, over `backlash_s`),
    /// when given.
    pub backlash: Option<BacklashPulse>,
}

impl PluginParams for QuadrantParams {
    /// Reads the plugin keys and loads the table (`file` is the job file).
    fn read(mut f: Fields<'_>, axis: &AxisContext, file: &Path) -> Result<Self, ConfigError> {
        let table_rel = f.str("table")?;
        let gain = f.f64_or("gain", Range::Within(0.0, 10.0), 1.0)?;
        let kp = read_kp(&mut f)?;
        let which = f.opt_str("axis")?.unwrap_or(axis.name.as_str()).to_string();
        let inject = f.opt_str("inject")?.unwrap_or("velocity");
        let PiGains { kv_key, kv, tv } = read_pi_gains(&mut f, axis.plant.kind())?;
        let inertia_key = key_for(axis.plant.kind(), "mass_kg", "inertia_kgm2");
        let inertia = f.f64_or(
            inertia_key,
            Range::Within(0.0, 1e9),
            axis.plant.total_inertia(),
        )?;
        let two_mass = axis.plant.two_mass();
        let jl = f.f64_or(
            "jl_kgm2",
            Range::Within(0.0, 1e9),
            two_mass.map_or(0.0, |t| t.jl_kgm2),
        )?;
        let kl = f.opt_f64("kl_nm_per_rad", Range::Within(1e-9, 1e15))?;
        let kl = kl.or(two_mass.map(|t| t.kl_nm_per_rad));
        let twist_s2 = match kl {
            Some(kl) if kl.is_finite() && kl > 0.0 => jl / kl,
            _ => 0.0,
        };
        if twist_s2 > 0.0 && jl > inertia {
            return Err(f.error(
                "jl_kgm2",
                format!("must not exceed the total inertia {inertia_key} = {inertia}, got {jl}"),
            ));
        }
        let inject = match inject {
            "velocity" => Injection::Velocity,
            "torque" => Injection::Torque {
                kv: kv.or(axis.defaults.kv).ok_or_else(|| {
                    f.error(
                        kv_key,
                        "is required by `inject = \"torque\"` (not in the model either)",
                    )
                })?,
                tv_s: tv.or(axis.defaults.tv_s).unwrap_or(0.0),
            },
            other => {
                return Err(f.error(
                    "inject",
                    format!("unknown injection `{other}` (velocity, torque)"),
                ))
            }
        };
        let friction = match f.opt_f64("fc_nm", Range::Within(0.0, 1e6))? {
            Some(fc) => {
                Some(FrictionCurve::read(&mut f, fc)?.unwrap_or(FrictionCurve::coulomb(fc)))
            }
            None => None,
        };
        let gap = f.f64_or("backlash_m", Range::Within(0.0, 1.0), 0.0)?;
        let gap_s = f.f64_or("backlash_s", Range::Within(1e-4, 1.0), 0.002)?;
        let lead_s = f.f64_or("backlash_lead_s", Range::Within(0.0, 1.0), 0.0)?;
        f.finish()?;
        let backlash = (gap > 0.0).then(|| BacklashPulse {
            gap_motor: gap * axis.plant.motor_per_load(),
            duration_s: gap_s,
            jm: (inertia - jl).max(0.0),
            lead_s: lead_s.min(gap_s),
        });
        let kp_per_s = axis.param_or_model(kp, axis.defaults.kp_per_s, "kp_per_s", file)?;
        let dir = file.parent().unwrap_or(Path::new("."));
        let table_path = dir.join(table_rel);
        if !table_path.exists() {
            return Err(ConfigError::new(
                file,
                "table",
                format!(
                    "table file {} does not exist (learn one with `feedloop learn quadrant`)",
                    table_path.display()
                ),
            ));
        }
        let table = QuadrantTable::load(&table_path)?;
        let pulses = table.axes.get(&which).cloned().unwrap_or_default();
        Ok(Self {
            table_path,
            pulses,
            gain,
            kp_per_s,
            motor_per_load: axis.plant.motor_per_load(),
            inject,
            inertia,
            twist_s2,
            load_inertia: jl,
            friction,
            backlash,
        })
    }
}

impl QuadrantParams {
    /// The motor-side inertia JM = J - JL (kg m^2; the mass on a rigid axis).
    pub fn motor_inertia(&self) -> f64 {
        if self.twist_s2 > 0.0 {
            (self.inertia - self.load_inertia).max(0.0)
        } else {
            self.inertia
        }
    }
}

/// The quadrant compensator.
#[derive(Debug, Clone)]
pub struct QuadrantCompensator {
    params: QuadrantParams,
    /// Pulses per direction (index `Direction::index`).
    pulses: [Vec<Pulse>; 2],
    /// Latest end time per direction, s.
    horizon: [f64; 2],
    detector: ReversalDetector,
    /// Reversal being played: (t_r, direction index).
    active: Option<(f64, usize)>,
    /// `active` is an anticipated reversal (t_r predicted from the reference), not yet seen.
    predicted: bool,
    /// How long before the reversal the earliest pulse starts, per direction, s (>= 0).
    lead: [f64; 2],
    /// Integral of the injected velocity (torque injection), motor units.
    integral: f64,
    /// Backlash crossing in progress: (start, sign of the new direction times the share of the
    /// gap it crosses, 1 but for the return of an anticipated crossing).
    crossing: Option<(f64, f64)>,
    /// The predicted reversal instant of a crossing started ahead of it, until the reversal
    /// is seen, s.
    crossing_ahead: Option<f64>,
}

axis_plugin!(
    QuadrantCompensator,
    QuadrantParams,
    "quadrant_compensator",
    Stage::Compensator
);

impl QuadrantCompensator {
    /// Plugin id ([`AxisPlugin::ID`], for callers without the trait in scope).
    pub const ID: &'static str = <Self as AxisPlugin>::ID;

    /// Builds the compensator.
    pub fn new(params: QuadrantParams) -> Self {
        let pulses = [
            params.pulses.to_positive.clone(),
            params.pulses.to_negative.clone(),
        ];
        let horizon = [0, 1].map(|i| pulses[i].iter().map(|p| p.end_s).fold(0.0, f64::max));
        let lead = [0, 1].map(|i| pulses[i].iter().map(|p| -p.start_s).fold(0.0, f64::max));
        Self {
            params,
            pulses,
            horizon,
            detector: ReversalDetector::new(),
            active: None,
            predicted: false,
            lead,
            integral: 0.0,
            crossing: None,
            crossing_ahead: None,
        }
    }

    /// Parameters.
    pub fn params(&self) -> &QuadrantParams {
        &self.params
    }

    /// Offset (load units) and its first four derivatives at `t_s`, given the active reversal.
    #[inline]
    fn offset(&self, t_s: f64) -> [f64; 5] {
        let mut sum = [0.0; 5];
        let Some((t_r, d)) = self.active else {
            return sum;
        };
        let tau = t_s - t_r;
        for p in &self.pulses[d] {
            for (s, x) in sum.iter_mut().zip(p.eval(tau)) {
                *s += x;
            }
        }
        sum
    }
}

impl Controller for QuadrantCompensator {
    reference_only_plugin!();

    fn step(&mut self, ctx: &CycleContext, io: &mut AxisSignals) {
        let mpl = self.params.motor_per_load;
        let v = io.reference[1] / mpl;
        let sign_of = |d: usize| if d == 0 { 1.0 } else { -1.0 };
        if let (Some(b), None) = (&self.params.backlash, self.crossing) {
            // a crossing with a lead starts before the reversal, from its predicted instant
            if b.lead_s > 0.0 {
                if let Some((t_to, d)) =
                    time_to_reversal(v, io.reference[2] / mpl, io.reference[3] / mpl)
                {
                    if t_to <= b.lead_s {
                        self.crossing = Some((ctx.t_s + t_to - b.lead_s, sign_of(d)));
                        self.crossing_ahead = Some(ctx.t_s + t_to);
                    }
                }
            }
        }
        if let Some(r) = self.detector.update(ctx.t_s, v) {
            self.active = Some((r.t_s, r.direction.index()));
            if self.params.backlash.is_some() {
                let sign = sign_of(r.direction.index());
                // the crossing started ahead of this reversal plays on
                if self.crossing_ahead.is_none() || self.crossing.is_none_or(|c| c.1 != sign) {
                    self.crossing = Some((r.t_s, sign));
                }
                self.crossing_ahead = None;
            }
            self.predicted = false;
        } else if self.active.is_none() || self.predicted {
            // Pulses that start before the reversal play from its predicted instant.
            if let Some((t_to, d)) =
                time_to_reversal(v, io.reference[2] / mpl, io.reference[3] / mpl)
            {
                if t_to <= self.lead[d] {
                    self.active = Some((ctx.t_s + t_to, d));
                    self.predicted = true;
                }
            }
        }
        if let Some((t_r, d)) = self.active {
            let tau = ctx.t_s - t_r;
            // a predicted reversal that did not come (the axis stopped) is dropped
            if tau > self.horizon[d] || (self.predicted && tau > 2.0 * ctx.period_s) {
                self.active = None;
                self.predicted = false;
            }
        }
        let [delta, rate, acc, jerk, snap] = self.offset(ctx.t_s);
        let p = &self.params;
        if let Some(c) = &p.friction {
            io.torque_ff += c.torque(io.reference[1]);
        }
        if let (Some(b), Some(t_r), Some((t0, sign))) =
            (&p.backlash, self.crossing_ahead, self.crossing)
        {
            // the reversal did not come (the axis stopped): the share of the gap crossed so far
            // is crossed back
            if ctx.t_s > t_r + 2.0 * ctx.period_s {
                self.crossing = Some((ctx.t_s, -sign * b.share(ctx.t_s, t0)));
                self.crossing_ahead = None;
            }
        }
        if let (Some(b), Some((t0, sign))) = (&p.backlash, self.crossing) {
            match b.at(ctx.t_s, t0, sign) {
                Some((wb, tb)) => {
                    io.vel_cmd += wb;
                    io.torque_ff += tb;
                }
                None => {
                    self.crossing = None;
                    self.crossing_ahead = None;
                }
            }
        }
        // load offset delta; the motor moves delta + twist, twist = (JL/KL) delta''
        let w = p.gain * (p.kp_per_s * delta + rate + p.twist_s2 * jerk) * p.motor_per_load;
        let tau =
            p.gain * (p.inertia * acc + p.motor_inertia() * p.twist_s2 * snap) * p.motor_per_load;
        if !(w.is_finite() && tau.is_finite()) {
            self.active = None;
            self.predicted = false;
            return;
        }
        io.torque_ff += tau;
        match p.inject {
            Injection::Velocity => io.vel_cmd += w,
            Injection::Torque { kv, tv_s } => {
                let i_term = if tv_s > 0.0 {
                    self.integral += ctx.period_s * w;
                    if !self.integral.is_finite() {
                        self.integral = 0.0;
                    }
                    self.integral / tv_s
                } else {
                    0.0
                };
                io.torque_ff += kv * (w + i_term);
            }
        }
    }

    /// Snapshot layout: [detector sign, last velocity, last time, active (0/1), t_r, direction,
    /// torque-injection integral, predicted (0/1), crossing (0/1), its start, its signed share,
    /// crossing ahead of the reversal (0/1), the reversal's predicted instant].
    fn snapshot(&self) -> ControllerState {
        let d = &self.detector;
        let (act, t_r, dir) = match self.active {
            Some((t, i)) => (1.0, t, i as f64),
            None => (0.0, 0.0, 0.0),
        };
        ControllerState::from_slice(&[
            d.sign as f64,
            d.last_v,
            d.last_t,
            act,
            t_r,
            dir,
            self.integral,
            self.predicted as u8 as f64,
            self.crossing.is_some() as u8 as f64,
            self.crossing.map_or(0.0, |c| c.0),
            self.crossing.map_or(0.0, |c| c.1),
            self.crossing_ahead.is_some() as u8 as f64,
            self.crossing_ahead.unwrap_or(0.0),
        ])
    }

    fn restore(&mut self, state: &ControllerState) {
        let at = |i: usize| state.finite_or_zero(i);
        self.detector = ReversalDetector {
            sign: at(0).signum() as i8 * (at(0) != 0.0) as i8,
            last_v: at(1),
            last_t: at(2),
        };
        self.active = (at(3) != 0.0).then(|| (at(4), (at(5) as usize).min(1)));
        self.integral = at(6);
        self.predicted = self.active.is_some() && at(7) != 0.0;
        self.crossing = (at(8) != 0.0).then(|| (at(9), at(10).clamp(-1.0, 1.0)));
        self.crossing_ahead = (self.crossing.is_some() && at(11) != 0.0).then(|| at(12));
    }

    fn initialize_from(&mut self, last: &AxisSignals) {
        // Knowing the last commanded velocity lets the first reversal after a switch count.
        // (Its time is unknown here; the next step's sample completes it.)
        self.detector = ReversalDetector::new();
        if last.reference[1].is_finite() && last.reference[1] != 0.0 {
            self.detector.sign = last.reference[1].signum() as i8;
            self.detector.last_v = last.reference[1];
            self.detector.last_t = f64::NAN;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The context of cycle `k` at period `t` (time = k t).
    fn at(k: u64, t: f64) -> CycleContext {
        CycleContext {
            period_s: t,
            cycle: k,
            t_s: k as f64 * t,
        }
    }

    pub(super) fn pulse() -> Pulse {
        Pulse {
            pass: 1,
            start_s: 0.001,
            peak_s: 0.004,
            end_s: 0.014,
            rise_split: 0.3,
            fall_split: 0.6,
            amplitude: 2e-6,
            profile: Profile::ConstantAcceleration,
        }
    }

    #[test]
    fn pulse_rises_to_its_amplitude_at_the_peak_and_returns_to_zero_with_zero_velocity() {
        let p = pulse();
        assert_eq!(p.eval(0.0005), [0.0; 5]);
        let [d, r, ..] = p.eval(0.004);
        assert!((d - 2e-6).abs() < 1e-15 && r.abs() < 1e-12, "{d} {r}");
        let [d, r, ..] = p.eval(0.014 - 1e-9);
        assert!(d.abs() < 1e-15 && r.abs() < 1e-9, "{d} {r}");
        // the rise's velocity peaks at its split: 2 A / span, after an acceleration 2 A / (a span^2)
        let [_, r, a, ..] = p.eval(0.001 + 0.3 * 0.003 - 1e-9);
        assert!((r - 2.0 * 2e-6 / 0.003).abs() < 1e-8, "{r}");
        assert!((a - 2.0 * 2e-6 / (0.3 * 0.003 * 0.003)).abs() < 1e-6, "{a}");
    }

    #[test]
    fn pulse_rate_and_acceleration_are_the_derivatives_of_its_offset() {
        let p = pulse();
        let h = 1e-7;
        for k in 1..140 {
            let t = k as f64 * 1e-4 + 3e-5;
            let v = (p.eval(t + h)[0] - p.eval(t - h)[0]) / (2.0 * h);
            assert!(
                (v - p.eval(t)[1]).abs() < 1e-6,
                "t {t}: {v} vs {:?}",
                p.eval(t)
            );
            let a = (p.eval(t + h)[1] - p.eval(t - h)[1]) / (2.0 * h);
            assert!(
                (a - p.eval(t)[2]).abs() < 1e-6 * a.abs().max(1.0),
                "t {t}: {a}"
            );
        }
    }

    #[test]
    fn sine_acceleration_pulse_has_continuous_derivatives_up_to_the_jerk() {
        let p = Pulse {
            profile: Profile::SineAcceleration,
            ..pulse()
        };
        let [d, r, a, j, _] = p.eval(0.004);
        assert!((d - 2e-6).abs() < 1e-15, "{d}");
        assert!(
            r.abs() < 1e-12 && a.abs() < 1e-6 && j.abs() < 1e-3,
            "{r} {a} {j}"
        );
        // each derivative is the central difference of the one before, across the joints too
        let h = 1e-8;
        for k in 1..1500 {
            let t = k as f64 * 1e-5 + 3e-7;
            let (lo, hi, mid) = (p.eval(t - h), p.eval(t + h), p.eval(t));
            for n in 0..4 {
                let fd = (hi[n] - lo[n]) / (2.0 * h);
                let scale = mid[n + 1].abs().max(p.eval(0.0025)[n + 1].abs());
                assert!(
                    (fd - mid[n + 1]).abs() <= 1e-4 * scale,
                    "t {t} order {}: {fd} vs {}",
                    n + 1,
                    mid[n + 1]
                );
            }
        }
        // velocity, acceleration and jerk vanish at the start, the peak and the end
        for t in [0.001, 0.004, 0.014] {
            for side in [-1e-9, 1e-9] {
                let v = p.eval(t + side);
                assert!(
                    v[1].abs() < 1e-9 && v[2].abs() < 1e-3 && v[3].abs() < 1.0,
                    "{t}: {v:?}"
                );
            }
        }
    }

    #[test]
    fn detector_interpolates_the_zero_crossing_and_names_the_new_direction() {
        let mut d = ReversalDetector::new();
        assert_eq!(d.update(0.0, 0.0), None);
        assert_eq!(d.update(0.1, 2.0), None);
        let r = d.update(0.2, -2.0).unwrap();
        assert!((r.t_s - 0.15).abs() < 1e-12);
        assert_eq!(r.direction, Direction::ToNegative);
        assert_eq!(d.update(0.3, 0.0), None);
        let r = d.update(0.4, 1.0).unwrap();
        assert!((r.t_s - 0.3).abs() < 1e-12, "{}", r.t_s);
        assert_eq!(r.direction, Direction::ToPositive);
        assert_eq!(d.update(0.5, f64::NAN), None);
        // rounding noise of a command at rest is no reversal
        assert_eq!(d.update(0.6, -1e-17), None);
        assert_eq!(d.update(0.7, 1e-17), None);
    }

    fn compensator(inject: Injection) -> QuadrantCompensator {
        QuadrantCompensator::new(QuadrantParams {
            table_path: PathBuf::new(),
            pulses: AxisPulses {
                to_positive: vec![pulse()],
                to_negative: vec![Pulse {
                    amplitude: -2e-6,
                    ..pulse()
                }],
            },
            gain: 1.0,
            kp_per_s: 50.0,
            motor_per_load: 100.0,
            inject,
            inertia: 0.0,
            twist_s2: 0.0,
            load_inertia: 0.0,
            friction: None,
            backlash: None,
        })
    }

    #[test]
    fn reversal_to_positive_plays_kp_offset_plus_rate_in_motor_units() {
        let mut c = compensator(Injection::Velocity);
        let t = 1e-4;
        let mut out = Vec::new();
        for k in 0..300 {
            // velocity is zero at k = 100 and positive after: t_r = 10 ms
            let mut io = AxisSignals::default();
            io.reference[1] = (k as f64 - 100.0) * 1e-3 * 100.0;
            c.step(&at(k, t), &mut io);
            out.push(io.vel_cmd);
        }
        assert!(out[..101].iter().all(|&v| v == 0.0));
        let k = 140; // tau = 4 ms: the peak, zero rate
        let expect = 50.0 * 2e-6 * 100.0;
        assert!((out[k] - expect).abs() < 1e-9, "{} vs {expect}", out[k]);
        assert!(out[101 + 141..].iter().all(|&v| v == 0.0));
    }

    #[test]
    fn torque_injection_equals_what_the_pi_would_make_of_the_velocity() {
        let mut cv = compensator(Injection::Velocity);
        let mut ct = compensator(Injection::Torque {
            kv: 5.0,
            tv_s: 0.005,
        });
        let mut pi = crate::PiVelocity::new(crate::PiVelocityParams {
            kv: 5.0,
            tv_s: 0.005,
            torque_limit: 1e9,
            filters: Default::default(),
        });
        let t = 1e-4;
        let mut integ = 0.0;
        for k in 0..300u64 {
            let ctx = at(k, t);
            let mut a = AxisSignals::default();
            a.reference[1] = 50.5 - k as f64;
            let mut b = a;
            cv.step(&ctx, &mut a);
            pi.step(&ctx, &mut a);
            ct.step(&ctx, &mut b);
            integ += b.torque_ff;
            assert!((a.torque - b.torque_ff).abs() < 1e-9, "k {k}");
        }
        assert!(integ != 0.0);
    }

    #[test]
    fn time_to_reversal_solves_the_zero_crossing_of_a_decelerating_command() {
        // v = 0.02 - 0.5 t + 0.4 t^2 / 2: the root nearest to v / |a| = 40 ms
        let (t, d) = time_to_reversal(0.02, -0.5, 0.4).unwrap();
        assert!((0.02 - 0.5 * t + 0.2 * t * t).abs() < 1e-12, "{t}");
        assert!((t - 0.04).abs() < 0.002, "{t}");
        assert_eq!(d, Direction::ToNegative.index());
        assert_eq!(time_to_reversal(-0.02, 0.5, 0.0).unwrap().1, 0);
        // accelerating away from zero, at rest, or not finite: no reversal ahead
        assert_eq!(time_to_reversal(0.02, 0.5, 0.0), None);
        assert_eq!(time_to_reversal(0.0, -0.5, 0.0), None);
        assert_eq!(time_to_reversal(0.02, f64::NAN, 0.0), None);
    }

    #[test]
    fn pulse_starting_before_the_reversal_plays_from_the_predicted_instant() {
        let early = Pulse {
            start_s: -0.004,
            peak_s: 0.0,
            end_s: 0.003,
            profile: Profile::SineAcceleration,
            ..pulse()
        };
        let mut c = QuadrantCompensator::new(QuadrantParams {
            pulses: AxisPulses {
                to_positive: vec![early],
                to_negative: vec![],
            },
            ..compensator(Injection::Velocity).params
        });
        let t = 1e-4;
        // reference velocity (motor units) (k - 100.5) * 0.1: crosses zero at k = 100.5
        let t_r = 100.5 * t;
        let mut played_before = 0;
        for k in 0..200u64 {
            let ts = k as f64 * t;
            let mut io = AxisSignals::default();
            io.reference[1] = (k as f64 - 100.5) * 0.1;
            io.reference[2] = 0.1 / t;
            c.step(&at(k, t), &mut io);
            let [d, r, ..] = early.eval(ts - t_r);
            let expect = (50.0 * d + r) * 100.0;
            assert!(
                (io.vel_cmd - expect).abs() <= 1e-9 * expect.abs().max(1e-3),
                "k {k}: {} vs {expect}",
                io.vel_cmd
            );
            played_before += (ts < t_r && io.vel_cmd != 0.0) as usize;
        }
        assert!(played_before >= 39, "{played_before}");
    }

    #[test]
    fn pulse_on_a_two_mass_axis_moves_the_motor_ahead_by_the_twist() {
        let p = Pulse {
            profile: Profile::SineAcceleration,
            ..pulse()
        };
        let params = |twist_s2| QuadrantParams {
            pulses: AxisPulses {
                to_positive: vec![p],
                to_negative: vec![],
            },
            inertia: 5e-3,
            twist_s2,
            load_inertia: 3e-3,
            friction: None,
            backlash: None,
            ..compensator(Injection::Velocity).params
        };
        let (mut rigid, mut two) = (
            QuadrantCompensator::new(params(0.0)),
            QuadrantCompensator::new(params(1e-6)),
        );
        let t = 1e-4;
        let mut twisted = 0;
        for k in 0..300u64 {
            let ctx = at(k, t);
            let mut a = AxisSignals::default();
            a.reference[1] = (k as f64 - 100.0) * 1e-3 * 100.0;
            let mut b = a;
            rigid.step(&ctx, &mut a);
            two.step(&ctx, &mut b);
            let e = p.eval(ctx.t_s - 0.01);
            // velocity + (JL/KL) jerk, torque + JM (JL/KL) snap (motor units: x 100)
            let dv = 1e-6 * e[3] * 100.0;
            let dt = 2e-3 * 1e-6 * e[4] * 100.0;
            assert!((b.vel_cmd - a.vel_cmd - dv).abs() < 1e-12, "k {k}");
            assert!((b.torque_ff - a.torque_ff - dt).abs() < 1e-12, "k {k}");
            twisted += (dv != 0.0) as usize;
        }
        assert!(twisted > 100, "{twisted}");
    }

    #[test]
    fn a_backlash_crossing_with_a_lead_is_centred_on_the_reversal_and_undone_at_a_stop() {
        let params = QuadrantParams {
            pulses: AxisPulses::default(),
            backlash: Some(BacklashPulse {
                gap_motor: 1e-3,
                duration_s: 5e-3,
                jm: 0.0,
                lead_s: 2.5e-3,
            }),
            ..compensator(Injection::Velocity).params
        };
        let t = 1e-4;
        // the commanded velocity falls by 1 load unit/s^2 through zero at 10.05 ms (a
        // reversal), or to rest at 10 ms (a stop)
        for reverses in [true, false] {
            let mut c = QuadrantCompensator::new(params.clone());
            let (mut area, mut first) = (0.0, None);
            for k in 0..400u64 {
                let mut io = AxisSignals::default();
                let v = 1e-4 * (100.5 - k as f64);
                io.reference[1] = if reverses { v } else { v.max(0.0) };
                io.reference[2] = if reverses || v > 0.0 { -1.0 } else { 0.0 };
                c.step(&at(k, t), &mut io);
                area += io.vel_cmd * t;
                if io.vel_cmd != 0.0 {
                    first.get_or_insert(k);
                }
            }
            // half the crossing (25 periods) ahead of the reversal
            let k0 = first.unwrap();
            assert!((75..=77).contains(&k0), "{k0}");
            if reverses {
                assert!((area + 1e-3).abs() < 1e-6, "{area}");
            } else {
                // within the period's share of the pulse cut off at the switch
                assert!(area.abs() < 3e-5, "{area}");
            }
            assert!(c.crossing.is_none() && c.crossing_ahead.is_none());
        }
    }

    #[test]
    fn snapshot_restores_a_reversal_in_progress() {
        // with and without a backlash crossing (5 ms, still under way when the snapshot is taken)
        let crossing = |c: &mut QuadrantCompensator| {
            c.params.backlash = Some(BacklashPulse {
                gap_motor: 1e-3,
                duration_s: 5e-3,
                jm: 1e-3,
                lead_s: 0.0,
            });
        };
        for with_backlash in [false, true] {
            let mut a = compensator(Injection::Velocity);
            let mut b = compensator(Injection::Velocity);
            if with_backlash {
                crossing(&mut a);
                crossing(&mut b);
            }
            let t = 1e-4;
            let ctx = |k: u64| at(k, t);
            for k in 0..120 {
                let mut io = AxisSignals::default();
                io.reference[1] = 100.5 - k as f64;
                a.step(&ctx(k), &mut io);
            }
            assert_eq!(a.crossing.is_some(), with_backlash);
            b.restore(&a.snapshot());
            for k in 120..200 {
                let mut ia = AxisSignals::default();
                ia.reference[1] = 100.5 - k as f64;
                let mut ib = ia;
                a.step(&ctx(k), &mut ia);
                b.step(&ctx(k), &mut ib);
                assert_eq!((ia.vel_cmd, ia.torque_ff), (ib.vel_cmd, ib.torque_ff));
            }
        }
    }
}
