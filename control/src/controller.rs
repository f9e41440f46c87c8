//! The controller plugin trait and the signals one axis passes along its chain each cycle.
//!
//! A chain per axis runs its stages in a fixed order: `position` -> `feedforward` ->
//! `compensator` -> (couplers across axes) -> `velocity`. Each stage reads what it needs from
//! [`AxisSignals`] and adds to or overwrites the signals it owns. All quantities are in motor
//! units: rad, rad/s, N m for a rotary motor; m, m/s, N for a linear motor.

use std::path::Path;

use feedloop_model::model::{ControllerParams, PlantParams};
use feedloop_model::params::{ConfigError, ConfigErrorKind};
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

    /// Value `i` for a restore: 0 where the snapshot is shorter or the value is not finite.
    pub fn finite_or_zero(&self, i: usize) -> f64 {
        self.as_slice()
            .get(i)
            .copied()
            .filter(|x| x.is_finite())
            .unwrap_or(0.0)
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

impl AxisContext {
    /// The value of a plugin parameter `key`: `given` in the plugin's params, else the model's
    /// `[controller]` default `model_default`; neither is an error naming `key` in `file` that
    /// says where it may be given.
    pub fn param_or_model(
        &self,
        given: Option<f64>,
        model_default: Option<f64>,
        key: &str,
        file: &Path,
    ) -> Result<f64, ConfigError> {
        given.or(model_default).ok_or_else(|| {
            ConfigError::of_kind(
                ConfigErrorKind::Missing,
                file,
                key,
                format!(
                    "is required: give it in the plugin params or in the [controller] table of axis `{}`'s model",
                    self.name
                ),
            )
        })
    }
}

/// A control law for one stage of one axis.
///
/// Implementations must not allocate, lock, log or panic in [`Controller::step`].
pub trait Controller: Send {
    /// The plugin id (e.g. `pi_velocity`).
    fn id(&self) -> &str;
    /// Runs one cycle: reads and updates `io`.
    fn step(&mut self, ctx: &CycleContext, io: &mut AxisSignals);
    /// Snapshot of the internal state (for replay and swaps). The default, for a stateless
    /// law, is an empty snapshot.
    fn snapshot(&self) -> ControllerState {
        ControllerState::EMPTY
    }
    /// Restores a snapshot taken from a controller of the same id (values that are missing or
    /// not finite read as 0: [`ControllerState::finite_or_zero`]). The default, for a stateless
    /// law, does nothing.
    fn restore(&mut self, _state: &ControllerState) {}
    /// Initialises internal state so that, given the signals of the last cycle (`last`, whose
    /// outputs were produced by the previous controller of this stage), the next output continues
    /// without a step (bumpless switching). The default does nothing.
    fn initialize_from(&mut self, _last: &AxisSignals) {}
    /// The controller's main gain, used to scale the bumpless bound of a swap (e.g. Kv of a
    /// velocity loop). `None` when the notion does not apply.
    fn gain(&self) -> Option<f64> {
        None
    }
    /// The gains this controller puts into the loop model
    /// ([`crate::loop_model::margins`]), checked before a swap or a retune is applied. The
    /// default: none known (the margin check then cannot be made and the answer says so).
    fn loop_gains(&self) -> crate::loop_model::LoopGains {
        crate::loop_model::LoopGains::default()
    }
    /// Whether [`Controller::step`] reads nothing of `io` but `reference` (besides the cycle's
    /// context and its own state) and only adds to `vel_cmd` and `torque_ff`: a feedforward computed from the references alone. The chain may then run it ahead,
    /// in the slack before the cycle's sample arrives (the references depend on time only),
    /// starting from zero outputs, and add what it produced when the sample comes: off the
    /// round trip. Once per cycle all the same. The default: no.
    fn reference_only(&self) -> bool {
        false
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
    /// Ahead of cycle `ctx.cycle`, in the slack before its sample arrives: `axes` hold that
    /// cycle's references (`reference`, motor units; nothing else is set). A coupler may work
    /// out here what depends on the references alone and use it in [`Coupler::step`] of the same
    /// cycle, off the round trip. The step's outputs must be the same whether or not this ran
    /// (it does not run in every cycle). The default does nothing.
    fn prepare(&mut self, _ctx: &CycleContext, _axes: &[AxisSignals]) {}
}

/// Creates controllers by plugin id. The built-in registry lives in the `plugins` crate and is
/// handed to the scheduler by the binary (so `runtime` does not depend on `plugins`).
pub trait PluginRegistry: Send + Sync {
    /// Ids of the available per-axis plugins and the stage each belongs to by default.
    fn ids(&self) -> Vec<(&'static str, Stage)>;
    /// The stages plugin `id` can fill (empty for an unknown id). The default: the one stage
    /// [`PluginRegistry::ids`] gives it. A plugin in another stage would compute the wrong
    /// signal (a torque where a velocity command is expected), so jobs and swaps refuse it.
    fn stages(&self, id: &str) -> Vec<Stage> {
        self.ids()
            .into_iter()
            .filter(|(i, _)| *i == id)
            .map(|(_, s)| s)
            .collect()
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use feedloop_model::model::RigidParams;

    fn axis() -> AxisContext {
        AxisContext {
            name: "x".into(),
            plant: PlantParams::Rigid(RigidParams {
                mass_kg: 10.0,
                viscous_ns_per_m: 0.0,
            }),
            defaults: ControllerParams::default(),
            period_s: 1e-4,
        }
    }

    #[test]
    fn a_plugin_parameter_comes_from_the_params_then_the_model_else_a_missing_error() {
        let a = axis();
        let f = Path::new("job.toml");
        assert_eq!(
            a.param_or_model(Some(2.0), Some(3.0), "kp_per_s", f)
                .unwrap(),
            2.0
        );
        assert_eq!(
            a.param_or_model(None, Some(3.0), "kp_per_s", f).unwrap(),
            3.0
        );
        let e = a.param_or_model(None, None, "kp_per_s", f).unwrap_err();
        assert_eq!(e.kind, ConfigErrorKind::Missing);
        assert_eq!(e.key, "kp_per_s");
        assert!(
            e.to_string().contains("[controller] table of axis `x`"),
            "{e}"
        );
    }

    #[test]
    fn a_restore_reads_missing_or_non_finite_values_as_zero() {
        let s = ControllerState::from_slice(&[1.5, f64::NAN, f64::INFINITY]);
        assert_eq!(
            [0, 1, 2, 3, 99].map(|i| s.finite_or_zero(i)),
            [1.5, 0.0, 0.0, 0.0, 0.0]
        );
    }

    struct Stateless;
    impl Controller for Stateless {
        fn id(&self) -> &str {
            "stateless"
        }
        fn step(&mut self, _ctx: &CycleContext, io: &mut AxisSignals) {
            io.torque = 1.0;
        }
    }

    #[test]
    fn a_stateless_law_needs_no_snapshot_or_restore_of_its_own() {
        let mut c = Stateless;
        assert_eq!(c.snapshot(), ControllerState::EMPTY);
        c.restore(&ControllerState::from_slice(&[1.0]));
        assert_eq!(c.snapshot().as_slice(), &[] as &[f64]);
    }
}
