//! Plant physics.
