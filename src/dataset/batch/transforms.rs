//! The dataset indexes: `OUT/index.json`, every view of the batch, and
//! `OUT/<scene>/transforms.json`, the nerfstudio / instant-ngp file of one several-camera
//! scene (its views only: nerfstudio reads a `transforms.json` as views of one static scene).
//!
//! Both give per view the same frame fields: `file_path` (the normal picture, the EXR without
//! PNGs: nerfstudio needs an image), `depth_file_path` (16-bit PNG), `mask_path` (hit mask),
//! `exr_file_path`, `camera_file_path`, `open3d_file_path`, and `transform_matrix`, the
//! OpenGL camera-to-world (x right, y up, z backward) that nerfstudio reads, row-major.
//! Intrinsics use nerfstudio's convention, `cx = W/2` (pixel centres at `i + 0.5`, its
//! default `pixel_offset = 0.5`). nerfstudio takes the depth scale from its parser option
//! `depth_unit_scale_factor` (default 1e-3), not from the file: the file's value says which
//! one to pass.

use super::options::BatchOptions;
use super::views::ViewSource;
use crate::output::format::exr::ExrLayout;
use crate::scene::Aov;
use crate::scene::camera::lens::Lens;
use crate::scene::camera::{Camera, Projection, rows};
use serde::Serialize;
use std::path::Path;

#[derive(Serialize, PartialEq, Clone, Copy, Debug, Default)]
struct Intrinsics {
    w: u32,
    h: u32,
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
    /// Distortion, nerfstudio's names (`OPENCV`: k1, k2, k3, p1, p2; `OPENCV_FISHEYE`:
    /// k1..k4); absent for the pinhole.
    #[serde(skip_serializing_if = "Option::is_none")]
    k1: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    k2: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    k3: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    k4: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    p1: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    p2: Option<f64>,
}

#[derive(Serialize)]
struct Frame {
    /// The view's nerfstudio camera model where it differs from the file's top-level one.
    #[serde(skip_serializing_if = "Option::is_none")]
    camera_model: Option<&'static str>,
    file_path: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_file_path: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mask_path: Option<String>,
    /// The layered EXR; with `--exr-layout per-aov`, `exr_file_paths` instead.
    #[serde(skip_serializing_if = "Option::is_none")]
    exr_file_path: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    exr_file_paths: Option<std::collections::BTreeMap<&'static str, String>>,
    camera_file_path: String,
    /// Written for pinhole views only.
    #[serde(skip_serializing_if = "Option::is_none")]
    open3d_file_path: Option<String>,
    transform_matrix: [[f64; 4]; 4],
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    intrinsics: Option<Intrinsics>,
}

#[derive(Serialize)]
struct Transforms {
    camera_model: &'static str,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    intrinsics: Option<Intrinsics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_unit_scale_factor: Option<f64>,
    principal_point_note: &'static str,
    frames: Vec<Frame>,
}

/// One view of `index.json`: where it came from, then its frame fields.
#[derive(Serialize)]
struct IndexView {
    /// The scene's name, and its file relative to the input folder (or the manifest's).
    scene: String,
    scene_file: String,
    /// The camera of the scene (0-based, file order).
    camera: usize,
    #[serde(flatten)]
    frame: Frame,
}

#[derive(Serialize)]
struct Index {
    camera_model: &'static str,
    /// The batch's input (scene folder or manifest) as given, made absolute: where
    /// `scene_file` paths are relative to (a manifest's folder), so `cylaov verify OUT`
    /// finds the scenes.
    input: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_unit_scale_factor: Option<f64>,
    principal_point_note: &'static str,
    layout_note: &'static str,
    views: Vec<IndexView>,
}

const PRINCIPAL_POINT_NOTE: &str = "cx = W/2, cy = H/2: pixel (i, j) has its centre at (i + 0.5, j + 0.5); transform_matrix is camera-to-world with OpenGL axes (x right, y up, z backward)";

/// What the indexes need of a view's camera.
#[derive(Clone, Copy, Debug)]
pub struct FrameCamera {
    intrinsics: Intrinsics,
    /// nerfstudio's `camera_model` for this view.
    model: &'static str,
    /// Whether the view is the pinhole (the only model with an Open3D camera file).
    pinhole: bool,
    /// OpenGL camera-to-world, row-major.
    transform_matrix: [[f64; 4]; 4],
    /// The AOVs in the view's EXR (bit k: `Aov::ALL[k]`), for per-AOV file names.
    aovs: u32,
}

impl FrameCamera {
    /// What the indexes need of `cam`, whose view's EXR holds `aovs`.
    pub fn new(cam: &Camera, aovs: &[Aov]) -> FrameCamera {
        FrameCamera {
            intrinsics: intrinsics(cam),
            model: nerfstudio_model(cam),
            pinhole: cam.is_pinhole(),
            transform_matrix: rows(cam.world_from_camera_opengl()),
            aovs: Aov::ALL
                .iter()
                .enumerate()
                .filter(|(_, a)| aovs.contains(a))
                .fold(0, |m, (k, _)| m | 1 << k),
        }
    }

    /// The image size, `(width, height)`.
    pub(super) fn size(&self) -> (u32, u32) {
        (self.intrinsics.w, self.intrinsics.h)
    }

    /// The AOVs in the view's EXR, in `Aov::ALL` order.
    pub(super) fn aovs(&self) -> impl Iterator<Item = Aov> + '_ {
        Aov::ALL
            .into_iter()
            .enumerate()
            .filter(|(k, _)| self.aovs & (1 << k) != 0)
            .map(|(_, a)| a)
    }
}

/// nerfstudio's `camera_model` for `cam`'s projection.
fn nerfstudio_model(cam: &Camera) -> &'static str {
    match cam.projection {
        Projection::Perspective | Projection::Lens(Lens::OpenCv { .. }) => "OPENCV",
        Projection::Orthographic { .. } => "ORTHOPHOTO",
        Projection::Lens(Lens::OpenCvFisheye { .. }) => "OPENCV_FISHEYE",
        Projection::Lens(Lens::Equirectangular { .. }) => "EQUIRECTANGULAR",
    }
}

/// Intrinsics as nerfstudio reads them, pixel centres at `i + 0.5` (its default
/// `pixel_offset`): the OpenCV models' principal point moves by half a pixel; an
/// orthophoto's focal length is pixels per world unit; an equirectangular image has
/// `fl_x = W/2`, `fl_y = H` (longitude `π·(x − cx)/fl_x`, colatitude `π·(½ + (y − cy)/fl_y)`).
fn intrinsics(cam: &Camera) -> Intrinsics {
    let (w, h) = (cam.width(), cam.height());
    let (wf, hf) = (w as f64, h as f64);
    let base = Intrinsics {
        w,
        h,
        cx: wf / 2.0,
        cy: hf / 2.0,
        ..Intrinsics::default()
    };
    match cam.projection {
        Projection::Perspective => {
            let (fl_x, fl_y) = cam.focal_px();
            Intrinsics { fl_x, fl_y, ..base }
        }
        Projection::Orthographic {
            half_width,
            half_height,
        } => Intrinsics {
            fl_x: wf / (2.0 * half_width),
            fl_y: hf / (2.0 * half_height),
            ..base
        },
        Projection::Lens(Lens::OpenCv {
            fx,
            fy,
            cx,
            cy,
            dist: [k1, k2, p1, p2, k3],
        }) => Intrinsics {
            fl_x: fx,
            fl_y: fy,
            cx: cx + 0.5,
            cy: cy + 0.5,
            k1: Some(k1),
            k2: Some(k2),
            k3: Some(k3),
            p1: Some(p1),
            p2: Some(p2),
            ..base
        },
        Projection::Lens(Lens::OpenCvFisheye { fx, fy, cx, cy, k }) => Intrinsics {
            fl_x: fx,
            fl_y: fy,
            cx: cx + 0.5,
            cy: cy + 0.5,
            k1: Some(k[0]),
            k2: Some(k[1]),
            k3: Some(k[2]),
            k4: Some(k[3]),
            ..base
        },
        Projection::Lens(Lens::Equirectangular { .. }) => Intrinsics {
            fl_x: wf / 2.0,
            fl_y: hf,
            ..base
        },
    }
}

/// The frame of view `name`, its paths prefixed by `prefix` (`""` or `"scene/"`).
fn frame(
    prefix: &str,
    name: &str,
    cam: &FrameCamera,
    own_intrinsics: bool,
    file_model: &'static str,
    opts: &BatchOptions,
) -> Frame {
    let p = |suffix: &str| format!("{prefix}{name}.{suffix}");
    let per_aov: Option<std::collections::BTreeMap<&'static str, String>> =
        (opts.exr_layout == ExrLayout::PerAov).then(|| {
            cam.aovs()
                .map(|a| (a.name(), p(&format!("{}.exr", a.name()))))
                .collect()
        });
    let first_exr = per_aov
        .as_ref()
        .and_then(|m| m.values().next().cloned())
        .unwrap_or_else(|| p("exr"));
    Frame {
        camera_model: (cam.model != file_model).then_some(cam.model),
        file_path: if opts.png {
            p("normal.preview.png")
        } else {
            first_exr
        },
        depth_file_path: opts.png.then(|| p("depth.png")),
        mask_path: opts.png.then(|| p("mask.png")),
        exr_file_path: per_aov.is_none().then(|| p("exr")),
        exr_file_paths: per_aov,
        camera_file_path: p("camera.json"),
        open3d_file_path: cam.pinhole.then(|| p("open3d.json")),
        transform_matrix: cam.transform_matrix,
        intrinsics: own_intrinsics.then_some(cam.intrinsics),
    }
}

/// The nerfstudio / instant-ngp `transforms.json` of the views of one scene, in camera
/// order, paths relative to the scene's folder. Shared intrinsics go at the top level; if
/// views differ, every frame carries its own.
pub fn transforms_json(views: &[(&str, FrameCamera)], opts: &BatchOptions) -> String {
    let shared = views
        .first()
        .map(|(_, c)| c.intrinsics)
        .filter(|first| views.iter().all(|(_, c)| c.intrinsics == *first));
    // nerfstudio reads one camera model per file: camera 0's; a view of another model
    // also names its own.
    let model = views.first().map_or("OPENCV", |(_, c)| c.model);
    let frames = views
        .iter()
        .map(|(name, cam)| frame("", name, cam, shared.is_none(), model, opts))
        .collect();
    let t = Transforms {
        camera_model: model,
        intrinsics: shared,
        depth_unit_scale_factor: opts.png.then(|| 1.0 / opts.depth_scale),
        principal_point_note: PRINCIPAL_POINT_NOTE,
        frames,
    };
    let mut s = crate::output::format::camera_files::record_json(&t);
    s.push('\n');
    s
}

/// `OUT/index.json`: every valid view of the batch in view-list order, each with its scene,
/// camera and frame fields (own intrinsics), paths relative to `OUT`.
/// `input_dir` is the folder scene paths are shown relative to (the input folder, or the
/// manifest's), so the views' entries do not depend on where the input lies; `input` is
/// the input as given, made absolute.
pub fn index_json(
    views: &[(&ViewSource, FrameCamera)],
    input: &Path,
    input_dir: &Path,
    opts: &BatchOptions,
) -> String {
    let views = views
        .iter()
        .map(|(v, cam)| {
            let prefix = v.folder.as_ref().map_or(String::new(), |f| format!("{f}/"));
            IndexView {
                scene: v.scene.clone(),
                scene_file: v
                    .path
                    .strip_prefix(input_dir)
                    .unwrap_or(&v.path)
                    .display()
                    .to_string(),
                camera: v.camera,
                frame: frame(&prefix, &v.name, cam, true, "OPENCV", opts),
            }
        })
        .collect();
    let index = Index {
        camera_model: "OPENCV",
        input: input.display().to_string(),
        depth_unit_scale_factor: opts.png.then(|| 1.0 / opts.depth_scale),
        principal_point_note: PRINCIPAL_POINT_NOTE,
        layout_note: "views of different scenes are unrelated: each several-camera scene has its own SCENE/transforms.json for nerfstudio (ns-train ... --data OUT/SCENE); a one-camera scene's files are OUT/SCENE.*",
        views,
    };
    let mut s = crate::output::format::camera_files::record_json(&index);
    s.push('\n');
    s
}
