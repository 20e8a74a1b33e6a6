//! `cylaov export-mitsuba` and `cylaov compare` as a user runs them: exit codes, messages,
//! and no output file on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn cylaov(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .output()
        .expect("running cylaov")
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A fresh scratch folder under the target dir (no extra crates).
fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch dir");
    dir
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

#[test]
fn export_writes_loadable_xml_and_rejects_bad_scenes() {
    let dir = scratch("export");
    let out = dir.join("single.xml");
    let scene = root().join("scenes/single.json");
    let o = cylaov(&["export-mitsuba", s(&scene), "-o", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let xml = std::fs::read_to_string(&out).expect("xml written");
    assert!(xml.contains("single.json"));
    assert_eq!(xml.matches("<shape ").count(), 3);

    let bad = dir.join("bad.json");
    std::fs::write(
        &bad,
        r#"{"camera": {"origin": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0],
            "fov_deg": 40, "width": 8, "height": 8},
            "cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": -1}]}"#,
    )
    .expect("write bad scene");
    let bad_out = dir.join("bad.xml");
    let o = cylaov(&["export-mitsuba", s(&bad), "-o", s(&bad_out)]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("cylinders[0].radius: must be > 0") && err.contains("got -1"),
        "{err}"
    );
    assert!(!bad_out.exists());
    // Nothing half-written is left behind either.
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .expect("read dir")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty());

    let o = cylaov(&["export-mitsuba", s(&scene), "-o", s(&scene)]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("would overwrite the input scene"));
}

#[test]
fn compare_exit_codes_json_and_heatmap() {
    let dir = scratch("compare");
    let single = root().join("reference/single.exr");
    let far = root().join("reference/far_narrow.exr");
    let heat = dir.join("heat.png");

    // Identical files pass, and the heatmap is written.
    let o = cylaov(&["compare", s(&single), s(&single), "--heatmap", s(&heat)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("mismatches: 0 (0.0000%)") && text.trim_end().ends_with("PASS"));
    assert!(
        std::fs::metadata(&heat)
            .map(|m| m.len() > 0)
            .unwrap_or(false)
    );

    // Render far_narrow with cylaov and compare at the default 0.1°: Mitsuba's float32
    // normals break it there (tests/reference.rs explains why), so the exit code is 1.
    let ours = dir.join("far_narrow.exr");
    let scene = root().join("scenes/far_narrow.json");
    let o = cylaov(&["render", s(&scene), "-o", s(&ours)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = cylaov(&["compare", s(&ours), s(&far), "--json"]);
    assert_eq!(o.status.code(), Some(1));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON report");
    assert_eq!(v["passed"], false);
    assert_eq!(v["report"]["identity"], "shape_id");
    assert!(
        v["failures"][0]
            .as_str()
            .unwrap_or("")
            .starts_with("normal angle error")
    );
    // A looser flag makes it pass.
    let o = cylaov(&["compare", s(&ours), s(&far), "--normal-deg", "0.45"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));

    // Different sizes: an error naming both sizes.
    let o = cylaov(&[
        "compare",
        s(&single),
        s(&root().join("reference/near_clip.exr")),
    ]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr)
            .contains("image sizes differ: A is 320x240, B is 240x180")
    );
    // Missing file.
    let o = cylaov(&["compare", s(&dir.join("nope.exr")), s(&single)]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("nope.exr"));
}
