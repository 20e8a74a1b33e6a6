//! The `model` a scene file's camera names, and which of the camera's optional fields
//! each model reads: one table, so a field given to a model that has no use for it is
//! refused by name instead of being silently ignored.

use super::Projection;
use super::lens::Lens;
use serde::{Deserialize, Serialize};

/// How the camera maps pixels to rays, as a scene file spells it (`"model"`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraModel {
    /// The pinhole with `fov_deg` / `fov_axis` (Mitsuba's `perspective`): the default.
    #[default]
    Perspective,
    /// Parallel rays along the view direction over `ortho_width` world units.
    Orthographic,
    /// OpenCV's pinhole with radial–tangential distortion (`cv2.projectPoints`).
    Opencv,
    /// OpenCV's fisheye (Kannala–Brandt) model (`cv2.fisheye.projectPoints`).
    OpencvFisheye,
    /// The full sphere: longitude across the width, latitude down the height.
    Equirectangular,
}

/// The optional per-model fields of a camera, by their scene-file names.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ModelFields {
    /// `fov_deg`.
    pub fov_deg: Option<f64>,
    /// `ortho_width`.
    pub ortho_width: Option<f64>,
    /// `fx`, `fy`, `cx`, `cy`.
    pub intrinsics: [Option<f64>; 4],
    /// `k1`, `k2`, `k3`, `k4`.
    pub k: [Option<f64>; 4],
    /// `p1`, `p2`.
    pub p: [Option<f64>; 2],
}

/// A refusal: the field at fault (scene-file name) and what is wrong.
pub type FieldError = (&'static str, String);

impl CameraModel {
    /// Every model, the default first.
    pub const ALL: [CameraModel; 5] = [
        CameraModel::Perspective,
        CameraModel::Orthographic,
        CameraModel::Opencv,
        CameraModel::OpencvFisheye,
        CameraModel::Equirectangular,
    ];

    /// The model a scene file's `name` spells, if any.
    pub fn from_name(name: &str) -> Option<CameraModel> {
        CameraModel::ALL.into_iter().find(|m| m.name() == name)
    }

    /// The name as scene files spell it.
    pub fn name(self) -> &'static str {
        match self {
            CameraModel::Perspective => "perspective",
            CameraModel::Orthographic => "orthographic",
            CameraModel::Opencv => "opencv",
            CameraModel::OpencvFisheye => "opencv_fisheye",
            CameraModel::Equirectangular => "equirectangular",
        }
    }

    /// The optional fields this model reads, required ones first (`required` of them).
    fn reads(self) -> (&'static [&'static str], usize) {
        match self {
            CameraModel::Perspective => (&["fov_deg", "fov_axis"], 1),
            CameraModel::Orthographic => (&["ortho_width"], 1),
            CameraModel::Opencv => (&["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"], 4),
            CameraModel::OpencvFisheye => (&["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"], 4),
            CameraModel::Equirectangular => (&[], 0),
        }
    }

    /// Check that `given` (with `fov_axis` given or not) holds exactly the fields this
    /// model reads, and build its projection over a `width` × `height` image. The
    /// perspective model's projection needs no parameters (`fov_deg` is checked with the
    /// rest of the camera).
    pub fn projection(
        self,
        given: &ModelFields,
        fov_axis_given: bool,
        width: u32,
        height: u32,
    ) -> Result<Projection, FieldError> {
        let [fx, fy, cx, cy] = given.intrinsics;
        let [k1, k2, k3, k4] = given.k;
        let [p1, p2] = given.p;
        let present: [(&'static str, Option<f64>); 13] = [
            ("fov_deg", given.fov_deg),
            ("fov_axis", fov_axis_given.then_some(0.0)),
            ("ortho_width", given.ortho_width),
            ("fx", fx),
            ("fy", fy),
            ("cx", cx),
            ("cy", cy),
            ("k1", k1),
            ("k2", k2),
            ("k3", k3),
            ("k4", k4),
            ("p1", p1),
            ("p2", p2),
        ];
        let (reads, required) = self.reads();
        for (name, v) in present {
            if v.is_some() && !reads.contains(&name) {
                let what = if reads.is_empty() {
                    "no parameters".to_string()
                } else {
                    reads.join(", ")
                };
                return Err((
                    name,
                    format!(
                        "is not a parameter of model \"{}\" (it reads {what})",
                        self.name()
                    ),
                ));
            }
        }
        for name in &reads[..required] {
            if present.iter().any(|(n, v)| n == name && v.is_none()) {
                return Err((name, format!("is required by model \"{}\"", self.name())));
            }
        }
        let z = |v: Option<f64>| v.unwrap_or(0.0);
        let lens = match self {
            CameraModel::Perspective => return Ok(Projection::Perspective),
            CameraModel::Orthographic => {
                let w = z(given.ortho_width);
                if !(w.is_finite() && w > 0.0 && w <= crate::scene::MAX_COORD) {
                    return Err((
                        "ortho_width",
                        format!(
                            "must be finite, > 0 and <= {:e}, got {}",
                            crate::scene::MAX_COORD,
                            crate::scene::num(w)
                        ),
                    ));
                }
                let half_width = w / 2.0;
                return Ok(Projection::Orthographic {
                    half_width,
                    half_height: half_width / (width as f64 / height as f64),
                });
            }
            CameraModel::Opencv => Lens::OpenCv {
                fx: z(fx),
                fy: z(fy),
                cx: z(cx),
                cy: z(cy),
                dist: [z(k1), z(k2), z(p1), z(p2), z(k3)],
            },
            CameraModel::OpencvFisheye => Lens::OpenCvFisheye {
                fx: z(fx),
                fy: z(fy),
                cx: z(cx),
                cy: z(cy),
                k: [z(k1), z(k2), z(k3), z(k4)],
            },
            CameraModel::Equirectangular => Lens::Equirectangular { width, height },
        };
        lens.validate(width, height)
            .map_err(|e| (e.field, e.message))?;
        Ok(Projection::Lens(lens))
    }
}

impl Projection {
    /// Whether this is the pinhole of `fov_deg` (the default model).
    pub fn is_pinhole(&self) -> bool {
        *self == Projection::Perspective
    }

    /// The scene-file model of this projection.
    pub fn model(&self) -> CameraModel {
        match self {
            Projection::Perspective => CameraModel::Perspective,
            Projection::Orthographic { .. } => CameraModel::Orthographic,
            Projection::Lens(Lens::OpenCv { .. }) => CameraModel::Opencv,
            Projection::Lens(Lens::OpenCvFisheye { .. }) => CameraModel::OpencvFisheye,
            Projection::Lens(Lens::Equirectangular { .. }) => CameraModel::Equirectangular,
        }
    }

    /// The optional fields a scene file gives for this projection (the inverse of
    /// [`CameraModel::projection`]; `fov_deg` is the caller's).
    pub fn fields(&self) -> ModelFields {
        match *self {
            Projection::Perspective | Projection::Lens(Lens::Equirectangular { .. }) => {
                ModelFields::default()
            }
            Projection::Orthographic { half_width, .. } => ModelFields {
                ortho_width: Some(2.0 * half_width),
                ..ModelFields::default()
            },
            Projection::Lens(Lens::OpenCv {
                fx,
                fy,
                cx,
                cy,
                dist: [k1, k2, p1, p2, k3],
            }) => ModelFields {
                intrinsics: [Some(fx), Some(fy), Some(cx), Some(cy)],
                k: [Some(k1), Some(k2), Some(k3), None],
                p: [Some(p1), Some(p2)],
                ..ModelFields::default()
            },
            Projection::Lens(Lens::OpenCvFisheye { fx, fy, cx, cy, k }) => ModelFields {
                intrinsics: [Some(fx), Some(fy), Some(cx), Some(cy)],
                k: k.map(Some),
                ..ModelFields::default()
            },
        }
    }

    /// What `depth` holds under this projection, as the camera file and the EXR header
    /// name it: `planar` (camera-space z), `euclidean` (distance from the camera centre),
    /// or `planar_in_front` (planar for rays less than 90° from `forward`, Euclidean for
    /// the rest: a fisheye that sees behind its image plane).
    pub fn depth_kind(&self) -> &'static str {
        match self {
            Projection::Perspective
            | Projection::Orthographic { .. }
            | Projection::Lens(Lens::OpenCv { .. }) => "planar",
            Projection::Lens(Lens::OpenCvFisheye { .. }) => "planar_in_front",
            Projection::Lens(Lens::Equirectangular { .. }) => "euclidean",
        }
    }

    /// What `depth` holds under this projection, in words: the `depth` AOV's meaning in
    /// the EXR header, the camera file and a tar sample's JSON, after its
    /// [`Self::depth_kind`].
    pub fn depth_meaning(&self) -> &'static str {
        match self.depth_kind() {
            "planar" => "camera-space z of the hit (distance * cos theta)",
            "planar_in_front" => {
                "camera-space z of the hit for rays less than 90 degrees from forward, else \
                 its Euclidean distance from the camera centre (as distance)"
            }
            _ => "the hit's Euclidean distance from the camera centre (as distance)",
        }
    }

    /// The model's parameters by their scene-file names (none for the perspective model,
    /// whose `fov_deg` is the camera's).
    pub fn named_params(&self) -> serde_json::Map<String, serde_json::Value> {
        let f = self.fields();
        let [fx, fy, cx, cy] = f.intrinsics;
        let [k1, k2, k3, k4] = f.k;
        let [p1, p2] = f.p;
        [
            ("ortho_width", f.ortho_width),
            ("fx", fx),
            ("fy", fy),
            ("cx", cx),
            ("cy", cy),
            ("k1", k1),
            ("k2", k2),
            ("p1", p1),
            ("p2", p2),
            ("k3", k3),
            ("k4", k4),
        ]
        .into_iter()
        .filter_map(|(n, v)| Some((n.to_string(), serde_json::Value::from(v?))))
        .collect()
    }
}
