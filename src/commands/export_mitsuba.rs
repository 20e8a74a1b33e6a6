//! `cylaov export-mitsuba`: scene file → Mitsuba 3 XML (see [`crate::output::format::mitsuba`]).

use crate::output::store::atomic::{NewDirs, atomic_write_bytes};

use crate::output::format::mitsuba::{shapes, to_xml};
use crate::output::store::targets::check_outputs;
use crate::scene;
use anyhow::{Context, Result};
use std::path::Path;

/// Export `scene_path` to `out` and return a one-line summary.
pub fn run(scene_path: &Path, out: &Path) -> Result<String> {
    let (scene, table) =
        scene::load_with_table(scene_path).with_context(|| format!("{}", scene_path.display()))?;
    let inputs: Vec<&Path> = std::iter::once(scene_path)
        .chain(table.as_deref())
        .collect();
    check_outputs(&[("-o", out)], &inputs)?;
    let xml = to_xml(&scene, &scene_path.display().to_string())
        .with_context(|| format!("{}", scene_path.display()))?;
    let mut dirs = NewDirs::default();
    dirs.create_parent(out)
        .with_context(|| format!("-o {}", out.display()))?;
    atomic_write_bytes(out, xml.as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    dirs.keep();
    Ok(format!(
        "{}: {} as {} Mitsuba shapes",
        out.display(),
        crate::output::console::count(scene.cylinders.len(), "cylinder"),
        shapes(&scene).len()
    ))
}
