//! An out-of-tree feedloop controller plugin behind the C ABI: a PI velocity loop
//! tau = Kv (e + I / Tv) + tau_ff, e = vel_cmd - motor_vel, clamped to the torque limit.
//!
//! Parameters (TOML text, `key = number` lines): `kv_nms_per_rad`, `tv_s`, `torque_limit_nm`;
//! each defaults to the axis model's value handed over in `FlAxis`.
//! For fault-injection tests: `test_fault = 1 | 2 | 3` makes the plugin, after
//! `test_fault_after_cycles` steps, report a failure (1: non-zero return code), write a NaN torque
//! (2), or abort the whole process (3: what a crashing native library does).
//! The layouts and the ABI version come from `feedloop-control`, the only feedloop crate a plugin
//! needs (no IPC stack: `cargo tree` here shows no iceoryx2).
//! Build: `cargo build --release` here, then
//! `feedloop swap --instance NAME --axis x --stage velocity --plugin pi_velocity_c --lib target/release/libfeedloop_plugin_pi_velocity_c.so`.

use std::ffi::c_void;
use std::panic::{catch_unwind, AssertUnwindSafe};

use feedloop_control::abi::FlAxis;
use feedloop_control::controller::{AxisSignals, CycleContext};

#[cfg(not(feature = "wrong-abi"))]
const ABI_VERSION: u32 = feedloop_control::abi::ABI_VERSION;
#[cfg(feature = "wrong-abi")]
const ABI_VERSION: u32 = 999;

struct Pi {
    kv: f64,
    tv: f64,
    limit: f64,
    period: f64,
    integral: f64,
    fault: u32,
    fault_after: u64,
    steps: u64,
}

fn parse(text: &str, axis: &FlAxis) -> Result<Pi, String> {
    let mut pi = Pi {
        kv: axis.kv,
        tv: if axis.tv_s.is_nan() { 0.0 } else { axis.tv_s },
        limit: axis.torque_limit,
        period: axis.period_s,
        integral: 0.0,
        fault: 0,
        fault_after: 0,
        steps: 0,
    };
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let (k, v) = line
            .split_once('=')
            .ok_or_else(|| format!("line {}: expected `key = number`", n + 1))?;
        let v: f64 = v
            .trim()
            .parse()
            .map_err(|_| format!("line {}: `{}` is not a number", n + 1, v.trim()))?;
        if !v.is_finite() {
            return Err(format!("line {}: value must be finite", n + 1));
        }
        match k.trim() {
            "kv_nms_per_rad" if v > 0.0 => pi.kv = v,
            "tv_s" if v >= 0.0 => pi.tv = v,
            "torque_limit_nm" if v > 0.0 => pi.limit = v,
            "test_fault" if [0.0, 1.0, 2.0, 3.0].contains(&v) => pi.fault = v as u32,
            "test_fault_after_cycles" if v >= 0.0 && v.fract() == 0.0 => pi.fault_after = v as u64,
            "kv_nms_per_rad" | "tv_s" | "torque_limit_nm" | "test_fault"
            | "test_fault_after_cycles" => {
                return Err(format!("line {}: `{}` out of range: {v}", n + 1, k.trim()))
            }
            other => return Err(format!("line {}: unknown key `{other}`", n + 1)),
        }
    }
    if !(pi.kv > 0.0) {
        return Err("kv_nms_per_rad is required (no model default)".into());
    }
    if !(pi.limit > 0.0) {
        return Err("torque_limit_nm is required (no model default)".into());
    }
    Ok(pi)
}

fn write_err(err: *mut u8, len: usize, msg: &str) {
    if err.is_null() || len == 0 {
        return;
    }
    let n = msg.len().min(len - 1);
    // SAFETY: the caller gave `len` writable bytes.
    unsafe {
        std::ptr::copy_nonoverlapping(msg.as_ptr(), err, n);
        *err.add(n) = 0;
    }
}

/// ABI version of this library.
#[no_mangle]
pub extern "C" fn feedloop_plugin_abi_version() -> u32 {
    ABI_VERSION
}

/// The stages this plugin can fill: the velocity loop only (bit 3).
#[no_mangle]
pub extern "C" fn feedloop_plugin_stages() -> u32 {
    1 << 3
}

/// Creates an instance; NULL with a reason in `err` on bad parameters.
///
/// # Safety
/// `params` must point to `params_len` bytes, `axis` to an `FlAxis`, `err` to `err_len` bytes.
#[no_mangle]
pub unsafe extern "C" fn feedloop_plugin_create(
    params: *const u8,
    params_len: usize,
    axis: *const FlAxis,
    err: *mut u8,
    err_len: usize,
) -> *mut c_void {
    let r = catch_unwind(|| {
        let text = if params.is_null() {
            ""
        } else {
            std::str::from_utf8(unsafe { std::slice::from_raw_parts(params, params_len) })
                .map_err(|_| "parameters are not UTF-8".to_string())?
        };
        parse(text, unsafe { &*axis })
    });
    match r {
        Ok(Ok(pi)) => Box::into_raw(Box::new(pi)) as *mut c_void,
        Ok(Err(msg)) => {
            write_err(err, err_len, &msg);
            std::ptr::null_mut()
        }
        Err(_) => {
            write_err(err, err_len, "panic while creating the plugin");
            std::ptr::null_mut()
        }
    }
}

/// One cycle (or, with `cycle == u64::MAX`, the bumpless initialisation).
///
/// # Safety
/// `state` from `feedloop_plugin_create`; `ctx`, `io` valid pointers.
#[no_mangle]
pub unsafe extern "C" fn feedloop_plugin_step(
    state: *mut c_void,
    ctx: *const CycleContext,
    io: *mut AxisSignals,
) -> i32 {
    let r = catch_unwind(AssertUnwindSafe(|| {
        let pi = unsafe { &mut *(state as *mut Pi) };
        let ctx = unsafe { &*ctx };
        let io = unsafe { &mut *io };
        let e = io.vel_cmd - io.motor_vel;
        if ctx.cycle == u64::MAX {
            if pi.tv > 0.0 && io.torque.is_finite() {
                pi.integral = ((io.torque - io.torque_ff) / pi.kv - e) * pi.tv;
            }
            return 0;
        }
        pi.steps += 1;
        if pi.fault != 0 && pi.steps > pi.fault_after {
            match pi.fault {
                1 => return 3,
                2 => {
                    io.torque = f64::NAN;
                    return 0;
                }
                _ => std::process::abort(),
            }
        }
        let prev = pi.integral;
        if pi.tv > 0.0 {
            pi.integral += pi.period * e;
        }
        let i = if pi.tv > 0.0 {
            pi.integral / pi.tv
        } else {
            0.0
        };
        let raw = pi.kv * (e + i) + io.torque_ff;
        let out = raw.clamp(-pi.limit, pi.limit);
        if out != raw && e * raw > 0.0 {
            pi.integral = prev;
        }
        if !out.is_finite() {
            return 1;
        }
        io.torque = out;
        0
    }));
    r.unwrap_or(2)
}

/// Frees an instance.
///
/// # Safety
/// `state` from `feedloop_plugin_create`, destroyed once.
#[no_mangle]
pub unsafe extern "C" fn feedloop_plugin_destroy(state: *mut c_void) {
    if !state.is_null() {
        drop(unsafe { Box::from_raw(state as *mut Pi) });
    }
}
