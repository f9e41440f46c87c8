//! The load inertia checked by simulation matching (seed 000, method 1): a fast move with the
//! inverse-model feedforward at the fitted inertia is run on the axis, the same move is
//! simulated on the identified model, and the model's JL is moved (secant) until the simulated
//! command-load deviation at the peak acceleration equals the measured one.
//!
//! What sets that deviation besides the inertia is where the table sits in the backlash when
//! the move starts: the motor crosses that part of the gap first, and the transient it leaves
//! at the probe is as large as a 10 % change of the inertia. The table's place is set by the
//! friction's split between motor and table (the table's own friction holds it where the first
//! move left it; a table without friction is thrown across when that move brakes), and the
//! traverses measure only the sum. So the model does not repeat the first move: its table starts
//! in the middle of a gap chosen to make the motor cross what the machine's motor crossed (the
//! motor-load offset's rise from rest to the probe matched). The check's tolerance comes from
//! the estimates' own uncertainties and the bound of the friction's unmeasured split.

use feedloop_model::job::Job;
use serde::Serialize;

use super::device::Device;
use super::excitation::Identified;
use super::facts::{entry, experiment, floats, per_axis, Facts};
use super::friction::Survey;
use super::model_out::{feedforward_params, model_text_viscous};
use super::Notes;
use crate::identify::inertia::{
    job_with_jl, records_deviation, records_deviation_read, run_axis, sim_match,
    simulated_deviation, DeviationKind, DeviationRead, InertiaEstimate, Probe,
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
    /// Whether they agree within `tolerance_pct`.
    pub agrees: bool,
    /// The difference both estimates' own uncertainties allow, % of the fit's: 95 % of the
    /// random part (the fit's interval, the simulation match's reading and stiffness) plus the
    /// bound of the friction's split.
    pub tolerance_pct: f64,
    /// The simulation match's standard deviation (reading and stiffness), % of its estimate.
    pub sim_match_sigma_pct: f64,
    /// How far the friction's unmeasured split between motor and table can move the simulation
    /// match (dry friction's twist in the crossing, viscous friction's side), % of its estimate.
    pub friction_split_pct: f64,
    /// What the machine's motor crossed of the backlash before it drove the table at the
    /// move's start (the model's gap is twice it: its table starts in the middle), m; `null`
    /// without a backlash.
    pub backlash_crossed_m: Option<f64>,
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
    t.insert("segments".into(), segments(axis, Some(pre), len, t_move));
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
    let measured =
        records_deviation_read(&rec.records[0], ratio, probe).map_err(|e| e.to_string())?;
    let dir = std::env::temp_dir().join(format!("feedloop-commission-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let sim = CheckSim {
        f,
        axis,
        s,
        id,
        job: &exp.job,
        dir: &dir,
        len,
        t_move,
        measured,
        probe: Probe {
            at: probe.at - pre,
            ..probe
        },
        rest: rest_window(rec.period_s),
    };
    let est = sim.estimate(&rec.records[0], probe);
    let _ = std::fs::remove_dir_all(&dir);
    let (est, gap, sigma_pct, split_pct) = est?;
    let diff = 100.0 * (est.jl_kgm2 / id.jl_kgm2 - 1.0);
    // 95 % of the difference of two independent estimates (the fit's interval is 1.96 of its
    // standard deviations), plus the bound of the friction's unmeasured split.
    let fit_sigma_pct = id.jl_ci_pct.unwrap_or(0.0) / 1.96;
    let tol = 1.96 * (fit_sigma_pct * fit_sigma_pct + sigma_pct * sigma_pct).sqrt() + split_pct;
    Ok(InertiaCheck {
        jl_two_mass_kgm2: id.jl_kgm2,
        jl_sim_match_kgm2: est.jl_kgm2,
        difference_pct: diff,
        agrees: diff.abs() <= tol,
        tolerance_pct: tol,
        sim_match_sigma_pct: sigma_pct,
        friction_split_pct: split_pct,
        backlash_crossed_m: gap.map(|g| 0.5 * g),
        iterations: est.iterations,
        deviation_m: measured.value,
    })
}

/// The check move's segments on `axis`: a first short move of `pre` (or a rest as long, for the
/// model), a rest, the move of `len` in `t_move`, a rest.
fn segments(axis: &str, pre: Option<f64>, len: f64, t_move: f64) -> toml::Value {
    let seg = |kind: &str, by: Option<f64>, d: f64| {
        let mut s = toml::Table::new();
        s.insert("kind".into(), kind.into());
        if let Some(b) = by {
            s.insert("by_m".into(), per_axis(axis, b));
        }
        s.insert("duration_s".into(), toml::Value::Float(d));
        toml::Value::Table(s)
    };
    let first = match pre {
        Some(p) => seg("move", Some(p), 0.2),
        None => seg("dwell", None, 0.2),
    };
    toml::Value::Array(vec![
        first,
        seg("dwell", None, 0.1),
        seg("move", Some(len), t_move),
        seg("dwell", None, 0.1),
    ])
}

/// The samples of the rest before the main move, at `period_s`: (its end, its length).
fn rest_window(period_s: f64) -> (usize, usize) {
    (
        ((0.2 + 0.1) / period_s).round() as usize,
        (0.05 / period_s).round() as usize,
    )
}

/// What the motor travels before it drives the table at the move's start: the motor-load
/// offset at `probe` (the screw's twist there included) less the one at rest before the move
/// (`rest`: its end and its length in samples).
fn offset_rise(
    r: &[feedloop_trace::log::AxisRecord],
    ratio: f64,
    probe: Probe,
    (start, settle): (usize, usize),
) -> Result<f64, String> {
    let twist_probe = Probe {
        kind: DeviationKind::MotorLoad,
        ..probe
    };
    let at_probe = records_deviation(r, ratio, twist_probe).map_err(|e| e.to_string())?;
    let rest = r
        .get(start.saturating_sub(settle)..start)
        .filter(|w| !w.is_empty())
        .ok_or("the check move's record is too short")?;
    let at_rest = rest.iter().map(|x| x.motor / ratio - x.load).sum::<f64>() / rest.len() as f64;
    Ok(at_probe - at_rest)
}

/// The simulation side of the check: the identified model run through the check move.
struct CheckSim<'a> {
    f: &'a Facts,
    axis: &'a str,
    s: &'a Survey,
    id: &'a Identified,
    /// The check move's job on the machine.
    job: &'a toml::Table,
    /// Where the model's files are written.
    dir: &'a std::path::Path,
    len: f64,
    t_move: f64,
    /// The measured command-load deviation at the probe (and its standard error), m.
    measured: DeviationRead,
    /// The probe on the model's record (which starts without the first short move).
    probe: Probe,
    /// The rest before the main move (see [`rest_window`]).
    rest: (usize, usize),
}

impl CheckSim<'_> {
    /// The model's job with a backlash `gap`, stiffness `kl`, and the measured viscous friction
    /// on the table's side when `viscous_on_load`.
    fn job(&self, gap: Option<f64>, kl: f64, viscous_on_load: bool) -> Result<Job, String> {
        let (f, s, id) = (self.f, self.s, self.id);
        let mut idg = id.clone();
        idg.backlash_m = gap;
        idg.kl_nm_per_rad = kl;
        let text = model_text_viscous(f, s, &idg, id.jl_kgm2, f.start, viscous_on_load);
        let model = self.dir.join("identified.toml");
        std::fs::write(&model, text).map_err(|e| format!("{}: {e}", model.display()))?;
        let mut table = self.job.clone();
        // The model starts with its table in the middle of its gap, where the simulation
        // starts it, and rests instead of the first move: the motor then crosses half the
        // model's gap before it drives the table, and the gap is set to make that what the
        // machine's motor crossed.
        if let Some(toml::Value::Table(traj)) = table.get_mut("trajectory") {
            traj.insert(
                "segments".into(),
                segments(self.axis, None, self.len, self.t_move),
            );
        }
        if let Some(toml::Value::Table(axes)) = table.get_mut("axes") {
            let mut a = toml::Table::new();
            a.insert("model".into(), model.display().to_string().into());
            axes.insert(self.axis.into(), toml::Value::Table(a));
        }
        Job::from_table(&table, &self.dir.join("check.toml")).map_err(|e| e.to_string())
    }

    /// The simulation match on the model with `gap`, `kl` and the viscous side.
    fn matched(&self, gap: Option<f64>, kl: f64, load: bool) -> Result<InertiaEstimate, String> {
        let job = self.job(gap.filter(|g| *g > 0.0), kl, load)?;
        sim_match(&job, 0, self.measured.value, self.probe).map_err(|e| e.to_string())
    }

    /// The model's gap that makes its motor cross what the machine's motor crossed (`rise`).
    ///
    /// The identified model carries all the friction on the motor side, so its table is thrown
    /// across the backlash whenever the first move brakes, whereas the machine's table stays
    /// where its own friction holds it: the motor then crosses a different part of the gap at
    /// the start, and that transient, not the inertia, sets the deviation at the probe. The
    /// rise moves one to one with the gap the model's table crosses: a few fixed-point steps.
    fn crossing_gap(&self, rise: f64) -> Result<Option<f64>, String> {
        let id = self.id;
        let mut gap = id.backlash_m.filter(|b| *b > 0.0);
        if gap.is_none() {
            return Ok(None);
        }
        for _ in 0..4 {
            let job = self.job(gap, id.kl_nm_per_rad, false)?;
            let with_jl =
                job_with_jl(&job, 0, id.jl_kgm2, id.jl_kgm2).map_err(|e| e.to_string())?;
            let sim = run_axis(&with_jl, 0).map_err(|e| e.to_string())?;
            let miss = rise - offset_rise(&sim, self.f.ratio(), self.probe, self.rest)?;
            let g = gap.unwrap_or(0.0);
            let next = (g + 2.0 * miss).max(0.0);
            gap = Some(next);
            if (next - g).abs() <= 1e-3 * id.backlash_m.unwrap_or(0.0) {
                break;
            }
        }
        Ok(gap)
    }

    /// The estimate, the model's gap, and the estimate's standard deviation and the bound of
    /// the friction's unmeasured split (both % of the estimate), from the machine's record
    /// `rec` read at `probe`.
    fn estimate(
        &self,
        rec: &[feedloop_trace::log::AxisRecord],
        probe: Probe,
    ) -> Result<(InertiaEstimate, Option<f64>, f64, f64), String> {
        let id = self.id;
        let rise = offset_rise(rec, self.f.ratio(), probe, self.rest)?;
        let gap = self.crossing_gap(rise)?;
        let est = self.matched(gap, id.kl_nm_per_rad, false)?;
        // The estimate's own uncertainty, as standard deviations of JL:
        // - reading: the measured deviation's standard error (its least-squares line in the
        //   window) over the deviation's change with JL;
        // - stiffness: the estimate with KL one standard deviation of the fit higher;
        // and, as bounds (the traverses measure the friction of motor and table together,
        // not its split):
        // - the crossing read from the offset rise includes the screw's twist under the
        //   table's share of the dry friction, anywhere from none to the whole over KL: the
        //   estimate with the model's gap less twice that twist;
        // - the viscous friction: the estimate with it all on the table's side.
        let jl = est.jl_kgm2;
        let job = self.job(gap.filter(|g| *g > 0.0), id.kl_nm_per_rad, false)?;
        let moved = simulated_deviation(&job, 0, 1.01 * jl, id.jl_kgm2, self.probe)
            .map_err(|e| e.to_string())?;
        let per_jl = (moved - est.deviation_model_m) / (0.01 * jl);
        let reading = self.measured.std_error / per_jl.abs().max(1e-300);
        let ratio = self.f.ratio();
        let split = match gap {
            Some(g) if g > 0.0 => {
                let kl_load = id.kl_nm_per_rad * ratio * ratio;
                let twist = self.s.friction.coulomb_nm() * ratio / kl_load;
                let e = self.matched(Some((g - 2.0 * twist).max(0.0)), id.kl_nm_per_rad, false)?;
                (e.jl_kgm2 - jl).abs()
            }
            _ => 0.0,
        };
        let stiffness = match id.kl_ci_pct {
            Some(ci) if ci > 0.0 => {
                let e = self.matched(gap, id.kl_nm_per_rad * (1.0 + ci / 196.0), false)?;
                (e.jl_kgm2 - jl).abs()
            }
            _ => 0.0,
        };
        let viscous = (self.matched(gap, id.kl_nm_per_rad, true)?.jl_kgm2 - jl).abs();
        let sigma = (reading * reading + stiffness * stiffness).sqrt();
        Ok((est, gap, 100.0 * sigma / jl, 100.0 * (split + viscous) / jl))
    }
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
