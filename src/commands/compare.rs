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
    pub a: PathBuf,
    pub b: PathBuf,
    /// The scene A was rendered from: enables the per-pixel float32 conditioning bounds.
    pub scene: Option<PathBuf>,
    /// The float32 ulps of ray error the conditioning bound allows (with `scene`).
    pub conditioning_ulps: f64,
    pub heatmap: Option<PathBuf>,
    pub json: bool,
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
    pub text: String,
    pub passed: bool,
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
        check_outputs(&[("--heatmap", path)], &[&args.a, &args.b])?;
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
            &heatmap(&a, &b, &report, &args.tolerances, cond.as_ref()),
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
