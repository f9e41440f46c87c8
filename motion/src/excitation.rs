//! Excitation commands for identification: kinds `random_segments`, `prbs`, `multisine`, and
//! [`write_excitation_csv`] to save any command as a trace.
//!
//! - `random_segments` (seed 001): the velocity holds a random level `v_i ~ U(-V, V)` for a random
//!   time `T_i ~ U(T_min, T_max)`; consecutive levels join with a C5 velocity change over
//!   `T_tr` (`v = v_i + (v_(i+1) - v_i) s(u)`). Independent levels give an approximately flat
//!   velocity spectrum up to about `1 / (2 T_mean)`, rolling off above `1 / T_tr`. An optional
//!   travel limit flips a level's sign (or steers back to the start) when the segment would leave
//!   `start +- travel`. Random numbers: SplitMix64 seeded by `seed` (same seed, same command).
//! - `prbs`: a maximum-length binary sequence of order `n` (period `2^n - 1` bits, Fibonacci
//!   LFSR) with bit time `T_b`, mapped to `+-A` in velocity (`amplitude_m_per_s`) or in position
//!   (`amplitude_m`), each switch a C5 change over `T_tr`. Axis `a` of `N` uses the sequence
//!   shifted by `a (2^n - 1) / N` bits.
//! - `multisine`: `m(t) = sum_k B_k sin(w_k t + phi_k)`, `w_k = 2 pi k / P` for every `k` with
//!   `f_min <= k / P <= f_max`, Schroeder phases `phi_k = -pi k (k - 1) / K` (low crest factor),
//!   flat amplitudes in position (`amplitude_m`: `B_k = c`) or velocity (`amplitude_m_per_s`:
//!   `B_k = c / w_k`), `c` scaled so the peak over a period equals the amplitude. The command is
//!   `p(t) = p0 + w(t) m(t - T_f)` with a C5 fade `w` over `T_f` before and after whole periods,
//!   derivatives by Leibniz' rule `p^(n) = sum_j C(n, j) w^(j) m^(n-j)`. Axis `a` of `N` is delayed
//!   by `a P / N`.

use std::f64::consts::PI;
use std::io::{self, Write};

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::params::{ConfigError, Fields, Range};
use feedloop_trace::TraceWriter;

use super::moves::finish;
use super::poly::{smoothstep, Builder};
use super::{per_axis, traverse, Ctx, RefState, Trajectory};

/// SplitMix64: a small, well-mixed 64-bit generator (deterministic per seed).
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }
}

/// Feedback taps (1-based, `x^n + ...`) of maximum-length LFSRs for orders 2..=20.
const PRBS_TAPS: [&[u32]; 19] = [
    &[2, 1],
    &[3, 2],
    &[4, 3],
    &[5, 3],
    &[6, 5],
    &[7, 6],
    &[8, 6, 5, 4],
    &[9, 5],
    &[10, 7],
    &[11, 9],
    &[12, 6, 4, 1],
    &[13, 4, 3, 1],
    &[14, 5, 3, 1],
    &[15, 14],
    &[16, 15, 13, 4],
    &[17, 14],
    &[18, 11],
    &[19, 6, 2, 1],
    &[20, 17],
];

/// One period (`2^order - 1` bits) of the maximum-length sequence of `order` (2..=20), as
/// `+1` / `-1`. Returns an empty vector for an unsupported order.
pub fn prbs_sequence(order: u32) -> Vec<i8> {
    if !(2..=20).contains(&order) {
        return Vec::new();
    }
    let taps = PRBS_TAPS[(order - 2) as usize];
    let len = (1usize << order) - 1;
    let mut state: u32 = 1;
    let mut out = Vec::with_capacity(len);
    for _ in 0..len {
        out.push(if state & 1 == 1 { 1 } else { -1 });
        let mut bit = 0;
        for t in taps {
            bit ^= (state >> (order - t)) & 1;
        }
        state = (state >> 1) | (bit << (order - 1));
    }
    out
}

fn start_positions(f: &mut Fields, ctx: &Ctx) -> Result<Vec<f64>, ConfigError> {
    Ok(
        per_axis(f, "start_m", "start_rad", ctx.axes, Range::Finite)?
            .into_iter()
            .map(|v| v.unwrap_or(0.0))
            .collect(),
    )
}

/// Reads one of two amplitude families: velocity (`..._per_s`) or position. Returns per-axis
/// amplitudes (0 for axes not given) and whether they are velocities.
fn amplitudes(f: &mut Fields, ctx: &Ctx) -> Result<(Vec<f64>, bool), ConfigError> {
    let vel = per_axis(
        f,
        "amplitude_m_per_s",
        "amplitude_rad_per_s",
        ctx.axes,
        Range::NonNegative,
    )?;
    let pos = per_axis(
        f,
        "amplitude_m",
        "amplitude_rad",
        ctx.axes,
        Range::NonNegative,
    )?;
    let any = |v: &[Option<f64>]| v.iter().any(|x| x.is_some_and(|x| x > 0.0));
    match (any(&vel), any(&pos)) {
        (true, true) => Err(f.error(
            "amplitude_m",
            "give either position amplitudes (amplitude_m / amplitude_rad) or velocity amplitudes (amplitude_m_per_s / amplitude_rad_per_s), not both",
        )),
        (false, false) => Err(f.error(
            "amplitude_m_per_s",
            "is required: a non-zero velocity amplitude (amplitude_m_per_s / amplitude_rad_per_s) or position amplitude (amplitude_m / amplitude_rad) for at least one axis",
        )),
        (is_vel, _) => {
            let src = if is_vel { vel } else { pos };
            Ok((src.into_iter().map(|x| x.unwrap_or(0.0)).collect(), is_vel))
        }
    }
}

/// The key an amplitude of either family is reported at.
fn amplitude_key(is_vel: bool) -> &'static str {
    if is_vel {
        "amplitude_m_per_s"
    } else {
        "amplitude_m"
    }
}

/// `kind = "random_segments"`.
pub(crate) fn random_segments(
    mut f: Fields,
    ctx: &Ctx,
) -> Result<Box<dyn Trajectory>, ConfigError> {
    let start = start_positions(&mut f, ctx)?;
    let vmax: Vec<f64> = per_axis(
        &mut f,
        "velocity_m_per_s",
        "velocity_rad_per_s",
        ctx.axes,
        Range::NonNegative,
    )?
    .into_iter()
    .map(|v| v.unwrap_or(0.0))
    .collect();
    if vmax.iter().all(|v| *v == 0.0) {
        return Err(f.error(
            "velocity_m_per_s",
            "is required: the largest velocity level for at least one axis (or velocity_rad_per_s)",
        ));
    }
    let travel = traverse::read_travel(&mut f, ctx)?;
    let trav = traverse::read(&mut f, ctx, &travel)?;
    // On a traverse the carrier uses the travel; the levels keep their own drift within a tenth.
    let travel: Vec<f64> = if trav.is_some() {
        travel.iter().map(|t| 0.1 * t).collect()
    } else {
        travel
    };
    let duration_s = f.f64("duration_s", Range::Positive)?;
    let min_s = f.f64("min_segment_s", Range::Positive)?;
    let max_s = f.f64("max_segment_s", Range::Positive)?;
    if max_s < min_s {
        return Err(f.error(
            "max_segment_s",
            format!("must be >= min_segment_s ({min_s} s), got {max_s}"),
        ));
    }
    let tr_s = read_transition(&mut f, ctx, 0.5 * min_s, ("min_segment_s", min_s))?;
    let seed = f.opt_i64("seed", 0, i64::MAX)?.unwrap_or(1) as u64;
    let return_s = f.opt_f64("return_s", Range::Positive)?;
    if let Some(r) = return_s {
        ctx.at_least_periods(&f, "return_s", r, 2.0)?;
    }

    let n = ctx.axes.len();
    let mut rng = SplitMix64::new(seed);
    let mut b = Builder::new(&start);
    let mut level = vec![0.0; n];
    let mut t = 0.0;
    while t < duration_s - 1e-12 {
        let mut seg = rng.uniform(min_s, max_s);
        if t + seg > duration_s {
            seg = duration_s - t;
            if seg < tr_s {
                break;
            }
        }
        let mut dv = vec![0.0; n];
        for a in 0..n {
            let mut v = rng.uniform(-vmax[a], vmax[a]);
            if travel[a].is_finite() {
                // Position at the segment's end for a candidate level `v`.
                let end = |v: f64| b.position()[a] + 0.5 * (level[a] + v) * tr_s + v * (seg - tr_s);
                let off = |p: f64| (p - start[a]).abs();
                if off(end(v)) > travel[a] {
                    v = -v;
                }
                if off(end(v)) > travel[a] {
                    // Steer back towards the start, as fast as allowed.
                    v = ((start[a] - b.position()[a] - 0.5 * level[a] * tr_s) / (seg - 0.5 * tr_s))
                        .clamp(-vmax[a], vmax[a]);
                }
            }
            dv[a] = v - level[a];
            level[a] = v;
        }
        b.smooth_velocity_change(tr_s, &dv);
        b.hold(seg - tr_s);
        t += seg;
    }
    let stop: Vec<f64> = level.iter().map(|v| -v).collect();
    b.smooth_velocity_change(tr_s, &stop);
    if let Some(r) = return_s {
        let back: Vec<f64> = start.iter().zip(b.position()).map(|(s, p)| s - p).collect();
        b.smooth_move(r, &back);
    }
    let out = finish("random_segments", ctx, b);
    let out = traverse::apply(&f, ctx, trav, out, "velocity_m_per_s", Some(&vmax))?;
    f.finish()?;
    Ok(out)
}

/// `transition_s` (default `default_s`, at least two periods), at most the key `limit` names
/// (its name and value).
fn read_transition(
    f: &mut Fields,
    ctx: &Ctx,
    default_s: f64,
    (limit_key, limit_s): (&str, f64),
) -> Result<f64, ConfigError> {
    let tr_s = f.f64_or("transition_s", Range::Positive, default_s)?;
    ctx.at_least_periods(f, "transition_s", tr_s, 2.0)?;
    if tr_s > limit_s {
        return Err(f.error(
            "transition_s",
            format!("must be <= {limit_key} ({limit_s} s), got {tr_s}"),
        ));
    }
    Ok(tr_s)
}

/// `kind = "prbs"`.
pub(crate) fn prbs(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let start = start_positions(&mut f, ctx)?;
    let (amp, is_vel) = amplitudes(&mut f, ctx)?;
    let order = f.opt_i64("order", 2, 20)?.unwrap_or(9) as u32;
    let bit_s = f.f64("bit_s", Range::Positive)?;
    ctx.at_least_periods(&f, "bit_s", bit_s, 2.0)?;
    let tr_s = read_transition(&mut f, ctx, 0.25 * bit_s, ("bit_s", bit_s))?;
    let periods = f.opt_i64("periods", 1, 10_000)?.unwrap_or(1) as usize;
    let dwell_s = f.f64_or("dwell_after_s", Range::NonNegative, 0.0)?;
    let travel = traverse::read_travel(&mut f, ctx)?;
    let trav = traverse::read(&mut f, ctx, &travel)?;

    let n = ctx.axes.len();
    let seq = prbs_sequence(order);
    let len = seq.len();
    let bits = len * periods;
    let mut b = Builder::new(&start);
    let mut cur = vec![0.0; n];
    for i in 0..bits {
        let mut step = vec![0.0; n];
        for a in 0..n {
            let shift = a * len / n;
            let target = amp[a] * seq[(i + shift) % len] as f64;
            step[a] = target - cur[a];
            cur[a] = target;
        }
        if is_vel {
            b.smooth_velocity_change(tr_s, &step);
        } else {
            b.smooth_move(tr_s, &step);
        }
        b.hold(bit_s - tr_s);
    }
    let back: Vec<f64> = cur.iter().map(|v| -v).collect();
    if is_vel {
        b.smooth_velocity_change(tr_s, &back);
    } else {
        b.smooth_move(tr_s, &back);
    }
    b.hold(dwell_s);
    let out = finish("prbs", ctx, b);
    let vel = is_vel.then_some(amp.as_slice());
    let out = traverse::apply(&f, ctx, trav, out, amplitude_key(is_vel), vel)?;
    f.finish()?;
    Ok(out)
}

/// A multisine command (kind `multisine`).
pub struct Multisine {
    axes: Vec<String>,
    start: Vec<f64>,
    /// Per axis scale `c_a` (0 for axes not excited).
    scale: Vec<f64>,
    /// Per axis delay, s.
    delay_s: Vec<f64>,
    /// Line spacing `2 pi / P`, rad/s.
    base_omega: f64,
    /// Harmonic number of the first line.
    k_lo: usize,
    /// Angular frequencies, rad/s.
    omega: Vec<f64>,
    /// Unit-scale amplitudes `B_k / c`.
    weight: Vec<f64>,
    /// `(cos phi_k, sin phi_k)` of the phases.
    phase_cs: Vec<(f64, f64)>,
    fade_s: f64,
    steady_s: f64,
    dwell_s: f64,
}

impl Multisine {
    /// `m^(d)(t) / c` for d = 0..5. The lines are consecutive harmonics, so `e^(i k theta)` is
    /// stepped from one line to the next by a complex product (one `sin_cos` per call).
    fn unit(&self, t: f64) -> RefState {
        let mut m = [0.0; REF_DERIVS];
        let theta = self.base_omega * t;
        let (s1, c1) = theta.sin_cos();
        let (mut sk, mut ck) = (self.k_lo as f64 * theta).sin_cos();
        for ((w, b), (cp, sp)) in self.omega.iter().zip(&self.weight).zip(&self.phase_cs) {
            // sin and cos of k theta + phi_k.
            let s = sk * cp + ck * sp;
            let c = ck * cp - sk * sp;
            // d/dt rotates (s, c) -> (c, -s) and scales by w.
            let mut f = *b;
            let cyc = [s, c, -s, -c];
            for (d, md) in m.iter_mut().enumerate() {
                *md += f * cyc[d % 4];
                f *= w;
            }
            (ck, sk) = (ck * c1 - sk * s1, sk * c1 + ck * s1);
        }
        m
    }

    /// Fade window `w(t)` and its derivatives.
    fn window(&self, t: f64) -> RefState {
        let end = self.fade_s + self.steady_s;
        if self.fade_s <= 0.0 {
            let mut w = [0.0; REF_DERIVS];
            w[0] = if (0.0..=end).contains(&t) { 1.0 } else { 0.0 };
            return w;
        }
        let (u, sign) = if t < end {
            (t / self.fade_s, 1.0)
        } else {
            ((end + self.fade_s - t) / self.fade_s, -1.0)
        };
        let s = smoothstep(u);
        let mut w = [0.0; REF_DERIVS];
        let mut k = 1.0;
        for d in 0..REF_DERIVS {
            w[d] = s[d] * k;
            k *= sign / self.fade_s;
        }
        w
    }
}

impl Trajectory for Multisine {
    axes_and_duration!(self => 2.0 * self.fade_s + self.steady_s + self.dwell_s);

    fn eval(&self, t_s: f64, out: &mut [RefState]) {
        const BINOM: [[f64; REF_DERIVS]; REF_DERIVS] = [
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [1.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            [1.0, 2.0, 1.0, 0.0, 0.0, 0.0],
            [1.0, 3.0, 3.0, 1.0, 0.0, 0.0],
            [1.0, 4.0, 6.0, 4.0, 1.0, 0.0],
            [1.0, 5.0, 10.0, 10.0, 5.0, 1.0],
        ];
        let active = t_s > 0.0 && t_s < 2.0 * self.fade_s + self.steady_s;
        let w = if active {
            self.window(t_s)
        } else {
            [0.0; REF_DERIVS]
        };
        for (a, o) in out.iter_mut().enumerate().take(self.axes.len()) {
            *o = [0.0; REF_DERIVS];
            o[0] = self.start[a];
            if !active || self.scale[a] == 0.0 {
                continue;
            }
            let m = self.unit(t_s - self.fade_s - self.delay_s[a]);
            for n in 0..REF_DERIVS {
                let mut acc = 0.0;
                for j in 0..=n {
                    acc += BINOM[n][j] * w[j] * m[n - j];
                }
                o[n] += self.scale[a] * acc;
            }
        }
    }

    fn kind(&self) -> &str {
        "multisine"
    }

    fn steady_windows_s(&self) -> Vec<[f64; 2]> {
        vec![[self.fade_s, self.fade_s + self.steady_s]]
    }
}

/// `kind = "multisine"`.
pub(crate) fn multisine(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let start = start_positions(&mut f, ctx)?;
    let (amp, is_vel) = amplitudes(&mut f, ctx)?;
    let period = f.f64("signal_period_s", Range::Positive)?;
    let f_min = f.f64("f_min_hz", Range::Positive)?;
    let f_max = f.f64("f_max_hz", Range::Positive)?;
    let nyquist = 0.5 / ctx.period_s;
    if f_max < f_min {
        return Err(f.error(
            "f_max_hz",
            format!("must be >= f_min_hz ({f_min} Hz), got {f_max}"),
        ));
    }
    if f_max > 0.5 * nyquist {
        return Err(f.error(
            "f_max_hz",
            format!(
                "{f_max} Hz is above half the Nyquist frequency of the control period ({} Hz)",
                0.5 * nyquist
            ),
        ));
    }
    let k_lo = (f_min * period).ceil().max(1.0) as usize;
    let k_hi = (f_max * period + 1e-9).floor() as usize;
    if k_hi < k_lo {
        return Err(f.error(
            "signal_period_s",
            format!(
                "no harmonic of 1/{period} Hz lies in [{f_min}, {f_max}] Hz: lengthen signal_period_s or widen the band"
            ),
        ));
    }
    if k_hi - k_lo + 1 > 5000 {
        return Err(f.error(
            "f_max_hz",
            format!(
                "{} components (at most 5000): narrow the band or shorten signal_period_s",
                k_hi - k_lo + 1
            ),
        ));
    }
    let periods = f.opt_i64("periods", 1, 100_000)?.unwrap_or(4) as usize;
    let fade_s = f.f64_or("fade_s", Range::NonNegative, 0.1 * period)?;
    if fade_s > 0.0 {
        ctx.at_least_periods(&f, "fade_s", fade_s, 2.0)?;
    }
    let dwell_s = f.f64_or("dwell_after_s", Range::NonNegative, 0.0)?;
    let travel = traverse::read_travel(&mut f, ctx)?;
    let trav = traverse::read(&mut f, ctx, &travel)?;

    let kcount = (k_hi - k_lo + 1) as f64;
    let mut omega = Vec::new();
    let mut weight = Vec::new();
    let mut phase_cs = Vec::new();
    for (i, k) in (k_lo..=k_hi).enumerate() {
        let w = 2.0 * PI * k as f64 / period;
        omega.push(w);
        weight.push(if is_vel { 1.0 / w } else { 1.0 });
        let kk = (i + 1) as f64;
        // Schroeder phases; the extra -pi/2 for velocity makes the velocity a sine sum.
        let phase = -PI * kk * (kk - 1.0) / kcount - if is_vel { PI / 2.0 } else { 0.0 };
        phase_cs.push((phase.cos(), phase.sin()));
    }
    let n = ctx.axes.len();
    let mut ms = Multisine {
        axes: ctx.axes.to_vec(),
        start,
        scale: vec![1.0; n],
        delay_s: (0..n).map(|a| a as f64 * period / n as f64).collect(),
        base_omega: 2.0 * PI / period,
        k_lo,
        omega,
        weight,
        phase_cs,
        fade_s,
        steady_s: periods as f64 * period,
        dwell_s,
    };
    // Peak of the unit signal (position or velocity) over one period, sampled densely.
    let d = usize::from(is_vel);
    let samples = ((20.0 * f_max * period).ceil() as usize).max(4096);
    let peak = (0..samples)
        .map(|i| ms.unit(i as f64 * period / samples as f64)[d].abs())
        .fold(0.0, f64::max);
    ms.scale = amp.iter().map(|a| a / peak).collect();
    let out: Box<dyn Trajectory> = Box::new(ms);
    let vel = is_vel.then_some(amp.as_slice());
    let out = traverse::apply(&f, ctx, trav, out, amplitude_key(is_vel), vel)?;
    f.finish()?;
    Ok(out)
}

/// Writes `traj` sampled every `period_s` from 0 to its end as a trace (format v1): columns
/// `t`, then per axis `A.cmd`, `A.cmd_vel`, `A.cmd_acc` (load units per s^n). Metadata:
/// `period_s`, `source=feedloop excitation <kind>`, then `meta`. Returns the writer.
/// The `A.cmd` columns read back with `kind = "trace"`.
pub fn write_excitation_csv<W: Write>(
    traj: &dyn Trajectory,
    period_s: f64,
    meta: &[(String, String)],
    w: W,
) -> io::Result<W> {
    if !(period_s.is_finite() && period_s > 0.0) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("period must be > 0 s, got {period_s}"),
        ));
    }
    let axes = traj.axes();
    let mut cols = vec!["t".to_string()];
    for a in axes {
        for s in ["cmd", "cmd_vel", "cmd_acc"] {
            cols.push(format!("{a}.{s}"));
        }
    }
    let mut all_meta = vec![
        ("period_s".to_string(), format!("{period_s}")),
        (
            "source".to_string(),
            format!("feedloop excitation {}", traj.kind()),
        ),
    ];
    all_meta.extend(meta.iter().cloned());
    let mut tw = TraceWriter::with_meta(w, &all_meta, &cols)?.with_period(period_s)?;
    let rows = (traj.duration_s() / period_s).round() as u64 + 1;
    let mut states = vec![[0.0; REF_DERIVS]; axes.len()];
    let mut row = vec![0.0; cols.len()];
    for k in 0..rows {
        let t = k as f64 * period_s;
        traj.eval(t, &mut states);
        row[0] = t;
        for (i, s) in states.iter().enumerate() {
            row[1 + 3 * i..4 + 3 * i].copy_from_slice(&s[..3]);
        }
        tw.write_cycle(k, &row)?;
    }
    tw.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::*;
    use feedloop_trace::Trace;
    use std::path::Path;

    const RANDOM: &str = r#"
kind = "random_segments"
velocity_m_per_s = { x = 0.02 }
max_travel_m = { x = 0.01 }
min_segment_s = 0.01
max_segment_s = 0.05
transition_s = 0.004
duration_s = 3.0
seed = 7
return_s = 0.3
"#;

    #[test]
    fn every_prbs_order_has_its_maximum_period_and_balance() {
        for order in 2..=20u32 {
            let seq = prbs_sequence(order);
            let len = (1usize << order) - 1;
            assert_eq!(seq.len(), len);
            let ones = seq.iter().filter(|b| **b == 1).count();
            assert_eq!(
                ones,
                1 << (order - 1),
                "order {order} is not maximum length"
            );
            // Maximum length <=> the register returns to its start only after 2^n - 1 steps:
            // checked through the balance above plus the two-level autocorrelation at lag 1.
            let r1: i64 = (0..len).map(|i| (seq[i] * seq[(i + 1) % len]) as i64).sum();
            assert_eq!(r1, -1, "order {order}: autocorrelation at lag 1 is {r1}");
        }
        assert!(prbs_sequence(21).is_empty());
    }

    #[test]
    fn random_segments_are_reproducible_bounded_and_smooth() {
        let a = built(RANDOM, &["x", "y"]);
        let b = built(RANDOM, &["x", "y"]);
        let other = built(&RANDOM.replace("seed = 7", "seed = 8"), &["x", "y"]);
        let mut differs = false;
        let mut vmax: f64 = 0.0;
        let mut xmax: f64 = 0.0;
        let mut levels = Vec::new();
        let n = 30_000;
        for k in 0..=n {
            let t = a.duration_s() * k as f64 / n as f64;
            let (sa, sb, so) = (at(a.as_ref(), t), at(b.as_ref(), t), at(other.as_ref(), t));
            assert_eq!(sa, sb, "same seed, same command");
            differs |= sa[0][0] != so[0][0];
            if t <= 3.004 {
                // The random part (the return move afterwards has its own speed).
                vmax = vmax.max(sa[0][1].abs());
            }
            xmax = xmax.max(sa[0][0].abs());
            assert_eq!(sa[1], [0.0; 6], "y is not excited");
            if sa[0][2].abs() < 1e-9 && t < 3.0 {
                levels.push(sa[0][1]);
            }
        }
        assert!(differs, "another seed gives another command");
        assert!(vmax <= 0.02 + 1e-12 && vmax > 0.015, "{vmax}");
        assert!(xmax <= 0.01 + 1e-9, "travel limit: {xmax}");
        // Levels spread over the range (uniform: mean ~0, both signs).
        let mean = levels.iter().sum::<f64>() / levels.len() as f64;
        assert!(mean.abs() < 0.005, "{mean}");
        assert!(levels.iter().any(|v| *v > 0.01) && levels.iter().any(|v| *v < -0.01));
        let worst = check_derivatives(a.as_ref(), 500, 1e-7, &[]);
        assert!(worst < 1e-4, "{worst}");
        let end = at(a.as_ref(), a.duration_s() + 1.0);
        assert!(
            end[0][0].abs() < 1e-12,
            "returns to the start: {}",
            end[0][0]
        );
        check_final_hold(a.as_ref());
    }

    #[test]
    fn the_random_segments_velocity_spectrum_is_flat_below_its_corner() {
        let tr = built("kind = \"random_segments\"\nvelocity_m_per_s = 0.02\nmin_segment_s = 0.002\nmax_segment_s = 0.006\ntransition_s = 0.0005\nduration_s = 20\nmax_travel_m = 0.05", &["x"]);
        // Band power of the velocity in [5, 15] Hz vs [25, 45] Hz (corner ~1/(2*0.004) = 125 Hz),
        // by direct DFT at 1 kHz over the 20 s.
        let h = 1e-3;
        let v: Vec<f64> = (0..20_000)
            .map(|k| at(tr.as_ref(), k as f64 * h)[0][1])
            .collect();
        let power = |f: f64| {
            let (mut re, mut im) = (0.0, 0.0);
            for (k, x) in v.iter().enumerate() {
                let (s, c) = (2.0 * PI * f * k as f64 * h).sin_cos();
                re += x * c;
                im -= x * s;
            }
            re * re + im * im
        };
        let band = |lo: f64, hi: f64| {
            let n = ((hi - lo) / 0.05) as usize;
            (0..n).map(|i| power(lo + 0.05 * i as f64)).sum::<f64>() / n as f64
        };
        let (low, mid) = (band(5.0, 15.0), band(25.0, 45.0));
        let ratio = low / mid;
        assert!(
            ratio > 0.6 && ratio < 1.6,
            "band powers {low} vs {mid}: ratio {ratio}"
        );
    }

    #[test]
    fn a_velocity_prbs_switches_between_plus_and_minus_the_amplitude() {
        let tr = built("kind = \"prbs\"\namplitude_m_per_s = { x = 0.01, y = 0.02 }\norder = 5\nbit_s = 0.01\ntransition_s = 0.002", &["x", "y"]);
        assert!((tr.duration_s() - (31.0 * 0.01 + 0.002)).abs() < 1e-9);
        let seq = prbs_sequence(5);
        for (i, bit) in seq.iter().enumerate() {
            let s = at(tr.as_ref(), i as f64 * 0.01 + 0.006);
            assert!((s[0][1] - 0.01 * *bit as f64).abs() < 1e-12, "bit {i}");
            let shifted = seq[(i + 15) % 31];
            assert!((s[1][1] - 0.02 * shifted as f64).abs() < 1e-12);
        }
        let worst = check_derivatives(tr.as_ref(), 300, 1e-7, &[]);
        assert!(worst < 1e-4, "{worst}");
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn a_position_prbs_holds_plus_or_minus_the_amplitude_and_returns() {
        let tr = built(
            "kind = \"prbs\"\namplitude_m = 1e-4\norder = 4\nbit_s = 0.02\nstart_m = 0.1",
            &["x"],
        );
        let seq = prbs_sequence(4);
        for (i, bit) in seq.iter().enumerate() {
            let s = at(tr.as_ref(), i as f64 * 0.02 + 0.015)[0];
            assert!((s[0] - (0.1 + 1e-4 * *bit as f64)).abs() < 1e-15);
        }
        assert!((at(tr.as_ref(), 10.0)[0][0] - 0.1).abs() < 1e-15);
    }

    #[test]
    fn prbs_amplitudes_of_both_kinds_are_refused() {
        refused_at(
            "kind = \"prbs\"\namplitude_m = 1e-4\namplitude_m_per_s = 0.01\nbit_s = 0.01",
            &["x"],
            "trajectory.amplitude_m",
        );
        refused_at(
            "kind = \"prbs\"\namplitude_m = 1e-4\nbit_s = 0.01\norder = 40",
            &["x"],
            "trajectory.order",
        );
    }

    const MULTI: &str = r#"
kind = "multisine"
amplitude_m_per_s = { x = 0.01 }
signal_period_s = 0.5
f_min_hz = 4
f_max_hz = 200
periods = 3
fade_s = 0.1
"#;

    #[test]
    fn a_velocity_multisine_has_its_peak_its_lines_and_whole_periods() {
        let tr = built(MULTI, &["x"]);
        assert!((tr.duration_s() - (1.5 + 0.2)).abs() < 1e-12);
        let w = tr.steady_windows_s();
        assert_eq!(w, vec![[0.1, 1.6]]);
        // Periodic in the steady part and peak velocity = amplitude.
        let mut peak: f64 = 0.0;
        for k in 0..5000 {
            let t = 0.1 + 0.5 * k as f64 / 5000.0;
            let (s0, s1) = (at(tr.as_ref(), t)[0], at(tr.as_ref(), t + 0.5)[0]);
            assert!((s0[1] - s1[1]).abs() < 1e-12);
            peak = peak.max(s0[1].abs());
        }
        assert!((peak - 0.01).abs() < 2e-4, "{peak}");
        // Lines: DFT of one period of velocity has flat magnitudes on 2..200 Hz, none outside.
        let n = 5000;
        let v: Vec<f64> = (0..n)
            .map(|k| at(tr.as_ref(), 0.1 + 0.5 * k as f64 / n as f64)[0][1])
            .collect();
        let mag = |k: usize| {
            let (mut re, mut im) = (0.0, 0.0);
            for (i, x) in v.iter().enumerate() {
                let (s, c) = (2.0 * PI * (k * i) as f64 / n as f64).sin_cos();
                re += x * c;
                im -= x * s;
            }
            re.hypot(im) * 2.0 / n as f64
        };
        let (m1, m10, m100) = (mag(1), mag(10), mag(100));
        assert!(m1 < 1e-9 * m10, "no line at 2 Hz, below the band: {m1}");
        assert!(
            (m10 / m100 - 1.0).abs() < 1e-6,
            "flat velocity lines: {m10} vs {m100}"
        );
        let worst = check_derivatives(tr.as_ref(), 400, 1e-7, &[]);
        assert!(worst < 1e-4, "{worst}");
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn a_multisine_above_the_usable_band_is_refused() {
        refused_at("kind = \"multisine\"\namplitude_m = 1e-5\nsignal_period_s = 1\nf_min_hz = 1\nf_max_hz = 4000", &["x"], "trajectory.f_max_hz");
    }

    #[test]
    fn an_excitation_written_as_csv_reads_back_as_a_trace_command() {
        let tr = built(RANDOM, &["x", "y"]);
        let bytes = write_excitation_csv(tr.as_ref(), 1e-4, &[], Vec::new()).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        let trace = Trace::parse(Path::new("exc.csv"), &text).unwrap();
        assert_eq!(
            trace.meta_value("source"),
            Some("feedloop excitation random_segments")
        );
        assert!((trace.period_s() - 1e-4).abs() < 1e-12);
        assert_eq!(trace.len(), (tr.duration_s() / 1e-4).round() as usize + 1);
        let x = trace.require("x.cmd").unwrap();
        let xv = trace.require("x.cmd_vel").unwrap();
        for k in (0..trace.len()).step_by(997) {
            let s = at(tr.as_ref(), k as f64 * 1e-4);
            assert_eq!(x[k].to_bits(), s[0][0].to_bits());
            assert_eq!(xv[k].to_bits(), s[0][1].to_bits());
        }
    }

    /// The three kinds, each without and with a traverse of `V` (x) inside `travel` (x).
    fn traversed_kinds(v: f64, travel: f64) -> Vec<(String, String)> {
        let tail = format!("\nmax_travel_m = {{ x = {travel} }}");
        let trav = format!("\ntraverse_m_per_s = {{ x = {v} }}\ntraverse_reversal_s = 0.05");
        [
            "kind = \"random_segments\"\nvelocity_m_per_s = { x = 0.01 }\nmin_segment_s = 0.002\nmax_segment_s = 0.006\ntransition_s = 0.001\nduration_s = 4\nseed = 3",
            "kind = \"prbs\"\namplitude_m_per_s = { x = 0.012 }\norder = 9\nbit_s = 0.004\nperiods = 2",
            "kind = \"multisine\"\namplitude_m_per_s = { x = 0.015 }\nsignal_period_s = 1\nf_min_hz = 2\nf_max_hz = 200\nperiods = 3",
        ]
        .iter()
        .map(|k| (format!("{k}{tail}"), format!("{k}{tail}{trav}")))
        .collect()
    }

    #[test]
    fn on_a_traverse_the_axis_reverses_only_in_the_turns_and_stays_within_its_travel() {
        let (v, travel, tr) = (0.02, 0.012, 0.05);
        for (plain, text) in traversed_kinds(v, travel) {
            let exc = built(&plain, &["x", "y"]);
            let tot = built(&text, &["x", "y"]);
            let start = at(tot.as_ref(), 0.0)[0][0];
            assert!(tot.duration_s() > exc.duration_s(), "{text}");
            let (mut turns, mut prev_dir, mut passes_checked) = (0, 0.0, 0);
            let mut prev_sign = 0.0;
            let dt = 1e-4;
            let n = (tot.duration_s() / dt) as usize;
            for k in 0..=n {
                let t = k as f64 * dt;
                let p = at(tot.as_ref(), t);
                let e = at(exc.as_ref(), t - tr);
                // y has no traverse: it is the excitation alone, delayed by the first ramp.
                assert_eq!(p[1][0].to_bits(), e[1][0].to_bits());
                assert!(
                    (p[0][0] - start).abs() <= travel * (1.0 + 1e-9),
                    "{text}: t {t}"
                );
                let carrier = p[0][1] - e[0][1];
                let in_pass = (carrier.abs() - v).abs() < 1e-9 * v;
                let sign = p[0][1].signum();
                if in_pass {
                    passes_checked += 1;
                    assert_eq!(
                        sign,
                        carrier.signum(),
                        "{text}: reversal within a pass at {t} s"
                    );
                    assert!(p[0][1].abs() > 0.2 * v, "{text}: {t} s");
                    if prev_dir != 0.0 && prev_dir != carrier.signum() {
                        turns += 1;
                    }
                    prev_dir = carrier.signum();
                } else if p[0][1] != 0.0 && prev_sign != 0.0 && sign != prev_sign {
                    // a sign change outside the passes: only in a turn (or the start and stop)
                    assert!(carrier.abs() < v, "{text}: {t} s");
                }
                if p[0][1] != 0.0 {
                    prev_sign = sign;
                }
            }
            assert!(turns >= 2, "{text}: {turns} turns");
            assert!(passes_checked > n / 2, "{text}");
            check_final_hold(tot.as_ref());
        }
    }

    #[test]
    fn an_excitation_not_below_its_traverse_is_refused_at_its_amplitude() {
        for (_, text) in traversed_kinds(0.01, 0.02) {
            let key = if text.contains("random_segments") {
                "trajectory.velocity_m_per_s"
            } else {
                "trajectory.amplitude_m_per_s"
            };
            let e = refused_at(&text, &["x"], key);
            assert!(e.to_string().contains("below"), "{e}");
        }
    }

    #[test]
    fn a_traverse_without_room_or_without_a_travel_is_refused() {
        for (_, text) in traversed_kinds(0.02, 0.001) {
            refused_at(&text, &["x"], "trajectory.max_travel_m");
            let no_travel: String = text
                .lines()
                .filter(|l| !l.starts_with("max_travel_m"))
                .collect::<Vec<_>>()
                .join("\n");
            refused_at(&no_travel, &["x"], "trajectory.max_travel_m");
        }
    }
}
