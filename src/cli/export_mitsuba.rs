//! `cylaov export-mitsuba`: the scene as Mitsuba 3 XML.

use crate::cli::common::say;
use clap::Args;
use cylaov::commands;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct ExportCli {
    /// Scene file (JSON).
    scene: PathBuf,
    /// Output XML.
    #[arg(short, long)]
    out: PathBuf,
}

pub fn run(a: ExportCli) -> anyhow::Result<ExitCode> {
    say(&commands::export_mitsuba::run(&a.scene, &a.out)?)?;
    Ok(ExitCode::SUCCESS)
}
