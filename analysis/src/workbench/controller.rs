//! The controller as a channel: the recorded torque against the model's controller law applied
//! to the recorded signals.
//!
//! The torque balance says whether the plant model explains the motion for the torque that was
//! applied; it cannot see what happened between the controller and the record. The controller
//! residual can: with the `[controller]` of the model file (P position loop on the load
//! position, PI velocity loop on the motor velocity, output limit), the law is evaluated on the
//! very samples the drive's controller read (`A.cmd`, `A.load`, the motor velocity) and compared
//! with `A.torque`. A clamp of the drive recorded after clamping, a different gain, or an input
//! added after the controller (a disturbance test, a feed-forward the model does not know)
//! show there directly, while the torque balance still closes.
//!
//! The law's discretisation is the one the record agrees with best among feedloop's (the
//! integrator by the rectangle rule, `I += e dt` then `u = clamp(Kv (e + I / Tv))`, conditional
//! anti-windup at the law's own limit), the integrator updated after the output, and either of
//! them with the output one period late (a drive that computes in one period what it applies in
//! the next). The velocity the drive used is not always recorded: the
//! `A.motor_vel` column, a backward difference, a two-sample average and a central difference
//! of the position (for a drive with an observer) are tried, and the one the record agrees
//! with best is used (and named). The integrator starts so
//! that the law's first output equals the first recorded one (bumpless).
//!
//! The channel's noise floor is estimated from the residual itself: the robust spread (median
//! absolute deviation) of its first difference, which steps and slow departures hardly touch.

use serde_json::{json, Value};

use super::data::AxisData;
use super::effects::WbModel;
use super::law::{best_law, AntiWindup, Discretisation, Law};
use super::signal::{densest_quarter, nrmse_pct, quantile, rms};

/// A stretch of time where the controller residual stands out of its noise.
#[derive(Debug, Clone)]
pub struct Event {
    /// First sample.
    pub start: usize,
    /// One past the last sample.
    pub end: usize,
    /// Start, s.
    pub start_s: f64,
    /// End, s.
    pub end_s: f64,
    /// Mean residual inside (recorded minus law), torque units.
    pub mean: f64,
    /// Largest absolute residual inside.
    pub peak: f64,
}

/// The controller channel of one axis.
#[derive(Debug, Clone)]
pub struct ControllerChannel {
    /// The torque column as recorded.
    pub recorded: Vec<f64>,
    /// The law's output on the recorded signals.
    pub law: Vec<f64>,
    /// What the record should hold by the model: the law, plus a declared added input, through
    /// the model's torque limit where the record sits at it.
    pub predicted: Vec<f64>,
    /// `recorded - predicted`.
    pub residual: Vec<f64>,
    /// RMS of the residual over the fit range.
    pub rms: f64,
    /// NRMSE of the residual against the recorded torque, %.
    pub nrmse_pct: f64,
    /// Noise floor of the residual (RMS), estimated from the data.
    pub noise_rms: f64,
    /// Which velocity the law was evaluated with.
    pub velocity: &'static str,
    /// Which discretisation of the law the record agrees with.
    pub discretisation: Discretisation,
    /// When the drive's velocity lags (positive) or leads the chosen estimate: by how much, s
    /// (taken into the law; `None` when it explains too little to count).
    pub velocity_lag_s: Option<f64>,
    /// Least-squares gain of the declared added input in the record (1: the record includes it;
    /// between 0.5 and 2 the input is taken into the prediction at this scale, else it is
    /// taken as not in the record).
    pub added_gain: Option<f64>,
    /// First and one-past-last sample compared.
    pub range: (usize, usize),
    /// The law evaluated (its gains, limit and anti-windup form).
    pub law_of: Law,
}

/// Noise floor of a residual: the larger of two robust spreads, that of its first difference
/// over `sqrt 2` (white noise) and that of the residual itself (coloured noise: the spread of
/// its densest quarter, see [`densest_quarter`]; a
/// departure that lasts less than three quarters of the time, such as a clamp, a pulse train
/// or a collision, leaves that quarter to the noise).
pub fn noise_floor(r: &[f64]) -> f64 {
    if r.len() < 3 {
        return 0.0;
    }
    let d: Vec<f64> = r.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    let white = 1.4826 * quantile(&d, 0.5) / std::f64::consts::SQRT_2;
    white.max(densest_quarter(r).1)
}

/// The added input the controller channel of `d` compares with: the one of its held law on a
/// long trace, else the declared column.
fn channel_add(d: &AxisData) -> Option<&[f64]> {
    match &d.held_law {
        Some(h) => h.add.as_deref(),
        None => d.added_input.as_ref().map(|(_, a)| a.as_slice()),
    }
}

/// Relative tolerance within which a recorded torque counts as sitting at a limit.
pub const AT_LIMIT_TOL: f64 = 5e-3;

/// Whether the recorded torque `u` sits at the limit `l` (within [`AT_LIMIT_TOL`]).
pub fn at_limit(u: f64, l: f64) -> bool {
    (u.abs() - l).abs() <= AT_LIMIT_TOL * l
}

/// What the record holds by the model: `law + add`, clamped to `limit` where the recorded
/// torque sits at the limit (a drive that reports the clamped value; one that reports its
/// command records the unclamped law and needs nothing here).
fn predict(law: &[f64], add: Option<&[f64]>, rec: &[f64], limit: Option<f64>) -> Vec<f64> {
    (0..law.len())
        .map(|k| {
            let p = law[k] + add.map_or(0.0, |a| a[k]);
            match limit {
                Some(l) if at_limit(rec[k], l) && p.abs() > l => p.clamp(-l, l),
                _ => p,
            }
        })
        .collect()
}

/// The laws tried on a record: the controller's own; with a drive clamp below its limit, that
/// clamp inside the law with the anti-windup form given, or each form when none is given (the
/// one the record agrees with best is kept, as the discretisation is).
fn laws_tried(law_p: Law, limit: Option<f64>, anti_windup: Option<AntiWindup>) -> Vec<Law> {
    let mut laws = vec![law_p];
    if let Some(l) = limit.filter(|l| *l < law_p.lim) {
        let forms: Vec<AntiWindup> = match anti_windup {
            Some(aw) => vec![aw],
            None => AntiWindup::ALL.to_vec(),
        };
        if anti_windup.is_some() {
            laws.clear();
        }
        laws.extend(forms.into_iter().map(|aw| Law {
            lim: l,
            anti_windup: aw,
            ..law_p
        }));
    }
    laws
}

/// The law `law_p` with its output limit moved after a declared added input: a drive or an
/// output stage (a DAC's +-10 V) that clamps the sum of the controller's output and the
/// injected signal, not the controller's output before it. `None` without an added input or
/// without a finite limit. Returned with the limit that then bounds the sum. A law that never
/// clamps has no anti-windup form: the variants of the clamped laws map to one law here.
fn clamp_on_sum(law_p: &Law, add: Option<&[f64]>, limit: Option<f64>) -> Option<(Law, f64)> {
    (add.is_some() && law_p.lim.is_finite()).then(|| {
        let on_sum = Law {
            lim: f64::INFINITY,
            anti_windup: AntiWindup::Held,
            ..*law_p
        };
        (on_sum, limit.map_or(law_p.lim, |l| l.min(law_p.lim)))
    })
}

/// A law as the record is read with it (see [`best_of`]).
struct LawRead {
    /// The law.
    law: Law,
    /// Its velocity estimate.
    velocity: &'static str,
    /// Its discretisation.
    disc: Discretisation,
    /// Its output.
    out: Vec<f64>,
    /// The limit its output (with the added input) is read through.
    limit: Option<f64>,
}

/// Of the laws `laws` (each also with its limit on the sum with the added input, see
/// [`clamp_on_sum`]), the one (with its velocity estimate and discretisation, see
/// [`best_law`]) whose output, through the drive's `limit` where the record `rec` sits at it,
/// reads the record best over the fit range.
fn best_of(
    laws: &[Law],
    d: &AxisData,
    rec: &[f64],
    add: Option<&[f64]>,
    limit: Option<f64>,
) -> Option<LawRead> {
    let x = d.load_in_motor_units();
    let q = d.motor_raw.as_deref().unwrap_or(&x);
    let (fa, fb) = d.range;
    let mut tried: Vec<(Law, Option<f64>)> = Vec::new();
    for lw in laws {
        let on_sum = clamp_on_sum(lw, add, limit).map(|(on_sum, l)| (on_sum, Some(l)));
        for t in std::iter::once((*lw, limit)).chain(on_sum) {
            if !tried.contains(&t) {
                tried.push(t);
            }
        }
    }
    let mut best: Option<(f64, LawRead)> = None;
    for (lw, limit) in tried {
        let Some((velocity, disc, out)) = best_law(
            &lw,
            &d.cmd,
            &x,
            q,
            d.motor_vel_raw.as_deref(),
            rec,
            add,
            d.dt,
        ) else {
            continue;
        };
        let p = predict(&out, add, rec, limit);
        let score = rms(&(fa..fb).map(|k| rec[k] - p[k]).collect::<Vec<f64>>());
        if best.as_ref().is_none_or(|b| score < b.0 * (1.0 - 1e-9)) {
            let read = LawRead {
                law: lw,
                velocity,
                disc,
                out,
                limit,
            };
            best = Some((score, read));
        }
    }
    best.map(|(_, read)| read)
}

impl ControllerChannel {
    /// The channel of `model` on `d`: `None` without a torque column or without a controller
    /// law in the model.
    pub fn new(model: &WbModel, d: &AxisData) -> Option<Self> {
        Self::with_anti_windup(model, d, None)
    }

    /// [`ControllerChannel::new`] with the drive's clamp inside the law: at the model's
    /// `torque_saturation` limit (when below the controller's own), the integrator doing what
    /// `anti_windup` says while clamped (`None`: held, feedloop's own form). A long trace held
    /// in block means keeps the law it was read with.
    pub fn with_anti_windup(
        model: &WbModel,
        d: &AxisData,
        anti_windup: Option<AntiWindup>,
    ) -> Option<Self> {
        let limit = model.drive_limit();
        let law_p = Law::of(&model.file)?;
        let add = channel_add(d);
        let laws = laws_tried(law_p, limit, anti_windup);
        let mut chosen = law_p;
        let (rec, velocity, discretisation, law, limit) = match &d.held_law {
            // a long trace: the law was evaluated at the recording's rate when it was read
            Some(h) if h.law_of == law_p => (
                h.recorded.clone(),
                h.velocity,
                h.discretisation,
                h.law.clone(),
                limit,
            ),
            Some(_) => return None,
            None => {
                let rec = d.torque_raw.clone()?;
                let read = best_of(&laws, d, &rec, add, limit)?;
                chosen = read.law;
                (rec, read.velocity, read.disc, read.out, read.limit)
            }
        };
        let (a, b) = (2.min(rec.len()), rec.len());
        let added_gain = add.map(|ad| {
            let (mut num, mut den) = (0.0, 0.0);
            for k in a..b {
                num += (rec[k] - law[k]) * ad[k];
                den += ad[k] * ad[k];
            }
            if den > 0.0 {
                num / den
            } else {
                0.0
            }
        });
        // the declared input as the record holds it (its least-squares scale, when that is
        // near 1: a drive's injection path has its own gain error)
        let scaled: Option<Vec<f64>> = match (add, added_gain) {
            (Some(ad), Some(g)) if (0.5..=2.0).contains(&g) => {
                Some(ad.iter().map(|x| g * x).collect())
            }
            _ => None,
        };
        let mut predicted = predict(&law, scaled.as_deref(), &rec, limit);
        let (fa, fb) = d.range;
        // the velocity the drive used may be none of the recorded ones (a filtered or true
        // velocity): a lag of the velocity estimate shows as Kv times the acceleration; when
        // that explains most of the departure, it is part of the law, not of the drive
        let lag_col: Vec<f64> = d.am.iter().map(|a| law_p.kv * a).collect();
        let res0: Vec<f64> = rec.iter().zip(&predicted).map(|(r, p)| r - p).collect();
        let (mut num, mut den) = (0.0, 0.0);
        for k in fa..fb {
            num += res0[k] * lag_col[k];
            den += lag_col[k] * lag_col[k];
        }
        let lag = if den > 0.0 { num / den } else { 0.0 };
        let e0: f64 = res0[fa..fb].iter().map(|x| x * x).sum();
        let e1: f64 = (fa..fb).map(|k| (res0[k] - lag * lag_col[k]).powi(2)).sum();
        let velocity_lag_s = (e1 < 0.5 * e0).then(|| {
            for (p, c) in predicted.iter_mut().zip(&lag_col) {
                *p += lag * c;
            }
            -lag
        });
        let residual: Vec<f64> = rec.iter().zip(&predicted).map(|(r, p)| r - p).collect();
        Some(Self {
            rms: rms(&residual[fa..fb]),
            nrmse_pct: nrmse_pct(&rec[fa..fb], &residual[fa..fb]),
            noise_rms: noise_floor(&residual[fa..fb]),
            velocity_lag_s,
            recorded: rec,
            law,
            predicted,
            residual,
            velocity,
            discretisation,
            added_gain,
            range: (fa, fb),
            law_of: chosen,
        })
    }

    /// The declared added input at the scale the record holds it (`None` without one, or when
    /// the record does not hold it).
    pub fn scaled_input(&self, d: &AxisData) -> Option<Vec<f64>> {
        let ad = channel_add(d)?;
        let g = self.added_gain.filter(|g| (0.5..=2.0).contains(g))?;
        Some(ad.iter().map(|x| g * x).collect())
    }

    /// Whether the record departs from the law by more than its noise can: the residual's RMS
    /// above three times its noise floor and above 0.5 % of the recorded torque's RMS (a
    /// departure smaller than that changes nothing a servo engineer tunes).
    pub fn fails(&self) -> bool {
        self.rms > 3.0 * self.noise_rms && self.nrmse_pct > 0.5
    }

    /// A clamp of the drive that the record shows: the limit (the largest recorded magnitude,
    /// where a clamped record sits), the residual's RMS with it, and what the drive's integrator
    /// does while clamped (the anti-windup form the record agrees with best: the law is run
    /// again with the clamp inside, so an integrator held or wound back at the drive's limit is
    /// part of the law, not a departure from it). `None` when it does not lower the residual.
    pub fn clamp_fit(&self, d: &AxisData) -> Option<(f64, f64, Option<AntiWindup>)> {
        let (a, b) = self.range;
        let l = self.recorded[a..b]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        if l <= 0.0 {
            return None;
        }
        let add = self.scaled_input(d);
        let score = |law: &[f64]| {
            let p = predict(law, add.as_deref(), &self.recorded, Some(l));
            rms(&(a..b)
                .map(|k| self.recorded[k] - p[k])
                .collect::<Vec<f64>>())
        };
        // (`None`: the law as evaluated, the clamp applied to its output only)
        let mut best = (score(&self.law), None);
        // the law again with the drive's clamp inside it (not on a long trace held in block
        // means: its law was evaluated at the recording's rate when it was read)
        let x = d.load_in_motor_units();
        let q = d.motor_raw.as_deref().unwrap_or(&x);
        let vel = (d.held_law.is_none())
            .then(|| super::law::velocity_named(self.velocity, q, d.motor_vel_raw.as_deref(), d.dt))
            .flatten();
        if let Some(vel) = vel {
            // (the rounding floor of a record the law reproduces exactly)
            let scale = rms(&self.recorded[a..b]);
            let first = self.recorded[0] - add.as_ref().map_or(0.0, |ad| ad[0]);
            for aw in AntiWindup::ALL {
                let law = Law {
                    lim: l.min(self.law_of.lim),
                    anti_windup: aw,
                    ..self.law_of
                };
                let out = law.run_as(&d.cmd, &x, &vel, d.dt, first, self.discretisation);
                // a form counts only when the clamped law then reads the record within its
                // noise (bounding an unrelated law's output lowers any error; it is no clamp)
                let r = score(&out);
                if r < best.0 * (1.0 - 1e-9) && r <= 3.0 * self.noise_rms + 1e-9 * scale {
                    best = (r, Some(aw));
                }
            }
        }
        (best.0 < self.rms).then_some((l, best.0, best.1))
    }

    /// Stretches where the residual stands out of its noise (above six times the noise floor
    /// and 1 % of the recorded torque's RMS); see [`find_events`].
    pub fn events(&self, d: &AxisData) -> Vec<Event> {
        let (a, b) = self.range;
        let thr = (6.0 * self.noise_rms).max(0.01 * rms(&self.recorded[a..b]));
        find_events(&self.residual, self.range, thr, d)
    }

    /// Share of the residual's energy inside `events`, and the share of the time they cover, %.
    pub fn event_shares(&self, events: &[Event]) -> (f64, f64) {
        event_shares(&self.residual, self.range, events)
    }

    /// JSON of the channel (without the series).
    pub fn to_json(&self, d: &AxisData) -> Value {
        let ev = self.events(d);
        let (share, time) = self.event_shares(&ev);
        json!({
            "controller_nrmse_pct": self.nrmse_pct,
            "controller_rms": self.rms,
            "noise_rms": self.noise_rms,
            "fails": self.fails(),
            "velocity": self.velocity,
            "discretisation": self.discretisation.name(),
            "velocity_lag_s": self.velocity_lag_s,
            "added_input": d.added_input.as_ref().map(|(n, _)| n.clone()),
            "added_input_gain": self.added_gain,
        })
        .as_object_mut()
        .map(|o| {
            o.extend(events_json(&ev, share, time));
            Value::Object(o.clone())
        })
        .unwrap_or_default()
    }
}

/// The JSON entries of a list of events (the first 50), their count and shares.
pub fn events_json(ev: &[Event], share: f64, time: f64) -> serde_json::Map<String, Value> {
    let mut m = serde_json::Map::new();
    m.insert(
        "events".into(),
        ev.iter()
            .take(50)
            .map(|e| {
                json!({
                    "t_start_s": e.start_s, "t_end_s": e.end_s, "mean": e.mean, "peak": e.peak,
                })
            })
            .collect(),
    );
    m.insert("event_count".into(), json!(ev.len()));
    m.insert("event_energy_share_pct".into(), json!(share));
    m.insert("event_time_share_pct".into(), json!(time));
    m
}

/// Stretches of `residual` (within `range`) whose magnitude exceeds `thr`, gaps shorter than
/// 2 ms merged, single samples dropped: what happened at a time rather than all along (an
/// input switched on, a collision, a clamp hitting).
pub fn find_events(residual: &[f64], range: (usize, usize), thr: f64, d: &AxisData) -> Vec<Event> {
    let (a, b) = range;
    let gap = ((2e-3 / d.dt).ceil() as usize).max(2);
    let mut out = Vec::new();
    let mut k = a;
    while k < b {
        if residual[k].abs() <= thr {
            k += 1;
            continue;
        }
        let s = k;
        let mut last = k;
        while k < b && k - last <= gap {
            if residual[k].abs() > thr {
                last = k;
            }
            k += 1;
        }
        let e = last + 1;
        if e - s >= 2 {
            let r = &residual[s..e];
            out.push(Event {
                start: s,
                end: e,
                start_s: d.t[s],
                end_s: d.t[e - 1],
                mean: r.iter().sum::<f64>() / r.len() as f64,
                peak: r.iter().fold(0.0f64, |m, x| m.max(x.abs())),
            });
        }
    }
    out
}

/// Share of `residual`'s energy (within `range`) inside `events`, and the share of the time
/// they cover, %.
pub fn event_shares(residual: &[f64], range: (usize, usize), events: &[Event]) -> (f64, f64) {
    let (a, b) = range;
    let total: f64 = residual[a..b].iter().map(|x| x * x).sum::<f64>();
    let (mut inside, mut cnt) = (0.0, 0usize);
    for e in events {
        let (s, t) = (e.start.max(a), e.end.min(b));
        if s < t {
            inside += residual[s..t].iter().map(|x| x * x).sum::<f64>();
            cnt += t - s;
        }
    }
    (
        100.0 * inside / total.max(1e-300),
        100.0 * cnt as f64 / (b - a).max(1) as f64,
    )
}

/// Events of the torque balance's residual: where it stands out of its own noise floor (six
/// times, and 1 % of the measured torque's RMS).
pub fn torque_events(residual: &[f64], measured: &[f64], d: &AxisData) -> Vec<Event> {
    let (a, b) = d.range;
    let thr = (6.0 * noise_floor(&residual[a..b])).max(0.01 * rms(&measured[a..b]));
    find_events(residual, d.range, thr, d)
}
