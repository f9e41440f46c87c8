//! The run-level commands: spawning the two processes (`launcher`), the processes themselves
//! (`plant_entry`, `scheduler_entry`, sharing `process_start`), the in-process simulation
//! (`sim`), and merging logs into `trace.csv` + `summary.json` (`merge`); `common` holds what
//! they share.

mod common;
mod launcher;
mod merge;
mod plant_entry;
mod process_start;
mod progress;
mod scheduler_entry;
mod sim;

pub use common::{read_json, write_json};
pub use launcher::{parse_pin, run, spawn};
pub use merge::merge_cmd;
pub(crate) use plant_entry::phase_json;
pub use plant_entry::plant;
pub use process_start::ProcArgs;
pub use scheduler_entry::scheduler;
pub use sim::sim;
