//! Load inertia estimation (seed 000).
//!
//! The deviation at a load position is read by a least-squares line `dev = a + b (thL - at)`
//! through the samples of the first pass within `+- half_window_m` of `at`; its value `a` at
//! `at` is the deviation. One sample would carry the sensors' noise and quantisation whole; the
//! line averages it. Two deviations ([`DeviationKind`]):
//! - `command-load` (default): the patent's position deviation `th - thL`, position command
//!   minus load position. At the feedforward's own inertia it is the feedforward's residual;
//!   it grows linearly with the plant's inertia away from it.
//! - `motor-load`: the screw's twist, motor position in load units minus load position. It is
//!   set by the physics (about `(JL thL'' + DL thL') / KL`) and hardly by the controller, so it
//!   does not see a residual of the controller's discretisation.
//!
//! The literal patent structure: the patent's estimation model (its Fig. 2) is a continuous-time
//! model in which the inverse feedforward is exact (`thL = th` at the right inertia). A machine
//! that runs the structure discretised (the brief: lags by backward Euler, PI by the rectangle
//! rule) leaves a residual `r` of the command-load deviation at the right inertia, and a
//! continuous-time model reads it as an inertia error `r / (d dev / d JL)`: the brief's 0.6 um
//! against about 10 um per +100 % gives about -6 %. [`sim_match`] estimates with the job's own
//! discrete controller (unbiased) and, when the feedforward is literal, also with the
//! continuous-time model (the split structure, exact to 0.007 um on the brief's move) and
//! reports the difference as `literal_bias_percent`.
//!
//! - Method 1 (`sim-match`): simulate the job (same command, controller and feedforward, the
//!   feedforward keeping the inertia it ran with) on the model with a candidate `jl_kgm2`, and
//!   adjust it by the secant method until the simulated deviation equals the measured one
//!   (the deviation is linear in JL, so 3 to 5 moves suffice).
//! - Method 2 (`linear`): interpolate JL linearly between a no-load and a known-load run.

use feedloop_model::job::Job;
use feedloop_model::model::PlantParams;
use feedloop_plugins::inverse_feedforward::TwoMassModel;
use feedloop_plugins::Builtins;
use feedloop_runtime::shared::wire::MAX_AXES;
use feedloop_trace::log::AxisRecord;
use feedloop_trace::Trace;
use serde::Serialize;

use super::IdentifyError;
use crate::sim::Simulation;

/// Plugin id of the inverse-model feedforward.
pub const FEEDFORWARD: &str = "inverse_feedforward";

/// Which deviation is read at the probe position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviationKind {
    /// The patent's position deviation: command minus load position (columns `A.cmd`,
    /// `A.load`).
    CommandLoad,
    /// The screw's twist: motor position in load units minus load position (`A.motor`,
    /// `A.load`).
    MotorLoad,
}

impl DeviationKind {
    /// Parses `command-load` / `motor-load`.
    pub fn parse(s: &str) -> Result<Self, IdentifyError> {
        match s {
            "command-load" => Ok(Self::CommandLoad),
            "motor-load" => Ok(Self::MotorLoad),
            other => Err(IdentifyError::Invalid(format!(
                "unknown deviation `{other}` (expected command-load or motor-load)"
            ))),
        }
    }

    /// The name `parse` accepts.
    pub fn name(self) -> &'static str {
        match self {
            Self::CommandLoad => "command-load",
            Self::MotorLoad => "motor-load",
        }
    }
}

/// Where and how the deviation is read.
#[derive(Debug, Clone, Copy)]
pub struct Probe {
    /// Load position, m (or rad).
    pub at: f64,
    /// Half width of the least-squares window, load units.
    pub half_window: f64,
    /// Which deviation.
    pub kind: DeviationKind,
}

/// Reads the deviation `reference / reference_per_load - load` at `probe` from aligned records
/// (`reference` is the command with `reference_per_load = 1`, or the motor position with the
/// motor units per load unit).
pub fn deviation(
    load: &[f64],
    reference: &[f64],
    reference_per_load: f64,
    probe: Probe,
) -> Result<f64, IdentifyError> {
    deviation_read(load, reference, reference_per_load, probe).map(|r| r.value)
}

/// A deviation read at a probe: the value of the window's least-squares line at the probe and
/// that value's standard error (the samples' scatter about the line; 0 when the window holds
/// too few samples for a scatter).
#[derive(Debug, Clone, Copy)]
pub struct DeviationRead {
    /// The deviation at the probe, load units.
    pub value: f64,
    /// Its standard error, load units.
    pub std_error: f64,
}

/// [`deviation`] with its standard error.
pub fn deviation_read(
    load: &[f64],
    reference: &[f64],
    reference_per_load: f64,
    probe: Probe,
) -> Result<DeviationRead, IdentifyError> {
    let n = load.len().min(reference.len());
    if n < 3 {
        return Err(IdentifyError::Invalid(
            "the record is too short to read a deviation".into(),
        ));
    }
    let at = probe.at;
    let s0 = (load[0] - at).signum();
    let lo = load[..n].iter().copied().fold(f64::INFINITY, f64::min);
    let hi = load[..n].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let k = (1..n).find(|&k| (load[k] - at).signum() != s0 && s0 != 0.0);
    let Some(k) = k else {
        return Err(IdentifyError::Invalid(format!(
            "position {at} is outside the move (the load travels {lo:.6} .. {hi:.6}); pick a \
             position the load passes while accelerating or braking"
        )));
    };
    let inside = |j: usize| (load[j] - at).abs() <= probe.half_window;
    let mut a = k;
    while a > 0 && inside(a - 1) {
        a -= 1;
    }
    let mut b = k;
    while b + 1 < n && inside(b + 1) {
        b += 1;
    }
    let point = |j: usize| (load[j] - at, reference[j] / reference_per_load - load[j]);
    let (mut sx, mut sy, mut sxx, mut sxy, mut m) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (x, y) in (a..=b).map(point) {
        sx += x;
        sy += y;
        sxx += x * x;
        sxy += x * y;
        m += 1.0;
    }
    let den = m * sxx - sx * sx;
    if m < 3.0 || den.abs() < 1e-300 {
        // Too few samples for a line: the mean (or the single crossing sample).
        return Ok(DeviationRead {
            value: sy / m,
            std_error: 0.0,
        });
    }
    let slope = (m * sxy - sx * sy) / den;
    let value = (sy - slope * sx) / m;
    // the intercept's standard error: the scatter about the line over m - 2 degrees of
    // freedom, times sqrt(1/m + mean(x)^2 / Sxx) with Sxx about the mean
    let scatter = (a..=b)
        .map(point)
        .map(|(x, y)| (y - value - slope * x).powi(2))
        .sum::<f64>()
        / (m - 2.0);
    let mx = sx / m;
    let sxx_mean = sxx - m * mx * mx;
    let std_error = (scatter * (1.0 / m + mx * mx / sxx_mean.max(1e-300))).sqrt();
    Ok(DeviationRead { value, std_error })
}

/// The deviation of `axis` in a trace (columns `A.load` and `A.cmd` or `A.motor`).
pub fn trace_deviation(
    trace: &Trace,
    axis: &str,
    motor_per_load: f64,
    probe: Probe,
) -> Result<f64, IdentifyError> {
    let load = trace.require(&format!("{axis}.load"))?;
    match probe.kind {
        DeviationKind::CommandLoad => {
            deviation(load, trace.require(&format!("{axis}.cmd"))?, 1.0, probe)
        }
        DeviationKind::MotorLoad => deviation(
            load,
            trace.require(&format!("{axis}.motor"))?,
            motor_per_load,
            probe,
        ),
    }
}

/// (load position, deviation) along the first pass of the move (from the start to the load's
/// farthest point), at most about `max_points` points: what the `--svg` plot draws.
pub fn deviation_profile(
    load: &[f64],
    reference: &[f64],
    reference_per_load: f64,
    max_points: usize,
) -> Vec<(f64, f64)> {
    let n = load.len().min(reference.len());
    if n == 0 {
        return vec![];
    }
    let far = (0..n)
        .max_by(|&a, &b| {
            (load[a] - load[0])
                .abs()
                .total_cmp(&(load[b] - load[0]).abs())
        })
        .unwrap_or(0);
    let step = (far / max_points.max(1)).max(1);
    (0..=far)
        .step_by(step)
        .map(|k| (load[k], reference[k] / reference_per_load - load[k]))
        .collect()
}

/// [`deviation_profile`] of `axis` in a trace.
pub fn trace_profile(
    trace: &Trace,
    axis: &str,
    motor_per_load: f64,
    kind: DeviationKind,
) -> Result<Vec<(f64, f64)>, IdentifyError> {
    let load = trace.require(&format!("{axis}.load"))?;
    Ok(match kind {
        DeviationKind::CommandLoad => {
            deviation_profile(load, trace.require(&format!("{axis}.cmd"))?, 1.0, 2000)
        }
        DeviationKind::MotorLoad => deviation_profile(
            load,
            trace.require(&format!("{axis}.motor"))?,
            motor_per_load,
            2000,
        ),
    })
}

/// [`deviation_profile`] of a simulated run of `job`'s axis `i` with plant inertia `plant_jl`
/// and feedforward inertia `ff_jl`.
pub fn simulated_profile(
    job: &Job,
    i: usize,
    plant_jl: f64,
    ff_jl: f64,
    kind: DeviationKind,
) -> Result<Vec<(f64, f64)>, IdentifyError> {
    let rec = run_axis(&job_with_jl(job, i, plant_jl, ff_jl)?, i)?;
    let load: Vec<f64> = rec.iter().map(|r| r.load).collect();
    Ok(match kind {
        DeviationKind::CommandLoad => {
            let c: Vec<f64> = rec.iter().map(|r| r.cmd).collect();
            deviation_profile(&load, &c, 1.0, 2000)
        }
        DeviationKind::MotorLoad => {
            let m: Vec<f64> = rec.iter().map(|r| r.motor).collect();
            deviation_profile(&load, &m, job.axes[i].model.plant.motor_per_load(), 2000)
        }
    })
}

/// The deviation of simulated records of one axis.
pub fn records_deviation(
    rec: &[AxisRecord],
    motor_per_load: f64,
    probe: Probe,
) -> Result<f64, IdentifyError> {
    records_deviation_read(rec, motor_per_load, probe).map(|r| r.value)
}

/// [`records_deviation`] with its standard error ([`deviation_read`]).
pub fn records_deviation_read(
    rec: &[AxisRecord],
    motor_per_load: f64,
    probe: Probe,
) -> Result<DeviationRead, IdentifyError> {
    let load: Vec<f64> = rec.iter().map(|r| r.load).collect();
    let (reference, per_load): (Vec<f64>, f64) = match probe.kind {
        DeviationKind::CommandLoad => (rec.iter().map(|r| r.cmd).collect(), 1.0),
        DeviationKind::MotorLoad => (rec.iter().map(|r| r.motor).collect(), motor_per_load),
    };
    deviation_read(&load, &reference, per_load, probe)
}

/// Index of `axis` in the job.
pub fn axis_index(job: &Job, axis: Option<&str>) -> Result<usize, IdentifyError> {
    match axis {
        None => Ok(0),
        Some(a) => job.axes.iter().position(|x| x.name == a).ok_or_else(|| {
            IdentifyError::Invalid(format!(
                "the job has no axis `{a}` (axes: {})",
                job.axis_names().join(", ")
            ))
        }),
    }
}

/// The inertia the job's feedforward of axis `i` uses (its `jl_kgm2`, else the model's).
pub fn feedforward_jl(job: &Job, i: usize) -> Option<f64> {
    let model_jl = job.axes[i].model.plant.two_mass()?.jl_kgm2;
    Some(
        job.chain
            .iter()
            .find(|c| c.axis == i && c.plugin == FEEDFORWARD)
            .and_then(|c| c.params.get("jl_kgm2").and_then(|v| v.as_float()))
            .unwrap_or(model_jl),
    )
}

/// A copy of `job` whose axis `i` plant has load inertia `plant_jl` and whose feedforward (if
/// any) uses `ff_jl`.
pub fn job_with_jl(job: &Job, i: usize, plant_jl: f64, ff_jl: f64) -> Result<Job, IdentifyError> {
    let mut j = job.clone();
    // The model's deviation is what the mechanics do: sensor noise and quantization belong to
    // the measurement (averaged over its window). Quantized, the simulated deviation would
    // move in steps of the scale's quantum, and the search would read a zero slope between
    // two inertias a quantum apart.
    j.axes[i].model.sensor = toml::Table::new();
    match &mut j.axes[i].model.plant {
        PlantParams::BallScrew { two_mass, .. } | PlantParams::Rotary { two_mass, .. } => {
            two_mass.jl_kgm2 = plant_jl;
        }
        PlantParams::Rigid(_) => {
            return Err(IdentifyError::Invalid(format!(
                "axis `{}` is rigid: it has no load inertia behind a spring",
                job.axes[i].name
            )))
        }
    }
    for c in j
        .chain
        .iter_mut()
        .filter(|c| c.axis == i && c.plugin == FEEDFORWARD)
    {
        c.params.insert("jl_kgm2".into(), toml::Value::Float(ff_jl));
    }
    Ok(j)
}

/// Runs `job` and returns the records of axis `i`.
pub fn run_axis(job: &Job, i: usize) -> Result<Vec<AxisRecord>, IdentifyError> {
    let mut sim =
        Simulation::new(job, &Builtins).map_err(|e| IdentifyError::Invalid(e.to_string()))?;
    let n = job.axes.len();
    let mut rows = [AxisRecord::default(); MAX_AXES];
    let mut out = Vec::with_capacity(sim.cycles() as usize);
    for _ in 0..sim.cycles() {
        sim.step(&mut rows[..n]);
        out.push(rows[i]);
    }
    Ok(out)
}

/// Refuses a recorded run (`what`: "the loaded run", ...) whose `A.torque` reaches the drive's
/// torque (force) limit `limit`: while it is clamped the deviation no longer grows linearly with
/// the inertia. Without a torque column or a known limit there is nothing to check.
pub fn check_unsaturated(
    trace: &Trace,
    axis: &str,
    limit: Option<f64>,
    what: &str,
) -> Result<(), IdentifyError> {
    let (Some(torque), Some(lim)) = (trace.column(&format!("{axis}.torque")), limit) else {
        return Ok(());
    };
    if !lim.is_finite() {
        return Ok(());
    }
    let at = |k: usize| torque[k].abs() >= 0.999 * lim;
    let Some(first) = (0..torque.len()).find(|&k| at(k)) else {
        return Ok(());
    };
    let n = (first..torque.len()).filter(|&k| at(k)).count();
    Err(IdentifyError::Invalid(format!(
        "{what} ({}) holds its torque at the limit {lim} of the model for {n} samples from \
         t = {:.4} s: the deviation is no longer linear in the inertia; record a gentler move",
        trace.path.display(),
        trace.t()[first],
    )))
}

/// The deviation of a simulated run.
pub fn simulated_deviation(
    job: &Job,
    i: usize,
    plant_jl: f64,
    ff_jl: f64,
    probe: Probe,
) -> Result<f64, IdentifyError> {
    let j = job_with_jl(job, i, plant_jl, ff_jl)?;
    let rec = run_axis(&j, i)?;
    if let Some(lim) = job.axes[i].model.controller.torque_limit {
        if let Some(k) = rec.iter().position(|r| r.torque.abs() >= 0.999 * lim) {
            return Err(IdentifyError::Invalid(format!(
                "the model saturates its torque limit {lim} at cycle {k} with jl_kgm2 = \
                 {plant_jl:.4e}: the deviation is no longer linear in the inertia; use a \
                 gentler move"
            )));
        }
    }
    records_deviation(&rec, job.axes[i].model.plant.motor_per_load(), probe)
}

/// Result of an inertia estimate.
#[derive(Debug, Clone, Serialize)]
pub struct InertiaEstimate {
    /// Estimated load inertia, kg m^2.
    pub jl_kgm2: f64,
    /// `sim-match` or `linear`.
    pub method: &'static str,
    /// Simulated moves (sim-match) or 0.
    pub iterations: usize,
    /// Measured deviation, load units.
    pub deviation_measured_m: f64,
    /// Deviation of the model at the estimate, load units.
    pub deviation_model_m: f64,
    /// Which deviation (`command-load` or `motor-load`).
    pub deviation: &'static str,
    /// Literal feedforward only (sim-match): the estimate of the patent's continuous-time
    /// model (exact inverse), kg m^2; `null` otherwise.
    pub jl_continuous_model_kgm2: Option<f64>,
    /// Literal feedforward only (sim-match): `100 (jl_continuous_model / jl - 1)`, the bias of
    /// estimating with the continuous-time model instead of the discrete controller the
    /// machine runs; `null` otherwise.
    pub literal_bias_percent: Option<f64>,
    /// What the estimate cannot vouch for (see [`unseen_load`]); empty when nothing.
    pub warnings: Vec<String>,
}

/// The share of the load inertia whose change the measured command-load deviation must at
/// least show to carry the inertia ([`unseen_load`]).
pub const VISIBLE_INERTIA_SHARE: f64 = 0.01;

/// The warning of a command-load estimate that the record does not carry. At the
/// feedforward's own inertia the command-load deviation is the feedforward's residual, whatever
/// that inertia is: a recorded run whose feedforward matched its load shows that residual, and
/// the search then returns the `--model` job's feedforward inertia `ff`, not the load's. So when
/// the measured deviation differs from the model's residual at `ff` by less than a change of
/// [`VISIBLE_INERTIA_SHARE`] of the estimate `jl` moves the deviation (`model_at_jl`: the
/// model's deviation at `jl`), the estimate holds only if the recorded run's feedforward used
/// `ff`. Two more simulated moves.
pub fn unseen_load(
    job: &Job,
    i: usize,
    jl: f64,
    ff: f64,
    measured: f64,
    model_at_jl: f64,
    probe: Probe,
) -> Result<Option<String>, IdentifyError> {
    let residual = simulated_deviation(job, i, ff, ff, probe)?;
    let moved = simulated_deviation(job, i, jl * (1.0 + VISIBLE_INERTIA_SHARE), ff, probe)?;
    let step = (moved - model_at_jl).abs();
    let carried = (measured - residual).abs();
    if carried >= step {
        return Ok(None);
    }
    Ok(Some(format!(
        "the measured command-load deviation ({measured:.3e}) differs from the feedforward's own \
         residual ({residual:.3e}: the deviation with the load at the feedforward's inertia \
         {ff:.4e} kg m^2) by {carried:.3e}, less than a {} % change of the load inertia moves it \
         ({step:.3e}): the record does not tell the load from the feedforward, and the estimate \
         is the feedforward's inertia, right only if the recorded run's feedforward used \
         jl_kgm2 = {ff:.4e}. Record the move with the feedforward at another inertia (or \
         without it), or read --deviation motor-load (the screw's twist, which the feedforward \
         does not cancel)",
        100.0 * VISIBLE_INERTIA_SHARE
    )))
}

/// Whether axis `i`'s feedforward runs the literal patent structure.
pub fn feedforward_is_literal(job: &Job, i: usize) -> bool {
    job.chain.iter().any(|c| {
        c.axis == i
            && c.plugin == FEEDFORWARD
            && c.params.get("structure").and_then(|v| v.as_str()) == Some("literal")
    })
}

/// Result of one secant search.
struct Match {
    jl: f64,
    iterations: usize,
    model_deviation: f64,
}

/// Secant search on the (linear) deviation characteristic of `job`'s axis `i`, the feedforward
/// keeping `ff`: started at `jl0` and 1.5 times it; at most 20 moves.
fn secant(
    job: &Job,
    i: usize,
    jl0: f64,
    ff: f64,
    measured: f64,
    probe: Probe,
) -> Result<Match, IdentifyError> {
    let f = |jl: f64| simulated_deviation(job, i, jl, ff, probe).map(|d| d - measured);
    let (mut xa, mut xb) = (jl0, 1.5 * jl0);
    let (mut fa, mut fb) = (f(xa)?, f(xb)?);
    let mut iterations = 2;
    // The deviation can be ~0 (command-load at the feedforward's own inertia): scale the
    // tolerance by the characteristic's change over the first step as well.
    let scale = measured.abs().max((fb - fa).abs()).max(1e-12);
    let tol = 1e-5 * scale;
    while fb.abs() > tol && iterations < 20 {
        let slope = (fb - fa) / (xb - xa);
        if !(slope.is_finite() && slope != 0.0) {
            return Err(IdentifyError::Invalid(format!(
                "the deviation at {} does not change with the load inertia: pick a position \
                 where the axis accelerates",
                probe.at
            )));
        }
        let xn = (xb - fb / slope).max(1e-3 * jl0);
        xa = xb;
        fa = fb;
        xb = xn;
        fb = f(xb)?;
        iterations += 1;
        if (xb - xa).abs() < 1e-9 * xb {
            break;
        }
    }
    if fb.abs() > 1e-3 * scale {
        return Err(IdentifyError::Invalid(format!(
            "no load inertia reproduces the measured deviation {measured:.4e} (best {xb:.4e} kg m^2 \
             leaves {fb:.3e}); check the model's KL, JM and controller"
        )));
    }
    Ok(Match {
        jl: xb,
        iterations,
        model_deviation: fb + measured,
    })
}

/// Method 1: adjusts the model's `jl_kgm2` until the simulated deviation at `probe` equals
/// `measured` (secant, started at the job's inertia and 1.5 times it; at most 20 moves). With
/// a literal feedforward the search is repeated on the continuous-time model (the job with the
/// split structure) and the difference reported as `literal_bias_percent`; `iterations`
/// counts the moves of both searches.
pub fn sim_match(
    job: &Job,
    i: usize,
    measured: f64,
    probe: Probe,
) -> Result<InertiaEstimate, IdentifyError> {
    let jl0 = job.axes[i]
        .model
        .plant
        .two_mass()
        .ok_or_else(|| IdentifyError::Invalid("a rigid axis has no load inertia".into()))?
        .jl_kgm2;
    let ff = feedforward_jl(job, i).unwrap_or(jl0);
    let m = secant(job, i, jl0, ff, measured, probe)?;
    let mut iterations = m.iterations;
    let (mut jl_cont, mut bias) = (None, None);
    if feedforward_is_literal(job, i) {
        let mut cont = job.clone();
        for c in cont
            .chain
            .iter_mut()
            .filter(|c| c.axis == i && c.plugin == FEEDFORWARD)
        {
            c.params
                .insert("structure".into(), toml::Value::String("split".into()));
        }
        let mc = secant(&cont, i, jl0, ff, measured, probe)?;
        iterations += mc.iterations;
        jl_cont = Some(mc.jl);
        bias = Some(100.0 * (mc.jl / m.jl - 1.0));
    }
    let warnings = match probe.kind {
        DeviationKind::CommandLoad => {
            unseen_load(job, i, m.jl, ff, measured, m.model_deviation, probe)?
                .into_iter()
                .collect()
        }
        DeviationKind::MotorLoad => vec![],
    };
    Ok(InertiaEstimate {
        warnings,
        jl_kgm2: m.jl,
        method: "sim-match",
        iterations,
        deviation_measured_m: measured,
        deviation_model_m: m.model_deviation,
        deviation: probe.kind.name(),
        jl_continuous_model_kgm2: jl_cont,
        literal_bias_percent: bias,
    })
}

/// How far beyond its two runs the linear characteristic may be extrapolated, in spans
/// (no-load to loaded).
pub const MAX_EXTRAPOLATION_SPANS: f64 = 3.0;

/// Method 2: JL from the linear deviation characteristic through a no-load run (`dev0` at
/// `jl0`) and a known-load run (`dev1` at `jl1`).
pub fn linear(
    dev0: f64,
    jl0: f64,
    dev1: f64,
    jl1: f64,
    measured: f64,
    kind: DeviationKind,
) -> Result<InertiaEstimate, IdentifyError> {
    for (flag, v) in [("--no-load-jl-kgm2", jl0), ("--loaded-jl-kgm2", jl1)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(IdentifyError::Invalid(format!(
                "{flag} must be a finite load inertia > 0 kg m^2, got {v}"
            )));
        }
    }
    if (dev1 - dev0).abs() <= 1e-12 || (jl1 - jl0).abs() <= 0.0 {
        return Err(IdentifyError::Invalid(format!(
            "the no-load and loaded runs give the same deviation ({dev0:.4e} / {dev1:.4e}) or \
             inertia: no characteristic to interpolate"
        )));
    }
    let spans = (measured - dev0) / (dev1 - dev0);
    let jl = jl0 + spans * (jl1 - jl0);
    if !(-MAX_EXTRAPOLATION_SPANS..=1.0 + MAX_EXTRAPOLATION_SPANS).contains(&spans) {
        return Err(IdentifyError::Invalid(format!(
            "the measured deviation lies {spans:.2} spans of the characteristic from the no-load \
             run (jl_kgm2 would be {jl:.4e}): more than {MAX_EXTRAPOLATION_SPANS} spans beyond \
             its two runs is an extrapolation nobody can vouch for; record a known-load run \
             nearer the machine's load"
        )));
    }
    if jl.is_nan() || jl <= 0.0 {
        return Err(IdentifyError::Invalid(format!(
            "the characteristic gives a non-positive inertia {jl:.4e} kg m^2"
        )));
    }
    Ok(InertiaEstimate {
        jl_kgm2: jl,
        method: "linear",
        iterations: 0,
        deviation_measured_m: measured,
        deviation_model_m: measured,
        deviation: kind.name(),
        jl_continuous_model_kgm2: None,
        literal_bias_percent: None,
        warnings: vec![],
    })
}

/// The model file of axis `i` with `jl_kgm2` set to `jl` (TOML text), and the feedforward
/// coefficients a1..a5 the new inertia gives with the model's Kv, Tv.
pub fn applied_model(job: &Job, i: usize, jl: f64) -> Result<(String, [f64; 5]), IdentifyError> {
    let m = &job.axes[i].model;
    let text = std::fs::read_to_string(&m.path)
        .map_err(|e| IdentifyError::Invalid(format!("reading {}: {e}", m.path.display())))?;
    let mut t: toml::Table = text
        .parse()
        .map_err(|e| IdentifyError::Invalid(format!("{}: {e}", m.path.display())))?;
    t.insert("jl_kgm2".into(), toml::Value::Float(jl));
    let mut plant = m.plant;
    if let PlantParams::BallScrew { two_mass, .. } | PlantParams::Rotary { two_mass, .. } =
        &mut plant
    {
        two_mass.jl_kgm2 = jl;
    }
    let kv = m.controller.kv.unwrap_or(5.0);
    let tv = m.controller.tv_s.unwrap_or(0.0);
    let a = TwoMassModel::of_plant(&plant).coefficients_a(kv, tv);
    let out = format!(
        "# {} with jl_kgm2 identified by feedloop identify inertia (feedforward a3..a5 = {:.6e}, \
         {:.6e}, {:.6e})\n{}",
        m.path.display(),
        a[2],
        a[3],
        a[4],
        toml::to_string(&t).map_err(|e| IdentifyError::Invalid(e.to_string()))?
    );
    Ok((out, a))
}
