//! `cylaov bench --scan`: a VLP-16 rotation at 0.2° (1 800 steps × 16 beams = 28 800
//! beams), three returns, in a scene of 10 000 dense-family cylinders with the sensor at
//! the origin (inside the field), in beams per second; and, given the reference venv's
//! python, Open3D's `RaycastingScene.cast_rays` on 16-segment meshes of the same cylinders
//! for the same beams (first hits only), warm, through `scripts/bench_open3d.py`.

use super::{AnchorRow, OPEN3D_SCRIPT, dense_scene};
use crate::scan::{Pose, ScanOptions, Sensor, beam_dir, scan};
use crate::scene::SceneFile;
use anyhow::{Context, Result, bail};
use glam::DVec3;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// The row's numbers.
#[derive(Clone, Debug)]
pub struct ScanBench {
    /// Beams of the rotation.
    pub beams: usize,
    /// Points reported (up to three a beam).
    pub points: usize,
    /// Fastest of three scans, seconds (BVH build included).
    pub seconds: f64,
    /// Open3D's warm `cast_rays` of the same beams, seconds, when timed.
    pub open3d_seconds: Option<f64>,
}

/// Time the scan (and Open3D with `python`).
pub fn run(python: Option<&Path>) -> Result<ScanBench> {
    let scene = dense_scene(10_000, 1, 8, 8);
    let sensor = Sensor::preset("vlp16").context("the vlp16 preset")?;
    let pose = Pose::new(DVec3::ZERO, 0.0, 0.0, 0.0);
    let opts = ScanOptions {
        returns: 3,
        ..ScanOptions::new(sensor.clone(), pose)
    };
    let mut seconds = f64::INFINITY;
    let mut points = 0;
    for _ in 0..3 {
        let t = Instant::now();
        let s = scan(&scene, &opts).map_err(anyhow::Error::msg)?;
        seconds = seconds.min(t.elapsed().as_secs_f64());
        points = s.len();
    }
    let steps = sensor.steps_per_rotation;
    let beams = sensor.beams() * steps as usize;
    let open3d_seconds = match python {
        None => None,
        Some(py) => {
            let dir = tempfile::Builder::new()
                .prefix("cylaov-bench-scan-")
                .tempdir()?;
            let json = dir.path().join("scene.json");
            std::fs::write(
                &json,
                serde_json::to_string(&SceneFile::from_scene(&scene))?,
            )?;
            let script = dir.path().join("bench_open3d.py");
            std::fs::write(&script, OPEN3D_SCRIPT)?;
            // The same beams as the scan: origin and unit direction, float32.
            let mut rays = Vec::with_capacity(beams * 6);
            for s in 0..steps {
                for ring in 0..sensor.beams() {
                    let az = s as f64 * 360.0 / steps as f64 + sensor.azimuth_offsets_deg[ring];
                    let d = beam_dir(sensor.elevations_deg[ring], az).normalize();
                    rays.extend([0.0, 0.0, 0.0, d.x as f32, d.y as f32, d.z as f32]);
                }
            }
            let npy = dir.path().join("rays.npy");
            let bytes = crate::npy::array(crate::npy::Dtype::F32, &[beams, 6], &rays);
            std::fs::write(&npy, bytes)?;
            let o = Command::new(py)
                .arg(&script)
                .arg(&json)
                .arg(dir.path().join("t.npy"))
                .arg(&npy)
                .output()
                .with_context(|| format!("running {}", py.display()))?;
            if !o.status.success() {
                bail!("open3d failed: {}", String::from_utf8_lossy(&o.stderr));
            }
            let text = String::from_utf8_lossy(&o.stdout);
            let line = text.lines().last().unwrap_or_default();
            let row: AnchorRow = serde_json::from_str(line)
                .with_context(|| format!("the open3d script printed {line:?}"))?;
            Some(row.render2_s)
        }
    };
    Ok(ScanBench {
        beams,
        points,
        seconds,
        open3d_seconds,
    })
}
