//! `feedloop bench latency`: a realtime run of the two processes that records every cycle's
//! round-trip latency (sample published -> command received) and the plant's wake-up jitter into
//! HDR histograms, and reports them with deadline misses, overruns and stalls.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use hdrhistogram::Histogram;
use serde_json::{json, Value};

use feedloop_runtime::job::{Mode, WaitKind};
use feedloop_runtime::record::{read_log, PlantRecord, REC_MISSED, REC_OVERRUN, REC_STALL};

use crate::processes::{read_json, spawn, write_json};

/// Benchmark subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum BenchCmd {
    /// Round-trip latency and period jitter of a realtime run (2 axes, full chain).
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
        } => latency(cycles, period_s, &wait, pin.as_deref(), fifo, &out),
    }
}

const MODEL_X: &str = include_str!("../../examples/models/xy-x.toml");
const MODEL_Y: &str = include_str!("../../examples/models/xy-y.toml");

fn bench_job(dir: &Path, period_s: f64, wait: WaitKind) -> Result<PathBuf> {
    std::fs::write(dir.join("bench-x.toml"), MODEL_X)?;
    std::fs::write(dir.join("bench-y.toml"), MODEL_Y)?;
    let job = format!(
        "# written by `feedloop bench latency`\nname = \"bench-latency\"\nperiod_s = {period_s:e}\n\
         [run]\nmode = \"realtime\"\nwait = \"{}\"\n[axes.x]\nmodel = \"bench-x.toml\"\n\
         [axes.y]\nmodel = \"bench-y.toml\"\n[trajectory]\nkind = \"dwell\"\nduration_s = 1.0\n",
        wait.id()
    );
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
) -> Result<ExitCode> {
    let wait_kind = WaitKind::parse(wait)
        .with_context(|| format!("--wait `{wait}`: expected busy, block or hybrid"))?;
    if !(period_s > 1e-6 && period_s <= 0.1) {
        bail!("--period-s {period_s}: must be within (1e-6, 0.1] s");
    }
    if cycles == 0 {
        bail!("--cycles must be > 0");
    }
    let cpus: Vec<usize> = match pin {
        None => vec![],
        Some(p) => p
            .split(',')
            .map(|c| {
                c.trim()
                    .parse::<usize>()
                    .with_context(|| format!("--pin `{p}`: expected two CPU numbers like 0,1"))
            })
            .collect::<Result<_>>()?,
    };
    if !cpus.is_empty() && cpus.len() != 2 {
        bail!("--pin takes two CPUs (plant,scheduler), got {}", cpus.len());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let job = bench_job(out, period_s, wait_kind)?;
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
        "wrote {} and {}",
        out.join("latency.json").display(),
        out.join("latency.svg").display()
    );
    Ok(ExitCode::SUCCESS)
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
