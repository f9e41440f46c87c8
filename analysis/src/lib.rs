//! Offline work on jobs and traces: in-process simulation, and the model-versus-measurement
//! workbench (compare, diagnose, fit), identification and tuning, the figures of
//! `bench latency`.
#![warn(missing_docs)]

pub mod identify;
pub mod latency;
pub mod sim;
pub mod workbench;
