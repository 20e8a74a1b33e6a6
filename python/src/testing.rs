//! `cylaov._cylaov._testing`: hooks for the tests and the bench, kept out of the package's
//! public module (`from cylaov._cylaov import _testing`).

use crate::pool::run;
use crate::scene::PyScene;
use cylaov::render::RenderOptions;
use cylaov::scene;
use glam::DVec3;
use pyo3::prelude::*;

/// The oracle's nearest hit (double-double, every cylinder tested) of each ray, for the
/// tests: `(t_hit, index)`, `inf` and -1 on a miss.
#[pyfunction]
fn _oracle_cast(
    scene: &Bound<'_, PyScene>,
    origins: Vec<[f64; 3]>,
    directions: Vec<[f64; 3]>,
) -> (Vec<f64>, Vec<i64>) {
    use cylaov::verify::oracle::{DD, Problem, intersect};
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
            std::hint::black_box(cylaov::render::render(sc, &opts));
        }
        t0.elapsed().as_secs_f64() / calls.max(1) as f64
    })
}

/// Add the submodule `_testing` to `m`, and to `sys.modules` so that
/// `import cylaov._cylaov._testing` finds it too (an extension's submodule is only an
/// attribute otherwise).
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    let t = PyModule::new(py, "_testing")?;
    t.add_function(wrap_pyfunction!(_oracle_cast, &t)?)?;
    t.add_function(wrap_pyfunction!(_time_render, &t)?)?;
    m.add_submodule(&t)?;
    py.import("sys")?
        .getattr("modules")?
        .set_item("cylaov._cylaov._testing", &t)?;
    Ok(())
}
