//! Trace format v1 (see `docs/trace-format.md`): writing and reading, with validation.
//!
//! (Being written: see the trace work item.)
