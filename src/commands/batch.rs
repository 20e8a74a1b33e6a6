//! `cylaov batch`: shard resolution from the command line and the environment, then
//! [`crate::dataset::batch::run`].

use crate::dataset::batch::{self, BatchOptions, ProgressMode, Shard, Summary};
use anyhow::Result;
use std::path::PathBuf;

/// Everything `batch` needs from the command line.
#[derive(Clone, Debug)]
pub struct BatchArgs {
    pub input: PathBuf,
    pub out: PathBuf,
    pub shard: Option<Shard>,
    pub shards: Option<u32>,
    pub options: BatchOptions,
    pub progress: ProgressMode,
    /// Bounds of `--verify-fraction`'s check.
    pub tolerances: crate::verify::compare::Tolerances,
}

/// Run the batch; the summary says what happened (failed views are not an `Err`).
pub fn run(args: &BatchArgs) -> Result<Summary> {
    let shard = batch::resolve_shard(args.shard, args.shards, &|k| std::env::var(k).ok())
        .map_err(anyhow::Error::msg)?;
    let verifier = verifier(args)?;
    batch::run(
        &args.input,
        &args.out,
        shard,
        &args.options,
        args.progress,
        verifier.as_ref().map(|v| v as &dyn batch::Verifier),
    )
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
        eprintln!("--verify-fraction: skipped: {why}");
    }
    Ok(found.ok())
}
