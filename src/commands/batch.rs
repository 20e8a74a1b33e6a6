//! `cylaov batch`: shard resolution from the command line and the environment, the
//! `--verify-fraction` verifier and `--report` page of both formats, then
//! [`crate::dataset::batch::run`] (files) or [`crate::dataset::batch::shards`] (tar shards).

use crate::dataset::batch::shards::{ShardOptions, ShardSummary, TarSelection};
use crate::dataset::batch::{self, BatchOptions, ProgressMode, Shard, Summary};
use anyhow::Result;
use std::path::PathBuf;

/// The depth PNG scale nerfstudio assumes (its `depth_unit_scale_factor` default 1e-3).
pub const NERFSTUDIO_DEPTH_SCALE: f64 = 1000.0;

/// Everything `batch` needs from the command line.
#[derive(Clone, Debug)]
pub struct BatchArgs {
    /// A folder of scene files or a `.jsonl` manifest.
    pub input: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// `--shard K/N`; with neither it nor `shards`: the SLURM array task, else every view.
    pub shard: Option<Shard>,
    /// `--shards N`, the index coming from the environment (Kubernetes Indexed Job or SLURM).
    pub shards: Option<u32>,
    /// How each view is rendered and written.
    pub options: BatchOptions,
    /// How progress is shown on stderr.
    pub progress: ProgressMode,
    /// Bounds of `--verify-fraction`'s check.
    pub tolerances: crate::verify::compare::Tolerances,
    /// `--report DIR`: the page of `verify --report` for the views checked.
    pub report: Option<PathBuf>,
}

/// Run the batch; the summary says what happened (failed views are not an `Err`).
pub fn run(args: &BatchArgs) -> Result<Summary> {
    crate::output::store::targets::check_output_dir("--out", &args.out)?;
    let shard = batch::resolve_shard(args.shard, args.shards, &|k| std::env::var(k).ok())
        .map_err(anyhow::Error::msg)?;
    // Bad values are refused before any advice about them is printed.
    args.options.validate().map_err(super::Usage)?;
    let verification = Verification::new(args)?;
    if args.options.png && args.options.depth_scale != NERFSTUDIO_DEPTH_SCALE {
        crate::output::console::warn(&format!(
            "warning: --depth-scale {}: nerfstudio reads depth PNGs at {NERFSTUDIO_DEPTH_SCALE} \
             per unit unless told otherwise: train with its parser option \
             depth_unit_scale_factor = {} (index.json and transforms.json record it, but \
             nerfstudio does not read it from there)",
            args.options.depth_scale,
            1.0 / args.options.depth_scale
        ));
    }
    let summary = batch::run(
        &args.input,
        &args.out,
        shard,
        &args.options,
        args.progress,
        verification.verifier(),
    )?;
    verification.finish(args)?;
    Ok(summary)
}

/// `batch --format webdataset`: the tar shards of this process (see
/// [`crate::dataset::batch::shards`]), verified and reported on as [`run`] does; failed
/// views are counted in the summary, not an `Err`.
pub fn shards(args: &BatchArgs, sopts: &ShardOptions) -> Result<ShardSummary> {
    let shard = batch::resolve_shard(args.shard, args.shards, &|k| std::env::var(k).ok())
        .map_err(anyhow::Error::msg)?;
    args.options.validate().map_err(super::Usage)?;
    let verification = Verification::new(args)?;
    let summary = batch::shards::write_shards(
        &args.input,
        &args.out,
        &TarSelection::Shard(shard),
        &args.options,
        sopts,
        args.progress,
        verification.verifier(),
    )?;
    verification.finish(args)?;
    Ok(summary)
}

/// `--verify-fraction` and `--report` of either format: the report folder checked, the
/// verifier found (keeping every checked view when there is a report), and the page
/// written once the views are done.
struct Verification {
    verifier: Option<crate::verify::reference::MitsubaVerifier>,
}

impl Verification {
    /// Refuse `--report` without `--verify-fraction` or with an unusable folder; find the
    /// verifier (without the venv, verification is skipped with a notice saying how to make
    /// it).
    fn new(args: &BatchArgs) -> Result<Verification> {
        if let Some(dir) = &args.report {
            if args.options.verify_fraction <= 0.0 {
                anyhow::bail!(
                    "--report {}: goes with --verify-fraction F (F > 0), the views it shows",
                    dir.display()
                );
            }
            crate::output::store::targets::check_output_dir("--report", dir)?;
        }
        let mut verifier = verifier(args)?;
        if let Some(v) = verifier.as_mut().filter(|_| args.report.is_some()) {
            v.keep = Some(std::sync::Mutex::new(Vec::new()));
        }
        Ok(Verification { verifier })
    }

    /// The verifier the batch calls, if any.
    fn verifier(&self) -> Option<&dyn batch::Verifier> {
        self.verifier.as_ref().map(|v| v as &dyn batch::Verifier)
    }

    /// Write `--report`'s page of the views checked.
    fn finish(self, args: &BatchArgs) -> Result<()> {
        if let (Some(dir), Some(kept)) = (&args.report, self.verifier.and_then(|v| v.keep)) {
            let kept = kept.into_inner().unwrap_or_else(|e| e.into_inner());
            crate::commands::verify::batch_report(dir, &args.out.display().to_string(), kept)?;
        }
        Ok(())
    }
}

/// The Mitsuba verifier for `--verify-fraction`, if asked for and the reference venv exists
/// (without it verification is skipped with a notice saying how to make the venv).
fn verifier(args: &BatchArgs) -> Result<Option<crate::verify::reference::MitsubaVerifier>> {
    if args.options.verify_fraction <= 0.0 {
        return Ok(None);
    }
    let found = crate::verify::reference::MitsubaVerifier::find(
        args.tolerances,
        args.options.precision,
        args.options.formula,
    );
    if let Err(why) = &found {
        crate::output::console::warn(&format!("--verify-fraction: skipped: {why}"));
    }
    Ok(found.ok())
}
