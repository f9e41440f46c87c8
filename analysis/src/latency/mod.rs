//! What `feedloop bench latency` makes of a realtime run: HDR histograms of the round trip and
//! the plant's wake-up lateness, deadline misses attributed to core losses of either process,
//! reference loops on the same CPUs, a percentile plot. The run itself (two processes) is
//! started by the binary; everything here works on the logs and on the calling thread's CPUs.

mod attribution;
mod plot;
pub mod reference;
mod run;

pub use attribution::{attribute_misses, Attribution};
pub use plot::{percentile_svg, ReferenceLoops};
pub use run::{hist_json, ns_histogram_of, Breakdown, RunFigures};

/// Errors of the latency figures.
#[derive(Debug, thiserror::Error)]
pub enum LatencyError {
    /// An HDR histogram could not be created.
    #[error("cannot create a latency histogram: {0}")]
    Histogram(#[from] hdrhistogram::CreationError),
    /// Two HDR histograms could not be merged.
    #[error("cannot merge latency histograms: {0}")]
    Merge(#[from] hdrhistogram::AdditionError),
    /// A reference-loop thread panicked.
    #[error("a reference-loop thread panicked")]
    ProbePanicked,
}

/// A histogram of nanosecond values from 1 ns to 60 s with three significant digits.
pub(crate) fn ns_histogram() -> Result<hdrhistogram::Histogram<u64>, LatencyError> {
    Ok(hdrhistogram::Histogram::<u64>::new_with_bounds(
        1,
        60_000_000_000,
        3,
    )?)
}
