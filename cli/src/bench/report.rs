//! What the benches print: `bench latency`'s summary of its `latency.json`, and `bench table`'s
//! markdown table of several.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use serde_json::Value;

use feedloop_analysis::latency::{Attribution, RunFigures};
use feedloop_model::units::{si, sig};

use crate::processes::read_json;

/// The figures of `latency.json` in a few lines.
pub(super) fn print_report(v: &Value, f: &RunFigures, a: &Attribution, period_ns: u64) {
    // the JSON figures are in us (the key says so); printed as seconds with a prefix that fits
    let us = |x: &Value| si(x.as_f64().unwrap_or(f64::NAN) * 1e-6, "s");
    let percentiles = |h: &Value| {
        format!(
            "p50 {}  p99 {}  p99.9 {}  max {}",
            us(&h["p50"]),
            us(&h["p99"]),
            us(&h["p999"]),
            us(&h["max"])
        )
    };
    println!("latency: {}", percentiles(&v["latency_us"]));
    println!("jitter:  {}", percentiles(&v["jitter_us"]));
    println!(
        "deadline misses {} ({} outside stalls), overruns {}, stalls {} (max {})",
        f.misses,
        f.misses_outside_stalls,
        f.overruns,
        f.stalls,
        si(f.stall_max_ms * 1e-3, "s")
    );
    let half_period = si(period_ns as f64 * 0.5e-9, "s");
    println!(
        "core lost for >= {half_period}: scheduler {} times (max {}), plant while waiting {} times; misses then: {}; misses outside stalls and core losses: {}",
        a.scheduler_losses,
        si(a.scheduler_max_ns as f64 * 1e-9, "s"),
        a.plant_losses,
        a.explained,
        a.unexplained
    );
    if !v["reference"].is_null() {
        let r = &v["reference"];
        println!(
            "reference on the same CPUs: sleeping loop jitter {} (SCHED_FIFO {}); \
             a bare spinning loop lost its core for >= {half_period} {} times ({}/s, max {})",
            percentiles(&r["sleeping_loop"]["jitter_us"]),
            r["sleeping_loop"]["sched_fifo"],
            r["spinning_loop"]["interruptions"],
            sig(r["spinning_loop"]["interruptions_per_s"]
                .as_f64()
                .unwrap_or(0.0)),
            us(&r["spinning_loop"]["max_us"]),
        );
    }
    let b = &v["breakdown_us"];
    let part = |k: &str| format!("{} / {}", us(&b[k]["p50"]), us(&b[k]["p99"]));
    println!(
        "round trip in parts (p50 / p99): to the scheduler {}, before computing {}, chain {}, \
         publish {}, back to the plant {}",
        part("to_scheduler"),
        part("before_compute"),
        part("chain"),
        part("publish"),
        part("to_plant"),
    );
    if let Some(line) = phase_line(&v["phase"]) {
        println!("{line}");
    }
    let pp = &v["iceoryx_pingpong"];
    if !pp.is_null() {
        let x = |k: &str| sig(pp["ratio"][k].as_f64().unwrap_or(f64::NAN));
        println!(
            "bare iceoryx2 ping-pong of the same messages: one per period {}, back to back {}; \
             the loop's round trip is {} x / {} x the paced one (p50 / p99), {} x / {} x the \
             back-to-back one; after the run the paced ping-pong was {} ({} x / {} x)",
            percentiles(&pp["paced_us"]),
            percentiles(&pp["back_to_back_us"]),
            x("p50"),
            x("p99"),
            x("p50_back_to_back"),
            x("p99_back_to_back"),
            percentiles(&pp["after"]["paced_us"]),
            x("p50_after"),
            x("p99_after"),
        );
        let pb = &pp["breakdown_us"];
        if !pb["to_echo"].is_null() {
            let part = |k: &str| format!("{} / {}", us(&pb[k]["p50"]), us(&pb[k]["p99"]));
            println!(
                "ping-pong in parts (p50 / p99, {} timed pings): to the echo, sample copied out \
                 {}, turnaround {}, publish {}, back to the pinger {}",
                pb["pings"],
                part("to_echo"),
                part("turnaround"),
                part("publish"),
                part("to_pinger"),
            );
        }
    }
}

/// Prints `bench table`'s markdown table.
pub(super) fn table(runs: &[PathBuf]) -> Result<ExitCode> {
    println!(
        "| run | host: spinning loop lost its core (per s, max) | ping-pong p50 / p99 (paced) | \
         loop p50 / p99 | ratio p50 / p99 | jitter p99: loop / sleeping loop | misses outside \
         stalls and core losses | start phase: time the host took from a cycle's window, at \
         the chosen / the worst phase (median of the parts' probes) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for r in runs {
        let path = if r.is_dir() {
            r.join("latency.json")
        } else {
            r.clone()
        };
        let v = read_json(&path).with_context(|| format!("reading {}", path.display()))?;
        let f = |x: &Value| x.as_f64().unwrap_or(f64::NAN);
        let us = |x: &Value| si(f(x) * 1e-6, "s");
        let pair = |h: &Value| format!("{} / {}", us(&h["p50"]), us(&h["p99"]));
        let spin = &v["reference"]["spinning_loop"];
        println!(
            "| {} | {} /s, max {} | {} | {} | {} x / {} x | {} / {} | {} | {} |",
            path.parent().unwrap_or(&path).display(),
            sig(f(&spin["interruptions_per_s"])),
            us(&spin["max_us"]),
            pair(&v["iceoryx_pingpong"]["paced_us"]),
            pair(&v["latency_us"]),
            sig(f(&v["iceoryx_pingpong"]["ratio"]["p50"])),
            sig(f(&v["iceoryx_pingpong"]["ratio"]["p99"])),
            us(&v["jitter_us"]["p99"]),
            us(&v["reference"]["sleeping_loop"]["jitter_us"]["p99"]),
            v["misses_outside_stalls_and_core_losses"],
            phase_cell(&v["phase"]["loop"]),
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The table's start-phase cell: per cycle, the time the host's interruptions took from the
/// window around a cycle's start during the plant's probes, at the chosen phase and at the
/// worst one (medians over the parts); `-` without probes.
fn phase_cell(parts: &Value) -> String {
    let median = |k: &str| {
        let mut xs: Vec<f64> = parts
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|p| p[k].as_f64())
            .collect();
        xs.sort_by(f64::total_cmp);
        xs.get(xs.len() / 2).copied()
    };
    match (
        median("delay_us_per_cycle"),
        median("worst_delay_us_per_cycle"),
    ) {
        (Some(at), Some(worst)) => format!(
            "{} / {} per cycle",
            si(at * 1e-6, "s"),
            si(worst * 1e-6, "s")
        ),
        _ => "-".to_string(),
    }
}

/// The summary's line on the start phase: where the parts' cycles started against where the
/// host's interruptions fell; `None` without probes.
fn phase_line(ph: &Value) -> Option<String> {
    let parts: Vec<&Value> = ph["loop"]
        .as_array()?
        .iter()
        .filter(|p| p["phase_us"].is_number())
        .collect();
    if parts.is_empty() {
        return None;
    }
    let range = |k: &str| {
        let xs: Vec<f64> = parts.iter().filter_map(|p| p[k].as_f64()).collect();
        let lo = xs.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (lo, hi)
    };
    let pct = |(lo, hi): (f64, f64)| format!("{}-{} %", sig(lo * 100.0), sig(hi * 100.0));
    let (ph_lo, ph_hi) = range("phase_us");
    let seen = range("interruptions");
    let probe_s = parts[0]["probe_s"].as_f64().unwrap_or(f64::NAN);
    Some(format!(
        "start phase: the plant's probe ({} s) saw the core taken {}-{} times; cycles started \
         {}-{} us into the period, where the host's interruptions hit the round trip's {} us \
         window in {} of periods, against {} at the worst phase ({} of {} parts)",
        sig(probe_s),
        seen.0,
        seen.1,
        sig(ph_lo),
        sig(ph_hi),
        sig(parts[0]["window_us"].as_f64().unwrap_or(f64::NAN)),
        pct(range("hit_share")),
        pct(range("worst_hit_share")),
        parts.len(),
        ph["loop"].as_array().map_or(0, |a| a.len()),
    ))
}
