//! What a controller plugin author depends on, and nothing more: no IPC, no loops.
//!
//! - [`controller`]: the plugin traits ([`controller::Controller`], [`controller::Coupler`],
//!   [`controller::PluginRegistry`]) and the signals one axis passes along its chain each cycle.
//! - [`axis_io`]: what the plant measures on one axis and what the scheduler asks of it.
//! - [`abi`]: the C ABI of plugins built as shared libraries.
//! - [`device`]: what the plant loop needs of a plant (simulated or real).
//! - [`loop_model`]: margins of the position and velocity loops on the axis model.
#![warn(missing_docs)]

pub mod abi;
pub mod axis_io;
pub mod controller;
pub mod device;
pub mod loop_model;

pub use feedloop_model as model;
