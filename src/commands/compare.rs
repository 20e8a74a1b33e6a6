//! `cylaov compare`: two AOV EXRs → report (table or JSON), optional heatmap, pass/fail.
//! With `--scene`, A must be a render of that scene (cylaov's or Mitsuba's, with `shape_id`,
//! `distance` and `normal`), and grazing pixels get their float32 conditioning bound.

use crate::output::aov::AovImage;
use crate::output::io::{check_memory, check_outputs};
use crate::output::preview::write_png;
use crate::verify::compare::{Conditioning, Report, Tolerances, compare_with, heatmap};
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
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .with_context(|| format!("reading {}", path.display()))?;
    let h = meta
        .headers
        .first()
        .with_context(|| format!("{}: no image in the file", path.display()))?;
    let size = h.layer_size;
    Ok((size.0 as u64 * size.1 as u64, h.channels.list.len() as u64))
}

/// Bytes a comparison holds at its peak: both images (4 bytes a sample, as they are read)
/// plus 16 bytes a pixel of the larger for the per-pixel classes, identities, errors and
/// the heatmap. Measured on 4096 x 4096: 1363 MiB peak for two 9-channel images
/// (estimate 1408), 325 MiB for two depth-only ones (estimate 384).
pub fn memory_needed(a: (u64, u64), b: (u64, u64)) -> u64 {
    4 * (a.0 * a.1 + b.0 * b.1) + 16 * a.0.max(b.0)
}

/// The tolerance line of a text report.
pub fn tolerance_line(t: &Tolerances) -> String {
    format!(
        "tolerances: silhouette mismatches <= {:.2e}, seam mismatches <= {:.2e}, rel distance <= {:.1e}, rel depth <= {:.1e}, normal <= {} deg",
        t.max_mismatch_fraction, t.max_seam_fraction, t.rel_distance, t.rel_depth, t.normal_deg
    )
}

/// `PASS`, or `FAIL:` and one indented line per broken tolerance.
pub fn verdict_lines(failures: &[String]) -> String {
    if failures.is_empty() {
        return "PASS".into();
    }
    let mut s = String::from("FAIL:");
    for f in failures {
        s += &format!("\n  {f}");
    }
    s
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
        memory_needed(sa, sb),
    )?;
    let a = AovImage::read_exr(&args.a)?;
    let b = AovImage::read_exr(&args.b)?;
    let cond = match &args.scene {
        None => None,
        Some(path) => {
            let scene = crate::scene::load(path)
                .map_err(|e| anyhow::anyhow!("--scene {}: {e}", path.display()))?;
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
    if let Some(path) = &args.heatmap {
        write_png(
            &annotate(heatmap(&a, &b, &report, &args.tolerances, cond.as_ref())),
            path,
        )?;
    }
    let failures = report.failures(&args.tolerances);
    let passed = failures.is_empty();
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

/// The heatmap made readable on its own: every failing pixel (red: a mismatch off a
/// silhouette; magenta: an error above its tolerance) ringed in white, since one such pixel
/// is invisible at a glance, and a legend strip of every colour under the image.
fn annotate(heat: image::RgbImage) -> image::RgbImage {
    use crate::output::plot;
    use crate::verify::compare::error_colour;
    use image::Rgb;
    const RED: Rgb<u8> = Rgb([255, 0, 0]);
    const MAGENTA: Rgb<u8> = Rgb([255, 0, 255]);
    let (w, h) = heat.dimensions();
    let scale = (w / 160).clamp(1, 4);
    let row = (8 * scale) as i64;
    let mut out = image::RgbImage::new(w, h + 2 + 4 * row as u32);
    image::imageops::replace(&mut out, &heat, 0, 0);
    let failing: Vec<(i64, i64)> = heat
        .enumerate_pixels()
        .filter(|(_, _, p)| **p == RED || **p == MAGENTA)
        .map(|(x, y, _)| (x as i64, y as i64))
        .collect();
    // Rings only where they can be told apart: beyond a few thousand the failing area is
    // itself visible.
    if failing.len() <= 4000 {
        let r = 3 + scale as i64;
        for &(x, y) in &failing {
            for d in -r..=r {
                for (px, py) in [
                    (x + d, y - r),
                    (x + d, y + r),
                    (x - r, y + d),
                    (x + r, y + d),
                ] {
                    if py < h as i64 && px >= 0 && py >= 0 && px < w as i64 {
                        let under = *heat.get_pixel(px as u32, py as u32);
                        if under != RED && under != MAGENTA {
                            out.put_pixel(px as u32, py as u32, plot::WHITE);
                        }
                    }
                }
            }
        }
    }
    let mut y = h as i64 + 3;
    let mut x = 1i64;
    let s = scale as i64;
    let entry = |out: &mut image::RgbImage, x: &mut i64, y: i64, c: Rgb<u8>, label: &str| {
        plot::fill(out, *x, y, 5 * scale, 5 * scale, c);
        if c == plot::WHITE {
            plot::fill(out, *x + s, y + s, 3 * scale, 3 * scale, plot::BLACK);
        }
        *x += 6 * s;
        plot::text(out, *x, y, scale, label, plot::WHITE);
        *x += plot::text_width(label, scale) + 3 * s;
    };
    entry(&mut out, &mut x, y, Rgb([28, 28, 28]), "BOTH MISS");
    entry(&mut out, &mut x, y, Rgb([255, 140, 0]), "EDGE MISMATCH");
    y += row;
    x = 1;
    entry(&mut out, &mut x, y, RED, "MISMATCH (FAIL)");
    entry(&mut out, &mut x, y, MAGENTA, "OVER TOL (FAIL)");
    y += row;
    x = 1;
    entry(&mut out, &mut x, y, plot::WHITE, "RING: FAILING PIXEL");
    y += row;
    // The error ramp, in units of the tolerance, log scale 1e-4 .. 1.
    let label = "ERR/TOL 1E-4";
    plot::text(&mut out, 1, y, scale, label, plot::WHITE);
    let x0 = 1 + plot::text_width(label, scale) + 2 * s;
    let x1 = (w as i64 - plot::text_width("1", scale) - 3 * s).max(x0 + 10);
    for px in x0..x1 {
        let e = 10f64.powf(-4.0 + 4.0 * (px - x0) as f64 / (x1 - x0 - 1).max(1) as f64);
        plot::fill(&mut out, px, y, 1, 5 * scale, error_colour(e));
    }
    plot::text(&mut out, x1 + 2 * s, y, scale, "1", plot::WHITE);
    out
}
