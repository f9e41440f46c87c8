//! Key readers several plugins share, so a key means the same (name by axis kind, range) in
//! every plugin that takes it.

use feedloop_model::model::AxisKind;
use feedloop_model::params::{ConfigError, Fields, Range};

use crate::filters::MAX_FRACTION_OF_RATE;

/// The key of a motor-unit quantity on an axis of `kind`: `rigid` on a rigid axis (N, m, kg),
/// `rotary` on a rotary-motor axis (N m, rad, kg m^2).
pub(crate) fn key_for(kind: AxisKind, rigid: &'static str, rotary: &'static str) -> &'static str {
    match kind {
        AxisKind::Rigid => rigid,
        _ => rotary,
    }
}

/// Parameter key names for an axis kind: (kv, limit).
pub fn key_names(kind: AxisKind) -> (&'static str, &'static str) {
    (
        key_for(kind, "kv_ns_per_m", "kv_nms_per_rad"),
        key_for(kind, "force_limit_n", "torque_limit_nm"),
    )
}

/// The PI velocity loop's gains as a plugin's keys give them (`None` = left out).
pub(crate) struct PiGains {
    /// Key of Kv on this axis kind.
    pub kv_key: &'static str,
    /// Kv, N m s/rad or N s/m.
    pub kv: Option<f64>,
    /// Tv (`tv_s`), s.
    pub tv: Option<f64>,
}

/// Reads Kv (key by axis kind) and then `tv_s`.
pub(crate) fn read_pi_gains(f: &mut Fields<'_>, kind: AxisKind) -> Result<PiGains, ConfigError> {
    let (kv_key, _) = key_names(kind);
    let kv = f.opt_f64(kv_key, Range::Within(1e-12, 1e9))?;
    let tv = f.opt_f64("tv_s", Range::Within(0.0, 1e3))?;
    Ok(PiGains { kv_key, kv, tv })
}

/// Reads the position loop gain `kp_per_s` (1/s), if given.
pub(crate) fn read_kp(f: &mut Fields<'_>) -> Result<Option<f64>, ConfigError> {
    f.opt_f64("kp_per_s", Range::Within(0.0, 1.0e5))
}

/// Reads an optional filter frequency `key` (0 = off), checking it against the sampling rate.
pub(crate) fn read_hz(
    f: &mut Fields<'_>,
    key: &str,
    period_s: f64,
) -> Result<Option<Option<f64>>, ConfigError> {
    let Some(hz) = f.opt_f64(key, Range::NonNegative)? else {
        return Ok(None);
    };
    if hz == 0.0 {
        return Ok(Some(None));
    }
    let max = MAX_FRACTION_OF_RATE / period_s;
    if hz > max {
        return Err(f.error(
            key,
            format!("must be <= 0.45 / period_s = {max} Hz at this job's period, got {hz}"),
        ));
    }
    Ok(Some(Some(hz)))
}
