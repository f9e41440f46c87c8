//! `feedloop`: the user's entry point.
//!
//! Subcommands: `run` (plant + scheduler as two processes), `sim` (the same in one process),
//! `plant` and `scheduler` (the two processes, also startable by hand), `merge` (export the
//! logs of hand-started processes).

mod bench;
mod choice;
mod commission;
mod control;
mod identify;
mod learn;
mod processes;
mod workbench_cmd;

use feedloop_cli::{scope, signals};

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
        /// How the processes keep time (default: the job's [run] mode).
        #[arg(long, value_enum)]
        mode: Option<choice::ModeArg>,
        /// How a process waits for the next message (default: the job's [run] wait).
        #[arg(long, value_enum)]
        wait: Option<choice::WaitArg>,
        /// Instance name (services are named per instance); default: unique per run.
        #[arg(long)]
        instance: Option<String>,
        /// CPUs for the plant and the scheduler, e.g. `0,1` (each process and its threads stay
        /// on its CPU; a spinning wait wants one core each).
        #[arg(long)]
        pin: Option<String>,
        /// Print the summary as JSON only.
        #[arg(long)]
        json: bool,
        /// Do not draw the live line (cycles, run time, plant overruns and deadline misses so
        /// far; drawn on standard error only when it is a terminal).
        #[arg(long)]
        quiet: bool,
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
        #[command(flatten)]
        args: processes::ProcArgs,
        /// Do not export trace.csv/summary.json at the end (used by `feedloop run`, which merges).
        #[arg(long)]
        no_export: bool,
    },
    /// The scheduler process: runs the controller chain for each sample.
    Scheduler {
        #[command(flatten)]
        args: processes::ProcArgs,
    },
    /// Swap (or retune) a controller of a running loop.
    Swap(control::SwapArgs),
    /// Status of a running loop (cycle, plugins per axis and stage, swaps).
    Status {
        /// Instance of the running loop.
        #[arg(long)]
        instance: String,
        /// Seconds to wait for the answer.
        #[arg(long, default_value_t = 5.0)]
        timeout_s: f64,
    },
    /// Live scope of a running loop (or of recorded traces) in the browser.
    Scope(scope::ScopeArgs),
    /// Identification: load inertia, screw stiffness.
    #[command(subcommand)]
    Identify(identify::IdentifyCmd),
    /// Grid search of control parameters on a constant-velocity ramp test.
    Tune(identify::TuneArgs),
    /// Commission one axis: measure it, identify, tune, set the feedforwards, verify.
    Commission(commission::CommissionArgs),
    /// Write an excitation command as a trace a job can play.
    Excite(identify::ExciteArgs),
    /// Learning compensators (the quadrant compensator).
    #[command(subcommand)]
    Learn(learn::LearnCmd),
    /// Benchmarks of the running loop.
    #[command(subcommand)]
    Bench(bench::BenchCmd),
    /// Model workbench: trace import, model init, compare, diagnose, fit.
    #[command(flatten)]
    Workbench(workbench_cmd::WorkbenchCmd),
    /// Export trace.csv and summary.json from the logs the two processes left in a folder.
    #[command(
        after_help = "Exit status: 0 when the run completed or an operator stopped it; 1 when \
                      trace.csv and summary.json were written (the export worked) but the run \
                      ended abnormally (a fault stop or a lost process: `end` in summary.json \
                      says which); 2 when the export failed (the error says why)."
    )]
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
    if !matches!(
        cli.command,
        Command::Plant { .. } | Command::Scheduler { .. }
    ) {
        // The loop's own processes keep their signals: nothing but a stop request ends them.
        signals::quiet_broken_pipe();
    }
    let result = match cli.command {
        Command::Run {
            job,
            out,
            mode,
            wait,
            instance,
            pin,
            json,
            quiet,
        } => processes::run(
            &job,
            &out,
            mode,
            wait,
            instance,
            pin.as_deref(),
            json,
            quiet,
        ),
        Command::Sim {
            job,
            out,
            json,
            quiet,
        } => processes::sim(&job, &out, json, quiet),
        Command::Plant { args, no_export } => processes::plant(&args, !no_export),
        Command::Scheduler { args } => processes::scheduler(&args),
        Command::Bench(cmd) => bench::run(cmd),
        Command::Learn(cmd) => learn::run(cmd),
        Command::Identify(c) => identify::identify(c),
        Command::Tune(a) => identify::tune(a),
        Command::Excite(a) => identify::excite(a),
        Command::Commission(a) => commission::run(a),
        Command::Swap(a) => control::swap(&a),
        Command::Scope(a) => scope::run(&a),
        Command::Status {
            instance,
            timeout_s,
        } => control::status(&instance, timeout_s),
        Command::Merge { dir, job, json } => processes::merge_cmd(&dir, &job, json),
        Command::Workbench(cmd) => workbench_cmd::run(cmd),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("feedloop: error: {}", error_text(&e));
            ExitCode::from(2)
        }
    }
}

/// An error with its causes, each said once ([`feedloop_cli::workbench_load::error_text`]).
fn error_text(e: &anyhow::Error) -> String {
    feedloop_cli::workbench_load::error_text(e)
}
