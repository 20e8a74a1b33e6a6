//! `cylaov.render` and `cylaov.camera_info`: a camera's view as arrays, and its metadata.

use crate::arrays::{arrays, arrays_to_dict, check_views_memory, traced};
use crate::convert::{aov_names, camera_arg, choice, json_to_py, kernel, parse_aovs};
use crate::errors::InternalError;
use crate::pool::{run_stoppable, threads_arg};
use crate::scene::PyScene;
use cylaov::render::{Accel, RenderOptions};
use cylaov::scene::Aov;
use cylaov::scene::camera::Camera;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Render `scene` from camera `camera` into numpy arrays, with no files.
///
/// Returns a dict keyed by AOV name: `depth`, `distance` (H, W) float32; `normal`,
/// `normal_camera`, `position` (H, W, 3) float32; `shape_id`, `part` (H, W) uint32; and
/// `mask` (H, W) bool (True where the pixel's ray hits a cylinder), always. A miss is 0 in
/// every AOV. The samples are, bit for bit, those of the EXR that `cylaov render` writes
/// with the same options (`precision` "f64" | "f32", `formula` "stable" | "literal",
/// `accel` "tiles" | "frustum" | "bvh"). The GIL is released while tracing (Ctrl-C raises
/// `KeyboardInterrupt` within a fraction of a second); `threads` (default: every core)
/// sizes the thread pool; use 1 inside DataLoader workers. A view whose planes do not fit
/// in the memory left raises `MemoryError` before anything is allocated.
#[pyfunction]
#[pyo3(signature = (scene, aovs=None, camera=0, precision="f64", formula="stable", accel="tiles", threads=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn render<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    aovs: Option<&Bound<'py, PyAny>>,
    #[pyo3(from_py_with = camera_arg)] camera: usize,
    precision: &str,
    formula: &str,
    accel: &str,
    #[pyo3(from_py_with = threads_arg)] threads: Option<usize>,
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
    check_views_memory((sc.camera.width, sc.camera.height), &opts.aovs, 1, threads)?;
    let a = run_stoppable(py, threads, |stop| {
        cylaov::render::render_until(&sc, &opts, stop).map(|r| arrays(r.image, &aovs))
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
pub(crate) fn camera_info<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    #[pyo3(from_py_with = camera_arg)] camera: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let sc = scene.get().with_camera(camera)?;
    let text = cylaov::output::format::camera_files::camera_json(&Camera::new(sc.camera), &sc.aovs);
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| PyValueError::new_err(e.to_string()))?;
    json_to_py(py, &v)
}
