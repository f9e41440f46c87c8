//! Ramp-test tuning (seed 001) on the reference X axis.

use std::sync::atomic::{AtomicUsize, Ordering};

use feedloop_analysis::identify::tune::{
    evaluate, job_with_gains, margins, parse_grid, tune, Gains,
};
use feedloop_runtime::job::Job;

static NEXT: AtomicUsize = AtomicUsize::new(0);

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
    let d = std::env::temp_dir().join(format!(
        "feedloop-id-tune-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::SeqCst)
    ));
    std::fs::create_dir_all(&d).unwrap();
    let ex = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    std::fs::write(
        d.join("job.toml"),
        JOB.replace("{examples}", &ex.display().to_string()),
    )
    .unwrap();
    Job::load(&d.join("job.toml")).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn a_1000_point_grid_of_1_s_ramps_finishes_under_60_s_and_the_tuned_job_beats_the_defaults() {
    let job = job();
    let grid = parse_grid("kp_per_s=20:120:10,kv_nms_per_rad=1:10:10,tv_s=0.002:0.02:10").unwrap();
    let t0 = std::time::Instant::now();
    let r = tune(&job, 0, &grid, [1.0, 0.1, 0.01], false, &|| {}).unwrap();
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
    )
    .unwrap();
    println!("margins {pm:.1} deg, {gm:.1} dB");
    assert!(pm > 30.0 && gm > 6.0);
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
