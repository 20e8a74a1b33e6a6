//! The Python extension module `cylaov._cylaov`, wrapped by the package `cylaov`
//! (`python/cylaov/`). A thin layer over the `cylaov` library's public API: each function
//! calls what the command line calls (`scene::load`, `render::render`, `output::format::exr`,
//! `verify::compare`, `dataset::generate`), so a render's arrays are the samples of the EXR
//! `cylaov render` writes, bit for bit. The arrays own the Rust buffers (no copy); the GIL
//! is released while tracing.
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

mod arrays;
mod compare;
mod convert;
mod dataset;
mod errors;
mod files;
mod pool;
mod rays;
mod render;
mod scan;
mod scene;
mod shards;
mod testing;

use errors::{InternalError, SceneError};
use pyo3::prelude::*;
use scene::PyScene;

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
    m.add_class::<dataset::_Views>()?;
    m.add_function(wrap_pyfunction!(render::render, m)?)?;
    m.add_function(wrap_pyfunction!(render::camera_info, m)?)?;
    m.add_function(wrap_pyfunction!(rays::camera_rays, m)?)?;
    m.add_function(wrap_pyfunction!(rays::_cast_rays, m)?)?;
    m.add_function(wrap_pyfunction!(rays::_spawn_rays, m)?)?;
    m.add_function(wrap_pyfunction!(scene::_scene_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::_generate, m)?)?;
    m.add_function(wrap_pyfunction!(files::read, m)?)?;
    m.add_function(wrap_pyfunction!(compare::compare, m)?)?;
    m.add_function(wrap_pyfunction!(files::_write_ply, m)?)?;
    shards::register(m)?;
    scan::register(m)?;
    testing::register(m)?;
    Ok(())
}
