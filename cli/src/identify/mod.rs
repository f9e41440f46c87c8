//! `feedloop identify inertia|stiffness`, `feedloop excite`, `feedloop tune`: one file per
//! command, `trace_input` holding the trace reading the identify commands share.

mod excite;
mod inertia;
mod stiffness;
mod trace_input;
mod tune;

use std::process::ExitCode;

pub use excite::{excite, ExciteArgs};
use inertia::InertiaArgs;
use stiffness::StiffnessArgs;
pub use tune::{tune, TuneArgs};

/// `feedloop identify ...`.
#[derive(clap::Subcommand, Debug)]
pub enum IdentifyCmd {
    /// Load inertia from the deviation between the position command and the load position (load-inertia patent).
    Inertia(InertiaArgs),
    /// Stiffness and load inertia from the torque -> motor velocity FRF (stiffness-identification patent).
    Stiffness(StiffnessArgs),
}

/// Runs `feedloop identify ...`.
pub fn identify(cmd: IdentifyCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        IdentifyCmd::Inertia(a) => inertia::inertia_cmd(a),
        IdentifyCmd::Stiffness(a) => stiffness::stiffness_cmd(a),
    }
}
