//! `cylaov compare`: two EXRs compared by the per-pixel rule.

use crate::cli;
use crate::cli::common::{TolerancesCli, non_negative};
use clap::Args;
use cylaov::commands;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct CompareCli {
    /// First image (usually cylaov's render).
    a: PathBuf,
    /// Second image (usually the Mitsuba reference).
    b: PathBuf,
    /// Write a PNG showing where the images differ, explained by the legend under the image
    /// (silhouette, seam and interior mismatches, errors against their tolerance).
    #[arg(long, value_name = "OUT.png")]
    heatmap: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// The scene A was rendered from: grazing pixels get their float32 conditioning bound
    /// (A must hold shape_id, distance and normal).
    #[arg(long, value_name = "SCENE.json")]
    scene: Option<PathBuf>,
    /// With --scene: the float32 ulps of sideways ray error the conditioning bound allows
    /// (2: the drift between two runs of one float32 renderer).
    #[arg(long, value_name = "K", default_value_t = cylaov::verify::compare::CONDITIONING_ULPS, value_parser = non_negative)]
    conditioning_ulps: f64,
    #[command(flatten)]
    tolerances: TolerancesCli,
}

/// 0 when every tolerance holds, 1 when one is broken, 2 when the comparison could not be
/// made (its errors, printing the report included, are reported here; a refused
/// allocation ends the process with 2 as well).
pub fn run(a: CompareCli) -> ExitCode {
    cylaov::mem::set_out_of_memory_status(2);
    let args = commands::compare::CompareArgs {
        a: a.a,
        b: a.b,
        scene: a.scene,
        conditioning_ulps: a.conditioning_ulps,
        heatmap: a.heatmap,
        json: a.json,
        tolerances: a.tolerances.get(),
    };
    cli::check_status(commands::compare::run(&args).map(|out| (out.text, u8::from(!out.passed))))
}
