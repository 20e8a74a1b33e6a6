//! Rendering one view: trace, write every file under the shard's partial folder, then
//! rename into place with the EXR last.

use super::options::BatchOptions;
use super::resume::{ViewFiles, render_stamp};
use crate::output::aov::{
    AovImage, ExrBands, ExrLayout, channel_names, exr_attributes, per_aov_image, render_memory,
    streams,
};
use crate::output::depth_png;
use crate::output::files::create_new;
use crate::output::io::{camera_json, explain, open3d_json};
use crate::output::preview;
use crate::render::{RenderOptions, render, render_bands};
use crate::scene::camera::Camera;
use crate::scene::{Aov, Scene};
use anyhow::{Context, Result, anyhow};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Time spent on one rendered view, and what its depth PNG could not hold.
#[derive(Clone, Copy, Debug, Default)]
pub struct ViewCost {
    /// BVH build + tracing into the in-memory AOV image; with one uncompressed EXR and
    /// no PNGs, the EXR too (written band by band during the trace).
    pub trace: Duration,
    /// PNG encoding, EXR encoding (unless streamed), camera JSON, all writes and renames.
    pub write: Duration,
    /// Hit pixels stored as 0 in the depth PNG (`--depth-out-of-range zero`).
    pub depth_zeroed: usize,
}

/// Write a file under `.partial/` through a buffer. No fsync: a rename after a complete
/// write is what makes a kill at any moment safe; fsync would only add power-loss
/// durability, at ~3 ms per file here (several files per view), and the resume check reads
/// every output back (a file emptied by a power cut fails it and is rendered again).
fn write_unsynced(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    let mut w = BufWriter::new(
        create_new(path)
            .map_err(explain)
            .with_context(|| format!("creating {}", path.display()))?,
    );
    fill(&mut w)
        .and_then(|()| Ok(w.flush()?))
        .with_context(|| format!("writing {}", path.display()))
}

/// The AOVs a view is traced with: the EXR's, plus depth and normal for the PNGs.
pub fn traced_aovs(scene: &Scene, opts: &BatchOptions) -> Vec<Aov> {
    let mut aovs = opts.exr_aovs(scene);
    if opts.png {
        for a in [Aov::Depth, Aov::Normal] {
            if !aovs.contains(&a) {
                aovs.push(a);
            }
        }
    }
    aovs
}

/// Bytes rendering and writing a view holds at its peak (see [`render_memory`]).
pub fn view_memory(scene: &Scene, opts: &BatchOptions) -> u64 {
    let c = &scene.camera;
    render_memory(
        (c.width, c.height),
        &traced_aovs(scene, opts),
        opts.exr_layout,
        opts.compression,
        opts.png,
    )
}

/// Render one view into `partial` (temporary names `TMP_STEM.*.tmp`) and move its files
/// into `dir` as `NAME.*`, the EXR last. A depth PNG that cannot hold the view's depths
/// (under [`OutOfRange::Fail`](depth_png::OutOfRange::Fail)) fails the view before
/// anything is moved.
pub fn render_view(
    dir: &Path,
    partial: &Path,
    name: &str,
    tmp_stem: &str,
    scene: &Scene,
    opts: &BatchOptions,
) -> Result<ViewCost> {
    let exr_aovs = opts.exr_aovs(scene);
    let tmp = |suffix: &str| partial.join(format!("{tmp_stem}.{suffix}.tmp"));
    let done = ViewFiles::new(dir, name);
    let cam = Camera::new(scene.camera);
    let render_opts = RenderOptions {
        precision: opts.precision,
        formula: opts.formula,
        ..RenderOptions::new(traced_aovs(scene, opts))
    };
    let t0 = Instant::now();
    // One uncompressed EXR and no pictures: written band by band while the view is
    // traced (see `render::render_bands`); `trace` then includes the EXR.
    if streams(opts.exr_layout, opts.compression, opts.png) {
        let exr_tmp = tmp("exr");
        let file = create_new(&exr_tmp)
            .map_err(explain)
            .with_context(|| format!("creating {}", exr_tmp.display()))?;
        let attrs = exr_attributes(&cam, &exr_aovs);
        let exr = ExrBands::new(&file, scene.camera.height as usize, &attrs);
        render_bands(scene, &render_opts, &|y0, band| exr.write_band(y0, band))
            .and_then(|_| exr.finish())
            .with_context(|| format!("writing {}", exr_tmp.display()))?;
        let trace = t0.elapsed();
        let t1 = Instant::now();
        let mut moves = write_texts(scene, opts, &cam, &exr_aovs, &tmp, &done)?;
        moves.push((exr_tmp, done.exr.clone()));
        put_in_place(&done, moves, opts.png)?;
        return Ok(ViewCost {
            trace,
            write: t1.elapsed(),
            depth_zeroed: 0,
        });
    }
    let mut image = render(scene, &render_opts).image;
    let trace = t0.elapsed();

    let t1 = Instant::now();
    // The depth PNG first: a view whose depths do not fit fails before any write.
    let depth = if opts.png {
        let d = depth_png::encode(&image, opts.depth_scale, opts.depth_out_of_range)
            .context("no depth AOV")?
            .map_err(|e| anyhow!(e))?;
        Some(d)
    } else {
        None
    };
    let mut moves = write_texts(scene, opts, &cam, &exr_aovs, &tmp, &done)?;
    let depth_zeroed = depth.as_ref().map_or(0, |d| d.zeroed);
    if let Some(depth) = depth {
        moves.extend(write_pictures(&image, depth.png, &tmp, &done)?);
    }
    let keep: Vec<&str> = exr_aovs
        .iter()
        .flat_map(|&a| channel_names(a).iter().copied())
        .collect();
    image.channels.retain(|c| keep.contains(&c.name.as_str()));
    moves.extend(write_exrs(&image, &cam, &exr_aovs, opts, &tmp, &done)?);
    put_in_place(&done, moves, opts.png)?;
    Ok(ViewCost {
        trace,
        write: t1.elapsed(),
        depth_zeroed,
    })
}

/// A file written under `.partial/` and where it goes.
type Move = (PathBuf, PathBuf);

/// The normal picture, the depth PNG and the mask, under their temporary names.
fn write_pictures(
    image: &AovImage,
    depth: depth_png::DepthPng,
    tmp: &dyn Fn(&str) -> PathBuf,
    done: &ViewFiles,
) -> Result<Vec<Move>> {
    let normal = preview::normal_rgb(image).context("no normal AOV")?;
    let mask = depth_png::mask(image).context("no depth AOV")?;
    let (normal_tmp, depth_tmp, mask_tmp) = (tmp("normal.png"), tmp("depth.png"), tmp("mask.png"));
    write_unsynced(&normal_tmp, |w| {
        Ok(normal.write_to(w, image::ImageFormat::Png)?)
    })?;
    write_unsynced(&depth_tmp, |w| {
        Ok(depth.write_to(w, image::ImageFormat::Png)?)
    })?;
    write_unsynced(
        &mask_tmp,
        |w| Ok(mask.write_to(w, image::ImageFormat::Png)?),
    )?;
    Ok(vec![
        (normal_tmp, done.normal_png.clone()),
        (depth_tmp, done.depth_png.clone()),
        (mask_tmp, done.mask_png.clone()),
    ])
}

/// The EXR (layered) or one EXR per AOV, under their temporary names.
/// The view's camera JSON, Open3D camera and render stamp, under their temporary names.
fn write_texts(
    scene: &Scene,
    opts: &BatchOptions,
    cam: &Camera,
    exr_aovs: &[Aov],
    tmp: &dyn Fn(&str) -> PathBuf,
    done: &ViewFiles,
) -> Result<Vec<Move>> {
    let mut moves = Vec::new();
    for (suffix, text, to) in [
        (
            "camera.json",
            camera_json(cam, exr_aovs),
            done.camera.clone(),
        ),
        ("open3d.json", open3d_json(cam), done.open3d.clone()),
        ("render.json", render_stamp(scene, opts), done.stamp.clone()),
    ] {
        let path = tmp(suffix);
        write_unsynced(&path, |w| Ok(w.write_all(text.as_bytes())?))?;
        moves.push((path, to));
    }
    Ok(moves)
}

fn write_exrs(
    image: &AovImage,
    cam: &Camera,
    exr_aovs: &[Aov],
    opts: &BatchOptions,
    tmp: &dyn Fn(&str) -> PathBuf,
    done: &ViewFiles,
) -> Result<Vec<Move>> {
    match opts.exr_layout {
        ExrLayout::Layers => {
            let attrs = exr_attributes(cam, exr_aovs);
            let exr_tmp = tmp("exr");
            write_unsynced(&exr_tmp, |w| {
                image.write_exr_with(w, opts.compression, &attrs)
            })?;
            Ok(vec![(exr_tmp, done.exr.clone())])
        }
        ExrLayout::PerAov => exr_aovs
            .iter()
            .map(|&a| {
                let one = per_aov_image(image, a)?;
                let attrs = exr_attributes(cam, &[a]);
                let path = tmp(&format!("{}.exr", a.name()));
                write_unsynced(&path, |w| one.write_exr_with(w, opts.compression, &attrs))?;
                Ok((path, done.per_aov(a)))
            })
            .collect(),
    }
}

/// Remove what the new files would contradict, then rename them into place, the EXR last.
///
/// An EXR in place is the view's "done" marker, so an older one goes before any new file
/// of the view replaces its sibling: a re-render killed between the renames leaves no
/// EXR (the view is rendered again), never a new camera beside old PNGs and an old EXR.
/// Every EXR of either layout is a "done" marker: all go first. Without PNGs, those of an
/// earlier run go too (they would not match the stamp), and the normal picture under its
/// pre-0.2 name always goes.
fn put_in_place(done: &ViewFiles, moves: Vec<Move>, png: bool) -> Result<()> {
    let mut stale: Vec<PathBuf> = vec![done.exr.clone()];
    stale.extend(Aov::ALL.iter().map(|&a| done.per_aov(a)));
    stale.push(done.legacy_normal_png.clone());
    if !png {
        stale.extend([
            done.normal_png.clone(),
            done.depth_png.clone(),
            done.mask_png.clone(),
        ]);
    }
    for path in stale {
        match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("removing the old {}", path.display()));
            }
            _ => {}
        }
    }
    // The EXRs were written last, so they are moved last.
    for (from, to) in moves {
        std::fs::rename(&from, &to)
            .with_context(|| format!("moving {} to {}", from.display(), to.display()))?;
    }
    Ok(())
}
