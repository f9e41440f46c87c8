//! Identification of the feed drive's mechanics (seeds 000 and 001): the frequency response of
//! torque -> motor velocity and the stiffness and load inertia read from its first
//! anti-resonance / resonance pair ([`stiffness`]).

pub mod frf;
pub mod inertia;
pub mod reversals;
pub mod stiffness;
pub mod svg;
pub mod tune;

use feedloop_trace::TraceError;

/// Errors of the identification tools.
#[derive(Debug, thiserror::Error)]
pub enum IdentifyError {
    /// The trace could not be read or lacks a column.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// The input cannot give a meaningful answer (the message says why).
    #[error("{0}")]
    Invalid(String),
    /// No anti-resonance / resonance pair was found in the band.
    #[error("no {what} found between {f_lo_hz:.1} and {f_hi_hz:.1} Hz: {why}")]
    NoResonance {
        /// `anti-resonance` or `resonance`.
        what: &'static str,
        /// Band start, Hz.
        f_lo_hz: f64,
        /// Band end, Hz.
        f_hi_hz: f64,
        /// Explanation.
        why: String,
    },
}
