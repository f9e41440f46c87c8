//! A constant traverse under an excitation (keys `traverse_m_per_s` / `traverse_rad_per_s`,
//! `traverse_reversal_s`, and the travel limit `max_travel_m` / `max_travel_rad`).
//!
//! The command is `p(t) = e(t - T_r) + c(t)`: the excitation `e` delayed by one reversal time
//! `T_r`, on top of a carrier `c` per axis that speeds up from rest to `+V` over `T_r` (C5), holds
//! `+-V` and turns `+V -> -V` over `T_r` (C5) before `|p - start|` could leave the travel, and
//! stops over `T_r` after the excitation. The excitation's velocity must stay below `V`, so the
//! axis never reverses within a pass (between two turns). The turn points are kept inside the
//! travel by the excitation's largest excursion from its start plus the carrier's stopping
//! distance `V T_r / 2`.

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::params::{ConfigError, Fields, Range};

use super::poly::{Builder, PiecewisePoly};
use super::{per_axis, Ctx, RefState, Trajectory};

/// Traverse keys read from a `[trajectory]` table.
#[derive(Debug, Clone)]
pub(crate) struct TraverseSpec {
    /// Per axis traverse velocity (0: none).
    velocity: Vec<f64>,
    /// Per axis travel limit about the start (infinite: none given).
    travel: Vec<f64>,
    /// Time of a turn (and of the start and stop ramps), s.
    reversal_s: f64,
}

/// Reads `traverse_m_per_s` / `traverse_rad_per_s` and `traverse_reversal_s`; `travel` is the
/// travel limit per axis (infinite when not given). `None` when no traverse is given.
pub(crate) fn read(
    f: &mut Fields,
    ctx: &Ctx,
    travel: &[f64],
) -> Result<Option<TraverseSpec>, ConfigError> {
    let velocity: Vec<f64> = per_axis(
        f,
        "traverse_m_per_s",
        "traverse_rad_per_s",
        ctx.axes,
        Range::NonNegative,
    )?
    .into_iter()
    .map(|v| v.unwrap_or(0.0))
    .collect();
    let reversal_s = f.f64_or("traverse_reversal_s", Range::Positive, 0.1)?;
    if velocity.iter().all(|v| *v == 0.0) {
        return Ok(None);
    }
    ctx.at_least_periods(f, "traverse_reversal_s", reversal_s, 2.0)?;
    for (a, v) in velocity.iter().enumerate() {
        if *v > 0.0 && !travel[a].is_finite() {
            return Err(f.error(
                "max_travel_m",
                format!(
                    "axis `{}` has a traverse and needs a travel limit (max_travel_m / \
                     max_travel_rad, > 0, about the start) to turn within",
                    ctx.axes[a]
                ),
            ));
        }
    }
    Ok(Some(TraverseSpec {
        velocity,
        travel: travel.to_vec(),
        reversal_s,
    }))
}

/// Reads the travel limit keys `max_travel_m` / `max_travel_rad` (infinite when not given).
pub(crate) fn read_travel(f: &mut Fields, ctx: &Ctx) -> Result<Vec<f64>, ConfigError> {
    Ok(per_axis(
        f,
        "max_travel_m",
        "max_travel_rad",
        ctx.axes,
        Range::Positive,
    )?
    .into_iter()
    .map(|v| v.unwrap_or(f64::INFINITY))
    .collect())
}

/// An excitation on top of a traverse.
pub struct Traversed {
    exc: Box<dyn Trajectory>,
    /// Per axis carrier (one-axis polynomial from 0), `None` for axes without a traverse.
    carrier: Vec<Option<PiecewisePoly>>,
    delay_s: f64,
    duration_s: f64,
}

impl Trajectory for Traversed {
    fn axes(&self) -> &[String] {
        self.exc.axes()
    }

    fn duration_s(&self) -> f64 {
        self.duration_s
    }

    fn eval(&self, t_s: f64, out: &mut [RefState]) {
        self.exc.eval(t_s - self.delay_s, out);
        let mut c = [[0.0; REF_DERIVS]; 1];
        for (o, carrier) in out.iter_mut().zip(&self.carrier) {
            if let Some(p) = carrier {
                p.eval(t_s, &mut c);
                for (x, y) in o.iter_mut().zip(&c[0]) {
                    *x += y;
                }
            }
        }
    }

    fn kind(&self) -> &str {
        self.exc.kind()
    }

    fn steady_windows_s(&self) -> Vec<[f64; 2]> {
        self.exc
            .steady_windows_s()
            .into_iter()
            .map(|[a, b]| [a + self.delay_s, b + self.delay_s])
            .collect()
    }

    fn breakpoints_s(&self) -> Vec<f64> {
        let mut b: Vec<f64> = self
            .exc
            .breakpoints_s()
            .into_iter()
            .map(|t| t + self.delay_s)
            .collect();
        for p in self.carrier.iter().flatten() {
            b.extend_from_slice(p.piece_starts());
            b.push(p.end_s());
        }
        b.sort_by(f64::total_cmp);
        b.dedup();
        b
    }
}

/// Puts `exc` on the traverse `spec` (returns it as it is without one). Refuses (at `amplitude_key`) an excitation whose velocity
/// is not below the traverse (its velocity amplitude `amplitude_per_s` when it has one, and its
/// sampled velocity), and (at `max_travel_m`) a travel too short for a pass.
pub(crate) fn apply(
    f: &Fields,
    ctx: &Ctx,
    spec: Option<TraverseSpec>,
    exc: Box<dyn Trajectory>,
    amplitude_key: &str,
    amplitude_per_s: Option<&[f64]>,
) -> Result<Box<dyn Trajectory>, ConfigError> {
    let Some(spec) = spec else {
        return Ok(exc);
    };
    let n = ctx.axes.len();
    let dt = ctx.period_s;
    let d = exc.duration_s();
    let tr = spec.reversal_s;
    // Excitation's start, peak velocity and largest excursion per axis, sampled every period.
    let mut s = vec![[0.0; REF_DERIVS]; n];
    exc.eval(-1.0, &mut s);
    let start: Vec<f64> = s.iter().map(|x| x[0]).collect();
    let mut vpeak = vec![0.0f64; n];
    let mut excursion = vec![0.0f64; n];
    let steps = (d / dt).ceil() as usize;
    for k in 0..=steps {
        exc.eval((k as f64 * dt).min(d), &mut s);
        for a in 0..n {
            vpeak[a] = vpeak[a].max(s[a][1].abs());
            excursion[a] = excursion[a].max((s[a][0] - start[a]).abs());
        }
    }
    let mut carrier = Vec::with_capacity(n);
    let end_exc = tr + d;
    for a in 0..n {
        let v = spec.velocity[a];
        if v == 0.0 {
            carrier.push(None);
            continue;
        }
        let peak = amplitude_per_s.map_or(0.0, |x| x[a]).max(vpeak[a]);
        if peak >= v {
            return Err(f.error(
                amplitude_key,
                format!(
                    "the excitation's velocity on axis `{}` reaches {:.6} m/s (rad/s on a rotary \
                     axis), not below its traverse ({v}, traverse_m_per_s / traverse_rad_per_s): the axis would \
                     reverse within a pass; give an amplitude below the traverse (about half of it)",
                    ctx.axes[a], peak
                ),
            ));
        }
        // Farthest the carrier may get from the start before a turn or the stop.
        let reach = spec.travel[a] - excursion[a] - 0.5 * v * tr;
        if reach <= v * tr {
            return Err(f.error(
                "max_travel_m",
                format!(
                    "{} on axis `{}` leaves no pass for a traverse of {v} m/s (rad/s): the excitation wanders \
                     {:.6} from its start and a turn over traverse_reversal_s = {tr} s needs {:.6}; \
                     give a travel above {:.6} (or a slower traverse, a shorter turn)",
                    spec.travel[a],
                    ctx.axes[a],
                    excursion[a],
                    0.5 * v * tr,
                    excursion[a] + 1.5 * v * tr
                ),
            ));
        }
        let mut b = Builder::new(&[0.0]);
        b.smooth_velocity_change(tr, &[v]);
        let mut dir = 1.0;
        loop {
            let pos = b.position()[0];
            let hold = ((reach - dir * pos) / v).max(0.0);
            let left = end_exc - b.time();
            if hold >= left {
                b.hold(left);
                break;
            }
            b.hold(hold);
            b.smooth_velocity_change(tr, &[-2.0 * dir * v]);
            dir = -dir;
            if b.time() >= end_exc {
                break;
            }
        }
        b.smooth_velocity_change(tr, &[-b.velocity()[0]]);
        carrier.push(Some(b.finish().0));
    }
    let duration_s = carrier
        .iter()
        .flatten()
        .map(|p| p.end_s())
        .fold(tr + d, f64::max);
    Ok(Box::new(Traversed {
        exc,
        carrier,
        delay_s: tr,
        duration_s,
    }))
}
