//! `feedloop merge`: the processes' logs into `trace.csv` and `summary.json` (also the end of
//! `feedloop run` and of a plant started by hand).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use serde_json::{json, Value};

use feedloop_analysis::sim::ContourJudge;
use feedloop_model::job::Job;

use feedloop_plugins::Builtins;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_trace::export::{
    human_summary, row_values, summary_json, timing_warning, trace_columns, EndInfo, SummaryInput,
};
use feedloop_trace::log::{read_log, PlantRecord, SchedRecord};
use feedloop_trace::summary::{timing, Tracking};
use feedloop_trace::TraceWriter;

use super::common::{read_json, write_json};

/// `feedloop merge`.
pub fn merge_cmd(dir: &Path, job_path: &Path, json_only: bool) -> Result<ExitCode> {
    let job = Job::load(job_path)?;
    let (v, code) = merge(dir, &job)?;
    if json_only {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print!("{}", human_summary(&v));
        println!(
            "  wrote {} and {}",
            dir.join("trace.csv").display(),
            dir.join("summary.json").display()
        );
    }
    if code != ExitCode::SUCCESS {
        eprintln!("{}", abnormal_end_note(&v));
    }
    Ok(code)
}

/// Why `merge` exits 1 although it wrote both files (on standard error, beside the summary).
fn abnormal_end_note(v: &Value) -> String {
    format!(
        "feedloop merge: exit status 1: the export worked (trace.csv and summary.json are \
         complete for the {} cycles logged), but the run ended abnormally (end: {} at cycle {}); \
         0 is a completed or operator-stopped run, 2 a failed export",
        v["cycles"],
        v["end"]["reason"].as_str().unwrap_or("unknown"),
        v["end"]["cycle"]
    )
}

/// Writes `trace.csv` in `dir` from the plant's records; returns the tracking figures and the
/// plant's compute time, ns.
fn write_trace(
    dir: &Path,
    job: &Job,
    cycle: &ControlCycle,
    records: &[PlantRecord],
) -> Result<(Tracking, u64)> {
    let names = job.axis_names();
    let n = names.len();
    let judge = ContourJudge::new(job, cycle);
    let mut tracking = Tracking::for_job(job);
    let trace_path = dir.join("trace.csv");
    let f = std::fs::File::create(&trace_path)
        .with_context(|| format!("creating {}", trace_path.display()))?;
    let mut w = TraceWriter::new(
        std::io::BufWriter::with_capacity(1 << 20, f),
        &trace_columns(&names),
    )?
    .with_period(job.period_s)?;
    let mut row = Vec::with_capacity(1 + 5 * n);
    let mut plant_compute_ns = 0u64;
    for r in records {
        row_values(r.seq, job.period_s, &r.axes[..n], &mut row);
        w.write_cycle(r.seq, &row)?;
        let ce = judge.error_m(cycle, cycle.time_of(r.seq), &r.axes[..n]);
        tracking.push(&r.axes[..n], ce);
        plant_compute_ns += u64::from(r.compute_ns);
    }
    w.finish()?;
    Ok((tracking, plant_compute_ns))
}

/// How the run ended, from plant.json (`plant_lost` without it; `incomplete_log` when a
/// completed run logged fewer or more cycles than planned).
fn merged_end(plant_info: Option<&Value>, cycles: u64, cycle: &ControlCycle) -> EndInfo {
    let end = match plant_info {
        None => EndInfo::new("plant_lost", cycles),
        Some(p) => {
            let e = &p["end"];
            let mut info = EndInfo::new(
                e["reason"].as_str().unwrap_or("unknown"),
                e["cycle"].as_u64().unwrap_or(cycles),
            );
            if let Some(obj) = e.as_object() {
                for (k, v) in obj {
                    if k != "reason" && k != "cycle" {
                        info.extra.insert(k.clone(), v.clone());
                    }
                }
            }
            info
        }
    };
    let planned = plant_info
        .and_then(|p| p["planned_cycles"].as_u64())
        .unwrap_or(cycle.cycles());
    if end.reason == "completed" && cycles != planned {
        return EndInfo::new("incomplete_log", cycles);
    }
    end
}

/// The scheduler's part of the summary's extra keys: its swaps, rejected requests, deadline
/// misses near the swaps and elsewhere, and its whole report.
fn scheduler_extra(s: &Value, records: &[PlantRecord], extra: &mut BTreeMap<String, Value>) {
    extra.insert("swaps".into(), s["swaps"].clone());
    extra.insert("rejected_requests".into(), s["rejected_requests"].clone());
    let swap_cycles: Vec<u64> = s["swaps"]
        .as_array()
        .map(|a| a.iter().filter_map(|w| w["cycle"].as_u64()).collect())
        .unwrap_or_default();
    if !swap_cycles.is_empty() {
        let (near, elsewhere) = misses_near(records, &swap_cycles, SWAP_WINDOW);
        let stats = |c: &WindowCount| {
            json!({"cycles": c.cycles, "misses": c.misses,
                   "rate": c.misses as f64 / c.cycles.max(1) as f64,
                   "late_cycles": c.late, "late_rate": c.late as f64 / c.cycles.max(1) as f64})
        };
        let mut n = stats(&near);
        n["window_cycles"] = json!(SWAP_WINDOW);
        extra.insert("deadline_misses_near_swaps".into(), n);
        extra.insert("deadline_misses_elsewhere".into(), stats(&elsewhere));
    }
    extra.insert("scheduler".into(), s.clone());
}

/// Builds trace.csv and summary.json in `dir` from the processes' logs.
pub(super) fn merge(dir: &Path, job: &Job) -> Result<(Value, ExitCode)> {
    let plant_log: PathBuf = dir.join("plant.log");
    let plant_recs = read_log::<PlantRecord>(&plant_log)
        .with_context(|| format!("reading {}", plant_log.display()))?;
    let sched_recs = read_log::<SchedRecord>(&dir.join("scheduler.log")).ok();
    let plant_info = read_json(&dir.join("plant.json"));
    let sched_info = read_json(&dir.join("scheduler.json"));
    let cycle = ControlCycle::new(job, &Builtins)?;
    let (tracking, plant_compute_ns) = write_trace(dir, job, &cycle, &plant_recs.records)?;
    let sched_compute_ns: u64 = sched_recs
        .as_ref()
        .map(|s| s.records.iter().map(|r| u64::from(r.compute_ns)).sum())
        .unwrap_or(0);
    let t = timing(&plant_recs.records);
    let mode = plant_info
        .as_ref()
        .and_then(|p| p["mode"].as_str().map(str::to_string))
        .unwrap_or_else(|| "unknown".into());
    let pids = match (&plant_info, &sched_info) {
        (Some(p), Some(s)) => Some((
            p["pid"].as_u64().unwrap_or(0) as u32,
            s["pid"].as_u64().unwrap_or(0) as u32,
        )),
        _ => None,
    };
    let cycles = plant_recs.records.len() as u64;
    let end = merged_end(plant_info.as_ref(), cycles, &cycle);
    let mut extra = BTreeMap::new();
    extra.insert(
        "wait".into(),
        plant_info
            .as_ref()
            .map(|p| p["wait"].clone())
            .unwrap_or(Value::Null),
    );
    extra.insert("bad_sequence".into(), json!(t.bad_sequence));
    extra.insert("late_commands".into(), json!(t.late_commands));
    extra.insert("duplicate_commands".into(), json!(t.duplicate_commands));
    extra.insert("torn_log_bytes".into(), json!(plant_recs.torn_bytes));
    if let Some(s) = plant_info.as_ref().map(|p| &p["startup"]) {
        if !s.is_null() {
            extra.insert("startup".into(), s.clone());
        }
    }
    if let Some(s) = &sched_info {
        scheduler_extra(s, &plant_recs.records, &mut extra);
    }
    let mut v = summary_json(&SummaryInput {
        job: &job.name,
        mode: &mode,
        period_s: job.period_s,
        cycles,
        timing: Some(&t),
        pids,
        compute_s: (plant_compute_ns + sched_compute_ns) as f64 * 1e-9,
        tracking: &tracking,
        end: &end,
        extra,
    });
    v["timing_warning"] = timing_warning(&v);
    write_json(&dir.join("summary.json"), &v)?;
    // A completed run and an operator stop are clean exits; every fault stop is not.
    let code = if end.reason == "completed" || end.reason == "operator_stop" {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    };
    Ok((v, code))
}

/// Cycles after a swap (the swap cycle and the next ones) counted as "near" it.
const SWAP_WINDOW: u64 = 10;

/// Cycle counts of one part of a run.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct WindowCount {
    cycles: u64,
    /// Deadline misses as the summary defines them: no command while the plant was on time.
    misses: u64,
    /// Cycles with a miss or a plant overrun (any timing fault, also when the machine is busy).
    late: u64,
}

/// Counts within `window` cycles from each swap cycle on (a union: overlapping windows count
/// once), and in all other cycles.
fn misses_near(records: &[PlantRecord], swaps: &[u64], window: u64) -> (WindowCount, WindowCount) {
    use feedloop_trace::log::{REC_MISSED, REC_OVERRUN};
    let mut sorted = swaps.to_vec();
    sorted.sort_unstable();
    let mut near = WindowCount::default();
    let mut far = WindowCount::default();
    let mut next = 0usize;
    for r in records {
        while next < sorted.len() && sorted[next] + window < r.seq {
            next += 1;
        }
        let is_near =
            next < sorted.len() && sorted[next] <= r.seq && r.seq <= sorted[next] + window;
        let slot = if is_near { &mut near } else { &mut far };
        slot.cycles += 1;
        slot.misses += u64::from(feedloop_trace::log::is_deadline_miss(r.flags));
        slot.late += u64::from(r.flags & (REC_MISSED | REC_OVERRUN) != 0);
    }
    (near, far)
}

#[cfg(test)]
mod swap_window_tests {
    use super::*;
    use feedloop_trace::log::{REC_MISSED, REC_OVERRUN};

    #[test]
    fn misses_are_split_into_swap_windows_and_the_rest() {
        let recs: Vec<PlantRecord> = (0..100u64)
            .map(|k| PlantRecord {
                seq: k,
                flags: match k {
                    12 | 50 | 95 => REC_MISSED,
                    13 => REC_MISSED | REC_OVERRUN,
                    _ => 0,
                },
                ..Default::default()
            })
            .collect();
        // Windows [10, 20] and [15, 25] overlap: 16 cycles; [90, 100] is cut at 99: 10 cycles.
        let (near, far) = misses_near(&recs, &[15, 10, 90], 10);
        assert_eq!((near.cycles, near.misses, near.late), (16 + 10, 2, 3));
        assert_eq!((far.cycles, far.misses, far.late), (100 - 26, 1, 1));
    }
}
