//! Job files: what to run (axes and their models, controller chain, trajectory, timing, IPC wait).
//!
//! ```toml
//! name = "single-axis-move"
//! period_s = 1.0e-4
//! [run]
//! mode = "lockstep"        # default mode of `feedloop run`: realtime | lockstep
//! wait = "hybrid"          # busy | block | hybrid
//! [axes.x]
//! model = "../models/ballscrew-x.toml"   # relative to this job file
//! [[chain]]                 # optional: overrides the default position_p + pi_velocity chain
//! axis = "x"
//! stage = "velocity"
//! plugin = "pi_velocity"
//! params = { kv_nms_per_rad = 4.0 }
//! [trajectory]
//! kind = "move"
//! ...
//! ```
//! See `docs/job-file.md` for every key.

use std::path::{Path, PathBuf};

use crate::model::ModelFile;
use crate::params::{read_toml_file, ConfigError, Fields, Range};
use crate::Stage;
use crate::MAX_AXES;

/// How plant and scheduler are paced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// The plant paces cycles at `period_s` with absolute deadlines.
    Realtime,
    /// The plant steps when the command for the cycle arrives (deterministic, as fast as possible).
    Lockstep,
}

impl Mode {
    /// Name on the command line and in files.
    pub fn id(self) -> &'static str {
        match self {
            Mode::Realtime => "realtime",
            Mode::Lockstep => "lockstep",
        }
    }
    /// Parses a mode name.
    pub fn parse(s: &str) -> Option<Mode> {
        match s {
            "realtime" => Some(Mode::Realtime),
            "lockstep" => Some(Mode::Lockstep),
            _ => None,
        }
    }
}

/// How a process waits for the other's message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WaitKind {
    /// Spin on `receive()` (lowest latency, owns a core).
    Busy,
    /// Block on an iceoryx2 event listener (no CPU while waiting, ~70 us cross-core wake-ups here).
    Block,
    /// Spin for a bounded time (`spin_us`), then block.
    Hybrid,
}

impl WaitKind {
    /// Name on the command line and in files.
    pub fn id(self) -> &'static str {
        match self {
            WaitKind::Busy => "busy",
            WaitKind::Block => "block",
            WaitKind::Hybrid => "hybrid",
        }
    }
    /// Parses a wait name.
    pub fn parse(s: &str) -> Option<WaitKind> {
        match s {
            "busy" => Some(WaitKind::Busy),
            "block" => Some(WaitKind::Block),
            "hybrid" => Some(WaitKind::Hybrid),
            _ => None,
        }
    }
}

/// Run-time options (`[run]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunOptions {
    /// Default mode for `feedloop run`.
    pub mode: Mode,
    /// Default wait strategy.
    pub wait: WaitKind,
    /// Hybrid wait: spin this long before blocking, microseconds. 0 (the default) means
    /// 0.9 periods + 20 us, capped to 20 .. 500 us: enough to catch the next message while
    /// spinning when the loop keeps its period, and to block when the peer is away.
    pub spin_us: f64,
    /// Plant watchdog: commands missing for this many on-time cycles means the scheduler is lost.
    /// Default: 100 cycles or [`DEFAULT_WATCHDOG_S`], whichever is longer.
    pub watchdog_cycles: u64,
    /// Lockstep: how long a process waits for its peer before declaring it lost, s. Default 5.
    pub peer_timeout_s: f64,
    /// Realtime start-up: how long the plant waits, holding the axes, for the first command
    /// before the loop counts as closed, s. The watchdog runs only after that. Default 2.
    pub startup_grace_s: f64,
    /// Realtime start-up: how long the plant watches its core, before the first sample, for the
    /// phase of the period that the host's periodic interruptions (a timer tick, a hypervisor's
    /// rhythm) leave alone; cycles then start at that phase. 0 starts them when the loop closes,
    /// at whatever phase that is. Default [`DEFAULT_PHASE_PROBE_S`].
    pub phase_probe_s: f64,
}

/// Default `[run] phase_probe_s`: 125 ticks of a 250 Hz kernel tick, enough for the phase not
/// to move with the interruptions that come at other rhythms.
pub const DEFAULT_PHASE_PROBE_S: f64 = 0.5;
/// Longest `[run] phase_probe_s` accepted, s.
pub const MAX_PHASE_PROBE_S: f64 = 10.0;

/// How the plant brings the axes to rest when a run must stop early.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafeStop {
    /// Zero torque at once (the axes coast).
    TorqueOff,
    /// Brake on motor velocity with the axis' velocity gain, within its torque limit, for
    /// `brake_time_s`, then torque off.
    BrakeRamp,
}

crate::key_choice!(SafeStop, "safe stop", default BrakeRamp,
    ["torque_off" => TorqueOff, "brake_ramp" => BrakeRamp]);

impl SafeStop {
    /// Name in files and summaries.
    pub fn id(self) -> &'static str {
        match self {
            SafeStop::TorqueOff => "torque_off",
            SafeStop::BrakeRamp => "brake_ramp",
        }
    }
}

/// Drive-side safety limits checked by the plant every cycle (`[safety]`).
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyOptions {
    /// What to do when stopping early. Default `brake_ramp`.
    pub safe_stop: SafeStop,
    /// Braking time of `brake_ramp`, s. Default 0.2.
    pub brake_time_s: f64,
    /// "Following error too large" alarm: |cmd - load| above this (load units) stops the run.
    pub max_following_error: Option<f64>,
    /// Torque at its limit for longer than this (s) stops the run.
    pub max_saturation_s: Option<f64>,
    /// Soft travel limits per axis (job order), load units: outside [lo, hi] stops the run.
    pub soft_limits: Vec<Option<(f64, f64)>>,
}

/// One axis of the job.
#[derive(Debug, Clone)]
pub struct JobAxis {
    /// Axis name (lowercase letters, digits, `_`).
    pub name: String,
    /// Its model file.
    pub model: ModelFile,
}

/// One `[[chain]]` entry.
#[derive(Debug, Clone)]
pub struct ChainEntry {
    /// Index of the axis in `Job::axes`.
    pub axis: usize,
    /// Stage it fills.
    pub stage: Stage,
    /// Plugin id.
    pub plugin: String,
    /// The plugin's own parameter keys.
    pub params: toml::Table,
    /// Key path of this entry in the job file, for messages (e.g. `chain[2]`).
    pub key: String,
}

/// A parsed, validated job file.
#[derive(Debug, Clone)]
pub struct Job {
    /// Where it was read from.
    pub path: PathBuf,
    /// Job name (default: the file stem).
    pub name: String,
    /// Control period, s.
    pub period_s: f64,
    /// Run length, s (default: the trajectory's duration).
    pub duration_s: Option<f64>,
    /// `[run]` options.
    pub run: RunOptions,
    /// `[safety]` options.
    pub safety: SafetyOptions,
    /// Axes in file order (this order is the wire order).
    pub axes: Vec<JobAxis>,
    /// Explicit chain entries; stages not given default to `position_p` + `pi_velocity`.
    pub chain: Vec<ChainEntry>,
    /// Couplers (`[[couplers]]`): plugin id, axes, params.
    pub couplers: Vec<CouplerEntry>,
    /// The `[trajectory]` table (validated by `trajectory::build`).
    pub trajectory: toml::Table,
}

/// One `[[couplers]]` entry.
#[derive(Debug, Clone)]
pub struct CouplerEntry {
    /// Plugin id.
    pub plugin: String,
    /// Indices of coupled axes.
    pub axes: Vec<usize>,
    /// Parameters.
    pub params: toml::Table,
    /// Key path for messages.
    pub key: String,
}

/// Checks an axis or instance name: lowercase letters, digits, `_` (and `-` when `dash`).
pub fn valid_name(s: &str, dash: bool) -> bool {
    !s.is_empty()
        && s.len() <= 64
        && s.bytes().all(|b| {
            b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || (dash && b == b'-')
        })
}

impl Job {
    /// Reads and validates a job file and the model files it names.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let table = read_toml_file(path)?;
        Self::from_table(&table, path)
    }

    /// Validates a parsed job table; model paths are resolved relative to `path`'s folder.
    pub fn from_table(table: &toml::Table, path: &Path) -> Result<Self, ConfigError> {
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut f = Fields::new(table, path, "");
        let name = match f.opt_str("name")? {
            Some(n) => n.to_string(),
            None => path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "job".into()),
        };
        let period_s = f.f64("period_s", Range::Positive)?;
        if period_s > 0.1 {
            return Err(f.error("period_s", format!("must be <= 0.1 s, got {period_s}")));
        }
        if period_s < 1e-6 {
            return Err(f.error("period_s", format!("must be >= 1e-6 s, got {period_s}")));
        }
        let duration_s = f.opt_f64("duration_s", Range::Positive)?;
        let run = match f.opt_table("run")? {
            Some(t) => run_options(t, path, period_s)?,
            None => run_options(&toml::Table::new(), path, period_s)?,
        };
        let axes = read_axes(&mut f, path, dir)?;
        let chain = match f.raw("chain") {
            Some(v) => read_chain(&f, v, &axes)?,
            None => Vec::new(),
        };
        let couplers = match f.raw("couplers") {
            Some(v) => read_couplers(&f, v, &axes)?,
            None => Vec::new(),
        };
        let safety = safety_options(f.opt_table("safety")?, path, &axes)?;
        let trajectory = f
            .opt_table("trajectory")?
            .cloned()
            .ok_or_else(|| f.error("trajectory", "is required: a [trajectory] table"))?;
        f.finish()?;
        Ok(Self {
            path: path.to_path_buf(),
            name,
            period_s,
            duration_s,
            run,
            safety,
            axes,
            chain,
            couplers,
            trajectory,
        })
    }

    /// Axis names in wire order.
    pub fn axis_names(&self) -> Vec<String> {
        self.axes.iter().map(|a| a.name.clone()).collect()
    }

    /// The hybrid wait's spin time, s (see [`RunOptions::spin_us`]).
    pub fn spin_s(&self) -> f64 {
        if self.run.spin_us > 0.0 {
            self.run.spin_us * 1e-6
        } else {
            (0.9 * self.period_s + 20e-6).clamp(20e-6, 500e-6)
        }
    }

    /// Number of cycles for a run of `duration_s`: round(duration / period).
    pub fn cycles_for(&self, duration_s: f64) -> u64 {
        (duration_s / self.period_s).round().max(1.0) as u64
    }
}

/// The `[axes.<name>]` tables: each axis's name and its model file (relative to `dir`).
fn read_axes(f: &mut Fields<'_>, path: &Path, dir: &Path) -> Result<Vec<JobAxis>, ConfigError> {
    let axes_table = f
        .opt_table("axes")?
        .ok_or_else(|| f.error("axes", "is required: at least one [axes.<name>] table"))?;
    if axes_table.is_empty() {
        return Err(f.error("axes", "must name at least one axis"));
    }
    if axes_table.len() > MAX_AXES {
        return Err(f.error(
            "axes",
            format!("at most {MAX_AXES} axes, got {}", axes_table.len()),
        ));
    }
    let mut axes = Vec::new();
    for (axis_name, v) in axes_table {
        let key = format!("axes.{axis_name}");
        if !valid_name(axis_name, false) {
            return Err(ConfigError::new(
                path,
                &key,
                "axis names use lowercase letters, digits and `_`",
            ));
        }
        let t = v
            .as_table()
            .ok_or_else(|| ConfigError::new(path, &key, "must be a table"))?;
        let mut af = Fields::new(t, path, &key);
        let model_rel = af.str("model")?;
        af.finish()?;
        let model_path = dir.join(model_rel);
        if !model_path.exists() {
            return Err(ConfigError::new(
                path,
                format!("{key}.model"),
                format!("model file {} does not exist", model_path.display()),
            ));
        }
        let model = ModelFile::load(&model_path)?;
        axes.push(JobAxis {
            name: axis_name.clone(),
            model,
        });
    }
    Ok(axes)
}

/// The index of the axis named `name`.
fn axis_index(axes: &[JobAxis], name: &str) -> Option<usize> {
    axes.iter().position(|a| a.name == name)
}

/// The tables of the array of tables `name` (`v`, read from `f`'s table), each with its dotted
/// key `name[i]`; an element that is no table is an error when the iteration reaches it.
fn array_of_tables<'a>(
    f: &Fields<'_>,
    v: &'a toml::Value,
    name: &str,
) -> Result<impl Iterator<Item = Result<(String, &'a toml::Table), ConfigError>>, ConfigError> {
    let arr = v
        .as_array()
        .ok_or_else(|| f.error(name, format!("must be an array of tables ([[{name}]])")))?;
    let (file, name) = (f.file().to_path_buf(), name.to_string());
    Ok(arr.iter().enumerate().map(move |(i, e)| {
        let key = format!("{name}[{i}]");
        match e.as_table() {
            Some(t) => Ok((key, t)),
            None => Err(ConfigError::new(&file, &key, "must be a table")),
        }
    }))
}

/// The `[[chain]]` tables (`v`): one stage of one axis each, at most one per axis and stage.
fn read_chain(
    f: &Fields<'_>,
    v: &toml::Value,
    axes: &[JobAxis],
) -> Result<Vec<ChainEntry>, ConfigError> {
    let path = f.file();
    let mut chain = Vec::new();
    for item in array_of_tables(f, v, "chain")? {
        let (key, t) = item?;
        let mut cf = Fields::new(t, path, &key);
        let axis = cf.str("axis")?;
        let axis = existing_axis(&cf, "axis", axes, axis)?;
        let stage_s = cf.str("stage")?;
        let stage = Stage::parse(stage_s).ok_or_else(|| {
            cf.error(
                "stage",
                format!("unknown stage `{stage_s}` (position, feedforward, compensator, velocity)"),
            )
        })?;
        let plugin = cf.str("plugin")?.to_string();
        let params = cf.opt_table("params")?.cloned().unwrap_or_default();
        cf.finish()?;
        if chain
            .iter()
            .any(|c: &ChainEntry| c.axis == axis && c.stage == stage)
        {
            return Err(ConfigError::new(
                path,
                &key,
                format!("axis `{}` has two `{stage}` stages", axes[axis].name),
            ));
        }
        chain.push(ChainEntry {
            axis,
            stage,
            plugin,
            params,
            key,
        });
    }
    Ok(chain)
}

/// The `[[couplers]]` tables (`v`): a plugin over named axes each.
fn read_couplers(
    f: &Fields<'_>,
    v: &toml::Value,
    axes: &[JobAxis],
) -> Result<Vec<CouplerEntry>, ConfigError> {
    let path = f.file();
    let mut couplers = Vec::new();
    for item in array_of_tables(f, v, "couplers")? {
        let (key, t) = item?;
        let mut cf = Fields::new(t, path, &key);
        let plugin = cf.str("plugin")?.to_string();
        let names_v = cf.opt_str_array("axes")?.unwrap_or_default();
        let mut idx = Vec::new();
        for n in &names_v {
            idx.push(existing_axis(&cf, "axes", axes, n)?);
        }
        let params = cf.opt_table("params")?.cloned().unwrap_or_default();
        cf.finish()?;
        couplers.push(CouplerEntry {
            plugin,
            axes: idx,
            params,
            key,
        });
    }
    Ok(couplers)
}

/// The index of axis `name` among `axes`, else the refusal of key `key` of `cf` naming them.
fn existing_axis(
    cf: &Fields<'_>,
    key: &str,
    axes: &[JobAxis],
    name: &str,
) -> Result<usize, ConfigError> {
    axis_index(axes, name).ok_or_else(|| {
        cf.error(
            key,
            format!(
                "axis `{name}` does not exist (axes of this job: {})",
                names(axes)
            ),
        )
    })
}

fn names(axes: &[JobAxis]) -> String {
    axes.iter()
        .map(|a| a.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

fn safety_options(
    t: Option<&toml::Table>,
    path: &Path,
    axes: &[JobAxis],
) -> Result<SafetyOptions, ConfigError> {
    let empty = toml::Table::new();
    let mut f = Fields::new(t.unwrap_or(&empty), path, "safety");
    let safe_stop: SafeStop = f.choose("safe_stop")?;
    let brake_time_s = f.f64_or("brake_time_s", Range::Within(0.0, 60.0), 0.2)?;
    let max_following_error = f.opt_f64("max_following_error_m", Range::Positive)?;
    let max_saturation_s = f.opt_f64("max_saturation_s", Range::Positive)?;
    let mut soft_limits = vec![None; axes.len()];
    if let Some(lims) = f.opt_table("soft_limits_m")? {
        for (name, v) in lims {
            let key = format!("safety.soft_limits_m.{name}");
            let i = axes.iter().position(|a| &a.name == name).ok_or_else(|| {
                ConfigError::new(path, &key, format!("axis `{name}` does not exist"))
            })?;
            let arr = v.as_array().filter(|a| a.len() == 2).ok_or_else(|| {
                ConfigError::new(
                    path,
                    &key,
                    "must be [lower, upper] in load units (m or rad)",
                )
            })?;
            let num = |x: &toml::Value| x.as_float().or_else(|| x.as_integer().map(|i| i as f64));
            match (num(&arr[0]), num(&arr[1])) {
                (Some(lo), Some(hi)) if lo.is_finite() && hi.is_finite() && lo < hi => {
                    soft_limits[i] = Some((lo, hi))
                }
                _ => {
                    return Err(ConfigError::new(
                        path,
                        &key,
                        "must be [lower, upper] with finite lower < upper",
                    ))
                }
            }
        }
    }
    f.finish()?;
    Ok(SafetyOptions {
        safe_stop,
        brake_time_s,
        max_following_error,
        max_saturation_s,
        soft_limits,
    })
}

/// Default watchdog: 100 cycles, and at least this long (a fieldbus drive's usual command
/// watchdog is 50-100 ms; a few ms is what a busy, non-realtime host can take from a process).
pub const DEFAULT_WATCHDOG_S: f64 = 0.05;

fn run_options(t: &toml::Table, path: &Path, period_s: f64) -> Result<RunOptions, ConfigError> {
    let mut f = Fields::new(t, path, "run");
    let mode = match f.opt_str("mode")? {
        None => Mode::Lockstep,
        Some(s) => Mode::parse(s)
            .ok_or_else(|| f.error("mode", format!("unknown mode `{s}` (realtime, lockstep)")))?,
    };
    let wait = match f.opt_str("wait")? {
        None => WaitKind::Hybrid,
        Some(s) => WaitKind::parse(s)
            .ok_or_else(|| f.error("wait", format!("unknown wait `{s}` (busy, block, hybrid)")))?,
    };
    let spin_us = f.f64_or("spin_us", Range::Within(0.0, 100_000.0), 0.0)?;
    let default_watchdog = ((DEFAULT_WATCHDOG_S / period_s).ceil() as u64).max(100);
    let watchdog_cycles = f
        .opt_i64("watchdog_cycles", 1, 1_000_000)?
        .map_or(default_watchdog, |c| c as u64);
    let peer_timeout_s = f.f64_or("peer_timeout_s", Range::Within(0.01, 3600.0), 5.0)?;
    let startup_grace_s = f.f64_or("startup_grace_s", Range::Within(0.001, 3600.0), 2.0)?;
    let phase_probe_s = f.f64_or(
        "phase_probe_s",
        Range::Within(0.0, MAX_PHASE_PROBE_S),
        DEFAULT_PHASE_PROBE_S,
    )?;
    f.finish()?;
    Ok(RunOptions {
        mode,
        wait,
        spin_us,
        watchdog_cycles,
        peer_timeout_s,
        startup_grace_s,
        phase_probe_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

    fn setup(job: &str) -> (PathBuf, Result<Job, ConfigError>) {
        let dir = std::env::temp_dir().join(format!(
            "feedloop-job-test-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, std::sync::atomic::Ordering::SeqCst)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        write(
            &dir,
            "m.toml",
            "kind = \"rigid\"\nmass_kg = 10\n[controller]\nkp_per_s = 30\nkv_ns_per_m = 2000\n",
        );
        let p = write(&dir, "j.toml", job);
        let r = Job::load(&p);
        // the job is read whole: its folder is not needed after loading
        std::fs::remove_dir_all(&dir).ok();
        (dir, r)
    }

    #[test]
    fn the_default_watchdog_is_100_cycles_or_50_ms_and_a_given_one_is_kept() {
        let job = |period: &str, run: &str| {
            setup(&format!(
                "period_s = {period}\n[run]\n{run}\n[axes.x]\nmodel = \"m.toml\"\n[trajectory]\nkind = \"dwell\"\n"
            ))
            .1
            .unwrap()
            .run
        };
        assert_eq!(job("1.0e-4", "").watchdog_cycles, 500);
        assert_eq!(job("1.0e-3", "").watchdog_cycles, 100);
        assert_eq!(job("2.0e-2", "").watchdog_cycles, 100);
        assert_eq!(job("1.0e-4", "watchdog_cycles = 20").watchdog_cycles, 20);
        let r = job("1.0e-4", "startup_grace_s = 0.5");
        assert_eq!(r.startup_grace_s, 0.5);
        assert_eq!(job("1.0e-4", "").startup_grace_s, 2.0);
    }

    #[test]
    fn the_phase_probe_defaults_to_half_a_second_and_is_refused_beyond_its_range() {
        let run = |run: &str| {
            setup(&format!(
                "period_s = 1e-4\n[run]\n{run}\n[axes.x]\nmodel = \"m.toml\"\n[trajectory]\nkind = \"dwell\"\n"
            ))
            .1
            .map(|j| j.run.phase_probe_s)
        };
        assert_eq!(run("").unwrap(), DEFAULT_PHASE_PROBE_S);
        assert_eq!(run("phase_probe_s = 0").unwrap(), 0.0);
        assert_eq!(run("phase_probe_s = 1.5").unwrap(), 1.5);
        let e = run("phase_probe_s = -1").unwrap_err().to_string();
        assert!(e.contains("phase_probe_s") && e.contains("j.toml"), "{e}");
    }

    #[test]
    fn axes_keep_the_order_of_the_file_not_of_their_names() {
        let (dir, r) = setup(
            "period_s = 0.001\n[axes.x]\nmodel = \"m.toml\"\n[axes.c]\nmodel = \"m.toml\"\n[axes.a]\nmodel = \"m.toml\"\n[trajectory]\nkind = \"move\"\nto_m = [0.01, 0.02, 0.03]\nduration_s = 0.1\n",
        );
        let job = r.unwrap();
        assert_eq!(job.axis_names(), ["x", "c", "a"]);
        // (that a per-axis trajectory array follows this order: motion/tests/job_order.rs)
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn chain_naming_a_missing_axis_is_refused() {
        let (_d, r) = setup(
            "period_s = 0.001\n[axes.x]\nmodel = \"m.toml\"\n[[chain]]\naxis = \"y\"\nstage = \"velocity\"\nplugin = \"pi_velocity\"\n[trajectory]\nkind = \"dwell\"\n",
        );
        let e = r.unwrap_err();
        assert_eq!(e.key, "chain[0].axis");
        assert!(e.reason.contains("`y` does not exist"), "{e}");
    }

    #[test]
    fn zero_period_is_refused() {
        let (_d, r) =
            setup("period_s = 0\n[axes.x]\nmodel = \"m.toml\"\n[trajectory]\nkind = \"dwell\"\n");
        assert_eq!(r.unwrap_err().key, "period_s");
    }

    #[test]
    fn unknown_top_level_key_is_refused() {
        let (_d, r) = setup(
            "period_s = 0.001\nspeed = 3\n[axes.x]\nmodel = \"m.toml\"\n[trajectory]\nkind = \"dwell\"\n",
        );
        assert_eq!(r.unwrap_err().key, "speed");
    }

    #[test]
    fn missing_model_file_is_named() {
        let (_d, r) = setup(
            "period_s = 0.001\n[axes.x]\nmodel = \"nope.toml\"\n[trajectory]\nkind = \"dwell\"\n",
        );
        let e = r.unwrap_err();
        assert_eq!(e.key, "axes.x.model");
    }
}
