//! The control service's requests and answers: the JSON the client sends and the scheduler
//! answers, as types both sides share (`feedloop swap`/`feedloop status`, tests and the
//! scheduler's [`ControlPlane`](super::ControlPlane)).
//!
//! Requests are tagged by `op`:
//! `{"op":"status"}`,
//! `{"op":"swap","axis":"x","stage":"velocity","plugin":"pi_velocity","params":"kv_nms_per_rad = 4.0","lib":null}`.
//! Answers are untagged: a status, a done swap (`{"swap":{...}}`) or a refusal
//! (`{"error":"..."}`, with the `swap` when a swap was rolled back).

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::Value;

use feedloop_model::Stage;

use super::origin::Origin;

/// A request to the control service.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "lowercase")]
pub enum Request {
    /// The loop's cycle, its axes' plugins and torques, and its counters.
    Status,
    /// Build a controller and switch it into a stage of an axis.
    Swap(SwapRequest),
}

/// The ops a [`Request`] can carry, as named in the refusal of an unknown one.
const OPS: [&str; 2] = ["status", "swap"];

/// What a swap request names.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwapRequest {
    /// Axis name, as in the job.
    pub axis: String,
    /// Stage name ([`Stage::id`]); checked by the scheduler.
    pub stage: String,
    /// Plugin id (built-in, or the id inside `lib`).
    pub plugin: String,
    /// TOML text of the plugin's parameters (merged into the stage's current ones when the
    /// plugin stays the same).
    #[serde(default)]
    pub params: Option<String>,
    /// Path of a plugin library to load `plugin` from.
    #[serde(default)]
    pub lib: Option<String>,
    /// Apply even when the loop model finds the set unstable or marginal, and keep it when its
    /// first cycles step the torque beyond the bumpless bound (both flagged in the swap's
    /// `warnings`). Written only when set, so a plain request reads as before.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub force: bool,
    /// The file `params` was read from, named in the errors about them (absent: the errors say
    /// `<swap --params>`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub params_file: Option<String>,
}

impl SwapRequest {
    /// The keys a swap cannot do without, in the order they are checked.
    const REQUIRED: [&'static str; 3] = ["axis", "stage", "plugin"];
}

/// Why a request was refused before it reached its op.
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    /// Not JSON, or a field of the wrong type.
    #[error("malformed request: {error}")]
    Malformed {
        /// The op, when one of the known ones ("" otherwise).
        op: &'static str,
        /// What the JSON parser said.
        error: serde_json::Error,
    },
    /// An `op` that is not one of [`Request`]'s.
    #[error("unknown op `{0}` (status, swap)")]
    UnknownOp(String),
    /// A required key is absent (or not a string).
    #[error("{op} needs `{key}`")]
    Missing {
        /// The op.
        op: &'static str,
        /// The key.
        key: &'static str,
    },
    /// The request's JSON does not fit a control request's buffer.
    #[error("request is {len} bytes, more than the {capacity} a control request holds")]
    TooLong {
        /// Length of the JSON, bytes.
        len: usize,
        /// Capacity of the buffer, bytes.
        capacity: usize,
    },
}

impl RequestError {
    /// The op of the refused request as sent ("" when it had none), for the run's summary.
    pub fn op(&self) -> &str {
        match self {
            RequestError::Malformed { op, .. } | RequestError::Missing { op, .. } => op,
            RequestError::UnknownOp(op) => op,
            RequestError::TooLong { .. } => "",
        }
    }
}

impl Request {
    /// Reads a request from its JSON text: malformed JSON, an unknown op and a missing key each
    /// get their own refusal.
    pub fn from_slice(text: &[u8]) -> Result<Self, RequestError> {
        let v: Value = serde_json::from_slice(text)
            .map_err(|error| RequestError::Malformed { op: "", error })?;
        let sent = v.get("op").and_then(Value::as_str).unwrap_or("");
        let Some(op) = OPS.into_iter().find(|o| *o == sent) else {
            return Err(RequestError::UnknownOp(sent.to_string()));
        };
        if op == "swap" {
            if let Some(key) = SwapRequest::REQUIRED
                .into_iter()
                .find(|k| v.get(k).and_then(Value::as_str).is_none())
            {
                return Err(RequestError::Missing { op, key });
            }
        }
        serde_json::from_value(v).map_err(|error| RequestError::Malformed { op, error })
    }
}

/// The answer to a request. A refusal travels with code 1, the others with code 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Answer {
    /// The request was refused, or its swap rolled back.
    Refused {
        /// Why, in words.
        error: String,
        /// The swap, when it was made and then rolled back.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        swap: Option<SwapEvent>,
    },
    /// A swap passed its probation.
    Swapped {
        /// The swap.
        swap: SwapEvent,
    },
    /// The loop's state.
    Status(Status),
}

impl Answer {
    /// A refusal for `error`.
    pub fn refused(error: impl Into<String>) -> Self {
        Answer::Refused {
            error: error.into(),
            swap: None,
        }
    }

    /// Whether the request was refused (or rolled back).
    pub fn is_refused(&self) -> bool {
        matches!(self, Answer::Refused { .. })
    }

    /// The response code it travels with: 0 done, 1 refused.
    pub fn code(&self) -> u32 {
        u32::from(self.is_refused())
    }
}

/// A running loop's state, as `feedloop status` prints it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// The cycle the answer was made in.
    pub cycle: u64,
    /// Its time, s.
    pub t_s: f64,
    /// Every axis, in job order.
    pub axes: Vec<AxisStatus>,
    /// Swaps so far.
    pub swaps: u64,
    /// Non-finite torques the chain caught.
    pub nonfinite_faults: u64,
    /// The plant's deadline misses as of its latest sample: over the cycles before `cycle`, counted
    /// as `summary.json`'s `deadline_misses` counts them.
    pub deadline_misses: u32,
    /// The plant's overruns (cycles it woke more than half a period late) over the cycles before
    /// `cycle`, counted as `summary.json`'s `plant_overruns` counts them.
    #[serde(default)]
    pub plant_overruns: u32,
    /// Refused requests so far.
    pub rejected_requests: u64,
    /// The last swaps (at most [`RECENT_SWAPS`], oldest first; rolled-back ones included), so a
    /// viewer learns of swaps other clients made and where they happened.
    #[serde(default)]
    pub recent_swaps: Vec<SwapEvent>,
    /// The job file the loop runs (as the scheduler was given it, made absolute), so a viewer
    /// can rebuild its path (contour errors).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job: Option<String>,
}

/// Most swaps a [`Status`] lists.
pub const RECENT_SWAPS: usize = 16;

/// One axis in a [`Status`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisStatus {
    /// Axis name.
    pub axis: String,
    /// The plugin of each filled stage.
    pub stages: StagePlugins,
    /// Latest torque command, N m (N); null when not finite.
    #[serde(deserialize_with = "f64_or_nan")]
    pub torque: f64,
    /// Latest position reference; null when not finite.
    #[serde(deserialize_with = "f64_or_nan")]
    pub reference: f64,
}

/// The plugin id of each stage of an axis (indexed by [`Stage::index`]); on the wire a map from
/// stage name to plugin id, in execution order, with empty stages left out.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StagePlugins(pub [Option<String>; 4]);

impl StagePlugins {
    /// The plugin in `stage`.
    pub fn get(&self, stage: Stage) -> Option<&str> {
        self.0[stage.index()].as_deref()
    }

    /// Sets the plugin in `stage`.
    pub fn set(&mut self, stage: Stage, id: Option<String>) {
        self.0[stage.index()] = id;
    }
}

impl Serialize for StagePlugins {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(
            Stage::ALL
                .into_iter()
                .filter_map(|st| self.get(st).map(|id| (st.id(), id))),
        )
    }
}

impl<'de> Deserialize<'de> for StagePlugins {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let map = std::collections::BTreeMap::<String, String>::deserialize(d)?;
        let mut out = StagePlugins::default();
        for (name, id) in map {
            let st = Stage::parse(&name)
                .ok_or_else(|| serde::de::Error::custom(format!("unknown stage `{name}`")))?;
            out.set(st, Some(id));
        }
        Ok(out)
    }
}

/// One swap, as reported in a swap's answer and in `summary.json`'s `swaps`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwapEvent {
    /// Time of the swap cycle, s.
    pub t_s: f64,
    /// Swap cycle.
    pub cycle: u64,
    /// Axis name.
    pub axis: String,
    /// Stage name.
    pub stage: String,
    /// Previous plugin id.
    pub from: String,
    /// New plugin id.
    pub to: String,
    /// |torque(swap cycle) - torque(previous cycle)|, N m (N); null when not finite.
    #[serde(deserialize_with = "f64_or_nan")]
    pub torque_step: f64,
    /// The bumpless bound: the largest cycle-to-cycle change in the 100 cycles before, times the
    /// gain ratio when the new gain is higher, plus 0.1 % of the torque limit.
    #[serde(deserialize_with = "f64_or_nan")]
    pub allowed_step: f64,
    /// Whether the swap was rolled back.
    pub rolled_back: bool,
    /// Why it was rolled back.
    pub reason: Option<String>,
    /// Phase margin of the axis' loops with the new controller, from the loop model (null when
    /// it could not be computed, e.g. a library plugin that reports no gains), deg.
    #[serde(default)]
    pub phase_margin_deg: Option<f64>,
    /// Gain margin likewise, dB.
    #[serde(default)]
    pub gain_margin_db: Option<f64>,
    /// Whether the request said `force`.
    #[serde(default)]
    pub forced: bool,
    /// What a forced swap was let through despite (and notes, e.g. margins not checked).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// What changed: `plugin: A -> B` for a new plugin, and each parameter the request set
    /// whose value differs from the stage's current one (`key: old -> new`, `key = new` when it
    /// had none).
    #[serde(default)]
    pub changed: Vec<String>,
    /// Who asked for it: the command line (user, process id) or a scope page (its address);
    /// null when the sender did not say.
    #[serde(default)]
    pub origin: Option<Origin>,
}

/// A number, or NaN for the `null` JSON writes for a non-finite one.
fn f64_or_nan<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn swap_request() -> Request {
        Request::Swap(SwapRequest {
            axis: "x".into(),
            stage: "velocity".into(),
            plugin: "pi_velocity".into(),
            params: Some("kv_nms_per_rad = 4.0".into()),
            lib: None,
            force: false,
            params_file: None,
        })
    }

    #[test]
    fn requests_are_written_as_before() {
        assert_eq!(
            serde_json::to_string(&Request::Status).unwrap(),
            json!({"op": "status"}).to_string()
        );
        // What `feedloop swap` sent as untyped JSON, key for key.
        let before = json!({"op": "swap", "axis": "x", "stage": "velocity",
                            "plugin": "pi_velocity", "params": "kv_nms_per_rad = 4.0",
                            "lib": null});
        assert_eq!(
            serde_json::to_string(&swap_request()).unwrap(),
            before.to_string()
        );
        assert_eq!(
            Request::from_slice(before.to_string().as_bytes()).unwrap(),
            swap_request()
        );
    }

    #[test]
    fn optional_keys_may_be_left_out_and_extra_keys_are_ignored() {
        let r = Request::from_slice(
            br#"{"op":"swap","axis":"x","stage":"velocity","plugin":"p","extra":1}"#,
        )
        .unwrap();
        let Request::Swap(s) = r else { panic!("{r:?}") };
        assert_eq!((s.params, s.lib), (None, None));
        assert_eq!(
            Request::from_slice(br#"{"op":"status","verbose":true}"#).unwrap(),
            Request::Status
        );
    }

    #[test]
    fn bad_requests_are_refused_with_the_reasons_of_before() {
        let refuse = |t: &str| {
            let e = Request::from_slice(t.as_bytes()).unwrap_err();
            (e.op().to_string(), e.to_string())
        };
        let (op, e) = refuse("{not json");
        assert_eq!(op, "");
        assert!(e.starts_with("malformed request: "), "{e}");
        assert_eq!(
            refuse(r#"{"op":"reboot"}"#),
            ("reboot".into(), "unknown op `reboot` (status, swap)".into())
        );
        assert_eq!(
            refuse(r#"{"axis":"x"}"#),
            ("".into(), "unknown op `` (status, swap)".into())
        );
        assert_eq!(
            refuse(r#"{"op":"swap","stage":"velocity","plugin":"p"}"#),
            ("swap".into(), "swap needs `axis`".into())
        );
        assert_eq!(
            refuse(r#"{"op":"swap","axis":"x","stage":3,"plugin":"p"}"#),
            ("swap".into(), "swap needs `stage`".into())
        );
        assert_eq!(
            refuse(r#"{"op":"swap","axis":"x","stage":"velocity"}"#),
            ("swap".into(), "swap needs `plugin`".into())
        );
        let (op, e) = refuse(r#"{"op":"swap","axis":"x","stage":"velocity","plugin":"p","lib":7}"#);
        assert_eq!(op, "swap");
        assert!(e.starts_with("malformed request: "), "{e}");
    }

    fn event(torque_step: f64) -> SwapEvent {
        SwapEvent {
            t_s: 1.5,
            cycle: 3000,
            axis: "x".into(),
            stage: "velocity".into(),
            from: "pi_velocity".into(),
            to: "pi_velocity_c".into(),
            torque_step,
            allowed_step: 0.25,
            rolled_back: false,
            reason: None,
            phase_margin_deg: Some(52.5),
            gain_margin_db: None,
            forced: true,
            warnings: vec!["kept although marginal".into()],
            changed: vec!["kv_nms_per_rad: 4.0 -> 4.75".into()],
            origin: Some(Origin::scope_page("127.0.0.1:50412")),
        }
    }

    #[test]
    fn answers_read_back_as_they_were_written() {
        let mut stages = StagePlugins::default();
        stages.set(Stage::Velocity, Some("pi_velocity".into()));
        stages.set(Stage::Position, Some("position_p".into()));
        let status = Answer::Status(Status {
            cycle: 12,
            t_s: 0.006,
            axes: vec![AxisStatus {
                axis: "x".into(),
                stages,
                torque: 0.5,
                reference: 0.0,
            }],
            swaps: 1,
            nonfinite_faults: 0,
            deadline_misses: 2,
            plant_overruns: 5,
            rejected_requests: 3,
            recent_swaps: vec![],
            job: None,
        });
        let text = serde_json::to_string(&status).unwrap();
        assert_eq!(
            text,
            json!({"cycle": 12, "t_s": 0.006,
                   "axes": [{"axis": "x",
                             "stages": {"position": "position_p", "velocity": "pi_velocity"},
                             "torque": 0.5, "reference": 0.0}],
                   "swaps": 1, "nonfinite_faults": 0, "deadline_misses": 2,
                   "plant_overruns": 5, "rejected_requests": 3, "recent_swaps": []})
            .to_string()
        );
        for a in [
            status,
            Answer::Swapped { swap: event(0.125) },
            Answer::refused("axis `q` does not exist (axes: x, y)"),
        ] {
            let text = serde_json::to_string(&a).unwrap();
            assert_eq!(serde_json::from_str::<Answer>(&text).unwrap(), a, "{text}");
        }
        assert_eq!(
            serde_json::to_string(&Answer::refused("no")).unwrap(),
            r#"{"error":"no"}"#
        );
    }

    #[test]
    fn a_rolled_back_swap_with_a_non_finite_step_reads_back() {
        let a = Answer::Refused {
            error: "rolled back: the new controller produced a non-finite torque".into(),
            swap: Some(event(f64::NAN)),
        };
        assert_eq!(a.code(), 1);
        let text = serde_json::to_string(&a).unwrap();
        assert!(text.starts_with(r#"{"error":"rolled back"#), "{text}");
        assert!(text.contains(r#""torque_step":null"#), "{text}");
        let back: Answer = serde_json::from_str(&text).unwrap();
        assert_eq!(serde_json::to_string(&back).unwrap(), text);
        let Answer::Refused { swap: Some(ev), .. } = back else {
            panic!("{back:?}")
        };
        assert!(ev.torque_step.is_nan());
    }
}
