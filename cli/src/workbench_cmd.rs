//! CLI of the model workbench: `trace import`, `model init`, `compare`, `diagnose`, `fit`.
//! (Being written.)

use std::process::ExitCode;

/// Workbench subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum WorkbenchCmd {}

/// Runs a workbench subcommand.
pub fn run(cmd: WorkbenchCmd) -> anyhow::Result<ExitCode> {
    match cmd {}
}
