//! `bostrack._bostrack`: the extension module behind the Python package `bostrack`
//! (python/bostrack/__init__.py wraps it into the documented functions).
//!
//! Every function calls the library crates (no subprocess): `locate` is
//! `bostrack_pipeline::locate`, `run` is `bostrack_pipeline::run_batch`, `fields` reads a
//! `dots.csv` into `bostrack_pipeline::LatticeFields`, `crlb` is `bostrack_theory::predict`.
//! The GIL is released while they compute; `run` works in a thread of its own and the calling
//! thread looks for signals (Ctrl-C) every 50 ms, asking the run to stop between frames. Errors
//! are Python exceptions carrying the message the command-line interface prints.

use bostrack_core::{Image, ImageMeta, Mask, NoiseModel};
use bostrack_io::Saturation;
use bostrack_pipeline::{
    BatchError, BatchOptions, FieldValues, FrameEvent, FrameStatus, LOCATE_COLUMNS, LatticeFields,
    LocateOptions, Plan, Progress, locate as locate_dots, parse_model, run_batch,
};
use numpy::{IntoPyArray, PyReadonlyArray2};
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

/// An error of a library call as a Python exception with its one-line message: files that are
/// not there are `FileNotFoundError`, other input and output problems `OSError`, the rest
/// `ValueError` (bad configuration or input values) or `RuntimeError`.
fn py_err(e: impl std::fmt::Display, kind: ErrKind) -> PyErr {
    let msg = e.to_string().replace('\n', " ");
    match kind {
        ErrKind::Value => PyValueError::new_err(msg),
        ErrKind::Os => PyOSError::new_err(msg),
        ErrKind::Runtime => PyRuntimeError::new_err(msg),
    }
}

#[derive(Clone, Copy)]
enum ErrKind {
    Value,
    Os,
    Runtime,
}

fn io_err(e: bostrack_io::IoError) -> PyErr {
    let msg = e.to_string();
    match e.kind {
        bostrack_io::IoErrorKind::NotFound => PyFileNotFoundError::new_err(msg),
        _ => PyOSError::new_err(msg),
    }
}

/// A 2-D numpy array of one of the image dtypes as an [`Image`] (samples copied in row-major
/// order whatever the array's strides), with the metadata of its bit depth.
fn array_image(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Image> {
    fn copy<T: numpy::Element + Copy + Into<f64>>(
        a: PyReadonlyArray2<'_, T>,
    ) -> (usize, usize, Vec<f64>) {
        let v = a.as_array();
        let (h, w) = v.dim();
        (w, h, v.iter().map(|&x| x.into()).collect())
    }
    let (w, h, data, bits) = if let Ok(a) = obj.extract::<PyReadonlyArray2<'_, u8>>() {
        let (w, h, d) = copy(a);
        (w, h, d, 8)
    } else if let Ok(a) = obj.extract::<PyReadonlyArray2<'_, u16>>() {
        let (w, h, d) = copy(a);
        (w, h, d, 16)
    } else if let Ok(a) = obj.extract::<PyReadonlyArray2<'_, f32>>() {
        let (w, h, d) = copy(a);
        (w, h, d, 32)
    } else if let Ok(a) = obj.extract::<PyReadonlyArray2<'_, f64>>() {
        let (w, h, d) = copy(a);
        (w, h, d, 64)
    } else {
        let ndim = obj
            .getattr("ndim")
            .ok()
            .and_then(|n| n.extract::<usize>().ok());
        let dtype = obj
            .getattr("dtype")
            .ok()
            .and_then(|d| d.str().ok())
            .map(|s| s.to_string());
        return Err(match (ndim, dtype) {
            (Some(n), _) if n != 2 => PyValueError::new_err(format!(
                "{what} must be a 2-D array (rows, columns), got {n} dimensions"
            )),
            (_, Some(d)) => PyTypeError::new_err(format!(
                "{what} must be an array of uint8, uint16, float32 or float64 in native byte \
                 order, got dtype {d}"
            )),
            _ => PyTypeError::new_err(format!(
                "{what} must be a numpy array or the path of an image file, got {}",
                obj.get_type()
                    .name()
                    .map_or_else(|_| "?".into(), |n| n.to_string())
            )),
        });
    };
    Image::new(w, h, data, ImageMeta::synthetic(bits))
        .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
}

/// The image argument of `locate`: a path (read as `bostrack locate` reads it, the clip level
/// from the file) or an array (the clip level from its samples); with its name for messages.
fn input_image(obj: &Bound<'_, PyAny>, saturation: Saturation) -> PyResult<(Image, PathBuf)> {
    if let Ok(path) = obj.extract::<PathBuf>() {
        let (img, _) = bostrack_io::read_image_clipped(&path, saturation).map_err(io_err)?;
        return Ok((img, path));
    }
    let mut img = array_image(obj, "image")?;
    bostrack_io::apply_saturation(&mut img, saturation, None).map_err(io_err)?;
    let name = PathBuf::from(format!(
        "image array ({} x {} px)",
        img.width(),
        img.height()
    ));
    Ok((img, name))
}

fn input_mask(obj: &Bound<'_, PyAny>, width: usize, height: usize) -> PyResult<Mask> {
    if let Ok(path) = obj.extract::<PathBuf>() {
        return bostrack_io::read_mask_for(&path, width, height).map_err(io_err);
    }
    let m = if let Ok(a) = obj.extract::<PyReadonlyArray2<'_, bool>>() {
        let v = a.as_array();
        let (h, w) = v.dim();
        let data = v.iter().map(|&b| f64::from(u8::from(b))).collect();
        Image::new(w, h, data, ImageMeta::synthetic(8))
            .map_err(|e| PyValueError::new_err(format!("mask: {e}")))?
    } else {
        array_image(obj, "mask")?
    };
    if (m.width(), m.height()) != (width, height) {
        return Err(PyValueError::new_err(format!(
            "mask is {} x {} pixels (rows x columns), the image {} x {}",
            m.height(),
            m.width(),
            height,
            width
        )));
    }
    bostrack_io::mask_of(&m).map_err(|k| PyValueError::new_err(format!("mask: {k}")))
}

fn saturation_arg(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Saturation> {
    let Some(obj) = obj else {
        return Ok(Saturation::Auto);
    };
    let s = if let Ok(text) = obj.extract::<String>() {
        text.parse::<Saturation>().map_err(PyValueError::new_err)?
    } else {
        Saturation::Counts(obj.extract::<f64>().map_err(|_| {
            PyTypeError::new_err("saturation must be \"auto\" or a number of counts")
        })?)
    };
    s.validate()
        .map_err(|e| PyValueError::new_err(format!("saturation: {e}")))?;
    Ok(s)
}

fn pool(jobs: Option<usize>) -> PyResult<rayon::ThreadPool> {
    let n = bostrack_pipeline::resolve_jobs(jobs.unwrap_or(0));
    if n > bostrack_pipeline::MAX_JOBS {
        return Err(PyValueError::new_err(format!(
            "jobs: {n} is more than {} threads",
            bostrack_pipeline::MAX_JOBS
        )));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(|e| py_err(e, ErrKind::Runtime))
}

/// Detects and fits every dot of an image; see `bostrack.locate`.
#[pyfunction]
#[pyo3(signature = (image, mask=None, *, spacing=None, diameter=None, model="elliptical", saturation=None, read_noise=None, jobs=None))]
#[allow(clippy::too_many_arguments)]
fn locate<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    spacing: Option<f64>,
    diameter: Option<f64>,
    model: &str,
    saturation: Option<&Bound<'py, PyAny>>,
    read_noise: Option<f64>,
    jobs: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut options = LocateOptions::default();
    options.detect.spacing = spacing;
    options.detect.diameter = diameter;
    options
        .detect
        .validate()
        .map_err(|e| py_err(e, ErrKind::Value))?;
    options.fit.model = parse_model(model).map_err(PyValueError::new_err)?;
    options
        .fit
        .validate()
        .map_err(|e| py_err(e, ErrKind::Value))?;
    if let Some(r) = read_noise {
        if !(r.is_finite() && r > 0.0) {
            return Err(PyValueError::new_err(format!(
                "read_noise must be a finite number of counts > 0, got {r}"
            )));
        }
        options.noise = Some(NoiseModel {
            read_variance: r * r,
            gain: 0.0,
            offset: 0.0,
        });
    }
    let saturation = saturation_arg(saturation)?;
    let t0 = std::time::Instant::now();
    let (img, name) = input_image(image, saturation)?;
    let mask = match mask {
        Some(m) if !m.is_none() => Some(input_mask(m, img.width(), img.height())?),
        _ => None,
    };
    let pool = pool(jobs)?;
    let found = py
        .detach(|| pool.install(|| locate_dots(&img, mask.as_ref(), &options, &name)))
        .map_err(|e| py_err(e, ErrKind::Value))?;
    let library_s = t0.elapsed().as_secs_f64();
    let rows = found.rows();
    let out = PyDict::new(py);
    let f64s = |f: &dyn Fn(&bostrack_pipeline::LocateRow) -> f64| -> Vec<f64> {
        rows.iter().map(f).collect()
    };
    for name in LOCATE_COLUMNS {
        match name {
            "i" => out.set_item(
                name,
                rows.iter()
                    .map(|r| r.i)
                    .collect::<Vec<_>>()
                    .into_pyarray(py),
            )?,
            "j" => out.set_item(
                name,
                rows.iter()
                    .map(|r| r.j)
                    .collect::<Vec<_>>()
                    .into_pyarray(py),
            )?,
            "status" => out.set_item(
                name,
                PyList::new(py, rows.iter().map(|r| r.status.to_string()))?,
            )?,
            "flags" => out.set_item(
                name,
                PyList::new(py, rows.iter().map(|r| r.flags.to_string()))?,
            )?,
            "iterations" => out.set_item(
                name,
                rows.iter()
                    .map(|r| r.iterations)
                    .collect::<Vec<_>>()
                    .into_pyarray(py),
            )?,
            _ => {
                let v = f64s(&|r| column_value(r, name));
                out.set_item(name, v.into_pyarray(py))?;
            }
        }
    }
    let info = PyDict::new(py);
    info.set_item("spacing_px", found.spacing)?;
    info.set_item("read_variance", found.noise.read_variance)?;
    info.set_item("gain", found.noise.gain)?;
    info.set_item("offset", found.noise.offset)?;
    info.set_item("saturation", img.meta.saturation)?;
    // seconds in the library (reading or copying the image, noise, detection, fits)
    info.set_item("library_seconds", library_s)?;
    out.set_item("__info__", info)?;
    Ok(out)
}

/// The float columns of a `locate` row by name.
fn column_value(r: &bostrack_pipeline::LocateRow, name: &str) -> f64 {
    match name {
        "x" => r.x,
        "y" => r.y,
        "sigma_x" => r.sigma_x,
        "sigma_y" => r.sigma_y,
        "rho" => r.rho,
        "amplitude" => r.amplitude,
        "background" => r.background,
        "crlb_x" => r.crlb_x,
        "crlb_y" => r.crlb_y,
        "rms" => r.rms,
        "x_pred" => r.x_pred,
        "y_pred" => r.y_pred,
        _ => f64::NAN,
    }
}

/// Progress of a run shared between its thread and the calling one.
#[derive(Debug, Default)]
struct SharedProgress {
    to_do: AtomicUsize,
    skipped: AtomicUsize,
    done: AtomicUsize,
    failed: AtomicUsize,
    stop: AtomicBool,
    messages: Mutex<Vec<String>>,
}

impl Progress for SharedProgress {
    fn start(&self, to_do: usize, skipped: usize) {
        self.to_do.store(to_do, Ordering::SeqCst);
        self.skipped.store(skipped, Ordering::SeqCst);
    }
    fn frame_done(&self, event: &FrameEvent<'_>) {
        self.done.fetch_add(1, Ordering::SeqCst);
        if event.status == FrameStatus::Failed {
            self.failed.fetch_add(1, Ordering::SeqCst);
        }
    }
    fn note(&self, message: &str) {
        if let Ok(mut m) = self.messages.lock() {
            m.push(format!("note: {message}"));
        }
    }
    fn phase(&self, what: &str) {
        if let Ok(mut m) = self.messages.lock() {
            m.push(what.to_string());
        }
    }
    fn cancelled(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }
}

/// Runs a campaign; see `bostrack.run`. `progress(done, to_do, failed, messages)` is called on
/// the calling thread whenever something changed.
#[pyfunction]
#[pyo3(signature = (config, out=None, *, jobs=None, force=false, progress=None))]
fn run<'py>(
    py: Python<'py>,
    config: PathBuf,
    out: Option<PathBuf>,
    jobs: Option<usize>,
    force: bool,
    progress: Option<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let plan = py.detach(|| Plan::load(&config)).map_err(|e| match &e {
        bostrack_pipeline::ConfigError::Read { source, .. }
            if source.kind() == std::io::ErrorKind::NotFound =>
        {
            PyFileNotFoundError::new_err(e.to_string())
        }
        _ => py_err(e, ErrKind::Value),
    })?;
    let warnings = plan.warnings.clone();
    let pool = pool(jobs.or((plan.config.run.jobs > 0).then_some(plan.config.run.jobs)))?;
    let threads = pool.current_num_threads();
    let options = BatchOptions {
        out_dir: out,
        force,
        shard: None,
    };
    let shared = std::sync::Arc::new(SharedProgress::default());
    let worker = {
        let shared = shared.clone();
        std::thread::Builder::new()
            .name("bostrack-run".into())
            .spawn(move || {
                pool.install(|| run_batch(&plan, &options, shared.as_ref()).map_err(Box::new))
            })
            .map_err(|e| py_err(e, ErrKind::Runtime))?
    };
    let mut last = (usize::MAX, usize::MAX, usize::MAX);
    let mut interrupt: Option<PyErr> = None;
    while !worker.is_finished() {
        py.detach(|| std::thread::sleep(Duration::from_millis(50)));
        if interrupt.is_none()
            && let Err(e) = py.check_signals()
        {
            shared.stop.store(true, Ordering::SeqCst);
            interrupt = Some(e);
        }
        if let Some(cb) = &progress {
            let now = (
                shared.done.load(Ordering::SeqCst),
                shared.to_do.load(Ordering::SeqCst),
                shared.failed.load(Ordering::SeqCst),
            );
            let messages: Vec<String> = shared
                .messages
                .lock()
                .map(|mut m| std::mem::take(&mut *m))
                .unwrap_or_default();
            if now != last || !messages.is_empty() {
                last = now;
                if let Err(e) = cb.call1((now.0, now.1, now.2, messages)) {
                    shared.stop.store(true, Ordering::SeqCst);
                    interrupt.get_or_insert(e);
                }
            }
        }
    }
    let result = worker
        .join()
        .map_err(|_| PyRuntimeError::new_err("the run's thread panicked"))?;
    if let Some(e) = interrupt {
        return Err(e);
    }
    let report = result.map_err(|e| match *e {
        BatchError::Config(_) | BatchError::Mismatch { .. } | BatchError::InputsChanged { .. } => {
            py_err(e, ErrKind::Value)
        }
        BatchError::Io(_) | BatchError::Write { .. } | BatchError::Read { .. } => {
            py_err(e, ErrKind::Os)
        }
        _ => py_err(e, ErrKind::Runtime),
    })?;
    let d = PyDict::new(py);
    d.set_item("out_dir", &report.out_dir)?;
    d.set_item("frames", report.frames)?;
    d.set_item("computed", report.computed)?;
    d.set_item("skipped", report.skipped)?;
    d.set_item("figures_drawn", report.figures_drawn)?;
    d.set_item("seconds", report.seconds)?;
    d.set_item("threads", threads)?;
    d.set_item("warnings", warnings)?;
    let failures = PyList::empty(py);
    for f in &report.failures {
        let x = PyDict::new(py);
        x.set_item("frame", f.frame)?;
        x.set_item("stem", &f.stem)?;
        x.set_item("file", &f.file)?;
        x.set_item("reason", &f.reason)?;
        failures.append(x)?;
    }
    d.set_item("failures", failures)?;
    Ok(d)
}

/// A frame's `dots.csv` on its lattice: `(i, j, {name: 2-D array}, {name: unit})`.
#[pyfunction]
fn fields<'py>(py: Python<'py>, dots_csv: PathBuf) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
    let f = py
        .detach(|| LatticeFields::read(&dots_csv).map_err(Box::new))
        .map_err(|e| match e.as_ref() {
            BatchError::Read { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
                PyFileNotFoundError::new_err(e.to_string())
            }
            _ => py_err(e, ErrKind::Value),
        })?;
    let (rows, cols) = f.shape();
    let arrays = PyDict::new(py);
    let shape = |e: numpy::ndarray::ShapeError| PyRuntimeError::new_err(e.to_string());
    for field in &f.fields {
        match &field.values {
            FieldValues::Float(v) => arrays.set_item(
                &field.name,
                numpy::ndarray::Array2::from_shape_vec((rows, cols), v.clone())
                    .map_err(shape)?
                    .into_pyarray(py),
            )?,
            FieldValues::Bool(v) => arrays.set_item(
                &field.name,
                numpy::ndarray::Array2::from_shape_vec((rows, cols), v.clone())
                    .map_err(shape)?
                    .into_pyarray(py),
            )?,
            FieldValues::Bits(v) => arrays.set_item(
                &field.name,
                numpy::ndarray::Array2::from_shape_vec((rows, cols), v.clone())
                    .map_err(shape)?
                    .into_pyarray(py),
            )?,
        }
    }
    let units = PyDict::new(py);
    for (name, unit) in f.units() {
        units.set_item(name, unit)?;
    }
    let i = f.i.clone().into_pyarray(py);
    let j = f.j.clone().into_pyarray(py);
    (i, j, arrays, units).into_pyobject(py)
}

/// `(name, bit)` of every per-dot flag.
#[pyfunction]
fn flag_bits() -> Vec<(&'static str, u32)> {
    bostrack_pipeline::flag_bits()
}

/// The prediction of a setup file as a JSON text; see `bostrack.crlb`.
#[pyfunction]
fn crlb(py: Python<'_>, setup: PathBuf) -> PyResult<String> {
    py.detach(|| crlb_json(&setup))
}

fn crlb_json(path: &Path) -> PyResult<String> {
    let text = bostrack_pipeline::read_config_text(path).map_err(|e| match &e {
        bostrack_pipeline::ConfigError::Read { source, .. }
            if source.kind() == std::io::ErrorKind::NotFound =>
        {
            PyFileNotFoundError::new_err(e.to_string())
        }
        _ => py_err(e, ErrKind::Value),
    })?;
    let named =
        |e: bostrack_theory::TheoryError| PyValueError::new_err(format!("{}: {e}", path.display()));
    let setup = bostrack_theory::Setup::from_toml(&text).map_err(named)?;
    let p = bostrack_theory::predict(&setup).map_err(named)?;
    let v = bostrack_theory::prediction_json(&p, path).map_err(|e| py_err(e, ErrKind::Runtime))?;
    serde_json::to_string(&v).map_err(|e| py_err(e, ErrKind::Runtime))
}

/// Reads an image file as `bostrack` reads it: a 2-D float64 array of its samples.
#[pyfunction]
fn read_image<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
    let img = py
        .detach(|| bostrack_io::read_image(&path))
        .map_err(io_err)?;
    let (w, h) = (img.width(), img.height());
    numpy::ndarray::Array2::from_shape_vec((h, w), img.into_data())
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

#[pymodule]
fn _bostrack(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(locate, m)?)?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(fields, m)?)?;
    m.add_function(wrap_pyfunction!(flag_bits, m)?)?;
    m.add_function(wrap_pyfunction!(crlb, m)?)?;
    m.add_function(wrap_pyfunction!(read_image, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
