//! `cylaov.scan`: a simulated LiDAR rotation as a dict of numpy arrays, the same columns
//! (names, dtypes, values) as the `.npz` that `cylaov scan` writes. The package's
//! `scan` prepares the arguments (sensor as a preset name or JSON text, trajectory as CSV
//! text).

use crate::arrays::shape_err;
use crate::convert::{integer, seed_arg};
use crate::pool::{run_stoppable, threads_arg};
use crate::scene::PyScene;
use cylaov::scan::{self, Column, Motion, Noise, Pose, ScanOptions, Sensor, Trajectory};
use numpy::IntoPyArray;
use numpy::ndarray::Array2;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Scan `scene`; `sensor` is a preset name or a sensor's JSON text, `pose` 3 or 6 numbers,
/// `trajectory` a trajectory CSV's text.
#[pyfunction]
#[pyo3(signature = (scene, sensor, pose, trajectory=None, returns=1, range_noise=0.0, dropout=0.0, seed=0, threads=None))]
#[allow(clippy::too_many_arguments)]
fn _scan<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    sensor: &str,
    pose: Vec<f64>,
    trajectory: Option<&str>,
    #[pyo3(from_py_with = returns_arg)] returns: u32,
    range_noise: f64,
    dropout: f64,
    #[pyo3(from_py_with = seed_arg)] seed: u64,
    #[pyo3(from_py_with = threads_arg)] threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let sensor = match Sensor::preset(sensor) {
        Some(s) => s,
        None if sensor.trim_start().starts_with('{') => {
            Sensor::from_json(sensor).map_err(|e| PyValueError::new_err(e.0))?
        }
        None => {
            let names: Vec<&str> = scan::sensor::PRESETS.iter().map(|p| p.0).collect();
            return Err(PyValueError::new_err(format!(
                "sensor: {:?} is not a preset ({}), a JSON file or a dict",
                cylaov::scene::strict::shorten(sensor),
                names.join(", ")
            )));
        }
    };
    let text = pose
        .iter()
        .map(|v| format!("{v:?}"))
        .collect::<Vec<_>>()
        .join(",");
    let pose = Pose::parse(&text, "pose").map_err(PyValueError::new_err)?;
    let motion = match trajectory {
        Some(csv) => Motion::Path(Trajectory::from_csv(csv).map_err(PyValueError::new_err)?),
        None => Motion::Fixed(pose),
    };
    let opts = ScanOptions {
        sensor,
        motion,
        returns,
        noise: Noise {
            range_sigma: range_noise,
            dropout,
            seed,
        },
    };
    opts.validate().map_err(PyValueError::new_err)?;
    // A scan that cannot fit raises `MemoryError` here, not an abort in the library.
    crate::pool::check_memory(
        threads,
        &format!("a scan of up to {} points", opts.most_points()),
        opts.memory(),
    )?;
    let sc = &scene.get().scene;
    let points = run_stoppable(py, threads, |stop| scan::scan_until(sc, &opts, stop))?
        .map_err(PyValueError::new_err)?
        .ok_or_else(|| {
            crate::errors::InternalError::new_err("internal error (please report): scan stopped")
        })?;
    let out = PyDict::new(py);
    let n = points.len();
    for (name, col) in points.columns() {
        match col {
            Column::F64(v) => out.set_item(name, v.to_vec().into_pyarray(py))?,
            Column::U32(v) => out.set_item(name, v.to_vec().into_pyarray(py))?,
            Column::F32x3(v) => out.set_item(
                name,
                Array2::from_shape_vec((n, 3), v.as_flattened().to_vec())
                    .map_err(shape_err)?
                    .into_pyarray(py),
            )?,
        }
    }
    Ok(out)
}

/// `returns=`: 1..=15 returns a beam, as the library bounds it.
fn returns_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    Ok(integer(obj, "returns", 1, i128::from(scan::MAX_RETURNS))? as u32)
}

/// Add `_scan` to the module.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(_scan, m)?)?;
    Ok(())
}
