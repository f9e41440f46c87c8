//! feedloop's configuration: validated job and model files, and the names they share.
//!
//! - [`params`]: typed reading of TOML tables with errors that name file, key, what is wrong and
//!   what is accepted.
//! - [`model`]: a model file (plant, effects, sensors, controller defaults) for one axis.
//! - [`job`]: a job file (axes, trajectory, chains, timing).
//! - [`units`]: printed figures (significant digits, an SI prefix that fits).
//! - [`Stage`]: the stages of an axis chain.
//! - [`EffectId`], [`Side`]: the effects a model file may switch on, and the body one acts on.
//!
//! No IPC, no physics: every other crate reads its configuration through this one.
#![warn(missing_docs)]

pub mod effect;
pub mod job;
pub mod model;
pub mod params;
mod stage;
pub mod units;

pub use effect::{EffectId, Side};
pub use stage::Stage;

/// Largest number of axes one instance can drive. The wire types and logs are sized for it.
pub const MAX_AXES: usize = 8;
