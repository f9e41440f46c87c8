//! The measured trace the identify commands read, and which of its axes they work on.

use std::path::Path;

use anyhow::Context;

use feedloop_trace::Trace;

/// Reads the trace at `p`.
pub(super) fn read_trace(p: &Path) -> anyhow::Result<Trace> {
    Ok(Trace::read(p)?)
}

/// The axis asked for, else the first of the trace's.
pub(super) fn trace_axis(t: &Trace, axis: Option<&str>) -> anyhow::Result<String> {
    match axis {
        Some(a) => Ok(a.to_string()),
        // The first axis with a command and a load column, else the first `A.*` column's
        // axis (the command then names the column it misses).
        None => t
            .axes()
            .into_iter()
            .next()
            .or_else(|| {
                t.columns
                    .iter()
                    .find_map(|c| c.split_once('.').map(|(a, _)| a.to_string()))
            })
            .with_context(|| {
                format!(
                    "{}: no axis columns (A.cmd, A.load, A.torque, A.motor_vel, ...); columns: {}",
                    t.path.display(),
                    t.columns.join(", ")
                )
            }),
    }
}
