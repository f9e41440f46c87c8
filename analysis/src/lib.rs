//! Offline work on jobs and traces: in-process simulation, identification, learning of
//! controller tables, and the model-versus-measurement workbench (compare, diagnose, fit).
#![warn(missing_docs)]

pub mod identify;
pub mod learn;
pub mod sim;
pub mod workbench;
