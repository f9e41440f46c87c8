//! `feedloop bench`: the loop's latency and what costs it. `latency` (a realtime run of the two
//! processes against the bare ping-pong of its messages and reference loops), `table` (one row
//! per such run), `scope` (the same chain with `feedloop scope` watching).
//!
//! `job` writes the benchmark's job and runs its processes (both benches use it), `pingpong`
//! measures the bare iceoryx2 floor, `latency` and `scope` are the two benches, `report` prints
//! `bench latency`'s summary and `bench table`.

mod job;
mod latency;
mod pingpong;
mod report;
mod scope;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;

use crate::choice::WaitArg;
use latency::LatencyOpts;

/// Benchmark subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum BenchCmd {
    /// Round-trip latency and period jitter of a realtime run: the X-C grinder of
    /// `examples/jobs/xc-full-chain.toml`, all four controllers of the patents on two axes.
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
    Scope(scope::ScopeBenchArgs),
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
        } => latency::latency(&LatencyOpts {
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
        BenchCmd::Table { runs } => report::table(&runs),
        BenchCmd::Scope(a) => scope::run(&a),
        BenchCmd::PingEcho {
            instance,
            cpu,
            stamps,
        } => pingpong::echo_side(&instance, cpu, &stamps),
    }
}
