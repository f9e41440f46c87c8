//! The scope's web server: the page (embedded), and a small JSON API the page polls.
//!
//! One page at a time is attached (a lease renewed by its polls, [`super::LEASE`]); a second
//! browser is told who holds the scope and may take it over. Every request is answered from the
//! scope's own state; none reaches the loop except a swap, which goes to the control service
//! exactly as `feedloop swap` would.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use serde_json::{json, Value};

use super::guard::query;
use super::server::{Request, Response, Server};
use super::store::{self, Condition, Store, Trigger, AXIS_SIGNALS, EVENT_KINDS, LATENCY};
use super::{Ctx, Session, Shared, LEASE};

/// Threads answering the page.
pub const WORKERS: usize = 4;
/// Largest trace the page may upload, bytes.
const MAX_UPLOAD: u64 = 512 << 20;
/// Most pixel columns a view asks for.
const MAX_COLS: usize = 4096;

const INDEX: &str = include_str!("page/index.html");
const SCRIPT: &str = include_str!("page/scope.js");
const STYLE: &str = include_str!("page/scope.css");

/// Binds the server; a port in use or an address that is not ours gets a message saying so.
pub fn bind(addr: &str, port: u16) -> Result<Arc<Server>> {
    let ip: std::net::IpAddr = addr.parse().with_context(|| {
        format!("--bind `{addr}` is not an IP address (e.g. 127.0.0.1, 0.0.0.0)")
    })?;
    match Server::bind(std::net::SocketAddr::new(ip, port), MAX_UPLOAD) {
        Ok(s) => Ok(Arc::new(s)),
        Err(e) => match e.kind() {
            std::io::ErrorKind::AddrInUse => bail!(
                "port {port} on {addr} is in use (another scope or server?); pick another with \
                 --port, or --port 0 for any free one"
            ),
            std::io::ErrorKind::AddrNotAvailable => {
                bail!("address {addr} is not one of this machine's (--bind)")
            }
            _ => Err(anyhow!("cannot listen on {addr}:{port}: {e}")),
        },
    }
}

/// Starts the worker threads.
pub fn serve(server: Arc<Server>, ctx: Arc<Ctx>) -> Vec<std::thread::JoinHandle<()>> {
    (0..WORKERS)
        .map(|_| {
            let (server, ctx) = (server.clone(), ctx.clone());
            std::thread::spawn(move || {
                while !ctx.stop.load(Ordering::Relaxed) {
                    match server.recv() {
                        Ok(rq) => handle(&ctx, rq),
                        Err(_) => break,
                    }
                }
            })
        })
        .collect()
}

/// `r` with the headers every answer carries (and never an Access-Control-Allow-Origin: no other
/// site may read the scope).
fn guarded(r: Response) -> Response {
    r.with_header("Cache-Control", "no-store")
        .with_header("Referrer-Policy", "no-referrer")
        .with_header("X-Content-Type-Options", "nosniff")
        .with_header("X-Frame-Options", "DENY")
}

fn reply(rq: Request, code: u16, kind: &str, body: String) {
    let r = Response::new(code, body).with_header("Content-Type", kind);
    rq.respond(guarded(r));
}

fn reply_json(rq: Request, code: u16, v: &Value) {
    reply(rq, code, "application/json", v.to_string());
}

fn param<'a>(q: &'a [(String, String)], k: &str) -> Option<&'a str> {
    q.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str())
}

fn num(q: &[(String, String)], k: &str) -> Option<f64> {
    param(q, k)
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| v.is_finite())
}

/// Checks (and renews) the page's lease; `Err` names who holds the scope.
fn attach(sh: &mut Shared, token: &str, addr: &str, takeover: bool) -> Result<(), String> {
    if token.is_empty() {
        return Err("the request carries no page session (x-scope-session)".into());
    }
    let now = Instant::now();
    match &mut sh.session {
        Some(s) if s.token == token => {
            s.last_seen = now;
            return Ok(());
        }
        Some(s) if !takeover && now.duration_since(s.last_seen) < LEASE => {
            let since = s
                .since
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs())
                .unwrap_or(0);
            return Err(format!(
                "another page (from {}) has been watching this scope since {} (unix time); one \
                 page at a time: close it, or take over",
                s.addr, since
            ));
        }
        _ => {}
    }
    let previous = sh.session.as_ref().map(|s| s.addr.clone());
    sh.session = Some(Session {
        token: token.to_string(),
        addr: addr.to_string(),
        since: std::time::SystemTime::now(),
        last_seen: now,
    });
    match previous {
        Some(p) => eprintln!("feedloop scope: a page from {addr} took over from {p}"),
        None => eprintln!("feedloop scope: a page from {addr} attached"),
    }
    Ok(())
}

/// The address of the request's peer, `IP:PORT`.
fn peer(rq: &Request) -> String {
    rq.peer().to_string()
}

/// Answers one request: screened first ([`super::guard`]: Host, token, Origin, read-only; every
/// refusal logged with the peer's address), then the page's files and the stats need no
/// session, the rest of the API the page's.
fn handle(ctx: &Ctx, rq: Request) {
    let url = rq.url().to_string();
    let path = url.split('?').next().unwrap_or("").to_string();
    let peer = peer(&rq);
    let screened = {
        let headers: Vec<(&str, &str)> = rq
            .headers()
            .iter()
            .map(|(k, v)| (k.as_str(), v.as_str()))
            .collect();
        ctx.guard.screen(rq.method(), &url, &headers)
    };
    if let Err(r) = screened {
        eprintln!(
            "feedloop scope: refused {} {} from {peer}: {} {}",
            rq.method(),
            super::guard::shown(&path),
            r.code,
            r.reason
        );
        return reply_json(rq, r.code, &json!({"error": r.reason, "refused": r.code}));
    }
    let q = query(&url);
    let Some(rq) = open_route(ctx, rq, &path) else {
        return;
    };
    let Some((rq, body)) = admit(ctx, rq, &path) else {
        return;
    };
    api(ctx, rq, &path, &q, &body, &peer);
}

/// Answers the page's files, the stats and a path outside the API; hands back any other request.
fn open_route(ctx: &Ctx, rq: Request, path: &str) -> Option<Request> {
    match (rq.method(), path) {
        ("GET", "/") | ("GET", "/index.html") => {
            reply(rq, 200, "text/html; charset=utf-8", INDEX.to_string())
        }
        ("GET", "/scope.js") => reply(
            rq,
            200,
            "text/javascript; charset=utf-8",
            SCRIPT.to_string(),
        ),
        ("GET", "/scope.css") => reply(rq, 200, "text/css; charset=utf-8", STYLE.to_string()),
        ("GET", "/api/stats") => {
            // for benchmarks and scripts: the token, but no page session needed; nothing changes
            let sh = ctx.lock();
            let v = json!({
                "views_served": ctx.views.load(Ordering::Relaxed),
                "lost_blocks": sh.store.lost_blocks[0] + sh.store.lost_blocks[1],
                "newest_cycle": sh.store.newest,
                "running": sh.running,
            });
            drop(sh);
            reply_json(rq, 200, &v)
        }
        (_, p) if !p.starts_with("/api/") => {
            reply_json(rq, 404, &json!({"error": format!("no page at {p}")}))
        }
        _ => return Some(rq),
    }
    None
}

/// Attaches the request's page session (or refuses a second page) and reads a POST's body;
/// hands back the request with its body, or `None` after answering an error.
fn admit(ctx: &Ctx, mut rq: Request, path: &str) -> Option<(Request, String)> {
    let token = rq.header("x-scope-session").unwrap_or_default().to_string();
    let addr = peer(&rq);
    let takeover = path == "/api/takeover";
    if let Err(e) = attach(&mut ctx.lock(), &token, &addr, takeover) {
        if !takeover {
            eprintln!("feedloop scope: refused a second page from {addr}");
        }
        reply_json(rq, 409, &json!({"error": e, "busy": true}));
        return None;
    }
    // the server took the body (at most MAX_UPLOAD: a longer one was refused before it came)
    let mut body = String::new();
    if rq.method() == "POST" {
        match String::from_utf8(rq.take_body()) {
            Ok(b) => body = b,
            Err(_) => {
                let e = "reading the request: stream did not contain valid UTF-8";
                reply_json(rq, 400, &json!({ "error": e }));
                return None;
            }
        }
    }
    Some((rq, body))
}

/// Answers an API request of the attached page (at `peer`).
fn api(ctx: &Ctx, rq: Request, path: &str, q: &[(String, String)], body: &str, peer: &str) {
    let name = rq
        .header("x-trace-name")
        .map(str::to_string)
        .unwrap_or_else(|| "uploaded.csv".into());
    let out: Result<Value> = match path {
        "/api/takeover" => Ok(json!({"ok": true})),
        "/api/state" => Ok(state(ctx)),
        "/api/view" if param(q, "fmt") == Some("bin") => {
            ctx.views.fetch_add(1, Ordering::Relaxed);
            return reply_view_bin(ctx, rq, q);
        }
        "/api/view" => {
            ctx.views.fetch_add(1, Ordering::Relaxed);
            view(ctx, q)
        }
        "/api/trigger" => arm(ctx, body),
        "/api/trigger/cancel" => {
            let mut sh = ctx.lock();
            sh.store.trigger = None;
            Ok(json!({"ok": true}))
        }
        "/api/swap" => serde_json::from_str::<Value>(body)
            .map_err(|e| anyhow!("the swap request is not JSON: {e}"))
            .and_then(|b| super::page_swap(ctx, &b, peer))
            .and_then(|a| Ok(serde_json::to_value(a)?)),
        "/api/capture/save" => {
            let cap = ctx.lock().capture.clone();
            match cap {
                Some(c) => {
                    super::save_capture(ctx, &c).map(|p| json!({"path": p.display().to_string()}))
                }
                None => Err(anyhow!("no capture yet: arm a trigger first")),
            }
        }
        "/api/capture.csv" => return reply_capture_csv(ctx, rq),
        "/api/open" => open_upload(ctx, &name, body),
        "/api/trace" => open_listed(ctx, q),
        p => Err(anyhow!("no API at {p}")),
    };
    match out {
        Ok(v) => reply_json(rq, 200, &v),
        Err(e) => reply_json(rq, 400, &json!({"error": format!("{e:#}")})),
    }
}

/// `/api/view?fmt=bin`: the view as bytes.
fn reply_view_bin(ctx: &Ctx, rq: Request, q: &[(String, String)]) {
    match view_bin(ctx, q) {
        Ok(bytes) => {
            let r =
                Response::new(200, bytes).with_header("Content-Type", "application/octet-stream");
            rq.respond(guarded(r));
        }
        Err(e) => reply_json(rq, 400, &json!({"error": format!("{e:#}")})),
    }
}

/// `/api/capture.csv`: the capture as a trace file.
fn reply_capture_csv(ctx: &Ctx, rq: Request) {
    let cap = ctx.lock().capture.clone();
    let Some(c) = cap else {
        return reply_json(rq, 404, &json!({"error": "no capture yet"}));
    };
    let text = super::capture_trace(
        &c,
        std::path::Path::new("capture.csv"),
        ctx.instance.as_deref(),
    )
    .and_then(|t| {
        let v = t.write_to(Vec::new())?;
        Ok(String::from_utf8_lossy(&v).into_owned())
    });
    match text {
        Ok(t) => reply(rq, 200, "text/csv", t),
        Err(e) => reply_json(rq, 500, &json!({"error": format!("{e:#}")})),
    }
}

fn columns_json(s: &Store) -> Value {
    Value::Array(
        s.columns
            .iter()
            .zip(&s.units)
            .map(|(c, u)| {
                let what = c
                    .rsplit('.')
                    .next()
                    .and_then(|sig| AXIS_SIGNALS.iter().find(|(n, _, _)| *n == sig))
                    .map(|(_, _, w)| *w)
                    .unwrap_or(if c == LATENCY {
                        "round trip: sample published -> command received"
                    } else {
                        ""
                    });
                json!({"name": c, "unit": u, "what": what})
            })
            .collect(),
    )
}

fn span_json(s: &Store) -> Value {
    s.span_s().map_or(Value::Null, |(a, b)| json!([a, b]))
}

/// Everything the page shows besides the curves.
fn state(ctx: &Ctx) -> Value {
    let mut sh = ctx.lock();
    if let Some(c) = sh.store.capture.take() {
        let view = super::capture_trace(&c, std::path::Path::new("capture"), None)
            .map(|t| Store::from_trace(&t))
            .ok();
        sh.capture_view = view;
        sh.capture = Some(c);
    }
    let s = &sh.store;
    let h = &s.latency;
    let q = |p: f64| {
        if h.is_empty() {
            Value::Null
        } else {
            json!(h.value_at_quantile(p) as f64 * 1e-3)
        }
    };
    // log-spaced bins from 0.25 us to 16 ms
    let edges: Vec<f64> = (0..=64)
        .map(|i| 250.0 * 2f64.powf(i as f64 / 4.0))
        .collect();
    let bins: Vec<Value> = edges
        .windows(2)
        .map(|w| {
            json!([
                w[0] * 1e-3,
                w[1] * 1e-3,
                h.count_between(w[0] as u64, w[1] as u64 - 1)
            ])
        })
        .collect();
    // the counts over the cycles the ring holds, as of the cycle of the loop's status when there
    // is one (so that they end where its figures since the start end): the page's "in the last N s"
    let end = sh.status.as_ref().map_or(u64::MAX, |st| st.cycle);
    let (counts, cycles) = s.window_before(end);
    let window_counts: serde_json::Map<String, Value> = EVENT_KINDS
        .iter()
        .zip(counts)
        .map(|(k, n)| (k.to_string(), json!(n)))
        .collect();
    let window = match s.oldest() {
        Some(first) if s.live && cycles > 0 => json!({
            "first_cycle": first, "end_cycle": first + cycles, "cycles": cycles,
            "seconds": cycles as f64 * s.period_s, "counts": window_counts}),
        _ => Value::Null,
    };
    let trig = s
        .trigger
        .as_ref()
        .map(|t| json!({"describe": t.describe, "pre_s": t.pre_s, "post_s": t.post_s}));
    let cap = sh.capture.as_ref().map(|c| {
        json!({"describe": c.describe, "trigger_t_s": c.trigger_t_s, "first_t_s": c.first_cycle as f64 * c.period_s,
               "cycles": c.data.first().map_or(0, Vec::len), "held_cells": c.held_cells,
               "events": c.events})
    });
    let events: Vec<&store::Event> = s.events.iter().rev().take(1000).collect();
    json!({
        "mode": if ctx.instance.is_some() { "live" } else { "trace" },
        "read_only": ctx.guard.read_only,
        "instance": ctx.instance,
        "connection": sh.connection,
        "running": sh.running,
        "runs": sh.runs,
        "period_s": s.period_s,
        "axes": s.axes,
        "columns": columns_json(s),
        "span_s": span_json(s),
        "events": events,
        "event_kinds": EVENT_KINDS,
        "window": window,
        "lost": {"plant_cycles": s.lost_plant, "scheduler_cycles": s.lost_sched,
                 "scope_blocks": s.lost_blocks[0] + s.lost_blocks[1],
                 "recorder_dropped": s.ring_dropped, "bad_blocks": sh.bad_blocks},
        "latency": {"count": h.len(), "p50_us": q(0.5), "p99_us": q(0.99), "p999_us": q(0.999),
                    "max_us": if h.is_empty() { Value::Null } else { json!(h.max() as f64 * 1e-3) },
                    "missed_cycles": s.missed_cycles, "bins": bins},
        "status": sh.status,
        "answers": sh.answers,
        "trigger": trig,
        "capture": cap,
        "capture_view": sh.capture_view.as_ref().map(|v| json!({"columns": columns_json(v), "span_s": span_json(v)})),
        "traces": sh.traces.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
    })
}

/// The envelopes of one view: its time span and, per signal, name, unit and min/max per column.
type Envelopes = (f64, f64, Vec<(String, String, Vec<Option<(f64, f64)>>)>);

/// Min/max envelopes of the asked signals over `cols` pixel columns.
fn envelopes(ctx: &Ctx, q: &[(String, String)]) -> Result<Option<Envelopes>> {
    let sh = ctx.lock();
    let src = param(q, "src").unwrap_or("live");
    let s = match src {
        "live" => &sh.store,
        "capture" => sh
            .capture_view
            .as_ref()
            .ok_or_else(|| anyhow!("no capture to show"))?,
        o => bail!("src `{o}`: live or capture"),
    };
    let cols = num(q, "cols").unwrap_or(800.0).clamp(1.0, MAX_COLS as f64) as usize;
    let Some(span) = s.span_s() else {
        return Ok(None);
    };
    let t1 = num(q, "t1").unwrap_or(span.1);
    let t0 = num(q, "t0").unwrap_or_else(|| t1 - num(q, "span").unwrap_or(1.0));
    let series = param(q, "sig")
        .unwrap_or("")
        .split(',')
        .filter_map(|name| {
            let c = s.column(name)?;
            Some((
                name.to_string(),
                s.units[c].clone(),
                s.envelope(c, t0, t1, cols),
            ))
        })
        .collect();
    Ok(Some((t0, t1, series)))
}

/// The envelopes as JSON: `{"t0", "t1", "series": [{"name", "unit", "lo": [...], "hi": [...]}]}`
/// (null where a column holds no cycle).
fn view(ctx: &Ctx, q: &[(String, String)]) -> Result<Value> {
    let Some((t0, t1, series)) = envelopes(ctx, q)? else {
        return Ok(json!({"t0": null, "t1": null, "series": []}));
    };
    let series: Vec<Value> = series
        .into_iter()
        .map(|(name, unit, env)| {
            let side = |pick: fn(&(f64, f64)) -> f64| -> Vec<Value> {
                env.iter()
                    .map(|e| e.as_ref().map_or(Value::Null, |e| json!(pick(e))))
                    .collect()
            };
            json!({"name": name, "unit": unit, "lo": side(|e| e.0), "hi": side(|e| e.1)})
        })
        .collect();
    Ok(json!({"t0": t0, "t1": t1, "series": series}))
}

/// The envelopes in the page's binary form: `u32` length of a JSON head (`t0`, `t1`, `cols`,
/// and per series `name`, `unit`, `offset`), the head padded with spaces to 4 bytes, then per
/// series `cols` minima and `cols` maxima as little-endian f32 of (value - offset), NaN where
/// a column holds no cycle. The offset (the series' first value) keeps f32's seven digits for
/// the detail, not for a large position.
fn view_bin(ctx: &Ctx, q: &[(String, String)]) -> Result<Vec<u8>> {
    let (t0, t1, series) = envelopes(ctx, q)?.unwrap_or((0.0, 0.0, Vec::new()));
    let cols = series.first().map_or(0, |s| s.2.len());
    let offsets: Vec<f64> = series
        .iter()
        .map(|s| s.2.iter().flatten().next().map_or(0.0, |e| e.0))
        .collect();
    let head = json!({
        "t0": t0, "t1": t1, "cols": cols,
        "series": series.iter().zip(&offsets)
            .map(|(s, o)| json!({"name": s.0, "unit": s.1, "offset": o}))
            .collect::<Vec<_>>(),
    })
    .to_string();
    let mut out = Vec::with_capacity(8 + head.len() + series.len() * cols * 8);
    let pad = (4 - head.len() % 4) % 4;
    out.extend_from_slice(&((head.len() + pad) as u32).to_le_bytes());
    out.extend_from_slice(head.as_bytes());
    out.extend(std::iter::repeat_n(b' ', pad));
    for ((_, _, env), off) in series.iter().zip(&offsets) {
        for pick in [|e: &(f64, f64)| e.0, |e: &(f64, f64)| e.1] {
            for e in env {
                let v = e.as_ref().map_or(f32::NAN, |e| (pick(e) - off) as f32);
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    Ok(out)
}

/// Arms a trigger from the page's JSON.
fn arm(ctx: &Ctx, body: &str) -> Result<Value> {
    let b: Value = serde_json::from_str(body).map_err(|e| anyhow!("trigger: not JSON: {e}"))?;
    let f = |k: &str, d: f64| -> Result<f64> {
        match b.get(k) {
            None | Some(Value::Null) => Ok(d),
            Some(v) => v
                .as_f64()
                .filter(|v| v.is_finite() && *v >= 0.0)
                .ok_or_else(|| anyhow!("trigger `{k}`: a number of seconds >= 0, got {v}")),
        }
    };
    let (pre_s, post_s) = (f("pre_s", 0.05)?, f("post_s", 0.1)?);
    let mut sh = ctx.lock();
    let limit = ctx.history_s / 2.0;
    if pre_s > limit || post_s > limit {
        bail!(
            "trigger: pre_s and post_s must be at most half the history ({limit} s; --history-s)"
        );
    }
    let kind = b.get("kind").and_then(Value::as_str).unwrap_or("");
    let (condition, describe) = match kind {
        "event" => {
            let e = b.get("event").and_then(Value::as_str).unwrap_or("");
            let Some(k) = EVENT_KINDS.iter().find(|k| **k == e) else {
                bail!("trigger event `{e}`: one of {}", EVENT_KINDS.join(", "));
            };
            (Condition::Event(k), format!("event {k}"))
        }
        "level" => {
            let name = b.get("signal").and_then(Value::as_str).unwrap_or("");
            let column = sh.store.column(name).ok_or_else(|| {
                anyhow!(
                    "trigger signal `{name}`: one of {}",
                    sh.store.columns.join(", ")
                )
            })?;
            let level = b
                .get("level")
                .and_then(Value::as_f64)
                .filter(|v| v.is_finite())
                .ok_or_else(|| anyhow!("trigger `level`: a finite number in the signal's unit"))?;
            let edge = b.get("edge").and_then(Value::as_str).unwrap_or("rising");
            let rising = match edge {
                "rising" => true,
                "falling" => false,
                o => bail!("trigger edge `{o}`: rising or falling"),
            };
            let unit = &sh.store.units[column];
            (
                Condition::Level {
                    column,
                    level,
                    rising,
                },
                format!("{name} {edge} through {level} {unit}"),
            )
        }
        o => bail!("trigger kind `{o}`: level or event"),
    };
    sh.store.trigger = Some(Trigger {
        condition,
        pre_s,
        post_s,
        describe: describe.clone(),
    });
    drop(sh);
    eprintln!("feedloop scope: trigger armed: {describe}");
    Ok(json!({"armed": describe}))
}

/// A trace uploaded from the page, shown as the capture view.
fn open_upload(ctx: &Ctx, name: &str, text: &str) -> Result<Value> {
    let tr = feedloop_trace::Trace::parse(std::path::Path::new(name), text)?;
    let view = Store::from_trace(&tr);
    let mut sh = ctx.lock();
    let rows = tr.len();
    sh.capture_view = Some(view);
    Ok(json!({"opened": name, "rows": rows}))
}

/// One of the listed traces (`--trace`, `--report`) as the main view.
fn open_listed(ctx: &Ctx, q: &[(String, String)]) -> Result<Value> {
    let i = num(q, "i").map(|v| v as usize);
    let sh = ctx.lock();
    let Some(p) = i.and_then(|i| sh.traces.get(i)).cloned() else {
        bail!(
            "trace `i`: an index into the list of {} traces",
            sh.traces.len()
        );
    };
    if ctx.instance.is_some() {
        bail!("a live scope shows its loop; open recordings with --trace or --report");
    }
    drop(sh);
    let tr = super::read_trace(&p)?;
    let mut sh = ctx.lock();
    sh.store = Store::from_trace(&tr);
    sh.connection = format!("trace {}", p.display());
    Ok(json!({"opened": p.display().to_string(), "rows": tr.len()}))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn query_values_are_unescaped() {
        let q = query("/api/view?sig=x.load%2Cy.load&t0=-1.5&n=a+b&bad=%zz");
        assert_eq!(param(&q, "sig"), Some("x.load,y.load"));
        assert_eq!(num(&q, "t0"), Some(-1.5));
        assert_eq!(param(&q, "n"), Some("a b"));
        assert_eq!(param(&q, "bad"), Some("%zz"));
    }
}
