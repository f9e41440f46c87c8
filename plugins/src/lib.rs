//! Built-in controller plugins of feedloop and the registry that creates them by id.
//!
//! One file per control law; each opens with its equation, units and source seed.
#![warn(missing_docs)]

pub mod filters;
pub mod friction_feedforward;
pub mod inverse_feedforward;
pub mod nl_pid_coupler;
pub mod pi_velocity;
pub mod position_p;
pub mod quadrant;

#[cfg(test)]
pub(crate) mod test_util;

use std::path::Path;

use feedloop_control::controller::{AxisContext, Controller, Coupler, PluginRegistry, Stage};
use feedloop_model::params::ConfigError;

pub use friction_feedforward::FrictionFeedforward;
pub use inverse_feedforward::{InverseFeedforward, InverseFeedforwardParams};
pub use nl_pid_coupler::{NlPidCoupler, NlPidCouplerParams};
pub use pi_velocity::{PiVelocity, PiVelocityParams};
pub use position_p::{PositionP, PositionPParams};
pub use quadrant::{QuadrantCompensator, QuadrantParams, QuadrantTable};

/// The registry of built-in plugins.
#[derive(Debug, Default, Clone, Copy)]
pub struct Builtins;

impl PluginRegistry for Builtins {
    fn ids(&self) -> Vec<(&'static str, Stage)> {
        vec![
            (PositionP::ID, Stage::Position),
            (PiVelocity::ID, Stage::Velocity),
            (InverseFeedforward::ID, Stage::Feedforward),
            (FrictionFeedforward::ID, Stage::Compensator),
            (QuadrantCompensator::ID, Stage::Compensator),
        ]
    }

    fn create(
        &self,
        id: &str,
        params: &toml::Table,
        axis: &AxisContext,
        file: &Path,
    ) -> Result<Box<dyn Controller>, ConfigError> {
        match id {
            PositionP::ID => Ok(Box::new(PositionP::new(PositionPParams::from_table(
                params, axis, file,
            )?))),
            PiVelocity::ID => Ok(Box::new(PiVelocity::new(PiVelocityParams::from_table(
                params, axis, file, None,
            )?))),
            InverseFeedforward::ID => Ok(Box::new(InverseFeedforward::new(
                InverseFeedforwardParams::from_table(params, axis, file)?,
            ))),
            FrictionFeedforward::ID => Ok(Box::new(FrictionFeedforward::from_table(
                params, axis, file,
            )?)),
            QuadrantCompensator::ID => Ok(Box::new(QuadrantCompensator::new(
                QuadrantParams::from_table(params, axis, file)?,
            ))),
            other => {
                let known: Vec<_> = self.ids().into_iter().map(|(i, _)| i).collect();
                Err(ConfigError::new(
                    file,
                    "plugin",
                    format!("unknown plugin `{other}` (built-in: {})", known.join(", ")),
                ))
            }
        }
    }

    fn create_coupler(
        &self,
        id: &str,
        params: &toml::Table,
        contexts: &[AxisContext],
        axes: &[usize],
        file: &Path,
    ) -> Result<Box<dyn Coupler>, ConfigError> {
        match id {
            NlPidCoupler::ID => Ok(Box::new(NlPidCoupler::new(
                NlPidCouplerParams::from_table(params, file)?,
                contexts,
                axes,
                file,
            )?)),
            other => Err(ConfigError::new(
                file,
                "plugin",
                format!(
                    "unknown coupler plugin `{other}` (built-in: {})",
                    NlPidCoupler::ID
                ),
            )),
        }
    }
}
