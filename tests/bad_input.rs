//! Bad scene input: one clear error naming the field and value, non-zero exit, no file
//! (the README's scene format). Runs the real binary.

use std::path::PathBuf;
use std::process::Command;

const GOOD_CAMERA: &str = r#""origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1],
    "fov_deg": 40, "width": 32, "height": 24"#;
const GOOD_CYL: &str = r#"{ "p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5 }"#;

fn scene(camera: &str, cylinders: &str) -> String {
    format!(r#"{{ "camera": {{ {camera} }}, "cylinders": [ {cylinders} ] }}"#)
}

fn tmp() -> PathBuf {
    let d = std::env::temp_dir().join(format!("cylaov-bad-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Render `json`; expect failure whose stderr contains every `needle`, and no output file.
fn rejects(name: &str, json: &str, needles: &[&str]) {
    let dir = tmp();
    let input = dir.join(format!("{name}.json"));
    let out = dir.join(format!("{name}.exr"));
    std::fs::write(&input, json).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args([
            "render",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{name}: accepted\n{json}");
    for n in needles {
        assert!(err.contains(n), "{name}: stderr lacks {n:?}:\n{err}");
    }
    assert_eq!(
        err.trim().lines().count(),
        1,
        "{name}: want one line:\n{err}"
    );
    assert!(!err.contains("panicked"), "{name}: panicked:\n{err}");
    assert!(!out.exists(), "{name}: wrote {}", out.display());
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.file_name().to_string_lossy().contains(name)
                && !e.file_name().to_string_lossy().ends_with(".json")
        })
        .collect();
    assert!(leftovers.is_empty(), "{name}: left {leftovers:?}");
}

#[test]
fn every_spec_case_is_rejected_clearly() {
    let cyl = |c: &str| scene(GOOD_CAMERA, c);
    let cam = |c: &str| scene(c, GOOD_CYL);
    rejects(
        "malformed",
        r#"{ "camera": { "origin": [1, 2"#,
        &["invalid JSON", "EOF"],
    );
    rejects("not_a_scene", "[1, 2, 3]", &["invalid JSON"]);
    rejects(
        "unknown_top",
        &format!(r#"{{"camera": {{ {GOOD_CAMERA} }}, "cylinders": [], "lights": 1}}"#),
        &["lights"],
    );
    rejects(
        "unknown_cyl",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1], "radius": 1, "colour": 3 }"#),
        &["cylinders[0]", "colour"],
    );
    rejects(
        "unknown_cam",
        &cam(&format!("{GOOD_CAMERA}, \"zoom\": 2")),
        &["camera", "zoom"],
    );
    rejects(
        "nan",
        &cyl(r#"{ "p0": [0,0,NaN], "p1": [0,0,1], "radius": 1 }"#),
        &["cylinders[0].p0"],
    );
    rejects(
        "inf",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1e999], "radius": 1 }"#),
        &["cylinders[0].p1"],
    );
    rejects(
        "huge",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1e13], "radius": 1 }"#),
        &["cylinders[0].p1[2]", "got 10000000000000"],
    );
    rejects(
        "radius_neg",
        &cyl(&format!(
            "{GOOD_CYL}, {{ \"p0\": [0,0,0], \"p1\": [0,0,1], \"radius\": -1 }}"
        )),
        &["cylinders[1].radius: must be > 0", "got -1"],
    );
    rejects(
        "radius_zero",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1], "radius": 0 }"#),
        &["cylinders[0].radius", "got 0"],
    );
    rejects(
        "p0_eq_p1",
        &cyl(r#"{ "p0": [1,2,3], "p1": [1,2,3], "radius": 1 }"#),
        &["cylinders[0].p1", "must differ from p0"],
    );
    rejects(
        "zero_axis",
        &cyl(r#"{ "center": [0,0,0], "axis": [0,0,0], "height": 1, "radius": 1 }"#),
        &["cylinders[0].axis", "non-zero"],
    );
    rejects(
        "height_neg",
        &cyl(r#"{ "center": [0,0,0], "axis": [0,0,1], "height": -2, "radius": 1 }"#),
        &["cylinders[0].height", "got -2"],
    );
    rejects(
        "mixed_forms",
        &cyl(r#"{ "p0": [0,0,0], "axis": [0,0,1], "height": 1, "radius": 1 }"#),
        &["cylinders[0]", "either p0 and p1"],
    );
    rejects(
        "id_zero",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1], "radius": 1, "id": 0 }"#),
        &["cylinders[0].id", "got 0"],
    );
    let cam_with = |k: &str, v: &str| {
        let base = r#""origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1], "fov_deg": 40, "width": 32, "height": 24"#;
        let mut fields: Vec<String> = base
            .split(", \"")
            .map(|f| f.trim_start_matches('"').to_string())
            .collect();
        fields.retain(|f| !f.starts_with(&format!("{k}\"")));
        fields.push(format!("{k}\": {v}"));
        cam(&fields
            .iter()
            .map(|f| format!("\"{f}"))
            .collect::<Vec<_>>()
            .join(", "))
    };
    rejects(
        "fov_zero",
        &cam_with("fov_deg", "0"),
        &["camera.fov_deg", "(0, 180)", "got 0"],
    );
    rejects(
        "fov_180",
        &cam_with("fov_deg", "180"),
        &["camera.fov_deg", "got 180"],
    );
    rejects(
        "width_zero",
        &cam_with("width", "0"),
        &["camera.width", "got 0"],
    );
    rejects(
        "height_huge",
        &cam_with("height", "100000"),
        &["camera.height", "got 100000"],
    );
    // Each side allowed, but the whole image absurd (9.7 GB of buffers with every AOV).
    let big = GOOD_CAMERA.replace(
        r#""width": 32, "height": 24"#,
        r#""width": 16384, "height": 16384"#,
    );
    rejects(
        "pixels_huge",
        &scene(&big, GOOD_CYL),
        &["camera.height", "16384 × 16384 = 268435456"],
    );
    rejects(
        "radius_1e300",
        &scene(
            GOOD_CAMERA,
            r#"{ "p0": [0,0,0], "p1": [0,0,1], "radius": 1e300 }"#,
        ),
        &["cylinders[0].radius", "got 1e300"],
    );
    rejects(
        "width_negative",
        &cam_with("width", "-5"),
        &["camera.width"],
    );
    rejects(
        "up_parallel",
        &cam_with("up", "[3, -5, 1.9]"),
        &["camera.up", "parallel"],
    );
    rejects(
        "target_eq_origin",
        &cam_with("target", "[3, -5, 2.5]"),
        &["camera.target"],
    );
    rejects(
        "near_zero",
        &cam_with("near_clip", "0"),
        &["camera.near_clip", "got 0"],
    );
    rejects(
        "near_ge_far",
        &cam_with("near_clip", "20000"),
        &["camera.far_clip", "near_clip"],
    );
    rejects(
        "fov_axis",
        &cam_with("fov_axis", "\"z\""),
        &["camera.fov_axis", "z"],
    );
    rejects(
        "aov",
        &format!(r#"{{"camera": {{ {GOOD_CAMERA} }}, "cylinders": [], "aovs": ["albedo"]}}"#),
        &["aovs[0]", "albedo"],
    );
}

#[test]
fn output_may_not_overwrite_the_input_and_missing_input_is_clear() {
    let dir = tmp();
    let run = |input: &PathBuf, out: &PathBuf| {
        Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args([
                "render",
                input.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ])
            .output()
            .unwrap()
    };
    // `-o` naming the input itself, or an EXR whose camera file would be the input.
    for (input, out) in [("self.json", "self.json"), ("v.camera.json", "v.exr")] {
        let input = dir.join(input);
        std::fs::write(&input, scene(GOOD_CAMERA, GOOD_CYL)).unwrap();
        let o = run(&input, &dir.join(out));
        assert!(!o.status.success(), "{out}: accepted");
        assert!(String::from_utf8_lossy(&o.stderr).contains("would overwrite the input"));
        assert_eq!(
            std::fs::read_to_string(&input).unwrap(),
            scene(GOOD_CAMERA, GOOD_CYL)
        );
    }
    let o = run(&PathBuf::from("/nonexistent/x.json"), &dir.join("x.exr"));
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/x.json"));
    assert!(!dir.join("x.exr").exists());
}

#[test]
fn a_failing_output_leaves_none_of_the_outputs() {
    let dir = tmp().join("partial");
    std::fs::create_dir_all(&dir).unwrap();
    let input = dir.join("s.json");
    std::fs::write(&input, scene(GOOD_CAMERA, GOOD_CYL)).unwrap();
    let run = |out: &str, extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args([
                "render",
                input.to_str().unwrap(),
                "-o",
                dir.join(out).to_str().unwrap(),
            ])
            .args(extra)
            .output()
            .unwrap()
    };
    // The camera file's name is taken by a directory: the EXR must not appear either.
    std::fs::create_dir_all(dir.join("a.camera.json")).unwrap();
    let o = run("a.exr", &[]);
    assert!(!o.status.success());
    assert!(!dir.join("a.exr").exists(), "EXR left behind");
    // --preview names a file, not a folder: neither the EXR nor the camera file appear.
    std::fs::write(dir.join("not-a-dir"), "x").unwrap();
    let o = run(
        "b.exr",
        &["--preview", dir.join("not-a-dir").to_str().unwrap()],
    );
    assert!(!o.status.success());
    assert!(!dir.join("b.exr").exists() && !dir.join("b.camera.json").exists());
    let tmp_left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(tmp_left.is_empty(), "temporary files left: {tmp_left:?}");
}
