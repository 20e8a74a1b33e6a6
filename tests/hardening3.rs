//! Rough edges a newcomer meets on the command line: an EXR written under a `.png` name,
//! "1 cylinders", the README tour's `data/` in `git status`.
//! Runs the real binary.

use std::path::Path;
use std::process::{Command, Output};

const SCENE: &str = r#"{ "camera": { "origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1],
    "fov_deg": 40, "width": 32, "height": 24 },
  "cylinders": [ { "p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5 } ],
  "aovs": ["depth", "normal", "shape_id"] }"#;

fn cylaov(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// `render -o out/x.png` is refused, naming the flags that make PNGs, and writes nothing.
#[test]
fn render_output_must_be_exr() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let png = d.path().join("out").join("x.png");
    let o = cylaov(&["render", s(&scene), "-o", s(&png)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let err = text(&o.stderr);
    assert!(err.contains(".exr"), "{err}");
    assert!(
        err.contains("--depth-png") && err.contains("--preview"),
        "{err}"
    );
    assert!(
        !d.path().join("out").exists(),
        "a refused render made its folder"
    );
    // Upper case is still an EXR name.
    let upper = d.path().join("x.EXR");
    let o = cylaov(&["render", s(&scene), "-o", s(&upper)]);
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// One cylinder is "1 cylinder" in render's and export-mitsuba's summaries.
#[test]
fn one_cylinder_is_singular() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let o = cylaov(&["render", s(&scene), "-o", s(&d.path().join("a.exr"))]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(out.contains(", 1 cylinder,"), "{out}");
    let o = cylaov(&[
        "export-mitsuba",
        s(&scene),
        "-o",
        s(&d.path().join("a.xml")),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(out.contains(": 1 cylinder as"), "{out}");
}

/// The README tour writes `data/`; it is output, not source.
#[test]
fn tour_data_ignored() {
    let ignore =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/.gitignore")).unwrap();
    assert!(ignore.lines().any(|l| l == "/data"), "{ignore}");
}
