//! `transforms.json`: the nerfstudio / instant-ngp index of the views.

use super::options::BatchOptions;
use crate::scene::camera::{Camera, rows};
use serde::Serialize;

#[derive(Serialize, PartialEq, Clone, Copy, Debug)]
struct Intrinsics {
    w: u32,
    h: u32,
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
}

#[derive(Serialize)]
struct Frame {
    file_path: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_file_path: Option<String>,
    exr_file_path: String,
    camera_file_path: String,
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

/// What `transforms.json` needs of a view's camera.
#[derive(Clone, Copy, Debug)]
pub struct FrameCamera {
    intrinsics: Intrinsics,
    /// OpenGL camera-to-world, row-major.
    transform_matrix: [[f64; 4]; 4],
}

impl FrameCamera {
    pub fn new(cam: &Camera) -> FrameCamera {
        FrameCamera {
            intrinsics: intrinsics(cam),
            transform_matrix: rows(cam.world_from_camera_opengl()),
        }
    }
}

fn intrinsics(cam: &Camera) -> Intrinsics {
    let (fl_x, fl_y) = cam.focal_px();
    let (w, h) = (cam.width(), cam.height());
    Intrinsics {
        w,
        h,
        fl_x,
        fl_y,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
    }
}

/// The nerfstudio / instant-ngp index of every valid view, in view-list order. Shared
/// intrinsics go at the top level; if views differ, every frame carries its own.
/// `file_path` is the normal PNG (the EXR when PNGs are off).
pub fn transforms_json(views: &[(&str, FrameCamera)], opts: &BatchOptions) -> String {
    let shared = views
        .first()
        .map(|(_, c)| c.intrinsics)
        .filter(|first| views.iter().all(|(_, c)| c.intrinsics == *first));
    let frames = views
        .iter()
        .map(|(name, cam)| Frame {
            file_path: if opts.png {
                format!("{name}.normal.png")
            } else {
                format!("{name}.exr")
            },
            depth_file_path: opts.png.then(|| format!("{name}.depth.png")),
            exr_file_path: format!("{name}.exr"),
            camera_file_path: format!("{name}.camera.json"),
            transform_matrix: cam.transform_matrix,
            intrinsics: if shared.is_some() {
                None
            } else {
                Some(cam.intrinsics)
            },
        })
        .collect();
    let t = Transforms {
        camera_model: "OPENCV",
        intrinsics: shared,
        depth_unit_scale_factor: opts.png.then(|| 1.0 / opts.depth_scale),
        principal_point_note: "cx = W/2, cy = H/2: pixel (i, j) has its centre at (i + 0.5, j + 0.5); transform_matrix is camera-to-world with OpenGL axes (x right, y up, z backward)",
        frames,
    };
    let mut s = serde_json::to_string_pretty(&t).unwrap_or_default();
    s.push('\n');
    s
}
