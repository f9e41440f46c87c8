//! One axis of a trace in the model's motor units, with zero-phase filtered derivatives.
//!
//! Positions are converted to motor units (a ball screw's table position in m times
//! `2 pi gear_ratio / lead_m`), filtered with a zero-phase 4th-order Butterworth low-pass and
//! differentiated by central differences, as the EMPS benchmark's authors do. The torque column
//! goes through the same zero-phase filter by default (parallel filtering), so the equation error
//! compares like with like.

use std::path::{Path, PathBuf};

use feedloop_model::model::{AxisKind, ModelFile};
use feedloop_trace::Trace;

use super::law::{best_law, HeldLaw, Law};
use super::lsq::{blocks, cross_validate, normals, CI_SIGMAS};
use super::signal::{
    block_centres, block_means, derivative, derivative_fine, filtfilt_butter4, span, std_dev,
    zoh_mid,
};
use super::WorkbenchError;

/// The trace columns (after `A.`) taken as a known input added after the controller when no
/// `--added-input` is given, in this order: `torque_add` (a test injection) and `tau_ff` (a
/// feed-forward torque the drive adds after its feedback law, as robot and CNC drives log it).
pub const ADDED_INPUT_COLUMNS: [&str; 2] = ["torque_add", "tau_ff"];

/// How the trace is prepared.
#[derive(Debug, Clone)]
pub struct Prep {
    /// Cut-off of the zero-phase filter applied to positions before differentiation, Hz
    /// (`None`: `min(100 Hz, fs / 10)`).
    pub cutoff_hz: Option<f64>,
    /// Filter the torque column with the same zero-phase filter ("parallel filtering", so the
    /// residual compares like with like and is not dominated by torque noise above the cut-off).
    pub filter_torque: bool,
    /// Column holding a known input added to the controller's output after the controller
    /// (`None`: `A.torque_add`, else `A.tau_ff`, when the trace has it; see
    /// [`ADDED_INPUT_COLUMNS`]). Same units as `A.torque`; the recorded
    /// torque is taken to include it, as a drive reports the total command.
    pub added_input: Option<String>,
}

impl Default for Prep {
    fn default() -> Self {
        Self {
            cutoff_hz: None,
            filter_torque: true,
            added_input: None,
        }
    }
}

/// One axis of a trace, motor units, with derivatives.
#[derive(Debug, Clone)]
pub struct AxisData {
    /// The trace file.
    pub path: PathBuf,
    /// Axis name.
    pub axis: String,
    /// Axis kind of the model.
    pub kind: AxisKind,
    /// Motor units per load unit (rad/m for a ball screw, else 1).
    pub r: f64,
    /// Sampling period, s.
    pub dt: f64,
    /// Time, s.
    pub t: Vec<f64>,
    /// Commanded position, motor units.
    pub cmd: Vec<f64>,
    /// Measured load position, load units (as in the trace).
    pub load_raw: Vec<f64>,
    /// Measured motor position, motor units, when the trace has `A.motor` (less the encoders'
    /// zero offset when one was found).
    pub motor_raw: Option<Vec<f64>>,
    /// The zero offset found between the motor and the load encoder and removed from
    /// `motor_raw`, motor units (see [`encoder_offset`]).
    pub encoder_offset: Option<f64>,
    /// Torque (force) column, motor units, when present (filtered when `torque_filtered`).
    pub torque: Option<Vec<f64>>,
    /// The torque column as recorded.
    pub torque_raw: Option<Vec<f64>>,
    /// Measured motor velocity (`A.motor_vel`), motor units/s, when the trace has it.
    pub motor_vel_raw: Option<Vec<f64>>,
    /// A known input added after the controller (see [`Prep::added_input`]): its column name
    /// and values, torque units, as recorded.
    pub added_input: Option<(String, Vec<f64>)>,
    /// Filtered motor position (from `A.motor`, else the load position in motor units).
    pub qm: Vec<f64>,
    /// Its velocity.
    pub vm: Vec<f64>,
    /// Its acceleration.
    pub am: Vec<f64>,
    /// Filtered load position in motor units.
    pub ql: Vec<f64>,
    /// Its velocity.
    pub vl: Vec<f64>,
    /// Its acceleration.
    pub al: Vec<f64>,
    /// Cut-off used, Hz.
    pub cutoff_hz: f64,
    /// Whether the torque column was filtered (then nonlinear regressor columns are filtered
    /// the same way after the nonlinearity).
    pub torque_filtered: bool,
    /// First and one-past-last sample used in fits (filter edges left out).
    pub range: (usize, usize),
    /// Recorded samples per sample held: 1, or on a long trace read with [`load_axis_held`] the
    /// size of the blocks whose means are held.
    pub sub: usize,
    /// On a long trace held in block means: the controller law evaluated at the recording's
    /// rate (see [`HeldLaw`]).
    pub held_law: Option<HeldLaw>,
}

impl AxisData {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// Whether the trace is empty.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Whether a separate motor position was measured.
    pub fn has_motor(&self) -> bool {
        self.motor_raw.is_some()
    }

    /// The measured load position in motor units (unfiltered).
    pub fn load_in_motor_units(&self) -> Vec<f64> {
        in_motor_units(&self.load_raw, self.r)
    }

    /// The same data prepared with another filter cut-off (derivatives, filtered torque and
    /// the fit range recomputed from the recorded columns).
    pub fn with_cutoff(&self, cutoff_hz: f64) -> AxisData {
        // the recorded columns only: the derived ones are made anew
        Recorded {
            path: self.path.clone(),
            axis: self.axis.clone(),
            kind: self.kind,
            r: self.r,
            dt: self.dt,
            t: self.t.clone(),
            cmd: self.cmd.clone(),
            load_raw: self.load_raw.clone(),
            motor_raw: self.motor_raw.clone(),
            encoder_offset: self.encoder_offset,
            torque_raw: self.torque_raw.clone(),
            motor_vel_raw: self.motor_vel_raw.clone(),
            added_input: self.added_input.clone(),
            torque_filtered: self.torque_filtered,
            sub: self.sub,
            held_law: self.held_law.clone(),
        }
        .prepared(cutoff_hz)
    }

    /// Every `q`-th sample of every series (the filtered ones are band-limited to the cut-off,
    /// so `q` up to `fs / (10 cut-off)` loses nothing of them).
    pub fn decimated(&self, q: usize) -> AxisData {
        let q = q.max(1);
        let dec = |x: &[f64]| x.iter().step_by(q).copied().collect::<Vec<f64>>();
        let opt = |x: &Option<Vec<f64>>| x.as_deref().map(dec);
        let (a, b) = self.range;
        let n = self.len().div_ceil(q);
        AxisData {
            path: self.path.clone(),
            axis: self.axis.clone(),
            kind: self.kind,
            r: self.r,
            dt: self.dt * q as f64,
            t: dec(&self.t),
            cmd: dec(&self.cmd),
            load_raw: dec(&self.load_raw),
            motor_raw: opt(&self.motor_raw),
            encoder_offset: self.encoder_offset,
            torque: opt(&self.torque),
            torque_raw: opt(&self.torque_raw),
            motor_vel_raw: opt(&self.motor_vel_raw),
            added_input: self
                .added_input
                .as_ref()
                .map(|(name, x)| (name.clone(), dec(x))),
            qm: dec(&self.qm),
            vm: dec(&self.vm),
            am: dec(&self.am),
            ql: dec(&self.ql),
            vl: dec(&self.vl),
            al: dec(&self.al),
            cutoff_hz: self.cutoff_hz,
            torque_filtered: self.torque_filtered,
            range: (a.div_ceil(q).min(n), (b / q).min(n)),
            sub: self.sub,
            held_law: None,
        }
    }

    /// The columns of this axis that were read from the trace (the axis' own columns and the
    /// declared added input), for error messages.
    pub fn columns_present(&self) -> Vec<String> {
        let a = &self.axis;
        let mut c = vec![format!("{a}.cmd"), format!("{a}.load")];
        for (name, has) in [
            ("motor", self.motor_raw.is_some()),
            ("torque", self.torque_raw.is_some()),
            ("motor_vel", self.motor_vel_raw.is_some()),
        ] {
            if has {
                c.push(format!("{a}.{name}"));
            }
        }
        if let Some((name, _)) = &self.added_input {
            c.push(name.clone());
        }
        c
    }

    /// The torque column or an error naming it and the method that needs it.
    pub fn require_torque(
        &self,
        needed_for: &str,
        trace: &Trace,
    ) -> Result<&[f64], WorkbenchError> {
        self.torque
            .as_deref()
            .ok_or_else(|| missing(trace, &format!("{}.torque", self.axis), needed_for))
    }
}

/// Load positions `load_raw` (load units) in motor units, `r` motor units per load unit.
fn in_motor_units(load_raw: &[f64], r: f64) -> Vec<f64> {
    load_raw.iter().map(|x| x * r).collect()
}

/// The recorded columns of an axis (see [`AxisData`] for each), from which
/// [`Recorded::prepared`] makes the filtered ones.
struct Recorded {
    path: PathBuf,
    axis: String,
    kind: AxisKind,
    r: f64,
    dt: f64,
    t: Vec<f64>,
    cmd: Vec<f64>,
    load_raw: Vec<f64>,
    motor_raw: Option<Vec<f64>>,
    encoder_offset: Option<f64>,
    torque_raw: Option<Vec<f64>>,
    motor_vel_raw: Option<Vec<f64>>,
    added_input: Option<(String, Vec<f64>)>,
    torque_filtered: bool,
    sub: usize,
    held_law: Option<HeldLaw>,
}

impl Recorded {
    /// The axis with the filtered positions, their derivatives, the filtered torque (when
    /// `torque_filtered`) and the fit range (filter edges left out) made from the recorded
    /// columns.
    fn prepared(self, cutoff_hz: f64) -> AxisData {
        let fs = 1.0 / self.dt;
        let n = self.t.len();
        let load_m = in_motor_units(&self.load_raw, self.r);
        let fine = self.sub > 1;
        let (ql, vl, al) = filtered_derivatives(&load_m, cutoff_hz, self.dt, fine);
        let (qm, vm, am) = match &self.motor_raw {
            Some(m) => filtered_derivatives(m, cutoff_hz, self.dt, fine),
            None => (ql.clone(), vl.clone(), al.clone()),
        };
        let torque = match &self.torque_raw {
            Some(y) if self.torque_filtered => Some(filtfilt_butter4(y, cutoff_hz, fs)),
            other => other.clone(),
        };
        let edge = ((fs / cutoff_hz).ceil() as usize * 2).min(n / 10);
        AxisData {
            path: self.path,
            axis: self.axis,
            kind: self.kind,
            r: self.r,
            dt: self.dt,
            t: self.t,
            cmd: self.cmd,
            load_raw: self.load_raw,
            motor_raw: self.motor_raw,
            encoder_offset: self.encoder_offset,
            torque,
            torque_raw: self.torque_raw,
            motor_vel_raw: self.motor_vel_raw,
            added_input: self.added_input,
            qm,
            vm,
            am,
            ql,
            vl,
            al,
            cutoff_hz,
            torque_filtered: self.torque_filtered,
            range: (edge, n - edge),
            sub: self.sub,
            held_law: self.held_law,
        }
    }
}

/// Takes the zero offset between the motor and the load encoder (see [`encoder_offset`]; `load_m`
/// in motor units) out of `motor`, when there is one; and that offset.
fn remove_encoder_offset(
    motor: &mut Option<Vec<f64>>,
    load_m: &[f64],
    torque: Option<&[f64]>,
    dt: f64,
) -> Option<f64> {
    let offset = motor
        .as_deref()
        .and_then(|m| encoder_offset(m, load_m, torque, dt));
    if let (Some(m), Some(c)) = (motor.as_mut(), offset) {
        m.iter_mut().for_each(|v| *v -= c);
    }
    offset
}

fn missing(trace: &Trace, column: &str, needed_for: &str) -> WorkbenchError {
    WorkbenchError::MissingColumn {
        path: trace.path.clone(),
        column: column.to_string(),
        needed_for: needed_for.to_string(),
        present: trace.columns.join(", "),
    }
}

/// A position filtered zero-phase at `cutoff` and its first two derivatives (by the 7-point
/// stencil when `fine`: a series held in block means, sampled at ten times the cut-off only).
fn filtered_derivatives(
    x: &[f64],
    cutoff: f64,
    dt: f64,
    fine: bool,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let q = filtfilt_butter4(x, cutoff, 1.0 / dt);
    let diff = if fine { derivative_fine } else { derivative };
    let v = diff(&q, dt);
    let a = diff(&v, dt);
    (q, v, a)
}

/// The axis prefixes of `trace`'s columns (`x` of `x.cmd`, `x.motor`, ...) in column order, each
/// with the first of the two columns every axis needs (`A.cmd`, `A.load`) that it lacks.
fn axis_prefixes(trace: &Trace) -> Vec<(String, Option<String>)> {
    let mut out: Vec<(String, Option<String>)> = Vec::new();
    for (a, _) in trace.columns.iter().filter_map(|c| c.split_once('.')) {
        if !out.iter().any(|(p, _)| p == a) {
            let lacks = ["cmd", "load"]
                .iter()
                .map(|s| format!("{a}.{s}"))
                .find(|c| trace.column(c).is_none());
            out.push((a.to_string(), lacks));
        }
    }
    out
}

/// The refusal of axis `a` (asked for, or the only prefix of the trace) whose columns are
/// partly there: the real column it lacks.
fn partial_axis(trace: &Trace, a: &str, lacks: &str) -> WorkbenchError {
    missing(
        trace,
        lacks,
        &format!("axis `{a}` (every workbench command reads `{a}.cmd` and `{a}.load`)"),
    )
}

/// Chooses the axis of `trace` the model applies to: `axis` when given (it must exist), else the
/// only axis of the trace.
pub fn pick_axis(
    trace: &Trace,
    model_path: &Path,
    axis: Option<&str>,
) -> Result<String, WorkbenchError> {
    let axes = trace.axes();
    let prefixes = axis_prefixes(trace);
    let lacking = |a: &str| {
        prefixes
            .iter()
            .find(|(p, _)| p == a)
            .and_then(|(_, l)| l.clone())
    };
    match axis {
        Some(a) if axes.iter().any(|x| x == a) => Ok(a.to_string()),
        Some(a) => match lacking(a) {
            Some(col) => Err(partial_axis(trace, a, &col)),
            None => {
                let names: Vec<String> = prefixes
                    .iter()
                    .map(|(p, l)| match l {
                        Some(l) => format!("{p} (no `{l}`)"),
                        None => p.clone(),
                    })
                    .collect();
                Err(WorkbenchError::Mismatch {
                    trace: trace.path.clone(),
                    model: model_path.to_path_buf(),
                    reason: format!(
                        "the trace has no axis `{a}` (axes: {}; column prefixes: {}); an axis \
                         needs the columns `A.cmd` and `A.load`",
                        if axes.is_empty() {
                            "none".to_string()
                        } else {
                            axes.join(", ")
                        },
                        if names.is_empty() {
                            "none".to_string()
                        } else {
                            names.join(", ")
                        },
                    ),
                })
            }
        },
        None => match axes.len() {
            1 => Ok(axes[0].clone()),
            0 => match prefixes
                .iter()
                .find_map(|(p, l)| l.as_ref().map(|l| (p, l)))
            {
                Some((p, col)) => Err(partial_axis(trace, p, col)),
                None => Err(missing(
                    trace,
                    "A.cmd",
                    "every workbench command (no axis columns `A.cmd`/`A.load`)",
                )),
            },
            _ => Err(WorkbenchError::Mismatch {
                trace: trace.path.clone(),
                model: model_path.to_path_buf(),
                reason: format!(
                    "the trace has {} axes ({}); choose the one the model describes with --axis",
                    axes.len(),
                    axes.join(", ")
                ),
            }),
        },
    }
}

/// Reads axis `axis` of `trace` in the units of `model` and prepares derivatives.
pub fn load_axis(
    trace: &Trace,
    model: &ModelFile,
    axis: &str,
    prep: &Prep,
) -> Result<AxisData, WorkbenchError> {
    let kind = model.plant.kind();
    let r = model.plant.motor_per_load();
    let col = |name: &str, why: &str| -> Result<Vec<f64>, WorkbenchError> {
        trace
            .column(&format!("{axis}.{name}"))
            .map(<[f64]>::to_vec)
            .ok_or_else(|| missing(trace, &format!("{axis}.{name}"), why))
    };
    let cmd_raw = col("cmd", "the commanded position")?;
    let load_raw = col("load", "the measured position")?;
    let motor_raw = trace.column(&format!("{axis}.motor")).map(<[f64]>::to_vec);
    let torque = trace.column(&format!("{axis}.torque")).map(<[f64]>::to_vec);
    let motor_vel_raw = trace
        .column(&format!("{axis}.motor_vel"))
        .map(<[f64]>::to_vec);
    let added_input = match &prep.added_input {
        Some(name) => Some((
            name.clone(),
            trace
                .column(name)
                .map(<[f64]>::to_vec)
                .ok_or_else(|| missing(trace, name, "the declared added input (--added-input)"))?,
        )),
        None => ADDED_INPUT_COLUMNS.iter().find_map(|c| {
            let name = format!("{axis}.{c}");
            trace.column(&name).map(|col| (name, col.to_vec()))
        }),
    };
    let n = trace.len();
    if n < 50 {
        return Err(WorkbenchError::Data {
            path: trace.path.clone(),
            reason: format!("only {n} samples; the workbench needs at least 50"),
        });
    }
    let dt = trace.period_s();
    let fs = 1.0 / dt;
    if let Some(m) = &motor_raw {
        check_travel(trace, model, axis, m, &load_raw)?;
    }
    let mut motor_raw = motor_raw;
    let offset = remove_encoder_offset(
        &mut motor_raw,
        &in_motor_units(&load_raw, r),
        torque.as_deref(),
        dt,
    );
    let cutoff = prep.cutoff_hz.unwrap_or((fs / 10.0).min(100.0));
    Ok(Recorded {
        path: trace.path.clone(),
        axis: axis.to_string(),
        kind,
        r,
        dt,
        t: trace.t().to_vec(),
        cmd: cmd_raw.iter().map(|x| x * r).collect(),
        load_raw,
        motor_raw,
        encoder_offset: offset,
        torque_raw: torque,
        motor_vel_raw,
        added_input,
        torque_filtered: prep.filter_torque,
        sub: 1,
        held_law: None,
    }
    .prepared(cutoff))
}

/// The zero offset between a motor and a load encoder (`motor` and `load`, both motor units),
/// `None` when there is none to speak of. The deflection `motor - load` is regressed on a
/// constant, the torque (what the transmission's compliance follows) and the direction of travel
/// (what a lost motion follows); the constant is an offset of the encoders' zeros, which no
/// physics of the transmission makes. It counts when it lies outside its own confidence
/// interval (3 standard errors over 5 blocks), exceeds half the RMS of the deflection the
/// other columns explain, and is larger than 1e-9 of the travel; a trace with no reversal
/// cannot tell it from a lost motion and gives `None`.
pub fn encoder_offset(motor: &[f64], load: &[f64], torque: Option<&[f64]>, dt: f64) -> Option<f64> {
    let full = motor.len().min(load.len());
    if full < 50 {
        return None;
    }
    // at most 200,000 evenly spread samples: a constant needs no more, and a long trace's
    // columns are not copied whole
    let step = (full / 200_000).max(1);
    let at: Vec<usize> = (0..full).step_by(step).collect();
    let n = at.len();
    let defl: Vec<f64> = at.iter().map(|&k| motor[k] - load[k]).collect();
    let vel: Vec<f64> = at
        .iter()
        .map(|&k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(full - 1));
            (motor[b] - motor[a]) / ((b - a).max(1) as f64 * dt)
        })
        .collect();
    let torque: Option<Vec<f64>> = torque.map(|y| at.iter().map(|&k| y[k]).collect());
    let vmax = vel.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let dir: Vec<f64> = vel
        .iter()
        .map(|v| {
            if v.abs() > 0.02 * vmax {
                v.signum()
            } else {
                0.0
            }
        })
        .collect();
    if !(dir.contains(&1.0) && dir.contains(&-1.0)) {
        return None;
    }
    let one = vec![1.0; n];
    let mut cols: Vec<&[f64]> = vec![&one, &dir];
    if let Some(y) = &torque {
        cols.push(y);
    }
    let cv = cross_validate(&normals(&cols, &defl, &blocks((0, n), 5)));
    let (c0, se) = (cv.theta[0], cv.theta_se[0]);
    let explained: Vec<f64> = (0..n)
        .map(|k| {
            (1..cols.len())
                .map(|j| cv.theta[j] * cols[j][k])
                .sum::<f64>()
        })
        .collect();
    let counts = c0.abs() > CI_SIGMAS * se
        && c0.abs() > 0.5 * std_dev(&explained)
        && c0.abs() > 1e-9 * span(motor);
    counts.then_some(c0)
}

/// Units check: with a motor column the ratio of motor to load travel must match the model.
fn check_travel(
    trace: &Trace,
    model: &ModelFile,
    axis: &str,
    m: &[f64],
    load: &[f64],
) -> Result<(), WorkbenchError> {
    let kind = model.plant.kind();
    let r = model.plant.motor_per_load();
    let (tm, tl) = (span(m), span(load));
    if tl > 0.0 && tm > 0.0 {
        let ratio = tm / tl;
        if (ratio / r - 1.0).abs() > 0.2 {
            return Err(WorkbenchError::Mismatch {
                trace: trace.path.clone(),
                model: model.path.clone(),
                reason: format!(
                    "axis `{axis}`: motor travel / load travel = {ratio:.4} but the model ({} axis) implies {r:.4} motor units per load unit (check lead_m, gear_ratio, kind or the trace's units)",
                    kind.id()
                ),
            });
        }
    }
    Ok(())
}

/// Recorded samples per held sample for a long trace of sampling period `dt` filtered at
/// `cutoff_hz`: `fs / (10 cutoff)`, so that the held rate is still ten times the cut-off (the
/// filtered signals lose nothing, see [`AxisData::decimated`]); 1 when the rate allows no less.
pub fn held_block(dt: f64, cutoff_hz: f64) -> usize {
    // (a ratio that is a whole number in decimal, 4 kHz over 1 kHz, may come out just below it)
    ((1.0 / (dt * 10.0 * cutoff_hz) * (1.0 + 1e-9)).floor() as usize).max(1)
}

/// Reads axis `axis` of a long `trace` like [`load_axis`], with the same checks, but holds the
/// means of blocks of `q` recorded samples (see [`held_block`]) instead of every sample: the
/// columns are taken out of the trace one by one, each reduced to its block means and freed,
/// so memory is that of the trace's columns for the axis and no more. The recorded torque is
/// held as the block means of the torque acting between the samples (the half-sample alignment
/// of `WbModel::applied_torque`, done here at the recording's rate); the filtered positions,
/// their derivatives and the filtered torque are then made from the block means at the held
/// rate, so every series of the equation error goes through the same block mean and filter. The
/// controller law, whose integrator sums every recorded sample, is evaluated on the recorded
/// samples before they are freed and kept at the block centres ([`HeldLaw`]).
pub fn load_axis_held(
    trace: Trace,
    file: &ModelFile,
    axis: &str,
    prep: &Prep,
    q: usize,
) -> Result<AxisData, WorkbenchError> {
    let q = q.max(1);
    let kind = file.plant.kind();
    let r = file.plant.motor_per_load();
    let added_name = held_checks(&trace, file, axis, prep, q)?;
    let dt = trace.period_s();
    let cutoff = prep.cutoff_hz.unwrap_or((1.0 / dt / 10.0).min(100.0));
    let path = trace.path.clone();
    let t = block_means(trace.t(), q);
    let mut c = FullRate::take(trace, axis, added_name.as_deref());
    let load_raw = block_means(&c.x, q);
    c.cmd.iter_mut().for_each(|v| *v *= r);
    c.x.iter_mut().for_each(|v| *v *= r);
    let offset = remove_encoder_offset(&mut c.motor, &c.x, c.torque.as_deref(), dt);
    let held_law = c.held_law(file, dt, q);
    // the torque acting between samples k - 1 and k, in block means
    let torque_raw = c.torque.map(|y| {
        (0..y.len() / q)
            .map(|b| (b * q..(b + 1) * q).map(|k| zoh_mid(&y, k)).sum::<f64>() / q as f64)
            .collect()
    });
    Ok(Recorded {
        path,
        axis: axis.to_string(),
        kind,
        r,
        dt: dt * q as f64,
        t,
        cmd: block_means(&c.cmd, q),
        load_raw,
        encoder_offset: offset,
        motor_raw: c.motor.map(|m| block_means(&m, q)),
        torque_raw,
        motor_vel_raw: c.motor_vel.map(|v| block_means(&v, q)),
        added_input: added_name.zip(c.added.map(|a| block_means(&a, q))),
        torque_filtered: prep.filter_torque,
        sub: q,
        held_law,
    }
    .prepared(cutoff))
}

/// The checks of [`load_axis_held`], those of [`load_axis`] on a trace held in blocks of `q`:
/// the axis' columns, the added input (its column name, when there is one), the length and the
/// travel ratio.
fn held_checks(
    trace: &Trace,
    file: &ModelFile,
    axis: &str,
    prep: &Prep,
    q: usize,
) -> Result<Option<String>, WorkbenchError> {
    let name = |c: &str| format!("{axis}.{c}");
    for (c, why) in [
        ("cmd", "the commanded position"),
        ("load", "the measured position"),
    ] {
        if !trace.has(&name(c)) {
            return Err(missing(trace, &name(c), why));
        }
    }
    let added_name = match &prep.added_input {
        Some(n) if trace.has(n) => Some(n.clone()),
        Some(n) => {
            return Err(missing(
                trace,
                n,
                "the declared added input (--added-input)",
            ))
        }
        None => ADDED_INPUT_COLUMNS
            .iter()
            .map(|c| name(c))
            .find(|n| trace.has(n)),
    };
    let n = trace.len();
    if n < 50 * q {
        return Err(WorkbenchError::Data {
            path: trace.path.clone(),
            reason: format!("only {n} samples; the workbench needs at least 50"),
        });
    }
    if let (Some(m), Some(l)) = (trace.column(&name("motor")), trace.column(&name("load"))) {
        check_travel(trace, file, axis, m, l)?;
    }
    Ok(added_name)
}

/// The columns of one axis of a long trace at the recording's rate, taken out of it.
struct FullRate {
    /// Commanded position.
    cmd: Vec<f64>,
    /// Load position.
    x: Vec<f64>,
    motor: Option<Vec<f64>>,
    motor_vel: Option<Vec<f64>>,
    torque: Option<Vec<f64>>,
    /// The added input (column `added_name`).
    added: Option<Vec<f64>>,
}

impl FullRate {
    /// Takes the columns of `axis` (checked by [`held_checks`]) and the added input named
    /// `added_name` out of `trace`, freeing the rest.
    fn take(trace: Trace, axis: &str, added_name: Option<&str>) -> Self {
        let name = |c: &str| format!("{axis}.{c}");
        let mut cols: Vec<(String, Vec<f64>)> = trace.into_columns();
        let mut take = |c: &str| {
            cols.iter()
                .position(|(k, _)| k == c)
                .map(|i| cols.swap_remove(i).1)
        };
        let (Some(cmd), Some(x)) = (take(&name("cmd")), take(&name("load"))) else {
            unreachable!("checked above")
        };
        let motor = take(&name("motor"));
        let motor_vel = take(&name("motor_vel"));
        let torque = take(&name("torque"));
        let added = added_name.and_then(&mut take);
        FullRate {
            cmd,
            x,
            motor,
            motor_vel,
            torque,
            added,
        }
    }

    /// The controller law of `file` evaluated on every recorded sample (period `dt`, positions
    /// in motor units), kept at the centres of blocks of `q` ([`HeldLaw`]).
    fn held_law(&self, file: &ModelFile, dt: f64, q: usize) -> Option<HeldLaw> {
        let (Some(law_p), Some(rec)) = (Law::of(file), &self.torque) else {
            return None;
        };
        best_law(
            &law_p,
            &self.cmd,
            &self.x,
            self.motor.as_deref().unwrap_or(&self.x),
            self.motor_vel.as_deref(),
            rec,
            self.added.as_deref(),
            dt,
        )
        .map(|(velocity, discretisation, law)| HeldLaw {
            law_of: law_p,
            recorded: block_centres(rec, q),
            law: block_centres(&law, q),
            add: self.added.as_deref().map(|a| block_centres(a, q)),
            velocity,
            discretisation,
        })
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;
    use crate::workbench::controller::ControllerChannel;
    use crate::workbench::effects::WbModel;

    fn model() -> WbModel {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/xy-x.toml");
        WbModel::load(&p).unwrap()
    }

    /// A trace of axis `x` of `n` samples at 10 kHz, motor and load consistent with `model`.
    fn trace(m: &WbModel, n: usize, with_load: bool) -> Trace {
        let r = m.file.plant.motor_per_load();
        let dt = 1e-4;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * dt).collect();
        let load: Vec<f64> = t
            .iter()
            .map(|t| 0.01 * (2.0 * PI * 3.0 * t).sin())
            .collect();
        let cmd: Vec<f64> = t
            .iter()
            .zip(&load)
            .map(|(t, l)| l + 1e-5 * (2.0 * PI * 3.0 * t).cos())
            .collect();
        let motor: Vec<f64> = load
            .iter()
            .enumerate()
            .map(|(k, l)| l * r + 1e-6 * ((k % 7) as f64 - 3.0))
            .collect();
        let motor_vel = derivative(&motor, dt);
        let torque: Vec<f64> = (0..n)
            .map(|k| 0.3 * (k as f64 * 1.3).sin() + 2.0 * (2.0 * PI * 3.0 * t[k]).cos())
            .collect();
        let mut names = vec!["t", "x.cmd"];
        let mut data = vec![t, cmd];
        if with_load {
            names.push("x.load");
            data.push(load);
        }
        names.extend(["x.motor", "x.motor_vel", "x.torque"]);
        data.extend([motor, motor_vel, torque]);
        Trace::from_columns(
            Path::new("long.csv"),
            vec![],
            names.iter().map(|s| s.to_string()).collect(),
            data,
        )
        .unwrap()
    }

    #[test]
    fn a_held_axis_holds_the_block_means_of_what_the_full_reading_holds() {
        let m = model();
        let q = 10;
        let tr = trace(&m, 2003, true);
        let full = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
        let held = load_axis_held(tr, &m.file, "x", &Prep::default(), q).unwrap();
        assert_eq!(held.len(), 200);
        assert_eq!(held.sub, q);
        assert!((held.dt - 1e-3).abs() < 1e-15);
        assert_eq!(held.t, block_means(&full.t, q));
        assert_eq!(held.cmd, block_means(&full.cmd, q));
        assert_eq!(held.load_raw, block_means(&full.load_raw, q));
        assert_eq!(
            held.motor_raw.as_deref().unwrap(),
            block_means(full.motor_raw.as_deref().unwrap(), q)
        );
        assert_eq!(
            held.motor_vel_raw.as_deref().unwrap(),
            block_means(full.motor_vel_raw.as_deref().unwrap(), q)
        );
        // the torque acting between samples: the half-sample alignment, then the block means
        let y = full.torque_raw.as_deref().unwrap();
        let aligned: Vec<f64> = (0..y.len()).map(|k| zoh_mid(y, k)).collect();
        let want = block_means(&aligned, q);
        for (a, b) in held.torque_raw.as_deref().unwrap().iter().zip(&want) {
            assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0));
        }
        // the controller law of every recorded sample, at the block centres
        let cc = ControllerChannel::new(&m, &full).unwrap();
        let h = held.held_law.as_ref().unwrap();
        assert_eq!(h.law, block_centres(&cc.law, q));
        assert_eq!(h.recorded, block_centres(&cc.recorded, q));
        assert_eq!(h.velocity, cc.velocity);
        assert_eq!(h.discretisation, cc.discretisation);
        let hc = ControllerChannel::new(&m, &held).unwrap();
        assert_eq!(hc.law, h.law);
        assert!(held.torque.is_some() && held.range.0 > 0 && held.range.1 < 200);
    }

    #[test]
    fn the_held_block_keeps_ten_samples_per_period_of_the_cut_off() {
        assert_eq!(held_block(1e-4, 100.0), 10);
        assert_eq!(held_block(2.5e-4, 100.0), 4);
        assert_eq!(held_block(1e-4, 400.0), 2);
        assert_eq!(held_block(1e-3, 100.0), 1);
        assert_eq!(held_block(1e-3, 200.0), 1);
    }

    #[test]
    fn a_held_axis_refuses_what_the_full_reading_refuses_naming_the_file_and_column() {
        let m = model();
        let tr = trace(&m, 600, false);
        let full = load_axis(&tr, &m.file, "x", &Prep::default())
            .unwrap_err()
            .to_string();
        let held = load_axis_held(tr, &m.file, "x", &Prep::default(), 10)
            .unwrap_err()
            .to_string();
        assert_eq!(held, full);
        assert!(
            held.contains("long.csv") && held.contains("x.load"),
            "{held}"
        );
    }
}
