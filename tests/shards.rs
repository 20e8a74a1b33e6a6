//! `batch --format webdataset`: deterministic tar shards (two runs, `--shard K/N` in three
//! processes), per-shard resume, refusals before rendering, failed views keeping their
//! slot, arrays bitwise those of the files format, and the size of a shard.

mod common;

use common::{cylaov, fresh_dir, ok, tree, venv_python};
use cylaov::image::AovImage;
use std::collections::BTreeMap;
use std::os::unix::fs::MetadataExt;
use std::path::Path;

/// `count` generated 320x240 scenes of 20 cylinders in `dir/data`.
fn generate(dir: &Path, count: usize) -> std::path::PathBuf {
    let data = dir.join("data");
    ok(&[
        "generate",
        "--count",
        &count.to_string(),
        "--seed",
        "3",
        "--cylinders",
        "20",
        "--out",
        data.to_str().unwrap(),
    ]);
    data
}

fn batch_wds(data: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "batch",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--format",
        "webdataset",
    ];
    args.extend_from_slice(extra);
    cylaov(&args)
}

fn must(o: std::process::Output) -> String {
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The shard files of `out` (tars, sidecars, shards.json): no failures lists, no locks.
fn shard_files(out: &Path) -> BTreeMap<String, Vec<u8>> {
    tree(out)
        .into_iter()
        .filter(|(k, _)| !k.starts_with("failures.") && !k.starts_with(".partial"))
        .collect()
}

/// The members of a tar, read back by this test's own ustar parser: (name, data).
fn members(tar: &[u8]) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut at = 0;
    while at + 512 <= tar.len() && tar[at..at + 512].iter().any(|&b| b != 0) {
        let h = &tar[at..at + 512];
        let name = String::from_utf8_lossy(&h[..100])
            .trim_end_matches('\0')
            .to_string();
        let size = usize::from_str_radix(
            String::from_utf8_lossy(&h[124..135]).trim_end_matches('\0'),
            8,
        )
        .unwrap();
        out.push((name, tar[at + 512..at + 512 + size].to_vec()));
        at += 512 + size.next_multiple_of(512);
    }
    assert_eq!(tar.len(), at + 1024, "two zero blocks end the archive");
    out
}

/// The float32 samples of a `.npy` member after its header.
fn npy_f32(bytes: &[u8]) -> (String, Vec<u32>) {
    let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = String::from_utf8_lossy(&bytes[10..10 + len]).into_owned();
    let data = bytes[10 + len..]
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    (header, data)
}

/// Two runs write the same bytes, and three processes `--shard K/3` write the tars,
/// sidecars and shards.json of one process; Python's `tarfile` reads every member with
/// mtime 0, uid 0 and mode 0644.
#[test]
fn shards_are_deterministic_across_runs_and_processes() {
    let dir = fresh_dir("shards", "determinism");
    let data = generate(dir.path(), 10);
    let (a, b, c) = (
        dir.path().join("a"),
        dir.path().join("b"),
        dir.path().join("c"),
    );
    let said = must(batch_wds(&data, &a, &["--shard-size", "3"]));
    assert!(
        said.contains("of tar shards (the files format: about"),
        "{said}"
    );
    // Progress as the files format shows it, each view counted once.
    assert!(
        said.contains("batch 0-of-1 10/10 (done 10 skipped 0 failed 0)"),
        "{said}"
    );
    let again = must(batch_wds(&data, &a, &["--shard-size", "3"]));
    assert!(
        again.contains("batch 0-of-1 10/10 (done 0 skipped 10 failed 0)"),
        "{again}"
    );
    must(batch_wds(&data, &b, &["--shard-size", "3"]));
    let one = shard_files(&a);
    assert_eq!(
        one.keys().cloned().collect::<Vec<_>>(),
        [
            "shard-000000.json",
            "shard-000000.tar",
            "shard-000001.json",
            "shard-000001.tar",
            "shard-000002.json",
            "shard-000002.tar",
            "shard-000003.json",
            "shard-000003.tar",
            "shards.json",
            "shards.settings.json"
        ]
    );
    assert_eq!(one, shard_files(&b));
    // One thread (render and append in turn) or three (windows of views rendering while
    // the last is appended, tars side by side): the same bytes.
    for threads in ["1", "3"] {
        let d = dir.path().join(format!("threads-{threads}"));
        must(batch_wds(
            &data,
            &d,
            &["--shard-size", "3", "--threads", threads],
        ));
        assert_eq!(one, shard_files(&d), "--threads {threads}");
    }
    // Three processes at once, several times over: they share `.partial`, which the last
    // to leave removes, and `shards.json`, which the last to finish writes.
    for round in 0..6 {
        let c = c.with_extension(round.to_string());
        let procs: Vec<_> = (0..3)
            .map(|k| {
                std::process::Command::new(env!("CARGO_BIN_EXE_cylaov"))
                    .args([
                        "batch",
                        data.to_str().unwrap(),
                        "--out",
                        c.to_str().unwrap(),
                    ])
                    .args(["--format", "webdataset", "--shard-size", "3"])
                    .args(["--shard", &format!("{k}/3")])
                    .env_remove("SLURM_ARRAY_TASK_ID")
                    .stdout(std::process::Stdio::piped())
                    .stderr(std::process::Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .collect();
        for p in procs {
            must(p.wait_with_output().unwrap());
        }
        assert_eq!(one, shard_files(&c), "round {round}");
    }
    let index: serde_json::Value = serde_json::from_slice(&one["shards.json"]).unwrap();
    assert_eq!(index["samples"], 10);
    assert_eq!(index["shards"][3]["samples"], 1);
    let keys: Vec<String> = members(&one["shard-000001.tar"])
        .into_iter()
        .map(|m| m.0)
        .collect();
    assert_eq!(
        keys[..5],
        [
            "000003.depth.npy",
            "000003.normal.npy",
            "000003.mask.npy",
            "000003.json",
            "000004.depth.npy"
        ]
    );
    let Some(py) = venv_python() else { return };
    let check = std::process::Command::new(py)
        .arg("-c")
        .arg(
            "import sys, tarfile\n\
             t = tarfile.open(sys.argv[1])\n\
             ms = t.getmembers()\n\
             assert len(ms) == 12, len(ms)\n\
             for m in ms:\n\
             \x20   assert m.isfile() and m.mtime == 0 and m.uid == 0 and m.gid == 0, m\n\
             \x20   assert m.mode == 0o644 and m.uname == 'cylaov', m\n\
             \x20   assert len(t.extractfile(m).read()) == m.size\n\
             print(t.getnames()[0])",
        )
        .arg(a.join("shard-000000.tar"))
        .output()
        .unwrap();
    assert!(
        check.status.success(),
        "{}",
        String::from_utf8_lossy(&check.stderr)
    );
    assert_eq!(
        String::from_utf8_lossy(&check.stdout).trim(),
        "000000.depth.npy"
    );
}

/// A rerun touches nothing; an edited scene redoes only its tar; a truncated tar is
/// redone; a missing sidecar redoes its tar. Each time the bytes are a fresh run's.
#[test]
fn resume_redoes_only_missing_stale_or_damaged_tars() {
    let dir = fresh_dir("shards", "resume");
    let data = generate(dir.path(), 6);
    let out = dir.path().join("out");
    must(batch_wds(&data, &out, &["--shard-size", "2"]));
    let first = shard_files(&out);
    let inodes = |out: &Path| -> Vec<(u64, i64)> {
        (0..3)
            .map(|j| {
                let m = std::fs::metadata(out.join(format!("shard-{j:06}.tar"))).unwrap();
                (m.ino(), m.mtime_nsec())
            })
            .collect()
    };
    let before = inodes(&out);
    must(batch_wds(&data, &out, &["--shard-size", "2"]));
    assert_eq!(inodes(&out), before, "a rerun rewrote a tar");
    assert_eq!(shard_files(&out), first);
    // Without the `exr` member the EXR compression changes no tar byte: nothing rewritten.
    must(batch_wds(
        &data,
        &out,
        &["--shard-size", "2", "--compression", "zip"],
    ));
    assert_eq!(inodes(&out), before, "--compression rewrote a tar");
    assert_eq!(shard_files(&out), first);

    // Scene 000003 is in tar 1 (views 2, 3).
    let scene = data.join("scenes/000003.json");
    let text = std::fs::read_to_string(&scene).unwrap();
    let edited = text.replacen("\"radius\": 0.", "\"radius\": 0.0", 1);
    assert_ne!(edited, text);
    std::fs::write(&scene, edited).unwrap();
    let stdout = ok(&[
        "batch",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--format",
        "webdataset",
        "--shard-size",
        "2",
    ]);
    assert!(stdout.contains("1 tar written, 2 skipped"), "{stdout}");
    let after = inodes(&out);
    assert_eq!((after[0], after[2]), (before[0], before[2]));
    assert_ne!(after[1], before[1]);
    let edited_files = shard_files(&out);
    assert_ne!(edited_files["shard-000001.tar"], first["shard-000001.tar"]);
    assert_eq!(edited_files["shard-000000.tar"], first["shard-000000.tar"]);

    // A truncated tar 2, and tar 0 without its sidecar: both redone, to the same bytes.
    let t2 = out.join("shard-000002.tar");
    let len = std::fs::metadata(&t2).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&t2)
        .unwrap()
        .set_len(len - 1024)
        .unwrap();
    std::fs::remove_file(out.join("shard-000000.json")).unwrap();
    std::fs::remove_file(out.join("shards.json")).unwrap();
    let stdout = ok(&[
        "batch",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--format",
        "webdataset",
        "--shard-size",
        "2",
    ]);
    assert!(stdout.contains("2 tars written, 1 skipped"), "{stdout}");
    assert_eq!(shard_files(&out), edited_files);
}

fn scene(cameras: usize) -> String {
    let cam = r#"{"origin": [0, -4, 1], "target": [0, 0, 0], "up": [0, 0, 1], "fov_deg": 50,
        "width": 32, "height": 24}"#;
    let cams = vec![cam; cameras].join(", ");
    let camera = if cameras == 1 {
        format!("\"camera\": {cam}")
    } else {
        format!("\"cameras\": [{cams}]")
    };
    format!(
        r#"{{{camera}, "cylinders": [{{"p0": [0, 0, -0.5], "p1": [0, 0, 0.5], "radius": 0.4, "caps": true}}]}}"#
    )
}

/// A scene name with a dot, and two views with one key, are refused before anything is
/// written, naming the scene; a several-camera scene's views are keyed SCENE_cNN.
#[test]
fn dotted_names_and_colliding_keys_are_refused() {
    let dir = fresh_dir("shards", "refusals");
    let data = dir.path().join("dotted");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(data.join("a.b.json"), scene(1)).unwrap();
    std::fs::write(data.join("c.json"), scene(1)).unwrap();
    let out = dir.path().join("out");
    let r = batch_wds(&data, &out, &[]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("scene name \"a.b\" has a '.'"), "{err}");
    assert!(!out.exists(), "something was written");

    let data = dir.path().join("clash");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(data.join("s.json"), scene(2)).unwrap();
    std::fs::write(data.join("s_c01.json"), scene(1)).unwrap();
    let r = batch_wds(&data, &out, &[]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("both have the key \"s_c01\""), "{err}");
    assert!(!out.exists(), "something was written");

    std::fs::remove_file(data.join("s_c01.json")).unwrap();
    must(batch_wds(&data, &out, &[]));
    let names: Vec<String> = members(&std::fs::read(out.join("shard-000000.tar")).unwrap())
        .into_iter()
        .map(|m| m.0)
        .filter(|n| n.ends_with(".json"))
        .collect();
    assert_eq!(names, ["s_c00.json", "s_c01.json"]);
}

/// A scene that does not load keeps its slot: absent from its tar, listed in the
/// failures file and the sidecar; the batch exits 1 and the other views are all there.
#[test]
fn failed_views_keep_their_slot() {
    let dir = fresh_dir("shards", "failed");
    let data = generate(dir.path(), 5);
    std::fs::write(data.join("scenes/000001.json"), "{\"cylinders\": []}").unwrap();
    let out = dir.path().join("out");
    let r = batch_wds(&data, &out, &["--shard-size", "2"]);
    assert_eq!(r.status.code(), Some(1));
    let failures = std::fs::read_to_string(out.join("failures.0-of-1.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = failures
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 1);
    assert_eq!(lines[0]["key"], "000001");
    let tar0 = members(&std::fs::read(out.join("shard-000000.tar")).unwrap());
    let keys: Vec<&str> = tar0
        .iter()
        .filter(|m| m.0.ends_with(".json"))
        .map(|m| m.0.as_str())
        .collect();
    assert_eq!(keys, ["000000.json"]);
    let tar1 = members(&std::fs::read(out.join("shard-000001.tar")).unwrap());
    assert!(tar1[0].0.starts_with("000002."), "{}", tar1[0].0);
    let car: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("shard-000000.json")).unwrap()).unwrap();
    assert_eq!(car["samples"], 1);
    assert_eq!(car["failures"][0]["key"], "000001");
}

/// The depth and normal arrays are bitwise the EXR channels of the files format, read
/// back with `AovImage::read_exr`; a tar is within 2% of its raw arrays plus headers; the
/// optional members are the files format's bytes.
#[test]
fn arrays_are_the_files_formats_samples() {
    let dir = fresh_dir("shards", "bitwise");
    let data = generate(dir.path(), 3);
    let files = dir.path().join("files");
    let shards = dir.path().join("shards");
    let said = must(cylaov(&[
        "batch",
        data.to_str().unwrap(),
        "--out",
        files.to_str().unwrap(),
    ]));
    // The files format's size line gives the shards' size too: 3 views of 1.31 MB.
    assert!(
        said.contains("as --format webdataset tar shards: about 3.8 MiB"),
        "{said}"
    );
    must(batch_wds(&data, &shards, &["--members", "exr,depth.png"]));
    let tar = std::fs::read(shards.join("shard-000000.tar")).unwrap();
    let m: BTreeMap<String, Vec<u8>> = members(&tar).into_iter().collect();
    for key in ["000000", "000001", "000002"] {
        let exr = AovImage::read_exr(&files.join(format!("{key}.exr"))).unwrap();
        let bits = |c: &str| -> Vec<u32> {
            exr.f32_channel(c)
                .unwrap()
                .iter()
                .map(|v| v.to_bits())
                .collect()
        };
        let (header, depth) = npy_f32(&m[&format!("{key}.depth.npy")]);
        assert!(header.contains("'shape': (240, 320)"), "{header}");
        assert_eq!(depth, bits("depth"));
        let (header, normal) = npy_f32(&m[&format!("{key}.normal.npy")]);
        assert!(header.contains("'shape': (240, 320, 3)"), "{header}");
        let (x, y, z) = (bits("normal.X"), bits("normal.Y"), bits("normal.Z"));
        let planar: Vec<u32> = (0..x.len()).flat_map(|i| [x[i], y[i], z[i]]).collect();
        assert_eq!(normal, planar);
        let hits = depth.iter().filter(|&&d| f32::from_bits(d) > 0.0).count();
        let mask = &m[&format!("{key}.mask.npy")];
        assert_eq!(mask[128..].iter().filter(|&&b| b == 1).count(), hits);
        assert!(hits > 0 && hits < depth.len());
        assert_eq!(
            m[&format!("{key}.exr")],
            std::fs::read(files.join(format!("{key}.exr"))).unwrap()
        );
        assert_eq!(
            m[&format!("{key}.depth.png")],
            std::fs::read(files.join(format!("{key}.depth.png"))).unwrap()
        );
        let meta: serde_json::Value = serde_json::from_slice(&m[&format!("{key}.json")]).unwrap();
        let cam: serde_json::Value = serde_json::from_slice(
            &std::fs::read(files.join(format!("{key}.camera.json"))).unwrap(),
        )
        .unwrap();
        for field in ["K", "K_opencv", "world_to_camera_opencv", "fl_x", "width"] {
            assert_eq!(meta[field], cam[field], "{field}");
        }
        assert_eq!(meta["key"], key);
        assert_eq!(meta["scene_file"], format!("scenes/{key}.json"));
        assert_eq!(meta["miss_values"]["depth"], 0);
    }

    // Depth and normal only: the tar is its raw arrays plus < 2% of headers and JSON.
    let lean = dir.path().join("lean");
    must(batch_wds(&data, &lean, &[]));
    let size = std::fs::metadata(lean.join("shard-000000.tar"))
        .unwrap()
        .len();
    let raw = 3 * 320 * 240 * (4 + 12 + 1);
    assert!(size > raw, "{size}");
    let over = (size - raw) as f64 / raw as f64;
    assert!(
        over < 0.02,
        "{size} bytes for {raw} of arrays: {:.2}% over",
        over * 100.0
    );
}

/// A folder holds one dataset: a rerun with another shard size or AOV set is refused before
/// anything is written, naming each difference; `--force` replaces the dataset (no tar of
/// the old shard size is left beside the new index); two runs with different settings at
/// once never mix their tars; `shards.json` lists the arrays the tars hold (depth and
/// normal always).
#[test]
fn one_folder_holds_one_dataset() {
    let dir = fresh_dir("shards", "one-dataset");
    let data = generate(dir.path(), 10);
    let out = dir.path().join("out");
    must(batch_wds(
        &data,
        &out,
        &["--shard-size", "3", "--aov", "depth"],
    ));
    let before = shard_files(&out);
    assert_eq!(before.keys().filter(|k| k.ends_with(".tar")).count(), 4);
    let index: serde_json::Value = serde_json::from_slice(&before["shards.json"]).unwrap();
    assert_eq!(index["aovs"], serde_json::json!(["depth", "normal"]));
    let tar = members(&before["shard-000000.tar"]);
    assert!(tar.iter().any(|(n, _)| n.ends_with(".normal.npy")));
    // The same settings resume (nothing to do); others are refused, naming each.
    must(batch_wds(
        &data,
        &out,
        &["--shard-size", "3", "--aov", "depth"],
    ));
    let r = batch_wds(
        &data,
        &out,
        &["--shard-size", "4", "--aov", "depth,shape_id"],
    );
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("shard size: 4 now, 3 in the folder")
            && err.contains("tars: 3 now, 4 in the folder")
            && err.contains("aovs: depth,shape_id now, depth in the folder")
            && err.contains("--force to replace it"),
        "{err}"
    );
    assert_eq!(
        shard_files(&out),
        before,
        "a refused run changed the folder"
    );
    // --force: the old dataset goes first; 3 tars of 4 views, nothing of the old one.
    must(batch_wds(&data, &out, &["--shard-size", "4", "--force"]));
    let after = shard_files(&out);
    let tars: Vec<&String> = after.keys().filter(|k| k.ends_with(".tar")).collect();
    assert_eq!(
        tars,
        ["shard-000000.tar", "shard-000001.tar", "shard-000002.tar"]
    );
    assert!(!out.join("shard-000003.json").exists());
    // With the settings the folder records, --force resumes: an array's tasks, each run
    // with --force, never remove each other's tars.
    let again = batch_wds(&data, &out, &["--shard-size", "4", "--force"]);
    let said = String::from_utf8_lossy(&again.stdout).into_owned();
    must(again);
    assert!(said.contains("0 tars written, 3 skipped"), "{said}");
    assert_eq!(shard_files(&out), after);
    // Two runs with different shard sizes at once into a new folder: one is refused or
    // both agree on what is there; never tars of both sizes.
    let both = dir.path().join("both");
    let spawn = |size: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args([
                "batch",
                data.to_str().unwrap(),
                "--out",
                both.to_str().unwrap(),
            ])
            .args(["--format", "webdataset", "--shard-size", size])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn("2"), spawn("5"));
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let won = [&a, &b].iter().filter(|o| o.status.success()).count();
    assert_eq!(
        won, 1,
        "exactly one of two different datasets may be written"
    );
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(both.join("shards.settings.json")).unwrap()).unwrap();
    let size = record["shard_size"].as_u64().unwrap();
    let tars = shard_files(&both)
        .keys()
        .filter(|k| k.ends_with(".tar"))
        .count() as u64;
    assert_eq!(tars, 10u64.div_ceil(size));
}

/// A run whose dataset another replaces (`--force`, other settings) while it writes stops
/// before its next tar lands: the folder ends holding the other dataset alone. The
/// writing run is paused (SIGSTOP) once its first tar is in place, the other runs to the
/// end, and the first goes on.
#[test]
fn a_dataset_replaced_while_written_gets_no_more_tars() {
    let dir = fresh_dir("shards", "replaced-while-written");
    let data = dir.path().join("data");
    ok(&[
        "generate",
        "--count",
        "40",
        "--seed",
        "5",
        "--cylinders",
        "100",
        "--width",
        "320",
        "--height",
        "240",
        "--out",
        data.to_str().unwrap(),
    ]);
    let mut exercised = 0;
    for attempt in 0..5 {
        let out = dir.path().join(format!("out{attempt}"));
        let a = std::process::Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args([
                "batch",
                data.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .args([
                "--format",
                "webdataset",
                "--shard-size",
                "2",
                "--threads",
                "1",
            ])
            .args(["--aov", "depth,normal,position"])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        while !out.join("shard-000000.json").exists()
            && start.elapsed() < std::time::Duration::from_secs(60)
        {
            std::thread::sleep(std::time::Duration::from_micros(200));
        }
        let pid = a.id().to_string();
        let signal = |s: &str| {
            assert!(
                std::process::Command::new("kill")
                    .args([s, &pid])
                    .status()
                    .unwrap()
                    .success()
            );
        };
        signal("-STOP");
        // Too fast to catch: every tar already landed.
        let caught = !out.join("shard-000019.json").exists();
        let b = batch_wds(&data, &out, &["--shard-size", "8", "--force"]);
        signal("-CONT");
        let a = a.wait_with_output().unwrap();
        must(b);
        if !caught {
            continue;
        }
        exercised += 1;
        let err = String::from_utf8_lossy(&a.stderr);
        assert_eq!(a.status.code(), Some(1), "{err}");
        assert!(
            err.contains("another run replaced the dataset")
                && err.contains("shard size: 2 now, 8 in the folder"),
            "{err}"
        );
        // The folder holds the second dataset alone: its 5 tars, all in the index.
        let files = shard_files(&out);
        let tars: Vec<&String> = files.keys().filter(|k| k.ends_with(".tar")).collect();
        assert_eq!(tars.len(), 5, "{tars:?}");
        let index: serde_json::Value = serde_json::from_slice(&files["shards.json"]).unwrap();
        assert_eq!(index["shards"].as_array().unwrap().len(), 5);
        assert_eq!(index["samples"], 40);
        assert_eq!(index["aovs"], serde_json::json!(["depth", "normal"]));
        for t in tars {
            assert!(
                members(&files[t])
                    .iter()
                    .all(|(n, _)| !n.ends_with(".position.npy")),
                "{t} holds the replaced dataset's arrays"
            );
        }
        assert!(!out.join(".partial").exists());
    }
    assert!(
        exercised > 0,
        "the first run finished before it could be paused, 5 times"
    );
}

/// The files format refuses a folder that holds a tar-shard dataset (it would overwrite
/// the dataset's failures file and sit beside an index that does not know it), touching
/// nothing there.
#[test]
fn the_files_format_keeps_out_of_a_tar_shard_folder() {
    let dir = fresh_dir("shards", "files-beside-tars");
    let data = generate(dir.path(), 3);
    let out = dir.path().join("out");
    must(batch_wds(&data, &out, &[]));
    let before = tree(&out);
    let o = cylaov(&[
        "batch",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("holds a tar-shard dataset") && err.contains("another --out"),
        "{err}"
    );
    assert_eq!(tree(&out), before);
}
