//! `cylaov export-mitsuba`: scene file → Mitsuba 3 XML (see [`crate::output::mitsuba`]).

use crate::output::io::atomic_write_bytes;
use crate::output::mitsuba::{shapes, to_xml};
use crate::scene;
use anyhow::{Context, Result, bail};
use std::path::Path;

/// Export `scene_path` to `out` and return a one-line summary.
pub fn run(scene_path: &Path, out: &Path) -> Result<String> {
    if let (Ok(a), Ok(b)) = (scene_path.canonicalize(), out.canonicalize())
        && a == b
    {
        bail!(
            "-o {}: would overwrite the input scene {}",
            out.display(),
            scene_path.display()
        );
    }
    let scene = scene::load(scene_path).with_context(|| format!("{}", scene_path.display()))?;
    let xml = to_xml(&scene, &scene_path.display().to_string());
    atomic_write_bytes(out, xml.as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(format!(
        "{}: {} cylinders as {} Mitsuba shapes",
        out.display(),
        scene.cylinders.len(),
        shapes(&scene).len()
    ))
}
