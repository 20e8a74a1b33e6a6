//! The failures file of a batch run, `OUT/failures.LABEL.jsonl`: one JSON object a line per
//! view that failed, written whole (staged, then renamed) once the run's views are done, so
//! a reader never sees half a record. Both formats write theirs through [`write_failures`].

use crate::output::store::atomic::atomic_write_bytes;
use anyhow::{Context, Result};
use serde::Serialize;
use std::path::Path;

/// Write `failures` to `path`, one JSON line each (an empty file when none failed).
pub(super) fn write_failures<T: Serialize>(path: &Path, failures: &[T]) -> Result<()> {
    let mut lines = String::new();
    for f in failures {
        lines.push_str(&serde_json::to_string(f)?);
        lines.push('\n');
    }
    atomic_write_bytes(path, lines.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}
