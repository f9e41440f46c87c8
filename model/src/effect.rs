//! The effects a model file may switch on with `[effects.<id>]`, and the body an effect acts on.
//!
//! [`EffectId`] is the one list of effects: the plant (`feedloop-plant`), the model workbench and
//! the command line all read it. The ids are a user-facing contract (model files name them):
//! never rename one. Each effect's law lives in its own file in `plant/src/effects/`, its
//! regressor form in `analysis/src/workbench/effects.rs`.

use std::fmt;

use crate::model::AxisKind;

/// One effect of the physics library.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum EffectId {
    /// `viscous_friction`: friction proportional to velocity.
    ViscousFriction,
    /// `coulomb_friction`: dry friction of constant magnitude, with sticking.
    CoulombFriction,
    /// `stribeck_friction`: dry friction with a breakaway level above the sliding level.
    StribeckFriction,
    /// `backlash`: a dead zone in the transmission.
    Backlash,
    /// `pitch_error`: lead error of the ball screw.
    PitchError,
    /// `cogging`: detent torque periodic in motor angle.
    Cogging,
    /// `constant_force`: a constant force on the load.
    ConstantForce,
    /// `third_mass`: a mass on a spring behind the load.
    ThirdMass,
    /// `delay`: transport delay of the torque command.
    Delay,
    /// `current_lag`: first-order lag of the current loop.
    CurrentLag,
    /// `torque_saturation`: the drive's torque clamp.
    TorqueSaturation,
    /// `unbalance`: a load torque of the axis' own angle (gravity on a rotary load).
    Unbalance,
    /// `directional_friction`: dry and viscous friction that differ between the directions.
    DirectionalFriction,
    /// `lost_motion`: a motor-to-load offset that flips with the direction of travel.
    LostMotion,
}

impl EffectId {
    /// Every effect, in the order error messages list them.
    pub const ALL: [EffectId; 14] = [
        EffectId::ViscousFriction,
        EffectId::CoulombFriction,
        EffectId::StribeckFriction,
        EffectId::Backlash,
        EffectId::PitchError,
        EffectId::Cogging,
        EffectId::ConstantForce,
        EffectId::ThirdMass,
        EffectId::Delay,
        EffectId::CurrentLag,
        EffectId::TorqueSaturation,
        EffectId::Unbalance,
        EffectId::DirectionalFriction,
        EffectId::LostMotion,
    ];

    /// Name used in model files (`[effects.<id>]`) and on the command line.
    pub fn id(self) -> &'static str {
        match self {
            EffectId::ViscousFriction => "viscous_friction",
            EffectId::CoulombFriction => "coulomb_friction",
            EffectId::StribeckFriction => "stribeck_friction",
            EffectId::Backlash => "backlash",
            EffectId::PitchError => "pitch_error",
            EffectId::Cogging => "cogging",
            EffectId::ConstantForce => "constant_force",
            EffectId::ThirdMass => "third_mass",
            EffectId::Delay => "delay",
            EffectId::CurrentLag => "current_lag",
            EffectId::TorqueSaturation => "torque_saturation",
            EffectId::Unbalance => "unbalance",
            EffectId::DirectionalFriction => "directional_friction",
            EffectId::LostMotion => "lost_motion",
        }
    }

    /// Parses an effect id.
    pub fn parse(s: &str) -> Option<EffectId> {
        EffectId::ALL.into_iter().find(|e| e.id() == s)
    }

    /// Whether a model file may give it several times (`[[effects.<id>]]`).
    pub fn repeatable(self) -> bool {
        matches!(
            self,
            EffectId::ViscousFriction
                | EffectId::CoulombFriction
                | EffectId::StribeckFriction
                | EffectId::Cogging
        )
    }

    /// The effect it contains and so replaces on the same body instead of adding to it:
    /// Stribeck friction is Coulomb friction with a hump at low speed.
    pub fn supersedes(self) -> Option<EffectId> {
        match self {
            EffectId::StribeckFriction | EffectId::DirectionalFriction => {
                Some(EffectId::CoulombFriction)
            }
            _ => None,
        }
    }

    /// Whether it acts on a [`Side`] chosen by its `side` key (the friction effects).
    pub fn has_side(self) -> bool {
        matches!(
            self,
            EffectId::ViscousFriction
                | EffectId::CoulombFriction
                | EffectId::StribeckFriction
                | EffectId::DirectionalFriction
        )
    }

    /// `; did you mean `ID`?` for a misspelled effect id close to one of the library (see
    /// [`crate::params::nearest`]), else empty.
    pub fn did_you_mean(typed: &str) -> String {
        crate::params::nearest(typed, EffectId::ALL.into_iter().map(EffectId::id))
            .map(|id| format!("; did you mean `{id}`?"))
            .unwrap_or_default()
    }

    /// The ids of the effects `keep` selects, comma-separated in [`EffectId::ALL`] order (for
    /// messages).
    pub fn list(keep: impl Fn(EffectId) -> bool) -> String {
        EffectId::ALL
            .into_iter()
            .filter(|e| keep(*e))
            .map(EffectId::id)
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl fmt::Display for EffectId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.id())
    }
}

/// Which body of the axis a friction effect acts on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// The motor (rotor, coupling, screw): N m and rad/s on rotary motors, N and m/s on a rigid axis.
    Motor,
    /// The load (table, rotary load): N and m/s on a ball-screw table, N m and rad/s on a rotary
    /// load. On a rigid axis motor and load are the same mass.
    Load,
}

impl Side {
    /// Name used in model files (the `side` key).
    pub fn id(self) -> &'static str {
        match self {
            Side::Motor => "motor",
            Side::Load => "load",
        }
    }

    /// Parses a side name.
    pub fn parse(s: &str) -> Option<Side> {
        [Side::Motor, Side::Load].into_iter().find(|x| x.id() == s)
    }

    /// Index of the body this side acts on: 0 motor, 1 load (a rigid axis has only body 0).
    pub fn body(self, kind: AxisKind) -> usize {
        match (self, kind) {
            (_, AxisKind::Rigid) => 0,
            (Side::Motor, _) => 0,
            (Side::Load, _) => 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_round_trip_and_are_unique() {
        for e in EffectId::ALL {
            assert_eq!(EffectId::parse(e.id()), Some(e));
        }
        assert_eq!(EffectId::parse("magic_friction"), None);
        assert_eq!(
            EffectId::list(EffectId::repeatable),
            "viscous_friction, coulomb_friction, stribeck_friction, cogging"
        );
    }
}
