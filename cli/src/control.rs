//! `feedloop swap` and `feedloop status`: clients of a running loop's control service.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result};
use feedloop_runtime::scheduler::control::protocol::{Answer, Request, SwapRequest};
use feedloop_runtime::scheduler::control::request;

use crate::choice::{Choice, StageArg};

/// Options of `feedloop swap`.
#[derive(clap::Args, Debug)]
pub struct SwapArgs {
    /// Instance of the running loop.
    #[arg(long)]
    pub instance: String,
    /// Axis name.
    #[arg(long)]
    pub axis: String,
    /// The stage of the axis' chain.
    #[arg(long, value_enum)]
    pub stage: StageArg,
    /// Plugin id (the same id with --params is a retune).
    #[arg(long)]
    pub plugin: String,
    /// TOML file with the plugin's own parameter keys (omitted keys keep their values).
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Shared-library plugin to load.
    #[arg(long)]
    pub lib: Option<PathBuf>,
    /// Apply a set the loop model finds unstable or marginal, and keep a swap whose first
    /// torque step exceeds the bumpless bound (both flagged in the answer and the summary).
    #[arg(long)]
    pub force: bool,
    /// Seconds to wait for the answer.
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
}

/// `feedloop swap`.
pub fn swap(a: &SwapArgs) -> Result<ExitCode> {
    let (params, lib) = (a.params.as_deref(), a.lib.as_deref());
    if lib.is_none() {
        crate::choice::builtin_plugin(&a.plugin)?;
    }
    let params_text = match params {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            // Validate the syntax here so the error names the file and line.
            feedloop_model::params::parse_toml(p, &text)?;
            Some(text)
        }
        None => None,
    };
    let lib_path = match lib {
        Some(l) => Some(
            std::fs::canonicalize(l)
                .with_context(|| format!("plugin library {}", l.display()))?
                .display()
                .to_string(),
        ),
        None => None,
    };
    let req = Request::Swap(SwapRequest {
        axis: a.axis.clone(),
        stage: a.stage.id().to_string(),
        plugin: a.plugin.clone(),
        params: params_text,
        lib: lib_path,
        force: a.force,
        params_file: params.map(|p| p.display().to_string()),
    });
    let answer = request(&a.instance, &req, Duration::from_secs_f64(a.timeout_s))?;
    print_answer(&answer)
}

/// `feedloop status`.
pub fn status(instance: &str, timeout_s: f64) -> Result<ExitCode> {
    let answer = request(
        instance,
        &Request::Status,
        Duration::from_secs_f64(timeout_s),
    )?;
    print_answer(&answer)
}

/// Prints `answer` as indented JSON; exit code 1 when it is a refusal.
fn print_answer(answer: &Answer) -> Result<ExitCode> {
    println!("{}", serde_json::to_string_pretty(answer)?);
    Ok(if answer.is_refused() {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}
