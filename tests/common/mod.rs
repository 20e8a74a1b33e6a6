//! Helpers shared by the integration tests.

use std::path::{Path, PathBuf};

/// The reference venv's Python (`$CYLAOV_VENV`, else `.venv`, as `scripts/setup-venv`
/// makes it). `None` (the caller skips, saying so) when it is missing, unless
/// `CYLAOV_REQUIRE_VENV=1` (set by `scripts/test` once it has made the venv): then a missing
/// venv fails the test instead of letting CI pass without it.
pub fn venv_python() -> Option<PathBuf> {
    let venv = std::env::var_os("CYLAOV_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv"));
    let py = venv.join("bin/python");
    if py.exists() {
        return Some(py);
    }
    assert!(
        std::env::var("CYLAOV_REQUIRE_VENV").as_deref() != Ok("1"),
        "CYLAOV_REQUIRE_VENV=1 but {} does not exist (run scripts/setup-venv)",
        py.display()
    );
    eprintln!("SKIPPED: no {} (run scripts/setup-venv)", py.display());
    None
}
