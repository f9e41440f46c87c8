//! Kinds `dwell`, `move`, `ramp` and `sequence`: piecewise polynomials (see [`super::poly`]).
//!
//! - C5 move by `D` in `T`: `p(t) = p0 + D s(tau)`, `tau = (t - t0) / T`, so
//!   `p^(k)(t) = D s^(k)(tau) / T^k`; peak velocity `2.707 D / T`.
//! - Jerk-limited move: 7 constant-jerk phases `+j, 0, -j, 0, -j, 0, +j` (S-curve) along the
//!   straight line, limits on the path velocity/acceleration/jerk; snap and crackle are zero
//!   between the jerk steps.
//! - Ramp: velocity `V s(tau)` over `T_a`, constant `V` for `T_c`, then `V (1 - s(tau))`;
//!   distance `V (T_a + T_c)`.

use feedloop_model::params::{ConfigError, Fields, Range};

use super::poly::Builder;
use super::{per_axis, Ctx, PolyTrajectory, Trajectory};

/// How a move is timed.
enum Profile {
    /// C5 smoothstep over a given duration, s.
    C5 { duration_s: f64 },
    /// Minimum-time S-curve with path limits (load units per s, s^2, s^3).
    JerkLimited { v: f64, a: f64, j: f64 },
}

const LIMIT_KEYS: [&str; 3] = [
    "max_velocity_m_per_s",
    "max_accel_m_per_s2",
    "max_jerk_m_per_s3",
];

fn profile(f: &mut Fields, ctx: &Ctx) -> Result<Profile, ConfigError> {
    match f.opt_str("profile")?.unwrap_or("c5") {
        "c5" => {
            if let Some(k) = LIMIT_KEYS.iter().find(|k| f.has(k)) {
                return Err(f.error(
                    k,
                    "only used with profile = \"jerk_limited\" (the C5 profile is timed by duration_s)",
                ));
            }
            let d = f.f64("duration_s", Range::Positive)?;
            ctx.at_least_periods(f, "duration_s", d, 2.0)?;
            Ok(Profile::C5 { duration_s: d })
        }
        "jerk_limited" => {
            if f.has("duration_s") {
                return Err(f.error(
                    "duration_s",
                    "not used with profile = \"jerk_limited\": its duration follows from the limits",
                ));
            }
            Ok(Profile::JerkLimited {
                v: f.f64(LIMIT_KEYS[0], Range::Positive)?,
                a: f.f64(LIMIT_KEYS[1], Range::Positive)?,
                j: f.f64(LIMIT_KEYS[2], Range::Positive)?,
            })
        }
        other => Err(f.error(
            "profile",
            format!("unknown profile `{other}` (c5, jerk_limited)"),
        )),
    }
}

fn append_move(b: &mut Builder, delta: &[f64], p: &Profile) {
    match *p {
        Profile::C5 { duration_s } => b.smooth_move(duration_s, delta),
        Profile::JerkLimited { v, a, j } => b.jerk_limited_move(delta, v, a, j),
    }
}

/// Per-axis values with a default for axes not given.
fn per_axis_or(
    f: &mut Fields,
    key_m: &str,
    key_rad: &str,
    ctx: &Ctx,
    range: Range,
    default: &[f64],
) -> Result<Vec<f64>, ConfigError> {
    Ok(per_axis(f, key_m, key_rad, ctx.axes, range)?
        .into_iter()
        .zip(default)
        .map(|(v, d)| v.unwrap_or(*d))
        .collect())
}

fn dwell_key(f: &mut Fields, ctx: &Ctx, key: &str) -> Result<f64, ConfigError> {
    let d = f.f64_or(key, Range::NonNegative, 0.0)?;
    if d > 0.0 {
        ctx.at_least_periods(f, key, d, 1.0)?;
    }
    Ok(d)
}

pub(crate) fn finish(kind: &'static str, ctx: &Ctx, b: Builder) -> Box<dyn Trajectory> {
    let (poly, windows) = b.finish();
    Box::new(PolyTrajectory {
        kind,
        axes: ctx.axes.to_vec(),
        poly,
        windows,
    })
}

/// `kind = "dwell"`: `duration_s` (default 1), `position_m` / `position_rad` per axis.
pub(crate) fn dwell(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let d = f.f64_or("duration_s", Range::Positive, 1.0)?;
    let zero = vec![0.0; ctx.axes.len()];
    let pos = per_axis_or(
        &mut f,
        "position_m",
        "position_rad",
        ctx,
        Range::Finite,
        &zero,
    )?;
    f.finish()?;
    let mut b = Builder::new(&pos);
    b.hold(d);
    Ok(finish("dwell", ctx, b))
}

/// `kind = "move"`.
pub(crate) fn single_move(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let zero = vec![0.0; ctx.axes.len()];
    let from = per_axis_or(&mut f, "from_m", "from_rad", ctx, Range::Finite, &zero)?;
    let to = per_axis_or(&mut f, "to_m", "to_rad", ctx, Range::Finite, &from)?;
    let p = profile(&mut f, ctx)?;
    let before = dwell_key(&mut f, ctx, "dwell_before_s")?;
    let after = dwell_key(&mut f, ctx, "dwell_after_s")?;
    f.finish()?;
    let delta: Vec<f64> = to.iter().zip(&from).map(|(t, s)| t - s).collect();
    let mut b = Builder::new(&from);
    b.hold(before);
    append_move(&mut b, &delta, &p);
    b.hold(after);
    Ok(finish("move", ctx, b))
}

/// Reads a ramp's velocity (per axis), acceleration time and constant time.
fn ramp_keys(f: &mut Fields, ctx: &Ctx) -> Result<(Vec<f64>, f64, f64), ConfigError> {
    let v = per_axis(
        f,
        "velocity_m_per_s",
        "velocity_rad_per_s",
        ctx.axes,
        Range::Finite,
    )?;
    if v.iter().all(|x| x.is_none_or(|x| x == 0.0)) {
        return Err(f.error(
            "velocity_m_per_s",
            "is required: a non-zero velocity for at least one axis (or velocity_rad_per_s)",
        ));
    }
    let v: Vec<f64> = v.into_iter().map(|x| x.unwrap_or(0.0)).collect();
    let accel_s = f.f64("accel_s", Range::Positive)?;
    ctx.at_least_periods(f, "accel_s", accel_s, 2.0)?;
    let constant_s = f.f64("constant_s", Range::NonNegative)?;
    Ok((v, accel_s, constant_s))
}

fn append_ramp(b: &mut Builder, v: &[f64], accel_s: f64, constant_s: f64) {
    let back: Vec<f64> = v.iter().map(|x| -x).collect();
    b.smooth_velocity_change(accel_s, v);
    b.cruise(constant_s);
    b.smooth_velocity_change(accel_s, &back);
}

/// `kind = "ramp"`.
pub(crate) fn ramp(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let zero = vec![0.0; ctx.axes.len()];
    let start = per_axis_or(&mut f, "start_m", "start_rad", ctx, Range::Finite, &zero)?;
    let (v, accel_s, constant_s) = ramp_keys(&mut f, ctx)?;
    let back = f.opt_bool("return")?.unwrap_or(false);
    let cycles = f.opt_i64("cycles", 1, 100_000)?.unwrap_or(1) as usize;
    let before = dwell_key(&mut f, ctx, "dwell_before_s")?;
    let between = dwell_key(&mut f, ctx, "dwell_between_s")?;
    let after = dwell_key(&mut f, ctx, "dwell_after_s")?;
    if !back && f.has("dwell_between_s") {
        return Err(f.error("dwell_between_s", "only used with return = true"));
    }
    f.finish()?;
    let neg: Vec<f64> = v.iter().map(|x| -x).collect();
    let mut b = Builder::new(&start);
    b.hold(before);
    for c in 0..cycles {
        append_ramp(&mut b, &v, accel_s, constant_s);
        if back {
            b.hold(between);
            append_ramp(&mut b, &neg, accel_s, constant_s);
        }
        if c + 1 < cycles {
            b.hold(between);
        }
    }
    b.hold(after);
    Ok(finish("ramp", ctx, b))
}

/// One parsed `[[trajectory.segments]]` entry.
enum Segment {
    Dwell(f64),
    Move {
        target: Vec<Option<f64>>,
        relative: bool,
        profile: Profile,
    },
    Ramp {
        v: Vec<f64>,
        accel_s: f64,
        constant_s: f64,
    },
}

/// `kind = "sequence"`.
pub(crate) fn sequence(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let zero = vec![0.0; ctx.axes.len()];
    let start = per_axis_or(&mut f, "start_m", "start_rad", ctx, Range::Finite, &zero)?;
    let repeat = f.opt_i64("repeat", 1, 100_000)?.unwrap_or(1) as usize;
    let seg_key = f.path("segments");
    let arr = match f.raw("segments") {
        Some(toml::Value::Array(a)) if !a.is_empty() => a,
        Some(toml::Value::Array(_)) => {
            return Err(f.error("segments", "needs at least one segment"));
        }
        Some(other) => {
            return Err(f.error(
                "segments",
                format!(
                    "must be an array of tables ([[{seg_key}]]), got {}",
                    other.type_str()
                ),
            ))
        }
        None => {
            return Err(f.error(
                "segments",
                format!("is required: one [[{seg_key}]] table per move, ramp or dwell"),
            ))
        }
    };
    let file = f.file();
    f.finish()?;
    let mut segments = Vec::with_capacity(arr.len());
    for (i, v) in arr.iter().enumerate() {
        let key = format!("{seg_key}[{i}]");
        let t = v
            .as_table()
            .ok_or_else(|| ConfigError::new(file, &key, "must be a table"))?;
        let mut sf = Fields::new(t, file, &key);
        let seg = segment(&mut sf, ctx)?;
        sf.finish()?;
        segments.push(seg);
    }
    let mut b = Builder::new(&start);
    for _ in 0..repeat {
        for s in &segments {
            play(&mut b, s);
        }
    }
    Ok(finish("sequence", ctx, b))
}

/// One `[[segments]]` table: a dwell, a move (to absolute or by relative targets) or a ramp.
fn segment(sf: &mut Fields, ctx: &Ctx) -> Result<Segment, ConfigError> {
    Ok(match sf.str("kind")? {
        "dwell" => {
            let d = sf.f64("duration_s", Range::Positive)?;
            ctx.at_least_periods(sf, "duration_s", d, 1.0)?;
            Segment::Dwell(d)
        }
        "move" => {
            let to = per_axis(sf, "to_m", "to_rad", ctx.axes, Range::Finite)?;
            let by = per_axis(sf, "by_m", "by_rad", ctx.axes, Range::Finite)?;
            let has_to = to.iter().any(Option::is_some);
            let has_by = by.iter().any(Option::is_some);
            if has_to && has_by {
                return Err(sf.error(
                    "by_m",
                    "give either absolute targets (to_m / to_rad) or relative ones (by_m / by_rad), not both",
                ));
            }
            if !has_to && !has_by {
                return Err(sf.error(
                    "to_m",
                    "is required: absolute targets (to_m / to_rad) or relative ones (by_m / by_rad)",
                ));
            }
            let profile = profile(sf, ctx)?;
            Segment::Move {
                target: if has_to { to } else { by },
                relative: has_by,
                profile,
            }
        }
        "ramp" => {
            let (v, accel_s, constant_s) = ramp_keys(sf, ctx)?;
            Segment::Ramp {
                v,
                accel_s,
                constant_s,
            }
        }
        other => {
            return Err(sf.error(
                "kind",
                format!("unknown segment kind `{other}` (move, ramp, dwell)"),
            ))
        }
    })
}

/// Appends segment `s` to the trajectory built so far.
fn play(b: &mut Builder, s: &Segment) {
    match s {
        Segment::Dwell(d) => b.hold(*d),
        Segment::Move {
            target,
            relative,
            profile,
        } => {
            let delta: Vec<f64> = target
                .iter()
                .zip(b.position())
                .map(|(t, p)| match (t, relative) {
                    (Some(t), false) => t - p,
                    (Some(t), true) => *t,
                    (None, _) => 0.0,
                })
                .collect();
            append_move(b, &delta, profile);
        }
        Segment::Ramp {
            v,
            accel_s,
            constant_s,
        } => append_ramp(b, v, *accel_s, *constant_s),
    }
}

#[cfg(test)]
mod tests {
    use crate::poly::SMOOTHSTEP_PEAK_SLOPE;
    use crate::test_util::*;

    #[test]
    fn a_c5_move_reaches_its_target_with_the_expected_peak_velocity() {
        let tr = built("kind = \"move\"\nto_m = 0.05\nduration_s = 0.3\ndwell_before_s = 0.1\ndwell_after_s = 0.2", &["x"]);
        assert!((tr.duration_s() - 0.6).abs() < 1e-12);
        let mid = at(tr.as_ref(), 0.25);
        assert!((mid[0][0] - 0.025).abs() < 1e-12);
        assert!((mid[0][1] - SMOOTHSTEP_PEAK_SLOPE * 0.05 / 0.3).abs() < 1e-9);
        assert_eq!(at(tr.as_ref(), 0.05)[0], [0.0; 6]);
        let end = at(tr.as_ref(), 0.45)[0];
        assert!((end[0] - 0.05).abs() < 1e-12, "{end:?}");
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn move_derivatives_match_central_differences() {
        let tr = built("kind = \"move\"\nfrom_m = { x = 0.01 }\nto_m = { x = 0.06, y = -0.02 }\nduration_s = 0.3", &["x", "y"]);
        let worst = check_derivatives(tr.as_ref(), 200, 1e-6, &[]);
        assert!(worst < 1e-5, "{worst}");
    }

    #[test]
    fn a_jerk_limited_move_respects_its_path_limits() {
        let tr = built("kind = \"move\"\nto_m = { x = 0.03, y = 0.04 }\nprofile = \"jerk_limited\"\nmax_velocity_m_per_s = 0.2\nmax_accel_m_per_s2 = 2.0\nmax_jerk_m_per_s3 = 50.0", &["x", "y"]);
        let (mut vmax, mut amax, mut jmax): (f64, f64, f64) = (0.0, 0.0, 0.0);
        let n = 20_000;
        for k in 0..=n {
            let s = at(tr.as_ref(), tr.duration_s() * k as f64 / n as f64);
            vmax = vmax.max(s[0][1].hypot(s[1][1]));
            amax = amax.max(s[0][2].hypot(s[1][2]));
            jmax = jmax.max(s[0][3].hypot(s[1][3]));
            assert_eq!(s[0][4], 0.0);
        }
        assert!(vmax <= 0.2 + 1e-12 && vmax > 0.199, "{vmax}");
        assert!(amax <= 2.0 + 1e-9 && amax > 1.99, "{amax}");
        assert!((jmax - 50.0).abs() < 1e-9, "{jmax}");
        let end = at(tr.as_ref(), tr.duration_s() + 1.0);
        assert!((end[0][0] - 0.03).abs() < 1e-15 && (end[1][0] - 0.04).abs() < 1e-15);
    }

    #[test]
    fn a_jerk_limited_move_refuses_a_duration() {
        refused_at("kind = \"move\"\nto_m = 0.1\nprofile = \"jerk_limited\"\nduration_s = 1\nmax_velocity_m_per_s = 0.2\nmax_accel_m_per_s2 = 2.0\nmax_jerk_m_per_s3 = 50.0", &["x"], "trajectory.duration_s");
    }

    #[test]
    fn a_c5_move_without_duration_is_refused() {
        let e = refused_at(
            "kind = \"move\"\nto_m = 0.1",
            &["x"],
            "trajectory.duration_s",
        );
        assert!(e.reason.contains("required"), "{e}");
    }

    #[test]
    fn a_move_shorter_than_two_periods_is_refused() {
        refused_at(
            "kind = \"move\"\nto_m = 0.1\nduration_s = 1e-4",
            &["x"],
            "trajectory.duration_s",
        );
    }

    #[test]
    fn a_ramp_reaches_constant_velocity_and_returns_to_its_start() {
        let tr = built("kind = \"ramp\"\nvelocity_m_per_s = 0.05\naccel_s = 0.1\nconstant_s = 0.4\nreturn = true\ndwell_between_s = 0.05\nstart_m = 0.01", &["x"]);
        assert!((tr.duration_s() - (2.0 * 0.6 + 0.05)).abs() < 1e-12);
        let w = tr.steady_windows_s();
        assert_eq!(w.len(), 2);
        assert!((w[0][0] - 0.1).abs() < 1e-12 && (w[0][1] - 0.5).abs() < 1e-12);
        for k in 0..=40 {
            let t = 0.1 + 0.4 * k as f64 / 40.0;
            let s = at(tr.as_ref(), t)[0];
            assert!((s[1] - 0.05).abs() < 1e-12, "{t}: {s:?}");
            assert!(s[2].abs() < 1e-9);
        }
        // Distance out = V (T_a + T_c) = 0.025 m.
        let turn = at(tr.as_ref(), 0.62)[0];
        assert!((turn[0] - 0.035).abs() < 1e-12, "{turn:?}");
        let worst = check_derivatives(tr.as_ref(), 300, 1e-6, &[]);
        assert!(worst < 1e-5, "{worst}");
        let end = at(tr.as_ref(), 10.0)[0];
        assert!((end[0] - 0.01).abs() < 1e-12);
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn a_ramp_without_velocity_names_the_key() {
        refused_at(
            "kind = \"ramp\"\naccel_s = 0.1\nconstant_s = 1",
            &["x"],
            "trajectory.velocity_m_per_s",
        );
    }

    #[test]
    fn a_sequence_chains_its_segments_continuously_and_repeats() {
        const REVERSAL: &str = r#"
kind = "sequence"
start_m = { x = 0.0 }
repeat = 2
[[segments]]
kind = "move"
by_m = { x = 0.01, y = 0.005 }
duration_s = 0.2
[[segments]]
kind = "dwell"
duration_s = 0.05
[[segments]]
kind = "move"
to_m = { x = 0.0, y = 0.0 }
profile = "jerk_limited"
max_velocity_m_per_s = 0.1
max_accel_m_per_s2 = 1.0
max_jerk_m_per_s3 = 100.0
[[segments]]
kind = "ramp"
velocity_m_per_s = { x = -0.02 }
accel_s = 0.05
constant_s = 0.1
"#;
        let tr = built(REVERSAL, &["x", "y"]);
        // C5 move 0.2 + dwell 0.05 + S-curve + ramp 0.2, twice.
        let d = tr.duration_s();
        assert!(d > 2.0 * 0.45 && d < 3.0, "{d}");
        // Position and velocity continuous everywhere (sampled finely across all joins).
        let n = 200_000;
        let h = d / n as f64;
        let mut prev = at(tr.as_ref(), 0.0);
        for k in 1..=n {
            let s = at(tr.as_ref(), k as f64 * h);
            for a in 0..2 {
                assert!(
                    (s[a][0] - prev[a][0]).abs() < 0.2 * h + 1e-15,
                    "pos jump at {}",
                    k as f64 * h
                );
                assert!(
                    (s[a][1] - prev[a][1]).abs() < 1e-2,
                    "vel jump at {}",
                    k as f64 * h
                );
            }
            prev = s;
        }
        // Each pass ends with the ramp from x = 0 (the absolute move) to -0.02 * (0.05 + 0.1).
        let end = at(tr.as_ref(), d + 1.0);
        assert!((end[0][0] - (-0.003)).abs() < 1e-12, "{:?}", end[0]);
        assert!(end[1][0].abs() < 1e-15);
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn a_sequence_of_c5_segments_has_continuous_derivatives_up_to_the_fifth_at_its_joins() {
        let tr = built("kind = \"sequence\"\n[[segments]]\nkind = \"move\"\nby_m = 0.01\nduration_s = 0.1\n[[segments]]\nkind = \"move\"\nby_m = -0.02\nduration_s = 0.1\n[[segments]]\nkind = \"ramp\"\nvelocity_m_per_s = 0.1\naccel_s = 0.05\nconstant_s = 0.0\n", &["x"]);
        for join in [0.1, 0.2, 0.25] {
            let lo = at(tr.as_ref(), join - 1e-9)[0];
            let hi = at(tr.as_ref(), join + 1e-9)[0];
            let peaks = [0.01, 0.3, 30.0, 5e3, 1e6, 2e8];
            for d in 0..6 {
                assert!(
                    (lo[d] - hi[d]).abs() < 1e-5 * peaks[d],
                    "derivative {d} jumps at {join}: {} vs {}",
                    lo[d],
                    hi[d]
                );
            }
        }
        let worst = check_derivatives(tr.as_ref(), 300, 1e-7, &[]);
        assert!(worst < 1e-4, "{worst}");
    }

    #[test]
    fn a_sequence_segment_with_a_bad_key_is_named_by_index() {
        refused_at("kind = \"sequence\"\n[[segments]]\nkind = \"dwell\"\nduration_s = 1\n[[segments]]\nkind = \"move\"\nby_m = 0.01\nduration_s = 0.1\nspeed = 3\n", &["x"], "trajectory.segments[1].speed");
        refused_at("kind = \"sequence\"\n[[segments]]\nkind = \"move\"\nto_m = { q = 1 }\nduration_s = 0.1\n", &["x"], "trajectory.segments[0].to_m.q");
    }
}
