//! The control service of an instance (iceoryx2 request-response `feedloop/<instance>/control`):
//! list plugins, read status, swap or retune a controller while the loop runs.
//!
//! Requests and responses are fixed-size `#[repr(C)]` buffers carrying JSON text, so the wire
//! layout never changes when a request gains a field. In the scheduler, [`ControlPlane`] polls
//! the server in the cycle's slack (non-blocking), hands swap requests to a builder thread that
//! parses and validates the new plugin outside the cycle, and switches the built controller in
//! at a cycle boundary, initialised from the old one's signals (bumpless). The first cycles after
//! a swap are a probation: a non-finite or out-of-limit torque rolls the swap back, and so does
//! a first cycle whose torque step exceeds the bumpless bound (unless the request says `force`).
//! Before that, the builder refuses a plugin in a stage it does not fill, and a gain set the loop
//! model (the one `feedloop tune` uses) finds unstable or marginal, unless `force`.

pub mod dry_run;
pub mod origin;
pub mod protocol;

mod builder;
mod client;
mod server;
mod wire;

pub use client::{request, request_from};
pub use origin::Origin;
pub use server::{ControlPlane, Rejection};
pub use wire::{ControlRequest, ControlResponse, REQUEST_BYTES, RESPONSE_BYTES};
