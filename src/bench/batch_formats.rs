//! `cylaov bench --batch-formats`: one generated dataset written by `batch` in the files
//! format (with pictures, and EXR-only) and as tar shards, side by side in one run, in
//! views per second of the whole batch (listing, rendering, encoding, writing).

use crate::commands::generate::{GenerateArgs, run as generate};
use crate::dataset::batch::shards::{ShardOptions, TarSelection, write_shards};
use crate::dataset::batch::{self, BatchOptions, ProgressMode, Shard};
use crate::dataset::generate::{ConfigFile, Range};
use anyhow::{Context, Result};
use std::path::Path;
use std::time::Instant;

/// One row: a format and its throughput.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FormatRow {
    /// `files`, `files --no-png` or `webdataset`.
    pub format: &'static str,
    /// Views written.
    pub views: usize,
    /// Wall seconds of the batch.
    pub seconds: f64,
    /// Views per second.
    pub views_per_s: f64,
    /// Bytes written.
    pub bytes: u64,
}

fn folder_bytes(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => folder_bytes(&e.path()),
            _ => e.metadata().map_or(0, |m| m.len()),
        })
        .sum()
}

/// Generate `views` scenes of `cylinders` cylinders at `width`×`height` in a temp folder
/// and time each format on them (depth+normal, the rayon pool as set).
pub fn run(views: u64, cylinders: u64, width: u32, height: u32) -> Result<Vec<FormatRow>> {
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-bench-formats-")
        .tempdir()
        .context("making a temp folder")?;
    let data = tmp.path().join("data");
    let n = cylinders.to_string();
    generate(&GenerateArgs {
        out: data.clone(),
        config: None,
        flags: ConfigFile {
            count: Some(views),
            seed: Some(1),
            cylinders: Some(Range::parse(&n).map_err(anyhow::Error::msg)?),
            width: Some(width),
            height: Some(height),
            ..ConfigFile::default()
        },
        force: false,
    })?;
    let opts = BatchOptions {
        aovs: Some(vec![crate::scene::Aov::Depth, crate::scene::Aov::Normal]),
        ..BatchOptions::default()
    };
    let mut rows = Vec::new();
    let mut row = |format, views: usize, t: Instant, out: &Path| {
        let seconds = t.elapsed().as_secs_f64();
        rows.push(FormatRow {
            format,
            views,
            seconds,
            views_per_s: views as f64 / seconds,
            bytes: folder_bytes(out),
        });
    };
    for (format, png) in [("files", true), ("files --no-png", false)] {
        let out = tmp.path().join(format.replace(' ', ""));
        let o = BatchOptions {
            png,
            ..opts.clone()
        };
        let t = Instant::now();
        let s = batch::run(&data, &out, Shard::ALL, &o, ProgressMode::Off, None)?;
        row(format, s.counts.done, t, &out);
    }
    let out = tmp.path().join("webdataset");
    let t = Instant::now();
    let s = write_shards(
        &data,
        &out,
        &TarSelection::Shard(Shard::ALL),
        &opts,
        &ShardOptions::default(),
        false,
    )?;
    row("webdataset", s.rendered, t, &out);
    Ok(rows)
}
