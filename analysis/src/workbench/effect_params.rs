//! An effect's regressor coefficients and the model file's typed parameters
//! ([`EffectParams`]), both ways: the one place where the workbench's form of an effect meets the
//! plant library's (no key is spelled here: the plant's typed form writes and reads them).

use std::f64::consts::PI;

use feedloop_model::model::AxisKind;
use feedloop_plant::effects::{
    BacklashParams, CoggingParams, CoggingPeriod, ConstantForceParams, CoulombFrictionParams, Ctx,
    CurrentLagParams, DelayParams, DirectionalFrictionParams, EffectParams, LostMotionParams,
    PitchErrorParams, StribeckFrictionParams, ThirdMassParams, TorqueSaturationParams,
    UnbalanceParams, ViscousFrictionParams,
};

use super::effects::{constant_force_value, round_sig, Effect, EffectId, Side};

impl Effect {
    /// The model file's typed form of this effect (SI, the units the plant library documents).
    /// One arm per effect, the mirror of [`Effect::from_params`].
    pub fn to_params(&self, kind: AxisKind, r: f64) -> EffectParams {
        let (tf, vf) = side_factors(kind, self.side, r);
        let side = self.side;
        match self.id {
            EffectId::ViscousFriction => {
                let c = self.coef[0] * tf / vf;
                EffectParams::ViscousFriction(ViscousFrictionParams { side, c, c_neg: c })
            }
            EffectId::CoulombFriction => {
                let (s, a) = (self.coef[0], self.coef[1]);
                let fc = (s + a) * tf;
                // an asymmetry below 1e-12 of the level is rounding, not a second level
                let fc_neg = if a.abs() > 1e-12 * s.abs().max(1e-300) {
                    (s - a) * tf
                } else {
                    fc
                };
                EffectParams::CoulombFriction(CoulombFrictionParams { side, fc, fc_neg })
            }
            EffectId::StribeckFriction => {
                let fc = self.coef[0] * tf;
                let fs = (self.coef[0] + self.coef[1].max(0.0)) * tf;
                EffectParams::StribeckFriction(StribeckFrictionParams {
                    side,
                    fc,
                    fs,
                    fc_neg: fc,
                    fs_neg: fs,
                    vs: self.hyper[0] * vf,
                    exponent: self.hyper[1],
                })
            }
            EffectId::ConstantForce => EffectParams::ConstantForce(ConstantForceParams {
                value: constant_force_value(self.coef[0], kind, r),
            }),
            EffectId::Cogging => {
                let (a, b) = (self.coef[0], self.coef[1]);
                EffectParams::Cogging(CoggingParams {
                    amplitude: a.hypot(b),
                    period: match kind {
                        AxisKind::Rigid => CoggingPeriod::Metres(self.hyper[0]),
                        AxisKind::BallScrew | AxisKind::Rotary => {
                            CoggingPeriod::PerRev((2.0 * PI / self.hyper[0]).round() as i64)
                        }
                    },
                    phase_rad: (-b).atan2(-a),
                })
            }
            EffectId::ThirdMass => {
                let w = 2.0 * PI * self.hyper[0];
                let (m, f) = (self.coef[0].max(0.0), third_mass_factor(kind, r));
                EffectParams::ThirdMass(ThirdMassParams {
                    mass: m * f,
                    stiffness: m * f * w * w,
                    damping: 2.0 * self.hyper[1] * w * m * f,
                })
            }
            EffectId::Delay => EffectParams::Delay(DelayParams {
                cycles: self.hyper[0].round() as i64,
            }),
            EffectId::CurrentLag => EffectParams::CurrentLag(CurrentLagParams {
                tau_s: self.hyper[0],
            }),
            EffectId::TorqueSaturation => EffectParams::TorqueSaturation(TorqueSaturationParams {
                limit: self.hyper[0],
            }),
            EffectId::Backlash => EffectParams::Backlash(self.backlash_params(kind, r)),
            EffectId::PitchError => EffectParams::PitchError(self.pitch_params(r)),
            EffectId::Unbalance => EffectParams::Unbalance(self.unbalance_params(r)),
            EffectId::LostMotion => EffectParams::LostMotion(self.lost_motion_params(kind, r)),
            EffectId::DirectionalFriction => {
                let c = &self.coef;
                EffectParams::DirectionalFriction(DirectionalFrictionParams {
                    side,
                    fc_pos: c[0] * tf,
                    fc_neg: c[1] * tf,
                    c_pos: c[2] * tf / vf,
                    c_neg: c[3] * tf / vf,
                })
            }
        }
    }

    /// The model file's form of an `unbalance` effect: the needed torque `a sin + b cos + k`
    /// (motor units) is minus the load's torque `constant - mgr sin(thL - zero)` through the gear.
    pub(crate) fn unbalance_params(&self, r: f64) -> UnbalanceParams {
        let (a, b, k) = (self.coef[0], self.coef[1], self.coef[2]);
        let period = self.hyper[0];
        UnbalanceParams {
            mgr_nm: r * a.hypot(b),
            zero_angle_rad: (-b).atan2(a) * period / (2.0 * PI),
            constant_nm: -r * k,
            period_rad: period,
        }
    }

    /// The model file's form of a `backlash` effect: the full gap at the load.
    pub(crate) fn backlash_params(&self, kind: AxisKind, r: f64) -> BacklashParams {
        BacklashParams {
            gap: match kind {
                AxisKind::BallScrew | AxisKind::Rotary => (2.0 * self.coef[0] / r).max(0.0),
                AxisKind::Rigid => (2.0 * self.coef[0]).max(0.0),
            },
        }
    }

    /// The model file's form of a `lost_motion` effect: the full offset and the transition
    /// velocity at the load.
    pub(crate) fn lost_motion_params(&self, kind: AxisKind, r: f64) -> LostMotionParams {
        let r = match kind {
            AxisKind::BallScrew | AxisKind::Rotary => r,
            AxisKind::Rigid => 1.0,
        };
        LostMotionParams {
            lost: (2.0 * self.coef[0] / r).max(0.0),
            transition: self
                .hyper
                .first()
                .copied()
                .unwrap_or(2.0 * self.coef[0])
                .abs()
                / r,
        }
    }

    /// The model file's form of a `pitch_error` effect.
    pub(crate) fn pitch_params(&self, r: f64) -> PitchErrorParams {
        // the deflection carries minus the lead error (the motor angle makes up for it)
        let (a, b) = (-self.coef[0], -self.coef[1]);
        PitchErrorParams {
            amplitude_m: a.hypot(b) / r,
            period_m: self.hyper[0],
            phase_rad: b.atan2(a),
            slope_um_per_m: -self.coef[2] * 1e6,
        }
    }

    /// Model-file keys and values of this effect, rounded to 7 significant digits.
    pub fn to_table(&self, kind: AxisKind, r: f64) -> toml::Table {
        let ctx = Ctx {
            kind,
            motor_per_load: r,
            lead_m: None,
        };
        let mut t = self.to_params(kind, r).to_table(&ctx);
        for (_, v) in t.iter_mut() {
            if let toml::Value::Float(x) = v {
                *x = round_sig(*x);
            }
        }
        t
    }

    /// The regressor form of an effect of a model file. One arm per effect, the mirror of
    /// [`Effect::to_params`].
    pub fn from_params(p: &EffectParams, kind: AxisKind, r: f64) -> Self {
        let side = p.side().unwrap_or(Side::Motor);
        let (tf, vf) = side_factors(kind, side, r);
        let mut e = Effect::new(p.id(), side, vec![]);
        match p {
            EffectParams::ViscousFriction(p) => e.coef = vec![0.5 * (p.c + p.c_neg) * vf / tf],
            EffectParams::CoulombFriction(p) => {
                e.coef = vec![0.5 * (p.fc + p.fc_neg) / tf, 0.5 * (p.fc - p.fc_neg) / tf];
            }
            EffectParams::StribeckFriction(p) => {
                e.hyper = vec![p.vs / vf, p.exponent];
                e.coef = vec![p.fc / tf, (p.fs - p.fc) / tf];
            }
            EffectParams::ConstantForce(p) => {
                e.coef = vec![match kind {
                    AxisKind::BallScrew | AxisKind::Rotary => -p.value / r,
                    AxisKind::Rigid => -p.value,
                }];
            }
            EffectParams::Cogging(p) => {
                e.hyper = vec![match p.period {
                    CoggingPeriod::Metres(period) => period,
                    CoggingPeriod::PerRev(n) => 2.0 * PI / n as f64,
                }];
                e.coef = vec![
                    -p.amplitude * p.phase_rad.cos(),
                    -p.amplitude * p.phase_rad.sin(),
                ];
            }
            EffectParams::ThirdMass(p) => {
                let w = (p.stiffness / p.mass).sqrt();
                e.hyper = vec![w / (2.0 * PI), p.damping / (2.0 * p.mass * w)];
                e.coef = vec![p.mass / third_mass_factor(kind, r)];
            }
            EffectParams::Delay(p) => e.hyper = vec![p.cycles as f64],
            EffectParams::CurrentLag(p) => e.hyper = vec![p.tau_s],
            EffectParams::TorqueSaturation(p) => e.hyper = vec![p.limit],
            EffectParams::Backlash(p) => {
                e.coef = vec![match kind {
                    AxisKind::BallScrew | AxisKind::Rotary => 0.5 * p.gap * r,
                    AxisKind::Rigid => 0.5 * p.gap,
                }];
            }
            EffectParams::LostMotion(p) => {
                let r = match kind {
                    AxisKind::BallScrew | AxisKind::Rotary => r,
                    AxisKind::Rigid => 1.0,
                };
                e.hyper = vec![p.transition * r];
                e.coef = vec![0.5 * p.lost * r];
            }
            EffectParams::DirectionalFriction(p) => {
                e.coef = vec![
                    p.fc_pos / tf,
                    p.fc_neg / tf,
                    p.c_pos * vf / tf,
                    p.c_neg * vf / tf,
                ];
            }
            EffectParams::Unbalance(p) => {
                e.hyper = vec![p.period_rad];
                let (s, c) = (2.0 * PI * p.zero_angle_rad / p.period_rad).sin_cos();
                e.coef = vec![p.mgr_nm * c / r, -p.mgr_nm * s / r, -p.constant_nm / r];
            }
            EffectParams::PitchError(p) => {
                let a = p.amplitude_m * r;
                let ph = p.phase_rad;
                e.hyper = vec![p.period_m];
                e.coef = vec![-a * ph.cos(), -a * ph.sin(), -p.slope_um_per_m * 1e-6];
            }
        }
        e
    }
}

/// Factors from motor-unit torque and velocity to the units of the keys of a friction table on
/// `side` (N and m/s on a linear body, else N m and rad/s).
fn side_factors(kind: AxisKind, side: Side, r: f64) -> (f64, f64) {
    let through_r = match kind {
        AxisKind::Rigid => true,
        AxisKind::BallScrew | AxisKind::Rotary => side == Side::Load,
    };
    if through_r {
        let rr = if kind == AxisKind::Rigid { 1.0 } else { r };
        (rr, 1.0 / rr)
    } else {
        (1.0, 1.0)
    }
}

/// Factor from a third mass in motor units to the model file's (`r^2` on a ball screw).
pub(crate) fn third_mass_factor(kind: AxisKind, r: f64) -> f64 {
    match kind {
        AxisKind::BallScrew | AxisKind::Rotary => r * r,
        AxisKind::Rigid => 1.0,
    }
}
