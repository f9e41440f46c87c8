//! `compare`: the equation error (inverse dynamics), error figures per channel, and where the
//! residual lives (segments ranked by their share of it).

use serde_json::{json, Value};

use super::controller::{event_shares, events_json, torque_events, ControllerChannel};
use super::data::AxisData;
use super::effects::WbModel;
use super::signal::{nrmse_pct, quantile, relative_error_pct, rms};
use super::window::{window_sim, WindowSim};

/// Equation error of one axis.
#[derive(Debug, Clone)]
pub struct EquationError {
    /// Applied torque (the recorded torque through the model's torque-path effects).
    pub measured: Vec<f64>,
    /// Torque the model needs for the measured motion.
    pub model: Vec<f64>,
    /// `measured - model`, where the model's dry friction sticks at rest: only what exceeds its
    /// breakaway level ([`WbModel::balance_residual`]).
    pub residual: Vec<f64>,
    /// NRMSE over the fit range, %.
    pub nrmse_pct: f64,
    /// Residual RMS, N m (N).
    pub rms: f64,
    /// `100 ||residual|| / ||measured||`, %.
    pub relative_error_pct: f64,
}

/// Computes the equation error of `model` on `d` (which must carry torque).
pub fn equation_error(model: &WbModel, d: &AxisData, y: &[f64]) -> EquationError {
    let measured = model.applied(d).unwrap_or_else(|| y.to_vec());
    let m = model.torque_needed(d);
    let residual = model.balance_residual(d, &measured, &m);
    let (a, b) = d.range;
    EquationError {
        nrmse_pct: nrmse_pct(&measured[a..b], &residual[a..b]),
        rms: rms(&residual[a..b]),
        relative_error_pct: relative_error_pct(&measured[a..b], &residual[a..b]),
        measured,
        model: m,
        residual,
    }
}

/// Kind of a stretch of the trace.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SegKind {
    /// At rest.
    Standstill,
    /// Around a velocity reversal.
    Reversal,
    /// Accelerating or decelerating.
    Acceleration,
    /// Moving at about constant velocity.
    ConstantVelocity,
}

impl SegKind {
    /// Name used in reports and JSON.
    pub fn id(self) -> &'static str {
        match self {
            SegKind::Standstill => "standstill",
            SegKind::Reversal => "reversal",
            SegKind::Acceleration => "acceleration",
            SegKind::ConstantVelocity => "constant_velocity",
        }
    }

    /// All kinds.
    pub const ALL: [SegKind; 4] = [
        SegKind::Reversal,
        SegKind::Acceleration,
        SegKind::ConstantVelocity,
        SegKind::Standstill,
    ];
}

/// Classifies every sample: reversal (a stretch below 10 % of the top speed between opposite
/// directions of travel, widened by 10 ms), standstill (below 2 % of the top speed for more
/// than 20 ms, not at a reversal), acceleration (|a| above 20 % of its 99th percentile),
/// constant velocity otherwise.
pub fn classify(d: &AxisData) -> Vec<SegKind> {
    let n = d.len();
    let (a, b) = d.range;
    let absv: Vec<f64> = d.vm[a..b].iter().map(|x| x.abs()).collect();
    let vmax = quantile(&absv, 0.99).max(1e-300);
    let absa: Vec<f64> = d.am[a..b].iter().map(|x| x.abs()).collect();
    let amax = quantile(&absa, 0.99).max(1e-300);
    let vlow = 0.02 * vmax;
    let vrev = 0.1 * vmax;
    let mut kind = vec![SegKind::ConstantVelocity; n];
    for (k, a) in kind.iter_mut().zip(&d.am) {
        if a.abs() > 0.2 * amax {
            *k = SegKind::Acceleration;
        }
    }
    let margin = (0.01 / d.dt).round() as usize;
    // standstill: long stretches below 2 % of the top speed
    for (start, k) in slow_runs(&d.vm, vlow) {
        if (k - start) as f64 * d.dt > 0.02 {
            for x in &mut kind[start..k] {
                *x = SegKind::Standstill;
            }
        }
    }
    // reversals: stretches below 10 % of the top speed between opposite directions
    for (start, end) in slow_runs(&d.vm, vrev) {
        let before = if start > 0 {
            d.vm[start - 1].signum()
        } else {
            0.0
        };
        let after = if end < n { d.vm[end].signum() } else { 0.0 };
        if before * after < 0.0 {
            let s = start.saturating_sub(margin);
            let e = (end + margin).min(n);
            for x in &mut kind[s..e] {
                *x = SegKind::Reversal;
            }
        }
    }
    kind
}

/// The longest stretches (first sample, one past the last) in which velocity `v` stays below
/// `thr` in magnitude.
fn slow_runs(v: &[f64], thr: f64) -> Vec<(usize, usize)> {
    let n = v.len();
    let mut runs = Vec::new();
    let mut k = 0;
    while k < n {
        if v[k].abs() >= thr {
            k += 1;
            continue;
        }
        let start = k;
        while k < n && v[k].abs() < thr {
            k += 1;
        }
        runs.push((start, k));
    }
    runs
}

/// One contiguous stretch of one kind and its share of the residual.
#[derive(Debug, Clone)]
pub struct Segment {
    /// Its kind.
    pub kind: SegKind,
    /// First sample.
    pub start: usize,
    /// One past the last sample.
    pub end: usize,
    /// Share of the residual's energy (sum of squares), %.
    pub share_pct: f64,
    /// Residual RMS inside it.
    pub rms: f64,
}

/// Share of the residual per kind of motion or per position band.
#[derive(Debug, Clone)]
pub struct Share {
    /// Name (kind id, or the band `lo..hi`).
    pub name: String,
    /// Share of the residual energy, %.
    pub share_pct: f64,
    /// Share of the time, %.
    pub time_pct: f64,
    /// Residual RMS inside.
    pub rms: f64,
}

/// Cuts the residual into segments and ranks them by their share of it.
pub fn segments(
    d: &AxisData,
    residual: &[f64],
    kinds: &[SegKind],
) -> (Vec<Segment>, Vec<Share>, Vec<Share>) {
    let (a, b) = d.range;
    let total: f64 = residual[a..b]
        .iter()
        .map(|x| x * x)
        .sum::<f64>()
        .max(1e-300);
    let mut segs = Vec::new();
    let mut k = a;
    while k < b {
        let s = k;
        while k < b && kinds[k] == kinds[s] {
            k += 1;
        }
        let e2: f64 = residual[s..k].iter().map(|x| x * x).sum();
        segs.push(Segment {
            kind: kinds[s],
            start: s,
            end: k,
            share_pct: 100.0 * e2 / total,
            rms: (e2 / (k - s) as f64).sqrt(),
        });
    }
    segs.sort_by(|x, y| y.share_pct.total_cmp(&x.share_pct));
    let span = (b - a) as f64;
    let by_kind = SegKind::ALL
        .iter()
        .map(|&kd| {
            let (mut e2, mut cnt) = (0.0, 0usize);
            for k in a..b {
                if kinds[k] == kd {
                    e2 += residual[k] * residual[k];
                    cnt += 1;
                }
            }
            Share {
                name: kd.id().to_string(),
                share_pct: 100.0 * e2 / total,
                time_pct: 100.0 * cnt as f64 / span,
                rms: if cnt > 0 {
                    (e2 / cnt as f64).sqrt()
                } else {
                    0.0
                },
            }
        })
        .collect();
    // position bands of the load (load units)
    let pos = &d.load_raw[a..b];
    let lo = pos.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = pos.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let nb = 8usize;
    let w = ((hi - lo) / nb as f64).max(1e-300);
    let mut e2 = vec![0.0; nb];
    let mut cnt = vec![0usize; nb];
    for (i, p) in pos.iter().enumerate() {
        let j = (((p - lo) / w) as usize).min(nb - 1);
        e2[j] += residual[a + i] * residual[a + i];
        cnt[j] += 1;
    }
    let by_pos = (0..nb)
        .map(|j| Share {
            name: format!("{:.6}..{:.6}", lo + w * j as f64, lo + w * (j + 1) as f64),
            share_pct: 100.0 * e2[j] / total,
            time_pct: 100.0 * cnt[j] as f64 / span,
            rms: if cnt[j] > 0 {
                (e2[j] / cnt[j] as f64).sqrt()
            } else {
                0.0
            },
        })
        .collect();
    (segs, by_kind, by_pos)
}

/// Everything `compare` computes for one axis.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// Equation error, when the trace has torque.
    pub eq: Option<EquationError>,
    /// Windowed and free-run simulation errors.
    pub sim: WindowSim,
    /// Per-sample kind of motion.
    pub kinds: Vec<SegKind>,
    /// Segments ranked by share of the residual.
    pub segments: Vec<Segment>,
    /// Share per kind of motion.
    pub by_kind: Vec<Share>,
    /// Share per load-position band.
    pub by_position: Vec<Share>,
    /// The controller channel (recorded torque against the controller law), when the trace
    /// has torque and the model a controller.
    pub controller: Option<ControllerChannel>,
}

/// Compares `model` with the axis data `d`.
pub fn compare(model: &WbModel, d: &AxisData, window_s: f64) -> Comparison {
    let eq = d.torque.as_ref().map(|y| equation_error(model, d, y));
    let sim = window_sim(model, d, window_s);
    let kinds = classify(d);
    let residual: Vec<f64> = match &eq {
        Some(e) => e.residual.clone(),
        None => sim.residual.clone(),
    };
    let (segments, by_kind, by_position) = segments(d, &residual, &kinds);
    Comparison {
        eq,
        sim,
        kinds,
        segments,
        by_kind,
        by_position,
        controller: ControllerChannel::new(model, d),
    }
}

fn share_json(s: &Share) -> Value {
    json!({"name": s.name, "share_pct": s.share_pct, "time_pct": s.time_pct, "rms": s.rms,
        "concentration": if s.time_pct > 0.0 { s.share_pct / s.time_pct } else { 0.0 }})
}

impl Comparison {
    /// The channel of the headline simulation figures (`torque`, `following_error`,
    /// `velocity`), None when nothing was simulated.
    pub fn headline_channel(&self) -> Option<&str> {
        self.sim.channels.first().map(|c| c.name.as_str())
    }

    /// What the headline figures mean when the trace has no torque column (None when it has
    /// one): then there is no equation error and the simulation compares another channel.
    pub fn no_torque_note(&self, d: &AxisData) -> Option<String> {
        if self.eq.is_some() || d.torque_raw.is_some() {
            return None;
        }
        let col = format!("{}.torque", d.axis);
        Some(match self.headline_channel() {
            Some("following_error") => format!(
                "the trace has no `{col}` column: there is no equation error, and the headline simulation NRMSE is that of the following error (command minus measured position, the model run in closed loop from the command), not of the torque; the residual shares are of the following error too"
            ),
            Some(other) => format!(
                "the trace has no `{col}` column: there is no equation error, and the headline simulation NRMSE is that of the {} channel, not of the torque",
                other.replace('_', " ")
            ),
            None => format!(
                "the trace has no `{col}` column and the model no [controller] to run it from the command: nothing is compared (no equation error, no simulation error)"
            ),
        })
    }

    /// The JSON printed by `compare --json`.
    pub fn to_json(&self, d: &AxisData) -> Value {
        let seg: Vec<Value> = self
            .segments
            .iter()
            .take(20)
            .map(|s| {
                json!({
                    "kind": s.kind.id(),
                    "t_start_s": d.t[s.start],
                    "t_end_s": d.t[s.end - 1],
                    "share_pct": s.share_pct,
                    "rms": s.rms,
                })
            })
            .collect();
        let mut channels = serde_json::Map::new();
        if let Some(e) = &self.eq {
            let ev = torque_events(&e.residual, &e.measured, d);
            let (share, time) = event_shares(&e.residual, d.range, &ev);
            let mut torque = serde_json::Map::new();
            torque.insert("equation_nrmse_pct".into(), json!(e.nrmse_pct));
            torque.insert("equation_fit_pct".into(), json!(100.0 - e.nrmse_pct));
            torque.insert("equation_rms".into(), json!(e.rms));
            torque.insert("relative_error_pct".into(), json!(e.relative_error_pct));
            torque.extend(events_json(&ev, share, time));
            channels.insert("torque".into(), Value::Object(torque));
        }
        if let Some(c) = &self.controller {
            channels.insert("controller".into(), c.to_json(d));
        }
        for c in &self.sim.channels {
            let entry = channels.entry(c.name.clone()).or_insert_with(|| json!({}));
            entry["window_sim_nrmse_pct"] = json!(c.window_nrmse_pct);
            entry["window_sim_rms"] = json!(c.window_rms);
            entry["free_sim_nrmse_pct"] = json!(c.free_nrmse_pct);
        }
        json!({
            "trace": d.path.display().to_string(),
            "axis": d.axis,
            "samples": d.len(),
            "period_s": d.dt,
            "filter_cutoff_hz": d.cutoff_hz,
            "equation_nrmse_pct": self.eq.as_ref().map(|e| e.nrmse_pct),
            "equation_rms": self.eq.as_ref().map(|e| e.rms),
            "relative_error_pct": self.eq.as_ref().map(|e| e.relative_error_pct),
            "window_sim_nrmse_pct": self.sim.headline_nrmse_pct(),
            "headline_channel": self.headline_channel(),
            "note": self.no_torque_note(d),
            "free_sim_nrmse_pct": self.sim.headline_free_nrmse_pct(),
            "controller_nrmse_pct": self.controller.as_ref().map(|c| c.nrmse_pct),
            "sim_mode": self.sim.mode,
            "sim_plant": self.sim.plant,
            "window_s": self.sim.window_s,
            "channels": channels,
            "segments": seg,
            "by_kind": self.by_kind.iter().map(share_json).collect::<Vec<_>>(),
            "by_position": self.by_position.iter().map(share_json).collect::<Vec<_>>(),
        })
    }
}
