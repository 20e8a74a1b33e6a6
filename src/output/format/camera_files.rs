//! The records cylaov writes beside its images: the camera metadata JSON, Open3D's
//! camera file, and the JSON and CSV encoding of its other records (stamps, indexes,
//! bench rows).

use crate::scene::Aov;
use crate::scene::camera::{Camera, rows};
use serde::Serialize;
use std::io;
use std::path::{Path, PathBuf};

/// Rows as CSV (the `csv` crate): the header from the row type's serde field names, so a
/// column's name and its value cannot drift apart; nothing at all for no rows.
pub fn csv_bytes<T: Serialize>(rows: impl IntoIterator<Item = T>) -> io::Result<Vec<u8>> {
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        w.serialize(r).map_err(io::Error::other)?;
    }
    w.into_inner().map_err(|e| io::Error::other(e.to_string()))
}

/// Where `render -o OUT.exr` puts the camera metadata: `OUT.camera.json` (not `OUT.json`,
/// which could be the scene itself).
pub fn camera_json_path(exr: &Path) -> PathBuf {
    exr.with_extension("camera.json")
}

#[derive(Serialize)]
struct AovMeaning {
    name: &'static str,
    channels: &'static [&'static str],
    meaning: String,
    miss: &'static str,
}

/// The pinhole's intrinsics, in both pixel conventions (the `perspective` model only).
#[derive(Serialize)]
struct PinholeMeta {
    fov_deg: f64,
    fov_axis: &'static str,
    near_clip: f64,
    far_clip: f64,
    /// Intrinsics in pixels, row-major, pixel centres at `i + 0.5`.
    #[serde(rename = "K")]
    k: [[f64; 3]; 3],
    principal_point_note: &'static str,
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
    /// The same intrinsics with pixel centres at integers.
    #[serde(rename = "K_opencv")]
    k_opencv: [[f64; 3]; 3],
    principal_point_note_opencv: &'static str,
    cx_opencv: f64,
    cy_opencv: f64,
}

/// Another model's name, depth rule and parameters (as the scene file names them).
#[derive(Serialize)]
struct ModelMeta {
    model: &'static str,
    depth_kind: &'static str,
    #[serde(flatten)]
    params: serde_json::Map<String, serde_json::Value>,
    near_clip: f64,
    far_clip: f64,
}

#[derive(Serialize)]
struct CameraMeta {
    width: u32,
    height: u32,
    #[serde(flatten)]
    pinhole: Option<PinholeMeta>,
    #[serde(flatten)]
    model: Option<ModelMeta>,
    camera_to_world_opencv: [[f64; 4]; 4],
    world_to_camera_opencv: [[f64; 4]; 4],
    camera_to_world_opengl: [[f64; 4]; 4],
    world_to_camera_opengl: [[f64; 4]; 4],
    conventions: &'static str,
    aovs: Vec<AovMeaning>,
}

/// Pretty JSON of one of cylaov's own records (camera metadata, stamps, indexes). They are
/// structs of numbers, strings and lists with string keys, which serde_json always serialises
/// (it fails only on non-string map keys or a failing custom `Serialize`), so a failure is a
/// bug in cylaov and is reported as one, never written as an empty file.
pub fn record_json(value: &impl serde::Serialize) -> String {
    serde_json::to_string_pretty(value).expect("cylaov's own records always serialise to JSON")
}

/// The camera metadata JSON for a render: intrinsics, both pose conventions, AOV meanings.
pub fn camera_json(cam: &Camera, aovs: &[Aov]) -> String {
    let cv = cam.world_from_camera_opencv();
    let gl = cam.world_from_camera_opengl();
    let (pinhole, model) = if cam.is_pinhole() {
        let (fx, fy) = cam.focal_px();
        let k = cam.k_matrix();
        let k_cv = cam.k_matrix_opencv();
        let meta = PinholeMeta {
            fov_deg: cam.spec.fov_deg,
            fov_axis: cam.spec.fov_axis.name(),
            near_clip: cam.spec.near_clip,
            far_clip: cam.spec.far_clip,
            k,
            principal_point_note: "K, cx, cy: cx = W/2, cy = H/2, pixel (i, j) has its centre at (i + 0.5, j + 0.5): nerfstudio, Mitsuba",
            fl_x: fx,
            fl_y: fy,
            cx: k[0][2],
            cy: k[1][2],
            k_opencv: k_cv,
            principal_point_note_opencv: "K_opencv, cx_opencv, cy_opencv: cx = W/2 - 0.5, cy = H/2 - 0.5, pixel (i, j) has its centre at (i, j): OpenCV, Open3D, COLMAP",
            cx_opencv: k_cv[0][2],
            cy_opencv: k_cv[1][2],
        };
        (Some(meta), None)
    } else {
        let p = &cam.projection;
        let meta = ModelMeta {
            model: p.model().name(),
            depth_kind: p.depth_kind(),
            params: p.named_params(),
            near_clip: cam.spec.near_clip,
            far_clip: cam.spec.far_clip,
        };
        (None, Some(meta))
    };
    let meta = CameraMeta {
        width: cam.width(),
        height: cam.height(),
        pinhole,
        model,
        camera_to_world_opencv: rows(cv),
        world_to_camera_opencv: rows(cv.inverse()),
        camera_to_world_opengl: rows(gl),
        world_to_camera_opengl: rows(gl.inverse()),
        conventions: "OpenCV camera axes: x right, y down, z forward. OpenGL: x right, y up, z backward. Matrices row-major; image row 0 is the top row.",
        aovs: aovs
            .iter()
            .map(|&a| {
                let spec = a.spec();
                AovMeaning {
                    name: a.name(),
                    channels: crate::output::format::exr::channel_names(a),
                    meaning: spec.meaning_under(&cam.projection),
                    miss: spec.miss,
                }
            })
            .collect(),
    };
    let mut s = record_json(&meta);
    s.push('\n');
    s
}

/// Open3D's `PinholeCameraParameters` file (`NAME.open3d.json`), which
/// `o3d.io.read_pinhole_camera_parameters` loads as it is: the intrinsic matrix with the
/// integer-centre principal point (`W/2 - 0.5`) and the extrinsic world-to-camera in OpenCV
/// axes (x right, y down, z forward), both column-major as Open3D (Eigen) stores them.
pub fn open3d_json(cam: &Camera) -> String {
    #[derive(Serialize)]
    struct Intrinsic {
        width: u32,
        height: u32,
        intrinsic_matrix: [f64; 9],
    }
    #[derive(Serialize)]
    struct Params {
        class_name: &'static str,
        version_major: u32,
        version_minor: u32,
        intrinsic: Intrinsic,
        extrinsic: [f64; 16],
    }
    let k = cam.k_matrix_opencv();
    let mut k_cols = [0.0; 9];
    for (c, col) in k_cols.chunks_exact_mut(3).enumerate() {
        for (r, x) in col.iter_mut().enumerate() {
            *x = k[r][c];
        }
    }
    let params = Params {
        class_name: "PinholeCameraParameters",
        version_major: 1,
        version_minor: 0,
        intrinsic: Intrinsic {
            width: cam.width(),
            height: cam.height(),
            intrinsic_matrix: k_cols,
        },
        // glam matrices are column-major already.
        extrinsic: cam.world_from_camera_opencv().inverse().to_cols_array(),
    };
    let mut s = record_json(&params);
    s.push('\n');
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The header comes from the field names; an absent value is an empty field; a text
    /// with a comma or a quote is quoted, so a kernel or family name can never shift columns.
    #[test]
    fn csv_rows_take_their_header_from_the_fields() {
        #[derive(Serialize)]
        struct Row {
            name: &'static str,
            ms: f64,
            peak: Option<f64>,
        }
        let rows = [
            Row {
                name: "a",
                ms: 1.5,
                peak: None,
            },
            Row {
                name: "b,\"c\"",
                ms: 1.2e-7,
                peak: Some(39.0),
            },
        ];
        let text = String::from_utf8(csv_bytes(&rows).unwrap()).unwrap();
        assert_eq!(text, "name,ms,peak\na,1.5,\n\"b,\"\"c\"\"\",1.2e-7,39.0\n");
        assert!(csv_bytes(Vec::<Row>::new()).unwrap().is_empty());
    }
}
