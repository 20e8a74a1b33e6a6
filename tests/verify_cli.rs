//! `cylaov verify` and `batch --verify-fraction` as a user runs them: exit codes, the
//! FAIL lines of `compare` in the console and the failures file, identity rendered
//! alongside a dataset that stores none, and verdicts kept so a resume does not run
//! Mitsuba again. Skipped (saying so) without the reference venv, unless
//! `CYLAOV_REQUIRE_VENV=1`.

mod common;
use common::{cylaov_with_venv as cylaov, text, venv_python};

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

#[test]
fn verify_exit_codes_table_and_json() {
    let Some(py) = venv_python() else { return };
    let scene = root().join("scenes/single.json");
    let dir_tmp = common::fresh_dir("verify", "verify-cli");
    let dir = dir_tmp.path();
    let o = cylaov(&py, &["verify", s(&scene), "--heatmap", s(dir)]);
    let out = text(&o);
    assert_eq!(o.status.code(), Some(0), "{out}");
    assert!(
        out.contains("single                   PASS      silhouette 0 px, seam 0 px"),
        "{out}"
    );
    assert!(out.contains("1 of 1 views checked: 1 passed, 0 failed, 0 could not be checked"));
    // Not a terminal: no progress on stderr, the row once (on stdout).
    assert_eq!(
        out.matches("single                   PASS").count(),
        1,
        "{out}"
    );
    assert!(
        o.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(dir.join("single.heatmap.png").is_file());

    // A scene far from the origin (scenes/stress/): Mitsuba's float32 is off by up to a
    // unit there, cylaov is exact: it passes, with Mitsuba's reference errors counted and
    // the note that Mitsuba cannot discriminate at that scale.
    let far = root().join("scenes/stress/far_offset.json");
    let o = cylaov(&py, &["verify", s(&far), "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(
        (v["checked"].as_u64(), v["passed"].as_u64()),
        (Some(1), Some(1))
    );
    let a = &v["views"][0]["arbitration"];
    // Measured: 1175 reference errors (123 silhouette, 26 seam), 0 of the other classes.
    let refs = a["reference_errors"].as_u64().expect("count");
    assert!((1000..1400).contains(&refs), "{a}");
    assert_eq!(a["candidate_errors"], 0);
    assert_eq!(a["unexplained_reference_errors"], 0);
    assert_eq!(a["cannot_discriminate"], true);
    assert_eq!(a["pixels"].as_array().map(Vec::len), Some(refs as usize));
    assert_eq!(a["pixels"][0]["class"], "reference_error");
    assert_eq!(v["views"][0]["report"]["identity"], "shape_id_part");
    let o = cylaov(&py, &["verify", s(&far)]);
    let out = text(&o);
    assert!(
        out.contains(
            "far_offset accepted: Mitsuba cannot discriminate here: its float32 ray error δ = 1.093"
        ),
        "{out}"
    );
    assert!(
        out.contains("far_offset accepted: reference error: "),
        "{out}"
    );

    // No venv: every view unchecked, exit 2, one line saying how to make it.
    let o = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(["verify", s(&scene)])
        .env("CYLAOV_VENV", dir.join("no-such-venv"))
        .output()
        .expect("running cylaov");
    let out = text(&o);
    assert_eq!(o.status.code(), Some(2), "{out}");
    // Said once, under the table (each row points there): how to make the venv.
    assert_eq!(
        out.matches("no Mitsuba venv (looked in ").count(),
        1,
        "{out}"
    );
    assert_eq!(out.matches("scripts/setup-venv").count(), 1, "{out}");
    assert!(
        out.contains("no Mitsuba venv (how to make one: below)"),
        "{out}"
    );

    // A bad scene in a folder: that view is unchecked (exit 2), the others still run.
    let mixed_tmp = common::fresh_dir("verify", "verify-cli-mixed");
    let mixed = mixed_tmp.path();
    std::fs::copy(&scene, mixed.join("a.json")).expect("copy");
    std::fs::write(mixed.join("b.json"), "{\"camera\": 1}").expect("bad scene");
    let o = cylaov(&py, &["verify", s(mixed)]);
    let out = text(&o);
    assert_eq!(o.status.code(), Some(2), "{out}");
    assert!(
        out.contains("2 of 2 views checked: 1 passed, 0 failed, 1 could not be checked"),
        "{out}"
    );
}

#[test]
fn batch_verifies_with_identity_and_keeps_verdicts() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify", "verify-batch");
    let dir = dir_tmp.path();
    let data = dir.join("data");
    let render = dir.join("render");
    // Two views: a generated one and far_offset (Mitsuba off by up to a unit there).
    let o = cylaov(
        &py,
        &[
            "generate",
            "--count",
            "1",
            "--seed",
            "5",
            "--out",
            s(&data),
            "--cylinders",
            "30",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let views = dir.join("views");
    std::fs::create_dir_all(&views).expect("views dir");
    std::fs::copy(data.join("scenes/000000.json"), views.join("gen.json")).expect("copy");
    std::fs::copy(
        root().join("scenes/stress/far_offset.json"),
        views.join("far_offset.json"),
    )
    .expect("copy");
    let data = views;
    // The dataset stores depth only: the check renders shape_id and part alongside.
    let batch = |extra: &[&str]| {
        let mut args = vec![
            "batch",
            s(&data),
            "--out",
            s(&render),
            "--aov",
            "depth",
            "--no-png",
            "--verify-fraction",
            "1",
        ];
        args.extend_from_slice(extra);
        cylaov(&py, &args)
    };
    let o = batch(&[]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert_eq!(
        out.matches("\nverify ").count() + usize::from(out.starts_with("verify ")),
        2,
        "{out}"
    );
    assert!(out.contains("verify gen: silhouette "), "{out}");
    assert!(out.contains("verify far_offset: silhouette "), "{out}");
    assert!(out.contains("candidate errors 0, ties "), "{out}");
    // The dataset stores depth only; the check rendered shape_id and part alongside.
    let exr = cylaov::image::AovImage::read_exr(&render.join("gen.exr")).expect("exr");
    let names: Vec<&str> = exr.names();
    assert_eq!(names, ["depth"], "the dataset's files are unchanged");
    for name in ["gen", "far_offset"] {
        let cached: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(render.join(format!("{name}.verify.json")))
                .expect("verdict kept"),
        )
        .expect("json");
        assert_eq!(cached["passed"], true, "{name}");
    }

    // Resume: both views done and their verdicts kept: Mitsuba does not run again.
    let o = batch(&[]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!text(&o).contains("verify "), "{}", text(&o));

    // Other bounds are another verdict: both checked again.
    let o = batch(&[
        "--max-mismatch-fraction",
        "0.5",
        "--max-seam-fraction",
        "0.5",
    ]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains("verify gen: ") && out.contains("verify far_offset: "),
        "{out}"
    );
}

/// `verify DIR --fraction F --seed S` checks the views `batch --verify-fraction F
/// --verify-seed S` checks: the choice is keyed on (scene, camera) by batch's view id, and
/// the rows are named `scene/camera`.
#[test]
fn verify_and_batch_pick_the_same_views() {
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify", "same-views");
    let dir = dir_tmp.path();
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).expect("scenes dir");
    let cameras: Vec<serde_json::Value> = (0..4)
        .map(|k| {
            serde_json::json!({
                "origin": [3.0 + f64::from(k) * 0.25, -5.0, 2.5], "target": [0, 0, 0.6],
                "up": [0, 0, 1], "fov_deg": 40, "width": 48, "height": 32
            })
        })
        .collect();
    for name in ["a", "b"] {
        let scene = serde_json::json!({
            "cameras": cameras,
            "cylinders": [{ "p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5 }],
            "aovs": ["depth"]
        });
        std::fs::write(scenes.join(format!("{name}.json")), scene.to_string()).expect("scene");
    }
    let render = dir.join("render");
    let o = cylaov(
        &py,
        &[
            "batch",
            s(&scenes),
            "--out",
            s(&render),
            "--no-png",
            "--verify-fraction",
            "0.5",
            "--verify-seed",
            "1",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let mut by_batch: Vec<String> = Vec::new();
    for name in ["a", "b"] {
        for k in 0..4 {
            if render.join(format!("{name}/{k:02}.verify.json")).is_file() {
                by_batch.push(format!("{name}/{k:02}"));
            }
        }
    }
    // The seed picks other cameras in the two scenes (keyed on the camera alone it could not).
    let cams =
        |n: &str| -> Vec<&str> { by_batch.iter().filter_map(|v| v.strip_prefix(n)).collect() };
    assert_ne!(cams("a/"), cams("b/"), "{by_batch:?}");
    let o = cylaov(
        &py,
        &[
            "verify",
            s(&scenes),
            "--fraction",
            "0.5",
            "--seed",
            "1",
            "--json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let by_verify: Vec<String> = v["views"]
        .as_array()
        .expect("views")
        .iter()
        .map(|r| r["name"].as_str().expect("name").to_string())
        .collect();
    assert_eq!(by_verify, by_batch);
}

/// An EXR changed after it was written fails `batch --verify-fraction` naming the view and
/// the pixel, whether or not an earlier verify passed (the kept verdict is the file's, by
/// its sha256): one depth sample × (1 + 1e-4), a 3×3 patch of flipped normals, one id.
#[test]
fn an_exr_changed_after_writing_fails() {
    use cylaov::image::{AovImage, ChannelMut};
    use cylaov::output::format::exr::Compression;
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify", "changed-exr");
    let dir = dir_tmp.path();
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).expect("scenes dir");
    std::fs::copy(root().join("scenes/single.json"), scenes.join("one.json")).expect("copy");
    let render = dir.join("render");
    let batch = |verify: bool| {
        let mut args = vec![
            "batch",
            s(&scenes),
            "--out",
            s(&render),
            "--no-png",
            "--aov",
            "depth,normal,shape_id",
        ];
        if verify {
            args.extend(["--verify-fraction", "1"]);
        }
        cylaov(&py, &args)
    };
    let exr = render.join("one.exr");
    let o = batch(true);
    assert!(o.status.success(), "{}", text(&o));
    let original = AovImage::read_exr(&exr).expect("exr");
    let (w, ids) = (
        original.width,
        original.u32_channel("shape_id").expect("ids").to_vec(),
    );
    let hits: Vec<usize> = (0..ids.len()).filter(|&k| ids[k] != 0).collect();
    let k = hits[hits.len() / 2];
    let at = format!("[{}, {}]", k % w, k / w);
    fn samples<'a>(img: &'a mut AovImage, name: &str) -> ChannelMut<'a> {
        img.channel_mut(name).expect("channel")
    }
    for (case, verified_before) in [("depth", true), ("normal", true), ("id", false)] {
        let mut img = original.clone();
        match (case, samples(&mut img, "depth")) {
            ("depth", ChannelMut::F32(mut v)) => v[k] *= 1.0 + 1e-4,
            ("normal", _) => {
                for c in ["normal.X", "normal.Y", "normal.Z"] {
                    if let ChannelMut::F32(mut v) = samples(&mut img, c) {
                        for dy in 0..3 {
                            for dx in 0..3 {
                                let j = k + dy * w + dx - w - 1;
                                v[j] = -v[j];
                            }
                        }
                    }
                }
            }
            _ => {
                if let ChannelMut::U32(mut v) = samples(&mut img, "shape_id") {
                    v[k] = 7;
                }
            }
        }
        if verified_before {
            // An earlier verify of the same file passed and its verdict is kept.
            let o = batch(true);
            assert!(o.status.success(), "{case}: {}", text(&o));
        } else {
            std::fs::remove_file(render.join("one.verify.json")).expect("no verdict");
        }
        img.write_exr(&exr, Compression::None).expect("write");
        let o = batch(true);
        assert!(!o.status.success(), "{case}: {}", text(&o));
        let failures =
            std::fs::read_to_string(render.join("failures.0-of-1.jsonl")).expect("failures");
        let line: serde_json::Value =
            serde_json::from_str(failures.lines().next().expect("a line")).expect("json");
        assert_eq!(line["name"], "one", "{case}: {failures}");
        let err = line["error"].as_str().expect("error");
        assert!(
            err.contains("one.exr differs from a fresh render of its scene"),
            "{case}: {err}"
        );
        // The first differing sample: the pixel, or the patch's first (top-left) pixel.
        let first = if case == "normal" {
            format!("[{}, {}]", k % w - 1, k / w - 1)
        } else {
            at.clone()
        };
        assert!(err.contains(&format!("at {first}")), "{case}: {err}");
        assert!(err.contains("candidate error: "), "{case}: {err}");
        // Restore the written file for the next case.
        original.write_exr(&exr, Compression::None).expect("write");
    }
}

/// `verify SCENE --candidate THEIR.exr`: another renderer's file judged by the exact answer
/// (K float32 ulps), channels mapped by `--channels`, a wrong sample named by pixel.
#[test]
fn verify_a_candidate_file() {
    use cylaov::geometry::{FormulaKind, Precision};
    use cylaov::image::{AovImage, Channel, ChannelMut};
    use cylaov::output::format::exr::Compression;
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify", "candidate");
    let dir = dir_tmp.path();
    let scene_path = root().join("scenes/single.json");
    let scene = cylaov::scene::load(&scene_path).expect("scene");
    let ours = cylaov::verify::reference::check_render(&scene, Precision::F64, FormulaKind::Stable);
    // Their file: depth as Z, normals as N.R/N.G/N.B, no identity channels.
    let rename = |name: &str| match name {
        "depth" => Some("Z".to_string()),
        "normal.X" => Some("N.R".into()),
        "normal.Y" => Some("N.G".into()),
        "normal.Z" => Some("N.B".into()),
        _ => None,
    };
    let theirs = AovImage::from_channels(
        ours.width,
        ours.height,
        ours.to_channels()
            .into_iter()
            .filter_map(|c| rename(&c.name).map(|name| Channel { name, data: c.data }))
            .collect(),
    );
    let good = dir.join("theirs.exr");
    theirs.write_exr(&good, Compression::None).expect("write");
    let run = |file: &Path, extra: &[&str]| {
        let mut args = vec!["verify", s(&scene_path), "--candidate", s(file)];
        args.extend_from_slice(extra);
        cylaov(&py, &args)
    };
    let o = run(&good, &["--channels", "depth=Z,normal=N"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(text(&o).contains("candidate errors 0"), "{}", text(&o));
    // Unmapped, nothing is readable as depth, distance or shape_id: could not be checked.
    let o = run(&good, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("cannot tell hits from misses"),
        "{}",
        text(&o)
    );
    // One depth sample off by 1e-3: a candidate error at that pixel.
    let mut bad = theirs.clone();
    let ids = ours.u32_channel("shape_id").expect("ids");
    let hits: Vec<usize> = (0..ids.len()).filter(|&k| ids[k] != 0).collect();
    let k = hits[hits.len() / 2];
    if let Some(ChannelMut::F32(mut v)) = bad.channel_mut("Z") {
        v[k] *= 1.001;
    }
    let bad_path = dir.join("bad.exr");
    bad.write_exr(&bad_path, Compression::None).expect("write");
    let o = run(&bad_path, &["--channels", "depth=Z,normal=N", "--json"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let a = &v["views"][0]["arbitration"];
    assert_eq!(a["candidate_errors"], 1, "{a}");
    assert_eq!(a["candidate_bound"]["storage_ulps"], 4.0);
    let p = a["pixels"]
        .as_array()
        .expect("pixels")
        .iter()
        .find(|p| p["class"] == "candidate_error")
        .expect("the pixel");
    assert_eq!(p["at"], serde_json::json!([k % ours.width, k / ours.width]));
    assert_eq!(p["kind"], "depth");
    // A camera the scene does not have, a mapping to no AOV: one line naming the flag.
    let o = run(&good, &["--camera", "3"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("--camera: the scene has 1 camera(s), got 3"),
        "{}",
        text(&o)
    );
    let o = run(&good, &["--channels", "colour=Z"]);
    assert_ne!(o.status.code(), Some(0), "{}", text(&o));
    assert!(
        text(&o).contains("--channels: \"colour\" is not one of"),
        "{}",
        text(&o)
    );
}

/// `verify OUT` of a batch's output checks the EXR files on disk, its scenes found from the
/// input `index.json` records: a written file passes, the same file with one depth sample
/// × (1 + 1e-6) (under the flat tolerance) fails naming the view and the pixel (its kept
/// verdict is the unchanged file's), `--json` gives that pixel's class; with the scenes
/// moved it says to give `--scenes`, which then finds them.
#[test]
fn verify_checks_the_files_a_batch_wrote() {
    use cylaov::image::{AovImage, ChannelMut};
    use cylaov::output::format::exr::Compression;
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify", "written");
    let dir = dir_tmp.path();
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).expect("scenes dir");
    std::fs::copy(root().join("scenes/single.json"), scenes.join("one.json")).expect("copy");
    let out = dir.join("render");
    let o = cylaov(
        &py,
        &[
            "batch",
            s(&scenes),
            "--out",
            s(&out),
            "--no-png",
            "--aov",
            "depth",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).expect("index"))
            .expect("json");
    assert_eq!(index["input"], s(&scenes), "the input, absolute");
    let verify = || cylaov(&py, &["verify", s(&out)]);
    let o = verify();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let table = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(table.contains("one                      PASS"), "{table}");
    // The row once, on stdout: no batch log line on stderr.
    assert!(
        o.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        table.contains("1 of 1 written views checked: 1 passed"),
        "{table}"
    );
    let exr = out.join("one.exr");
    let mut img = AovImage::read_exr(&exr).expect("exr");
    let w = img.width;
    let name = img.names()[0].to_string();
    let k = match img.channel_mut(&name).expect("a channel") {
        ChannelMut::F32(mut v) => {
            let hits: Vec<usize> = (0..v.len()).filter(|&k| v[k] > 0.0).collect();
            let k = hits[hits.len() / 2];
            v[k] *= 1.0 + 1e-6;
            k
        }
        ChannelMut::U32(_) => panic!("depth is u32"),
    };
    img.write_exr(&exr, Compression::None).expect("write");
    let o = verify();
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let table = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(table.contains("one                      FAIL"), "{table}");
    let at = format!("at [{}, {}]", k % w, k / w);
    assert!(table.contains(&format!("depth {at}")), "{table}");
    assert!(table.contains("candidate error: 1 px"), "{table}");
    let o = cylaov(&py, &["verify", s(&out), "--json"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let a = &v["views"][0]["arbitration"];
    assert_eq!(a["candidate_errors"], 1, "{a}");
    let p = a["pixels"]
        .as_array()
        .expect("pixels")
        .iter()
        .find(|p| p["class"] == "candidate_error")
        .expect("the pixel");
    assert_eq!(p["at"], serde_json::json!([k % w, k / w]));
    assert_eq!(p["kind"], "depth");
    assert_eq!(
        p["disagrees"], false,
        "Mitsuba agrees within the flat tolerance"
    );
    // The scenes moved: the recorded input is gone, `--scenes` says where they are now.
    let moved = dir.join("moved");
    std::fs::rename(&scenes, &moved).expect("move");
    let o = verify();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains(&format!(
            "index.json: the batch's input {} is gone; give the folder or manifest its scenes are in now with --scenes DIR",
            scenes.display()
        )),
        "{}",
        text(&o)
    );
    let o = cylaov(&py, &["verify", s(&out), "--scenes", s(&moved)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stdout).contains(&format!("depth {at}")),
        "{}",
        text(&o)
    );
}

/// `verify OUT` of a `--format webdataset` folder: each sample's arrays are judged as the
/// files format's EXR is; a depth sample changed inside a tar fails, named by its pixel.
#[test]
fn verify_checks_the_samples_of_tar_shards() {
    use cylaov::npy::{self, Dtype};
    use cylaov::output::format::tar::{TarReader, TarWriter};
    let Some(py) = venv_python() else { return };
    let dir_tmp = common::fresh_dir("verify", "shards");
    let dir = dir_tmp.path();
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).expect("scenes dir");
    std::fs::copy(root().join("scenes/single.json"), scenes.join("one.json")).expect("copy");
    std::fs::copy(root().join("scenes/cluster.json"), scenes.join("two.json")).expect("copy");
    let out = dir.join("shards");
    let o = cylaov(
        &py,
        &[
            "batch",
            s(&scenes),
            "--out",
            s(&out),
            "--format",
            "webdataset",
            "--shard-size",
            "1",
            "--aov",
            "depth,shape_id",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("shards.json")).expect("shards.json"))
            .expect("json");
    assert_eq!(
        index["scenes_dir"],
        s(&scenes),
        "the scenes' folder, absolute"
    );
    let verify = || cylaov(&py, &["verify", s(&out)]);
    let o = verify();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let table = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(table.contains("one                      PASS"), "{table}");
    assert!(table.contains("two                      PASS"), "{table}");
    assert!(
        table.contains("2 of 2 written views checked: 2 passed"),
        "{table}"
    );
    // Sample `two`'s depth, one hit pixel times (1 + 1e-6), in a rewritten tar.
    let tar = out.join("shard-000001.tar");
    let bytes = std::fs::read(&tar).expect("tar");
    let mut r = TarReader::new(&bytes[..]);
    let mut w = TarWriter::new(Vec::new());
    let mut at = None;
    while let Some((name, data)) = r.next_member().expect("member") {
        let data = if name == "two.depth.npy" {
            let a = npy::parse(&data).expect("npy");
            let (h, wd) = (a.shape[0], a.shape[1]);
            let mut v: Vec<f32> = a
                .data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            let hits: Vec<usize> = (0..v.len()).filter(|&k| v[k] > 0.0).collect();
            let k = hits[hits.len() / 2];
            v[k] *= 1.0 + 1e-6;
            at = Some(format!("at [{}, {}]", k % wd, k / wd));
            npy::array(Dtype::F32, &[h, wd], &v)
        } else {
            data
        };
        w.append(&name, &data).expect("append");
    }
    std::fs::write(&tar, w.finish().expect("finish").0).expect("write");
    let at = at.expect("two.depth.npy in shard 1");
    let o = verify();
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let table = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(table.contains("one                      PASS"), "{table}");
    assert!(table.contains("two                      FAIL"), "{table}");
    assert!(table.contains(&format!("depth {at}")), "{table}");
    assert!(table.contains("candidate error: 1 px"), "{table}");
    // The scenes moved: `--scenes` says where they are now.
    let moved = dir.join("moved");
    std::fs::rename(&scenes, &moved).expect("move");
    let o = verify();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--scenes DIR"), "{}", text(&o));
    let o = cylaov(&py, &["verify", s(&out), "--scenes", s(&moved)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    // A damaged tar is an error naming it, not a verdict.
    std::fs::write(&tar, b"not a tar, just some bytes").expect("write");
    let o = cylaov(&py, &["verify", s(&out), "--scenes", s(&moved)]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("shard-000001.tar"), "{}", text(&o));
}
