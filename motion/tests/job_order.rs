//! A per-axis array of a trajectory is applied in the order of the job file's axes, not in the
//! order of their names.

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::job::Job;

#[test]
fn a_per_axis_array_follows_the_axes_in_file_order() {
    let dir =
        std::env::temp_dir().join(format!("feedloop-motion-job-order-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("m.toml"),
        "kind = \"rigid\"\nmass_kg = 10\n[controller]\nkp_per_s = 30\nkv_ns_per_m = 2000\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("j.toml"),
        "period_s = 0.001\n[axes.x]\nmodel = \"m.toml\"\n[axes.c]\nmodel = \"m.toml\"\n[axes.a]\nmodel = \"m.toml\"\n[trajectory]\nkind = \"move\"\nto_m = [0.01, 0.02, 0.03]\nduration_s = 0.1\n",
    )
    .unwrap();
    let job = Job::load(&dir.join("j.toml")).unwrap();
    assert_eq!(job.axis_names(), ["x", "c", "a"]);
    let traj =
        feedloop_motion::build(&job.trajectory, &job.path, &job.axis_names(), 0.001).unwrap();
    let mut out = vec![[0.0; REF_DERIVS]; 3];
    traj.eval(1.0, &mut out);
    assert_eq!([out[0][0], out[1][0], out[2][0]], [0.01, 0.02, 0.03]);
    std::fs::remove_dir_all(dir).ok();
}
