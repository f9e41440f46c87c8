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

use latency::LatencyOpts;

/// Benchmark subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum BenchCmd {
    /// Round-trip latency and period jitter of a realtime run: the X-C grinder of
    /// `examples/jobs/xc-full-chain.toml`, all four controllers of the patents on two axes.
    Latency(LatencyOpts),
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
        BenchCmd::Latency(o) => latency::latency(&o),
        BenchCmd::Table { runs } => report::table(&runs),
        BenchCmd::Scope(a) => scope::run(&a),
        BenchCmd::PingEcho {
            instance,
            cpu,
            stamps,
        } => pingpong::echo_side(&instance, cpu, &stamps),
    }
}
