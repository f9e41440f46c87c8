//! Plant physics of feedloop: the feed-drive axes the simulator process stands in for.
//!
//! A [`Plant`] holds every axis of a job; each [`AxisPlant`] is one of three kinds (see
//! `feedloop_model::model`):
//!
//! - `ballscrew`: 2-mass model on the motor side (rad):
//!   `JM thM'' = T - DM wM - KL (thM - thL) - CL (wM - wL)`,
//!   `JL thL'' = KL (thM - thL) + CL (wM - wL) - DL wL`; the table position is
//!   `thL lead_m / (2 pi gear_ratio)` m.
//! - `rotary`: the same 2-mass model with the load in rad.
//! - `rigid`: `m x'' = F - c x'` (m, N).
//!
//! The linear part is discretised exactly for a held (zero-order-hold) torque with the matrix
//! exponential, computed once when the axis is built, so a stiff mode of a few kHz stays exact
//! at 1 kHz or 10 kHz. Physical effects ([`effects`], switched on by `[effects.<id>]` tables)
//! and the sensor model (`[sensor]`, see [`sensor`]) are validated with
//! `feedloop_model::params::Fields`: errors name the model file and the dotted key.
//!
//! [`Plant::sense`] and [`Plant::step`] are the hot path: no allocation, no lock, no logging and
//! no panic for any input; the same inputs give bit-identical outputs (the sensor noise comes
//! from a seeded generator per axis).
#![warn(missing_docs)]

mod axis;
pub mod effects;
mod linear;
pub mod sensor;

use feedloop_control::axis_io::{AxisCommand, AxisSensor};
use feedloop_control::device::PlantDevice;
use feedloop_model::job::Job;
use feedloop_model::model::ModelFile;
use feedloop_model::params::ConfigError;
use feedloop_model::MAX_AXES;

pub use axis::{AxisPlant, TORQUE_BOUND};
pub use feedloop_model::{EffectId, Side};

/// All axes of a job, stepped together.
#[derive(Debug, Clone)]
pub struct Plant {
    axes: Vec<AxisPlant>,
    period_s: f64,
}

impl Plant {
    /// Builds every axis of `job` from its model file, at the job's period.
    pub fn new(job: &Job) -> Result<Plant, ConfigError> {
        let models: Vec<&ModelFile> = job.axes.iter().map(|a| &a.model).collect();
        Self::from_models(&models, job.period_s)
    }

    /// Builds one axis per model, in order, for a control period `period_s` (s).
    pub fn from_models(models: &[&ModelFile], period_s: f64) -> Result<Plant, ConfigError> {
        if models.len() > MAX_AXES {
            return Err(ConfigError::new(
                &models[MAX_AXES].path,
                "",
                format!(
                    "a plant drives at most {MAX_AXES} axes, got {}",
                    models.len()
                ),
            ));
        }
        let axes = models
            .iter()
            .enumerate()
            .map(|(i, m)| AxisPlant::new_indexed(m, period_s, i))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Plant { axes, period_s })
    }

    /// Number of axes.
    pub fn axis_count(&self) -> usize {
        self.axes.len()
    }

    /// Control period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Axis `i` (job order), if it exists.
    pub fn axis(&self, i: usize) -> Option<&AxisPlant> {
        self.axes.get(i)
    }

    /// Axis `i` for changes (e.g. its initial position), if it exists.
    pub fn axis_mut(&mut self, i: usize) -> Option<&mut AxisPlant> {
        self.axes.get_mut(i)
    }

    /// All axes in job order.
    pub fn axes(&self) -> &[AxisPlant] {
        &self.axes
    }

    /// Puts every axis at rest at these load positions (m for ballscrew/rigid, rad for rotary),
    /// springs relaxed. Axes beyond `load_pos.len()` are put at 0.
    pub fn set_initial_positions(&mut self, load_pos: &[f64]) {
        for (i, a) in self.axes.iter_mut().enumerate() {
            a.set_initial_position(load_pos.get(i).copied().unwrap_or(0.0));
        }
    }

    /// Writes the measurement at the current time (sensor model applied) into
    /// `out[..axis_count]`: motor_pos, motor_vel, load_pos, and the torque applied during
    /// the previous period. Other fields of `out` are left as they are.
    #[inline]
    pub fn sense(&mut self, out: &mut [AxisSensor]) {
        for (o, a) in out.iter_mut().zip(&self.axes) {
            *o = a.sense_axis();
        }
    }

    /// Advances one period with each axis' commanded torque `cmd[i].torque` (N m, or N on a
    /// rigid axis) held constant. Non-finite torques count as 0.
    #[inline]
    pub fn step(&mut self, cmd: &[AxisCommand]) {
        for (a, c) in self.axes.iter_mut().zip(cmd) {
            a.step_axis(c.torque);
        }
    }
}

/// The simulated plant is what the plant process drives when no hardware is attached.
impl PlantDevice for Plant {
    fn axis_count(&self) -> usize {
        Plant::axis_count(self)
    }
    fn sense(&mut self, out: &mut [AxisSensor]) {
        Plant::sense(self, out)
    }
    fn step(&mut self, cmd: &[AxisCommand]) {
        Plant::step(self, cmd)
    }
}
