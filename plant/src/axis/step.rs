//! One period of an axis: the held torques, the sub-steps and the events located in them.

use crate::effects::{backlash, current_lag, torque_saturation};
use crate::linear::{State, MAX_N, NU};

use super::body::Body;
use super::{AxisPlant, FINE_LEVELS, MAX_BISECTIONS, TORQUE_BOUND};

impl AxisPlant {
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
