//! Ramp-test tuning (seed 001) on the reference X axis.

use feedloop_analysis::identify::tune::{
    evaluate, job_with_gains, margins, parse_grid, ramp_error, tune, Gains,
};
use feedloop_model::job::Job;

mod controllers_util;

use controllers_util::{job_from_text, temp_dir};

const JOB: &str = r#"
name = "tune-ramp"
period_s = 1.0e-4
[axes.x]
model = "{examples}/models/xy-x.toml"
[trajectory]
kind = "ramp"
velocity_m_per_s = { x = 0.1 }
accel_s = 0.1
constant_s = 0.8
dwell_after_s = 0.05
"#;

fn job() -> Job {
    job_from_text("id-tune", JOB)
}

#[test]
fn a_1000_point_grid_of_1_s_ramps_finishes_under_60_s_and_the_tuned_job_beats_the_defaults() {
    let job = job();
    let grid = parse_grid("kp_per_s=20:120:10,kv_nms_per_rad=1:10:10,tv_s=0.002:0.02:10").unwrap();
    let t0 = std::time::Instant::now();
    let r = tune(&job, 0, &grid, [1.0, 0.1, 0.01], 1, false, &|| {}).unwrap();
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "{} sets in {secs:.1} s ({} rejected): best {:?}, E {:.4e} vs default {:.4e}",
        r.evaluated, r.rejected, r.best, r.e_best, r.e_default
    );
    assert_eq!(r.evaluated, 1000);
    assert!(secs < 60.0, "{secs} s");
    // Afresh: the tuned job's E is below the default's.
    let fresh = evaluate(
        &job_with_gains(&job, 0, r.best),
        0,
        r.best,
        [1.0, 0.1, 0.01],
        1,
    );
    assert!(fresh.e.unwrap() < r.e_default, "{fresh:?}");
}

#[test]
fn the_default_gains_kp_50_kv_5_tv_5ms_have_margins_above_30_deg_and_6_db() {
    let job = job();
    let (pm, gm) = margins(
        &job.axes[0].model.plant,
        Gains {
            kp_per_s: 50.0,
            kv_nms_per_rad: 5.0,
            tv_s: 0.005,
        },
        job.period_s,
        job.period_s,
    )
    .unwrap();
    println!("margins {pm:.1} deg, {gm:.1} dB");
    assert!(pm > 30.0 && gm > 6.0);
}

fn gains(kv: f64) -> Gains {
    Gains {
        kp_per_s: 50.0,
        kv_nms_per_rad: kv,
        tv_s: 0.005,
    }
}

#[test]
fn a_set_stable_in_continuous_time_but_under_30_deg_with_the_sampling_delay_is_rejected() {
    let job = job();
    let plant = &job.axes[0].model.plant;
    let t = job.period_s;
    // The first velocity gain (kp 50, tv 5 ms) that passes in continuous time but not with the
    // zero-order hold and one period of transport delay.
    let mut found = None;
    for kv in (1..=40).map(f64::from) {
        let c = margins(plant, gains(kv), 0.0, 0.0).unwrap();
        let d = margins(plant, gains(kv), t, t).unwrap();
        if c.0 >= 30.0 && c.1 >= 6.0 && d.0 < 30.0 {
            println!(
                "kv {kv}: continuous {:.1} deg / {:.1} dB, with hold + 1 period {:.1} deg / {:.1} dB",
                c.0, c.1, d.0, d.1
            );
            found = Some(kv);
            break;
        }
    }
    let kv = found.expect("a gain the delay makes marginal");
    let e = evaluate(&job, 0, gains(kv), [1.0, 0.1, 0.01], 1);
    println!("{e:?}");
    assert!(e.e.is_none());
    assert!(
        e.rejected.as_deref().unwrap_or("").contains("margins"),
        "{e:?}"
    );
    // The same set runs without trouble on the in-process simulator, which applies the torque
    // in the period of its sample (hold only): the rejection is the margin check's.
    let (_, tmax) = ramp_error(&job_with_gains(&job, 0, gains(kv)), 0, [1.0, 0.1, 0.01]).unwrap();
    assert!(tmax < 29.0, "{tmax}");
}

#[test]
fn the_delayed_loop_model_predicts_where_the_simulated_loop_with_a_one_cycle_delay_goes_unstable() {
    // Plant with [effects.delay] delay_cycles = 1: the simulated loop is the hold plus one
    // period, which the margin model with delay_s = T describes.
    let base = job();
    let d = temp_dir("id-tune-delay");
    let model = std::fs::read_to_string(&base.axes[0].model.path).unwrap();
    std::fs::write(
        d.join("model.toml"),
        format!("{model}\n[effects.delay]\ndelay_cycles = 1\n"),
    )
    .unwrap();
    std::fs::write(
        d.join("job.toml"),
        JOB.replace("{examples}/models/xy-x.toml", "model.toml"),
    )
    .unwrap();
    let job = Job::load(&d.join("job.toml")).unwrap_or_else(|e| panic!("{e}"));
    let plant = &job.axes[0].model.plant;
    let t = job.period_s;
    let lim = job.axes[0].model.controller.torque_limit.unwrap();
    let mut stable_seen = false;
    let mut unstable_seen = false;
    for kv in [10.0, 15.0, 30.0, 40.0] {
        let (_, gm) = margins(plant, gains(kv), t, t).unwrap();
        let (_, gm_hold) = margins(plant, gains(kv), t, 0.0).unwrap();
        let (e, tmax) = ramp_error(&job_with_gains(&job, 0, gains(kv)), 0, [1.0, 0.1, 0.01])
            .unwrap_or((f64::NAN, f64::INFINITY));
        let diverged = !e.is_finite() || tmax >= 0.999 * lim;
        println!(
            "kv {kv}: gain margin {gm:.1} dB with hold + 1 period ({gm_hold:.1} dB hold only); simulated with a 1-cycle delay: E {e:.3e}, max torque {tmax:.1} N m{}",
            if diverged { " (diverges)" } else { "" }
        );
        if gm > 1.0 {
            assert!(!diverged, "kv {kv}: predicted stable, simulated unstable");
            stable_seen = true;
        } else if gm < -1.0 {
            assert!(diverged, "kv {kv}: predicted unstable, simulated stable");
            unstable_seen = true;
        }
    }
    assert!(stable_seen && unstable_seen);
}

#[test]
fn an_empty_or_malformed_grid_is_a_clear_error() {
    for g in [
        "",
        "kp_per_s=20:10:5",
        "gain=1:2:3",
        "kp_per_s=1:2:0",
        "kp_per_s=1:2",
    ] {
        let e = parse_grid(g).unwrap_err();
        println!("`{g}`: {e}");
    }
}
