//! `feedloop identify inertia`: load inertia from the deviation between the position command
//! and the load position at a load position (the load-inertia patent, docs/sources.md).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};

use crate::choice::{Choice, DeviationArg, MethodArg};
use feedloop_analysis::identify::inertia::{self, Probe};
use feedloop_analysis::plot::{Axis, Mark, Plot, Series};
use feedloop_model::job::Job;
use feedloop_model::units::{si, sig};
use feedloop_trace::Trace;

use super::trace_input::{read_trace, trace_axis};

/// `feedloop identify inertia`.
#[derive(clap::Args, Debug)]
pub struct InertiaArgs {
    /// sim-match (method 1) or linear (method 2).
    #[arg(long, value_enum, default_value = "sim-match")]
    pub method: MethodArg,
    /// The measured trace (columns A.load and A.cmd, or A.motor with --deviation motor-load).
    #[arg(long)]
    pub trace: PathBuf,
    /// sim-match: the job that produced the trace (its axis model is the one adjusted; the
    /// feedforward keeps the inertia it ran with).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// linear: trace of the run without workpiece.
    #[arg(long)]
    pub no_load: Option<PathBuf>,
    /// linear: trace of the run with a known load.
    #[arg(long)]
    pub loaded: Option<PathBuf>,
    /// linear: inertia of the loaded run, kg m^2.
    #[arg(long)]
    pub loaded_jl_kgm2: Option<f64>,
    /// linear: inertia of the no-load run, kg m^2 (default: the --model job's jl_kgm2).
    #[arg(long)]
    pub no_load_jl_kgm2: Option<f64>,
    /// Load position where the deviation is read, m (or rad), passed while accelerating.
    #[arg(long)]
    pub at: f64,
    /// Half width of the least-squares window around --at, load units.
    #[arg(long, default_value_t = 2e-3)]
    pub window: f64,
    /// command-load (the position command minus the load position, as the load-inertia patent reads it) | motor-load (the
    /// screw's twist, motor position in load units minus load position).
    #[arg(long, value_enum, default_value = "command-load")]
    pub deviation: DeviationArg,
    /// Axis (default: the first).
    #[arg(long)]
    pub axis: Option<String>,
    /// Write the axis model with the estimated jl_kgm2 here (the feedforward's a3..a5 follow).
    #[arg(long)]
    pub apply: Option<PathBuf>,
    /// Plot (SVG) of the deviation along the move: the measured trace and the model at the
    /// estimate (sim-match) or the three traces (linear), the probe position marked.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Print JSON only.
    #[arg(long)]
    pub json: bool,
}

/// A curve of the `identify inertia --svg` plot: label, colour, (load position, deviation).
type Curve = (String, &'static str, Vec<(f64, f64)>);

/// What `identify inertia` reads before estimating: the probe, the model job and its axis, the
/// measured trace.
struct InertiaInput {
    probe: Probe,
    job: Option<Job>,
    /// Index of the axis in `job` (0 without a job).
    i: usize,
    /// Motor rad per load unit of the job's axis.
    mpl: Option<f64>,
    trace: Trace,
    axis: String,
}

fn inertia_input(a: &InertiaArgs) -> anyhow::Result<InertiaInput> {
    let probe = Probe {
        at: a.at,
        half_window: a.window,
        kind: inertia::DeviationKind::parse(a.deviation.id())?,
    };
    let job = match &a.model {
        Some(p) => Some(Job::load(p)?),
        None => None,
    };
    let i = match &job {
        Some(j) => inertia::axis_index(j, a.axis.as_deref())?,
        None => 0,
    };
    let mpl = job.as_ref().map(|j| j.axes[i].model.plant.motor_per_load());
    let trace = read_trace(&a.trace)?;
    let axis = match &job {
        Some(j) => j.axes[i].name.clone(),
        None => trace_axis(&trace, a.axis.as_deref())?,
    };
    Ok(InertiaInput {
        probe,
        job,
        i,
        mpl,
        trace,
        axis,
    })
}

pub(super) fn inertia_cmd(a: InertiaArgs) -> anyhow::Result<ExitCode> {
    let inp = inertia_input(&a)?;
    let mut curves: Vec<Curve> = vec![];
    let est = match a.method.id() {
        "sim-match" => sim_match_estimate(&a, &inp, &mut curves)?,
        "linear" => linear_estimate(&a, &inp, &mut curves)?,
        other => bail!("unknown method `{other}` (expected sim-match or linear)"),
    };
    if let Some(p) = &a.svg {
        write_deviation_svg(p, &curves, &est, a.at)?;
    }
    if let Some(out) = &a.apply {
        let job = inp
            .job
            .as_ref()
            .context("--apply needs --model JOB (its axis model is rewritten)")?;
        let (text, coef) = inertia::applied_model(job, inp.i, est.jl_kgm2)?;
        std::fs::write(out, text).with_context(|| format!("writing {}", out.display()))?;
        if !a.json {
            eprintln!(
                "wrote {} (feedforward a3 {:.6e}, a4 {:.6e}, a5 {:.6e})",
                out.display(),
                coef[2],
                coef[3],
                coef[4]
            );
        }
    }
    print_inertia(&a, &est)?;
    Ok(ExitCode::SUCCESS)
}

/// Method 1: the model job simulated until its deviation matches the measured one (with --svg,
/// the measured and the simulated curves into `curves`).
fn sim_match_estimate(
    a: &InertiaArgs,
    inp: &InertiaInput,
    curves: &mut Vec<Curve>,
) -> anyhow::Result<inertia::InertiaEstimate> {
    let (probe, i, trace, axis) = (inp.probe, inp.i, &inp.trace, inp.axis.as_str());
    let job = inp
        .job
        .as_ref()
        .context("--method sim-match needs --model JOB")?;
    let mpl = inp.mpl.unwrap_or(1.0);
    let limit = job.axes[i].model.controller.torque_limit;
    inertia::check_unsaturated(trace, axis, limit, "the measured run")?;
    let measured = inertia::trace_deviation(trace, axis, mpl, probe)?;
    let est = inertia::sim_match(job, i, measured, probe)?;
    if a.svg.is_some() {
        let ff = inertia::feedforward_jl(job, i).unwrap_or(est.jl_kgm2);
        curves.push((
            format!("measured ({})", a.trace.display()),
            "black",
            inertia::trace_profile(trace, axis, mpl, probe.kind)?,
        ));
        curves.push((
            format!("model at jl_kgm2 = {}", sig(est.jl_kgm2)),
            "steelblue",
            inertia::simulated_profile(job, i, est.jl_kgm2, ff, probe.kind)?,
        ));
    }
    Ok(est)
}

/// Method 2: the deviation interpolated between a no-load and a loaded run (with --svg, the
/// three traces' curves into `curves`).
fn linear_estimate(
    a: &InertiaArgs,
    inp: &InertiaInput,
    curves: &mut Vec<Curve>,
) -> anyhow::Result<inertia::InertiaEstimate> {
    let (probe, trace, axis) = (inp.probe, &inp.trace, inp.axis.as_str());
    let (Some(n0), Some(n1), Some(j1)) = (&a.no_load, &a.loaded, a.loaded_jl_kgm2) else {
        bail!("--method linear needs --no-load T0 --loaded T1 --loaded-jl-kgm2 J1");
    };
    let j0 = match (a.no_load_jl_kgm2, &inp.job) {
        (Some(v), _) => v,
        (None, Some(j)) => {
            inertia::feedforward_jl(j, inp.i).context("the --model axis has no load inertia")?
        }
        (None, None) => {
            bail!("--method linear needs the no-load inertia: --no-load-jl-kgm2 J0 or --model JOB")
        }
    };
    let mpl = match inp.mpl {
        Some(m) => m,
        None => {
            bail!("--method linear needs --model JOB for the screw lead (motor rad per load m)")
        }
    };
    let (t0, t1) = (read_trace(n0)?, read_trace(n1)?);
    let limit = inp
        .job
        .as_ref()
        .and_then(|j| j.axes[inp.i].model.controller.torque_limit);
    for (t, what) in [
        (&t0, "the no-load run"),
        (&t1, "the loaded run"),
        (trace, "the measured run"),
    ] {
        inertia::check_unsaturated(t, axis, limit, what)?;
    }
    let d0 = inertia::trace_deviation(&t0, axis, mpl, probe)?;
    let d1 = inertia::trace_deviation(&t1, axis, mpl, probe)?;
    let d = inertia::trace_deviation(trace, axis, mpl, probe)?;
    let est = inertia::linear(d0, j0, d1, j1, d, probe.kind)?;
    if a.svg.is_some() {
        for (t, label, colour) in [
            (&t0, format!("no load, jl_kgm2 = {}", sig(j0)), "grey"),
            (&t1, format!("loaded, jl_kgm2 = {}", sig(j1)), "steelblue"),
            (
                trace,
                format!("measured: jl_kgm2 = {}", sig(est.jl_kgm2)),
                "black",
            ),
        ] {
            curves.push((
                label,
                colour,
                inertia::trace_profile(t, axis, mpl, probe.kind)?,
            ));
        }
    }
    Ok(est)
}

/// The `identify inertia --svg` plot: the deviation curves along the move, the probe marked.
fn write_deviation_svg(
    p: &Path,
    curves: &[Curve],
    est: &inertia::InertiaEstimate,
    at: f64,
) -> anyhow::Result<()> {
    let mut plot = Plot::new(
        &format!(
            "identify inertia: {} deviation along the move ({}), jl_kgm2 = {}",
            est.deviation,
            est.method,
            sig(est.jl_kgm2)
        ),
        Axis::linear("load position", "m").si(),
        Axis::linear("deviation", "m").si(),
    )
    .size(860.0, 420.0);
    for (label, color, points) in curves {
        plot = plot.series(Series::points(label, color, points));
    }
    let text = plot
        .vline(Mark::new(&format!("probe --at {}", sig(at)), at, "red"))
        .svg();
    std::fs::write(p, text).with_context(|| format!("writing {}", p.display()))
}

fn print_inertia(a: &InertiaArgs, est: &inertia::InertiaEstimate) -> anyhow::Result<()> {
    if a.json {
        println!("{}", serde_json::to_string(est)?);
        return Ok(());
    }
    println!(
        "jl_kgm2 = {:.6e} ({}, {} simulated moves; {} deviation at {} measured {}, model {}; read by a least-squares line over +-{} around the position)",
        est.jl_kgm2,
        est.method,
        est.iterations,
        est.deviation,
        sig(a.at),
        si(est.deviation_measured_m, "m"),
        si(est.deviation_model_m, "m"),
        sig(a.window)
    );
    if let (Some(b), Some(jc)) = (est.literal_bias_percent, est.jl_continuous_model_kgm2) {
        println!(
            "literal feedforward: the load-inertia patent's continuous-time model would give {jc:.6e} kg m^2 ({b:+.2} %); the estimate above uses the job's own discrete controller"
        );
    }
    for w in &est.warnings {
        println!("warning: {w}");
    }
    Ok(())
}
