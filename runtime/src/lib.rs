//! feedloop runtime: what the two processes share, grouped by the process that runs it.
//!
//! - [`shared`]: the `#[repr(C)]` wire types, the iceoryx2 endpoints, the recorder, clocks and
//!   real-time setup.
//! - [`scheduler`]: the scheduler process's loop, the controller chain and the control cycle
//!   (also run by the in-process simulation), the control service, the plugin-library loader.
//! - [`plant`]: the plant process's loop around a [`plant::PlantDevice`].
//!
//! Configuration, controller traits, trajectories and trace formats live in their own crates
//! (`feedloop-model`, `feedloop-control`, `feedloop-motion`, `feedloop-trace`), which need no IPC.
#![warn(missing_docs)]

pub mod plant;
pub mod scheduler;
pub mod shared;
