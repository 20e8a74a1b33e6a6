//! `cylaov compare`: two AOV EXRs → report (table or JSON), optional heatmap, pass/fail.
//! With `--scene`, A must be a render of that scene (cylaov's or Mitsuba's, with `shape_id`,
//! `distance` and `normal`), and grazing pixels get their float32 conditioning bound.

use crate::image::AovImage;
use crate::mem::check_memory;
use crate::output::pipeline::files::write_png;
use crate::output::store::targets::check_outputs;
use crate::verify::compare::{
    Conditioning, Report, Tolerances, compare_with, heatmap_figure, tolerance_line, verdict_lines,
};
use anyhow::{Context, Result, bail};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Everything `compare` needs from the command line.
#[derive(Clone, Debug)]
pub struct CompareArgs {
    /// Image A (usually cylaov's render).
    pub a: PathBuf,
    /// Image B (usually the Mitsuba reference).
    pub b: PathBuf,
    /// The scene A was rendered from: enables the per-pixel float32 conditioning bounds.
    pub scene: Option<PathBuf>,
    /// The float32 ulps of ray error the conditioning bound allows (with `scene`).
    pub conditioning_ulps: f64,
    /// `--heatmap`: where to write a PNG showing where the images differ.
    pub heatmap: Option<PathBuf>,
    /// Print the report as JSON instead of text.
    pub json: bool,
    /// The pass/fail bounds.
    pub tolerances: Tolerances,
}

/// What `--json` prints.
#[derive(Serialize)]
struct JsonOut<'a> {
    a: String,
    b: String,
    passed: bool,
    failures: Vec<String>,
    tolerances: Tolerances,
    report: &'a Report,
}

/// The outcome: the text to print and whether every tolerance held.
pub struct CompareOutcome {
    /// The report as text or JSON (`--json`).
    pub text: String,
    /// Whether every tolerance held.
    pub passed: bool,
    /// The comparison itself.
    pub report: Report,
}

/// Pixels and channels of an EXR's first layer, from its header alone (nothing is
/// allocated for the pixels).
fn header_size(path: &Path) -> Result<(u64, u64)> {
    // Opened as an input (a FIFO is refused, not waited on) and read once for the header.
    let file = crate::output::store::files::open_input(path)
        .with_context(|| format!("reading {}", path.display()))?;
    let meta = exr::meta::MetaData::read_from_buffered(std::io::BufReader::new(file), false)
        .with_context(|| format!("reading {}", path.display()))?;
    let h = meta
        .headers
        .first()
        .with_context(|| format!("{}: no image in the file", path.display()))?;
    let size = h.layer_size;
    Ok((size.0 as u64 * size.1 as u64, h.channels.list.len() as u64))
}

/// Refuse a `--scene` whose camera is not the one `a`'s header records: the camera model
/// (`cylaov:camera_model`, a perspective camera where a file with `worldToCamera` has
/// none) and `worldToCamera` (each entry within 1e-6 of the matrix's largest). The bounds
/// would otherwise be another view's. A file without `worldToCamera` (a Mitsuba reference)
/// records no camera and is taken at its word.
fn same_camera(a: &Path, scene_path: &Path, scene: &crate::scene::Scene) -> Result<()> {
    use exr::meta::attribute::AttributeValue;
    let file = crate::output::store::files::open_input(a)
        .with_context(|| format!("reading {}", a.display()))?;
    let meta = exr::meta::MetaData::read_from_buffered(std::io::BufReader::new(file), false)
        .with_context(|| format!("reading {}", a.display()))?;
    let Some(h) = meta.headers.first() else {
        bail!("{}: no image in the file", a.display());
    };
    let attrs = &h.own_attributes;
    let Some(recorded) = attrs.world_to_camera else {
        return Ok(());
    };
    let cam = crate::scene::camera::Camera::new(scene.camera);
    let model = cam.projection.model().name();
    let recorded_model = match attrs
        .other
        .get(&exr::meta::attribute::Text::from("cylaov:camera_model"))
    {
        Some(AttributeValue::Text(t)) => t.to_string(),
        _ => "perspective".to_string(),
    };
    if recorded_model != model {
        bail!(
            "--scene {}: its camera is {model}, {} was rendered with a {recorded_model} camera",
            scene_path.display(),
            a.display()
        );
    }
    let want = crate::output::format::exr::exr_attributes(&cam, &[])
        .into_iter()
        .find_map(|at| match at {
            crate::output::format::exr::ExrAttr::M44f("worldToCamera", m) => Some(m),
            _ => None,
        })
        .context("the scene's camera has no worldToCamera")?;
    let scale = want
        .iter()
        .chain(&recorded)
        .fold(1.0f64, |m, &x| m.max(f64::from(x).abs()));
    let off = want
        .iter()
        .zip(&recorded)
        .map(|(&p, &q)| (f64::from(p) - f64::from(q)).abs())
        .fold(0.0f64, f64::max);
    if off > 1e-6 * scale || off.is_nan() {
        bail!(
            "--scene {}: its camera (origin {:?}, target {:?}) is not the one {} was rendered from: its worldToCamera differs by {off:.3e}",
            scene_path.display(),
            scene.camera.origin.to_array(),
            scene.camera.target.to_array(),
            a.display()
        );
    }
    Ok(())
}

/// Bytes a comparison holds at its peak, for images of `(pixels, channels)` (both held, 4
/// bytes a sample as they are read) and per pixel of the larger, when every pixel is a hit
/// of the same part (the worst case): 32 bytes of labels while they are built (cylinder
/// and (cylinder, part) key of each image, 24 kept), 9 for the classes and the list of
/// same pixels, 32 for two error lists at a time (value and pixel, 16 bytes each); with
/// the scene's conditioning 16 for its bounds and 16 for splitting each list. The heatmap
/// classifies again after the report is freed and holds less. 2 MiB more for the read
/// buffers and the report. `tests/memory_messages.rs` counts what the allocator hands out
/// at 256² and 1024²: the peaks lie within this estimate, which is at most a quarter above
/// them plus 8 MiB.
pub fn memory_needed(a: (u64, u64), b: (u64, u64), scene: bool) -> u64 {
    let per_pixel = 32 + 9 + 32 + if scene { 32 } else { 0 };
    4 * (a.0 * a.1 + b.0 * b.1) + per_pixel * a.0.max(b.0) + (2 << 20)
}

/// Read both images, compare, write the heatmap if asked, and format the result.
pub fn run(args: &CompareArgs) -> Result<CompareOutcome> {
    if let Some(path) = &args.heatmap {
        let mut inputs = vec![args.a.as_path(), args.b.as_path()];
        inputs.extend(args.scene.as_deref());
        check_outputs(&[("--heatmap", path)], &inputs)?;
    }
    let (sa, sb) = (header_size(&args.a)?, header_size(&args.b)?);
    check_memory(
        &format!("comparing {} with {}", args.a.display(), args.b.display()),
        memory_needed(sa, sb, args.scene.is_some()),
    )?;
    let a = AovImage::read_exr(&args.a)?;
    let b = AovImage::read_exr(&args.b)?;
    let cond = match &args.scene {
        None => None,
        Some(path) => {
            let scene = crate::scene::load(path)
                .map_err(|e| anyhow::anyhow!("--scene {}: {e}", path.display()))?;
            same_camera(&args.a, path, &scene)?;
            if !crate::verify::arbiter::has_mitsuba_sensor(&scene.camera.projection) {
                bail!(
                    "--scene {}: camera.model {}: the float32 conditioning bound follows Mitsuba's perspective and orthographic rays; compare without --scene",
                    path.display(),
                    scene.camera.projection.model().name()
                );
            }
            match Conditioning::with_ulps(&scene, &a, args.conditioning_ulps) {
                Some(c) => Some(c),
                None => bail!(
                    "--scene: {} must be that scene's render with shape_id, distance and normal, at its size",
                    args.a.display()
                ),
            }
        }
    };
    let report = compare_with(&a, &b, cond.as_ref())
        .with_context(|| format!("comparing {} with {}", args.a.display(), args.b.display()))?;
    let failures = report.failures(&args.tolerances);
    let passed = failures.is_empty();
    if let Some(path) = &args.heatmap {
        let name = |p: &Path| {
            p.file_name()
                .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
        };
        let title = format!(
            "{} VS {}: {}",
            name(&args.a),
            name(&args.b),
            if passed { "PASS" } else { "FAIL" }
        );
        write_png(
            &heatmap_figure(&a, &b, &report, &args.tolerances, cond.as_ref(), &title),
            path,
        )?;
    }
    let text = if args.json {
        let out = JsonOut {
            a: args.a.display().to_string(),
            b: args.b.display().to_string(),
            passed,
            failures,
            tolerances: args.tolerances,
            report: &report,
        };
        serde_json::to_string_pretty(&out)?
    } else {
        let mut s = format!(
            "A: {}\nB: {}\n{report}\n{}\n",
            args.a.display(),
            args.b.display(),
            tolerance_line(&args.tolerances),
        );
        for line in report.explained_lines(&args.tolerances) {
            s += &format!("accepted: {line}\n");
        }
        s + &verdict_lines(&failures)
    };
    Ok(CompareOutcome {
        text,
        passed,
        report,
    })
}
