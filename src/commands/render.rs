//! `cylaov render`: scene file → EXR (+ camera JSON, Open3D camera, optional 16-bit depth PNG
//! and PNG previews).
//!
//! Beside `OUT.exr` it writes `OUT.camera.json` and `OUT.open3d.json`; `--depth-png` adds
//! `OUT.depth.png` (the same 16-bit depth PNG as `batch`, see [`crate::output::depth_png`]);
//! `--preview DIR` writes `DIR/OUT.normal.preview.png` and `DIR/OUT.depth.preview.png`
//! (pictures for people: the names say so).

use crate::output::aov::{Compression, ExrLayout, exr_attributes, per_aov_image};
use crate::output::depth_png::{self, OutOfRange};
use crate::output::io::{Staged, camera_json, camera_json_path, commit_all, open3d_json, stage};
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
    pub scene: PathBuf,
    pub out: PathBuf,
    /// Overrides the scene's AOVs.
    pub aovs: Option<Vec<Aov>>,
    pub options: RenderOptions,
    pub preview: Option<PathBuf>,
    pub compression: Compression,
    /// `--camera K`: the camera of a several-camera scene (0 = the first).
    pub camera: usize,
    /// `--depth-png`: also write `OUT.depth.png` at this many values per world unit.
    pub depth_png: Option<f64>,
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

/// Same file, however it is spelled (the output may not exist yet).
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Run a render and return the one-line summary.
pub fn run(args: &RenderArgs) -> Result<String> {
    let start = Instant::now();
    let cam_path = camera_json_path(&args.out);
    if same_file(&args.scene, &args.out) || same_file(&args.scene, &cam_path) {
        bail!(
            "-o {}: would overwrite the input scene {}",
            args.out.display(),
            args.scene.display()
        );
    }
    let mut scene =
        scene::load(&args.scene).with_context(|| format!("{}", args.scene.display()))?;
    scene
        .select_camera(args.camera)
        .with_context(|| format!("--camera {}: {}", args.camera, args.scene.display()))?;
    let aovs = args.aovs.clone().unwrap_or_else(|| scene.aovs.clone());
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
    // were written: a failure leaves none of them.
    let t1 = Instant::now();
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
            for &a in &aovs {
                let one = per_aov_image(&r.image, a)?;
                let attrs = exr_attributes(&cam, &[a]);
                staged.push(one.stage_exr_with(
                    &per_aov_path(&args.out, a),
                    args.compression,
                    &attrs,
                )?);
            }
        }
    }
    let cam_text = camera_json(&cam, &aovs);
    staged.push(
        stage(&cam_path, |f| f.write_all(cam_text.as_bytes()))
            .with_context(|| format!("writing {}", cam_path.display()))?,
    );
    let o3d_path = open3d_json_path(&args.out);
    let o3d_text = open3d_json(&cam);
    staged.push(
        stage(&o3d_path, |f| f.write_all(o3d_text.as_bytes()))
            .with_context(|| format!("writing {}", o3d_path.display()))?,
    );
    if let Some(png) = &depth {
        staged.push(preview::stage_png(png, &depth_png_path(&args.out))?);
    }
    let write_ms = t1.elapsed().as_secs_f64() * 1e3;
    if let Some(dir) = &args.preview {
        staged.extend(stage_previews(&r.image, dir, &stem(&args.out))?);
    }
    commit_all(staged).context("putting the outputs in place")?;
    let (w, h) = (r.image.width, r.image.height);
    let peak =
        crate::output::io::peak_rss_mib().map_or(String::new(), |m| format!(", peak {m:.0} MiB"));
    Ok(format!(
        "{}: {w}x{h}, {} cylinders, {} hits ({:.1}%), {:?}/{:?}, trace {trace_ms:.1} ms, write {write_ms:.1} ms, total {:.1} ms{peak}",
        args.out.display(),
        scene.cylinders.len(),
        r.hits,
        100.0 * r.hits as f64 / (w * h) as f64,
        opts.formula,
        opts.precision,
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
    if let Some(p) = preview::normal_rgb(img) {
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
