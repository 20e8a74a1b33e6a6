//! `cylaov render`: scene file → EXR (+ camera JSON, Open3D camera, optional 16-bit depth PNG
//! and PNG previews).
//!
//! Beside `OUT.exr` it writes `OUT.camera.json` and `OUT.open3d.json`; `--depth-png` adds
//! `OUT.depth.png` (the same 16-bit depth PNG as `batch`, see [`crate::output::depth_png`]);
//! `--preview DIR` writes `DIR/OUT.normal.preview.png` and `DIR/OUT.depth.preview.png`
//! (pictures for people: the names say so).

use crate::mem::check_memory;
use crate::output::aov::AovImage;
use crate::output::aov::{
    Compression, ExrBands, ExrLayout, exr_attributes, per_aov_image, render_memory, streams,
};
use crate::output::depth_png::{self, DepthPng, OutOfRange};
use crate::output::io::{
    NewDirs, Staged, camera_json, camera_json_path, check_output_dir, check_outputs, commit_all,
    open3d_json, stage,
};
use crate::output::preview;
use crate::render::{RenderOptions, render, render_bands};
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

/// Every file a render writes, named before any work so that each can be checked.
struct Outputs {
    /// The layered EXR, or one EXR per AOV (in `aovs` order).
    exrs: Vec<PathBuf>,
    camera: PathBuf,
    open3d: PathBuf,
    depth_png: Option<PathBuf>,
    previews: Vec<PathBuf>,
}

impl Outputs {
    fn new(args: &RenderArgs, aovs: &[Aov]) -> Result<Outputs> {
        let name = stem(&args.out);
        let previews = match &args.preview {
            Some(dir) => {
                check_output_dir("--preview", dir)?;
                ["normal", "depth", "distance"]
                    .iter()
                    .map(|k| dir.join(format!("{name}.{k}.preview.png")))
                    .collect()
            }
            None => Vec::new(),
        };
        Ok(Outputs {
            exrs: match args.exr_layout {
                ExrLayout::Layers => vec![args.out.clone()],
                ExrLayout::PerAov => aovs.iter().map(|&a| per_aov_path(&args.out, a)).collect(),
            },
            camera: camera_json_path(&args.out),
            open3d: open3d_json_path(&args.out),
            depth_png: args.depth_png.map(|_| depth_png_path(&args.out)),
            previews,
        })
    }

    /// None may be the scene or a file that is not a regular file (see `io::check_outputs`).
    fn check(&self, scene: &Path) -> Result<()> {
        let mut list: Vec<(&str, &Path)> = self.exrs.iter().map(|p| ("-o", p.as_path())).collect();
        list.extend([("-o", self.camera.as_path()), ("-o", self.open3d.as_path())]);
        list.extend(self.depth_png.iter().map(|p| ("--depth-png", p.as_path())));
        list.extend(self.previews.iter().map(|p| ("--preview", p.as_path())));
        check_outputs(&list, &[scene])?;
        Ok(())
    }
}

/// Run a render and return the one-line summary.
pub fn run(args: &RenderArgs) -> Result<String> {
    let start = Instant::now();
    let mut scene =
        scene::load(&args.scene).with_context(|| format!("{}", args.scene.display()))?;
    scene
        .select_camera(args.camera)
        .with_context(|| format!("--camera {}: {}", args.camera, args.scene.display()))?;
    let aovs = args.aovs.clone().unwrap_or_else(|| scene.aovs.clone());
    let outputs = Outputs::new(args, &aovs)?;
    outputs.check(&args.scene)?;
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
    let pictures = args.preview.is_some() || args.depth_png.is_some();
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
        render_memory(
            (scene.camera.width, scene.camera.height),
            &opts.aovs,
            args.exr_layout,
            args.compression,
            pictures,
        ),
    )?;
    let dirs = make_dirs(args)?;
    let cam = Camera::new(scene.camera);
    let t0 = Instant::now();
    // The common case (one uncompressed EXR, no pictures) is written band by band while
    // the render runs, since nothing needs the whole image (see `render::render_bands`).
    let streamed = streams(args.exr_layout, args.compression, pictures);
    let (hits, mut traced) = if streamed {
        let staged = stage(&args.out, |_| Ok(()))
            .with_context(|| format!("writing {}", args.out.display()))?;
        let attrs = exr_attributes(&cam, &aovs);
        let exr = ExrBands::new(staged.file(), scene.camera.height as usize, &attrs);
        let (hits, _) = render_bands(&scene, &opts, &|y0, band| exr.write_band(y0, band))
            .and_then(|r| exr.finish().map(|()| r))
            .map_err(crate::output::io::explain)
            .with_context(|| format!("writing {}", args.out.display()))?;
        (hits, Traced::Streamed(staged))
    } else {
        let r = render(&scene, &opts);
        (r.hits, Traced::Image(r.image))
    };
    let trace_ms = t0.elapsed().as_secs_f64() * 1e3;
    let depth = match &traced {
        Traced::Image(image) => depth_png(args, image)?,
        Traced::Streamed(_) => None,
    };
    if let Traced::Image(image) = &mut traced
        && !aovs.contains(&Aov::Depth)
    {
        image.channels.retain(|c| c.name != "depth");
    }
    let t1 = Instant::now();
    let (exrs, image) = match traced {
        Traced::Streamed(staged) => (vec![staged], None),
        Traced::Image(image) => (
            stage_exrs(args, &outputs, &cam, &aovs, &image)?,
            Some(image),
        ),
    };
    write(
        args,
        &outputs,
        &cam,
        &aovs,
        exrs,
        image.as_ref(),
        depth.as_ref(),
    )?;
    dirs.keep();
    let write_ms = t1.elapsed().as_secs_f64() * 1e3;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let peak = crate::mem::peak_rss_mib().map_or(String::new(), |m| format!(", peak {m:.0} MiB"));
    // Streamed, the EXR was written during the trace: say so rather than time it twice.
    let trace = if streamed {
        format!("trace and EXR {trace_ms:.1} ms, other files {write_ms:.1} ms")
    } else {
        format!("trace {trace_ms:.1} ms, write {write_ms:.1} ms")
    };
    Ok(format!(
        "{}: {w}x{h}, {} cylinders, {hits} hits ({:.1}%), {}, {trace}, total {:.1} ms{peak}",
        args.out.display(),
        scene.cylinders.len(),
        100.0 * hits as f64 / (w * h) as f64,
        crate::geometry::Kernel::new(opts.formula, opts.precision),
        start.elapsed().as_secs_f64() * 1e3
    ))
}

/// What the trace left: the whole image, or (streamed) the EXR already staged.
enum Traced {
    Image(AovImage),
    Streamed(Staged),
}

/// The output's parent folder and the preview folder, made now and removed again unless
/// the render succeeds.
fn make_dirs(args: &RenderArgs) -> Result<NewDirs> {
    let mut dirs = NewDirs::default();
    dirs.create_parent(&args.out)
        .with_context(|| format!("-o {}", args.out.display()))?;
    if let Some(dir) = &args.preview {
        dirs.create(dir)
            .with_context(|| format!("--preview {}", dir.display()))?;
    }
    Ok(dirs)
}

/// The EXR (layered) or EXRs (one per AOV) of a whole image, staged.
fn stage_exrs(
    args: &RenderArgs,
    outputs: &Outputs,
    cam: &Camera,
    aovs: &[Aov],
    image: &AovImage,
) -> Result<Vec<Staged>> {
    let mut staged = Vec::new();
    match args.exr_layout {
        ExrLayout::Layers => {
            let attrs = exr_attributes(cam, aovs);
            staged.push(image.stage_exr_with(&args.out, args.compression, &attrs)?);
        }
        ExrLayout::PerAov => {
            for (&a, path) in aovs.iter().zip(&outputs.exrs) {
                let one = per_aov_image(image, a)?;
                let attrs = exr_attributes(cam, &[a]);
                staged.push(one.stage_exr_with(path, args.compression, &attrs)?);
            }
        }
    }
    Ok(staged)
}

/// The 16-bit depth PNG, when asked for: a depth beyond 16 bits fails the render, or is
/// stored as 0 and counted (`--depth-out-of-range`).
fn depth_png(args: &RenderArgs, image: &AovImage) -> Result<Option<DepthPng>> {
    let Some(scale) = args.depth_png else {
        return Ok(None);
    };
    let d = depth_png::encode(image, scale, args.depth_out_of_range)
        .context("no depth AOV")?
        .map_err(anyhow::Error::msg)
        .with_context(|| format!("{}", args.scene.display()))?;
    if d.zeroed > 0 {
        crate::output::io::warn(&format!(
            "{}: depth PNG: {} hit pixels beyond 16 bits at --depth-scale {scale} stored as 0",
            args.out.display(),
            d.zeroed
        ));
    }
    Ok(Some(d.png))
}

/// Stage the other outputs beside the staged EXRs, then rename them all into place only
/// when every one was written: a failure leaves none of them.
fn write(
    args: &RenderArgs,
    outputs: &Outputs,
    cam: &Camera,
    aovs: &[Aov],
    mut staged: Vec<Staged>,
    image: Option<&AovImage>,
    depth: Option<&DepthPng>,
) -> Result<()> {
    for (path, text) in [
        (&outputs.camera, camera_json(cam, aovs)),
        (&outputs.open3d, open3d_json(cam)),
    ] {
        staged.push(
            stage(path, |f| f.write_all(text.as_bytes()))
                .with_context(|| format!("writing {}", path.display()))?,
        );
    }
    if let (Some(png), Some(path)) = (depth, &outputs.depth_png) {
        staged.push(preview::stage_png(png, path)?);
    }
    if let (Some(dir), Some(image)) = (&args.preview, image) {
        staged.extend(stage_previews(image, dir, &stem(&args.out))?);
    }
    commit_all(staged).context("putting the outputs in place")?;
    Ok(())
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
