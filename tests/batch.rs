//! `generate` and `batch` end to end, through the binary: determinism, sharding, resume
//! after kill -9, a bad scene among good ones, and the back-projection example.

mod common;
use common::{cylaov, ok, tree};

use cylaov::image::AovImage;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn fresh_dir(name: &str) -> tempfile::TempDir {
    common::fresh_dir("batch", name)
}

/// The arguments of `cylaov batch INPUT --out OUT EXTRA...`.
fn batch_args<'a>(input: &'a Path, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![
        "batch",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    args
}

/// `cylaov batch INPUT --out OUT EXTRA...`, which must succeed; its stdout.
fn batch_ok(input: &Path, out: &Path, extra: &[&str]) -> String {
    ok(&batch_args(input, out, extra))
}

/// `cylaov batch INPUT --out OUT EXTRA...`: its output, whatever its exit status.
fn run_batch(input: &Path, out: &Path, extra: &[&str]) -> Output {
    cylaov(&batch_args(input, out, extra))
}

/// `cylaov batch INPUT --out OUT`, which must fail; its output, to check the reason.
fn batch_fails(input: &Path, out: &Path) -> Output {
    let o = run_batch(input, out, &[]);
    assert!(!o.status.success(), "batch {} succeeded", input.display());
    o
}

fn generate(out: &Path, seed: &str, count: &str, extra: &[&str]) {
    let mut args = vec![
        "generate",
        "--count",
        count,
        "--seed",
        seed,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    ok(&args);
}

/// A fresh folder `name` holding `count` generated scenes (`seed`, `extra` options) in
/// its `data` folder: the folder (removed when dropped) and that path.
fn generated(name: &str, seed: &str, count: &str, extra: &[&str]) -> (tempfile::TempDir, PathBuf) {
    let tmp = fresh_dir(name);
    let data = tmp.path().join("data");
    generate(&data, seed, count, extra);
    (tmp, data)
}

const SMALL: &[&str] = &["--width", "64", "--height", "48", "--cylinders", "3..6"];

#[test]
fn same_seed_gives_identical_bytes() {
    let tmp = fresh_dir("determinism");
    let dir = tmp.path();
    let (a, b, c) = (dir.join("a"), dir.join("b"), dir.join("c"));
    generate(&a, "42", "6", SMALL);
    generate(&b, "42", "6", SMALL);
    generate(&c, "43", "6", SMALL);
    let (ta, tb, tc) = (tree(&a), tree(&b), tree(&c));
    assert_eq!(ta.len(), 6 + 2, "{:?}", ta.keys());
    assert_eq!(ta, tb);
    assert_ne!(ta.get("scenes/000000.json"), tc.get("scenes/000000.json"));
    let manifest = String::from_utf8(ta["manifest.jsonl"].clone()).unwrap();
    assert_eq!(
        manifest.lines().nth(2),
        Some(r#"{"name":"000002","scene":"scenes/000002.json"}"#)
    );
    // The recorded options regenerate the same files.
    let d = dir.join("d");
    let config = a.join("generate.json");
    ok(&[
        "generate",
        "--config",
        config.to_str().unwrap(),
        "--out",
        d.to_str().unwrap(),
    ]);
    assert_eq!(tree(&d), ta);

    // Rendering is deterministic too, bytes included.
    for (src, out) in [(&a, "ra"), (&b, "rb")] {
        batch_ok(src, &dir.join(out), &[]);
    }
    let (mut ra, mut rb) = (tree(&dir.join("ra")), tree(&dir.join("rb")));
    assert_eq!(ra.len(), 6 * 7 + 2, "{:?}", ra.keys());
    // index.json records where its input was (for `cylaov verify OUT`); all else is equal.
    for (t, src) in [(&mut ra, &a), (&mut rb, &b)] {
        let text = String::from_utf8(t["index.json"].clone()).unwrap();
        let line = format!("  \"input\": {:?},\n", src.to_str().unwrap());
        assert!(text.contains(&line), "{line}: {text}");
        t.insert("index.json".into(), text.replace(&line, "").into_bytes());
    }
    assert_eq!(ra, rb);
    // Without PNGs each EXR is written band by band during the trace: the same bytes as
    // the whole-image write of the run with PNGs.
    batch_ok(&a, &dir.join("rn"), &["--no-png"]);
    let rn = tree(&dir.join("rn"));
    let exrs: Vec<_> = ra.keys().filter(|k| k.ends_with(".exr")).collect();
    assert_eq!(exrs.len(), 6);
    for k in exrs {
        assert!(rn.get(k) == ra.get(k), "{k} differs without PNGs");
    }
}

#[test]
fn bad_generate_options_name_the_flag() {
    let tmp = fresh_dir("badgen");
    let dir = tmp.path();
    let out = cylaov(&[
        "generate",
        "--count",
        "3",
        "--radius",
        "-1..2",
        "--out",
        dir.join("x").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--radius: must be > 0"), "{err}");
    assert!(!dir.join("x").exists(), "nothing is written on bad options");
}

#[test]
fn shards_partition_the_views_and_agree_on_transforms() {
    let (tmp, data) = generated("shards", "5", "9", SMALL);
    let dir = tmp.path();
    let full = dir.join("full");
    batch_ok(&data, &full, &[]);
    let full_tree = tree(&full);
    let all: BTreeSet<String> = full_tree
        .keys()
        .filter(|k| k.ends_with(".exr"))
        .cloned()
        .collect();
    assert_eq!(all.len(), 9);
    let index = &full_tree["index.json"];
    for n in [1u32, 2, 7] {
        let mut union = BTreeSet::new();
        for k in 0..n {
            let out = dir.join(format!("s{k}-{n}"));
            let shard = format!("{k}/{n}");
            batch_ok(&data, &out, &["--shard", &shard]);
            let t = tree(&out);
            assert_eq!(&t["index.json"], index, "shard {shard}");
            assert!(t.contains_key(&format!("failures.{k}-of-{n}.jsonl")));
            for (name, bytes) in &t {
                if name.ends_with(".exr") {
                    assert!(union.insert(name.clone()), "{name} in two shards (N = {n})");
                }
                if name != "index.json" && !name.starts_with("failures") {
                    assert_eq!(Some(bytes), full_tree.get(name), "{name} differs");
                }
            }
        }
        assert_eq!(union, all, "N = {n}");
    }
    // Kubernetes Indexed Job: the index from the environment.
    let out = dir.join("k8s");
    let o = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args([
            "batch",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--shards",
            "4",
        ])
        .env("JOB_COMPLETION_INDEX", "1")
        .output()
        .unwrap();
    assert!(o.status.success());
    let exrs: Vec<String> = tree(&out)
        .into_keys()
        .filter(|k| k.ends_with(".exr"))
        .collect();
    assert_eq!(exrs, vec!["000001.exr", "000005.exr"]);
}

#[test]
fn a_bad_scene_fails_alone() {
    let (tmp, data) = generated("bad", "9", "5", SMALL);
    let dir = tmp.path();
    // Read through a folder (no manifest): move the scenes up and break the middle one.
    let scenes = dir.join("scenes");
    std::fs::rename(data.join("scenes"), &scenes).unwrap();
    let bad = scenes.join("000002.json");
    let text = std::fs::read_to_string(&bad).unwrap();
    std::fs::write(&bad, text.replacen("\"radius\": ", "\"_radius\": ", 1)).unwrap();
    let out = dir.join("out");
    let o = run_batch(&scenes, &out, &[]);
    assert!(
        !o.status.success(),
        "a failed view makes the exit status non-zero"
    );
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("done 4 / skipped 0 / failed 1"), "{stdout}");
    let failures = std::fs::read_to_string(out.join("failures.0-of-1.jsonl")).unwrap();
    assert_eq!(failures.lines().count(), 1, "{failures}");
    assert!(failures.contains("000002.json"), "{failures}");
    assert!(failures.contains("unknown field `_radius`"), "{failures}");
    for i in [0, 1, 3, 4] {
        assert!(out.join(format!("00000{i}.exr")).is_file());
    }
    assert!(!out.join("000002.exr").exists());
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    assert_eq!(t["views"].as_array().unwrap().len(), 4);

    // A semantic error names the field and the value.
    std::fs::write(&bad, text.replacen("\"radius\": ", "\"radius\": -1.5, \"caps\": true, \"id\": 7 }, { \"p0\": [0,0,0], \"p1\": [0,0,1], \"radius\": ", 1)).unwrap();
    let o = batch_fails(&scenes, &out);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("done 0 / skipped 4 / failed 1"), "{stdout}");
    let failures = std::fs::read_to_string(out.join("failures.0-of-1.jsonl")).unwrap();
    assert!(
        failures.contains("cylinders[0].radius: must be > 0"),
        "{failures}"
    );
    assert!(failures.contains("-1.5"), "{failures}");
}

#[test]
fn resume_after_kill_completes_with_correct_files() {
    let tmp = fresh_dir("kill");
    let dir = tmp.path();
    let data = dir.join("data");
    // Slow enough to be caught mid-way on one thread.
    generate(&data, "11", "40", &["--cylinders", "100"]);
    let reference = dir.join("reference");
    let out = dir.join("out");
    let run = |out: &Path| {
        Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args([
                "batch",
                data.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--threads",
                "1",
            ])
            .env_remove("SLURM_ARRAY_TASK_ID")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap()
    };
    let mut child = run(&out);
    let t0 = Instant::now();
    let count_exr = || {
        std::fs::read_dir(&out)
            .map(|d| {
                d.filter(|e| {
                    e.as_ref()
                        .is_ok_and(|e| e.path().extension().is_some_and(|x| x == "exr"))
                })
                .count()
            })
            .unwrap_or(0)
    };
    while count_exr() < 4 && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(
        child.try_wait().unwrap().is_none(),
        "finished before the kill: make it slower"
    );
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let killed_at = count_exr();
    assert!((4..40).contains(&killed_at), "{killed_at}");
    // Whatever is in place is whole: every EXR reads back with its pixels.
    for (name, _) in tree(&out) {
        if name.ends_with(".exr") && !name.starts_with(".partial") {
            AovImage::read_exr(&out.join(&name)).unwrap();
        }
        assert!(
            !name.ends_with(".tmp") || name.starts_with(".partial/"),
            "{name}: temporary file outside .partial"
        );
    }

    let o = run_batch(&data, &out, &[]);
    assert!(o.status.success());
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains(&format!("skipped {killed_at} /")),
        "{stdout}"
    );
    assert!(
        !out.join(".partial").exists(),
        ".partial is removed at the end"
    );

    batch_ok(&data, &reference, &[]);
    let (got, want) = (tree(&out), tree(&reference));
    // Per view: EXR, camera, Open3D camera, normal preview, depth, mask, stamp; then
    // index.json and the failures file.
    assert_eq!(got.len(), 40 * 7 + 2);
    assert!(got.keys().all(|k| !k.ends_with(".tmp")));
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        want.keys().collect::<Vec<_>>()
    );
    for (k, v) in &want {
        assert!(&got[k] == v, "{k} differs from an uninterrupted run");
    }
}

#[test]
fn manifest_and_folder_inputs() {
    let (tmp, data) = generated("inputs", "3", "3", SMALL);
    let dir = tmp.path();
    // A manifest with its own names, in its own order.
    let manifest = dir.join("views.jsonl");
    std::fs::write(
        &manifest,
        "{\"name\": \"b\", \"scene\": \"data/scenes/000002.json\"}\n\n\
         {\"name\": \"a\", \"scene\": \"data/scenes/000000.json\", \"split\": \"train\"}\n",
    )
    .unwrap();
    let out = dir.join("out");
    batch_ok(&manifest, &out, &["--no-png", "--aov", "depth,shape_id"]);
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    let paths: Vec<&str> = t["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["file_path"].as_str().unwrap())
        .collect();
    assert_eq!(paths, vec!["b.exr", "a.exr"]);
    assert!(t.get("depth_unit_scale_factor").is_none());
    let img = AovImage::read_exr(&out.join("a.exr")).unwrap();
    let names: Vec<&str> = img.names();
    assert_eq!(names, vec!["depth", "shape_id"]);
    assert!(!out.join("a.depth.png").exists());

    // Duplicate names are refused before anything is rendered.
    std::fs::create_dir_all(dir.join("twice/x")).unwrap();
    std::fs::copy(data.join("scenes/000000.json"), dir.join("twice/s.json")).unwrap();
    std::fs::copy(data.join("scenes/000001.json"), dir.join("twice/x/s.json")).unwrap();
    let o = batch_fails(&dir.join("twice"), &dir.join("o2"));
    assert!(String::from_utf8_lossy(&o.stderr).contains("view name \"s\" is used twice"));
    assert!(!dir.join("o2/s.exr").exists());
}

/// The dataset index matches the per-view camera files and the depth PNG scale.
#[test]
fn transforms_match_cameras_and_depth_png() {
    let (tmp, data) = generated(
        "transforms",
        "8",
        "2",
        &["--width", "80", "--height", "60", "--cylinders", "20"],
    );
    let dir = tmp.path();
    let out = dir.join("out");
    let o = run_batch(&data, &out, &["--depth-scale", "500"]);
    assert!(o.status.success());
    // nerfstudio does not read the scale from the file: the batch says what to pass.
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("warning: --depth-scale 500")
            && err.contains("depth_unit_scale_factor = 0.002"),
        "{err}"
    );
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    let v = &t["views"][1];
    assert_eq!((&v["scene"], &v["camera"]), (&"000001".into(), &0.into()));
    assert_eq!(v["w"], 80);
    assert_eq!(v["cx"], 40.0);
    assert_eq!(v["cy"], 30.0);
    assert_eq!(v["mask_path"], "000001.mask.png");
    assert_eq!(t["depth_unit_scale_factor"], 0.002);
    let cam: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("000001.camera.json")).unwrap()).unwrap();
    assert_eq!(v["transform_matrix"], cam["camera_to_world_opengl"]);
    assert_eq!(v["fl_x"], cam["fl_x"]);
    assert_eq!(
        (&cam["cx_opencv"], &cam["cy_opencv"]),
        (&39.5.into(), &29.5.into())
    );
    // 16-bit depth PNG = round(depth * 500).
    let hits = assert_depth_png_scale(&out, "000001", 500.0);
    assert!(hits > 100, "{hits} hits");
}

/// `--verify-fraction` plumbing with a stand-in reference (the Mitsuba one is
/// `cylaov::verify`): every selected view is checked, a disagreement fails that view alone.
#[test]
fn verify_fraction_checks_selected_views_and_fails_disagreements() {
    use cylaov::dataset::batch::{
        self, BatchOptions, ProgressMode, Shard, Verdict, Verifier, ViewSource,
    };
    struct ReadsBack;
    impl Verifier for ReadsBack {
        fn check(
            &self,
            view: &ViewSource,
            scene: &cylaov::scene::Scene,
            exr: &Path,
            work: &Path,
        ) -> anyhow::Result<Verdict> {
            assert!(work.is_dir());
            let img = AovImage::read_exr(exr)?;
            let ok = img.width == scene.camera.width as usize && view.name != "000001";
            Ok(Verdict {
                passes: ok,
                report: format!("stand-in verdict for {}", view.name),
            })
        }
    }
    let (tmp, data) = generated("verify", "2", "4", SMALL);
    let dir = tmp.path();
    let out = dir.join("out");
    let opts = |fraction| BatchOptions {
        verify_fraction: fraction,
        verify_seed: 1,
        ..BatchOptions::default()
    };
    let s = batch::run(
        &data,
        &out,
        Shard::ALL,
        &opts(1.0),
        ProgressMode::Off,
        Some(&ReadsBack),
    )
    .unwrap();
    assert_eq!(
        (s.counts.done, s.counts.failed, s.verified),
        (3, 1, 4),
        "{s}"
    );
    assert!(
        s.failures[0]
            .error
            .contains("disagrees with the reference: stand-in verdict for 000001")
    );
    let s = batch::run(
        &data,
        &out,
        Shard::ALL,
        &opts(0.0),
        ProgressMode::Off,
        Some(&ReadsBack),
    )
    .unwrap();
    assert_eq!(
        (s.counts.skipped, s.counts.failed, s.verified),
        (4, 0, 0),
        "{s}"
    );
    let picked = (0..4)
        .filter(|i| batch::selected_for_verify(1, &format!("{i:06}"), 0.5))
        .count();
    let s = batch::run(
        &data,
        &out,
        Shard::ALL,
        &opts(0.5),
        ProgressMode::Off,
        Some(&ReadsBack),
    )
    .unwrap();
    assert_eq!(s.verified, picked);
}

/// `--verify-fraction 1` against real Mitsuba renders (skipped, saying so, without the
/// reference venv; failed then under `CYLAOV_REQUIRE_VENV=1`): every view is verified and
/// agrees.
#[test]
fn verify_fraction_with_mitsuba_agrees_on_generated_views() {
    if common::venv_python().is_none() {
        return;
    }
    let (tmp, data) = generated("verify-mitsuba", "3", "3", SMALL);
    let dir = tmp.path();
    let out = dir.join("out");
    let text = batch_ok(&data, &out, &["--verify-fraction", "1"]);
    assert!(
        text.contains("3 views verified") && text.contains("failed 0"),
        "{text}"
    );
}

/// Every view of a several-camera scene is checked against Mitsuba's render of its own
/// sensor (the export writes one per camera; the reference script takes the index): with
/// sensor 0 for all, views 01 and 02 would disagree.
#[test]
fn verify_fraction_checks_every_camera_of_a_scene() {
    if common::venv_python().is_none() {
        return;
    }
    let (tmp, data) = generated(
        "verify-cameras",
        "4",
        "1",
        &[SMALL, &["--views-per-scene", "3"]].concat(),
    );
    let dir = tmp.path();
    let out = dir.join("out");
    let text = batch_ok(&data, &out, &["--verify-fraction", "1"]);
    assert!(
        text.contains("done 3 /") && text.contains("3 views verified") && text.contains("failed 0"),
        "{text}"
    );
}

/// A scene whose camera changed under the same name is rendered again, not skipped.
#[test]
fn changed_camera_is_rendered_again() {
    let (tmp, data) = generated("changed", "6", "3", SMALL);
    let dir = tmp.path();
    let out = dir.join("out");
    batch_ok(&data, &out, &[]);
    let scene = data.join("scenes/000001.json");
    let text = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(
        &scene,
        text.replace("\"fov_deg\": 50.0", "\"fov_deg\": 40.0"),
    )
    .unwrap();
    let stdout = batch_ok(&data, &out, &[]);
    assert!(stdout.contains("done 1 / skipped 2 / failed 0"), "{stdout}");
    let cam = std::fs::read_to_string(out.join("000001.camera.json")).unwrap();
    assert!(cam.contains("\"fov_deg\": 40.0"), "{cam}");

    // A cylinder changed, the camera not: rendered again too (the render stamp).
    let scene = data.join("scenes/000002.json");
    let text = std::fs::read_to_string(&scene).unwrap();
    assert!(text.contains("\"radius\": 0."));
    std::fs::write(
        &scene,
        text.replacen("\"radius\": 0.", "\"radius\": 0.0", 1),
    )
    .unwrap();
    let stdout = batch_ok(&data, &out, &[]);
    assert!(stdout.contains("done 1 / skipped 2 / failed 0"), "{stdout}");
}

/// Temporary names: hidden, ending in `.tmp`, in the target's folder, distinct per call
/// (shards on different nodes can share a PID), with the host and PID in the name; the
/// committed file has the mode a plain `File::create` gives, and an uncommitted one is gone
/// when dropped.
#[test]
fn staged_files_have_unique_temporary_names_and_plain_modes() {
    use cylaov::output::store::atomic::stage;
    use std::io::Write;
    use std::os::unix::fs::PermissionsExt;
    let tmp = fresh_dir("staged");
    let dir = tmp.path();
    let target = dir.join("000001.exr");
    let a = stage(&target, |f| f.write_all(b"a")).unwrap();
    let b = stage(&target, |f| f.write_all(b"b")).unwrap();
    assert_ne!(a.temp_path(), b.temp_path());
    for p in [a.temp_path(), b.temp_path()] {
        assert_eq!(p.parent(), target.parent());
        let name = p.file_name().unwrap().to_string_lossy();
        assert!(name.starts_with(".000001.exr."), "{name}");
        assert!(name.ends_with(".tmp"), "{name}");
        assert!(
            name.contains(&format!(".{}.", std::process::id())),
            "{name}"
        );
        assert!(p.exists(), "{name}");
    }
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty());
    if let Some(host) = host {
        let name = a
            .temp_path()
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let safe: String = host
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '.')
            .take(16)
            .collect();
        assert!(name.contains(&safe), "{name} lacks {safe}");
    }
    let b_tmp = b.temp_path().to_path_buf();
    drop(b);
    assert!(!b_tmp.exists(), "a dropped staged file is removed");
    a.commit().unwrap();
    assert_eq!(std::fs::read(&target).unwrap(), b"a");
    let plain = dir.join("plain");
    std::fs::File::create(&plain).unwrap();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&target), mode(&plain));
    let left: Vec<_> = std::fs::read_dir(dir).unwrap().collect();
    assert_eq!(left.len(), 2, "only the output and the plain file remain");
}

/// An input without views is an error that names it; nothing is written.
#[test]
fn empty_input_is_an_error() {
    let tmp = fresh_dir("empty");
    let dir = tmp.path();
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = dir.join("out");
    let o = batch_fails(&empty, &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(empty.to_str().unwrap()), "{err}");
    assert!(err.contains("no scene files"), "{err}");
    assert!(!out.join("index.json").exists());

    // An empty manifest.
    let manifest = dir.join("none.jsonl");
    std::fs::write(&manifest, "\n").unwrap();
    let o = batch_fails(&manifest, &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(manifest.to_str().unwrap()), "{err}");
    assert!(!out.join("index.json").exists());

    // --out equal to the input: every scene file lies under --out and is excluded.
    let scenes = dir.join("scenes");
    generate(&dir.join("data"), "1", "2", SMALL);
    std::fs::rename(dir.join("data/scenes"), &scenes).unwrap();
    let o = batch_fails(&scenes, &scenes);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(scenes.to_str().unwrap()), "{err}");
    assert!(err.contains("skipped 2 *.json files under it"), "{err}");
    assert!(!scenes.join("index.json").exists());
}
/// A re-render whose commit cannot put a file in place (a folder in its place) moves
/// none of the view's files: the old camera and EXR stay together, and the next run
/// renders the view again. (The old EXR goes before any new file of its view is renamed
/// into place; `view_writer.rs` checks a commit that fails half-way.)
#[test]
fn interrupted_rerender_leaves_no_stale_exr() {
    let (tmp, data) = generated("stale", "13", "2", SMALL);
    let dir = tmp.path();
    let out = dir.join("out");
    let batch = || run_batch(&data, &out, &[]);
    assert!(batch().status.success());
    let old_png = std::fs::read(out.join("000001.normal.preview.png")).unwrap();
    // A new camera for view 1, and a normal PNG that cannot be replaced (a folder in its
    // place): the re-render fails before it moves anything.
    let scene = data.join("scenes/000001.json");
    let text = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(
        &scene,
        text.replace("\"fov_deg\": 50.0", "\"fov_deg\": 40.0"),
    )
    .unwrap();
    let png = out.join("000001.normal.preview.png");
    std::fs::remove_file(&png).unwrap();
    std::fs::create_dir_all(png.join("blocker")).unwrap();
    let o = batch();
    assert!(!o.status.success());
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("done 0 / skipped 1 / failed 1"), "{stdout}");
    let cam = std::fs::read_to_string(out.join("000001.camera.json")).unwrap();
    assert!(cam.contains("\"fov_deg\": 50.0"), "no new file was moved");
    assert!(out.join("000001.exr").exists(), "the old view stays whole");
    // Put the old PNG back: the stamp no longer matches the scene, so the view renders.
    std::fs::remove_dir_all(&png).unwrap();
    std::fs::write(&png, old_png).unwrap();
    let o = batch();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("done 1 / skipped 1 / failed 0"), "{stdout}");
    let fresh = dir.join("fresh");
    batch_ok(&data, &fresh, &[]);
    assert_eq!(tree(&out), tree(&fresh));
}

/// Every 16-bit depth PNG value of `name` in `out` is round(depth × scale) of its EXR;
/// returns the pixels with a depth.
fn assert_depth_png_scale(out: &Path, name: &str, scale: f64) -> usize {
    let img = AovImage::read_exr(&out.join(format!("{name}.exr"))).unwrap();
    let depth = img.f32_channel("depth").unwrap();
    let png = image::open(out.join(format!("{name}.depth.png")))
        .unwrap()
        .into_luma16();
    let mut hits = 0;
    for (k, p) in png.pixels().enumerate() {
        let want = if depth[k] > 0.0 {
            (depth[k] as f64 * scale).round().min(65535.0) as u16
        } else {
            0
        };
        assert_eq!(p.0[0], want, "{name} pixel {k} at scale {scale}");
        hits += (want > 0) as usize;
    }
    assert!(hits > 50, "{name}: {hits} hits");
    hits
}

/// A rerun with an option that changes the output bytes renders the views again; the same
/// options skip them.
#[test]
fn changed_options_are_rendered_again() {
    let (tmp, data) = generated("options", "12", "3", SMALL);
    let dir = tmp.path();
    let out = dir.join("out");
    let batch = |extra: &[&str]| batch_ok(&data, &out, extra);
    let stdout = batch(&[]);
    assert!(stdout.contains("done 3 / skipped 0"), "{stdout}");
    assert_depth_png_scale(&out, "000001", 1000.0);
    let stdout = batch(&[]);
    assert!(stdout.contains("done 0 / skipped 3"), "{stdout}");

    // The reproduction: --depth-scale 10 must rewrite the PNGs, not only the index.
    let stdout = batch(&["--depth-scale", "10"]);
    assert!(stdout.contains("done 3 / skipped 0"), "{stdout}");
    for name in ["000000", "000001", "000002"] {
        assert_depth_png_scale(&out, name, 10.0);
    }
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    assert_eq!(t["depth_unit_scale_factor"], 0.1);
    let stdout = batch(&["--depth-scale", "10"]);
    assert!(stdout.contains("done 0 / skipped 3"), "{stdout}");

    // Every other option that changes the bytes, one at a time.
    for extra in [
        &["--depth-scale", "10", "--precision", "f32"][..],
        &[
            "--depth-scale",
            "10",
            "--precision",
            "f32",
            "--formula",
            "literal",
        ],
        &[
            "--depth-scale",
            "10",
            "--precision",
            "f32",
            "--formula",
            "literal",
            "--compression",
            "zip",
        ],
        &[
            "--depth-scale",
            "10",
            "--precision",
            "f32",
            "--formula",
            "literal",
            "--compression",
            "zip",
            "--aov",
            "depth",
        ],
    ] {
        let stdout = batch(extra);
        assert!(stdout.contains("done 3 / skipped 0"), "{extra:?}: {stdout}");
        let stdout = batch(extra);
        assert!(stdout.contains("done 0 / skipped 3"), "{extra:?}: {stdout}");
    }
    // --no-png renders again and leaves the outputs of a fresh --no-png run (no PNGs).
    let stdout = batch(&["--no-png"]);
    assert!(stdout.contains("done 3 / skipped 0"), "{stdout}");
    assert!(!out.join("000001.depth.png").exists());
    assert!(!out.join("000001.normal.preview.png").exists());
    assert!(!out.join("000001.mask.png").exists());
    let fresh = dir.join("fresh");
    batch_ok(&data, &fresh, &["--no-png"]);
    assert_eq!(tree(&out), tree(&fresh));
    // Without PNGs the depth scale changes nothing.
    let stdout = batch(&["--no-png", "--depth-scale", "7"]);
    assert!(stdout.contains("done 0 / skipped 3"), "{stdout}");
}

/// `--ply` writes `NAME.ply` per view: the points `render --ply` writes for the view (one
/// vertex per hit pixel of the EXR's depth), whatever `--aov` holds. Turning it on renders
/// the views again; turning it off renders them again and removes the point clouds.
#[test]
fn ply_writes_each_views_hit_points() {
    let (tmp, data) = generated("ply", "21", "2", SMALL);
    let out = tmp.path().join("out");
    let stdout = batch_ok(&data, &out, &["--aov", "depth"]);
    assert!(stdout.contains("done 2 / skipped 0"), "{stdout}");
    assert!(!out.join("000000.ply").exists());
    let stdout = batch_ok(&data, &out, &["--aov", "depth", "--ply"]);
    assert!(stdout.contains("done 2 / skipped 0"), "{stdout}");
    let stdout = batch_ok(&data, &out, &["--aov", "depth", "--ply"]);
    assert!(stdout.contains("done 0 / skipped 2"), "{stdout}");
    let body = |b: &[u8]| {
        let end = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let head = String::from_utf8(b[..end].to_vec()).unwrap();
        let n: usize = head
            .lines()
            .find_map(|l| l.strip_prefix("element vertex "))
            .unwrap()
            .parse()
            .unwrap();
        (n, b[end..].to_vec())
    };
    for name in ["000000", "000001"] {
        let (n, points) = body(&std::fs::read(out.join(format!("{name}.ply"))).unwrap());
        let img = AovImage::read_exr(&out.join(format!("{name}.exr"))).unwrap();
        let hits = img
            .f32_channel("depth")
            .unwrap()
            .iter()
            .filter(|&&z| z > 0.0)
            .count();
        assert!(hits > 20, "{name}: {hits} hits");
        assert_eq!(n, hits, "{name}");
        assert_eq!(points.len(), n * 36, "{name}");
        let alone = tmp.path().join(format!("{name}.ply"));
        ok(&[
            "render",
            &data.join(format!("scenes/{name}.json")).to_string_lossy(),
            "-o",
            &tmp.path().join(format!("{name}.exr")).to_string_lossy(),
            "--ply",
            &alone.to_string_lossy(),
        ]);
        assert_eq!(body(&std::fs::read(&alone).unwrap()).1, points, "{name}");
    }
    let stdout = batch_ok(&data, &out, &["--aov", "depth"]);
    assert!(stdout.contains("done 2 / skipped 0"), "{stdout}");
    assert!(!out.join("000000.ply").exists());
    let o = run_batch(&data, &out, &["--format", "webdataset", "--ply"]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr)
            .contains("--ply: with --format webdataset, ask for --members ply"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // The tars' EXR member is one layered file: a per-AOV layout is refused, not ignored.
    let tars = tmp.path().join("tars");
    let o = run_batch(
        &data,
        &tars,
        &["--format", "webdataset", "--exr-layout", "per-aov"],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains(
            "--exr-layout per-aov: with --format webdataset a view's EXR (--members exr) is one layered file"
        ),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!tars.exists());
}
