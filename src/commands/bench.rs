//! `cylaov bench`: print the time-vs-error table, optionally as CSV.

use crate::bench::{self, BenchOptions, Row};
use crate::io::atomic_write_bytes;
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Run the table, printing rows as they finish; write CSV if asked.
pub fn run(opts: &BenchOptions, csv: Option<PathBuf>) -> Result<Vec<Row>> {
    println!(
        "cylaov bench: {}x{}, seed {}, min of {} runs, {} threads; times in ms, err = relative distance error vs stable-f64",
        opts.width,
        opts.height,
        opts.seed,
        opts.repeats,
        rayon::current_num_threads()
    );
    println!("{}", bench::header());
    let rows = bench::run(opts, |r| println!("{}", bench::format_row(r)))?;
    if let Some(path) = csv {
        atomic_write_bytes(&path, bench::csv(&rows).as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(rows)
}
