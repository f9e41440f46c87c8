//! The built-in registry knows every plugin id it lists, by stage.

use std::path::Path;

#[allow(dead_code)]
#[path = "../src/test_util.rs"]
mod test_util;

use feedloop_control::controller::{AxisContext, PluginRegistry, Stage};
use feedloop_plugins::Builtins;

fn axis() -> AxisContext {
    test_util::ballscrew_axis(1e-4)
}

#[test]
fn registry_lists_the_four_seed_plugins_at_their_stages() {
    let ids = Builtins.ids();
    for (id, stage) in [
        ("position_p", Stage::Position),
        ("pi_velocity", Stage::Velocity),
        ("inverse_feedforward", Stage::Feedforward),
        ("friction_feedforward", Stage::Compensator),
        ("quadrant_compensator", Stage::Compensator),
    ] {
        assert!(ids.contains(&(id, stage)), "{id}");
    }
}

#[test]
fn every_listed_plugin_but_the_table_driven_one_builds_from_the_model_defaults() {
    let empty = toml::Table::new();
    for (id, _) in Builtins.ids() {
        let r = Builtins.create(id, &empty, &axis(), Path::new("j.toml"));
        if id == "quadrant_compensator" {
            assert_eq!(r.err().unwrap().key, "table");
        } else {
            assert_eq!(r.unwrap().id(), id);
        }
    }
}

#[test]
fn unknown_coupler_is_refused_naming_the_built_in_one() {
    let e = Builtins
        .create_coupler(
            "ccc",
            &toml::Table::new(),
            &[axis()],
            &[0],
            Path::new("j.toml"),
        )
        .err()
        .unwrap();
    assert!(e.reason.contains("nl_pid_coupler"), "{e}");
}

#[test]
fn quadrant_compensator_reports_a_missing_table_file_by_its_key() {
    let t: toml::Table = "table = \"no-such-table.toml\"".parse().unwrap();
    let e = Builtins
        .create(
            "quadrant_compensator",
            &t,
            &axis(),
            Path::new("/tmp/j.toml"),
        )
        .err()
        .unwrap();
    assert_eq!(e.key, "table");
    assert!(e.reason.contains("does not exist"), "{e}");
}
