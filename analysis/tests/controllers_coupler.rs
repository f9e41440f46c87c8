//! Experiments with `nl_pid_coupler` (seed 003) on an X-C cam grinder with mismatched axes.

mod controllers_util;

use controllers_util::{job_from_text, run};
use feedloop_model::job::Job;

const GEOMETRY: &str =
    "wheel_radius_m = 0.2\nprofile = \"eccentric\"\neccentricity_m = 0.005\ndisc_radius_m = 0.03";

/// An X-C job: X and C loops from the example models (with `x_gains` / `c_gains` overriding
/// their position_p / pi_velocity params), and the coupler params `coupler` (None = no coupler).
fn xc_job(x_gains: (&str, &str), c_gains: (&str, &str), coupler: Option<&str>) -> Job {
    let stage = |axis: &str, stage: &str, plugin: &str, p: &str| {
        format!("[[chain]]\naxis = \"{axis}\"\nstage = \"{stage}\"\nplugin = \"{plugin}\"\nparams = {{ {p} }}\n")
    };
    let mut text = String::from(
        "period_s = 1.0e-4\n[axes.x]\nmodel = \"{examples}/models/xc-x.toml\"\n[axes.c]\nmodel = \"{examples}/models/xc-c.toml\"\n",
    );
    text += &stage("x", "position", "position_p", x_gains.0);
    text += &stage("x", "velocity", "pi_velocity", x_gains.1);
    text += &stage("c", "position", "position_p", c_gains.0);
    text += &stage("c", "velocity", "pi_velocity", c_gains.1);
    if let Some(p) = coupler {
        text += &format!(
            "[[couplers]]\nplugin = \"nl_pid_coupler\"\naxes = [\"x\", \"c\"]\n[couplers.params]\n{GEOMETRY}\n{p}\n"
        );
    }
    text += &format!(
        "[trajectory]\nkind = \"xc_cam\"\naxes = [\"x\", \"c\"]\n{GEOMETRY}\nspeed_rad_per_s = 6.283185307179586\nturns = 1.5\nramp_s = 0.3\ndwell_after_s = 0.4\n"
    );
    job_from_text("xc", &text)
}

/// What a run shows.
struct Figures {
    /// Largest |exact profile error| over the run, m (inf if non-finite).
    max_profile_error_m: f64,
    /// Whether both axes' errors die out in the final dwell: the largest |error| of the last
    /// 0.1 s is below 0.7 x that of the 0.1 s before, or below 1e-8 (m or rad). An unstable loop
    /// grows or keeps a limit cycle there.
    settles: bool,
}

#[allow(clippy::needless_range_loop)] // indexes two parallel record arrays by cycle
fn figures(job: &Job) -> Figures {
    let rec = run(job);
    let traj = feedloop_motion::build(&job.trajectory, &job.path, &job.axis_names(), job.period_s)
        .unwrap();
    let n = rec[0].len();
    let w = (0.1 / job.period_s) as usize;
    let mut worst: f64 = 0.0;
    let (mut before, mut last) = ([0.0f64; 2], [0.0f64; 2]);
    for k in 0..n {
        let actual = [rec[0][k].load, rec[1][k].load];
        if let Some(e) = traj.contour_error_m(k as f64 * job.period_s, &actual) {
            worst = worst.max(if e.is_finite() {
                e.abs()
            } else {
                f64::INFINITY
            });
        }
        for a in 0..2 {
            let e = (rec[a][k].cmd - rec[a][k].load).abs();
            let e = if e.is_finite() { e } else { f64::INFINITY };
            if k + w >= n {
                last[a] = last[a].max(e);
            } else if k + 2 * w >= n {
                before[a] = before[a].max(e);
            }
        }
    }
    Figures {
        max_profile_error_m: worst,
        settles: (0..2).all(|a| last[a] < 1e-8 || last[a] < 0.7 * before[a]),
    }
}

fn gains(kp: u32) -> String {
    format!("kp_per_s = {kp}")
}

#[test]
fn coupler_cuts_the_max_profile_error_of_mismatched_x_c_axes_from_777_to_264_um() {
    // X: Kp 60 1/s on a 600 rad/s velocity loop; C: Kp 25 1/s on a 200 rad/s one.
    let without = figures(&xc_job(("", ""), ("", ""), None));
    let with = figures(&xc_job(("", ""), ("", ""), Some("")));
    let (a, b) = (without.max_profile_error_m, with.max_profile_error_m);
    eprintln!("X-C cam, max profile error: independent loops {a:.3e} m, nl_pid_coupler {b:.3e} m ({:.2}x)", a / b);
    assert!(a > 5e-4, "{a}");
    assert!(b < a / 2.0, "{b} vs {a}");
    assert!(with.settles);
}

#[test]
fn coupler_with_default_gains_settles_and_never_worsens_any_axis_gain_pair_that_settles_alone() {
    let mut checked = 0;
    for kpx in [30, 60, 120, 200] {
        for kpc in [10, 25, 60] {
            let (x, c) = (gains(kpx), gains(kpc));
            let alone = figures(&xc_job((&x, ""), (&c, ""), None));
            if !alone.settles {
                continue;
            }
            checked += 1;
            let coupled = figures(&xc_job((&x, ""), (&c, ""), Some("")));
            eprintln!(
                "Kp x {kpx} c {kpc}: {:.3e} m alone, {:.3e} m coupled",
                alone.max_profile_error_m, coupled.max_profile_error_m
            );
            assert!(
                coupled.settles,
                "Kp x {kpx} c {kpc}: the coupled loops do not settle"
            );
            assert!(
                coupled.max_profile_error_m <= alone.max_profile_error_m,
                "Kp x {kpx} c {kpc}"
            );
        }
    }
    assert!(checked >= 8, "only {checked} gain pairs settle alone");
}

#[test]
fn coupler_at_the_ends_of_its_gain_ranges_never_destabilises_stable_axes() {
    for (kpx, kpc) in [(60, 25), (150, 50)] {
        let (x, c) = (gains(kpx), gains(kpc));
        assert!(figures(&xc_job((&x, ""), (&c, ""), None)).settles);
        for kp in [0, 200] {
            for ki in [0, 20000] {
                for kd in [0.0, 0.5] {
                    let p = format!(
                        "kp_min_per_s = {kp}\nkp_max_per_s = {kp}\nki_max_per_s2 = {ki}\nkd_min = {kd}\nkd_max = {kd}\nmax_correction_m_per_s = 10"
                    );
                    let f = figures(&xc_job((&x, ""), (&c, ""), Some(&p)));
                    assert!(
                        f.settles && f.max_profile_error_m.is_finite(),
                        "axes Kp {kpx}/{kpc}, coupler kp {kp} ki {ki} kd {kd}"
                    );
                }
            }
        }
    }
}

#[test]
fn shipped_xc_cam_example_with_the_coupler_grinds_at_least_twice_as_true() {
    let job = Job::load(&controllers_util::examples().join("jobs/xc-cam-coupled.toml")).unwrap();
    let mut alone = job.clone();
    alone.couplers.clear();
    let (a, b) = (
        figures(&alone).max_profile_error_m,
        figures(&job).max_profile_error_m,
    );
    assert!(b < a / 2.0, "{b} vs {a}");
}
