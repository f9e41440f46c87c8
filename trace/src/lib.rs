//! What feedloop records and what it makes of it, for offline tools (no IPC).
//!
//! - trace format v1 ([`Trace`], [`TraceWriter`], [`TraceError`]): the CSV every run writes and
//!   every tool reads;
//! - [`log`]: the per-cycle records both processes stream to disk, and their block format;
//! - [`export`]: trace rows and `summary.json` from records;
//! - [`summary`]: timing and tracking figures.
#![warn(missing_docs)]

pub mod export;
mod format;
pub mod log;
pub mod summary;

pub use format::*;
