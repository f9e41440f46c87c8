//! `feedloop identify inertia|stiffness`, `feedloop excite`, `feedloop tune`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};

use crate::choice::{Choice, DeviationArg, EstimatorArg, ExciteKind, FrfArg, MethodArg};
use feedloop_analysis::identify::inertia::{self, Probe};
use feedloop_analysis::identify::stiffness::{
    identify_stiffness, Estimator, FrfKind, StiffnessOptions,
};
use feedloop_analysis::identify::svg::{bode_svg, tune_heatmap_svg};
use feedloop_analysis::plot::{Axis, Mark, Plot, Series};
use feedloop_model::job::Job;
use feedloop_model::units::{si, sig};
use feedloop_motion::{build_at, excitation::write_excitation_csv};
use feedloop_trace::Trace;

/// `feedloop identify ...`.
#[derive(clap::Subcommand, Debug)]
pub enum IdentifyCmd {
    /// Load inertia from the deviation th - thL at a load position (seed 000).
    Inertia(InertiaArgs),
    /// Stiffness and load inertia from the torque -> motor velocity FRF (seed 001).
    Stiffness(StiffnessArgs),
}

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
    /// command-load (the patent's th - thL, command minus load position) | motor-load (the
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

/// `feedloop identify stiffness`.
#[derive(clap::Args, Debug)]
pub struct StiffnessArgs {
    /// Trace of an excitation run (columns A.torque, A.motor_vel, and A.cmd as instrument).
    #[arg(long)]
    pub trace: PathBuf,
    /// Motor inertia JM from the data sheet, kg m^2.
    #[arg(long)]
    pub jm_kgm2: f64,
    /// Axis (default: the trace's first).
    #[arg(long)]
    pub axis: Option<String>,
    /// Band start, Hz.
    #[arg(long, default_value_t = 5.0)]
    pub f_min_hz: f64,
    /// Band end, Hz (default 0.4 x sample rate).
    #[arg(long)]
    pub f_max_hz: Option<f64>,
    /// Frequency resolution, Hz.
    #[arg(long, default_value_t = 0.3)]
    pub resolution_hz: f64,
    /// Time cut after each reversal (and before the next) from the one-direction windows, s.
    #[arg(long, default_value_t = 0.2)]
    pub settle_s: f64,
    /// The FRF estimator.
    #[arg(long, value_enum, default_value = "auto")]
    pub estimator: EstimatorArg,
    /// The FRF measured (command-table is refused, with the reason).
    #[arg(long, value_enum, default_value = "torque-velocity")]
    pub frf: FrfArg,
    /// Bode plot (SVG) with the picked points.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Report a result that fails its checks (too few segments, low coherence, picks that do
    /// not fit JM, ...) instead of refusing it; it is flagged in the text and the JSON.
    #[arg(long)]
    pub force: bool,
    /// Print JSON only.
    #[arg(long)]
    pub json: bool,
}

/// `feedloop excite`.
#[derive(clap::Args, Debug)]
pub struct ExciteArgs {
    /// The excitation signal.
    #[arg(long, value_enum)]
    pub kind: ExciteKind,
    /// Axis name.
    #[arg(long, default_value = "x")]
    pub axis: String,
    /// Sample period, s.
    #[arg(long, default_value_t = 1e-4)]
    pub period_s: f64,
    /// Extra keys of the kind (see docs/trajectories.md), `key=value` (TOML value), repeatable;
    /// they override the defaults.
    #[arg(long = "set")]
    pub set: Vec<String>,
    /// Output trace (t, A.cmd, A.cmd_vel, A.cmd_acc), playable with `kind = "trace"`.
    #[arg(long)]
    pub out: PathBuf,
    /// Print JSON only.
    #[arg(long)]
    pub json: bool,
}

/// `feedloop tune`.
#[derive(clap::Args, Debug)]
pub struct TuneArgs {
    /// The job whose ramp test is run.
    #[arg(long)]
    pub job: PathBuf,
    /// Grid, `name=lo:hi:n,...` over kp_per_s, kv_nms_per_rad, tv_s.
    #[arg(long)]
    pub grid: String,
    /// l1,l2,l3 of E = l1 RMS(x err) + l2 RMS(v err) + l3 RMS(a err).
    #[arg(long, default_value = "1,0.1,0.01")]
    pub weights: String,
    /// Refine the best grid point with a local optimiser.
    #[arg(long)]
    pub refine: bool,
    /// Heat map of E (SVG).
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Write the tuned job here.
    #[arg(long)]
    pub apply: Option<PathBuf>,
    /// Axis to tune (default: every axis whose command has a ramp, one after another, each with
    /// the axes before it at their tuned gains).
    #[arg(long)]
    pub axis: Option<String>,
    /// Transport delay of the drive for the margin check, control periods (on top of the
    /// zero-order hold and the model's [effects.delay]).
    #[arg(long, default_value_t = 1)]
    pub delay_cycles: u32,
    /// Print JSON only.
    #[arg(long)]
    pub json: bool,
}

/// Runs `feedloop identify ...`.
pub fn identify(cmd: IdentifyCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        IdentifyCmd::Inertia(a) => inertia_cmd(a),
        IdentifyCmd::Stiffness(a) => stiffness_cmd(a),
    }
}

fn read_trace(p: &Path) -> anyhow::Result<Trace> {
    Ok(Trace::read(p)?)
}

fn trace_axis(t: &Trace, axis: Option<&str>) -> anyhow::Result<String> {
    match axis {
        Some(a) => Ok(a.to_string()),
        // The first axis with a command and a load column, else the first `A.*` column's
        // axis (the command then names the column it misses).
        None => t
            .axes()
            .into_iter()
            .next()
            .or_else(|| {
                t.columns
                    .iter()
                    .find_map(|c| c.split_once('.').map(|(a, _)| a.to_string()))
            })
            .with_context(|| {
                format!(
                    "{}: no axis columns (A.cmd, A.load, A.torque, A.motor_vel, ...); columns: {}",
                    t.path.display(),
                    t.columns.join(", ")
                )
            }),
    }
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

fn inertia_cmd(a: InertiaArgs) -> anyhow::Result<ExitCode> {
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
            "literal feedforward: the patent's continuous-time model would give {jc:.6e} kg m^2 ({b:+.2} %); the estimate above uses the job's own discrete controller"
        );
    }
    Ok(())
}

fn stiffness_cmd(a: StiffnessArgs) -> anyhow::Result<ExitCode> {
    let mut opts = StiffnessOptions::new(a.jm_kgm2);
    opts.f_min_hz = a.f_min_hz;
    opts.f_max_hz = a.f_max_hz;
    opts.resolution_hz = a.resolution_hz;
    opts.settle_s = a.settle_s;
    opts.estimator = match a.estimator {
        EstimatorArg::Auto => Estimator::Auto,
        EstimatorArg::H1 => Estimator::H1,
        EstimatorArg::Instrument => Estimator::Instrument,
    };
    opts.frf = match a.frf {
        FrfArg::TorqueVelocity => FrfKind::TorqueToVelocity,
        FrfArg::CommandTable => FrfKind::CommandToTable,
    };
    let trace = read_trace(&a.trace)?;
    let axis = trace_axis(&trace, a.axis.as_deref())?;
    let r = identify_stiffness(&trace, &axis, &opts)?;
    if let (Some(p), Some(frf)) = (&a.svg, &r.frf) {
        let f_hi = a.f_max_hz.unwrap_or(0.4 / trace.period_s());
        let mut marks = vec![
            ("anti-resonance", r.antiresonance_hz),
            ("resonance", r.resonance_hz),
        ];
        if let Some(s) = r.second {
            marks.push(("2nd anti-res.", s.antiresonance_hz));
            marks.push(("2nd res.", s.resonance_hz));
        }
        std::fs::write(p, bode_svg(frf, a.f_min_hz, f_hi, &marks))
            .with_context(|| format!("writing {}", p.display()))?;
    }
    let c = &r.checks;
    let refused = !r.credible && !a.force;
    if a.json {
        let mut v = serde_json::to_value(&r)?;
        v["refused"] = serde_json::json!(refused);
        println!("{v}");
    } else if refused {
        eprintln!(
            "feedloop: identify stiffness: refusing KL = {:.4} N m/rad, JL = {:.4e} kg m^2 \
             (anti-resonance {:.4} Hz, resonance {:.4} Hz): the result is not credible:",
            r.kl_nm_per_rad, r.jl_kgm2, r.antiresonance_hz, r.resonance_hz
        );
        for p in &c.problems {
            eprintln!("  - {p}");
        }
        for p in &c.advice {
            eprintln!("  to do: {p}");
        }
        eprintln!("  (--force reports it anyway, flagged)");
    } else {
        println!(
            "KL = {:.2} N m/rad, JL = {:.5e} kg m^2 (anti-resonance {:.2} Hz, resonance {:.2} Hz, coherence >= {:.3}, {} segments, {})",
            r.kl_nm_per_rad,
            r.jl_kgm2,
            r.antiresonance_hz,
            r.resonance_hz,
            r.coherence_min,
            r.segments,
            r.estimator
        );
        if let Some(s) = r.second {
            println!(
                "second pair: anti-resonance {:.2} Hz, resonance {:.2} Hz (another mass behind the load?)",
                s.antiresonance_hz, s.resonance_hz
            );
        }
        println!(
            "checks: coherence {:.2} around the anti-resonance, {:.2} around the resonance; \
             prominence {:.1} / {:.1} dB; {} reversals{}{}",
            c.coherence_antiresonance,
            c.coherence_resonance,
            c.prominence_antiresonance_db,
            c.prominence_resonance_db,
            c.reversals,
            if c.reversals_cut > 0 {
                format!(
                    " ({} cut out: {} + {} segments from {} + {} windows of positive + negative \
                     velocity)",
                    c.reversals_cut,
                    c.segments_positive,
                    c.segments_negative,
                    c.windows_positive,
                    c.windows_negative
                )
            } else {
                String::new()
            },
            c.jm_from_response_kgm2
                .map(|j| format!("; JM from the response above the resonance {j:.4e} kg m^2"))
                .unwrap_or_default()
        );
        if let Some(e) = &r.reversal_effects {
            for line in reversal_lines(e) {
                println!("{line}");
            }
        }
        if let (Some(k), Some(j)) = (c.kl_ci_pct, c.jl_ci_pct) {
            println!(
                "two-mass fit over {} bins around the picks: KL +-{} %, JL +-{} % (95 %)",
                c.fit_bins,
                sig(k),
                sig(j)
            );
        }
        for p in &c.problems {
            println!("NOT CREDIBLE (kept with --force): {p}");
        }
        for p in &c.advice {
            println!("to do: {p}");
        }
    }
    Ok(if refused {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// The quantity a per-axis excitation key names, without its unit (`amplitude` for
/// `amplitude_m_per_s`), for the keys that come in several units.
fn quantity_stem(key: &str) -> Option<&str> {
    ["_m_per_s", "_rad_per_s", "_m", "_rad"]
        .iter()
        .find_map(|u| key.strip_suffix(u))
        .filter(|s| ["amplitude", "velocity", "max_travel", "traverse"].contains(s))
}

/// Runs `feedloop excite`.
pub fn excite(a: ExciteArgs) -> anyhow::Result<ExitCode> {
    let ax = &a.axis;
    let defaults: &[(&str, &str)] = match a.kind.id() {
        "random-segments" => &[
            ("kind", "\"random_segments\""),
            ("velocity_m_per_s", "0.02"),
            ("max_travel_m", "0.01"),
            ("min_segment_s", "0.001"),
            ("max_segment_s", "0.003"),
            ("transition_s", "0.0005"),
            ("duration_s", "12.0"),
        ],
        "prbs" => &[
            ("kind", "\"prbs\""),
            ("amplitude_m_per_s", "0.01"),
            ("order", "11"),
            ("bit_s", "0.002"),
            ("periods", "3"),
        ],
        "multisine" => &[
            ("kind", "\"multisine\""),
            ("amplitude_m_per_s", "0.02"),
            ("signal_period_s", "2.0"),
            ("f_min_hz", "1.0"),
            ("f_max_hz", "1000.0"),
            ("periods", "4"),
        ],
        o => bail!("unknown excitation `{o}` (expected random-segments, prbs or multisine)"),
    };
    let mut text = String::new();
    let mut set: Vec<(String, String)> = defaults
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    for s in &a.set {
        let (k, v) = s
            .split_once('=')
            .with_context(|| format!("--set `{s}`: expected key=value"))?;
        let k = k.trim().to_string();
        // A quantity given in any unit replaces the default of that quantity in every unit
        // (`amplitude_m` replaces the default `amplitude_m_per_s`, `velocity_rad_per_s` the
        // default `velocity_m_per_s`): the kinds refuse two of them.
        if let Some(stem) = quantity_stem(&k) {
            set.retain(|(x, _)| *x == k || quantity_stem(x) != Some(stem));
        }
        match set.iter_mut().find(|(x, _)| *x == k) {
            Some(e) => e.1 = v.trim().to_string(),
            None => set.push((k, v.trim().to_string())),
        }
    }
    for (k, v) in &set {
        text.push_str(&format!("{k} = {v}\n"));
    }
    let table: toml::Table = text
        .parse()
        .with_context(|| format!("excitation keys:\n{text}"))?;
    let traj = build_at(
        &table,
        Path::new("<feedloop excite>"),
        "excite",
        std::slice::from_ref(ax),
        a.period_s,
    )?;
    let f =
        std::fs::File::create(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let meta: Vec<(String, String)> = vec![];
    write_excitation_csv(traj.as_ref(), a.period_s, &meta, std::io::BufWriter::new(f))
        .with_context(|| format!("writing {}", a.out.display()))?;
    let rows = (traj.duration_s() / a.period_s).round() as u64 + 1;
    if a.json {
        println!(
            "{}",
            serde_json::json!({"out": a.out.display().to_string(), "kind": a.kind.id(), "duration_s": traj.duration_s(), "rows": rows})
        );
    } else {
        println!(
            "wrote {} ({} excitation, {}, {rows} rows); play it with [trajectory] kind = \"trace\", file = \"{}\"",
            a.out.display(),
            a.kind.id(),
            si(traj.duration_s(), "s"),
            a.out.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// One tuned axis.
struct TunedAxis {
    name: String,
    result: feedloop_analysis::identify::tune::TuneResult,
    seconds: f64,
}

/// `path` for the only axis, `stem-axis.ext` when several are tuned.
fn per_axis_path(p: &Path, axis: &str, several: bool) -> PathBuf {
    if !several {
        return p.to_path_buf();
    }
    let stem = p.file_stem().map_or("tune".into(), |s| s.to_string_lossy());
    let name = match p.extension() {
        Some(e) => format!("{stem}-{axis}.{}", e.to_string_lossy()),
        None => format!("{stem}-{axis}"),
    };
    p.with_file_name(name)
}

/// Sets `position_p { kp_per_s }` and `pi_velocity { kv_nms_per_rad, tv_s }` of `axis` in the
/// job's `[[chain]]` array (adding the entries if missing).
fn apply_gains(
    chain: &mut Vec<toml::Value>,
    axis: &str,
    b: feedloop_analysis::identify::tune::Gains,
) {
    for (plugin, stage, keys) in [
        ("position_p", "position", vec![("kp_per_s", b.kp_per_s)]),
        (
            "pi_velocity",
            "velocity",
            vec![("kv_nms_per_rad", b.kv_nms_per_rad), ("tv_s", b.tv_s)],
        ),
    ] {
        let pos = chain.iter().position(|e| {
            e.get("plugin").and_then(|v| v.as_str()) == Some(plugin)
                && e.get("axis").and_then(|v| v.as_str()) == Some(axis)
        });
        let k = match pos {
            Some(k) => k,
            None => {
                let mut e = toml::Table::new();
                e.insert("axis".into(), axis.into());
                e.insert("stage".into(), stage.into());
                e.insert("plugin".into(), plugin.into());
                chain.push(toml::Value::Table(e));
                chain.len() - 1
            }
        };
        if let Some(e) = chain[k].as_table_mut() {
            let params = e
                .entry("params")
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            if let Some(pt) = params.as_table_mut() {
                for (key, v) in keys {
                    pt.insert(key.into(), v.into());
                }
            }
        }
    }
}

/// Parses `--weights l1,l2,l3`.
fn parse_weights(s: &str) -> anyhow::Result<[f64; 3]> {
    let w: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--weights `{s}`: expected l1,l2,l3"))?;
    let [l1, l2, l3] = w[..] else {
        bail!("--weights `{s}`: expected three numbers l1,l2,l3");
    };
    Ok([l1, l2, l3])
}

/// Axes `tune` leaves out: (name, reason).
type Skipped = Vec<(String, String)>;

/// Which axes to tune: the one asked for, else every axis whose command has a ramp to score;
/// also the axes left out, with the reason (printed on standard error).
fn tunable_axes(
    a: &TuneArgs,
    job: &Job,
    weights: [f64; 3],
) -> anyhow::Result<(Vec<usize>, Skipped)> {
    use feedloop_analysis::identify::tune as t;
    let mut skipped: Skipped = vec![];
    let axes: Vec<usize> = match &a.axis {
        Some(name) => vec![inertia::axis_index(job, Some(name))?],
        None => (0..job.axes.len())
            .filter(|&i| match t::ramp_error(job, i, weights) {
                Ok(_) => true,
                Err(e) => {
                    skipped.push((job.axes[i].name.clone(), e.to_string()));
                    false
                }
            })
            .collect(),
    };
    if axes.is_empty() {
        let why: Vec<String> = skipped.iter().map(|(n, e)| format!("{n}: {e}")).collect();
        bail!(
            "{}: no axis can be tuned ({})",
            a.job.display(),
            why.join("; ")
        );
    }
    for (n, e) in &skipped {
        eprintln!("axis {n} not tuned: {e}");
    }
    Ok((axes, skipped))
}

/// Tunes `axes` one after another, each with the axes before it at their tuned gains.
fn tune_axes(
    a: &TuneArgs,
    job: &Job,
    grid: &[feedloop_analysis::identify::tune::GridAxis],
    weights: [f64; 3],
    axes: &[usize],
) -> anyhow::Result<Vec<TunedAxis>> {
    use feedloop_analysis::identify::tune as t;
    let per_axis: u64 = grid.iter().map(|g| g.values.len() as u64).product();
    let bar = if a.json {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(per_axis * axes.len() as u64).with_style(
            indicatif::ProgressStyle::with_template("tune {msg} {bar:40} {pos}/{len} sets ({eta})")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        )
    };
    let mut cur = job.clone();
    let mut tuned: Vec<TunedAxis> = vec![];
    for &i in axes {
        let name = job.axes[i].name.clone();
        bar.set_message(format!("axis {name}"));
        let t0 = std::time::Instant::now();
        let r = t::tune(&cur, i, grid, weights, a.delay_cycles, a.refine, &|| {
            bar.inc(1)
        })
        .with_context(|| format!("tuning axis `{name}` of {}", a.job.display()))?;
        cur = t::job_with_gains(&cur, i, r.best);
        tuned.push(TunedAxis {
            name,
            result: r,
            seconds: t0.elapsed().as_secs_f64(),
        });
    }
    bar.finish_and_clear();
    Ok(tuned)
}

/// `tune --apply`: the job file with absolute model paths and the tuned gains in its chain.
fn write_tuned_job(a: &TuneArgs, job: &Job, out: &Path, tuned: &[TunedAxis]) -> anyhow::Result<()> {
    let text =
        std::fs::read_to_string(&a.job).with_context(|| format!("reading {}", a.job.display()))?;
    let mut table: toml::Table = text
        .parse()
        .with_context(|| format!("{}", a.job.display()))?;
    if let Some(toml::Value::Table(axes)) = table.get_mut("axes") {
        for ja in &job.axes {
            if let Some(toml::Value::Table(ax)) = axes.get_mut(&ja.name) {
                let abs =
                    std::fs::canonicalize(&ja.model.path).unwrap_or_else(|_| ja.model.path.clone());
                ax.insert("model".into(), abs.display().to_string().into());
            }
        }
    }
    let mut chain = match table.remove("chain") {
        Some(toml::Value::Array(c)) => c,
        _ => vec![],
    };
    let mut summary = vec![];
    for ta in tuned {
        apply_gains(&mut chain, &ta.name, ta.result.best);
        summary.push(format!(
            "{}: E {:.4e}, defaults {:.4e}",
            ta.name, ta.result.e_best, ta.result.e_default
        ));
    }
    table.insert("chain".into(), toml::Value::Array(chain));
    std::fs::write(
        out,
        format!(
            "# {} tuned by feedloop tune ({})\n{}",
            a.job.display(),
            summary.join("; "),
            toml::to_string(&table)?
        ),
    )
    .with_context(|| format!("writing {}", out.display()))
}

/// `tune --json`: one axis flat, several keyed by axis name (counts and seconds summed).
fn tune_json(a: &TuneArgs, tuned: &[TunedAxis], skipped: &[(String, String)]) -> serde_json::Value {
    let skipped_json: Vec<serde_json::Value> = skipped
        .iter()
        .map(|(n, e)| serde_json::json!({"axis": n, "reason": e}))
        .collect();
    if let [ta] = tuned {
        let r = &ta.result;
        return serde_json::json!({"best": r.best, "e_best": r.e_best, "e_default": r.e_default,
            "evaluated": r.evaluated, "rejected": r.rejected, "seconds": ta.seconds,
            "axis": ta.name, "delay_cycles": a.delay_cycles, "skipped": skipped_json});
    }
    let mut best = serde_json::Map::new();
    let mut e_best = serde_json::Map::new();
    let mut e_default = serde_json::Map::new();
    for ta in tuned {
        best.insert(ta.name.clone(), serde_json::json!(ta.result.best));
        e_best.insert(ta.name.clone(), serde_json::json!(ta.result.e_best));
        e_default.insert(ta.name.clone(), serde_json::json!(ta.result.e_default));
    }
    serde_json::json!({"best": best, "e_best": e_best, "e_default": e_default,
        "evaluated": tuned.iter().map(|x| x.result.evaluated).sum::<usize>(),
        "rejected": tuned.iter().map(|x| x.result.rejected).sum::<usize>(),
        "seconds": tuned.iter().map(|x| x.seconds).sum::<f64>(),
        "axes": tuned.iter().map(|x| x.name.clone()).collect::<Vec<_>>(),
        "delay_cycles": a.delay_cycles, "skipped": skipped_json})
}

/// Runs `feedloop tune`.
pub fn tune(a: TuneArgs) -> anyhow::Result<ExitCode> {
    use feedloop_analysis::identify::tune as t;
    let job = Job::load(&a.job)?;
    let grid = t::parse_grid(&a.grid)?;
    let weights = parse_weights(&a.weights)?;
    let (axes, skipped) = tunable_axes(&a, &job, weights)?;
    let tuned = tune_axes(&a, &job, &grid, weights, &axes)?;
    let several = tuned.len() > 1;
    if let Some(p) = &a.svg {
        for ta in &tuned {
            let out = per_axis_path(p, &ta.name, several);
            std::fs::write(&out, tune_heatmap_svg(&grid, &ta.result, &ta.name))
                .with_context(|| format!("writing {}", out.display()))?;
        }
    }
    if let Some(out) = &a.apply {
        write_tuned_job(&a, &job, out, &tuned)?;
    }
    if a.json {
        println!("{}", tune_json(&a, &tuned, &skipped));
        return Ok(ExitCode::SUCCESS);
    }
    for ta in &tuned {
        let r = &ta.result;
        println!(
            "axis {}: best kp_per_s {} kv_nms_per_rad {} tv_s {}: E {} (defaults {}); {} sets evaluated, {} rejected, {}",
            ta.name,
            sig(r.best.kp_per_s),
            sig(r.best.kv_nms_per_rad),
            sig(r.best.tv_s),
            sig(r.e_best),
            sig(r.e_default),
            r.evaluated,
            r.rejected,
            si(ta.seconds, "s")
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// What the traverse's reversals show, in words with sizes (friction, then backlash).
fn reversal_lines(e: &feedloop_analysis::identify::reversals::ReversalEffects) -> Vec<String> {
    let mut out = Vec::new();
    let coulomb = match (e.coulomb_nm, e.coulomb_ci_nm, e.damping_nms_per_rad) {
        (Some(fc), Some(ci), Some(d)) => format!(
            "Coulomb {} +- {}, damping {} N m s/rad",
            si(fc, "N m"),
            si(ci, "N m"),
            sig(d)
        ),
        _ => "Coulomb and damping not separated".into(),
    };
    out.push(format!(
        "{}: the torque differs by {} between the directions at the traverse speed, over {} \
         reversals ({coulomb}, motor side)",
        if e.friction_seen {
            "friction (a torque step at each reversal)"
        } else {
            "no friction step told apart from damping"
        },
        si(2.0 * e.friction_nm.abs(), "N m"),
        e.reversals,
    ));
    if let Some(sw) = e.flank_swing_m {
        out.push(format!(
            "contact: the deflection swings {} within a direction, {} times further one way \
             than the other ({})",
            si(sw, "m"),
            sig(e.flank_lopsided.unwrap_or(f64::NAN)),
            if e.flank_lifted {
                "the excitation lifts the nut off its flank"
            } else {
                "the nut stays on its flank"
            }
        ));
    }
    if let (Some(lost), Some(ci), Some(el)) = (e.lost_motion_m, e.lost_motion_ci_m, e.elastic_m) {
        out.push(if e.backlash_seen {
            format!(
                "backlash: a dead band of about {} (lost motion {} +- {} at each reversal, of \
                 which the spring explains at most {})",
                si(e.backlash_m.unwrap_or(0.0), "m"),
                si(lost, "m"),
                si(ci, "m"),
                si(el, "m")
            )
        } else {
            format!(
                "backlash: none told apart (lost motion {} +- {}, the spring explains up to {})",
                si(lost, "m"),
                si(ci, "m"),
                si(el, "m")
            )
        });
    }
    out
}
