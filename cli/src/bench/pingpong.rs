//! The bare iceoryx2 ping-pong of the loop's own messages, `bench latency`'s floor: the pinging
//! side in this process, the echoing side a `bench ping-echo` process it starts, and the timed
//! pings' parts.

use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use serde_json::{json, Value};

use feedloop_analysis::latency::{hist_json, ns_histogram_of};
use feedloop_runtime::shared::pingpong::{echo, ping, EchoStamp, Pacing, PingPong};
use feedloop_runtime::shared::rt::{apply, RtRequest};

/// `bench ping-echo`: the echoing side of the ping-pong of `instance` (pinned to `cpu` when
/// given); writes its timings of the timed pings to `stamps`.
pub(super) fn echo_side(instance: &str, cpu: Option<usize>, stamps: &Path) -> Result<ExitCode> {
    // best effort, as for the ping side: what was refused only makes the floor slower
    apply(&RtRequest {
        mlockall: true,
        fifo_priority: None,
        cpu,
    });
    let (_, st) = echo(instance, Duration::from_secs(30))
        .map_err(|e| anyhow::anyhow!("ping-pong echo: {e}"))?;
    let bytes: Vec<u8> = st
        .iter()
        .flat_map(|s| [s.seq, s.received_ns, s.publish_ns, s.published_ns])
        .flat_map(u64::to_le_bytes)
        .collect();
    std::fs::write(stamps, bytes).with_context(|| format!("writing {}", stamps.display()))?;
    Ok(ExitCode::SUCCESS)
}

/// The bare iceoryx2 ping-pong of the loop's messages (2 axes, as the bench job's) between
/// this process (a thread pinned to the first of `cpus`) and an echo process (on the second):
/// `n` round trips back to back, then `n` one per `period_ns`, at the phase a probe of
/// `phase_probe_s` chose (as the plant does; 0: at whatever phase).
pub(super) fn pingpong(
    cpus: &[usize],
    period_ns: u64,
    n: u64,
    phase_probe_s: f64,
    dir: &Path,
) -> Result<(PingPong, Vec<EchoStamp>)> {
    let instance = format!("pingpong{}", std::process::id());
    let exe = std::env::current_exe().context("locating the feedloop binary")?;
    let stamps = dir.join("pingpong-echo.bin");
    let mut cmd = std::process::Command::new(exe);
    cmd.args(["bench", "ping-echo", "--instance", &instance, "--stamps"]);
    cmd.arg(&stamps);
    if let Some(c) = cpus.get(1) {
        cmd.args(["--cpu", &c.to_string()]);
    }
    crate::signals::die_with_parent(&mut cmd);
    let mut child = cmd.spawn().context("starting the ping-pong echo process")?;
    let first = cpus.first().copied();
    let result = std::thread::scope(|sc| {
        sc.spawn(|| {
            apply(&RtRequest {
                mlockall: true,
                fifo_priority: None,
                cpu: first,
            });
            ping(
                &instance,
                2,
                n,
                n,
                Pacing {
                    period_ns,
                    phase_probe_s,
                },
                Duration::from_secs(10),
            )
        })
        .join()
    });
    let status = child.wait();
    let pp = result
        .map_err(|_| anyhow::anyhow!("the ping-pong thread panicked"))?
        .map_err(|e| anyhow::anyhow!("ping-pong: {e}"))?;
    if let Ok(s) = status {
        if !s.success() {
            bail!("the ping-pong echo process failed ({s})");
        }
    }
    let bytes = std::fs::read(&stamps).with_context(|| format!("reading {}", stamps.display()))?;
    let _ = std::fs::remove_file(&stamps);
    let word = |c: &[u8]| u64::from_le_bytes(c.try_into().unwrap_or([0; 8]));
    let st = bytes
        .chunks_exact(32)
        .map(|c| EchoStamp {
            seq: word(&c[0..8]),
            received_ns: word(&c[8..16]),
            publish_ns: word(&c[16..24]),
            published_ns: word(&c[24..32]),
        })
        .collect();
    Ok((pp, st))
}

/// One ping-pong's timed pings: the pinger's `(seq, sent, answer held)` and the echo's stamps.
pub(super) type TimedPings = (Vec<(u64, u64, u64)>, Vec<EchoStamp>);

/// The timed pings of a ping-pong in parts (as `latency.json`'s `iceoryx_pingpong.breakdown_us`):
/// per ping-pong, the pinger's readings `(seq, sent, answer held)` joined with the echo's of the
/// same seq.
pub(super) fn pingpong_parts(pings: &[TimedPings]) -> Result<Value> {
    let mut parts: Vec<Vec<u64>> = vec![Vec::new(); 4];
    for (pinger, echo) in pings {
        let by_seq: std::collections::HashMap<u64, &EchoStamp> =
            echo.iter().map(|e| (e.seq, e)).collect();
        for (seq, t0, t1) in pinger {
            let Some(e) = by_seq.get(seq) else { continue };
            // as the loop's parts: each from the last reading before it (the echo's reading
            // after its publication can fall after the pinger already holds the answer)
            let marks = [*t0, e.received_ns, e.publish_ns, e.published_ns, *t1];
            for (i, w) in marks.windows(2).enumerate() {
                parts[i].push(w[1].saturating_sub(w[0]).max(1));
            }
        }
    }
    let h = |v: &[u64]| -> Result<Value> {
        Ok(if v.is_empty() {
            Value::Null
        } else {
            hist_json(&ns_histogram_of(v)?)
        })
    };
    Ok(json!({
        "what": "one paced ping in 8, timed by the echo too: publication -> the sample copied out \
                 at the echo; -> the answer's publication starts; -> published; -> the pinger \
                 holds the answer",
        "pings": parts[0].len(),
        "to_echo": h(&parts[0])?,
        "turnaround": h(&parts[1])?,
        "publish": h(&parts[2])?,
        "to_pinger": h(&parts[3])?,
    }))
}
