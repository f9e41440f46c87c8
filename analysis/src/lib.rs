//! Offline analysis.
