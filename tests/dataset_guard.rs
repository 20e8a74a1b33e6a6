//! A dataset folder is never wrecked by the next command: `generate` keeps, extends or
//! refuses what `--out` already holds and never overwrites its own `--config`; `--force`
//! replaces generate's own files only; `batch` removes the files of views a scene no
//! longer has (and only cylaov's own names); `batch` says how much it is about to write.

mod common;

use common::{cylaov, ok, tree};
use std::os::unix::fs::MetadataExt;
use std::path::Path;

fn fresh_dir(name: &str) -> tempfile::TempDir {
    common::fresh_dir("dataset_guard", name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `cylaov ARGS`, which must exit 1; its stderr.
fn refused(args: &[&str]) -> String {
    let out = cylaov(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "cylaov {args:?}: {err}");
    err
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn generate(out: &Path, extra: &[&str]) -> String {
    let mut args = vec![
        "generate",
        "--out",
        s(out),
        "--width",
        "32",
        "--height",
        "24",
    ];
    args.extend_from_slice(extra);
    ok(&args)
}

/// Other settings and a smaller `--count` are refused, saying what differs, and leave
/// every file as it was (they rewrote scenes and cut the manifest).
#[test]
fn a_dataset_with_other_settings_or_more_scenes_is_refused() {
    let dir = fresh_dir("refused");
    let out = dir.path().join("data");
    generate(&out, &["--count", "4", "--seed", "1"]);
    let before = tree(&out);
    let base = [
        "generate",
        "--out",
        s(&out),
        "--width",
        "32",
        "--height",
        "24",
    ];
    let with =
        |extra: &[&'static str]| -> Vec<&str> { base.iter().chain(extra).copied().collect() };

    let err = refused(&with(&["--count", "4", "--seed", "2"]));
    assert!(err.contains("other settings"), "{err}");
    assert!(err.contains("--seed 1 there, 2 here"), "{err}");
    let err = refused(&with(&["--count", "4", "--seed", "1", "--fov", "40"]));
    assert!(err.contains("--fov 50 there, 40 here"), "{err}");
    assert!(!err.contains("--seed"), "{err}");
    let err = refused(&["generate", "--out", s(&out), "--count", "4", "--seed", "1"]);
    assert!(err.contains("--height 24 there, 240 here"), "{err}");
    assert!(err.contains("--width 32 there, 320 here"), "{err}");
    let err = refused(&with(&["--count", "2", "--seed", "1"]));
    assert!(err.contains("--count 2"), "{err}");
    assert!(err.contains("holds 4 scenes"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert_eq!(tree(&out), before);
}

/// The same settings: nothing to do, nothing written (also through its own
/// `generate.json` as `--config`). A larger `--count` extends the dataset: the first scene
/// files are left as they are (same inode), the new ones and the manifest are a fresh run's.
#[test]
fn the_same_settings_do_nothing_and_a_larger_count_extends() {
    let dir = fresh_dir("extend");
    let out = dir.path().join("data");
    generate(&out, &["--count", "3", "--seed", "7"]);
    let before = tree(&out);
    let inode = |i: u32| {
        std::fs::metadata(out.join(format!("scenes/{i:06}.json")))
            .unwrap()
            .ino()
    };
    let inodes: Vec<u64> = (0..3).map(inode).collect();

    let again = generate(&out, &["--count", "3", "--seed", "7"]);
    assert!(again.starts_with("nothing to do"), "{again}");
    let config = out.join("generate.json");
    let own = ok(&["generate", "--config", s(&config), "--out", s(&out)]);
    assert!(own.starts_with("nothing to do"), "{own}");
    assert_eq!(tree(&out), before);
    assert_eq!((0..3).map(inode).collect::<Vec<_>>(), inodes);

    let more = generate(&out, &["--count", "5", "--seed", "7"]);
    assert!(more.starts_with("extended from 3 to 5 scenes"), "{more}");
    assert_eq!((0..3).map(inode).collect::<Vec<_>>(), inodes);
    let fresh = dir.path().join("fresh");
    generate(&fresh, &["--count", "5", "--seed", "7"]);
    assert_eq!(tree(&out), tree(&fresh));
    assert_eq!(
        std::fs::read_to_string(out.join("manifest.jsonl"))
            .unwrap()
            .lines()
            .count(),
        5
    );
}

/// A dataset whose writing was cut short (scene files and the manifest missing beside its
/// generate.json) is completed by the same command: the missing files are written, the
/// others left as they are.
#[test]
fn the_same_command_completes_a_dataset_cut_short() {
    let dir = fresh_dir("complete");
    let out = dir.path().join("data");
    generate(&out, &["--count", "4"]);
    let want = tree(&out);
    std::fs::remove_file(out.join("manifest.jsonl")).unwrap();
    std::fs::remove_file(out.join("scenes/000002.json")).unwrap();
    let kept = std::fs::metadata(out.join("scenes/000001.json"))
        .unwrap()
        .ino();
    let said = generate(&out, &["--count", "4"]);
    assert!(said.starts_with("completed 4 scenes"), "{said}");
    assert_eq!(tree(&out), want);
    let now = std::fs::metadata(out.join("scenes/000001.json"))
        .unwrap()
        .ino();
    assert_eq!(now, kept);
}

/// `--force` replaces generate.json, manifest.jsonl and the scene files (those past the new
/// count go) and nothing else: a `render/` beside them, a note in `--out` and a file of
/// another name in `scenes/` stay.
#[test]
fn force_replaces_generates_files_and_nothing_else() {
    let dir = fresh_dir("force");
    let out = dir.path().join("data");
    generate(&out, &["--count", "4"]);
    std::fs::create_dir(out.join("render")).unwrap();
    std::fs::write(out.join("render/000000.exr"), b"a render").unwrap();
    std::fs::write(out.join("notes.txt"), b"mine").unwrap();
    std::fs::write(out.join("scenes/README.txt"), b"also mine").unwrap();

    let said = generate(&out, &["--count", "2", "--seed", "3", "--force"]);
    assert!(said.starts_with("replaced the dataset: 2 scenes"), "{said}");
    let fresh = dir.path().join("fresh");
    generate(&fresh, &["--count", "2", "--seed", "3"]);
    let mut want = tree(&fresh);
    want.insert("render/000000.exr".into(), b"a render".to_vec());
    want.insert("notes.txt".into(), b"mine".to_vec());
    want.insert("scenes/README.txt".into(), b"also mine".to_vec());
    assert_eq!(tree(&out), want);
}

/// A run that would overwrite its own `--config` is refused before anything is written,
/// naming it: a config kept as a scene file the run would write, as `manifest.jsonl`, or
/// as `generate.json` of a dataset being extended (each was overwritten).
#[test]
fn generate_never_overwrites_its_own_config() {
    let dir = fresh_dir("own-config");
    let out = dir.path().join("data");
    generate(&out, &["--count", "3"]);
    let config = out.join("scenes/000004.json");
    std::fs::write(&config, r#"{"count": 5, "width": 32, "height": 24}"#).unwrap();
    let before = tree(&out);
    let err = refused(&["generate", "--config", s(&config), "--out", s(&out)]);
    assert!(err.contains("would overwrite its own input"), "{err}");
    assert!(err.contains(s(&config)), "{err}");
    assert_eq!(tree(&out), before);

    let extend = refused(&[
        "generate",
        "--config",
        s(&out.join("generate.json")),
        "--count",
        "6",
        "--out",
        s(&out),
    ]);
    assert!(extend.contains("would overwrite its own input"), "{extend}");
    assert_eq!(tree(&out), before);

    let other = dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    let manifest = other.join("manifest.jsonl");
    std::fs::write(&manifest, r#"{"count": 2}"#).unwrap();
    let err = refused(&["generate", "--config", s(&manifest), "--out", s(&other)]);
    assert!(err.contains("would overwrite its own input"), "{err}");
    assert_eq!(names(&other), ["manifest.jsonl"]);
    assert_eq!(
        std::fs::read_to_string(&manifest).unwrap(),
        r#"{"count": 2}"#
    );
}

/// Edit a generated scene file to keep its first `n` cameras (`n` >= 1).
fn keep_cameras(scene: &Path, n: usize, from: &Path) {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(from).unwrap()).unwrap();
    let cams = v["cameras"].as_array().unwrap()[..n].to_vec();
    v.as_object_mut().unwrap().remove("cameras");
    if n == 1 {
        v["camera"] = cams[0].clone();
    } else {
        v["cameras"] = cams.into();
    }
    std::fs::write(scene, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// A scene cut from three cameras to one takes the flat layout and its folder goes (a
/// user's file in it stays, and so does the folder then); one cut to two loses `02.*` and
/// its `transforms.json` lists two frames; one grown back to three loses its flat files.
#[test]
fn a_scene_with_fewer_cameras_loses_the_files_of_its_gone_views() {
    let dir = fresh_dir("stale");
    let generated = dir.path().join("generated");
    generate(&generated, &["--count", "2", "--views-per-scene", "3"]);
    let input = dir.path().join("in");
    let out = dir.path().join("out");
    std::fs::create_dir(&input).unwrap();
    let original = |k: usize| generated.join(format!("scenes/{k:06}.json"));
    for k in 0..2 {
        std::fs::copy(original(k), input.join(format!("{k:06}.json"))).unwrap();
    }
    let batch = || ok(&["batch", s(&input), "--out", s(&out)]);
    batch();
    assert!(out.join("000000/02.exr").exists());
    std::fs::write(out.join("000001/mine.txt"), b"mine").unwrap();

    keep_cameras(&input.join("000000.json"), 1, &original(0));
    keep_cameras(&input.join("000001.json"), 2, &original(1));
    batch();
    assert!(out.join("000000.exr").exists());
    assert!(
        !out.join("000000").exists(),
        "{:?}",
        names(&out.join("000000"))
    );
    let kept = names(&out.join("000001"));
    assert!(kept.contains(&"01.exr".to_string()), "{kept:?}");
    assert!(kept.contains(&"mine.txt".to_string()), "{kept:?}");
    assert!(!kept.iter().any(|n| n.starts_with("02.")), "{kept:?}");
    let frames = json(&out.join("000001/transforms.json"))["frames"]
        .as_array()
        .unwrap()
        .len();
    assert_eq!(frames, 2);
    assert_eq!(
        json(&out.join("index.json"))["views"]
            .as_array()
            .unwrap()
            .len(),
        3
    );

    // The user's file keeps a folder whose views are gone.
    std::fs::write(out.join("000001/mine.txt"), b"mine").unwrap();
    keep_cameras(&input.join("000001.json"), 1, &original(1));
    std::fs::copy(original(0), input.join("000000.json")).unwrap();
    batch();
    assert_eq!(names(&out.join("000001")), ["mine.txt"]);
    assert!(out.join("000001.exr").exists());
    assert!(out.join("000000/02.exr").exists());
    let flat: Vec<String> = names(&out)
        .into_iter()
        .filter(|n| n.starts_with("000000."))
        .collect();
    assert!(flat.is_empty(), "{flat:?}");
}

/// Before it starts, batch prints the estimated size of what it writes; for generated
/// 640x480 views with depth and normal it is within 5 % of the bytes written.
#[test]
fn batch_prints_its_estimated_output_size_first() {
    let dir = fresh_dir("estimate");
    let data = dir.path().join("data");
    let out = dir.path().join("out");
    ok(&[
        "generate",
        "--count",
        "4",
        "--seed",
        "2",
        "--width",
        "640",
        "--height",
        "480",
        "--out",
        s(&data),
    ]);
    let run = cylaov(&["batch", s(&data), "--out", s(&out), "--aov", "depth,normal"]);
    assert!(run.status.success());
    let err = String::from_utf8_lossy(&run.stderr).into_owned();
    let first = err.lines().next().unwrap_or_default();
    assert!(
        first.starts_with("batch 0-of-1: 4 views at 640x480, depth+normal: about "),
        "{err}"
    );
    let mib: f64 = first
        .split("about ")
        .nth(1)
        .and_then(|t| t.split(" MiB").next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no size in {first:?}"));
    let written: usize = tree(&out).values().map(Vec::len).sum();
    let estimated = mib * (1u64 << 20) as f64;
    assert!(
        (estimated / written as f64 - 1.0).abs() < 0.05,
        "estimated {estimated}, wrote {written}"
    );
    assert!(!first.contains("--compression zip"), "{first}");
}
