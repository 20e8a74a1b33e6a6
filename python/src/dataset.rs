//! `cylaov.generate` and `cylaov.Dataset`: `cylaov generate`'s scenes and their views,
//! rendered on demand.

use crate::arrays::{Arrays, arrays, arrays_to_dict, check_views_memory, traced};
use crate::convert::{integer, json_to_py, parse_aovs, seed_arg};
use crate::errors::scene_error;
use crate::pool::{on_pool, run_stoppable, threads_arg};
use crate::scene::PyScene;
use cylaov::dataset::generate::{ConfigFile, GenerateOptions};
use cylaov::output::format::exr::channel_names;
use cylaov::render::RenderOptions;
use cylaov::scene::Aov;
use cylaov::scene::camera::Camera;
use numpy::PyReadwriteArray1;
use pyo3::exceptions::{PyIndexError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::sync::atomic::AtomicBool;

/// The options of `cylaov generate` from the keys of `generate.json` (JSON text; `None`:
/// the defaults) and the seed; the settings' `count` is ignored, a different `seed` refused.
fn options(settings: Option<&str>, seed: u64) -> PyResult<(GenerateOptions, ConfigFile)> {
    let config: ConfigFile = match settings {
        None => ConfigFile::default(),
        Some(text) => {
            let mut de = serde_json::Deserializer::from_str(text);
            let config = serde_path_to_error::deserialize(&mut de).map_err(|e| {
                let path = e.path().to_string();
                PyValueError::new_err(format!("settings.{path}: {}", e.into_inner()))
            })?;
            // A second object after the first would otherwise be ignored.
            de.end().map_err(|e| {
                PyValueError::new_err(format!(
                    "settings: text after the end of the JSON object at line {} column {}",
                    e.line(),
                    e.column()
                ))
            })?;
            config
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
pub(crate) fn _generate(
    settings: Option<&str>,
    #[pyo3(from_py_with = seed_arg)] seed: u64,
    #[pyo3(from_py_with = index_arg)] index: u64,
) -> PyResult<PyScene> {
    let (o, _) = options(settings, seed)?;
    generated(&o, seed, index, None)
}

/// The dataset's state (the package's `Dataset` wraps it): options, seed, length, AOVs.
#[pyclass(module = "cylaov", frozen)]
pub(crate) struct _Views {
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
        #[pyo3(from_py_with = seed_arg)] seed: u64,
        #[pyo3(from_py_with = length_arg)] length: u64,
        aovs: Vec<String>,
        #[pyo3(from_py_with = views_per_scene_arg)] views_per_scene: Option<u32>,
        #[pyo3(from_py_with = threads_arg)] threads: Option<usize>,
    ) -> PyResult<Self> {
        let (mut options, config) = options(settings, seed)?;
        // `None`: the settings' count (a `generate.json` written with --views-per-scene
        // needs no repeating), else 1; given, it must agree with the settings.
        let views_per_scene = match (config.views_per_scene, views_per_scene) {
            (Some(v), Some(a)) if v != a => {
                return Err(PyValueError::new_err(format!(
                    "settings.views_per_scene: {v} differs from the views_per_scene argument {a}"
                )));
            }
            (_, Some(a)) => a,
            (Some(v), None) => v,
            (None, None) => 1,
        };
        options.views_per_scene = views_per_scene;
        // The options passed before; the message names `views_per_scene` itself.
        options.validate().map_err(PyValueError::new_err)?;
        // Each view allocates its planes afresh: kept by the allocator, their pages are
        // reused warm instead of faulted in again (`cylaov bench --python` times a 320x240
        // depth+normal view with it). A process-wide policy, taken by streaming datasets only.
        cylaov::mem::keep_freed_memory();
        Ok(_Views {
            options,
            seed,
            length,
            aovs: parse_aovs(&aovs)?,
            threads,
        })
    }

    /// Views a scene: the argument, else the settings', else 1.
    #[getter]
    fn views_per_scene(&self) -> u32 {
        self.options.views_per_scene
    }

    /// View `i`: the arrays of `render` and `camera_info` under `"camera_info"`.
    fn item<'py>(&self, py: Python<'py>, i: i128) -> PyResult<Bound<'py, PyDict>> {
        let k = self.position(i)?;
        self.check_memory(1)?;
        // Generation, validation, the trace and the arrays in one trip to the pool, the
        // GIL released: each trip costs a hand-over to a worker and back.
        let (a, v) = run_stoppable(py, self.threads, |stop| self.view(k, stop))??;
        view_dict(py, a, &v)
    }

    /// Views `indices` in one trip to the pool (`Dataset.__getitems__`, which PyTorch's
    /// `DataLoader` calls once a batch): the views render side by side, each one also on
    /// the pool, so small views fill the cores that one alone leaves idle. Each item is the
    /// same as `item(i)`: a render is a pure function of its view.
    fn items<'py>(&self, py: Python<'py>, indices: Vec<i128>) -> PyResult<Bound<'py, PyList>> {
        let ks = indices
            .iter()
            .map(|&i| self.position(i))
            .collect::<PyResult<Vec<_>>>()?;
        // Every view's arrays are held until the list is made.
        self.check_memory(ks.len())?;
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

    /// An item's arrays as `(name, numpy dtype, shape)`, in the order of its dict: the
    /// same for every view, so a batch's buffer can be sized before it renders.
    fn layout(&self) -> Vec<(&'static str, &'static str, Vec<usize>)> {
        let (h, w) = (self.options.height as usize, self.options.width as usize);
        let mut v: Vec<_> = self
            .aovs
            .iter()
            .map(|&a| {
                let c = channel_names(a).len();
                let dtype = if a.is_u32() { "uint32" } else { "float32" };
                let shape = if c == 1 { vec![h, w] } else { vec![h, w, c] };
                (a.name(), dtype, shape)
            })
            .collect();
        v.push(("mask", "bool", vec![h, w]));
        v
    }

    /// Views `indices` rendered as `items` renders them, each array copied into `out`
    /// (bytes) while the render has it in cache: array `k` of item `j` at
    /// `offsets[k] + j * bytes(k)`, `offsets` ascending. A batch's arrays thus lie back to
    /// back, each one already the stacked tensor collation would copy them into. Returns
    /// each item's `camera_info`.
    fn items_into<'py>(
        &self,
        py: Python<'py>,
        indices: Vec<i128>,
        mut out: PyReadwriteArray1<'py, u8>,
        offsets: Vec<usize>,
    ) -> PyResult<Bound<'py, PyList>> {
        let ks = indices
            .iter()
            .map(|&i| self.position(i))
            .collect::<PyResult<Vec<_>>>()?;
        // A view's arrays are dropped once copied into `out`, but the pool may have every
        // view of the batch under way at once (a thread waiting inside one view's render
        // takes up the next view).
        self.check_memory(ks.len())?;
        let sizes: Vec<usize> = self
            .layout()
            .iter()
            .map(|(_, dtype, shape)| {
                let item = if *dtype == "bool" { 1 } else { 4 };
                shape.iter().product::<usize>() * item
            })
            .collect();
        if offsets.len() != sizes.len() {
            return Err(PyValueError::new_err(format!(
                "offsets: {} of them for {} arrays an item",
                offsets.len(),
                sizes.len()
            )));
        }
        let buf = out.as_slice_mut()?;
        // Each item's destinations, split off the buffer block by block.
        let mut slots: Vec<Vec<&mut [u8]>> = ks.iter().map(|_| Vec::new()).collect();
        let (mut rest, mut at) = (buf, 0usize);
        for (&off, &size) in offsets.iter().zip(&sizes) {
            let len = size * ks.len();
            if off < at || off - at + len > rest.len() {
                return Err(PyValueError::new_err(format!(
                    "offsets: {offsets:?} do not fit a buffer of {} bytes for {} items",
                    at + rest.len(),
                    ks.len()
                )));
            }
            let (block, tail) = std::mem::take(&mut rest)[off - at..].split_at_mut(len);
            if size > 0 {
                for (slot, chunk) in slots.iter_mut().zip(block.chunks_exact_mut(size)) {
                    slot.push(chunk);
                }
            }
            rest = tail;
            at = off + len;
        }
        let infos = run_stoppable(py, self.threads, |stop| {
            use rayon::prelude::*;
            ks.par_iter()
                .zip(slots.into_par_iter())
                .map(|(&k, mut slot)| {
                    let (a, v) = self.view(k, stop)?;
                    let src = a.bytes();
                    let fits = src.len() == slot.len()
                        && src.iter().zip(&slot).all(|(s, d)| s.len() == d.len());
                    if !fits {
                        return Err(PyValueError::new_err(format!(
                            "view {k}: its arrays do not match the dataset's layout"
                        )));
                    }
                    for (s, d) in src.iter().zip(slot.iter_mut()) {
                        d.copy_from_slice(s);
                    }
                    Ok(v)
                })
                .collect::<PyResult<Vec<_>>>()
        })??;
        let list = PyList::empty(py);
        for v in &infos {
            list.append(json_to_py(py, v)?)?;
        }
        Ok(list)
    }
}

impl _Views {
    /// Refuse, as `MemoryError`, rendering `views` views at once when they do not fit.
    fn check_memory(&self, views: usize) -> PyResult<()> {
        let size = (self.options.width, self.options.height);
        check_views_memory(size, &traced(&self.aovs), views, self.threads)
    }

    /// Index `i` (negative counts from the end) as a view number, or `IndexError`.
    fn position(&self, i: i128) -> PyResult<u64> {
        let n = i128::from(self.length);
        let k = if i < 0 { i + n } else { i };
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
        let r = cylaov::render::render_until(&sc, &opts, stop)
            .ok_or_else(|| PyValueError::new_err("stopped"))?;
        let a = arrays(r.image, &self.aovs);
        let text =
            cylaov::output::format::camera_files::camera_json(&Camera::new(sc.camera), &self.aovs);
        let v: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok((a, v))
    }
}

/// `index=` of `generate`: any integer of 64 bits, >= 0.
fn index_arg(obj: &Bound<'_, PyAny>) -> PyResult<u64> {
    Ok(integer(obj, "index", 0, i128::from(u64::MAX))? as u64)
}

/// `length=` of a `Dataset`: its views, 0 to 2**63 - 1: `len()` of a Python object is at
/// most `sys.maxsize`, and a dataset whose `len` raises is of no use to a `DataLoader`.
fn length_arg(obj: &Bound<'_, PyAny>) -> PyResult<u64> {
    Ok(integer(obj, "length", 0, i128::from(i64::MAX))? as u64)
}

/// `views_per_scene=` of a `Dataset`: `None` (see `_Views::new`) or
/// 1..=`MAX_VIEWS_PER_SCENE` (the library's bound).
fn views_per_scene_arg(obj: &Bound<'_, PyAny>) -> PyResult<Option<u32>> {
    if obj.is_none() {
        return Ok(None);
    }
    let max = cylaov::dataset::generate::MAX_VIEWS_PER_SCENE;
    Ok(Some(
        integer(obj, "views_per_scene", 1, i128::from(max))? as u32
    ))
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
