//! `cylaov.Scene`: a validated scene, its constructors, and its pickled state.

use crate::convert::{described, integer, json_to_py, opt_flag, opt_text, py_to_json, shorten};
use crate::errors::{os_error, scene_error};
use crate::pool::on_pool;
use cylaov::dataset::generate::to_json;
use cylaov::scene::{self, Aov, CameraFile, CylinderFile, SceneFile};
use glam::DVec3;
use numpy::{PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::exceptions::{PyIndexError, PyIsADirectoryError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use std::path::PathBuf;

/// A validated cylinder scene: the cylinders and one or more cameras, as a scene file
/// holds them.
///
/// Make one with `Scene.load(path)`, `Scene.from_json(text)`, `Scene.from_dict(d)` or
/// `Scene.from_arrays(p0, p1, radius, ...)`, or get one from `cylaov.generate`. Every
/// constructor validates as `cylaov render` does and raises `cylaov.SceneError` naming the
/// field and the value. A Scene pickles (as its JSON).
#[pyclass(name = "Scene", module = "cylaov", frozen)]
pub struct PyScene {
    pub(crate) scene: scene::Scene,
    /// The file it came from, when `to_json` must give its exact bytes (a generated scene:
    /// `p1` as drawn, not recomputed from the validated axis and height).
    pub(crate) file: Option<SceneFile>,
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
pub(crate) fn _scene_from_state(state: &[u8]) -> PyResult<PyScene> {
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
        .map(|(i, (c, (&caps, &id)))| cylaov::geometry::Cylinder {
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
    c: &cylaov::scene::camera::CameraSpec,
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
    pub(crate) fn load(path: PathBuf) -> PyResult<PyScene> {
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
        format: Option<&Bound<'_, PyAny>>,
        label: Option<&Bound<'_, PyAny>>,
        caps: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyScene> {
        use cylaov::scene::table::{LabelRule, TableFormat, TableOptions, load_table};
        let format = opt_text(format, "format")?
            .map(|f| {
                TableFormat::parse(&f).ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "format: expected one of {}, got {}",
                        TableFormat::ALL.map(|f| f.name()).join(", "),
                        shorten(&format!("{f:?}"))
                    ))
                })
            })
            .transpose()?;
        let label = opt_text(label, "label")?
            .map(|l| {
                LabelRule::parse(&l).ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "label: expected one of {}, got {}",
                        LabelRule::ALL.map(|f| f.name()).join(", "),
                        shorten(&format!("{l:?}"))
                    ))
                })
            })
            .transpose()?;
        let caps = opt_flag(caps, "caps")?;
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
        let file = table.scene_file(cylaov::scene::framing::Frame::default());
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
        cylaov::output::format::mitsuba::to_xml(&self.scene, source_name)
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
        // Python ints too large for any integer dtype (`[2**64, 2]`): each on its own.
        "O" => a
            .call_method0("tolist")?
            .try_iter()?
            .enumerate()
            .map(|(i, x)| {
                let x = x?;
                match integer(&x, "ids", 0, i128::from(u32::MAX)) {
                    Ok(v) => Ok(v as u32),
                    Err(_) => Err(range(i, &described(&x))),
                }
            })
            .collect(),
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
    pub(crate) fn with_camera(&self, camera: usize) -> PyResult<scene::Scene> {
        let mut s = self.scene.clone();
        s.select_camera(camera)
            .map_err(|e| PyIndexError::new_err(format!("camera: {e}")))?;
        Ok(s)
    }
}
