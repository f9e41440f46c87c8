//! Built-in controller plugins.
