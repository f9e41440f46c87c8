//! The controller law of a model's `[controller]` as the workbench evaluates it on a trace: the
//! law itself, the discretisations and velocity estimates a drive may use, the best of them for
//! a record, and the law of a long trace held in block means. It reads no other part of the
//! workbench, so the trace's reading (`data.rs`) and the controller channel (`controller.rs`)
//! both build on it.

use std::borrow::Cow;

use feedloop_model::model::ModelFile;

use super::signal::densest_quarter;

/// The model's controller law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Law {
    /// Position gain, 1/s.
    pub kp: f64,
    /// Velocity gain, torque units per motor unit/s.
    pub kv: f64,
    /// Integral time, s (0: no integral action).
    pub tv: f64,
    /// Output limit of the law, torque units (infinite when the model gives none).
    pub lim: f64,
    /// Share of the commanded velocity fed forward into the velocity command (0: none).
    pub vff: f64,
    /// Inertia the commanded acceleration is fed forward with into the torque (0: none).
    pub tff: f64,
    /// What the integrator does while the output is clamped.
    pub anti_windup: AntiWindup,
}

/// What a velocity loop's integrator does while its output sits at the limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AntiWindup {
    /// Held while the clamp is active and the error pushes further into it (conditional
    /// integration; feedloop's `pi_velocity`).
    Held,
    /// Wound back by the clamped part of the output (back-calculation, tracking time Tv).
    BackCalculation,
    /// Integrates on (no anti-windup).
    None,
}

impl AntiWindup {
    /// All the forms tried.
    pub const ALL: [AntiWindup; 3] = [
        AntiWindup::Held,
        AntiWindup::BackCalculation,
        AntiWindup::None,
    ];

    /// Its words in a diagnosis.
    pub fn words(self) -> &'static str {
        match self {
            AntiWindup::Held => "its velocity integrator held while clamped (conditional anti-windup)",
            AntiWindup::BackCalculation => {
                "its velocity integrator wound back by the clamped part (back-calculation anti-windup)"
            }
            AntiWindup::None => "its velocity integrator running on while clamped (no anti-windup)",
        }
    }
}

impl Law {
    /// The law of `model`'s `[controller]`, when it has a position and a velocity gain.
    pub fn of(model: &ModelFile) -> Option<Self> {
        let c = &model.controller;
        Some(Self {
            kp: c.kp_per_s?,
            kv: c.kv?,
            tv: c.tv_s.unwrap_or(0.0),
            lim: c.torque_limit.unwrap_or(f64::INFINITY),
            vff: c.velocity_ff.unwrap_or(0.0),
            tff: c.torque_ff.unwrap_or(0.0),
            anti_windup: AntiWindup::Held,
        })
    }

    /// The command's velocity and acceleration (central differences, motor units), when the
    /// law feeds either forward (empty otherwise).
    fn command_derivatives(&self, cmd: &[f64], dt: f64) -> (Vec<f64>, Vec<f64>) {
        if self.vff == 0.0 && self.tff == 0.0 {
            return (Vec::new(), Vec::new());
        }
        let n = cmd.len();
        let d1 = |x: &[f64], k: usize| -> f64 {
            if n < 2 {
                0.0
            } else if k == 0 {
                (x[1] - x[0]) / dt
            } else if k + 1 >= n {
                (x[k] - x[k - 1]) / dt
            } else {
                (x[k + 1] - x[k - 1]) / (2.0 * dt)
            }
        };
        let v: Vec<f64> = (0..n).map(|k| d1(cmd, k)).collect();
        // the three-point second difference (the most local estimate of the acceleration)
        let a: Vec<f64> = (0..n)
            .map(|k| {
                let (lo, hi) = (k.saturating_sub(1), (k + 1).min(n.saturating_sub(1)));
                if hi >= lo + 2 {
                    (cmd[hi] - 2.0 * cmd[k] + cmd[lo]) / (dt * dt)
                } else {
                    0.0
                }
            })
            .collect();
        (v, a)
    }

    /// The law's output at every sample, for the recorded position `x` (motor units), command
    /// `cmd` and velocity `vel`; the integrator starts so that the first output is `first`.
    pub fn run(&self, cmd: &[f64], x: &[f64], vel: &[f64], dt: f64, first: f64) -> Vec<f64> {
        self.run_as(cmd, x, vel, dt, first, Discretisation::FEEDLOOP)
    }

    /// [`Law::run`] in discretisation `disc`.
    pub fn run_as(
        &self,
        cmd: &[f64],
        x: &[f64],
        vel: &[f64],
        dt: f64,
        first: f64,
        disc: Discretisation,
    ) -> Vec<f64> {
        let n = cmd.len();
        let mut out = vec![0.0; n];
        let use_i = self.tv > 0.0;
        let mut integ = 0.0;
        let (vcmd, acmd) = self.command_derivatives(cmd, dt);
        let ff = |c: &[f64], k: usize, g: f64| if g == 0.0 { 0.0 } else { g * c[k] };
        for k in 0..n {
            let e = self.kp * (cmd[k] - x[k]) + ff(&vcmd, k, self.vff) - vel[k];
            let e = if e.is_finite() { e } else { 0.0 };
            let prev = integ;
            if use_i && k == 0 {
                // bumpless: the first output is the first recorded one
                integ = ((first - ff(&acmd, 0, self.tff)) / self.kv - e) * self.tv;
                if !integ.is_finite() {
                    integ = 0.0;
                }
            } else if use_i && !disc.integrate_after_output {
                integ += dt * e;
            }
            let raw =
                self.kv * (e + if use_i { integ / self.tv } else { 0.0 }) + ff(&acmd, k, self.tff);
            let u = raw.clamp(-self.lim, self.lim);
            if use_i && k > 0 && disc.integrate_after_output {
                integ += dt * e;
            }
            if k > 0 && u != raw {
                match self.anti_windup {
                    AntiWindup::Held if e * raw > 0.0 => integ = prev,
                    AntiWindup::BackCalculation if use_i => {
                        integ += dt * (u - raw) / self.kv;
                    }
                    AntiWindup::Held | AntiWindup::BackCalculation | AntiWindup::None => {}
                }
            }
            out[k] = u;
        }
        if disc.output_delay && n > 1 {
            out.rotate_right(1);
            out[0] = out[1];
        }
        out
    }
}

/// How a drive may discretise the same law: where the integrator is updated and whether the
/// output computed from a sample is applied (and recorded) one period later.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Discretisation {
    /// The integrator is updated after the output is formed (`u_k` uses `I_(k-1)`).
    pub integrate_after_output: bool,
    /// The output formed from sample `k` is recorded at sample `k + 1`.
    pub output_delay: bool,
}

impl Discretisation {
    /// feedloop's velocity loop: integrate, then form the output, in the same period.
    pub const FEEDLOOP: Self = Self {
        integrate_after_output: false,
        output_delay: false,
    };

    /// All the variants tried.
    pub const ALL: [Self; 4] = [
        Self::FEEDLOOP,
        Self {
            integrate_after_output: true,
            output_delay: false,
        },
        Self {
            integrate_after_output: false,
            output_delay: true,
        },
        Self {
            integrate_after_output: true,
            output_delay: true,
        },
    ];

    /// Name in reports.
    pub fn name(self) -> &'static str {
        match (self.integrate_after_output, self.output_delay) {
            (false, false) => "integrator updated before the output",
            (true, false) => "integrator updated after the output",
            (false, true) => "integrator before the output, output one period late",
            (true, true) => "integrator after the output, output one period late",
        }
    }
}

/// How many velocity estimates [`velocity_source`] offers.
const VELOCITY_SOURCES: usize = 4;

/// Velocity estimate `i` the drive may have used, from the position `q` (motor units) or the
/// recorded motor velocity: (name, values); `None` for the motor velocity when it was not
/// recorded. Made one at a time, so that a long trace holds one of them at once.
fn velocity_source<'a>(
    i: usize,
    q: &[f64],
    motor_vel: Option<&'a [f64]>,
    dt: f64,
) -> Option<(&'static str, Cow<'a, [f64]>)> {
    let n = q.len();
    let back = |k: usize| {
        if k == 0 {
            0.0
        } else {
            (q[k] - q[k - 1]) / dt
        }
    };
    let v: Vec<f64> = match i {
        0 => return motor_vel.map(|c| ("the motor_vel column", Cow::Borrowed(c))),
        1 => (0..n).map(back).collect(),
        2 => (0..n)
            .map(|k| {
                if k == 0 || k + 1 >= n {
                    back(k)
                } else {
                    (q[k + 1] - q[k - 1]) / (2.0 * dt)
                }
            })
            .collect(),
        _ => (0..n)
            .map(|k| {
                if k < 2 {
                    back(k)
                } else {
                    (q[k] - q[k - 2]) / (2.0 * dt)
                }
            })
            .collect(),
    };
    let name = match i {
        1 => "a backward difference of the position",
        2 => "a central difference of the position (an observer's or the true velocity)",
        _ => "a two-sample average of the position's differences",
    };
    Some((name, Cow::Owned(v)))
}

/// The velocity estimate named `name` (as [`best_law`] names it) from the position `q` (motor
/// units) or the recorded motor velocity.
pub fn velocity_named(
    name: &str,
    q: &[f64],
    motor_vel: Option<&[f64]>,
    dt: f64,
) -> Option<Vec<f64>> {
    (0..VELOCITY_SOURCES)
        .filter_map(|i| velocity_source(i, q, motor_vel, dt))
        .find(|(n, _)| *n == name)
        .map(|(_, v)| v.into_owned())
}

/// The velocity estimate and discretisation of `law_p` the record `rec` agrees with best, and
/// the law's output with them: `cmd` and `x` (command and load position) and `q` (the position
/// the velocity is estimated from) in motor units, `motor_vel` the recorded motor velocity,
/// `add` a declared added input. Scored on at most 200,000 evenly spread samples, so a long
/// trace costs no more than a sort of those.
#[allow(clippy::too_many_arguments)]
pub fn best_law(
    law_p: &Law,
    cmd: &[f64],
    x: &[f64],
    q: &[f64],
    motor_vel: Option<&[f64]>,
    rec: &[f64],
    add: Option<&[f64]>,
    dt: f64,
) -> Option<(&'static str, Discretisation, Vec<f64>)> {
    let first = rec[0] - add.map_or(0.0, |a| a[0]);
    let (a, b) = (2.min(rec.len()), rec.len());
    let step = ((b - a) / 200_000).max(1);
    let mut best: Option<(f64, &'static str, Discretisation, Vec<f64>)> = None;
    for i in 0..VELOCITY_SOURCES {
        let Some((name, v)) = velocity_source(i, q, motor_vel, dt) else {
            continue;
        };
        for disc in Discretisation::ALL {
            let law = law_p.run_as(cmd, x, &v, dt, first, disc);
            let dev: Vec<f64> = (a..b)
                .step_by(step)
                .map(|k| rec[k] - law[k] - add.map_or(0.0, |x| x[k]))
                .collect();
            let score = densest_quarter(&dev).1;
            if best.as_ref().is_none_or(|(s, ..)| score < *s) {
                best = Some((score, name, disc, law));
            }
        }
    }
    best.map(|(_, name, disc, law)| (name, disc, law))
}

/// The controller law of a long trace evaluated at the recording's rate, kept at the samples
/// its axis is held at (see [`AxisData::sub`]): the law applied to every recorded sample (a
/// drive's integrator sums each of them), then taken with the recorded torque and the added
/// input at the centre of each block of samples.
#[derive(Debug, Clone)]
pub struct HeldLaw {
    /// The law evaluated.
    pub law_of: Law,
    /// The recorded torque at the block centres.
    pub recorded: Vec<f64>,
    /// The law's output there.
    pub law: Vec<f64>,
    /// The declared added input there.
    pub add: Option<Vec<f64>>,
    /// Which velocity the law was evaluated with.
    pub velocity: &'static str,
    /// Which discretisation the record agrees with.
    pub discretisation: Discretisation,
}
