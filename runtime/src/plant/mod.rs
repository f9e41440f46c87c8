//! The plant process: its loop around a [`PlantDevice`] (the physics, or hardware).

mod run;

pub use run::*;
