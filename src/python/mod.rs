//! The Python extension module `cylaov._cylaov` (cargo feature `python`), wrapped by the
//! package `cylaov` (`src/python/cylaov/`). A thin layer: each function calls what the
//! command line calls (`scene::load`, `render::render`, `output::aov`, `verify::compare`,
//! `dataset::generate`), so a render's arrays are the samples of the EXR `cylaov render`
//! writes, bit for bit. The arrays own the Rust buffers (no copy); the GIL is released
//! while tracing.
//!
//! **Threads**: every call runs on a rayon pool of this module's own, one per thread count
//! and per process id: a pool inherited through `fork` (PyTorch's `DataLoader` workers on
//! Linux) has no threads behind it, so a child builds its own on first use.
//!
//! **Ctrl-C**: Python runs its signal handlers only between bytecodes of the main thread,
//! so a long call (`render`, `cast_rays`, `Dataset[i]`, `write_shards`) looks for them
//! itself: the calling thread waits for the pool's work 20 ms at a time (`SIGNAL_POLL`) and,
//! between waits, asks Python to run its handlers; when one raises (`KeyboardInterrupt`), it
//! sets the work's stop flag, waits for the work to wind down and raises that exception.

use crate::dataset::generate::{ConfigFile, GenerateOptions, to_json};
use crate::geometry::Kernel;
use crate::output::aov::{AovBuffer, AovImage, ChannelData, channel_names, per_aov_channel_names};
use crate::render::cast::{self, Ray};
use crate::render::{Accel, RenderOptions};
use crate::scene::camera::{Camera, Projection};
use crate::scene::{self, Aov, CameraFile, CylinderFile, SceneFile};
use crate::verify::compare::{self as verify, Conditioning, Tolerances};
use glam::DVec3;
use numpy::ndarray::{Array2, Array3, ArrayD, IxDyn};
use numpy::{IntoPyArray, PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::create_exception;
use pyo3::exceptions::{
    PyFileNotFoundError, PyIndexError, PyIsADirectoryError, PyOSError, PyPermissionError,
    PyTypeError, PyValueError,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

mod scan;
mod shards;

create_exception!(
    cylaov,
    SceneError,
    PyValueError,
    "A scene that cylaov refuses; the text is the command line's error line without \
     `error: `, naming the field and the value (`cylinders[3].radius: must be > 0 ...`)."
);

// ---- thread pools ------------------------------------------------------------------------

/// The pools of this process, by thread count, and the process they belong to.
static POOLS: Mutex<Option<(u32, Pools)>> = Mutex::new(None);

/// One process's pools, by thread count.
type Pools = HashMap<usize, Arc<rayon::ThreadPool>>;

/// The pool of `threads` threads (`None`: every core) of this process, made on first use.
fn pool(threads: Option<usize>) -> PyResult<Arc<rayon::ThreadPool>> {
    let n = match threads {
        Some(n) if !(1..=MAX_THREADS).contains(&n) => {
            return Err(PyValueError::new_err(format!(
                "threads: must be in 1..={MAX_THREADS}, got {n}"
            )));
        }
        Some(n) => n,
        None => cores(),
    };
    let pid = std::process::id();
    let mut guard = POOLS.lock().unwrap_or_else(|e| e.into_inner());
    if guard.as_ref().is_some_and(|(p, _)| *p != pid) {
        // Inherited through fork: its threads live in the parent only. Dropping it would
        // wait on them; forget it instead.
        std::mem::forget(guard.take());
    }
    let (_, pools) = guard.get_or_insert_with(|| (pid, HashMap::new()));
    if let Some(p) = pools.get(&n) {
        return Ok(p.clone());
    }
    if pools.len() >= MAX_POOLS {
        // Forget the pools no call is using (their threads exit), so distinct counts do
        // not pile up threads for the life of the process.
        pools.retain(|_, p| Arc::strong_count(p) > 1);
    }
    let p = rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(|e| PyOSError::new_err(format!("cannot start {n} threads: {e}")))?;
    let p = Arc::new(p);
    pools.insert(n, p.clone());
    Ok(p)
}

/// The bounds of `threads=`, those of `--threads`.
const MAX_THREADS: usize = 1024;

/// Pools kept at most (beyond those in use): one per distinct thread count asked for.
const MAX_POOLS: usize = 4;

/// The cores this process may use, asked once: the standard library reads the cgroup's
/// files on every call, which costs more than a small view's trace gains from the pool.
fn cores() -> usize {
    static CORES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// Run pure Rust `f` on this process's pool of `threads` threads, the GIL held (for quick
/// work: parsing, validation). Whatever uses rayon outside a pool's `install` takes rayon's
/// global pool, which after a fork is the parent's, without threads: so nothing here does.
fn on_pool<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
    pool(threads)?
        .install(|| std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)))
        .map_err(panic_error)
}

/// Run `f` on the pool of `threads` threads with the GIL released.
fn run<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    f: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    let pool = pool(threads)?;
    py.detach(|| pool.install(|| std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))))
        .map_err(panic_error)
}

/// How long the calling thread of a stoppable call waits for the work between two looks
/// for a signal: a Ctrl-C raises `KeyboardInterrupt` within this plus the time the work
/// takes to notice its stop flag (one band of a render, one view of a tar).
const SIGNAL_POLL: Duration = Duration::from_millis(20);

/// [`run`] for long work that takes a stop flag: the work runs on the pool while this
/// thread, the GIL released, waits for it and looks for signals every [`SIGNAL_POLL`]. An
/// exception from a signal handler (Ctrl-C's `KeyboardInterrupt`) sets the flag; the work
/// is waited for (it ends at its next look at the flag, cleaning up as it goes) and the
/// exception raised instead of its result.
fn run_stoppable<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    f: impl FnOnce(&AtomicBool) -> T + Send,
) -> PyResult<T> {
    let pool = pool(threads)?;
    let stop = AtomicBool::new(false);
    // The work's result, and the condition variable its thread signals it on: no channel,
    // whose receiver would spin on the cores the work needs before it sleeps.
    let done: (Mutex<Option<std::thread::Result<T>>>, std::sync::Condvar) = Default::default();
    pool.in_place_scope(|s| {
        let (stop, done) = (&stop, &done);
        s.spawn(move |_| {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(stop)));
            *done.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(r);
            done.1.notify_one();
        });
        let mut raised: Option<PyErr> = None;
        loop {
            let got = py.detach(|| {
                let guard = done.0.lock().unwrap_or_else(|e| e.into_inner());
                let (mut guard, _) = done
                    .1
                    .wait_timeout_while(guard, SIGNAL_POLL, |r| r.is_none())
                    .unwrap_or_else(|e| e.into_inner());
                guard.take()
            });
            if let Some(r) = got {
                return match raised {
                    Some(e) => Err(e),
                    None => r.map_err(panic_error),
                };
            }
            if raised.is_none()
                && let Err(e) = py.check_signals()
            {
                stop.store(true, Ordering::Relaxed);
                raised = Some(e);
            }
        }
    })
}

// ---- conversions -------------------------------------------------------------------------

/// A JSON value as Python objects (dicts, lists, floats, ints, strings, None).
fn json_to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    use serde_json::Value;
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
        Value::Number(n) => match (n.as_u64(), n.as_i64()) {
            (Some(u), _) => u.into_pyobject(py)?.into_any(),
            (None, Some(i)) => i.into_pyobject(py)?.into_any(),
            _ => n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any(),
        },
        Value::String(s) => s.into_pyobject(py)?.into_any(),
        Value::Array(a) => {
            let l = PyList::empty(py);
            for x in a {
                l.append(json_to_py(py, x)?)?;
            }
            l.into_any()
        }
        Value::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, json_to_py(py, x)?)?;
            }
            d.into_any()
        }
    })
}

/// A Python object as JSON text, through the standard `json` module (NaN refused).
fn py_to_json(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<String> {
    let json = obj.py().import("json")?;
    let kw = PyDict::new(obj.py());
    kw.set_item("allow_nan", false)?;
    json.call_method("dumps", (obj,), Some(&kw))
        .map_err(|e| PyValueError::new_err(format!("{what}: not JSON data: {e}")))?
        .extract()
}

create_exception!(
    cylaov,
    InternalError,
    pyo3::exceptions::PyRuntimeError,
    "A fault inside cylaov (a Rust panic, caught): a bug to report, with the call that \
     raised it. The process stays usable."
);

/// A caught panic's message as an `InternalError`.
fn panic_error(p: Box<dyn std::any::Any + Send>) -> PyErr {
    let msg = p
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into());
    InternalError::new_err(format!("internal error (please report): {msg}"))
}

fn scene_error(e: impl std::fmt::Display) -> PyErr {
    SceneError::new_err(e.to_string())
}

/// An IO error as the `OSError` subclass Python users expect, the path first.
fn os_error(path: &Path, e: &std::io::Error) -> PyErr {
    use std::io::ErrorKind;
    let msg = format!("{}: {e}", path.display());
    match e.kind() {
        ErrorKind::NotFound => PyFileNotFoundError::new_err(msg),
        ErrorKind::PermissionDenied => PyPermissionError::new_err(msg),
        _ => PyOSError::new_err(msg),
    }
}

fn parse_aov(name: &str, field: &str) -> PyResult<Aov> {
    Aov::parse(name).ok_or_else(|| {
        let all: Vec<_> = Aov::ALL.iter().map(|a| a.name()).collect();
        PyValueError::new_err(format!(
            "{field}: unknown AOV {name:?}; one of {}",
            all.join(", ")
        ))
    })
}

fn parse_aovs(aovs: &[String]) -> PyResult<Vec<Aov>> {
    let mut out = Vec::new();
    for (i, a) in aovs.iter().enumerate() {
        let aov = parse_aov(a, &format!("aovs[{i}]"))?;
        if !out.contains(&aov) {
            out.push(aov);
        }
    }
    if out.is_empty() {
        return Err(PyValueError::new_err("aovs: name at least one AOV"));
    }
    Ok(out)
}

/// The AOVs to trace for `aovs`: depth joins when none of them tells a hit from a miss
/// exactly (`position`'s zero vector is also a hit at the world origin; `label` 0 is also a
/// cylinder without a label), so the mask is exact.
fn traced(aovs: &[Aov]) -> Vec<Aov> {
    let mut t = aovs.to_vec();
    if aovs
        .iter()
        .all(|&a| matches!(a, Aov::Position | Aov::Label))
    {
        t.push(Aov::Depth);
    }
    t
}

/// `aovs=` as a list of names: one string is one name (as `cast_rays` takes it).
fn aov_names(obj: &Bound<'_, PyAny>) -> PyResult<Vec<String>> {
    names(obj, "aovs: an AOV name or a sequence of AOV names")
}

/// A parameter that takes one name or a sequence of names, as a list; else a `TypeError`
/// saying `what`.
fn names(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<String>> {
    if let Ok(s) = obj.extract::<String>() {
        return Ok(vec![s]);
    }
    obj.extract()
        .map_err(|_| PyTypeError::new_err(what.to_string()))
}

/// The value of keyword `keyword` named `name`; the library's refusal under Python's
/// spelling of the option (`precision: unknown value "f16": expected one of f32, f64`).
pub(crate) fn choice<T: crate::choice::Choice>(name: &str, keyword: &str) -> PyResult<T> {
    T::parse(name).map_err(|e| PyValueError::new_err(format!("{keyword}: {e}")))
}

fn kernel(precision: &str, formula: &str) -> PyResult<Kernel> {
    Ok(Kernel::new(
        choice(formula, "formula")?,
        choice(precision, "precision")?,
    ))
}

/// AOV name and its array: the AOV's buffer, `(H, W)` or `(H, W, 3)` as the render
/// filled it.
enum Plane {
    F32(Vec<f32>),
    U32(Vec<u32>),
    Vec3(Vec<f32>),
}

/// An image's arrays before they become Python objects: built with the GIL released, on
/// the call's pool.
struct Arrays {
    width: usize,
    height: usize,
    planes: Vec<(Aov, Plane)>,
    mask: Option<Vec<bool>>,
}

/// The image's requested AOVs (owned: the arrays take the buffers as they are, no copy;
/// float32 ids of a per-AOV file become uint32) and the `mask`.
fn arrays(mut image: AovImage, aovs: &[Aov]) -> Arrays {
    let (w, h) = (image.width, image.height);
    // Depth traced only for the mask (see `traced`).
    let depth_mask = match image.take_aov_buffer(Aov::Depth) {
        Some(b) if !aovs.contains(&Aov::Depth) => match b.data {
            ChannelData::F32(v) if v.len() == w * h => Some(v.iter().map(|&x| x > 0.0).collect()),
            _ => None,
        },
        Some(b) => {
            image.buffers.push(b);
            None
        }
        None => None,
    };
    let mut planes: Vec<(Aov, Plane)> = Vec::new();
    for &a in aovs {
        let Some(buffer) = image.take_aov_buffer(a) else {
            continue;
        };
        let plane = match (buffer.data, channel_names(a).len()) {
            (ChannelData::F32(v), 1) if a.is_u32() => {
                Plane::U32(v.into_iter().map(|x| x as u32).collect())
            }
            (ChannelData::F32(v), 1) => Plane::F32(v),
            (ChannelData::U32(v), 1) => Plane::U32(v),
            (ChannelData::F32(v), 3) => Plane::Vec3(v),
            _ => continue,
        };
        planes.push((a, plane));
    }
    let mask = depth_mask.or_else(|| mask_of(&planes, w * h));
    Arrays {
        width: w,
        height: h,
        planes,
        mask,
    }
}

/// The arrays as a dict keyed by AOV name, `mask` beside them; numpy takes the buffers.
fn arrays_to_dict<'py>(py: Python<'py>, arrays: Arrays) -> PyResult<Bound<'py, PyDict>> {
    let Arrays {
        width: w,
        height: h,
        planes,
        mask,
    } = arrays;
    let d = PyDict::new(py);
    for (a, plane) in planes {
        let arr = match plane {
            Plane::F32(v) => Array2::from_shape_vec((h, w), v)
                .map_err(shape_err)?
                .into_pyarray(py)
                .into_any(),
            Plane::U32(v) => Array2::from_shape_vec((h, w), v)
                .map_err(shape_err)?
                .into_pyarray(py)
                .into_any(),
            Plane::Vec3(v) => Array3::from_shape_vec((h, w, 3), v)
                .map_err(shape_err)?
                .into_pyarray(py)
                .into_any(),
        };
        d.set_item(a.name(), arr)?;
    }
    if let Some(m) = mask {
        d.set_item(
            "mask",
            Array2::from_shape_vec((h, w), m)
                .map_err(shape_err)?
                .into_pyarray(py),
        )?;
    }
    Ok(d)
}

/// The image's AOVs by name (owned: the arrays take the buffers), the `mask` beside them.
fn image_to_dict<'py>(
    py: Python<'py>,
    image: AovImage,
    aovs: &[Aov],
) -> PyResult<Bound<'py, PyDict>> {
    arrays_to_dict(py, on_pool(None, || arrays(image, aovs))?)
}

fn shape_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(format!("image size: {e}"))
}

/// Hit or miss per pixel, from the first AOV that tells: a miss is 0 in every channel, a
/// hit has depth, distance, id and part > 0 and a unit normal.
fn mask_of(planes: &[(Aov, Plane)], n: usize) -> Option<Vec<bool>> {
    let order = [
        Aov::Depth,
        Aov::Distance,
        Aov::ShapeId,
        Aov::Part,
        Aov::Normal,
        Aov::NormalCamera,
        // Last: a hit exactly at the world origin reads as a miss. `render` and `Dataset`
        // trace depth beside a lone position; only `read` of a position file relies on it.
        Aov::Position,
    ];
    for want in order {
        let Some((_, p)) = planes.iter().find(|(a, _)| *a == want) else {
            continue;
        };
        return Some(match p {
            Plane::F32(v) => v.iter().map(|&x| x > 0.0).collect(),
            Plane::U32(v) => v.iter().map(|&x| x != 0).collect(),
            Plane::Vec3(v) => v.chunks_exact(3).map(|c| c != [0.0; 3]).collect(),
        });
    }
    (n == 0).then(Vec::new)
}

// ---- Scene -------------------------------------------------------------------------------

/// A validated cylinder scene: the cylinders and one or more cameras, as a scene file
/// holds them.
///
/// Make one with `Scene.load(path)`, `Scene.from_json(text)`, `Scene.from_dict(d)` or
/// `Scene.from_arrays(p0, p1, radius, ...)`, or get one from `cylaov.generate`. Every
/// constructor validates as `cylaov render` does and raises `cylaov.SceneError` naming the
/// field and the value. A Scene pickles (as its JSON).
#[pyclass(name = "Scene", module = "cylaov", frozen)]
pub struct PyScene {
    scene: scene::Scene,
    /// The file it came from, when `to_json` must give its exact bytes (a generated scene:
    /// `p1` as drawn, not recomputed from the validated axis and height).
    file: Option<SceneFile>,
}

impl From<scene::Scene> for PyScene {
    fn from(scene: scene::Scene) -> Self {
        PyScene { scene, file: None }
    }
}

/// A validated scene's exact state, for pickling: the cameras as written and every
/// cylinder's validated fields (base, unit axis, height, radius), so that nothing is
/// recomputed on the way back.
#[derive(serde::Serialize, serde::Deserialize)]
struct State {
    cameras: Vec<CameraFile>,
    /// `[base.x, base.y, base.z, axis.x, axis.y, axis.z, height, radius]` per cylinder.
    cylinders: Vec<[f64; 8]>,
    caps: Vec<bool>,
    ids: Vec<u32>,
    /// Per cylinder; absent (all 0) in states written before labels existed.
    #[serde(default)]
    labels: Vec<u32>,
    aovs: Vec<Aov>,
    file: Option<SceneFile>,
}

/// A Scene from the state `Scene.__reduce__` wrote (the cameras validated again).
#[pyfunction]
fn _scene_from_state(state: &[u8]) -> PyResult<PyScene> {
    let st: State = serde_json::from_slice(state)
        .map_err(|e| PyValueError::new_err(format!("scene state: {e}")))?;
    let cams = SceneFile {
        camera: None,
        cameras: Some(st.cameras),
        cylinders: Vec::new(),
        aovs: Some(st.aovs),
    };
    let cams = on_pool(None, || cams.validate())?.map_err(scene_error)?;
    let cylinders = st
        .cylinders
        .iter()
        .zip(st.caps.iter().zip(&st.ids))
        .enumerate()
        .map(|(i, (c, (&caps, &id)))| crate::geometry::Cylinder {
            base: DVec3::new(c[0], c[1], c[2]),
            axis: DVec3::new(c[3], c[4], c[5]),
            height: c[6],
            radius: c[7],
            caps,
            id,
            label: st.labels.get(i).copied().unwrap_or(0),
        })
        .collect();
    Ok(PyScene {
        scene: scene::Scene { cylinders, ..cams },
        file: st.file,
    })
}

fn camera_dict<'py>(
    py: Python<'py>,
    c: &crate::scene::camera::CameraSpec,
) -> PyResult<Bound<'py, PyAny>> {
    let v = serde_json::to_value(CameraFile::from_spec(c))
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    json_to_py(py, &v)
}

#[pymethods]
impl PyScene {
    /// Read and validate a scene file (the format `cylaov render` reads).
    ///
    /// Raises FileNotFoundError / PermissionError / IsADirectoryError (OSError) when the
    /// file cannot be read, SceneError when it is not a valid scene; both texts start with
    /// the path, as the command line's error line does.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<PyScene> {
        match std::fs::metadata(&path) {
            Err(e) => return Err(os_error(&path, &e)),
            Ok(m) if m.is_dir() => {
                return Err(PyIsADirectoryError::new_err(format!(
                    "{}: not a regular file but a folder",
                    path.display()
                )));
            }
            Ok(_) => {}
        }
        let scene = on_pool(None, || scene::load(&path))?
            .map_err(|e| scene_error(format!("{}: {e}", path.display())))?;
        Ok(scene.into())
    }

    /// A scene from a cylinder table, as `cylaov import` makes it: a TreeQSM `cyl_data`
    /// text, a SimpleForest or aRchi CSV, or a CSV with `x0,y0,z0,x1,y1,z1,radius` (and
    /// optional `id`, `label`, `caps`) columns, or an `.npz` of arrays `p0 (N, 3)`,
    /// `p1 (N, 3)`, `radius (N,)` (optional `id`, `label`, `caps`), with one 640 × 480 camera
    /// framing every cylinder. `format` is one of `"csv"`, `"npz"`, `"treeqsm"`,
    /// `"simpleforest"`, `"archi"`
    /// (default: from the header or the column count); `label` one of `"none"`,
    /// `"branch_order"` (BranchOrder + 1), `"branch"` (branch id + 1), `"segment"` (the
    /// cylinder's id) (default: a csv table's `label` column, else none); `caps` closes
    /// every cylinder's ends (default True; a csv `caps` column wins).
    ///
    /// Raises OSError when the file cannot be read, SceneError naming the line and column
    /// of a bad row, ValueError for an unknown `format` or `label`.
    #[staticmethod]
    #[pyo3(signature = (path, format=None, label=None, caps=None))]
    fn from_table(
        path: PathBuf,
        format: Option<&str>,
        label: Option<&str>,
        caps: Option<bool>,
    ) -> PyResult<PyScene> {
        use crate::scene::table::{LabelRule, TableFormat, TableOptions, load_table};
        let format = format
            .map(|f| {
                TableFormat::parse(f).ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "format: expected one of {}, got {f:?}",
                        TableFormat::ALL.map(|f| f.name()).join(", ")
                    ))
                })
            })
            .transpose()?;
        let label = label
            .map(|l| {
                LabelRule::parse(l).ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "label: expected one of {}, got {l:?}",
                        LabelRule::ALL.map(|f| f.name()).join(", ")
                    ))
                })
            })
            .transpose()?;
        if let Err(e) = std::fs::metadata(&path) {
            return Err(os_error(&path, &e));
        }
        let opts = TableOptions {
            format,
            label,
            caps,
        };
        let table = on_pool(None, || load_table(&path, &opts))?
            .map_err(|e| scene_error(format!("{}: {e}", path.display())))?;
        let file = table.scene_file(crate::scene::framing::Frame::default());
        let scene = on_pool(None, || file.validate())?
            .map_err(|e| scene_error(format!("{}: {e}", path.display())))?;
        Ok(PyScene {
            scene,
            file: Some(file),
        })
    }

    /// Parse and validate scene JSON (`str`, or `bytes` of UTF-8 text).
    #[staticmethod]
    fn from_json(text: &Bound<'_, PyAny>) -> PyResult<PyScene> {
        let scene = if let Ok(b) = text.cast::<pyo3::types::PyBytes>() {
            let bytes = b.as_bytes();
            let s = std::str::from_utf8(bytes)
                .map_err(|e| scene_error(format!("not UTF-8 text (byte {})", e.valid_up_to())))?;
            on_pool(None, || scene::parse(s))?
        } else {
            let s: String = text
                .extract()
                .map_err(|_| PyTypeError::new_err("from_json: text must be str or bytes"))?;
            on_pool(None, || scene::parse(&s))?
        };
        Ok(scene.map_err(scene_error)?.into())
    }

    /// Validate a scene given as a dict of the scene file's keys (`camera` or `cameras`,
    /// `cylinders`, optional `aovs`).
    #[staticmethod]
    fn from_dict(d: &Bound<'_, PyAny>) -> PyResult<PyScene> {
        let text = py_to_json(d, "from_dict")?;
        let scene = on_pool(None, || scene::parse(&text))?.map_err(scene_error)?;
        Ok(scene.into())
    }

    /// A scene from arrays: `p0`, `p1` of shape (N, 3) and `radius` of shape (N,), any
    /// real array-likes (lists, int or float arrays: converted to float64 as
    /// `numpy.asarray(x, dtype=float64)` does; the end centres and radii, world units);
    /// `caps` one bool or (N,) bools; `ids` (N,) positive integers of any dtype (float
    /// values must be whole numbers; default 1..N); exactly one of `camera` (a dict of the
    /// scene file's camera keys) and `cameras` (a list of them: `render(scene, camera=k)`
    /// picks one). Validated as a scene file is: errors name the index,
    /// `cylinders[3].radius: must be > 0 ...`.
    #[staticmethod]
    #[pyo3(signature = (p0, p1, radius, caps=None, ids=None, camera=None, cameras=None))]
    #[allow(clippy::too_many_arguments)]
    fn from_arrays(
        p0: &Bound<'_, PyAny>,
        p1: &Bound<'_, PyAny>,
        radius: &Bound<'_, PyAny>,
        caps: Option<&Bound<'_, PyAny>>,
        ids: Option<&Bound<'_, PyAny>>,
        camera: Option<&Bound<'_, PyAny>>,
        cameras: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyScene> {
        let radius = f64_array(radius, "radius")?;
        let radius = radius.as_array();
        if radius.ndim() != 1 {
            return Err(PyValueError::new_err(format!(
                "radius: shape must be (N,), got {:?}",
                radius.shape()
            )));
        }
        let n = radius.len();
        let (p0, p1) = (f64_array(p0, "p0")?, f64_array(p1, "p1")?);
        let (p0, p1) = (p0.as_array(), p1.as_array());
        for (name, a) in [("p0", &p0), ("p1", &p1)] {
            if a.shape() != [n, 3] {
                return Err(PyValueError::new_err(format!(
                    "{name}: shape must be ({n}, 3) for {n} radii, got {:?}",
                    a.shape()
                )));
            }
        }
        let caps: Vec<bool> = match caps {
            None => vec![true; n],
            Some(c) => match c.extract::<bool>() {
                Ok(b) => vec![b; n],
                Err(_) => {
                    let v: Vec<bool> = c.extract().map_err(|_| {
                        PyTypeError::new_err("caps: one bool or a sequence of N bools")
                    })?;
                    if v.len() != n {
                        return Err(PyValueError::new_err(format!(
                            "caps: {} values for {n} cylinders",
                            v.len()
                        )));
                    }
                    v
                }
            },
        };
        let ids = ids.map(|a| ids_of(a, n)).transpose()?;
        let cam = |obj: &Bound<'_, PyAny>, field: &str| -> PyResult<CameraFile> {
            let text = py_to_json(obj, field)?;
            let de = &mut serde_json::Deserializer::from_str(&text);
            serde_path_to_error::deserialize(de).map_err(|e| {
                let path = e.path().to_string();
                let at = if path == "." {
                    field.to_string()
                } else {
                    format!("{field}.{path}")
                };
                scene_error(format!("{at}: {}", e.into_inner()))
            })
        };
        let camera = camera.map(|c| cam(c, "camera")).transpose()?;
        let cameras = match cameras {
            None => None,
            Some(list) => {
                let mut v = Vec::new();
                for (k, c) in list.try_iter()?.enumerate() {
                    v.push(cam(&c?, &format!("cameras[{k}]"))?);
                }
                Some(v)
            }
        };
        let file = SceneFile {
            camera,
            cameras,
            cylinders: (0..n)
                .map(|i| CylinderFile {
                    p0: Some([p0[[i, 0]], p0[[i, 1]], p0[[i, 2]]]),
                    p1: Some([p1[[i, 0]], p1[[i, 1]], p1[[i, 2]]]),
                    radius: radius[i],
                    caps: caps[i],
                    id: ids.as_ref().map(|v| v[i]),
                    ..CylinderFile::default()
                })
                .collect(),
            aovs: None,
        };
        Ok(on_pool(None, || file.validate())?
            .map_err(scene_error)?
            .into())
    }

    /// The cameras, in file order, each a dict of the scene file's camera keys.
    #[getter]
    fn cameras<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyAny>>> {
        self.scene
            .cameras
            .iter()
            .map(|c| camera_dict(py, c))
            .collect()
    }

    /// The number of cylinders.
    fn __len__(&self) -> usize {
        self.scene.cylinders.len()
    }

    /// The scene as a scene file (JSON text, every field explicit, as `cylaov generate`
    /// writes it).
    fn to_json(&self) -> PyResult<String> {
        let text = match &self.file {
            Some(f) => to_json(f),
            None => to_json(&SceneFile::from_scene(&self.scene)),
        };
        text.map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// The scene as Mitsuba 3 XML (what `cylaov export-mitsuba` writes), for camera 0;
    /// `source_name` is named in the comment at the top.
    #[pyo3(signature = (source_name="python"))]
    fn to_mitsuba_xml(&self, source_name: &str) -> PyResult<String> {
        crate::output::mitsuba::to_xml(&self.scene, source_name)
            .map_err(|e| PyValueError::new_err(e.to_string()))
    }

    fn __repr__(&self) -> String {
        let c = &self.scene.camera;
        format!(
            "<cylaov.Scene: {} cylinders, {} camera(s), {}x{}>",
            self.scene.cylinders.len(),
            self.scene.cameras.len(),
            c.width,
            c.height
        )
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other
            .cast::<PyScene>()
            .is_ok_and(|o| o.get().scene == self.scene)
    }

    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (Vec<u8>,))> {
        let me = slf.get();
        let sc = &me.scene;
        let st = State {
            cameras: sc.cameras.iter().map(CameraFile::from_spec).collect(),
            cylinders: sc
                .cylinders
                .iter()
                .map(|c| {
                    let (b, a) = (c.base, c.axis);
                    [b.x, b.y, b.z, a.x, a.y, a.z, c.height, c.radius]
                })
                .collect(),
            caps: sc.cylinders.iter().map(|c| c.caps).collect(),
            ids: sc.cylinders.iter().map(|c| c.id).collect(),
            labels: sc.cylinders.iter().map(|c| c.label).collect(),
            aovs: sc.aovs.clone(),
            file: me.file.clone(),
        };
        let bytes = serde_json::to_vec(&st).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let f = slf
            .py()
            .import("cylaov._cylaov")?
            .getattr("_scene_from_state")?;
        Ok((f, (bytes,)))
    }
}

/// `x` as a float64 array, converted as `numpy.asarray(x, dtype=float64)` converts it;
/// complex values (whose imaginary part that would drop) and what numpy cannot convert
/// raise `ValueError` naming `name`.
fn f64_array<'py>(x: &Bound<'py, PyAny>, name: &str) -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
    let np = x.py().import("numpy")?;
    let bad =
        |e: PyErr| PyValueError::new_err(format!("{name}: not an array of real numbers: {e}"));
    let a = np.call_method1("asarray", (x,)).map_err(bad)?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    if kind == "c" {
        return Err(PyValueError::new_err(format!(
            "{name}: complex values; the coordinates are real numbers"
        )));
    }
    let a = np.call_method1("asarray", (a, "float64")).map_err(bad)?;
    a.extract::<PyReadonlyArrayDyn<'py, f64>>().map_err(bad)
}

/// `ids=` as u32 values: a sequence of N integers of any integer dtype, or of floats with
/// whole values, each in 0..=4294967295 (the scene's validation refuses 0, naming the
/// cylinder); others raise `ValueError` naming `ids[i]`.
fn ids_of(obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<u32>> {
    let np = obj.py().import("numpy")?;
    let a = np
        .call_method1("asarray", (obj,))
        .map_err(|e| PyValueError::new_err(format!("ids: not an array of integers: {e}")))?;
    let shape: Vec<usize> = a.getattr("shape")?.extract()?;
    if shape != [n] {
        return Err(PyValueError::new_err(format!(
            "ids: shape must be ({n},) for {n} radii, got {shape:?}"
        )));
    }
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    let range = |i: usize, x: &dyn std::fmt::Display| {
        PyValueError::new_err(format!(
            "ids[{i}]: must be a whole number in 1..=4294967295, got {x}"
        ))
    };
    // Every integer dtype fits i64 or u64; whole floats are compared as floats.
    let as_u32 = |i: usize, x: i128| u32::try_from(x).map_err(|_| range(i, &x));
    match kind.as_str() {
        "i" => {
            let v: PyReadonlyArray1<'_, i64> =
                np.call_method1("asarray", (a, "int64"))?.extract()?;
            v.as_array()
                .iter()
                .enumerate()
                .map(|(i, &x)| as_u32(i, x.into()))
                .collect()
        }
        "u" => {
            let v: PyReadonlyArray1<'_, u64> =
                np.call_method1("asarray", (a, "uint64"))?.extract()?;
            v.as_array()
                .iter()
                .enumerate()
                .map(|(i, &x)| as_u32(i, x.into()))
                .collect()
        }
        "f" => {
            let v: PyReadonlyArray1<'_, f64> =
                np.call_method1("asarray", (a, "float64"))?.extract()?;
            v.as_array()
                .iter()
                .enumerate()
                .map(|(i, &x)| {
                    if x.fract() == 0.0 && (0.0..=f64::from(u32::MAX)).contains(&x) {
                        Ok(x as u32)
                    } else {
                        Err(range(i, &x))
                    }
                })
                .collect()
        }
        _ => {
            let dtype = a.getattr("dtype")?.str()?.to_string();
            Err(PyValueError::new_err(format!(
                "ids: whole numbers in 1..=4294967295, got an array of {dtype}"
            )))
        }
    }
}

impl PyScene {
    /// The scene with camera `camera` selected.
    fn with_camera(&self, camera: usize) -> PyResult<scene::Scene> {
        let mut s = self.scene.clone();
        s.select_camera(camera)
            .map_err(|e| PyIndexError::new_err(format!("camera: {e}")))?;
        Ok(s)
    }
}

// ---- render ------------------------------------------------------------------------------

/// Render `scene` from camera `camera` into numpy arrays, with no files.
///
/// Returns a dict keyed by AOV name: `depth`, `distance` (H, W) float32; `normal`,
/// `normal_camera`, `position` (H, W, 3) float32; `shape_id`, `part` (H, W) uint32; and
/// `mask` (H, W) bool (True where the pixel's ray hits a cylinder), always. A miss is 0 in
/// every AOV. The samples are, bit for bit, those of the EXR that `cylaov render` writes
/// with the same options (`precision` "f64" | "f32", `formula` "stable" | "literal",
/// `accel` "tiles" | "frustum" | "bvh"). The GIL is released while tracing (Ctrl-C raises
/// `KeyboardInterrupt` within a fraction of a second); `threads` (default: every core)
/// sizes the thread pool; use 1 inside DataLoader workers.
#[pyfunction]
#[pyo3(signature = (scene, aovs=None, camera=0, precision="f64", formula="stable", accel="tiles", threads=None))]
#[allow(clippy::too_many_arguments)]
fn render<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    aovs: Option<&Bound<'py, PyAny>>,
    camera: usize,
    precision: &str,
    formula: &str,
    accel: &str,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let aovs = match aovs {
        None => vec![Aov::Depth, Aov::Normal],
        Some(a) => parse_aovs(&aov_names(a)?)?,
    };
    let k = kernel(precision, formula)?;
    let accel: Accel = choice(accel, "accel")?;
    let sc = scene.get().with_camera(camera)?;
    let opts = RenderOptions {
        aovs: traced(&aovs),
        precision: k.precision,
        formula: k.formula,
        accel,
    };
    let a = run_stoppable(py, threads, |stop| {
        crate::render::render_until(&sc, &opts, stop).map(|r| arrays(r.image, &aovs))
    })?;
    // `None` only when stopped, and then `run_stoppable` raised.
    let a =
        a.ok_or_else(|| InternalError::new_err("internal error (please report): render stopped"))?;
    arrays_to_dict(py, a)
}

/// The camera metadata of `cylaov render`'s `OUT.camera.json` for camera `camera`: `K`
/// (pixel centres at i + 0.5) and `K_opencv` (at integers), `camera_to_world_opencv` and
/// `camera_to_world_opengl` (4x4, row-major), `width`, `height`, clip planes, and the
/// conventions in words.
#[pyfunction]
#[pyo3(signature = (scene, camera=0))]
fn camera_info<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    camera: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let sc = scene.get().with_camera(camera)?;
    let text = crate::output::io::camera_json(&Camera::new(sc.camera), &sc.aovs);
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| PyValueError::new_err(e.to_string()))?;
    json_to_py(py, &v)
}

/// The camera's own pixel rays, `(origins, directions)`, each (H, W, 3) float64: the
/// direction through pixel (i, j)'s centre, scaled so its camera-space z is 1 (so `t` along
/// it is planar depth). Cast with `t_min=near_clip, t_max=far_clip`, they are the rays a
/// render traces, bit for bit. Every model's own rays ([`Camera::pixel_ray`]): the
/// orthographic camera's start on its image plane at the pixel's offset; a lens model's
/// rays whose depth is Euclidean (equirectangular, a fisheye at or beyond 90°) are unit,
/// so `t` is their distance and the clips bound it, as the render counts them.
#[pyfunction]
#[pyo3(signature = (scene, camera=0))]
fn camera_rays<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    camera: usize,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let sc = scene.get().with_camera(camera)?;
    let cam = Camera::new(sc.camera);
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let mut o = Vec::with_capacity(3 * w * h);
    let mut d = Vec::with_capacity(3 * w * h);
    for j in 0..h as u32 {
        let y = cam.row_offset(j);
        for i in 0..w as u32 {
            if cam.is_pinhole() {
                let v = cam.pixel_vector(cam.column_offset(i), y);
                o.extend(cam.origin.to_array());
                d.extend(v.to_array());
                continue;
            }
            let r = cam.pixel_ray(i, j);
            // Orthographic rays run along `forward` itself (camera-space z 1 as given); a
            // lens model's planar rays are scaled to z = 1, its Euclidean ones stay unit.
            let scale = match cam.projection {
                Projection::Lens(_) if r.planar_depth => 1.0 / r.dir.dot(cam.forward),
                _ => 1.0,
            };
            o.extend(r.origin.to_array());
            d.extend((r.dir * scale).to_array());
        }
    }
    let o = Array3::from_shape_vec((h, w, 3), o).map_err(shape_err)?;
    let d = Array3::from_shape_vec((h, w, 3), d).map_err(shape_err)?;
    Ok((o.into_pyarray(py).into_any(), d.into_pyarray(py).into_any()))
}

/// Flat f64 values of a contiguous array argument.
fn flat<'a>(a: &'a numpy::PyReadonlyArrayDyn<'_, f64>, name: &str) -> PyResult<&'a [f64]> {
    a.as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name}: must be a C-contiguous float64 array")))
}

/// Cast rays (the package's `cast_rays` prepares the arguments): `origins` and
/// `directions` (N, 3), `t_min` and `t_max` (N,), all float64. Returns the requested
/// arrays, flat.
#[pyfunction]
#[pyo3(signature = (scene, origins, directions, t_min, t_max, aovs, precision="f64", formula="stable", threads=None))]
#[allow(clippy::too_many_arguments)]
fn _cast_rays<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    origins: numpy::PyReadonlyArrayDyn<'py, f64>,
    directions: numpy::PyReadonlyArrayDyn<'py, f64>,
    t_min: numpy::PyReadonlyArrayDyn<'py, f64>,
    t_max: numpy::PyReadonlyArrayDyn<'py, f64>,
    aovs: Vec<String>,
    precision: &str,
    formula: &str,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let k = kernel(precision, formula)?;
    let (o, d) = (flat(&origins, "origins")?, flat(&directions, "directions")?);
    let (lo, hi) = (flat(&t_min, "t_min")?, flat(&t_max, "t_max")?);
    let n = lo.len();
    if o.len() != 3 * n || d.len() != 3 * n || hi.len() != n {
        return Err(PyValueError::new_err(
            "origins, directions, t_min, t_max: sizes differ",
        ));
    }
    const KINDS: [&str; 6] = [
        "t_hit",
        "normal",
        "shape_id",
        "part",
        "position",
        "position_error",
    ];
    for (i, a) in aovs.iter().enumerate() {
        if !KINDS.contains(&a.as_str()) {
            return Err(PyValueError::new_err(format!(
                "aovs[{i}]: unknown ray output {a:?}; one of {}",
                KINDS.join(", ")
            )));
        }
    }
    let rays: Vec<Ray> = (0..n)
        .map(|i| Ray {
            origin: DVec3::from_slice(&o[3 * i..3 * i + 3]),
            dir: DVec3::from_slice(&d[3 * i..3 * i + 3]),
            t_min: lo[i],
            t_max: hi[i],
        })
        .collect();
    let sc = &scene.get().scene;
    let hits = run_stoppable(py, threads, |stop| cast::cast_until(sc, k, &rays, stop))?
        .map_err(PyValueError::new_err)?
        // `None` only when stopped, and then `run_stoppable` raised.
        .ok_or_else(|| InternalError::new_err("internal error (please report): cast stopped"))?;
    let out = PyDict::new(py);
    let want = |a: &str| aovs.iter().any(|x| x == a);
    let dyn1 = |v| ArrayD::from_shape_vec(IxDyn(&[n]), v).map_err(shape_err);
    if want("t_hit") {
        let v: Vec<f64> = hits
            .iter()
            .map(|h| h.map_or(f64::INFINITY, |h| h.t))
            .collect();
        out.set_item("t_hit", dyn1(v)?.into_pyarray(py))?;
    }
    let vec3 = |f: &dyn Fn(&cast::RayHit, &Ray) -> DVec3| -> PyResult<Bound<'py, PyAny>> {
        let mut v = Vec::with_capacity(3 * n);
        for (h, r) in hits.iter().zip(&rays) {
            v.extend(h.map_or([0.0; 3], |h| f(&h, r).to_array()));
        }
        Ok(Array2::from_shape_vec((n, 3), v)
            .map_err(shape_err)?
            .into_pyarray(py)
            .into_any())
    };
    if want("normal") {
        out.set_item("normal", vec3(&|h, _| h.normal)?)?;
    }
    if want("position") {
        out.set_item("position", vec3(&|h, _| h.position)?)?;
    }
    if want("position_error") {
        out.set_item("position_error", vec3(&|h, _| h.position_error)?)?;
    }
    for (name, f) in [
        (
            "shape_id",
            (|h: &cast::RayHit| h.id) as fn(&cast::RayHit) -> u32,
        ),
        ("part", |h: &cast::RayHit| h.part),
    ] {
        if want(name) {
            let v: Vec<u32> = hits.iter().map(|h| h.as_ref().map_or(0, f)).collect();
            out.set_item(
                name,
                Array2::from_shape_vec((n, 1), v)
                    .map_err(shape_err)?
                    .into_shape_with_order(n)
                    .map_err(shape_err)?
                    .into_pyarray(py),
            )?;
        }
    }
    Ok(out)
}

/// Origins of rays continuing from hits (the package's `spawn_rays` prepares the
/// arguments): `position`, `position_error`, `normal` and `directions`, each (N, 3)
/// float64; returns (N, 3) origins, NaN where the normal is 0 (a miss).
#[pyfunction]
fn _spawn_rays<'py>(
    py: Python<'py>,
    position: numpy::PyReadonlyArrayDyn<'py, f64>,
    position_error: numpy::PyReadonlyArrayDyn<'py, f64>,
    normal: numpy::PyReadonlyArrayDyn<'py, f64>,
    directions: numpy::PyReadonlyArrayDyn<'py, f64>,
) -> PyResult<Bound<'py, PyAny>> {
    let p = flat(&position, "position")?;
    let e = flat(&position_error, "position_error")?;
    let nrm = flat(&normal, "normal")?;
    let d = flat(&directions, "directions")?;
    let n = p.len() / 3;
    if p.len() != 3 * n || e.len() != 3 * n || nrm.len() != 3 * n || d.len() != 3 * n {
        return Err(PyValueError::new_err(
            "position, position_error, normal, directions: sizes differ",
        ));
    }
    let at = |a: &[f64], i: usize| DVec3::from_slice(&a[3 * i..3 * i + 3]);
    let v: Vec<f64> = (0..n)
        .flat_map(|i| cast::offset_origin(at(p, i), at(e, i), at(nrm, i), at(d, i)).to_array())
        .collect();
    Ok(Array2::from_shape_vec((n, 3), v)
        .map_err(shape_err)?
        .into_pyarray(py)
        .into_any())
}

/// The oracle's nearest hit (double-double, every cylinder tested) of each ray, for the
/// tests: `(t_hit, index)`, `inf` and -1 on a miss.
#[pyfunction]
fn _oracle_cast(
    scene: &Bound<'_, PyScene>,
    origins: Vec<[f64; 3]>,
    directions: Vec<[f64; 3]>,
) -> (Vec<f64>, Vec<i64>) {
    use crate::verify::oracle::{DD, Problem, intersect};
    let sc = &scene.get().scene;
    origins
        .iter()
        .zip(&directions)
        .map(|(o, d)| {
            let (o, d) = (DVec3::from_array(*o), DVec3::from_array(*d));
            sc.cylinders
                .iter()
                .enumerate()
                .filter_map(|(i, c)| {
                    intersect(&Problem::new(c, o, d), DD::ZERO, DD::new(f64::INFINITY))
                        .map(|h| (h.t.to_f64(), i as i64))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .unwrap_or((f64::INFINITY, -1))
        })
        .unzip()
}

/// Seconds per `render` of camera 0 with the default AOVs, timed inside Rust over `calls`
/// calls (the bench's measure of what a Python call adds).
#[pyfunction]
fn _time_render(py: Python<'_>, scene: &Bound<'_, PyScene>, calls: usize) -> PyResult<f64> {
    let sc = &scene.get().scene;
    let opts = RenderOptions::new(scene::default_aovs());
    run(py, None, || {
        let t0 = std::time::Instant::now();
        for _ in 0..calls {
            std::hint::black_box(crate::render::render(sc, &opts));
        }
        t0.elapsed().as_secs_f64() / calls.max(1) as f64
    })
}

// ---- generate ----------------------------------------------------------------------------

/// The options of `cylaov generate` from the keys of `generate.json` (JSON text; `None`:
/// the defaults) and the seed; the settings' `count` is ignored, a different `seed` refused.
fn options(settings: Option<&str>, seed: u64) -> PyResult<(GenerateOptions, ConfigFile)> {
    let config: ConfigFile = match settings {
        None => ConfigFile::default(),
        Some(text) => {
            let de = &mut serde_json::Deserializer::from_str(text);
            serde_path_to_error::deserialize(de).map_err(|e| {
                let path = e.path().to_string();
                PyValueError::new_err(format!("settings.{path}: {}", e.into_inner()))
            })?
        }
    };
    if let Some(s) = config.seed
        && s != seed
    {
        return Err(PyValueError::new_err(format!(
            "settings.seed: {s} differs from the seed argument {seed}"
        )));
    }
    let mut o = GenerateOptions::default();
    o.apply(&config);
    o.validate()
        .map_err(|e| PyValueError::new_err(format!("settings: {e}")))?;
    Ok((o, config))
}

fn generated(
    o: &GenerateOptions,
    seed: u64,
    index: u64,
    threads: Option<usize>,
) -> PyResult<PyScene> {
    let (file, scene) = on_pool(threads, || {
        let file = o.scene(seed, index)?;
        let scene = file.validate().map_err(|e| e.to_string());
        Ok::<_, String>((file, scene))
    })?
    .map_err(PyValueError::new_err)?;
    Ok(PyScene {
        scene: scene.map_err(scene_error)?,
        file: Some(file),
    })
}

/// Scene `index` of `seed` with the options `settings` (JSON text of `generate.json`'s
/// keys, or None), as `cylaov generate` writes it.
#[pyfunction]
#[pyo3(signature = (settings, seed, index))]
fn _generate(settings: Option<&str>, seed: u64, index: u64) -> PyResult<PyScene> {
    let (o, _) = options(settings, seed)?;
    generated(&o, seed, index, None)
}

/// The dataset's state (the package's `Dataset` wraps it): options, seed, length, AOVs.
#[pyclass(module = "cylaov", frozen)]
struct _Views {
    options: GenerateOptions,
    seed: u64,
    length: u64,
    aovs: Vec<Aov>,
    threads: Option<usize>,
}

#[pymethods]
impl _Views {
    #[new]
    #[pyo3(signature = (settings, seed, length, aovs, views_per_scene, threads))]
    fn new(
        settings: Option<&str>,
        seed: u64,
        length: u64,
        aovs: Vec<String>,
        views_per_scene: u32,
        threads: Option<usize>,
    ) -> PyResult<Self> {
        let (mut options, config) = options(settings, seed)?;
        if let Some(v) = config.views_per_scene
            && v != views_per_scene
        {
            return Err(PyValueError::new_err(format!(
                "settings.views_per_scene: {v} differs from the views_per_scene argument {views_per_scene}"
            )));
        }
        options.views_per_scene = views_per_scene;
        options
            .validate()
            .map_err(|e| PyValueError::new_err(format!("views_per_scene: {e}")))?;
        if threads == Some(0) {
            return Err(PyValueError::new_err("threads: must be >= 1, got 0"));
        }
        // Each view allocates its planes afresh: kept by the allocator, their pages are
        // reused warm instead of faulted in again (`cylaov bench --python` times a 320x240
        // depth+normal view with it). A process-wide policy, taken by streaming datasets only.
        crate::mem::keep_freed_memory();
        Ok(_Views {
            options,
            seed,
            length,
            aovs: parse_aovs(&aovs)?,
            threads,
        })
    }

    /// View `i`: the arrays of `render` and `camera_info` under `"camera_info"`.
    fn item<'py>(&self, py: Python<'py>, i: i64) -> PyResult<Bound<'py, PyDict>> {
        let k = self.position(i)?;
        // Generation, validation, the trace and the arrays in one trip to the pool, the
        // GIL released: each trip costs a hand-over to a worker and back.
        let (a, v) = run_stoppable(py, self.threads, |stop| self.view(k, stop))??;
        view_dict(py, a, &v)
    }

    /// Views `indices` in one trip to the pool (`Dataset.__getitems__`, which PyTorch's
    /// `DataLoader` calls once a batch): the views render side by side, each one also on
    /// the pool, so small views fill the cores that one alone leaves idle. Each item is the
    /// same as `item(i)`: a render is a pure function of its view.
    fn items<'py>(&self, py: Python<'py>, indices: Vec<i64>) -> PyResult<Bound<'py, PyList>> {
        let ks = indices
            .iter()
            .map(|&i| self.position(i))
            .collect::<PyResult<Vec<_>>>()?;
        let views = run_stoppable(py, self.threads, |stop| {
            use rayon::prelude::*;
            ks.par_iter()
                .map(|&k| self.view(k, stop))
                .collect::<PyResult<Vec<_>>>()
        })??;
        let out = PyList::empty(py);
        for (a, v) in views {
            out.append(view_dict(py, a, &v)?)?;
        }
        Ok(out)
    }
}

impl _Views {
    /// Index `i` (negative counts from the end) as a view number, or `IndexError`.
    fn position(&self, i: i64) -> PyResult<u64> {
        let n = i128::from(self.length);
        let k = if i < 0 {
            i128::from(i) + n
        } else {
            i128::from(i)
        };
        if !(0..n).contains(&k) {
            return Err(PyIndexError::new_err(format!(
                "index {i} out of range for a dataset of {n} views"
            )));
        }
        Ok(k as u64)
    }

    /// View `k` rendered, with its `camera_info` as JSON (on a pool thread, no GIL).
    fn view(&self, k: u64, stop: &AtomicBool) -> PyResult<(Arrays, serde_json::Value)> {
        let v = self.options.views_per_scene as u64;
        let (index, camera) = (k / v, (k % v) as usize);
        let file = self
            .options
            .scene(self.seed, index)
            .map_err(PyValueError::new_err)?;
        let mut sc = file.validate().map_err(scene_error)?;
        sc.select_camera(camera)
            .map_err(|e| PyIndexError::new_err(format!("camera: {e}")))?;
        let opts = RenderOptions::new(traced(&self.aovs));
        // `None` only when stopped, and then `run_stoppable` raises instead.
        let r = crate::render::render_until(&sc, &opts, stop)
            .ok_or_else(|| PyValueError::new_err("stopped"))?;
        let a = arrays(r.image, &self.aovs);
        let text = crate::output::io::camera_json(&Camera::new(sc.camera), &self.aovs);
        let v: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok((a, v))
    }
}

/// A view's dict: its arrays and `"camera_info"`.
fn view_dict<'py>(
    py: Python<'py>,
    a: Arrays,
    info: &serde_json::Value,
) -> PyResult<Bound<'py, PyDict>> {
    let d = arrays_to_dict(py, a)?;
    d.set_item("camera_info", json_to_py(py, info)?)?;
    Ok(d)
}

// ---- files -------------------------------------------------------------------------------

/// Which AOV a per-AOV file holds: the header's `cylaov:channel:NAME` attribute.
fn header_dict<'py>(py: Python<'py>, path: &Path) -> PyResult<(Bound<'py, PyDict>, Vec<String>)> {
    use exr::meta::attribute::AttributeValue;
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| PyOSError::new_err(format!("{}: {e}", path.display())))?;
    let d = PyDict::new(py);
    let mut aovs = Vec::new();
    let Some(h) = meta.headers.first() else {
        return Ok((d, aovs));
    };
    let m44 = |m: &[f32; 16]| -> Vec<Vec<f32>> { m.chunks(4).map(|r| r.to_vec()).collect() };
    if let Some(m) = &h.own_attributes.world_to_camera {
        d.set_item("worldToCamera", m44(m))?;
    }
    if let Some(m) = &h.own_attributes.world_to_normalized_device {
        d.set_item("worldToNDC", m44(m))?;
    }
    for (k, v) in h
        .own_attributes
        .other
        .iter()
        .chain(&h.shared_attributes.other)
    {
        let key = k.to_string();
        if let Some(a) = key.strip_prefix("cylaov:channel:") {
            aovs.push(a.to_string());
        }
        match v {
            AttributeValue::Text(t) => d.set_item(key, t.to_string())?,
            AttributeValue::F32(x) => d.set_item(key, *x)?,
            AttributeValue::F64(x) => d.set_item(key, *x)?,
            AttributeValue::I32(x) => d.set_item(key, *x)?,
            AttributeValue::Matrix4x4(m) => d.set_item(key, m44(m))?,
            _ => {}
        }
    }
    Ok((d, aovs))
}

/// Read one of cylaov's EXRs (layered, or one AOV of the per-AOV layout) into arrays keyed
/// by AOV, as `render` returns them (`mask` included), and the header's attributes under
/// `"header"`. Raises FileNotFoundError (OSError) when the file cannot be read.
#[pyfunction]
fn read<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    exr_input(&path)?;
    let (header, named) = header_dict(py, &path)?;
    let mut image = run(py, None, || AovImage::read_exr(&path))?
        .map_err(|e| PyOSError::new_err(format!("{e:#}")))?;
    // Per-AOV files name their channels Y or R, G, B: rename to the AOV's channels.
    let per_aov = image
        .names()
        .iter()
        .all(|c| ["Y", "R", "G", "B"].contains(c));
    let mut aovs: Vec<Aov> = Vec::new();
    if per_aov && named.len() == 1 {
        let a = parse_aov(&named[0], "header cylaov:channel")?;
        for (from, to) in per_aov_channel_names(a).iter().zip(channel_names(a)) {
            image.rename_channel(from, to);
        }
        image = image.regrouped();
        aovs.push(a);
    } else {
        aovs.extend(
            Aov::ALL
                .into_iter()
                .filter(|&a| image.aov_buffer(a).is_some()),
        );
    }
    if aovs.is_empty() {
        let want: Vec<String> = Aov::ALL
            .iter()
            .map(|&a| channel_names(a).join(", "))
            .collect();
        return Err(PyValueError::new_err(format!(
            "{}: not one of cylaov's EXRs: its channels are [{}]; expected the channels of at \
             least one AOV ({}), or a per-AOV file (Y or R, G, B) with a cylaov:channel:NAME \
             attribute",
            path.display(),
            image.names().join(", "),
            want.join("; ")
        )));
    }
    let d = image_to_dict(py, image, &aovs)?;
    d.set_item("header", header)?;
    Ok(d)
}

/// Refuse what is not a regular EXR file that fits in memory, before reading a sample:
/// a FIFO or a device would block with the GIL held, and a header may claim any size
/// (the memory check of `cylaov compare`, a `MemoryError` instead of an abort).
fn exr_input(path: &Path) -> PyResult<()> {
    let m = std::fs::metadata(path).map_err(|e| os_error(path, &e))?;
    if m.is_dir() {
        return Err(PyIsADirectoryError::new_err(format!(
            "{}: is a directory, not an EXR file",
            path.display()
        )));
    }
    if !m.is_file() {
        return Err(PyOSError::new_err(format!(
            "{}: not a regular file",
            path.display()
        )));
    }
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| PyOSError::new_err(format!("{}: {e}", path.display())))?;
    let Some(h) = meta.headers.first() else {
        return Err(PyOSError::new_err(format!(
            "{}: no image in the file",
            path.display()
        )));
    };
    let pixels = h.layer_size.0 as u64 * h.layer_size.1 as u64;
    // 4 bytes a sample as it is read, 2 MiB for the read buffers.
    let bytes = 4 * pixels * h.channels.list.len() as u64 + (2 << 20);
    crate::mem::check_memory(&format!("reading {}", path.display()), bytes)
        .map_err(|e| pyo3::exceptions::PyMemoryError::new_err(e.to_string()))
}

/// An image from a path or from a dict of arrays (as `render` or `read` return).
fn image_of(obj: &Bound<'_, PyAny>, which: &str) -> PyResult<(AovImage, String)> {
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut buffers = Vec::new();
        let (mut w, mut h) = (0usize, 0usize);
        for a in Aov::ALL {
            let Some(arr) = d.get_item(a.name())? else {
                continue;
            };
            let np = obj.py().import("numpy")?;
            let names = channel_names(a);
            let dtype = if a.is_u32() { "uint32" } else { "float32" };
            let arr = np.call_method1("ascontiguousarray", (arr, dtype))?;
            let shape: Vec<usize> = arr.getattr("shape")?.extract()?;
            let (hh, ww) = match (&shape[..], names.len()) {
                ([hh, ww], 1) => (*hh, *ww),
                ([hh, ww, 3], 3) => (*hh, *ww),
                _ => {
                    return Err(PyValueError::new_err(format!(
                        "{which}[{:?}]: shape {shape:?} is not (H, W){}",
                        a.name(),
                        if names.len() == 3 { " x 3" } else { "" }
                    )));
                }
            };
            if !buffers.is_empty() && (ww, hh) != (w, h) {
                return Err(PyValueError::new_err(format!(
                    "{which}: arrays of different sizes: {:?} is {hh} x {ww}, the AOVs before it {h} x {w}",
                    a.name()
                )));
            }
            (w, h) = (ww, hh);
            let data = if a.is_u32() {
                ChannelData::U32(arr.call_method0("ravel")?.extract()?)
            } else {
                ChannelData::F32(arr.call_method0("ravel")?.extract()?)
            };
            buffers.push(AovBuffer::new(names, data));
        }
        if buffers.is_empty() {
            return Err(PyValueError::new_err(format!(
                "{which}: no AOV arrays in the dict"
            )));
        }
        return Ok((
            AovImage {
                width: w,
                height: h,
                buffers,
            },
            format!("<{which}>"),
        ));
    }
    let path: PathBuf = obj
        .extract()
        .map_err(|_| PyTypeError::new_err(format!("{which}: a path or a dict of arrays")))?;
    exr_input(&path)?;
    let img = on_pool(None, || AovImage::read_exr(&path))?
        .map_err(|e| PyOSError::new_err(format!("{e:#}")))?;
    Ok((img, path.display().to_string()))
}

/// Compare two renders pixel by pixel, as `cylaov compare --json` does, and return its
/// report as a dict (`report["passed"]`, `["failures"]`, `["tolerances"]`, `["report"]`).
///
/// `a`, `b`: EXR paths or dicts of arrays (`render`'s or `read`'s). Keywords, the command's
/// flags in snake_case: `max_mismatch_fraction`, `max_seam_fraction`, `rel_distance`,
/// `rel_depth`, `normal_deg`, and `scene` (a Scene or a path: grazing pixels of A get
/// their float32 conditioning bound) with `conditioning_ulps`.
#[pyfunction]
#[pyo3(signature = (a, b, **options))]
fn compare<'py>(
    py: Python<'py>,
    a: &Bound<'py, PyAny>,
    b: &Bound<'py, PyAny>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let mut tol = Tolerances::default();
    let mut scene_arg = None;
    let mut ulps = verify::CONDITIONING_ULPS;
    if let Some(opts) = options {
        for (k, v) in opts.iter() {
            let key: String = k.extract()?;
            let num = |v: &Bound<'_, PyAny>| -> PyResult<f64> {
                let x: f64 = v.extract()?;
                if x.is_nan() || x < 0.0 {
                    return Err(PyValueError::new_err(format!(
                        "{key}: must be >= 0, got {x}"
                    )));
                }
                Ok(x)
            };
            match key.as_str() {
                "max_mismatch_fraction" => tol.max_mismatch_fraction = num(&v)?,
                "max_seam_fraction" => tol.max_seam_fraction = num(&v)?,
                "rel_distance" => tol.rel_distance = num(&v)?,
                "rel_depth" => tol.rel_depth = num(&v)?,
                "normal_deg" => tol.normal_deg = num(&v)?,
                "conditioning_ulps" => ulps = num(&v)?,
                "scene" => scene_arg = Some(v),
                _ => {
                    return Err(PyTypeError::new_err(format!(
                        "compare: unknown option {key:?}; one of max_mismatch_fraction, max_seam_fraction, rel_distance, rel_depth, normal_deg, scene, conditioning_ulps"
                    )));
                }
            }
        }
    }
    let (ia, la) = image_of(a, "a")?;
    let (ib, lb) = image_of(b, "b")?;
    let scene = match &scene_arg {
        None => None,
        Some(s) => Some(match s.cast::<PyScene>() {
            Ok(s) => s.get().scene.clone(),
            Err(_) => PyScene::load(s.extract()?)?.scene,
        }),
    };
    let report = run(py, None, || -> Result<_, String> {
        let cond = match &scene {
            None => None,
            Some(sc) => Some(Conditioning::with_ulps(sc, &ia, ulps).ok_or_else(|| {
                format!("scene: {la} must be that scene's render with shape_id, distance and normal, at its size")
            })?),
        };
        verify::compare_with(&ia, &ib, cond.as_ref()).map_err(|e| format!("comparing {la} with {lb}: {e:#}"))
    })?.map_err(PyValueError::new_err)?;
    let failures = report.failures(&tol);
    let v = serde_json::json!({
        "a": la,
        "b": lb,
        "passed": failures.is_empty(),
        "failures": failures,
        "tolerances": tol,
        "report": report,
    });
    json_to_py(py, &v)
}

/// Write hit points as a PLY point cloud (`cylaov.to_ply` prepares the flat arrays): the
/// file is refused where `render --ply` refuses it (a link, a FIFO) and written whole or
/// not at all. Returns the number of points.
#[pyfunction]
fn _write_ply(
    py: Python<'_>,
    position: PyReadonlyArray1<'_, f32>,
    normal: PyReadonlyArray1<'_, f32>,
    ids: PyReadonlyArray1<'_, u32>,
    path: PathBuf,
) -> PyResult<usize> {
    use crate::output::ply::{Hit, encode};
    let (p, n, ids) = (position.as_slice()?, normal.as_slice()?, ids.as_slice()?);
    let count = ids.len() / 3;
    if p.len() != 3 * count || n.len() != 3 * count || ids.len() != 3 * count {
        return Err(PyValueError::new_err(
            "to_ply: position, normal and the ids must describe the same points",
        ));
    }
    let hits: Vec<Hit> = (0..count)
        .map(|i| Hit {
            position: [p[3 * i], p[3 * i + 1], p[3 * i + 2]],
            normal: [n[3 * i], n[3 * i + 1], n[3 * i + 2]],
            shape_id: ids[3 * i],
            part: ids[3 * i + 1],
            label: ids[3 * i + 2],
        })
        .collect();
    py.detach(|| {
        crate::output::io::check_output("path", &path, &[])?;
        let bytes = encode(
            &hits,
            &format!("cylaov {} hit points", env!("CARGO_PKG_VERSION")),
        );
        crate::output::io::atomic_write_bytes(&path, &bytes)
    })
    .map_err(|e| os_error(&path, &e))?;
    Ok(count)
}

// ---- the module --------------------------------------------------------------------------

/// The compiled half of the `cylaov` package (import `cylaov`, not this).
#[pymodule]
fn _cylaov(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("SceneError", m.py().get_type::<SceneError>())?;
    m.add("InternalError", m.py().get_type::<InternalError>())?;
    // numpy's API capsule now, not in the first call that returns an array, where a
    // signal arriving during the import would surface as a panic.
    numpy::PyArray1::<u8>::zeros(m.py(), 0, false);
    m.add_class::<PyScene>()?;
    m.add_class::<_Views>()?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(camera_info, m)?)?;
    m.add_function(wrap_pyfunction!(camera_rays, m)?)?;
    m.add_function(wrap_pyfunction!(_cast_rays, m)?)?;
    m.add_function(wrap_pyfunction!(_spawn_rays, m)?)?;
    m.add_function(wrap_pyfunction!(_oracle_cast, m)?)?;
    m.add_function(wrap_pyfunction!(_scene_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(_time_render, m)?)?;
    m.add_function(wrap_pyfunction!(_generate, m)?)?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(_write_ply, m)?)?;
    shards::register(m)?;
    scan::register(m)?;
    Ok(())
}
