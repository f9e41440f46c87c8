//! Where a control request came from: the command line (its user and process id) or a page of
//! `feedloop scope` (the page's address, and the scope's user and process id).
//!
//! The sender fills it in and it travels in a fixed-size `#[repr(C)]` field of the request
//! ([`ControlRequest::origin`](super::ControlRequest)), so the scheduler copies it into its swap
//! records without parsing or allocating. The control service is private to the user who runs the
//! loop (its shared memory is mode 0600), so the origin is what that user's own client says: an
//! audit trail of who changed what, not an authentication.

use iceoryx2::prelude::*;
use serde::{Deserialize, Serialize};

/// Bytes of a user name kept (longer names are cut at a character boundary).
pub const USER_BYTES: usize = 32;
/// Bytes of a page's address kept (an IPv6 address with its port fits).
pub const PEER_BYTES: usize = 64;

/// `via` of an origin the sender did not say.
const VIA_UNKNOWN: u32 = 0;
/// `via` of `feedloop swap` / `feedloop status` (and library callers).
const VIA_COMMAND_LINE: u32 = 1;
/// `via` of a page of `feedloop scope`.
const VIA_SCOPE: u32 = 2;

/// The origin of a control request, as it travels (fixed size, no pointers).
#[derive(Clone, Copy, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[serde(into = "OriginJson", try_from = "OriginJson")]
pub struct Origin {
    /// 0 unknown, 1 command line, 2 scope page.
    via: u32,
    /// Process id of the sender (the scope's, for a page).
    pid: u32,
    /// User id of the sender.
    uid: u32,
    /// Bytes used in `user`.
    user_len: u32,
    /// User name of the sender (UTF-8).
    user: [u8; USER_BYTES],
    /// Bytes used in `peer`.
    peer_len: u32,
    /// The page's address, `IP:PORT` (UTF-8; empty for the command line).
    peer: [u8; PEER_BYTES],
}

impl std::fmt::Debug for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.describe())
    }
}

impl Default for Origin {
    fn default() -> Self {
        Self {
            via: VIA_UNKNOWN,
            pid: 0,
            uid: 0,
            user_len: 0,
            user: [0; USER_BYTES],
            peer_len: 0,
            peer: [0; PEER_BYTES],
        }
    }
}

/// Copies the longest prefix of `s` that fits `dst` and ends on a character boundary; returns
/// its length.
fn fill(dst: &mut [u8], s: &str) -> u32 {
    let mut n = s.len().min(dst.len());
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    dst[..n].copy_from_slice(&s.as_bytes()[..n]);
    n as u32
}

fn text(b: &[u8], len: u32) -> &str {
    let n = (len as usize).min(b.len());
    std::str::from_utf8(&b[..n]).unwrap_or("?")
}

impl Origin {
    /// This process, as the command line: its user and process id.
    pub fn command_line() -> Self {
        let mut o = Self::this_process();
        o.via = VIA_COMMAND_LINE;
        o
    }

    /// A page of the scope (this process) at `peer` (`IP:PORT`).
    pub fn scope_page(peer: &str) -> Self {
        let mut o = Self::this_process();
        o.via = VIA_SCOPE;
        o.peer_len = fill(&mut o.peer, peer);
        o
    }

    fn this_process() -> Self {
        // SAFETY: getuid cannot fail.
        let uid = unsafe { libc::getuid() };
        let mut o = Self {
            pid: std::process::id(),
            uid,
            ..Self::default()
        };
        let name = user_name(uid).unwrap_or_else(|| uid.to_string());
        o.user_len = fill(&mut o.user, &name);
        o
    }

    /// Whether the sender said where it came from.
    pub fn is_known(&self) -> bool {
        self.via != VIA_UNKNOWN
    }

    /// `command_line`, `scope` or `unknown`.
    pub fn via(&self) -> &'static str {
        match self.via {
            VIA_COMMAND_LINE => "command_line",
            VIA_SCOPE => "scope",
            _ => "unknown",
        }
    }

    /// The sender's user name.
    pub fn user(&self) -> &str {
        text(&self.user, self.user_len)
    }

    /// The page's address (empty unless via the scope).
    pub fn peer(&self) -> &str {
        text(&self.peer, self.peer_len)
    }

    /// The sender's process id.
    pub fn pid(&self) -> u32 {
        self.pid
    }

    /// The sender's user id.
    pub fn uid(&self) -> u32 {
        self.uid
    }

    /// One line, e.g. `command line (user root, pid 812)` or `scope page 127.0.0.1:50412 (feedloop
    /// scope pid 790, user root)`.
    pub fn describe(&self) -> String {
        match self.via {
            VIA_COMMAND_LINE => format!("command line (user {}, pid {})", self.user(), self.pid),
            VIA_SCOPE => format!(
                "scope page {} (feedloop scope pid {}, user {})",
                self.peer(),
                self.pid,
                self.user()
            ),
            _ => "unknown".into(),
        }
    }
}

/// The name of user `uid` from the password database.
fn user_name(uid: u32) -> Option<String> {
    let mut buf = vec![0 as libc::c_char; 4096];
    // SAFETY: an all-zero passwd is a valid value to be overwritten by getpwuid_r.
    let mut pw: libc::passwd = unsafe { std::mem::zeroed() };
    let mut out: *mut libc::passwd = std::ptr::null_mut();
    // SAFETY: every pointer points to live memory of the stated size for the call's duration.
    let rc = unsafe { libc::getpwuid_r(uid, &mut pw, buf.as_mut_ptr(), buf.len(), &mut out) };
    if rc != 0 || out.is_null() || pw.pw_name.is_null() {
        return None;
    }
    // SAFETY: getpwuid_r succeeded: pw_name points to a NUL-terminated string inside `buf`.
    let name = unsafe { std::ffi::CStr::from_ptr(pw.pw_name) };
    Some(name.to_string_lossy().into_owned())
}

/// An origin as JSON: `{"via": "command_line", "user": "root", "uid": 0, "pid": 812}`, with
/// `"peer": "127.0.0.1:50412"` for a page.
#[derive(Serialize, Deserialize)]
struct OriginJson {
    via: String,
    #[serde(default)]
    user: String,
    #[serde(default)]
    uid: u32,
    #[serde(default)]
    pid: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    peer: Option<String>,
}

impl From<Origin> for OriginJson {
    fn from(o: Origin) -> Self {
        Self {
            via: o.via().to_string(),
            user: o.user().to_string(),
            uid: o.uid,
            pid: o.pid,
            peer: (o.via == VIA_SCOPE).then(|| o.peer().to_string()),
        }
    }
}

impl TryFrom<OriginJson> for Origin {
    type Error = String;
    fn try_from(j: OriginJson) -> Result<Self, String> {
        let via = match j.via.as_str() {
            "command_line" => VIA_COMMAND_LINE,
            "scope" => VIA_SCOPE,
            "unknown" => VIA_UNKNOWN,
            o => {
                return Err(format!(
                    "origin `via` `{o}`: command_line, scope or unknown"
                ))
            }
        };
        let mut o = Self {
            via,
            pid: j.pid,
            uid: j.uid,
            ..Self::default()
        };
        o.user_len = fill(&mut o.user, &j.user);
        o.peer_len = fill(&mut o.peer, j.peer.as_deref().unwrap_or(""));
        Ok(o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_command_line_names_its_user_and_process() {
        let o = Origin::command_line();
        assert_eq!(o.via(), "command_line");
        assert_eq!(o.pid(), std::process::id());
        // SAFETY: getuid cannot fail.
        assert_eq!(o.uid(), unsafe { libc::getuid() });
        assert!(!o.user().is_empty());
        let j = serde_json::to_value(o).unwrap();
        assert_eq!(j["via"], "command_line");
        assert!(j.get("peer").is_none(), "{j}");
        assert_eq!(serde_json::from_value::<Origin>(j).unwrap(), o);
    }

    #[test]
    fn a_page_keeps_its_address_and_long_text_is_cut_on_a_character_boundary() {
        let o = Origin::scope_page("[2001:db8::1]:50412");
        assert_eq!((o.via(), o.peer()), ("scope", "[2001:db8::1]:50412"));
        assert!(o
            .describe()
            .starts_with("scope page [2001:db8::1]:50412 (feedloop scope pid"));
        let j = serde_json::to_value(o).unwrap();
        assert_eq!(j["peer"], "[2001:db8::1]:50412");
        assert_eq!(serde_json::from_value::<Origin>(j).unwrap(), o);
        let long = "é".repeat(40);
        let o = Origin::scope_page(&long);
        assert_eq!(o.peer(), "é".repeat(32));
        assert!(serde_json::from_str::<Origin>(r#"{"via":"mail"}"#).is_err());
        assert!(!Origin::default().is_known());
    }
}
