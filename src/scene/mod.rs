//! Scene files (SPEC §2): the serde schema, defaults, and validation into a [`Scene`].
//!
//! Serde types live here only; everything past [`Scene`] is plain validated data. Every
//! rejection names the field and the value: `cylinders[3].radius: must be > 0, got -1`.

pub mod camera;
mod fast_json;

use crate::geometry::Cylinder;
use crate::scene::camera::{CameraSpec, FovAxis};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// Largest coordinate, radius or height accepted: f32 squares overflow near 1.8e19 (SPEC §7).
pub const MAX_COORD: f64 = 1e12;
/// Largest image side accepted.
pub const MAX_SIDE: u32 = 16384;
/// Largest image accepted, in pixels (8192 × 8192): with every AOV that is 2.4 GB of
/// buffers; 16384 × 16384 would be 9.7 GB.
pub const MAX_PIXELS: u64 = 1 << 26;

/// One AOV (SPEC §4).
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    Serialize,
    Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum Aov {
    /// Euclidean distance from the camera origin to the hit.
    Distance,
    /// Planar depth: camera-space z of the hit.
    Depth,
    /// World-space unit outward normal (normal.X/Y/Z).
    Normal,
    /// World-space hit point (position.X/Y/Z).
    Position,
    /// u32 id of the hit cylinder (0 = miss).
    #[value(name = "shape_id")]
    ShapeId,
}

impl Aov {
    pub const ALL: [Aov; 5] = [
        Aov::Distance,
        Aov::Depth,
        Aov::Normal,
        Aov::Position,
        Aov::ShapeId,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Aov::Distance => "distance",
            Aov::Depth => "depth",
            Aov::Normal => "normal",
            Aov::Position => "position",
            Aov::ShapeId => "shape_id",
        }
    }

    pub fn parse(s: &str) -> Option<Aov> {
        Aov::ALL.into_iter().find(|a| a.name() == s)
    }
}

impl fmt::Display for Aov {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The default AOV set (SPEC §2).
pub fn default_aovs() -> Vec<Aov> {
    vec![Aov::Depth, Aov::Normal]
}

/// A validated scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub camera: CameraSpec,
    pub cylinders: Vec<Cylinder>,
    /// Requested AOVs, in file order, without repeats.
    pub aovs: Vec<Aov>,
}

/// A scene that could not be read: the field path (empty for whole-file errors) and why.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    pub field: String,
    pub message: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.field.is_empty() {
            f.write_str(&self.message)
        } else {
            write!(f, "{}: {}", self.field, self.message)
        }
    }
}

impl std::error::Error for SceneError {}

fn err(field: impl Into<String>, message: impl Into<String>) -> SceneError {
    SceneError {
        field: field.into(),
        message: message.into(),
    }
}

// ---- the file schema -------------------------------------------------------------------

/// The camera as written in a scene file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    pub origin: [f64; 3],
    pub target: [f64; 3],
    pub up: [f64; 3],
    pub fov_deg: f64,
    #[serde(default)]
    pub fov_axis: FovAxis,
    pub width: u32,
    pub height: u32,
    #[serde(default = "default_near")]
    pub near_clip: f64,
    #[serde(default = "default_far")]
    pub far_clip: f64,
}

fn default_near() -> f64 {
    0.01
}
fn default_far() -> f64 {
    10000.0
}
fn default_caps() -> bool {
    true
}

/// A cylinder as written: `p0`/`p1`, or the seed's `center`/`axis`/`height`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CylinderFile {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p0: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p1: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axis: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub height: Option<f64>,
    pub radius: f64,
    #[serde(default = "default_caps")]
    pub caps: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<u32>,
}

/// A whole scene file (SPEC §2).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub camera: CameraFile,
    pub cylinders: Vec<CylinderFile>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aovs: Option<Vec<Aov>>,
}

// ---- loading and validation ------------------------------------------------------------

/// Read and validate a scene file.
pub fn load(path: &Path) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| err("", format!("cannot read {}: {e}", path.display())))?;
    parse(&text)
}

/// Parse and validate scene JSON.
pub fn parse(text: &str) -> Result<Scene, SceneError> {
    if let Some(file) = fast_json::scene_file(text) {
        return file.validate();
    }
    let de = &mut serde_json::Deserializer::from_str(text);
    let file: SceneFile = serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        let field = if path == "." { String::new() } else { path };
        err(field, format!("invalid JSON: {inner}"))
    })?;
    file.validate()
}

/// A number as a person reads it in a message: plain, or in exponent form when plain would
/// be a wall of digits (1e300) or zeros (1e-300).
fn num(x: f64) -> String {
    if x.is_finite() && x != 0.0 && !(1e-6..1e16).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

fn check_vec(field: &str, v: [f64; 3]) -> Result<DVec3, SceneError> {
    for (k, x) in v.iter().enumerate() {
        if !x.is_finite() || x.abs() > MAX_COORD {
            return Err(err(
                format!("{field}[{k}]"),
                format!(
                    "must be finite with magnitude <= {MAX_COORD:e}, got {}",
                    num(*x)
                ),
            ));
        }
    }
    Ok(DVec3::from_array(v))
}

fn check_positive(field: &str, x: f64) -> Result<f64, SceneError> {
    if !x.is_finite() || x <= 0.0 || x > MAX_COORD {
        return Err(err(
            field,
            format!("must be > 0 and <= {MAX_COORD:e}, got {}", num(x)),
        ));
    }
    Ok(x)
}

impl SceneFile {
    /// The file form of a validated scene (cylinders as `p0`/`p1`, every field explicit),
    /// for writing generated scenes.
    pub fn from_scene(scene: &Scene) -> SceneFile {
        let c = &scene.camera;
        SceneFile {
            camera: CameraFile {
                origin: c.origin.to_array(),
                target: c.target.to_array(),
                up: c.up.to_array(),
                fov_deg: c.fov_deg,
                fov_axis: c.fov_axis,
                width: c.width,
                height: c.height,
                near_clip: c.near_clip,
                far_clip: c.far_clip,
            },
            cylinders: scene
                .cylinders
                .iter()
                .map(|y| CylinderFile {
                    p0: Some(y.base.to_array()),
                    p1: Some(y.top().to_array()),
                    radius: y.radius,
                    caps: y.caps,
                    id: Some(y.id),
                    ..CylinderFile::default()
                })
                .collect(),
            aovs: Some(scene.aovs.clone()),
        }
    }

    /// Check every field and build the validated scene.
    pub fn validate(&self) -> Result<Scene, SceneError> {
        let camera = self.camera.validate()?;
        // In parallel; on an error, again in order, to report the first one.
        let cylinders = match self
            .cylinders
            .par_iter()
            .enumerate()
            .map(|(i, c)| c.validate(i))
            .collect::<Result<Vec<_>, _>>()
        {
            Ok(list) => list,
            Err(_) => self
                .cylinders
                .iter()
                .enumerate()
                .map(|(i, c)| c.validate(i))
                .collect::<Result<Vec<_>, _>>()?,
        };
        let aovs = match &self.aovs {
            None => default_aovs(),
            Some(list) if list.is_empty() => {
                return Err(err("aovs", "must list at least one AOV, got []"));
            }
            Some(list) => {
                let mut out: Vec<Aov> = Vec::new();
                for a in list {
                    if !out.contains(a) {
                        out.push(*a);
                    }
                }
                out
            }
        };
        Ok(Scene {
            camera,
            cylinders,
            aovs,
        })
    }
}

impl CameraFile {
    fn validate(&self) -> Result<CameraSpec, SceneError> {
        let origin = check_vec("camera.origin", self.origin)?;
        let target = check_vec("camera.target", self.target)?;
        let up = check_vec("camera.up", self.up)?;
        let fov = self.fov_deg;
        if !(fov.is_finite() && fov > 0.0 && fov < 180.0) {
            return Err(err(
                "camera.fov_deg",
                format!("must be in (0, 180), got {}", num(fov)),
            ));
        }
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_SIDE {
                return Err(err(
                    format!("camera.{name}"),
                    format!("must be in 1..={MAX_SIDE}, got {v}"),
                ));
            }
        }
        let pixels = self.width as u64 * self.height as u64;
        if pixels > MAX_PIXELS {
            return Err(err(
                "camera.height",
                format!(
                    "width × height must be <= {MAX_PIXELS} pixels (8192 × 8192), got {} × {} = {pixels}",
                    self.width, self.height
                ),
            ));
        }
        let (near, far) = (self.near_clip, self.far_clip);
        if !(near.is_finite() && near > 0.0) {
            return Err(err(
                "camera.near_clip",
                format!("must be > 0, got {}", num(near)),
            ));
        }
        if !(far.is_finite() && far > near) {
            return Err(err(
                "camera.far_clip",
                format!(
                    "must be finite and > near_clip ({}), got {}",
                    num(near),
                    num(far)
                ),
            ));
        }
        let forward = target - origin;
        if forward.length() == 0.0 {
            return Err(err(
                "camera.target",
                format!("must differ from camera.origin, got {:?}", self.target),
            ));
        }
        if up.length() == 0.0 {
            return Err(err(
                "camera.up",
                format!("must be non-zero, got {:?}", self.up),
            ));
        }
        // Same test as the frame construction: up × forward must be a usable direction.
        let sin = up.normalize().cross(forward.normalize()).length();
        if sin < 1e-9 {
            return Err(err(
                "camera.up",
                format!(
                    "must not be parallel to the view direction (target - origin), got {:?}",
                    self.up
                ),
            ));
        }
        Ok(CameraSpec {
            origin,
            target,
            up,
            fov_deg: fov,
            fov_axis: self.fov_axis,
            width: self.width,
            height: self.height,
            near_clip: near,
            far_clip: far,
        })
    }
}

impl CylinderFile {
    fn validate(&self, index: usize) -> Result<Cylinder, SceneError> {
        let f = |name: &str| format!("cylinders[{index}].{name}");
        let radius = check_positive(&f("radius"), self.radius)?;
        let (base, axis, height) = match (self.p0, self.p1, self.center, self.axis, self.height) {
            (Some(p0), Some(p1), None, None, None) => {
                let (p0, p1) = (check_vec(&f("p0"), p0)?, check_vec(&f("p1"), p1)?);
                let h = (p1 - p0).length();
                if h == 0.0 {
                    return Err(err(
                        f("p1"),
                        format!(
                            "must differ from p0 by a length > 0, got {:?}",
                            self.p1.unwrap_or_default()
                        ),
                    ));
                }
                (p0, (p1 - p0) / h, h)
            }
            (None, None, Some(c), Some(a), Some(h)) => {
                let c = check_vec(&f("center"), c)?;
                let a = check_vec(&f("axis"), a)?;
                let h = check_positive(&f("height"), h)?;
                let len = a.length();
                if len == 0.0 || !len.is_finite() {
                    return Err(err(
                        f("axis"),
                        format!("must be non-zero, got {:?}", a.to_array()),
                    ));
                }
                (c, a / len, h)
            }
            _ => {
                return Err(err(
                    format!("cylinders[{index}]"),
                    "give either p0 and p1, or center, axis and height (not a mix)",
                ));
            }
        };
        let top = base + axis * height;
        if top.abs().max_element() > MAX_COORD {
            return Err(err(
                f("height"),
                format!("puts the top at {:?}, beyond {MAX_COORD:e}", top.to_array()),
            ));
        }
        let id = match self.id {
            Some(0) => return Err(err(f("id"), "must be > 0 (0 means miss), got 0")),
            Some(id) => id,
            None => u32::try_from(index + 1).map_err(|_| err(f("id"), "too many cylinders"))?,
        };
        Ok(Cylinder {
            base,
            axis,
            height,
            radius,
            caps: self.caps,
            id,
        })
    }
}
