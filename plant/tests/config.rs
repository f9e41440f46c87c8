//! Bad effect and sensor parameters are refused with messages naming the file and dotted key.

mod common;

use common::*;

fn err(extra: &str) -> feedloop_model::params::ConfigError {
    let e = build_error(&format!("{BALLSCREW}\n{extra}"));
    println!("{e}");
    e
}

#[test]
fn negative_backlash_gap_is_refused_naming_effects_backlash_gap_m() {
    let e = err("[effects.backlash]\ngap_m = -1e-6\n");
    assert_eq!(e.key, "effects.backlash.gap_m");
    assert!(e.reason.contains(">= 0"));
}

#[test]
fn non_integer_cogging_order_is_refused() {
    let e = err("[effects.cogging]\namplitude_nm = 0.1\nperiods_per_rev = 12.5\n");
    assert_eq!(e.key, "effects.cogging.periods_per_rev");
    assert!(e.reason.contains("whole number"));
    let e = err("[effects.cogging]\namplitude_nm = 0.1\nperiods_per_rev = 0\n");
    assert_eq!(e.key, "effects.cogging.periods_per_rev");
}

#[test]
fn zero_lead_is_refused_by_the_model_and_a_zero_pitch_period_by_the_effect() {
    let e = build_error(&BALLSCREW.replace("lead_m = 0.01", "lead_m = 0.0"));
    assert_eq!(e.key, "lead_m");
    let e = err("[effects.pitch_error]\namplitude_m = 1e-6\nperiod_m = 0\n");
    assert_eq!(e.key, "effects.pitch_error.period_m");
}

#[test]
fn static_friction_below_coulomb_is_refused() {
    let e = err("[effects.stribeck_friction]\nfc_nm = 0.5\nfs_nm = 0.4\nvs_rad_per_s = 1\n");
    assert_eq!(e.key, "effects.stribeck_friction.fs_nm");
}

#[test]
fn a_force_key_on_the_motor_side_is_refused_with_a_hint_to_the_torque_key() {
    let e = err("[effects.coulomb_friction]\nfc_n = 10\n");
    assert_eq!(e.key, "effects.coulomb_friction.fc_n");
    assert!(e.reason.contains("fc_nm"));
}

#[test]
fn two_dry_frictions_on_one_side_are_refused() {
    let e = err("[effects.coulomb_friction]\nfc_nm = 0.1\n[effects.stribeck_friction]\nfc_nm = 0.1\nfs_nm = 0.2\nvs_rad_per_s = 1\n");
    assert!(e.reason.contains("already has"), "{e}");
}

#[test]
fn backlash_and_pitch_error_need_a_transmission() {
    let e = build_error("kind = \"rigid\"\nmass_kg = 1\n[effects.backlash]\ngap_m = 1e-5\n");
    assert_eq!(e.key, "effects.backlash");
    let rotary = BALLSCREW
        .replace("ballscrew", "rotary")
        .replace("lead_m = 0.01", "");
    let e = build_error(&format!(
        "{rotary}\n[effects.pitch_error]\namplitude_m = 1e-6\n"
    ));
    assert_eq!(e.key, "effects.pitch_error");
}

#[test]
fn repeating_a_single_effect_is_refused() {
    let e = err("[[effects.backlash]]\ngap_m = 1e-5\n[[effects.backlash]]\ngap_m = 2e-5\n");
    assert_eq!(e.key, "effects.backlash");
    assert!(e.reason.contains("only once"));
}

#[test]
fn unknown_side_and_unknown_key_in_an_effect_are_refused() {
    let e = err("[effects.viscous_friction]\nside = \"table\"\nc_nms_per_rad = 1\n");
    assert_eq!(e.key, "effects.viscous_friction.side");
    let e = err("[effects.delay]\ndelay_cycles = 2\njitter = 1\n");
    assert_eq!(e.key, "effects.delay.jitter");
    let e = err("[effects.delay]\ndelay_cycles = 1.5\n");
    assert_eq!(e.key, "effects.delay.delay_cycles");
}

#[test]
fn array_entries_are_named_with_their_index() {
    let e = err("[[effects.cogging]]\namplitude_nm = 0.1\nperiods_per_rev = 12\n[[effects.cogging]]\namplitude_nm = -0.1\nperiods_per_rev = 24\n");
    assert_eq!(e.key, "effects.cogging[1].amplitude_nm");
}

#[test]
fn sensor_counts_must_be_whole_and_velocity_estimate_known() {
    let e = err("[sensor]\nmotor_counts_per_rev = 1000.5\n");
    assert_eq!(e.key, "sensor.motor_counts_per_rev");
    let e = err("[sensor]\nvelocity_estimate = \"kalman\"\n");
    assert_eq!(e.key, "sensor.velocity_estimate");
}

#[test]
fn every_effect_combined_builds_on_a_ballscrew() {
    let ax = ballscrew_with(
        r#"
[[effects.viscous_friction]]
c_nms_per_rad = 0.001
[[effects.viscous_friction]]
side = "load"
c_ns_per_m = 300
[effects.coulomb_friction]
fc_nm = 0.1
[effects.stribeck_friction]
side = "load"
fc_n = 20
fs_n = 30
vs_m_per_s = 0.001
[effects.backlash]
gap_m = 5e-6
[effects.pitch_error]
amplitude_m = 2e-6
[effects.cogging]
amplitude_nm = 0.02
periods_per_rev = 36
[effects.constant_force]
force_n = -100
[effects.third_mass]
mass_kg = 100
stiffness_n_per_m = 5e7
[effects.delay]
delay_cycles = 1
[effects.current_lag]
tau_s = 2e-4
[effects.torque_saturation]
limit_nm = 20
[sensor]
motor_counts_per_rev = 1048576
load_resolution_m = 1e-8
load_pos_noise_m = 1e-8
"#,
        1e-4,
    );
    assert_eq!(ax.state_dim(), 7);
}
