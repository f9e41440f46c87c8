//! Turning per-cycle records into `trace.csv` rows and `summary.json`.
//!
//! Both the two-process run (from the plant's log) and the in-process simulation go through
//! [`trace_columns`] and [`row_values`], so the same cycles give byte-identical trace files.

use std::collections::BTreeMap;

use feedloop_model::units::si;
use serde_json::{json, Value};

use crate::log::AxisRecord;
use crate::summary::{ContourFigures, Timing, Tracking};

/// Trace columns for axes `names`: `t`, then per axis `A.cmd, A.load, A.motor, A.motor_vel, A.torque`.
pub fn trace_columns(names: &[String]) -> Vec<String> {
    let mut c = vec!["t".to_string()];
    for n in names {
        for s in ["cmd", "load", "motor", "motor_vel", "torque"] {
            c.push(format!("{n}.{s}"));
        }
    }
    c
}

/// Fills `out` with one trace row for cycle `seq` (t = seq * period; a writer given the period
/// prints that time exactly with [`crate::TraceWriter::write_cycle`]).
#[inline]
pub fn row_values(seq: u64, period_s: f64, axes: &[AxisRecord], out: &mut Vec<f64>) {
    out.clear();
    out.push(seq as f64 * period_s);
    for a in axes {
        out.extend_from_slice(&[a.cmd, a.load, a.motor, a.motor_vel, a.torque]);
    }
}

/// How a run ended, for `summary.json`'s `end`.
#[derive(Debug, Clone, PartialEq)]
pub struct EndInfo {
    /// `completed`, `scheduler_lost`, `plant_lost`, `operator_stop`, ...
    pub reason: String,
    /// Cycle at which it ended.
    pub cycle: u64,
    /// Extra keys (e.g. `detected_after_cycles`, `safe_stop`, `detail`).
    pub extra: BTreeMap<String, Value>,
}

impl EndInfo {
    /// A plain end.
    pub fn new(reason: &str, cycle: u64) -> Self {
        Self {
            reason: reason.to_string(),
            cycle,
            extra: BTreeMap::new(),
        }
    }
}

/// Everything `summary.json` says.
#[derive(Debug, Clone)]
pub struct SummaryInput<'a> {
    /// Job name.
    pub job: &'a str,
    /// `realtime`, `lockstep` or `sim`.
    pub mode: &'a str,
    /// Control period, s.
    pub period_s: f64,
    /// Cycles in the trace.
    pub cycles: u64,
    /// Timing figures (None in sim).
    pub timing: Option<&'a Timing>,
    /// (plant, scheduler) process ids (None in sim).
    pub pids: Option<(u32, u32)>,
    /// CPU time in physics and control, s.
    pub compute_s: f64,
    /// Tracking figures.
    pub tracking: &'a Tracking,
    /// End of the run.
    pub end: &'a EndInfo,
    /// Extra top-level keys.
    pub extra: BTreeMap<String, Value>,
}

/// Builds the `summary.json` value.
pub fn summary_json(s: &SummaryInput<'_>) -> Value {
    let t = s.timing.cloned().unwrap_or_default();
    let latency = match (s.timing, t.latency_us) {
        (Some(_), Some(p)) => json!({"p50": p.p50, "p99": p.p99, "p999": p.p999, "max": p.max}),
        _ => Value::Null,
    };
    let processes = match s.pids {
        Some((p, q)) => json!({"plant_pid": p, "scheduler_pid": q}),
        None => Value::Null,
    };
    let axes: serde_json::Map<String, Value> = s
        .tracking
        .axes_in_order()
        .into_iter()
        .map(|(k, v, unit)| {
            let mut a = json!({"max_following_error": v.max_following_error, "rms_following_error": v.rms_following_error});
            if let Some(u) = unit {
                a["unit"] = json!(u);
            }
            (k, a)
        })
        .collect();
    let contour = match s.tracking.contour() {
        Some(ContourFigures {
            max_error,
            rms_error,
        }) => {
            json!({"max_error": max_error, "rms_error": rms_error})
        }
        None => Value::Null,
    };
    let mut end = json!({"reason": s.end.reason, "cycle": s.end.cycle});
    for (k, v) in &s.end.extra {
        end[k] = v.clone();
    }
    let mut v = json!({
        "job": s.job,
        "mode": s.mode,
        "period_s": s.period_s,
        "cycles": s.cycles,
        "deadline_misses": t.deadline_misses,
        "plant_overruns": t.plant_overruns,
        "stalls": {"count": t.stalls.count, "max_ms": t.stalls.max_ms},
        "latency_us": latency,
        "processes": processes,
        "compute_s": s.compute_s,
        "axes": axes,
        "contour": contour,
        "end": end,
    });
    for (k, x) in &s.extra {
        v[k] = x.clone();
    }
    v
}

/// A short human-readable summary.
pub fn human_summary(v: &Value) -> String {
    let mut out = String::new();
    let f = |x: &Value| x.as_f64().unwrap_or(f64::NAN);
    // latency_us and max_ms hold their unit in the key; print them as seconds with a prefix
    let us = |x: &Value| si(f(x) * 1e-6, "s");
    out.push_str(&format!(
        "{} [{}]: {} cycles of {}, ended: {}\n",
        v["job"].as_str().unwrap_or("?"),
        v["mode"].as_str().unwrap_or("?"),
        v["cycles"],
        si(f(&v["period_s"]), "s"),
        v["end"]["reason"].as_str().unwrap_or("?")
    ));
    if let Some(axes) = v["axes"].as_object() {
        for (name, a) in axes {
            // rotary axes are in rad, linear ones in m
            let unit = if a["unit"] == "rad" { "rad" } else { "m" };
            out.push_str(&format!(
                "  axis {name}: following error max {}, rms {}\n",
                si(f(&a["max_following_error"]), unit),
                si(f(&a["rms_following_error"]), unit)
            ));
        }
    }
    if !v["contour"].is_null() {
        out.push_str(&format!(
            "  contour error max {}, rms {}\n",
            si(f(&v["contour"]["max_error"]), "m"),
            si(f(&v["contour"]["rms_error"]), "m")
        ));
    }
    // a lockstep run waits for itself: its wall-clock round trips say nothing about the loop
    if !v["latency_us"].is_null() && v["mode"] != "lockstep" {
        let l = &v["latency_us"];
        out.push_str(&format!(
            "  latency: p50 {}  p99 {}  p99.9 {}  max {}\n",
            us(&l["p50"]),
            us(&l["p99"]),
            us(&l["p999"]),
            us(&l["max"])
        ));
    }
    if v["mode"] == "realtime" {
        out.push_str(&format!(
            "  deadline misses {}, plant overruns {}, stalls {} (max {})\n",
            v["deadline_misses"],
            v["plant_overruns"],
            v["stalls"]["count"],
            si(f(&v["stalls"]["max_ms"]) * 1e-3, "s")
        ));
    }
    out.push_str(&format!(
        "  compute {} (physics + control)\n",
        si(f(&v["compute_s"]), "s")
    ));
    if let Some(closed) = v["startup"]["loop_closed_after_s"].as_f64() {
        out.push_str(&format!(
            "  loop closed {} after the first sample (start-up grace {})\n",
            si(closed, "s"),
            si(f(&v["startup"]["grace_s"]), "s")
        ));
    }
    if let Some(advice) = end_advice(v) {
        out.push_str(&advice);
    }
    out.push_str(&timing_warning_text(&v["timing_warning"]));
    out
}

/// The share of a realtime run's cycles above which its plant overruns or its deadline misses
/// are warned about (`timing_warning` in summary.json).
pub const TIMING_WARN_SHARE: f64 = 0.01;

/// summary.json's `timing_warning`: `null` unless the run is realtime and its plant overruns
/// or its deadline misses exceed [`TIMING_WARN_SHARE`] of its cycles; then the shares, which of
/// the two exceeded it, a message and what to change (from the summary `v`'s `wait`,
/// `period_s`, counts).
pub fn timing_warning(v: &Value) -> Value {
    let cycles = v["cycles"].as_u64().unwrap_or(0);
    if v["mode"] != "realtime" || cycles == 0 {
        return Value::Null;
    }
    let count = |k: &str| v[k].as_u64().unwrap_or(0);
    let (overruns, misses) = (count("plant_overruns"), count("deadline_misses"));
    let share = |n: u64| n as f64 / cycles as f64;
    let period = si(v["period_s"].as_f64().unwrap_or(f64::NAN), "s");
    let mut said = vec![];
    let mut exceeded = vec![];
    for (key, n, what) in [
        (
            "plant_overruns",
            overruns,
            "plant overruns (the plant woke more than half a period late)",
        ),
        (
            "deadline_misses",
            misses,
            "deadline misses (no command from the scheduler in time)",
        ),
    ] {
        if share(n) > TIMING_WARN_SHARE {
            exceeded.push(key);
            said.push(format!(
                "{what} in {:.1} % of the cycles ({n} of {cycles})",
                100.0 * share(n)
            ));
        }
    }
    if exceeded.is_empty() {
        return Value::Null;
    }
    let mut advice = vec![];
    match v["wait"].as_str() {
        Some("block") => advice.push(
            "a blocking wait (--wait block) wakes too late for this period here: use --wait \
             busy or --wait hybrid"
                .to_string(),
        ),
        Some("hybrid") => advice.push("use --wait busy (it spins, without sleeping)".into()),
        _ => {}
    }
    advice.push("pin the plant and the scheduler to a CPU each (--pin 0,1)".into());
    advice.push(format!("lengthen the job's period_s (now {period})"));
    advice.push("stop other work on the machine".into());
    json!({
        "share_limit": TIMING_WARN_SHARE,
        "plant_overrun_share": share(overruns),
        "deadline_miss_share": share(misses),
        "exceeded": exceeded,
        "message": format!(
            "{}: more than {} % of the cycles, so the run did not keep its {period} period",
            said.join("; "),
            100.0 * TIMING_WARN_SHARE
        ),
        "advice": advice,
    })
}

/// The summary's lines of a `timing_warning` (empty when it is `null`).
fn timing_warning_text(w: &Value) -> String {
    let Some(message) = w["message"].as_str() else {
        return String::new();
    };
    let mut out = format!("  warning: {message}.\n");
    if let Some(advice) = w["advice"].as_array() {
        let a: Vec<&str> = advice.iter().filter_map(Value::as_str).collect();
        out.push_str(&format!("  to keep the period: {}.\n", a.join("; or ")));
    }
    out
}

/// What an early end means and what to change, for the ends a user can act on.
pub fn end_advice(v: &Value) -> Option<String> {
    let end = &v["end"];
    if end["reason"] != "scheduler_lost" {
        return None;
    }
    let sched_alive = v["scheduler"]["end"]["reason"] == "plant_ended";
    let alive = if sched_alive {
        "The scheduler process was still running (it ended when the plant stopped): "
    } else {
        "If the scheduler process was still running (see scheduler.json), "
    };
    if end["during_handshake"] == true {
        let t = si(end["peer_timeout_s"].as_f64().unwrap_or(f64::NAN), "s");
        return Some(format!(
            "  the scheduler did not answer the handshake within the peer timeout ({t}): did it \
             start (see its error above)? On a busy machine raise [run] peer_timeout_s.\n"
        ));
    }
    if end["during_startup"] == true {
        let grace = si(end["startup_grace_s"].as_f64().unwrap_or(f64::NAN), "s");
        return Some(format!(
            "  the scheduler sent no first command within the start-up grace ({grace}).\n  \
             {alive}the machine was too busy to start it in time: raise [run] startup_grace_s.\n"
        ));
    }
    let n = end["detected_after_cycles"].as_u64().unwrap_or(0);
    let period = v["period_s"].as_f64().unwrap_or(f64::NAN);
    Some(format!(
        "  no command for {n} consecutive cycles ({}) while the plant kept its schedule.\n  \
         {alive}the machine was too busy for this period: raise [run] watchdog_cycles (now {n}), \
         pin the two processes (--pin 0,1), lengthen period_s, or stop other work.\n",
        si(n as f64 * period, "s")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lost_scheduler_gets_advice_naming_the_key_to_change() {
        let mut v = json!({"period_s": 1e-4, "end": {"reason": "scheduler_lost",
            "detected_after_cycles": 500}, "scheduler": {"end": {"reason": "plant_ended"}}});
        let a = end_advice(&v).unwrap();
        assert!(
            a.contains("watchdog_cycles (now 500)") && a.contains("(50 ms)"),
            "{a}"
        );
        assert!(a.contains("still running"), "{a}");
        v["end"]["during_startup"] = json!(true);
        v["end"]["startup_grace_s"] = json!(2.0);
        let a = end_advice(&v).unwrap();
        assert!(a.contains("startup_grace_s") && a.contains("(2 s)"), "{a}");
        v["end"] = json!({"reason": "completed"});
        assert!(end_advice(&v).is_none());
    }
    use crate::log::AxisRecord;
    use crate::summary::Tracking;

    #[test]
    fn summary_lists_axes_in_job_order_with_their_units_and_prints_errors_with_a_fitting_prefix() {
        let dir = std::env::temp_dir().join(format!("feedloop-export-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("x.toml"),
            "kind = \"rigid\"\nmass_kg = 10\n[controller]\nkp_per_s = 30\nkv_ns_per_m = 2000\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("c.toml"),
            "kind = \"rotary\"\njm_kgm2 = 0.01\nkl_nm_per_rad = 1e5\njl_kgm2 = 0.05\n[controller]\nkp_per_s = 30\nkv_nms_per_rad = 2\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("j.toml"),
            "period_s = 0.001\n[axes.x]\nmodel = \"x.toml\"\n[axes.c]\nmodel = \"c.toml\"\n[trajectory]\nkind = \"dwell\"\n",
        )
        .unwrap();
        let job = feedloop_model::job::Job::load(&dir.join("j.toml")).unwrap();
        let mut t = Tracking::for_job(&job);
        let rec = |cmd: f64, load: f64| AxisRecord {
            cmd,
            load,
            ..Default::default()
        };
        t.push(&[rec(0.0, 2e-6), rec(0.0, -3e-3)], None);
        let v = summary_json(&SummaryInput {
            job: "j",
            mode: "sim",
            period_s: 0.001,
            cycles: 1,
            timing: None,
            pids: None,
            compute_s: 0.0,
            tracking: &t,
            end: &EndInfo::new("completed", 1),
            extra: BTreeMap::new(),
        });
        let keys: Vec<&String> = v["axes"].as_object().unwrap().keys().collect();
        assert_eq!(keys, ["x", "c"]);
        assert_eq!(v["axes"]["x"]["unit"], "m");
        assert_eq!(v["axes"]["c"]["unit"], "rad");
        assert_eq!(v["axes"]["c"]["max_following_error"], 3e-3);
        let text = human_summary(&v);
        // significant digits with a prefix that fits: a nanometre error is not `0.000 um`
        assert!(
            text.contains("axis x: following error max 2 um, rms 2 um"),
            "{text}"
        );
        assert!(
            text.contains("axis c: following error max 3 mrad"),
            "{text}"
        );
        assert!(text.contains(" cycles of 1 ms, "), "{text}");
        assert!(text.find("axis x").unwrap() < text.find("axis c").unwrap());
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn nanometre_errors_and_short_times_print_with_their_own_prefix() {
        let v = json!({
            "job": "j", "mode": "realtime", "cycles": 3, "period_s": 0.00025,
            "end": {"reason": "completed"},
            "axes": {"x": {"unit": "m", "max_following_error": 3e-9, "rms_following_error": 1.2e-9}},
            "contour": {"max_error": 4.5e-9, "rms_error": 2e-9},
            "latency_us": {"p50": 12.5, "p99": 40.0, "p999": 1500.0, "max": 2000.0},
            "deadline_misses": 0, "plant_overruns": 0, "stalls": {"count": 0, "max_ms": 0.0},
            "compute_s": 0.0123
        });
        let text = human_summary(&v);
        for want in [
            "3 cycles of 250 us, ended: completed",
            "axis x: following error max 3 nm, rms 1.2 nm",
            "contour error max 4.5 nm, rms 2 nm",
            "latency: p50 12.5 us  p99 40 us  p99.9 1.5 ms  max 2 ms",
            "stalls 0 (max 0 s)",
            "compute 12.3 ms",
        ] {
            assert!(text.contains(want), "missing `{want}` in:\n{text}");
        }
    }
}
