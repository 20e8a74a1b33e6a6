//! The camera seam: the perspective projection's pixel rays are the render's, bit for bit,
//! and every model's pixel ray projects back onto its pixel centre; lens models that cannot
//! be inverted are refused with the field named.

use cylaov::scene::camera::lens::{INVERSE_TOLERANCE_PX, Lens};
use cylaov::scene::camera::{Camera, CameraSpec, FovAxis, Projection};
use glam::{DVec2, DVec3};

fn spec(width: u32, height: u32) -> CameraSpec {
    CameraSpec {
        origin: DVec3::new(0.3, -4.0, 1.2),
        target: DVec3::new(0.0, 0.0, 0.5),
        up: DVec3::Z,
        fov_deg: 50.0,
        fov_axis: FovAxis::X,
        width,
        height,
        near_clip: 0.01,
        far_clip: 1e4,
        projection: Projection::Perspective,
    }
}

#[test]
fn perspective_pixel_ray_is_the_render_ray_bit_for_bit_and_projects_back() {
    let cam = Camera::new(spec(37, 23));
    assert!(cam.is_pinhole());
    for j in 0..23 {
        for i in 0..37 {
            let r = cam.pixel_ray(i, j);
            let (d, len) = cam.dir_and_length(cam.column_offset(i), cam.row_offset(j));
            assert_eq!(r.dir, d);
            assert_eq!((r.tmin, r.tmax), cam.clip_range(len));
            assert_eq!(r.dir, cam.ray_dir(i, j));
            let p = cam.project(r.origin + r.dir * 3.7).unwrap();
            let centre = DVec2::new(i as f64 + 0.5, j as f64 + 0.5);
            assert!((p - centre).length() < 1e-9, "({i}, {j}): {p} vs {centre}");
        }
    }
    assert_eq!(cam.project(cam.origin - cam.forward), None);
}

#[test]
fn orthographic_rays_are_parallel_and_span_the_width() {
    // Mitsuba's measured frame: look_at origin (0,0,5), target 0, up +y on a 40×20 film;
    // the top-left corner lies at world (-hw, +hh), the bottom-right at (+hw, -hh).
    let mut s = spec(40, 20);
    s.origin = DVec3::new(0.0, 0.0, 5.0);
    s.target = DVec3::ZERO;
    s.up = DVec3::Y;
    let cam = Camera::new(s).with_projection(Projection::Orthographic {
        half_width: 2.0,
        half_height: 1.0,
    });
    let tl = cam.pixel_ray(0, 0);
    let br = cam.pixel_ray(39, 19);
    assert_eq!(tl.dir, DVec3::new(0.0, 0.0, -1.0));
    assert_eq!(br.dir, tl.dir);
    assert!((tl.origin - DVec3::new(-1.95, 0.95, 5.0)).length() < 1e-12);
    assert!((br.origin - DVec3::new(1.95, -0.95, 5.0)).length() < 1e-12);
    for (i, j) in [(0, 0), (17, 3), (39, 19)] {
        let r = cam.pixel_ray(i, j);
        let p = cam.project(r.origin + r.dir * 2.5).unwrap();
        assert!((p - DVec2::new(i as f64 + 0.5, j as f64 + 0.5)).length() < 1e-9);
    }
}

fn roundtrip(lens: Lens, w: u32, h: u32, centre_offset: f64) -> f64 {
    lens.validate(w, h).unwrap();
    let cam = Camera::new(spec(w, h)).with_projection(Projection::Lens(lens));
    let mut worst = 0.0f64;
    for j in 0..h {
        for i in 0..w {
            let r = cam.pixel_ray(i, j);
            assert!(r.tmin < r.tmax);
            assert!((r.dir.length() - 1.0).abs() < 1e-12);
            let p = cam.project(r.origin + r.dir * 5.0).unwrap();
            let c = DVec2::new(i as f64 + centre_offset, j as f64 + centre_offset);
            worst = worst.max((p - c).length());
        }
    }
    assert!(worst <= INVERSE_TOLERANCE_PX, "worst {worst} px");
    worst
}

#[test]
fn opencv_rays_project_back_within_the_bound() {
    let lens = Lens::OpenCv {
        fx: 60.0,
        fy: 58.0,
        cx: 31.7,
        cy: 24.2,
        dist: [-0.28, 0.07, 0.001, -0.0015, -0.01],
    };
    roundtrip(lens, 64, 48, 0.0);
}

#[test]
fn fisheye_beyond_180_degrees_projects_back_and_looks_behind() {
    // fx = 20 on 96 px: the corners ask for θ_d ≈ 3.3, a ray ~ 105° off axis.
    let lens = Lens::OpenCvFisheye {
        fx: 20.0,
        fy: 20.0,
        cx: 47.5,
        cy: 35.5,
        k: [0.02, -0.003, 0.0005, -0.00002],
    };
    roundtrip(lens, 96, 72, 0.0);
    let cam = Camera::new(spec(96, 72)).with_projection(Projection::Lens(lens));
    let corner = cam.pixel_ray(0, 0);
    assert!(
        corner.dir.dot(cam.forward) < 0.0,
        "the corner looks behind the camera"
    );
    assert!(!corner.planar_depth);
    assert!(cam.pixel_ray(48, 36).planar_depth);
}

#[test]
fn equirectangular_longitude_and_latitude_follow_the_pixel_centres() {
    let lens = Lens::Equirectangular {
        width: 64,
        height: 32,
    };
    roundtrip(lens, 64, 32, 0.5);
    let v = lens.unproject(32, 16).unwrap();
    // Column 32 of 64: longitude 0.5/64 · 2π toward +x; row 16 of 32: latitude -0.5/32 · π.
    let lon = v.x.atan2(v.z);
    let lat = (-v.y).asin();
    assert!((lon - std::f64::consts::TAU * 0.5 / 64.0).abs() < 1e-14);
    assert!((lat + std::f64::consts::PI * 0.5 / 32.0).abs() < 1e-14);
    assert!(!lens.planar_depth(v));
}

#[test]
fn folding_distortion_is_refused_naming_the_coefficient() {
    let lens = Lens::OpenCv {
        fx: 30.0,
        fy: 30.0,
        cx: 31.5,
        cy: 23.5,
        dist: [-0.6, 0.0, 0.0, 0.0, 0.0],
    };
    let e = lens.validate(64, 48).unwrap_err();
    assert_eq!(e.field, "k1");
    assert!(e.message.contains("folds over"), "{}", e.message);
}

#[test]
fn non_monotonic_fisheye_is_refused_naming_the_angle() {
    let lens = Lens::OpenCvFisheye {
        fx: 20.0,
        fy: 20.0,
        cx: 47.5,
        cy: 35.5,
        k: [0.0, 0.0, 0.0, -0.01],
    };
    let e = lens.validate(96, 72).unwrap_err();
    assert_eq!(e.field, "k4");
    assert!(
        e.message.contains("stops increasing at θ = "),
        "{}",
        e.message
    );
    assert!(e.message.contains('°'));
}

#[test]
fn bad_intrinsics_are_refused_by_field() {
    let lens = Lens::OpenCv {
        fx: 0.0,
        fy: 30.0,
        cx: 1.0,
        cy: 1.0,
        dist: [0.0; 5],
    };
    assert_eq!(lens.validate(4, 4).unwrap_err().field, "fx");
    let lens = Lens::OpenCvFisheye {
        fx: 10.0,
        fy: 10.0,
        cx: f64::NAN,
        cy: 1.0,
        k: [0.0; 4],
    };
    assert_eq!(lens.validate(4, 4).unwrap_err().field, "cx");
    // Each value is finite, but no ray reaches the image: named by the one at fault, not
    // by a distortion coefficient the camera does not have.
    let opencv = |fx: f64, cx: f64| Lens::OpenCv {
        fx,
        fy: 30.0,
        cx,
        cy: 1.0,
        dist: [0.0; 5],
    };
    for (lens, field, says) in [
        (
            opencv(30.0, 1e300),
            "cx",
            "the image edge lies 3.3333333333333335e298 focal lengths from the principal point (fx = 30, cx = 1e300)",
        ),
        (
            opencv(1e-300, 1.0),
            "fx",
            "focal lengths from the principal point (fx = 1e-300, cx = 1)",
        ),
        (
            opencv(1e300, 1.0),
            "fx",
            "must be finite, > 0 and <= 3.4028235e38 pixels, got 1e300",
        ),
    ] {
        let e = lens.validate(4, 4).unwrap_err();
        assert_eq!(e.field, field, "{}", e.message);
        assert!(e.message.contains(says), "{}", e.message);
    }
}

mod common;

/// Project every pixel's ray with OpenCV itself and return the worst distance, in pixels,
/// from the pixel centre (integers, OpenCV's convention).
fn worst_by_opencv(py: &std::path::Path, lens: Lens, w: u32, h: u32) -> f64 {
    let (call, params) = match lens {
        Lens::OpenCv {
            fx,
            fy,
            cx,
            cy,
            dist,
        } => ("cv2.projectPoints", (fx, fy, cx, cy, dist.to_vec())),
        Lens::OpenCvFisheye { fx, fy, cx, cy, k } => {
            ("cv2.fisheye.projectPoints", (fx, fy, cx, cy, k.to_vec()))
        }
        Lens::Equirectangular { .. } => unreachable!(),
    };
    let mut dirs = Vec::new();
    for j in 0..h {
        for i in 0..w {
            let v = lens.unproject(i, j).unwrap();
            dirs.push([v.x, v.y, v.z]);
        }
    }
    let input = serde_json::json!({"params": params, "dirs": dirs, "w": w, "h": h});
    let script = format!(
        r#"
import json, sys, numpy as np, cv2
d = json.load(sys.stdin)
fx, fy, cx, cy, dist = d["params"]
K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], float)
P = np.array(d["dirs"], float).reshape(-1, 1, 3)
z = np.zeros((3, 1))
px, _ = {call}(P, z, z, K, np.array(dist, float))
px = px.reshape(d["h"], d["w"], 2)
j, i = np.mgrid[0:d["h"], 0:d["w"]]
print(float(np.hypot(px[..., 0] - i, px[..., 1] - j).max()))
"#
    );
    use std::io::Write;
    let mut child = std::process::Command::new(py)
        .args(["-c", &script])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.to_string().as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout)
        .unwrap()
        .trim()
        .parse()
        .unwrap()
}

#[test]
fn opencv_itself_projects_every_ray_onto_its_pixel_centre() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let pinhole = Lens::OpenCv {
        fx: 60.0,
        fy: 58.0,
        cx: 31.7,
        cy: 24.2,
        dist: [-0.28, 0.07, 0.001, -0.0015, -0.01],
    };
    let worst = worst_by_opencv(&py, pinhole, 64, 48);
    eprintln!("cv2.projectPoints: worst {worst:e} px");
    assert!(worst < 1e-3, "cv2.projectPoints: {worst} px");
    // cv2.fisheye.projectPoints takes θ = atan(r) from x/z, so only rays in front of the
    // camera: about 148° across the diagonal here (θ_d = 1.32 at the corners).
    let fisheye = Lens::OpenCvFisheye {
        fx: 45.0,
        fy: 45.0,
        cx: 47.5,
        cy: 35.5,
        k: [0.02, -0.003, 0.0005, -0.00002],
    };
    let worst = worst_by_opencv(&py, fisheye, 96, 72);
    eprintln!("cv2.fisheye.projectPoints: worst {worst:e} px");
    assert!(worst < 1e-3, "cv2.fisheye.projectPoints: {worst} px");
}
