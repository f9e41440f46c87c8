//! Offline work on jobs and traces: in-process simulation, identification and tuning, learning
//! of controller tables, the model-versus-measurement workbench (compare, diagnose, fit), the
//! figures of `bench latency`.
#![warn(missing_docs)]

pub mod commission;
pub mod identify;
pub mod latency;
pub mod learn;
pub mod plot;
pub mod sim;
pub mod workbench;
