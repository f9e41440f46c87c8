//! The scope's request handling, driven over loopback like anyone on the network would
//! ([`feedloop_cli::scope_sandbox`]): random but well-formed-ish requests (methods, paths, queries
//! with percent escapes, headers, JSON bodies of the wrong types, huge numbers and NaN-like
//! strings) each get a well-formed answer, with a reason whenever they are refused; and the
//! fuzz campaign's seeds and the inputs it ever crashed on (`fuzz/seeds/scope_request`,
//! `fuzz/regressions/scope_request`) are answered so too, the two that found defects of the
//! former HTTP server (tiny_http 0.12) with the answers they must get.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::time::Duration;

use feedloop_cli::scope_sandbox::{judge, judge_all, known_defect, Reply, Sandbox};
use proptest::prelude::*;
use serde_json::{json, Value};

fn ask(sb: &Sandbox, raw: &[u8]) -> Option<Reply> {
    sb.reset();
    let answer = sb.ask(raw).expect("the scope answers in time");
    judge(&answer).unwrap_or_else(|e| panic!("{e}\nrequest: {}", String::from_utf8_lossy(raw)))
}

/// A request's bytes: `method path HTTP/1.1`, the headers, a `Content-Length` and the body.
fn request(method: &str, target: &str, headers: &[(String, String)], body: &[u8]) -> Vec<u8> {
    let mut r = format!("{method} {target} HTTP/1.1\r\nHost: {{host}}\r\n");
    for (k, v) in headers {
        r += &format!("{k}: {v}\r\n");
    }
    r += &format!("Content-Length: {}\r\n\r\n", body.len());
    let mut r = r.into_bytes();
    r.extend_from_slice(body);
    r
}

fn percent_escaped(s: &str) -> String {
    s.bytes().map(|b| format!("%{b:02X}")).collect()
}

fn number_text() -> impl Strategy<Value = String> {
    prop_oneof![
        (-1e4..1e4f64).prop_map(|v| v.to_string()),
        Just("1e308".to_string()),
        Just("-1e999".to_string()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("-0".to_string()),
        Just("18446744073709551617".to_string()),
        Just("0x10".to_string()),
        Just(String::new()),
    ]
}

fn word() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("x.cmd".to_string()),
        Just("x.load,y.load".to_string()),
        Just("latency_us".to_string()),
        Just("live".to_string()),
        Just("capture".to_string()),
        Just("bin".to_string()),
        "[a-z.,_%+=&?#/-]{0,12}",
    ]
}

/// A query value: a number, a name, raw or percent-escaped, or a broken escape.
fn query_value() -> impl Strategy<Value = String> {
    prop_oneof![
        number_text(),
        word(),
        prop_oneof![word(), "\\PC{0,8}"].prop_map(|w| percent_escaped(&w)),
        Just("%".to_string()),
        Just("%zz%4".to_string()),
        Just("%e2%82".to_string()),
        Just("a+b%20c".to_string()),
    ]
}

fn query() -> impl Strategy<Value = String> {
    let key = prop_oneof![
        Just("sig"),
        Just("t0"),
        Just("t1"),
        Just("span"),
        Just("cols"),
        Just("src"),
        Just("fmt"),
        Just("i"),
        Just("token"),
        Just(""),
    ];
    proptest::collection::vec((key, query_value()), 0..6).prop_map(|kv| {
        kv.iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join("&")
    })
}

fn path() -> impl Strategy<Value = String> {
    prop_oneof![
        8 => prop_oneof![
            Just("/"), Just("/index.html"), Just("/scope.js"), Just("/scope.css"),
            Just("/api/stats"), Just("/api/state"), Just("/api/view"), Just("/api/trigger"),
            Just("/api/trigger/cancel"), Just("/api/swap"), Just("/api/capture/save"),
            Just("/api/capture.csv"), Just("/api/open"), Just("/api/trace"), Just("/api/takeover"),
        ].prop_map(str::to_string),
        1 => "/[a-z/.%]{0,16}",
        1 => "/api/[a-zA-Z0-9/._%-]{0,12}",
    ]
}

/// A JSON value of any type, numbers that do not fit, NaN-like strings.
fn json_value() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::from),
        (-1e6..1e6f64).prop_map(Value::from),
        any::<i64>().prop_map(Value::from),
        Just(json!(1e308)),
        Just(json!(u64::MAX)),
        prop_oneof![
            Just("NaN"),
            Just("Infinity"),
            Just("-inf"),
            Just("1e999"),
            Just("")
        ]
        .prop_map(Value::from),
        word().prop_map(Value::from),
    ];
    leaf.prop_recursive(2, 8, 3, |inner| {
        prop_oneof![
            proptest::collection::vec(inner.clone(), 0..3).prop_map(Value::from),
            proptest::collection::btree_map("[a-z_]{1,6}", inner, 0..3)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

/// A body the API reads: an object of its keys with plausible or wrong values, JSON of another
/// shape, text that is not JSON, or a small trace.
fn body() -> impl Strategy<Value = Vec<u8>> {
    let key = prop_oneof![
        Just("kind"),
        Just("event"),
        Just("signal"),
        Just("level"),
        Just("edge"),
        Just("pre_s"),
        Just("post_s"),
        Just("axis"),
        Just("stage"),
        Just("plugin"),
        Just("params"),
        Just("force"),
    ];
    let plausible = prop_oneof![
        Just(json!("level")),
        Just(json!("event")),
        Just(json!("swap")),
        Just(json!("x.cmd")),
        Just(json!("falling")),
        Just(json!(0.01)),
        Just(json!("velocity")),
        Just(json!("kv_nms_per_rad = 4.0")),
        Just(json!("kv_nms_per_rad = [")),
    ];
    let value = prop_oneof![plausible, json_value()];
    prop_oneof![
        4 => proptest::collection::vec((key, value), 0..6).prop_map(|kv| {
            let m: serde_json::Map<String, Value> =
                kv.into_iter().map(|(k, v)| (k.to_string(), v)).collect();
            Value::Object(m).to_string().into_bytes()
        }),
        1 => json_value().prop_map(|v| v.to_string().into_bytes()),
        1 => proptest::collection::vec(any::<u8>(), 0..64),
        1 => Just(b"# feedloop-trace v1\nt,x.cmd,x.load\n0,0,0\n0.001,1,1\n".to_vec()),
    ]
}

fn headers() -> impl Strategy<Value = Vec<(String, String)>> {
    let session = prop_oneof![
        3 => Just(Some("page-one".to_string())),
        1 => Just(Some(String::new())),
        1 => Just(None),
    ];
    let other = proptest::collection::vec(
        (
            prop_oneof![
                Just("x-trace-name".to_string()),
                Just("Content-Type".to_string()),
                Just("Origin".to_string()),
                Just("x-scope-token".to_string()),
                "[A-Za-z-]{1,10}",
            ],
            "[ -~]{0,20}",
        ),
        0..3,
    );
    let token = prop_oneof![
        4 => Just(Some("{token}".to_string())),
        1 => Just(Some("not-the-token".to_string())),
        1 => Just(None),
    ];
    (session, token, other).prop_map(|(s, t, mut h)| {
        if let Some(s) = s {
            h.push(("x-scope-session".into(), s));
        }
        if let Some(t) = t {
            h.push(("x-scope-token".into(), t));
        }
        h
    })
}

fn method() -> impl Strategy<Value = String> {
    prop_oneof![
        4 => Just("GET".to_string()),
        4 => Just("POST".to_string()),
        1 => prop_oneof![Just("PUT"), Just("DELETE"), Just("OPTIONS"), Just("PATCH")]
            .prop_map(str::to_string),
        1 => "[A-Z]{1,7}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn every_request_gets_a_well_formed_answer_with_a_reason_when_refused(
        m in method(),
        p in path(),
        q in query(),
        h in headers(),
        b in body(),
    ) {
        thread_local!(static SB: Sandbox = Sandbox::start().expect("the sandboxed scope starts"));
        let target = if q.is_empty() { p.clone() } else { format!("{p}?{q}") };
        let raw = request(&m, &target, &h, &b);
        let reply = SB.with(|sb| ask(sb, &raw));
        let reply = reply.unwrap_or_else(|| panic!("no answer to {target}"));
        let session = h.iter().any(|(k, v)| k == "x-scope-session" && !v.is_empty());
        let page_file = ["/", "/index.html", "/scope.js", "/scope.css", "/api/stats"];
        if !p.starts_with("/api/") && !page_file.contains(&p.as_str()) {
            prop_assert_eq!(reply.code, 404, "{}", target);
        }
        let tokens: Vec<&String> = h
            .iter()
            .filter(|(k, _)| k.eq_ignore_ascii_case("x-scope-token"))
            .map(|(_, v)| v)
            .collect();
        let token = tokens.len() == 1 && tokens[0] == "{token}";
        if p.starts_with("/api/") && !token {
            // no token, another one, or a method the path does not take
            prop_assert!([401, 403, 405].contains(&reply.code), "{} {}: {}", m, target, reply.code);
        }
        if p.starts_with("/api/") && p != "/api/stats" && token && !session {
            // no page session, a foreign origin or a method the path does not take
            prop_assert!([403, 405, 409].contains(&reply.code), "{} {}: {}", m, target, reply.code);
        }
    }
}

/// The files of `fuzz/<kind>/scope_request`.
#[test]
fn the_fuzz_seeds_and_regressions_are_answered_well() {
    let sb = Sandbox::start().unwrap();
    let seeds = feedloop_test_support::fuzz_inputs("seeds", "scope_request");
    assert!(seeds.len() >= 10, "seeds: {seeds:?}");
    for f in seeds.iter().chain(&feedloop_test_support::fuzz_inputs(
        "regressions",
        "scope_request",
    )) {
        let raw = std::fs::read(f).unwrap();
        let reply = ask(&sb, &raw);
        assert!(reply.is_some(), "{}: no answer", f.display());
    }
}

#[test]
fn the_page_session_views_and_triggers_work_in_the_sandbox() {
    let sb = Sandbox::start().unwrap();
    let s = [
        ("x-scope-session".to_string(), "p".to_string()),
        ("x-scope-token".to_string(), "{token}".to_string()),
    ];
    let get = |target: &str| ask(&sb, &request("GET", target, &s, b"")).unwrap();
    let json = |r: &Reply| serde_json::from_slice::<Value>(&r.body).unwrap();
    let state = get("/api/state");
    assert_eq!(state.code, 200);
    assert_eq!(json(&state)["axes"], json!(["x", "y"]));
    let view = get("/api/view?sig=x.cmd%2Cy.load&t0=0&t1=1.999&cols=10");
    assert_eq!(view.code, 200);
    let v = json(&view);
    assert_eq!(v["series"].as_array().unwrap().len(), 2);
    assert_eq!(v["series"][0]["lo"].as_array().unwrap().len(), 10);
    let refused = ask(
        &sb,
        &request(
            "POST",
            "/api/trigger",
            &s,
            br#"{"kind":"level","signal":"x.cmd","level":"NaN"}"#,
        ),
    )
    .unwrap();
    assert_eq!(refused.code, 400);
    assert!(json(&refused)["error"].as_str().unwrap().contains("level"));
    let swap = ask(&sb, &request("POST", "/api/swap", &s, b"{}")).unwrap();
    assert_eq!(swap.code, 400);
    assert!(json(&swap)["error"]
        .as_str()
        .unwrap()
        .contains("recordings"));
}

/// The regression inputs whose name starts with `prefix`.
fn regressions(prefix: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let found: Vec<_> = feedloop_test_support::fuzz_inputs("regressions", "scope_request")
        .into_iter()
        .filter(|f| f.file_name().unwrap().to_string_lossy().starts_with(prefix))
        .map(|f| {
            let raw = std::fs::read(&f).unwrap();
            (f, raw)
        })
        .collect();
    assert!(!found.is_empty(), "no regressions/scope_request/{prefix}*");
    found
}

#[test]
fn the_fuzz_target_passes_over_no_seed_or_regression() {
    for f in feedloop_test_support::fuzz_inputs("seeds", "scope_request")
        .iter()
        .chain(&feedloop_test_support::fuzz_inputs(
            "regressions",
            "scope_request",
        ))
    {
        assert_eq!(
            known_defect(&std::fs::read(f).unwrap()),
            None,
            "{}",
            f.display()
        );
    }
}

/// Found by the fuzz campaign: tiny_http 0.12 allocated the unread rest of a body at once when
/// the request was dropped, and a `Content-Length` beyond the machine's memory aborted the whole
/// scope. The body is refused (413) before any of it is read, and the scope answers on.
#[test]
fn a_content_length_beyond_memory_is_refused_and_the_scope_answers_on() {
    let sb = Sandbox::start().unwrap();
    for (f, raw) in regressions("huge-content-length") {
        let reply = ask(&sb, &raw);
        assert_eq!(reply.as_ref().map(|r| r.code), Some(413), "{}", f.display());
        let body: Value = serde_json::from_slice(&reply.unwrap().body).unwrap();
        assert!(body["error"].as_str().unwrap().contains("MB"), "{body}");
        let token = [("x-scope-token".to_string(), "{token}".to_string())];
        let stats = request("GET", "/api/stats", &token, b"");
        let stats = ask(&sb, &stats).map(|r| r.code);
        assert_eq!(stats, Some(200), "{}", f.display());
    }
    // with the scope's token and a page session too: refused before the body
    let big = [
        ("x-scope-token".to_string(), "{token}".to_string()),
        ("x-scope-session".to_string(), "p".to_string()),
    ];
    let mut raw = request("POST", "/api/open", &big, b"");
    let at = raw
        .windows(17)
        .position(|w| w == b"Content-Length: 0")
        .unwrap();
    raw.splice(at + 16..at + 17, b"536870913".iter().copied());
    assert_eq!(ask(&sb, &raw).map(|r| r.code), Some(413));
}

/// Found by the fuzz campaign: a request line of HTTP/2.0 or HTTP/3.0 was never answered, and
/// tiny_http kept its connection open after the client finished sending. It gets 505 and the
/// connection is closed, after the answers to the requests before it on the connection.
#[test]
fn a_request_of_another_http_version_is_refused_and_closed() {
    let sb = Sandbox::start().unwrap();
    for (f, raw) in regressions("hang") {
        let answer = sb
            .ask(&raw)
            .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        let codes: Vec<u16> = judge_all(&answer)
            .unwrap_or_else(|e| panic!("{}: {e}", f.display()))
            .iter()
            .map(|r| r.code)
            .collect();
        assert_eq!(codes.len(), 2, "{}: {codes:?}", f.display());
        assert_eq!(codes[1], 505, "{}: {codes:?}", f.display());
    }
    // without closing the sending side: the scope closes the connection itself
    let host = sb.host();
    let mut s = TcpStream::connect(&host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let raw =
        format!("GET /api/stats HTTP/3.0\r\nHost: {host}\r\nx-scope-token: sandbox-token\r\n\r\n");
    s.write_all(raw.as_bytes()).unwrap();
    let mut answer = Vec::new();
    s.read_to_end(&mut answer)
        .expect("the scope closes the connection");
    let reply = judge(&answer).unwrap().unwrap();
    assert_eq!(reply.code, 505);
    assert_eq!(reply.header("connection"), Some("close"));
}

/// Requests one after the other on one connection, sent at once or waiting for each answer,
/// are answered in order; `Connection: close` ends the connection after its answer.
#[test]
fn requests_on_one_connection_are_answered_in_order() {
    let sb = Sandbox::start().unwrap();
    let host = sb.host();
    let get = |path: &str, last: bool| {
        let close = if last { "Connection: close\r\n" } else { "" };
        format!(
            "GET {path} HTTP/1.1\r\nHost: {host}\r\nx-scope-token: sandbox-token\r\n{close}\r\n"
        )
    };
    let piped = get("/api/stats", false) + &get("/nothing", false) + &get("/api/stats", true);
    let mut s = TcpStream::connect(&host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(piped.as_bytes()).unwrap();
    let mut answer = Vec::new();
    s.read_to_end(&mut answer)
        .expect("closed after the last answer");
    let codes: Vec<u16> = judge_all(&answer).unwrap().iter().map(|r| r.code).collect();
    assert_eq!(codes, [200, 404, 200]);
    let mut s = TcpStream::connect(&host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    for _ in 0..3 {
        s.write_all(get("/api/stats", false).as_bytes()).unwrap();
        let mut buf = [0u8; 4096];
        let n = s.read(&mut buf).unwrap();
        assert_eq!(judge(&buf[..n]).unwrap().unwrap().code, 200);
    }
}
