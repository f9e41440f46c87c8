//! feedloop runtime: everything both processes share.
//!
//! - [`wire`]: the `#[repr(C)]` sample and command that cross the process boundary.
//! - [`params`], [`model`], [`job`]: validated configuration files.
//! - [`controller`]: the plugin trait, the per-axis signals, and [`chain`] that runs them.
//! - [`trajectory`]: command sources with analytic derivatives.
//! - [`trace`]: trace format v1.
#![warn(missing_docs)]

pub mod abi;
pub mod chain;
pub mod clock;
pub mod control;
pub mod controller;
pub mod cycle;
pub mod export;
pub mod ipc;
pub mod job;
pub mod model;
pub mod params;
pub mod plant_loop;
pub mod record;
pub mod rt;
pub mod scheduler;
pub mod summary;
pub mod trace;
pub mod trajectory;
pub mod wire;
