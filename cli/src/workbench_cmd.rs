//! CLI of the model workbench: `trace import`, `trace export`, `model init`, `compare`, `diagnose`, `fit`.
//!
//! With `--json` a command prints pure JSON on standard output (progress and hints go to
//! standard error).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use feedloop_analysis::workbench::{
    auto::{auto, diagnosis_html},
    compare::compare,
    data::AxisData,
    diagnose::{diagnose, DiagOptions},
    effects::WbModel,
    fit::{fit, parse_effects},
    import::{import, model_init, parse_map, InitSpec},
    report, WorkbenchError,
};
use feedloop_cli::trace_export::{export, ExportFormat};
use feedloop_cli::trace_import::{import_hal, ImportFormat};
use feedloop_cli::workbench_load::{self, dictionary_columns, LoadOptions};
use feedloop_model::model::AxisKind;
use feedloop_model::units::{si, sig};
use feedloop_trace::Trace;

/// Workbench subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum WorkbenchCmd {
    /// Traces: bring another tool's export into trace format v1.
    Trace {
        /// What to do.
        #[command(subcommand)]
        cmd: TraceCmd,
    },
    /// Model files: a nominal starting model from a trace.
    Model {
        /// What to do.
        #[command(subcommand)]
        cmd: ModelCmd,
    },
    /// Compare a model with a trace: equation error, simulation error, where it fails; report.html.
    Compare {
        /// Trace (format v1).
        #[arg(long)]
        trace: PathBuf,
        /// Model file (TOML).
        #[arg(long)]
        model: PathBuf,
        /// Output folder (report.html, compare.json).
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        common: Common,
    },
    /// Rank the candidate causes of the misfit (missing effects, wrong base parameters).
    Diagnose {
        /// Trace (format v1).
        #[arg(long)]
        trace: PathBuf,
        /// Model file (TOML).
        #[arg(long)]
        model: PathBuf,
        /// Output folder (report.html, diagnose.json; with --auto also model.toml).
        #[arg(long)]
        out: Option<PathBuf>,
        /// The guided loop: add the most significant effect, refit, diagnose again.
        #[arg(long)]
        auto: bool,
        /// Most additions of the guided loop.
        #[arg(long, default_value_t = 6)]
        max_steps: usize,
        /// A trace column added to the dictionary of terms the remaining residual is described
        /// by (e.g. another joint's angle `j3.load`); repeatable or comma-separated.
        #[arg(long, value_delimiter = ',')]
        dictionary_column: Vec<String>,
        #[command(flatten)]
        common: Common,
    },
    /// Add effects, refit, write the new model file, print the errors before and after.
    Fit {
        /// Trace (format v1).
        #[arg(long)]
        trace: PathBuf,
        /// Model file (TOML).
        #[arg(long)]
        model: PathBuf,
        /// Effects to add, comma-separated (ids of the effect library).
        #[arg(long, value_delimiter = ',')]
        add: Vec<String>,
        /// Parameters to refit: base keys and ids of effects already in the model (default: all base parameters and every effect's coefficients).
        #[arg(long, value_delimiter = ',')]
        free: Option<Vec<String>>,
        /// New model file.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        common: Common,
    },
}

/// Options shared by compare, diagnose and fit.
#[derive(clap::Args, Debug)]
pub struct Common {
    /// Axis of the trace the model describes (default: the only axis).
    #[arg(long)]
    axis: Option<String>,
    /// Cut-off of the zero-phase filter before differentiation, Hz (default min(100, fs/10));
    /// above 0 and below the trace's Nyquist frequency fs/2.
    #[arg(long, allow_negative_numbers = true)]
    cutoff_hz: Option<f64>,
    /// Use the torque column unfiltered (default: the same zero-phase filter as the positions).
    #[arg(long)]
    raw_torque: bool,
    /// Length of the simulation windows restarted from the measured state, s (at least two
    /// sample periods of the trace).
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true)]
    window_s: f64,
    /// A trace column holding a known input added to the controller's output after the
    /// controller (torque units, included in the recorded torque), e.g. `x.pulses`; default
    /// `A.torque_add`, else `A.tau_ff` (a drive's feed-forward torque), when the trace has it.
    #[arg(long)]
    added_input: Option<String>,
    /// Print pure JSON on standard output.
    #[arg(long)]
    json: bool,
}

impl Common {
    /// The options that decide how the input is read.
    fn options(&self) -> LoadOptions {
        LoadOptions {
            axis: self.axis.clone(),
            cutoff_hz: self.cutoff_hz,
            raw_torque: self.raw_torque,
            window_s: self.window_s,
            added_input: self.added_input.clone(),
        }
    }
}

/// `feedloop trace ...`
#[derive(clap::Subcommand, Debug)]
pub enum TraceCmd {
    /// Import another tool's export (CSV, LinuxCNC halsampler or halscope) with explicit
    /// column mapping and scaling.
    Import {
        /// Source file (CSV: header row; `,`, `;` or tab separated).
        #[arg(long)]
        from: PathBuf,
        /// What the source is: a CSV with a header row, halsampler output (fields named 1, 2,
        /// ... by position) or a halscope log file (channels named by their HAL names).
        #[arg(long, value_enum, default_value_t = ImportFormat::Csv)]
        format: ImportFormat,
        /// `target=source[*factor][/divisor][+offset],...`, e.g. "t=time_ms*0.001,x.cmd=ref_mm*0.001".
        #[arg(long)]
        map: String,
        /// Sampling period when no time column is mapped, s.
        #[arg(long)]
        period_s: Option<f64>,
        /// Output trace (format v1).
        #[arg(long)]
        out: PathBuf,
        /// Print pure JSON.
        #[arg(long)]
        json: bool,
    },
    /// Write a trace as MCAP (Foxglove, PlotJuggler: one channel per axis) or Parquet (pandas,
    /// polars, DuckDB: the trace's columns).
    Export {
        /// Trace (format v1).
        trace: PathBuf,
        /// Output format.
        #[arg(long, value_enum)]
        format: ExportFormat,
        /// Output file.
        #[arg(long)]
        out: PathBuf,
    },
}

/// `model init --kind`: the structures a nominal model can have.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum InitKind {
    /// Rotary motor, ball screw, table (2-mass, load in m).
    Ballscrew,
    /// One rigid mass driven by a force (load in m).
    Rigid,
    /// Rotary motor, gear or shaft, rotary load (2-mass, load in rad; one encoder: rigid).
    Rotary,
}

impl InitKind {
    fn axis_kind(self) -> AxisKind {
        match self {
            InitKind::Ballscrew => AxisKind::BallScrew,
            InitKind::Rigid => AxisKind::Rigid,
            InitKind::Rotary => AxisKind::Rotary,
        }
    }
}

/// `feedloop model ...`
#[derive(clap::Subcommand, Debug)]
pub enum ModelCmd {
    /// A nominal model for a trace: base parameters by least squares, no effects.
    Init {
        /// Trace (format v1) with a torque column.
        #[arg(long)]
        trace: PathBuf,
        /// The axis' structure.
        #[arg(long, value_enum)]
        kind: InitKind,
        /// Axis (default: the only axis).
        #[arg(long)]
        axis: Option<String>,
        /// Screw lead for a ball screw, m (default: from the motor/load travel ratio).
        #[arg(long)]
        lead_m: Option<f64>,
        /// Gear ratio of a rotary axis, motor revolutions per load revolution (default: from the
        /// motor/load travel ratio; 1 with one encoder).
        #[arg(long)]
        gear_ratio: Option<f64>,
        /// Output model file.
        #[arg(long)]
        out: PathBuf,
        /// Print pure JSON.
        #[arg(long)]
        json: bool,
    },
}

/// Reads the model and the trace's axis it describes ([`workbench_load::load`]) and prints
/// the warnings about the pair on standard error (they are returned for the JSON's `warnings`).
fn load(
    trace: &Path,
    model: &Path,
    c: &Common,
    need_torque: Option<&str>,
    held: bool,
) -> Result<(WbModel, AxisData, Vec<String>), WorkbenchError> {
    let r = workbench_load::load(trace, model, &c.options(), need_torque, held)?;
    for w in &r.2 {
        eprintln!("warning: {w}");
    }
    Ok(r)
}

fn mkdir(dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create folder", dir.display()))
}

fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("{}: cannot write", path.display()))
}

fn opt(v: Option<f64>) -> String {
    v.map(|x| format!("{x:.2} %")).unwrap_or_else(|| "-".into())
}

/// Writes `report.html` and the JSON file `json_name` into `out`.
fn write_report(
    out: &Path,
    html: &str,
    json_name: &str,
    j: &serde_json::Value,
) -> anyhow::Result<()> {
    write(&out.join("report.html"), html)?;
    write(&out.join(json_name), &serde_json::to_string_pretty(j)?)
}

/// Prints `j` as pretty JSON on standard output.
fn print_json(j: &serde_json::Value) -> anyhow::Result<()> {
    println!("{}", serde_json::to_string_pretty(j)?);
    Ok(())
}

/// Runs a workbench subcommand.
pub fn run(cmd: WorkbenchCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        WorkbenchCmd::Trace {
            cmd:
                TraceCmd::Import {
                    from,
                    format,
                    map,
                    period_s,
                    out,
                    json,
                },
        } => trace_import(&from, format, &map, period_s, &out, json)?,
        WorkbenchCmd::Trace {
            cmd: TraceCmd::Export { trace, format, out },
        } => {
            let tr = Trace::read(&trace)?;
            export(&tr, format, &out)?;
            println!(
                "wrote {} ({}: {} samples, {} columns)",
                out.display(),
                format.id(),
                tr.len(),
                tr.columns.len()
            );
        }
        WorkbenchCmd::Model {
            cmd:
                ModelCmd::Init {
                    trace,
                    kind,
                    axis,
                    lead_m,
                    gear_ratio,
                    out,
                    json,
                },
        } => {
            let spec = InitSpec {
                kind: kind.axis_kind(),
                lead_m,
                gear_ratio,
            };
            init_model(&trace, &spec, axis.as_deref(), &out, json)?
        }
        WorkbenchCmd::Compare {
            trace,
            model,
            out,
            common,
        } => compare_cmd(&trace, &model, &out, &common)?,
        WorkbenchCmd::Diagnose {
            trace,
            model,
            out,
            auto: guided,
            max_steps,
            dictionary_column,
            common,
        } => {
            let (m, d, warnings) = load(
                &trace,
                &model,
                &common,
                Some("diagnose (the equation error is measured on it)"),
                // the ranking alone holds a long trace in block means; the report's windowed
                // simulation and the guided loop's refits need every recorded sample
                !guided && out.is_none(),
            )?;
            if guided {
                let out = out.ok_or_else(|| anyhow::anyhow!("diagnose --auto: --out DIR is required (the final model and report are written there)"))?;
                diagnose_auto(&m, &d, &out, max_steps, &common, &warnings)?;
            } else {
                let extra = dictionary_columns(&trace, &dictionary_column, &d)?;
                diagnose_once(&m, &d, out.as_deref(), &common, &warnings, extra)?;
            }
        }
        WorkbenchCmd::Fit {
            trace,
            model,
            add,
            free,
            out,
            common,
        } => fit_cmd(&trace, &model, &add, free.as_deref(), &out, &common)?,
    }
    Ok(ExitCode::SUCCESS)
}

/// `feedloop trace import`.
fn trace_import(
    from: &Path,
    format: ImportFormat,
    map: &str,
    period_s: Option<f64>,
    out: &Path,
    json: bool,
) -> anyhow::Result<()> {
    let m = parse_map(map)?;
    let tr = match format {
        ImportFormat::Csv => import(from, &m, period_s, out)?,
        _ => import_hal(from, format, &m, period_s, out)?,
    };
    if json {
        println!(
            "{}",
            serde_json::json!({"out": out.display().to_string(), "samples": tr.len(), "period_s": tr.period_s(), "columns": tr.columns})
        );
    } else {
        println!(
            "wrote {} ({} samples at {}; columns {})",
            out.display(),
            tr.len(),
            si(tr.period_s(), "s"),
            tr.columns.join(", ")
        );
    }
    Ok(())
}

/// `feedloop model init`.
fn init_model(
    trace: &Path,
    spec: &InitSpec,
    axis: Option<&str>,
    out: &Path,
    json: bool,
) -> anyhow::Result<()> {
    let kind = spec.kind.id();
    let tr = Trace::read(trace)?;
    let m = model_init(&tr, spec, axis, out)?;
    let params: serde_json::Map<String, serde_json::Value> = m
        .base
        .iter()
        .map(|(k, v)| (k.key().to_string(), serde_json::json!(v)))
        .collect();
    if json {
        println!(
            "{}",
            serde_json::json!({"out": out.display().to_string(), "kind": kind, "params": params})
        );
    } else {
        println!(
            "wrote {}: {}",
            out.display(),
            m.base
                .iter()
                .map(|(k, v)| format!("{k} = {v:.6e}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(())
}

/// `feedloop compare`.
fn compare_cmd(trace: &Path, model: &Path, out: &Path, common: &Common) -> anyhow::Result<()> {
    let (m, d, warnings) = load(trace, model, common, None, false)?;
    let c = compare(&m, &d, common.window_s);
    mkdir(out)?;
    let mut j = c.to_json(&d);
    j["warnings"] = serde_json::json!(warnings);
    let report_path = out.join("report.html");
    j["report"] = serde_json::json!(report_path.display().to_string());
    let title = format!("compare: {} vs {}", model.display(), trace.display());
    write_report(out, &report::html(&d, &c, &title, ""), "compare.json", &j)?;
    if common.json {
        return print_json(&j);
    }
    println!(
        "equation error NRMSE: {}   windowed simulation NRMSE ({}): {}   free run: {}",
        opt(j["equation_nrmse_pct"].as_f64()),
        c.headline_channel().unwrap_or("nothing simulated"),
        opt(j["window_sim_nrmse_pct"].as_f64()),
        opt(j["free_sim_nrmse_pct"].as_f64())
    );
    if let Some(note) = c.no_torque_note(&d) {
        println!("note: {note}");
    }
    if let Some(cc) = &c.controller {
        let ev = cc.events(&d);
        println!(
            "controller channel (recorded torque against the controller law) NRMSE: {}{}",
            opt(Some(cc.nrmse_pct)),
            if cc.fails() {
                format!(
                    "; departs beyond its noise, in {} stretches{}",
                    ev.len(),
                    ev.first()
                        .map(|e| format!(
                            " (first {} .. {}, {} mean)",
                            si(e.start_s, "s"),
                            si(e.end_s, "s"),
                            sig(e.mean)
                        ))
                        .unwrap_or_default()
                )
            } else {
                String::new()
            }
        );
    }
    for s in &c.by_kind {
        println!(
            "  {:<18} {:5.1} % of the residual in {:5.1} % of the time",
            s.name, s.share_pct, s.time_pct
        );
    }
    println!("report: {}", report_path.display());
    Ok(())
}

/// `feedloop diagnose --auto`: the guided loop; writes model.toml, report.html, diagnose.json.
fn diagnose_auto(
    m: &WbModel,
    d: &AxisData,
    out: &Path,
    max_steps: usize,
    common: &Common,
    warnings: &[String],
) -> anyhow::Result<()> {
    mkdir(out)?;
    let r = auto(m, d, common.window_s, max_steps)?;
    let model_path = out.join("model.toml");
    r.model.write(&model_path)?;
    let c = compare(&r.model, d, common.window_s);
    let extra = format!("{}{}", r.html(), diagnosis_html(&r.last));
    let html = report::html(d, &c, "diagnose --auto: final model", &extra);
    let mut j = r.to_json();
    j["model"] = serde_json::json!(model_path.display().to_string());
    j["warnings"] = serde_json::json!(warnings);
    write_report(out, &html, "diagnose.json", &j)?;
    if common.json {
        return print_json(&j);
    }
    for (i, s) in r.steps.iter().enumerate() {
        println!(
            "step {i}: {:<40} equation NRMSE {}  windowed sim NRMSE {}",
            if s.added.is_empty() {
                "(nominal)".to_string()
            } else {
                s.added.join(", ")
            },
            opt(s.errors.equation_nrmse_pct),
            opt(s.errors.window_sim_nrmse_pct)
        );
    }
    println!("{}\nfinal model: {}", r.last.verdict, model_path.display());
    Ok(())
}

/// `feedloop diagnose` without `--auto`: ranks the candidates once (report files with `--out`).
fn diagnose_once(
    m: &WbModel,
    d: &AxisData,
    out: Option<&Path>,
    common: &Common,
    warnings: &[String],
    extra_terms: Vec<(String, Vec<f64>)>,
) -> anyhow::Result<()> {
    let opts = DiagOptions {
        extra_terms,
        ..DiagOptions::default()
    };
    let dg = diagnose(m, d, &opts);
    let j = workbench_load::diagnosis_json(&dg, d, warnings);
    if let Some(out) = out {
        mkdir(out)?;
        let c = compare(m, d, common.window_s);
        let html = report::html(d, &c, "diagnose", &diagnosis_html(&dg));
        write_report(out, &html, "diagnose.json", &j)?;
    }
    if common.json {
        return print_json(&j);
    }
    for c in &dg.candidates {
        println!(
            "{:<20} {:<10} {:>6.1} %  {}  {}",
            c.effect,
            c.class,
            c.error_reduction_pct,
            if c.significant {
                "significant"
            } else {
                "-          "
            },
            c.evidence
        );
    }
    for t in &dg.residual_terms {
        println!(
            "residual follows   {:<20} {:>6.1} %  {}  {}",
            t.term,
            t.cut_pct,
            if t.significant {
                "significant"
            } else {
                "-          "
            },
            t.words
        );
    }
    let p = &dg.sparse_peer;
    println!(
        "sparse regression on the same dictionary (the generic peer): equation NRMSE {} % with {}",
        sig(p.equation_nrmse_pct),
        if p.terms.is_empty() {
            "no term".to_string()
        } else {
            p.terms.join(", ")
        }
    );
    println!("{}", dg.verdict);
    if let Some(h) = j.get("held_in_block_means") {
        println!("note: {}", h["why"].as_str().unwrap_or_default());
    }
    Ok(())
}

/// `feedloop fit`.
fn fit_cmd(
    trace: &Path,
    model: &Path,
    add: &[String],
    free: Option<&[String]>,
    out: &Path,
    common: &Common,
) -> anyhow::Result<()> {
    let (m, d, warnings) = load(trace, model, common, None, false)?;
    let add = parse_effects(add)?;
    let r = fit(&m, &d, &add, free, common.window_s)?;
    r.model.write(out)?;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    if common.json {
        let mut j = r.to_json();
        let all: Vec<&String> = warnings.iter().chain(&r.warnings).collect();
        j["warnings"] = serde_json::json!(all);
        return print_json(&j);
    }
    for (k, v) in &r.params {
        println!("{k} = {v:.6}");
    }
    println!(
        "equation NRMSE {} -> {} (where the axis moves: {} -> {}); windowed simulation NRMSE {} -> {}",
        opt(r.before.equation_nrmse_pct),
        opt(r.after.equation_nrmse_pct),
        opt(r.before.equation_moving_nrmse_pct),
        opt(r.after.equation_moving_nrmse_pct),
        opt(r.before.window_sim_nrmse_pct),
        opt(r.after.window_sim_nrmse_pct)
    );
    println!("wrote {}", out.display());
    Ok(())
}
