//! `feedloop tune`: the controller gains of a job's axes from its ramp test.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};

use feedloop_analysis::identify::inertia::{self};
use feedloop_analysis::identify::svg::tune_heatmap_svg;
use feedloop_model::job::Job;
use feedloop_model::units::{si, sig};

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

/// One tuned axis.
struct TunedAxis {
    name: String,
    result: feedloop_analysis::identify::tune::TuneResult,
    seconds: f64,
    /// The parameters whose best value is on an edge of the grid.
    edges: Vec<feedloop_analysis::identify::tune::EdgeWarning>,
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
            edges: t::edge_warnings(grid, r.best),
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
            "axis": ta.name, "delay_cycles": a.delay_cycles, "skipped": skipped_json,
            "edge_warnings": ta.edges});
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
        "delay_cycles": a.delay_cycles, "skipped": skipped_json,
        "edge_warnings": tuned.iter().map(|x| (x.name.clone(), serde_json::json!(x.edges)))
            .collect::<serde_json::Map<_, _>>()})
}

/// The text of a best set on the edge of its grid.
fn edge_text(axis: &str, w: &feedloop_analysis::identify::tune::EdgeWarning) -> String {
    let at = if sig(w.best) == sig(w.bound) {
        format!("the {} bound of its grid", w.edge)
    } else {
        // refined past the grid
        format!("beyond the {} bound {} of its grid", w.edge, sig(w.bound))
    };
    format!(
        "axis {axis}: warning: the best {} is {}, {at}: the error may fall further beyond it; \
         widen the range, e.g. --grid {}",
        w.parameter,
        sig(w.best),
        w.widened
    )
}

/// Runs `feedloop tune`.
pub fn tune(a: TuneArgs) -> anyhow::Result<ExitCode> {
    use feedloop_analysis::identify::tune as t;
    let job = Job::load(&a.job)?;
    let grid = t::parse_grid(&a.grid)?;
    let weights = parse_weights(&a.weights)?;
    let (axes, skipped) = tunable_axes(&a, &job, weights)?;
    // the folders of what is written at the end, made before the grid is computed (as `sim` and
    // `run` make theirs): a missing folder must not cost the whole search
    for p in a.svg.iter().chain(a.apply.iter()) {
        if let Some(d) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(d)
                .with_context(|| format!("{}: cannot create folder", d.display()))?;
        }
    }
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
        for w in &ta.edges {
            println!("{}", edge_text(&ta.name, w));
        }
    }
    Ok(ExitCode::SUCCESS)
}
