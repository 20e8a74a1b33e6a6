//! Camera rigs: `"cameras": {"orbit": {...}}` or `{"sphere": {...}}` in a scene file, many
//! cameras around whatever cylinders the scene holds, resolved deterministically with
//! `generate`'s own draws ([`crate::scene::framing`]).
//!
//! - `orbit`: camera 0's direction is drawn area-uniformly from the elevation band
//!   (`SplitMix64::for_item(seed, 0)`), cameras 1, 2, … are it turned about +z by
//!   `k · 360° / count` (`generate --orbit`).
//! - `sphere`: camera `k`'s direction is drawn area-uniformly from the band with
//!   `SplitMix64::for_item(seed, k)`.
//!
//! Every camera looks at the centre of the sphere holding the cylinders, from `distance`
//! times the distance at which that sphere just fills the smaller field of view (`"fit"`
//! = 1).

use crate::rng::SplitMix64;
use crate::scene::framing::{
    Frame, band_direction, bounding_sphere, fit_distance, framed_camera_at, orbit,
};
use crate::scene::{CameraFile, CylinderFile, MAX_COORD, SceneError, err, num};
use serde::{Deserialize, Serialize};

/// Most cameras one rig makes.
pub const MAX_RIG_CAMERAS: u32 = 100_000;

/// `"cameras": {"orbit": {...}}` or `{"sphere": {...}}`: exactly one.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraRig {
    /// Cameras on one orbit about +z.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orbit: Option<RigSpec>,
    /// Cameras in directions drawn area-uniformly from the elevation band.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sphere: Option<RigSpec>,
}

/// A rig's cameras.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigSpec {
    /// How many cameras, 1..=[`MAX_RIG_CAMERAS`].
    pub count: u32,
    /// Elevation band above the xy plane, degrees, within -85..85; default `[-20, 60]`.
    #[serde(default = "default_elevation")]
    pub elevation_deg: [f64; 2],
    /// `"fit"` (default) or a factor of the fit distance.
    #[serde(default)]
    pub distance: Distance,
    /// The seed of the draws; default 0.
    #[serde(default)]
    pub seed: u64,
    /// Image width; default 640.
    #[serde(default = "default_width")]
    pub width: u32,
    /// Image height; default 480.
    #[serde(default = "default_height")]
    pub height: u32,
    /// Horizontal field of view, degrees; default 50.
    #[serde(default = "default_fov")]
    pub fov_deg: f64,
}

/// `"fit"` or a factor of the fit distance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Distance {
    /// A word: only `"fit"` is one.
    Word(String),
    /// A factor of the fit distance.
    Factor(f64),
}

impl Default for Distance {
    fn default() -> Self {
        Distance::Word("fit".into())
    }
}

fn default_elevation() -> [f64; 2] {
    [-20.0, 60.0]
}
fn default_width() -> u32 {
    640
}
fn default_height() -> u32 {
    480
}
fn default_fov() -> f64 {
    50.0
}

impl RigSpec {
    /// The rig's defaults with `count` cameras.
    pub fn new(count: u32) -> RigSpec {
        RigSpec {
            count,
            elevation_deg: default_elevation(),
            distance: Distance::default(),
            seed: 0,
            width: default_width(),
            height: default_height(),
            fov_deg: default_fov(),
        }
    }
}

impl CameraRig {
    /// The cameras of this rig around `cylinders`; errors name the field under `at`
    /// (`cameras`).
    pub fn resolve(
        &self,
        cylinders: &[CylinderFile],
        at: &str,
    ) -> Result<Vec<CameraFile>, SceneError> {
        let (kind, spec, is_orbit) = match (&self.orbit, &self.sphere) {
            (Some(s), None) => ("orbit", s, true),
            (None, Some(s)) => ("sphere", s, false),
            _ => {
                return Err(err(
                    at,
                    "give exactly one of \"orbit\": {...} and \"sphere\": {...}",
                ));
            }
        };
        let f = |name: &str| format!("{at}.{kind}.{name}");
        if spec.count == 0 || spec.count > MAX_RIG_CAMERAS {
            return Err(err(
                f("count"),
                format!("must be in 1..={MAX_RIG_CAMERAS}, got {}", spec.count),
            ));
        }
        let [lo, hi] = spec.elevation_deg;
        if !(lo.is_finite() && hi.is_finite() && -85.0 <= lo && lo <= hi && hi <= 85.0) {
            return Err(err(
                f("elevation_deg"),
                format!(
                    "must be [low, high] with -85 <= low <= high <= 85 (the up hint is +z), got [{}, {}]",
                    num(lo),
                    num(hi)
                ),
            ));
        }
        let factor = match &spec.distance {
            Distance::Word(w) if w == "fit" => 1.0,
            Distance::Factor(x) if x.is_finite() && *x > 0.0 && *x <= 1e6 => *x,
            Distance::Word(w) => {
                return Err(err(
                    f("distance"),
                    format!(
                        "must be \"fit\" or a factor of the fit distance in (0, 1e6], got {:?}",
                        crate::scene::strict::shorten(w)
                    ),
                ));
            }
            Distance::Factor(x) => {
                return Err(err(
                    f("distance"),
                    format!(
                        "must be \"fit\" or a factor of the fit distance in (0, 1e6], got {}",
                        num(*x)
                    ),
                ));
            }
        };
        if !(spec.fov_deg > 0.0 && spec.fov_deg < 180.0) {
            return Err(err(
                f("fov_deg"),
                format!("must be in (0, 180), got {}", num(spec.fov_deg)),
            ));
        }
        let frame = Frame {
            width: spec.width,
            height: spec.height,
            fov_deg: spec.fov_deg,
        };
        let (centre, radius) = bounding_sphere(cylinders);
        // Where the cameras stand, checked here so the message names the rig's fields
        // rather than the origin they produce: within a camera origin's bound, and far
        // enough from the centre to differ from it (4 ulps of its largest coordinate).
        let dist = fit_distance(radius, spec.fov_deg, spec.width, spec.height) * factor;
        let centre_max = centre.abs().max_element();
        let reach = centre_max + dist;
        if !reach.is_finite() || reach > MAX_COORD {
            return Err(err(
                f("fov_deg"),
                format!(
                    "{} puts the cameras {} from the cylinders' centre, past the \
                     {MAX_COORD:e} a camera's origin may reach: widen the field of view or \
                     lower the distance factor",
                    num(spec.fov_deg),
                    num(dist)
                ),
            ));
        }
        if dist.is_nan() || dist <= 4.0 * f64::EPSILON * centre_max {
            return Err(err(
                f("distance"),
                format!(
                    "a factor of {} puts the cameras {} from the cylinders' centre, too close \
                     to tell from it",
                    num(factor),
                    num(dist)
                ),
            ));
        }
        let camera = |k: u32| {
            let mut rng = SplitMix64::for_item(spec.seed, k as u64);
            let dir = band_direction(&mut rng, lo, hi);
            framed_camera_at(centre, radius, dir, frame, factor)
        };
        Ok(if is_orbit {
            let first = camera(0);
            (0..spec.count)
                .map(|k| {
                    if k == 0 {
                        first.clone()
                    } else {
                        orbit(&first, k, spec.count)
                    }
                })
                .collect()
        } else {
            (0..spec.count).map(camera).collect()
        })
    }
}
