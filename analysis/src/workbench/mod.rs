//! The model-versus-measurement workbench: compare a model with a trace, diagnose which physical
//! effect (or which wrong base parameter) explains the misfit, fit the added effects, and report.
//!
//! Everything works on any trace in format v1 plus a model file:
//! - [`data`] reads one axis of a trace into motor units, with zero-phase filtered derivatives;
//! - [`effects`] holds the workbench's own regressor form of every effect of the physics library
//!   (independent of the plant simulator's exact formulas);
//! - [`compare`] computes the equation error (inverse dynamics), NRMSE per channel and the
//!   segments that carry the residual; [`report`] draws them as `report.html` with SVG plots;
//! - [`diagnose`] ranks candidate causes by their error reduction under blocked cross-validation;
//! - [`fit`] adds effects, refits and writes a new model file;
//! - [`import`] brings foreign CSV exports into format v1 and builds a nominal model from a trace.

mod adder;
pub mod auto;
pub mod base;
mod beyond;
mod candidates;
pub mod compare;
pub mod controller;
mod controller_candidates;
pub mod data;
pub mod diagnose;
pub mod dictionary;
pub mod effect_params;
pub mod effects;
pub mod fit;
mod gap_sizing;
mod grids;
pub mod import;
pub mod law;
pub mod lsq;
mod pair;
mod pinned;
pub mod refit;
pub mod report;
mod scoring;
mod side;
pub mod signal;
mod standstill;
mod verdict;
pub mod window;
pub mod words;

use std::path::PathBuf;

use feedloop_model::params::ConfigError;
use feedloop_trace::TraceError;

/// Errors of the workbench; each names the file, line or key it is about.
#[derive(Debug, thiserror::Error)]
pub enum WorkbenchError {
    /// The trace could not be read or is malformed.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// The model file could not be read or is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A column the chosen method needs is absent.
    #[error("{}: missing column `{column}`, needed for {needed_for} (columns present: {present})", path.display())]
    MissingColumn {
        /// The trace file.
        path: PathBuf,
        /// The column.
        column: String,
        /// What needs it.
        needed_for: String,
        /// Columns that are there.
        present: String,
    },
    /// The model does not match the trace (axis, units, kind).
    #[error("{}: model {} does not match the trace: {reason}", trace.display(), model.display())]
    Mismatch {
        /// The trace file.
        trace: PathBuf,
        /// The model file.
        model: PathBuf,
        /// What does not match.
        reason: String,
    },
    /// A bad command-line argument (e.g. an unknown effect id or parameter name).
    #[error("{arg}: {reason}")]
    BadArgument {
        /// The argument (flag and value).
        arg: String,
        /// What is wrong.
        reason: String,
    },
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// An effect asked for with `fit --add` could not be fitted on this trace.
    #[error("cannot add `{effect}`: {reason}; {advice}")]
    EffectRefused {
        /// The effect id.
        effect: String,
        /// Why its fit was refused.
        reason: String,
        /// What to do.
        advice: String,
    },
    /// The data does not allow the requested computation (too short, no motion, singular fit).
    #[error("{}: {reason}", path.display())]
    Data {
        /// The trace file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

impl WorkbenchError {
    /// An I/O error about `path`.
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        WorkbenchError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}
