//! The Python package's native part (`feedloop._feedloop`): a thin binding of feedloop's crates.
//! Each function does what the matching CLI command does, through the same library functions,
//! and returns its JSON as text (the Python side turns it into result objects). The Rust work
//! runs with the interpreter lock released, so Python threads run it in parallel.

// The functions take the CLI's options as keyword arguments of Python, one parameter each.
#![allow(clippy::too_many_arguments)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use anyhow::Context;
use feedloop_analysis::workbench::{
    auto::{auto, diagnosis_html},
    compare::compare,
    diagnose::{diagnose, DiagOptions},
    effects::WbModel,
    fit::{fit, parse_effects},
    report,
};
use feedloop_cli::workbench_load::{
    diagnosis_json, error_text, prepare, read_axis_columns, LoadOptions,
};
use feedloop_trace::Trace;
use numpy::PyArray1;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

pyo3::create_exception!(
    _feedloop,
    FeedloopError,
    PyException,
    "An error of feedloop: the message names the file, key or line and what is accepted."
);

/// An error as the CLI words it.
fn py_err(e: anyhow::Error) -> PyErr {
    FeedloopError::new_err(error_text(&e))
}

/// A folder of this process's own under the system's temporary folder, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> anyhow::Result<TempDir> {
        static N: AtomicU64 = AtomicU64::new(0);
        let p = std::env::temp_dir().join(format!(
            "feedloop-py-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&p)
            .with_context(|| format!("{}: cannot create folder", p.display()))?;
        Ok(TempDir(p))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A trace held in memory (trace format v1), column-major.
#[pyclass(frozen, name = "Trace", module = "feedloop")]
struct PyTrace {
    inner: Arc<Trace>,
}

#[pymethods]
impl PyTrace {
    /// Column names, in file order.
    #[getter]
    fn columns(&self) -> Vec<String> {
        self.inner.columns.clone()
    }

    /// Sampling period: the median time step, s.
    #[getter]
    fn period_s(&self) -> f64 {
        self.inner.period_s()
    }

    /// Where the trace came from.
    #[getter]
    fn path(&self) -> String {
        self.inner.path.display().to_string()
    }

    /// `# key=value` metadata, in file order.
    #[getter]
    fn meta(&self) -> Vec<(String, String)> {
        self.inner.meta.clone()
    }

    /// Axis names (those with both `A.cmd` and `A.load`).
    #[getter]
    fn axes(&self) -> Vec<String> {
        self.inner.axes()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __contains__(&self, name: &str) -> bool {
        self.inner.has(name)
    }

    /// The values of a column as a read-only float64 numpy array that views the trace's memory
    /// (no copy; `.copy()` gives a writable one); a missing column raises KeyError naming the
    /// file and the columns there are.
    fn __getitem__<'py>(slf: &Bound<'py, Self>, name: &str) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = slf
            .get()
            .inner
            .require(name)
            .map_err(|e| pyo3::exceptions::PyKeyError::new_err(e.to_string()))?;
        let view = numpy::ndarray::ArrayView1::from(c);
        // SAFETY: the array's base object is this trace, which keeps the column alive; the trace
        // is frozen behind an Arc and never changes, and the array is made read-only.
        let a = unsafe { PyArray1::borrow_from_array(&view, slf.clone().into_any()) };
        let kw = pyo3::types::PyDict::new(slf.py());
        kw.set_item("write", false)?;
        a.call_method("setflags", (), Some(&kw))?;
        Ok(a)
    }

    /// The trace as a pandas DataFrame, one float64 column per trace column (needs pandas).
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let pd = py.import("pandas").map_err(|_| {
            pyo3::exceptions::PyImportError::new_err(
                "Trace.to_pandas() needs pandas: pip install pandas",
            )
        })?;
        let cols = pyo3::types::PyDict::new(py);
        for (i, name) in self.inner.columns.iter().enumerate() {
            let c = self.inner.column_at(i).unwrap_or(&[]);
            cols.set_item(name, PyArray1::from_slice(py, c))?;
        }
        pd.call_method1("DataFrame", (cols,))
    }

    fn __repr__(&self) -> String {
        format!("<feedloop.Trace {}>", self.inner)
    }

    /// Writes the trace as a trace file (format v1), as the CLI writes it.
    fn write(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let tr = self.inner.clone();
        py.detach(move || {
            tr.write(&path)
                .with_context(|| format!("{}: cannot write", path.display()))
        })
        .map_err(py_err)
    }
}

/// Reads a trace file (format v1).
#[pyfunction]
fn read_trace(py: Python<'_>, path: PathBuf) -> PyResult<PyTrace> {
    let tr = py
        .detach(|| Trace::read(&path))
        .map_err(|e| py_err(e.into()))?;
    Ok(PyTrace {
        inner: Arc::new(tr),
    })
}

/// Simulates a job file in one process (what `feedloop sim` does) and returns its trace, read
/// back from the file the simulation wrote, so that it equals the CLI's trace.csv to the bit.
#[pyfunction]
fn simulate(py: Python<'_>, job: PathBuf) -> PyResult<PyTrace> {
    let tr = py
        .detach(|| -> anyhow::Result<Trace> {
            let j = feedloop_model::job::Job::load(&job)?;
            let dir = TempDir::new()?;
            let out = dir.0.join("trace.csv");
            feedloop_analysis::sim::simulate(
                &j,
                &feedloop_plugins::Builtins,
                Some(&out),
                &mut |_, _| {},
            )?;
            let mut tr = Trace::read(&out)?;
            tr.path = job.with_extension("sim.csv");
            Ok(tr)
        })
        .map_err(py_err)?;
    Ok(PyTrace {
        inner: Arc::new(tr),
    })
}

/// The trace argument: a `Trace` object or a path.
enum TraceArg {
    Held(Arc<Trace>),
    File(PathBuf),
}

impl TraceArg {
    fn of(obj: &Bound<'_, PyAny>) -> PyResult<TraceArg> {
        if let Ok(t) = obj.cast::<PyTrace>() {
            return Ok(TraceArg::Held(t.get().inner.clone()));
        }
        Ok(TraceArg::File(obj.extract::<PathBuf>().map_err(|_| {
            FeedloopError::new_err("trace: expected a feedloop.Trace or the path of a trace file")
        })?))
    }

    fn path(&self) -> PathBuf {
        match self {
            TraceArg::Held(t) => t.path.clone(),
            TraceArg::File(p) => p.clone(),
        }
    }
}

/// The model argument: the path of a model file, or its TOML text (written to a temporary
/// file, so that messages and the CLI's reading stay the same).
struct ModelArg {
    path: PathBuf,
    _dir: Option<TempDir>,
}

impl ModelArg {
    fn of(model: &str) -> anyhow::Result<ModelArg> {
        let p = Path::new(model);
        if p.exists() || !(model.contains('\n') || model.contains('=')) {
            return Ok(ModelArg {
                path: p.to_path_buf(),
                _dir: None,
            });
        }
        let dir = TempDir::new()?;
        let path = dir.0.join("model.toml");
        std::fs::write(&path, model)
            .with_context(|| format!("{}: cannot write", path.display()))?;
        Ok(ModelArg {
            path,
            _dir: Some(dir),
        })
    }
}

/// Reads the model and prepares the trace's axis it describes, as the CLI does.
fn load(
    trace: &TraceArg,
    model: &ModelArg,
    opts: &LoadOptions,
    need_torque: Option<&str>,
    held: bool,
) -> anyhow::Result<(
    WbModel,
    feedloop_analysis::workbench::data::AxisData,
    Vec<String>,
)> {
    feedloop_cli::workbench_load::check_window_and_cutoff(opts, None)?;
    let m = WbModel::load(&model.path)?;
    let tr = match trace {
        TraceArg::Held(t) => (**t).clone(),
        TraceArg::File(p) => read_axis_columns(p, opts)?,
    };
    Ok(prepare(m, tr, &model.path, opts, need_torque, held)?)
}

fn options(
    axis: Option<String>,
    cutoff_hz: Option<f64>,
    raw_torque: bool,
    window_s: f64,
    added_input: Option<String>,
) -> LoadOptions {
    LoadOptions {
        axis,
        cutoff_hz,
        raw_torque,
        window_s,
        added_input,
    }
}

/// `compare`: returns (JSON text, report HTML).
#[pyfunction]
#[pyo3(signature = (trace, model, axis=None, cutoff_hz=None, raw_torque=false, window_s=0.05, added_input=None))]
fn compare_json(
    py: Python<'_>,
    trace: &Bound<'_, PyAny>,
    model: &str,
    axis: Option<String>,
    cutoff_hz: Option<f64>,
    raw_torque: bool,
    window_s: f64,
    added_input: Option<String>,
) -> PyResult<(String, String)> {
    let trace = TraceArg::of(trace)?;
    let model = model.to_string();
    py.detach(move || -> anyhow::Result<(String, String)> {
        let opts = options(axis, cutoff_hz, raw_torque, window_s, added_input);
        let ma = ModelArg::of(&model)?;
        let (m, d, warnings) = load(&trace, &ma, &opts, None, false)?;
        let c = compare(&m, &d, opts.window_s);
        let mut j = c.to_json(&d);
        j["warnings"] = serde_json::json!(warnings);
        let title = format!(
            "compare: {} vs {}",
            ma.path.display(),
            trace.path().display()
        );
        let html = report::html(&d, &c, &title, "");
        Ok((j.to_string(), html))
    })
    .map_err(py_err)
}

/// `diagnose` (with `auto`, the guided loop): returns (JSON text, report HTML, final model
/// text when guided).
#[pyfunction]
#[pyo3(signature = (trace, model, auto_loop=false, max_steps=6, dictionary_columns=None, axis=None, cutoff_hz=None, raw_torque=false, window_s=0.05, added_input=None, report_html=false))]
fn diagnose_json(
    py: Python<'_>,
    trace: &Bound<'_, PyAny>,
    model: &str,
    auto_loop: bool,
    max_steps: usize,
    dictionary_columns: Option<Vec<String>>,
    axis: Option<String>,
    cutoff_hz: Option<f64>,
    raw_torque: bool,
    window_s: f64,
    added_input: Option<String>,
    report_html: bool,
) -> PyResult<(String, String, Option<String>)> {
    let trace = TraceArg::of(trace)?;
    let model = model.to_string();
    let extra_names = dictionary_columns.unwrap_or_default();
    py.detach(
        move || -> anyhow::Result<(String, String, Option<String>)> {
            let opts = options(axis, cutoff_hz, raw_torque, window_s, added_input);
            let ma = ModelArg::of(&model)?;
            let (m, d, warnings) = load(
                &trace,
                &ma,
                &opts,
                Some("diagnose (the equation error is measured on it)"),
                !auto_loop && !report_html,
            )?;
            if auto_loop {
                let r = auto(&m, &d, opts.window_s, max_steps)?;
                let text = r.model.text();
                let c = compare(&r.model, &d, opts.window_s);
                let extra = format!("{}{}", r.html(), diagnosis_html(&r.last));
                let html = report::html(&d, &c, "diagnose --auto: final model", &extra);
                let mut j = r.to_json();
                j["warnings"] = serde_json::json!(warnings);
                return Ok((j.to_string(), html, Some(text)));
            }
            let extra =
                feedloop_cli::workbench_load::dictionary_columns(&trace.path(), &extra_names, &d)?;
            let dg = diagnose(
                &m,
                &d,
                &DiagOptions {
                    extra_terms: extra,
                    ..DiagOptions::default()
                },
            );
            let j = diagnosis_json(&dg, &d, &warnings);
            let html = if report_html {
                let c = compare(&m, &d, opts.window_s);
                report::html(&d, &c, "diagnose", &diagnosis_html(&dg))
            } else {
                diagnosis_html(&dg)
            };
            Ok((j.to_string(), html, None))
        },
    )
    .map_err(py_err)
}

/// `fit`: returns (JSON text, the fitted model's text).
#[pyfunction]
#[pyo3(signature = (trace, model, add, free=None, axis=None, cutoff_hz=None, raw_torque=false, window_s=0.05, added_input=None))]
fn fit_json(
    py: Python<'_>,
    trace: &Bound<'_, PyAny>,
    model: &str,
    add: Vec<String>,
    free: Option<Vec<String>>,
    axis: Option<String>,
    cutoff_hz: Option<f64>,
    raw_torque: bool,
    window_s: f64,
    added_input: Option<String>,
) -> PyResult<(String, String)> {
    let trace = TraceArg::of(trace)?;
    let model = model.to_string();
    py.detach(move || -> anyhow::Result<(String, String)> {
        let opts = options(axis, cutoff_hz, raw_torque, window_s, added_input);
        let ma = ModelArg::of(&model)?;
        let (m, d, warnings) = load(&trace, &ma, &opts, None, false)?;
        let add = parse_effects(&add)?;
        let r = fit(&m, &d, &add, free.as_deref(), opts.window_s)?;
        let text = r.model.text();
        let mut j = r.to_json();
        let all: Vec<&String> = warnings.iter().chain(&r.warnings).collect();
        j["warnings"] = serde_json::json!(all);
        Ok((j.to_string(), text))
    })
    .map_err(py_err)
}

/// The native module.
#[pymodule]
fn _feedloop(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("FeedloopError", m.py().get_type::<FeedloopError>())?;
    m.add_class::<PyTrace>()?;
    m.add_function(wrap_pyfunction!(read_trace, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(compare_json, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose_json, m)?)?;
    m.add_function(wrap_pyfunction!(fit_json, m)?)?;
    Ok(())
}
