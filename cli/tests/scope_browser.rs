//! `feedloop scope` end to end in a real headless Chromium, driven over the DevTools protocol:
//! the page loads against a running realtime loop, plots receive data, a trigger on a swap
//! captures it, a swap sent from the page reaches the loop and its answer appears, the capture
//! saves as a trace and reloads into the view, a second browser is told the scope is taken, and
//! the page says when the loop ends; the page is opened at the address with its launch token, and
//! a `--read-only` scope's page hides swaps and retunes. A screenshot of each state is written to
//! `target/tmp/scope-e2e/` (the paths are printed). Without a browser the test says so and is
//! skipped, except on CI (`CI=true`), where it fails.

mod scope_common;

use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{json, Value};

use scope_common::{bin, long_job, request, start_run, start_scope, Proc};

/// The browser, or `None` after saying the test `what` is skipped (on CI a missing one fails).
fn browser_or_skip(what: &str) -> Option<PathBuf> {
    let missing = format!("{}: {what}", feedloop_cli::browser::NOT_FOUND);
    feedloop_test_support::found_or_skip(feedloop_cli::browser::on_path(), missing)
}

/// A DevTools-protocol session with one page.
struct Cdp {
    ws: tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>,
    next: u64,
    /// The output of the loop under test, shown when a wait fails.
    run_log: PathBuf,
}

impl Cdp {
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.next += 1;
        let id = self.next;
        let msg = json!({"id": id, "method": method, "params": params}).to_string();
        self.ws.send(tungstenite::Message::text(msg)).unwrap();
        loop {
            let m = self.ws.read().unwrap();
            let Ok(text) = m.to_text() else { continue };
            let v: Value = serde_json::from_str(text).unwrap_or(Value::Null);
            if v.get("id").and_then(Value::as_u64) == Some(id) {
                if let Some(e) = v.get("error") {
                    panic!("{method}: {e}");
                }
                return v["result"].clone();
            }
        }
    }

    /// Evaluates `expr` in the page (promises awaited) and returns its value.
    fn eval(&mut self, expr: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expr, "returnByValue": true, "awaitPromise": true}),
        );
        if let Some(ex) = r.get("exceptionDetails") {
            panic!("page threw on `{expr}`: {ex}");
        }
        r["result"]["value"].clone()
    }

    /// Waits until `expr` is true in the page; panics with `what` and the page's state after `secs`.
    fn wait_for(&mut self, expr: &str, secs: f64, what: &str) {
        let t = Instant::now();
        while t.elapsed().as_secs_f64() < secs {
            if self.eval(expr) == Value::Bool(true) {
                return;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        let seen = self.eval(
            "JSON.stringify({err: scope.lastError, busy: scope.busy, frames: scope.frames, \
             banner: document.getElementById('banner').textContent, answer: scope.lastAnswer, \
             trigger: scope.state && scope.state.trigger, capture: scope.state && scope.state.capture && scope.state.capture.describe})",
        );
        let run = std::fs::read_to_string(&self.run_log).unwrap_or_default();
        panic!("{what}: not within {secs} s; page: {seen}\nthe loop's output:\n{run}");
    }

    fn screenshot(&mut self, path: &Path) {
        let r = self.call("Page.captureScreenshot", json!({"format": "png"}));
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(r["data"].as_str().unwrap())
            .unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        std::fs::write(path, &bytes).unwrap();
        eprintln!("screenshot: {}", path.display());
    }
}

/// Starts headless Chromium with a DevTools port and opens a session on its page.
fn chromium(browser: &Path, profile: &Path) -> (Proc, Cdp) {
    let mut child = Command::new(browser)
        .args(feedloop_cli::browser::HEADLESS_FLAGS)
        .args([
            "--hide-scrollbars",
            &format!("--user-data-dir={}", profile.display()),
            "about:blank",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut port = None;
    let mut line = String::new();
    let t = Instant::now();
    while port.is_none() && t.elapsed() < Duration::from_secs(30) {
        line.clear();
        if err.read_line(&mut line).unwrap_or(0) == 0 {
            break;
        }
        if let Some(rest) = line
            .trim()
            .strip_prefix("DevTools listening on ws://127.0.0.1:")
        {
            port = rest.split('/').next().map(str::to_string);
        }
    }
    // keep draining Chromium's chatter so it never blocks on a full pipe
    std::thread::spawn(move || {
        let mut sink = String::new();
        while err.read_line(&mut sink).unwrap_or(0) > 0 {
            sink.clear();
        }
    });
    let port = port.expect("Chromium printed no DevTools address");
    let proc = Proc(child);
    let addr = format!("127.0.0.1:{port}");
    let targets = request(&addr, "GET", "/json/list", &[], "").json();
    let ws_url = targets
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["type"] == "page")
        .and_then(|t| t["webSocketDebuggerUrl"].as_str())
        .expect("a page target")
        .to_string();
    let (ws, _) = tungstenite::connect(ws_url).unwrap();
    (
        proc,
        Cdp {
            ws,
            next: 0,
            run_log: PathBuf::new(),
        },
    )
}

#[test]
fn the_scope_page_watches_a_running_loop_triggers_on_a_swap_it_sent_and_reloads_its_capture() {
    let Some(browser) = browser_or_skip("scope not tested in a browser") else {
        return;
    };
    let shots = Path::new(env!("CARGO_TARGET_TMPDIR")).join("scope-e2e");
    let _ = std::fs::remove_dir_all(&shots);
    std::fs::create_dir_all(&shots).unwrap();
    let d = std::env::temp_dir().join(format!("feedloop-scope-e2e-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let instance = format!("scopee2e{}", std::process::id());
    let captures = d.join("captures");

    // The scope first: it waits for the loop and says so.
    let mut scope = start_scope(&[
        "--instance",
        &instance,
        "--captures",
        captures.to_str().unwrap(),
    ]);
    let addr = scope.addr.clone();
    let r = scope.api("GET", "/api/state", "probe", "");
    assert_eq!(r.code, 200, "{r:?}");
    let st = r.json();
    assert!(
        st["connection"].as_str().unwrap().contains("is running")
            || st["connection"].as_str().unwrap().contains("waiting"),
        "{st}"
    );
    // the probe's lease must not block the browser: take over from it below

    let job = long_job(&d, 30.0);
    let mut run = start_run(&job, &d.join("run"), &instance);

    let (_chrome, mut cdp) = chromium(&browser, &d.join("profile"));
    cdp.run_log = d.join("run.out");
    cdp.call("Page.enable", json!({}));
    std::thread::sleep(Duration::from_secs(3)); // the probe's lease runs out
                                                // the address as the scope printed it, token included
    cdp.call(
        "Page.navigate",
        json!({"url": format!("http://{addr}/?token={}", scope.token)}),
    );
    cdp.wait_for(
        "!!(window.scope && scope.state && scope.state.running && scope.frames > 10 && scope.points > 1000)",
        40.0,
        "the page draws the running loop",
    );
    let signals = cdp.eval("scope.panes.map(p => p.signals).flat().join(',')");
    assert!(signals.as_str().unwrap().contains("x.load"), "{signals}");
    cdp.wait_for(
        "!!(scope.state.status && scope.state.status.axes.length === 2)",
        10.0,
        "the loop's status appears",
    );
    // the contour error, from the job the loop's status names
    cdp.wait_for(
        "api('/api/view?sig=contour_error&cols=20&span=0.2').then(v => v.series[0].hi.filter(x => x !== null && x < 1e-3).length > 10)",
        15.0,
        "the contour error is measured",
    );
    cdp.screenshot(&shots.join("1-live.png"));
    let status_seen = page_counters_agree(&mut cdp);
    for width in [1400, 1920] {
        page_fits(&mut cdp, width);
        cdp.screenshot(&shots.join(format!("1-live-{width}.png")));
    }
    legends_beside_plots_and_colours_apart(&mut cdp);
    dense_events_are_one_translucent_band(&mut cdp);

    // A second browser is told who holds the scope.
    let r = scope.api("GET", "/api/state", "second-browser", "");
    assert_eq!(r.code, 409, "{r:?}");
    assert!(r.body.contains("another page"), "{r:?}");

    // Trigger on a swap, then retune the velocity loop from the page.
    cdp.eval(
        "document.getElementById('trig-kind').value = 'event';
         document.getElementById('trig-event').value = 'swap';
         document.getElementById('trig-pre').value = '0.05';
         document.getElementById('trig-post').value = '0.1';
         document.getElementById('trig-arm').click(); true",
    );
    cdp.wait_for(
        "!!(scope.state.trigger && scope.state.trigger.describe === 'event swap')",
        10.0,
        "the trigger is armed",
    );
    cdp.eval(
        "document.getElementById('sw-axis').value = 'x';
         document.getElementById('sw-stage').value = 'velocity';
         document.getElementById('sw-plugin').value = 'pi_velocity';
         document.getElementById('sw-params').value = 'kv_nms_per_rad = 4.75';
         scope.lastAnswer = null;
         document.getElementById('sw-send').click(); true",
    );
    cdp.wait_for("scope.lastAnswer !== null", 15.0, "the swap is answered");
    let answer = cdp.eval("scope.lastAnswer");
    assert_eq!(answer["outcome"], "accepted", "{answer}");
    assert!(
        answer["answer"]["swap"]["to"] == "pi_velocity"
            && answer["answer"]["swap"]["rolled_back"] == false,
        "{answer}"
    );
    // recorded as sent from this page, at the browser's address
    let origin = &answer["answer"]["swap"]["origin"];
    assert_eq!(origin["via"], "scope", "{answer}");
    assert!(
        origin["peer"].as_str().unwrap().starts_with("127.0.0.1:"),
        "{answer}"
    );
    cdp.wait_for(
        "document.getElementById('answers').textContent.includes('within bound')",
        5.0,
        "the answer is listed beside the plot",
    );
    cdp.wait_for(
        "!!(scope.state.capture && scope.state.capture.describe.includes('swap'))",
        15.0,
        "the swap trigger captured",
    );
    // the page's swap is counted since start and in the window, once its status has come
    cdp.wait_for(
        "scope.state.status.swaps === 1 && scope.state.window.counts.swap === 1 && \
         document.querySelector('#status-line [data-counter=swaps]').dataset.value === '1'",
        10.0,
        "the swap is counted in both columns",
    );
    let cap = cdp.eval("scope.state.capture");
    let period = cdp.eval("scope.state.period_s").as_f64().unwrap();
    let cycles = cap["cycles"].as_u64().unwrap();
    let want = (0.15 / period).round() as u64 + 1;
    assert!(
        cycles + 2 >= want && cycles <= want,
        "{cycles} cycles, want {want}"
    );
    assert!(
        cap["events"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["kind"] == "swap"),
        "{cap}"
    );
    let swap_t = answer["t_s"].as_f64().unwrap();
    assert!(
        (cap["trigger_t_s"].as_f64().unwrap() - swap_t).abs() < 1e-9,
        "{cap}"
    );
    // the live view around the swap, paused
    cdp.eval("document.getElementById('pause').click(); document.getElementById('span').value = '0.2'; true");
    std::thread::sleep(Duration::from_millis(500));
    cdp.screenshot(&shots.join("2-swap-answered.png"));

    // The capture: shown, saved as a trace, reloaded into the same view.
    cdp.eval("document.getElementById('source').value = 'capture'; document.getElementById('span').value = 'all'; true");
    cdp.wait_for(
        "scope.frames > 0 && !!scope.state.capture_view",
        10.0,
        "the capture view",
    );
    std::thread::sleep(Duration::from_millis(500));
    cdp.screenshot(&shots.join("3-capture.png"));
    event_kinds_hide_and_show(&mut cdp, "swap");
    cdp.eval("document.getElementById('cap-save').click(); true");
    cdp.wait_for(
        "scope.savedPath !== null && document.getElementById('cap-saved').textContent.startsWith('saved to')",
        10.0,
        "the capture is saved",
    );
    let saved = cdp.eval("scope.savedPath");
    let saved = PathBuf::from(saved.as_str().unwrap());
    let tr = feedloop_trace::Trace::read(&saved).unwrap();
    assert_eq!(tr.len() as u64, cycles);
    assert_eq!(tr.axes(), vec!["x", "y"]);
    assert!(tr.has("x.torque_ff") && tr.has("latency_us"));
    let text = std::fs::read_to_string(&saved).unwrap();
    let opened = cdp.eval(&format!(
        "post('/api/open', {}, {{'x-trace-name': 'reloaded.csv'}}).then(r => r.rows)",
        serde_json::to_string(&text).unwrap()
    ));
    assert_eq!(opened.as_u64(), Some(cycles));
    let frames = cdp.eval("scope.frames").as_u64().unwrap();
    cdp.wait_for(
        &format!("scope.frames > {frames} + 5"),
        10.0,
        "the reloaded capture is drawn",
    );
    cdp.screenshot(&shots.join("4-reloaded.png"));

    // The loop ends (operator stop): the page says so, the scope stays up.
    // SAFETY: signalling our own child.
    unsafe { libc::kill(run.0.id() as i32, libc::SIGINT) };
    let _ = run.0.wait();
    totals_match_the_run_record(&status_seen, &d.join("run").join("plant.log"));
    cdp.eval("document.getElementById('source').value = 'live'; true");
    cdp.wait_for(
        "document.getElementById('banner').textContent.includes('ended')",
        15.0,
        "the page says the loop ended",
    );
    cdp.screenshot(&shots.join("5-loop-ended.png"));

    // The same instance starts again: the page follows the new run.
    let _run2 = start_run(&job, &d.join("run2"), &instance);
    cdp.run_log = d.join("run2.out");
    cdp.wait_for(
        "document.getElementById('banner').textContent.includes('run 2') && scope.state.runs === 2 && scope.state.running",
        30.0,
        "the page follows the restarted loop",
    );
    let t_before = cdp.eval("scope.state.span_s[1]").as_f64().unwrap();
    cdp.wait_for(
        &format!("scope.state.span_s[1] > {t_before} + 0.5"),
        15.0,
        "the restarted loop's cycles arrive",
    );
    cdp.screenshot(&shots.join("6-restarted.png"));
    scope.seen.extend(scope.log.try_iter());
    let log = scope.seen.join("\n");
    for want in [
        "attached to loop",
        "refused a second page",
        "swap from the page",
        "ended",
        "restarted",
    ] {
        assert!(
            log.contains(want),
            "scope's command line lacks `{want}`:\n{log}"
        );
    }
    drop(_run2);

    // A read-only scope (here of the saved capture): the page hides swaps and retunes.
    let ro = start_scope(&["--trace", saved.to_str().unwrap(), "--read-only"]);
    cdp.call(
        "Page.navigate",
        json!({"url": format!("http://{}/?token={}", ro.addr, ro.token)}),
    );
    cdp.wait_for(
        "!!(window.scope && scope.state && scope.state.read_only && scope.frames > 0 && \
         document.getElementById('swap-panel').hidden && \
         document.getElementById('title').textContent.includes('read-only'))",
        15.0,
        "a read-only scope's page hides the swap panel",
    );
    // A recorded trace: none of the live loop's controls or figures.
    let tr = start_scope(&["--trace", saved.to_str().unwrap()]);
    cdp.call(
        "Page.navigate",
        json!({"url": format!("http://{}/?token={}", tr.addr, tr.token)}),
    );
    cdp.wait_for(
        "!!(window.scope && scope.state && scope.state.mode === 'trace' && scope.frames > 2)",
        15.0,
        "the recorded trace is drawn",
    );
    let shown = cdp.eval(
        "JSON.stringify(['trigger-panel', 'swap-panel', 'latency-panel', 'counters-panel', \
         'status-panel', 'pause', 'cap-save', 'event-kinds'].filter(id => { const e = document.getElementById(id); \
         return !e || getComputedStyle(e).display !== 'none' && e.offsetParent !== null; }))",
    );
    assert_eq!(shown, "[]", "live-only controls shown for a trace");
    let text = cdp.eval("document.body.innerText");
    let text = text.as_str().unwrap();
    for word in ["n/a", "Arm", "Swap or retune", "not armed", "p99"] {
        assert!(!text.contains(word), "`{word}` on a trace's page:\n{text}");
    }
    cdp.screenshot(&shots.join("7-trace.png"));
    let _ = std::fs::remove_dir_all(&d);
}

/// The counters on the page's status line are the table's "since start" figures, which are the
/// loop's status; both say their window. Returns the status they came from.
fn page_counters_agree(cdp: &mut Cdp) -> Value {
    cdp.wait_for(
        "!!(scope.state.status && scope.state.window && \
         document.querySelectorAll('#status-line [data-counter]').length >= 4)",
        10.0,
        "the counters and the status line are shown",
    );
    let seen = cdp.eval(
        "(() => {
           const status = scope.state.status;
           const line = [...document.querySelectorAll('#status-line [data-counter]')].map(sp => ({
             key: sp.dataset.counter, window: sp.dataset.window, value: Number(sp.dataset.value),
             table: (document.querySelector('#counters tr[data-counter=\"' + sp.dataset.counter +
                     '\"] td[data-window=\"since start\"]') || {dataset: {}}).dataset.value }));
           const windowed = [...document.querySelectorAll('#counters td[data-window]')]
             .map(td => td.dataset.window).filter(w => w !== 'since start');
           return { status, line, windowed, seconds: scope.state.window.seconds, counts: scope.state.window.counts,
                    first: scope.state.window.first_cycle, end: scope.state.window.end_cycle, lost: scope.state.lost,
                    lineText: document.getElementById('status-line').textContent,
                    head: document.querySelector('#counters tr').textContent };
         })()",
    );
    let line = seen["line"].as_array().unwrap();
    for key in [
        "deadline_misses",
        "plant_overruns",
        "swaps",
        "rejected_requests",
    ] {
        let c = line
            .iter()
            .find(|c| c["key"] == key)
            .unwrap_or_else(|| panic!("no {key} on the status line: {seen}"));
        assert_eq!(c["window"], "since start", "{seen}");
        assert_eq!(c["value"], seen["status"][key], "{seen}");
        assert_eq!(
            c["table"].as_str().and_then(|v| v.parse::<u64>().ok()),
            seen["status"][key].as_u64(),
            "the table's {key} differs from the status line: {seen}"
        );
    }
    assert!(
        seen["lineText"].as_str().unwrap().contains("since start"),
        "{seen}"
    );
    // the window ends where the status' figures end: it holds no more than they count
    for (total, windowed) in [
        ("deadline_misses", "deadline_miss"),
        ("plant_overruns", "plant_overrun"),
        ("swaps", "swap"),
    ] {
        assert!(
            seen["counts"][windowed].as_u64().unwrap() <= seen["status"][total].as_u64().unwrap(),
            "{seen}"
        );
    }
    // the scope watched from the loop's first cycle, lost none and has received every cycle up
    // to the status' one (on a busy machine it may lag the status by a few blocks): it counts
    // what the loop counts
    let whole = seen["first"] == 0
        && seen["end"] == seen["status"]["cycle"]
        && seen["lost"]["plant_cycles"] == 0
        && seen["lost"]["scope_blocks"] == 0
        && seen["lost"]["recorder_dropped"] == 0;
    if whole {
        assert_eq!(
            seen["counts"]["deadline_miss"], seen["status"]["deadline_misses"],
            "{seen}"
        );
        assert_eq!(
            seen["counts"]["plant_overrun"], seen["status"]["plant_overruns"],
            "{seen}"
        );
    } else {
        eprintln!("the scope did not hold every cycle: its window is not compared: {seen}");
    }
    // the windowed column says its window
    let windowed = seen["windowed"].as_array().unwrap();
    assert!(windowed.len() >= 5, "{seen}");
    for w in windowed {
        assert!(
            w.as_str().unwrap().starts_with("in the last ")
                && seen["head"].as_str().unwrap().contains(w.as_str().unwrap()),
            "{seen}"
        );
    }
    assert!(
        seen["head"].as_str().unwrap().contains("since start"),
        "{seen}"
    );
    seen["status"].clone()
}

/// The loop's "since start" figures at a cycle are what its plant log (the summary's source)
/// counts over the cycles before it.
fn totals_match_the_run_record(status: &Value, plant_log: &Path) {
    let cycle = status["cycle"].as_u64().unwrap();
    let log = feedloop_trace::log::read_log::<feedloop_trace::log::PlantRecord>(plant_log).unwrap();
    let before: Vec<_> = log.records.into_iter().filter(|r| r.seq < cycle).collect();
    assert_eq!(
        before.len() as u64,
        cycle,
        "the plant log holds every cycle"
    );
    let t = feedloop_trace::summary::timing(&before);
    assert_eq!(
        (t.deadline_misses, t.plant_overruns),
        (
            status["deadline_misses"].as_u64().unwrap(),
            status["plant_overruns"].as_u64().unwrap()
        ),
        "status at cycle {cycle}: {status}"
    );
}

/// At `width` px the page has no horizontal scroll: the sidebar's tables wrap instead.
fn page_fits(cdp: &mut Cdp, width: u32) {
    cdp.call(
        "Emulation.setDeviceMetricsOverride",
        json!({"width": width, "height": 1300, "deviceScaleFactor": 1, "mobile": false}),
    );
    let frames = cdp.eval("scope.frames").as_u64().unwrap();
    cdp.wait_for(
        &format!(
            "scope.frames > {frames} + 3 && document.querySelectorAll('#status tr').length >= 5"
        ),
        10.0,
        "the page drawn at the new width",
    );
    let seen = cdp.eval(
        "(() => {
           const t = document.getElementById('status');
           const wide = [...document.querySelectorAll('aside section, aside table')]
             .filter(e => e.offsetParent !== null && e.scrollWidth > e.clientWidth)
             .map(e => (e.id || e.tagName) + ' ' + e.scrollWidth + ' > ' + e.clientWidth);
           return { table: [t.scrollWidth, t.clientWidth], section: [t.parentElement.scrollWidth,
                    t.parentElement.clientWidth], page: [document.documentElement.scrollWidth,
                    document.documentElement.clientWidth], wide };
         })()",
    );
    let pair = |k: &str| (seen[k][0].as_u64().unwrap(), seen[k][1].as_u64().unwrap());
    for k in ["table", "section", "page"] {
        let (scroll, client) = pair(k);
        assert!(scroll <= client, "{width} px: {k} scrolls sideways: {seen}");
    }
    assert_eq!(seen["page"][1].as_u64(), Some(u64::from(width)), "{seen}");
    assert_eq!(seen["wide"], json!([]), "{width} px: {seen}");
}

/// Each pane's legend is outside its plot area, and its signals' colours are far apart.
fn legends_beside_plots_and_colours_apart(cdp: &mut Cdp) {
    let seen = cdp.eval(
        "scope.panes.map(p => {
           const c = p.canvas.getBoundingClientRect(), l = p.legend.getBoundingClientRect();
           const a = { left: c.left + p.plot.x, top: c.top + p.plot.y };
           a.right = a.left + p.plot.w; a.bottom = a.top + p.plot.h;
           const apart = l.bottom <= a.top || l.top >= a.bottom || l.right <= a.left || l.left >= a.right;
           const swatches = [...p.legend.querySelectorAll('.swatch')].map(s => getComputedStyle(s).backgroundColor);
           return { signals: p.signals, colors: p.signals.map(n => p.colors[n].color), swatches,
                    legend: [l.left, l.top, l.right, l.bottom], plot: [a.left, a.top, a.right, a.bottom],
                    apart, legendHeight: l.height };
         })",
    );
    let panes = seen.as_array().unwrap();
    assert!(panes.len() >= 3, "{seen}");
    for p in panes {
        assert_eq!(p["apart"], true, "a legend covers its plot: {p}");
        assert!(p["legendHeight"].as_f64().unwrap() > 0.0, "{p}");
        let colors: Vec<[f64; 3]> = p["colors"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| cie_lab(c.as_str().unwrap()))
            .collect();
        assert_eq!(p["swatches"].as_array().unwrap().len(), colors.len(), "{p}");
        for (i, a) in colors.iter().enumerate() {
            for b in &colors[..i] {
                // CIE76 colour difference: above 25 another colour at a glance
                let d =
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
                assert!(
                    d > 25.0,
                    "two signals of a pane look alike (delta E {d:.0}): {p}"
                );
            }
        }
    }
}

/// CIE L*a*b* of a `#rrggbb` colour (sRGB, D65).
fn cie_lab(hex: &str) -> [f64; 3] {
    let h = hex.trim_start_matches('#');
    let [r, g, b] = [0, 2, 4].map(|i| {
        let c = u8::from_str_radix(&h[i..i + 2], 16).unwrap() as f64 / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    });
    let x = (0.4124 * r + 0.3576 * g + 0.1805 * b) / 0.95047;
    let y = 0.2126 * r + 0.7152 * g + 0.0722 * b;
    let z = (0.0193 * r + 0.1192 * g + 0.9505 * b) / 1.08883;
    let f = |v: f64| {
        if v > 0.008856 {
            v.cbrt()
        } else {
            7.787 * v + 16.0 / 116.0
        }
    };
    [
        116.0 * f(y) - 16.0,
        500.0 * (f(x) - f(y)),
        200.0 * (f(y) - f(z)),
    ]
}

/// A dense run of events is drawn as one translucent band, not a solid line per event.
fn dense_events_are_one_translucent_band(cdp: &mut Cdp) {
    let seen = cdp.eval(
        "(() => {
           const keep = [scope.eventMarks, scope.eventsInView];
           scope.eventMarks = {}; scope.eventsInView = {};
           const c = document.createElement('canvas'); c.width = 1000; c.height = 200;
           const g = c.getContext('2d');
           const ev = [];
           for (let i = 0; i < 500; i++) ev.push({ kind: 'plant_overrun', t_s: 1 + i * 0.0005 });
           ev.push({ kind: 'swap', t_s: 1.9 });
           drawEvents(g, ev, t => 70 + (t - 1) * 900, 1, 2, 70, 6, 900, 160);
           const px = g.getImageData(0, 100, 1000, 1).data;
           let covered = 0, darkest = 0;
           for (let x = 0; x < 1000; x++) { const a = px[4 * x + 3]; if (a > 0) covered++; darkest = Math.max(darkest, a); }
           const out = { marks: scope.eventMarks, inView: scope.eventsInView, covered, darkest };
           [scope.eventMarks, scope.eventsInView] = keep;
           return out;
         })()",
    );
    assert_eq!(seen["inView"]["plant_overrun"], 500, "{seen}");
    assert_eq!(seen["marks"]["plant_overrun"], 1, "one band: {seen}");
    assert_eq!(seen["marks"]["swap"], 1, "{seen}");
    // the band covers the run's 225 px, translucent (the curves show through)
    let covered = seen["covered"].as_u64().unwrap();
    assert!((220..=240).contains(&covered), "{seen}");
    assert!(seen["darkest"].as_u64().unwrap() < 128, "{seen}");
}

/// The event legend has a tick box per kind; unticking `kind` takes its marks off the plots.
fn event_kinds_hide_and_show(cdp: &mut Cdp, kind: &str) {
    let boxes = cdp.eval(
        "[...document.querySelectorAll('#event-kinds input[type=checkbox]')].map(b => b.value).join(',') \
         === scope.state.event_kinds.join(',')",
    );
    assert_eq!(boxes, true, "a tick box per event kind");
    cdp.wait_for(
        &format!("(scope.eventMarks['{kind}'] || 0) > 0"),
        10.0,
        "the event is marked",
    );
    let toggle = format!(
        "document.querySelector('#event-kinds input[value=\"{kind}\"]').click(); \
         document.querySelector('#event-kinds input[value=\"{kind}\"]').checked"
    );
    assert_eq!(cdp.eval(&toggle), false);
    let frames = cdp.eval("scope.frames").as_u64().unwrap();
    cdp.wait_for(
        &format!(
            "scope.frames > {frames} + 2 && !scope.eventMarks['{kind}'] && scope.eventsInView['{kind}'] > 0"
        ),
        10.0,
        "the unticked kind is hidden",
    );
    assert_eq!(cdp.eval(&toggle), true);
    cdp.wait_for(
        &format!("(scope.eventMarks['{kind}'] || 0) > 0"),
        10.0,
        "the ticked kind shows again",
    );
}

#[test]
fn a_recorded_trace_opens_in_the_scope_and_bad_arguments_are_named() {
    let d = std::env::temp_dir().join(format!("feedloop-scope-trace-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let t = d.join("t.csv");
    let mut text = String::from("# feedloop-trace v1\nt,x.cmd,x.load,x.torque\n");
    for k in 0..1000 {
        let v = (k as f64 * 0.01).sin();
        text.push_str(&format!(
            "{},{},{},{}\n",
            0.5 + k as f64 * 1e-3,
            v,
            v * 0.9,
            if k == 500 { 7.0 } else { 0.0 }
        ));
    }
    std::fs::write(&t, text).unwrap();
    let scope = start_scope(&["--trace", t.to_str().unwrap()]);
    let addr = scope.addr.clone();
    let r = scope.api("GET", "/api/state", "a", "");
    assert_eq!(r.code, 200);
    let st = r.json();
    assert_eq!(st["mode"], "trace");
    let span = st["span_s"].as_array().unwrap();
    assert!(
        (span[0].as_f64().unwrap() - 0.5).abs() < 1e-12
            && (span[1].as_f64().unwrap() - 1.499).abs() < 1e-9
    );
    // a one-sample spike is kept by the envelope of a 100-column view
    let v = scope
        .api(
            "GET",
            "/api/view?sig=x.torque,x.following_error&cols=100&t0=0.5&t1=1.5",
            "a",
            "",
        )
        .json();
    let hi: Vec<f64> = v["series"][0]["hi"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_f64)
        .collect();
    assert_eq!(hi.iter().cloned().fold(f64::MIN, f64::max), 7.0);
    assert_eq!(v["series"][1]["name"], "x.following_error");

    // bad input: the file, the port, the address
    let o = Command::new(bin())
        .args(["scope", "--trace"])
        .arg(d.join("missing.csv"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.csv"));
    let port = addr.rsplit(':').next().unwrap();
    let o = Command::new(bin())
        .args(["scope", "--trace", t.to_str().unwrap(), "--port", port])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("in use") && err.contains(port),
        "{err}"
    );
    let o = Command::new(bin())
        .args(["scope", "--instance", "Bad Name"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("invalid instance name"));
    let _ = std::fs::remove_dir_all(&d);
}
