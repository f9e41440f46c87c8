//! The builder thread of the control service: parses and validates a swapped-in plugin outside
//! the cycle, judges its gains with the loop model, and drops retired controllers.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::sync::Arc;

use feedloop_control::controller::{AxisContext, Controller, PluginRegistry, Stage};
use feedloop_control::loop_model::{self, LoopGains};
use feedloop_model::params::ConfigError;

use feedloop_model::job::Job;

use super::protocol::StagePlugins;
use crate::scheduler::cycle::ControlCycle;
use crate::scheduler::plugin_lib::AbiError;

pub(super) struct BuildJob {
    pub(super) axis: usize,
    pub(super) stage: Stage,
    pub(super) plugin: String,
    pub(super) params: Option<String>,
    pub(super) lib: Option<String>,
    pub(super) force: bool,
    /// The file `params` came from (for errors).
    pub(super) params_file: Option<String>,
}

/// A stage's plugin id and the parameters it was built from.
type StageEntry = (String, toml::Table);

/// What the builder thread is asked to do.
pub(super) enum ToBuilder {
    /// Build a controller.
    Build(BuildJob),
    /// A swap passed its probation: its plugin and parameters are now the stage's current ones
    /// (the base a later retune of the same plugin merges its keys into). A rolled-back swap
    /// sends nothing, so the previous entry stays.
    Settled {
        axis: usize,
        stage: Stage,
        entry: (String, toml::Table),
        gains: LoopGains,
    },
    /// A controller taken out of the chain: dropped here, not in the cycle.
    Retire(Box<dyn Controller>),
}

/// Why a swap was refused.
#[derive(Debug, thiserror::Error)]
pub(super) enum SwapError {
    /// No axis of that name.
    #[error("axis `{axis}` does not exist (axes: {known})")]
    UnknownAxis { axis: String, known: String },
    /// No stage of that name.
    #[error("unknown stage `{0}` (position, feedforward, compensator, velocity)")]
    UnknownStage(String),
    /// The plugin library refused.
    #[error(transparent)]
    Library(#[from] AbiError),
    /// The parameters, or the plugin built from them, were refused.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The plugin does not fill the stage asked for.
    #[error("{0}")]
    WrongStage(String),
    /// The loop model finds the axis unstable or marginal with the new controller.
    #[error("refused before it was applied: {0}; check the gains, or send it with --force to apply it anyway")]
    Unsafe(String),
}

pub(super) struct Built {
    pub(super) controller: Result<Box<dyn Controller>, SwapError>,
    /// The stage's current (plugin, parameters) once this controller is confirmed.
    pub(super) entry: (String, toml::Table),
    /// What the swap changes ([`SwapEvent::changed`](super::protocol::SwapEvent::changed)),
    /// worked out here rather than in the cycle.
    pub(super) changed: Vec<String>,
    /// What the builder found out about it.
    pub(super) check: Checked,
}

/// The builder's findings on a new controller, carried into its [`SwapEvent`].
#[derive(Default)]
pub(super) struct Checked {
    pub(super) gains: LoopGains,
    pub(super) margins: Option<(f64, f64)>,
    pub(super) force: bool,
    pub(super) warnings: Vec<String>,
}

/// What the builder needs to judge a new controller with the loop model.
pub(super) struct LoopCheck {
    /// Per axis, what each stage's current controller contributes.
    pub(super) gains: Vec<[LoopGains; 4]>,
    /// The same for the chain the job started with (the loop its operator accepted).
    pub(super) initial: Vec<[LoopGains; 4]>,
    /// Per axis, the transport delay of the margin check (the model's own), s.
    pub(super) delays_s: Vec<f64>,
}

/// What the builder builds and judges a swap against, from the chain a loop starts with.
pub(super) struct ChainState {
    /// Per axis, what its plugins are built for.
    pub(super) contexts: Vec<AxisContext>,
    /// Per axis and stage, the current plugin id and the parameters it was built from.
    pub(super) current: Vec<[(String, toml::Table); 4]>,
    /// The loop model's view of the chain.
    pub(super) model: LoopCheck,
}

impl ChainState {
    /// The state of `cycle`'s chain as `job` built it, and the plugin of each stage of each axis.
    pub(super) fn of(job: &Job, cycle: &ControlCycle) -> (Self, Vec<StagePlugins>) {
        let contexts: Vec<AxisContext> = cycle
            .chain()
            .axes()
            .iter()
            .map(|a| a.context.clone())
            .collect();
        let mut current: Vec<[(String, toml::Table); 4]> = Vec::new();
        let mut plugin_ids = Vec::new();
        let mut gains: Vec<[LoopGains; 4]> = Vec::new();
        for (i, a) in cycle.chain().axes().iter().enumerate() {
            let mut cur: [(String, toml::Table); 4] = Default::default();
            let mut ids = StagePlugins::default();
            let mut g = [LoopGains::default(); 4];
            for st in Stage::ALL {
                if let Some(c) = &a.stages[st.index()] {
                    g[st.index()] = c.loop_gains();
                    let params = job
                        .chain
                        .iter()
                        .find(|e| e.axis == i && e.stage == st)
                        .map(|e| e.params.clone())
                        .unwrap_or_default();
                    cur[st.index()] = (c.id().to_string(), params);
                    ids.set(st, Some(c.id().to_string()));
                }
            }
            current.push(cur);
            plugin_ids.push(ids);
            gains.push(g);
        }
        let model = LoopCheck {
            initial: gains.clone(),
            gains,
            delays_s: (0..job.axes.len())
                // this runtime applies a command within the period of its sample: the hold
                // and the model's own [effects.delay] are the loop's delay
                .map(|i| loop_model::loop_delay_s(job, i, 0))
                .collect(),
        };
        let state = Self {
            contexts,
            current,
            model,
        };
        (state, plugin_ids)
    }

    /// `job`'s controller built from its parameters (merged into the stage's current ones when
    /// the plugin stays) and judged by the loop model, with the stage's entry once it is
    /// confirmed; or why it is refused.
    pub(super) fn build(
        &self,
        job: &BuildJob,
        registry: &dyn PluginRegistry,
        job_path: &Path,
    ) -> Result<(Box<dyn Controller>, StageEntry, Checked), SwapError> {
        let (c, entry) = build_one(job, registry, &self.contexts, &self.current, job_path)?;
        let check = judge(job, c.as_ref(), &self.contexts, &self.model)?;
        Ok((c, entry, check))
    }
}

pub(super) fn builder(
    jobs: mpsc::Receiver<ToBuilder>,
    done: mpsc::Sender<Built>,
    registry: Arc<dyn PluginRegistry>,
    mut state: ChainState,
    job_path: PathBuf,
) {
    // Blocks until there is work: no periodic wake-ups to preempt a spinning loop.
    loop {
        let job = match jobs.recv() {
            Ok(ToBuilder::Build(j)) => j,
            Ok(ToBuilder::Retire(old)) => {
                drop(old);
                continue;
            }
            Ok(ToBuilder::Settled {
                axis,
                stage,
                entry,
                gains,
            }) => {
                if let Some(slot) = state.current.get_mut(axis) {
                    slot[stage.index()] = entry;
                }
                if let Some(slot) = state.model.gains.get_mut(axis) {
                    slot[stage.index()] = gains;
                }
                continue;
            }
            Err(mpsc::RecvError) => return,
        };
        let refused = |e| Built {
            controller: Err(e),
            entry: Default::default(),
            changed: Vec::new(),
            check: Checked::default(),
        };
        let built = match state.build(&job, registry.as_ref(), &job_path) {
            Ok((c, entry, check)) => Built {
                controller: Ok(c),
                changed: changes(&state.current[job.axis][job.stage.index()], &entry, &job),
                entry,
                check,
            },
            Err(e) => refused(e),
        };
        if done.send(built).is_err() {
            return;
        }
    }
}

/// The loop model's verdict on the axis with `new` in the stage of `job`: its margins, or the
/// refusal of an unstable or marginal set (a warning when the request says `force`).
fn judge(
    job: &BuildJob,
    new: &dyn Controller,
    contexts: &[AxisContext],
    model: &LoopCheck,
) -> Result<Checked, SwapError> {
    let ctx = &contexts[job.axis];
    let delay = model.delays_s[job.axis];
    let margins_of = |stages: &[LoopGains; 4]| {
        LoopGains::combine(stages)
            .and_then(|g| loop_model::margins(&ctx.plant, g, ctx.period_s, delay))
    };
    let mut stages = model.gains[job.axis];
    let gains = new.loop_gains();
    stages[job.stage.index()] = gains;
    let mut check = Checked {
        gains,
        force: job.force,
        ..Default::default()
    };
    match margins_of(&stages) {
        None => check.warnings.push(
            "margins not checked: the loop's gains are not all known (a plugin that reports none)"
                .into(),
        ),
        Some((pm, gm)) => {
            check.margins = Some((pm, gm));
            if let Some(why) = loop_model::margin_failure(pm, gm) {
                // a loop already short of margin (now, or as the job started it) is not blamed on
                // a swap that does not make it worse (a feedforward swap, a softer gain)
                let no_worse = [&model.gains[job.axis], &model.initial[job.axis]]
                    .into_iter()
                    .filter_map(margins_of)
                    .any(|(p0, g0)| pm >= p0 - 0.5 && gm >= g0 - 0.1);
                if no_worse {
                    check.warnings.push(format!(
                        "{why}: no worse than the loop before this swap or as the job started it"
                    ));
                } else if !job.force {
                    return Err(SwapError::Unsafe(why));
                } else {
                    check
                        .warnings
                        .push(format!("{why}: applied anyway (force)"));
                }
            }
        }
    }
    Ok(check)
}

/// What replacing the stage's `current` entry by `new` changes, in words: the plugin when it
/// differs, then each parameter whose value differs (a library's parameters are its own text:
/// their lines as sent).
fn changes(current: &StageEntry, new: &StageEntry, job: &BuildJob) -> Vec<String> {
    const MOST: usize = 32;
    let (cur_id, cur) = current;
    let (new_id, params) = new;
    let mut out = Vec::new();
    if cur_id != new_id {
        out.push(format!("plugin: {cur_id} -> {new_id}"));
    }
    if job.lib.is_some() {
        let text = job.params.as_deref().unwrap_or("");
        out.extend(
            text.lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with('#'))
                .take(MOST)
                .map(str::to_string),
        );
        return out;
    }
    for (k, v) in params {
        match cur.get(k).filter(|_| cur_id == new_id) {
            Some(old) if old == v => {}
            Some(old) => out.push(format!("{k}: {old} -> {v}")),
            None => out.push(format!("{k} = {v}")),
        }
        if out.len() >= MOST {
            break;
        }
    }
    out
}

fn build_one(
    job: &BuildJob,
    registry: &dyn PluginRegistry,
    contexts: &[AxisContext],
    current: &[[(String, toml::Table); 4]],
    job_path: &Path,
) -> Result<(Box<dyn Controller>, StageEntry), SwapError> {
    if let Some(lib) = &job.lib {
        let c = crate::scheduler::plugin_lib::LibController::load(
            Path::new(lib),
            &job.plugin,
            job.params.as_deref().unwrap_or(""),
            &contexts[job.axis],
        )?;
        if let Some(fits) = c.stages() {
            if !fits.contains(&job.stage) {
                return Err(SwapError::WrongStage(crate::scheduler::chain::wrong_stage(
                    &job.plugin,
                    job.stage,
                    &fits,
                )));
            }
        }
        // A library's parameters are its own text: a later built-in retune starts afresh.
        return Ok((
            Box::new(c),
            (format!("{}@{lib}", job.plugin), toml::Table::new()),
        ));
    }
    let fits = registry.stages(&job.plugin);
    if !fits.is_empty() && !fits.contains(&job.stage) {
        return Err(SwapError::WrongStage(crate::scheduler::chain::wrong_stage(
            &job.plugin,
            job.stage,
            &fits,
        )));
    }
    let src = Path::new(job.params_file.as_deref().unwrap_or("<swap --params>"));
    let (cur_id, cur_params) = &current[job.axis][job.stage.index()];
    let mut params = if *cur_id == job.plugin {
        cur_params.clone()
    } else {
        toml::Table::new()
    };
    if let Some(text) = &job.params {
        let t = feedloop_model::params::parse_toml(src, text)?;
        for (k, v) in t {
            params.insert(k, v);
        }
    }
    let c = registry.create(&job.plugin, &params, &contexts[job.axis], src)?;
    let _ = job_path;
    Ok((c, (job.plugin.clone(), params)))
}
