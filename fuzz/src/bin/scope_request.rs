//! Any bytes sent to the scope's page server get a well-formed answer or none, never a panic:
//! a sandboxed scope on a small synthetic recording (no loop) answers them over loopback, each
//! as the first request of a page (`{host}` in the bytes becomes the scope's `HOST:PORT`).
//! Inputs that hit a known, not yet fixed defect of the HTTP server are passed over
//! ([`known_defect`]).

use std::sync::OnceLock;

use feedloop_cli::scope_sandbox::{judge, known_defect, Sandbox};

fn main() {
    static SANDBOX: OnceLock<Sandbox> = OnceLock::new();
    afl::fuzz!(|data: &[u8]| {
        if known_defect(data).is_some() {
            return;
        }
        let sb = SANDBOX.get_or_init(|| Sandbox::start().expect("the sandboxed scope starts"));
        sb.reset();
        let answer = sb.ask(data).expect("the scope answers or closes in time");
        if let Err(e) = judge(&answer) {
            panic!("{e}");
        }
    });
}
