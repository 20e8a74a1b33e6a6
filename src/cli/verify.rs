//! `cylaov verify`: views checked against Mitsuba or a candidate, pixel by pixel.

use crate::cli;
use crate::cli::common::TolerancesCli;
use clap::Args;
use cylaov::commands;
use cylaov::geometry::{FormulaKind, Precision};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct VerifyCli {
    /// A scene file, a folder of scene files (or holding manifest.jsonl), or a .jsonl
    /// manifest.
    input: PathBuf,
    /// Fraction of the views to check, chosen from --seed and each view's batch name
    /// (`scene` or `scene/NN`).
    #[arg(
        long,
        default_value_t = 1.0,
        value_name = "F",
        allow_hyphen_values = true
    )]
    fraction: f64,
    /// Seed of the --fraction choice (the views batch --verify-seed checks).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write DIR/NAME.heatmap.png for every checked view: where cylaov and Mitsuba differ,
    /// explained by the legend under the image.
    #[arg(long, value_name = "DIR")]
    heatmap: Option<PathBuf>,
    /// Print the results as JSON.
    #[arg(long)]
    json: bool,
    /// Kernel precision of cylaov's side when it renders a scene file (a batch folder's
    /// views are rendered with the kernel each view's stamp records).
    #[arg(long, value_parser = cli::choice::<Precision>(), default_value_t = Precision::F64)]
    precision: Precision,
    /// Kernel formulation of cylaov's side when it renders a scene file (a batch folder's
    /// views use their stamp's).
    #[arg(long, value_parser = cli::choice::<FormulaKind>(), default_value_t = FormulaKind::Stable)]
    formula: FormulaKind,
    /// Check another renderer's AOV EXR of the scene file instead of cylaov's render:
    /// against the exact answer, with Mitsuba as a second opinion.
    #[arg(long, value_name = "THEIR.exr")]
    candidate: Option<PathBuf>,
    /// With --candidate: its channel names, AOV=NAME, comma-separated (normal=N maps
    /// N.X/N.Y/N.Z or N.R/N.G/N.B); unmapped channels are read by cylaov's names.
    #[arg(long, value_delimiter = ',', value_name = "AOV=NAME")]
    channels: Vec<String>,
    /// With --candidate: its bound, in float32 ulps of storage and of sideways ray error.
    #[arg(long, value_name = "K", default_value_t = 4.0)]
    candidate_ulps: f64,
    /// With --candidate: the scene's camera it shows (0-based; needed for a scene with
    /// several cameras).
    #[arg(long, value_name = "K")]
    camera: Option<usize>,
    /// Write DIR/index.html: a self-contained page (images beside it) with the per-view
    /// table, each view's pictures with legends, and its worst pixels' three answers.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// With a batch's output folder (holding index.json) as input: the scene folder or
    /// manifest the batch read, instead of the one index.json records (scenes moved since).
    /// The EXR files on disk are checked, not a fresh render.
    #[arg(long, value_name = "DIR")]
    scenes: Option<PathBuf>,
    #[command(flatten)]
    tolerances: TolerancesCli,
}

/// 0 when every checked view agrees, 1 when one breaks a tolerance, 2 when a view could
/// not be checked or the check could not start (reported here; a refused allocation ends
/// the process with 2 as well).
pub fn run(a: VerifyCli) -> ExitCode {
    cylaov::mem::set_out_of_memory_status(2);
    let args = commands::verify::VerifyArgs {
        input: a.input,
        fraction: a.fraction,
        seed: a.seed,
        heatmap: a.heatmap,
        json: a.json,
        tolerances: a.tolerances.get(),
        precision: a.precision,
        formula: a.formula,
        candidate: a.candidate,
        channels: a.channels,
        candidate_ulps: a.candidate_ulps,
        camera: a.camera,
        report: a.report,
        scenes: a.scenes,
    };
    cli::check_status(commands::verify::run(&args).map(|out| (out.text, out.code)))
}
