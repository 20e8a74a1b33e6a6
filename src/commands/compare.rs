//! `cylaov compare`: two AOV EXRs → report (table or JSON), optional heatmap, pass/fail.

use crate::output::aov::AovImage;
use crate::output::preview::write_png;
use crate::verify::compare::{Report, Tolerances, compare, heatmap};
use anyhow::{Context, Result};
use serde::Serialize;
use std::path::PathBuf;

/// Everything `compare` needs from the command line.
#[derive(Clone, Debug)]
pub struct CompareArgs {
    pub a: PathBuf,
    pub b: PathBuf,
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

/// Read both images, compare, write the heatmap if asked, and format the result.
pub fn run(args: &CompareArgs) -> Result<CompareOutcome> {
    let a = AovImage::read_exr(&args.a)?;
    let b = AovImage::read_exr(&args.b)?;
    let report = compare(&a, &b)
        .with_context(|| format!("comparing {} with {}", args.a.display(), args.b.display()))?;
    if let Some(path) = &args.heatmap {
        write_png(&heatmap(&a, &b, &report, &args.tolerances), path)?;
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
        let t = &args.tolerances;
        let mut s = format!(
            "A: {}\nB: {}\n{report}\n",
            args.a.display(),
            args.b.display()
        );
        s += &format!(
            "tolerances: mismatches <= {:.2e} (silhouettes only), rel distance <= {:.1e}, rel depth <= {:.1e}, normal <= {} deg\n",
            t.max_mismatch_fraction, t.rel_distance, t.rel_depth, t.normal_deg
        );
        if passed {
            s += "PASS";
        } else {
            s += "FAIL:";
            for f in &failures {
                s += &format!("\n  {f}");
            }
        }
        s
    };
    Ok(CompareOutcome {
        text,
        passed,
        report,
    })
}
