//! The control service's checks of a request (decode, axis, stage, plugin, parameters, the loop
//! model's verdict), without the service ([`DryRun`]): random swap and retune requests, well-formed
//! or not, each get a verdict or a refusal with its reason; and the fuzz campaign's seeds and
//! the inputs it ever crashed on (`fuzz/seeds/control_request`, `fuzz/regressions/control_request`)
//! are checked so too.

use std::path::Path;
use std::sync::Arc;

use feedloop_control::controller::PluginRegistry;
use feedloop_model::job::Job;
use feedloop_plugins::Builtins;
use feedloop_runtime::scheduler::control::dry_run::{
    request_bytes, request_from_bytes, DryRun, Verdict,
};
use feedloop_runtime::scheduler::control::protocol::{Answer, Request};
use feedloop_runtime::scheduler::cycle::ControlCycle;
use proptest::prelude::*;
use serde_json::{json, Value};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap()
}

/// The checks of a loop running the two-axis full chain (axes `x`, `c`).
fn dry_run() -> DryRun {
    let job = Job::load(&root().join("examples/jobs/xc-full-chain.toml")).unwrap();
    let cycle = ControlCycle::new(&job, &Builtins).unwrap();
    DryRun::new(&job, &cycle, Arc::new(Builtins))
}

/// The verdict on `text`, a refusal read back through a response buffer as the client reads it.
fn verdict(dry: &DryRun, text: &[u8]) -> Result<Verdict, String> {
    dry.answer(&request_from_bytes(&request_bytes(text)))
        .map_err(|a| match *a {
            Answer::Refused { error, swap: None } => error,
            other => panic!("a refusal read back as {other:?}"),
        })
}

fn param_value() -> impl Strategy<Value = String> {
    prop_oneof![
        (-1e4..1e4f64).prop_map(|v| format!("{v:?}")),
        (0.0..1e3f64).prop_map(|v| format!("{v:?}")),
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("1e308".to_string()),
        Just("-0.0".to_string()),
        Just("9223372036854775807".to_string()),
        Just("\"4.0\"".to_string()),
        Just("true".to_string()),
        Just("[1.0, 2.0]".to_string()),
        Just("{ a = 1 }".to_string()),
        Just("\"split\"".to_string()),
        Just("\"literal\"".to_string()),
    ]
}

fn params() -> impl Strategy<Value = Option<String>> {
    let key = prop_oneof![
        Just("kp_per_s"),
        Just("kv_nms_per_rad"),
        Just("kv_ns_per_m"),
        Just("tv_s"),
        Just("vel_filter_hz"),
        Just("notch_hz"),
        Just("notch_q"),
        Just("notch_depth"),
        Just("torque_lowpass_hz"),
        Just("torque_limit_nm"),
        Just("structure"),
        Just("velocity_ff"),
        Just("kp_min_per_s"),
        Just("kp_max_per_s"),
        Just("unknown_key"),
    ];
    prop_oneof![
        1 => Just(None),
        1 => Just(Some("kv_nms_per_rad = [".to_string())),
        6 => proptest::collection::vec((key, param_value()), 0..4).prop_map(|kv| {
            Some(kv.iter().map(|(k, v)| format!("{k} = {v}\n")).collect())
        }),
    ]
}

fn name(known: Vec<String>) -> impl Strategy<Value = Value> {
    prop_oneof![
        6 => proptest::sample::select(known).prop_map(Value::from),
        1 => "[a-z_]{0,8}".prop_map(Value::from),
        1 => Just(json!(3)),
        1 => Just(Value::Null),
    ]
}

fn swap_request() -> impl Strategy<Value = Value> {
    let plugins: Vec<String> = Builtins
        .ids()
        .iter()
        .map(|(id, _)| id.to_string())
        .collect();
    let stages = ["position", "feedforward", "compensator", "velocity"]
        .map(String::from)
        .to_vec();
    (
        name(vec!["x".into(), "c".into()]),
        name(stages),
        name(plugins),
        params(),
        prop_oneof![Just(json!(false)), Just(json!(true)), Just(json!("yes"))],
    )
        .prop_map(|(axis, stage, plugin, params, force)| {
            json!({"op": "swap", "axis": axis, "stage": stage, "plugin": plugin,
                   "params": params, "force": force})
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn every_swap_request_gets_a_verdict_or_a_refusal_with_its_reason(req in swap_request()) {
        thread_local!(static DRY: DryRun = dry_run());
        let text = req.to_string();
        let v = DRY.with(|d| verdict(d, text.as_bytes()));
        match v {
            Ok(Verdict::Swap { plugin, .. }) => {
                prop_assert_eq!(Some(plugin.as_str()), req["plugin"].as_str(), "{}", text);
            }
            Ok(other) => prop_assert!(false, "{text}: {other:?}"),
            Err(e) => {
                prop_assert!(!e.trim().is_empty(), "{}", text);
                let axis = req["axis"].as_str();
                let named = req["stage"].is_string() && req["plugin"].is_string() && req["force"].is_boolean();
                if named && axis.is_some_and(|a| a != "x" && a != "c") {
                    prop_assert!(e.contains("does not exist"), "{}: {}", text, e);
                }
            }
        }
    }

    #[test]
    fn any_bytes_in_the_buffer_are_refused_with_a_reason_or_read(
        b in proptest::collection::vec(any::<u8>(), 0..64),
    ) {
        thread_local!(static DRY: DryRun = dry_run());
        let msg = request_from_bytes(&b);
        if let Err(a) = DRY.with(|d| d.answer(&msg)) {
            prop_assert!(a.is_refused());
        }
    }
}

#[test]
fn a_request_reads_back_from_its_bytes() {
    let text = br#"{"op":"swap","axis":"x","stage":"velocity","plugin":"pi_velocity"}"#;
    let msg = request_from_bytes(&request_bytes(text));
    assert_eq!(
        msg.request().unwrap(),
        Request::from_slice(text).unwrap(),
        "the bytes hold the request"
    );
    // a length beyond the buffer reads as much as there is, no further
    let mut long = request_bytes(br#"{"op":"status"}"#);
    long[4..8].copy_from_slice(&u32::MAX.to_ne_bytes());
    assert!(request_from_bytes(&long).request().is_err());
}

#[test]
fn retunes_swaps_and_refusals_are_told_apart() {
    let dry = dry_run();
    let retune = verdict(
        &dry,
        br#"{"op":"swap","axis":"x","stage":"velocity","plugin":"pi_velocity"}"#,
    );
    assert!(
        matches!(&retune, Ok(Verdict::Swap { plugin, margins: Some(_), .. }) if plugin == "pi_velocity"),
        "{retune:?}"
    );
    let loud =
        r#""axis":"x","stage":"velocity","plugin":"pi_velocity","params":"kv_ns_per_m = 1e9""#;
    let unsafe_ = verdict(&dry, format!(r#"{{"op":"swap",{loud}}}"#).as_bytes()).unwrap_err();
    assert!(
        unsafe_.contains("refused before it was applied"),
        "{unsafe_}"
    );
    let forced = verdict(
        &dry,
        format!(r#"{{"op":"swap",{loud},"force":true}}"#).as_bytes(),
    );
    assert!(
        matches!(&forced, Ok(Verdict::Swap { warnings, .. }) if warnings.iter().any(|w| w.contains("force"))),
        "{forced:?}"
    );
    assert_eq!(verdict(&dry, br#"{"op":"status"}"#), Ok(Verdict::Status));
    let lib = br#"{"op":"swap","axis":"x","stage":"velocity","plugin":"p","lib":"/x.so"}"#;
    assert_eq!(verdict(&dry, lib), Ok(Verdict::Library));
    let wrong = verdict(
        &dry,
        br#"{"op":"swap","axis":"x","stage":"position","plugin":"pi_velocity"}"#,
    )
    .unwrap_err();
    assert!(wrong.contains("pi_velocity"), "{wrong}");
    let range = verdict(
        &dry,
        br#"{"op":"swap","axis":"c","stage":"position","plugin":"position_p","params":"kp_per_s = -5.0"}"#,
    )
    .unwrap_err();
    assert!(range.contains("kp_per_s"), "{range}");
    let axis = verdict(
        &dry,
        br#"{"op":"swap","axis":"z","stage":"velocity","plugin":"pi_velocity"}"#,
    )
    .unwrap_err();
    assert!(axis.contains("axis `z` does not exist"), "{axis}");
    // a file named in the parameters is read only so far: /dev/zero would fill the memory
    let zero =
        std::fs::read(root().join("fuzz/regressions/control_request/table-dev-zero")).unwrap();
    let refusal = match dry.answer(&request_from_bytes(&zero)) {
        Err(a) => format!("{a:?}"),
        Ok(v) => panic!("{v:?}"),
    };
    assert!(refusal.contains("larger than 64 MiB"), "{refusal}");
}

#[test]
fn the_fuzz_seeds_and_regressions_are_checked_without_a_panic() {
    let dry = dry_run();
    let seeds = feedloop_test_support::fuzz_inputs("seeds", "control_request");
    assert!(seeds.len() >= 5, "seeds: {seeds:?}");
    for f in seeds.iter().chain(&feedloop_test_support::fuzz_inputs(
        "regressions",
        "control_request",
    )) {
        let msg = request_from_bytes(&std::fs::read(f).unwrap());
        if let Err(a) = dry.answer(&msg) {
            assert!(a.is_refused(), "{}: {a:?}", f.display());
        }
    }
}
