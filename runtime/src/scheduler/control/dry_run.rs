//! The control service's checks of a request without the service: a request's wire buffer
//! decoded, its axis and stage found, its controller built from its parameters and judged by
//! the loop model, exactly as the scheduler does before it switches a controller in, but with no
//! iceoryx2 service, no loop and nothing applied. What the control fuzz target (`fuzz/`,
//! `control_request`) and the request property tests drive.

use std::path::PathBuf;
use std::sync::Arc;

use feedloop_control::controller::PluginRegistry;
use feedloop_model::job::Job;

use super::builder::ChainState;
use super::protocol::{Answer, Request};
use super::server::build_job;
use super::wire::{ControlRequest, ControlResponse};
use crate::scheduler::cycle::ControlCycle;

/// What the service would do with a request that passed its checks.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// A status request: answered with the loop's status.
    Status,
    /// A swap (or a retune: the same plugin, new parameters) that would be switched in and put
    /// on probation.
    Swap {
        /// The plugin built.
        plugin: String,
        /// Phase (deg) and gain (dB) margins of the axis with it, when the model computed them.
        margins: Option<(f64, f64)>,
        /// What it was let through despite.
        warnings: Vec<String>,
    },
    /// A swap from a plugin library: not built here, as loading a library runs its code.
    Library,
}

/// The checks of the control service of a loop running `job`, without the service.
pub struct DryRun {
    names: Vec<String>,
    state: ChainState,
    registry: Arc<dyn PluginRegistry>,
    job_path: PathBuf,
}

impl DryRun {
    /// The checks of a loop that starts `job` as `cycle` (built from it with `registry`).
    pub fn new(job: &Job, cycle: &ControlCycle, registry: Arc<dyn PluginRegistry>) -> Self {
        let (state, _) = ChainState::of(job, cycle);
        Self {
            names: job.axis_names(),
            state,
            registry,
            job_path: job.path.clone(),
        }
    }

    /// What the service makes of the request in `msg` short of applying it; `Err` holds the
    /// refusal the client would read.
    pub fn vet(&self, msg: &ControlRequest) -> Result<Verdict, String> {
        let swap = match msg.request().map_err(|e| e.to_string())? {
            Request::Status => return Ok(Verdict::Status),
            Request::Swap(s) => s,
        };
        let job = build_job(&self.names, swap).map_err(|e| e.to_string())?;
        if job.lib.is_some() {
            return Ok(Verdict::Library);
        }
        let (c, _, check) = self
            .state
            .build(&job, self.registry.as_ref(), &self.job_path)
            .map_err(|e| e.to_string())?;
        Ok(Verdict::Swap {
            plugin: c.id().to_string(),
            margins: check.margins,
            warnings: check.warnings,
        })
    }

    /// [`DryRun::vet`] as the client reads it: the answer through a response buffer (a
    /// refusal, or for an accepted swap, none: its answer comes after the probation).
    pub fn answer(&self, msg: &ControlRequest) -> Result<Verdict, Box<Answer>> {
        self.vet(msg).map_err(|e| {
            let a = ControlResponse::new(&Answer::refused(e))
                .answer()
                .unwrap_or_else(|e| Answer::refused(format!("unreadable answer: {e}")));
            Box::new(a)
        })
    }
}

/// A control request as its raw bytes lie in the service's shared memory: the protocol version
/// and the text's length (native-endian `u32` each), then the text; missing bytes are zero,
/// bytes beyond the buffer are cut.
pub fn request_from_bytes(b: &[u8]) -> ControlRequest {
    let word = |i: usize| {
        let mut w = [0u8; 4];
        for (k, x) in w.iter_mut().enumerate() {
            *x = b.get(i + k).copied().unwrap_or(0);
        }
        u32::from_ne_bytes(w)
    };
    let mut r = ControlRequest {
        protocol: word(0),
        len: word(4),
        ..Default::default()
    };
    let text = b.get(8..).unwrap_or(&[]);
    let n = text.len().min(r.text.len());
    r.text[..n].copy_from_slice(&text[..n]);
    r
}

/// The bytes of a request holding the JSON `text` (the inverse of [`request_from_bytes`] for
/// texts that fit): for seeds and tests.
pub fn request_bytes(text: &[u8]) -> Vec<u8> {
    let mut b = crate::shared::wire::PROTOCOL_VERSION.to_ne_bytes().to_vec();
    b.extend_from_slice(&(text.len() as u32).to_ne_bytes());
    b.extend_from_slice(text);
    b
}
