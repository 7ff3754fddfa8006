//! `visco._native`: the Rust side of the Python package `visco` (python/visco/).
//!
//! Thin on purpose: every number comes from the host crate `visco` (host-sim), the same code
//! the `visco` command runs. This module only moves data across: recordings as a metadata dict
//! and named numpy columns, reports as the JSON text the command writes (the Python side
//! parses it with `json.loads`), per-sample series as numpy arrays, errors as `ViscoError`
//! carrying the command's `FILE[:ENTRY][:LINE]: reason (fix: ...)` text and its parts.
//!
//! Long calls run with the GIL released; `diagnose` checks for Ctrl-C (and calls the caller's
//! progress callback) at every step of its search.
#![forbid(unsafe_code)]

use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::{PyKeyError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use visco::diagnose::report::analyse;
use visco::diagnose::search::SearchOptions;
use visco::experiment::concealed;
use visco::identify::{identify, IdentifyError, Options as IdentifyOptions};
use visco::plant::effects::EffectKind;
use visco::recording::import::{Import, ImportOptions};
use visco::recording::{keys, Column, Metadata, Mode, Recording, RecordingError};
use visco_core::DiveRegressor;

create_exception!(
    _native,
    ViscoError,
    PyValueError,
    "A refusal of the visco tools: `str(e)` is the command line's one-line message \
     `FILE[:ENTRY][:LINE]: reason (fix: ...)`; the parts are e.file, e.entry, e.line, e.reason, \
     e.fix."
);

/// A `ViscoError` with the parts set as attributes.
fn visco_error(
    py: Python<'_>,
    file: &Path,
    entry: Option<&str>,
    line: Option<u64>,
    reason: &str,
    fix: Option<&str>,
    text: String,
) -> PyErr {
    let err = ViscoError::new_err(text);
    let v = err.value(py);
    // Setting attributes on a fresh exception instance cannot fail.
    let _ = v.setattr("file", file.display().to_string());
    let _ = v.setattr("entry", entry);
    let _ = v.setattr("line", line);
    let _ = v.setattr("reason", reason);
    let _ = v.setattr("fix", fix);
    err
}

fn recording_error(py: Python<'_>, e: &RecordingError) -> PyErr {
    visco_error(
        py,
        &e.file,
        e.entry.as_deref(),
        e.line,
        &e.reason,
        e.fix.as_deref(),
        e.to_string(),
    )
}

fn identify_error(py: Python<'_>, e: &IdentifyError) -> PyErr {
    visco_error(
        py,
        &e.file,
        e.entry.as_deref(),
        e.line,
        &e.reason,
        e.fix.as_deref(),
        e.to_string(),
    )
}

// ---------------------------------------------------------------------------------------
// Recordings across the boundary
// ---------------------------------------------------------------------------------------

/// The metadata as a dict keyed by the contract's names (`recording.md`): the typed values as
/// int/str/float (absent optional values left out), every other key as its text.
fn meta_to_py<'py>(py: Python<'py>, m: &Metadata) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item(keys::VERSION, m.version)?;
    d.set_item(keys::MODE, m.mode.as_str())?;
    d.set_item(keys::SAMPLE_RATE_HZ, m.sample_rate_hz)?;
    d.set_item(keys::CANTILEVER_K_N_PER_M, m.cantilever_k_n_per_m)?;
    let optional = [
        (keys::CANTILEVER_C_NS_PER_M, m.cantilever_c_ns_per_m),
        (keys::CANTILEVER_M_KG, m.cantilever_m_kg),
        (keys::CANTILEVER_F0_HZ, m.cantilever_f0_hz),
        (keys::CANTILEVER_Q, m.cantilever_q),
    ];
    for (k, v) in optional {
        if let Some(v) = v {
            d.set_item(k, v)?;
        }
    }
    d.set_item(keys::TIP_RADIUS_M, m.tip_radius_m)?;
    if let Some(v) = m.deflection_noise_m {
        d.set_item(keys::DEFLECTION_NOISE_M, v)?;
    }
    for (k, v) in &m.extra {
        d.set_item(k, v)?;
    }
    Ok(d)
}

/// Every column, in the file's order, as (name, float64 array); `tap` as an int64 array.
fn columns_to_py<'py>(py: Python<'py>, r: &Recording) -> PyResult<Bound<'py, PyList>> {
    let out = PyList::empty(py);
    let f = |v: &[f64]| PyArray1::from_slice(py, v);
    out.append(("t_s", f(&r.t_s)))?;
    out.append(("u_m", f(&r.u_m)))?;
    out.append(("d_m", f(&r.d_m)))?;
    if let (Some(x), Some(y)) = (&r.x_m, &r.y_m) {
        out.append(("x_m", f(x)))?;
        out.append(("y_m", f(y)))?;
    }
    if let Some(t) = &r.tap {
        let v: Vec<i64> = t.iter().map(|&x| i64::from(x)).collect();
        out.append(("tap", PyArray1::from_vec(py, v)))?;
    }
    for c in &r.extra {
        out.append((c.name.as_str(), f(&c.values)))?;
    }
    Ok(out)
}

fn recording_to_py<'py>(
    py: Python<'py>,
    r: &Recording,
) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyList>)> {
    Ok((meta_to_py(py, &r.meta)?, columns_to_py(py, r)?))
}

/// A float metadata value: a number, or the text of one.
fn meta_f64(d: &Bound<'_, PyDict>, key: &str) -> PyResult<Option<f64>> {
    match d.get_item(key)? {
        None => Ok(None),
        Some(v) if v.is_none() => Ok(None),
        Some(v) => {
            if let Ok(s) = v.extract::<String>() {
                s.trim().parse::<f64>().map(Some).map_err(|_| {
                    PyValueError::new_err(format!("metadata `{key}`: `{s}` is not a number"))
                })
            } else {
                v.extract::<f64>().map(Some).map_err(|_| {
                    PyValueError::new_err(format!("metadata `{key}` must be a number"))
                })
            }
        }
    }
}

fn required_f64(d: &Bound<'_, PyDict>, key: &str) -> PyResult<f64> {
    meta_f64(d, key)?.ok_or_else(|| PyKeyError::new_err(format!("metadata `{key}` is required")))
}

/// The metadata dict back into typed metadata (values range-checked later, by the writer).
fn meta_from_py(d: &Bound<'_, PyDict>) -> PyResult<Metadata> {
    let mode_text: String = match d.get_item(keys::MODE)? {
        Some(v) => v.extract()?,
        None => return Err(PyKeyError::new_err("metadata `mode` is required")),
    };
    let mode = Mode::parse(&mode_text).ok_or_else(|| {
        PyValueError::new_err(format!(
            "mode `{mode_text}` is not one of dive, sve, force-curve"
        ))
    })?;
    let mut m = Metadata::new(
        mode,
        required_f64(d, keys::SAMPLE_RATE_HZ)?,
        required_f64(d, keys::CANTILEVER_K_N_PER_M)?,
        required_f64(d, keys::TIP_RADIUS_M)?,
    );
    if let Some(v) = d.get_item(keys::VERSION)? {
        m.version = v.str()?.to_string().trim().parse().map_err(|_| {
            PyValueError::new_err("metadata `visco-recording` must be a whole number")
        })?;
    }
    m.cantilever_c_ns_per_m = meta_f64(d, keys::CANTILEVER_C_NS_PER_M)?;
    m.cantilever_m_kg = meta_f64(d, keys::CANTILEVER_M_KG)?;
    m.cantilever_f0_hz = meta_f64(d, keys::CANTILEVER_F0_HZ)?;
    m.cantilever_q = meta_f64(d, keys::CANTILEVER_Q)?;
    m.deflection_noise_m = meta_f64(d, keys::DEFLECTION_NOISE_M)?;
    for (k, v) in d.iter() {
        let k: String = k.extract()?;
        if keys::TYPED.contains(&k.as_str()) || v.is_none() {
            continue;
        }
        // Kept as text, as in the file.
        m.extra.push((k, v.str()?.to_string()));
    }
    Ok(m)
}

/// Metadata and (name, float64 array) columns into a recording (the contract is checked when
/// it is written, by [`checked`]).
fn recording_from_py(
    meta: &Bound<'_, PyDict>,
    columns: Vec<(String, PyReadonlyArray1<'_, f64>)>,
) -> PyResult<Recording> {
    let mut rec = Recording::new(meta_from_py(meta)?);
    let mut seen = [false; 3];
    for (name, arr) in columns {
        let v = arr.as_array().to_vec();
        match name.as_str() {
            "t_s" => (rec.t_s, seen[0]) = (v, true),
            "u_m" => (rec.u_m, seen[1]) = (v, true),
            "d_m" => (rec.d_m, seen[2]) = (v, true),
            "x_m" => rec.x_m = Some(v),
            "y_m" => rec.y_m = Some(v),
            "tap" => {
                let mut t = Vec::with_capacity(v.len());
                for (i, x) in v.iter().enumerate() {
                    if !(x.fract() == 0.0 && *x >= 0.0 && *x <= f64::from(u32::MAX)) {
                        return Err(PyValueError::new_err(format!(
                            "column `tap`, row {}: {x} is not a non-negative whole number",
                            i + 1
                        )));
                    }
                    t.push(*x as u32);
                }
                rec.tap = Some(t);
            }
            _ => rec.extra.push(Column { name, values: v }),
        }
    }
    if seen != [true; 3] {
        return Err(PyValueError::new_err(
            "a recording needs the columns t_s, u_m and d_m",
        ));
    }
    Ok(rec)
}

/// Checks the recording against the contract by writing it where it is needed (`path`), with
/// the writer the command line uses, so that the refusals are the same; errors name `label`
/// instead of a temporary path.
fn write_checked(
    py: Python<'_>,
    rec: &Recording,
    path: &Path,
    label: Option<&str>,
) -> PyResult<()> {
    py.detach(|| rec.write(path)).map_err(|mut e| {
        if let Some(l) = label {
            e.file = PathBuf::from(l);
        }
        recording_error(py, &e)
    })
}

// ---------------------------------------------------------------------------------------
// The functions
// ---------------------------------------------------------------------------------------

/// Reads a recording CSV or imports a vendor file. Returns (format, [(curve, meta, columns)],
/// warnings).
#[pyfunction]
#[pyo3(signature = (path, curve=None, all=false, spring_constant=None, sensitivity=None, tip_radius=None, sample_rate=None))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn read<'py>(
    py: Python<'py>,
    path: PathBuf,
    curve: Option<usize>,
    all: bool,
    spring_constant: Option<f64>,
    sensitivity: Option<f64>,
    tip_radius: Option<f64>,
    sample_rate: Option<f64>,
) -> PyResult<(
    String,
    Vec<(usize, Bound<'py, PyDict>, Bound<'py, PyList>)>,
    Vec<String>,
)> {
    let is_recording = py.detach(|| {
        let mut head = [0u8; 17];
        std::fs::File::open(&path)
            .and_then(|mut f| std::io::Read::read(&mut f, &mut head))
            .map(|n| head[..n].starts_with(b"# visco-recording"))
            .unwrap_or(false)
    });
    if is_recording {
        let rec = py
            .detach(|| Recording::read(&path))
            .map_err(|e| recording_error(py, &e))?;
        let (m, c) = recording_to_py(py, &rec)?;
        return Ok(("visco-recording".into(), vec![(0, m, c)], Vec::new()));
    }
    let opts = ImportOptions {
        spring_constant_n_per_m: spring_constant,
        sensitivity_m_per_unit: sensitivity,
        tip_radius_m: tip_radius,
        sample_rate_hz: sample_rate,
    };
    let (format, recs, warnings) = py
        .detach(|| -> Result<_, RecordingError> {
            let mut imp = Import::open(&path, &opts)?;
            let available = imp.curves();
            let chosen: Vec<usize> = match curve {
                Some(c) => vec![c],
                None if all || available.len() == 1 => available,
                None => {
                    return Err(RecordingError::new(
                        &path,
                        visco::recording::ErrorKind::Usage,
                        format!("the map holds {} curves", available.len()),
                    )
                    .with_fix("pass curve=INDEX for one, or call visco.read_all for all"))
                }
            };
            let mut recs = Vec::with_capacity(chosen.len());
            for c in chosen {
                recs.push((c, imp.read_curve(c)?));
            }
            Ok((imp.format().name(), recs, imp.warnings().to_vec()))
        })
        .map_err(|e| recording_error(py, &e))?;
    let mut out = Vec::with_capacity(recs.len());
    for (c, r) in &recs {
        let (m, cols) = recording_to_py(py, r)?;
        out.push((*c, m, cols));
    }
    Ok((format.to_string(), out, warnings))
}

/// Writes a recording CSV (atomically, checked against the contract); errors name `label`
/// instead of `path` when given.
#[pyfunction]
#[pyo3(signature = (meta, columns, path, label=None))]
fn write(
    py: Python<'_>,
    meta: &Bound<'_, PyDict>,
    columns: Vec<(String, PyReadonlyArray1<'_, f64>)>,
    path: PathBuf,
    label: Option<&str>,
) -> PyResult<()> {
    let rec = recording_from_py(meta, columns)?;
    write_checked(py, &rec, &path, label)
}

/// Identifies the recording CSV at `path` exactly as `visco identify PATH --json JSON` does
/// (every output written); returns the report's JSON text and the files written.
#[pyfunction]
#[pyo3(signature = (path, json, out_dir=None, regressor="offset", element_pitch=100e-9, lattice_origin=None, readout=10e-3, pixels=50, lines=None, contact_sigma=5.0))]
#[allow(clippy::too_many_arguments)]
fn identify_file(
    py: Python<'_>,
    path: PathBuf,
    json: PathBuf,
    out_dir: Option<PathBuf>,
    regressor: &str,
    element_pitch: f64,
    lattice_origin: Option<[f64; 2]>,
    readout: f64,
    pixels: usize,
    lines: Option<usize>,
    contact_sigma: f64,
) -> PyResult<(String, Vec<PathBuf>)> {
    let regressor = match regressor {
        "offset" => DiveRegressor::Offset,
        "paper" => DiveRegressor::Paper,
        other => {
            return Err(PyValueError::new_err(format!(
                "regressor `{other}` is not one of offset, paper"
            )))
        }
    };
    let opts = IdentifyOptions {
        json: json.clone(),
        out_dir,
        regressor,
        element_pitch_m: element_pitch,
        lattice_origin_m: lattice_origin,
        readout_s: readout,
        pixels,
        lines,
        contact_sigma,
    };
    let report = py
        .detach(|| identify(&path, &opts))
        .map_err(|e| identify_error(py, &e))?;
    Ok((visco::report::to_pretty(&report.json), report.files))
}

/// The panic payload that carries a Ctrl-C (or a raising progress callback) out of the
/// diagnosis: raised with `resume_unwind`, which runs no panic hook (nothing printed).
struct Interrupted(PyErr);

/// Diagnoses a recording held in memory (checked against the contract by the caller, with
/// `write`) as `visco diagnose` does; returns the report's JSON
/// text (the command's, less the output file names) and the per-sample series as
/// (name, array) columns, `phase` as a list of str.
#[pyfunction]
#[pyo3(signature = (meta, columns, label, alpha=0.01, max_effects=3, effects=None, progress=None))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn diagnose<'py>(
    py: Python<'py>,
    meta: &Bound<'py, PyDict>,
    columns: Vec<(String, PyReadonlyArray1<'py, f64>)>,
    label: String,
    alpha: f64,
    max_effects: usize,
    effects: Option<Vec<String>>,
    progress: Option<Py<PyAny>>,
) -> PyResult<(String, Bound<'py, PyList>)> {
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(PyValueError::new_err(format!(
            "alpha = {alpha} is not in (0, 1)"
        )));
    }
    let kinds = match effects {
        None => EffectKind::ALL.to_vec(),
        Some(names) => names
            .iter()
            .map(|s| {
                EffectKind::parse(s).ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "`{s}` is not an effect; one of {}",
                        EffectKind::ALL.map(|k| k.as_str()).join(", ")
                    ))
                })
            })
            .collect::<PyResult<Vec<_>>>()?,
    };
    // The caller has checked the contract (`Recording.check`, as the command's reader does).
    let rec = recording_from_py(meta, columns)?;
    let opts = SearchOptions {
        alpha,
        max_effects,
        kinds,
        // The command's default (the machine's cores); the result does not depend on it.
        ..SearchOptions::default()
    };
    let outcome = py.detach(|| {
        catch_unwind(AssertUnwindSafe(|| {
            analyse(&rec, &opts, |step: &str| {
                let r = Python::attach(|py| -> PyResult<()> {
                    py.check_signals()?;
                    if let Some(cb) = &progress {
                        cb.call1(py, (step,))?;
                    }
                    Ok(())
                });
                if let Err(e) = r {
                    resume_unwind(Box::new(Interrupted(e)));
                }
            })
            .map(|d| {
                (
                    visco::report::to_pretty(&d.to_json(&label, &rec)),
                    d.series_csv(),
                )
            })
        }))
    });
    let (json, series) = match outcome {
        Ok(Ok(v)) => v,
        Ok(Err(reason)) => {
            let e = IdentifyError::new(Path::new(&label), reason);
            return Err(identify_error(py, &e));
        }
        Err(payload) => match payload.downcast::<Interrupted>() {
            Ok(i) => return Err(i.0),
            Err(other) => resume_unwind(other),
        },
    };
    Ok((json, parse_series(py, &series)?))
}

/// A series CSV (`# comment` lines, a header, rows) as (name, column) pairs: float64 arrays,
/// or lists of str for text columns. Numbers are written in shortest round-trip notation, so
/// they come back bit for bit.
fn parse_series<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyList>> {
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let names: Vec<&str> = match lines.next() {
        Some(h) => h.split(',').collect(),
        None => return Ok(PyList::empty(py)),
    };
    let mut cells: Vec<Vec<&str>> = vec![Vec::new(); names.len()];
    for l in lines.filter(|l| !l.is_empty()) {
        for (i, c) in l.split(',').enumerate() {
            if let Some(col) = cells.get_mut(i) {
                col.push(c);
            }
        }
    }
    let out = PyList::empty(py);
    for (name, col) in names.iter().zip(&cells) {
        let nums: Option<Vec<f64>> = col
            .iter()
            .map(|c| match *c {
                "NaN" | "nan" => Some(f64::NAN),
                c => c.parse::<f64>().ok(),
            })
            .collect();
        match nums {
            Some(v) => out.append((*name, PyArray1::from_vec(py, v)))?,
            None => out.append((*name, col.clone()))?,
        }
    }
    Ok(out)
}

/// Reads a series CSV the tools wrote (`<stem>_fit.csv`, `<stem>_series.csv`).
#[pyfunction]
fn read_series<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyList>> {
    let text = std::fs::read_to_string(&path).map_err(|e| {
        let e = IdentifyError::io(&path, "cannot read", &e);
        identify_error(py, &e)
    })?;
    parse_series(py, &text)
}

/// The simulated instruments `simulate` offers (the concealed-effect suite's setups).
#[pyfunction]
fn setups() -> Vec<(String, bool, f64, f64, f64)> {
    concealed::setups()
        .into_iter()
        .map(|s| {
            (
                s.name.to_string(),
                s.tap,
                s.cantilever.k_n_per_m,
                s.tip_radius_m,
                s.rate_hz,
            )
        })
        .collect()
}

/// Every effect's identifier and the physics it stands for.
#[pyfunction]
fn effects() -> Vec<(&'static str, &'static str)> {
    EffectKind::ALL
        .iter()
        .map(|k| (k.as_str(), k.physics()))
        .collect()
}

/// One tap or force curve on a simulated instrument with the named effects. Returns the
/// recording (meta, columns), the noise-free D with and without the effects, the noise RMS
/// and each effect's parameters and peak |ΔD| over the noise RMS.
#[pyfunction]
#[pyo3(signature = (setup, effects=Vec::new(), magnitude=5.0, seed=0, noise=true))]
#[allow(clippy::type_complexity)]
fn simulate<'py>(
    py: Python<'py>,
    setup: &str,
    effects: Vec<String>,
    magnitude: f64,
    seed: u64,
    noise: bool,
) -> PyResult<(
    Bound<'py, PyDict>,
    Bound<'py, PyList>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    f64,
    Vec<(String, Vec<(String, f64)>, f64)>,
)> {
    let kinds = effects
        .iter()
        .map(|s| {
            EffectKind::parse(s).ok_or_else(|| {
                PyValueError::new_err(format!(
                    "`{s}` is not an effect; one of {}",
                    EffectKind::ALL.map(|k| k.as_str()).join(", ")
                ))
            })
        })
        .collect::<PyResult<Vec<_>>>()?;
    let sim = py
        .detach(|| concealed::simulate(setup, &kinds, magnitude, seed, noise))
        .map_err(PyValueError::new_err)?;
    let (m, c) = recording_to_py(py, &sim.recording)?;
    let found = sim
        .effects
        .iter()
        .map(|(spec, ratio)| (spec.kind().as_str().to_string(), spec.parameters(), *ratio))
        .collect();
    Ok((
        m,
        c,
        PyArray1::from_slice(py, &sim.truth_d_m),
        PyArray1::from_slice(py, &sim.clean_d_m),
        sim.noise_m,
        found,
    ))
}

/// The extension module.
#[pymodule]
#[pyo3(name = "_native")]
fn native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("ViscoError", m.py().get_type::<ViscoError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(write, m)?)?;
    m.add_function(wrap_pyfunction!(identify_file, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(read_series, m)?)?;
    m.add_function(wrap_pyfunction!(setups, m)?)?;
    m.add_function(wrap_pyfunction!(effects, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    Ok(())
}
