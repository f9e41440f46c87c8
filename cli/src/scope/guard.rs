//! Who the scope answers: the checks every request passes before it is served.
//!
//! - **Host**: only a request whose `Host` names the address the scope listens on (with its port;
//!   for a loopback address also `localhost`, `127.0.0.1` and `[::1]`) is answered, so a web page
//!   whose own name resolves to this machine (DNS rebinding) gets nothing.
//! - **Token**: every API request carries the launch token, a random secret printed with the
//!   address (`?token=`), in the header `x-scope-token` or the query parameter `token`; it is
//!   compared in constant time. The page and its script and style load without it.
//! - **Origin**: a request that changes the scope or the loop (swap, trigger, capture, take-over,
//!   open) is refused when its `Origin` is present and is not the scope's own, token or not.
//! - **Read-only** (`--read-only`): swaps and retunes are refused.
//!
//! [`Guard::check`] takes the request's head as plain strings, so it runs without a socket.

use std::net::IpAddr;

use anyhow::{Context, Result};

/// Name of the header that carries the token.
pub const TOKEN_HEADER: &str = "x-scope-token";
/// Name of the query parameter that carries the token.
pub const TOKEN_PARAM: &str = "token";
/// Random bytes of a token (256 bits, written as 64 hex digits).
const TOKEN_BYTES: usize = 32;

/// API paths that change the scope's state or the loop's: POST only, own origin only.
const CHANGING: [&str; 7] = [
    "/api/takeover",
    "/api/trigger",
    "/api/trigger/cancel",
    "/api/capture/save",
    "/api/swap",
    "/api/open",
    "/api/trace",
];
/// API paths a read-only scope refuses (swaps and retunes).
const CONTROL: [&str; 1] = ["/api/swap"];

/// The head of one request, as the checks see it.
#[derive(Debug, Clone, Copy, Default)]
pub struct Head<'a> {
    /// `GET`, `POST`, ...
    pub method: &'a str,
    /// The path, without the query.
    pub path: &'a str,
    /// The `Host` header.
    pub host: Option<&'a str>,
    /// The `Origin` header.
    pub origin: Option<&'a str>,
    /// The `x-scope-token` header.
    pub token_header: Option<&'a str>,
    /// The `token` query parameter.
    pub token_param: Option<&'a str>,
}

/// A refused request: the HTTP status and the reason given (and logged).
#[derive(Debug, Clone, PartialEq)]
pub struct Refusal {
    /// 401, 403, 405 or 421.
    pub code: u16,
    /// Why, in words.
    pub reason: String,
}

fn refuse(code: u16, reason: String) -> Result<(), Refusal> {
    Err(Refusal { code, reason })
}

/// The checks of one scope: its token, its address and whether it only watches.
pub struct Guard {
    token: String,
    bind: IpAddr,
    port: u16,
    /// This machine's name (accepted as a Host of a scope bound beyond loopback).
    hostname: Option<String>,
    /// `--read-only`.
    pub read_only: bool,
}

impl Guard {
    /// The guard of a scope listening on `bind`:`port`, with a fresh random token.
    pub fn new(bind: IpAddr, port: u16, read_only: bool) -> Result<Self> {
        let mut bytes = [0u8; TOKEN_BYTES];
        getrandom::fill(&mut bytes)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .context("reading random bytes for the scope's token")?;
        let token = bytes.iter().map(|b| format!("{b:02x}")).collect();
        Ok(Self::with_token(bind, port, read_only, token))
    }

    /// The guard with a given token.
    pub fn with_token(bind: IpAddr, port: u16, read_only: bool, token: String) -> Self {
        Self {
            token,
            bind,
            port,
            hostname: machine_name(),
            read_only,
        }
    }

    /// The token.
    pub fn token(&self) -> &str {
        &self.token
    }

    /// The address to open, token included: `http://HOST:PORT/?token=T`.
    pub fn url(&self) -> String {
        format!(
            "http://{}/?{TOKEN_PARAM}={}",
            std::net::SocketAddr::new(self.bind, self.port),
            self.token()
        )
    }

    /// Whether the scope listens beyond this machine (then the token is all that protects it).
    pub fn beyond_loopback(&self) -> bool {
        !self.bind.is_loopback()
    }

    /// Whether the request `method` `url` with `headers` (name, value) may be served: its head
    /// picked out and [`Guard::check`]ed. Needs no socket.
    pub fn screen(&self, method: &str, url: &str, headers: &[(&str, &str)]) -> Result<(), Refusal> {
        let path = url.split('?').next().unwrap_or("");
        let q = query(url);
        // a repeated Host or Origin names no one thing: treat it as a foreign one
        let one = |name: &str| {
            let mut it = headers.iter().filter(|(k, _)| k.eq_ignore_ascii_case(name));
            match (it.next(), it.next()) {
                (Some((_, v)), None) => Some(*v),
                (Some(_), Some(_)) => Some(""),
                (None, _) => None,
            }
        };
        let origin = one("origin").map(|o| if o.is_empty() { "(several)" } else { o });
        self.check(&Head {
            method,
            path,
            host: one("host"),
            origin,
            token_header: one(TOKEN_HEADER),
            token_param: q
                .iter()
                .find(|(k, _)| k == TOKEN_PARAM)
                .map(|(_, v)| v.as_str()),
        })
    }

    /// Whether request `h` may be served; the refusal says why not.
    pub fn check(&self, h: &Head) -> Result<(), Refusal> {
        let Some(host) = h.host.filter(|v| self.host_ok(v)) else {
            return refuse(
                421,
                format!(
                    "Host `{}` is not this scope's address ({}): a page under another name \
                     (DNS rebinding) is not answered",
                    shown(h.host.unwrap_or("")),
                    std::net::SocketAddr::new(self.bind, self.port)
                ),
            );
        };
        if !h.path.starts_with("/api/") {
            return Ok(());
        }
        let changing = CHANGING.contains(&h.path);
        if changing && h.method != "POST" {
            return refuse(405, format!("{} changes the scope: POST only", h.path));
        }
        self.token_ok(h.token_header.or(h.token_param))?;
        if changing {
            if let Some(o) = h.origin {
                if !o.eq_ignore_ascii_case(&format!("http://{host}")) {
                    return refuse(
                        403,
                        format!(
                            "a request from another site (Origin `{}`) may not change the \
                             scope; only its own page (http://{host}) may",
                            shown(o)
                        ),
                    );
                }
            }
        }
        if self.read_only && CONTROL.contains(&h.path) {
            return refuse(
                403,
                "this scope is read-only (--read-only): swaps and retunes are refused; watching, \
                 triggers and captures work"
                    .into(),
            );
        }
        Ok(())
    }

    fn token_ok(&self, given: Option<&str>) -> Result<(), Refusal> {
        match given {
            None | Some("") => refuse(
                401,
                format!(
                    "no token: open the address `feedloop scope` printed \
                     (http://HOST:PORT/?{TOKEN_PARAM}=...), or send the header {TOKEN_HEADER}"
                ),
            ),
            Some(t) if same(self.token.as_bytes(), t.as_bytes()) => Ok(()),
            Some(_) => refuse(
                403,
                "wrong token: use the address the running `feedloop scope` printed".into(),
            ),
        }
    }

    /// Whether `host` (a Host header: name or IP, and port) names this scope.
    fn host_ok(&self, host: &str) -> bool {
        let Some((name, port)) = split_host(host) else {
            return false;
        };
        if port != self.port {
            return false;
        }
        let name = name.to_ascii_lowercase();
        if let Ok(ip) = name.parse::<IpAddr>() {
            return if self.bind.is_unspecified() {
                // an address, not a name: nothing an outside DNS can point here
                true
            } else if self.bind.is_loopback() {
                ip == self.bind
                    || ip == IpAddr::from(std::net::Ipv4Addr::LOCALHOST)
                    || ip == IpAddr::from(std::net::Ipv6Addr::LOCALHOST)
            } else {
                ip == self.bind
            };
        }
        if name == "localhost" {
            return self.bind.is_loopback() || self.bind.is_unspecified();
        }
        !self.bind.is_loopback()
            && self
                .hostname
                .as_deref()
                .is_some_and(|h| h.eq_ignore_ascii_case(&name))
    }
}

/// The query parameters of `url`, unescaped.
pub fn query(url: &str) -> Vec<(String, String)> {
    let Some((_, q)) = url.split_once('?') else {
        return Vec::new();
    };
    q.split('&')
        .map(|kv| {
            let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
            (unescape(k), unescape(v))
        })
        .collect()
}

/// `s` with `+` as a space and `%XX` as its byte (a bad escape stays as it is).
pub fn unescape(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'+' => out.push(b' '),
            b'%' if i + 2 < b.len() => {
                let hex = |c: u8| (c as char).to_digit(16);
                match (hex(b[i + 1]), hex(b[i + 2])) {
                    (Some(h), Some(l)) => {
                        out.push((h * 16 + l) as u8);
                        i += 2;
                    }
                    _ => out.push(b'%'),
                }
            }
            c => out.push(c),
        }
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// `s` as it may be shown on a terminal and in a log line: at most 100 characters, control
/// characters escaped (a Host or Origin header is whatever the client sent).
pub fn shown(s: &str) -> String {
    let mut out: String = s
        .chars()
        .take(100)
        .flat_map(|c| {
            let esc = c
                .is_control()
                .then(|| c.escape_default().collect::<String>());
            esc.unwrap_or_else(|| c.to_string())
                .chars()
                .collect::<Vec<_>>()
        })
        .collect();
    if s.chars().count() > 100 {
        out.push_str("...");
    }
    out
}

/// `host` split into its name (IPv6 without brackets) and port (80 when absent); `None` when it
/// is not `NAME[:PORT]` or `[IPV6][:PORT]`.
fn split_host(host: &str) -> Option<(&str, u16)> {
    let host = host.trim();
    let (name, port) = if let Some(rest) = host.strip_prefix('[') {
        let (ip, after) = rest.split_once(']')?;
        match after {
            "" => (ip, None),
            p => (ip, Some(p.strip_prefix(':')?)),
        }
    } else {
        match host.split_once(':') {
            Some((n, p)) => (n, Some(p)),
            None => (host, None),
        }
    };
    if name.is_empty() {
        return None;
    }
    let port = match port {
        None => 80,
        Some(p) if !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()) => p.parse().ok()?,
        Some(_) => return None,
    };
    Some((name, port))
}

/// Whether `given` equals `expected`, in a time that depends on `expected`'s length only.
fn same(expected: &[u8], given: &[u8]) -> bool {
    let mut diff = expected.len() ^ given.len();
    for (i, e) in expected.iter().enumerate() {
        diff |= usize::from(e ^ given.get(i).copied().unwrap_or(0));
    }
    std::hint::black_box(diff) == 0
}

/// This machine's host name.
fn machine_name() -> Option<String> {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most `buf.len()` bytes into `buf`.
    let rc = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) };
    if rc != 0 {
        return None;
    }
    let n = buf.iter().position(|b| *b == 0).unwrap_or(buf.len());
    std::str::from_utf8(&buf[..n])
        .ok()
        .filter(|s| !s.is_empty())
        .map(str::to_string)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guard(bind: &str, read_only: bool) -> Guard {
        let mut g = Guard::with_token(bind.parse().unwrap(), 8080, read_only, "s3cret".into());
        g.hostname = Some("machine".into());
        g
    }

    fn head<'a>(method: &'a str, path: &'a str, host: &'a str) -> Head<'a> {
        Head {
            method,
            path,
            host: Some(host),
            token_header: Some("s3cret"),
            ..Head::default()
        }
    }

    fn code(g: &Guard, h: &Head) -> u16 {
        g.check(h).err().map_or(200, |r| r.code)
    }

    #[test]
    fn a_loopback_scope_answers_its_own_names_with_its_port_only() {
        let g = guard("127.0.0.1", false);
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "LocalHost:8080",
            "[::1]:8080",
        ] {
            assert_eq!(code(&g, &head("GET", "/api/state", ok)), 200, "{ok}");
        }
        for bad in [
            "attacker.example:8080",
            "127.0.0.1:8081",
            "127.0.0.1",
            "machine:8080",
            "127.0.0.2:8080",
            "",
            ":8080",
            "127.0.0.1:80x",
            "[::1:8080",
        ] {
            assert_eq!(code(&g, &head("GET", "/", bad)), 421, "{bad}");
        }
        let mut h = head("GET", "/", "x");
        h.host = None;
        assert_eq!(code(&g, &h), 421);
    }

    #[test]
    fn a_scope_bound_beyond_loopback_answers_addresses_and_the_machines_name() {
        let g = guard("0.0.0.0", false);
        for ok in ["192.168.1.5:8080", "machine:8080", "localhost:8080"] {
            assert_eq!(code(&g, &head("GET", "/", ok)), 200, "{ok}");
        }
        assert_eq!(code(&g, &head("GET", "/", "evil.example:8080")), 421);
        let g = guard("192.168.1.5", false);
        assert_eq!(code(&g, &head("GET", "/", "192.168.1.5:8080")), 200);
        assert_eq!(code(&g, &head("GET", "/", "192.168.1.6:8080")), 421);
        assert_eq!(code(&g, &head("GET", "/", "localhost:8080")), 421);
        assert!(g.beyond_loopback() && !guard("::1", false).beyond_loopback());
        assert_eq!(guard("::1", false).url(), "http://[::1]:8080/?token=s3cret");
    }

    #[test]
    fn the_api_needs_the_token_the_page_does_not() {
        let g = guard("127.0.0.1", false);
        let mut h = head("GET", "/api/state", "127.0.0.1:8080");
        h.token_header = None;
        assert_eq!(code(&g, &h), 401);
        assert_eq!(code(&g, &head("GET", "/", "127.0.0.1:8080")), 200);
        assert_eq!(
            code(
                &g,
                &Head {
                    path: "/scope.js",
                    ..h
                }
            ),
            200
        );
        for wrong in ["s3cre", "s3cret!", "S3CRET", "x"] {
            h.token_header = Some(wrong);
            assert_eq!(code(&g, &h), 403, "{wrong}");
        }
        h.token_header = None;
        h.token_param = Some("s3cret");
        assert_eq!(code(&g, &h), 200);
    }

    #[test]
    fn a_change_from_another_site_is_refused_even_with_the_token() {
        let g = guard("127.0.0.1", false);
        let mut h = head("POST", "/api/swap", "localhost:8080");
        assert_eq!(code(&g, &h), 200, "no Origin: a script or curl");
        h.origin = Some("http://localhost:8080");
        assert_eq!(code(&g, &h), 200);
        for o in ["http://attacker.example", "http://127.0.0.1:8080", "null"] {
            h.origin = Some(o);
            assert_eq!(code(&g, &h), 403, "{o}");
        }
        // reading is not changing
        let mut h = head("GET", "/api/state", "localhost:8080");
        h.origin = Some("http://attacker.example");
        assert_eq!(code(&g, &h), 200);
        assert_eq!(code(&g, &head("GET", "/api/swap", "localhost:8080")), 405);
    }

    #[test]
    fn a_read_only_scope_refuses_swaps_and_keeps_triggers() {
        let g = guard("127.0.0.1", true);
        let r = g
            .check(&head("POST", "/api/swap", "127.0.0.1:8080"))
            .unwrap_err();
        assert_eq!(r.code, 403);
        assert!(r.reason.contains("read-only"), "{r:?}");
        for p in ["/api/trigger", "/api/capture/save", "/api/takeover"] {
            assert_eq!(code(&g, &head("POST", p, "127.0.0.1:8080")), 200, "{p}");
        }
    }

    #[test]
    fn a_whole_request_is_screened_from_its_url_and_headers() {
        let g = guard("127.0.0.1", false);
        let host = ("Host", "127.0.0.1:8080");
        let code =
            |m: &str, url: &str, h: &[(&str, &str)]| g.screen(m, url, h).err().map(|r| r.code);
        assert_eq!(code("GET", "/api/state?token=s3cret", &[host]), None);
        assert_eq!(code("GET", "/api/state?to%6Ben=s3cre%74", &[host]), None);
        assert_eq!(code("GET", "/api/state?token=nope", &[host]), Some(403));
        assert_eq!(
            code("GET", "/api/state", &[host, ("X-Scope-Token", "s3cret")]),
            None
        );
        assert_eq!(
            code("GET", "/api/state?token=s3cret", &[host, host]),
            Some(421)
        );
        let origin = ("Origin", "http://127.0.0.1:8080");
        assert_eq!(
            code("POST", "/api/trigger?token=s3cret", &[host, origin]),
            None
        );
        assert_eq!(
            code("POST", "/api/trigger?token=s3cret", &[host, origin, origin]),
            Some(403)
        );
        assert_eq!(code("GET", "/?token=", &[host]), None);
        assert_eq!(code("GET", "/", &[]), Some(421));
    }

    #[test]
    fn what_a_client_sent_is_shown_escaped_and_cut() {
        assert_eq!(
            shown("evil\x1b[2J\r\nfeedloop scope: ok"),
            "evil\\u{1b}[2J\\r\\nfeedloop scope: ok"
        );
        assert_eq!(shown(&"a".repeat(150)), format!("{}...", "a".repeat(100)));
        let g = guard("127.0.0.1", false);
        let r = g.check(&head("GET", "/", "x\n:8080")).unwrap_err();
        assert!(!r.reason.contains('\n'), "{r:?}");
    }

    #[test]
    fn tokens_are_fresh_and_long() {
        let ip = "127.0.0.1".parse().unwrap();
        let (a, b) = (
            Guard::new(ip, 1, false).unwrap(),
            Guard::new(ip, 1, false).unwrap(),
        );
        assert_ne!(a.token(), b.token());
        assert_eq!(a.token().len(), 64);
        assert!(a.token().bytes().all(|c| c.is_ascii_hexdigit()));
        assert!(same(b"abc", b"abc") && !same(b"abc", b"abd") && !same(b"abc", b"ab"));
    }
}
