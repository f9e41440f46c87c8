//! `third_mass`: a mass on a spring behind the load (a heavy fixture, a tool slide on a saddle,
//! the machine bed): a second resonance.
//!
//! Equation (load position `xL`, third-mass position `x3`, load units):
//! `m3 x3'' = k3 (xL - x3) + c3 (vL - v3)`; the load feels the opposite force.
//! Reflected to the motor of a ball screw: `J3 = m3 / r^2`, `K3 = k3 / r^2`, `C3 = c3 / r^2`
//! with `r = 2 pi gear / lead` rad per m.
//!
//! Keys: ball screw and rigid: `mass_kg` (> 0), `stiffness_n_per_m` (> 0), optional
//! `damping_ns_per_m` (>= 0, default 0); rotary: `inertia_kgm2`, `stiffness_nm_per_rad`,
//! optional `damping_nms_per_rad`.
//!
//! Typical values: 20 .. 500 kg on 1e7 .. 1e8 N/m (50 .. 300 Hz), damping ratio 1 .. 5 %.
//!
//! Signature: a second anti-resonance/resonance pair in the torque -> motor velocity frequency
//! response, near `sqrt(k3/m3)` (anti-resonance seen from the load) and above it.
//!
//! Integration: two more states of the exactly discretised linear part (exact).

use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};
use nalgebra::DMatrix;

use super::{check_keys, put, Ctx, EffectTable};

/// The third mass in motor units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ThirdMass {
    /// Inertia, kg m^2 (kg on a rigid axis).
    pub inertia: f64,
    /// Stiffness, N m/rad (N/m).
    pub stiffness: f64,
    /// Damping, N m s/rad (N s/m).
    pub damping: f64,
}

/// Adds the third mass (position state `i3`, inertia `j3`, stiffness `k3`, damping `c3`, motor
/// units) to the continuous `A`, hung on the load (position and velocity states `load`, inertia
/// `jload`).
pub(crate) fn stamp(
    a: &mut DMatrix<f64>,
    load: (usize, usize),
    jload: f64,
    (i3, j3, k3, c3): (usize, f64, f64, f64),
) {
    let (lp, lv) = load;
    let v3 = i3 + 1;
    a[(i3, v3)] = 1.0;
    a[(lv, lp)] -= k3 / jload;
    a[(lv, i3)] += k3 / jload;
    a[(lv, lv)] -= c3 / jload;
    a[(lv, v3)] += c3 / jload;
    a[(v3, lp)] += k3 / j3;
    a[(v3, i3)] -= k3 / j3;
    a[(v3, lv)] += c3 / j3;
    a[(v3, v3)] -= c3 / j3;
}

/// `[effects.third_mass]` in load units: kg, N/m and N s/m on a linear axis, kg m^2, N m/rad and
/// N m s/rad on a rotary one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThirdMassParams {
    /// Mass or inertia, > 0.
    pub mass: f64,
    /// Stiffness of its spring, > 0.
    pub stiffness: f64,
    /// Damping of its spring (default 0).
    pub damping: f64,
}

/// Keys (mass, stiffness, damping) on an axis of `kind`.
fn keys(kind: AxisKind) -> (&'static str, &'static str, &'static str) {
    if kind == AxisKind::Rotary {
        (
            "inertia_kgm2",
            "stiffness_nm_per_rad",
            "damping_nms_per_rad",
        )
    } else {
        ("mass_kg", "stiffness_n_per_m", "damping_ns_per_m")
    }
}

impl EffectTable for ThirdMassParams {
    /// Reads `[effects.third_mass]`.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        let (km, kk, kc) = keys(ctx.kind);
        check_keys(f, &[km, kk, kc])?;
        let mass = f.f64(km, Range::Positive)?;
        let stiffness = f.f64(kk, Range::Positive)?;
        let damping = f.f64_or(kc, Range::NonNegative, 0.0)?;
        Ok(Self {
            mass,
            stiffness,
            damping,
        })
    }

    /// The model-file table.
    fn to_table(&self, ctx: &Ctx) -> toml::Table {
        let (km, kk, kc) = keys(ctx.kind);
        let mut t = toml::Table::new();
        put(&mut t, km, self.mass);
        put(&mut t, kk, self.stiffness);
        put(&mut t, kc, self.damping);
        t
    }
}

impl ThirdMassParams {
    /// In motor units.
    pub(crate) fn motor(&self, ctx: &Ctx) -> ThirdMass {
        let r2 = ctx.load_units().vel_to_motor.powi(2);
        ThirdMass {
            inertia: self.mass / r2,
            stiffness: self.stiffness / r2,
            damping: self.damping / r2,
        }
    }
}
