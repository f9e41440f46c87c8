//! The stages of an axis chain, as job files and requests name them.

use std::fmt;

/// Where a controller sits in an axis chain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Stage {
    /// Position loop: writes `vel_cmd`.
    Position,
    /// Feedforward: adds to `vel_cmd` and/or `torque_ff`.
    Feedforward,
    /// Compensators (e.g. quadrant): add to `vel_cmd` and/or `torque_ff`.
    Compensator,
    /// Velocity loop: writes `torque` (including `torque_ff`).
    Velocity,
}

impl Stage {
    /// All stages in execution order.
    pub const ALL: [Stage; 4] = [
        Stage::Position,
        Stage::Feedforward,
        Stage::Compensator,
        Stage::Velocity,
    ];

    /// Name used in job files and on the command line.
    pub fn id(self) -> &'static str {
        match self {
            Stage::Position => "position",
            Stage::Feedforward => "feedforward",
            Stage::Compensator => "compensator",
            Stage::Velocity => "velocity",
        }
    }

    /// Parses a stage name.
    pub fn parse(s: &str) -> Option<Stage> {
        Stage::ALL.into_iter().find(|st| st.id() == s)
    }

    /// Index in [`Stage::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.id())
    }
}
