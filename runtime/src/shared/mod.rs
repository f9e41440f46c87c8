//! Used by both processes: wire types, iceoryx2 endpoints, recorder, clocks, real-time setup.

pub mod clock;
pub mod ipc;
pub mod phase;
pub mod pingpong;
pub mod record;
pub mod rt;
pub mod scope;
pub mod wire;
