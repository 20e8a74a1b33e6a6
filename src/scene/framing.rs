//! Framing: where a camera stands so that a sphere just fills its view. `generate` places
//! its random cameras with it and `import` frames a whole table of cylinders with it, so
//! both agree on what "the scene fills the image" means.

use crate::rng::SplitMix64;
use crate::scene::camera::FovAxis;
use crate::scene::{CameraFile, CylinderFile};
use glam::DVec3;

/// The distance from which a sphere of `radius` just fills the smaller field of view of a
/// `width` × `height` image whose horizontal field of view is `fov_deg`: a sphere of
/// radius R fills a half angle a from R / sin(a).
pub fn fit_distance(radius: f64, fov_deg: f64, width: u32, height: u32) -> f64 {
    let aspect = width as f64 / height as f64;
    let tan_x = (fov_deg.to_radians() / 2.0).tan();
    let tan_small = tan_x.min(tan_x / aspect);
    let sin_small = tan_small / (1.0 + tan_small * tan_small).sqrt();
    radius / sin_small
}

/// The up hint for a camera looking along `forward`: +z (scenes stand on the xy plane),
/// or +y when the view is within about 6 degrees of vertical, where +z is unusable.
pub fn up_for(forward: DVec3) -> DVec3 {
    if forward.cross(DVec3::Z).length() > 0.1 {
        DVec3::Z
    } else {
        DVec3::Y
    }
}

/// A sphere holding every cylinder: centred on the box around their end centres, as large
/// as the farthest end centre plus its radius (a cylinder lies within its radius of the
/// segment between its ends, and the farthest point of a segment is one of its ends).
pub fn bounding_sphere(cylinders: &[CylinderFile]) -> (DVec3, f64) {
    let ends = || {
        cylinders.iter().flat_map(|c| {
            let base = c.p0.or(c.center).map(DVec3::from_array);
            let top = match (c.p1, c.center, c.axis, c.height) {
                (Some(p1), ..) => Some(DVec3::from_array(p1)),
                (None, Some(b), Some(a), Some(h)) => {
                    let a = DVec3::from_array(a);
                    Some(DVec3::from_array(b) + a / a.length() * h)
                }
                _ => None,
            };
            [base, top]
                .into_iter()
                .flatten()
                .map(move |p| (p, c.radius))
        })
    };
    let (lo, hi) = ends().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), (p, _)| (lo.min(p), hi.max(p)),
    );
    if !lo.is_finite() {
        return (DVec3::ZERO, 1.0);
    }
    let centre = (lo + hi) / 2.0;
    let radius = ends().fold(0.0f64, |m, (p, r)| m.max((p - centre).length() + r));
    (centre, radius)
}

/// The size and field of view of a framing camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
}

impl Default for Frame {
    fn default() -> Self {
        Frame {
            width: 640,
            height: 480,
            fov_deg: 50.0,
        }
    }
}

/// A pinhole camera looking at `centre` from direction `dir` (a unit vector from the
/// centre toward the camera) at the distance where a sphere of `radius` about `centre`
/// just fills the smaller field of view: everything inside the sphere is in the image.
/// The clip planes hold the whole sphere.
pub fn framed_camera(centre: DVec3, radius: f64, dir: DVec3, frame: Frame) -> CameraFile {
    framed_camera_at(centre, radius, dir, frame, 1.0)
}

/// [`framed_camera`] at `factor` times the fit distance (below 1 the sphere overfills the
/// view).
pub fn framed_camera_at(
    centre: DVec3,
    radius: f64,
    dir: DVec3,
    frame: Frame,
    factor: f64,
) -> CameraFile {
    let dist = fit_distance(radius, frame.fov_deg, frame.width, frame.height) * factor;
    let origin = centre + dir * dist;
    let gap = dist - radius;
    let near = if gap > 0.0 {
        0.01f64.min(0.5 * gap)
    } else {
        0.01
    };
    let far = (2.0 * (dist + radius)).max(10000.0);
    CameraFile {
        origin: origin.to_array(),
        target: centre.to_array(),
        up: up_for(-dir).to_array(),
        fov_deg: Some(frame.fov_deg),
        fov_axis: Some(FovAxis::X),
        width: frame.width,
        height: frame.height,
        near_clip: near,
        far_clip: far,
        ..CameraFile::default()
    }
}

/// The default view of an imported scene: from the -y side, 15 degrees above the
/// horizon (trees and most scanned scenes stand along +z).
pub fn default_view() -> DVec3 {
    let e = 15f64.to_radians();
    DVec3::new(0.0, -e.cos(), e.sin())
}

/// One camera framing all of `cylinders` from [`default_view`].
pub fn frame_all(cylinders: &[CylinderFile], frame: Frame) -> CameraFile {
    let (centre, radius) = bounding_sphere(cylinders);
    framed_camera(centre, radius, default_view(), frame)
}

/// A unit direction drawn area-uniformly from the band of the sphere between elevations
/// `lo_deg` and `hi_deg` (Archimedes: z uniform in the band is area-uniform), from two
/// draws of `rng`: z, then the azimuth.
pub fn band_direction(rng: &mut SplitMix64, lo_deg: f64, hi_deg: f64) -> DVec3 {
    let (z_lo, z_hi) = (lo_deg.to_radians().sin(), hi_deg.to_radians().sin());
    let z = z_lo + (z_hi - z_lo) * rng.unit();
    let (cx, cy) = rng.unit_circle();
    let s = (1.0 - z * z).max(0.0).sqrt();
    DVec3::new(s * cx, s * cy, z)
}

/// Camera `k` of `count` on the orbit of `first`: its offset from the target turned about
/// +z by `k · 360° / count` (same target, distance and height; the same up rule).
pub fn orbit(first: &CameraFile, k: u32, count: u32) -> CameraFile {
    let target = DVec3::from_array(first.target);
    let v = DVec3::from_array(first.origin) - target;
    let a = std::f64::consts::TAU * k as f64 / count as f64;
    let (s, c) = a.sin_cos();
    let origin = target + DVec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z);
    let up = up_for((target - origin).normalize());
    CameraFile {
        origin: origin.to_array(),
        up: up.to_array(),
        ..first.clone()
    }
}
