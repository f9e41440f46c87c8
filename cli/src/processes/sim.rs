//! `feedloop sim`: the plant and the scheduler in one process.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::ExitCode;

use anyhow::Result;
use serde_json::json;

use feedloop_analysis::sim::simulate;
use feedloop_model::job::Job;

use feedloop_plant::Plant;
use feedloop_plugins::Builtins;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_trace::export::{summary_json, EndInfo, SummaryInput};

use super::common::{create_dir, write_summary};

/// `feedloop sim`.
pub fn sim(job_path: &Path, out: &Path, json_only: bool, quiet: bool) -> Result<ExitCode> {
    let job = Job::load(job_path)?;
    // Validate everything before touching the output folder.
    ControlCycle::new(&job, &Builtins)?;
    Plant::new(&job)?;
    create_dir(out)?;
    let bar = if quiet || json_only {
        indicatif::ProgressBar::hidden()
    } else {
        let b = indicatif::ProgressBar::new(0);
        b.set_style(
            indicatif::ProgressStyle::with_template("sim {bar:40} {pos}/{len} cycles ({eta})")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    };
    let trace = out.join("trace.csv");
    let report = simulate(&job, &Builtins, Some(&trace), &mut |done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    let end = EndInfo::new("completed", report.cycles);
    let mut extra = BTreeMap::new();
    extra.insert("trace_export_s".to_string(), json!(report.trace_s));
    extra.insert("tracking_s".to_string(), json!(report.tracking_s));
    let v = summary_json(&SummaryInput {
        job: &job.name,
        mode: "sim",
        period_s: job.period_s,
        cycles: report.cycles,
        timing: None,
        pids: None,
        compute_s: report.compute_s,
        tracking: &report.tracking,
        end: &end,
        extra,
    });
    write_summary(out, &v, json_only)?;
    Ok(ExitCode::SUCCESS)
}
