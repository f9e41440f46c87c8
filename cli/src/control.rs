//! `feedloop swap` and `feedloop status`: clients of a running loop's control service.

use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result};
use feedloop_runtime::scheduler::control::protocol::{Answer, Request, SwapRequest};
use feedloop_runtime::scheduler::control::request;

/// `feedloop swap`.
pub fn swap(
    instance: &str,
    axis: &str,
    stage: &str,
    plugin: &str,
    params: Option<&Path>,
    lib: Option<&Path>,
    timeout_s: f64,
) -> Result<ExitCode> {
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
        axis: axis.to_string(),
        stage: stage.to_string(),
        plugin: plugin.to_string(),
        params: params_text,
        lib: lib_path,
        params_file: params.map(|p| p.display().to_string()),
    });
    let answer = request(instance, &req, Duration::from_secs_f64(timeout_s))?;
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
