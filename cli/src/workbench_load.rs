//! How the workbench commands (`compare`, `diagnose`, `fit`) read their input: the model, the
//! trace's axis it describes (only that axis' columns are read from a file) and the checks of
//! the window and cut-off options. Shared by the `feedloop` binary and the Python package, so
//! that both refuse the same input with the same words.

use std::path::Path;

use feedloop_analysis::workbench::{
    data::{held_block, load_axis, load_axis_held, pick_axis, AxisData, Prep},
    diagnose::Diagnosis,
    effects::WbModel,
    refit::LONG_TRACE,
    WorkbenchError,
};
use feedloop_model::model::AxisKind;
use feedloop_model::units::{si, sig};
use feedloop_trace::Trace;

/// The options of `compare`, `diagnose` and `fit` that decide how the input is read.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadOptions {
    /// Axis of the trace the model describes (default: the only axis).
    pub axis: Option<String>,
    /// Cut-off of the zero-phase filter before differentiation, Hz (default min(100, fs/10)).
    pub cutoff_hz: Option<f64>,
    /// Use the torque column unfiltered.
    pub raw_torque: bool,
    /// Length of the simulation windows restarted from the measured state, s.
    pub window_s: f64,
    /// A trace column holding a known input added after the controller.
    pub added_input: Option<String>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            axis: None,
            cutoff_hz: None,
            raw_torque: false,
            window_s: 0.05,
            added_input: None,
        }
    }
}

/// Reads the model file `model` and the columns of trace file `trace` that the chosen axis needs,
/// then prepares that axis ([`prepare`]).
pub fn load(
    trace: &Path,
    model: &Path,
    c: &LoadOptions,
    need_torque: Option<&str>,
    held: bool,
) -> Result<(WbModel, AxisData, Vec<String>), WorkbenchError> {
    check_window_and_cutoff(c, None)?;
    let m = WbModel::load(model)?;
    let tr = read_axis_columns(trace, c)?;
    prepare(m, tr, model, c, need_torque, held)
}

/// Reads only the columns of the axis the model describes (and the declared added input): a long
/// multi-axis trace then takes one axis' memory.
pub fn read_axis_columns(trace: &Path, c: &LoadOptions) -> Result<Trace, WorkbenchError> {
    let header = Trace::read_header(trace)?;
    let axes = feedloop_trace::axes_of(&header);
    let chosen = match (&c.axis, axes.as_slice()) {
        (Some(a), _) => Some(a.clone()),
        (None, [one]) => Some(one.clone()),
        _ => None,
    };
    Ok(match &chosen {
        // an axis with no column at all is read whole: its refusal lists the axes there are
        Some(a) if header.iter().any(|h| h.starts_with(&format!("{a}."))) => {
            let prefix = format!("{a}.");
            let added = c.added_input.clone();
            Trace::read_columns(trace, &|name: &str| {
                name.starts_with(&prefix) || added.as_deref() == Some(name)
            })?
        }
        _ => Trace::read(trace)?,
    })
}

/// Prepares the axis of trace `tr` that model `m` (read from `model`) describes. The trace itself
/// is dropped once its axis is prepared; `need_torque` names what needs the torque column when
/// one does. Warnings about the pair are returned (the caller shows them). With `held`, a long
/// trace ([`LONG_TRACE`] samples or more, when its rate is at least twenty times the filter's
/// cut-off) is held in block means ([`load_axis_held`]): memory and time then grow with the
/// trace's length ten times slower.
pub fn prepare(
    m: WbModel,
    tr: Trace,
    model: &Path,
    c: &LoadOptions,
    need_torque: Option<&str>,
    held: bool,
) -> Result<(WbModel, AxisData, Vec<String>), WorkbenchError> {
    check_window_and_cutoff(c, None)?;
    let trace = tr.path.clone();
    let trace = trace.as_path();
    check_window_and_cutoff(c, Some((trace, tr.period_s())))?;
    let axis = pick_axis(&tr, model, c.axis.as_deref())?;
    let prep = Prep {
        cutoff_hz: c.cutoff_hz,
        filter_torque: !c.raw_torque,
        added_input: c.added_input.clone(),
    };
    let dt = tr.period_s();
    let q = held_block(dt, c.cutoff_hz.unwrap_or((0.1 / dt).min(100.0)));
    // (without the torque column the ordinary reading says what is missing)
    let d = if held && tr.len() >= LONG_TRACE && q >= 2 && tr.has(&format!("{axis}.torque")) {
        load_axis_held(tr, &m.file, &axis, &prep, q)?
    } else {
        let d = load_axis(&tr, &m.file, &axis, &prep)?;
        if let Some(why) = need_torque {
            d.require_torque(why, &tr)?;
        }
        d
    };
    let mut warnings: Vec<String> = one_position_warning(&m, &d, model).into_iter().collect();
    if let Some(c) = d.encoder_offset {
        let at_load = match m.kind() {
            AxisKind::BallScrew => si(c / d.r, "m"),
            AxisKind::Rotary | AxisKind::Rigid => format!("{} rad", sig(c / d.r)),
        };
        warnings.push(format!(
            "{}: the motor and load encoders' zeros differ by {} rad on the motor side ({at_load} at the load); removed from `{}.motor` before every fit and simulation",
            trace.display(),
            sig(c),
            d.axis
        ));
    }
    Ok((m, d, warnings))
}

/// Refuses a `--window-s` or `--cutoff-hz` outside its range; `trace` (file, sampling period)
/// adds the limits that depend on the trace.
pub fn check_window_and_cutoff(
    c: &LoadOptions,
    trace: Option<(&Path, f64)>,
) -> Result<(), WorkbenchError> {
    let bad = |flag: &str, v: f64, reason: String| WorkbenchError::BadArgument {
        arg: format!("{flag} {v}"),
        reason,
    };
    if !(c.window_s.is_finite() && c.window_s > 0.0) {
        return Err(bad(
            "--window-s",
            c.window_s,
            "must be a finite length of time > 0 s, at least two sample periods of the trace (default 0.05 s)".into(),
        ));
    }
    if let Some(f) = c.cutoff_hz {
        if !(f.is_finite() && f > 0.0) {
            return Err(bad(
                "--cutoff-hz",
                f,
                "must be a finite frequency > 0 Hz, below the trace's Nyquist frequency (half its sampling rate)".into(),
            ));
        }
    }
    let Some((path, dt)) = trace else {
        return Ok(());
    };
    // (a trace's period is the median of its steps, a hair off the nominal one)
    if c.window_s < 2.0 * dt * (1.0 - 1e-6) {
        return Err(bad(
            "--window-s",
            c.window_s,
            format!(
                "shorter than two sample periods of {} ({} s each): a window must be at least {} s",
                path.display(),
                sig6(dt),
                sig6(2.0 * dt)
            ),
        ));
    }
    let nyquist = 0.5 / dt;
    if let Some(f) = c.cutoff_hz {
        if f >= nyquist {
            return Err(bad(
                "--cutoff-hz",
                f,
                format!(
                    "at or above the Nyquist frequency of {} ({} Hz at {} s per sample): give a cut-off in (0, {}) Hz (default min(100 Hz, fs/10) = {} Hz)",
                    path.display(),
                    sig6(nyquist),
                    sig6(dt),
                    sig6(nyquist),
                    sig6((0.1 / dt).min(100.0))
                ),
            ));
        }
    }
    Ok(())
}

/// `x` to 6 significant digits, printed shortest (a trace's period of 0.0010000000000000009 s
/// reads 0.001).
pub fn sig6(x: f64) -> f64 {
    format!("{x:.5e}").parse().unwrap_or(x)
}

/// A warning when a two-body model (ball screw or rotary: motor and load coupled by a spring)
/// meets a trace with one position (no `A.motor`): motor and load are then taken to move
/// together, so the figures judge the sum of the two bodies and nothing of the spring.
pub fn one_position_warning(m: &WbModel, d: &AxisData, model: &Path) -> Option<String> {
    if d.kind == AxisKind::Rigid || d.has_motor() {
        return None;
    }
    Some(format!(
        "{} is a {} model (motor and load coupled by kl_nm_per_rad) but {} has no `{}.motor` column, only one measured position: motor and load are taken to move together, so the figures judge jm_kgm2 + jl_kgm2 (and dm + dl) as one rigid body and say nothing about kl_nm_per_rad, cl_nms_per_rad or the split between motor and load; use a kind = \"rigid\" model, or a trace that records `{}.motor`",
        model.display(),
        m.kind().id(),
        d.path.display(),
        d.axis,
        d.axis
    ))
}

/// The trace columns `names` at the samples of axis `d` (block means of a long trace held in
/// them), for the dictionary of `diagnose`; a missing column is refused with the columns there.
pub fn dictionary_columns(
    trace: &Path,
    names: &[String],
    d: &AxisData,
) -> Result<Vec<(String, Vec<f64>)>, WorkbenchError> {
    if names.is_empty() {
        return Ok(Vec::new());
    }
    let tr = Trace::read_columns(trace, &|n: &str| names.iter().any(|x| x == n))?;
    names
        .iter()
        .map(|n| {
            let c = tr.column(n).ok_or_else(|| WorkbenchError::MissingColumn {
                path: trace.to_path_buf(),
                column: n.clone(),
                needed_for: "--dictionary-column".into(),
                present: Trace::read_header(trace)
                    .map(|h| h.join(", "))
                    .unwrap_or_default(),
            })?;
            let mut v = if d.sub > 1 {
                feedloop_analysis::workbench::signal::block_means(c, d.sub)
            } else {
                c.to_vec()
            };
            v.resize(d.len(), v.last().copied().unwrap_or(0.0));
            Ok((n.clone(), v))
        })
        .collect()
}

/// What `diagnose` (without `--auto`) prints with `--json`: the diagnosis of axis `d`, the
/// warnings about the input and, for a long trace held in block means, how it was held.
pub fn diagnosis_json(dg: &Diagnosis, d: &AxisData, warnings: &[String]) -> serde_json::Value {
    let mut j = dg.to_json();
    j["warnings"] = serde_json::json!(warnings);
    if d.sub > 1 {
        j["held_in_block_means"] = serde_json::json!({
            "recorded_samples_per_block": d.sub,
            "blocks": d.len(),
            "why": format!(
                "a long trace ({} samples or more) is held as the means of blocks of {} samples (the held rate is ten times the filter's cut-off of {} Hz or more); the controller law is evaluated on every recorded sample",
                LONG_TRACE, d.sub, d.cutoff_hz
            ),
        });
    }
    j
}

/// An error with its causes, each said once: a message that already quotes its cause (`FILE:
/// cannot read trace: No such file or directory`) is not followed by that cause again.
pub fn error_text(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text = format!("{text}: {c}");
        }
    }
    text
}
