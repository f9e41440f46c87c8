//! Who `feedloop scope` answers (issue 31), with plain HTTP requests against a running scope: a
//! foreign `Host` is refused (DNS rebinding), the API needs the launch token the scope printed,
//! a change sent from another site (`Origin`) is refused even with the token, `--read-only`
//! refuses swaps and retunes and still watches and triggers, no answer allows another origin to
//! read it (CORS), every refusal is logged with the peer's address, and every swap applied to
//! the loop says where it came from (the scope page or the command line) in `feedloop status`
//! and the run's `summary.json`.

mod scope_common;

use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use scope_common::{
    bin, long_job, request, scratch, start_run, start_scope, status, stop, Reply, Scope,
};

/// One realtime loop at a time from this file: they share two cores with everything else.
static LOOPS: Mutex<()> = Mutex::new(());

fn no_cors(r: &Reply) {
    assert!(
        r.headers
            .iter()
            .all(|(k, _)| !k.starts_with("access-control-")),
        "an answer allows another origin: {r:?}"
    );
}

/// A recorded trace of 1000 rows (enough for a scope to open).
fn trace(dir: &std::path::Path) -> std::path::PathBuf {
    let mut text = String::from("# feedloop-trace v1\nt,x.cmd,x.load\n");
    for k in 0..1000 {
        let v = (k as f64 * 0.01).sin();
        text.push_str(&format!("{},{v},{}\n", k as f64 * 1e-3, v * 0.9));
    }
    let p = dir.join("t.csv");
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn the_scope_answers_its_own_host_with_its_token_only() {
    let d = scratch("scope-guard");
    let t = trace(&d);
    let mut scope = start_scope(&["--trace", t.to_str().unwrap()]);
    let (addr, token) = (scope.addr.clone(), scope.token.clone());
    assert!(token.len() >= 32, "{token}");
    let port = addr.rsplit(':').next().unwrap().to_string();

    // DNS rebinding: another name that resolves here is not answered, not even the page
    let foreign = format!("attacker.example:{port}");
    for path in ["/", "/api/state"] {
        let r = request(
            &addr,
            "GET",
            path,
            &[("Host", &foreign), ("x-scope-token", &token)],
            "",
        );
        assert_eq!(r.code, 421, "{r:?}");
        assert!(
            r.json()["error"].as_str().unwrap().contains("Host"),
            "{r:?}"
        );
        no_cors(&r);
    }
    // the page loads without the token, under each loopback name
    for host in [addr.clone(), format!("localhost:{port}")] {
        let r = request(&addr, "GET", "/", &[("Host", &host)], "");
        assert_eq!(r.code, 200, "{r:?}");
        assert!(r.body.contains("<script src=\"/scope.js\">"), "{r:?}");
        no_cors(&r);
    }
    // the API: no token, a wrong one, the right one (header or query)
    let r = request(&addr, "GET", "/api/state", &[], "");
    assert_eq!(r.code, 401, "{r:?}");
    assert!(r.json()["error"].as_str().unwrap().contains("no token"));
    // the last character changed (to 0, or to 1 where it is 0 already)
    let last = if token.ends_with('0') { "1" } else { "0" };
    let wrong = format!("{}{last}", &token[..token.len() - 1]);
    for (path, headers) in [
        ("/api/state", vec![("x-scope-token", wrong.as_str())]),
        ("/api/stats", vec![("x-scope-token", "")]),
        (&*format!("/api/state?token={wrong}"), vec![]),
    ] {
        let r = request(&addr, "GET", path, &headers, "");
        assert!(r.code == 403 || r.code == 401, "{path}: {r:?}");
        assert!(r.json()["error"].is_string(), "{r:?}");
    }
    let r = scope.api("GET", "/api/state", "p", "");
    assert_eq!(r.code, 200, "{r:?}");
    assert_eq!(r.json()["mode"], "trace");
    assert_eq!(r.json()["read_only"], false);
    let r = request(
        &addr,
        "GET",
        &format!("/api/state?token={token}"),
        &[("x-scope-session", "p")],
        "",
    );
    assert_eq!(r.code, 200, "{r:?}");
    let r = request(&addr, "GET", &format!("/api/stats?token={token}"), &[], "");
    assert_eq!(r.code, 200, "{r:?}");

    another_site_reads_and_changes_nothing(&scope);

    // each refusal is on the scope's command line with the peer's address and the reason
    scope.wait_line(
        &["refused GET /api/state from 127.0.0.1:", "421", "Host"],
        5.0,
    );
    scope.wait_line(
        &["refused GET /api/state from 127.0.0.1:", "401", "no token"],
        5.0,
    );
    scope.wait_line(&["refused GET /api/state from", "403", "wrong token"], 5.0);
    scope.wait_line(
        &["refused POST /api/trigger from", "403", "attacker.example"],
        5.0,
    );
    scope.seen.extend(scope.log.try_iter());
    assert!(
        !scope.seen.iter().any(|l| l.contains("only protection")),
        "a loopback scope warned: {:?}",
        scope.seen
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_scope_bound_beyond_loopback_warns_and_still_checks_host_and_token() {
    let d = scratch("scope-bind-any");
    let t = trace(&d);
    let mut scope = start_scope(&["--trace", t.to_str().unwrap(), "--bind", "0.0.0.0"]);
    let warning = scope.wait_line(&["warning", "token", "only protection"], 5.0);
    assert!(
        warning.contains("not encrypted") && warning.contains("ssh -L"),
        "{warning}"
    );
    let port = scope.addr.rsplit(':').next().unwrap().to_string();
    assert!(scope.addr.starts_with("0.0.0.0:"), "{}", scope.addr);
    let here = format!("127.0.0.1:{port}");
    let with_token = [
        ("x-scope-token", scope.token.as_str()),
        ("x-scope-session", "p"),
    ];
    let r = request(&here, "GET", "/api/state", &with_token, "");
    assert_eq!(r.code, 200, "{r:?}");
    let foreign = format!("attacker.example:{port}");
    let r = request(
        &here,
        "GET",
        "/api/state",
        &[with_token[0], with_token[1], ("Host", &foreign)],
        "",
    );
    assert_eq!(r.code, 421, "{r:?}");
    let r = request(&here, "GET", "/api/state", &[("x-scope-session", "p")], "");
    assert_eq!(r.code, 401, "{r:?}");
    let _ = std::fs::remove_dir_all(&d);
}

/// Another site's page, even holding the token, may read nothing (no CORS header) and change
/// nothing (`Origin`); the scope's own page may.
fn another_site_reads_and_changes_nothing(scope: &Scope) {
    let (addr, token) = (&scope.addr, &scope.token);
    // another site may read nothing (no CORS) and change nothing, token or not
    let evil = [
        ("x-scope-token", token.as_str()),
        ("x-scope-session", "p"),
        ("Origin", "http://attacker.example"),
    ];
    let r = request(addr, "GET", "/api/state", &evil, "");
    no_cors(&r);
    let arm = json!({"kind": "level", "signal": "x.load", "level": 0.5}).to_string();
    let r = request(addr, "POST", "/api/trigger", &evil, &arm);
    assert_eq!(r.code, 403, "{r:?}");
    assert!(r.json()["error"].as_str().unwrap().contains("another site"));
    no_cors(&r);
    assert_eq!(
        scope.api("GET", "/api/state", "p", "").json()["trigger"],
        Value::Null
    );
    let own = format!("http://{addr}");
    let r = request(
        addr,
        "POST",
        "/api/trigger",
        &[
            ("x-scope-token", token),
            ("x-scope-session", "p"),
            ("Origin", &own),
        ],
        &arm,
    );
    assert_eq!(r.code, 200, "{r:?}");
    assert!(scope.api("GET", "/api/state", "p", "").json()["trigger"].is_object());
}

/// The loop of `instance` running `job`, once its control service answers.
fn running_loop(d: &std::path::Path, instance: &str) -> scope_common::Proc {
    let job = long_job(d, 8.0);
    let run = start_run(&job, &d.join("run"), instance);
    status(instance, 30.0);
    run
}

/// Swap from the page: the body the page sends, with the page's own origin unless `origin` says.
fn page_swap(s: &Scope, origin: Option<&str>, kv: f64) -> Reply {
    let own = format!("http://{}", s.addr);
    let body = json!({"axis": "x", "stage": "velocity", "plugin": "pi_velocity",
                      "params": format!("kv_nms_per_rad = {kv}"), "force": false});
    request(
        &s.addr,
        "POST",
        "/api/swap",
        &[
            ("x-scope-token", &s.token),
            ("x-scope-session", "page"),
            ("Origin", origin.unwrap_or(&own)),
        ],
        &body.to_string(),
    )
}

#[test]
fn a_foreign_origin_cannot_swap_and_every_swap_says_where_it_came_from() {
    let _one = LOOPS.lock().unwrap_or_else(|p| p.into_inner());
    let d = scratch("scope-audit");
    let instance = format!("scopeaudit{}", std::process::id());
    let mut scope = start_scope(&["--instance", &instance]);
    let mut run = running_loop(&d, &instance);

    let r = page_swap(&scope, Some("http://attacker.example"), 4.5);
    assert_eq!(r.code, 403, "{r:?}");
    no_cors(&r);
    scope.wait_line(
        &["refused POST /api/swap from 127.0.0.1:", "attacker.example"],
        5.0,
    );
    assert_eq!(
        status(&instance, 5.0)["swaps"],
        0,
        "the refused swap reached the loop"
    );

    let r = page_swap(&scope, None, 4.5);
    assert_eq!(r.code, 200, "{r:?}");
    let a = r.json();
    assert_eq!(a["outcome"], "accepted", "{a}");
    scope.wait_line(&["swap from the page at 127.0.0.1:"], 5.0);

    let params = d.join("kv.toml");
    std::fs::write(&params, "kv_nms_per_rad = 4.75\n").unwrap();
    let child = Command::new(bin())
        .args([
            "swap",
            "--instance",
            &instance,
            "--axis",
            "x",
            "--stage",
            "velocity",
        ])
        .args([
            "--plugin",
            "pi_velocity",
            "--params",
            params.to_str().unwrap(),
        ])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let cli_pid = u64::from(child.id());
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
    let answered: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(answered["swap"]["origin"]["pid"], cli_pid, "{answered}");

    let st = status(&instance, 5.0);
    let recent = st["recent_swaps"].as_array().unwrap();
    assert_eq!(recent.len(), 2, "{st}");
    check_origins(recent, scope.proc.0.id(), cli_pid);
    assert_eq!(
        recent[1]["changed"],
        json!(["kv_nms_per_rad: 4.5 -> 4.75"]),
        "{st}"
    );

    stop(&mut run);
    let sum: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("run/summary.json")).unwrap())
            .unwrap();
    let swaps = sum["swaps"].as_array().unwrap();
    assert_eq!(swaps.len(), 2, "{sum}");
    check_origins(swaps, scope.proc.0.id(), cli_pid);
    assert!(swaps
        .iter()
        .all(|s| s["cycle"].as_u64().unwrap() > 0 && s["t_s"].as_f64().unwrap() > 0.0));
    drop(scope);
    let _ = std::fs::remove_dir_all(&d);
}

/// The first swap came from a page of the scope (process `scope_pid`) at a loopback address,
/// the second from `feedloop swap` (process `cli_pid`) run by this user.
fn check_origins(swaps: &[Value], scope_pid: u32, cli_pid: u64) {
    // SAFETY: getuid cannot fail.
    let uid = u64::from(unsafe { libc::getuid() });
    let (page, cli) = (&swaps[0]["origin"], &swaps[1]["origin"]);
    assert_eq!(page["via"], "scope", "{page}");
    assert!(
        page["peer"].as_str().unwrap().starts_with("127.0.0.1:"),
        "{page}"
    );
    assert_eq!(page["pid"], u64::from(scope_pid), "{page}");
    assert_eq!(cli["via"], "command_line", "{cli}");
    assert_eq!(cli["pid"], cli_pid, "{cli}");
    assert_ne!(cli_pid, u64::from(std::process::id()));
    assert_eq!(
        (page["uid"].as_u64(), cli["uid"].as_u64()),
        (Some(uid), Some(uid))
    );
    assert!(!cli["user"].as_str().unwrap().is_empty(), "{cli}");
    assert!(cli.get("peer").is_none(), "{cli}");
    // the job sets no chain parameters (the model's): the first swap sets the key
    assert_eq!(
        swaps[0]["changed"],
        json!(["kv_nms_per_rad = 4.5"]),
        "{}",
        swaps[0]
    );
}

#[test]
fn a_read_only_scope_refuses_swaps_and_retunes_and_still_watches_and_triggers() {
    let _one = LOOPS.lock().unwrap_or_else(|p| p.into_inner());
    let d = scratch("scope-read-only");
    let instance = format!("scopero{}", std::process::id());
    let mut scope = start_scope(&["--instance", &instance, "--read-only"]);
    let mut run = running_loop(&d, &instance);

    let st = scope.api("GET", "/api/state", "page", "").json();
    assert_eq!(st["read_only"], true, "{st}");
    // the scope watches: the loop's curves arrive
    let t = Instant::now();
    while !scope.api("GET", "/api/state", "page", "").json()["columns"]
        .as_array()
        .unwrap()
        .iter()
        .any(|c| c["name"] == "x.cmd")
    {
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "no curves from the loop"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    for kv in [4.5, 4.75] {
        let r = page_swap(&scope, None, kv);
        assert_eq!(r.code, 403, "{r:?}");
        assert!(
            r.json()["error"].as_str().unwrap().contains("read-only"),
            "{r:?}"
        );
    }
    scope.wait_line(
        &["refused POST /api/swap from 127.0.0.1:", "read-only"],
        5.0,
    );

    // a trigger on x.cmd rising through the circle's centre (once a turn, 1.9 s) captures
    let own = format!("http://{}", scope.addr);
    let arm = json!({"kind": "level", "signal": "x.cmd", "level": 0.0, "edge": "rising",
                     "pre_s": 0.01, "post_s": 0.01});
    let r = request(
        &scope.addr,
        "POST",
        "/api/trigger",
        &[
            ("x-scope-token", &scope.token),
            ("x-scope-session", "page"),
            ("Origin", &own),
        ],
        &arm.to_string(),
    );
    assert_eq!(r.code, 200, "{r:?}");
    let t = Instant::now();
    let captured = loop {
        let st = scope.api("GET", "/api/state", "page", "").json();
        if st["capture"].is_object() {
            break st;
        }
        assert!(t.elapsed() < Duration::from_secs(20), "no capture: {st}");
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(captured["capture"]["describe"]
        .as_str()
        .unwrap()
        .contains("x.cmd rising"));
    let v = scope.api("GET", "/api/view?sig=x.load&cols=10&span=0.5", "page", "");
    assert_eq!(v.code, 200, "{v:?}");
    assert_eq!(v.json()["series"][0]["name"], "x.load");

    assert_eq!(
        status(&instance, 5.0)["swaps"],
        0,
        "a read-only scope swapped"
    );
    stop(&mut run);
    let _ = std::fs::remove_dir_all(&d);
}
