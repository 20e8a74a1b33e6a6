//! Datasets with several views per scene, end to end through the binary: scene files with
//! `"cameras"`, `generate --views-per-scene`, the batch layout (`OUT/<scene>/NN.*`,
//! `OUT/<scene>/transforms.json`, `OUT/index.json`), `render --camera`, the Mitsuba export
//! of every camera, and the 16-bit depth PNG that fails rather than lose far pixels.

mod common;
use common::{cylaov, ok};

use cylaov::image::AovImage;
use std::path::Path;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn fresh_dir(name: &str) -> tempfile::TempDir {
    common::fresh_dir("dataset", name)
}

fn fails(args: &[&str]) -> String {
    let out = cylaov(args);
    assert!(!out.status.success(), "cylaov {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap_or_else(|e| panic!("{path:?}: {e}")))
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

const SMALL: &[&str] = &["--width", "64", "--height", "48", "--cylinders", "3..6"];

fn generate(out: &Path, count: &str, views: &str) {
    let mut args = vec!["generate", "--count", count, "--seed", "5", "--out", s(out)];
    args.extend_from_slice(SMALL);
    args.extend_from_slice(&["--views-per-scene", views]);
    ok(&args);
}

/// `--views-per-scene 1` is byte-identical to no option, and camera 0 of a several-camera
/// scene is the camera the one-camera scene gets.
#[test]
fn one_view_per_scene_keeps_the_bytes_and_camera_0_is_shared() {
    let tmp = fresh_dir("gen");
    let dir = tmp.path();
    let plain = dir.join("plain");
    let mut args = vec![
        "generate",
        "--count",
        "3",
        "--seed",
        "5",
        "--out",
        s(&plain),
    ];
    args.extend_from_slice(SMALL);
    ok(&args);
    let one = dir.join("one");
    generate(&one, "3", "1");
    let three = dir.join("three");
    generate(&three, "3", "3");
    for f in [
        "scenes/000000.json",
        "scenes/000002.json",
        "manifest.jsonl",
        "generate.json",
    ] {
        assert_eq!(
            std::fs::read(plain.join(f)).unwrap(),
            std::fs::read(one.join(f)).unwrap(),
            "{f}"
        );
    }
    for k in 0..3 {
        let name = format!("scenes/{k:06}.json");
        let a = json(&one.join(&name));
        let b = json(&three.join(&name));
        assert!(a.get("cameras").is_none() && b.get("camera").is_none());
        let cams = b["cameras"].as_array().unwrap();
        assert_eq!(cams.len(), 3);
        assert_eq!(cams[0], a["camera"], "{name}: camera 0");
        assert_ne!(cams[1], cams[0]);
        assert_eq!(a["cylinders"], b["cylinders"], "{name}: same cylinders");
    }
    assert_eq!(json(&three.join("generate.json"))["views_per_scene"], 3);
}

/// Scene files take exactly one of "camera" and "cameras".
#[test]
fn camera_and_cameras_are_exclusive() {
    let tmp = fresh_dir("exclusive");
    let dir = tmp.path();
    let cam = r#"{"origin": [3, -5, 2], "target": [0, 0, 0], "up": [0, 0, 1], "fov_deg": 40, "width": 32, "height": 24}"#;
    let cyl = r#""cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.3}]"#;
    for (body, want) in [
        (
            format!(r#"{{"camera": {cam}, "cameras": [{cam}], {cyl}}}"#),
            "exactly one of \"camera\" and \"cameras\", got both",
        ),
        (format!(r#"{{{cyl}}}"#), "missing the camera"),
        (
            format!(r#"{{"cameras": [], {cyl}}}"#),
            "cameras: must list at least one camera",
        ),
        (
            format!(
                r#"{{"cameras": [{cam}, {}], {cyl}}}"#,
                cam.replace("40", "0")
            ),
            "cameras[1].fov_deg: must be in (0, 180), got 0",
        ),
    ] {
        let path = dir.join("s.json");
        std::fs::write(&path, &body).unwrap();
        let err = fails(&["render", s(&path), "-o", s(&dir.join("x.exr"))]);
        assert!(err.contains(want), "{body}\n{err}");
        assert!(!dir.join("x.exr").exists());
    }
}

/// The layout: a several-camera scene in `OUT/<scene>/`, views `00`, `01`, … with that
/// scene's `transforms.json` (relative paths); one-camera scenes flat; `index.json` lists
/// every view with its scene and camera. `render --camera K` and view K agree bit for bit,
/// and the Mitsuba export has one sensor per camera.
#[test]
fn several_cameras_make_a_folder_per_scene_and_one_index() {
    let tmp = fresh_dir("layout");
    let dir = tmp.path();
    let multi = dir.join("multi");
    generate(&multi, "2", "3");
    let input = dir.join("input");
    std::fs::create_dir_all(&input).unwrap();
    for k in 0..2 {
        let f = format!("{k:06}.json");
        std::fs::copy(multi.join("scenes").join(&f), input.join(format!("m{f}"))).unwrap();
    }
    std::fs::copy(
        Path::new(ROOT).join("scenes/single.json"),
        input.join("single.json"),
    )
    .unwrap();
    let out = dir.join("out");
    // A dataset of an older version: its index of unrelated scenes must not survive.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("transforms.json"), "{\"frames\": []}").unwrap();
    let text = ok(&["batch", s(&input), "--out", s(&out)]);
    assert!(
        text.contains("done 7 / skipped 0 / failed 0 of 7 views"),
        "{text}"
    );
    assert!(!out.join("transforms.json").exists(), "stale index left");

    let index = json(&out.join("index.json"));
    let views = index["views"].as_array().unwrap();
    let listed: Vec<(String, u64, String)> = views
        .iter()
        .map(|v| {
            (
                v["scene"].as_str().unwrap().to_string(),
                v["camera"].as_u64().unwrap(),
                v["exr_file_path"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    let want: Vec<(String, u64, String)> = [
        ("m000000", 0, "m000000/00.exr"),
        ("m000000", 1, "m000000/01.exr"),
        ("m000000", 2, "m000000/02.exr"),
        ("m000001", 0, "m000001/00.exr"),
        ("m000001", 1, "m000001/01.exr"),
        ("m000001", 2, "m000001/02.exr"),
        ("single", 0, "single.exr"),
    ]
    .iter()
    .map(|(a, b, c)| (a.to_string(), *b, c.to_string()))
    .collect();
    assert_eq!(listed, want);
    for v in views {
        for key in [
            "file_path",
            "depth_file_path",
            "mask_path",
            "exr_file_path",
            "camera_file_path",
            "open3d_file_path",
        ] {
            let p = out.join(v[key].as_str().unwrap());
            assert!(p.is_file(), "{key}: {p:?}");
        }
    }

    let scene_dir = out.join("m000001");
    let t = json(&scene_dir.join("transforms.json"));
    let frames = t["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 3);
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(f["file_path"], format!("{k:02}.normal.preview.png"));
        assert_eq!(f["mask_path"], format!("{k:02}.mask.png"));
        assert!(
            scene_dir
                .join(f["depth_file_path"].as_str().unwrap())
                .is_file()
        );
        let cam = json(&scene_dir.join(format!("{k:02}.camera.json")));
        assert_eq!(f["transform_matrix"], cam["camera_to_world_opengl"]);
        assert_eq!(f["transform_matrix"], views[3 + k]["transform_matrix"]);
    }
    assert!(!out.join("single").exists() && out.join("single.exr").is_file());

    // render --camera 2 is view 02, pixel for pixel; a camera that does not exist is refused.
    let scene = input.join("m000001.json");
    let exr = dir.join("r.exr");
    ok(&["render", s(&scene), "-o", s(&exr), "--camera", "2"]);
    assert_eq!(
        AovImage::read_exr(&exr).unwrap(),
        AovImage::read_exr(&scene_dir.join("02.exr")).unwrap()
    );
    let err = fails(&[
        "render",
        s(&scene),
        "-o",
        s(&dir.join("n.exr")),
        "--camera",
        "3",
    ]);
    assert!(err.contains("3 camera(s), numbered 0..=2, got 3"), "{err}");

    // export-mitsuba: one sensor per camera, in file order.
    let xml = dir.join("m.xml");
    ok(&["export-mitsuba", s(&scene), "-o", s(&xml)]);
    let xml = std::fs::read_to_string(&xml).unwrap();
    assert_eq!(xml.matches("<sensor type=\"perspective\">").count(), 3);
    let cams = json(&scene)["cameras"].clone();
    let origins: Vec<usize> = (0..3)
        .map(|k| {
            let o = cams[k]["origin"][0].as_f64().unwrap().to_string();
            xml.find(&format!("origin=\"{o}")).unwrap()
        })
        .collect();
    assert!(origins.windows(2).all(|w| w[0] < w[1]), "{origins:?}");

    // Resume: every view is skipped, the index bytes unchanged.
    let before = std::fs::read(out.join("index.json")).unwrap();
    let text = ok(&["batch", s(&input), "--out", s(&out)]);
    assert!(text.contains("done 0 / skipped 7"), "{text}");
    assert_eq!(std::fs::read(out.join("index.json")).unwrap(), before);
}

/// The far camera: 11 099 hits in the EXR would all be beyond 65.535 units at the default
/// scale. By default the view fails with its range and a scale that fits, and writes
/// nothing; `--depth-out-of-range zero` stores them as 0 and says how many.
#[test]
fn far_depth_fails_loudly_or_zeroes_with_a_count() {
    let tmp = fresh_dir("far");
    let dir = tmp.path();
    let input = dir.join("in");
    std::fs::create_dir_all(&input).unwrap();
    std::fs::copy(
        Path::new(ROOT).join("scenes/far_camera.json"),
        input.join("far.json"),
    )
    .unwrap();
    let out = dir.join("out");
    let o = cylaov(&["batch", s(&input), "--out", s(&out)]);
    assert!(!o.status.success());
    let failures = std::fs::read_to_string(out.join("failures.0-of-1.jsonl")).unwrap();
    assert!(
        failures.contains("11099 hit pixels do not fit 16 bits at --depth-scale 1000"),
        "{failures}"
    );
    assert!(
        failures.contains("the largest --depth-scale that fits is"),
        "{failures}"
    );
    for f in [
        "far.exr",
        "far.depth.png",
        "far.camera.json",
        "far.mask.png",
    ] {
        assert!(!out.join(f).exists(), "{f} written for a failed view");
    }
    // The scale the message names does fit.
    let hint: f64 = failures
        .split("fits is ")
        .nth(1)
        .and_then(|r| r.split(',').next())
        .unwrap()
        .parse()
        .unwrap();
    let text = ok(&[
        "batch",
        s(&input),
        "--out",
        s(&out),
        "--depth-scale",
        &hint.to_string(),
    ]);
    assert!(text.contains("done 1 /"), "{text}");
    let png = image::open(out.join("far.depth.png"))
        .unwrap()
        .into_luma16();
    let nonzero = png.pixels().filter(|p| p.0[0] > 0).count();
    assert_eq!(nonzero, 11099);
    assert!(
        png.pixels().any(|p| p.0[0] >= 65000),
        "the hint is near the top of the range"
    );

    let o = cylaov(&[
        "batch",
        s(&input),
        "--out",
        s(&dir.join("zero")),
        "--depth-out-of-range",
        "zero",
    ]);
    assert!(o.status.success());
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stdout.contains("depth PNG: 11099 hit pixels beyond 16 bits stored as 0 in 1 views"),
        "{stdout}"
    );
    assert!(
        stderr.contains("far: depth PNG: 11099 hit pixels"),
        "{stderr}"
    );
    let png = image::open(dir.join("zero/far.depth.png"))
        .unwrap()
        .into_luma16();
    assert!(png.pixels().all(|p| p.0[0] == 0));
}

/// `normal_camera` is the world normal in OpenCV camera axes (the camera JSON's
/// world_to_camera_opencv rotation), unit length, 0 on a miss.
#[test]
fn normal_camera_is_the_world_normal_in_opencv_axes() {
    let tmp = fresh_dir("normal-camera");
    let dir = tmp.path();
    let exr = dir.join("c.exr");
    let scene = Path::new(ROOT).join("scenes/cluster.json");
    ok(&[
        "render",
        s(&scene),
        "-o",
        s(&exr),
        "--aov",
        "depth,normal,normal_camera",
    ]);
    let img = AovImage::read_exr(&exr).unwrap();
    let cam = json(&dir.join("c.camera.json"));
    let m = &cam["world_to_camera_opencv"];
    let r = |i: usize, j: usize| m[i][j].as_f64().unwrap();
    let [wx, wy, wz] = img.vec3_channel("normal").unwrap();
    let [cx, cy, cz] = img.vec3_channel("normal_camera").unwrap();
    let depth = img.f32_channel("depth").unwrap();
    let (mut worst, mut hits) = (0.0f64, 0);
    for k in 0..depth.len() {
        let c = [cx[k] as f64, cy[k] as f64, cz[k] as f64];
        if depth[k] == 0.0 {
            assert_eq!(c, [0.0; 3], "pixel {k}: a miss");
            continue;
        }
        hits += 1;
        let w = [wx[k] as f64, wy[k] as f64, wz[k] as f64];
        for (i, ci) in c.iter().enumerate() {
            let want = r(i, 0) * w[0] + r(i, 1) * w[1] + r(i, 2) * w[2];
            worst = worst.max((ci - want).abs());
        }
        let len = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-6, "pixel {k}: |n| = {len}");
    }
    // One rounding to f32 of a rotation of the stored normal: half an f32 ulp of 1 (6e-8)
    // plus the rotation's f64 rounding.
    assert!(
        hits > 1000 && worst <= 1.2e-7,
        "{hits} hits, worst {worst:e}"
    );
}

/// Ids above 2^24 cannot be stored exactly as float32: the per-AOV layout refuses them and
/// writes nothing; the layered file stores them as u32.
#[test]
fn per_aov_layout_refuses_ids_a_float_cannot_hold() {
    let tmp = fresh_dir("big-id");
    let dir = tmp.path();
    let scene = dir.join("s.json");
    std::fs::write(
        &scene,
        r#"{"camera": {"origin": [3, -5, 2], "target": [0, 0, 0.5], "up": [0, 0, 1], "fov_deg": 40, "width": 32, "height": 24},
            "cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.5, "id": 16777217}]}"#,
    )
    .unwrap();
    let out = dir.join("o.exr");
    let err = fails(&[
        "render",
        s(&scene),
        "-o",
        s(&out),
        "--aov",
        "depth,shape_id",
        "--exr-layout",
        "per-aov",
    ]);
    assert!(
        err.contains("shape_id 16777217 does not fit a float32 channel exactly"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        left,
        vec![std::ffi::OsString::from("s.json")],
        "nothing written"
    );
    ok(&[
        "render",
        s(&scene),
        "-o",
        s(&out),
        "--aov",
        "depth,shape_id",
    ]);
    let img = AovImage::read_exr(&out).unwrap();
    assert!(
        img.u32_channel("shape_id")
            .unwrap()
            .iter()
            .any(|&id| id == 16777217)
    );
}

/// The per-AOV layout resumes like the layered one, and switching layouts renders again and
/// leaves only the new layout's EXRs.
#[test]
fn per_aov_layout_resumes_and_switches_cleanly() {
    let tmp = fresh_dir("per-aov");
    let dir = tmp.path();
    let data = dir.join("data");
    generate(&data, "2", "2");
    let out = dir.join("out");
    let run = |layout: &str| {
        ok(&[
            "batch",
            s(&data),
            "--out",
            s(&out),
            "--aov",
            "depth,normal",
            "--exr-layout",
            layout,
        ])
    };
    assert!(run("per-aov").contains("done 4 / skipped 0"));
    assert!(out.join("000001/01.normal.exr").is_file() && !out.join("000001/01.exr").exists());
    let normal = AovImage::read_exr(&out.join("000001/01.normal.exr")).unwrap();
    let names: Vec<&str> = normal.names();
    assert_eq!(names, ["B", "G", "R"]);
    assert!(run("per-aov").contains("done 0 / skipped 4"));
    // A truncated per-AOV file is caught by the resume check.
    let depth = out.join("000000/00.depth.exr");
    let bytes = std::fs::read(&depth).unwrap();
    std::fs::write(&depth, &bytes[..bytes.len() - 100]).unwrap();
    assert!(run("per-aov").contains("done 1 / skipped 3"));
    assert!(run("layers").contains("done 4 / skipped 0"));
    assert!(out.join("000001/01.exr").is_file());
    assert!(
        !out.join("000001/01.normal.exr").exists() && !out.join("000001/01.depth.exr").exists()
    );
}

/// `--orbit`: cameras 1.. circle camera 0's target at its distance and height, 360°/V apart.
#[test]
fn orbit_cameras_circle_the_target() {
    let tmp = fresh_dir("orbit");
    let dir = tmp.path();
    let out = dir.join("g");
    let mut args = vec!["generate", "--count", "2", "--seed", "5", "--out", s(&out)];
    args.extend_from_slice(SMALL);
    args.extend_from_slice(&["--views-per-scene", "4", "--orbit"]);
    ok(&args);
    let plain = dir.join("p");
    generate(&plain, "2", "1");
    let scene = json(&out.join("scenes/000001.json"));
    let cams = scene["cameras"].as_array().unwrap();
    assert_eq!(cams[0], json(&plain.join("scenes/000001.json"))["camera"]);
    let v3 = |c: &serde_json::Value, k: &str| -> [f64; 3] {
        let a = c[k].as_array().unwrap();
        [0, 1, 2].map(|i| a[i].as_f64().unwrap())
    };
    let t = v3(&cams[0], "target");
    let rel = |c: &serde_json::Value| {
        let o = v3(c, "origin");
        [o[0] - t[0], o[1] - t[1], o[2] - t[2]]
    };
    let r0 = rel(&cams[0]);
    for (k, c) in cams.iter().enumerate() {
        assert_eq!(v3(c, "target"), t);
        let r = rel(c);
        assert!((r[2] - r0[2]).abs() < 1e-12, "height of camera {k}");
        let (a0, a) = (r0[1].atan2(r0[0]), r[1].atan2(r[0]));
        let step = (a - a0).rem_euclid(std::f64::consts::TAU);
        let want = std::f64::consts::FRAC_PI_2 * k as f64;
        assert!(
            (step - want).abs() < 1e-9,
            "camera {k}: azimuth step {step}"
        );
        assert!((r[0].hypot(r[1]) - r0[0].hypot(r0[1])).abs() < 1e-9);
    }
    assert_eq!(json(&out.join("generate.json"))["orbit"], true);
}
