//! One body of an axis that may carry dry friction (the motor or the load).

use crate::effects::coulomb_friction::DryLaw;
use crate::effects::{viscous_friction, EffectSet, Viscous};

use super::structure::Structure;
use crate::linear::{dot8, State, MAX_N, NU};

/// One body that may carry friction (the motor or the load).
#[derive(Debug, Clone, Copy)]
pub(super) struct Body {
    pub(super) pos: usize,
    pub(super) vel: usize,
    pub(super) dry: bool,
    pub(super) law: DryLaw,
    /// Explicit direction-dependent viscous part: torque = -c_half |v|.
    pub(super) c_half: f64,
    pub(super) stuck: bool,
    pub(super) dir: f64,
    /// Net torque on the body (without its own friction) = row . x + u_row . u, for spring
    /// [off, on]; the body's own velocity coefficient is zero.
    pub(super) net_row: [[f64; MAX_N]; 2],
    pub(super) net_u: [[f64; NU]; 2],
}

impl Body {
    pub(super) fn inert(pos: usize, vel: usize) -> Self {
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
    pub(super) fn friction(&self, v: f64) -> f64 {
        let av = v.abs();
        let mut t = viscous_friction::asymmetric_torque(self.c_half, av);
        if self.dry && !self.stuck {
            t -= self.dir * self.law.sliding_level(self.dir, av);
        }
        t
    }

    #[inline]
    pub(super) fn net(&self, x: &State, spring: usize, u: &[f64; NU]) -> f64 {
        let ur = &self.net_u[spring & 1];
        dot8(&self.net_row[spring & 1], x) + ((ur[0] * u[0] + ur[1] * u[1]) + ur[2] * u[2])
    }

    #[inline]
    pub(super) fn holds(&self, net: f64) -> bool {
        self.law.holds(net)
    }
}

/// The motor and the load body of an axis of structure `st` with the effects' friction, and
/// how many of them there are (one on a rigid axis): each body's net torque rows, with the
/// spring off and on.
pub(super) fn bodies(st: &Structure, fx: &EffectSet) -> ([Body; 2], usize) {
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
    (bodies, nbodies)
}
