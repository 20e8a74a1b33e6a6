//! Every camera model rendered end to end and checked with its definer's own code: the
//! `position` of each hit pixel, projected by `cv2.projectPoints` (`opencv`) or
//! `cv2.fisheye.projectPoints` (`opencv_fisheye`), lands on the pixel's centre; the
//! equirectangular longitude and latitude of `position − origin` are the pixel's; the
//! orthographic rays are parallel and start where the pixel says. `depth` follows each
//! model's rule against `distance`, and the files say which rule that is.

mod common;

use serde_json::Value;
use std::path::Path;

/// Render `model` (its fields merged into the camera) at 64×48 with every AOV; returns
/// the output folder's EXR path.
fn render(dir: &Path, name: &str, model: Value) -> std::path::PathBuf {
    render_scene(dir, name, &common::lens_test_scene(&model).to_string())
}

/// Render the scene `text` as [`render`] does.
fn render_scene(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let path = dir.join(format!("{name}.json"));
    std::fs::write(&path, text).unwrap();
    let exr = dir.join(format!("{name}.exr"));
    common::ok(&[
        "render",
        path.to_str().unwrap(),
        "-o",
        exr.to_str().unwrap(),
        "--aov",
        "depth,distance,position,normal,shape_id,part",
        "--threads",
        "2",
    ]);
    exr
}

/// Reads the EXR and its camera file, checks the model with OpenCV / numpy, and prints the
/// measured numbers as JSON.
const CHECK: &str = r#"
import json, sys, numpy as np, cv2, OpenEXR
exr, camfile = sys.argv[1], sys.argv[2]
f = OpenEXR.File(exr)
ch = f.channels()
hdr = f.header()
cam = json.load(open(camfile))
depth = ch["depth"].pixels.astype(np.float64)
dist = ch["distance"].pixels.astype(np.float64)
pos = np.stack([ch[f"position.{a}"].pixels for a in "XYZ"], -1).astype(np.float64)
ids = ch["shape_id"].pixels
H, W = depth.shape
j, i = np.nonzero(ids)
c2w = np.array(cam["camera_to_world_opencv"])
R, o = c2w[:3, :3], c2w[:3, 3]
pc = (pos[j, i] - o) @ R  # camera-space (OpenCV axes), per hit
out = {"hits": int(len(i)), "pixels": W * H, "model": cam["model"],
       "depth_kind": cam["depth_kind"],
       "header_model": str(hdr.get("cylaov:camera_model")),
       "header_depth_kind": str(hdr.get("cylaov:depth_kind")),
       "header_depth_meaning": str(hdr.get("cylaov:channel:depth")),
       "file_depth_meaning": [a["meaning"] for a in cam["aovs"] if a["name"] == "depth"][0],
       "has_fl_x": "cylaov:fl_x" in hdr, "has_ndc": "worldToNDC" in hdr}
z, d = depth[j, i], dist[j, i]
r = np.linalg.norm(pc, axis=1)
# Distance is from the ray's origin: the camera centre, except orthographic.
if cam["model"] != "orthographic":
    out["euclid_rel"] = float(np.max(np.abs(r - d) / d))
if cam["model"] in ("opencv", "opencv_fisheye"):
    K = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]], float)
    zero = np.zeros((3, 1))
    if cam["model"] == "opencv":
        dc = np.array([cam[k] for k in ("k1", "k2", "p1", "p2", "k3")], float)
        front = pc[:, 2] > 0
        px, _ = cv2.projectPoints(pc.reshape(-1, 1, 3), zero, zero, K, dc)
    else:
        dc = np.array([cam[k] for k in ("k1", "k2", "k3", "k4")], float)
        # cv2.fisheye takes θ = atan(r/z): points in front of the camera only.
        front = pc[:, 2] > 0
        px = np.zeros((len(pc), 1, 2))
        px[front], _ = cv2.fisheye.projectPoints(pc[front].reshape(-1, 1, 3), zero, zero, K, dc)
    err = np.hypot(px[:, 0, 0] - i, px[:, 0, 1] - j)[front]
    out["cv2_points"] = int(front.sum())
    out["reproj_max_px"] = float(err.max())
    planar = front
elif cam["model"] == "equirectangular":
    lon = np.arctan2(pc[:, 0], pc[:, 2])
    lat = np.arcsin(np.clip(-pc[:, 1] / r, -1, 1))
    lon_want = ((i + 0.5) / W - 0.5) * 2 * np.pi
    lat_want = (0.5 - (j + 0.5) / H) * np.pi
    dlon = np.abs((lon - lon_want + np.pi) % (2 * np.pi) - np.pi)
    out["lon_max_rad"] = float(dlon.max())
    out["lon_cos_lat_max_rad"] = float((dlon * np.cos(lat_want)).max())
    out["lat_max_rad"] = float(np.abs(lat - lat_want).max())
    planar = np.zeros(len(i), bool)
else:  # orthographic
    w = cam["ortho_width"]
    h = w * H / W
    out["lateral_x_max"] = float(np.abs(pc[:, 0] - ((i + 0.5) / W - 0.5) * w).max())
    out["lateral_y_max"] = float(np.abs(pc[:, 1] - ((j + 0.5) / H - 0.5) * h).max())
    out["distance_is_depth"] = bool(np.array_equal(z, d))
    planar = np.ones(len(i), bool)
# Planar depth is camera-space z; positions and depths are f32, so the error is relative to
# the larger of |position| and the depth. Euclidean depth is the distance itself, to the bit.
scale = np.linalg.norm(pos[j, i], axis=1) + d
out["planar_pixels"] = int(planar.sum())
out["planar_rel"] = float(np.max((np.abs(z - pc[:, 2]) / scale)[planar], initial=0))
out["planar_below_distance"] = bool(np.all(z[planar] <= d[planar] * (1 + 1e-7)))
out["euclid_pixels"] = int((~planar).sum())
out["euclid_equal"] = bool(np.array_equal(z[~planar], d[~planar]))
print(json.dumps(out))
"#;

fn check(py: &Path, exr: &Path) -> Value {
    let cam = exr.with_extension("camera.json");
    let out = std::process::Command::new(py)
        .args(["-c", CHECK, exr.to_str().unwrap(), cam.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    eprintln!("{}: {v}", exr.display());
    v
}

fn num(v: &Value, k: &str) -> f64 {
    v[k].as_f64()
        .unwrap_or_else(|| panic!("{k} missing in {v}"))
}

/// What every model's files say: the model and depth rule in the camera file and the EXR
/// header, no pinhole intrinsics or NDC matrix, no Open3D file; and most pixels hit.
fn common_checks(exr: &Path, v: &Value, model: &str, depth_kind: &str, min_hits: u64) {
    assert_eq!(v["model"], model);
    assert_eq!(v["depth_kind"], depth_kind);
    assert_eq!(v["header_model"], model);
    assert!(
        v["header_depth_kind"]
            .as_str()
            .unwrap()
            .starts_with(&format!("{depth_kind}: ")),
        "{v}"
    );
    // The depth channel's meaning names the same rule, in the header and the file.
    let meaning = format!("{depth_kind} depth: ");
    assert!(
        v["header_depth_meaning"]
            .as_str()
            .unwrap()
            .starts_with(&format!("depth: {meaning}")),
        "{v}"
    );
    assert!(
        v["file_depth_meaning"]
            .as_str()
            .unwrap()
            .starts_with(&meaning),
        "{v}"
    );
    assert_eq!(v["has_fl_x"], false);
    assert_eq!(v["has_ndc"], false);
    assert!(!exr.with_extension("open3d.json").exists());
    assert!(v["hits"].as_u64().unwrap() >= min_hits, "{v}");
    // position − origin has the length `distance` (f32 rounding of both).
    if model != "orthographic" {
        assert!(num(v, "euclid_rel") < 1e-6, "{v}");
    }
}

#[test]
fn opencv_positions_project_onto_their_pixel_centres() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let dir = common::fresh_dir("camera-models", "opencv");
    let [(_, opencv), ..] = common::lens_models();
    let exr = render(dir.path(), "opencv", opencv);
    let v = check(&py, &exr);
    common_checks(&exr, &v, "opencv", "planar", 3072);
    assert_eq!(v["cv2_points"], v["hits"]);
    assert!(num(&v, "reproj_max_px") < 1e-3, "{v}");
    assert_eq!(v["euclid_pixels"], 0);
    assert!(num(&v, "planar_rel") < 1e-6, "{v}");
    assert_eq!(v["planar_below_distance"], true);
}

/// A strong distortion that rises to r_d = 3.04 at r = 1.367 and folds beyond, while the
/// image corners need r_d = 1.364 only: Newton from the undistorted corner lands past the
/// fold, on a mirrored sheet whose ray points 60° the other way (and sees cylinder 2
/// there). Every pixel's ray is the one on the axis's sheet: each hit projects back onto
/// its own pixel by `cv2.projectPoints`.
#[test]
fn opencv_rays_stay_on_the_axis_side_of_a_fold() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let dir = common::fresh_dir("camera-models", "opencv-fold");
    let scene = r#"{"camera": {"origin": [0, 0, 0], "target": [1, 0, 0], "up": [0, 0, 1],
        "model": "opencv", "fx": 21.480559426740786, "fy": 21.480559426740786,
        "cx": 23.5, "cy": 17.5, "k1": 0.42541429036981393, "k2": 0.919193210524019,
        "k3": -0.4259741016336118, "width": 48, "height": 36},
      "cylinders": [
        {"p0": [5, 3.385, 2.22], "p1": [5, 3.385, 2.82], "radius": 0.3, "id": 1},
        {"p0": [5, -6.88, -5.96], "p1": [5, -6.88, -4.36], "radius": 0.8, "id": 2}]}"#;
    let exr = render_scene(dir.path(), "fold", scene);
    let v = check(&py, &exr);
    assert!(num(&v, "hits") >= 20.0, "{v}");
    assert_eq!(v["cv2_points"], v["hits"]);
    assert!(num(&v, "reproj_max_px") < 1e-3, "{v}");
}

#[test]
fn fisheye_positions_project_onto_their_pixel_centres_and_see_behind() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let dir = common::fresh_dir("camera-models", "fisheye");
    // fx = 18 on 64 px: the corners ask for θ_d = 2.2, rays about 125° off the axis.
    let [_, (_, fisheye), _] = common::lens_models();
    let exr = render(dir.path(), "fisheye", fisheye);
    let v = check(&py, &exr);
    // Every ray meets the tube, but a few within a hair of 90° meet it at a camera-space z
    // below near_clip (planar clips bound z): 3 of 3072 pixels.
    common_checks(&exr, &v, "opencv_fisheye", "planar_in_front", 3060);
    assert!(num(&v, "reproj_max_px") < 1e-3, "{v}");
    // Both rules appear: rays in front (planar) and behind the image plane (Euclidean).
    assert!(v["cv2_points"].as_u64().unwrap() > 1500, "{v}");
    assert!(v["euclid_pixels"].as_u64().unwrap() > 200, "{v}");
    assert!(num(&v, "planar_rel") < 1e-6, "{v}");
    assert_eq!(v["planar_below_distance"], true);
    assert_eq!(v["euclid_equal"], true);
}

#[test]
fn equirectangular_positions_have_their_pixels_longitude_and_latitude() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let dir = common::fresh_dir("camera-models", "equirect");
    let exr = render(
        dir.path(),
        "equirect",
        serde_json::json!({"model": "equirectangular"}),
    );
    let v = check(&py, &exr);
    common_checks(&exr, &v, "equirectangular", "euclidean", 3072);
    assert!(num(&v, "lat_max_rad") < 1e-6, "{v}");
    // Longitude is ill-conditioned near the poles (f32 positions): measured as arc length.
    assert!(num(&v, "lon_cos_lat_max_rad") < 1e-6, "{v}");
    assert_eq!(v["planar_pixels"], 0);
    assert_eq!(v["euclid_equal"], true);
}

#[test]
fn orthographic_rays_are_parallel_from_their_pixels() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let dir = common::fresh_dir("camera-models", "ortho");
    let exr = render(
        dir.path(),
        "ortho",
        serde_json::json!({"model": "orthographic", "ortho_width": 7.5}),
    );
    let v = check(&py, &exr);
    common_checks(&exr, &v, "orthographic", "planar", 3072);
    // Every hit lies on its pixel's ray: lateral offsets as the pixel centre says.
    assert!(num(&v, "lateral_x_max") < 2e-6, "{v}");
    assert!(num(&v, "lateral_y_max") < 2e-6, "{v}");
    assert_eq!(v["distance_is_depth"], true);
    assert!(num(&v, "planar_rel") < 1e-6, "{v}");
}

/// An orthographic camera sees a closed cylinder side-on as the rectangle of its
/// silhouette, whatever the distance: exactly the pixels whose centres fall inside it.
#[test]
fn orthographic_silhouette_of_a_cylinder_is_its_rectangle() {
    let dir = common::fresh_dir("camera-models", "ortho-rect");
    let scene = serde_json::json!({
        "camera": {"origin": [0, -10, 0], "target": [0, 0, 0], "up": [0, 0, 1],
            "width": 40, "height": 30, "model": "orthographic", "ortho_width": 4},
        "cylinders": [{"p0": [0, 0, -1.0], "p1": [0, 0, 1.0], "radius": 0.5}]
    });
    let path = dir.path().join("rect.json");
    std::fs::write(&path, scene.to_string()).unwrap();
    let out = dir.path().join("rect.exr");
    let stdout = common::ok(&[
        "render",
        path.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--aov",
        "shape_id",
    ]);
    // 0.1 world units per pixel: |x| < 0.5 is 10 columns, |z| < 1 is 20 rows: 200 pixels.
    assert!(stdout.contains("200 hits"), "{stdout}");
}

/// A field the model does not read, a missing required one and a fisheye that folds are
/// each refused naming the field.
#[test]
fn model_fields_are_checked_by_name() {
    let dir = common::fresh_dir("camera-models", "refuse");
    let cases = [
        (
            serde_json::json!({"model": "opencv", "fx": 40, "fy": 40, "cx": 30, "cy": 20, "fov_deg": 40}),
            "camera.fov_deg: is not a parameter of model \"opencv\"",
        ),
        (
            serde_json::json!({"model": "opencv_fisheye", "fx": 40, "fy": 40, "cx": 30}),
            "camera.cy: is required by model \"opencv_fisheye\"",
        ),
        (
            serde_json::json!({"model": "opencv_fisheye", "fx": 10, "fy": 10, "cx": 30, "cy": 20, "k1": -0.3}),
            "camera.k1: the fisheye polynomial with k = [-0.3, 0.0, 0.0, 0.0] stops increasing at θ = 52.304°",
        ),
        (
            serde_json::json!({"model": "orthographic", "ortho_width": 0}),
            "camera.ortho_width: must be finite, > 0",
        ),
        // A subnormal width halves to zero; one under the spacing of coordinates at the
        // origin (4, whose ulp is 8.9e-16) moves no pixel's ray either.
        (
            serde_json::json!({"model": "orthographic", "ortho_width": 5e-324}),
            "camera.ortho_width: is too small: 5e-324 over 64x48 pixels is a pixel 0 wide",
        ),
        (
            serde_json::json!({"model": "orthographic", "ortho_width": 1e-13}),
            "camera.ortho_width: is too small: 1e-13 over 64x48 pixels is a pixel 1.5625e-15 wide, not more than the spacing of coordinates at the camera's origin (3.552713678800501e-15)",
        ),
        (
            serde_json::json!({"model": "equirectangular", "p1": 0}),
            "camera.p1: is not a parameter of model \"equirectangular\"",
        ),
        (
            serde_json::json!({}),
            "camera.fov_deg: is required by model \"perspective\"",
        ),
        (
            serde_json::json!({"fov_deg": 40, "fx": 3}),
            "camera.fx: is not a parameter of model \"perspective\" (it reads fov_deg, fov_axis)",
        ),
    ];
    for (k, (model, want)) in cases.iter().enumerate() {
        let mut cam = serde_json::json!({
            "origin": [0, -4, 0], "target": [0, 0, 0], "up": [0, 0, 1], "width": 64, "height": 48
        });
        for (f, v) in model.as_object().unwrap() {
            cam[f] = v.clone();
        }
        let path = dir.path().join(format!("bad{k}.json"));
        std::fs::write(
            &path,
            serde_json::json!({"camera": cam, "cylinders": []}).to_string(),
        )
        .unwrap();
        let out = dir.path().join(format!("bad{k}.exr"));
        let o = common::cylaov(&[
            "render",
            path.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.contains(want), "want {want:?}, got {err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(!out.exists());
    }
}

/// `export-mitsuba` writes an orthographic camera as Mitsuba's `orthographic` sensor whose
/// rays are ours: Mitsuba's own `sample_ray` at each pixel centre passes through the hit
/// cylaov found there, along the same direction. The lens models are refused, saying why.
#[test]
fn mitsuba_orthographic_sensor_casts_our_rays_and_lens_models_are_refused() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let dir = common::fresh_dir("camera-models", "mitsuba");
    let exr = render(
        dir.path(),
        "ortho",
        serde_json::json!({"model": "orthographic", "ortho_width": 7.5}),
    );
    let xml = dir.path().join("ortho.xml");
    let scene = dir.path().join("ortho.json");
    common::ok(&[
        "export-mitsuba",
        scene.to_str().unwrap(),
        "-o",
        xml.to_str().unwrap(),
    ]);
    let script = r#"
import json, sys, numpy as np, mitsuba as mi, OpenEXR
mi.set_variant("scalar_rgb")
s = mi.load_file(sys.argv[1]).sensors()[0]
ch = OpenEXR.File(sys.argv[2]).channels()
pos = np.stack([ch[f"position.{a}"].pixels for a in "XYZ"], -1).astype(np.float64)
ids = ch["shape_id"].pixels
H, W = ids.shape
off, ang = 0.0, 0.0
for j, i in zip(*np.nonzero(ids)):
    r, _ = s.sample_ray(0.0, 0.5, mi.Point2f((i + 0.5) / W, (j + 0.5) / H), mi.Point2f(0.5, 0.5))
    o, d = np.array(r.o, float), np.array(r.d, float)
    v = pos[j, i] - o
    off = max(off, float(np.linalg.norm(v - v.dot(d) * d)))
    ang = max(ang, float(np.linalg.norm(np.cross(d, np.array(s.world_transform() @ mi.Vector3f(0, 0, 1))))))
print(json.dumps({"type": type(s).__name__, "hits": int((ids > 0).sum()), "off_max": off, "dir_max": ang}))
"#;
    let out = std::process::Command::new(&py)
        .args(["-c", script, xml.to_str().unwrap(), exr.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    eprintln!("mitsuba orthographic: {v}");
    assert_eq!(v["hits"], 3072);
    // Mitsuba's rays are float32: hits a few units away lie within 2.1e-6 of them.
    assert!(num(&v, "off_max") < 1e-5, "{v}");
    assert!(num(&v, "dir_max") < 1e-6, "{v}");

    for (name, model) in [
        (
            "opencv",
            serde_json::json!({"model": "opencv", "fx": 40, "fy": 40, "cx": 31.5, "cy": 23.5}),
        ),
        ("equirect", serde_json::json!({"model": "equirectangular"})),
    ] {
        render(dir.path(), name, model.clone());
        let scene = dir.path().join(format!("{name}.json"));
        let xml = dir.path().join(format!("{name}.xml"));
        let o = common::cylaov(&[
            "export-mitsuba",
            scene.to_str().unwrap(),
            "-o",
            xml.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        let want = format!(
            "camera.model: Mitsuba 3 has no \"{}\" sensor (only the pinhole `perspective` and `orthographic`)",
            model["model"].as_str().unwrap()
        );
        assert!(err.contains(&want), "{err}");
        assert!(!xml.exists());
    }
}

/// A batch of a scene with four camera models: `transforms.json` names camera 0's
/// nerfstudio model at the top and each other view's model on its frame, with nerfstudio's
/// parameter names and its half-pixel principal point; only the pinhole view has an Open3D
/// file; a second run skips every view, and a changed coefficient renders that view again.
#[test]
fn batch_transforms_name_each_view_model() {
    let dir = common::fresh_dir("camera-models", "batch");
    let scenes = dir.path().join("scenes");
    std::fs::create_dir(&scenes).unwrap();
    let base = serde_json::json!({
        "origin": [0, -4, 0.3], "target": [0, 0, 0], "up": [0, 0, 1], "width": 32, "height": 24
    });
    let with = |extra: Value| {
        let mut c = base.clone();
        for (k, v) in extra.as_object().unwrap() {
            c[k] = v.clone();
        }
        c
    };
    let mut scene = serde_json::json!({
        "cameras": [
            with(serde_json::json!({"model": "opencv_fisheye", "fx": 12, "fy": 12.5, "cx": 15.5, "cy": 11.25, "k1": 0.01})),
            with(serde_json::json!({"model": "equirectangular"})),
            with(serde_json::json!({"fov_deg": 50})),
            with(serde_json::json!({"model": "orthographic", "ortho_width": 5})),
            with(serde_json::json!({"model": "opencv", "fx": 30, "fy": 30, "cx": 15.5, "cy": 11.5, "p2": 0.001})),
        ],
        "cylinders": [{"p0": [-1, 0, -1], "p1": [-1, 0, 1], "radius": 0.4},
                      {"p0": [1, 0, -1], "p1": [1, 0, 1], "radius": 0.4}]
    });
    std::fs::write(scenes.join("multi.json"), scene.to_string()).unwrap();
    let out = dir.path().join("out");
    let run = || {
        common::ok(&[
            "batch",
            scenes.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--threads",
            "2",
        ])
    };
    let first = run();
    assert!(first.contains("done 5 / skipped 0"), "{first}");
    let t: Value =
        serde_json::from_slice(&std::fs::read(out.join("multi/transforms.json")).unwrap()).unwrap();
    assert_eq!(t["camera_model"], "OPENCV_FISHEYE");
    let f = &t["frames"];
    assert!(f[0].get("camera_model").is_none());
    assert_eq!(
        [&f[0]["fl_x"], &f[0]["fl_y"], &f[0]["cx"], &f[0]["cy"]],
        [12.0, 12.5, 16.0, 11.75]
    );
    assert_eq!([&f[0]["k1"], &f[0]["k4"]], [0.01, 0.0]);
    assert!(f[0].get("p1").is_none());
    assert_eq!(f[1]["camera_model"], "EQUIRECTANGULAR");
    assert_eq!([&f[1]["fl_x"], &f[1]["fl_y"]], [16.0, 24.0]);
    assert_eq!(f[2]["camera_model"], "OPENCV");
    assert!(f[2].get("k1").is_none());
    assert_eq!(f[3]["camera_model"], "ORTHOPHOTO");
    assert_eq!([&f[3]["fl_x"], &f[3]["fl_y"]], [6.4, 6.4]);
    assert_eq!(f[4]["camera_model"], "OPENCV");
    assert_eq!([&f[4]["p2"], &f[4]["cx"]], [0.001, 16.0]);
    assert!(f[4].get("k4").is_none());
    for (k, frame) in f.as_array().unwrap().iter().enumerate() {
        let o3d = out.join(format!("multi/{k:02}.open3d.json"));
        assert_eq!(frame.get("open3d_file_path").is_some(), k == 2);
        assert_eq!(o3d.exists(), k == 2);
    }
    let again = run();
    assert!(again.contains("done 0 / skipped 5"), "{again}");
    scene["cameras"][0]["k1"] = serde_json::json!(0.02);
    std::fs::write(scenes.join("multi.json"), scene.to_string()).unwrap();
    let changed = run();
    assert!(changed.contains("done 1 / skipped 4"), "{changed}");
}

/// `generate --camera-model`: the same seed draws the same cylinders and (but for the
/// orthographic camera, moved back along its view) the same camera poses under every
/// model; the lens parameters lie in the documented ranges, one lens per scene; every
/// draw validates (the fisheye polynomial stays monotonic out to the corners) and sees
/// the scene.
#[test]
fn generate_draws_each_model_around_the_same_scene() {
    use cylaov::dataset::generate::GenerateOptions;
    use cylaov::render::{RenderOptions, render};
    use cylaov::scene::Aov;
    use cylaov::scene::camera::model::CameraModel;

    let base = GenerateOptions {
        width: 48,
        height: 32,
        views_per_scene: 3,
        ..GenerateOptions::default()
    };
    for model in CameraModel::ALL {
        let o = GenerateOptions {
            camera_model: model,
            ..base.clone()
        };
        let (mut covered, mut pixels) = (0usize, 0usize);
        for index in 0..60 {
            let pinhole = base.scene(11, index).unwrap();
            let file = o.scene(11, index).unwrap();
            assert_eq!(
                serde_json::to_value(&file.cylinders).unwrap(),
                serde_json::to_value(&pinhole.cylinders).unwrap(),
                "{model:?} view {index}: the cylinders are the seed's"
            );
            let (cams, pins) = (file.cameras.clone().unwrap(), pinhole.cameras.unwrap());
            let first = serde_json::to_value(&cams[0]).unwrap();
            for (c, p) in cams.iter().zip(&pins) {
                assert_eq!(c.model, model);
                assert_eq!(c.target, p.target);
                let (o1, o0, t) = (
                    glam::DVec3::from_array(c.origin),
                    glam::DVec3::from_array(p.origin),
                    glam::DVec3::from_array(p.target),
                );
                if model == CameraModel::Orthographic {
                    // Same direction from the target, farther back.
                    let (a, b) = ((o1 - t).normalize(), (o0 - t).normalize());
                    assert!((a - b).length() < 1e-12, "{a} {b}");
                    // Nothing of the scene behind its image plane.
                    for cyl in &file.cylinders {
                        for q in [cyl.p0.unwrap(), cyl.p1.unwrap()] {
                            let ahead = (glam::DVec3::from_array(q) - o1).dot(-a);
                            assert!(ahead - cyl.radius > c.near_clip, "{ahead}");
                        }
                    }
                } else if matches!(
                    model,
                    CameraModel::OpencvFisheye | CameraModel::Equirectangular
                ) {
                    // Same direction from the target, closer.
                    let (a, b) = ((o1 - t).normalize(), (o0 - t).normalize());
                    assert!((a - b).length() < 1e-12, "{a} {b}");
                    assert!((o1 - t).length() < (o0 - t).length());
                } else {
                    assert_eq!(c.origin, p.origin);
                }
                // One lens per scene: every camera has camera 0's parameters.
                let v = serde_json::to_value(c).unwrap();
                for k in ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4", "p1", "p2"] {
                    assert_eq!(v.get(k), first.get(k), "{model:?} {k}");
                }
            }
            let c = &cams[0];
            let within = |v: Option<f64>, lim: f64| v.is_some_and(|v| v.abs() <= lim);
            match model {
                CameraModel::Perspective => assert_eq!(c.fov_deg, Some(50.0)),
                CameraModel::Orthographic => assert!(c.ortho_width.unwrap() > 0.0),
                CameraModel::Opencv => {
                    let f = 24.0 / (25f64.to_radians()).tan();
                    assert!((c.fx.unwrap() - f).abs() < 1e-9 && c.fy == c.fx);
                    assert_eq!((c.cx, c.cy), (Some(23.5), Some(15.5)));
                    let k1 = c.k1.unwrap();
                    assert!((-0.25..0.05).contains(&k1), "k1 {k1}");
                    assert!(within(c.k2, 0.02) && within(c.p1, 1e-3) && within(c.p2, 1e-3));
                    assert_eq!(c.k3, Some(0.0));
                }
                CameraModel::OpencvFisheye => {
                    let f = 47f64.hypot(31.0) / std::f64::consts::PI;
                    assert!((c.fx.unwrap() - f).abs() < 1e-9 && c.fy == c.fx);
                    assert!(within(c.k1, 0.02) && within(c.k2, 2e-3));
                    assert!(within(c.k3, 2e-4) && within(c.k4, 2e-5));
                }
                CameraModel::Equirectangular => assert!(c.fx.is_none() && c.fov_deg.is_none()),
            }
            let scene = file.validate().unwrap();
            let r = render(&scene, &RenderOptions::new(vec![Aov::ShapeId]));
            covered += r.hits;
            pixels += 48 * 32;
        }
        // Measured share of hit pixels over these 60 scenes: perspective 0.096,
        // orthographic 0.101, opencv 0.094, fisheye 0.089, equirectangular 0.145; a model
        // that framed its scenes badly (the fisheye from the pinhole's distance: 0.011,
        // the panorama from outside the scene: 0.003) falls under the bound.
        let share = covered as f64 / pixels as f64;
        eprintln!("{model:?}: {share:.3} of pixels hit");
        assert!(share > 0.05, "{model:?}: {share}");
    }
}

/// `cameras --orbit` takes its size from the scene's first camera whatever its model, and
/// its field of view only from a pinhole: an orthographic 320×240 first camera gives
/// 320×240 pinholes of 50°.
#[test]
fn a_rig_takes_the_first_cameras_size_whatever_its_model() {
    let dir = common::fresh_dir("camera-models", "rig-size");
    let scene = dir.path().join("ortho.json");
    std::fs::write(
        &scene,
        r#"{"camera": {"origin": [0, -4, 0], "target": [0, 0, 0], "up": [0, 0, 1],
            "model": "orthographic", "ortho_width": 3, "width": 320, "height": 240},
          "cylinders": [{"p0": [0, 0, -1], "p1": [0, 0, 1], "radius": 0.5}]}"#,
    )
    .unwrap();
    let out = dir.path().join("rig.json");
    common::ok(&[
        "cameras",
        scene.to_str().unwrap(),
        "--orbit",
        "3",
        "-o",
        out.to_str().unwrap(),
    ]);
    let s = cylaov::scene::load(&out).unwrap();
    assert_eq!(s.cameras.len(), 3);
    for c in &s.cameras {
        assert_eq!((c.width, c.height), (320, 240));
        assert!(c.projection.is_pinhole());
        assert_eq!(c.fov_deg, 50.0);
    }
}

/// Times `Lens::validate` (every pixel unprojected) for 1920×1080 OpenCV cameras, a mild
/// and a strong distortion, and a fisheye: run with `--ignored --nocapture` to compare
/// builds on one machine.
#[test]
#[ignore]
fn lens_validation_timing_1920x1080() {
    use cylaov::scene::camera::lens::Lens;
    let lenses = [
        (
            "opencv mild",
            Lens::OpenCv {
                fx: 1200.0,
                fy: 1260.0,
                cx: 959.5,
                cy: 539.5,
                dist: [-0.21, 0.04, 0.0012, -0.0017, 0.005],
            },
        ),
        (
            "opencv strong",
            Lens::OpenCv {
                fx: 900.0,
                fy: 900.0,
                cx: 955.0,
                cy: 545.0,
                dist: [
                    0.42541429036981393,
                    0.919193210524019,
                    0.01,
                    -0.02,
                    -0.4259741016336118,
                ],
            },
        ),
        (
            "fisheye",
            Lens::OpenCvFisheye {
                fx: 540.0,
                fy: 555.0,
                cx: 948.0,
                cy: 702.0,
                k: [0.03, -0.004, 0.0006, -0.00003],
            },
        ),
    ];
    for (name, lens) in lenses {
        let mut best = f64::INFINITY;
        for _ in 0..3 {
            let t = std::time::Instant::now();
            lens.validate(1920, 1080).unwrap();
            best = best.min(t.elapsed().as_secs_f64());
        }
        println!("validate 1920x1080 {name}: {best:.3} s (best of 3)");
    }
}
