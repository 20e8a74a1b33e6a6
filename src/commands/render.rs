//! `cylaov render`: scene file → EXR (+ camera JSON, optional PNG previews).

use crate::output::aov::Compression;
use crate::output::io::{
    NewDirs, Staged, camera_json, camera_json_path, check_memory, check_output_dir, check_outputs,
    commit_all, stage,
};
use crate::output::preview;
use crate::render::{RenderOptions, render};
use crate::scene::camera::Camera;
use crate::scene::{self, Aov};
use anyhow::{Context, Result};
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
    let name = stem(&args.out);
    let previews: Vec<PathBuf> = match &args.preview {
        Some(dir) => {
            check_output_dir("--preview", dir)?;
            ["normal", "depth", "distance"]
                .iter()
                .map(|k| dir.join(format!("{name}.{k}.png")))
                .collect()
        }
        None => Vec::new(),
    };
    let mut outputs = vec![("-o", args.out.as_path()), ("-o", cam_path.as_path())];
    outputs.extend(previews.iter().map(|p| ("--preview", p.as_path())));
    check_outputs(&outputs, &[&args.scene])?;
    let mut scene =
        scene::load(&args.scene).with_context(|| format!("{}", args.scene.display()))?;
    scene
        .select_camera(args.camera)
        .with_context(|| format!("--camera {}: {}", args.camera, args.scene.display()))?;
    let aovs = args.aovs.clone().unwrap_or_else(|| scene.aovs.clone());
    let opts = RenderOptions {
        aovs: aovs.clone(),
        ..args.options.clone()
    };
    check_memory(
        &format!(
            "rendering {}x{} with {}",
            scene.camera.width,
            scene.camera.height,
            aovs.iter().map(|a| a.name()).collect::<Vec<_>>().join(",")
        ),
        memory_needed(
            scene.camera.width,
            scene.camera.height,
            &aovs,
            args.compression,
            args.preview.is_some(),
        ),
    )?;
    let t0 = Instant::now();
    let r = render(&scene, &opts);
    let trace_ms = t0.elapsed().as_secs_f64() * 1e3;
    // Every output is staged under a temporary name and renamed into place only when all
    // were written: a failure leaves none of them.
    let t1 = Instant::now();
    let mut dirs = NewDirs::default();
    dirs.create_parent(&args.out)
        .with_context(|| format!("-o {}", args.out.display()))?;
    if let Some(dir) = &args.preview {
        dirs.create(dir)
            .with_context(|| format!("--preview {}", dir.display()))?;
    }
    let mut staged = vec![r.image.stage_exr(&args.out, args.compression)?];
    let cam = Camera::new(scene.camera);
    let cam_text = camera_json(&cam, &aovs);
    staged.push(
        stage(&cam_path, |f| f.write_all(cam_text.as_bytes()))
            .with_context(|| format!("writing {}", cam_path.display()))?,
    );
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

/// `DIR/NAME.normal.png` and `DIR/NAME.depth.png` (or `.distance.png`) for whichever of
/// the AOVs exist, staged.
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
            &dir.join(format!("{name}.normal.png")),
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
            &dir.join(format!("{name}.{c}.png")),
        )?);
    }
    Ok(out)
}
