//! The one constructor shape of a per-axis plugin: what the registry table builds it by.

use std::path::Path;

use feedloop_control::controller::{AxisContext, Controller, Stage};
use feedloop_model::params::{ConfigError, Fields};

/// A per-axis plugin as the registry knows it: its id, the stage it fills and how it is built
/// from its keys. A new controller implements this and [`Controller`] in its own file and adds
/// one [`crate::PluginEntry::of`] line to [`crate::PLUGINS`].
pub trait AxisPlugin: Controller + Sized + 'static {
    /// Plugin id, as job files and swaps name it.
    const ID: &'static str;
    /// The stage the plugin fills.
    const STAGE: Stage;
    /// Builds the plugin for `axis` from its keys `params` (keys left out default to the axis
    /// model's `[controller]` values); `file` names where the params came from.
    fn build(params: &toml::Table, axis: &AxisContext, file: &Path) -> Result<Self, ConfigError>;
}

/// A plugin's parameters as read from its keys.
pub trait PluginParams: Sized {
    /// Reads the parameters from the plugin's keys `f` (keys left out default to the axis
    /// model's `[controller]` values); `file` names where the keys came from.
    fn read(f: Fields<'_>, axis: &AxisContext, file: &Path) -> Result<Self, ConfigError>;

    /// Reads the parameters from the plugin's key table `params`.
    fn from_table(
        params: &toml::Table,
        axis: &AxisContext,
        file: &Path,
    ) -> Result<Self, ConfigError> {
        Self::read(Fields::new(params, file, ""), axis, file)
    }
}

/// Implements [`AxisPlugin`] for a plugin whose `new` takes its [`PluginParams`]:
/// `axis_plugin!(Plugin, Params, "id", Stage::...)`.
macro_rules! axis_plugin {
    ($plugin:ty, $params:ty, $id:literal, $stage:expr) => {
        impl $crate::plugin::AxisPlugin for $plugin {
            const ID: &'static str = $id;
            const STAGE: feedloop_control::controller::Stage = $stage;

            fn build(
                params: &toml::Table,
                axis: &feedloop_control::controller::AxisContext,
                file: &std::path::Path,
            ) -> Result<Self, feedloop_model::params::ConfigError> {
                let params =
                    <$params as $crate::plugin::PluginParams>::from_table(params, axis, file)?;
                Ok(Self::new(params))
            }
        }
    };
}

/// The [`Controller`] methods of a plugin that reads the references only: its id
/// ([`AxisPlugin::ID`]) and [`Controller::reference_only`].
macro_rules! reference_only_plugin {
    () => {
        fn id(&self) -> &str {
            <Self as $crate::plugin::AxisPlugin>::ID
        }

        fn reference_only(&self) -> bool {
            // reads the references only and adds to vel_cmd / torque_ff
            true
        }
    };
}

pub(crate) use {axis_plugin, reference_only_plugin};
