//! Any bytes in a control request's buffer are decoded and checked as the scheduler's control
//! service does before it applies a swap or retune (axis, stage, plugin, parameters, the loop
//! model's verdict), on a two-axis job with a full chain, without the service: a verdict or a
//! refusal with its reason, never a panic.

use std::sync::{Arc, OnceLock};

use feedloop_runtime::scheduler::control::dry_run::{request_from_bytes, DryRun};

/// The job whose loop the requests are checked against.
const JOB: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../examples/jobs/xc-full-chain.toml"
);

fn dry_run() -> DryRun {
    let job = feedloop_model::job::Job::load(std::path::Path::new(JOB)).expect("the job loads");
    let cycle =
        feedloop_runtime::scheduler::cycle::ControlCycle::new(&job, &feedloop_plugins::Builtins)
            .expect("the job's chain builds");
    DryRun::new(&job, &cycle, Arc::new(feedloop_plugins::Builtins))
}

fn main() {
    static DRY: OnceLock<DryRun> = OnceLock::new();
    // built before the fork server starts (no threads): every run starts from the same state
    DRY.get_or_init(dry_run);
    afl::fuzz!(|data: &[u8]| {
        let dry = DRY.get_or_init(dry_run);
        if let Err(a) = dry.answer(&request_from_bytes(data)) {
            let error = match *a {
                feedloop_runtime::scheduler::control::protocol::Answer::Refused {
                    error, ..
                } => error,
                other => panic!("a refusal read back as {other:?}"),
            };
            assert!(!error.trim().is_empty(), "a refusal without a reason");
        }
    });
}
