//! The control service's name and its fixed-size message buffers (JSON text in `#[repr(C)]`
//! arrays), shared by the client and the server.

use iceoryx2::active_request::ActiveRequest;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;

use super::origin::Origin;
use super::protocol::{Answer, Request, RequestError};
use crate::shared::ipc::IpcError;

/// Capacity of a request's JSON text, bytes.
pub const REQUEST_BYTES: usize = 8192;
/// Capacity of a response's JSON text, bytes.
pub const RESPONSE_BYTES: usize = 16384;

/// A control request: a [`Request`] as JSON text, e.g. `{"op":"swap","axis":"x","stage":"velocity","plugin":"pi_velocity","params":"kv_nms_per_rad = 4.0"}`,
/// and where it came from.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("FeedloopControlRequestV2")]
pub struct ControlRequest {
    /// `wire::PROTOCOL_VERSION` of the sender.
    pub protocol: u32,
    /// Valid bytes in `text`.
    pub len: u32,
    /// UTF-8 JSON.
    pub text: [u8; REQUEST_BYTES],
    /// Who sent it (kept with the swaps it makes: the audit trail).
    pub origin: Origin,
}

/// A control response: an [`Answer`] as JSON text; `code` 0 = done, 1 = refused (reason in the
/// JSON's `error`).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("FeedloopControlResponseV1")]
pub struct ControlResponse {
    /// 0 ok, 1 refused.
    pub code: u32,
    /// Valid bytes in `text`.
    pub len: u32,
    /// UTF-8 JSON.
    pub text: [u8; RESPONSE_BYTES],
}

impl Default for ControlRequest {
    fn default() -> Self {
        Self {
            protocol: crate::shared::wire::PROTOCOL_VERSION,
            len: 0,
            text: [0; REQUEST_BYTES],
            origin: Origin::default(),
        }
    }
}

impl Default for ControlResponse {
    fn default() -> Self {
        Self {
            code: 0,
            len: 0,
            text: [0; RESPONSE_BYTES],
        }
    }
}

impl ControlRequest {
    /// A request holding `req` sent from `origin` (refused when its JSON is longer than the
    /// buffer).
    pub fn new(req: &Request, origin: Origin) -> Result<Self, RequestError> {
        let s = json_text(req);
        if s.len() > REQUEST_BYTES {
            return Err(RequestError::TooLong {
                len: s.len(),
                capacity: REQUEST_BYTES,
            });
        }
        let mut r = Self::default();
        r.text[..s.len()].copy_from_slice(s.as_bytes());
        r.len = s.len() as u32;
        r.origin = origin;
        Ok(r)
    }

    /// The request it holds.
    pub fn request(&self) -> Result<Request, RequestError> {
        let n = (self.len as usize).min(REQUEST_BYTES);
        Request::from_slice(&self.text[..n])
    }
}

impl ControlResponse {
    /// A response holding `answer` (replaced by a refusal when too long), with its code.
    pub fn new(answer: &Answer) -> Self {
        let mut s = json_text(answer);
        let mut code = answer.code();
        if s.len() > RESPONSE_BYTES {
            let short = Answer::refused("response too long for the control buffer");
            s = json_text(&short);
            code = short.code();
        }
        let mut r = Self::default();
        r.text[..s.len()].copy_from_slice(s.as_bytes());
        r.len = s.len() as u32;
        r.code = code;
        r
    }

    /// The answer it holds.
    pub fn answer(&self) -> Result<Answer, serde_json::Error> {
        let n = (self.len as usize).min(RESPONSE_BYTES);
        serde_json::from_slice(&self.text[..n])
    }
}

/// The JSON text of a request or an answer (their types always serialise).
fn json_text<T: serde::Serialize>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|e| unreachable!("control messages serialise: {e}"))
}

pub(super) type CtlServer = Server<ipc::Service, ControlRequest, (), ControlResponse, ()>;
pub(super) type CtlActive = ActiveRequest<ipc::Service, ControlRequest, (), ControlResponse, ()>;

pub(super) fn service_name(instance: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(&format!("feedloop/{instance}/control")).map_err(|e| IpcError::Setup {
        what: "name the control service".into(),
        detail: format!("{e:?}"),
    })
}
