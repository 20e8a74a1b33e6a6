//! The load path at scale, as whole `cylaov render` processes: the dense family's 100 000
//! cylinders in a 16×16 view (nearly all reading, validating, preparing and sorting the
//! cylinders; 256 pixels to trace) and at 1920×1080, each against its 1 000 cylinders at
//! 1920×1080 (mostly tracing). The ratios say what a big scene's loading costs next to an
//! ordinary render, on this machine, whatever its speed.

use super::{Family, time_process};
use crate::geometry::Kernel;
use crate::render::Accel;
use crate::scene::{Aov, SceneFile};
use anyhow::Result;
use serde::Serialize;
use std::path::Path;

/// One case of the load table.
#[derive(Clone, Debug, Serialize)]
pub struct LoadRow {
    /// Cylinders and view, e.g. `dense 100000 at 16x16`.
    pub case: String,
    /// The whole process, ms (the minimum over the rounds).
    pub process_ms: f64,
    /// `process_ms` over the 1 000-cylinder 1920×1080 case's.
    pub ratio: f64,
}

/// The cases: cylinders, width, height; the first is the reference of the ratios.
const CASES: [(usize, u32, u32); 3] =
    [(1000, 1920, 1080), (100_000, 16, 16), (100_000, 1920, 1080)];

/// Time the cases with `exe` (stable f64, depth and normal, screen tiles), each round every
/// case once in turn, so a slow spell of a shared machine hits them alike; `rounds` at
/// least five. Scenes and images go to `dir`.
pub fn run(exe: &Path, seed: u64, rounds: usize, dir: &Path) -> Result<Vec<LoadRow>> {
    let aovs = [Aov::Depth, Aov::Normal];
    let mut scenes = Vec::new();
    for (n, w, h) in CASES {
        let path = dir.join(format!("load-{n}-{w}x{h}.json"));
        let scene = Family::Dense.scene(n, seed, w, h);
        std::fs::write(
            &path,
            serde_json::to_string(&SceneFile::from_scene(&scene))?,
        )?;
        scenes.push(path);
    }
    let mut best = [f64::INFINITY; CASES.len()];
    for _ in 0..rounds.max(5) {
        for (k, scene) in scenes.iter().enumerate() {
            let out = dir.join("load.exr");
            let (ms, _) = time_process(exe, scene, &out, Kernel::STABLE_F64, &aovs, Accel::Tiles)?;
            best[k] = best[k].min(ms);
        }
    }
    Ok(CASES
        .iter()
        .zip(best)
        .map(|(&(n, w, h), ms)| LoadRow {
            case: format!("dense {n} at {w}x{h}"),
            process_ms: ms,
            ratio: ms / best[0],
        })
        .collect())
}
