//! The controller chain of a job: per-axis stages, couplers, and the conversion between the
//! wire (load units) and the controllers (motor units).
//!
//! One call of [`Chain::step`] is one control cycle. It does not allocate, lock or log, and it
//! never lets a non-finite torque through: a stage that produces NaN/inf yields zero torque
//! for that cycle and the fault is counted.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use crate::shared::wire::{ActuatorCommand, SensorSample};
use feedloop_control::controller::{
    AxisContext, AxisSignals, Controller, ControllerState, Coupler, CycleContext, PluginRegistry,
    Stage,
};
use feedloop_model::job::Job;
use feedloop_model::params::ConfigError;
use feedloop_motion::RefState;

/// The stages of one axis.
pub struct AxisChain {
    /// Axis context (name, plant, defaults).
    pub context: AxisContext,
    /// Units conversion: motor units per load unit.
    pub motor_per_load: f64,
    /// One optional controller per stage, indexed by `Stage::index()`.
    pub stages: [Option<Box<dyn Controller>>; 4],
}

impl AxisChain {
    /// The axis context with the position and velocity gains the chain's stages report
    /// ([`Controller::loop_gains`]) in place of the model's defaults where they give one.
    fn running_context(&self) -> AxisContext {
        let mut ctx = self.context.clone();
        let gains = |stage: Stage| {
            self.stages[stage.index()]
                .as_ref()
                .map(|c| c.loop_gains())
                .unwrap_or_default()
        };
        let (position, velocity) = (gains(Stage::Position), gains(Stage::Velocity));
        let d = &mut ctx.defaults;
        d.kp_per_s = position.kp_per_s.or(d.kp_per_s);
        d.kv = velocity.kv.or(d.kv);
        d.tv_s = velocity.tv_s.or(d.tv_s);
        ctx
    }
}

/// All axes' chains plus couplers.
pub struct Chain {
    axes: Vec<AxisChain>,
    couplers: Vec<Box<dyn Coupler>>,
    signals: Vec<AxisSignals>,
    /// Outputs `(vel_cmd, torque_ff)` of each axis' reference-only stages (feedforward,
    /// compensator; [`Controller::reference_only`]) for cycle `prepared_for`, run ahead by
    /// [`Chain::prepare`].
    prepared: Vec<[Option<(f64, f64)>; 2]>,
    /// Those stages' states before they ran ahead: a preparation for a cycle that does not come
    /// (a skipped sample) is undone, so that every stage steps once per answered cycle.
    before_ahead: Vec<[ControllerState; 2]>,
    prepared_for: Option<u64>,
    /// The next cycle's references (motor units) for the couplers' [`Coupler::prepare`].
    ahead: Vec<AxisSignals>,
    /// Cycles in which some axis produced a non-finite torque (forced to zero).
    pub nonfinite_faults: u64,
    /// Plugin steps that panicked (caught at the plugin boundary; the scheduler then asks the
    /// plant for a safe stop).
    pub plugin_panics: u64,
}

/// Stages filled when a job gives none for an axis.
pub const DEFAULT_CHAIN: [(Stage, &str); 2] = [
    (Stage::Position, "position_p"),
    (Stage::Velocity, "pi_velocity"),
];

/// Why plugin `id` cannot fill `stage`, naming the stages it can fill.
pub fn wrong_stage(id: &str, stage: Stage, fits: &[Stage]) -> String {
    let names: Vec<&str> = fits.iter().map(|s| s.id()).collect();
    format!(
        "plugin `{id}` cannot fill the {} stage (it fills: {}); a stage's plugin must compute \
         that stage's signal",
        stage.id(),
        names.join(", ")
    )
}

impl Chain {
    /// Builds the chain of `job` from `registry` (validates every plugin's parameters).
    pub fn build(job: &Job, registry: &dyn PluginRegistry) -> Result<Self, ConfigError> {
        let contexts: Vec<AxisContext> = job
            .axes
            .iter()
            .map(|a| AxisContext {
                name: a.name.clone(),
                plant: a.model.plant,
                defaults: a.model.controller,
                period_s: job.period_s,
            })
            .collect();
        let mut axes = Vec::with_capacity(job.axes.len());
        for (i, ctx) in contexts.iter().enumerate() {
            let mut stages: [Option<Box<dyn Controller>>; 4] = [None, None, None, None];
            let explicit: Vec<_> = job.chain.iter().filter(|c| c.axis == i).collect();
            for e in &explicit {
                let fits = registry.stages(&e.plugin);
                if !fits.is_empty() && !fits.contains(&e.stage) {
                    return Err(ConfigError::new(
                        &job.path,
                        format!("{}.stage", e.key),
                        wrong_stage(&e.plugin, e.stage, &fits),
                    ));
                }
                let c = registry
                    .create(&e.plugin, &e.params, ctx, &job.path)
                    .map_err(|err| prefix_key(err, &e.key))?;
                stages[e.stage.index()] = Some(c);
            }
            if explicit.is_empty() {
                for (stage, id) in DEFAULT_CHAIN {
                    let c = registry
                        .create(id, &toml::Table::new(), ctx, &job.path)
                        .map_err(|err| {
                            ConfigError::new(
                                &job.path,
                                format!("axes.{}", ctx.name),
                                format!(
                                    "the default `{id}` stage cannot be built from the model's [controller] ({}): {}",
                                    err.file.display(),
                                    err.reason
                                ),
                            )
                        })?;
                    stages[stage.index()] = Some(c);
                }
            }
            if stages[Stage::Velocity.index()].is_none() {
                return Err(ConfigError::new(
                    &job.path,
                    "chain",
                    format!(
                        "axis `{}` has no velocity stage: nothing would produce its torque",
                        ctx.name
                    ),
                ));
            }
            axes.push(AxisChain {
                motor_per_load: ctx.plant.motor_per_load(),
                context: ctx.clone(),
                stages,
            });
        }
        // couplers see the gains each axis' chain runs with (a chain's params override the
        // model's `[controller]`), e.g. to keep their own loop below the velocity loop
        let coupler_contexts: Vec<AxisContext> =
            axes.iter().map(AxisChain::running_context).collect();
        let mut couplers = Vec::new();
        for c in &job.couplers {
            couplers.push(
                registry
                    .create_coupler(&c.plugin, &c.params, &coupler_contexts, &c.axes, &job.path)
                    .map_err(|err| prefix_key(err, &c.key))?,
            );
        }
        let n = axes.len();
        Ok(Self {
            axes,
            couplers,
            signals: vec![AxisSignals::default(); n],
            prepared: vec![[None; 2]; n],
            before_ahead: vec![[ControllerState::EMPTY; 2]; n],
            prepared_for: None,
            ahead: vec![AxisSignals::default(); n],
            nonfinite_faults: 0,
            plugin_panics: 0,
        })
    }

    /// Number of axes.
    pub fn axis_count(&self) -> usize {
        self.axes.len()
    }

    /// The axes' chains.
    pub fn axes(&self) -> &[AxisChain] {
        &self.axes
    }

    /// Signals of the last cycle (motor units).
    pub fn signals(&self) -> &[AxisSignals] {
        &self.signals
    }

    /// The internal state of every stage of `axis` (empty for an empty stage). No allocation.
    pub fn snapshot_axis(&self, axis: usize) -> [ControllerState; 4] {
        let mut out = [ControllerState::EMPTY; 4];
        for (o, st) in out.iter_mut().zip(&self.axes[axis].stages) {
            if let Some(c) = st {
                *o = c.snapshot();
            }
        }
        out
    }

    /// Undoes a cycle of `axis` that must not count: every stage back to `states` (from
    /// [`Chain::snapshot_axis`] before the cycle) and the torque of its signals set to `torque`,
    /// the one actually sent. No allocation.
    pub fn undo_cycle(&mut self, axis: usize, states: &[ControllerState; 4], torque: f64) {
        for (st, s) in self.axes[axis].stages.iter_mut().zip(states) {
            if let Some(c) = st {
                c.restore(s);
            }
        }
        self.signals[axis].torque = torque;
    }

    /// Replaces the controller of `axis`/`stage`, initialised from the last cycle's signals;
    /// returns the previous one.
    pub fn replace(
        &mut self,
        axis: usize,
        stage: Stage,
        mut new: Box<dyn Controller>,
    ) -> Option<Box<dyn Controller>> {
        new.initialize_from(&self.signals[axis]);
        // what the old controller prepared for the next cycle is not the new one's
        if let Some(p) = PREPARED_STAGES.iter().position(|s| *s == stage) {
            self.prepared[axis][p] = None;
        }
        self.axes[axis].stages[stage.index()].replace(new)
    }

    /// Runs the reference-only stages ([`Controller::reference_only`]) of every axis, and the
    /// couplers' [`Coupler::prepare`], for the cycle of `ctx` with its references `refs` (load
    /// units, job order), ahead of its sample: a scheduler calls it in the slack after
    /// answering the previous cycle. [`Chain::step`]
    /// of that cycle then adds their outputs instead of running them; it runs them itself when
    /// nothing was prepared for its cycle, in the same way, so the command is the same.
    pub fn prepare(&mut self, ctx: &CycleContext, refs: &[RefState]) {
        for ((axis, a), r) in self.axes.iter().zip(self.ahead.iter_mut()).zip(refs) {
            for (d, v) in a.reference.iter_mut().zip(r.iter()) {
                *d = v * axis.motor_per_load;
            }
        }
        for c in &mut self.couplers {
            let ahead = &self.ahead;
            if catch_unwind(AssertUnwindSafe(|| c.prepare(ctx, ahead))).is_err() {
                self.plugin_panics += 1;
            }
        }
        for (i, axis) in self.axes.iter_mut().enumerate() {
            for (p, stage) in PREPARED_STAGES.iter().enumerate() {
                let earlier = self.prepared[i][p].take();
                self.prepared[i][p] = match &mut axis.stages[stage.index()] {
                    Some(c) if c.reference_only() => {
                        // a preparation no step used is undone first
                        if earlier.is_some() {
                            c.restore(&self.before_ahead[i][p]);
                        }
                        self.before_ahead[i][p] = c.snapshot();
                        let (out, panicked) =
                            run_ahead(c.as_mut(), ctx, &refs[i], axis.motor_per_load);
                        self.plugin_panics += u64::from(panicked);
                        Some(out)
                    }
                    _ => None,
                };
            }
        }
        self.prepared_for = Some(ctx.cycle);
    }

    /// One control cycle: `refs` are the references of every axis in load units (job order),
    /// `sample` the plant's measurement; writes torques and references into `cmd`.
    pub fn step(
        &mut self,
        ctx: &CycleContext,
        refs: &[RefState],
        sample: &SensorSample,
        cmd: &mut ActuatorCommand,
    ) {
        let ready = self.prepared_for == Some(ctx.cycle);
        self.prepared_for = None;
        for (i, (axis, sig)) in self
            .axes
            .iter_mut()
            .zip(self.signals.iter_mut())
            .enumerate()
        {
            let k = axis.motor_per_load;
            let s = &sample.axes[i];
            let r = &refs[i];
            for (d, v) in sig.reference.iter_mut().zip(r.iter()) {
                *d = v * k;
            }
            sig.load_pos = s.load_pos * k;
            sig.motor_pos = s.motor_pos;
            sig.motor_vel = s.motor_vel;
            sig.vel_cmd = 0.0;
            sig.torque_ff = 0.0;
            sig.torque = 0.0;
            if let Some(c) = &mut axis.stages[Stage::Position.index()] {
                if catch_unwind(AssertUnwindSafe(|| c.step(ctx, sig))).is_err() {
                    self.plugin_panics += 1;
                }
            }
            for (p, stage) in PREPARED_STAGES.iter().enumerate() {
                let Some(c) = &mut axis.stages[stage.index()] else {
                    continue;
                };
                if !c.reference_only() {
                    if catch_unwind(AssertUnwindSafe(|| c.step(ctx, sig))).is_err() {
                        self.plugin_panics += 1;
                    }
                    continue;
                }
                // run ahead in the slack, or now in the same way (the same outputs); a stage
                // that ran ahead for another cycle goes back to its state before
                let (v, t) = match self.prepared[i][p].take() {
                    Some(out) if ready => out,
                    stale => {
                        if stale.is_some() {
                            c.restore(&self.before_ahead[i][p]);
                        }
                        let (out, panicked) = run_ahead(c.as_mut(), ctx, r, k);
                        self.plugin_panics += u64::from(panicked);
                        out
                    }
                };
                sig.vel_cmd += v;
                sig.torque_ff += t;
            }
        }
        for c in &mut self.couplers {
            let signals = &mut self.signals;
            if catch_unwind(AssertUnwindSafe(|| c.step(ctx, signals))).is_err() {
                self.plugin_panics += 1;
            }
        }
        let mut fault = false;
        for (i, (axis, sig)) in self
            .axes
            .iter_mut()
            .zip(self.signals.iter_mut())
            .enumerate()
        {
            if let Some(c) = &mut axis.stages[Stage::Velocity.index()] {
                if catch_unwind(AssertUnwindSafe(|| c.step(ctx, sig))).is_err() {
                    self.plugin_panics += 1;
                    sig.torque = 0.0;
                }
            }
            if !sig.torque.is_finite() {
                sig.torque = 0.0;
                fault = true;
            }
            // Last line of defence: never command more than the axis' torque limit.
            if let Some(lim) = axis.context.defaults.torque_limit {
                sig.torque = sig.torque.clamp(-lim, lim);
            }
            cmd.axes[i].torque = sig.torque;
            cmd.axes[i].reference = refs[i][0];
        }
        if fault {
            self.nonfinite_faults += 1;
        }
        cmd.axis_count = self.axes.len() as u32;
        cmd.seq = sample.seq;
    }
}

/// The stages a reference-only controller may fill, in chain order.
const PREPARED_STAGES: [Stage; 2] = [Stage::Feedforward, Stage::Compensator];

/// One step of a reference-only stage on the references `r` (load units; `k` motor units per
/// load unit) from zero outputs: its `(vel_cmd, torque_ff)`, and whether it panicked (then
/// zero).
fn run_ahead(
    c: &mut dyn Controller,
    ctx: &CycleContext,
    r: &RefState,
    k: f64,
) -> ((f64, f64), bool) {
    let mut sig = AxisSignals::default();
    for (d, v) in sig.reference.iter_mut().zip(r.iter()) {
        *d = v * k;
    }
    match catch_unwind(AssertUnwindSafe(|| c.step(ctx, &mut sig))) {
        Ok(()) => ((sig.vel_cmd, sig.torque_ff), false),
        Err(_) => ((0.0, 0.0), true),
    }
}

fn prefix_key(mut e: ConfigError, key: &str) -> ConfigError {
    if e.file.as_os_str().is_empty() || e.file == Path::new("") {
        e.key = format!("{key}.params.{}", e.key);
    } else {
        e.key = if e.key.is_empty() {
            key.to_string()
        } else {
            format!("{key}.params.{}", e.key)
        };
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shared::wire::{ActuatorCommand, SensorSample};
    use feedloop_control::controller::{AxisSignals, ControllerState};

    /// Produces `value` as torque, or panics when `value` is NaN.
    struct Fixed(f64);

    impl Controller for Fixed {
        fn id(&self) -> &str {
            "fixed"
        }
        fn step(&mut self, _ctx: &CycleContext, io: &mut AxisSignals) {
            if self.0.is_nan() {
                panic!("plugin bug");
            }
            io.torque = self.0;
        }
        fn snapshot(&self) -> ControllerState {
            ControllerState::EMPTY
        }
        fn restore(&mut self, _s: &ControllerState) {}
    }

    struct Reg(f64);

    impl PluginRegistry for Reg {
        fn ids(&self) -> Vec<(&'static str, Stage)> {
            vec![("fixed", Stage::Velocity)]
        }
        fn create(
            &self,
            _id: &str,
            _params: &toml::Table,
            _axis: &AxisContext,
            _file: &Path,
        ) -> Result<Box<dyn Controller>, ConfigError> {
            Ok(Box::new(Fixed(self.0)))
        }
    }

    fn chain(torque: f64) -> Chain {
        let dir =
            std::env::temp_dir().join(format!("feedloop-chain-{}-{torque}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("m.toml"),
            "kind = \"rigid\"\nmass_kg = 10\n[controller]\nforce_limit_n = 100\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("j.toml"),
            "period_s = 0.001\n[axes.x]\nmodel = \"m.toml\"\n[[chain]]\naxis = \"x\"\nstage = \"velocity\"\nplugin = \"fixed\"\n[trajectory]\nkind = \"dwell\"\n",
        )
        .unwrap();
        let job = Job::load(&dir.join("j.toml")).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        Chain::build(&job, &Reg(torque)).unwrap()
    }

    fn step(c: &mut Chain) -> f64 {
        let ctx = CycleContext {
            period_s: 0.001,
            cycle: 0,
            t_s: 0.0,
        };
        let sample = SensorSample::empty(1, 0);
        let mut cmd = ActuatorCommand::empty(1, 0);
        c.step(&ctx, &[[0.0; 6]], &sample, &mut cmd);
        cmd.axes[0].torque
    }

    #[test]
    fn a_panicking_plugin_is_contained_and_yields_zero_torque() {
        let prev = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let mut c = chain(f64::NAN);
        let t = step(&mut c);
        std::panic::set_hook(prev);
        assert_eq!(t, 0.0);
        assert_eq!(c.plugin_panics, 1);
    }

    #[test]
    fn torque_beyond_the_axis_limit_never_reaches_the_wire() {
        let mut c = chain(1.0e6);
        assert_eq!(step(&mut c), 100.0);
        let mut c = chain(-1.0e6);
        assert_eq!(step(&mut c), -100.0);
    }

    #[test]
    fn infinite_torque_is_forced_to_zero_and_counted() {
        let mut c = chain(f64::INFINITY);
        assert_eq!(step(&mut c), 0.0);
        assert_eq!(c.nonfinite_faults, 1);
    }
}
