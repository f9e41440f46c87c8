//! `feedloop identify stiffness`: stiffness and load inertia from the torque -> motor velocity
//! FRF (the stiffness-identification patent, docs/sources.md).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;

use crate::choice::{EstimatorArg, FrfArg};
use feedloop_analysis::identify::frf::Frf;
use feedloop_analysis::identify::stiffness::{
    identify_stiffness, Estimator, FrfKind, StiffnessChecks, StiffnessOptions, StiffnessResult,
};
use feedloop_analysis::identify::svg::bode_svg;
use feedloop_model::units::{si, sig};
use feedloop_trace::Trace;

use super::trace_input::{read_trace, trace_axis};

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

pub(super) fn stiffness_cmd(a: StiffnessArgs) -> anyhow::Result<ExitCode> {
    let opts = stiffness_options(&a);
    let trace = read_trace(&a.trace)?;
    let axis = trace_axis(&trace, a.axis.as_deref())?;
    let r = identify_stiffness(&trace, &axis, &opts)?;
    if let (Some(p), Some(frf)) = (&a.svg, &r.frf) {
        write_bode(&a, &trace, &r, frf, p)?;
    }
    let refused = !r.credible && !a.force;
    if a.json {
        let mut v = serde_json::to_value(&r)?;
        v["refused"] = serde_json::json!(refused);
        println!("{v}");
    } else if refused {
        print_refusal(&r);
    } else {
        print_stiffness(&r);
    }
    Ok(if refused {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// The identification's options from the command line.
fn stiffness_options(a: &StiffnessArgs) -> StiffnessOptions {
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
    opts
}

/// `--svg`: the Bode plot of the FRF `frf` with the picked (anti-)resonances marked.
fn write_bode(
    a: &StiffnessArgs,
    trace: &Trace,
    r: &StiffnessResult,
    frf: &Frf,
    p: &Path,
) -> anyhow::Result<()> {
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
        .with_context(|| format!("writing {}", p.display()))
}

/// The refusal of a result that is not credible, with its problems and what to do.
fn print_refusal(r: &StiffnessResult) {
    let c = &r.checks;
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
}

/// The result in words: the figures, the checks, what the reversals show, the fit's
/// confidence, and the problems of a result reported with --force.
fn print_stiffness(r: &StiffnessResult) {
    let c = &r.checks;
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
    println!("{}", checks_line(c));
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

/// The checks' line: coherence and prominence at the picks, the reversals (and what was cut
/// out around them), the motor inertia the response shows.
fn checks_line(c: &StiffnessChecks) -> String {
    format!(
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
    )
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
