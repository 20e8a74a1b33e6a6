//! `cylaov stress`: run the stress families through every kernel, print the table, and
//! optionally write the per-ray CSV and a log-log plot of error against difficulty.

use crate::output::store::atomic::atomic_write_bytes;

use crate::output::store::targets::check_outputs;

use crate::output::format::camera_files::csv_bytes;
use crate::verify::stress::{self, Family, Record, TABLE_HEADER, TABLE_ORDER};
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod plot;

/// Everything `stress` needs from the command line.
#[derive(Clone, Debug)]
pub struct StressArgs {
    /// One family, or all.
    pub family: Option<String>,
    /// Rays per parameter value.
    pub rays: usize,
    /// `--csv`: write one CSV line per ray and kernel here.
    pub csv: Option<PathBuf>,
    /// `--plot`: write a log-log PNG of error against difficulty here.
    pub plot: Option<PathBuf>,
    /// Print the Markdown table of docs/accuracy.md instead of the text table (no timing: the same
    /// bytes on every run).
    pub markdown: bool,
}

/// Run the suite; returns the table text.
pub fn run(args: &StressArgs) -> Result<String> {
    let families: Vec<Family> = match &args.family {
        None => Family::ALL.to_vec(),
        Some(name) => match Family::parse(name) {
            Some(f) => vec![f],
            None => bail!(
                "--family: unknown family {name:?}; expected one of {}",
                Family::ALL.map(|f| f.name()).join(", ")
            ),
        },
    };
    if args.rays == 0 {
        return super::usage("--rays: must be >= 1, got 0");
    }
    let mut outputs: Vec<(&str, &Path)> = Vec::new();
    if let Some(p) = &args.csv {
        outputs.push(("--csv", p));
    }
    if let Some(p) = &args.plot {
        outputs.push(("--plot", p));
    }
    check_outputs(&outputs, &[])?;
    let start = Instant::now();
    let records: Vec<Record> = families
        .iter()
        .flat_map(|&f| stress::run_family(f, args.rays, &TABLE_ORDER))
        .collect();
    let summaries = stress::summarise(&records);
    let out = if args.markdown {
        let mut md = stress::markdown_table(&summaries);
        md.pop(); // the caller ends the line
        md
    } else {
        let mut out = format!("{TABLE_HEADER}\n");
        for s in &summaries {
            out.push_str(&format!("{s}\n"));
        }
        out.push_str(&format!(
            "{} rays x {} kernels in {:.2} s; err/eps is |dt|/(eps t) with eps the kernel's unit roundoff; \
             stats over rays outside the tangency band where both hit",
            records.len() / TABLE_ORDER.len(),
            TABLE_ORDER.len(),
            start.elapsed().as_secs_f64()
        ));
        out
    };
    if let Some(path) = &args.csv {
        let text = csv_bytes(records.iter().map(Record::csv_row))?;
        atomic_write_bytes(path, &text).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.plot {
        crate::output::pipeline::files::write_png(&plot::plot(&records, &families), path)?;
    }
    Ok(out)
}
