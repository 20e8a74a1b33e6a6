//! `scripts/backproject.py` turns a batch view into world points that lie on the cylinders:
//! the distance to the nearest finite cylinder surface (side or cap) is at most
//! 1e-4 of that cylinder's radius. Runs with the reference venv's Python (numpy).
//! Without the venv it is skipped, saying so; with `CYLAOV_REQUIRE_VENV=1` it fails.

mod common;
use common::{distance_to_surface, read_npy, venv_python};

use cylaov::image::AovImage;
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_cylaov");

/// The venv's Python with numpy, or `None` (skipped, or failed under
/// `CYLAOV_REQUIRE_VENV=1`).
fn python() -> Option<PathBuf> {
    let py = venv_python()?;
    let ok = Command::new(&py)
        .args(["-c", "import numpy"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(ok, "{} has no numpy (run scripts/setup-venv)", py.display());
    Some(py)
}

#[test]
fn backprojected_points_lie_on_the_cylinders() {
    let Some(py) = python() else { return };
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-backproject-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let data = dir.join("data");
    let run = |args: &[&str]| {
        let o = Command::new(BIN).args(args).output().unwrap();
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    run(&[
        "generate",
        "--count",
        "2",
        "--seed",
        "4",
        "--out",
        data.to_str().unwrap(),
        "--width",
        "96",
        "--height",
        "72",
        "--cylinders",
        "12",
        "--caps-prob",
        "0.5",
    ]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/backproject.py");
    for compression in ["none", "zip"] {
        let out = dir.join(compression);
        run(&[
            "batch",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--compression",
            compression,
        ]);
        for name in ["000000", "000001"] {
            let exr = out.join(format!("{name}.exr"));
            let npy = out.join(format!("{name}.npy"));
            let o = Command::new(&py)
                .arg(&script)
                .arg(&exr)
                .arg("--out")
                .arg(&npy)
                .output()
                .unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let points = read_npy(&npy);
            let depth = AovImage::read_exr(&exr).unwrap();
            let hits = depth
                .f32_channel("depth")
                .unwrap()
                .iter()
                .filter(|z| **z > 0.0)
                .count();
            assert_eq!(points.len(), hits);
            assert!(hits > 300, "{name}: only {hits} hit pixels");
            let scene = cylaov::scene::load(&data.join(format!("scenes/{name}.json"))).unwrap();
            let mut worst = (0.0f64, DVec3::ZERO);
            for p in &points {
                let (d, r) = scene
                    .cylinders
                    .iter()
                    .map(|c| (distance_to_surface(c, *p), c.radius))
                    .fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a });
                if d / r > worst.0 {
                    worst = (d / r, *p);
                }
            }
            println!(
                "{compression} {name}: {hits} points, max distance / radius {:.3e}",
                worst.0
            );
            assert!(
                worst.0 <= 1e-4,
                "{name}: point {:?} is {:.3e} radii off",
                worst.1,
                worst.0
            );
            // The check can fail: the same points 1% further along their rays are off.
            let cam = scene.camera.origin;
            let moved = points.iter().map(|p| cam + (*p - cam) * 1.01);
            let off = moved
                .map(|p| {
                    scene
                        .cylinders
                        .iter()
                        .map(|c| distance_to_surface(c, p) / c.radius)
                        .fold(f64::INFINITY, f64::min)
                })
                .fold(0.0, f64::max);
            assert!(off > 1e-3, "{off}");
        }
    }
}
