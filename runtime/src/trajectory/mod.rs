//! Command trajectories with analytic derivatives up to the 5th.
//!
//! (Being written: see the trajectory work item.)

use std::path::Path;

use crate::controller::REF_DERIVS;
use crate::params::{ConfigError, Fields};

/// Position and its time derivatives 1..5 of one axis, in load units (m or rad) per s^n.
pub type RefState = [f64; REF_DERIVS];

/// A command source for the axes of a job.
pub trait Trajectory: Send + Sync {
    /// Names of the axes it drives, in the order of `eval`'s output.
    fn axes(&self) -> &[String];
    /// Length of the trajectory, s (after it ends, `eval` holds the final state).
    fn duration_s(&self) -> f64;
    /// Writes the reference of each driven axis at time `t_s` into `out` (`out.len() == axes().len()`).
    /// Must not allocate: it runs in the control cycle.
    fn eval(&self, t_s: f64, out: &mut [RefState]);
}

/// Builds the trajectory described by a job's `[trajectory]` table.
pub fn build(
    table: &toml::Table,
    file: &Path,
    job_axes: &[String],
    _period_s: f64,
) -> Result<Box<dyn Trajectory>, ConfigError> {
    let mut f = Fields::new(table, file, "trajectory");
    let kind = f.str("kind")?;
    match kind {
        "dwell" => {
            let d = f.f64_or("duration_s", crate::params::Range::Positive, 1.0)?;
            f.finish()?;
            Ok(Box::new(Dwell {
                axes: job_axes.to_vec(),
                duration_s: d,
            }))
        }
        other => Err(f.error("kind", format!("unknown trajectory kind `{other}`"))),
    }
}

struct Dwell {
    axes: Vec<String>,
    duration_s: f64,
}

impl Trajectory for Dwell {
    fn axes(&self) -> &[String] {
        &self.axes
    }
    fn duration_s(&self) -> f64 {
        self.duration_s
    }
    fn eval(&self, _t_s: f64, out: &mut [RefState]) {
        for o in out {
            *o = [0.0; REF_DERIVS];
        }
    }
}
