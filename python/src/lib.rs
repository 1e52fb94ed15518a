//! `hemodpd._hemodpd`: the native half of the Python package. It runs scenarios in-process
//! through the same code as the CLI (`hemodpd::run`), reads trajectories frame by frame
//! (`hemodpd_io::TrajectoryReader`) and runs the CLI's analyses. Structured results cross as JSON
//! text and arrays as raw little-endian bytes; `python/hemodpd/__init__.py` turns them into
//! dicts and numpy arrays. Every failure is a Python exception with the CLI's message.

use hemodpd_io::TrajectoryReader;
use pyo3::exceptions::{PyIndexError, PyKeyboardInterrupt, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Duration;

/// A library error as a Python `RuntimeError`, with the whole chain of causes.
fn runtime(e: impl Into<anyhow::Error>) -> PyErr {
    PyRuntimeError::new_err(format!("{:#}", e.into()))
}

fn to_json(v: &impl serde::Serialize) -> PyResult<String> {
    serde_json::to_string(v).map_err(runtime)
}

/// f64 values as native-endian bytes (numpy's `float64` on every platform we build for).
fn f64_bytes<'py>(py: Python<'py>, values: impl Iterator<Item = f64>) -> Bound<'py, PyBytes> {
    let buf: Vec<u8> = values.flat_map(f64::to_ne_bytes).collect();
    PyBytes::new(py, &buf)
}

fn vec3_bytes<'py>(py: Python<'py>, v: &[glam::DVec3]) -> Bound<'py, PyBytes> {
    f64_bytes(py, v.iter().flat_map(|p| [p.x, p.y, p.z]))
}

fn open(path: &Path) -> PyResult<TrajectoryReader> {
    TrajectoryReader::open(path).map_err(runtime)
}

/// Runs `work` on its own thread with the GIL released, polling Python's signal handlers every
/// 50 ms. A Ctrl-C asks the run to checkpoint and stop, exactly as the CLI's first Ctrl-C does,
/// waits for it, and raises `KeyboardInterrupt` with the run's message (how to resume).
fn run_interruptible<T: Send + 'static>(
    py: Python<'_>,
    work: impl FnOnce() -> anyhow::Result<T> + Send + 'static,
) -> PyResult<T> {
    hemodpd_scenario::INTERRUPTED.store(false, Ordering::SeqCst);
    let handle = std::thread::spawn(work);
    let mut interrupted = None;
    while !handle.is_finished() {
        py.detach(|| std::thread::sleep(Duration::from_millis(50)));
        if interrupted.is_none() {
            if let Err(e) = py.check_signals() {
                hemodpd_scenario::INTERRUPTED.store(true, Ordering::SeqCst);
                interrupted = Some(e);
            }
        }
    }
    let result = handle.join();
    hemodpd_scenario::INTERRUPTED.store(false, Ordering::SeqCst);
    let result = result.map_err(|_| PyRuntimeError::new_err("the run panicked (a bug: please report it)"))?;
    match (result, interrupted) {
        (Ok(v), None) => Ok(v),
        (Err(e), Some(_)) => Err(PyKeyboardInterrupt::new_err(format!("{e:#}"))),
        // the signal came as the run finished: the result stands, the interrupt goes on
        (Ok(_), Some(sig)) => Err(sig),
        (Err(e), None) => Err(run_error(e)),
    }
}

/// A bad scenario (a key, a value, a missing file) as `ValueError`; anything else as
/// `RuntimeError`.
fn run_error(e: anyhow::Error) -> PyErr {
    if e.chain().any(|c| c.is::<hemodpd_scenario::ScenarioError>()) {
        PyValueError::new_err(format!("{e:#}"))
    } else {
        runtime(e)
    }
}

/// Runs the scenario file `path` with `sets` (`KEY=VALUE`) into `out` (default `runs/STEM`);
/// returns (summary.json text, run directory).
#[pyfunction]
#[pyo3(signature = (path, sets, out=None, threads=None, quiet=false))]
fn run_scenario(
    py: Python<'_>,
    path: PathBuf,
    sets: Vec<String>,
    out: Option<PathBuf>,
    threads: Option<usize>,
    quiet: bool,
) -> PyResult<(String, String)> {
    let out_dir = out.unwrap_or_else(|| hemodpd::run::default_out_dir(&path));
    let dir = out_dir.clone();
    let summary = run_interruptible(py, move || {
        hemodpd::run::run_one(&path, &sets, Some(dir), threads, quiet)
    })?;
    Ok((to_json(&summary)?, out_dir.display().to_string()))
}

/// Resumes the run in `dir` from its checkpoint; returns the summary.json text.
#[pyfunction]
#[pyo3(signature = (dir, threads=None, quiet=false))]
fn resume_run(py: Python<'_>, dir: PathBuf, threads: Option<usize>, quiet: bool) -> PyResult<String> {
    let d = dir.clone();
    run_interruptible(py, move || hemodpd::run::resume_run(&d, threads, quiet))?;
    std::fs::read_to_string(dir.join("summary.json")).map_err(runtime)
}

/// A scenario given as JSON text (a dict on the Python side) as TOML text, checked: the same
/// validation as a file, with `sets` applied, so a bad key fails here with its name.
#[pyfunction]
#[pyo3(signature = (json_text, sets))]
fn scenario_toml_from_json(json_text: &str, sets: Vec<String>) -> PyResult<String> {
    let value: Value = serde_json::from_str(json_text).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let table: toml::Table = toml::Table::try_from(value)
        .map_err(|e| PyValueError::new_err(format!("the scenario dict is not a TOML table: {e}")))?;
    let text = toml::to_string(&table).map_err(runtime)?;
    hemodpd_scenario::load_str(&text, "<scenario dict>", &sets).map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(text)
}

/// The unit mapping of a scenario (a file, or TOML text) as JSON: kind, the `--explain-units`
/// text and, for kinds written in SI, the scales, the fluid and the groups.
#[pyfunction]
#[pyo3(signature = (path=None, text=None, sets=Vec::new()))]
fn explain_units(path: Option<PathBuf>, text: Option<String>, sets: Vec<String>) -> PyResult<String> {
    let scenario = match (path, text) {
        (Some(p), None) => hemodpd_scenario::load(&p, &sets),
        (None, Some(t)) => hemodpd_scenario::load_str(&t, "<scenario dict>", &sets),
        _ => return Err(PyValueError::new_err("give a scenario file or a scenario dict")),
    }
    .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let text = scenario.explain_units().transpose().map_err(runtime)?;
    let mapping = scenario.unit_mapping_json().transpose().map_err(runtime)?;
    to_json(&json!({ "kind": scenario.kind(), "text": text, "mapping": mapping }))
}

/// What a trajectory holds, as JSON: metadata, membrane frames (steps, times, vertex count,
/// scalars), fluid frames and binned fields (grid, components, units, frames).
#[pyfunction]
fn trajectory_info(path: PathBuf) -> PyResult<String> {
    let r = open(&path)?;
    let meta = r.metadata();
    let mut fields = serde_json::Map::new();
    for name in r.field_names().map_err(runtime)? {
        let f = r.field_info(&name).map_err(runtime)?;
        fields.insert(
            name,
            json!({
                "origin_m": f.grid.origin.to_array(), "spacing_m": f.grid.spacing.to_array(),
                "shape": f.grid.shape, "components": f.components, "units": f.units, "frames": f.frames,
            }),
        );
    }
    let has_membrane = r.has_membrane();
    let (steps, times, scalars, vertices, triangles) = if has_membrane {
        let n = r.membrane_frames().map_err(runtime)?;
        let vertices = if n > 0 {
            r.membrane_frame(0).map_err(runtime)?.positions.len()
        } else {
            0
        };
        (
            r.membrane_steps().map_err(runtime)?,
            r.membrane_times().map_err(runtime)?,
            r.membrane_scalar_names().map_err(runtime)?,
            vertices,
            r.triangles().map_err(runtime)?.len(),
        )
    } else {
        (Vec::new(), Vec::new(), Vec::new(), 0, 0)
    };
    to_json(&json!({
        "path": path, "scenario_kind": meta.scenario_name, "scenario_toml": meta.scenario_toml,
        "has_membrane": has_membrane, "membrane_steps": steps, "membrane_times_s": times,
        "vertices": vertices, "triangles": triangles, "membrane_scalars": scalars,
        "fluid_frames": r.fluid_frames().map_err(runtime)?, "fields": fields,
    }))
}

fn check_index(i: usize, n: usize, what: &str) -> PyResult<()> {
    if i >= n {
        return Err(PyIndexError::new_err(format!("{what} frame {i}: the file has {n}")));
    }
    Ok(())
}

/// Membrane frame `i`: (step, time s, positions m as bytes, velocities m/s as bytes or None).
#[allow(clippy::type_complexity)]
#[pyfunction]
fn membrane_frame<'py>(
    py: Python<'py>,
    path: PathBuf,
    i: usize,
) -> PyResult<(u64, f64, Bound<'py, PyBytes>, Option<Bound<'py, PyBytes>>)> {
    let r = open(&path)?;
    check_index(i, r.membrane_frames().map_err(runtime)?, "membrane")?;
    let f = r.membrane_frame(i).map_err(runtime)?;
    let v = f.velocities.as_ref().map(|v| vec3_bytes(py, v));
    Ok((f.step, f.time, vec3_bytes(py, &f.positions), v))
}

/// The membrane's triangles as u32 bytes (3 vertex indices each).
#[pyfunction]
fn triangles<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyBytes>> {
    let t = open(&path)?.triangles().map_err(runtime)?;
    let buf: Vec<u8> = t.iter().flatten().flat_map(|k| k.to_ne_bytes()).collect();
    Ok(PyBytes::new(py, &buf))
}

/// A per-frame membrane scalar (e.g. the stretching force) as f64 bytes.
#[pyfunction]
fn membrane_scalar<'py>(py: Python<'py>, path: PathBuf, name: &str) -> PyResult<Bound<'py, PyBytes>> {
    let v = open(&path)?.membrane_scalar(name).map_err(runtime)?;
    Ok(f64_bytes(py, v.into_iter()))
}

/// Frame `i` of binned field `name`: (step, time s, values as f64 bytes, x fastest, then the
/// components).
#[pyfunction]
fn field_frame<'py>(py: Python<'py>, path: PathBuf, name: &str, i: usize) -> PyResult<(u64, f64, Bound<'py, PyBytes>)> {
    let r = open(&path)?;
    check_index(i, r.field_info(name).map_err(runtime)?.frames, name)?;
    let f = r.field_frame(name, i).map_err(runtime)?;
    Ok((f.step, f.time, f64_bytes(py, f.values.into_iter())))
}

/// Fluid frame `i`: (step, time s, positions, velocities or None, types as u8 bytes or None).
#[allow(clippy::type_complexity)]
#[pyfunction]
fn fluid_frame<'py>(
    py: Python<'py>,
    path: PathBuf,
    i: usize,
) -> PyResult<(
    u64,
    f64,
    Bound<'py, PyBytes>,
    Option<Bound<'py, PyBytes>>,
    Option<Bound<'py, PyBytes>>,
)> {
    let r = open(&path)?;
    check_index(i, r.fluid_frames().map_err(runtime)?, "fluid")?;
    let f = r.fluid_frame(i).map_err(runtime)?;
    let v = f.velocities.as_ref().map(|v| vec3_bytes(py, v));
    let t = f.types.as_ref().map(|t| PyBytes::new(py, t));
    Ok((f.step, f.time, vec3_bytes(py, &f.positions), v, t))
}

/// `hemodpd analyze`'s per-frame shape metrics (and rotation for shear runs) as JSON.
#[pyfunction]
fn analyze(path: PathBuf) -> PyResult<String> {
    let a = hemodpd_io::analysis::analyze_file(&path, &hemodpd_io::analysis::AnalysisOptions::default())
        .map_err(runtime)?;
    to_json(&a)
}

/// The capillary measures of every frame (the run's `cell.csv` columns) as JSON.
#[pyfunction]
fn capillary_measures(path: PathBuf) -> PyResult<String> {
    to_json(&hemodpd_scenario::capillary::analyze_trajectory(&path).map_err(runtime)?)
}

/// A shear run's per-frame motion and its classification (from `start_strain` on, default the
/// run's own window) as JSON `{"frames": [...], "classification": {...}}`.
#[pyfunction]
#[pyo3(signature = (path, start_strain=None))]
fn shear_motion(path: PathBuf, start_strain: Option<f64>) -> PyResult<String> {
    let (frames, class) = hemodpd_scenario::shear::analyze_trajectory(&path, start_strain).map_err(runtime)?;
    to_json(&json!({ "frames": frames, "classification": class }))
}

/// The table of a sweep directory (what `sweep.json` holds), collected now, as JSON.
#[pyfunction]
fn sweep_table(dir: PathBuf) -> PyResult<String> {
    to_json(&hemodpd::sweep::table_json(&dir).map_err(runtime)?)
}

#[pymodule]
fn _hemodpd(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run_scenario, m)?)?;
    m.add_function(wrap_pyfunction!(resume_run, m)?)?;
    m.add_function(wrap_pyfunction!(scenario_toml_from_json, m)?)?;
    m.add_function(wrap_pyfunction!(explain_units, m)?)?;
    m.add_function(wrap_pyfunction!(trajectory_info, m)?)?;
    m.add_function(wrap_pyfunction!(membrane_frame, m)?)?;
    m.add_function(wrap_pyfunction!(triangles, m)?)?;
    m.add_function(wrap_pyfunction!(membrane_scalar, m)?)?;
    m.add_function(wrap_pyfunction!(field_frame, m)?)?;
    m.add_function(wrap_pyfunction!(fluid_frame, m)?)?;
    m.add_function(wrap_pyfunction!(analyze, m)?)?;
    m.add_function(wrap_pyfunction!(capillary_measures, m)?)?;
    m.add_function(wrap_pyfunction!(shear_motion, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_table, m)?)?;
    Ok(())
}
