//! Procedural scenes for datasets (`cylaov generate`): a seeded, hand-written random stream
//! and the sampling of cylinders and cameras. Pure: IO lives in `commands::generate`.
//!
//! **Determinism invariant**: view `i` of seed `s` depends only on `(s, i)` and the
//! options, through [`SplitMix64`] (`crate::rng`, written out: no crate whose stream could
//! change under us) and [`SplitMix64::for_item`], and every number is produced by IEEE-754 operations with a defined result
//! (`+ - * /`, `sqrt`; the one transcendental is `tan(fov/2)` and `sin` of the elevation
//! bounds, once per run). The same command therefore gives the same files, byte for byte
//! (serde_json prints every f64 as its shortest round-trip form).
//!
//! | option | default | meaning |
//! |---|---|---|
//! | `cylinders` | `8..32` | cylinder count per scene, inclusive range or one number |
//! | `radius` | `0.05..0.3` | radius, uniform |
//! | `length` | `0.2..2` | height (`p0`→`p1` distance), uniform |
//! | `volume` | `2,2,1` | half extents of the box, centred at the origin, holding the cylinders' midpoints |
//! | `caps_prob` | `0.8` | probability that a cylinder is closed by caps |
//! | `width`, `height` | `320`, `240` | image size |
//! | `fov` | `50` | horizontal field of view in degrees (`fov_axis` x) |
//! | `elevation` | `-20..60` | camera elevation above the xy plane, degrees; directions uniform over that band of the sphere |
//! | `distance` | `0.55..0.9` | camera distance in units of the fit distance (at 1 the bounding sphere of every possible cylinder just fills the smaller fov; the cylinders' midpoints fill far less) |
//! | `views_per_scene` | `1` | cameras per scene; with more than one the file has `"cameras"` |
//! | `orbit` | `false` | cameras 1, 2, … on camera 0's orbit (same target, distance and height, azimuth stepped by 360°/V) instead of drawn at random |
//!
//! **Several views of one scene.** Camera 0 is drawn exactly as a one-camera scene's (same
//! stream position), and cameras 1, 2, … are drawn after it from the same stream and the
//! same distributions, so `views_per_scene = 1` gives the same bytes as before the option
//! existed, and camera 0 of a V-camera scene is the camera of the one-camera scene.

use crate::rng::SplitMix64;
use crate::scene::camera::FovAxis;
use crate::scene::camera::model::{CameraModel, ModelFields};
use crate::scene::framing::{band_direction, fit_distance, orbit, up_for};
use crate::scene::{self, CameraFile, CylinderFile, SceneFile};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::fmt;

/// Uniform in `[r.min, r.max]` (`r.min` when the range is one point).
fn uniform(rng: &mut SplitMix64, r: Range) -> f64 {
    rng.range(r.min, r.max)
}

/// A closed interval of reals, written `A..B` or as one number `A`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RangeRepr", into = "RangeRepr")]
pub struct Range {
    /// Lower end, inclusive.
    pub min: f64,
    /// Upper end, inclusive; >= `min`.
    pub max: f64,
}

impl Range {
    /// The interval `[min, max]`, unchecked.
    pub const fn new(min: f64, max: f64) -> Self {
        Range { min, max }
    }

    /// Parse `A..B` or `A`.
    pub fn parse(s: &str) -> Result<Range, String> {
        let num = |t: &str| -> Result<f64, String> {
            let t = t.trim();
            let x: f64 = t
                .parse()
                .map_err(|_| format!("expected a number or MIN..MAX, got {s:?}"))?;
            if !x.is_finite() {
                return Err(format!("must be finite, got {s:?}"));
            }
            Ok(x)
        };
        let r = match s.split_once("..") {
            // `A...B` would read B as `.B`, a tenth of what a typo meant.
            Some((_, b)) if b.starts_with('.') => {
                return Err(format!("expected MIN..MAX with two dots, got {s:?}"));
            }
            Some((a, b)) => Range::new(num(a)?, num(b)?),
            None => {
                let x = num(s)?;
                Range::new(x, x)
            }
        };
        if r.min > r.max {
            return Err(format!("MIN must be <= MAX, got {s:?}"));
        }
        Ok(r)
    }
}

/// As a message shows it: `A..B`, or `A` when the ends agree, each end in exponent form
/// where plain would be a wall of digits (`1e300`).
impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use crate::scene::num;
        if self.min == self.max {
            write!(f, "{}", num(self.min))
        } else {
            write!(f, "{}..{}", num(self.min), num(self.max))
        }
    }
}

/// How a range may be written in a config file: `"A..B"`, `A`, or `[A, B]`.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum RangeRepr {
    Text(String),
    Number(f64),
    Pair([f64; 2]),
    /// Anything else, refused naming the value (an untagged enum's own error names none).
    Other(serde_json::Value),
}

impl TryFrom<RangeRepr> for Range {
    type Error = String;
    fn try_from(r: RangeRepr) -> Result<Range, String> {
        match r {
            RangeRepr::Text(s) => Range::parse(&s),
            RangeRepr::Number(x) => Range::parse(&x.to_string()),
            RangeRepr::Pair([a, b]) => Range::parse(&format!("{a}..{b}")),
            RangeRepr::Other(v) => Err(format!(
                "expected \"MIN..MAX\", a number or [MIN, MAX], got {}",
                crate::scene::strict::shorten(&v.to_string())
            )),
        }
    }
}

/// Written plain (`generate.json` keeps the bytes it always had), each end exact.
impl From<Range> for RangeRepr {
    fn from(r: Range) -> RangeRepr {
        RangeRepr::Text(if r.min == r.max {
            format!("{}", r.min)
        } else {
            format!("{}..{}", r.min, r.max)
        })
    }
}

/// The options that shape every scene; each can come from the config file or a flag.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GenerateOptions {
    /// Cylinders per scene: whole numbers, uniform in the range.
    pub cylinders: Range,
    /// Cylinder radius, world units, uniform.
    pub radius: Range,
    /// Cylinder height (`p0`→`p1` distance), world units, uniform.
    pub length: Range,
    /// Half extents of the placement box (centred at the origin).
    pub volume: [f64; 3],
    /// Probability that a cylinder is closed by caps, in [0, 1].
    pub caps_prob: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal field of view in degrees (`fov_axis` x).
    pub fov: f64,
    /// Camera elevation above the xy plane, degrees (directions uniform over that band).
    pub elevation: Range,
    /// Camera distance in fit distances (1: the sphere bounding all cylinders just fills the view).
    pub distance: Range,
    /// Cameras per scene (left out of `generate.json` when 1, so that file keeps its bytes).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub views_per_scene: u32,
    /// Cameras 1.. on camera 0's orbit (left out of `generate.json` when false).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub orbit: bool,
    /// The camera model of every view, with its parameters drawn per scene (left out of
    /// `generate.json` when `perspective`, so that file keeps its bytes).
    #[serde(default, skip_serializing_if = "is_perspective")]
    pub camera_model: CameraModel,
}

fn is_perspective(m: &CameraModel) -> bool {
    *m == CameraModel::Perspective
}

fn one() -> u32 {
    1
}
fn is_one(v: &u32) -> bool {
    *v == 1
}

/// Largest `views_per_scene`.
pub const MAX_VIEWS_PER_SCENE: u32 = 1000;

impl Default for GenerateOptions {
    fn default() -> Self {
        GenerateOptions {
            cylinders: Range::new(8.0, 32.0),
            radius: Range::new(0.05, 0.3),
            length: Range::new(0.2, 2.0),
            volume: [2.0, 2.0, 1.0],
            caps_prob: 0.8,
            width: 320,
            height: 240,
            fov: 50.0,
            elevation: Range::new(-20.0, 60.0),
            distance: Range::new(0.55, 0.9),
            views_per_scene: 1,
            orbit: false,
            camera_model: CameraModel::Perspective,
        }
    }
}

/// The config file: any subset of the options, same names as the long flags
/// (`caps_prob` for `--caps-prob`); ranges as `"A..B"`, `[A, B]` or one number.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfigFile {
    /// `--count`: number of scenes to write.
    pub count: Option<u64>,
    /// `--seed`: the random seed (default 0).
    pub seed: Option<u64>,
    /// `--cylinders`: [`GenerateOptions::cylinders`].
    pub cylinders: Option<Range>,
    /// `--radius`: [`GenerateOptions::radius`].
    pub radius: Option<Range>,
    /// `--length`: [`GenerateOptions::length`].
    pub length: Option<Range>,
    /// `--volume`: [`GenerateOptions::volume`].
    pub volume: Option<Volume>,
    /// `--caps-prob`: [`GenerateOptions::caps_prob`].
    pub caps_prob: Option<f64>,
    /// `--width`: [`GenerateOptions::width`].
    pub width: Option<u32>,
    /// `--height`: [`GenerateOptions::height`].
    pub height: Option<u32>,
    /// `--fov`: [`GenerateOptions::fov`].
    pub fov: Option<f64>,
    /// `--elevation`: [`GenerateOptions::elevation`].
    pub elevation: Option<Range>,
    /// `--distance`: [`GenerateOptions::distance`].
    pub distance: Option<Range>,
    /// `--views-per-scene`: [`GenerateOptions::views_per_scene`].
    pub views_per_scene: Option<u32>,
    /// `--orbit`: [`GenerateOptions::orbit`].
    pub orbit: Option<bool>,
    /// `--camera-model`: [`GenerateOptions::camera_model`].
    pub camera_model: Option<CameraModel>,
}

impl ConfigFile {
    /// Whether the file sets option `key` (a [`GenerateOptions`] field name).
    pub fn sets(&self, key: &str) -> bool {
        match key {
            "cylinders" => self.cylinders.is_some(),
            "radius" => self.radius.is_some(),
            "length" => self.length.is_some(),
            "volume" => self.volume.is_some(),
            "caps_prob" => self.caps_prob.is_some(),
            "width" => self.width.is_some(),
            "height" => self.height.is_some(),
            "fov" => self.fov.is_some(),
            "elevation" => self.elevation.is_some(),
            "distance" => self.distance.is_some(),
            "views_per_scene" => self.views_per_scene.is_some(),
            "orbit" => self.orbit.is_some(),
            "camera_model" => self.camera_model.is_some(),
            "count" => self.count.is_some(),
            "seed" => self.seed.is_some(),
            _ => false,
        }
    }
}

/// Half extents `X,Y,Z`, or one number for a cube.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(try_from = "VolumeRepr")]
pub struct Volume(pub [f64; 3]);

#[derive(Deserialize)]
#[serde(untagged)]
enum VolumeRepr {
    Text(String),
    Number(f64),
    Triple([f64; 3]),
    /// Anything else, refused naming the value.
    Other(serde_json::Value),
}

impl TryFrom<VolumeRepr> for Volume {
    type Error = String;
    fn try_from(v: VolumeRepr) -> Result<Volume, String> {
        match v {
            VolumeRepr::Text(s) => Volume::parse(&s),
            VolumeRepr::Number(x) => Ok(Volume([x; 3])),
            VolumeRepr::Triple(v) => Ok(Volume(v)),
            VolumeRepr::Other(v) => Err(format!(
                "expected \"X,Y,Z\", a number or [X, Y, Z] (half extents), got {}",
                crate::scene::strict::shorten(&v.to_string())
            )),
        }
    }
}

impl Volume {
    /// Parse `S` (a cube of half extent S) or `X,Y,Z`.
    pub fn parse(s: &str) -> Result<Volume, String> {
        let parts: Vec<f64> = s
            .split(',')
            .map(|t| t.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("expected S or X,Y,Z (half extents), got {s:?}"))?;
        match parts[..] {
            [x] => Ok(Volume([x; 3])),
            [x, y, z] => Ok(Volume([x, y, z])),
            _ => Err(format!("expected S or X,Y,Z (half extents), got {s:?}")),
        }
    }
}

/// Options that can make an invalid scene together, though each is valid alone: which
/// (config keys, as [`GenerateOptions::validate_together`] names them) and why.
#[derive(Clone, Debug, PartialEq)]
pub struct Conflict {
    /// The options the message names.
    pub keys: Vec<&'static str>,
    /// The message, naming each option and its value.
    pub message: String,
}

/// The farthest from its centre, in focal lengths, an `opencv` image's corner may lie (see
/// [`GenerateOptions::validate_together`]).
const OPENCV_MAX_CORNER: f64 = 0.7;

/// Shortest cylinder length (and orthographic half height) generate accepts at all.
const MIN_LENGTH: f64 = 1e-290;

/// Farthest the pinhole placement every camera model starts from may put a camera.
const MAX_PINHOLE_DISTANCE: f64 = 1e150;

/// How much closer than the farthest coordinate a camera may stand to its target.
const MIN_REL_DISTANCE: f64 = 1e-6;

/// Whether `x <= limit` (false when either is NaN: a NaN is never within a bound).
fn at_most(x: f64, limit: f64) -> bool {
    x <= limit
}

/// Largest cylinder count per generated scene.
pub const MAX_CYLINDERS: f64 = 1_000_000.0;

impl GenerateOptions {
    /// Overlay the options a config file sets.
    pub fn apply(&mut self, c: &ConfigFile) {
        macro_rules! take {
            ($($f:ident),*) => { $( if let Some(v) = c.$f { self.$f = v; } )* };
        }
        take!(
            cylinders,
            radius,
            length,
            caps_prob,
            width,
            height,
            fov,
            elevation,
            distance,
            views_per_scene,
            orbit,
            camera_model
        );
        if let Some(v) = c.volume {
            self.volume = v.0;
        }
    }

    /// Check every option; the error names the option (see [`crate::spelling`]) and the
    /// value.
    pub fn validate(&self) -> Result<(), String> {
        self.validate_naming(&crate::spelling::opt)
    }

    /// [`validate`](Self::validate), naming option `key` as `opt(key)`: a front end that
    /// read the value from a file names the file and its key.
    pub fn validate_naming(&self, opt: &dyn Fn(&str) -> String) -> Result<(), String> {
        self.validate_each_naming(opt)?;
        self.validate_together(opt).map_err(|c| c.message)
    }

    /// The checks of one option at a time (each option's own bounds), naming option `key`
    /// as `opt(key)`; [`validate_together`](Self::validate_together) checks the options
    /// that only together can make an invalid scene.
    pub fn validate_each_naming(&self, opt: &dyn Fn(&str) -> String) -> Result<(), String> {
        let c = self.cylinders;
        if c.min < 1.0 || c.max > MAX_CYLINDERS || c.min.fract() != 0.0 || c.max.fract() != 0.0 {
            return Err(format!(
                "{}: must be whole numbers in 1..={MAX_CYLINDERS}, got {c}",
                opt("cylinders")
            ));
        }
        for (key, r) in [("radius", self.radius), ("length", self.length)] {
            if r.min <= 0.0 || r.max > scene::MAX_COORD {
                return Err(format!(
                    "{}: must be > 0 and <= {:e}, got {r}",
                    opt(key),
                    scene::MAX_COORD
                ));
            }
        }
        if self
            .volume
            .iter()
            .any(|v| !v.is_finite() || *v < 0.0 || *v > scene::MAX_COORD)
        {
            return Err(format!(
                "{}: half extents must be in [0, {:e}], got {:?}",
                opt("volume"),
                scene::MAX_COORD,
                self.volume
            ));
        }
        if !(0.0..=1.0).contains(&self.caps_prob) {
            return Err(format!(
                "{}: must be in [0, 1], got {}",
                opt("caps_prob"),
                self.caps_prob
            ));
        }
        for (key, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > scene::MAX_SIDE {
                return Err(format!(
                    "{}: must be in 1..={}, got {v}",
                    opt(key),
                    scene::MAX_SIDE
                ));
            }
        }
        if !(self.fov > 0.0 && self.fov < 180.0) {
            return Err(format!(
                "{}: must be in (0, 180), got {}",
                opt("fov"),
                self.fov
            ));
        }
        let e = self.elevation;
        if e.min < -85.0 || e.max > 85.0 {
            return Err(format!(
                "{}: must lie in -85..85 degrees (the camera's up is +z), got {e}",
                opt("elevation")
            ));
        }
        let d = self.distance;
        if d.min <= 0.0 || d.max > 1e6 {
            return Err(format!(
                "{}: must be > 0 and <= 1e6, got {d}",
                opt("distance")
            ));
        }
        let v = self.views_per_scene;
        if v == 0 || v > MAX_VIEWS_PER_SCENE {
            return Err(format!(
                "{}: must be in 1..={MAX_VIEWS_PER_SCENE}, got {v}",
                opt("views_per_scene")
            ));
        }
        Ok(())
    }

    /// The checks of options that only together can make an invalid scene (a camera or a
    /// cylinder end beyond [`scene::MAX_COORD`], ends that round to one point, an image
    /// over [`scene::MAX_PIXELS`], a lens that folds over): refused here, before anything
    /// is written, rather than at the scene (and seed) that first hits them. Options that
    /// pass these and [`validate_each_naming`](Self::validate_each_naming) give a valid
    /// scene for every seed and index. The error lists the options it is about.
    /// Expects options that pass `validate_each_naming`.
    pub fn validate_together(&self, opt: &dyn Fn(&str) -> String) -> Result<(), Conflict> {
        let conflict = |keys: &[&'static str], why: String| {
            let named: Vec<String> = keys
                .iter()
                .map(|k| format!("{} {}", opt(k), self.value_text(k)))
                .collect();
            Err(Conflict {
                keys: keys.to_vec(),
                message: format!("{}: {why}", named.join(", ")),
            })
        };
        let (w, h) = (self.width, self.height);
        let (wf, hf) = (w as f64, h as f64);
        // Every camera model: the image size a scene file may have.
        let pixels = w as u64 * h as u64;
        if pixels > scene::MAX_PIXELS {
            return conflict(
                &["width", "height"],
                format!(
                    "width × height must be <= {} pixels (64 megapixels, e.g. 8192 × 8192), \
                        got {pixels}",
                    scene::MAX_PIXELS
                ),
            );
        }
        let model = self.camera_model;
        // The fisheye's focal length is diagonal / π and it moves by the ratio of the fit
        // distances, sin(pinhole half angle) / sin(θ at the shorter side's edge): both need
        // (w−1) and (h−1) > 0.
        if model == CameraModel::OpencvFisheye && (w < 2 || h < 2) {
            return conflict(
                &["camera_model", "width", "height"],
                "an opencv_fisheye image needs width and height >= 2 (its focal length and \
                    framing are set by the pixels from the centre to the edges)"
                    .into(),
            );
        }
        // The pinhole's focal length in pixels, as a scene file's camera is checked (the
        // perspective and opencv models use the --fov one): w/2 / tan(fov/2), at most
        // f32::MAX.
        let tan_x = (self.fov.to_radians() / 2.0).tan();
        let focal = wf / 2.0 / tan_x;
        if model != CameraModel::OpencvFisheye
            && model != CameraModel::Orthographic
            && model != CameraModel::Equirectangular
            && !(tan_x > 0.0 && focal <= f32::MAX as f64)
        {
            return conflict(
                &["fov", "width"],
                format!(
                    "the focal length of {} px is beyond the {:e} a camera may have",
                    scene::num(focal),
                    f32::MAX
                ),
            );
        }
        // opencv: the distortion is drawn with k1 in [-0.25, 0.05], k2 in ±0.02, p1, p2 in
        // ±1e-3 (k3 = 0). The radial slope 1 + 3 k1 ρ² + 5 k2 ρ⁴ is smallest at k1 = -0.25,
        // k2 = -0.02, where it reaches 0 at ρ² = 1.155 and the distorted radius peaks at
        // 0.736: an image whose corner lies further out (in focal lengths) folds over for
        // some draws. The corner must lie within 0.7 (there the worst slope is 0.34, far
        // above the < 0.01 the tangential terms can take away).
        if model == CameraModel::Opencv {
            let corner = (wf - 1.0).hypot(hf - 1.0) / 2.0 / focal;
            if !at_most(corner, OPENCV_MAX_CORNER) {
                return conflict(
                    &["camera_model", "fov", "width", "height"],
                    format!(
                        "the image corners lie {} focal lengths from the centre, beyond the \
                            {OPENCV_MAX_CORNER} where some drawn distortions (k1 down to -0.25) \
                         fold over: narrow the field of view",
                        scene::num(corner)
                    ),
                );
            }
        }
        let vol = self.volume;
        let max_vol = vol[0].max(vol[1]).max(vol[2]);
        // Cylinders: the midpoint has |mid_k| <= volume_k (exactly: |2u − 1| <= 1), the ends
        // lie half a length along a unit axis from it, so |end_k| <= volume_k + length/2;
        // 1e-12 of relative room covers the rounding of the ends and of the top the scene
        // check recomputes from p0 and the height.
        let reach = max_vol + self.length.max / 2.0;
        if !at_most(reach, scene::MAX_COORD * (1.0 - 1e-12)) {
            return conflict(
                &["volume", "length"],
                format!(
                    "cylinder ends can lie {} from the origin, beyond the {:e} a coordinate \
                        may reach",
                    scene::num(reach),
                    scene::MAX_COORD
                ),
            );
        }
        // Ends that round to one point make no cylinder (the scene check wants p1 − p0 of
        // length > 0). The unit axis has a component of at least 1/√3, so the ends differ
        // by at least 2 · length/2 / √3 in it, around a midpoint of magnitude at most
        // max(volume); that rounds apart when it is over 2 ulp (ulp(x) <= 2ε|x|) of the
        // largest coordinate: length >= 4√3 ε · max(volume). Asked here with a margin,
        // length >= 16 ε · max(volume), and at least 1e-290 (half of it normal, and the
        // difference's square not lost below the normal range).
        let min_length = (16.0 * f64::EPSILON * max_vol).max(MIN_LENGTH);
        if self.length.min < min_length {
            return conflict(
                &["length", "volume"],
                format!(
                    "a cylinder this short has ends that round to one point this far from \
                        the origin: the length must be >= {} (16 × 2^-52 × the largest half \
                         extent, and >= {MIN_LENGTH:e})",
                    scene::num(min_length)
                ),
            );
        }
        // Cameras. The target is jitter · volume / 4 with |jitter_k| <= 1, so |target_k| <=
        // volume_k / 4. Every camera stands at distance D from its target (orbit cameras
        // too: a turn about +z keeps the offset's length), so |origin_k| <= max(volume)/4 +
        // D. D = fit · d for d drawn from --distance (fit = R / sin(smaller half angle), R
        // the bounding radius), times the fisheye's ratio of fit distances, or 1/5 of it for
        // equirectangular; orthographic cameras stand at 2R whatever d is.
        let r = self.bounding_radius();
        let fit = fit_distance(r, self.fov, w, h);
        let d = self.distance;
        let (lo, hi) = match model {
            CameraModel::Orthographic => (2.0 * r, 2.0 * r),
            CameraModel::Equirectangular => (fit * d.min * 0.2, fit * d.max * 0.2),
            CameraModel::OpencvFisheye => {
                let s = self.fisheye_scale();
                (fit * d.min * s, fit * d.max * s)
            }
            CameraModel::Perspective | CameraModel::Opencv => (fit * d.min, fit * d.max),
        };
        let camera_keys: &[&'static str] = &[
            "volume",
            "length",
            "radius",
            "fov",
            "distance",
            "width",
            "height",
            "camera_model",
        ];
        // Every model's camera is first drawn as the pinhole's, at fit · d, then moved
        // along its offset from the target (which is normalised: its square must stay
        // finite, so that pinhole distance is asked to be <= 1e150). Both placements must
        // pass the checks below: coordinates within their limit, and a camera apart from
        // its target by far more than the rounding of its coordinates (<= ε · far per
        // component; asked >= 1e-6 · far), so that origin ≠ target and the view direction
        // is the drawn one to within ~1e-9 (the up vector was chosen at > 0.1 from it),
        // and by at least 1e-100, so that squared lengths stay normal. 1e-9 of relative
        // room covers the rounding of the distance and the placement.
        let placements = [
            (fit * d.min, fit * d.max, MAX_PINHOLE_DISTANCE),
            (lo, hi, scene::MAX_COORD),
        ];
        for (lo, hi, limit) in placements {
            let far = max_vol / 4.0 + hi * (1.0 + 1e-9);
            if !at_most(far, limit) {
                return conflict(
                    camera_keys,
                    format!(
                        "cameras can stand {} from the origin, beyond the {:e} a coordinate \
                         may reach (the scene's bounding radius is {}, the distance at which \
                         it fills the view {})",
                        scene::num(far),
                        limit,
                        scene::num(r),
                        scene::num(fit)
                    ),
                );
            }
            let near = (far * MIN_REL_DISTANCE).max(1e-100);
            if !at_most(near, lo) {
                return conflict(
                    camera_keys,
                    format!(
                        "cameras can stand as close as {} to what they look at, too close to \
                         tell from it at coordinates up to {} (at least {} is needed)",
                        scene::num(lo),
                        scene::num(far),
                        scene::num(near)
                    ),
                );
            }
        }
        // far_clip = 2 (D + R) (6R orthographic): finite under the bounds above.
        if model == CameraModel::Orthographic {
            // ortho_width = 2R · d · max(aspect, 1): a pixel step of 2R·d / min(w, h) must
            // exceed the spacing 4ε · max|origin_k| <= 4ε (max(volume)/4 + 2R), asked
            // with a factor 4 of room; half the height, R·d·max(1, 1/aspect) >= R·d, must
            // be normal (asked >= 1e-290), and the width at most MAX_COORD.
            let width_max = 2.0 * r * d.max * (wf / hf).max(1.0);
            if !at_most(width_max, scene::MAX_COORD * (1.0 - 1e-9)) {
                return conflict(
                    &["volume", "length", "radius", "distance", "width", "height"],
                    format!(
                        "the orthographic view can be {} wide, beyond {:e}",
                        scene::num(width_max),
                        scene::MAX_COORD
                    ),
                );
            }
            let step = 2.0 * r * d.min / wf.min(hf);
            let spacing = 16.0 * f64::EPSILON * (max_vol / 4.0 + 2.0 * r);
            if !(step > spacing && r * d.min >= MIN_LENGTH) {
                return conflict(
                    &["distance", "width", "height", "volume"],
                    format!(
                        "an orthographic pixel can be {} wide, too small to tell apart at \
                            coordinates up to {} (more than {} is needed)",
                        scene::num(step),
                        scene::num(max_vol / 4.0 + 2.0 * r),
                        scene::num(spacing)
                    ),
                );
            }
        }
        Ok(())
    }

    /// Option `key`'s value as a message shows it.
    fn value_text(&self, key: &str) -> String {
        use crate::scene::num;
        match key {
            "cylinders" => self.cylinders.to_string(),
            "radius" => self.radius.to_string(),
            "length" => self.length.to_string(),
            "volume" => self.volume.map(num).join(","),
            "caps_prob" => num(self.caps_prob),
            "width" => self.width.to_string(),
            "height" => self.height.to_string(),
            "fov" => num(self.fov),
            "elevation" => self.elevation.to_string(),
            "distance" => self.distance.to_string(),
            "views_per_scene" => self.views_per_scene.to_string(),
            "orbit" => self.orbit.to_string(),
            "camera_model" => self.camera_model.name().to_string(),
            _ => String::new(),
        }
    }

    /// The factor a fisheye camera's distance is scaled by: the ratio R / sin(a) of the
    /// fit distances of the `--fov` pinhole and the fisheye, at their smaller half angles.
    /// The fisheye's is θ_d at the middle of the shorter side's edge (θ ≈ θ_d: the drawn
    /// k move it by under 2%).
    fn fisheye_scale(&self) -> f64 {
        let (w, h) = (self.width as f64, self.height as f64);
        let f = (w - 1.0).hypot(h - 1.0) / std::f64::consts::PI;
        let theta = ((w.min(h) - 1.0) / 2.0 / f).min(std::f64::consts::FRAC_PI_2);
        let tan_x = (self.fov.to_radians() / 2.0).tan();
        let pinhole = (tan_x.min(tan_x * h / w)).atan();
        pinhole.sin() / theta.sin()
    }

    /// Radius of a sphere about the origin that holds every cylinder any scene can have.
    fn bounding_radius(&self) -> f64 {
        DVec3::from_array(self.volume).length() + self.length.max / 2.0 + self.radius.max
    }

    /// Generate view `index` of `seed`: a complete scene file, validated.
    pub fn scene(&self, seed: u64, index: u64) -> Result<SceneFile, String> {
        let mut rng = SplitMix64::for_item(seed, index);
        let volume = DVec3::from_array(self.volume);

        // Place the cylinders: midpoint in the box, axis uniform on the sphere.
        let count = rng.int_in(self.cylinders.min as u32, self.cylinders.max as u32);
        let mut cylinders = Vec::with_capacity(count as usize);
        for _ in 0..count {
            let unit = DVec3::new(rng.unit(), rng.unit(), rng.unit());
            let mid = (unit * 2.0 - 1.0) * volume;
            let axis = rng.unit_vector();
            let half = uniform(&mut rng, self.length) / 2.0;
            let radius = uniform(&mut rng, self.radius);
            let caps = rng.unit() < self.caps_prob;
            cylinders.push(CylinderFile {
                p0: Some((mid - axis * half).to_array()),
                p1: Some((mid + axis * half).to_array()),
                radius,
                caps,
                ..CylinderFile::default()
            });
        }

        // Camera 0 first, exactly where a one-camera scene draws its camera.
        let mut cameras: Vec<CameraFile> = Vec::new();
        for k in 0..self.views_per_scene {
            let cam = match cameras.first() {
                Some(first) if self.orbit => orbit(first, k, self.views_per_scene),
                _ => self.camera(&mut rng),
            };
            cameras.push(cam);
        }
        if self.camera_model != CameraModel::Perspective {
            // Its own stream: the cylinders and camera poses are those of the same seed
            // with the perspective model, only the lens differs.
            let mut lens_rng = SplitMix64::for_item(seed ^ LENS_STREAM, index);
            let lens = self.lens(&mut lens_rng);
            for cam in &mut cameras {
                self.apply_lens(&lens, cam);
            }
        }
        let (camera, cameras) = if cameras.len() == 1 {
            (cameras.pop(), None)
        } else {
            (None, Some(cameras))
        };
        let file = SceneFile {
            camera,
            cameras,
            cylinders,
            aovs: Some(scene::default_aovs()),
        };
        file.validate()
            .map_err(|e| format!("generated view {index} is invalid: {e}"))?;
        Ok(file)
    }
}

impl GenerateOptions {
    /// Draw one camera from `rng`.
    fn camera(&self, rng: &mut SplitMix64) -> CameraFile {
        let volume = DVec3::from_array(self.volume);
        // Place the camera: on a sphere around the scene, far enough that the bounding
        // sphere fits the smaller field of view at distance factor 1, looking at a point
        // near the centre.
        let fit = fit_distance(self.bounding_radius(), self.fov, self.width, self.height);
        let dist = fit * uniform(rng, self.distance);
        let dir = band_direction(rng, self.elevation.min, self.elevation.max);
        let jitter = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 2.0 - 1.0;
        let target = jitter * volume * 0.25;
        let origin = target + dir * dist;
        // The elevation bound keeps +z usable; fall back to +y if the jitter ever tilts
        // the view within ~6 degrees of it.
        let up = up_for((target - origin).normalize());
        let far = (2.0 * (dist + self.bounding_radius())).max(10000.0);
        CameraFile {
            origin: origin.to_array(),
            target: target.to_array(),
            up: up.to_array(),
            fov_deg: Some(self.fov),
            fov_axis: Some(FovAxis::X),
            width: self.width,
            height: self.height,
            near_clip: 0.01,
            far_clip: far,
            ..CameraFile::default()
        }
    }
}

/// Salt of the stream the lens parameters are drawn from (so the perspective stream, and
/// with it every perspective dataset, keeps its bytes).
const LENS_STREAM: u64 = 0x6c65_6e73_5f76_3031;

impl GenerateOptions {
    /// The camera model's parameters for one scene, drawn from `rng` (one draw per scene:
    /// every camera of a scene is the same lens, as on a rig). The ranges are those of
    /// real lenses: barrel distortion `k1` in [-0.25, 0.05] with a small `k2` and decentring
    /// `p1`, `p2` within ±1e-3 for `opencv`; for `opencv_fisheye` a full-frame fisheye whose
    /// diagonal spans 180° (`fx = diagonal / π`, so the corners need θ_d = π/2) with
    /// |k1| ≤ 0.02, |k2| ≤ 2e-3, |k3| ≤ 2e-4, |k4| ≤ 2e-5. Then for θ ≤ 1.9 the derivative
    /// dθ_d/dθ = 1 + 3k1θ² + 5k2θ⁴ + 7k3θ⁶ + 9k4θ⁸ stays ≥ 1 − 0.45 > 0, and θ_d(1.9) ≥
    /// 1.69 > π/2, so every draw is monotonic out to the corners. The `orthographic` view
    /// spans the bounding sphere times a `--distance` factor across its smaller side.
    fn lens(&self, rng: &mut SplitMix64) -> ModelFields {
        let (w, h) = (self.width as f64, self.height as f64);
        // OpenCV puts pixel centres at integers: the image centre is ((w−1)/2, (h−1)/2).
        let (cx, cy) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
        let blank = ModelFields::default();
        match self.camera_model {
            CameraModel::Perspective | CameraModel::Equirectangular => blank,
            CameraModel::Orthographic => {
                let aspect = w / h;
                let across_small = 2.0 * self.bounding_radius() * uniform(rng, self.distance);
                ModelFields {
                    ortho_width: Some(across_small * aspect.max(1.0)),
                    ..blank
                }
            }
            CameraModel::Opencv => {
                // The focal length of the `--fov` pinhole, so the framing is the same.
                let f = (w / 2.0) / (self.fov.to_radians() / 2.0).tan();
                // Drawn in this order: k1, k2, p1, p2.
                let (k1, k2) = (rng.range(-0.25, 0.05), rng.range(-0.02, 0.02));
                let (p1, p2) = (rng.range(-1e-3, 1e-3), rng.range(-1e-3, 1e-3));
                ModelFields {
                    intrinsics: [Some(f), Some(f), Some(cx), Some(cy)],
                    k: [Some(k1), Some(k2), Some(0.0), None],
                    p: [Some(p1), Some(p2)],
                    ..blank
                }
            }
            CameraModel::OpencvFisheye => {
                // The corner pixel centres lie (w−1)/2, (h−1)/2 from (cx, cy).
                let f = (w - 1.0).hypot(h - 1.0) / std::f64::consts::PI;
                ModelFields {
                    intrinsics: [Some(f), Some(f), Some(cx), Some(cy)],
                    k: [
                        Some(rng.range(-0.02, 0.02)),
                        Some(rng.range(-2e-3, 2e-3)),
                        Some(rng.range(-2e-4, 2e-4)),
                        Some(rng.range(-2e-5, 2e-5)),
                    ],
                    ..blank
                }
            }
        }
    }

    /// Give `cam` (a perspective camera drawn as usual) this run's model and the
    /// parameters `lens`.
    /// A fisheye camera moves closer along its view, by the ratio of the fit distances; an
    /// equirectangular one to a fifth of its distance, among the cylinders.
    /// An orthographic camera is moved back along its view direction to twice the
    /// bounding radius from its target, so nothing of the scene lies behind its image
    /// plane.
    fn apply_lens(&self, lens: &ModelFields, cam: &mut CameraFile) {
        let model = self.camera_model;
        *cam = CameraFile {
            fov_deg: None,
            fov_axis: None,
            ..cam.clone()
        }
        .with_model(model, lens);
        if let (CameraModel::OpencvFisheye, Some(_)) = (model, lens.intrinsics[0]) {
            // The pose was drawn to fit the `--fov` pinhole; bring the camera closer by the
            // ratio of the fit distances R / sin(a) of the two smaller half angles, so the
            // scene fills the fisheye's view as much. The fisheye's is θ_d at the middle of
            // the shorter side's edge (θ ≈ θ_d: the drawn k move it by under 2%).
            let scale = self.fisheye_scale();
            let target = DVec3::from_array(cam.target);
            cam.origin = (target + (DVec3::from_array(cam.origin) - target) * scale).to_array();
        }
        if model == CameraModel::Equirectangular {
            // A panorama sees every direction: taken from among the cylinders (a fifth of
            // the drawn distance from the target) rather than from outside the scene,
            // where the scene is a small patch of the sphere.
            let target = DVec3::from_array(cam.target);
            cam.origin = (target + (DVec3::from_array(cam.origin) - target) * 0.2).to_array();
        }
        if model == CameraModel::Orthographic {
            let r = self.bounding_radius();
            let target = DVec3::from_array(cam.target);
            let back = (DVec3::from_array(cam.origin) - target).normalize();
            cam.origin = (target + back * (2.0 * r)).to_array();
            cam.far_clip = (6.0 * r).max(10000.0);
        }
    }
}

/// Pretty JSON with every array of plain values on one line (`[1.0, 2.0, 3.0]`): scene files
/// stay readable with one line per vector. Written by serde_json through [`VectorFormatter`],
/// so what counts as an array is serde's structure, never the text (a string such as
/// `"x[1,2]"` is written as it is).
pub fn to_json(value: &impl Serialize) -> serde_json::Result<String> {
    let mut out = Vec::new();
    value.serialize(&mut serde_json::Serializer::with_formatter(
        &mut out,
        VectorFormatter::default(),
    ))?;
    out.push(b'\n');
    String::from_utf8(out).map_err(serde::ser::Error::custom)
}

/// serde_json's pretty layout (two spaces a level), except that an array whose first element
/// is a number, bool or null is written on one line, `[a, b, c]` (arrays of strings, such as
/// `aovs`, keep one line per name, as they always had).
/// The layout of an array is decided at its first element, before anything of it is written.
#[derive(Default)]
pub struct VectorFormatter {
    /// Open arrays and objects, innermost last.
    open: Vec<Open>,
}

enum Open {
    /// An array: `None` until its first element shows whether it is a line of values,
    /// `first` while its next element is the first, `pending` between `begin_array_value`
    /// and the element itself.
    Array {
        inline: Option<bool>,
        first: bool,
        pending: bool,
    },
    /// An object, and whether it has a member yet.
    Object { members: bool },
}

impl VectorFormatter {
    fn indent<W: ?Sized + std::io::Write>(&self, w: &mut W) -> std::io::Result<()> {
        w.write_all(b"\n")?;
        for _ in 0..self.open.len() {
            w.write_all(b"  ")?;
        }
        Ok(())
    }

    /// Before an element of any kind: the separator its array's layout asks for. `one_line`:
    /// whether an array that starts with this element goes on one line.
    fn element<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        one_line: bool,
    ) -> std::io::Result<()> {
        let Some(Open::Array {
            inline,
            first,
            pending,
        }) = self.open.last_mut()
        else {
            return Ok(());
        };
        if !std::mem::take(pending) {
            return Ok(());
        }
        let first = std::mem::take(first);
        let inline = *inline.get_or_insert(one_line);
        if inline {
            if !first {
                w.write_all(b", ")?;
            }
            Ok(())
        } else {
            if !first {
                w.write_all(b",")?;
            }
            self.indent(w)
        }
    }
}

/// Scalars: the element separator, then serde_json's own (compact) text for the value.
macro_rules! scalar {
    ($($f:ident($t:ty)),*) => {$(
        fn $f<W: ?Sized + std::io::Write>(&mut self, w: &mut W, v: $t) -> std::io::Result<()> {
            self.element(w, true)?;
            serde_json::ser::CompactFormatter.$f(w, v)
        }
    )*};
}

impl serde_json::ser::Formatter for VectorFormatter {
    fn write_null<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        self.element(w, true)?;
        w.write_all(b"null")
    }
    scalar!(
        write_bool(bool),
        write_i8(i8),
        write_i16(i16),
        write_i32(i32),
        write_i64(i64),
        write_i128(i128),
        write_u8(u8),
        write_u16(u16),
        write_u32(u32),
        write_u64(u64),
        write_u128(u128),
        write_f32(f32),
        write_f64(f64),
        write_number_str(&str)
    );
    fn begin_string<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        self.element(w, false)?;
        w.write_all(b"\"")
    }
    fn begin_array<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        self.element(w, false)?;
        self.open.push(Open::Array {
            inline: None,
            first: true,
            pending: false,
        });
        w.write_all(b"[")
    }
    fn begin_array_value<W: ?Sized + std::io::Write>(
        &mut self,
        _w: &mut W,
        _first: bool,
    ) -> std::io::Result<()> {
        if let Some(Open::Array { pending, .. }) = self.open.last_mut() {
            *pending = true;
        }
        Ok(())
    }
    fn end_array_value<W: ?Sized + std::io::Write>(&mut self, _w: &mut W) -> std::io::Result<()> {
        Ok(())
    }
    fn end_array<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        if let Some(Open::Array {
            inline: Some(false),
            ..
        }) = self.open.pop()
        {
            self.indent(w)?;
        }
        w.write_all(b"]")
    }
    fn begin_object<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        self.element(w, false)?;
        self.open.push(Open::Object { members: false });
        w.write_all(b"{")
    }
    fn begin_object_key<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        if let Some(Open::Object { members }) = self.open.last_mut() {
            *members = true;
        }
        if !first {
            w.write_all(b",")?;
        }
        self.indent(w)
    }
    fn begin_object_value<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        w.write_all(b": ")
    }
    fn end_object<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        if let Some(Open::Object { members: true }) = self.open.pop() {
            self.indent(w)?;
        }
        w.write_all(b"}")
    }
}

/// The file name stem of view `index`: six digits, more when needed.
pub fn view_name(index: u64) -> String {
    format!("{index:06}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn to_json_puts_number_arrays_on_one_line_and_leaves_strings_alone() {
        let v = serde_json::json!({
            "p": [1.5, -2.0, 3e-7],
            "name": "x[1,2]",
            "names": ["a[1, 2]", "b"],
            "nested": [{"q": [0, 1]}, {"q": []}],
            "empty": {}
        });
        let text = to_json(&v).unwrap();
        assert_eq!(
            text,
            "{\n  \"empty\": {},\n  \"name\": \"x[1,2]\",\n  \"names\": [\n    \"a[1, 2]\",\n    \"b\"\n  ],\n  \"nested\": [\n    {\n      \"q\": [0, 1]\n    },\n    {\n      \"q\": []\n    }\n  ],\n  \"p\": [1.5, -2.0, 3e-7]\n}\n"
        );
        let back: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(back, v);
    }

    #[test]
    fn ranges_parse_and_reject() {
        assert_eq!(Range::parse("1..2"), Ok(Range::new(1.0, 2.0)));
        assert_eq!(Range::parse("3"), Ok(Range::new(3.0, 3.0)));
        assert!(
            Range::parse("2..1")
                .unwrap_err()
                .contains("MIN must be <= MAX")
        );
        assert!(Range::parse("x").is_err());
        assert!(Range::parse("nan").is_err());
        let c: ConfigFile =
            serde_json::from_str(r#"{"radius": [0.1, 0.2], "length": "1..3", "cylinders": 5}"#)
                .unwrap();
        assert_eq!(c.radius, Some(Range::new(0.1, 0.2)));
        assert_eq!(c.length, Some(Range::new(1.0, 3.0)));
        assert_eq!(c.cylinders, Some(Range::new(5.0, 5.0)));
    }

    #[test]
    fn scenes_are_valid_deterministic_and_in_range() {
        let o = GenerateOptions::default();
        for i in 0..50 {
            let a = serde_json::to_string(&o.scene(7, i).unwrap()).unwrap();
            let b = serde_json::to_string(&o.scene(7, i).unwrap()).unwrap();
            assert_eq!(a, b);
            let s = o.scene(7, i).unwrap().validate().unwrap();
            let n = s.cylinders.len() as f64;
            assert!((o.cylinders.min..=o.cylinders.max).contains(&n));
            for c in &s.cylinders {
                assert!((o.radius.min..=o.radius.max).contains(&c.radius));
                assert!((o.length.min - 1e-12..=o.length.max + 1e-12).contains(&c.height));
                let mid = c.base + c.axis * c.height / 2.0;
                for k in 0..3 {
                    assert!(mid[k].abs() <= o.volume[k] + 1e-12, "{mid:?}");
                }
            }
            // The camera sits outside the bounding sphere and looks at the scene.
            let cam = s.camera;
            assert!(cam.origin.length() > o.bounding_radius() * 0.9);
            let fwd = (cam.target - cam.origin).normalize();
            assert!(fwd.dot(-cam.origin.normalize()) > 0.9);
        }
        assert_ne!(
            serde_json::to_string(&o.scene(7, 0).unwrap()).unwrap(),
            serde_json::to_string(&o.scene(8, 0).unwrap()).unwrap()
        );
    }

    /// What an edge case sets, its range, and whether it searches up.
    type Edge = (&'static str, fn(&mut GenerateOptions, f64), f64, f64, bool);
    /// What a bad case sets.
    type Set = fn(&mut GenerateOptions);

    /// The largest (`up`) or smallest `x` in `[lo, hi]` for which `set(o, x)` passes
    /// `validate`, by bisection (`None` when none does).
    fn edge(
        base: &GenerateOptions,
        set: fn(&mut GenerateOptions, f64),
        lo: f64,
        hi: f64,
        up: bool,
    ) -> Option<GenerateOptions> {
        let with = |x: f64| {
            let mut o = base.clone();
            set(&mut o, x);
            o
        };
        let (mut good, mut bad) = if up { (lo, hi) } else { (hi, lo) };
        if with(good).validate().is_err() {
            return None;
        }
        // Bisect in the exponent and mantissa alike: the midpoint of the bit patterns.
        for _ in 0..200 {
            let mid = f64::from_bits((good.to_bits() + bad.to_bits()) / 2);
            if mid == good || mid == bad {
                break;
            }
            if with(mid).validate().is_ok() {
                good = mid;
            } else {
                bad = mid;
            }
        }
        Some(with(good))
    }

    #[test]
    fn options_at_the_edge_of_every_bound_give_valid_scenes() {
        use CameraModel::*;
        for model in [
            Perspective,
            Orthographic,
            Opencv,
            OpencvFisheye,
            Equirectangular,
        ] {
            let base = GenerateOptions {
                camera_model: model,
                cylinders: Range::new(1.0, 2.0),
                ..GenerateOptions::default()
            };
            let edges: [Edge; 7] = [
                (
                    "volume",
                    |o, x| o.volume = [x, x / 3.0, x / 7.0],
                    1.0,
                    1e12,
                    true,
                ),
                ("distance max", |o, x| o.distance.max = x, 1.0, 1e6, true),
                (
                    "distance min",
                    |o, x| o.distance.min = x,
                    1e-300,
                    0.55,
                    false,
                ),
                ("fov", |o, x| o.fov = x, 1e-300, 50.0, false),
                ("fov up", |o, x| o.fov = x, 1.0, 179.999, true),
                ("length", |o, x| o.length.min = x, 1e-300, 0.2, false),
                (
                    "length tiny volume",
                    |o, x| {
                        o.volume = [1e-3; 3];
                        o.length.min = x;
                    },
                    1e-300,
                    0.2,
                    false,
                ),
            ];
            for (what, set, lo, hi, up) in edges {
                let Some(o) = edge(&base, set, lo, hi, up) else {
                    continue;
                };
                for i in 0..40 {
                    if let Err(e) = o.scene(3, i) {
                        panic!("{model:?} at the {what} edge ({o:?}): {e}");
                    }
                }
            }
        }
    }

    #[test]
    fn options_that_make_invalid_scenes_are_refused_up_front() {
        let bad = |f: fn(&mut GenerateOptions)| {
            let mut o = GenerateOptions::default();
            f(&mut o);
            o.validate().unwrap_err()
        };
        let cases: [(Set, &str); 8] = [
            (
                |o| (o.width, o.height) = (16384, 16384),
                "width 16384, height 16384",
            ),
            (|o| o.volume = [1e12; 3], "volume"),
            (|o| o.volume = [2.2e11; 3], "cameras can stand"),
            (|o| o.fov = 1e-10, "fov 1e-10"),
            (|o| o.length = Range::new(1e-300, 1.0), "length 1e-300..1"),
            (
                |o| o.distance = Range::new(1e-300, 1.0),
                "distance 1e-300..1",
            ),
            (
                |o| (o.camera_model, o.fov) = (CameraModel::Opencv, 120.0),
                "fold over",
            ),
            (
                |o| (o.camera_model, o.height) = (CameraModel::OpencvFisheye, 1),
                "width and height >= 2",
            ),
        ];
        for (f, needle) in cases {
            let e = bad(f);
            assert!(e.contains(needle), "{e}");
            assert!(!e.contains("generated view"), "{e}");
        }
    }

    #[test]
    fn options_name_the_bad_flag() {
        let bad = |f: fn(&mut GenerateOptions)| {
            let mut o = GenerateOptions::default();
            f(&mut o);
            o.validate().unwrap_err()
        };
        assert!(bad(|o| o.radius = Range::new(-1.0, 1.0)).starts_with("radius"));
        assert!(bad(|o| o.caps_prob = 2.0).starts_with("caps_prob"));
        assert!(bad(|o| o.cylinders = Range::new(0.0, 3.0)).starts_with("cylinders"));
        assert!(bad(|o| o.elevation = Range::new(0.0, 90.0)).starts_with("elevation"));
        assert!(bad(|o| o.fov = 180.0).starts_with("fov"));
    }
}
