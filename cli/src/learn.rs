//! `feedloop learn quadrant`: the learning passes of the quadrant compensator (the quadrant-crossing patent, docs/sources.md).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use serde_json::json;

use feedloop_analysis::learn::quadrant::{learn_quadrant, LearnOptions};
use feedloop_analysis::sim::run_records;
use feedloop_model::job::Job;
use feedloop_model::units::{si, sig};
use feedloop_plugins::Builtins;

/// Learning subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum LearnCmd {
    /// Learn the reversal pulses of a job's `quadrant_compensator` stage(s) over N passes.
    Quadrant {
        /// Job with a `quadrant_compensator` stage (its `table` key names the table file; that
        /// file is read by the job, not overwritten unless given with --table).
        #[arg(long)]
        job: PathBuf,
        /// Learning passes after the uncompensated run.
        #[arg(long, default_value_t = 2)]
        passes: usize,
        /// Output folder: the learned table is written here under the file name of the job's
        /// `table` (default: out/learn-JOBNAME).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the table to this file instead (e.g. the job's own `table` path, to update it).
        #[arg(long)]
        table: Option<PathBuf>,
        /// Stop when every axis' spike is at or below this, load units (m or rad).
        #[arg(long, default_value_t = 0.0)]
        accept: f64,
        /// Print JSON only.
        #[arg(long)]
        json: bool,
    },
}

/// Runs a learn subcommand.
pub fn run(cmd: LearnCmd) -> Result<ExitCode> {
    let LearnCmd::Quadrant {
        job,
        passes,
        out,
        table,
        accept,
        json,
    } = cmd;
    let job = Job::load(&job)?;
    let out_dir = match (&table, out) {
        (Some(_), _) => None,
        (None, Some(d)) => Some(d),
        (None, None) => Some(PathBuf::from("out").join(format!("learn-{}", job.name))),
    };
    if let Some(d) = &out_dir {
        std::fs::create_dir_all(d)
            .with_context(|| format!("{}: cannot create folder", d.display()))?;
    }
    let options = LearnOptions {
        table,
        out_dir,
        accept,
        ..LearnOptions::default()
    };
    let mut runs = 0usize;
    let report = learn_quadrant(&job, passes, &options, &mut |j: &Job| {
        runs += 1;
        if !json {
            eprintln!("  run {runs}: simulating {}", j.name);
        }
        run_records(j, &Builtins).map_err(|e| e.to_string())
    })
    .context("learning the quadrant pulses")?;
    let base: Vec<f64> = report
        .passes
        .first()
        .map(|p| p.axes.iter().map(|a| a.spike).collect())
        .unwrap_or_default();
    let passes_json: Vec<_> = report
        .passes
        .iter()
        .map(|p| {
            json!({"pass": p.pass, "runs": p.runs, "axes": p.axes.iter().enumerate().map(|(i, a)| json!({
                "axis": a.axis, "spike": a.spike, "reversals": a.reversals, "pulses": a.pulses,
                "ratio_to_pass0": base.get(i).map(|b| if *b > 0.0 { a.spike / b } else { f64::NAN }),
            })).collect::<Vec<_>>()})
        })
        .collect();
    let v = json!({"table": report.table_path.display().to_string(),
        "job_table": report.job_table.display().to_string(), "passes": passes_json,
        "lead_s": options.lead_s, "window_s": options.window_s});
    if json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        for p in &report.passes {
            let cells: Vec<String> = p
                .axes
                .iter()
                .enumerate()
                .map(|(i, a)| {
                    let r = base.get(i).map(|b| a.spike / b).unwrap_or(f64::NAN);
                    format!(
                        "{} spike {} ({} of pass 0)",
                        a.axis,
                        si(a.spike, "m"),
                        sig(r)
                    )
                })
                .collect();
            println!("pass {}: {}", p.pass, cells.join(", "));
        }
        println!(
            "(spike: the largest |e - e(t_r - {})| of one reversal from {} before to {} after it)",
            si(options.lead_s, "s"),
            si(options.lead_s, "s"),
            si(options.window_s, "s")
        );
        println!("wrote {}", report.table_path.display());
        let same = |a: &std::path::Path, b: &std::path::Path| {
            a == b
                || matches!(
                    (std::fs::canonicalize(a), std::fs::canonicalize(b)),
                    (Ok(x), Ok(y)) if x == y
                )
        };
        if !same(&report.table_path, &report.job_table) {
            println!(
                "the job's own table {} is unchanged: copy the new one over it, or learn with --table {} to write it there",
                report.job_table.display(),
                report.job_table.display()
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
