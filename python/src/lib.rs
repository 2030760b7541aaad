//! `morph._morph`: the library behind the Python module `morph` (see `morph/__init__.py`, which
//! gives it its Python face: keyword settings, mesh arguments, result objects).
//!
//! Settings come as the scene file's JSON (the same keys, read by the same code), events as
//! the `--json` lines' JSON text, frames as numpy arrays. The GIL is released while the morph
//! runs; callbacks take it back. A callback that returns `False` (or raises) stops the run at
//! its next evaluation, as Ctrl-C does; so does Ctrl-C in Python.

use morph::output::{OutputRequest, morph_to_folder};
use morph::progress::ProgressMeter;
use morph::scene_file::SceneFile;
use morph::{Frame, Job, MeshSource, MorphError, MorphEvent, MorphSettings, Observer};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

pyo3::create_exception!(
    morph,
    Error,
    PyException,
    "A morph failed; the message is the CLI's."
);
pyo3::create_exception!(
    morph,
    SettingsError,
    Error,
    "Bad settings (the CLI's exit code 2)."
);
pyo3::create_exception!(morph, MeshError, Error, "A mesh that cannot be morphed.");
pyo3::create_exception!(morph, SimulationError, Error, "The simulation failed.");
pyo3::create_exception!(
    morph,
    OutputError,
    Error,
    "The output folder could not be written."
);
pyo3::create_exception!(
    morph,
    Cancelled,
    Error,
    "A callback (or Ctrl-C) stopped the run."
);

/// The Python exception for a library error, with the CLI's one-line message.
fn py_err(e: MorphError) -> PyErr {
    let message = e.to_string();
    match e {
        MorphError::Settings(_) | MorphError::Mesh(morph::geometry::MeshError::BadOption(_)) => {
            SettingsError::new_err(message)
        }
        MorphError::Mesh(_) => MeshError::new_err(message),
        // An optimization that could not work (a non-finite objective, no segment moved)
        // is the simulation's failure to do what was asked, as the CLI's exit 1 says.
        // So is a device that cannot run it (no GPU adapter for `device = "gpu"`).
        MorphError::Sim(_) | MorphError::Optimization(_) | MorphError::Device(_) => {
            SimulationError::new_err(message)
        }
        MorphError::Output(_) | MorphError::Resume(_) => OutputError::new_err(message),
        MorphError::Interrupted { .. } => Cancelled::new_err("cancelled"),
    }
}

/// The settings from the scene file's keys (JSON text), over the preset they name. Messages
/// read "settings: ..." (the scene file's code names the file it reads).
fn settings(json: &str) -> PyResult<MorphSettings> {
    const NAME: &str = "<settings>.json";
    SceneFile::parse(json, Path::new(NAME), None)
        .map(|scene| scene.settings)
        .map_err(|e| {
            let e = e.replacen(&format!("scene file '{NAME}':"), "settings:", 1);
            SettingsError::new_err(e)
        })
}

/// A mesh given as arrays: `vertices` (n x 3, f64) and `triangles` (m x 3, i64), checked and
/// repaired as a loaded file would be.
fn memory_mesh(
    name: &str,
    vertices: PyReadonlyArray2<f64>,
    triangles: PyReadonlyArray2<i64>,
) -> PyResult<MeshSource> {
    let (v, t) = (vertices.as_array(), triangles.as_array());
    if v.ncols() != 3 || t.ncols() != 3 {
        return Err(MeshError::new_err(format!(
            "'{name}': vertices and triangles must have 3 columns, got {} and {}",
            v.ncols(),
            t.ncols()
        )));
    }
    let n = v.nrows() as i64;
    let mut triangles = Vec::with_capacity(t.nrows());
    for (i, row) in t.rows().into_iter().enumerate() {
        if let Some(bad) = row.iter().find(|&&k| !(0..n).contains(&k)) {
            return Err(MeshError::new_err(format!(
                "'{name}': triangle {} uses vertex {bad}, but there are {n} vertices",
                i + 1
            )));
        }
        triangles.push([row[0] as u32, row[1] as u32, row[2] as u32]);
    }
    let mesh = morph::geometry::TriMesh {
        vertices: v
            .rows()
            .into_iter()
            .map(|r| nalgebra::Vector3::new(r[0], r[1], r[2]))
            .collect(),
        triangles,
    };
    let loaded = morph::geometry::prepare_mesh(Path::new(name), mesh, Vec::new())
        .map_err(|e| py_err(e.into()))?;
    Ok(MeshSource::Memory {
        name: name.into(),
        mesh: loaded,
    })
}

/// A mesh argument: a path, or `(name, vertices, triangles)`.
fn mesh_source(arg: &Bound<PyAny>) -> PyResult<MeshSource> {
    if let Ok((name, v, t)) =
        arg.extract::<(String, PyReadonlyArray2<f64>, PyReadonlyArray2<i64>)>()
    {
        return memory_mesh(&name, v, t);
    }
    Ok(MeshSource::File(arg.extract::<PathBuf>()?))
}

/// The first exception a callback raised (or Ctrl-C's `KeyboardInterrupt`), re-raised when
/// the run ends.
type Raised = Mutex<Option<PyErr>>;

fn keep(raised: &Raised, e: PyErr) {
    raised.lock().expect("not poisoned").get_or_insert(e);
}

/// A frame for Python: its index, time, and positions, velocities and J (world units), flat.
type FrameData = (usize, f64, Vec<f64>, Vec<f64>, Vec<f64>);

fn frame_data(frame: &Frame) -> FrameData {
    let flat = |v: &[nalgebra::Vector3<f64>]| v.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    (
        frame.index,
        frame.time,
        flat(&frame.world.x),
        flat(&frame.world.v),
        frame.world.j.clone(),
    )
}

/// The Python callbacks of one run, and whether the run should stop: a callback returned
/// `False` (`None`, the usual answer, goes on) or raised, or Ctrl-C was pressed. Used from
/// the thread that runs the morph, without the GIL: each call takes it.
struct Callbacks {
    on_event: Option<Py<PyAny>>,
    on_frame: Option<Py<PyAny>>,
    raised: Raised,
    /// The fraction done, as `--progress openjd` reports it, added to each event.
    meter: Mutex<ProgressMeter>,
}

impl Callbacks {
    /// Calls `callback(arg)` with the GIL; whether the run should stop.
    fn ask<'py>(&self, py: Python<'py>, callback: &Py<PyAny>, arg: impl IntoPyObject<'py>) -> bool {
        match callback.call1(py, (arg,)) {
            Ok(answer) => answer.bind(py).is(&*pyo3::types::PyBool::new(py, false)),
            Err(e) => {
                keep(&self.raised, e);
                true
            }
        }
    }

    /// The `--json` event with `progress`, the fraction of the run done (0 to 1).
    fn event(&self, event: &MorphEvent) -> bool {
        let Some(cb) = &self.on_event else {
            return false;
        };
        let progress = self.meter.lock().expect("not poisoned").observe(event);
        let mut value = serde_json::to_value(event).expect("events serialize");
        value["progress"] = progress.into();
        Python::attach(|py| self.ask(py, cb, value.to_string()))
    }

    fn frame(&self, data: &FrameData) -> bool {
        let Some(cb) = &self.on_frame else {
            return false;
        };
        Python::attach(|py| match frame_dict(py, data) {
            Ok(d) => self.ask(py, cb, d),
            Err(e) => {
                keep(&self.raised, e);
                true
            }
        })
    }

    /// Ctrl-C in Python: its handler runs when asked.
    fn interrupted(&self) -> bool {
        Python::attach(|py| py.check_signals())
            .map_err(|e| keep(&self.raised, e))
            .is_err()
    }

    /// The exception to raise instead of the run's own result, if any.
    fn raised(&self) -> Option<PyErr> {
        self.raised.lock().expect("not poisoned").take()
    }
}

/// Watches a run in memory for Python: events and frames to the callbacks, the frames kept
/// for the result.
struct PyObserver {
    callbacks: Callbacks,
    keep_frames: bool,
    frames: Vec<FrameData>,
    stop: bool,
}

impl Observer for PyObserver {
    fn event(&mut self, event: &MorphEvent) {
        self.stop |= self.callbacks.event(event);
    }

    fn frame(&mut self, frame: &Frame) -> Result<(), MorphError> {
        let data = frame_data(frame);
        self.stop |= self.callbacks.frame(&data);
        if self.keep_frames {
            self.frames.push(data);
        }
        Ok(())
    }

    fn stop_requested(&self) -> usize {
        usize::from(self.stop || self.callbacks.interrupted())
    }
}

/// A frame as a dict of numpy arrays: index (0-based), time, positions and velocities (n x 3),
/// J (n).
fn frame_dict<'py>(
    py: Python<'py>,
    (index, time, x, v, j): &FrameData,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let n = j.len();
    d.set_item("index", index)?;
    d.set_item("time", time)?;
    d.set_item("positions", PyArray1::from_slice(py, x).reshape([n, 3])?)?;
    d.set_item("velocities", PyArray1::from_slice(py, v).reshape([n, 3])?)?;
    d.set_item("J", PyArray1::from_slice(py, j))?;
    Ok(d)
}

/// Runs a morph. `source` and `targets`: paths or `(name, vertices, triangles)`. With `out`,
/// writes the output folder (as the CLI does) and returns its summary as JSON text; without,
/// returns a dict with the frames (numpy arrays), the judge's verdict and the losses.
#[pyfunction]
#[pyo3(signature = (source, targets, settings_json, out=None, overwrite=false, resume=false, on_event=None, on_frame=None, keep_frames=true))]
#[allow(clippy::too_many_arguments)]
fn run<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    targets: &Bound<'py, PyList>,
    settings_json: &str,
    out: Option<PathBuf>,
    overwrite: bool,
    resume: bool,
    on_event: Option<Py<PyAny>>,
    on_frame: Option<Py<PyAny>>,
    keep_frames: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let settings = settings(settings_json)?;
    let source = mesh_source(source)?;
    let targets = targets
        .iter()
        .map(|t| mesh_source(&t))
        .collect::<PyResult<Vec<_>>>()?;
    if let Some(out) = out {
        let path = |m: MeshSource| match m {
            MeshSource::File(p) => Ok(p),
            MeshSource::Memory { name, .. } => Err(SettingsError::new_err(format!(
                "'{name}': a run into a folder takes mesh files (the carried surface is the source file itself)"
            ))),
        };
        let source = path(source)?;
        let targets = targets
            .into_iter()
            .map(path)
            .collect::<PyResult<Vec<_>>>()?;
        let callbacks = (on_event, on_frame);
        return run_to_folder(
            py,
            &settings,
            &source,
            &targets,
            &out,
            (overwrite, resume),
            callbacks,
        );
    }
    let job = Job {
        source,
        targets,
        settings,
    };
    let mut observer = PyObserver {
        callbacks: Callbacks {
            on_event,
            on_frame,
            raised: Mutex::new(None),
            meter: Mutex::new(ProgressMeter::new()),
        },
        keep_frames,
        frames: Vec::new(),
        stop: false,
    };
    // The simulation runs without the GIL; the callbacks take it for each call.
    let outcome = {
        let observer = &mut observer;
        let job = &job;
        py.detach(move || {
            morph::run(job, observer).map(|(prep, result)| {
                let quality = prep.quality(&result.final_state);
                let fps = 1.0 / (prep.sim_frame_every() as f64 * prep.model().dt);
                (quality, fps, result)
            })
        })
    };
    if let Some(e) = observer.callbacks.raised() {
        return Err(e);
    }
    let (quality, fps, result) = outcome.map_err(py_err)?;
    let d = PyDict::new(py);
    let frames = PyList::empty(py);
    for f in &observer.frames {
        frames.append(frame_dict(py, f)?)?;
    }
    d.set_item("frames", frames)?;
    d.set_item("fps", fps)?;
    d.set_item("quality", serde_json::to_string(&quality).expect("plain"))?;
    d.set_item("initial_loss", result.initial_loss)?;
    d.set_item("final_loss", result.final_loss)?;
    d.set_item("seconds", result.seconds)?;
    Ok(d.into_any())
}

/// [`run`] into a folder: the CLI's `morph SOURCE TARGETS -o OUT`.
fn run_to_folder<'py>(
    py: Python<'py>,
    settings: &MorphSettings,
    source: &Path,
    targets: &[PathBuf],
    out: &Path,
    (overwrite, resume): (bool, bool),
    (on_event, on_frame): (Option<Py<PyAny>>, Option<Py<PyAny>>),
) -> PyResult<Bound<'py, PyAny>> {
    let settings = &settings.clone().checked().map_err(SettingsError::new_err)?;
    let stop = AtomicUsize::new(0);
    let callbacks = Callbacks {
        on_event,
        on_frame,
        raised: Mutex::new(None),
        meter: Mutex::new(ProgressMeter::new()),
    };
    let asked = |stopped: bool| {
        if stopped {
            stop.store(2, Ordering::SeqCst);
        }
    };
    let frame_seen = |frame: &Frame| {
        if callbacks.on_frame.is_some() {
            asked(callbacks.frame(&frame_data(frame)));
        }
    };
    let outcome = py.detach(|| {
        let request = OutputRequest {
            out,
            overwrite,
            resume,
            stop: Some(&stop),
            memory_limit: Default::default(),
            scene: None,
            on_frame: Some(&frame_seen),
        };
        morph_to_folder(settings, source, targets, &request, |event| {
            asked(callbacks.event(event) || callbacks.interrupted());
        })
    });
    if let Some(e) = callbacks.raised() {
        return Err(e);
    }
    let summary = outcome.map_err(py_err)?;
    Ok(serde_json::to_string(&summary)
        .expect("plain summary")
        .into_pyobject(py)?
        .into_any())
}

/// `morph inspect MESH` as JSON text.
#[pyfunction]
#[pyo3(signature = (mesh, resolution=32))]
fn inspect(mesh: PathBuf, resolution: usize) -> PyResult<String> {
    let report = morph::geometry::inspect(&mesh, resolution).map_err(|e| py_err(e.into()))?;
    Ok(serde_json::to_string(&report).expect("plain report"))
}

/// `morph compare A B` as JSON text: two nodal mass grids within tolerance or not.
#[pyfunction]
#[pyo3(signature = (a, b, rtol=1e-5, atol=1e-8))]
fn compare(a: PathBuf, b: PathBuf, rtol: f64, atol: f64) -> PyResult<String> {
    use morph::io::massgrid::{MassGrid, compare};
    if !(rtol.is_finite() && rtol >= 0.0 && atol.is_finite() && atol >= 0.0) {
        return Err(SettingsError::new_err(
            "--rtol and --atol must be finite and >= 0",
        ));
    }
    let (ga, gb) = (
        MassGrid::read(&a).map_err(SettingsError::new_err)?,
        MassGrid::read(&b).map_err(SettingsError::new_err)?,
    );
    let c = compare(&ga, &gb, rtol, atol).map_err(Error::new_err)?;
    Ok(serde_json::to_string(&c).expect("plain"))
}

#[pymodule]
fn _morph(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(inspect, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    let py = m.py();
    m.add("MorphError", py.get_type::<Error>())?;
    m.add("SettingsError", py.get_type::<SettingsError>())?;
    m.add("MeshError", py.get_type::<MeshError>())?;
    m.add("SimulationError", py.get_type::<SimulationError>())?;
    m.add("OutputError", py.get_type::<OutputError>())?;
    m.add("Cancelled", py.get_type::<Cancelled>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
