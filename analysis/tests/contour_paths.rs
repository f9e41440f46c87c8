//! Contour errors of general 2-D paths, end to end, with a P/PI cascade that lags the command by
//! up to 1.7 mm: the distance from the table to the commanded path, not the lag behind the
//! command.
//!
//! The shipped `xy-program` job (a plate outline with corners, a dwell, rapids, a full circle and
//! a reversal): every row's contour error is checked two ways:
//! - against the simulated command itself: the distance from the table to the polyline of the
//!   commanded positions of the cycles in the same time window (2 s back, 0.5 s ahead), found by
//!   brute force (every 25th row);
//! - against the *programmed* geometry (lines and arcs of the parsed program): the commanded path
//!   is the programmed one with corners cut by at most `corner_tolerance_m`, so the distance to
//!   the programmed path exceeds the contour error by at most that (it can be far smaller where
//!   the program passes the same place at another time).

mod controllers_util;

use controllers_util::{examples, job_from_text};
use feedloop_analysis::sim::{simulate, ContourJudge, Simulation};
use feedloop_model::job::Job;
use feedloop_motion::gcode::parse_program;
use feedloop_motion::path_index::{WINDOW_AHEAD_S, WINDOW_BEHIND_S};
use feedloop_plugins::Builtins;
use feedloop_trace::log::AxisRecord;

fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let l2 = dx * dx + dy * dy;
    let s = if l2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - s * dx).hypot(p[1] - a[1] - s * dy)
}

/// The largest following error of any axis of the run, load units.
fn max_following_error(report: &feedloop_analysis::sim::SimReport) -> f64 {
    report
        .tracking
        .axes()
        .values()
        .map(|a| a.max_following_error)
        .fold(0.0, f64::max)
}

/// Whether the table of row `r` lags the command by more than 100 um while its contour error
/// `e` is under a tenth of that lag.
fn lags_far_behind(r: &[AxisRecord; 2], e: f64) -> bool {
    let lag = (r[0].cmd - r[0].load).hypot(r[1].cmd - r[1].load);
    lag > 1e-4 && e.abs() < 0.1 * lag
}

#[test]
fn program_contour_error_is_the_distance_to_the_path_not_the_lag_behind_the_command() {
    let job = Job::load(&examples().join("jobs/xy-program.toml")).unwrap();
    let tol = job.trajectory["corner_tolerance_m"].as_float().unwrap();
    let file = examples().join("programs/plate.nc");
    let program = parse_program(&file, &std::fs::read_to_string(&file).unwrap()).unwrap();

    let report = simulate(&job, &Builtins, None, &mut |_, _| {}).unwrap();
    let summary = report.tracking.contour().expect("a program has a contour");

    let mut sim = Simulation::new(&job, &Builtins).unwrap();
    let judge = ContourJudge::new(&job, &sim.cycle);
    let n = sim.cycles() as usize;
    let mut rows = vec![[AxisRecord::default(); 2]; n];
    let mut errors = Vec::with_capacity(n);
    for (k, r) in rows.iter_mut().enumerate() {
        sim.step(r);
        errors.push(
            judge
                .error_m(&sim.cycle, sim.cycle.time_of(k as u64), r)
                .unwrap(),
        );
    }
    let h = job.period_s;
    let (behind, ahead) = (
        (WINDOW_BEHIND_S / h).round() as usize,
        (WINDOW_AHEAD_S / h).round() as usize,
    );
    let (mut max_contour, mut worst_brute, mut brute_checks) = (0.0f64, 0.0f64, 0);
    let (mut max_programmed, mut far_behind) = (0.0f64, 0);
    for (k, (r, e)) in rows.iter().zip(&errors).enumerate() {
        let p = [r[0].load, r[1].load];
        max_contour = max_contour.max(e.abs());
        let d = program.distance_xy_m(p);
        max_programmed = max_programmed.max(d);
        assert!(
            d <= e.abs() + tol + 1e-9,
            "cycle {k}: contour error {e}, distance to the programmed path {d}"
        );
        if k % 25 == 0 {
            let cmd = |j: usize| [rows[j][0].cmd, rows[j][1].cmd];
            let brute = (k.saturating_sub(behind)..(k + ahead).min(n - 1))
                .map(|j| segment_distance(p, cmd(j), cmd(j + 1)))
                .fold(f64::INFINITY, f64::min);
            assert!(
                (e.abs() - brute).abs() <= 5e-9,
                "cycle {k}: contour error {e}, brute force over the commanded positions {brute}"
            );
            worst_brute = worst_brute.max((e.abs() - brute).abs());
            brute_checks += 1;
        }
        if lags_far_behind(r, *e) {
            far_behind += 1;
        }
    }
    let following = max_following_error(&report);
    println!(
        "xy-program: max following error {:.1} um, max contour error {:.2} um (summary {:.2} um); \
         {brute_checks} rows within {:.1e} m of brute force; max distance to the programmed path \
         {:.2} um; {far_behind} rows lag > 100 um with a contour error under a tenth of it",
        following * 1e6,
        max_contour * 1e6,
        summary.max_error * 1e6,
        worst_brute,
        max_programmed * 1e6,
    );
    assert_eq!(
        summary.max_error, max_contour,
        "the summary reports the same rows"
    );
    assert!(
        following > 10.0 * max_contour,
        "{following} vs {max_contour}"
    );
    assert!(far_behind > 10_000, "{far_behind}");
}

/// A `sequence` of straight moves on two axes: a corner taken at rest, a dwell, a diagonal and a
/// reversal back along it. The commanded path is exactly the polyline through the move targets
/// (each move is a straight line between rests), so every row's contour error must equal the
/// distance from the table to that polyline, computed here on its own.
#[test]
fn sequence_contour_error_is_the_distance_to_the_polyline_through_its_targets() {
    let job = job_from_text(
        "contour-sequence",
        r#"
period_s = 1.0e-4
[axes.x]
model = "{examples}/models/xy-x.toml"
[axes.y]
model = "{examples}/models/xy-y.toml"
[trajectory]
kind = "sequence"
[[trajectory.segments]]
kind = "move"
by_m = { x = 0.01 }
duration_s = 0.3
[[trajectory.segments]]
kind = "move"
by_m = { y = 0.01 }
duration_s = 0.3
[[trajectory.segments]]
kind = "dwell"
duration_s = 0.05
[[trajectory.segments]]
kind = "move"
by_m = { x = -0.02, y = -0.005 }
duration_s = 0.4
[[trajectory.segments]]
kind = "move"
by_m = { x = 0.015, y = 0.00375 }
duration_s = 0.3
"#,
    );
    let corners = [
        [0.0, 0.0],
        [0.01, 0.0],
        [0.01, 0.01],
        [-0.01, 0.005],
        [0.005, 0.00875],
    ];
    let report = simulate(&job, &Builtins, None, &mut |_, _| {}).unwrap();
    let summary = report
        .tracking
        .contour()
        .expect("two driven axes have a contour");
    let mut sim = Simulation::new(&job, &Builtins).unwrap();
    let judge = ContourJudge::new(&job, &sim.cycle);
    let mut r = [AxisRecord::default(); 2];
    let (mut max_polyline, mut far_behind) = (0.0f64, 0);
    for k in 0..sim.cycles() {
        sim.step(&mut r);
        let e = judge.error_m(&sim.cycle, sim.cycle.time_of(k), &r).unwrap();
        let p = [r[0].load, r[1].load];
        let d = corners
            .windows(2)
            .map(|w| segment_distance(p, w[0], w[1]))
            .fold(f64::INFINITY, f64::min);
        assert!(
            (e.abs() - d).abs() < 1e-9,
            "cycle {k}: contour error {e}, distance to the polyline {d}"
        );
        max_polyline = max_polyline.max(d);
        if lags_far_behind(&r, d) {
            far_behind += 1;
        }
    }
    let following = max_following_error(&report);
    println!(
        "sequence: max following error {:.1} um, contour error max {:.4} um (summary), distance \
         to the polyline max {:.4} um; {far_behind} rows lag > 100 um",
        following * 1e6,
        summary.max_error * 1e6,
        max_polyline * 1e6
    );
    assert!((summary.max_error - max_polyline).abs() < 1e-9);
    assert!(following > 100.0 * summary.max_error);
    assert!(far_behind > 5_000, "{far_behind}");
}
