//! The benchmark's chain as a job (the X-C grinder with the four controllers of the patents, written
//! beside the run) and its two processes run to the end: what `bench latency` and `bench scope`
//! both measure.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use feedloop_model::job::{Mode, WaitKind};
use toml::{Table, Value};

use crate::choice::{Choice, WaitArg};
use crate::processes::spawn;

const JOB: &str = include_str!("../../../examples/jobs/xc-full-chain.toml");
const MODEL_X: &str = include_str!("../../../examples/models/xc-x.toml");
const MODEL_C: &str = include_str!("../../../examples/models/xc-c.toml");
const QUADRANT_TABLE: &str = include_str!("../../../examples/tables/xy-circle-quadrant.toml");

/// The loop settings both benches take: the period, the wait and the CPUs.
#[derive(clap::Args, Debug)]
pub struct ChainArgs {
    /// Control period, s.
    #[arg(long, default_value_t = 1.0e-4)]
    pub period_s: f64,
    /// How each process waits for the next message.
    #[arg(long, value_enum, default_value = "busy")]
    pub wait: WaitArg,
    /// CPUs for the plant and the scheduler, e.g. `0,1`.
    #[arg(long)]
    pub pin: Option<String>,
}

impl ChainArgs {
    /// The wait asked for, with the period checked.
    pub(super) fn checked(&self) -> Result<WaitKind> {
        let wait = self.wait.id();
        let wait_kind = WaitKind::parse(wait)
            .with_context(|| format!("--wait `{wait}`: expected busy, block or hybrid"))?;
        let period_s = self.period_s;
        if !(period_s > 1e-6 && period_s <= 0.1) {
            bail!("--period-s {period_s}: must be within (1e-6, 0.1] s");
        }
        Ok(wait_kind)
    }

    /// The CPUs asked for (none: unpinned).
    pub(super) fn cpus(&self) -> Result<Vec<usize>> {
        Ok(match self.pin.as_deref() {
            None => vec![],
            Some(p) => crate::processes::parse_pin(p)?.to_vec(),
        })
    }
}

/// The benchmark's job: `examples/jobs/xc-full-chain.toml` (the four controllers of the patents on two
/// axes) with its files beside it, at `period_s`, grinding long enough to keep moving for
/// `cycles`.
pub(super) fn bench_job(
    dir: &Path,
    period_s: f64,
    wait: WaitKind,
    cycles: u64,
    phase_probe_s: f64,
) -> Result<PathBuf> {
    std::fs::write(dir.join("bench-x.toml"), MODEL_X)?;
    std::fs::write(dir.join("bench-c.toml"), MODEL_C)?;
    std::fs::write(dir.join("bench-quadrant.toml"), QUADRANT_TABLE)?;
    // one revolution per second: enough turns to keep the cam turning through the whole run
    let turns = (cycles as f64 * period_s).ceil() + 1.0;
    let mut job: Table = JOB
        .parse()
        .context("reading the shipped xc-full-chain job")?;
    job.insert("name".into(), "bench-latency".into());
    job.insert("period_s".into(), period_s.into());
    let mut run = Table::new();
    run.insert("mode".into(), "realtime".into());
    run.insert("wait".into(), wait.id().into());
    run.insert("phase_probe_s".into(), phase_probe_s.into());
    job.insert("run".into(), run.into());
    // a whole number, written as an integer
    job.get_mut("trajectory")
        .and_then(Value::as_table_mut)
        .context("the shipped job has no [trajectory]")?
        .insert("turns".into(), Value::Integer(turns as i64));
    for (_, v) in job.iter_mut() {
        point_beside(v);
    }
    let p = dir.join("bench-job.toml");
    std::fs::write(&p, toml::to_string(&job)?)?;
    Ok(p)
}

/// Points the job's models and quadrant table (wherever they are named) at the copies written
/// beside it.
fn point_beside(v: &mut Value) {
    match v {
        Value::String(s) => {
            let beside = match s.as_str() {
                "../models/xc-x.toml" => "bench-x.toml",
                "../models/xc-c.toml" => "bench-c.toml",
                "../tables/xy-circle-quadrant.toml" => "bench-quadrant.toml",
                _ => return,
            };
            *s = beside.to_string();
        }
        Value::Array(a) => a.iter_mut().for_each(point_beside),
        Value::Table(t) => t.iter_mut().for_each(|(_, v)| point_beside(v)),
        Value::Integer(_) | Value::Float(_) | Value::Boolean(_) | Value::Datetime(_) => {}
    }
}

/// Runs the plant and the scheduler of `job` in realtime for `cycles`, each on its CPU of
/// `cpus` (when given), and waits for both.
pub(super) fn run_processes(
    job: &Path,
    out: &Path,
    wait: WaitKind,
    cycles: u64,
    cpus: &[usize],
    fifo: Option<i32>,
    instance: &str,
) -> Result<()> {
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
    let mut plant = spawn("plant", instance, job, out, Mode::Realtime, wait, &extra(0))?;
    let mut sched = spawn(
        "scheduler",
        instance,
        job,
        out,
        Mode::Realtime,
        wait,
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
    Ok(())
}
