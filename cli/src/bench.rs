//! `feedloop bench latency`: a realtime run of the two processes that records every cycle's
//! round-trip latency (sample published -> command received) and the plant's wake-up jitter into
//! HDR histograms, and reports them with deadline misses, overruns and stalls.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use serde_json::{json, Value};

use feedloop_analysis::latency::{
    attribute_misses, hist_json, ns_histogram_of, percentile_svg, reference, Attribution,
    Breakdown, ReferenceLoops, RunFigures,
};
use feedloop_model::job::WaitKind;
use feedloop_model::units::{si, sig};
use feedloop_trace::log::{read_log, PlantRecord, SchedRecord};

use crate::bench_run::{bench_job, run_processes};
use crate::choice::{Choice, WaitArg};
use crate::processes::{read_json, write_json};
use feedloop_runtime::shared::pingpong::{echo, ping, EchoStamp, Pacing, PingPong};
use feedloop_runtime::shared::rt::{apply, RtRequest};

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
        /// How each process waits for the next message.
        #[arg(long, value_enum, default_value = "busy")]
        wait: WaitArg,
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
        /// Round trips of the bare iceoryx2 ping-pong of the loop's own messages, measured on
        /// the same CPUs just before the run (before each of its parts), back to back and again
        /// one per period (default: --cycles, so that the floor is measured as long as the loop;
        /// 0 skips it).
        #[arg(long)]
        pingpong_cycles: Option<u64>,
        /// Slices the run into this many parts, each preceded by its share of the ping-pong, so
        /// that the loop and its floor see the same states of the host (which can move the floor
        /// 2.5x within minutes); the figures pool all parts. Default: one part per 30,000
        /// cycles, at most 10. The parts' logs go to `segment-K/` in --out.
        #[arg(long)]
        segments: Option<u64>,
        /// How long the plant (and the ping-pong's pinger) watch their core before starting,
        /// to start the cycles at the phase of the period the host's periodic interruptions
        /// leave alone (the job's `[run] phase_probe_s`); 0 starts them at whatever phase.
        #[arg(long, default_value_t = feedloop_model::job::DEFAULT_PHASE_PROBE_S)]
        phase_probe_s: f64,
    },
    /// One table row per `latency.json` (of `bench latency` runs, e.g. from
    /// `scripts/latency-series`): the host's state, the bare ping-pong, the loop, their ratio,
    /// the jitter against the sleeping loop's and the misses the loop is responsible for.
    Table {
        /// `latency.json` files or the folders holding them.
        #[arg(required = true)]
        runs: Vec<PathBuf>,
    },
    /// The loop's latency and misses with `feedloop scope` attached and a headless browser
    /// drawing its page, against the same run without it, side by side (`scope-bench.json`),
    /// with the scope's resident memory sampled through the run.
    Scope(crate::bench_scope::ScopeBenchArgs),
    /// The echoing side of `bench latency`'s ping-pong (started by it).
    #[command(hide = true)]
    PingEcho {
        /// Instance name of the ping-pong.
        #[arg(long)]
        instance: String,
        /// CPU to pin to.
        #[arg(long)]
        cpu: Option<usize>,
        /// Where to write the echo's timings of the timed pings.
        #[arg(long)]
        stamps: PathBuf,
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
            pingpong_cycles,
            segments,
            phase_probe_s,
        } => latency(&LatencyOpts {
            phase_probe_s,
            pingpong_cycles: pingpong_cycles.unwrap_or(cycles),
            segments: segments.unwrap_or(cycles.div_ceil(30_000).clamp(1, 10)),
            cycles,
            period_s,
            wait,
            pin,
            fifo,
            out,
            reference_s,
        }),
        BenchCmd::Table { runs } => table(&runs),
        BenchCmd::Scope(a) => crate::bench_scope::run(&a),
        BenchCmd::PingEcho {
            instance,
            cpu,
            stamps,
        } => {
            // best effort, as for the ping side: what was refused only makes the floor slower
            apply(&RtRequest {
                mlockall: true,
                fifo_priority: None,
                cpu,
            });
            let (_, st) = echo(&instance, Duration::from_secs(30))
                .map_err(|e| anyhow::anyhow!("ping-pong echo: {e}"))?;
            let bytes: Vec<u8> = st
                .iter()
                .flat_map(|s| [s.seq, s.received_ns, s.publish_ns, s.published_ns])
                .flat_map(u64::to_le_bytes)
                .collect();
            std::fs::write(&stamps, bytes)
                .with_context(|| format!("writing {}", stamps.display()))?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// The bare iceoryx2 ping-pong of the loop's messages (2 axes, as the bench job's) between
/// this process (a thread pinned to the first of `cpus`) and an echo process (on the second):
/// `n` round trips back to back, then `n` one per `period_ns`, at the phase a probe of
/// `phase_probe_s` chose (as the plant does; 0: at whatever phase).
fn pingpong(
    cpus: &[usize],
    period_ns: u64,
    n: u64,
    phase_probe_s: f64,
    dir: &Path,
) -> Result<(PingPong, Vec<EchoStamp>)> {
    let instance = format!("pingpong{}", std::process::id());
    let exe = std::env::current_exe().context("locating the feedloop binary")?;
    let stamps = dir.join("pingpong-echo.bin");
    let mut cmd = std::process::Command::new(exe);
    cmd.args(["bench", "ping-echo", "--instance", &instance, "--stamps"]);
    cmd.arg(&stamps);
    if let Some(c) = cpus.get(1) {
        cmd.args(["--cpu", &c.to_string()]);
    }
    crate::signals::die_with_parent(&mut cmd);
    let mut child = cmd.spawn().context("starting the ping-pong echo process")?;
    let first = cpus.first().copied();
    let result = std::thread::scope(|sc| {
        sc.spawn(|| {
            apply(&RtRequest {
                mlockall: true,
                fifo_priority: None,
                cpu: first,
            });
            ping(
                &instance,
                2,
                n,
                n,
                Pacing {
                    period_ns,
                    phase_probe_s,
                },
                Duration::from_secs(10),
            )
        })
        .join()
    });
    let status = child.wait();
    let pp = result
        .map_err(|_| anyhow::anyhow!("the ping-pong thread panicked"))?
        .map_err(|e| anyhow::anyhow!("ping-pong: {e}"))?;
    if let Ok(s) = status {
        if !s.success() {
            bail!("the ping-pong echo process failed ({s})");
        }
    }
    let bytes = std::fs::read(&stamps).with_context(|| format!("reading {}", stamps.display()))?;
    let _ = std::fs::remove_file(&stamps);
    let word = |c: &[u8]| u64::from_le_bytes(c.try_into().unwrap_or([0; 8]));
    let st = bytes
        .chunks_exact(32)
        .map(|c| EchoStamp {
            seq: word(&c[0..8]),
            received_ns: word(&c[8..16]),
            publish_ns: word(&c[16..24]),
            published_ns: word(&c[24..32]),
        })
        .collect();
    Ok((pp, st))
}

/// What `bench latency` was asked for.
struct LatencyOpts {
    cycles: u64,
    period_s: f64,
    wait: WaitArg,
    pin: Option<String>,
    fifo: Option<i32>,
    out: PathBuf,
    reference_s: f64,
    pingpong_cycles: u64,
    segments: u64,
    phase_probe_s: f64,
}

fn latency(o: &LatencyOpts) -> Result<ExitCode> {
    let (cycles, period_s, wait, pin, fifo, out, reference_s, pingpong_cycles) = (
        o.cycles,
        o.period_s,
        o.wait.id(),
        o.pin.as_deref(),
        o.fifo,
        o.out.as_path(),
        o.reference_s,
        o.pingpong_cycles,
    );
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
    let max_probe_s = feedloop_model::job::MAX_PHASE_PROBE_S;
    if !(o.phase_probe_s.is_finite() && (0.0..=max_probe_s).contains(&o.phase_probe_s)) {
        bail!(
            "--phase-probe-s {}: must be within [0, {max_probe_s}] s",
            o.phase_probe_s
        );
    }
    let cpus: Vec<usize> = match pin {
        None => vec![],
        Some(p) => crate::processes::parse_pin(p)?.to_vec(),
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let job = bench_job(out, period_s, wait_kind, cycles, o.phase_probe_s)?;
    let period_ns = (period_s * 1e9).round() as u64;
    let probe_cpus: Vec<usize> = if cpus.is_empty() {
        (0..std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .min(2))
            .collect()
    } else {
        cpus.clone()
    };
    let (reference, reference_plot) = if reference_s > 0.0 {
        let (v, sleeping, spinning_max_ns) = reference_loops(&probe_cpus, period_ns, reference_s)?;
        (v, Some((sleeping, spinning_max_ns)))
    } else {
        (Value::Null, None)
    };
    let segments = o.segments.clamp(1, cycles);
    if segments > 1 {
        eprintln!(
            "bench latency: {segments} parts, each its share of the ping-pong, then of the run"
        );
    }
    let instance = format!("bench{}", std::process::id());
    // the parts' records joined as one run: each part's cycle numbers shifted past the last
    let mut recs: Vec<PlantRecord> = Vec::with_capacity(cycles as usize);
    let mut sched: Vec<SchedRecord> = Vec::with_capacity(cycles as usize);
    let mut pp: Option<PingPong> = None;
    let mut stamps: Vec<TimedPings> = Vec::new();
    let mut last_dir = out.to_path_buf();
    // per part: the phase the plant's probe chose, and the ping-pong's
    let (mut loop_phases, mut pp_phases) = (Vec::new(), Vec::new());
    for k in 0..segments {
        let share = |n: u64| n / segments + u64::from(k < n % segments);
        if pingpong_cycles > 0 {
            eprintln!(
                "bench latency: bare iceoryx2 ping-pong of the loop's messages, {} round trips \
                 back to back and {} one per period",
                share(pingpong_cycles),
                share(pingpong_cycles)
            );
            let (p, st) = pingpong(
                &probe_cpus,
                period_ns,
                share(pingpong_cycles),
                o.phase_probe_s,
                out,
            )?;
            let all = pp.get_or_insert_with(PingPong::default);
            all.back_to_back_ns.extend(&p.back_to_back_ns);
            all.paced_ns.extend(&p.paced_ns);
            pp_phases.push(p.phase.map_or(Value::Null, crate::processes::phase_json));
            stamps.push((p.stamped, st));
        }
        let n = share(cycles);
        eprintln!(
            "bench latency: {n} cycles at {:.1} kHz, wait {wait}, about {:.1} s{}",
            1e-3 / period_s,
            n as f64 * period_s,
            if segments > 1 {
                format!(" (part {} of {segments})", k + 1)
            } else {
                String::new()
            }
        );
        let dir = if segments > 1 {
            out.join(format!("segment-{}", k + 1))
        } else {
            out.to_path_buf()
        };
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        run_processes(&job, &dir, wait_kind, n, &cpus, fifo, &instance)?;
        loop_phases
            .push(read_json(&dir.join("plant.json")).map_or(Value::Null, |v| v["phase"].clone()));
        let base = recs.last().map_or(0, |r| r.seq + 1_000);
        let mut p = read_log::<PlantRecord>(&dir.join("plant.log"))?.records;
        let mut s = read_log::<SchedRecord>(&dir.join("scheduler.log"))
            .map(|l| l.records)
            .unwrap_or_default();
        p.iter_mut().for_each(|r| r.seq += base);
        s.iter_mut().for_each(|r| r.seq += base);
        recs.extend(p);
        sched.extend(s);
        last_dir = dir;
    }
    // the same ping-pong again just after: how far the host's state moved during the run
    let pp_after = if pingpong_cycles > 0 {
        eprintln!("bench latency: the ping-pong again, after the run");
        Some(
            pingpong(
                &probe_cpus,
                period_ns,
                pingpong_cycles.div_ceil(segments),
                o.phase_probe_s,
                out,
            )?
            .0,
        )
    } else {
        None
    };
    let figures = RunFigures::from_records(&recs)?;
    // Which misses fell while the scheduler had lost its core (it records, per answered cycle,
    // the longest stretch without a poll): such a miss is the machine's, not the loop's.
    let attribution = attribute_misses(&recs, &sched, period_ns);
    let parts = Breakdown::from_records(&recs, &sched)?;
    let pingpong_json = match (&pp, &pp_after) {
        (Some(pp), Some(after)) => {
            let parts = pingpong_parts(&stamps)?;
            let after_paced = ns_histogram_of(&after.paced_ns)?;
            let after_b2b = ns_histogram_of(&after.back_to_back_ns)?;
            let b2b = ns_histogram_of(&pp.back_to_back_ns)?;
            let paced = ns_histogram_of(&pp.paced_ns)?;
            let q = |h: &hdrhistogram::Histogram<u64>, p: f64| h.value_at_quantile(p) as f64;
            let ratio = |h: &hdrhistogram::Histogram<u64>, p: f64| {
                q(&figures.latency, p) / q(h, p).max(1.0)
            };
            json!({
                "what": "the loop's own SensorSample / ActuatorCommand (2 axes) through plain \
                         iceoryx2 ports on services configured as the loop's, between two \
                         processes on the same CPUs, measured just before the run (before each \
                         of its parts)",
                "segments": segments,
                "back_to_back_us": hist_json(&b2b),
                "paced_us": hist_json(&paced),
                "ratio": {
                    "p50": ratio(&paced, 0.5),
                    "p99": ratio(&paced, 0.99),
                    "p50_back_to_back": ratio(&b2b, 0.5),
                    "p99_back_to_back": ratio(&b2b, 0.99),
                    "p50_after": ratio(&after_paced, 0.5),
                    "p99_after": ratio(&after_paced, 0.99),
                },
                "breakdown_us": parts,
                "after": {
                    "what": "the same ping-pong just after the run (the host's drift)",
                    "back_to_back_us": hist_json(&after_b2b),
                    "paced_us": hist_json(&after_paced),
                },
            })
        }
        _ => Value::Null,
    };
    let plant_info = read_json(&last_dir.join("plant.json")).unwrap_or(Value::Null);
    let sched_info = read_json(&last_dir.join("scheduler.json")).unwrap_or(Value::Null);
    let v = json!({
        "cycles": recs.len(),
        "segments": segments,
        "period_s": period_s,
        "wait": wait_kind.id(),
        "latency_us": hist_json(&figures.latency),
        "jitter_us": hist_json(&figures.jitter),
        "deadline_misses": figures.misses,
        "plant_overruns": figures.overruns,
        "stalls": {"count": figures.stalls, "max_ms": figures.stall_max_ms},
        "misses_outside_stalls": figures.misses_outside_stalls,
        "core_losses": {
            "threshold_us": (period_ns / 2) as f64 / 1000.0,
            "scheduler": attribution.scheduler_losses,
            "scheduler_max_us": attribution.scheduler_max_ns as f64 / 1000.0,
            "plant_waits": attribution.plant_losses,
        },
        "misses_during_core_losses": attribution.explained,
        "misses_outside_stalls_and_core_losses": attribution.unexplained,
        "reference": reference,
        "iceoryx_pingpong": pingpong_json,
        "phase": {
            "what": "per part, what a probe of the core saw before the cycles started (the \
                     plant's, and the ping-pong pinger's before its paced pings) and the phase \
                     of the period they were started at: the one whose window the host's \
                     interruptions hit least (hit_share: share of periods hit at that phase, \
                     worst_hit_share: at the worst phase)",
            "probe_s": o.phase_probe_s,
            "loop": loop_phases,
            "pingpong": pp_phases,
        },
        "breakdown_us": {
            "what": "each answered cycle's round trip in parts, from the shared monotonic clock",
            "cycles": parts.cycles,
            "to_scheduler": hist_json(&parts.to_scheduler),
            "before_compute": hist_json(&parts.before_compute),
            "chain": hist_json(&parts.chain),
            "publish": hist_json(&parts.publish),
            "to_plant": hist_json(&parts.to_plant),
        },
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
    std::fs::write(
        out.join("latency.svg"),
        percentile_svg(
            &figures.latency,
            &figures.jitter,
            period_ns,
            reference_plot
                .as_ref()
                .map(|(sleeping, spinning_max_ns)| ReferenceLoops {
                    sleeping: &sleeping.lateness,
                    spinning_max_ns: *spinning_max_ns,
                })
                .as_ref(),
        ),
    )?;
    print_report(&v, &figures, &attribution, period_ns);
    println!(
        "wrote {} and {}",
        out.join("latency.json").display(),
        out.join("latency.svg").display()
    );
    Ok(ExitCode::SUCCESS)
}

/// One ping-pong's timed pings: the pinger's `(seq, sent, answer held)` and the echo's stamps.
type TimedPings = (Vec<(u64, u64, u64)>, Vec<EchoStamp>);

/// The timed pings of a ping-pong in parts (as `latency.json`'s `iceoryx_pingpong.breakdown_us`):
/// per ping-pong, the pinger's readings `(seq, sent, answer held)` joined with the echo's of the
/// same seq.
fn pingpong_parts(pings: &[TimedPings]) -> Result<Value> {
    let mut parts: Vec<Vec<u64>> = vec![Vec::new(); 4];
    for (pinger, echo) in pings {
        let by_seq: std::collections::HashMap<u64, &EchoStamp> =
            echo.iter().map(|e| (e.seq, e)).collect();
        for (seq, t0, t1) in pinger {
            let Some(e) = by_seq.get(seq) else { continue };
            // as the loop's parts: each from the last reading before it (the echo's reading
            // after its publication can fall after the pinger already holds the answer)
            let marks = [*t0, e.received_ns, e.publish_ns, e.published_ns, *t1];
            for (i, w) in marks.windows(2).enumerate() {
                parts[i].push(w[1].saturating_sub(w[0]).max(1));
            }
        }
    }
    let h = |v: &[u64]| -> Result<Value> {
        Ok(if v.is_empty() {
            Value::Null
        } else {
            hist_json(&ns_histogram_of(v)?)
        })
    };
    Ok(json!({
        "what": "one paced ping in 8, timed by the echo too: publication -> the sample copied out \
                 at the echo; -> the answer's publication starts; -> published; -> the pinger \
                 holds the answer",
        "pings": parts[0].len(),
        "to_echo": h(&parts[0])?,
        "turnaround": h(&parts[1])?,
        "publish": h(&parts[2])?,
        "to_pinger": h(&parts[3])?,
    }))
}

/// The sleeping and the spinning reference loop on `cpus`, `seconds` each, as `latency.json`'s
/// `reference`, with the sleeping loop's histogram and the spinning loop's longest loss (ns)
/// for the plot.
fn reference_loops(
    cpus: &[usize],
    period_ns: u64,
    seconds: f64,
) -> Result<(Value, reference::Sleeping, u64)> {
    eprintln!(
        "reference: a sleeping loop, then a spinning loop, {seconds} s each on CPUs {cpus:?}"
    );
    let time = Duration::from_secs_f64(seconds);
    let sleeping = reference::sleeping_loop(cpus, period_ns, time)?;
    let spinning = reference::spinning_loop(cpus, period_ns / 2, time)?;
    let v = json!({
        "seconds": seconds,
        "cpus": cpus,
        "sleeping_loop": {
            "jitter_us": hist_json(&sleeping.lateness),
            "sched_fifo": sleeping.sched_fifo,
        },
        "spinning_loop": {
            "threshold_us": (period_ns / 2) as f64 / 1000.0,
            "interruptions": spinning.count,
            "interruptions_per_s": spinning.count as f64 / seconds,
            "interrupted_share": spinning.lost_ns as f64 / (seconds * 1e9 * cpus.len() as f64),
            "max_us": spinning.max_ns as f64 / 1000.0,
        },
    });
    Ok((v, sleeping, spinning.max_ns))
}

/// The figures of `latency.json` in a few lines.
fn print_report(v: &Value, f: &RunFigures, a: &Attribution, period_ns: u64) {
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
fn table(runs: &[PathBuf]) -> Result<ExitCode> {
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
