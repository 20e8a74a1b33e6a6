//! `compare --scene` checks that the scene's camera is the one A's header records: another
//! camera (of the same image size) or another camera model is refused with exit 2, naming
//! it, instead of judging A with that camera's float32 bounds.

mod common;

use cylaov::image::AovImage;
use cylaov::output::format::exr::Compression;

fn text(o: &std::process::Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn compare_refuses_a_scene_whose_camera_is_not_the_files() {
    let dir_tmp = common::fresh_dir("verify-compare", "camera");
    let dir = dir_tmp.path();
    let scene = |origin: serde_json::Value, model: Option<serde_json::Value>| {
        let mut camera = serde_json::json!({
            "origin": origin, "target": [0, 0, 0.6], "up": [0, 0, 1],
            "fov_deg": 40, "width": 32, "height": 24, "far_clip": 1e12
        });
        if let Some(serde_json::Value::Object(fields)) = model {
            camera.as_object_mut().expect("camera").remove("fov_deg");
            for (k, v) in fields {
                camera[k] = v;
            }
        }
        serde_json::json!({
            "camera": camera,
            "cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5},
                          {"p0": [1, 0.5, 0], "p1": [1.2, 0.7, 1], "radius": 0.2, "id": 9}]
        })
        .to_string()
    };
    let path = |n: &str| dir.join(n).to_str().expect("utf-8").to_string();
    std::fs::write(path("a.json"), scene(serde_json::json!([3, -5, 2.5]), None)).expect("a");
    std::fs::write(
        path("far.json"),
        scene(serde_json::json!([3e9, -5e9, 2.5e9]), None),
    )
    .expect("far");
    std::fs::write(
        path("moved.json"),
        scene(serde_json::json!([3, -5, 2.501]), None),
    )
    .expect("moved");
    std::fs::write(
        path("cv.json"),
        scene(
            serde_json::json!([3, -5, 2.5]),
            Some(serde_json::json!({"model": "opencv", "fx": 30, "fy": 30, "cx": 16, "cy": 12})),
        ),
    )
    .expect("cv");
    let o = common::cylaov(&[
        "render",
        &path("a.json"),
        "-o",
        &path("a.exr"),
        "--aov",
        "depth,distance,normal,shape_id,part",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    // B: cylinder 9's distance off by 1e-3 (relative), far above the flat bound.
    let mut b = AovImage::read_exr(std::path::Path::new(&path("a.exr"))).expect("a");
    let ids = b.u32_channel("shape_id").expect("ids").to_vec();
    let mut d = b.f32_channel_mut("distance").expect("distance");
    for (k, &id) in ids.iter().enumerate() {
        if id == 9 {
            d[k] *= 1.001;
        }
    }
    b.write_exr(std::path::Path::new(&path("b.exr")), Compression::None)
        .expect("b");
    let compare = |scene: &str| {
        common::cylaov(&[
            "compare",
            &path("a.exr"),
            &path("b.exr"),
            "--scene",
            &path(scene),
        ])
    };
    let o = compare("a.json");
    assert_eq!(
        o.status.code(),
        Some(1),
        "the right scene fails: {}",
        text(&o)
    );
    for (scene, why) in [
        ("far.json", "is not the one"),
        ("moved.json", "is not the one"),
        ("cv.json", "its camera is opencv, "),
    ] {
        let o = compare(scene);
        assert_eq!(o.status.code(), Some(2), "{scene}: {}", text(&o));
        assert!(text(&o).contains(why), "{scene}: {}", text(&o));
    }
}
