//! `cylaov bench --scaling`: how each way of making views scales with the threads. One
//! generated dataset (320×240, depth+normal, 100 cylinders a scene) is made views by
//! `render` (in memory, one view after another, each on the whole pool), by `batch` to
//! files (`--no-png`) and as tar shards (`--format webdataset`), at 1, 2, 4, … threads up to
//! the cores present; and, where a Python with the package is at hand, by the package's
//! `Dataset` through a PyTorch `DataLoader` with that many workers (`threads=1` each,
//! batches of 32). Each row is views a second and the parallel efficiency,
//! `views/s(n) / (n · views/s(1))`: 1 is perfect scaling. The two `batch` formats run
//! twice at each thread count, in both orders, and each keeps its faster run.

use super::batch_formats::{sync_tree, timed_batch};
use crate::dataset::batch::BatchOptions;
use crate::dataset::batch::shards::ShardOptions;
use crate::render::{RenderOptions, render};
use crate::scene::Aov;
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The view size, cylinder count and generator seed of the dataset every row makes.
pub const WIDTH: u32 = 320;
/// See [`WIDTH`].
pub const HEIGHT: u32 = 240;
/// See [`WIDTH`].
pub const CYLINDERS: u64 = 100;
/// See [`WIDTH`]; the Python `Dataset` takes the same seed, so it renders the same scenes.
pub const SEED: u64 = 1;
/// Views a tar in the webdataset rows: enough tars that every thread owns some.
pub const SHARD_SIZE: usize = 25;
/// Views a `DataLoader` batch.
pub const BATCH_SIZE: usize = 32;

/// `scripts/bench_dataloader.py`, compiled in so the binary runs it from anywhere.
pub const DATALOADER_SCRIPT: &str = include_str!("../../scripts/bench_dataloader.py");

/// The ways of making views, in the table's order.
pub const WORKLOADS: [&str; 4] = ["render", "batch files", "batch webdataset", "DataLoader"];

/// One row: a workload at a thread count.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ScalingRow {
    /// Threads (the pool's size; the `DataLoader`'s workers).
    pub threads: usize,
    /// One of [`WORKLOADS`].
    pub workload: &'static str,
    /// Views made.
    pub views: usize,
    /// Wall seconds.
    pub seconds: f64,
    /// Views a second.
    pub views_per_s: f64,
    /// `views_per_s / (threads · views_per_s at 1 thread)`.
    pub efficiency: f64,
}

/// 1, 2, 4, … below `cores`, then `cores`.
pub fn thread_counts(cores: usize) -> Vec<usize> {
    let mut v: Vec<usize> = std::iter::successors(Some(1usize), |&n| n.checked_mul(2))
        .take_while(|&n| n < cores)
        .collect();
    v.push(cores.max(1));
    v
}

/// Time every workload on the generated dataset `data` (its `views` views, [`WIDTH`] ×
/// [`HEIGHT`], [`CYLINDERS`] a scene, seed [`SEED`]: the caller generates and syncs it) at
/// each of `threads`; the `DataLoader` rows only when `python` is given (a Python with the
/// package and torch). `note` is told each row as it is measured.
pub fn run(
    data: &Path,
    views: u64,
    threads: &[usize],
    python: Option<&Path>,
    mut note: impl FnMut(&ScalingRow) -> Result<()>,
) -> Result<Vec<ScalingRow>> {
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-bench-scaling-")
        .tempdir()
        .context("making a temp folder")?;
    let data = data.to_path_buf();
    let scenes = scene_files(&data.join("scenes"))?
        .iter()
        .map(|p| crate::scene::load(p).with_context(|| format!("loading {}", p.display())))
        .collect::<Result<Vec<_>>>()?;
    let aovs = vec![Aov::Depth, Aov::Normal];
    let opts = BatchOptions {
        aovs: Some(aovs.clone()),
        png: false,
        ..BatchOptions::default()
    };
    let script = tmp.path().join("bench_dataloader.py");
    std::fs::write(&script, DATALOADER_SCRIPT).context("writing the DataLoader script")?;
    let mut rows: Vec<ScalingRow> = Vec::new();
    for &n in threads {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .context("making a thread pool")?;
        let mut measured: Vec<(&'static str, usize, f64)> = Vec::new();
        // Render: each view on the whole pool, the next when it is done, nothing kept.
        let ropts = RenderOptions::new(aovs.clone());
        let t = Instant::now();
        pool.install(|| {
            for s in &scenes {
                std::hint::black_box(render(s, &ropts));
            }
        });
        measured.push(("render", scenes.len(), t.elapsed().as_secs_f64()));
        // The two batch formats twice, each order once, each its faster run: a VM's
        // disk can slow down for a while after a gigabyte or two of writes, and in one
        // fixed order the second format would always pay for the first one's.
        let sopts = ShardOptions {
            shard_size: SHARD_SIZE,
            ..ShardOptions::default()
        };
        let mut best = [f64::INFINITY; 2];
        let mut done = [0usize; 2];
        for first in [0, 1] {
            for k in [first, 1 - first] {
                let out = tmp
                    .path()
                    .join(format!("{}-{n}", ["files", "webdataset"][k]));
                let (made, seconds) =
                    pool.install(|| timed_batch(&data, &out, &opts, [None, Some(&sopts)][k]))?;
                (done[k], best[k]) = (made, best[k].min(seconds));
                sync_tree(&out)?;
            }
        }
        measured.push(("batch files", done[0], best[0]));
        measured.push(("batch webdataset", done[1], best[1]));
        if let Some(py) = python {
            let (v, secs) = dataloader(py, &script, views, n)?;
            measured.push(("DataLoader", v, secs));
        }
        for (workload, v, seconds) in measured {
            let views_per_s = v as f64 / seconds;
            let one = rows
                .iter()
                .find(|r| r.workload == workload && r.threads == 1)
                .map_or(views_per_s, |r| r.views_per_s);
            let row = ScalingRow {
                threads: n,
                workload,
                views: v,
                seconds,
                views_per_s,
                efficiency: views_per_s / (n as f64 * one),
            };
            note(&row)?;
            rows.push(row);
        }
    }
    Ok(rows)
}

/// The scene files of a `generate` output, in name order.
fn scene_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .collect();
    v.sort();
    Ok(v)
}

/// Views and seconds of the package's `Dataset` through a `DataLoader` of `workers`
/// workers, as the script reports them (`VIEWS SECONDS` on its last line): its fastest
/// pass, alternated with passes rendering the same views in one process, whose ratio it
/// prints above (the loader's cost of handing batches over, in one run).
fn dataloader(python: &Path, script: &Path, views: u64, workers: usize) -> Result<(usize, f64)> {
    let out = std::process::Command::new(python)
        .arg(script)
        .args([
            "--views",
            &views.to_string(),
            "--workers",
            &workers.to_string(),
        ])
        .args([
            "--seed",
            &SEED.to_string(),
            "--cylinders",
            &CYLINDERS.to_string(),
        ])
        .args([
            "--width",
            &WIDTH.to_string(),
            "--height",
            &HEIGHT.to_string(),
        ])
        .args(["--batch-size", &BATCH_SIZE.to_string()])
        .output()
        .with_context(|| format!("running {}", python.display()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        bail!(
            "the DataLoader rows: {} {} failed ({}): {}",
            python.display(),
            script.display(),
            out.status,
            err.trim().lines().last().unwrap_or("")
        );
    }
    let last = text.trim().lines().last().unwrap_or("");
    let mut it = last.split_whitespace();
    match (
        it.next().and_then(|v| v.parse().ok()),
        it.next().and_then(|s| s.parse().ok()),
    ) {
        (Some(v), Some(s)) => Ok((v, s)),
        _ => bail!("the DataLoader script printed {last:?}, not `VIEWS SECONDS`"),
    }
}

/// The rows as a table: a line per thread count, each workload's views/s and efficiency,
/// and the tar shards' views/s over the files'.
pub fn table(rows: &[ScalingRow]) -> String {
    let mut counts: Vec<usize> = rows.iter().map(|r| r.threads).collect();
    counts.dedup();
    let present: Vec<&str> = WORKLOADS
        .iter()
        .copied()
        .filter(|w| rows.iter().any(|r| r.workload == *w))
        .collect();
    let mut s = format!("{:>7}", "threads");
    for w in &present {
        s += &format!(" {:>24}", format!("{w} views/s (eff.)"));
    }
    s += &format!(" {:>18}\n", "webdataset/files");
    for n in counts {
        s += &format!("{n:>7}");
        let get = |w: &str| rows.iter().find(|r| r.threads == n && r.workload == w);
        for w in &present {
            match get(w) {
                Some(r) => {
                    s += &format!(
                        " {:>24}",
                        format!("{:.1} ({:.2})", r.views_per_s, r.efficiency)
                    )
                }
                None => s += &format!(" {:>24}", "-"),
            }
        }
        match (get("batch webdataset"), get("batch files")) {
            (Some(t), Some(f)) => s += &format!(" {:>18.2}\n", t.views_per_s / f.views_per_s),
            _ => s += &format!(" {:>18}\n", "-"),
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thread_counts_double_up_to_the_cores() {
        assert_eq!(thread_counts(1), [1]);
        assert_eq!(thread_counts(2), [1, 2]);
        assert_eq!(thread_counts(6), [1, 2, 4, 6]);
        assert_eq!(thread_counts(16), [1, 2, 4, 8, 16]);
    }
}
