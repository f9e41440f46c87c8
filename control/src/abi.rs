//! The C ABI of third-party controller plugins built as shared libraries.
//!
//! A plugin library exports four symbols (version [`ABI_VERSION`]):
//!
//! ```c
//! uint32_t feedloop_plugin_abi_version(void);
//! /* params: the plugin's TOML parameter text; axis: what it controls. Returns NULL on error and
//!    writes a NUL-terminated reason into err (err_len bytes). */
//! void *feedloop_plugin_create(const uint8_t *params, size_t params_len, const FlAxis *axis,
//!                              uint8_t *err, size_t err_len);
//! /* One cycle: read and update io (same layout as feedloop's AxisSignals). 0 = ok; anything else
//!    is a fault: feedloop discards the output (zero torque) and rolls the swap back. */
//! int32_t feedloop_plugin_step(void *state, const CycleContext *ctx, AxisSignals *io);
//! void feedloop_plugin_destroy(void *state);
//! ```
//!
//! Optional: `uint32_t feedloop_plugin_stages(void);` the stages the plugin can fill, one bit per
//! stage in [`feedloop_model::Stage::ALL`] order (1 position, 2 feedforward, 4 compensator,
//! 8 velocity). A swap into another stage is refused; a library without the symbol is taken
//! for any stage (its torque is still checked against the bumpless bound).
//!
//! A step with `ctx->cycle == UINT64_MAX` is the bumpless initialisation: `io` holds the last
//! cycle's signals, whose `torque` the previous controller produced; the plugin sets its state so
//! that its next output continues from it.
//!
//! A panic must not unwind across `extern "C"`: a Rust plugin wraps its step in `catch_unwind`
//! (the example in `examples/plugins/pi-velocity-c/` does). A library that crashes the process is
//! a lost scheduler: the plant's watchdog stops the axes.

use std::ffi::c_void;

use crate::controller::{AxisSignals, CycleContext};

/// Version of this ABI; a library reporting another one is refused.
pub const ABI_VERSION: u32 = 1;

/// What a plugin is told about its axis (motor units; NaN where the model gives no default).
#[derive(Debug, Clone, Copy)]
#[repr(C)]
pub struct FlAxis {
    /// Control period, s.
    pub period_s: f64,
    /// 0 ballscrew, 1 rotary, 2 rigid.
    pub kind: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Motor units per load unit.
    pub motor_per_load: f64,
    /// Model default Kp, 1/s.
    pub kp_per_s: f64,
    /// Model default Kv (N m s/rad or N s/m).
    pub kv: f64,
    /// Model default Tv, s.
    pub tv_s: f64,
    /// Model default torque (force) limit.
    pub torque_limit: f64,
}

/// `feedloop_plugin_abi_version`.
pub type AbiVersionFn = unsafe extern "C" fn() -> u32;
/// `feedloop_plugin_create`.
pub type CreateFn =
    unsafe extern "C" fn(*const u8, usize, *const FlAxis, *mut u8, usize) -> *mut c_void;
/// `feedloop_plugin_step`.
pub type StepFn = unsafe extern "C" fn(*mut c_void, *const CycleContext, *mut AxisSignals) -> i32;
/// `feedloop_plugin_stages` (optional).
pub type StagesFn = unsafe extern "C" fn() -> u32;
/// `feedloop_plugin_destroy`.
pub type DestroyFn = unsafe extern "C" fn(*mut c_void);
