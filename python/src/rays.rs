//! Rays: the camera's own pixel rays, rays cast from any origin, and rays continued from
//! their hits.

use crate::arrays::shape_err;
use crate::convert::{camera_arg, kernel};
use crate::errors::{InternalError, memory_error};
use crate::pool::{run_stoppable, threads_arg};
use crate::scene::PyScene;
use cylaov::mem::try_reserve;
use cylaov::render::cast::{self, Ray};
use cylaov::scene::camera::{Camera, Projection};
use glam::DVec3;
use numpy::IntoPyArray;
use numpy::ndarray::{Array2, Array3, ArrayD, IxDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The camera's own pixel rays, `(origins, directions)`, each (H, W, 3) float64: the
/// direction through pixel (i, j)'s centre, scaled so its camera-space z is 1 (so `t` along
/// it is planar depth). Cast with `t_min=near_clip, t_max=far_clip`, they are the rays a
/// render traces, bit for bit. Every model's own rays ([`Camera::pixel_ray`]): the
/// orthographic camera's start on its image plane at the pixel's offset; a lens model's
/// rays whose depth is Euclidean (equirectangular, a fisheye at or beyond 90°) are unit,
/// so `t` is their distance and the clips bound it, as the render counts them. Rays that
/// do not fit in the memory left raise `MemoryError` (48 bytes a pixel).
#[pyfunction]
#[pyo3(signature = (scene, camera=0))]
pub(crate) fn camera_rays<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    #[pyo3(from_py_with = camera_arg)] camera: usize,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let sc = scene.get().with_camera(camera)?;
    let cam = Camera::new(sc.camera);
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    // Both arrays, 3 float64 a pixel each, handed to numpy as they are. Checked first, as
    // the machine may promise memory it cannot give (overcommit); reserved fallibly, as a
    // refusal would otherwise abort the interpreter.
    let n = 3 * w * h;
    let what = format!("the camera rays of {w}x{h}");
    crate::pool::check_memory(None, &what, 2 * 8 * n as u64)?;
    let (mut o, mut d) = (Vec::new(), Vec::new());
    try_reserve(&mut o, n, "the camera rays' origins").map_err(memory_error)?;
    try_reserve(&mut d, n, "the camera rays' directions").map_err(memory_error)?;
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
/// `directions` (N, 3), `t_min` and `t_max` (N,), all float64; `origins` may be one row,
/// and `t_min`, `t_max` one value, for every ray (a copy a ray would say the same in
/// memory and time). Returns the requested arrays, flat.
#[pyfunction]
#[pyo3(signature = (scene, origins, directions, t_min, t_max, aovs, precision="f64", formula="stable", threads=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn _cast_rays<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    origins: numpy::PyReadonlyArrayDyn<'py, f64>,
    directions: numpy::PyReadonlyArrayDyn<'py, f64>,
    t_min: numpy::PyReadonlyArrayDyn<'py, f64>,
    t_max: numpy::PyReadonlyArrayDyn<'py, f64>,
    aovs: Vec<String>,
    precision: &str,
    formula: &str,
    #[pyo3(from_py_with = threads_arg)] threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let k = kernel(precision, formula)?;
    let (o, d) = (flat(&origins, "origins")?, flat(&directions, "directions")?);
    let (lo, hi) = (flat(&t_min, "t_min")?, flat(&t_max, "t_max")?);
    let n = d.len() / 3;
    let fits = |len: usize, per: usize| len == per || len == per * n;
    if d.len() != 3 * n || !fits(o.len(), 3) || !fits(lo.len(), 1) || !fits(hi.len(), 1) {
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
    // What a cast holds at its peak, a ray: the ray (64 bytes), its place in the grouping
    // by origin (4), its hit twice (96 each: as found, then gathered) and the outputs
    // asked for (at most 88): checked first, as a refusal would end the interpreter.
    let bytes = n as u64 * (64 + 4 + 2 * 96 + 88);
    crate::pool::check_memory(threads, &format!("casting {n} rays"), bytes)?;
    // Ray `i`'s value of an argument given once or a ray.
    let at = |a: &[f64], per: usize, i: usize| if a.len() == per { 0 } else { per * i };
    let mut rays: Vec<Ray> = Vec::new();
    try_reserve(&mut rays, n, "the rays").map_err(memory_error)?;
    rays.extend((0..n).map(|i| Ray {
        origin: DVec3::from_slice(&o[at(o, 3, i)..at(o, 3, i) + 3]),
        dir: DVec3::from_slice(&d[3 * i..3 * i + 3]),
        t_min: lo[at(lo, 1, i)],
        t_max: hi[at(hi, 1, i)],
    }));
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
pub(crate) fn _spawn_rays<'py>(
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
