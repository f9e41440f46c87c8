//! The first measurements: slow traverses at several speeds in both directions give the
//! friction curve of each direction (Coulomb, viscous and Stribeck), the noise floor at
//! standstill and the lost motion at the reversals; short fast moves give the total inertia.

use feedloop_trace::log::AxisRecord;
use serde::Serialize;

use super::device::{Device, Recording};
use super::facts::{cascade, experiment, per_axis, Facts};
use super::Notes;
use crate::workbench::signal::{mean, std_dev};

/// The friction of one direction, motor side: `T(w) = fc + (fs - fc) exp(-(w / vs)^e) + d w`.
#[derive(Debug, Clone, Copy, Serialize, Default)]
pub struct FrictionSide {
    /// Coulomb (sliding) level, N m.
    pub coulomb_nm: f64,
    /// Static (breakaway) level, N m.
    pub static_nm: f64,
    /// Stribeck velocity, rad/s (motor).
    pub stribeck_rad_per_s: f64,
    /// Shape exponent.
    pub exponent: f64,
    /// Viscous coefficient, N m s/rad.
    pub viscous_nms_per_rad: f64,
    /// Root-mean-square residual of the fit, N m.
    pub residual_nm: f64,
}

impl FrictionSide {
    /// The friction torque at motor speed `w` >= 0, N m.
    pub fn at(&self, w: f64) -> f64 {
        self.coulomb_nm
            + (self.static_nm - self.coulomb_nm)
                * (-(w / self.stribeck_rad_per_s).powf(self.exponent)).exp()
            + self.viscous_nms_per_rad * w
    }
}

/// The friction of both directions, with the measured points.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Friction {
    /// Positive velocity.
    pub positive: FrictionSide,
    /// Negative velocity (levels as magnitudes).
    pub negative: FrictionSide,
    /// Measured points `(motor speed rad/s, torque magnitude N m)` of the positive direction.
    pub points_positive: Vec<(f64, f64)>,
    /// The same of the negative direction.
    pub points_negative: Vec<(f64, f64)>,
}

impl Friction {
    /// Signed friction torque at signed motor velocity `w`.
    pub fn signed(&self, w: f64) -> f64 {
        if w >= 0.0 {
            self.positive.at(w)
        } else {
            -self.negative.at(-w)
        }
    }

    /// Mean Coulomb level of the two directions, N m.
    pub fn coulomb_nm(&self) -> f64 {
        0.5 * (self.positive.coulomb_nm + self.negative.coulomb_nm)
    }

    /// Speed (rad/s) above which both directions slide at their Coulomb level (three Stribeck
    /// velocities).
    pub fn sliding_rad_per_s(&self) -> f64 {
        3.0 * self
            .positive
            .stribeck_rad_per_s
            .max(self.negative.stribeck_rad_per_s)
    }
}

/// What the traverses found.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Survey {
    /// Friction per direction.
    pub friction: Friction,
    /// Standard deviation of the motor velocity at standstill, rad/s.
    pub noise_rad_per_s: f64,
    /// Lost motion at the reversals of the slow traverses (motor less load position, m).
    pub lost_motion_m: f64,
    /// Total inertia JM + JL from the accelerations, kg m^2.
    pub total_inertia_kgm2: f64,
}

/// Table speeds of the traverses, m/s: from below any Stribeck velocity to the sliding range.
const SPEEDS_M_PER_S: [f64; 10] = [5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 4e-2];

/// Runs the traverses and the inertia moves, fits the friction.
pub fn survey(
    dev: &mut dyn Device,
    f: &Facts,
    axis: &str,
    notes: &mut Notes,
) -> Result<Survey, String> {
    let ratio = f.ratio();
    let mut pos = Vec::new();
    let mut neg = Vec::new();
    let mut lost = Vec::new();
    let mut noise = 0.0;
    for (i, &v) in SPEEDS_M_PER_S.iter().enumerate() {
        let v = v.min(0.4 * f.travel_m);
        let constant_s = (0.3 * f.travel_m / v).clamp(0.3, 1.2);
        let mut t = toml::Table::new();
        t.insert("kind".into(), "ramp".into());
        t.insert("velocity_m_per_s".into(), per_axis(axis, v));
        t.insert("accel_s".into(), toml::Value::Float(0.05));
        t.insert("constant_s".into(), toml::Value::Float(constant_s));
        t.insert("return".into(), toml::Value::Boolean(true));
        t.insert(
            "dwell_before_s".into(),
            toml::Value::Float(if i == 0 { 0.5 } else { 0.05 }),
        );
        t.insert("dwell_between_s".into(), toml::Value::Float(0.1));
        t.insert("dwell_after_s".into(), toml::Value::Float(0.05));
        let name = format!("traverse {:.3} mm/s", v * 1e3);
        let exp = experiment(
            &name,
            f,
            &[axis],
            cascade(axis, f.start),
            t,
            f.bounds(5.0 * v / f.start.kp_per_s + 1e-3),
        );
        let rec = dev.run(&exp)?;
        notes.push(
            &name,
            &rec,
            "friction at this speed in both directions, lost motion at the reversal",
        );
        if let Some(why) = &rec.stopped {
            return Err(why.clone());
        }
        let r = &rec.records[0];
        if i == 0 {
            let n = (0.4 / rec.period_s) as usize;
            noise = std_dev(&r.iter().take(n).map(|x| x.motor_vel).collect::<Vec<_>>());
        }
        let w = constant_windows(r, v, rec.period_s);
        for (a, b, s) in &w {
            let seg = &r[*a..*b];
            let torque = mean(&seg.iter().map(|x| x.torque).collect::<Vec<_>>());
            let speed =
                (seg[seg.len() - 1].motor - seg[0].motor) / ((b - a - 1) as f64 * rec.period_s);
            let p = (speed.abs(), torque * s);
            if *s > 0.0 {
                pos.push(p)
            } else {
                neg.push(p)
            }
        }
        if v <= 2e-3 {
            if let [(a0, b0, _), (a1, b1, _), ..] = w.as_slice() {
                let d = |a: usize, b: usize| {
                    mean(
                        &r[a..b]
                            .iter()
                            .map(|x| x.motor / ratio - x.load)
                            .collect::<Vec<_>>(),
                    )
                };
                lost.push((d(*a0, *b0) - d(*a1, *b1)).abs());
            }
        }
    }
    let friction = Friction {
        positive: fit_side(&pos),
        negative: fit_side(&neg),
        points_positive: pos,
        points_negative: neg,
    };
    lost.sort_by(f64::total_cmp);
    let lost_motion_m = lost.get(lost.len() / 2).copied().unwrap_or(0.0);
    let total = inertia(dev, f, axis, &friction, notes)?;
    Ok(Survey {
        friction,
        noise_rad_per_s: noise,
        lost_motion_m,
        total_inertia_kgm2: total,
    })
}

/// The settled halves of the windows where the command moves at +-`v` (start, end, sign).
fn constant_windows(r: &[AxisRecord], v: f64, dt: f64) -> Vec<(usize, usize, f64)> {
    let mut out = Vec::new();
    let mut k = 1;
    while k < r.len() {
        let vel = |k: usize| (r[k].cmd - r[k - 1].cmd) / dt;
        if (vel(k).abs() - v).abs() < 1e-3 * v {
            let s = vel(k).signum();
            let a = k;
            while k < r.len() && (vel(k) - s * v).abs() < 1e-3 * v {
                k += 1;
            }
            if k - a > 100 {
                out.push(((a + k) / 2, k, s));
            }
        }
        k += 1;
    }
    out
}

/// Least squares of `T = c0 + c1 exp(-(w/vs)^e) + c2 w` over a grid of `vs` and `e`.
fn fit_side(p: &[(f64, f64)]) -> FrictionSide {
    let mut best = FrictionSide {
        residual_nm: f64::INFINITY,
        ..Default::default()
    };
    for e in [1.0, 1.5, 2.0] {
        for i in 0..=80 {
            let vs = 1e-3 * 10f64.powf(i as f64 * 5.0 / 80.0);
            let rows: Vec<[f64; 3]> = p
                .iter()
                .map(|(w, _)| [1.0, (-(w / vs).powf(e)).exp(), *w])
                .collect();
            let y: Vec<f64> = p.iter().map(|(_, t)| *t).collect();
            let Some(c) = least_squares(&rows, &y) else {
                continue;
            };
            if c[1] < 0.0 || c[0] < 0.0 {
                continue;
            }
            let side = FrictionSide {
                coulomb_nm: c[0],
                static_nm: c[0] + c[1],
                stribeck_rad_per_s: vs,
                exponent: e,
                viscous_nms_per_rad: c[2],
                residual_nm: 0.0,
            };
            let res = (p
                .iter()
                .map(|(w, t)| (side.at(*w) - t).powi(2))
                .sum::<f64>()
                / p.len().max(1) as f64)
                .sqrt();
            if res < best.residual_nm {
                best = FrictionSide {
                    residual_nm: res,
                    ..side
                };
            }
        }
    }
    best
}

/// Least squares of three columns (normal equations).
fn least_squares(rows: &[[f64; 3]], y: &[f64]) -> Option<[f64; 3]> {
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    for (r, yv) in rows.iter().zip(y) {
        let v = nalgebra::Vector3::from_row_slice(r);
        a += v * v.transpose();
        b += v * *yv;
    }
    let x = a.lu().solve(&b)?;
    Some([x[0], x[1], x[2]])
}

/// Total inertia from short fast moves: `J = sum a (T - F(w)) / sum a^2` over the samples of
/// large acceleration (motor position differenced over 1 ms).
fn inertia(
    dev: &mut dyn Device,
    f: &Facts,
    axis: &str,
    fr: &Friction,
    notes: &mut Notes,
) -> Result<f64, String> {
    let ratio = f.ratio();
    // Accelerate 10 times the motor inertia to a third of the torque limit at most.
    let a_max = 0.3 * f.torque_limit_nm / (10.0 * f.jm_kgm2) / ratio;
    let v = (0.04f64).min(0.3 * f.travel_m);
    let accel_s = (1.9 * v / a_max).max(0.02);
    let mut t = toml::Table::new();
    t.insert("kind".into(), "ramp".into());
    t.insert("velocity_m_per_s".into(), per_axis(axis, v));
    t.insert("accel_s".into(), toml::Value::Float(accel_s));
    t.insert("constant_s".into(), toml::Value::Float(0.05));
    t.insert("return".into(), toml::Value::Boolean(true));
    t.insert("cycles".into(), toml::Value::Integer(3));
    t.insert("dwell_between_s".into(), toml::Value::Float(0.05));
    t.insert("dwell_after_s".into(), toml::Value::Float(0.05));
    let name = "inertia moves";
    let exp = experiment(name, f, &[axis], cascade(axis, f.start), t, f.bounds(0.02));
    let rec: Recording = dev.run(&exp)?;
    notes.push(
        name,
        &rec,
        "total inertia from the torque during the accelerations",
    );
    if let Some(why) = &rec.stopped {
        return Err(why.clone());
    }
    let r = &rec.records[0];
    let m = (1e-3 / rec.period_s).round().max(1.0) as usize;
    let h = m as f64 * rec.period_s;
    let mut acc = Vec::new();
    for k in m..r.len().saturating_sub(m) {
        let a = (r[k + m].motor - 2.0 * r[k].motor + r[k - m].motor) / (h * h);
        let w = (r[k + m].motor - r[k - m].motor) / (2.0 * h);
        let torque = mean(
            &r[k - m / 2..k + m / 2 + 1]
                .iter()
                .map(|x| x.torque)
                .collect::<Vec<_>>(),
        );
        acc.push((a, torque - fr.signed(w)));
    }
    let peak = acc.iter().map(|(a, _)| a.abs()).fold(0.0, f64::max);
    let (num, den) = acc
        .iter()
        .filter(|(a, _)| a.abs() > 0.5 * peak)
        .fold((0.0, 0.0), |(n, d), (a, t)| (n + a * t, d + a * a));
    if den <= 0.0 {
        return Err("the inertia moves did not accelerate the axis".into());
    }
    Ok(num / den)
}
