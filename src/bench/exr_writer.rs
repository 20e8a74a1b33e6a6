//! `cylaov bench --exr-writer`: the uncompressed EXR writer on the render's AOV buffers
//! (a vector AOV's three channels side by side in one buffer, so each of its rows is
//! gathered channel by channel) against the same image held one plane per channel (each
//! row a contiguous slice), side by side in one run. Both give the same bytes (checked
//! before timing). Each is timed encoding into memory (the writer alone) and writing a
//! file in the temp folder through the same 1 MiB buffer `cylaov render` uses (what a
//! user waits for).

use crate::image::{AovBuffer, AovImage};
use crate::render::{RenderOptions, render};
use crate::scene::Aov;
use anyhow::{Context, Result, bail};
use std::path::Path;
use std::time::Instant;

/// One row: an AOV set, where it goes, and the writer's time on each layout.
#[derive(Clone, Debug, serde::Serialize)]
pub struct WriterRow {
    /// The AOVs written, comma-separated.
    pub aovs: String,
    /// `memory` or `file`.
    pub target: &'static str,
    /// Image width and height.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Bytes of the file.
    pub bytes: usize,
    /// Fastest write from the AOV buffers, milliseconds.
    pub buffers_ms: f64,
    /// Fastest write from one plane per channel, milliseconds.
    pub planes_ms: f64,
    /// `planes_ms / buffers_ms`: above 1, the buffers are the faster.
    pub speed_ratio: f64,
}

/// The same image with every channel a buffer of its own.
fn as_planes(img: &AovImage) -> AovImage {
    AovImage {
        width: img.width,
        height: img.height,
        buffers: img
            .to_channels()
            .into_iter()
            .map(|c| AovBuffer {
                names: vec![c.name],
                data: c.data,
            })
            .collect(),
    }
}

/// One uncompressed write of `img` into memory reserved for it beforehand, ms, and the
/// bytes.
fn time_write(img: &AovImage, size: usize) -> Result<(f64, Vec<u8>)> {
    let mut bytes = Vec::with_capacity(size);
    let t = Instant::now();
    img.write_uncompressed(&mut bytes)?;
    Ok((t.elapsed().as_secs_f64() * 1e3, bytes))
}

/// One uncompressed write of `img` into a new file at `path`, ms (created, written through a
/// 1 MiB buffer, flushed and closed, no fsync, as `cylaov render` writes; removed
/// afterwards).
fn time_file(img: &AovImage, path: &Path) -> Result<f64> {
    let t = Instant::now();
    let mut out = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(path)?);
    img.write_uncompressed(&mut out)?;
    drop(out.into_inner().map_err(|e| e.into_error())?);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    std::fs::remove_file(path)?;
    Ok(ms)
}

/// Time the writer on a render of the bench's dense scene (`cylinders` cylinders) at
/// `width`×`height`, for depth+normal and for every AOV, into memory and into a file; the
/// two layouts take turns, so a slow spell of the machine falls on both alike.
pub fn run(cylinders: usize, width: u32, height: u32, repeats: usize) -> Result<Vec<WriterRow>> {
    let scene = super::dense_scene(cylinders, 1, width, height);
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-bench-exr-")
        .tempdir()
        .context("making a temp folder")?;
    let path = tmp.path().join("view.exr");
    let mut rows = Vec::new();
    for aovs in [vec![Aov::Depth, Aov::Normal], Aov::ALL.to_vec()] {
        let img = render(&scene, &RenderOptions::new(aovs.clone())).image;
        let planes = as_planes(&img);
        let bytes = time_write(&img, 0)?.1.len();
        for target in ["memory", "file"] {
            let (mut b_ms, mut p_ms) = (f64::INFINITY, f64::INFINITY);
            for _ in 0..repeats.max(1) {
                let (b, p) = if target == "memory" {
                    let (b, b_bytes) = time_write(&img, bytes)?;
                    let (p, p_bytes) = time_write(&planes, bytes)?;
                    if b_bytes != p_bytes {
                        bail!("the two layouts wrote different bytes: a bug in the writer");
                    }
                    (b, p)
                } else {
                    (time_file(&img, &path)?, time_file(&planes, &path)?)
                };
                (b_ms, p_ms) = (b_ms.min(b), p_ms.min(p));
            }
            rows.push(WriterRow {
                aovs: aovs.iter().map(|a| a.name()).collect::<Vec<_>>().join(","),
                target,
                width: img.width,
                height: img.height,
                bytes,
                buffers_ms: b_ms,
                planes_ms: p_ms,
                speed_ratio: p_ms / b_ms,
            });
        }
    }
    Ok(rows)
}

/// The rows as the table `cylaov bench --exr-writer` prints.
pub fn table(rows: &[WriterRow]) -> String {
    let mut t = format!(
        "{:<14} {:<7} {:>10} {:>7} {:>11} {:>10} {:>6}\n",
        "AOVs", "into", "size", "MiB", "buffers ms", "planes ms", "ratio"
    );
    for r in rows {
        let aovs = if r.aovs.split(',').count() == Aov::ALL.len() {
            "every AOV"
        } else {
            r.aovs.as_str()
        };
        t += &format!(
            "{:<14} {:<7} {:>10} {:>7.1} {:>11.2} {:>10.2} {:>6.2}\n",
            aovs,
            r.target,
            format!("{}x{}", r.width, r.height),
            r.bytes as f64 / (1u64 << 20) as f64,
            r.buffers_ms,
            r.planes_ms,
            r.speed_ratio
        );
    }
    t.pop();
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both layouts of a small render, the bytes checked equal inside `run`, every AOV.
    #[test]
    fn both_layouts_write_the_same_file() {
        let rows = run(50, 64, 48, 1).unwrap();
        assert_eq!(rows.len(), 4);
        assert!(rows.iter().all(|r| r.bytes > 64 * 48 * 4 * 4), "{rows:?}");
    }
}
