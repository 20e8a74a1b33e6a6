//! Rendering one view: trace, write every file under the shard's partial folder, then
//! rename into place with the EXR last.

use super::options::BatchOptions;
use super::resume::{ViewFiles, render_stamp};
use crate::output::aov::channel_names;
use crate::output::io::camera_json;
use crate::output::preview;
use crate::render::{RenderOptions, render};
use crate::scene::camera::Camera;
use crate::scene::{Aov, Scene};
use anyhow::{Context, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[derive(Clone, Copy, Debug, Default)]
pub struct ViewCost {
    /// BVH build + tracing into the in-memory AOV image.
    pub trace: Duration,
    /// PNG encoding, EXR encoding, camera JSON, all writes and renames.
    pub write: Duration,
}

/// Write a file under `.partial/` through a buffer. No fsync: a rename after a complete
/// write is what makes a kill at any moment safe; fsync would only add power-loss
/// durability, at ~3 ms per file here (four files per view), and the resume check reads
/// every output back (a file emptied by a power cut fails it and is rendered again).
fn write_unsynced(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    let mut w =
        BufWriter::new(File::create(path).with_context(|| format!("creating {}", path.display()))?);
    fill(&mut w)
        .and_then(|()| Ok(w.flush()?))
        .with_context(|| format!("writing {}", path.display()))
}

/// Render one view into `partial` and move its files into `dir`, the EXR last.
pub fn render_view(
    dir: &Path,
    partial: &Path,
    name: &str,
    scene: &Scene,
    opts: &BatchOptions,
) -> Result<ViewCost> {
    let exr_aovs = opts.exr_aovs(scene);
    let mut aovs = exr_aovs.clone();
    if opts.png {
        for a in [Aov::Depth, Aov::Normal] {
            if !aovs.contains(&a) {
                aovs.push(a);
            }
        }
    }
    let t0 = Instant::now();
    let mut image = render(
        scene,
        &RenderOptions {
            precision: opts.precision,
            formula: opts.formula,
            ..RenderOptions::new(aovs.clone())
        },
    )
    .image;
    let trace = t0.elapsed();

    let t1 = Instant::now();
    let tmp = |suffix: &str| partial.join(format!("{name}.{suffix}.tmp"));
    let done = ViewFiles::new(dir, name);
    let mut moves = Vec::new();
    let cam = Camera::new(scene.camera);
    let camera = tmp("camera.json");
    write_unsynced(&camera, |w| {
        Ok(w.write_all(camera_json(&cam, &exr_aovs).as_bytes())?)
    })?;
    moves.push((camera, &done.camera));
    let stamp = tmp("render.json");
    write_unsynced(&stamp, |w| {
        Ok(w.write_all(render_stamp(scene, opts).as_bytes())?)
    })?;
    moves.push((stamp, &done.stamp));
    if opts.png {
        let normal = preview::normal_rgb(&image).context("no normal AOV")?;
        let depth = preview::depth_u16(&image, opts.depth_scale).context("no depth AOV")?;
        let (normal_tmp, depth_tmp) = (tmp("normal.png"), tmp("depth.png"));
        write_unsynced(&normal_tmp, |w| {
            Ok(normal.write_to(w, image::ImageFormat::Png)?)
        })?;
        write_unsynced(&depth_tmp, |w| {
            Ok(depth.write_to(w, image::ImageFormat::Png)?)
        })?;
        moves.push((normal_tmp, &done.normal_png));
        moves.push((depth_tmp, &done.depth_png));
    }
    let keep: Vec<&str> = exr_aovs
        .iter()
        .flat_map(|&a| channel_names(a).iter().copied())
        .collect();
    image.channels.retain(|c| keep.contains(&c.name.as_str()));
    let exr_tmp = tmp("exr");
    write_unsynced(&exr_tmp, |w| image.write_exr_to(w, opts.compression))?;
    moves.push((exr_tmp, &done.exr));
    // An EXR in place is the view's "done" marker, so an older one goes before any new file
    // of the view replaces its sibling: a re-render killed between the renames leaves no
    // EXR (the view is rendered again), never a new camera beside old PNGs and an old EXR.
    // The EXR goes last: once it is in place, so is everything else of the view.
    // Without PNGs, those of an earlier run go too (they would not match the stamp).
    let stale: &[&PathBuf] = if opts.png {
        &[&done.exr]
    } else {
        &[&done.exr, &done.normal_png, &done.depth_png]
    };
    for path in stale {
        match std::fs::remove_file(path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("removing the old {}", path.display()));
            }
            _ => {}
        }
    }
    for (from, to) in moves {
        std::fs::rename(&from, to)
            .with_context(|| format!("moving {} to {}", from.display(), to.display()))?;
    }
    Ok(ViewCost {
        trace,
        write: t1.elapsed(),
    })
}
