//! The contour error of a part program, end to end: the shipped `xy-program` job (a plate outline
//! with corners, a dwell, rapids, a full circle and a reversal) simulated with a P/PI cascade that
//! lags the command by up to 1 mm. Every row's contour error is checked two ways:
//! - against the simulated command itself: the distance from the table to the polyline of the
//!   commanded positions of the cycles in the same time window (2 s back, 0.5 s ahead), found by
//!   brute force (every 25th row);
//! - against the *programmed* geometry (lines and arcs of the parsed program): the commanded path
//!   is the programmed one with corners cut by at most `corner_tolerance_m`, so the distance to
//!   the programmed path exceeds the contour error by at most that (it can be far smaller where
//!   the program passes the same place at another time).

mod controllers_util;

use controllers_util::examples;
use feedloop_analysis::sim::{simulate, Simulation};
use feedloop_plugins::Builtins;
use feedloop_runtime::job::Job;
use feedloop_runtime::record::AxisRecord;
use feedloop_runtime::trajectory::gcode::parse_program;
use feedloop_runtime::trajectory::path_index::{WINDOW_AHEAD_S, WINDOW_BEHIND_S};

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

#[test]
fn program_contour_error_is_the_distance_to_the_path_not_the_lag_behind_the_command() {
    let job = Job::load(&examples().join("jobs/xy-program.toml")).unwrap();
    let tol = job.trajectory["corner_tolerance_m"].as_float().unwrap();
    let file = examples().join("programs/plate.nc");
    let program = parse_program(&file, &std::fs::read_to_string(&file).unwrap()).unwrap();

    let report = simulate(&job, &Builtins, None, &mut |_, _| {}).unwrap();
    let summary = report.tracking.contour().expect("a program has a contour");

    let mut sim = Simulation::new(&job, &Builtins).unwrap();
    let n = sim.cycles() as usize;
    let mut rows = vec![[AxisRecord::default(); 2]; n];
    let mut errors = Vec::with_capacity(n);
    for (k, r) in rows.iter_mut().enumerate() {
        sim.step(r);
        let e = sim
            .cycle
            .trajectory()
            .contour_error_m(sim.cycle.time_of(k as u64), &[r[0].load, r[1].load])
            .unwrap();
        errors.push(e);
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
        let lag = (r[0].cmd - p[0]).hypot(r[1].cmd - p[1]);
        if lag > 1e-4 && e.abs() < 0.1 * lag {
            far_behind += 1;
        }
    }
    let following = report
        .tracking
        .axes()
        .values()
        .map(|a| a.max_following_error)
        .fold(0.0, f64::max);
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
