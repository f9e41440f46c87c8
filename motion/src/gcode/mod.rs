//! Kind `program`: a small G-code subset planned into a C5-blended trajectory with look-ahead.
//!
//! # Language
//! `G0` rapid, `G1` line, `G2`/`G3` cw/ccw arc in the X-Y plane with centre offsets `I`, `J`
//! (incremental from the arc's start; end point = start gives a full circle), `G4 P<s>` dwell
//! (seconds), `G17` (X-Y plane, the only one), `G21` (mm, the only unit), `G90`/`G91`
//! absolute/incremental, `F` feed in mm/min, `X Y Z` in mm, `N` line numbers (ignored), `M2`/`M30`
//! end of program, comments in `( )` and after `;`, `%` lines ignored. Anything else is refused
//! with the file, the line and the word.
//!
//! # Planning (velocity blending)
//! Each motion segment `i` (length `L_i`, unit-speed path `P_i(sigma)`) is traversed by an
//! arc-length profile `sigma_i(t)`: speed `F_i s(u)` over `A_i`, `F_i` for `C_i`, `F_i (1 - s(u))`
//! over `D_i`, so `L_i = F_i (A_i/2 + C_i + D_i/2)`. The deceleration of segment `i` and the
//! acceleration of segment `i+1` run at the same time (`D_i = A_(i+1) = B_i`); the command is the
//! sum of the segments' displacements:
//!
//! `p(t) = Q_i + [P_i(sigma_i(t)) - P_i(0)] + [P_(i+1)(sigma_(i+1)(t)) - P_(i+1)(0)]`
//!
//! where `Q_i` is the programmed start of the earliest unfinished segment. In a blend the velocity
//! moves from `F_i T_i` to `F_(i+1) T_(i+1)` along `s(u)`: collinear segments join at exactly the
//! feed, corners are rounded. Every term is C5, so position and derivatives 1..5 are continuous;
//! derivatives come from jets ([`super::jet`]) of `sigma_i` through the line or arc geometry.
//!
//! With the velocity change `dv = |F_(i+1) T_(i+1) - F_i T_i|` at a corner, the blend time is
//! `B >= max(2.707 dv / a, sqrt(11.27 dv / j), 2.707 da / j, 4 periods)` (`a`, `j` the
//! acceleration and jerk budgets, `da` the change of centripetal acceleration), and the corner
//! is cut by `0.0564 B dv` (the path at mid-blend). Look-ahead lowers the feeds on both sides of a
//! corner until that deviation is within `corner_tolerance_m`, lowers the feed on arcs to
//! `F^2 / R <= a/2` and `F^3 / R^2 <= j/2`, and lowers a segment's feed until its blends fit in
//! it (`C_i >= 0`). Where an arc meets a blend the tangential budget is halved. A dwell (or the
//! program's start and end) brings the path to rest.
//!
//! The commanded path (the blended one) is a [`super::ContourShape::Path`]: contour error =
//! distance from the measured point to it, searched over the path around the current command
//! ([`super::path_index`]); the programmed geometry is [`Program::segments`].
//!
//! # Layout
//! `parse` reads the program text into [`Program`] (programmed geometry, metres);
//! `plan` turns it into timed motions with look-ahead ([`ProgramTrajectory::plan`]);
//! `evaluate` gives the command and its derivatives at a time (the [`Trajectory`] face).
//! This file reads the job's `[trajectory]` keys and ties the three together.

mod evaluate;
mod parse;
mod plan;

pub use parse::{parse_program, GcodeError, PathSegment, Program};
pub use plan::{PlanLimits, ProgramTrajectory, H_HALF, SMOOTHSTEP_PEAK_CURVATURE};

use std::path::Path;

use feedloop_model::params::{ConfigError, Fields, Range};

use super::{per_axis, Ctx, Trajectory};

/// `kind = "program"`.
pub(crate) fn build(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let rel = f.str("file")?;
    let path = f.file().parent().unwrap_or(Path::new(".")).join(rel);
    let v = f.f64("max_velocity_m_per_s", Range::Positive)?;
    let a = f.f64("max_accel_m_per_s2", Range::Positive)?;
    let j = f.f64("max_jerk_m_per_s3", Range::Positive)?;
    let tol = f.f64_or("corner_tolerance_m", Range::Positive, 1e-5)?;
    let mut map: [Option<usize>; 3] = [0, 1, 2].map(|k| {
        let letter = ["x", "y", "z"][k];
        ctx.axes.iter().position(|a| a == letter)
    });
    if let Some(t) = f.opt_table("axes")? {
        map = [None; 3];
        for (letter, name) in t {
            let key = format!("axes.{letter}");
            let k = ["x", "y", "z"]
                .iter()
                .position(|l| l == letter)
                .ok_or_else(|| f.error(&key, "program axes are x, y and z"))?;
            let name = name.as_str().ok_or_else(|| {
                f.error(
                    &key,
                    format!("must be a job axis name, got {}", name.type_str()),
                )
            })?;
            map[k] = Some(ctx.axis_index(&f, &key, name)?);
        }
    }
    let origin: Vec<f64> = per_axis(&mut f, "origin_m", "origin_rad", ctx.axes, Range::Finite)?
        .into_iter()
        .map(|v| v.unwrap_or(0.0))
        .collect();
    let before = f.f64_or("dwell_before_s", Range::NonNegative, 0.0)?;
    let after = f.f64_or("dwell_after_s", Range::NonNegative, 0.0)?;
    let file = f.file();
    let k_file = f.path("file");
    f.finish()?;
    let text = std::fs::read_to_string(&path).map_err(|e| {
        ConfigError::new(
            file,
            &k_file,
            format!("cannot read {}: {e}", path.display()),
        )
    })?;
    let program =
        parse_program(&path, &text).map_err(|e| ConfigError::new(file, &k_file, e.to_string()))?;
    for (k, used) in program.uses.iter().enumerate() {
        if *used && map[k].is_none() {
            let letter = ["X", "Y", "Z"][k];
            return Err(ConfigError::new(
                file,
                &k_file,
                format!(
                    "{} uses {letter}, which is not mapped to a job axis (axes: {}); map it with axes = {{ {} = \"...\" }}",
                    path.display(),
                    ctx.axes.join(", "),
                    letter.to_ascii_lowercase()
                ),
            ));
        }
    }
    let limits = PlanLimits {
        max_velocity_m_per_s: v,
        max_accel_m_per_s2: a,
        max_jerk_m_per_s3: j,
        corner_tolerance_m: tol,
        min_blend_s: 4.0 * ctx.period_s,
    };
    Ok(Box::new(ProgramTrajectory::plan(
        program, ctx.axes, map, origin, limits, before, after,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    pub(super) fn parse(text: &str) -> Result<Program, GcodeError> {
        parse_program(Path::new("part.nc"), text)
    }

    pub(super) fn write_job_dir(tag: &str, program: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("feedloop-gcode-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("part.nc"), program).unwrap();
        d
    }

    pub(super) fn build_program(
        dir: &Path,
        extra: &str,
        axes: &[&str],
    ) -> Result<Box<dyn Trajectory>, ConfigError> {
        let text = format!(
            "kind = \"program\"\nfile = \"part.nc\"\nmax_velocity_m_per_s = 0.05\nmax_accel_m_per_s2 = 1.0\nmax_jerk_m_per_s3 = 100.0\n{extra}"
        );
        let t: toml::Table = text.parse().unwrap();
        let axes: Vec<String> = axes.iter().map(|s| s.to_string()).collect();
        crate::build(&t, &dir.join("job.toml"), &axes, 1e-4)
    }

    pub(super) const PART: &str = "G21 G90 G17\nG1 X20 F1800\nG1 X20 Y10\nG3 X10 Y20 I-10 J0\nG1 X0 Y20\nG1 X0 Y0\nG4 P0.2\nG1 X5 Y0\nG1 X10 Y0\n";

    #[test]
    fn an_unmapped_program_axis_and_a_bad_line_are_reported() {
        let dir = write_job_dir("map", "G1 F100 X1 Z2\n");
        let e = build_program(&dir, "", &["x", "y"]).err().unwrap();
        assert_eq!(e.key, "trajectory.file");
        assert!(e.reason.contains("uses Z"), "{e}");
        std::fs::write(dir.join("part.nc"), "G1 F100 X1\nG1 Q7\n").unwrap();
        let e = build_program(&dir, "", &["x", "y"]).err().unwrap();
        assert!(
            e.reason.contains("part.nc: line 2: unsupported word `Q7`"),
            "{e}"
        );
        let e = build_program(&dir, "axes = { w = \"x\" }\n", &["x", "y"])
            .err()
            .unwrap();
        assert_eq!(e.key, "trajectory.axes.w");
        std::fs::remove_dir_all(&dir).ok();
    }
}
