//! The load inertia checked by simulation matching (seed 000, method 1): a fast move with the
//! inverse-model feedforward at the fitted inertia is run on the axis, the same move is
//! simulated on the identified model, and the model's JL is moved (secant) until the simulated
//! command-load deviation at the peak acceleration equals the measured one. Near the
//! feedforward's own inertia the deviation is linear in the load inertia's error and hardly
//! depends on the friction, so the match reads the inertia where the frequency response's notch
//! is noisiest.

use feedloop_model::job::Job;
use serde::Serialize;

use super::device::Device;
use super::excitation::Identified;
use super::facts::{entry, experiment, floats, per_axis, Facts};
use super::friction::Survey;
use super::model_out::{feedforward_params, model_text};
use super::Notes;
use crate::identify::inertia::{
    job_with_jl, records_deviation, run_axis, sim_match, DeviationKind, InertiaEstimate, Probe,
};

/// The two estimates of the load inertia.
#[derive(Debug, Clone, Serialize)]
pub struct InertiaCheck {
    /// From the two-mass fit, kg m^2.
    pub jl_two_mass_kgm2: f64,
    /// From simulation matching, kg m^2.
    pub jl_sim_match_kgm2: f64,
    /// Their difference, % of the fit's.
    pub difference_pct: f64,
    /// Whether they agree within three of the fit's confidences (at least 2 %).
    pub agrees: bool,
    /// Moves simulated by the search.
    pub iterations: usize,
    /// Measured command-load deviation at the probe, m.
    pub deviation_m: f64,
}

/// Runs the move and matches it.
pub fn check_inertia(
    dev: &mut dyn Device,
    f: &Facts,
    axis: &str,
    s: &Survey,
    id: &Identified,
    notes: &mut Notes,
) -> Result<InertiaCheck, String> {
    let ratio = f.ratio();
    let j = f.jm_kgm2 + id.jl_kgm2;
    let len = (0.05f64).min(0.4 * f.travel_m);
    // C5 move: peak acceleration 5.77 L / T^2, at a third of the torque limit.
    let t_move = (5.77 * len * ratio * j / (0.3 * f.torque_limit_nm))
        .sqrt()
        .max(0.1);
    let pre = 5e-4;
    let mut t = toml::Table::new();
    t.insert("kind".into(), "sequence".into());
    let seg = |kind: &str, by: Option<f64>, d: f64| {
        let mut s = toml::Table::new();
        s.insert("kind".into(), kind.into());
        if let Some(b) = by {
            s.insert("by_m".into(), per_axis(axis, b));
        }
        s.insert("duration_s".into(), toml::Value::Float(d));
        toml::Value::Table(s)
    };
    t.insert(
        "segments".into(),
        toml::Value::Array(vec![
            seg("move", Some(pre), 0.2),
            seg("dwell", None, 0.1),
            seg("move", Some(len), t_move),
            seg("dwell", None, 0.1),
        ]),
    );
    let chain = check_chain(f, axis, s, id);
    let name = "inertia check move";
    let exp = experiment(name, f, &[axis], chain, t, f.bounds(0.01));
    let rec = dev.run(&exp)?;
    notes.push(
        name,
        &rec,
        &format!(
            "the load-inertia patent's check of the load inertia (simulation matching): {:.0} mm in {:.3} s (a third of the torque limit at the peak acceleration), the feedforward at the fitted inertia",
            len * 1e3,
            t_move
        ),
    );
    if let Some(why) = rec.stopped {
        return Err(why);
    }
    let probe = Probe {
        at: pre + 0.067 * len,
        half_window: 0.03 * len,
        kind: DeviationKind::CommandLoad,
    };
    let measured = records_deviation(&rec.records[0], ratio, probe).map_err(|e| e.to_string())?;
    // Where the table sits in the backlash when the move starts: what the motor travels before
    // it drives the table (the motor-load offset at the probe less the one at rest before the
    // move, the screw's twist at the probe included).
    let start = ((0.2 + 0.1) / rec.period_s).round() as usize;
    let settle = (0.05 / rec.period_s).round() as usize;
    let model_probe = Probe {
        at: probe.at - pre,
        ..probe
    };
    let offset_rise =
        |r: &[feedloop_trace::log::AxisRecord], probe: Probe| -> Result<f64, String> {
            let twist_probe = Probe {
                kind: DeviationKind::MotorLoad,
                ..probe
            };
            let at_probe = records_deviation(r, ratio, twist_probe).map_err(|e| e.to_string())?;
            let rest = r
                .get(start.saturating_sub(settle)..start)
                .filter(|w| !w.is_empty())
                .ok_or("the check move's record is too short")?;
            let at_rest =
                rest.iter().map(|x| x.motor / ratio - x.load).sum::<f64>() / rest.len() as f64;
            Ok(at_probe - at_rest)
        };
    let rise = offset_rise(&rec.records[0], probe)?;
    let dir = std::env::temp_dir().join(format!("feedloop-commission-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let model = dir.join("identified.toml");
    let job_with_gap = |gap: Option<f64>| -> Result<Job, String> {
        let mut idg = id.clone();
        idg.backlash_m = gap;
        std::fs::write(&model, model_text(f, s, &idg, id.jl_kgm2, f.start))
            .map_err(|e| format!("{}: {e}", model.display()))?;
        let mut table = exp.job.clone();
        // The model starts with its table in the middle of its gap, where the simulation
        // starts it, and rests instead of the first move: the motor then crosses half the
        // model's gap before it drives the table, and the gap is set to make that what the
        // machine's motor crossed.
        if let Some(toml::Value::Table(traj)) = table.get_mut("trajectory") {
            traj.insert(
                "segments".into(),
                toml::Value::Array(vec![
                    seg("dwell", None, 0.2),
                    seg("dwell", None, 0.1),
                    seg("move", Some(len), t_move),
                    seg("dwell", None, 0.1),
                ]),
            );
        }
        if let Some(toml::Value::Table(axes)) = table.get_mut("axes") {
            let mut a = toml::Table::new();
            a.insert("model".into(), model.display().to_string().into());
            axes.insert(axis.into(), toml::Value::Table(a));
        }
        Job::from_table(&table, &dir.join("check.toml")).map_err(|e| e.to_string())
    };
    let est = (|| -> Result<(InertiaEstimate, Option<f64>), String> {
        // The identified model carries all the friction on the motor side, so its table is
        // thrown across the backlash whenever the first move brakes, whereas the machine's
        // table stays where its own friction holds it: the motor then crosses a different
        // part of the gap at the start, and that transient, not the inertia, sets the
        // deviation at the probe. So the model's gap is set to what the measured motor crosses
        // (its offset rise matched, at most a few fixed-point steps: the rise moves one to one
        // with the gap the model's table crosses).
        let mut gap = id.backlash_m.filter(|b| *b > 0.0);
        if gap.is_some() {
            for _ in 0..4 {
                let job = job_with_gap(gap)?;
                let sim = run_axis(
                    &job_with_jl(&job, 0, id.jl_kgm2, id.jl_kgm2).map_err(|e| e.to_string())?,
                    0,
                )
                .map_err(|e| e.to_string())?;
                let miss = rise - offset_rise(&sim, model_probe)?;
                let g = gap.unwrap_or(0.0);
                let next = (g + 2.0 * miss).max(0.0);
                gap = Some(next);
                if (next - g).abs() <= 1e-3 * id.backlash_m.unwrap_or(0.0) {
                    break;
                }
            }
        }
        let job = job_with_gap(gap.filter(|g| *g > 0.0))?;
        let est = sim_match(&job, 0, measured, model_probe).map_err(|e| e.to_string())?;
        Ok((est, gap))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    let (est, _crossed) = est?;
    let diff = 100.0 * (est.jl_kgm2 / id.jl_kgm2 - 1.0);
    let tol = (3.0 * id.jl_ci_pct.unwrap_or(1.0)).max(2.0);
    Ok(InertiaCheck {
        jl_two_mass_kgm2: id.jl_kgm2,
        jl_sim_match_kgm2: est.jl_kgm2,
        difference_pct: diff,
        agrees: diff.abs() <= tol,
        iterations: est.iterations,
        deviation_m: measured,
    })
}

/// The starting cascade with the inverse-model feedforward at the fitted inertia.
fn check_chain(f: &Facts, axis: &str, s: &Survey, id: &Identified) -> Vec<toml::Value> {
    vec![
        entry(
            axis,
            "position",
            "position_p",
            floats(&[("kp_per_s", f.start.kp_per_s)]),
        ),
        entry(axis, "feedforward", "inverse_feedforward", {
            let mut p = feedforward_params(f, s, id, id.jl_kgm2);
            p.insert(
                "kv_nms_per_rad".into(),
                toml::Value::Float(f.start.kv_nms_per_rad),
            );
            p.insert("tv_s".into(), toml::Value::Float(f.start.tv_s));
            p
        }),
        entry(
            axis,
            "velocity",
            "pi_velocity",
            floats(&[
                ("kv_nms_per_rad", f.start.kv_nms_per_rad),
                ("tv_s", f.start.tv_s),
            ]),
        ),
    ]
}
