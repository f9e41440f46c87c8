//! What the scope's tests share: the binary, a realtime loop, `feedloop scope` with its printed
//! address and token, and plain HTTP requests over a TcpStream.

#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_feedloop")
}

pub fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

/// Kills a child process when dropped (a failing test leaves nothing running).
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// An HTTP answer.
#[derive(Debug)]
pub struct Reply {
    pub code: u16,
    /// Header names in lowercase.
    pub headers: Vec<(String, String)>,
    pub body: String,
}

impl Reply {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.body).unwrap_or_else(|e| panic!("{e}: {self:?}"))
    }
}

/// A plain HTTP/1.1 request to `addr` with `headers` (a `Host: addr` header is added unless
/// `headers` has one).
pub fn request(
    addr: &str,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> Reply {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut head = format!("{method} {path} HTTP/1.1\r\n");
    if !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("host")) {
        head.push_str(&format!("Host: {addr}\r\n"));
    }
    for (k, v) in headers {
        head.push_str(&format!("{k}: {v}\r\n"));
    }
    head.push_str(&format!(
        "Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    ));
    s.write_all(head.as_bytes()).unwrap();
    // read the head, then as many bytes as it announces (DevTools keeps the connection open)
    let mut r = BufReader::new(s);
    let mut status = String::new();
    r.read_line(&mut status).unwrap();
    let code = status[9..12].parse().unwrap();
    let mut got = Vec::new();
    loop {
        let mut h = String::new();
        r.read_line(&mut h).unwrap();
        if h.trim().is_empty() {
            break;
        }
        if let Some((k, v)) = h.split_once(':') {
            got.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
        }
    }
    let len = got
        .iter()
        .find(|(k, _)| k == "content-length")
        .and_then(|(_, v)| v.parse::<usize>().ok());
    let mut body = Vec::new();
    match len {
        Some(n) => {
            body.resize(n, 0);
            r.read_exact(&mut body).unwrap();
        }
        None => {
            r.read_to_end(&mut body).unwrap();
        }
    }
    Reply {
        code,
        headers: got,
        body: String::from_utf8_lossy(&body).into_owned(),
    }
}

/// A running `feedloop scope`: its address, its token and its command-line lines.
pub struct Scope {
    pub proc: Proc,
    /// `HOST:PORT`.
    pub addr: String,
    pub token: String,
    /// What it printed on stderr, line by line.
    pub log: Receiver<String>,
    /// The lines taken from `log` so far.
    pub seen: Vec<String>,
}

impl Scope {
    /// A request with the token (header `x-scope-token`) and a page session.
    pub fn api(&self, method: &str, path: &str, session: &str, body: &str) -> Reply {
        request(
            &self.addr,
            method,
            path,
            &[("x-scope-token", &self.token), ("x-scope-session", session)],
            body,
        )
    }

    /// Waits up to `secs` for a stderr line containing every one of `words`; returns it.
    pub fn wait_line(&mut self, words: &[&str], secs: f64) -> String {
        let t = Instant::now();
        loop {
            if let Some(l) = self
                .seen
                .iter()
                .find(|l| words.iter().all(|w| l.contains(w)))
            {
                return l.clone();
            }
            let left = secs - t.elapsed().as_secs_f64();
            if left <= 0.0 {
                panic!(
                    "the scope printed no line with {words:?}:\n{}",
                    self.seen.join("\n")
                );
            }
            if let Ok(l) = self
                .log
                .recv_timeout(Duration::from_secs_f64(left.min(0.5)))
            {
                self.seen.push(l);
            }
        }
    }
}

/// Starts `feedloop scope` with `args` (on a free port) and reads its address and token from
/// its first line, `feedloop scope: open http://HOST:PORT/?token=T`.
pub fn start_scope(args: &[&str]) -> Scope {
    let mut child = Command::new(bin())
        .arg("scope")
        .args(args)
        .args(["--port", "0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let url = line
        .trim()
        .strip_prefix("feedloop scope: open http://")
        .unwrap_or_else(|| panic!("scope printed `{line}`"));
    let (addr, token) = url
        .split_once("/?token=")
        .unwrap_or_else(|| panic!("no token in `{line}`"));
    let (tx, rx) = std::sync::mpsc::channel();
    let err = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        for l in BufReader::new(err).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    Scope {
        proc: Proc(child),
        addr: addr.to_string(),
        token: token.to_string(),
        log: rx,
        seen: Vec::new(),
    }
}

/// `feedloop run JOB --out OUT` in realtime as `instance`, its output in `OUT.out`.
pub fn start_run(job: &Path, out: &Path, instance: &str) -> Proc {
    let log = out.with_extension("out");
    Proc(
        Command::new(bin())
            .arg("run")
            .arg(job)
            .arg("--out")
            .arg(out)
            .args(["--mode", "realtime", "--instance", instance])
            .stdout(std::fs::File::create(&log).unwrap())
            .stderr(std::fs::File::create(log.with_extension("err")).unwrap())
            .spawn()
            .unwrap(),
    )
}

/// A copy of the circle job running `turns` turns at 4 kHz, with model paths made absolute.
pub fn long_job(dir: &Path, turns: f64) -> PathBuf {
    let text = std::fs::read_to_string(repo("examples/jobs/xy-circle.toml"))
        .unwrap()
        .replace("turns = 2.0", &format!("turns = {turns}"))
        // 4 kHz: the loop, the scope and the browser share this machine's cores with the other
        // tests; the behaviour under test does not depend on the rate
        .replace("period_s = 1.0e-4", "period_s = 2.5e-4")
        .replace(
            "\"../models/",
            &format!("\"{}/", repo("examples/models").display()),
        );
    let p = dir.join("job.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// `feedloop status --instance` as JSON, once the loop's control service answers (up to `secs`).
pub fn status(instance: &str, secs: f64) -> serde_json::Value {
    let t = Instant::now();
    loop {
        let o = Command::new(bin())
            .args(["status", "--instance", instance, "--timeout-s", "2"])
            .output()
            .unwrap();
        if o.status.success() {
            return serde_json::from_slice(&o.stdout).unwrap();
        }
        if t.elapsed().as_secs_f64() > secs {
            panic!(
                "no status from `{instance}` within {secs} s: {}",
                String::from_utf8_lossy(&o.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(300));
    }
}

/// A fresh scratch folder under the system's temporary folder.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("feedloop-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Stops a running loop as an operator does (SIGINT) and waits for it.
pub fn stop(run: &mut Proc) {
    // SAFETY: signalling our own child.
    unsafe { libc::kill(run.0.id() as i32, libc::SIGINT) };
    let _ = run.0.wait();
}
