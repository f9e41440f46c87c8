//! The scheduler process: its loop, the per-axis controller chain, the control cycle (trajectory
//! and chain, shared with the in-process simulation), the control service and the loader of
//! plugin libraries.

pub mod chain;
pub mod control;
pub mod cycle;
pub mod plugin_lib;
mod run;

pub use run::*;
