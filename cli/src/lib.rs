//! What the `feedloop` binary shares with the tests and the fuzz targets of this package: where
//! the browser is, the scope (its request handling is fuzzed over a socket, [`scope_sandbox`]) and
//! the signal handlers it installs.

pub mod browser;
pub mod scope;
pub mod scope_sandbox;
pub mod signals;
pub mod trace_export;
pub mod trace_import;
pub mod workbench_load;
