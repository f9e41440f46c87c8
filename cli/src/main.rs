//! `feedloop`: the user's entry point.
//!
//! Subcommands: `run` (plant + scheduler as two processes), `sim` (the same in one process),
//! `plant` and `scheduler` (the two processes, also startable by hand), `merge` (export the
//! logs of hand-started processes).

mod processes;
mod signals;
mod workbench_cmd;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Real-time control runtime for CNC feed drives.
#[derive(Parser, Debug)]
#[command(name = "feedloop", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a job with the plant and the scheduler as two processes talking over iceoryx2.
    Run {
        /// Job file (TOML).
        job: PathBuf,
        /// Output folder (trace.csv, summary.json, process logs).
        #[arg(long)]
        out: PathBuf,
        /// realtime | lockstep (default: the job's [run] mode).
        #[arg(long)]
        mode: Option<String>,
        /// busy | block | hybrid (default: the job's [run] wait).
        #[arg(long)]
        wait: Option<String>,
        /// Instance name (services are named per instance); default: unique per run.
        #[arg(long)]
        instance: Option<String>,
        /// Print the summary as JSON only.
        #[arg(long)]
        json: bool,
    },
    /// Simulate a job in one process (same plant and controller code, no IPC).
    Sim {
        /// Job file (TOML).
        job: PathBuf,
        /// Output folder (trace.csv, summary.json).
        #[arg(long)]
        out: PathBuf,
        /// Print the summary as JSON only.
        #[arg(long)]
        json: bool,
        /// Do not draw a progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// The plant process: owns the physics, publishes a sample each cycle.
    Plant {
        /// Instance name.
        #[arg(long)]
        instance: String,
        /// Job file.
        #[arg(long)]
        job: PathBuf,
        /// Output folder for the plant's log.
        #[arg(long, default_value = ".")]
        out: PathBuf,
        /// realtime | lockstep.
        #[arg(long)]
        mode: Option<String>,
        /// busy | block | hybrid.
        #[arg(long)]
        wait: Option<String>,
        /// Do not export trace.csv/summary.json at the end (used by `feedloop run`, which merges).
        #[arg(long)]
        no_export: bool,
    },
    /// The scheduler process: runs the controller chain for each sample.
    Scheduler {
        /// Instance name.
        #[arg(long)]
        instance: String,
        /// Job file.
        #[arg(long)]
        job: PathBuf,
        /// Output folder for the scheduler's log.
        #[arg(long, default_value = ".")]
        out: PathBuf,
        /// realtime | lockstep.
        #[arg(long)]
        mode: Option<String>,
        /// busy | block | hybrid.
        #[arg(long)]
        wait: Option<String>,
    },
    /// Model workbench: trace import, model init, compare, diagnose, fit.
    #[command(flatten)]
    Workbench(workbench_cmd::WorkbenchCmd),
    /// Export trace.csv and summary.json from the logs the two processes left in a folder.
    Merge {
        /// Folder holding plant.log / plant.json (and scheduler.log / scheduler.json).
        dir: PathBuf,
        /// The job both ran.
        #[arg(long)]
        job: PathBuf,
        /// Print the summary as JSON only.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run {
            job,
            out,
            mode,
            wait,
            instance,
            json,
        } => processes::run(&job, &out, mode, wait, instance, json),
        Command::Sim {
            job,
            out,
            json,
            quiet,
        } => processes::sim(&job, &out, json, quiet),
        Command::Plant {
            instance,
            job,
            out,
            mode,
            wait,
            no_export,
        } => processes::plant(&instance, &job, &out, mode, wait, !no_export),
        Command::Scheduler {
            instance,
            job,
            out,
            mode,
            wait,
        } => processes::scheduler(&instance, &job, &out, mode, wait),
        Command::Merge { dir, job, json } => processes::merge_cmd(&dir, &job, json),
        Command::Workbench(cmd) => workbench_cmd::run(cmd),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("feedloop: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
