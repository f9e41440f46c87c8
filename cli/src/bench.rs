//! `feedloop bench latency`: a realtime run of the two processes that records every cycle's
//! round-trip latency (sample published -> command received) and the plant's wake-up jitter into
//! HDR histograms, and reports them with deadline misses, overruns and stalls.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use hdrhistogram::Histogram;
use serde_json::{json, Value};

use feedloop_model::job::{Mode, WaitKind};
use feedloop_trace::log::{
    read_log, PlantRecord, SchedRecord, REC_MISSED, REC_OVERRUN, REC_STALL, REC_WAIT_INTERRUPTED,
};

use crate::processes::{read_json, spawn, write_json};

/// Benchmark subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum BenchCmd {
    /// Round-trip latency and period jitter of a realtime run: the X-C grinder of
    /// `examples/jobs/xc-full-chain.toml`, all four seed controllers on two axes.
    Latency {
        /// Cycles to run.
        #[arg(long, default_value_t = 100_000)]
        cycles: u64,
        /// Control period, s.
        #[arg(long, default_value_t = 1.0e-4)]
        period_s: f64,
        /// busy | block | hybrid.
        #[arg(long, default_value = "busy")]
        wait: String,
        /// CPUs for the plant and the scheduler, e.g. `0,1`.
        #[arg(long)]
        pin: Option<String>,
        /// SCHED_FIFO priority for both processes (refused with busy waits).
        #[arg(long)]
        fifo: Option<i32>,
        /// Output folder (latency.json, latency.svg, the run's logs).
        #[arg(long)]
        out: PathBuf,
        /// Seconds of each reference measurement taken on the same CPUs just before the run: a
        /// cyclictest-style sleeping loop at the same period (SCHED_FIFO 80 when permitted) and
        /// a bare spinning loop that counts how often the machine takes a core away. 0 skips them.
        #[arg(long, default_value_t = 10.0)]
        reference_s: f64,
    },
}

/// Runs a bench subcommand.
pub fn run(cmd: BenchCmd) -> Result<ExitCode> {
    match cmd {
        BenchCmd::Latency {
            cycles,
            period_s,
            wait,
            pin,
            fifo,
            out,
            reference_s,
        } => latency(
            cycles,
            period_s,
            &wait,
            pin.as_deref(),
            fifo,
            &out,
            reference_s,
        ),
    }
}

const JOB: &str = include_str!("../../examples/jobs/xc-full-chain.toml");
const MODEL_X: &str = include_str!("../../examples/models/xc-x.toml");
const MODEL_C: &str = include_str!("../../examples/models/xc-c.toml");
const QUADRANT_TABLE: &str = include_str!("../../examples/tables/xy-circle-quadrant.toml");

/// The benchmark's job: `examples/jobs/xc-full-chain.toml` (the four seed controllers on two
/// axes) with its files beside it, at `period_s`, grinding long enough to keep moving for
/// `cycles`.
fn bench_job(dir: &Path, period_s: f64, wait: WaitKind, cycles: u64) -> Result<PathBuf> {
    std::fs::write(dir.join("bench-x.toml"), MODEL_X)?;
    std::fs::write(dir.join("bench-c.toml"), MODEL_C)?;
    std::fs::write(dir.join("bench-quadrant.toml"), QUADRANT_TABLE)?;
    // one revolution per second: enough turns to keep the cam turning through the whole run
    let turns = (cycles as f64 * period_s).ceil() + 1.0;
    let mut job = String::new();
    for line in JOB.lines() {
        let key = line.split('=').next().unwrap_or("").trim();
        let line = match key {
            "name" => "name = \"bench-latency\"".to_string(),
            "period_s" => format!(
                "period_s = {period_s:e}\n\n[run]\nmode = \"realtime\"\nwait = \"{}\"",
                wait.id()
            ),
            "turns" => format!("turns = {turns}"),
            _ => line
                .replace("../models/xc-x.toml", "bench-x.toml")
                .replace("../models/xc-c.toml", "bench-c.toml")
                .replace("../tables/xy-circle-quadrant.toml", "bench-quadrant.toml"),
        };
        job.push_str(&line);
        job.push('\n');
    }
    let p = dir.join("bench-job.toml");
    std::fs::write(&p, job)?;
    Ok(p)
}

fn hist_json(h: &Histogram<u64>) -> Value {
    let us = |v: u64| v as f64 / 1000.0;
    json!({
        "p50": us(h.value_at_quantile(0.5)),
        "p99": us(h.value_at_quantile(0.99)),
        "p999": us(h.value_at_quantile(0.999)),
        "max": us(h.max()),
        "count": h.len(),
    })
}

fn latency(
    cycles: u64,
    period_s: f64,
    wait: &str,
    pin: Option<&str>,
    fifo: Option<i32>,
    out: &Path,
    reference_s: f64,
) -> Result<ExitCode> {
    let wait_kind = WaitKind::parse(wait)
        .with_context(|| format!("--wait `{wait}`: expected busy, block or hybrid"))?;
    if !(period_s > 1e-6 && period_s <= 0.1) {
        bail!("--period-s {period_s}: must be within (1e-6, 0.1] s");
    }
    if cycles == 0 {
        bail!("--cycles must be > 0");
    }
    if !(reference_s.is_finite() && (0.0..=3600.0).contains(&reference_s)) {
        bail!("--reference-s {reference_s}: must be within [0, 3600] s");
    }
    let cpus: Vec<usize> = match pin {
        None => vec![],
        Some(p) => crate::processes::parse_pin(p)?.to_vec(),
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let job = bench_job(out, period_s, wait_kind, cycles)?;
    let instance = format!("bench{}", std::process::id());
    let extra = |i: usize| {
        let mut v = vec!["--cycles".to_string(), cycles.to_string()];
        if let Some(c) = cpus.get(i) {
            v.extend(["--cpu".to_string(), c.to_string()]);
        }
        if let Some(f) = fifo {
            v.extend(["--fifo".to_string(), f.to_string()]);
        }
        v
    };
    for f in ["plant.log", "plant.json", "scheduler.log", "scheduler.json"] {
        let _ = std::fs::remove_file(out.join(f));
    }
    let period_ns = (period_s * 1e9).round() as u64;
    let probe_cpus: Vec<usize> = if cpus.is_empty() {
        (0..std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .min(2))
            .collect()
    } else {
        cpus.clone()
    };
    let reference = if reference_s > 0.0 {
        eprintln!(
            "reference: a sleeping loop, then a spinning loop, {reference_s} s each on CPUs {probe_cpus:?}"
        );
        let secs = Duration::from_secs_f64(reference_s);
        let sleeping = probe::sleeping_loop(&probe_cpus, period_ns, secs)?;
        let spinning = probe::spinning_loop(&probe_cpus, period_ns / 2, secs)?;
        json!({
            "seconds": reference_s,
            "cpus": probe_cpus,
            "sleeping_loop": {
                "jitter_us": hist_json(&sleeping.lateness),
                "sched_fifo": sleeping.sched_fifo,
            },
            "spinning_loop": {
                "threshold_us": (period_ns / 2) as f64 / 1000.0,
                "interruptions": spinning.count,
                "interruptions_per_s": spinning.count as f64 / reference_s,
                "interrupted_share": spinning.lost_ns as f64 / (reference_s * 1e9 * probe_cpus.len() as f64),
                "max_us": spinning.max_ns as f64 / 1000.0,
            },
        })
    } else {
        Value::Null
    };
    eprintln!(
        "bench latency: {cycles} cycles at {:.1} kHz, wait {wait}, about {:.1} s",
        1e-3 / period_s,
        cycles as f64 * period_s
    );
    let mut plant = spawn(
        "plant",
        &instance,
        &job,
        out,
        Mode::Realtime,
        wait_kind,
        &extra(0),
    )?;
    let mut sched = spawn(
        "scheduler",
        &instance,
        &job,
        out,
        Mode::Realtime,
        wait_kind,
        &extra(1),
    )?;
    let ps = plant.wait()?;
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while sched.try_wait()?.is_none() {
        if std::time::Instant::now() > deadline {
            let _ = sched.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = sched.wait();
    if !ps.success() && !out.join("plant.json").exists() {
        bail!("the plant process failed ({ps})");
    }
    let recs = read_log::<PlantRecord>(&out.join("plant.log"))?.records;
    let mut lat = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3)?;
    let mut jit = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3)?;
    let (mut misses, mut overruns, mut stall_count, mut stall_max, mut in_stall) =
        (0u64, 0u64, 0u64, 0.0f64, false);
    let mut miss_outside = 0u64;
    for r in &recs {
        if r.latency_ns != u64::MAX {
            lat.saturating_record(r.latency_ns.max(1));
        }
        jit.saturating_record(r.wake_late_ns.max(1));
        let stalled = r.flags & REC_STALL != 0;
        if r.flags & REC_MISSED != 0 {
            misses += 1;
            if !stalled {
                miss_outside += 1;
            }
        }
        if r.flags & REC_OVERRUN != 0 {
            overruns += 1;
        }
        if stalled {
            if !in_stall {
                stall_count += 1;
            }
            stall_max = stall_max.max(r.wake_late_ns as f64 * 1e-6);
        }
        in_stall = stalled;
    }
    // Which misses fell while the scheduler had lost its core (it records, per answered cycle,
    // the longest stretch without a poll): such a miss is the machine's, not the loop's.
    let sched = read_log::<SchedRecord>(&out.join("scheduler.log"))
        .map(|l| l.records)
        .unwrap_or_default();
    let attribution = attribute_misses(&recs, &sched, period_ns);
    let plant_info = read_json(&out.join("plant.json")).unwrap_or(Value::Null);
    let sched_info = read_json(&out.join("scheduler.json")).unwrap_or(Value::Null);
    let v = json!({
        "cycles": recs.len(),
        "period_s": period_s,
        "wait": wait_kind.id(),
        "latency_us": hist_json(&lat),
        "jitter_us": hist_json(&jit),
        "deadline_misses": misses,
        "plant_overruns": overruns,
        "stalls": {"count": stall_count, "max_ms": stall_max},
        "misses_outside_stalls": miss_outside,
        "core_losses": {
            "threshold_us": (period_ns / 2) as f64 / 1000.0,
            "scheduler": attribution.scheduler_losses,
            "scheduler_max_us": attribution.scheduler_max_ns as f64 / 1000.0,
            "plant_waits": attribution.plant_losses,
        },
        "misses_during_core_losses": attribution.explained,
        "misses_outside_stalls_and_core_losses": attribution.unexplained,
        "reference": reference,
        "realtime": {
            "mlockall": plant_info["realtime"]["mlockall"].as_bool().unwrap_or(false)
                && sched_info["realtime"]["mlockall"].as_bool().unwrap_or(false),
            "sched_fifo": plant_info["realtime"]["sched_fifo"].as_bool().unwrap_or(false)
                && sched_info["realtime"]["sched_fifo"].as_bool().unwrap_or(false),
            "pinned": cpus,
            "plant": plant_info["realtime"],
            "scheduler": sched_info["realtime"],
        },
        "peak_rss_bytes": {"plant": plant_info["peak_rss_bytes"], "scheduler": sched_info["peak_rss_bytes"]},
        "end": plant_info["end"],
    });
    write_json(&out.join("latency.json"), &v)?;
    std::fs::write(out.join("latency.svg"), percentile_svg(&lat, &jit))?;
    println!(
        "latency us: p50 {:.2}  p99 {:.2}  p99.9 {:.2}  max {:.2}",
        v["latency_us"]["p50"],
        v["latency_us"]["p99"],
        v["latency_us"]["p999"],
        v["latency_us"]["max"]
    );
    println!(
        "jitter  us: p50 {:.2}  p99 {:.2}  p99.9 {:.2}  max {:.2}",
        v["jitter_us"]["p50"], v["jitter_us"]["p99"], v["jitter_us"]["p999"], v["jitter_us"]["max"]
    );
    println!(
        "deadline misses {misses} ({miss_outside} outside stalls), overruns {overruns}, stalls {stall_count} (max {stall_max:.2} ms)"
    );
    println!(
        "core lost for >= {:.0} us: scheduler {} times (max {:.0} us), plant while waiting {} times; misses then: {}; misses outside stalls and core losses: {}",
        period_ns as f64 / 2000.0,
        attribution.scheduler_losses,
        attribution.scheduler_max_ns as f64 / 1000.0,
        attribution.plant_losses,
        attribution.explained,
        attribution.unexplained
    );
    if !v["reference"].is_null() {
        let r = &v["reference"];
        println!(
            "reference on the same CPUs: sleeping loop jitter p50 {:.2} p99 {:.2} p99.9 {:.2} max {:.2} us (SCHED_FIFO {}); \
             a bare spinning loop lost its core for >= {:.0} us {} times ({:.1}/s, max {:.0} us)",
            r["sleeping_loop"]["jitter_us"]["p50"],
            r["sleeping_loop"]["jitter_us"]["p99"],
            r["sleeping_loop"]["jitter_us"]["p999"],
            r["sleeping_loop"]["jitter_us"]["max"],
            r["sleeping_loop"]["sched_fifo"],
            period_ns as f64 / 2000.0,
            r["spinning_loop"]["interruptions"],
            r["spinning_loop"]["interruptions_per_s"].as_f64().unwrap_or(0.0),
            r["spinning_loop"]["max_us"].as_f64().unwrap_or(0.0),
        );
    }
    println!(
        "wrote {} and {}",
        out.join("latency.json").display(),
        out.join("latency.svg").display()
    );
    Ok(ExitCode::SUCCESS)
}

/// Deadline misses split by whether a process had lost its core when they happened.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Attribution {
    /// Answered cycles around which the scheduler went at least half a period without progress.
    scheduler_losses: u64,
    /// Longest such stretch, ns.
    scheduler_max_ns: u64,
    /// Missed cycles during whose wait the plant itself lost its core for half a period.
    plant_losses: u64,
    /// Misses (outside plant stalls) covered by a core loss of either process.
    explained: u64,
    /// Misses outside plant stalls and outside core losses.
    unexplained: u64,
}

/// A miss of cycle `s` is covered when the plant lost its core while waiting for it
/// (`REC_WAIT_INTERRUPTED`), or when the first cycle the scheduler answered at or after `s` came
/// after a stretch without progress (or a computation) of at least half a period that reaches
/// back to `s`'s period: the scheduler could not have answered `s` in time.
fn attribute_misses(plant: &[PlantRecord], sched: &[SchedRecord], period_ns: u64) -> Attribution {
    let half = period_ns / 2;
    let mut a = Attribution::default();
    let lost = |r: &SchedRecord| u64::from(r.poll_gap_ns).max(u64::from(r.compute_ns));
    for r in sched {
        if lost(r) >= half {
            a.scheduler_losses += 1;
            a.scheduler_max_ns = a.scheduler_max_ns.max(lost(r));
        }
    }
    let mut j = 0usize;
    for p in plant {
        if p.flags & REC_MISSED == 0 {
            continue;
        }
        let plant_lost = p.flags & REC_WAIT_INTERRUPTED != 0;
        if plant_lost {
            a.plant_losses += 1;
        }
        if p.flags & REC_STALL != 0 {
            continue;
        }
        // scheduler records are in cycle order: advance to the first at or after this cycle
        while j < sched.len() && sched[j].seq < p.seq {
            j += 1;
        }
        let covered = plant_lost
            || sched.get(j).is_some_and(|r| {
                let g = lost(r);
                g >= half && (r.seq - p.seq) * period_ns <= g + period_ns
            });
        if covered {
            a.explained += 1;
        } else {
            a.unexplained += 1;
        }
    }
    a
}

/// Reference loops run on the benchmark's CPUs before the run, one thread per CPU.
mod probe {
    use std::time::Duration;

    use anyhow::Result;
    use hdrhistogram::Histogram;

    use feedloop_runtime::shared::clock::{now_ns, sleep_until_ns};
    use feedloop_runtime::shared::rt::{apply, RtRequest};

    /// Result of [`sleeping_loop`].
    pub struct Sleeping {
        /// Wake-up lateness of every period on every CPU, ns.
        pub lateness: Histogram<u64>,
        /// Whether SCHED_FIFO was granted on every CPU.
        pub sched_fifo: bool,
    }

    /// A cyclictest-style loop on each CPU: sleep to an absolute deadline every `period_ns`
    /// (SCHED_FIFO 80 when permitted, memory locked), record how late each wake-up is.
    pub fn sleeping_loop(cpus: &[usize], period_ns: u64, time: Duration) -> Result<Sleeping> {
        let results: Vec<(Histogram<u64>, bool)> = std::thread::scope(|sc| {
            let handles: Vec<_> = cpus
                .iter()
                .map(|&cpu| {
                    sc.spawn(move || -> Result<(Histogram<u64>, bool)> {
                        let applied = apply(&RtRequest {
                            mlockall: true,
                            fifo_priority: Some(80),
                            cpu: Some(cpu),
                        });
                        let mut h = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3)?;
                        let start = now_ns() + 1_000_000;
                        let end = start + time.as_nanos() as u64;
                        let mut next = start;
                        while next < end {
                            sleep_until_ns(next);
                            h.saturating_record(now_ns().saturating_sub(next).max(1));
                            next += period_ns;
                        }
                        Ok((h, applied.sched_fifo))
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|t| {
                    t.join()
                        .unwrap_or_else(|_| Err(anyhow::anyhow!("probe thread panicked")))
                })
                .collect::<Result<Vec<_>>>()
        })?;
        let mut lateness = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3)?;
        let mut fifo = !results.is_empty();
        for (h, f) in &results {
            lateness.add(h)?;
            fifo &= *f;
        }
        Ok(Sleeping {
            lateness,
            sched_fifo: fifo,
        })
    }

    /// Result of [`spinning_loop`].
    pub struct Spinning {
        /// Stretches of at least the threshold between two clock readings, all CPUs.
        pub count: u64,
        /// Their total length, ns.
        pub lost_ns: u64,
        /// The longest, ns.
        pub max_ns: u64,
    }

    /// A bare spinning loop on each CPU (what a busy-polling process does, without any IPC):
    /// counts the stretches of at least `threshold_ns` between two consecutive clock readings,
    /// i.e. the times the OS or the hypervisor took the core away.
    pub fn spinning_loop(cpus: &[usize], threshold_ns: u64, time: Duration) -> Result<Spinning> {
        let results: Vec<(u64, u64, u64)> = std::thread::scope(|sc| {
            let handles: Vec<_> = cpus
                .iter()
                .map(|&cpu| {
                    sc.spawn(move || {
                        apply(&RtRequest {
                            mlockall: false,
                            fifo_priority: None,
                            cpu: Some(cpu),
                        });
                        let (mut count, mut lost, mut max) = (0u64, 0u64, 0u64);
                        let end = now_ns() + time.as_nanos() as u64;
                        let mut prev = now_ns();
                        while prev < end {
                            let now = now_ns();
                            let gap = now - prev;
                            if gap >= threshold_ns {
                                count += 1;
                                lost += gap;
                                max = max.max(gap);
                            }
                            prev = now;
                        }
                        (count, lost, max)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|t| t.join().unwrap_or((0, 0, 0)))
                .collect()
        });
        Ok(Spinning {
            count: results.iter().map(|r| r.0).sum(),
            lost_ns: results.iter().map(|r| r.1).sum(),
            max_ns: results.iter().map(|r| r.2).max().unwrap_or(0),
        })
    }
}

/// A percentile plot (latency and jitter, log-scaled tail axis) as a standalone SVG.
fn percentile_svg(lat: &Histogram<u64>, jit: &Histogram<u64>) -> String {
    let (w, h, l, r, t, b) = (720.0, 420.0, 70.0, 20.0, 30.0, 60.0);
    // x: -log10(1 - q) from 0 (p0) to 5 (p99.999)
    let qs: Vec<f64> = (0..=100).map(|i| i as f64 * 0.05).collect();
    let val = |hist: &Histogram<u64>, x: f64| {
        let q = (1.0 - 10f64.powf(-x)).clamp(0.0, 1.0);
        hist.value_at_quantile(q) as f64 / 1000.0
    };
    let ymax = qs
        .iter()
        .map(|x| val(lat, *x).max(val(jit, *x)))
        .fold(1.0f64, f64::max);
    let (ylo, yhi) = (0.1f64.log10(), (ymax * 1.5).log10());
    let px = |x: f64| l + (w - l - r) * x / 5.0;
    let py = |y: f64| t + (h - t - b) * (1.0 - ((y.max(0.1).log10() - ylo) / (yhi - ylo)));
    let line = |hist: &Histogram<u64>| {
        qs.iter()
            .map(|x| format!("{:.1},{:.1}", px(*x), py(val(hist, *x))))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let mut s = format!(
        "<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='sans-serif' font-size='12'>\
         <rect width='100%' height='100%' fill='white'/>\
         <text x='{l}' y='18' font-size='14'>feedloop bench latency: percentiles (us, log scale)</text>"
    );
    for (x, label) in [
        (0.0, "p0"),
        (0.301, "p50"),
        (1.0, "p90"),
        (2.0, "p99"),
        (3.0, "p99.9"),
        (4.0, "p99.99"),
        (5.0, "p99.999"),
    ] {
        s += &format!(
            "<line x1='{0:.1}' x2='{0:.1}' y1='{t}' y2='{1}' stroke='#ddd'/><text x='{0:.1}' y='{2}' text-anchor='middle'>{label}</text>",
            px(x),
            h - b,
            h - b + 16.0
        );
    }
    let mut y = 10f64.powf(ylo.ceil());
    while y.log10() <= yhi {
        s += &format!(
            "<line x1='{l}' x2='{0}' y1='{1:.1}' y2='{1:.1}' stroke='#ddd'/><text x='{2}' y='{3:.1}' text-anchor='end'>{y}</text>",
            w - r,
            py(y),
            l - 6.0,
            py(y) + 4.0
        );
        y *= 10.0;
    }
    s += &format!(
        "<polyline fill='none' stroke='#1f77b4' stroke-width='2' points='{}'/>",
        line(lat)
    );
    s += &format!(
        "<polyline fill='none' stroke='#d62728' stroke-width='2' points='{}'/>",
        line(jit)
    );
    s += &format!(
        "<text x='{0}' y='{1}' fill='#1f77b4'>round trip (sample -> command)</text><text x='{0}' y='{2}' fill='#d62728'>plant wake-up lateness (jitter)</text>",
        l + 10.0,
        t + 16.0,
        t + 32.0
    );
    s += &format!(
        "<text x='{0}' y='{1}' text-anchor='middle'>percentile</text></svg>\n",
        (l + w - r) / 2.0,
        h - 12.0
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plant(seq: u64, flags: u8) -> PlantRecord {
        PlantRecord {
            seq,
            flags,
            ..Default::default()
        }
    }

    fn sched(seq: u64, poll_gap_us: u32) -> SchedRecord {
        SchedRecord {
            seq,
            compute_ns: 300,
            poll_gap_ns: poll_gap_us * 1000,
            ..Default::default()
        }
    }

    #[test]
    fn misses_are_explained_only_by_a_core_loss_that_reaches_back_to_them() {
        let period = 100_000;
        // cycles 10..=12 missed; the scheduler answered 13 after 350 us without a poll: all three
        // are covered. Cycle 20 missed, but 21 was answered after only 2 us: not covered. Cycle 30
        // missed during a plant stall: neither. Cycle 40 missed and the next answer (45) came
        // after a 120 us loss that cannot reach back five periods: not covered.
        let mut p: Vec<PlantRecord> = (0..50).map(|k| plant(k, 0)).collect();
        for k in [10, 11, 12, 20, 40] {
            p[k].flags = REC_MISSED;
        }
        p[30].flags = REC_MISSED | REC_STALL;
        let mut s: Vec<SchedRecord> = (0..50)
            .filter(|k| ![10, 11, 12, 20, 30, 40, 41, 42, 43, 44].contains(k))
            .map(|k| sched(k, 1))
            .collect();
        for r in s.iter_mut() {
            match r.seq {
                13 => r.poll_gap_ns = 350_000,
                21 => r.poll_gap_ns = 2_000,
                45 => r.poll_gap_ns = 120_000,
                _ => {}
            }
        }
        let a = attribute_misses(&p, &s, period);
        assert_eq!(a.scheduler_losses, 2);
        assert_eq!(a.scheduler_max_ns, 350_000);
        assert_eq!(a.explained, 3);
        assert_eq!(a.unexplained, 2);
        // a long computation counts like a long stretch without a poll
        s.iter_mut().find(|r| r.seq == 21).unwrap().compute_ns = 90_000;
        let b = attribute_misses(&p, &s, period);
        assert_eq!((b.explained, b.unexplained, b.scheduler_losses), (4, 1, 3));
        // and so does the plant losing its core while it waited for cycle 40
        p[40].flags |= REC_WAIT_INTERRUPTED;
        let c = attribute_misses(&p, &s, period);
        assert_eq!((c.explained, c.unexplained, c.plant_losses), (5, 0, 1));
    }

    #[test]
    fn a_spinning_probe_sees_a_forced_gap_and_a_sleeping_probe_records_every_period() {
        // with a zero threshold every stretch between two clock readings counts, and together
        // they cover the whole window; with an unreachable threshold none does
        let all = probe::spinning_loop(&[0], 0, Duration::from_millis(20)).unwrap();
        assert!(all.count > 1000, "{} stretches", all.count);
        assert!(all.lost_ns > 10_000_000 && all.lost_ns <= 40_000_000);
        let none = probe::spinning_loop(&[0], u64::MAX, Duration::from_millis(20)).unwrap();
        assert_eq!((none.count, none.lost_ns, none.max_ns), (0, 0, 0));
        let s = probe::sleeping_loop(&[0], 1_000_000, Duration::from_millis(50)).unwrap();
        assert_eq!(s.lateness.len(), 50);
    }
}
