//! The one constructor shape of a per-axis plugin: what the registry table builds it by.

use std::path::Path;

use feedloop_control::controller::{AxisContext, Controller, Stage};
use feedloop_model::params::ConfigError;

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
