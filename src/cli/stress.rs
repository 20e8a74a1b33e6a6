//! `cylaov stress`: the hard ray families against the exact oracle.

use crate::cli::common::{at_least_one, say, shorten};
use clap::Args;
use cylaov::commands;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct StressCli {
    /// Run one family only: grazing, near-axis, far, scale, inside, rims, input.
    #[arg(long, value_parser = family)]
    family: Option<String>,
    /// Seeded rays per value of the difficulty parameter.
    #[arg(long, default_value_t = 64, value_parser = at_least_one)]
    rays: usize,
    /// Write one CSV line per ray and kernel (inputs included, to reproduce a ray).
    #[arg(long, value_name = "OUT")]
    csv: Option<PathBuf>,
    /// Write a log-log PNG of error against the difficulty parameter.
    #[arg(long, value_name = "OUT.png")]
    plot: Option<PathBuf>,
    /// Print the table as Markdown, as in the README (the same bytes on every run).
    #[arg(long)]
    markdown: bool,
}

pub fn family(s: &str) -> Result<String, String> {
    use cylaov::verify::stress::Family;
    match Family::parse(s) {
        Some(_) => Ok(s.to_string()),
        None => Err(format!(
            "unknown family {:?}; expected one of {}",
            shorten(s),
            Family::ALL.map(|f| f.name()).join(", ")
        )),
    }
}

pub fn run(a: StressCli) -> anyhow::Result<ExitCode> {
    let args = commands::stress::StressArgs {
        family: a.family,
        rays: a.rays,
        csv: a.csv,
        plot: a.plot,
        markdown: a.markdown,
    };
    say(&commands::stress::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}
