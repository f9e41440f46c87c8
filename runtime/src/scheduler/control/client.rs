//! The client side of the control service: one request, one answer.

use std::time::Duration;

use super::origin::Origin;
use super::protocol::{Answer, Request};
use super::wire::{service_name, ControlRequest, ControlResponse};
use crate::shared::clock::now_ns;
use crate::shared::ipc::{create_node, IpcError};

/// Sends one request to the scheduler of `instance` and waits up to `timeout` for the answer;
/// its origin is this process, as the command line ([`Origin::command_line`]).
pub fn request(instance: &str, req: &Request, timeout: Duration) -> Result<Answer, IpcError> {
    request_from(instance, req, Origin::command_line(), timeout)
}

/// [`request`] sent on behalf of `origin` (e.g. a page of the scope).
pub fn request_from(
    instance: &str,
    req: &Request,
    origin: Origin,
    timeout: Duration,
) -> Result<Answer, IpcError> {
    let node = create_node(instance, "control-client")?;
    let setup = |what: &str, e: &dyn std::fmt::Debug| IpcError::Setup {
        what: what.to_string(),
        detail: format!("{e:?}"),
    };
    let svc = node
        .service_builder(&service_name(instance)?)
        .request_response::<ControlRequest, ControlResponse>()
        .open()
        .map_err(|e| {
            setup(
                &format!("reach the control service of instance `{instance}` (is its scheduler running?)"),
                &e,
            )
        })?;
    let client = svc
        .client_builder()
        .create()
        .map_err(|e| setup("create a control client", &e))?;
    let msg = ControlRequest::new(req, origin).map_err(|e| IpcError::Send(e.to_string()))?;
    let start = now_ns();
    let limit = timeout.as_nanos() as u64;
    // The server connects lazily: resend until a response arrives.
    let mut pending = client
        .send_copy(msg)
        .map_err(|e| IpcError::Send(format!("{e:?}")))?;
    let mut last_send = now_ns();
    loop {
        if let Some(r) = pending
            .receive()
            .map_err(|e| IpcError::Receive(format!("{e:?}")))?
        {
            return r
                .answer()
                .map_err(|e| IpcError::Receive(format!("malformed answer: {e}")));
        }
        if now_ns() - start > limit {
            return Err(IpcError::PeerTimeout {
                peer: "scheduler (control service)",
                instance: instance.to_string(),
                seconds: timeout.as_secs_f64(),
            });
        }
        if pending.number_of_server_connections() == 0 && now_ns() - last_send > 50_000_000 {
            pending = client
                .send_copy(msg)
                .map_err(|e| IpcError::Send(format!("{e:?}")))?;
            last_send = now_ns();
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}
