//! What the `feedloop` binary shares with the tests of this package: where the browser is.

pub mod browser;
