//! Built-in controller plugins of feedloop and the registry that creates them by id.
//!
//! One file per control law; each opens with its equation, units and source seed.
#![warn(missing_docs)]

pub mod pi_velocity;
pub mod position_p;

use std::path::Path;

use feedloop_runtime::controller::{AxisContext, Controller, PluginRegistry, Stage};
use feedloop_runtime::params::ConfigError;

pub use pi_velocity::{PiVelocity, PiVelocityParams};
pub use position_p::{PositionP, PositionPParams};

/// The registry of built-in plugins.
#[derive(Debug, Default, Clone, Copy)]
pub struct Builtins;

impl PluginRegistry for Builtins {
    fn ids(&self) -> Vec<(&'static str, Stage)> {
        vec![
            (PositionP::ID, Stage::Position),
            (PiVelocity::ID, Stage::Velocity),
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
}
