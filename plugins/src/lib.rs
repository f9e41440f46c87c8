//! Built-in controller plugins of feedloop and the registry that creates them by id.
//!
//! One file per control law; each opens with its equation, units and source seed. A per-axis
//! plugin implements [`AxisPlugin`] (its id, stage and constructor) and has one line in
//! [`PLUGINS`], from which the registry's ids, stages and constructors all come.
#![warn(missing_docs)]

pub mod filters;
pub mod friction_feedforward;
pub mod inverse_feedforward;
mod keys;
pub mod nl_pid_coupler;
pub mod pi_velocity;
pub mod plugin;
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
pub use plugin::{AxisPlugin, PluginParams};
pub use position_p::{PositionP, PositionPParams};
pub use quadrant::{QuadrantCompensator, QuadrantParams, QuadrantTable};

/// How a registry entry builds its plugin (the boxed [`AxisPlugin::build`]).
pub type CreateFn =
    fn(&toml::Table, &AxisContext, &Path) -> Result<Box<dyn Controller>, ConfigError>;

/// One row of the registry table: a per-axis plugin's id, its stage and its constructor.
#[derive(Debug, Clone, Copy)]
pub struct PluginEntry {
    /// Plugin id.
    pub id: &'static str,
    /// The stage it fills.
    pub stage: Stage,
    /// Its constructor.
    pub create: CreateFn,
}

impl PluginEntry {
    /// The entry of plugin `P`.
    pub const fn of<P: AxisPlugin>() -> Self {
        Self {
            id: P::ID,
            stage: P::STAGE,
            create: create_boxed::<P>,
        }
    }
}

fn create_boxed<P: AxisPlugin>(
    params: &toml::Table,
    axis: &AxisContext,
    file: &Path,
) -> Result<Box<dyn Controller>, ConfigError> {
    Ok(Box::new(P::build(params, axis, file)?))
}

/// The built-in per-axis plugins, in the order [`PluginRegistry::ids`] lists them.
pub const PLUGINS: &[PluginEntry] = &[
    PluginEntry::of::<PositionP>(),
    PluginEntry::of::<PiVelocity>(),
    PluginEntry::of::<InverseFeedforward>(),
    PluginEntry::of::<FrictionFeedforward>(),
    PluginEntry::of::<QuadrantCompensator>(),
];

/// How a coupler entry builds its coupler over the axes it names.
pub type CreateCouplerFn =
    fn(&toml::Table, &[AxisContext], &[usize], &Path) -> Result<Box<dyn Coupler>, ConfigError>;

/// The built-in couplers: id and constructor.
pub const COUPLERS: &[(&str, CreateCouplerFn)] =
    &[(NlPidCoupler::ID, |params, contexts, axes, file| {
        Ok(Box::new(NlPidCoupler::new(
            NlPidCouplerParams::from_table(params, file)?,
            contexts,
            axes,
            file,
        )?))
    })];

/// The registry of built-in plugins.
#[derive(Debug, Default, Clone, Copy)]
pub struct Builtins;

impl PluginRegistry for Builtins {
    fn ids(&self) -> Vec<(&'static str, Stage)> {
        PLUGINS.iter().map(|e| (e.id, e.stage)).collect()
    }

    fn create(
        &self,
        id: &str,
        params: &toml::Table,
        axis: &AxisContext,
        file: &Path,
    ) -> Result<Box<dyn Controller>, ConfigError> {
        match PLUGINS.iter().find(|e| e.id == id) {
            Some(e) => (e.create)(params, axis, file),
            None => Err(unknown(file, "plugin", id, PLUGINS.iter().map(|e| e.id))),
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
        match COUPLERS.iter().find(|(i, _)| *i == id) {
            Some((_, create)) => create(params, contexts, axes, file),
            None => Err(unknown(
                file,
                "coupler plugin",
                id,
                COUPLERS.iter().map(|(i, _)| *i),
            )),
        }
    }
}

/// The refusal of an unknown id, naming the built-in ones.
fn unknown<'a>(
    file: &Path,
    what: &str,
    id: &str,
    known: impl Iterator<Item = &'a str>,
) -> ConfigError {
    let known: Vec<_> = known.collect();
    ConfigError::new(
        file,
        "plugin",
        format!("unknown {what} `{id}` (built-in: {})", known.join(", ")),
    )
}
