//! The controller plugin trait and the signals one axis passes along its chain each cycle.
//!
//! A chain per axis runs its stages in a fixed order: `position` -> `feedforward` ->
//! `compensator` -> (couplers across axes) -> `velocity`. Each stage reads what it needs from
//! [`AxisSignals`] and adds to or overwrites the signals it owns. All quantities are in motor
//! units: rad, rad/s, N m for a rotary motor; m, m/s, N for a linear motor.

use std::path::Path;

use feedloop_model::model::{ControllerParams, PlantParams};
use feedloop_model::params::ConfigError;
pub use feedloop_model::Stage;

/// Number of reference derivatives carried (position and its 1st..5th time derivatives).
pub const REF_DERIVS: usize = 6;

/// Signals of one axis in one cycle. `#[repr(C)]`: shared-library plugins receive a pointer to it
/// (see [`crate::abi`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[repr(C)]
pub struct AxisSignals {
    /// Commanded position and its time derivatives 1..5 (motor units per s^n).
    pub reference: [f64; REF_DERIVS],
    /// Measured load position converted to motor units (seed 000: thL).
    pub load_pos: f64,
    /// Measured motor position (motor units).
    pub motor_pos: f64,
    /// Measured motor velocity (motor units per s).
    pub motor_vel: f64,
    /// Velocity command for the velocity loop (position stage output + feedforward), motor units/s.
    pub vel_cmd: f64,
    /// Torque feed-forward added to the velocity loop's output, N m (N).
    pub torque_ff: f64,
    /// Final torque (force) command for this cycle, N m (N).
    pub torque: f64,
}

/// Timing of the current cycle. `#[repr(C)]`: passed to shared-library plugins.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct CycleContext {
    /// Control period, s.
    pub period_s: f64,
    /// Cycle number, 0-based.
    pub cycle: u64,
    /// Time of the sample, s (= cycle * period).
    pub t_s: f64,
}

/// Maximum number of state values a controller can snapshot.
pub const STATE_CAPACITY: usize = 16;

/// A fixed-size snapshot of a controller's internal state (integrators, filter memories).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControllerState {
    /// Number of valid entries.
    pub len: usize,
    /// Values; meaning is defined by the plugin.
    pub values: [f64; STATE_CAPACITY],
}

impl ControllerState {
    /// An empty snapshot.
    pub const EMPTY: ControllerState = ControllerState {
        len: 0,
        values: [0.0; STATE_CAPACITY],
    };

    /// A snapshot of `values` (at most `STATE_CAPACITY`; extra values are dropped).
    pub fn from_slice(values: &[f64]) -> Self {
        let mut s = Self::EMPTY;
        let n = values.len().min(STATE_CAPACITY);
        s.values[..n].copy_from_slice(&values[..n]);
        s.len = n;
        s
    }

    /// The valid values.
    pub fn as_slice(&self) -> &[f64] {
        &self.values[..self.len]
    }
}

/// What a plugin is told about the axis it will control.
#[derive(Debug, Clone)]
pub struct AxisContext {
    /// Axis name in the job.
    pub name: String,
    /// Plant base parameters of the axis' model.
    pub plant: PlantParams,
    /// Controller defaults from the model file (job parameters override them).
    pub defaults: ControllerParams,
    /// Control period, s.
    pub period_s: f64,
}

/// A control law for one stage of one axis.
///
/// Implementations must not allocate, lock, log or panic in [`Controller::step`].
pub trait Controller: Send {
    /// The plugin id (e.g. `pi_velocity`).
    fn id(&self) -> &str;
    /// Runs one cycle: reads and updates `io`.
    fn step(&mut self, ctx: &CycleContext, io: &mut AxisSignals);
    /// Snapshot of the internal state (for replay and swaps).
    fn snapshot(&self) -> ControllerState;
    /// Restores a snapshot taken from a controller of the same id.
    fn restore(&mut self, state: &ControllerState);
    /// Initialises internal state so that, given the signals of the last cycle (`last`, whose
    /// outputs were produced by the previous controller of this stage), the next output continues
    /// without a step (bumpless switching). The default does nothing.
    fn initialize_from(&mut self, _last: &AxisSignals) {}
    /// The controller's main gain, used to scale the bumpless bound of a swap (e.g. Kv of a
    /// velocity loop). `None` when the notion does not apply.
    fn gain(&self) -> Option<f64> {
        None
    }
}

/// A multi-axis law that runs after the pre-velocity stages of all axes (e.g. a contour coupler).
pub trait Coupler: Send {
    /// The plugin id.
    fn id(&self) -> &str;
    /// Indices (job axis order) of the axes it couples.
    fn axes(&self) -> &[usize];
    /// Runs one cycle over all axes' signals.
    fn step(&mut self, ctx: &CycleContext, axes: &mut [AxisSignals]);
}

/// Creates controllers by plugin id. The built-in registry lives in the `plugins` crate and is
/// handed to the scheduler by the binary (so `runtime` does not depend on `plugins`).
pub trait PluginRegistry: Send + Sync {
    /// Ids of the available per-axis plugins and the stage each belongs to by default.
    fn ids(&self) -> Vec<(&'static str, Stage)>;
    /// Builds plugin `id` for `axis` from `params` (keys of the plugin; keys left out default
    /// to the axis model's `[controller]` values). `file` names where the params came from.
    fn create(
        &self,
        id: &str,
        params: &toml::Table,
        axis: &AxisContext,
        file: &Path,
    ) -> Result<Box<dyn Controller>, ConfigError>;
    /// Builds coupler `id` over the axes `axes` (indices into `contexts`, job order).
    fn create_coupler(
        &self,
        id: &str,
        _params: &toml::Table,
        _contexts: &[AxisContext],
        _axes: &[usize],
        file: &Path,
    ) -> Result<Box<dyn Coupler>, ConfigError> {
        Err(ConfigError::new(
            file,
            "plugin",
            format!("unknown coupler plugin `{id}`"),
        ))
    }
}
