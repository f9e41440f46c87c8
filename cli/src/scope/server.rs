//! The scope's HTTP/1.1 server: small, for a browser or two on the scope's page.
//!
//! One thread accepts connections, one thread per connection reads its requests (the head with
//! `httparse`, at most [`MAX_HEAD`] bytes within [`HEAD_WITHIN`]; the body by `Content-Length`
//! or chunks, at most the server's body limit) and hands each whole request to the worker
//! threads blocked in [`Server::recv`]; the connection waits for the answer, writes it and reads
//! the next request (keep-alive for HTTP/1.1, pipelined requests answered in order). A body
//! beyond the limit is refused (413) before any of it is read, a version other than HTTP/1.0
//! and 1.1 gets 505, a malformed head 400; each of these closes the connection. Every answer
//! has a `Content-Length`; none ever carries a CORS header.

use std::collections::{HashMap, VecDeque};
use std::io::{self, Read, Write};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::{mpsc, Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::guard::shown;

/// Largest request head (request line and headers), bytes.
pub const MAX_HEAD: usize = 64 << 10;
/// Most header lines of a request.
const MAX_HEADERS: usize = 100;
/// Longest a request head may take to come (also how long an idle connection is kept).
const HEAD_WITHIN: Duration = Duration::from_secs(30);
/// Longest wait for the next bytes of a body, and for an answer to be taken by the client.
const IDLE: Duration = Duration::from_secs(30);
/// Most connections open at once (the scope has a browser or two).
const MAX_CONNECTIONS: usize = 64;
/// Bytes read at a time.
const READ_CHUNK: usize = 16 << 10;
/// Longest line of a chunked body's size.
const MAX_CHUNK_LINE: usize = 4096;

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// An answer: status code, headers and body (its `Content-Length` is added when sent).
#[derive(Debug, Clone)]
pub struct Response {
    code: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Response {
    /// An answer of `code` with `body`.
    pub fn new(code: u16, body: impl Into<Vec<u8>>) -> Self {
        Self {
            code,
            headers: Vec::new(),
            body: body.into(),
        }
    }

    /// The answer with one more header (line breaks in it removed; `Content-Length` and
    /// `Connection` are the server's own and ignored).
    pub fn with_header(mut self, name: &str, value: &str) -> Self {
        let clean = |s: &str| s.replace(['\r', '\n'], "");
        let n = clean(name);
        if !n.eq_ignore_ascii_case("content-length") && !n.eq_ignore_ascii_case("connection") {
            self.headers.push((n, clean(value)));
        }
        self
    }

    /// A JSON answer `{"error": reason}` of the server itself.
    fn error(code: u16, reason: &str) -> Self {
        Self::new(code, serde_json::json!({ "error": reason }).to_string())
            .with_header("Content-Type", "application/json")
            .with_header("Cache-Control", "no-store")
            .with_header("X-Content-Type-Options", "nosniff")
    }
}

/// One whole request; answered with [`Request::respond`] (a request dropped unanswered gets a
/// 500).
pub struct Request {
    method: String,
    url: String,
    headers: Vec<(String, String)>,
    peer: SocketAddr,
    body: Vec<u8>,
    reply: Option<mpsc::Sender<Response>>,
}

impl Request {
    /// The method, as sent (`GET`, `POST`, ...).
    pub fn method(&self) -> &str {
        &self.method
    }

    /// The request target, as sent (path and query).
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The header lines (name, value), in their order.
    pub fn headers(&self) -> &[(String, String)] {
        &self.headers
    }

    /// The value of the first header `name` (any case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    /// The client's address.
    pub fn peer(&self) -> SocketAddr {
        self.peer
    }

    /// The body (chunks joined).
    pub fn body(&self) -> &[u8] {
        &self.body
    }

    /// The body, taken out of the request (empty after).
    pub fn take_body(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.body)
    }

    /// Sends `r` as the answer.
    pub fn respond(mut self, r: Response) {
        if let Some(tx) = self.reply.take() {
            let _ = tx.send(r);
        }
    }
}

impl Drop for Request {
    fn drop(&mut self) {
        if let Some(tx) = self.reply.take() {
            let _ = tx.send(Response::error(500, "the request was not answered"));
        }
    }
}

/// Requests waiting for a worker.
#[derive(Default)]
struct Queue {
    waiting: VecDeque<Request>,
    stopped: bool,
}

/// What the server's threads share.
struct Inner {
    queue: Mutex<Queue>,
    ready: Condvar,
    open: Mutex<HashMap<u64, TcpStream>>,
    max_body: u64,
}

impl Inner {
    fn stopped(&self) -> bool {
        lock(&self.queue).stopped
    }

    /// Queues `rq` for a worker; false when the server has stopped.
    fn push(&self, rq: Request) -> bool {
        let mut q = lock(&self.queue);
        if q.stopped {
            return false;
        }
        q.waiting.push_back(rq);
        drop(q);
        self.ready.notify_one();
        true
    }
}

/// The server: listening from [`Server::bind`] until [`Server::stop`] (or dropped).
pub struct Server {
    inner: Arc<Inner>,
    addr: SocketAddr,
}

impl Server {
    /// Listens on `addr` (port 0: any free one) for requests whose bodies are at most `max_body`
    /// bytes.
    pub fn bind(addr: SocketAddr, max_body: u64) -> io::Result<Self> {
        let listener = TcpListener::bind(addr)?;
        let addr = listener.local_addr()?;
        let inner = Arc::new(Inner {
            queue: Mutex::new(Queue::default()),
            ready: Condvar::new(),
            open: Mutex::new(HashMap::new()),
            max_body,
        });
        let i = inner.clone();
        std::thread::Builder::new()
            .name("scope-accept".into())
            .spawn(move || accept(&i, listener))?;
        Ok(Self { inner, addr })
    }

    /// The address it listens on (the port chosen when 0 was asked).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The next request; an error once the server has stopped.
    pub fn recv(&self) -> io::Result<Request> {
        let mut q = lock(&self.inner.queue);
        loop {
            if q.stopped {
                return Err(io::Error::other("the scope's server has stopped"));
            }
            if let Some(rq) = q.waiting.pop_front() {
                return Ok(rq);
            }
            q = self.inner.ready.wait(q).unwrap_or_else(|p| p.into_inner());
        }
    }

    /// Stops: every [`Server::recv`] returns an error, no connection is taken any more and the
    /// open ones are closed.
    pub fn stop(&self) {
        let unanswered = {
            let mut q = lock(&self.inner.queue);
            if q.stopped {
                return;
            }
            q.stopped = true;
            std::mem::take(&mut q.waiting)
        };
        self.inner.ready.notify_all();
        drop(unanswered);
        for s in lock(&self.inner.open).values() {
            let _ = s.shutdown(Shutdown::Both);
        }
        // wake the accepting thread
        let ip = match self.addr.ip() {
            IpAddr::V4(a) if a.is_unspecified() => IpAddr::V4(Ipv4Addr::LOCALHOST),
            IpAddr::V6(a) if a.is_unspecified() => IpAddr::V6(Ipv6Addr::LOCALHOST),
            ip => ip,
        };
        let wake = SocketAddr::new(ip, self.addr.port());
        let _ = TcpStream::connect_timeout(&wake, Duration::from_secs(1));
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Takes connections until the server stops, a thread for each.
fn accept(inner: &Arc<Inner>, listener: TcpListener) {
    let mut next = 0u64;
    for stream in listener.incoming() {
        if inner.stopped() {
            break;
        }
        let Ok(mut stream) = stream else {
            // out of descriptors or the like: let some connections end
            std::thread::sleep(Duration::from_millis(20));
            continue;
        };
        let (Ok(peer), Ok(clone)) = (stream.peer_addr(), stream.try_clone()) else {
            continue;
        };
        {
            let mut open = lock(&inner.open);
            if open.len() >= MAX_CONNECTIONS {
                drop(open);
                let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
                let busy = Response::error(503, "too many connections to the scope");
                let _ = write_response(&mut stream, &busy, false, false);
                continue;
            }
            next += 1;
            open.insert(next, clone);
        }
        let (i, id) = (inner.clone(), next);
        let spawned = std::thread::Builder::new()
            .name("scope-connection".into())
            .spawn(move || {
                serve_connection(&i, stream, peer);
                lock(&i.open).remove(&id);
            });
        if spawned.is_err() {
            lock(&inner.open).remove(&id);
        }
    }
}

/// Why a connection ends early: an answer of the server, then close; or close at once.
enum Fail {
    Answer(u16, String),
    Close,
}

fn fail<T>(code: u16, reason: impl Into<String>) -> Result<T, Fail> {
    Err(Fail::Answer(code, reason.into()))
}

/// Answers the requests of one connection in order until it ends.
fn serve_connection(inner: &Inner, stream: TcpStream, peer: SocketAddr) {
    let _ = stream.set_nodelay(true);
    let _ = stream.set_write_timeout(Some(IDLE));
    let mut c = Conn {
        stream,
        buf: Vec::new(),
    };
    loop {
        let (mut rq, keep) = match c.next(inner.max_body, peer) {
            Ok(Some(r)) => r,
            Ok(None) | Err(Fail::Close) => return,
            Err(Fail::Answer(code, reason)) => {
                let _ =
                    write_response(&mut c.stream, &Response::error(code, &reason), false, false);
                return linger(&mut c.stream);
            }
        };
        let head_only = rq.method == "HEAD";
        let (tx, rx) = mpsc::channel();
        rq.reply = Some(tx);
        if !inner.push(rq) {
            return;
        }
        let Ok(answer) = rx.recv() else {
            return;
        };
        if write_response(&mut c.stream, &answer, head_only, keep).is_err() {
            return;
        }
        if !keep {
            return linger(&mut c.stream);
        }
    }
}

/// Closes gracefully: no more writes, and the client's last bytes read (a little while at most)
/// so that the answer is not lost to a reset.
fn linger(s: &mut TcpStream) {
    let _ = s.shutdown(Shutdown::Write);
    let until = Instant::now() + Duration::from_secs(2);
    let _ = s.set_read_timeout(Some(Duration::from_millis(200)));
    let mut scratch = vec![0u8; READ_CHUNK];
    let mut total = 0usize;
    while Instant::now() < until && total < (4 << 20) {
        match s.read(&mut scratch) {
            Ok(0) | Err(_) => break,
            Ok(n) => total += n,
        }
    }
}

/// The reason phrase of `code`.
fn reason(code: u16) -> &'static str {
    match code {
        100 => "Continue",
        200 => "OK",
        400 => "Bad Request",
        401 => "Unauthorized",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        408 => "Request Timeout",
        409 => "Conflict",
        411 => "Length Required",
        413 => "Content Too Large",
        421 => "Misdirected Request",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        501 => "Not Implemented",
        503 => "Service Unavailable",
        505 => "HTTP Version Not Supported",
        c if c < 300 => "Success",
        c if c < 500 => "Client Error",
        _ => "Server Error",
    }
}

/// Writes `r` (without its body for a HEAD request), with `Connection: close` unless `keep`.
fn write_response(s: &mut TcpStream, r: &Response, head_only: bool, keep: bool) -> io::Result<()> {
    let mut head = format!("HTTP/1.1 {} {}\r\n", r.code, reason(r.code));
    for (k, v) in &r.headers {
        head.push_str(&format!("{k}: {v}\r\n"));
    }
    head.push_str(&format!("Content-Length: {}\r\n", r.body.len()));
    if !keep {
        head.push_str("Connection: close\r\n");
    }
    head.push_str("\r\n");
    let mut out = head.into_bytes();
    if !head_only {
        out.extend_from_slice(&r.body);
    }
    s.write_all(&out)?;
    s.flush()
}

/// How a request's body comes.
enum Body {
    Empty,
    Length(usize),
    Chunked,
}

/// One connection's stream and the bytes read from it but not used yet.
struct Conn {
    stream: TcpStream,
    buf: Vec<u8>,
}

impl Conn {
    /// Reads more bytes into the buffer, waiting at most `wait`; `Ok(0)` at the end.
    fn fill(&mut self, wait: Duration) -> io::Result<usize> {
        self.stream
            .set_read_timeout(Some(wait.max(Duration::from_millis(1))))?;
        let old = self.buf.len();
        self.buf.resize(old + READ_CHUNK, 0);
        let got = self.stream.read(&mut self.buf[old..]);
        self.buf.truncate(old + *got.as_ref().unwrap_or(&0));
        got
    }

    /// The next request and whether the connection stays open after it; `None` when the
    /// client has closed the connection (or left it idle) between requests.
    fn next(&mut self, max_body: u64, peer: SocketAddr) -> Result<Option<(Request, bool)>, Fail> {
        let Some(end) = self.read_head()? else {
            return Ok(None);
        };
        let (method, url, version, headers) = parse_head(&self.buf[..end])?;
        self.buf.drain(..end);
        let body = framing(&headers, max_body)?;
        let has = |name: &str, token: &str| {
            headers
                .iter()
                .filter(|(n, _)| n.eq_ignore_ascii_case(name))
                .flat_map(|(_, v)| v.split(','))
                .any(|t| t.trim().eq_ignore_ascii_case(token))
        };
        let keep = version == 1 && !has("connection", "close");
        let expects = version == 1 && has("expect", "100-continue");
        if expects && !matches!(body, Body::Empty) {
            self.stream
                .write_all(b"HTTP/1.1 100 Continue\r\n\r\n")
                .map_err(|_| Fail::Close)?;
        }
        let body = match body {
            Body::Empty => Vec::new(),
            Body::Length(n) => {
                let mut b = Vec::with_capacity(n.min(1 << 20));
                self.read_into(&mut b, n)?;
                b
            }
            Body::Chunked => self.read_chunked(max_body)?,
        };
        let rq = Request {
            method,
            url,
            headers,
            peer,
            body,
            reply: None,
        };
        Ok(Some((rq, keep)))
    }

    /// Reads until a whole head is in the buffer; its length, or `None` when the connection
    /// ends (or stays idle) before a request starts.
    fn read_head(&mut self) -> Result<Option<usize>, Fail> {
        let deadline = Instant::now() + HEAD_WITHIN;
        let mut scanned = 0;
        loop {
            // blank lines before a request line are ignored (RFC 9112, 2.2)
            let lead = self.buf.iter().take_while(|b| matches!(b, b'\r' | b'\n'));
            let lead = lead.count();
            if lead > 0 {
                self.buf.drain(..lead);
                scanned = 0;
            }
            check_version(&self.buf)?;
            if let Some(end) = head_end(&self.buf, scanned) {
                if end > MAX_HEAD {
                    break;
                }
                return Ok(Some(end));
            }
            scanned = self.buf.len();
            if self.buf.len() > MAX_HEAD {
                break;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            match self.fill(left) {
                Ok(0) if self.buf.is_empty() => return Ok(None),
                Ok(0) => return fail(400, "the connection ended inside a request head"),
                Ok(_) => {}
                Err(e) if timed_out(&e) && self.buf.is_empty() => return Ok(None),
                Err(e) if timed_out(&e) => {
                    let s = HEAD_WITHIN.as_secs();
                    return fail(408, format!("the request head did not come within {s} s"));
                }
                Err(_) => return Err(Fail::Close),
            }
        }
        let kib = MAX_HEAD >> 10;
        fail(431, format!("a request head of more than {kib} KiB"))
    }

    /// Reads more of the body into the buffer; `ended` is the refusal when the peer closes
    /// first.
    fn fill_body(&mut self, ended: &str) -> Result<(), Fail> {
        match self.fill(IDLE) {
            Ok(0) => fail(400, ended),
            Ok(_) => Ok(()),
            Err(e) if timed_out(&e) => {
                let s = IDLE.as_secs();
                fail(408, format!("no byte of the body for {s} s"))
            }
            Err(_) => Err(Fail::Close),
        }
    }

    /// Appends `n` bytes of the body to `out`.
    fn read_into(&mut self, out: &mut Vec<u8>, n: usize) -> Result<(), Fail> {
        let mut left = n;
        while left > 0 {
            if self.buf.is_empty() {
                self.fill_body("the body ended before its announced length")?;
            }
            let k = left.min(self.buf.len());
            out.extend(self.buf.drain(..k));
            left -= k;
        }
        Ok(())
    }

    /// One line (without its line break), at most `limit` bytes.
    fn read_line(&mut self, limit: usize) -> Result<String, Fail> {
        loop {
            if let Some(i) = self.buf.iter().position(|b| *b == b'\n') {
                if i > limit {
                    break;
                }
                let line: Vec<u8> = self.buf.drain(..=i).collect();
                let text = String::from_utf8_lossy(&line);
                return Ok(text.trim_end_matches(['\r', '\n']).to_string());
            }
            if self.buf.len() > limit {
                break;
            }
            self.fill_body("the body ended inside its chunks")?;
        }
        fail(400, "a line of the chunked body is too long")
    }

    /// A chunked body, joined, at most `max_body` bytes.
    fn read_chunked(&mut self, max_body: u64) -> Result<Vec<u8>, Fail> {
        let mut body = Vec::new();
        loop {
            let line = self.read_line(MAX_CHUNK_LINE)?;
            let digits = line.split(';').next().unwrap_or("").trim();
            let size = (!digits.is_empty() && digits.bytes().all(|b| b.is_ascii_hexdigit()))
                .then(|| u64::from_str_radix(digits, 16).unwrap_or(u64::MAX));
            let Some(size) = size else {
                return fail(
                    400,
                    format!("chunk size `{}` is not hexadecimal", shown(&line)),
                );
            };
            if size == 0 {
                return self.skip_trailers().map(|_| body);
            }
            if (body.len() as u64).saturating_add(size) > max_body {
                return fail(413, too_large(max_body));
            }
            self.read_into(&mut body, size as usize)?;
            if !self.read_line(2)?.is_empty() {
                return fail(400, "a chunk longer than its size");
            }
        }
    }

    /// The trailer lines after the last chunk, up to the blank line (ignored).
    fn skip_trailers(&mut self) -> Result<(), Fail> {
        let mut total = 0;
        loop {
            let line = self.read_line(MAX_HEAD)?;
            total += line.len() + 2;
            if total > MAX_HEAD {
                let kib = MAX_HEAD >> 10;
                return fail(431, format!("trailers of more than {kib} KiB"));
            }
            if line.is_empty() {
                return Ok(());
            }
        }
    }
}

fn timed_out(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
    )
}

fn too_large(max_body: u64) -> String {
    format!("more than {} MB", max_body >> 20)
}

/// The end of the head in `buf` (just after its blank line), searching from `from` on.
fn head_end(buf: &[u8], from: usize) -> Option<usize> {
    let start = from.saturating_sub(3);
    let rest = buf.get(start..)?;
    rest.windows(2).enumerate().find_map(|(i, w)| match w {
        [b'\n', b'\n'] => Some(start + i + 2),
        [b'\n', b'\r'] if rest.get(i + 2) == Some(&b'\n') => Some(start + i + 3),
        _ => None,
    })
}

/// A 505 when the request line (once whole) names a version other than HTTP/1.0 and 1.1,
/// whatever else is wrong with it.
fn check_version(buf: &[u8]) -> Result<(), Fail> {
    let Some(nl) = buf.iter().position(|b| *b == b'\n') else {
        return Ok(());
    };
    let line = buf[..nl].strip_suffix(b"\r").unwrap_or(&buf[..nl]);
    let version = line.rsplit(|b| *b == b' ').next().unwrap_or(b"");
    if version.starts_with(b"HTTP/") && version != b"HTTP/1.0" && version != b"HTTP/1.1" {
        let v = shown(&String::from_utf8_lossy(version));
        return fail(
            505,
            format!("{v}: only HTTP/1.1 and HTTP/1.0 are spoken here"),
        );
    }
    Ok(())
}

/// A head's method, target, minor version and headers.
type Head = (String, String, u8, Vec<(String, String)>);

/// Parses a whole head (`head` ends with its blank line).
fn parse_head(head: &[u8]) -> Result<Head, Fail> {
    let mut slots = [httparse::EMPTY_HEADER; MAX_HEADERS];
    let mut rq = httparse::Request::new(&mut slots);
    match rq.parse(head) {
        Ok(httparse::Status::Complete(_)) => {}
        Ok(httparse::Status::Partial) => return fail(400, "a malformed request head"),
        Err(httparse::Error::TooManyHeaders) => {
            return fail(431, format!("more than {MAX_HEADERS} header lines"))
        }
        Err(httparse::Error::Version) => {
            return fail(505, "only HTTP/1.1 and HTTP/1.0 are spoken here")
        }
        Err(e) => return fail(400, format!("a malformed request head ({e})")),
    }
    let mut headers = Vec::with_capacity(rq.headers.len());
    for h in rq.headers.iter() {
        let value = std::str::from_utf8(h.value).ok().filter(|v| v.is_ascii());
        let Some(value) = value else {
            return fail(
                400,
                format!("header `{}`: a value that is not ASCII", shown(h.name)),
            );
        };
        headers.push((h.name.to_string(), value.trim().to_string()));
    }
    let method = rq.method.unwrap_or_default().to_string();
    let url = rq.path.unwrap_or_default().to_string();
    Ok((method, url, rq.version.unwrap_or(1), headers))
}

/// How the body of a request with `headers` comes: refused (413) when it is announced longer
/// than `max_body`, before any of it is read.
fn framing(headers: &[(String, String)], max_body: u64) -> Result<Body, Fail> {
    let values = |name: &str| -> Vec<&str> {
        headers
            .iter()
            .filter(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
            .collect()
    };
    let (te, cl) = (values("transfer-encoding"), values("content-length"));
    if !te.is_empty() {
        if !cl.is_empty() {
            return fail(400, "both Transfer-Encoding and Content-Length");
        }
        let te = te.join(", ");
        if !te.trim().eq_ignore_ascii_case("chunked") {
            let te = shown(&te);
            return fail(
                501,
                format!("Transfer-Encoding `{te}`: only chunked bodies are taken"),
            );
        }
        return Ok(Body::Chunked);
    }
    let mut length: Option<u64> = None;
    for v in cl {
        if v.is_empty() || !v.bytes().all(|b| b.is_ascii_digit()) {
            let v = shown(v);
            return fail(
                400,
                format!("Content-Length `{v}` is not a number of bytes"),
            );
        }
        let n = v.parse::<u64>().unwrap_or(u64::MAX);
        if length.is_some_and(|l| l != n) {
            return fail(400, "two different Content-Length values");
        }
        length = Some(n);
    }
    match length {
        Some(n) if n > max_body => fail(413, too_large(max_body)),
        Some(n) if n > 0 => Ok(Body::Length(n as usize)),
        _ => Ok(Body::Empty),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_end_of_a_head_is_found_across_reads() {
        assert_eq!(head_end(b"GET / HTTP/1.1\r\n\r\nx", 0), Some(18));
        assert_eq!(head_end(b"GET / HTTP/1.1\n\nx", 0), Some(16));
        assert_eq!(head_end(b"GET / HTTP/1.1\r\nA: b\r\n", 0), None);
        assert_eq!(head_end(b"GET / HTTP/1.1\r\nA: b\r\n\r\n", 22), Some(24));
    }

    #[test]
    fn versions_other_than_1_0_and_1_1_are_refused() {
        let code = |b: &[u8]| match check_version(b) {
            Err(Fail::Answer(c, _)) => c,
            _ => 0,
        };
        assert_eq!(code(b"GET / HTTP/3.0\r\n"), 505);
        assert_eq!(code(b"GET /\0x HTTP/2\r\n"), 505);
        assert_eq!(code(b"GET / HTTP/1.1\r\n"), 0);
        assert_eq!(code(b"GET / HTTP/1.0\n"), 0);
        assert_eq!(code(b"GET / HTTP/3.0"), 0, "not a whole line yet");
    }

    #[test]
    fn bodies_are_framed_and_limited_before_they_are_read() {
        let h = |k: &str, v: &str| vec![(k.to_string(), v.to_string())];
        let code = |r: Result<Body, Fail>| match r {
            Err(Fail::Answer(c, _)) => c,
            Ok(Body::Empty) => 0,
            Ok(Body::Length(n)) => n as u16,
            Ok(Body::Chunked) => 1,
            Err(Fail::Close) => 2,
        };
        assert_eq!(code(framing(&h("content-length", "12"), 100)), 12);
        assert_eq!(code(framing(&h("Content-Length", "101"), 100)), 413);
        assert_eq!(
            code(framing(
                &h("content-length", "99999999999999999999999"),
                100
            )),
            413
        );
        assert_eq!(code(framing(&h("content-length", "-1"), 100)), 400);
        assert_eq!(code(framing(&h("transfer-encoding", "Chunked"), 100)), 1);
        assert_eq!(code(framing(&h("transfer-encoding", "gzip"), 100)), 501);
        assert_eq!(code(framing(&[], 100)), 0);
    }
}
