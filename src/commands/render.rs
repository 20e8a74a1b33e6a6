//! `cylaov render`: scene file → EXR (+ camera JSON, Open3D camera, optional 16-bit depth PNG
//! and PNG previews).
//!
//! Beside `OUT.exr` it writes `OUT.camera.json` and `OUT.open3d.json`; `--depth-png` adds
//! `OUT.depth.png` (the same 16-bit depth PNG as `batch`, see [`crate::output::depth_png`]);
//! `--preview DIR` writes `DIR/OUT.normal.preview.png` and `DIR/OUT.depth.preview.png`
//! (pictures for people: the names say so).

use crate::output::aov::{Compression, ExrLayout, exr_attributes, per_aov_image};
use crate::output::depth_png::{self, OutOfRange};
use crate::output::io::{
    NewDirs, Staged, camera_json, camera_json_path, check_memory, check_output_dir, check_outputs,
    commit_all, open3d_json, stage,
};
use crate::output::preview;
use crate::render::{RenderOptions, render};
use crate::scene::camera::Camera;
use crate::scene::{self, Aov};
use anyhow::{Context, Result, bail};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything `render` needs from the command line.
#[derive(Clone, Debug)]
pub struct RenderArgs {
    /// The scene file.
    pub scene: PathBuf,
    /// Output EXR (`-o`); the sidecar files are named after it.
    pub out: PathBuf,
    /// Overrides the scene's AOVs.
    pub aovs: Option<Vec<Aov>>,
    /// Kernel and acceleration choice; its `aovs` are replaced by the resolved AOV list.
    pub options: RenderOptions,
    /// `--preview DIR`: also write the PNG previews into this folder.
    pub preview: Option<PathBuf>,
    /// EXR compression.
    pub compression: Compression,
    /// `--camera K`: the camera of a several-camera scene (0 = the first).
    pub camera: usize,
    /// `--depth-png`: also write `OUT.depth.png` at this many values per world unit.
    pub depth_png: Option<f64>,
    /// With `depth_png`, what a hit whose depth × scale does not fit 16 bits does.
    pub depth_out_of_range: OutOfRange,
    /// One layered `OUT.exr`, or `OUT.<aov>.exr` per AOV.
    pub exr_layout: ExrLayout,
}

/// Where `render -o OUT.exr --exr-layout per-aov` puts AOV `aov`: `OUT.<aov>.exr`.
pub fn per_aov_path(exr: &Path, aov: Aov) -> PathBuf {
    exr.with_extension(format!("{}.exr", aov.name()))
}

/// Where `render -o OUT.exr` puts the 16-bit depth PNG: `OUT.depth.png`.
pub fn depth_png_path(exr: &Path) -> PathBuf {
    exr.with_extension("depth.png")
}

/// Where `render -o OUT.exr` puts the Open3D camera: `OUT.open3d.json`.
pub fn open3d_json_path(exr: &Path) -> PathBuf {
    exr.with_extension("open3d.json")
}

/// Bytes a render of `width × height` with `aovs` holds at its peak: one plane per channel
/// (4 bytes a sample), twice over when compressed (the `exr` crate encodes from its own
/// copy; the uncompressed writer streams from the planes), plus the RGB previews (3 bytes a
/// pixel each, one at a time) when asked. Measured peaks stay within this estimate plus
/// the process's fixed ~10 MiB.
pub fn memory_needed(
    width: u32,
    height: u32,
    aovs: &[Aov],
    compression: Compression,
    previews: bool,
) -> u64 {
    let pixels = width as u64 * height as u64;
    let channels: u64 = aovs
        .iter()
        .map(|&a| crate::output::aov::channel_names(a).len() as u64)
        .sum();
    let copies = if compression == Compression::None {
        1
    } else {
        2
    };
    let planes = pixels * 4 * channels * copies;
    planes + if previews { pixels * 3 } else { 0 }
}

/// Run a render and return the one-line summary.
pub fn run(args: &RenderArgs) -> Result<String> {
    let start = Instant::now();
    let cam_path = camera_json_path(&args.out);
    let o3d_path = open3d_json_path(&args.out);
    let name = stem(&args.out);
    let previews: Vec<PathBuf> = match &args.preview {
        Some(dir) => {
            check_output_dir("--preview", dir)?;
            ["normal", "depth", "distance"]
                .iter()
                .map(|k| dir.join(format!("{name}.{k}.preview.png")))
                .collect()
        }
        None => Vec::new(),
    };
    let mut scene =
        scene::load(&args.scene).with_context(|| format!("{}", args.scene.display()))?;
    scene
        .select_camera(args.camera)
        .with_context(|| format!("--camera {}: {}", args.camera, args.scene.display()))?;
    let aovs = args.aovs.clone().unwrap_or_else(|| scene.aovs.clone());
    // Every file this render can write, checked against the scene before any work.
    let exrs: Vec<PathBuf> = match args.exr_layout {
        ExrLayout::Layers => vec![args.out.clone()],
        ExrLayout::PerAov => aovs.iter().map(|&a| per_aov_path(&args.out, a)).collect(),
    };
    let depth_path = depth_png_path(&args.out);
    let mut outputs: Vec<(&str, &Path)> = exrs.iter().map(|p| ("-o", p.as_path())).collect();
    outputs.extend([("-o", cam_path.as_path()), ("-o", o3d_path.as_path())]);
    if args.depth_png.is_some() {
        outputs.push(("--depth-png", depth_path.as_path()));
    }
    outputs.extend(previews.iter().map(|p| ("--preview", p.as_path())));
    check_outputs(&outputs, &[&args.scene])?;
    if let Some(s) = args.depth_png
        && !(s.is_finite() && s > 0.0)
    {
        bail!("--depth-scale: must be finite and > 0, got {s}");
    }
    // The depth PNG needs planar depth even when the EXR does not store it.
    let mut traced = aovs.clone();
    if args.depth_png.is_some() && !traced.contains(&Aov::Depth) {
        traced.push(Aov::Depth);
    }
    let opts = RenderOptions {
        aovs: traced,
        ..args.options.clone()
    };
    check_memory(
        &format!(
            "rendering {}x{} with {}",
            scene.camera.width,
            scene.camera.height,
            opts.aovs
                .iter()
                .map(|a| a.name())
                .collect::<Vec<_>>()
                .join(",")
        ),
        memory_needed(
            scene.camera.width,
            scene.camera.height,
            &opts.aovs,
            args.compression,
            args.preview.is_some() || args.depth_png.is_some(),
        ),
    )?;
    let t0 = Instant::now();
    let mut r = render(&scene, &opts);
    let trace_ms = t0.elapsed().as_secs_f64() * 1e3;
    let depth = match args.depth_png {
        Some(scale) => {
            let d = depth_png::encode(&r.image, scale, args.depth_out_of_range)
                .context("no depth AOV")?
                .map_err(anyhow::Error::msg)
                .with_context(|| format!("{}", args.scene.display()))?;
            if d.zeroed > 0 {
                eprintln!(
                    "{}: depth PNG: {} hit pixels beyond 16 bits at --depth-scale {scale} stored as 0",
                    args.out.display(),
                    d.zeroed
                );
            }
            Some(d.png)
        }
        None => None,
    };
    if !aovs.contains(&Aov::Depth) {
        r.image.channels.retain(|c| c.name != "depth");
    }
    // Every output is staged under a temporary name and renamed into place only when all
    // were written: a failure leaves none of them (nor the folders it made for them).
    let t1 = Instant::now();
    let mut dirs = NewDirs::default();
    dirs.create_parent(&args.out)
        .with_context(|| format!("-o {}", args.out.display()))?;
    if let Some(dir) = &args.preview {
        dirs.create(dir)
            .with_context(|| format!("--preview {}", dir.display()))?;
    }
    let cam = Camera::new(scene.camera);
    let attrs = exr_attributes(&cam, &aovs);
    let mut staged = Vec::new();
    match args.exr_layout {
        ExrLayout::Layers => {
            staged.push(
                r.image
                    .stage_exr_with(&args.out, args.compression, &attrs)?,
            );
        }
        ExrLayout::PerAov => {
            for (&a, path) in aovs.iter().zip(&exrs) {
                let one = per_aov_image(&r.image, a)?;
                let attrs = exr_attributes(&cam, &[a]);
                staged.push(one.stage_exr_with(path, args.compression, &attrs)?);
            }
        }
    }
    let cam_text = camera_json(&cam, &aovs);
    staged.push(
        stage(&cam_path, |f| f.write_all(cam_text.as_bytes()))
            .with_context(|| format!("writing {}", cam_path.display()))?,
    );
    let o3d_text = open3d_json(&cam);
    staged.push(
        stage(&o3d_path, |f| f.write_all(o3d_text.as_bytes()))
            .with_context(|| format!("writing {}", o3d_path.display()))?,
    );
    if let Some(png) = &depth {
        staged.push(preview::stage_png(png, &depth_path)?);
    }
    let write_ms = t1.elapsed().as_secs_f64() * 1e3;
    if let Some(dir) = &args.preview {
        staged.extend(stage_previews(&r.image, dir, &name)?);
    }
    commit_all(staged).context("putting the outputs in place")?;
    dirs.keep();
    let (w, h) = (r.image.width, r.image.height);
    let peak =
        crate::output::io::peak_rss_mib().map_or(String::new(), |m| format!(", peak {m:.0} MiB"));
    Ok(format!(
        "{}: {w}x{h}, {} cylinders, {} hits ({:.1}%), {}, trace {trace_ms:.1} ms, write {write_ms:.1} ms, total {:.1} ms{peak}",
        args.out.display(),
        scene.cylinders.len(),
        r.hits,
        100.0 * r.hits as f64 / (w * h) as f64,
        crate::geometry::Kernel::new(opts.formula, opts.precision),
        start.elapsed().as_secs_f64() * 1e3
    ))
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "render".into())
}

/// `DIR/NAME.normal.preview.png` and `DIR/NAME.depth.preview.png` (or
/// `.distance.preview.png`) for whichever of the AOVs exist, staged.
pub fn stage_previews(
    img: &crate::output::aov::AovImage,
    dir: &Path,
    name: &str,
) -> Result<Vec<Staged>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut out = Vec::new();
    if let Some(p) = preview::normal_preview(img) {
        out.push(preview::stage_png(
            &p,
            &dir.join(format!("{name}.normal.preview.png")),
        )?);
    }
    let depthlike = ["depth", "distance"]
        .into_iter()
        .find(|c| img.f32_channel(c).is_some());
    if let Some(c) = depthlike
        && let Some(p) = preview::depth_colormap(img, c)
    {
        out.push(preview::stage_png(
            &p,
            &dir.join(format!("{name}.{c}.preview.png")),
        )?);
    }
    Ok(out)
}
