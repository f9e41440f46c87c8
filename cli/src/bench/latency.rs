//! `feedloop bench latency`: a realtime run of the two processes that records every cycle's
//! round-trip latency (sample published -> command received) and the plant's wake-up jitter into
//! HDR histograms, and reports them with deadline misses, overruns and stalls.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use serde_json::{json, Value};

use feedloop_analysis::latency::{
    attribute_misses, hist_json, ns_histogram_of, percentile_svg, reference, Attribution,
    Breakdown, ReferenceLoops, RunFigures,
};
use feedloop_model::job::WaitKind;
use feedloop_runtime::shared::pingpong::PingPong;
use feedloop_trace::log::{read_log, PlantRecord, SchedRecord};

use super::job::{bench_job, run_processes, ChainArgs};
use super::pingpong::{pingpong, pingpong_parts, TimedPings};
use super::report::print_report;
use crate::choice::Choice;
use crate::processes::{read_json, write_json};

/// What `bench latency` was asked for.
#[derive(clap::Args, Debug)]
pub struct LatencyOpts {
    /// Cycles to run.
    #[arg(long, default_value_t = 100_000)]
    pub(super) cycles: u64,
    #[command(flatten)]
    pub(super) chain: ChainArgs,
    /// SCHED_FIFO priority for both processes (refused with busy waits).
    #[arg(long)]
    pub(super) fifo: Option<i32>,
    /// Output folder (latency.json, latency.svg, the run's logs).
    #[arg(long)]
    pub(super) out: PathBuf,
    /// Seconds of each reference measurement taken on the same CPUs just before the run: a
    /// cyclictest-style sleeping loop at the same period (SCHED_FIFO 80 when permitted) and
    /// a bare spinning loop that counts how often the machine takes a core away. 0 skips them.
    #[arg(long, default_value_t = 10.0)]
    pub(super) reference_s: f64,
    /// Round trips of the bare iceoryx2 ping-pong of the loop's own messages, measured on
    /// the same CPUs just before the run (before each of its parts), back to back and again
    /// one per period (default: --cycles, so that the floor is measured as long as the loop;
    /// 0 skips it).
    #[arg(long)]
    pub(super) pingpong_cycles: Option<u64>,
    /// Slices the run into this many parts, each preceded by its share of the ping-pong, so
    /// that the loop and its floor see the same states of the host (which can move the floor
    /// 2.5x within minutes); the figures pool all parts. Default: one part per 30,000
    /// cycles, at most 10. The parts' logs go to `segment-K/` in --out.
    #[arg(long)]
    pub(super) segments: Option<u64>,
    /// How long the plant (and the ping-pong's pinger) watch their core before starting,
    /// to start the cycles at the phase of the period the host's periodic interruptions
    /// leave alone (the job's `[run] phase_probe_s`); 0 starts them at whatever phase.
    #[arg(long, default_value_t = feedloop_model::job::DEFAULT_PHASE_PROBE_S)]
    pub(super) phase_probe_s: f64,
}

impl LatencyOpts {
    /// Round trips of the bare ping-pong (default: `cycles`).
    fn pingpong_cycles(&self) -> u64 {
        self.pingpong_cycles.unwrap_or(self.cycles)
    }

    /// Parts of the run (default: one per 30,000 cycles, at most 10).
    fn segments(&self) -> u64 {
        self.segments
            .unwrap_or(self.cycles.div_ceil(30_000).clamp(1, 10))
    }
}

/// A checked `bench latency` and what its parts share.
struct Bench<'a> {
    o: &'a LatencyOpts,
    wait_kind: WaitKind,
    /// the CPUs asked for (none: unpinned)
    cpus: Vec<usize>,
    /// the CPUs of the ping-pong and the reference loops: those asked for, else the first two
    probe_cpus: Vec<usize>,
    period_ns: u64,
    job: PathBuf,
    segments: u64,
    instance: String,
}

/// The parts' records joined as one run, with the ping-pongs taken before them.
#[derive(Default)]
struct Joined {
    recs: Vec<PlantRecord>,
    sched: Vec<SchedRecord>,
    pp: Option<PingPong>,
    stamps: Vec<TimedPings>,
    last_dir: PathBuf,
    /// per part: the phase the plant's probe chose, and the ping-pong's
    loop_phases: Vec<Value>,
    pp_phases: Vec<Value>,
}

/// What the joined run's records and the reference loops came to.
struct Measured {
    figures: RunFigures,
    attribution: Attribution,
    parts: Breakdown,
    reference: Value,
    pingpong: Value,
}

pub(super) fn latency(o: &LatencyOpts) -> Result<ExitCode> {
    let (wait_kind, cpus) = checked(o)?;
    let out = o.out.as_path();
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let job = bench_job(out, o.chain.period_s, wait_kind, o.cycles, o.phase_probe_s)?;
    let period_ns = (o.chain.period_s * 1e9).round() as u64;
    let probe_cpus: Vec<usize> = if cpus.is_empty() {
        (0..std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .min(2))
            .collect()
    } else {
        cpus.clone()
    };
    let (reference, reference_plot) = if o.reference_s > 0.0 {
        let (v, sleeping, spinning_max_ns) =
            reference_loops(&probe_cpus, period_ns, o.reference_s)?;
        (v, Some((sleeping, spinning_max_ns)))
    } else {
        (Value::Null, None)
    };
    let segments = o.segments().clamp(1, o.cycles);
    if segments > 1 {
        eprintln!(
            "bench latency: {segments} parts, each its share of the ping-pong, then of the run"
        );
    }
    let b = Bench {
        o,
        wait_kind,
        cpus,
        probe_cpus,
        period_ns,
        job,
        segments,
        instance: format!("bench{}", std::process::id()),
    };
    let mut joined = Joined {
        recs: Vec::with_capacity(o.cycles as usize),
        sched: Vec::with_capacity(o.cycles as usize),
        last_dir: out.to_path_buf(),
        ..Joined::default()
    };
    for k in 0..segments {
        b.run_part(k, &mut joined)?;
    }
    let pp_after = b.pingpong_after()?;
    let figures = RunFigures::from_records(&joined.recs)?;
    // Which misses fell while the scheduler had lost its core (it records, per answered cycle,
    // the longest stretch without a poll): such a miss is the machine's, not the loop's.
    let attribution = attribute_misses(&joined.recs, &joined.sched, period_ns);
    let parts = Breakdown::from_records(&joined.recs, &joined.sched)?;
    let pingpong = pingpong_json(&joined, pp_after.as_ref(), &figures, segments)?;
    let m = Measured {
        figures,
        attribution,
        parts,
        reference,
        pingpong,
    };
    let v = b.latency_json(&joined, &m);
    write_json(&out.join("latency.json"), &v)?;
    std::fs::write(
        out.join("latency.svg"),
        percentile_svg(
            &m.figures.latency,
            &m.figures.jitter,
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
    print_report(&v, &m.figures, &m.attribution, period_ns);
    println!(
        "wrote {} and {}",
        out.join("latency.json").display(),
        out.join("latency.svg").display()
    );
    Ok(ExitCode::SUCCESS)
}

/// The options checked: the wait and the CPUs asked for.
fn checked(o: &LatencyOpts) -> Result<(WaitKind, Vec<usize>)> {
    let (cycles, reference_s) = (o.cycles, o.reference_s);
    let wait_kind = o.chain.checked()?;
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
    let cpus = o.chain.cpus()?;
    Ok((wait_kind, cpus))
}

impl Bench<'_> {
    /// Part `k`'s share of `n`.
    fn share(&self, k: u64, n: u64) -> u64 {
        n / self.segments + u64::from(k < n % self.segments)
    }

    /// Part `k`: its share of the ping-pong, then of the run, joined to `j` (the part's cycle
    /// numbers shifted past the last).
    fn run_part(&self, k: u64, j: &mut Joined) -> Result<()> {
        let (o, segments) = (self.o, self.segments);
        let out = o.out.as_path();
        if o.pingpong_cycles() > 0 {
            let n = self.share(k, o.pingpong_cycles());
            eprintln!(
                "bench latency: bare iceoryx2 ping-pong of the loop's messages, {n} round trips \
                 back to back and {n} one per period",
            );
            let (p, st) = pingpong(&self.probe_cpus, self.period_ns, n, o.phase_probe_s, out)?;
            let all = j.pp.get_or_insert_with(PingPong::default);
            all.back_to_back_ns.extend(&p.back_to_back_ns);
            all.paced_ns.extend(&p.paced_ns);
            j.pp_phases
                .push(p.phase.map_or(Value::Null, crate::processes::phase_json));
            j.stamps.push((p.stamped, st));
        }
        let n = self.share(k, o.cycles);
        eprintln!(
            "bench latency: {n} cycles at {:.1} kHz, wait {}, about {:.1} s{}",
            1e-3 / o.chain.period_s,
            o.chain.wait.id(),
            n as f64 * o.chain.period_s,
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
        run_processes(
            &self.job,
            &dir,
            self.wait_kind,
            n,
            &self.cpus,
            o.fifo,
            &self.instance,
        )?;
        j.loop_phases
            .push(read_json(&dir.join("plant.json")).map_or(Value::Null, |v| v["phase"].clone()));
        let base = j.recs.last().map_or(0, |r| r.seq + 1_000);
        let mut p = read_log::<PlantRecord>(&dir.join("plant.log"))?.records;
        let mut s = read_log::<SchedRecord>(&dir.join("scheduler.log"))
            .map(|l| l.records)
            .unwrap_or_default();
        p.iter_mut().for_each(|r| r.seq += base);
        s.iter_mut().for_each(|r| r.seq += base);
        j.recs.extend(p);
        j.sched.extend(s);
        j.last_dir = dir;
        Ok(())
    }

    /// The same ping-pong again just after: how far the host's state moved during the run.
    fn pingpong_after(&self) -> Result<Option<PingPong>> {
        let o = self.o;
        if o.pingpong_cycles() == 0 {
            return Ok(None);
        }
        eprintln!("bench latency: the ping-pong again, after the run");
        Ok(Some(
            pingpong(
                &self.probe_cpus,
                self.period_ns,
                o.pingpong_cycles().div_ceil(self.segments),
                o.phase_probe_s,
                &o.out,
            )?
            .0,
        ))
    }

    /// `latency.json`.
    fn latency_json(&self, j: &Joined, m: &Measured) -> Value {
        let (o, figures, attribution, parts) = (self.o, &m.figures, &m.attribution, &m.parts);
        let plant_info = read_json(&j.last_dir.join("plant.json")).unwrap_or(Value::Null);
        let sched_info = read_json(&j.last_dir.join("scheduler.json")).unwrap_or(Value::Null);
        json!({
            "cycles": j.recs.len(),
            "segments": self.segments,
            "period_s": o.chain.period_s,
            "wait": self.wait_kind.id(),
            "latency_us": hist_json(&figures.latency),
            "jitter_us": hist_json(&figures.jitter),
            "deadline_misses": figures.misses,
            "plant_overruns": figures.overruns,
            "stalls": {"count": figures.stalls, "max_ms": figures.stall_max_ms},
            "misses_outside_stalls": figures.misses_outside_stalls,
            "core_losses": {
                "threshold_us": (self.period_ns / 2) as f64 / 1000.0,
                "scheduler": attribution.scheduler_losses,
                "scheduler_max_us": attribution.scheduler_max_ns as f64 / 1000.0,
                "plant_waits": attribution.plant_losses,
            },
            "misses_during_core_losses": attribution.explained,
            "misses_outside_stalls_and_core_losses": attribution.unexplained,
            "reference": m.reference,
            "iceoryx_pingpong": m.pingpong,
            "phase": {
                "what": "per part, what a probe of the core saw before the cycles started (the \
                         plant's, and the ping-pong pinger's before its paced pings) and the \
                         phase of the period they were started at: the one whose window the \
                         host's interruptions hit least (hit_share: share of periods hit at that \
                         phase, worst_hit_share: at the worst phase)",
                "probe_s": o.phase_probe_s,
                "loop": j.loop_phases,
                "pingpong": j.pp_phases,
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
                "pinned": self.cpus,
                "plant": plant_info["realtime"],
                "scheduler": sched_info["realtime"],
            },
            "peak_rss_bytes": {"plant": plant_info["peak_rss_bytes"], "scheduler": sched_info["peak_rss_bytes"]},
            "end": plant_info["end"],
        })
    }
}

/// `latency.json`'s `iceoryx_pingpong`: the ping-pongs before the parts and the one after, their
/// ratios to the loop's round trip and the timed pings' parts; null without a ping-pong.
fn pingpong_json(
    j: &Joined,
    pp_after: Option<&PingPong>,
    figures: &RunFigures,
    segments: u64,
) -> Result<Value> {
    let (Some(pp), Some(after)) = (&j.pp, pp_after) else {
        return Ok(Value::Null);
    };
    let parts = pingpong_parts(&j.stamps)?;
    let after_paced = ns_histogram_of(&after.paced_ns)?;
    let after_b2b = ns_histogram_of(&after.back_to_back_ns)?;
    let b2b = ns_histogram_of(&pp.back_to_back_ns)?;
    let paced = ns_histogram_of(&pp.paced_ns)?;
    let q = |h: &hdrhistogram::Histogram<u64>, p: f64| h.value_at_quantile(p) as f64;
    let ratio =
        |h: &hdrhistogram::Histogram<u64>, p: f64| q(&figures.latency, p) / q(h, p).max(1.0);
    Ok(json!({
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
