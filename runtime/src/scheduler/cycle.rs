//! One control cycle of a job: trajectory -> references -> controller chain -> command.
//!
//! [`ControlCycle`] is what the scheduler process runs per sample and what the in-process
//! simulation runs per step: the same code in both, which is what makes a lockstep run and a
//! simulation of the same job produce bit-identical traces.

use crate::scheduler::chain::Chain;
use crate::shared::wire::{ActuatorCommand, SensorSample};
use feedloop_control::controller::{CycleContext, PluginRegistry, REF_DERIVS};
use feedloop_model::job::Job;
use feedloop_model::params::ConfigError;
use feedloop_motion::{RefState, Trajectory};

/// Trajectory + chain of one job, with all buffers allocated up front.
pub struct ControlCycle {
    trajectory: Box<dyn Trajectory>,
    chain: Chain,
    map: Vec<Option<usize>>,
    traj_out: Vec<RefState>,
    refs: Vec<RefState>,
    /// The cycle whose references `refs` hold (see [`ControlCycle::prepare`]).
    refs_for: Option<u64>,
    period_s: f64,
    cycles: u64,
    identity: bool,
}

impl ControlCycle {
    /// Builds the trajectory and the chain of `job`.
    pub fn new(job: &Job, registry: &dyn PluginRegistry) -> Result<Self, ConfigError> {
        let names = job.axis_names();
        let trajectory = feedloop_motion::build(&job.trajectory, &job.path, &names, job.period_s)?;
        let map = names
            .iter()
            .map(|n| trajectory.axes().iter().position(|a| a == n))
            .collect::<Vec<_>>();
        let chain = Chain::build(job, registry)?;
        let duration = job.duration_s.unwrap_or_else(|| trajectory.duration_s());
        if !(duration.is_finite() && duration > 0.0) {
            return Err(ConfigError::new(
                &job.path,
                "duration_s",
                format!("the run length must be > 0 s (trajectory gives {duration})"),
            ));
        }
        let cycles = job.cycles_for(duration);
        let identity = map.iter().enumerate().all(|(i, m)| *m == Some(i))
            && trajectory.axes().len() == names.len();
        let mut me = Self {
            identity,
            traj_out: vec![[0.0; REF_DERIVS]; trajectory.axes().len()],
            refs: vec![[0.0; REF_DERIVS]; names.len()],
            refs_for: None,
            trajectory,
            chain,
            map,
            period_s: job.period_s,
            cycles,
        };
        me.eval(0.0);
        Ok(me)
    }

    /// Number of cycles of the run (round(duration / period)).
    pub fn cycles(&self) -> u64 {
        self.cycles
    }

    /// Overrides the number of cycles (e.g. for benchmarks); the trajectory holds its end state.
    pub fn set_cycles(&mut self, cycles: u64) {
        self.cycles = cycles.max(1);
    }

    /// Control period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// The trajectory.
    pub fn trajectory(&self) -> &dyn Trajectory {
        self.trajectory.as_ref()
    }

    /// The chain (for swaps and inspection).
    pub fn chain_mut(&mut self) -> &mut Chain {
        &mut self.chain
    }

    /// The chain.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// Load positions of every axis at t = 0 (where the plant should start at rest).
    pub fn initial_positions(&self) -> Vec<f64> {
        let mut out = vec![[0.0; REF_DERIVS]; self.traj_out.len()];
        self.trajectory.eval(0.0, &mut out);
        self.map
            .iter()
            .map(|m| m.map(|i| out[i][0]).unwrap_or(0.0))
            .collect()
    }

    /// Time of cycle `seq`, s.
    #[inline]
    pub fn time_of(&self, seq: u64) -> f64 {
        seq as f64 * self.period_s
    }

    fn eval(&mut self, t: f64) {
        if self.identity {
            // The trajectory drives every job axis in job order (all built-in kinds do).
            self.trajectory.eval(t, &mut self.refs);
            return;
        }
        self.trajectory.eval(t, &mut self.traj_out);
        for (r, m) in self.refs.iter_mut().zip(&self.map) {
            *r = match m {
                Some(i) => self.traj_out[*i],
                None => [0.0; REF_DERIVS],
            };
        }
    }

    /// Evaluates the references of cycle `seq` ahead of its sample, and runs the chain's
    /// reference-only stages on them ([`Chain::prepare`]): the trajectory depends on time only,
    /// so a scheduler can do this in the slack after answering a cycle and take it off the next
    /// round trip. [`ControlCycle::step`] uses them if its sample is cycle `seq` (and evaluates
    /// them itself otherwise): the command is the same either way.
    #[inline]
    pub fn prepare(&mut self, seq: u64) {
        let t = self.time_of(seq);
        self.eval(t);
        self.refs_for = Some(seq);
        let ctx = CycleContext {
            period_s: self.period_s,
            cycle: seq,
            t_s: t,
        };
        self.chain.prepare(&ctx, &self.refs);
    }

    /// Runs the cycle answering `sample`: writes the command (torques, references, seq).
    #[inline]
    pub fn step(&mut self, sample: &SensorSample, cmd: &mut ActuatorCommand) {
        let t = self.time_of(sample.seq);
        if self.refs_for != Some(sample.seq) {
            self.eval(t);
        }
        self.refs_for = None;
        let ctx = CycleContext {
            period_s: self.period_s,
            cycle: sample.seq,
            t_s: t,
        };
        self.chain.step(&ctx, &self.refs, sample, cmd);
    }
}
