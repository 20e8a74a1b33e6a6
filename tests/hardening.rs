//! What cylaov must never destroy and which resources it must bound: output targets that
//! are devices, FIFOs or inputs; closed or full stdout; the exit-status rule; memory and
//! thread limits; clean-up after a failure. Runs the real binary.

use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

const SCENE: &str = r#"{ "camera": { "origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1],
    "fov_deg": 40, "width": 32, "height": 24 },
  "cylinders": [ { "p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5 } ],
  "aovs": ["depth", "normal", "shape_id"] }"#;

/// A fresh folder for one test, removed when the guard drops.
fn dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("cylaov-hard-{name}-"))
        .tempdir()
        .unwrap()
}

fn cylaov(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn mkfifo(p: &Path) {
    let st = Command::new("mkfifo").arg(p).status().unwrap();
    assert!(st.success(), "mkfifo {}", p.display());
}

fn is_fifo(p: &Path) -> bool {
    std::fs::symlink_metadata(p)
        .map(|m| m.file_type().is_fifo())
        .unwrap_or(false)
}

/// A scene and its render, for the commands that read images.
fn scene_and_render(d: &Path) -> (PathBuf, PathBuf) {
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let exr = d.join("s.exr");
    let o = cylaov(&["render", s(&scene), "-o", s(&exr)]);
    assert!(o.status.success(), "{}", stderr(&o));
    (scene, exr)
}

/// Every command that writes refuses a FIFO, a symlink to a FIFO and a symlink to a
/// character device as its target, exits 1, and leaves the target as it was.
#[test]
fn outputs_that_are_not_regular_files_are_refused() {
    let tmp = dir("targets");
    let d = tmp.path();
    let (scene, exr) = scene_and_render(d);
    let fifo = d.join("fifo");
    mkfifo(&fifo);
    let to_fifo = d.join("to-fifo");
    std::os::unix::fs::symlink(&fifo, &to_fifo).unwrap();
    let to_null = d.join("to-null");
    std::os::unix::fs::symlink("/dev/null", &to_null).unwrap();
    // --preview DIR: the preview's own name is taken by a FIFO.
    let pv = d.join("pv");
    std::fs::create_dir_all(&pv).unwrap();
    mkfifo(&pv.join("s.depth.preview.png"));
    let mut failures = Vec::new();
    for target in [&fifo, &to_fifo, &to_null] {
        let t = s(target);
        let cases: Vec<(&str, Vec<&str>)> = vec![
            ("render -o", vec!["render", s(&scene), "-o", t]),
            (
                "export-mitsuba -o",
                vec!["export-mitsuba", s(&scene), "-o", t],
            ),
            (
                "compare --heatmap",
                vec!["compare", s(&exr), s(&exr), "--heatmap", t],
            ),
            (
                "stress --csv",
                vec!["stress", "--family", "far", "--rays", "1", "--csv", t],
            ),
            (
                "stress --plot",
                vec!["stress", "--family", "far", "--rays", "1", "--plot", t],
            ),
            (
                "bench --csv",
                vec!["bench", "--counts", "1", "--quick", "--csv", t],
            ),
            (
                "bench --plot",
                vec!["bench", "--counts", "1", "--quick", "--plot", t],
            ),
        ];
        for (what, args) in cases {
            let o = cylaov(&args);
            let err = stderr(&o);
            let code = o.status.code();
            let want = if what.starts_with("compare") { 2 } else { 1 };
            if code != Some(want) || !err.contains("not a regular file") {
                failures.push(format!("{what} {t}: exit {code:?}, stderr {err:?}"));
            }
        }
    }
    let o = cylaov(&[
        "render",
        s(&scene),
        "-o",
        s(&d.join("o/s.exr")),
        "--preview",
        s(&pv),
    ]);
    if o.status.code() != Some(1) || !stderr(&o).contains("s.depth.preview.png") {
        failures.push(format!("render --preview: {:?} {}", o.status, stderr(&o)));
    }
    // bench --keep-scenes DIR: a kept scene's own name is taken by a FIFO.
    mkfifo(&pv.join("dense-1.json"));
    let o = cylaov(&[
        "bench",
        "--counts",
        "1",
        "--quick",
        "--family",
        "dense",
        "--keep-scenes",
        s(&pv),
    ]);
    if o.status.code() != Some(1) || !stderr(&o).contains("dense-1.json") {
        failures.push(format!(
            "bench --keep-scenes: {:?} {}",
            o.status,
            stderr(&o)
        ));
    }
    assert!(is_fifo(&pv.join("dense-1.json")), "a FIFO was replaced");
    // Output folders (batch --out, verify --heatmap, bench --keep-scenes): a FIFO or a link
    // to a device is not one.
    for target in [&fifo, &to_null] {
        for (args, want) in [
            (vec!["batch", s(&scene), "--out", s(target)], 1),
            (vec!["verify", s(&scene), "--heatmap", s(target)], 2),
            (
                vec![
                    "bench",
                    "--counts",
                    "1",
                    "--quick",
                    "--keep-scenes",
                    s(target),
                ],
                1,
            ),
        ] {
            let o = cylaov(&args);
            if o.status.code() != Some(want) || !stderr(&o).contains("not a folder") {
                failures.push(format!("{args:?}: {:?} {}", o.status, stderr(&o)));
            }
        }
    }
    assert!(
        is_fifo(&fifo) && is_fifo(&pv.join("s.depth.preview.png")),
        "a FIFO was replaced"
    );
    assert!(
        std::fs::symlink_metadata(&to_fifo)
            .unwrap()
            .file_type()
            .is_symlink()
            && std::fs::symlink_metadata(&to_null)
                .unwrap()
                .file_type()
                .is_symlink(),
        "a link was replaced"
    );
    assert!(
        std::fs::metadata("/dev/null")
            .unwrap()
            .file_type()
            .is_char_device(),
        "/dev/null is no longer a character device"
    );
    assert!(!d.join("o").exists());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// No output may be an input, however it is reached: itself, a hard link, a symlink.
#[test]
fn outputs_may_not_be_inputs_through_links() {
    let tmp = dir("inputs");
    let d = tmp.path();
    let (scene, exr) = scene_and_render(d);
    let exr_bytes = std::fs::read(&exr).unwrap();
    let hard = d.join("hard.exr");
    std::fs::hard_link(&exr, &hard).unwrap();
    let soft = d.join("soft.xml");
    std::os::unix::fs::symlink(&scene, &soft).unwrap();
    // A scene that sits in the preview folder under the name of a preview.
    let pv = d.join("pv");
    std::fs::create_dir_all(&pv).unwrap();
    let pv_scene = pv.join("o.normal.preview.png");
    std::fs::write(&pv_scene, SCENE).unwrap();
    let o_exr = d.join("o.exr");
    let cases: Vec<(&str, Vec<&str>, i32)> = vec![
        (
            "heatmap = A",
            vec!["compare", s(&exr), s(&hard), "--heatmap", s(&exr)],
            2,
        ),
        (
            "heatmap = B via hard link",
            vec!["compare", s(&exr), s(&exr), "--heatmap", s(&hard)],
            2,
        ),
        (
            "export over scene via symlink",
            vec!["export-mitsuba", s(&scene), "-o", s(&soft)],
            1,
        ),
        (
            "preview over scene",
            vec!["render", s(&pv_scene), "-o", s(&o_exr), "--preview", s(&pv)],
            1,
        ),
    ];
    let mut failures = Vec::new();
    for (what, args, want) in cases {
        let o = cylaov(&args);
        if o.status.code() != Some(want) || !stderr(&o).contains("would overwrite the input") {
            failures.push(format!(
                "{what}: exit {:?}, {}",
                o.status.code(),
                stderr(&o)
            ));
        }
    }
    assert_eq!(std::fs::read(&exr).unwrap(), exr_bytes, "input EXR changed");
    assert_eq!(std::fs::read_to_string(&scene).unwrap(), SCENE);
    assert_eq!(std::fs::read_to_string(&pv_scene).unwrap(), SCENE);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The table a scene's `"cylinders": {"file": ...}` names is an input as much as the
/// scene: no output of `render`, `cameras`, `export-mitsuba` or `scan` may overwrite it,
/// whatever its name.
#[test]
fn a_scenes_table_is_never_overwritten() {
    let tmp = dir("table-input");
    let d = tmp.path();
    let table = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/tables/tree_cyl_data.txt"),
    )
    .unwrap();
    let camera = r#"{"origin":[0.3,-11,5],"target":[0.3,0,2.8],"up":[0,0,1],"fov_deg":50,"width":32,"height":24}"#;
    let mut failures = Vec::new();
    for (name, args) in [
        (
            "t.csv",
            vec!["cameras", "SCENE", "-o", "t.csv", "--orbit", "3"],
        ),
        ("t.csv", vec!["export-mitsuba", "SCENE", "-o", "t.csv"]),
        (
            "t.ply",
            vec!["render", "SCENE", "-o", "o.exr", "--ply", "t.ply"],
        ),
        ("o.camera.json", vec!["render", "SCENE", "-o", "o.exr"]),
        // Not written but removed as an earlier render's depth PNG.
        ("o.depth.png", vec!["render", "SCENE", "-o", "o.exr"]),
        (
            "t.ply",
            vec![
                "scan", "SCENE", "-o", "t.ply", "--sensor", "vlp16", "--pose", "0,-11,3",
            ],
        ),
    ] {
        let path = d.join(name);
        std::fs::write(&path, &table).unwrap();
        let scene = d.join("scene.json");
        std::fs::write(
            &scene,
            format!(r#"{{"camera":{camera},"cylinders":{{"file":"{name}","format":"treeqsm"}}}}"#),
        )
        .unwrap();
        let args: Vec<String> = args
            .iter()
            .map(|a| match *a {
                "SCENE" => scene.display().to_string(),
                a if a.contains('.') => d.join(a).display().to_string(),
                a => a.to_string(),
            })
            .collect();
        let o = cylaov(&args.iter().map(String::as_str).collect::<Vec<_>>());
        let kept = std::fs::read(&path).unwrap() == table;
        if o.status.code() != Some(1) || !stderr(&o).contains("would overwrite the input") || !kept
        {
            failures.push(format!(
                "{args:?}: exit {:?}, table kept: {kept}, {}",
                o.status.code(),
                stderr(&o)
            ));
        }
        std::fs::remove_file(&path).unwrap();
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A render to `-o OUT` replaces the files an earlier render to `OUT` left beside it and
/// this one does not write (an Open3D camera after an orthographic view, a depth PNG,
/// the other EXR layout's files), which would describe another view.
#[test]
fn a_render_removes_the_files_of_an_earlier_one_it_does_not_write() {
    let tmp = dir("render-stale");
    let d = tmp.path();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let out = d.join("v.exr");
    let o = cylaov(&[
        "render",
        s(&scenes.join("single.json")),
        "-o",
        s(&out),
        "--depth-png",
        "--exr-layout",
        "per-aov",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = [
        "v.depth.exr",
        "v.normal.exr",
        "v.depth.png",
        "v.open3d.json",
    ];
    for n in before {
        assert!(d.join(n).exists(), "{n}");
    }
    let o = cylaov(&[
        "render",
        s(&scenes.join("orthographic.json")),
        "-o",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut left: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["v.camera.json", "v.exr"]);
}

/// Run with stdout a pipe whose reader has already gone.
fn closed_stdout(args: &[&str]) -> Output {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

fn full_stdout(args: &[&str]) -> Output {
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .stdout(full)
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

/// A closed pipe ends quietly with the command's own status; a full stdout is an error
/// with a message; neither panics (exit 101).
#[test]
fn stdout_failures_never_panic_and_keep_the_exit_status() {
    let tmp = dir("stdout");
    let d = tmp.path();
    let (scene, exr) = scene_and_render(d);
    let other = d.join("other.exr");
    let moved = d.join("moved.json");
    std::fs::write(&moved, SCENE.replace("[3, -5, 2.5]", "[3.01, -5, 2.5]")).unwrap();
    let o = cylaov(&["render", s(&moved), "-o", s(&other)]);
    assert!(o.status.success());
    let out = d.join("o.exr");
    let tight = [
        "--rel-distance",
        "0",
        "--normal-deg",
        "0",
        "--rel-depth",
        "0",
    ];
    let mut differ = vec!["compare", s(&exr), s(&other), "--json"];
    differ.extend(tight);
    let xml = d.join("x.xml");
    let cases: Vec<(&str, Vec<&str>, i32, i32)> = vec![
        // (what, args, exit with a closed pipe, exit with /dev/full)
        ("render", vec!["render", s(&scene), "-o", s(&out)], 0, 1),
        (
            "compare equal",
            vec!["compare", s(&exr), s(&exr), "--json"],
            0,
            2,
        ),
        ("compare different", differ, 1, 2),
        (
            "compare missing",
            vec!["compare", s(&exr), "/nonexistent.exr"],
            2,
            2,
        ),
        (
            "export",
            vec!["export-mitsuba", s(&scene), "-o", s(&xml)],
            0,
            1,
        ),
        ("help", vec!["--help"], 0, 0),
    ];
    let mut failures = Vec::new();
    for (what, args, closed, full) in cases {
        let o = closed_stdout(&args);
        let err = stderr(&o);
        if o.status.code() != Some(closed)
            || err.contains("panicked")
            || err.contains("Broken pipe")
        {
            failures.push(format!(
                "{what} | closed: exit {:?}, {err}",
                o.status.code()
            ));
        }
        let o = full_stdout(&args);
        let err = stderr(&o);
        // --help goes through clap, which ignores a failed print.
        let said = full == 0 || err.contains("No space left") || what == "compare missing";
        if o.status.code() != Some(full) || err.contains("panicked") || !said {
            failures.push(format!(
                "{what} > /dev/full: exit {:?}, {err}",
                o.status.code()
            ));
        }
    }
    // A full stderr: the error cannot be shown, but the status is still the command's.
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(["render", "/nonexistent.json", "-o", s(&out)])
        .stderr(full)
        .output()
        .unwrap();
    if o.status.code() != Some(1) {
        failures.push(format!("render 2> /dev/full: exit {:?}", o.status.code()));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// One rule for every command: 0 done, 1 input rejected or a check failed, 2 usage error or
/// a check that could not be made. The README and `--help` state it.
#[test]
fn exit_status_rule_holds_for_every_command() {
    let tmp = dir("exit");
    let d = tmp.path();
    let (scene, exr) = scene_and_render(d);
    let bad = d.join("bad.json");
    std::fs::write(&bad, SCENE.replace("\"radius\": 0.5", "\"radius\": -1")).unwrap();
    let o = |n: &str| d.join(n).to_str().unwrap().to_string();
    let (o1, o2, o3) = (o("a.exr"), o("b.xml"), o("g"));
    let cases: Vec<(Vec<&str>, i32)> = vec![
        (vec!["render", s(&scene), "-o", &o1], 0),
        (vec!["render", s(&bad), "-o", &o1], 1),
        (vec!["render", "/nonexistent.json", "-o", &o1], 1),
        (vec!["render", s(&scene)], 2),
        (vec!["render", s(&scene), "-o", &o1, "--threads", "0"], 2),
        (vec!["render", s(&scene), "-o", &o1, "--threads", "1025"], 2),
        (vec!["render", s(&scene), "-o", &o1, "--aov", "albedo"], 2),
        (vec!["export-mitsuba", s(&scene), "-o", &o2], 0),
        (vec!["export-mitsuba", s(&bad), "-o", &o2], 1),
        (vec!["compare", s(&exr), s(&exr)], 0),
        (vec!["compare", s(&exr), "/nonexistent.exr"], 2),
        (vec!["compare", s(&exr), s(&exr), "--rel-depth", "-1"], 2),
        (vec!["generate", "--count", "0", "--out", &o3], 2),
        (vec!["generate", "--count", "2", "--out", &o3], 0),
        (vec!["stress", "--family", "nope"], 2),
        (vec!["stress", "--rays", "0"], 2),
        (vec!["bench", "--threads", "100000"], 2),
        (vec!["no-such-command"], 2),
        (vec!["--version"], 0),
    ];
    let mut failures = Vec::new();
    for (args, want) in cases {
        let r = cylaov(&args);
        let err = stderr(&r);
        if r.status.code() != Some(want) || err.contains("panicked") {
            failures.push(format!(
                "{args:?}: exit {:?} (want {want}): {err}",
                r.status.code()
            ));
        }
    }
    let help = String::from_utf8_lossy(&cylaov(&["--help"]).stdout).into_owned();
    assert!(
        help.contains("Exit status") && help.contains("2 = usage error"),
        "{help}"
    );
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).unwrap();
    assert!(
        readme.contains("## Exit status"),
        "README lacks the exit-status section"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// `-1` as a value reaches the option's own check; too many threads are refused at once.
#[test]
fn negative_values_and_thread_counts_get_clear_messages() {
    let tmp = dir("threads");
    let d = tmp.path();
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let out = d.join("o.exr");
    for n in ["-1", "50000", "100000"] {
        let o = cylaov(&["render", s(&scene), "-o", s(&out), "--threads", n]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "--threads {n}: {err}");
        assert!(
            err.contains("from 1 to 1024") && err.contains(n),
            "--threads {n}: {err}"
        );
        assert!(!err.contains("unexpected argument"), "{err}");
    }
    let o = cylaov(&[
        "generate",
        "--count",
        "1",
        "--width",
        "-5",
        "--out",
        s(&d.join("g")),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--width") && !stderr(&o).contains("unexpected argument"));
    // The cap itself works (1024 threads on a 32 x 24 image).
    let o = cylaov(&["render", s(&scene), "-o", s(&out), "--threads", "1024"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Run `cylaov args` with the address space limited to `kib` (ulimit -v).
fn with_ulimit(kib: u64, args: &[&str]) -> Output {
    let mut cmd = format!("ulimit -v {kib} && exec '{}'", env!("CARGO_BIN_EXE_cylaov"));
    for a in args {
        cmd += &format!(" '{a}'");
    }
    Command::new("sh").args(["-c", &cmd]).output().unwrap()
}

/// A render that holds the whole image and cannot fit fails before allocating, with a
/// message, not an abort (per-AOV EXRs need the whole image: 11 planes of 16384 x 4096).
#[test]
fn memory_is_checked_before_a_render_and_a_comparison() {
    let tmp = dir("memory");
    let d = tmp.path();
    let scene = d.join("big.json");
    std::fs::write(
        &scene,
        SCENE.replace(
            "\"width\": 32, \"height\": 24",
            "\"width\": 16384, \"height\": 4096",
        ),
    )
    .unwrap();
    let out = d.join("big.exr");
    let all = "distance,depth,normal,position,shape_id";
    let o = with_ulimit(
        1_500_000,
        &[
            "render",
            s(&scene),
            "-o",
            s(&out),
            "--aov",
            all,
            "--exr-layout",
            "per-aov",
        ],
    );
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("needs about 3074 MiB") && err.contains("available"),
        "{err}"
    );
    assert!(!out.exists());
    // An EXR whose header claims 16384 x 65533 pixels: refused from the header alone.
    let fake = d.join("fake.exr");
    std::fs::write(&fake, exr_header(16384, 65533)).unwrap();
    let o = with_ulimit(4_000_000, &["compare", s(&fake), s(&fake)]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("needs about") && err.contains("comparing"),
        "{err}"
    );
}

/// The header of an uncompressed one-channel float EXR of `w x h`, without its pixels.
fn exr_header(w: i32, h: i32) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&20000630i32.to_le_bytes());
    v.extend_from_slice(&2i32.to_le_bytes());
    let mut attr = |name: &str, ty: &str, value: &[u8]| {
        for s in [name, ty] {
            v.extend_from_slice(s.as_bytes());
            v.push(0);
        }
        v.extend_from_slice(&(value.len() as i32).to_le_bytes());
        v.extend_from_slice(value);
    };
    let mut ch = b"depth\0".to_vec();
    for x in [2i32, 0, 1, 1] {
        ch.extend_from_slice(&x.to_le_bytes());
    }
    ch.push(0);
    let window: Vec<u8> = [0, 0, w - 1, h - 1]
        .iter()
        .flat_map(|x: &i32| x.to_le_bytes())
        .collect();
    attr("channels", "chlist", &ch);
    attr("compression", "compression", &[0]);
    attr("dataWindow", "box2i", &window);
    attr("displayWindow", "box2i", &window);
    attr("lineOrder", "lineOrder", &[0]);
    attr("pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr("screenWindowCenter", "v2f", &[0; 8]);
    attr("screenWindowWidth", "float", &1f32.to_le_bytes());
    v.push(0);
    v
}

/// A failed command removes the folders it made; a full disk says so (injected).
#[test]
fn failures_clean_up_and_a_full_disk_says_so() {
    let tmp = dir("cleanup");
    let d = tmp.path();
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let run_full = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args(args)
            .env("CYLAOV_FAIL_WRITES", "ENOSPC")
            .output()
            .unwrap()
    };
    let new = d.join("new");
    let cases: Vec<Vec<String>> = vec![
        vec![
            "render".into(),
            s(&scene).into(),
            "-o".into(),
            s(&new.join("sub/x.exr")).into(),
        ],
        vec![
            "render".into(),
            s(&scene).into(),
            "-o".into(),
            s(&d.join("y.exr")).into(),
            "--preview".into(),
            s(&new.join("pv")).into(),
        ],
        vec![
            "export-mitsuba".into(),
            s(&scene).into(),
            "-o".into(),
            s(&new.join("a/b.xml")).into(),
        ],
        vec![
            "generate".into(),
            "--count".into(),
            "3".into(),
            "--out".into(),
            s(&new.join("set")).into(),
        ],
    ];
    for args in cases {
        let args: Vec<&str> = args.iter().map(|a| a.as_str()).collect();
        let o = run_full(&args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("disk is full"), "{args:?}: {err}");
        assert!(!new.exists(), "{args:?} left {}", new.display());
        let left: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n != "s.json")
            .collect();
        assert!(left.is_empty(), "{args:?} left {left:?}");
    }
    // An existing folder stays, and so do files that were there before.
    let keep = d.join("keep");
    std::fs::create_dir_all(&keep).unwrap();
    std::fs::write(keep.join("mine.txt"), "x").unwrap();
    let o = run_full(&["render", s(&scene), "-o", s(&keep.join("x.exr"))]);
    assert_eq!(o.status.code(), Some(1));
    assert!(keep.join("mine.txt").exists());
}

/// A file where a folder should be is named; a long valid output name is accepted (its
/// temporary name is shortened to fit the 255-byte limit).
#[test]
fn parent_path_and_long_names() {
    let tmp = dir("names");
    let d = tmp.path();
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let o = cylaov(&["render", s(&scene), "-o", s(&d.join("s.json/sub/x.exr"))]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        err.contains("s.json is a regular file, not a folder"),
        "{err}"
    );
    // 240 + ".camera.json" = 252 bytes: valid; the temporary name would be ~300.
    let long = d.join(format!("{}.exr", "n".repeat(240)));
    let o = cylaov(&["render", s(&scene), "-o", s(&long)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(long.exists() && long.with_extension("camera.json").exists());
    let tmp: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(tmp.is_empty(), "{tmp:?}");
    // Too long for the file system itself: refused by name, before any work.
    let too_long = d.join(format!("{}.exr", "n".repeat(252)));
    let o = cylaov(&["render", s(&scene), "-o", s(&too_long)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("the limit is 255"), "{}", stderr(&o));
}

/// Pictures read without the README: the depth preview carries a titled, ticked legend, the
/// normal preview a key, and every failing pixel of a heatmap is ringed in white.
#[test]
fn previews_and_heatmaps_carry_their_legends() {
    let tmp = dir("pictures");
    let d = tmp.path();
    let (scene, exr) = scene_and_render(d);
    let pv = d.join("pv");
    let o = cylaov(&[
        "render",
        s(&scene),
        "-o",
        s(&d.join("v.exr")),
        "--preview",
        s(&pv),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // Below the 24 image rows: legend rows with white text (ticks, labels, title).
    for name in ["v.depth.preview.png", "v.normal.preview.png"] {
        let img = image::open(pv.join(name)).unwrap().to_rgb8();
        assert!(img.height() >= 24 + 15, "{name}: {} rows", img.height());
        let white = img
            .enumerate_pixels()
            .filter(|(_, y, p)| *y >= 24 && p.0 == [255, 255, 255])
            .count();
        assert!(white > 40, "{name}: {white} white legend pixels");
    }
    // One camera nudged: a few pixels break a tight tolerance; each gets a white ring.
    let moved = d.join("moved.json");
    std::fs::write(&moved, SCENE.replace("[3, -5, 2.5]", "[3, -5, 2.5001]")).unwrap();
    let other = d.join("moved.exr");
    assert!(
        cylaov(&["render", s(&moved), "-o", s(&other)])
            .status
            .success()
    );
    let heat = d.join("heat.png");
    let o = cylaov(&[
        "compare",
        s(&exr),
        s(&other),
        "--heatmap",
        s(&heat),
        "--rel-depth",
        "1e-9",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let img = image::open(&heat).unwrap().to_rgb8();
    assert!(
        img.height() > 24 + 20,
        "no legend strip: {} rows",
        img.height()
    );
    let failing: Vec<(u32, u32)> = img
        .enumerate_pixels()
        .filter(|(_, y, p)| *y < 24 && p.0 == [255, 0, 255])
        .map(|(x, y, _)| (x, y))
        .collect();
    assert!(!failing.is_empty(), "no failing pixel to ring");
    let ringed = |&(x, y): &(u32, u32)| {
        (0..img.width()).any(|i| {
            (0..24).any(|j| {
                img.get_pixel(i, j).0 == [255, 255, 255] && i.abs_diff(x) <= 8 && j.abs_diff(y) <= 8
            })
        })
    };
    let bare: Vec<_> = failing.iter().filter(|p| !ringed(p)).collect();
    assert!(
        bare.len() < failing.len(),
        "no failing pixel is ringed: {bare:?}"
    );
}

/// An AOV named twice in `--aov` is stored once, as a scene's `"aovs"` are: `render` and
/// `batch` write the bytes of the list without the repeat (a repeated channel attribute
/// made a header OpenEXR refuses; a repeated per-AOV file collided with itself).
#[test]
fn an_aov_named_twice_is_stored_once() {
    let tmp = dir("aov-twice");
    let d = tmp.path();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/single.json");
    let mut failures = Vec::new();
    for (twice, once, layout) in [
        ("normal,normal", "normal", "layers"),
        ("depth,shape_id,depth", "depth,shape_id", "layers"),
        ("depth,depth", "depth", "per-aov"),
    ] {
        let mut bytes = Vec::new();
        for (tag, list) in [("twice", twice), ("once", once)] {
            let out = d.join(format!("{tag}-{layout}.exr"));
            let o = cylaov(&[
                "render",
                s(&scene),
                "-o",
                s(&out),
                "--aov",
                list,
                "--exr-layout",
                layout,
            ]);
            assert!(o.status.success(), "{list} {layout}: {}", stderr(&o));
            let file = match layout {
                "layers" => out,
                _ => d.join(format!("{tag}-{layout}.depth.exr")),
            };
            bytes.push(std::fs::read(file).unwrap());
        }
        if bytes[0] != bytes[1] {
            failures.push(format!("render --aov {twice} --exr-layout {layout}"));
        }
    }
    let input = d.join("in");
    std::fs::create_dir(&input).unwrap();
    std::fs::copy(&scene, input.join("a.json")).unwrap();
    let mut bytes = Vec::new();
    for (tag, list) in [("twice", "shape_id,shape_id"), ("once", "shape_id")] {
        let out = d.join(format!("batch-{tag}"));
        let o = cylaov(&["batch", s(&input), "--out", s(&out), "--aov", list]);
        assert!(o.status.success(), "{list}: {}", stderr(&o));
        bytes.push(std::fs::read(out.join("a.exr")).unwrap());
    }
    if bytes[0] != bytes[1] {
        failures.push("batch --aov shape_id,shape_id".into());
    }
    assert!(
        failures.is_empty(),
        "not the bytes without the repeat: {failures:?}"
    );
}

/// A camera rig whose cameras would stand past a camera origin's bound (a field of view of
/// 1e-20 degrees) or on the cylinders' centre (a distance factor of 1e-300) is refused
/// naming the rig's field (the flag on the command line), not the origin it would make.
#[test]
fn rig_distances_out_of_range_name_the_rig() {
    let tmp = dir("rig-reach");
    let d = tmp.path();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cluster.json");
    let out = d.join("c.json");
    let mut failures = Vec::new();
    for (flags, want) in [
        (
            ["--fov", "1e-20"],
            "error: --fov: 1e-20 puts the cameras 6.2",
        ),
        (
            ["--distance", "1e-300"],
            "error: --distance: a factor of 1e-300 puts the cameras",
        ),
    ] {
        let mut args = vec!["cameras", s(&scene), "-o", s(&out), "--orbit", "3"];
        args.extend(flags);
        let o = cylaov(&args);
        if o.status.code() != Some(2) || !stderr(&o).starts_with(want) {
            failures.push(format!("{flags:?}: {:?} {}", o.status.code(), stderr(&o)));
        }
    }
    let rig = d.join("rig.json");
    std::fs::write(
        &rig,
        r#"{"cameras": {"orbit": {"count": 2, "fov_deg": 1e-30}},
            "cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.5}]}"#,
    )
    .unwrap();
    let o = cylaov(&["render", s(&rig), "-o", s(&d.join("r.exr"))]);
    if o.status.code() != Some(1) || !stderr(&o).contains("cameras.orbit.fov_deg: 1e-30 puts") {
        failures.push(format!("scene rig: {:?} {}", o.status.code(), stderr(&o)));
    }
    assert!(!out.exists());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
