//! `cylaov.compare`: two renders compared as `cylaov compare` compares them.

use crate::convert::{json_to_py, real};
use crate::files::exr_input;
use crate::pool::{on_pool, run};
use crate::scene::PyScene;
use cylaov::image::{AovBuffer, AovImage, ChannelData};
use cylaov::output::format::exr::channel_names;
use cylaov::scene::Aov;
use cylaov::verify::compare::{self as verify, Conditioning, Tolerances};
use pyo3::exceptions::{PyOSError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

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
            // (H, W) for one channel, (H, W, C) for C (`uv` 2, `normal` 3): as `render` returns.
            let (hh, ww) = match (&shape[..], names.len()) {
                ([hh, ww], 1) => (*hh, *ww),
                ([hh, ww, c], n) if n > 1 && *c == n => (*hh, *ww),
                (_, n) => {
                    let want = if n > 1 {
                        format!("(H, W, {n})")
                    } else {
                        "(H, W)".to_string()
                    };
                    return Err(PyValueError::new_err(format!(
                        "{which}[{:?}]: shape {shape:?} is not {want}",
                        a.name()
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
pub(crate) fn compare<'py>(
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
                let x = real(v, &key)?;
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
                // `None`, the stub's default, is no scene.
                "scene" => scene_arg = (!v.is_none()).then_some(v),
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
