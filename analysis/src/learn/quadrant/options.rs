//! What the learning loop is asked and what it reports.

use std::path::PathBuf;

use feedloop_model::job::Job;
use feedloop_model::params::ConfigError;
use feedloop_trace::log::AxisRecord;

use feedloop_plugins::quadrant::{Profile, QuadrantTable};

/// Records of one run, per axis (`records[axis][cycle]`, job axis order, load units).
pub type RunRecords = Vec<Vec<AxisRecord>>;

/// How [`learn_quadrant`](crate::learn::quadrant::learn_quadrant) runs a job: returns its records or a message.
pub type RunJob<'a> = dyn FnMut(&Job) -> Result<RunRecords, String> + 'a;

/// Options of the learning loop.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnOptions {
    /// Error window after each reversal, s (also cut at the next reversal). Default 0.08.
    pub window_s: f64,
    /// Error window before each reversal (the approach), s; pulses may start that early, played
    /// from the reversal instant the compensator predicts. Default 0.08.
    pub lead_s: f64,
    /// Start/end points: where |e| falls to this fraction of the maximum. Default 0.01.
    pub threshold: f64,
    /// Stop when every axis' spike is at or below this, load units (m or rad). Default 0.
    pub accept: f64,
    /// Write the table here instead of the path in the job's `table` key.
    pub table: Option<PathBuf>,
    /// Without `table`: write the table into this folder, under the file name of the job's
    /// `table` (the job's own table file is then left as it is).
    pub out_dir: Option<PathBuf>,
    /// Learning gain of the first pass: the fitted amplitude is scaled by it. Default 1.
    pub gain: f64,
    /// Learning gain of the later passes (which fit smaller, faster residuals, where the plant
    /// answers a compensation less faithfully). Default 0.5.
    pub refine_gain: f64,
    /// Later passes fit residual lobes at least this fraction of the largest. Default 0.3.
    pub lobe_fraction: f64,
    /// Shape of the learned pulses. Default [`Profile::SineAcceleration`].
    pub profile: Profile,
    /// Shortest acceleration or deceleration phase of a learned pulse, s: the splits are kept
    /// so, and a lobe too short for two phases gets no pulse. Default 1 ms.
    pub min_phase_s: f64,
}

impl Default for LearnOptions {
    fn default() -> Self {
        Self {
            window_s: 0.08,
            lead_s: 0.08,
            threshold: 0.01,
            accept: 0.0,
            table: None,
            out_dir: None,
            gain: 1.0,
            refine_gain: 0.5,
            lobe_fraction: 0.3,
            profile: Profile::SineAcceleration,
            min_phase_s: 0.001,
        }
    }
}

/// Errors of [`learn_quadrant`](crate::learn::quadrant::learn_quadrant).
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    /// No stage to learn for.
    #[error("the job has no `quadrant_compensator` stage: add one (with a `table` path) to the axes to learn")]
    NoCompensator,
    /// Stages point at different tables.
    #[error("the quadrant_compensator stages name different tables ({0} and {1}): learn one table at a time")]
    SeveralTables(PathBuf, PathBuf),
    /// Invalid job or parameters.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Writing the table failed.
    #[error("writing the table {path}: {source}")]
    Write {
        /// Table file.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The run closure failed.
    #[error("running the job: {0}")]
    Run(String),
    /// The run returned a wrong shape.
    #[error("the run returned {got} axes of records, the job has {want}")]
    RecordShape {
        /// Axes returned.
        got: usize,
        /// Axes of the job.
        want: usize,
    },
}

/// One axis after one pass.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisSpike {
    /// Axis name.
    pub axis: String,
    /// Largest |e(tau) - e(0)| over all reversal windows, load units (m or rad).
    pub spike: f64,
    /// Reversals seen.
    pub reversals: usize,
    /// Pulses in the table that produced this run.
    pub pulses: usize,
}

/// One pass (0 = the run before learning).
#[derive(Debug, Clone, PartialEq)]
pub struct PassReport {
    /// Pass number.
    pub pass: usize,
    /// Per learned axis, as run with the table of this pass.
    pub axes: Vec<AxisSpike>,
    /// Runs this pass took (more than 1 when an axis' new pulses had to be scaled back).
    pub runs: usize,
}

/// Times a pass' new pulses of an axis are halved before they are dropped (each costs a run).
pub const MAX_BACKTRACKS: usize = 3;

/// What [`learn_quadrant`](crate::learn::quadrant::learn_quadrant) did.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnReport {
    /// Where the table was written.
    pub table_path: PathBuf,
    /// The table file the job's stages name (the same as `table_path` unless the table was
    /// written elsewhere).
    pub job_table: PathBuf,
    /// Pass 0 (no compensation) and every learning pass run.
    pub passes: Vec<PassReport>,
    /// The final table.
    pub table: QuadrantTable,
}
