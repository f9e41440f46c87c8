//! The side of a dry friction on an axis whose motor and load are both measured: the torque
//! balance holds the sum of the two sides' friction and tells them apart only in the instants
//! around a reversal, where the motor has turned and the load not yet; the motion after those
//! instants shows where the friction acts (the spring carries a load's friction, not a motor's).

use super::data::AxisData;
use super::effects::{Effect, EffectId, Side, WbModel};
use super::lsq::material_cut;
use super::window::windowed_only;

/// Length of the windows a friction's side is judged on (`compare`'s default), s.
const SIDE_WINDOW_S: f64 = 0.05;

/// Whether effect `id` is a dry friction (at most one on each side).
pub(super) fn is_dry(id: EffectId) -> bool {
    matches!(
        id,
        EffectId::CoulombFriction | EffectId::StribeckFriction | EffectId::DirectionalFriction
    )
}

/// Whether `model` carries a dry friction on side `s`.
pub(super) fn taken(model: &WbModel, s: Side) -> bool {
    model.effects.iter().any(|e| is_dry(e.id) && e.side == s)
}

/// The side a dry friction of effect `id` may also take besides `side`: on an axis whose motor
/// and load are both measured and modelled as two masses, the motor's or the load's. `None`
/// for any other effect or axis.
pub(super) fn other_side(id: EffectId, model: &WbModel, d: &AxisData, side: Side) -> Option<Side> {
    (is_dry(id) && d.has_motor() && model.file.plant.two_mass().is_some()).then_some(match side {
        Side::Motor => Side::Load,
        Side::Load => Side::Motor,
    })
}

/// Which of `model` with effect `first` and with effect `second` (the same friction fitted on
/// either side, or the two forms of a delay) simulates the record better, window by window:
/// `Some(true)` the second, `Some(false)` the first (its windowed simulation error materially
/// lower ([`material_cut`]), or only it simulated by the plant), `None` when neither does.
pub(super) fn simulation_prefers(
    first: &Effect,
    second: &Effect,
    model: &WbModel,
    d: &AxisData,
) -> Option<bool> {
    let windowed = |e: &Effect| -> Option<f64> {
        let mut with = model.clone();
        with.effects.push(e.clone());
        let w = windowed_only(&with, d, SIDE_WINDOW_S);
        w.on_plant().then(|| w.headline_nrmse_pct()).flatten()
    };
    match (windowed(first), windowed(second)) {
        (Some(ea), Some(eb)) if material_cut(ea, eb) => Some(true),
        (Some(ea), Some(eb)) if material_cut(eb, ea) => Some(false),
        (None, Some(_)) => Some(true),
        (Some(_), None) => Some(false),
        _ => None,
    }
}
