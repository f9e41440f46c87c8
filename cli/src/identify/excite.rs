//! `feedloop excite`: writes an excitation run's job and command for an axis.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};

use crate::choice::{Choice, ExciteKind};
use feedloop_model::units::si;
use feedloop_motion::{build_at, excitation::write_excitation_csv};

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
    /// The job that will play the file (need not exist yet): the `file = ...` line printed is
    /// the path from its folder (default: a job in the output's own folder).
    #[arg(long)]
    pub for_job: Option<PathBuf>,
    /// Print JSON only.
    #[arg(long)]
    pub json: bool,
}

/// `p` absolute, with `.` and `..` folded away (without touching the file system).
fn lexical_absolute(p: &Path) -> PathBuf {
    let abs = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// The path of `file` as a job in `job_dir` writes it: relative to that folder, which is where
/// a job's `file` is read from.
fn path_from_job_dir(file: &Path, job_dir: &Path) -> PathBuf {
    let (f, d) = (lexical_absolute(file), lexical_absolute(job_dir));
    let (fc, dc): (Vec<_>, Vec<_>) = (f.components().collect(), d.components().collect());
    let common = fc.iter().zip(&dc).take_while(|(a, b)| a == b).count();
    let mut rel = PathBuf::new();
    for _ in common..dc.len() {
        rel.push("..");
    }
    for c in &fc[common..] {
        rel.push(c);
    }
    rel
}

/// The job folder the printed `file = ...` line is for (`--for-job`'s folder, else the output's),
/// as the user gave it ("." for the current folder), and the line's path.
fn job_file_line(a: &ExciteArgs) -> (PathBuf, PathBuf) {
    let dir = match &a.for_job {
        Some(j) => j.parent().unwrap_or(Path::new("")).to_path_buf(),
        None => a.out.parent().unwrap_or(Path::new("")).to_path_buf(),
    };
    let dir = if dir.as_os_str().is_empty() {
        PathBuf::from(".")
    } else {
        dir
    };
    // an absolute output is found the same from any folder
    let rel = if a.out.is_absolute() && a.for_job.is_some() {
        a.out.clone()
    } else {
        path_from_job_dir(&a.out, &dir)
    };
    (dir, rel)
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
    let (job_dir, job_file) = job_file_line(&a);
    if a.json {
        println!(
            "{}",
            serde_json::json!({"out": a.out.display().to_string(), "kind": a.kind.id(),
                "duration_s": traj.duration_s(), "rows": rows,
                "job_file": job_file.display().to_string(),
                "job_folder": job_dir.display().to_string()})
        );
    } else {
        println!(
            "wrote {} ({} excitation, {}, {rows} rows); play it with [trajectory] kind = \"trace\", \
             file = \"{}\" in a job in {}/ (a job's `file` is read from the job's own folder{})",
            a.out.display(),
            a.kind.id(),
            si(traj.duration_s(), "s"),
            job_file.display(),
            job_dir.display(),
            if a.for_job.is_some() {
                ""
            } else {
                "; --for-job JOB gives the path from another job's folder"
            }
        );
    }
    Ok(ExitCode::SUCCESS)
}
