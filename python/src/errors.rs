//! The package's exceptions, and Rust errors and panics as the Python exceptions users
//! expect.

use pyo3::create_exception;
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyPermissionError, PyValueError};
use pyo3::prelude::*;
use std::path::Path;

create_exception!(
    cylaov,
    SceneError,
    PyValueError,
    "A scene that cylaov refuses; the text is the command line's error line without \
     `error: `, naming the field and the value (`cylinders[3].radius: must be > 0 ...`)."
);

create_exception!(
    cylaov,
    InternalError,
    pyo3::exceptions::PyRuntimeError,
    "A fault inside cylaov (a Rust panic, caught): a bug to report, with the call that \
     raised it. The process stays usable."
);

/// A caught panic's message as an `InternalError`.
pub(crate) fn panic_error(p: Box<dyn std::any::Any + Send>) -> PyErr {
    let msg = p
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into());
    InternalError::new_err(format!("internal error (please report): {msg}"))
}

pub(crate) fn scene_error(e: impl std::fmt::Display) -> PyErr {
    SceneError::new_err(e.to_string())
}

/// An IO error as the `OSError` subclass Python users expect, the path first.
pub(crate) fn os_error(path: &Path, e: &std::io::Error) -> PyErr {
    use std::io::ErrorKind;
    let msg = format!("{}: {e}", path.display());
    match e.kind() {
        ErrorKind::NotFound => PyFileNotFoundError::new_err(msg),
        ErrorKind::PermissionDenied => PyPermissionError::new_err(msg),
        _ => PyOSError::new_err(msg),
    }
}

/// A failure as Python's kind: an IO error (a full disk, a permission, a path that is not
/// a folder) as `OSError` (see [`io_kind_error`]), the rest (bad options, bad input) as
/// `ValueError`.
pub(crate) fn value_error(e: anyhow::Error) -> PyErr {
    let msg = format!("{e:#}");
    match e.chain().find_map(|c| c.downcast_ref::<std::io::Error>()) {
        Some(io) => io_kind_error(io, msg),
        None => PyValueError::new_err(msg),
    }
}

/// An IO error with the text `msg` as the `OSError` subclass of its errno, else of its
/// kind: the library's own refusals (a path that is a file where a folder belongs) carry
/// no errno, and `OSError(0, msg)` would print a meaningless `[Errno 0]`. Out of memory
/// (the memory check before a large buffer, or its refusal) is Python's `MemoryError`.
pub(crate) fn io_kind_error(e: &std::io::Error, msg: String) -> PyErr {
    use pyo3::exceptions::{
        PyFileExistsError, PyIsADirectoryError, PyMemoryError, PyNotADirectoryError,
    };
    use std::io::ErrorKind;
    if let Some(errno) = e.raw_os_error() {
        // Python picks the subclass of the errno (`FileNotFoundError` for ENOENT, ...).
        return PyOSError::new_err((errno, msg));
    }
    match e.kind() {
        ErrorKind::OutOfMemory => PyMemoryError::new_err(msg),
        ErrorKind::NotFound => PyFileNotFoundError::new_err(msg),
        ErrorKind::PermissionDenied => PyPermissionError::new_err(msg),
        ErrorKind::AlreadyExists => PyFileExistsError::new_err(msg),
        ErrorKind::NotADirectory => PyNotADirectoryError::new_err(msg),
        ErrorKind::IsADirectory => PyIsADirectoryError::new_err(msg),
        _ => PyOSError::new_err(msg),
    }
}

/// A memory check's refusal (`cylaov::mem::check_memory`, `try_reserve`, `try_zeroed`) as
/// `MemoryError`, with its text (what needed the memory, how much, how much is left).
pub(crate) fn memory_error(e: std::io::Error) -> PyErr {
    let msg = e.to_string();
    io_kind_error(&e, msg)
}
