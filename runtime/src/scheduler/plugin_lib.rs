//! Loads third-party controller plugins from shared libraries speaking the C ABI of
//! [`feedloop_control::abi`] (the symbols, the layouts and the rules are described there).

use std::ffi::c_void;
use std::path::Path;
use std::sync::Arc;

use feedloop_control::abi::{
    AbiVersionFn, CreateFn, DestroyFn, FlAxis, StagesFn, StepFn, ABI_VERSION,
};
use feedloop_control::controller::{
    AxisContext, AxisSignals, Controller, ControllerState, CycleContext,
};
use feedloop_model::model::AxisKind;

/// Errors loading a plugin library.
#[derive(Debug, thiserror::Error)]
pub enum AbiError {
    /// The file could not be loaded as a shared library.
    #[error("cannot load plugin library {path}: {reason}")]
    Load {
        /// Library path.
        path: String,
        /// Loader's message.
        reason: String,
    },
    /// A required symbol is missing.
    #[error("plugin library {path} lacks the symbol `{symbol}` (not a feedloop plugin of ABI {ABI_VERSION}?)")]
    MissingSymbol {
        /// Library path.
        path: String,
        /// Symbol name.
        symbol: &'static str,
    },
    /// The library speaks another ABI version.
    #[error("plugin library {path} was built for ABI version {found}, this feedloop speaks {ABI_VERSION}")]
    Version {
        /// Library path.
        path: String,
        /// Version it reports.
        found: u32,
    },
    /// The plugin refused its parameters.
    #[error("plugin library {path} refused its parameters: {reason}")]
    Create {
        /// Library path.
        path: String,
        /// Plugin's message.
        reason: String,
    },
}

/// The required function `name` of the library `lib` loaded from `path`.
///
/// # Safety
/// `T` must be the type the documented ABI gives the symbol.
unsafe fn symbol<T: Copy>(
    lib: &libloading::Library,
    path: &str,
    name: &'static str,
) -> Result<T, AbiError> {
    // SAFETY: the caller names the symbol's type.
    match unsafe { lib.get::<T>(name) } {
        Ok(f) => Ok(*f),
        Err(_) => Err(AbiError::MissingSymbol {
            path: path.to_string(),
            symbol: name,
        }),
    }
}

/// A controller living in a shared library.
pub struct LibController {
    id: String,
    state: *mut c_void,
    step: StepFn,
    destroy: DestroyFn,
    stages: Option<u32>,
    // Keeps the code mapped as long as the state lives (dropped after `destroy`).
    _lib: Arc<libloading::Library>,
}

// SAFETY: the plugin state is only touched through `step`/`destroy`, from one thread at a time
// (the controller moves between the builder thread and the cycle, never shared).
unsafe impl Send for LibController {}

impl LibController {
    /// Loads `path`, checks its ABI version and symbols, and creates an instance with `params`.
    pub fn load(path: &Path, id: &str, params: &str, axis: &AxisContext) -> Result<Self, AbiError> {
        let p = path.display().to_string();
        // SAFETY: loading a library runs its initialisers; the user asked for this library.
        let lib = unsafe { libloading::Library::new(path) }.map_err(|e| AbiError::Load {
            path: p.clone(),
            reason: e.to_string(),
        })?;
        // SAFETY: symbol types follow the documented ABI; a wrong signature is the library's bug.
        unsafe {
            let version: AbiVersionFn = symbol(&lib, &p, "feedloop_plugin_abi_version")?;
            let create: CreateFn = symbol(&lib, &p, "feedloop_plugin_create")?;
            let step: StepFn = symbol(&lib, &p, "feedloop_plugin_step")?;
            let destroy: DestroyFn = symbol(&lib, &p, "feedloop_plugin_destroy")?;
            let stages = lib
                .get::<StagesFn>(b"feedloop_plugin_stages\0")
                .ok()
                .map(|f| f());
            let found = version();
            if found != ABI_VERSION {
                return Err(AbiError::Version { path: p, found });
            }
            let d = &axis.defaults;
            let fl = FlAxis {
                period_s: axis.period_s,
                kind: match axis.plant.kind() {
                    AxisKind::BallScrew => 0,
                    AxisKind::Rotary => 1,
                    AxisKind::Rigid => 2,
                },
                reserved: 0,
                motor_per_load: axis.plant.motor_per_load(),
                kp_per_s: d.kp_per_s.unwrap_or(f64::NAN),
                kv: d.kv.unwrap_or(f64::NAN),
                tv_s: d.tv_s.unwrap_or(f64::NAN),
                torque_limit: d.torque_limit.unwrap_or(f64::NAN),
            };
            let mut err = [0u8; 512];
            let state = create(
                params.as_ptr(),
                params.len(),
                &fl,
                err.as_mut_ptr(),
                err.len(),
            );
            if state.is_null() {
                let n = err.iter().position(|b| *b == 0).unwrap_or(err.len());
                return Err(AbiError::Create {
                    path: p,
                    reason: String::from_utf8_lossy(&err[..n]).into_owned(),
                });
            }
            Ok(Self {
                id: id.to_string(),
                state,
                step,
                destroy,
                stages,
                _lib: Arc::new(lib),
            })
        }
    }

    /// The stages the library declares it can fill (`None`: it does not say).
    pub fn stages(&self) -> Option<Vec<feedloop_model::Stage>> {
        self.stages.map(|mask| {
            feedloop_model::Stage::ALL
                .into_iter()
                .filter(|s| mask >> s.index() & 1 == 1)
                .collect()
        })
    }
}

impl Controller for LibController {
    fn id(&self) -> &str {
        &self.id
    }

    fn step(&mut self, ctx: &CycleContext, io: &mut AxisSignals) {
        // SAFETY: state came from the library's create and is used from one thread.
        let rc = unsafe { (self.step)(self.state, ctx, io) };
        if rc != 0 {
            io.torque = f64::NAN;
        }
    }

    fn snapshot(&self) -> ControllerState {
        ControllerState::EMPTY
    }

    fn restore(&mut self, _state: &ControllerState) {}

    fn initialize_from(&mut self, last: &AxisSignals) {
        // Bumpless start: one step on last cycle's signals lets the plugin set its integrator
        // from the torque it is asked to continue (the ABI example does so when its state is new).
        let mut io = *last;
        let ctx = CycleContext {
            period_s: 0.0,
            cycle: u64::MAX,
            t_s: f64::NAN,
        };
        // SAFETY: as in `step`.
        unsafe { (self.step)(self.state, &ctx, &mut io) };
    }
}

impl Drop for LibController {
    fn drop(&mut self) {
        // SAFETY: state came from create and is destroyed exactly once.
        unsafe { (self.destroy)(self.state) };
    }
}
