//! A circle test run both ways (`direction = "ccw_cw"`), the reversal study of a ballbar test: on
//! the X-Y table with Stribeck friction at the motors and Coulomb friction at the tables, and a
//! split feedforward that removes the lag, the radial error shows a spike after every axis
//! reversal (quadrant glitch) in both passes, at the same places and of about the same size.

mod controllers_util;

use controllers_util::{ff_chain, job_from_text, run};

/// The job; `{chain}` stands for the cascades of both axes.
const JOB: &str = r#"
period_s = 1.0e-4
[axes.x]
model = "{examples}/models/xy-x-friction.toml"
[axes.y]
model = "{examples}/models/xy-y-friction.toml"
{chain}[trajectory]
kind = "circle"
axes = ["x", "y"]
center_m = [0.0, 0.0]
radius_m = 0.01
feed_m_per_s = 0.0333333333333
turns = 1.25
direction = "ccw_cw"
dwell_between_s = 0.1
ramp_s = 0.1
"#;

#[test]
fn a_circle_run_both_ways_shows_the_quadrant_glitches_of_both_directions_at_the_same_places() {
    let chain = ff_chain("x", None) + &ff_chain("y", None);
    let job = job_from_text("circle-both-ways", &JOB.replace("{chain}", &chain));
    let traj = feedloop_motion::build(&job.trajectory, &job.path, &job.axis_names(), job.period_s)
        .unwrap();
    let windows = traj.steady_windows_s();
    assert_eq!(windows.len(), 2, "one steady window per direction");
    let rows = run(&job);
    let h = job.period_s;
    let deg = 180.0 / std::f64::consts::PI;
    // (commanded angle in degrees, 0..360, radial error) of each steady row of a pass
    let pass = |w: [f64; 2]| -> Vec<(f64, f64)> {
        (0..rows[0].len())
            .filter(|&k| k as f64 * h > w[0] && (k as f64 * h) < w[1])
            .map(|k| {
                let (cx, cy) = (rows[0][k].cmd, rows[1][k].cmd);
                let (x, y) = (rows[0][k].load, rows[1][k].load);
                ((cy.atan2(cx) * deg).rem_euclid(360.0), x.hypot(y) - 0.01)
            })
            .collect()
    };
    let (ccw, cw) = (pass(windows[0]), pass(windows[1]));
    // An axis reverses where the circle's tangent is parallel to the other axis: x at 0 and
    // 180 degrees, y at 90 and 270. The glitch follows the reversal in the direction of travel.
    let spike = |p: &[(f64, f64)], at: f64, sign: f64| -> f64 {
        p.iter()
            .filter(|(a, _)| {
                let d = (sign * (a - at)).rem_euclid(360.0);
                d < 20.0
            })
            .map(|(_, e)| e.abs())
            .fold(0.0, f64::max)
    };
    // The level between reversals: the median |error| 30..60 degrees past each reversal.
    let quiet = |p: &[(f64, f64)], sign: f64| -> f64 {
        let mut v: Vec<f64> = p
            .iter()
            .filter(|(a, _)| {
                let d = (sign * a).rem_euclid(90.0);
                (30.0..60.0).contains(&d)
            })
            .map(|(_, e)| e.abs())
            .collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (q_ccw, q_cw) = (quiet(&ccw, 1.0), quiet(&cw, -1.0));
    println!(
        "level between reversals: ccw {:.3} nm, cw {:.3} nm",
        q_ccw * 1e9,
        q_cw * 1e9
    );
    for at in [0.0, 90.0, 180.0, 270.0] {
        let (a, b) = (spike(&ccw, at, 1.0), spike(&cw, at, -1.0));
        println!(
            "reversal at {at:>3} deg: spike {:.0} nm ccw, {:.0} nm cw",
            a * 1e9,
            b * 1e9
        );
        assert!(a > 3.0 * q_ccw && b > 3.0 * q_cw, "{at}: {a} {b}");
        assert!(a / b > 0.7 && a / b < 1.4, "{at}: {a} vs {b}");
    }
}
