//! `verify OUT` judges the files on disk: a file missing channels its record lists fails,
//! a verdict kept beside a file is not reused once the scene changed, a file is rendered
//! again with the kernel its record gives, paths leading out of OUT are refused, and a
//! candidate channel the check cannot read is refused by name. Skipped (saying so) without
//! the reference venv, unless `CYLAOV_REQUIRE_VENV=1`.

mod common;
use common::{cylaov_with_venv as cylaov, text, venv_python};

use cylaov::image::{AovImage, Channel, ChannelData};
use cylaov::output::format::exr::Compression;
use std::path::{Path, PathBuf};
use std::process::Command;

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A small scene (two cylinders, 32×24) as `dir/scenes/a.json`.
const SCENE: &str = r#"{"camera": {"origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1], "fov_deg": 40, "width": 32, "height": 24},
 "cylinders": [{"p0": [0,0,0], "p1": [0,0,1.5], "radius": 0.5}, {"p0": [1,0.5,0], "p1": [1.2,0.7,1], "radius": 0.2, "caps": false, "id": 9}],
 "aovs": ["depth","distance","normal","position","shape_id","part"]}"#;

fn scenes(dir: &Path) -> PathBuf {
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).expect("scenes dir");
    std::fs::write(scenes.join("a.json"), SCENE).expect("scene");
    scenes
}

/// `cylaov batch SCENES --out OUT EXTRA...`, which must succeed.
fn batch(py: &Path, scenes: &Path, out: &Path, extra: &[&str]) {
    let mut args = vec!["batch", s(scenes), "--out", s(out)];
    args.extend_from_slice(extra);
    let o = cylaov(py, &args);
    assert!(o.status.success(), "{}", text(&o));
}

/// `img` with only the channels `keep` says.
fn only(img: &AovImage, keep: impl Fn(&str) -> bool) -> AovImage {
    let channels = img
        .names()
        .into_iter()
        .filter(|n| keep(n))
        .map(|n| Channel {
            name: n.to_string(),
            data: match img.channel(n).expect("channel") {
                cylaov::image::ChannelRef::F32(v) => ChannelData::F32(v.to_vec()),
                cylaov::image::ChannelRef::U32(v) => ChannelData::U32(v.to_vec()),
            },
        })
        .collect();
    AovImage::from_channels(img.width, img.height, channels)
}

/// A file holding only `part` of what its stamp lists fails (naming the missing channels)
/// and leaves no verdict; one with `depth` stored as u32 fails naming the type.
#[test]
fn a_file_missing_channels_fails() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify-written", "missing");
    let dir = dir_tmp.path();
    let scenes = scenes(dir);
    let out = dir.join("out");
    batch(&py, &scenes, &out, &["--no-png"]);
    let exr = out.join("a.exr");
    let full = AovImage::read_exr(&exr).expect("exr");
    only(&full, |n| n == "part")
        .write_exr(&exr, Compression::None)
        .expect("write");
    let o = cylaov(&py, &["verify", s(&out)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let t = text(&o);
    assert!(
        t.contains("missing from the file: depth, distance, normal.X, normal.Y, normal.Z, position.X, position.Y, position.Z, shape_id"),
        "{t}"
    );
    assert!(!out.join("a.verify.json").exists(), "no verdict kept");
    // depth as u32: the same name, another type.
    let mut channels: Vec<Channel> = Vec::new();
    for n in full.names() {
        let data = match (n, full.channel(n).expect("channel")) {
            ("depth", cylaov::image::ChannelRef::F32(v)) => {
                ChannelData::U32(v.to_vec().iter().map(|x| *x as u32).collect())
            }
            (_, cylaov::image::ChannelRef::F32(v)) => ChannelData::F32(v.to_vec()),
            (_, cylaov::image::ChannelRef::U32(v)) => ChannelData::U32(v.to_vec()),
        };
        channels.push(Channel {
            name: n.to_string(),
            data,
        });
    }
    AovImage::from_channels(full.width, full.height, channels)
        .write_exr(&exr, Compression::None)
        .expect("write");
    let o = cylaov(&py, &["verify", s(&out)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        text(&o).contains("depth: u32 in the file, float32 in the render"),
        "{}",
        text(&o)
    );
}

/// A tar sample holding only `part` fails as the EXR does.
#[test]
fn a_tar_sample_missing_channels_fails() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify-written", "tar");
    let dir = dir_tmp.path();
    let scenes = scenes(dir);
    let out = dir.join("wds");
    batch(&py, &scenes, &out, &["--format", "webdataset"]);
    let o = cylaov(&py, &["verify", s(&out)]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    // The tar rewritten with the sample's part, mask and JSON only.
    let tar = out.join("shard-000000.tar");
    let x = dir.join("x");
    std::fs::create_dir_all(&x).expect("x");
    let run = |args: &[&str], at: &Path| {
        let o = Command::new("tar")
            .args(args)
            .current_dir(at)
            .output()
            .expect("tar");
        assert!(o.status.success(), "{}", text(&o));
    };
    run(&["xf", s(&tar)], &x);
    run(&["cf", s(&tar), "a.part.npy", "a.mask.npy", "a.json"], &x);
    let o = cylaov(&py, &["verify", s(&out)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        text(&o).contains("missing from the file: depth"),
        "{}",
        text(&o)
    );
}

/// A batch verified at f64 keeps its verdict; the scene edited afterwards (a radius) is
/// checked again, and the text and `--json` agree: FAIL.
#[test]
fn a_kept_verdict_is_not_reused_after_the_scene_changes() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify-written", "stale");
    let dir = dir_tmp.path();
    let scenes = scenes(dir);
    let out = dir.join("out");
    batch(&py, &scenes, &out, &["--no-png", "--verify-fraction", "1"]);
    assert!(out.join("a.verify.json").is_file(), "a verdict kept");
    std::fs::write(
        scenes.join("a.json"),
        SCENE.replace("\"radius\": 0.2", "\"radius\": 0.25"),
    )
    .expect("edit");
    let o = cylaov(&py, &["verify", s(&out)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        text(&o).contains("a.exr differs from a fresh render of its scene"),
        "{}",
        text(&o)
    );
    let o = cylaov(&py, &["verify", s(&out), "--json"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
}

/// A `--precision f32` batch is rendered again at f32 (the precision its stamp records),
/// and passes with and without `--json`, whatever `verify --precision` says.
#[test]
fn a_file_is_checked_with_the_kernel_its_stamp_records() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify-written", "f32");
    let dir = dir_tmp.path();
    let scenes = scenes(dir);
    let out = dir.join("out");
    batch(&py, &scenes, &out, &["--no-png", "--precision", "f32"]);
    for extra in [&[][..], &["--json"], &["--precision", "f64", "--json"]] {
        let mut args = vec!["verify", s(&out)];
        args.extend(extra);
        let o = cylaov(&py, &args);
        assert_eq!(o.status.code(), Some(0), "{extra:?}: {}", text(&o));
    }
    let o = cylaov(&py, &["verify", s(&out)]);
    let table = String::from_utf8_lossy(&o.stdout).to_string();
    // The row of a view checked now carries its summary.
    assert!(
        table.contains("a                        PASS      silhouette "),
        "{table}"
    );
}

/// An index whose `exr_file_path` is absolute or climbs out of OUT is refused, naming it;
/// nothing is written outside OUT.
#[test]
fn index_paths_out_of_the_folder_are_refused() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify-written", "escape");
    let dir = dir_tmp.path();
    let scenes = scenes(dir);
    let out = dir.join("out");
    batch(&py, &scenes, &out, &["--no-png"]);
    let victim = dir.join("victim");
    std::fs::create_dir_all(&victim).expect("victim");
    for f in ["a.exr", "a.render.json"] {
        std::fs::copy(out.join(f), victim.join(f)).expect("copy");
    }
    let index_path = out.join("index.json");
    let index = std::fs::read_to_string(&index_path).expect("index");
    for path in [
        s(&victim.join("a.exr")).to_string(),
        "../victim/a.exr".into(),
    ] {
        std::fs::write(
            &index_path,
            index.replace(
                "\"exr_file_path\": \"a.exr\"",
                &format!("\"exr_file_path\": {path:?}"),
            ),
        )
        .expect("index");
        let o = cylaov(&py, &["verify", s(&out)]);
        assert_eq!(o.status.code(), Some(2), "{path}: {}", text(&o));
        assert!(
            text(&o).contains(&format!("exr_file_path {path:?} is not a path inside")),
            "{}",
            text(&o)
        );
        assert!(!victim.join("a.verify.json").exists(), "{path}");
    }
}

/// A candidate whose `distance` is u32 is refused naming the channel (exit 2); one with a
/// wrong `label` passes with a line saying `label` was not judged.
#[test]
fn candidate_channels_the_check_cannot_judge_are_named() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify-written", "candidate");
    let dir = dir_tmp.path();
    let scene = dir.join("a.json");
    std::fs::write(&scene, SCENE).expect("scene");
    let full = dir.join("full.exr");
    let o = cylaov(
        &py,
        &[
            "render",
            s(&scene),
            "-o",
            s(&full),
            "--aov",
            "depth,distance,normal,position,shape_id,part,label",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let img = AovImage::read_exr(&full).expect("exr");
    let mut channels: Vec<Channel> = Vec::new();
    for n in img.names() {
        let data = match (n, img.channel(n).expect("channel")) {
            ("distance", cylaov::image::ChannelRef::F32(v)) => ChannelData::U32(
                v.to_vec()
                    .iter()
                    .map(|x| (*x > 0.0) as u32 * 1000)
                    .collect(),
            ),
            ("label", cylaov::image::ChannelRef::U32(v)) => {
                ChannelData::U32(v.to_vec().iter().map(|x| x + 5).collect())
            }
            (_, cylaov::image::ChannelRef::F32(v)) => ChannelData::F32(v.to_vec()),
            (_, cylaov::image::ChannelRef::U32(v)) => ChannelData::U32(v.to_vec()),
        };
        channels.push(Channel {
            name: n.to_string(),
            data,
        });
    }
    let bad = dir.join("bad.exr");
    AovImage::from_channels(img.width, img.height, channels)
        .write_exr(&bad, Compression::None)
        .expect("write");
    let o = cylaov(&py, &["verify", s(&scene), "--candidate", s(&bad)]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o)
            .contains("candidate: distance is stored as u32, where the check reads float samples"),
        "{}",
        text(&o)
    );
    // Only the label wrong: passes, saying the label went unjudged.
    let label_only = only(&AovImage::read_exr(&bad).expect("bad"), |n| n != "distance");
    label_only
        .write_exr(&bad, Compression::None)
        .expect("write");
    let o = cylaov(&py, &["verify", s(&scene), "--candidate", s(&bad)]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(
        text(&o).contains("accepted: not judged: label: the exact answer has no value for them"),
        "{}",
        text(&o)
    );
}
