//! Offline work on jobs and traces: in-process simulation, and the model-versus-measurement
//! workbench (compare, diagnose, fit).
#![warn(missing_docs)]

pub mod identify;
pub mod sim;
pub mod workbench;
