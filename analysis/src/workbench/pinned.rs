//! A record held at the controller's limit: the loop asked for all it may and the motion could
//! not follow, the case where a drive's own clamp and the inertia trade off (the search of
//! `torque_saturation` in the refit module).

use super::data::AxisData;
use super::effects::WbModel;

/// Whether the recorded torque sits at the model's controller limit (within 0.1 %) for at least
/// 1 % of the samples: the loop asked for all it may, the motion could not follow.
pub(super) fn held_at_controller_limit(model: &WbModel, d: &AxisData) -> bool {
    let (Some(lim), Some(y)) = (model.file.controller.torque_limit, &d.torque_raw) else {
        return false;
    };
    let (a, b) = d.range;
    let at = y[a..b].iter().filter(|x| x.abs() >= 0.999 * lim).count();
    lim > 0.0 && b > a && at * 100 >= b - a
}
