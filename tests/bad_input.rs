//! Bad scene input: one clear error naming the field and value, exit status 1, no file.
//! Runs the real binary. Each test is a table of cases and reports every failing case, not
//! just the first.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

const GOOD_CAMERA: &str = r#""origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1],
    "fov_deg": 40, "width": 32, "height": 24"#;
const GOOD_CYL: &str = r#"{ "p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5 }"#;

fn scene(camera: &str, cylinders: &str) -> String {
    format!(r#"{{ "camera": {{ {camera} }}, "cylinders": [ {cylinders} ] }}"#)
}

fn tmp() -> &'static Path {
    common::shared_dir("bad")
}

/// Render `json`; expect exit status 1 whose stderr is one line containing every `needle`,
/// and no output file. `Err` says what went wrong.
fn check_rejects(name: &str, json: &[u8], needles: &[&str]) -> Result<(), String> {
    let dir = tmp();
    let input = dir.join(format!("{name}.json"));
    std::fs::write(&input, json).unwrap();
    check_rejects_file(name, &input, needles)
}

/// [`check_rejects`] for an input path that already exists (FIFOs, links, sparse files).
fn check_rejects_file(name: &str, input: &Path, needles: &[&str]) -> Result<(), String> {
    let dir = tmp();
    let out = dir.join(format!("{name}.exr"));
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
    if o.status.code() != Some(1) {
        return Err(format!(
            "{name}: exit {:?}, want 1:\n{err}",
            o.status.code()
        ));
    }
    for n in needles {
        if !err.contains(n) {
            return Err(format!("{name}: stderr lacks {n:?}:\n{err}"));
        }
    }
    if err.trim().lines().count() != 1 {
        return Err(format!("{name}: want one line:\n{err}"));
    }
    if err.contains("panicked") {
        return Err(format!("{name}: panicked:\n{err}"));
    }
    if out.exists() {
        return Err(format!("{name}: wrote {}", out.display()));
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.file_name().to_string_lossy().contains(name)
                && !e.file_name().to_string_lossy().ends_with(".json")
        })
        .collect();
    if !leftovers.is_empty() {
        return Err(format!("{name}: left {leftovers:?}"));
    }
    Ok(())
}

/// Collects the failing cases of one table.
#[derive(Default)]
struct Table(Vec<String>);

impl Table {
    fn rejects(&mut self, name: &str, json: &str, needles: &[&str]) {
        if let Err(e) = check_rejects(name, json.as_bytes(), needles) {
            self.0.push(e);
        }
    }
    fn rejects_bytes(&mut self, name: &str, json: &[u8], needles: &[&str]) {
        if let Err(e) = check_rejects(name, json, needles) {
            self.0.push(e);
        }
    }
    fn rejects_file(&mut self, name: &str, input: &Path, needles: &[&str]) {
        if let Err(e) = check_rejects_file(name, input, needles) {
            self.0.push(e);
        }
    }
    fn done(self) {
        assert!(
            self.0.is_empty(),
            "{} failing cases:\n{}",
            self.0.len(),
            self.0.join("\n")
        );
    }
}

#[test]
fn every_spec_case_is_rejected_clearly() {
    let mut t = Table::default();
    let cyl = |c: &str| scene(GOOD_CAMERA, c);
    let cam = |c: &str| scene(c, GOOD_CYL);
    t.rejects(
        "malformed",
        r#"{ "camera": { "origin": [1, 2"#,
        &["invalid JSON", "EOF"],
    );
    t.rejects("not_a_scene", "[1, 2, 3]", &["invalid JSON"]);
    t.rejects(
        "unknown_top",
        &format!(r#"{{"camera": {{ {GOOD_CAMERA} }}, "cylinders": [], "lights": 1}}"#),
        &["lights"],
    );
    t.rejects(
        "unknown_cyl",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1], "radius": 1, "colour": 3 }"#),
        &["cylinders[0]", "colour"],
    );
    t.rejects(
        "unknown_cam",
        &cam(&format!("{GOOD_CAMERA}, \"zoom\": 2")),
        &["camera", "zoom"],
    );
    t.rejects(
        "nan",
        &cyl(r#"{ "p0": [0,0,NaN], "p1": [0,0,1], "radius": 1 }"#),
        &["cylinders[0].p0"],
    );
    t.rejects(
        "inf",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1e999], "radius": 1 }"#),
        &["cylinders[0].p1"],
    );
    t.rejects(
        "huge",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1e13], "radius": 1 }"#),
        &["cylinders[0].p1[2]", "got 10000000000000"],
    );
    t.rejects(
        "radius_neg",
        &cyl(&format!(
            "{GOOD_CYL}, {{ \"p0\": [0,0,0], \"p1\": [0,0,1], \"radius\": -1 }}"
        )),
        &["cylinders[1].radius: must be > 0", "got -1"],
    );
    t.rejects(
        "radius_zero",
        &cyl(r#"{ "p0": [0,0,0], "p1": [0,0,1], "radius": 0 }"#),
        &["cylinders[0].radius", "got 0"],
    );
    t.rejects(
        "p0_eq_p1",
        &cyl(r#"{ "p0": [1,2,3], "p1": [1,2,3], "radius": 1 }"#),
        &["cylinders[0].p1", "must differ from p0"],
    );
    t.rejects(
        "zero_axis",
        &cyl(r#"{ "center": [0,0,0], "axis": [0,0,0], "height": 1, "radius": 1 }"#),
        &["cylinders[0].axis", "non-zero"],
    );
    t.rejects(
        "height_neg",
        &cyl(r#"{ "center": [0,0,0], "axis": [0,0,1], "height": -2, "radius": 1 }"#),
        &["cylinders[0].height", "got -2"],
    );
    t.rejects(
        "mixed_forms",
        &cyl(r#"{ "p0": [0,0,0], "axis": [0,0,1], "height": 1, "radius": 1 }"#),
        &["cylinders[0]", "either p0 and p1"],
    );
    t.rejects(
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
    t.rejects(
        "fov_zero",
        &cam_with("fov_deg", "0"),
        &["camera.fov_deg", "(0, 180)", "got 0"],
    );
    t.rejects(
        "fov_180",
        &cam_with("fov_deg", "180"),
        &["camera.fov_deg", "got 180"],
    );
    t.rejects(
        "width_zero",
        &cam_with("width", "0"),
        &["camera.width", "got 0"],
    );
    t.rejects(
        "height_huge",
        &cam_with("height", "100000"),
        &["camera.height", "got 100000"],
    );
    // Each side allowed, but the whole image absurd (9.7 GB of buffers with every AOV).
    let big = GOOD_CAMERA.replace(
        r#""width": 32, "height": 24"#,
        r#""width": 16384, "height": 16384"#,
    );
    t.rejects(
        "pixels_huge",
        &scene(&big, GOOD_CYL),
        &["camera.height", "16384 × 16384 = 268435456"],
    );
    t.rejects(
        "radius_1e300",
        &scene(
            GOOD_CAMERA,
            r#"{ "p0": [0,0,0], "p1": [0,0,1], "radius": 1e300 }"#,
        ),
        &["cylinders[0].radius", "got 1e300"],
    );
    t.rejects(
        "width_negative",
        &cam_with("width", "-5"),
        &["camera.width"],
    );
    t.rejects(
        "up_parallel",
        &cam_with("up", "[3, -5, 1.9]"),
        &["camera.up", "parallel"],
    );
    t.rejects(
        "target_eq_origin",
        &cam_with("target", "[3, -5, 2.5]"),
        &["camera.target"],
    );
    t.rejects(
        "near_zero",
        &cam_with("near_clip", "0"),
        &["camera.near_clip", "got 0"],
    );
    t.rejects(
        "near_ge_far",
        &cam_with("near_clip", "20000"),
        &["camera.far_clip", "near_clip"],
    );
    t.rejects(
        "fov_axis",
        &cam_with("fov_axis", "\"z\""),
        &["camera.fov_axis", "z"],
    );
    t.rejects(
        "aov",
        &format!(r#"{{"camera": {{ {GOOD_CAMERA} }}, "cylinders": [], "aovs": ["albedo"]}}"#),
        &["aovs[0]", "albedo"],
    );
    t.done();
}

/// What `serde_json` accepts or words poorly by default, and files that are not scenes.
#[test]
fn documents_that_are_not_one_scene_object_are_rejected_clearly() {
    let mut t = Table::default();
    let good = scene(GOOD_CAMERA, GOOD_CYL);
    t.rejects(
        "two_scenes",
        &format!("{good}\n{good}"),
        &["text after the end", "two scenes in one file"],
    );
    t.rejects("text_after", &format!("{good} x"), &["text after the end"]);
    t.rejects(
        "positional_top",
        &format!("[{{ {GOOD_CAMERA} }}, [{GOOD_CYL}]]"),
        &["invalid JSON", "sequence", "JSON object"],
    );
    t.rejects(
        "positional_camera",
        &scene_with_camera("[[3, -5, 2.5], [0, 0, 0.6], [0, 0, 1], 40, \"x\", 32, 24, 0.01, 100]"),
        &["camera", "sequence", "JSON object"],
    );
    t.rejects(
        "positional_cylinder",
        &scene(
            GOOD_CAMERA,
            "[[0, 0, 0], [0, 0, 1], null, null, null, 0.5, true, null]",
        ),
        &["cylinders[0]", "sequence", "JSON object"],
    );
    let mut bom = vec![0xef, 0xbb, 0xbf];
    bom.extend_from_slice(good.as_bytes());
    t.rejects_bytes("bom", &bom, &["byte order mark"]);
    t.rejects(
        "p0_four",
        &scene(
            GOOD_CAMERA,
            r#"{ "p0": [0, 0, 0, 0], "p1": [0, 0, 1], "radius": 1 }"#,
        ),
        &["cylinders[0].p0", "must have 3 numbers", "got 4"],
    );
    t.rejects(
        "origin_two",
        &scene(&GOOD_CAMERA.replace("[3, -5, 2.5]", "[3, -5]"), GOOD_CYL),
        &["camera.origin", "must have 3 numbers", "got 2"],
    );
    t.rejects_bytes("not_utf8", b"{\"camera\": \xff}", &["not UTF-8"]);
    t.done();
}

fn scene_with_camera(camera: &str) -> String {
    format!(r#"{{ "camera": {camera}, "cylinders": [ {GOOD_CYL} ] }}"#)
}

/// Long numbers and names are cut in messages; a message stays one short line.
#[test]
fn long_values_are_shortened_in_messages() {
    let digits = "9".repeat(600);
    let cases = [
        (
            "long_number",
            scene(
                GOOD_CAMERA,
                &format!(r#"{{ "p0": [0, 0, 0], "p1": [0, 0, 1], "radius": {digits} }}"#),
            ),
            "cylinders[0].radius",
        ),
        (
            "long_variant",
            scene(
                &format!(r#"{GOOD_CAMERA}, "fov_axis": "{digits}""#),
                GOOD_CYL,
            ),
            "camera.fov_axis",
        ),
        (
            "long_field",
            scene(&format!(r#"{GOOD_CAMERA}, "{digits}": 1"#), GOOD_CYL),
            "camera",
        ),
    ];
    let mut t = Table::default();
    for (name, json, field) in &cases {
        t.rejects(name, json, &[field]);
        let input = tmp().join(format!("{name}.json"));
        let o = Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args([
                "render",
                input.to_str().unwrap(),
                "-o",
                "/nonexistent/x.exr",
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        // The file's path is the user's; the rest of the message is ours to keep short.
        let ours = err.replace(input.to_str().unwrap(), "").len();
        if ours > 300 || err.contains(&"9".repeat(41)) {
            t.0.push(format!(
                "{name}: message of {ours} bytes besides the path: {err}"
            ));
        }
    }
    t.done();
}

/// A scene file must be a regular file no larger than 512 MiB: a FIFO would block, a device
/// never end.
#[test]
fn scene_files_that_are_not_regular_or_too_large_are_refused() {
    let dir = tmp().join("special");
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("fifo.json");
    let _ = std::fs::remove_file(&fifo);
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let zero = dir.join("zero.json");
    let _ = std::fs::remove_file(&zero);
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    // Sparse: 600 MiB of length, no blocks on disk.
    let big = dir.join("big.json");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(600 << 20)
        .unwrap();
    let mut t = Table::default();
    t.rejects_file("fifo", &fifo, &["fifo.json", "not a regular file"]);
    t.rejects_file("zero", &zero, &["zero.json", "not a regular file"]);
    t.rejects_file("folder", &dir, &["not a regular file but a folder"]);
    t.rejects_file("big", &big, &["629145600 bytes", "512 MiB"]);
    std::fs::remove_file(&big).unwrap();
    t.done();
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
