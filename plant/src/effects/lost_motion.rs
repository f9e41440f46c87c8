//! `lost_motion`: an offset between motor and load that follows the direction of travel: the
//! load trails the motor by half the lost motion while moving forward and leads it by as much
//! while moving back, whatever torque is transmitted, and stays where it was at a standstill.
//!
//! Equation: the spring's rest point moves by an offset `e` (motor units): the deflection becomes
//! `d = thM + e - thL`, so the spring torque is `KL (thM + e - thL) + CL (wM - wL)`. The offset
//! relaxes toward `-(L / 2) sign(wM)` (`L` the full lost motion) over the motor's travel, not over
//! time: `de/dthM = (-(L / 2) sign(wM) - e) / s_t`, with `s_t` the transition travel (63 % of a
//! flip). A smooth law of the travel (not a step, so the spring takes no impulse at a reversal;
//! not of the time, so it holds at a standstill, as a play taken up by friction does).
//!
//! Backlash differs: its dead zone follows the sign of the transmitted torque (a braking axis
//! closes the gap on the other flank while still moving forward); lost motion follows the
//! direction of travel (a friction-dragged gear, a coupling's hysteresis, the windup of a long
//! shaft by a load friction the model does not carry).
//!
//! Keys (ball-screw and rotary axes): `lost_motion_m` (ball screw, m at the load) or
//! `lost_motion_rad` (rotary, rad at the load), >= 0, the full offset between the two directions;
//! optional `transition_m` / `transition_rad` (the load travel over which 63 % of a flip
//! happens, at least the lost motion itself, its default: the motor cannot cross the play in less
//! travel than the play, and a faster flip would give the spring a negative stiffness).
//!
//! Typical values: ball screw with a worn nut 5 .. 30 um; a gearbox 1e-4 .. 2e-3 rad at the
//! load.
//!
//! Signature: motor minus load position steps by about `L` over a short travel after each
//! reversal and stays there while the axis moves or stands, the same during acceleration and
//! braking.
//!
//! Integration: the offset is advanced once per period over the motor's travel in that period
//! (velocity at the period start times the period, exactly for the exponential law) and held,
//! as the pitch error's; the spring torque it adds enters as a held input.

use feedloop_model::params::{ConfigError, Fields, Range};

use super::{check_keys, needs_transmission, put, Ctx, EffectTable};

/// `[effects.lost_motion]` as the model file gives it (load units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LostMotionParams {
    /// Full offset between the two directions of travel, load units, >= 0.
    pub lost: f64,
    /// Load travel of a flip (63 %), load units, > 0.
    pub transition: f64,
}

impl EffectTable for LostMotionParams {
    /// Reads `[effects.lost_motion]`.
    fn read(f: &mut Fields<'_>, ctx: &Ctx) -> Result<Self, ConfigError> {
        needs_transmission(f, ctx, "lost_motion")?;
        let u = ctx.load_units();
        let (lost_key, tr_key) = (
            format!("lost_motion_{}", u.pos),
            format!("transition_{}", u.pos),
        );
        check_keys(f, &[&lost_key, &tr_key])?;
        let lost = f.f64(&lost_key, Range::NonNegative)?;
        let transition = match f.opt_f64(&tr_key, Range::Positive)? {
            Some(t) if t < lost => {
                return Err(f.error(
                    &tr_key,
                    format!(
                        "must be at least {lost_key} = {lost} (the motor crosses the play by travelling it; a shorter transition would give the spring a negative stiffness), got {t}"
                    ),
                ))
            }
            Some(t) => t,
            None => lost,
        };
        Ok(Self { lost, transition })
    }

    /// The model-file table.
    fn to_table(&self, ctx: &Ctx) -> toml::Table {
        let u = ctx.load_units();
        let mut t = toml::Table::new();
        put(&mut t, format!("lost_motion_{}", u.pos), self.lost);
        put(&mut t, format!("transition_{}", u.pos), self.transition);
        t
    }
}

impl LostMotionParams {
    /// The law in motor units (`None` for no lost motion).
    pub(crate) fn motor(&self, ctx: &Ctx) -> Option<LostMotion> {
        let k = ctx.load_units().vel_to_motor;
        (self.lost > 0.0 && self.transition > 0.0).then_some(LostMotion {
            half: 0.5 * self.lost * k,
            travel: self.transition * k,
        })
    }
}

/// The lost-motion law as the integrator evaluates it (motor units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LostMotion {
    /// Half the full offset, motor units.
    half: f64,
    /// Transition travel, motor units.
    travel: f64,
}

impl LostMotion {
    /// The offset after a travel at velocity `wm` for `dt` seconds from offset `e` (motor units):
    /// it relaxes toward `-half sign(wm)` by `1 - exp(-|wm| dt / travel)`; unchanged at rest.
    #[inline]
    pub fn advance(&self, e: f64, wm: f64, dt: f64) -> f64 {
        let target = if wm > 0.0 {
            -self.half
        } else if wm < 0.0 {
            self.half
        } else {
            return e;
        };
        let next = target + (e - target) * (-(wm.abs() * dt) / self.travel).exp();
        if next.is_finite() {
            next
        } else {
            e
        }
    }

    /// The offsets along a series of motor positions `q` (motor units), from a centred start:
    /// the state a window restarted from measured positions cannot measure, replayed from the
    /// travel that led to it.
    pub fn series(&self, q: &[f64]) -> Vec<f64> {
        let mut e = 0.0;
        let mut prev = q.first().copied().unwrap_or(0.0);
        q.iter()
            .map(|&x| {
                e = self.advance(e, x - prev, 1.0);
                prev = x;
                e
            })
            .collect()
    }

    /// The settled offset of an axis moving at `wm` (0 at rest: centred).
    #[inline]
    pub fn settled(&self, wm: f64) -> f64 {
        self.advance(0.0, wm, f64::INFINITY)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_offset_follows_the_travel_holds_at_rest_and_is_smooth() {
        let l = LostMotion {
            half: 1e-3,
            travel: 0.01,
        };
        // moving forward the load trails (a negative rest-point offset), back it leads
        assert!((l.settled(5.0) + 1e-3).abs() < 1e-15);
        assert!((l.settled(-5.0) - 1e-3).abs() < 1e-15);
        assert_eq!(l.settled(0.0), 0.0);
        // at a standstill it holds what the last travel left
        assert_eq!(l.advance(-7e-4, 0.0, 1.0), -7e-4);
        // a travel of one transition takes 63 % of the way, whatever the speed
        let slow = l.advance(1e-3, 0.01, 1.0);
        let fast = l.advance(1e-3, 1.0, 0.01);
        let expect = -1e-3 + 2e-3 * (-1.0f64).exp();
        assert!((slow - expect).abs() < 1e-15 && (fast - expect).abs() < 1e-15);
        assert!(l.advance(2e-4, f64::NAN, 1e-3).is_finite());
    }
}
