//! `feedloop sim`: the plant and the controller chain of a job in one process, no IPC.
//!
//! Per cycle k it does exactly what the two processes do in lockstep: the plant senses sample k,
//! the control cycle answers it, the plant applies the command for one period. The rows go
//! through the same export functions, so a lockstep run and a simulation of the same job give
//! byte-identical traces.

use std::io::Write;
use std::path::Path;

use feedloop_control::controller::PluginRegistry;
use feedloop_model::job::Job;
use feedloop_model::params::ConfigError;
use feedloop_motion::path_index::PathIndex;
use feedloop_plant::Plant;
use feedloop_runtime::scheduler::cycle::ControlCycle;
use feedloop_runtime::shared::wire::{ActuatorCommand, SensorSample, MAX_AXES};
use feedloop_trace::export::{row_values, trace_columns};
use feedloop_trace::log::AxisRecord;
use feedloop_trace::summary::Tracking;
use feedloop_trace::TraceWriter;

/// Errors of a simulation.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// Invalid job, model or plugin parameters.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Writing the trace failed.
    #[error("writing {path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Error.
        source: std::io::Error,
    },
}

/// A job's plant and control cycle, stepped in one process.
pub struct Simulation {
    /// The control cycle (trajectory + chain).
    pub cycle: ControlCycle,
    /// The plant.
    pub plant: Plant,
    sample: SensorSample,
    cmd: ActuatorCommand,
    k: u64,
    n: usize,
}

impl Simulation {
    /// Builds the plant and the chain of `job`, with the plant at rest at the trajectory's start.
    pub fn new(job: &Job, registry: &dyn PluginRegistry) -> Result<Self, SimError> {
        let cycle = ControlCycle::new(job, registry)?;
        let mut plant = Plant::new(job)?;
        plant.set_initial_positions(&cycle.initial_positions());
        let n = job.axes.len();
        Ok(Self {
            cycle,
            plant,
            sample: SensorSample::empty(n as u32, 0),
            cmd: ActuatorCommand::empty(n as u32, 0),
            k: 0,
            n,
        })
    }

    /// Cycles of the whole run.
    pub fn cycles(&self) -> u64 {
        self.cycle.cycles()
    }

    /// Cycle number of the next step.
    pub fn position(&self) -> u64 {
        self.k
    }

    /// Runs one cycle and writes its trace row of each axis into `rows[..n]`.
    #[inline]
    pub fn step(&mut self, rows: &mut [AxisRecord]) {
        let k = self.k;
        self.sample.seq = k;
        self.sample.plant_time_s = self.cycle.time_of(k);
        self.plant.sense(&mut self.sample.axes);
        self.cycle.step(&self.sample, &mut self.cmd);
        self.plant.step(&self.cmd.axes);
        for ((row, s), c) in rows
            .iter_mut()
            .zip(&self.sample.axes)
            .zip(&self.cmd.axes)
            .take(self.n)
        {
            *row = AxisRecord::of(s, c);
        }
        self.k += 1;
    }
}

/// Result of [`simulate`].
#[derive(Debug, Clone)]
pub struct SimReport {
    /// Cycles run.
    pub cycles: u64,
    /// Wall time spent in physics and control (trace I/O excluded), s.
    pub compute_s: f64,
    /// Wall time spent formatting and writing the trace, s.
    pub trace_s: f64,
    /// Wall time spent on the tracking and contour-error figures, s.
    pub tracking_s: f64,
    /// Tracking figures.
    pub tracking: Tracking,
}

/// How a job's contour error is measured, row by row: by the trajectory's own contour (circle,
/// part program, X-C profile), else, with two or more driven axes, as the distance from the
/// measured point of the first two to their commanded path (around the current command, through
/// a [`PathIndex`] of the trajectory: across corners, rests and reversals).
pub struct ContourJudge {
    kind: JudgeKind,
}

enum JudgeKind {
    None,
    Trajectory,
    Path { axes: [usize; 2], index: PathIndex },
}

impl ContourJudge {
    /// The judge for `job` run by `cycle` (samples the commanded path once when the trajectory
    /// has no contour of its own).
    pub fn new(job: &Job, cycle: &ControlCycle) -> Self {
        let traj = cycle.trajectory();
        if traj.contour().is_some() {
            return Self {
                kind: JudgeKind::Trajectory,
            };
        }
        let names = job.axis_names();
        let driven: Vec<usize> = traj
            .axes()
            .iter()
            .filter_map(|a| names.iter().position(|n| n == a))
            .collect();
        let kind = if driven.len() >= 2 {
            let axes = [driven[0], driven[1]];
            JudgeKind::Path {
                axes,
                index: PathIndex::build(traj, axes),
            }
        } else {
            JudgeKind::None
        };
        Self { kind }
    }

    /// The contour error (m) of one trace row: time `t_s`, measured load positions in `rows`
    /// (job order).
    #[inline]
    pub fn error_m(&self, cycle: &ControlCycle, t_s: f64, rows: &[AxisRecord]) -> Option<f64> {
        match &self.kind {
            JudgeKind::None => None,
            JudgeKind::Trajectory => {
                let mut loads = [0.0; MAX_AXES];
                for (l, r) in loads.iter_mut().zip(rows) {
                    *l = r.load;
                }
                cycle
                    .trajectory()
                    .contour_error_m(t_s, &loads[..rows.len()])
            }
            JudgeKind::Path { axes, index } => {
                let p = [rows.get(axes[0])?.load, rows.get(axes[1])?.load];
                Some(index.distance_m(cycle.trajectory(), t_s, p))
            }
        }
    }
}

/// Runs a whole job; writes `trace` (trace format v1) when given. `progress` is called now and
/// then with (cycles done, cycles total).
pub fn simulate(
    job: &Job,
    registry: &dyn PluginRegistry,
    trace: Option<&Path>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<SimReport, SimError> {
    let mut sim = Simulation::new(job, registry)?;
    let names = job.axis_names();
    let n = names.len();
    let total = sim.cycles();
    let judge = ContourJudge::new(job, &sim.cycle);
    let mut tracking = Tracking::for_job(job);
    let io_err = |p: &Path, e: std::io::Error| SimError::Io {
        path: p.display().to_string(),
        source: e,
    };
    let mut writer = match trace {
        Some(p) => {
            let f = std::fs::File::create(p).map_err(|e| io_err(p, e))?;
            Some((
                p,
                TraceWriter::new(
                    std::io::BufWriter::with_capacity(1 << 20, f),
                    &trace_columns(&names),
                )
                .and_then(|w| w.with_period(job.period_s))
                .map_err(|e| io_err(p, e))?,
            ))
        }
        None => None,
    };
    // Rows of a batch side by side (n axes each): 1024 rows of two axes are 80 kB, so the
    // tracking and export passes read them from cache.
    const BATCH_ROWS: usize = 1024;
    let mut batch = vec![AxisRecord::default(); BATCH_ROWS * n];
    let mut row = Vec::with_capacity(1 + 5 * n);
    let mut compute = std::time::Duration::ZERO;
    let mut trace_t = std::time::Duration::ZERO;
    let mut tracking_t = std::time::Duration::ZERO;
    let period = job.period_s;
    while sim.position() < total {
        let first = sim.position();
        let m = ((total - first) as usize).min(BATCH_ROWS);
        let t0 = std::time::Instant::now();
        for rows in batch.chunks_exact_mut(n).take(m) {
            sim.step(rows);
        }
        compute += t0.elapsed();
        let t1 = std::time::Instant::now();
        for (j, rows) in batch.chunks_exact(n).take(m).enumerate() {
            let seq = first + j as u64;
            let ce = judge.error_m(&sim.cycle, sim.cycle.time_of(seq), &rows[..n]);
            tracking.push(&rows[..n], ce);
        }
        let t2 = std::time::Instant::now();
        tracking_t += t2 - t1;
        if let Some((_, w)) = writer.as_mut() {
            for (j, rows) in batch.chunks_exact(n).take(m).enumerate() {
                let seq = first + j as u64;
                row_values(seq, period, rows, &mut row);
                w.write_cycle(seq, &row)
                    .map_err(|e| io_err(trace.unwrap(), e))?;
            }
        }
        trace_t += t2.elapsed();
        progress(sim.position(), total);
    }
    if let Some((p, w)) = writer {
        let t = std::time::Instant::now();
        let mut inner = w.finish().map_err(|e| io_err(p, e))?;
        inner.flush().map_err(|e| io_err(p, e))?;
        trace_t += t.elapsed();
    }
    Ok(SimReport {
        cycles: total,
        compute_s: compute.as_secs_f64(),
        trace_s: trace_t.as_secs_f64(),
        tracking_s: tracking_t.as_secs_f64(),
        tracking,
    })
}

/// Runs a whole job in process and returns its trace rows per axis (`[axis][cycle]`).
pub fn run_records(
    job: &Job,
    registry: &dyn PluginRegistry,
) -> Result<Vec<Vec<AxisRecord>>, SimError> {
    let mut sim = Simulation::new(job, registry)?;
    let n = job.axes.len();
    let cycles = sim.cycles() as usize;
    let mut out = vec![Vec::with_capacity(cycles); n];
    let mut rows = [AxisRecord::default(); MAX_AXES];
    for _ in 0..cycles {
        sim.step(&mut rows[..n]);
        for (o, r) in out.iter_mut().zip(&rows[..n]) {
            o.push(*r);
        }
    }
    Ok(out)
}
