//! Command trajectories with analytic derivatives up to the 5th.
//!
//! A trajectory gives, for every axis of the job (in job order) and any time `t` (s), the
//! reference `[p, p', p'', p''', p'''', p''''']` in load units (m or rad) per s^n. `t = 0` is
//! the first control cycle; before it the start is held, after [`Trajectory::duration_s`] the
//! final position is held with zero derivatives. Kinds (`kind = "..."` in `[trajectory]`, every
//! key in `docs/trajectories.md`):
//!
//! - `dwell`: `p(t) = p0`.
//! - `move`: `p(t) = p_from + (p_to - p_from) s((t - t0) / T)` with the C5 smoothstep `s`
//!   (degree 11, derivatives 1..5 zero at both ends, see [`poly`]), or a 7-phase jerk-limited
//!   S-curve (`profile = "jerk_limited"`).
//! - `ramp`: velocity `v(t) = V s((t - t0) / T_a)` up, constant, and down again (optionally back).
//! - `sequence`: moves, ramps and dwells chained (`[[trajectory.segments]]`), optionally repeated.
//! - `circle`: `x = c_x + R cos(phi)`, `y = c_y + R sin(phi)`, `phi = phi_0 +- sigma(t) / R`
//!   where the arc length `sigma(t)` has a C5 feed ramp; derivatives by Faa di Bruno ([`jet`]).
//! - `trace`: the `A.cmd` columns of a trace file; derivatives from zero-phase local polynomial
//!   (Savitzky-Golay) fits ([`from_trace`]).
//! - `random_segments`, `prbs`, `multisine`: excitation commands for identification
//!   ([`excitation`]).
//! - `program`: a G-code subset (G0/G1/G2/G3/G4), planned with C5 velocity blending and
//!   look-ahead at corners ([`gcode`]).
//! - `xc_cam`: X-C cam grinding (seed 003): `X`, `C` from the profile `r(phi)` and the wheel
//!   radius, with the profile error and the coupling gains `Gx`, `Gc` ([`cam`]).
//!
//! Positions are continuous up to the 5th derivative everywhere except the jerk-limited profile
//! (jerk steps) and the ends of a `trace` command that does not start or end at rest.

use std::path::Path;

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::params::{ConfigError, Fields, Range};
use feedloop_model::MAX_AXES;

/// The [`Trajectory::axes`] (the field `axes`) and [`Trajectory::duration_s`] of a
/// trajectory: `axes_and_duration!(self => <duration>)`.
macro_rules! axes_and_duration {
    ($self:ident => $duration:expr) => {
        fn axes(&self) -> &[String] {
            &self.axes
        }

        fn duration_s(&$self) -> f64 {
            $duration
        }
    };
}

pub mod cam;
mod circle;
pub mod excitation;
pub mod from_trace;
pub mod gcode;
pub mod jet;
mod moves;
pub mod path_index;
pub mod poly;
pub mod traverse;
pub mod trig;

pub use excitation::write_excitation_csv;
pub use from_trace::{differentiate, TraceCommand};

/// Position and its time derivatives 1..5 of one axis, in load units (m or rad) per s^n.
pub type RefState = [f64; REF_DERIVS];

/// The geometry a contour error is measured against, in the plane of two job axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contour {
    /// Indices (job axis order) of the two axes: `[x, y]` for a plane, `[x, c]` for X-C.
    pub axes: [usize; 2],
    /// The shape.
    pub shape: ContourShape,
}

/// Shapes of [`Contour`]. Prefer [`Trajectory::contour_error_m`] to matching on this: it
/// computes the error for every shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ContourShape {
    /// A circle. Error = `|p - center| - radius` (m), positive outside.
    Circle {
        /// Centre `[x, y]`, m.
        center_m: [f64; 2],
        /// Radius, m.
        radius_m: f64,
    },
    /// The commanded path itself. Error = distance from the measured point to the nearest
    /// point of the commanded path around the current command (m), positive to the left of the
    /// direction of travel. Part programs search the path from 2 s before to 0.5 s after the
    /// command ([`path_index`]), across corners, dwells and reversals.
    Path,
    /// An X-C ground profile: the trajectory computes the profile error from both axes.
    Profile,
}

impl Contour {
    /// Radial error of a circle contour at the measured point `p` (m); `None` for other shapes.
    pub fn radial_error_m(&self, p: [f64; 2]) -> Option<f64> {
        match self.shape {
            ContourShape::Circle { center_m, radius_m } => {
                Some((p[0] - center_m[0]).hypot(p[1] - center_m[1]) - radius_m)
            }
            _ => None,
        }
    }
}

/// A command source for the axes of a job.
pub trait Trajectory: Send + Sync {
    /// Names of the axes it drives, in the order of `eval`'s output (the job's axes, job order,
    /// for every built-in kind).
    fn axes(&self) -> &[String];
    /// Length of the trajectory, s (after it ends, `eval` holds the final state).
    fn duration_s(&self) -> f64;
    /// Writes the reference of each driven axis at time `t_s` into `out` (`out.len() == axes().len()`).
    /// Must not allocate: it runs in the control cycle.
    fn eval(&self, t_s: f64, out: &mut [RefState]);

    /// The `kind` it was built from (e.g. `circle`).
    fn kind(&self) -> &str {
        "custom"
    }

    /// The contour the axes follow, if it is a 2-D contour (circle, path, X-C profile).
    fn contour(&self) -> Option<Contour> {
        None
    }

    /// Contour error at time `t_s` for the measured load positions `actual` (all axes, job
    /// order), m; `None` when the trajectory has no contour. Does not allocate in the control
    /// cycle. The default answers a circle; a trajectory whose contour needs its own geometry
    /// overrides it (the X-C cam's profile, a part program's path through its
    /// [`path_index::PathIndex`]).
    fn contour_error_m(&self, _t_s: f64, actual: &[f64]) -> Option<f64> {
        let c = self.contour()?;
        let p = [*actual.get(c.axes[0])?, *actual.get(c.axes[1])?];
        match c.shape {
            ContourShape::Circle { .. } => c.radial_error_m(p),
            ContourShape::Path | ContourShape::Profile => None,
        }
    }

    /// Time windows `[start, end]` (s) of constant commanded velocity (the steady-state parts a
    /// tuning criterion is evaluated over); empty when there are none.
    fn steady_windows_s(&self) -> Vec<[f64; 2]> {
        Vec::new()
    }

    /// Times (s) at which the trajectory changes its law (piece boundaries, motion starts and
    /// ends), for code that samples the path ([`path_index::PathIndex`]): a sampler that visits
    /// them never steps over a short motion or the start of a rest. Empty when unknown.
    fn breakpoints_s(&self) -> Vec<f64> {
        Vec::new()
    }
}

/// Builds the trajectory described by a job's `[trajectory]` table. `file` is the job file
/// (relative paths in the table are resolved from its folder), `job_axes` the job's axes in
/// order (every built-in kind drives all of them), `period_s` the control period.
pub fn build(
    table: &toml::Table,
    file: &Path,
    job_axes: &[String],
    period_s: f64,
) -> Result<Box<dyn Trajectory>, ConfigError> {
    build_at(table, file, "trajectory", job_axes, period_s)
}

/// Like [`build`] for a table found under the dotted key `prefix` (for messages).
pub fn build_at(
    table: &toml::Table,
    file: &Path,
    prefix: &str,
    job_axes: &[String],
    period_s: f64,
) -> Result<Box<dyn Trajectory>, ConfigError> {
    if job_axes.is_empty() || job_axes.len() > MAX_AXES {
        return Err(ConfigError::new(
            file,
            prefix,
            format!(
                "a trajectory drives 1..={MAX_AXES} axes, the job has {}",
                job_axes.len()
            ),
        ));
    }
    if !(period_s.is_finite() && period_s > 0.0) {
        return Err(ConfigError::new(
            file,
            prefix,
            format!("control period must be > 0 s, got {period_s}"),
        ));
    }
    let mut f = Fields::new(table, file, prefix);
    let kind = f.str("kind")?;
    let ctx = Ctx {
        axes: job_axes,
        period_s,
    };
    match kind {
        "dwell" => moves::dwell(f, &ctx),
        "move" => moves::single_move(f, &ctx),
        "ramp" => moves::ramp(f, &ctx),
        "sequence" => moves::sequence(f, &ctx),
        "circle" => circle::build(f, &ctx),
        "trace" => from_trace::build(f, &ctx),
        "random_segments" => excitation::random_segments(f, &ctx),
        "prbs" => excitation::prbs(f, &ctx),
        "multisine" => excitation::multisine(f, &ctx),
        "program" => gcode::build(f, &ctx),
        "xc_cam" => cam::build(f, &ctx),
        other => Err(f.error(
            "kind",
            format!(
                "unknown trajectory kind `{other}` (known: {})",
                KINDS.join(", ")
            ),
        )),
    }
}

/// The kinds [`build`] knows.
pub const KINDS: &[&str] = &[
    "dwell",
    "move",
    "ramp",
    "sequence",
    "circle",
    "trace",
    "random_segments",
    "prbs",
    "multisine",
    "program",
    "xc_cam",
];

/// What every kind's builder needs to know about the job.
pub(crate) struct Ctx<'a> {
    pub axes: &'a [String],
    pub period_s: f64,
}

impl Ctx<'_> {
    /// Refuses a duration (s) shorter than `n` control periods.
    pub fn at_least_periods(
        &self,
        f: &Fields,
        key: &str,
        value: f64,
        n: f64,
    ) -> Result<(), ConfigError> {
        if value < n * self.period_s * (1.0 - 1e-9) {
            return Err(f.error(
                key,
                format!(
                    "{value} s is shorter than {n} control periods ({} s)",
                    n * self.period_s
                ),
            ));
        }
        Ok(())
    }

    /// Index of axis `name`, or an error at `key`.
    pub fn axis_index(&self, f: &Fields, key: &str, name: &str) -> Result<usize, ConfigError> {
        self.axes.iter().position(|a| a == name).ok_or_else(|| {
            f.error(
                key,
                format!(
                    "`{name}` is not an axis of this job (axes: {})",
                    self.axes.join(", ")
                ),
            )
        })
    }
}

fn number(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Float(x) => Some(*x),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

/// Reads one per-axis quantity from `key`: a table keyed by axis name (`{ x = 0.05 }`), an
/// array in job axis order, or a plain number when the job has one axis.
fn per_axis_one(
    f: &mut Fields,
    key: &str,
    axes: &[String],
    range: Range,
) -> Result<Option<Vec<Option<f64>>>, ConfigError> {
    let Some(v) = f.raw(key) else {
        return Ok(None);
    };
    let mut out = vec![None; axes.len()];
    let check = |f: &Fields, k: &str, x: &toml::Value| -> Result<f64, ConfigError> {
        let n = number(x)
            .ok_or_else(|| f.wrong_type(k, format!("must be a number, got {}", x.type_str())))?;
        range.check(n).map_err(|r| f.out_of_range(k, r.0))?;
        Ok(n)
    };
    match v {
        toml::Value::Table(t) => {
            for (name, x) in t {
                let k = format!("{key}.{name}");
                let i = axes.iter().position(|a| a == name).ok_or_else(|| {
                    f.error(
                        &k,
                        format!(
                            "`{name}` is not an axis of this job (axes: {})",
                            axes.join(", ")
                        ),
                    )
                })?;
                out[i] = Some(check(f, &k, x)?);
            }
        }
        toml::Value::Array(arr) => {
            if arr.len() != axes.len() {
                return Err(f.error(
                    key,
                    format!(
                        "array has {} values, the job has {} axes ({}); or give a table {{ {} = ... }}",
                        arr.len(),
                        axes.len(),
                        axes.join(", "),
                        axes[0]
                    ),
                ));
            }
            for (i, x) in arr.iter().enumerate() {
                out[i] = Some(check(f, &format!("{key}[{i}]"), x)?);
            }
        }
        x if number(x).is_some() => {
            if axes.len() != 1 {
                return Err(f.error(
                    key,
                    format!(
                        "the job has {} axes ({}): give a table keyed by axis name, e.g. {{ {} = ... }}",
                        axes.len(),
                        axes.join(", "),
                        axes[0]
                    ),
                ));
            }
            out[0] = Some(check(f, key, x)?);
        }
        other => {
            return Err(f.error(
                key,
                format!(
                    "must be a table keyed by axis name, an array or a number, got {}",
                    other.type_str()
                ),
            ))
        }
    }
    Ok(Some(out))
}

/// Reads a per-axis quantity that may be given for linear axes under `key_m` and for rotary
/// axes under `key_rad` (both optional; an axis in both is refused). `None` per axis not given.
pub(crate) fn per_axis(
    f: &mut Fields,
    key_m: &str,
    key_rad: &str,
    axes: &[String],
    range: Range,
) -> Result<Vec<Option<f64>>, ConfigError> {
    let m = per_axis_one(f, key_m, axes, range)?;
    let r = per_axis_one(f, key_rad, axes, range)?;
    let mut out = vec![None; axes.len()];
    for (i, o) in out.iter_mut().enumerate() {
        let a = m.as_ref().and_then(|v| v[i]);
        let b = r.as_ref().and_then(|v| v[i]);
        if a.is_some() && b.is_some() {
            return Err(f.error(
                key_rad,
                format!("axis `{}` is also given in `{key_m}`", axes[i]),
            ));
        }
        *o = a.or(b);
    }
    Ok(out)
}

/// A trajectory that is one piecewise polynomial over all job axes.
pub(crate) struct PolyTrajectory {
    pub kind: &'static str,
    pub axes: Vec<String>,
    pub poly: poly::PiecewisePoly,
    pub windows: Vec<[f64; 2]>,
}

impl Trajectory for PolyTrajectory {
    axes_and_duration!(self => self.poly.end_s());
    fn eval(&self, t_s: f64, out: &mut [RefState]) {
        self.poly.eval(t_s, out)
    }
    fn kind(&self) -> &str {
        self.kind
    }
    fn steady_windows_s(&self) -> Vec<[f64; 2]> {
        self.windows.clone()
    }
    fn breakpoints_s(&self) -> Vec<f64> {
        self.poly.piece_starts().to_vec()
    }
}

#[cfg(test)]
pub(crate) mod test_util {
    //! Shared checks for the trajectory tests.
    use super::*;

    /// Parses `[trajectory]` TOML text and builds it for `axes` at 10 kHz.
    pub fn build_str(text: &str, axes: &[&str]) -> Result<Box<dyn Trajectory>, ConfigError> {
        let t: toml::Table = text.parse().expect("test TOML");
        let axes: Vec<String> = axes.iter().map(|s| s.to_string()).collect();
        build(&t, Path::new("job.toml"), &axes, 1e-4)
    }

    /// Builds `[trajectory]` TOML text that must be valid.
    pub fn built(text: &str, axes: &[&str]) -> Box<dyn Trajectory> {
        build_str(text, axes).expect("a valid trajectory")
    }

    /// Builds `[trajectory]` TOML text that must be refused and returns the error.
    pub fn refused(text: &str, axes: &[&str]) -> ConfigError {
        build_str(text, axes)
            .err()
            .expect("the trajectory is refused")
    }

    /// Builds `[trajectory]` TOML text that must be refused at `key` and returns the error.
    pub fn refused_at(text: &str, axes: &[&str], key: &str) -> ConfigError {
        let e = refused(text, axes);
        assert_eq!(e.key, key, "{e}");
        e
    }

    /// Evaluates all axes at `t`.
    pub fn at(tr: &dyn Trajectory, t: f64) -> Vec<RefState> {
        let mut out = vec![[0.0; REF_DERIVS]; tr.axes().len()];
        tr.eval(t, &mut out);
        out
    }

    /// Checks every derivative d = 1..5 against the central difference of derivative d-1 at
    /// `n` points spread over the trajectory (skipping points within `h` of `skip` times where
    /// a derivative may step). Returns the worst relative error seen.
    pub fn check_derivatives(tr: &dyn Trajectory, n: usize, h: f64, skip: &[f64]) -> f64 {
        let dur = tr.duration_s();
        let mut worst: f64 = 0.0;
        let axes = tr.axes().len();
        let mut peak = vec![[0.0f64; REF_DERIVS]; axes];
        for k in 0..=n {
            let t = dur * k as f64 / n as f64;
            for (a, s) in at(tr, t).iter().enumerate() {
                for d in 0..REF_DERIVS {
                    peak[a][d] = peak[a][d].max(s[d].abs());
                }
            }
        }
        for k in 1..n {
            let t = dur * (k as f64 + 0.37) / n as f64;
            if skip.iter().any(|s| (t - s).abs() < 3.0 * h) {
                continue;
            }
            let lo = at(tr, t - h);
            let mid = at(tr, t);
            let hi = at(tr, t + h);
            for a in 0..axes {
                for d in 1..REF_DERIVS {
                    let fd = (hi[a][d - 1] - lo[a][d - 1]) / (2.0 * h);
                    let scale = peak[a][d].max(1e-12);
                    let err = (fd - mid[a][d]).abs() / scale;
                    assert!(
                        err < 1e-4,
                        "{}: axis {a} derivative {d} at t = {t}: analytic {} vs central difference {fd} (peak {scale})",
                        tr.kind(),
                        mid[a][d]
                    );
                    worst = worst.max(err);
                }
            }
        }
        worst
    }

    /// Checks that the final state is held with zero derivatives after the end.
    pub fn check_final_hold(tr: &dyn Trajectory) {
        let end = tr.duration_s();
        let last = at(tr, end);
        for t in [end + 1e-4, end + 1.0, end + 1e3] {
            let s = at(tr, t);
            for (a, (x, y)) in s.iter().zip(&last).enumerate() {
                assert_eq!(x[0], y[0], "axis {a} position moves after the end");
                assert!(x[1..].iter().all(|v| *v == 0.0), "axis {a}: {x:?}");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::test_util::*;

    #[test]
    fn an_unknown_kind_is_refused_listing_the_known_ones() {
        let e = refused_at("kind = \"spiral\"", &["x"], "trajectory.kind");
        assert!(e.reason.contains("circle"), "{e}");
    }

    #[test]
    fn an_unknown_key_is_refused_with_its_dotted_path() {
        let e = refused_at(
            "kind = \"dwell\"\nduration_s = 1\nspeed = 2",
            &["x"],
            "trajectory.speed",
        );
        assert!(e
            .to_string()
            .starts_with("job.toml: key `trajectory.speed`"));
    }

    #[test]
    fn a_dwell_holds_its_positions_for_its_duration() {
        let tr = built("kind = \"dwell\"\nduration_s = 0.5\nposition_m = { y = 0.01 }\nposition_rad = { c = 1.5 }", &["x", "y", "c"]);
        assert_eq!(tr.duration_s(), 0.5);
        let s = at(tr.as_ref(), 0.25);
        assert_eq!([s[0][0], s[1][0], s[2][0]], [0.0, 0.01, 1.5]);
        check_final_hold(tr.as_ref());
    }

    #[test]
    fn an_axis_in_both_metre_and_radian_keys_is_refused() {
        refused_at(
            "kind = \"dwell\"\nposition_m = { x = 0.01 }\nposition_rad = { x = 1 }",
            &["x"],
            "trajectory.position_rad",
        );
    }

    #[test]
    fn a_multi_axis_position_is_refused_unless_a_table_of_its_axes() {
        // (position_m, the key refused, what the reason says)
        for (position, key, reason) in [
            ("{ z = 0.01 }", "trajectory.position_m.z", "axes: x, y"),
            ("0.01", "trajectory.position_m", "table keyed by axis name"),
        ] {
            let text = format!("kind = \"dwell\"\nposition_m = {position}");
            let e = refused_at(&text, &["x", "y"], key);
            assert!(e.reason.contains(reason), "{e}");
        }
    }
}

#[cfg(test)]
mod timing {
    use super::test_util::*;
    use super::*;

    /// Measures (does not assert) the cost of one `eval` per kind: `cargo test --release -p
    /// feedloop-runtime eval_cost -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn eval_cost_is_measured_per_kind() {
        let cases = [
            ("move", "kind = \"move\"\nto_m = 0.05\nduration_s = 0.3", vec!["x"]),
            (
                "circle",
                "kind = \"circle\"\ncenter_m = [-0.01, 0]\nradius_m = 0.01\nfeed_m_per_s = 0.0333\nturns = 2",
                vec!["x", "y"],
            ),
            (
                "multisine 100 lines",
                "kind = \"multisine\"\namplitude_m_per_s = 0.01\nsignal_period_s = 1\nf_min_hz = 1\nf_max_hz = 100",
                vec!["x"],
            ),
            (
                "random_segments",
                "kind = \"random_segments\"\nvelocity_m_per_s = 0.02\nmin_segment_s = 0.01\nmax_segment_s = 0.05\nduration_s = 60\nmax_travel_m = 0.01",
                vec!["x"],
            ),
            (
                "xc_cam table 32 harmonics",
                "kind = \"xc_cam\"\nwheel_radius_m = 0.2\nprofile = \"table\"\nradius_table_m = [0.03, 0.031, 0.032, 0.031, 0.03, 0.029, 0.028, 0.029, 0.03, 0.031, 0.032, 0.031, 0.03, 0.029, 0.028, 0.029]\nspeed_rad_per_s = 6\nturns = 3",
                vec!["x", "c"],
            ),
        ];
        for (name, text, axes) in cases {
            let tr = build_str(text, &axes).unwrap();
            let mut out = vec![[0.0; REF_DERIVS]; axes.len()];
            let n = 200_000;
            let dur = tr.duration_s();
            let start = std::time::Instant::now();
            let mut acc = 0.0;
            for k in 0..n {
                tr.eval(dur * k as f64 / n as f64, &mut out);
                acc += out[0][5];
            }
            let ns = start.elapsed().as_secs_f64() / n as f64 * 1e9;
            println!("{name}: {ns:.0} ns per eval ({acc:.1e})");
        }
    }
}
