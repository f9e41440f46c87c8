//! The loop model: margins of a P position loop around a PI velocity loop on the axis model,
//! with the controller's sampling hold and a transport delay. `feedloop tune` rejects gain sets
//! with it, and the scheduler checks a swap or a retune with it before applying it.

use std::f64::consts::PI;

use feedloop_model::job::Job;
use feedloop_model::model::PlantParams;
use feedloop_model::Stage;
use nalgebra::{DMatrix, DVector};
use num_complex::Complex64;

/// Smallest phase margin a loop may have, deg.
pub const MIN_PHASE_MARGIN_DEG: f64 = 30.0;
/// Smallest gain margin a loop may have, dB.
pub const MIN_GAIN_MARGIN_DB: f64 = 6.0;
/// The drive's transport delay assumed by default, control periods (on top of the hold).
pub const DEFAULT_DELAY_CYCLES: u32 = 1;

/// The gains of a P position loop around a PI velocity loop.
#[derive(Debug, Clone, Copy, serde::Serialize, PartialEq)]
pub struct Gains {
    /// Position gain, 1/s.
    pub kp_per_s: f64,
    /// Velocity gain, N m s/rad.
    pub kv_nms_per_rad: f64,
    /// Integral time, s.
    pub tv_s: f64,
}

impl Gains {
    /// Sets the parameter `name` (one of `kp_per_s`, `kv_nms_per_rad`, `tv_s`).
    pub fn set(&mut self, name: &str, v: f64) {
        match name {
            "kp_per_s" => self.kp_per_s = v,
            "kv_nms_per_rad" => self.kv_nms_per_rad = v,
            _ => self.tv_s = v,
        }
    }
}

/// What a controller contributes to the loop model (each `None` when it has no such gain).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoopGains {
    /// Position gain Kp, 1/s.
    pub kp_per_s: Option<f64>,
    /// Velocity gain Kv, N m s/rad (N s/m).
    pub kv: Option<f64>,
    /// Integral time Tv, s (0: proportional only).
    pub tv_s: Option<f64>,
}

impl LoopGains {
    /// The loop's gains from an axis' stages (indexed by [`Stage::index`]): Kp from the position
    /// stage, else another; Kv and Tv from the velocity stage, else another. `None` without a Kp
    /// or a Kv.
    pub fn combine(stages: &[LoopGains; 4]) -> Option<Gains> {
        let first = |lead: Stage, get: fn(&LoopGains) -> Option<f64>| {
            get(&stages[lead.index()]).or_else(|| stages.iter().find_map(get))
        };
        Some(Gains {
            kp_per_s: first(Stage::Position, |s| s.kp_per_s)?,
            kv_nms_per_rad: first(Stage::Velocity, |s| s.kv)?,
            tv_s: first(Stage::Velocity, |s| s.tv_s).unwrap_or(0.0),
        })
    }
}

/// Why a gain set fails the margin check, in words (`None` when it passes).
pub fn margin_failure(pm_deg: f64, gm_db: f64) -> Option<String> {
    let unstable = pm_deg <= 0.0 || gm_db <= 0.0;
    (pm_deg < MIN_PHASE_MARGIN_DEG || gm_db < MIN_GAIN_MARGIN_DB).then(|| {
        format!(
            "{}: phase margin {pm_deg:.1} deg (at least {MIN_PHASE_MARGIN_DEG} needed), gain margin {gm_db:.1} dB (at least {MIN_GAIN_MARGIN_DB})",
            if unstable { "unstable loop" } else { "marginal loop" }
        )
    })
}

/// Phase and gain margins (deg, dB) of the velocity loop and of the position loop around it,
/// from the axis model (2-mass, or a rigid mass); the worse of the two loops. The phase margin
/// is the smallest distance of the phase from -180 deg at any gain crossover; the gain margin
/// the smallest -|L| dB where the unwrapped phase crosses -180 deg (mod 360).
///
/// With `period_s = T > 0` the loop is the digital one exactly: the axis model sampled with its
/// zero-order hold (the matrix exponential of its state-space model over a period, so the
/// response up to the Nyquist frequency includes what aliasing does), the PI as the plugin runs
/// it (rectangle rule, integrator updated before the output), evaluated on z = e^{jwT} up to
/// and including Nyquist. `delay_s` adds a transport delay `e^{-jw delay_s}` (computation,
/// fieldbus: one period when the drive applies the command at the next cycle).
/// `period_s = 0` is the continuous-time loop. `None` when a margin cannot be
/// computed (a non-finite or non-positive gain or model value).
pub fn margins(plant: &PlantParams, g: Gains, period_s: f64, delay_s: f64) -> Option<(f64, f64)> {
    let finite = [g.kp_per_s, g.kv_nms_per_rad, g.tv_s, period_s, delay_s]
        .iter()
        .all(|x| x.is_finite() && *x >= 0.0);
    if !finite || g.kv_nms_per_rad <= 0.0 {
        return None;
    }
    let (lv, lp) = if period_s > 0.0 {
        sampled_loops(plant, g, period_s, delay_s)?
    } else {
        continuous_loops(plant, g, delay_s)
    };
    let (pv, gmv) = crossing_margins(&lv);
    let (pp, gmp) = crossing_margins(&lp);
    let (gmv, gmp) = (
        at_nyquist(&lv, gmv, period_s),
        at_nyquist(&lp, gmp, period_s),
    );
    let (pm, gm) = (pv.min(pp), gmv.min(gmp));
    (!pm.is_nan() && !gm.is_nan()).then_some((pm, gm))
}

/// An open loop's frequency response: (f in Hz, L(f)) on the margin check's grid.
type Response = Vec<(f64, Complex64)>;

/// Frequency points of the margin check.
const GRID_POINTS: usize = 4000;

/// The margin check's frequencies, Hz: log-spaced from 0.1 Hz to `f_max`.
fn grid(f_max: f64) -> impl Iterator<Item = f64> {
    let n = GRID_POINTS;
    (0..n).map(move |k| 0.1 * (f_max / 0.1).powf(k as f64 / (n - 1) as f64))
}

/// The open velocity loop and the open position loop, (f, L(f)) up to Nyquist, of the digital
/// loop exactly: the plant sampled with its zero-order hold, the PI as it runs (rectangle rule,
/// integrator updated before the output).
fn sampled_loops(
    plant: &PlantParams,
    g: Gains,
    period_s: f64,
    delay_s: f64,
) -> Option<(Response, Response)> {
    let mut lv = Vec::with_capacity(GRID_POINTS);
    let mut lp = Vec::with_capacity(GRID_POINTS);
    let plant_z = Sampled::new(plant, period_s)?;
    for f in grid(0.5 / period_s) {
        let w = 2.0 * PI * f;
        let z = Complex64::from_polar(1.0, w * period_s);
        let (gv, gp) = plant_z.at(z)?;
        let delay = Complex64::from_polar(1.0, -w * delay_s);
        let cv = delay
            * if g.tv_s > 0.0 {
                g.kv_nms_per_rad * (1.0 + period_s / g.tv_s * z / (z - 1.0))
            } else {
                Complex64::new(g.kv_nms_per_rad, 0.0)
            };
        let l_v = cv * gv;
        lv.push((f, l_v));
        lp.push((f, g.kp_per_s * cv * gp / (1.0 + l_v)));
    }
    Some((lv, lp))
}

/// The open velocity and position loops of the continuous-time loop, up to 10 kHz.
fn continuous_loops(plant: &PlantParams, g: Gains, delay_s: f64) -> (Response, Response) {
    let mut lv = Vec::with_capacity(GRID_POINTS);
    let mut lp = Vec::with_capacity(GRID_POINTS);
    for f in grid(1e4) {
        let s = Complex64::new(0.0, 2.0 * PI * f);
        let delay = (-s * delay_s).exp();
        let (gv, load_per_motor) = continuous_axis(plant, s);
        let cv = delay
            * if g.tv_s > 0.0 {
                g.kv_nms_per_rad * (1.0 + 1.0 / (g.tv_s * s))
            } else {
                Complex64::new(g.kv_nms_per_rad, 0.0)
            };
        let l_v = cv * gv;
        lv.push((f, l_v));
        // load position per velocity command, through the closed velocity loop
        let th_l_over_v = load_per_motor * l_v / ((1.0 + l_v) * s);
        lp.push((f, g.kp_per_s * th_l_over_v));
    }
    (lv, lp)
}

/// Motor velocity per torque, and load position per motor position, at s.
fn continuous_axis(plant: &PlantParams, s: Complex64) -> (Complex64, Complex64) {
    match plant {
        PlantParams::Rigid(r) => (
            1.0 / (r.mass_kg * s + r.viscous_ns_per_m),
            Complex64::new(1.0, 0.0),
        ),
        PlantParams::BallScrew { two_mass: t, .. } | PlantParams::Rotary { two_mass: t, .. } => {
            let ks = t.kl_nm_per_rad + t.cl_nms_per_rad * s;
            let a = t.jm_kgm2 * s * s + t.dm_nms_per_rad * s + ks;
            let b = t.jl_kgm2 * s * s + t.dl_nms_per_rad * s + ks;
            (s * b / (a * b - ks * ks), ks / b)
        }
    }
}

/// Phase and gain margin (deg, dB) of an open loop sampled on a frequency grid: the phase
/// margin at every crossing of |L| = 1, the gain margin at every crossing of the unwrapped
/// phase through -180 deg (mod 360).
fn crossing_margins(l: &[(f64, Complex64)]) -> (f64, f64) {
    let mut pm = f64::INFINITY;
    let mut gm = f64::INFINITY;
    let mut prev_phase = l[0].1.arg();
    let mut phase = prev_phase;
    for w in l.windows(2) {
        let p = w[1].1.arg();
        let mut dp = p - prev_phase;
        while dp > PI {
            dp -= 2.0 * PI;
        }
        while dp < -PI {
            dp += 2.0 * PI;
        }
        let ph0 = phase;
        phase += dp;
        prev_phase = p;
        let (m0, m1) = (w[0].1.norm(), w[1].1.norm());
        if (m0 - 1.0) * (m1 - 1.0) <= 0.0 {
            let p = w[1].1.arg().to_degrees();
            pm = pm.min(180.0 - p.abs());
        }
        let c0 = ((ph0 + PI) / (2.0 * PI)).floor();
        let c1 = ((phase + PI) / (2.0 * PI)).floor();
        if c0 != c1 {
            gm = gm.min(-20.0 * m1.log10());
        }
    }
    (pm, gm)
}

/// A sampled loop can reach -180 deg exactly at Nyquist (where it is real): its gain margin.
fn at_nyquist(l: &[(f64, Complex64)], gm: f64, period_s: f64) -> f64 {
    match l.last() {
        Some((_, x)) if period_s > 0.0 && x.re < 0.0 && x.im.abs() <= 1e-6 * x.norm() => {
            gm.min(-20.0 * x.norm().log10())
        }
        _ => gm,
    }
}

/// An axis model sampled with a zero-order hold (exact: the matrix exponential of its
/// state-space model over one period).
struct Sampled {
    phi: DMatrix<Complex64>,
    gamma: DVector<Complex64>,
    /// Index of the motor velocity and of the load position in the state.
    vel: usize,
    pos: usize,
}

impl Sampled {
    fn new(plant: &PlantParams, t: f64) -> Option<Self> {
        let (a, b, vel, pos) = match plant {
            PlantParams::Rigid(r) => {
                let (m, c) = (r.mass_kg, r.viscous_ns_per_m);
                (
                    DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, -c / m]),
                    vec![0.0, 1.0 / m],
                    1,
                    0,
                )
            }
            PlantParams::BallScrew { two_mass: p, .. }
            | PlantParams::Rotary { two_mass: p, .. } => {
                let (jm, dm, kl, cl, jl, dl) = (
                    p.jm_kgm2,
                    p.dm_nms_per_rad,
                    p.kl_nm_per_rad,
                    p.cl_nms_per_rad,
                    p.jl_kgm2,
                    p.dl_nms_per_rad,
                );
                // state: motor angle, motor velocity, load angle, load velocity
                #[rustfmt::skip]
                let a = DMatrix::from_row_slice(4, 4, &[
                    0.0, 1.0, 0.0, 0.0,
                    -kl / jm, -(dm + cl) / jm, kl / jm, cl / jm,
                    0.0, 0.0, 0.0, 1.0,
                    kl / jl, cl / jl, -kl / jl, -(dl + cl) / jl,
                ]);
                (a, vec![0.0, 1.0 / jm, 0.0, 0.0], 1, 2)
            }
        };
        let n = a.nrows();
        // exp([[A, B], [0, 0]] T) = [[Phi, Gamma], [0, 1]]
        let mut m = DMatrix::<f64>::zeros(n + 1, n + 1);
        for i in 0..n {
            for j in 0..n {
                m[(i, j)] = a[(i, j)] * t;
            }
            m[(i, n)] = b[i] * t;
        }
        if !m.iter().all(|x| x.is_finite()) {
            return None;
        }
        let e = m.exp();
        let phi = DMatrix::from_fn(n, n, |i, j| Complex64::new(e[(i, j)], 0.0));
        let gamma = DVector::from_fn(n, |i, _| Complex64::new(e[(i, n)], 0.0));
        Some(Self {
            phi,
            gamma,
            vel,
            pos,
        })
    }

    /// Motor velocity and load position per torque at `z`.
    fn at(&self, z: Complex64) -> Option<(Complex64, Complex64)> {
        let mut k = -self.phi.clone();
        for i in 0..k.nrows() {
            k[(i, i)] += z;
        }
        let x = k.lu().solve(&self.gamma)?;
        Some((x[self.vel], x[self.pos]))
    }
}

/// The plant's own transport delay of axis `i` (`[effects.delay] delay_cycles`), cycles.
pub fn model_delay_cycles(job: &Job, i: usize) -> u32 {
    job.axes[i]
        .model
        .effects
        .get("delay")
        .and_then(|d| d.get("delay_cycles"))
        .and_then(|v| v.as_integer())
        .map_or(0, |n| n.clamp(0, 10_000) as u32)
}

/// Transport delay of the margin check, s: `delay_cycles` (the drive's computation / output
/// delay) plus the model's own `[effects.delay]`, in periods.
pub fn loop_delay_s(job: &Job, i: usize, delay_cycles: u32) -> f64 {
    job.period_s * f64::from(delay_cycles + model_delay_cycles(job, i))
}

#[cfg(test)]
mod tests {
    use super::*;
    use feedloop_model::model::RigidParams;

    fn rigid() -> PlantParams {
        PlantParams::Rigid(RigidParams {
            mass_kg: 20.0,
            viscous_ns_per_m: 50.0,
        })
    }

    #[test]
    fn a_rigid_axis_has_margins_that_fall_with_the_velocity_gain_and_the_delay() {
        let g = |kv: f64| Gains {
            kp_per_s: 50.0,
            kv_nms_per_rad: kv,
            tv_s: 0.01,
        };
        // Kv / m = 200 rad/s crossover: wide phase margin with a 1 ms hold.
        let (pm, gm) = margins(&rigid(), g(4000.0), 1e-3, 0.0).unwrap();
        assert!(pm > 45.0 && gm > 6.0, "{pm} deg, {gm} dB");
        assert!(margin_failure(pm, gm).is_none());
        // A hundred times the gain puts the crossover near Nyquist: unstable with the delay.
        let (pm2, gm2) = margins(&rigid(), g(4.0e5), 1e-3, 1e-3).unwrap();
        assert!(gm2 < 0.0, "{pm2} deg, {gm2} dB");
        assert!(margin_failure(pm2, gm2).unwrap().starts_with("unstable"));
        // Nothing to judge without a velocity gain, or with a non-finite one.
        assert!(margins(&rigid(), g(0.0), 1e-3, 0.0).is_none());
        assert!(margins(&rigid(), g(f64::NAN), 1e-3, 0.0).is_none());
    }

    /// The digital loop on the rigid axis, simulated: P position and PI velocity sampled every
    /// `t`, the torque held, the mass integrated in 100 sub-steps. Whether it diverges.
    fn diverges(kv: f64, tv: f64, t: f64) -> bool {
        let (m, c, kp) = (20.0, 50.0, 50.0);
        let (mut x, mut v, mut integral) = (0.0f64, 0.0f64, 0.0f64);
        for _ in 0..20_000 {
            let e = kp * (1e-3 - x) - v;
            integral += t * e;
            let u = kv * e + if tv > 0.0 { kv / tv * integral } else { 0.0 };
            let h = t / 100.0;
            for _ in 0..100 {
                v += h * (u - c * v) / m;
                x += h * v;
            }
            if v.is_nan() || v.abs() >= 1e6 {
                return true;
            }
        }
        false
    }

    #[test]
    fn the_sampled_loop_model_agrees_with_a_simulation_of_the_digital_loop_near_nyquist() {
        let t = 1e-4;
        // P-only velocity loop: the sampled loop goes unstable near (kv + c) t / m = 2.
        for (kv, tv) in [
            (2.0e5, 0.0),
            (3.2e5, 0.0),
            (5.0e5, 0.0),
            (3.0e5, 0.01),
            (4.5e5, 0.01),
        ] {
            let g = Gains {
                kp_per_s: 50.0,
                kv_nms_per_rad: kv,
                tv_s: tv,
            };
            let (pm, gm) = margins(&rigid(), g, t, 0.0).unwrap();
            let stable_by_model = pm > 0.0 && gm > 0.0;
            assert_eq!(
                stable_by_model,
                !diverges(kv, tv, t),
                "kv {kv}, tv {tv}: model {pm:.1} deg / {gm:.2} dB"
            );
        }
    }

    #[test]
    fn the_loop_gains_come_from_the_position_and_the_velocity_stage() {
        let p = LoopGains {
            kp_per_s: Some(40.0),
            ..Default::default()
        };
        let v = LoopGains {
            kv: Some(5.0),
            tv_s: Some(0.004),
            ..Default::default()
        };
        let none = LoopGains::default();
        // stages in Stage::ALL order: position, feedforward, compensator, velocity
        let g = LoopGains::combine(&[p, none, none, v]).unwrap();
        assert_eq!((g.kp_per_s, g.kv_nms_per_rad, g.tv_s), (40.0, 5.0, 0.004));
        assert!(LoopGains::combine(&[none, none, none, v]).is_none());
    }
}
