//! `cylaov bench`: run time against error, per kernel, AOV set and cylinder count.
//!
//! Scenes are generated from a fixed seed: `n` cylinders in a fixed cube, their size shrunk
//! by `(1000/n)^(1/3)` so every count fills the view about the same way. Every number in a
//! row comes from one run on this machine; compare ratios within a table, not across runs.

use crate::camera::{CameraSpec, FovAxis};
use crate::geometry::Cylinder;
use crate::rng::SplitMix64;
use crate::scene::{Aov, Scene};
use glam::DVec3;

/// `n` random cylinders at `width`×`height`, the bench's standard scene.
pub fn random_scene(n: usize, seed: u64, width: u32, height: u32) -> Scene {
    let mut rng = SplitMix64::new(seed);
    let size = (1000.0 / n.max(1) as f64).cbrt().min(4.0);
    let cylinders = (0..n)
        .map(|i| {
            let base = DVec3::new(
                rng.range(-5.0, 5.0),
                rng.range(-5.0, 5.0),
                rng.range(-5.0, 5.0),
            );
            let axis = loop {
                let a = DVec3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                );
                if a.length() > 0.1 && a.length() <= 1.0 {
                    break a.normalize();
                }
            };
            Cylinder {
                base,
                axis,
                height: rng.range(0.3, 1.5) * size,
                radius: rng.range(0.03, 0.15) * size,
                caps: rng.unit() < 0.7,
                id: i as u32 + 1,
            }
        })
        .collect();
    Scene {
        camera: CameraSpec {
            origin: DVec3::new(12.0, -16.0, 8.0),
            target: DVec3::ZERO,
            up: DVec3::Z,
            fov_deg: 45.0,
            fov_axis: FovAxis::X,
            width,
            height,
            near_clip: 0.01,
            far_clip: 10000.0,
        },
        cylinders,
        aovs: vec![Aov::Depth, Aov::Normal],
    }
}
