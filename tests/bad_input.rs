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

/// The table of bad scenes the Python tests read too: every case of the scene format's
/// rules (unknown fields, non-finite, huge or non-positive values, degenerate cylinders and
/// cameras, unknown AOVs) and documents that are not one scene object (two scenes, text
/// after the end, positional arrays, a byte order mark, not UTF-8).
fn bad_input_cases() -> Vec<(String, Vec<u8>, Vec<String>)> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bad_input.json");
    let table: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let hex = |h: &str| -> Vec<u8> {
        (0..h.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&h[i..i + 2], 16).unwrap())
            .collect()
    };
    table["cases"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let bytes = match (c["text"].as_str(), c["bytes_hex"].as_str()) {
                (Some(t), None) => t.as_bytes().to_vec(),
                (None, Some(h)) => hex(h),
                _ => panic!("{c}: one of text and bytes_hex"),
            };
            let needles = c["needles"]
                .as_array()
                .unwrap()
                .iter()
                .map(|n| n.as_str().unwrap().to_string())
                .collect();
            (c["name"].as_str().unwrap().to_string(), bytes, needles)
        })
        .collect()
}

#[test]
fn every_case_of_the_table_is_rejected_clearly() {
    let cases = bad_input_cases();
    assert!(cases.len() >= 37, "{} cases", cases.len());
    let mut t = Table::default();
    for (name, bytes, needles) in &cases {
        let needles: Vec<&str> = needles.iter().map(String::as_str).collect();
        t.rejects_bytes(name, bytes, &needles);
    }
    t.done();
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
        // The file's path is the user's; the rest of the message is ours to keep short
        // (the camera's list of valid fields, every model's parameters, is ~230 bytes).
        let ours = err.replace(input.to_str().unwrap(), "").len();
        if ours > 400 || err.contains(&"9".repeat(41)) {
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

/// The exit statuses `cylaov --help` lists: a flag's value out of its range, or flags that
/// do not go together, is a usage error (2) whether clap or the command finds it; a bad
/// value in a file is an input refused (1), naming the file and its key. Each case says
/// one line naming the flag, and writes nothing.
#[test]
fn bad_flag_values_exit_2_and_bad_file_values_exit_1() {
    let tmp = common::fresh_dir("bad", "flags");
    let d = tmp.path();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/asymmetric.json");
    let scene = scene.to_str().unwrap();
    let generated = common::fresh_dir("bad", "flags-gen");
    let generated = generated.path().join("g");
    let gen_dir = generated.to_str().unwrap().to_string();
    common::ok(&[
        "generate", "--count", "1", "--out", &gen_dir, "--width", "8", "--height", "6",
    ]);
    let config = d.join("cfg.json");
    std::fs::write(&config, r#"{"radius": "-1..2"}"#).unwrap();
    let table = d.join("t.csv");
    std::fs::write(&table, "x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,0.1\n").unwrap();
    let out = d.join("out");
    let (o, cfg, tab) = (
        out.to_str().unwrap(),
        config.to_str().unwrap(),
        table.to_str().unwrap(),
    );
    let exr = d.join("out.exr");
    let exr = exr.to_str().unwrap();
    let las = d.join("out.las");
    let las = las.to_str().unwrap();
    let cases: &[(&[&str], i32, &str)] = &[
        (
            &[
                "render",
                scene,
                "-o",
                exr,
                "--depth-png",
                "--depth-scale",
                "0",
            ],
            2,
            "--depth-scale: must be finite and > 0, got 0",
        ),
        (
            &["generate", "--out", o, "--count", "1", "--volume", "1e300"],
            2,
            "--volume: half extents must be in [0, 1e12], got [1e300, 1e300, 1e300]",
        ),
        (
            &["generate", "--out", o, "--count", "1", "--radius", "-1..2"],
            2,
            "--radius: must be > 0",
        ),
        (&["generate", "--out", o], 2, "--count: required"),
        (
            &["generate", "--out", o, "--count", "1", "--config", cfg],
            1,
            "cfg.json: radius: must be > 0",
        ),
        (
            &["cameras", scene, "-o", exr, "--orbit", "0"],
            2,
            "--orbit: must be in 1..=",
        ),
        (
            &[
                "cameras",
                scene,
                "-o",
                exr,
                "--orbit",
                "3",
                "--elevation",
                "0..90",
            ],
            2,
            "--elevation: must lie in -85..85",
        ),
        (
            &[
                "cameras", scene, "-o", exr, "--orbit", "3", "--fov", "1e-20",
            ],
            2,
            "--fov: 1e-20 puts the cameras",
        ),
        (
            &["batch", &gen_dir, "--out", o, "--verify-fraction", "-0.1"],
            2,
            "--verify-fraction: must be in [0, 1], got -0.1",
        ),
        (
            &["batch", &gen_dir, "--out", o, "--shard-size", "3"],
            2,
            "--shard-size: only with --format webdataset",
        ),
        (
            &[
                "scan",
                scene,
                "--sensor",
                "vlp16",
                "-o",
                las,
                "--dropout",
                "2",
            ],
            2,
            "--dropout: must be in [0, 1], got 2",
        ),
        (
            &["import", tab, "-o", o, "--fov", "0"],
            2,
            "--fov: must be in (0, 180), got 0",
        ),
        (
            &["verify", &gen_dir, "--fraction", "2"],
            2,
            "--fraction: must be in [0, 1], got 2",
        ),
    ];
    let mut failures = Vec::new();
    for (args, code, want) in cases {
        let run = common::cylaov(args);
        let err = String::from_utf8_lossy(&run.stderr);
        if run.status.code() != Some(*code)
            || !err.starts_with("error: ")
            || !err.contains(want)
            || err.trim_end().lines().count() != 1
        {
            failures.push(format!(
                "{args:?}: exit {:?}, want {code}: {err}",
                run.status.code()
            ));
        }
        if [o, exr, las].iter().any(|p| Path::new(p).exists()) {
            failures.push(format!("{args:?}: wrote an output"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Files whose mistakes were read past or misnamed: each refused in one line naming the
/// file and the key, or read as meant.
#[test]
fn file_mistakes_name_the_file_and_key() {
    let tmp = common::fresh_dir("bad", "file-mistakes");
    let d = tmp.path();
    let p = |name: &str, text: &str| {
        let path = d.join(name);
        std::fs::write(&path, text).unwrap();
        path.to_str().unwrap().to_string()
    };
    let out = d.join("out");
    let o = out.to_str().unwrap();
    let csv = p("t.csv", "x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,0.1\n");
    let cam = r#""camera":{"origin":[0,-4,1],"target":[0,0,0.5],"up":[0,0,1],"fov_deg":50,"width":16,"height":12}"#;
    let exr = d.join("r.exr");
    let r = exr.to_str().unwrap();
    let npy = d.join("a.npy");
    std::fs::write(&npy, b"\x93NUMPY\x01\x00").unwrap();
    let npy = npy.to_str().unwrap().to_string();
    let cases: Vec<(Vec<String>, &str)> = vec![
        // A second object after the settings was ignored: count 2, seed 0.
        (
            vec![
                "generate".into(),
                "--out".into(),
                o.into(),
                "--config".into(),
                p("two.json", r#"{"count": 2} {"count": 5, "seed": 3}"#),
            ],
            "two.json: text after the end of the settings' JSON object at line 1 column 14",
        ),
        // `0.1...2` read as 0.1..0.2.
        (
            vec![
                "generate".into(),
                "--out".into(),
                o.into(),
                "--count".into(),
                "1".into(),
                "--radius".into(),
                "0.1...2".into(),
            ],
            "expected MIN..MAX with two dots, got \"0.1...2\"",
        ),
        (
            vec![
                "generate".into(),
                "--out".into(),
                o.into(),
                "--config".into(),
                p("pair.json", r#"{"count": 1, "radius": [1]}"#),
            ],
            "pair.json: radius: expected \"MIN..MAX\", a number or [MIN, MAX], got [1]",
        ),
        // A table reference without its file said a list of cylinders was expected.
        (
            vec![
                "render".into(),
                p(
                    "nofile.json",
                    &format!(r#"{{{cam}, "cylinders": {{"format": "csv"}}}}"#),
                ),
                "-o".into(),
                r.into(),
            ],
            "nofile.json: cylinders: missing field `file`",
        ),
        // A scene's label named the command line's flag.
        (
            vec![
                "render".into(),
                p(
                    "label.json",
                    &format!(
                        r#"{{{cam}, "cylinders": {{"file": "t.csv", "label": "branch_order"}}}}"#
                    ),
                ),
                "-o".into(),
                r.into(),
            ],
            "label.json: cylinders.label: ",
        ),
        // One .npy array said "not UTF-8 text".
        (
            vec!["import".into(), npy, "-o".into(), o.into()],
            "one NumPy array (.npy); a table of arrays is an .npz archive",
        ),
    ];
    let mut failures = Vec::new();
    for (args, want) in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let run = common::cylaov(&args);
        let err = String::from_utf8_lossy(&run.stderr);
        if run.status.code() == Some(0) || !err.contains(want) || err.contains("--label") {
            failures.push(format!("{args:?}: exit {:?}: {err}", run.status.code()));
        }
        if out.exists() || exr.exists() {
            failures.push(format!("{args:?}: wrote an output"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    let _ = csv;
}

/// A table's blank and comment lines take no room: a cylinder followed by two million
/// comment lines reserved 320 MB for two million cylinders, refused under a 100 MB limit.
#[test]
fn comment_lines_reserve_no_cylinders() {
    let tmp = common::fresh_dir("bad", "comment-lines");
    let d = tmp.path();
    let mut text = String::from("x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,0.1\n");
    text.push_str(&"#\n".repeat(2_000_000));
    let table = d.join("t.csv");
    std::fs::write(&table, text).unwrap();
    let out = d.join("t.json");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args([
            "import",
            table.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .env("CYLAOV_FAIL_ALLOC_OVER", "100000000")
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let scene: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(scene["cylinders"].as_array().unwrap().len(), 1);
}

/// `generate` refuses options that can never make a valid scene before writing anything,
/// naming the options and their values: exit 2 for flags, 1 naming the config file's key
/// (never a scene field of some view N, after N scenes were written).
#[test]
fn generate_refuses_options_that_make_invalid_scenes_up_front() {
    let tmp = common::fresh_dir("bad", "gen-together");
    let d = tmp.path();
    let out = d.join("o");
    let o = out.to_str().unwrap();
    let cfg = d.join("cfg.json");
    let c = cfg.to_str().unwrap();
    let cases: &[(&[&str], &str, i32, &str)] = &[
        (
            &["--width", "16384", "--height", "16384"],
            "",
            2,
            "--width 16384, --height 16384",
        ),
        (&["--volume", "1e12"], "", 2, "--volume 1000000000000"),
        (&["--fov", "1e-10"], "", 2, "--fov 1e-10"),
        (&["--length", "1e-300"], "", 2, "--length 1e-300"),
        (&["--distance", "1e-300"], "", 2, "--distance 1e-300"),
        (&["--volume", "2.2e11"], "", 2, "--volume 220000000000"),
        (
            &["--camera-model", "opencv", "--fov", "120"],
            "",
            2,
            "fold over",
        ),
        (
            &["--config", c],
            r#"{"volume": 2.2e11}"#,
            1,
            "cfg.json: volume 220000000000",
        ),
        (
            &["--config", c, "--fov", "1"],
            r#"{"volume": 1e10}"#,
            1,
            "cfg.json: volume 10000000000,10000000000,10000000000, --length 0.2..2",
        ),
    ];
    let mut failures = Vec::new();
    for (flags, config, code, needle) in cases {
        let _ = std::fs::remove_dir_all(&out);
        std::fs::write(&cfg, config).unwrap();
        let mut args = vec!["generate", "--out", o, "--count", "300"];
        args.extend_from_slice(flags);
        let r = common::cylaov(&args);
        let err = common::text(&r);
        if r.status.code() != Some(*code)
            || !err.contains(needle)
            || err.contains("generated view")
            || out.exists()
        {
            failures.push(format!(
                "{flags:?} {config}: exit {:?}, wrote {}: {err}",
                r.status.code(),
                out.exists()
            ));
        }
    }
    // A flag's value checked with the config file's others, not the defaults.
    let _ = std::fs::remove_dir_all(&out);
    std::fs::write(&cfg, r#"{"volume": 0}"#).unwrap();
    common::ok(&[
        "generate", "--out", o, "--count", "2", "--config", c, "--length", "1e-200",
    ]);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
