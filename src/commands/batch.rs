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
}

/// Run the batch; the summary says what happened (failed views are not an `Err`).
pub fn run(args: &BatchArgs) -> Result<Summary> {
    crate::output::io::check_output_dir("--out", &args.out)?;
    let shard = batch::resolve_shard(args.shard, args.shards, &|k| std::env::var(k).ok())
        .map_err(anyhow::Error::msg)?;
    let verifier = verifier(args.options.verify_fraction)?;
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
/// (without it verification is skipped with a notice: the issue's "when the reference venv
/// is present").
fn verifier(fraction: f64) -> Result<Option<crate::verify::reference::MitsubaVerifier>> {
    if fraction <= 0.0 {
        return Ok(None);
    }
    let found = crate::verify::reference::MitsubaVerifier::find();
    if let Err(why) = &found {
        eprintln!("--verify-fraction: skipped: {why}");
    }
    Ok(found.ok())
}
