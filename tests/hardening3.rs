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

/// Every file `verify --report DIR` writes is checked as an output target and staged: a link
/// planted at a picture's name is refused (the file it points to keeps its bytes), a FIFO
/// there is refused at once (no write blocks on it), and a refused page leaves nothing
/// behind. The page is written through the library, as `verify` and `batch
/// --verify-fraction` both write it.
#[test]
fn report_pictures_refuse_links_and_fifos() {
    use cylaov::image::{AovImage, Channel, ChannelData};
    use cylaov::verify::report::{ReportView, write_report};
    let depth = |v: f32| {
        AovImage::from_channels(
            4,
            3,
            vec![Channel {
                name: "depth".into(),
                data: ChannelData::F32(vec![v; 12]),
            }],
        )
    };
    let (cand, mitsuba) = (depth(2.0), depth(2.0));
    let heat = image::RgbImage::new(4, 3);
    fn page<'a>(c: &'a AovImage, m: &'a AovImage, h: &'a image::RgbImage) -> ReportView<'a> {
        ReportView {
            name: "single",
            verdict: "PASS",
            summary: "ok".into(),
            worst: 0.0,
            arbitration: None,
            lines: Vec::new(),
            images: Some((c, m, h)),
        }
    }
    let view = || page(&cand, &mitsuba, &heat);
    let d = tempfile::tempdir().unwrap();
    let outside = d.path().join("precious.txt");
    std::fs::write(&outside, b"keep me").unwrap();
    for name in ["candidate", "mitsuba", "heatmap"] {
        let dir = d.path().join(format!("link-{name}"));
        std::fs::create_dir_all(&dir).unwrap();
        std::os::unix::fs::symlink(&outside, dir.join(format!("view0.{name}.png"))).unwrap();
        let err = write_report(&dir, "t", &[view()]).unwrap_err();
        let msg = format!("{err:#}");
        assert!(msg.contains(&format!("view0.{name}.png")), "{msg}");
        assert_eq!(std::fs::read(&outside).unwrap(), b"keep me");
        assert!(
            !dir.join("index.html").exists(),
            "a refused page was written"
        );
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 1, "only the planted link remains: {left:?}");
    }
    // A FIFO: refused without opening it (a write would block until a reader came).
    let dir = d.path().join("fifo");
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("view0.heatmap.png");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let (tx, rx) = std::sync::mpsc::channel();
    let dir2 = dir.clone();
    let (c2, m2, h2) = (cand.clone(), mitsuba.clone(), heat.clone());
    std::thread::spawn(move || {
        let v = page(&c2, &m2, &h2);
        let _ = tx.send(write_report(&dir2, "t", &[v]).map_err(|e| format!("{e:#}")));
    });
    let got = rx
        .recv_timeout(std::time::Duration::from_secs(20))
        .expect("the report blocked on a FIFO");
    let msg = got.unwrap_err();
    assert!(msg.contains("FIFO") || msg.contains("fifo"), "{msg}");
    // Without planted files the page and its three pictures are written.
    let dir = d.path().join("clean");
    write_report(&dir, "t", &[view()]).unwrap();
    for f in [
        "index.html",
        "view0.candidate.png",
        "view0.mitsuba.png",
        "view0.heatmap.png",
    ] {
        assert!(dir.join(f).is_file(), "{f}");
    }
}

/// Run `args`, killing the command if it has not finished after `secs` seconds (a read that
/// blocks on a FIFO never would).
fn cylaov_within(args: &[&str], secs: u64) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(secs);
    while child.try_wait().unwrap().is_none() {
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("cylaov {args:?} was still running after {secs} s");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// `compare` and `verify --candidate` refuse an input that is a FIFO at once (reading it
/// would block until a writer came), naming it; a link to a regular EXR is still read.
#[test]
fn exr_inputs_refuse_fifos() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let exr = d.path().join("a.exr");
    let o = cylaov(&["render", s(&scene), "-o", s(&exr)]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let fifo = d.path().join("pipe.exr");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    for (a, b) in [(&fifo, &exr), (&exr, &fifo)] {
        let o = cylaov_within(&["compare", s(a), s(b)], 20);
        assert_ne!(o.status.code(), Some(0));
        let err = text(&o.stderr);
        assert!(err.contains("pipe.exr") && err.contains("FIFO"), "{err}");
    }
    let o = cylaov_within(&["verify", s(&scene), "--candidate", s(&fifo)], 20);
    assert_ne!(o.status.code(), Some(0));
    let err = text(&o.stderr) + &text(&o.stdout);
    assert!(err.contains("FIFO"), "{err}");
    let link = d.path().join("link.exr");
    std::os::unix::fs::symlink(&exr, &link).unwrap();
    let o = cylaov_within(&["compare", s(&exr), s(&link)], 60);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
}

/// A RAM disk is where fast scratch output goes: `render`, `generate` and `batch` write
/// under `/dev/shm` (a tmpfs), also through a link from elsewhere, and `/dev/../tmp` is
/// judged where it leads (a regular folder); a new name in `/dev` itself is still refused.
#[test]
fn ram_disk_under_dev_shm_is_writable() {
    let kind = Command::new("stat")
        .args(["-f", "-c", "%T", "/dev/shm"])
        .output()
        .unwrap();
    assert_eq!(
        text(&kind.stdout).trim(),
        "tmpfs",
        "this test needs /dev/shm to be a tmpfs, as on Linux machines and containers"
    );
    let shm = tempfile::Builder::new()
        .prefix("cylaov-test-")
        .tempdir_in("/dev/shm")
        .unwrap();
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let direct = shm.path().join("x").join("a.exr");
    let o = cylaov(&["render", s(&scene), "-o", s(&direct)]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(direct.is_file());
    let link = d.path().join("scratch");
    std::os::unix::fs::symlink(shm.path(), &link).unwrap();
    let via = link.join("y").join("b.exr");
    let o = cylaov(&["render", s(&scene), "-o", s(&via)]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(shm.path().join("y").join("b.exr").is_file());
    let data = shm.path().join("data");
    let o = cylaov(&["generate", "--count", "2", "--seed", "1", "--out", s(&data)]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = shm.path().join("out");
    let o = cylaov(&["batch", s(&data), "--out", s(&out), "--no-png"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(out.join("index.json").is_file());
    // `..` is resolved before judging: /dev/../tmp is /tmp.
    let up = format!("/dev/..{}/z.exr", d.path().display());
    let o = cylaov(&["render", s(&scene), "-o", &up]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(d.path().join("z.exr").is_file());
    // /dev's own entries and its other file systems stay refused.
    for target in [
        format!("/dev/cylaov-{}.exr", std::process::id()),
        format!("/dev/pts/cylaov-{}.exr", std::process::id()),
        format!(
            "{}/../../cylaov-{}.exr",
            shm.path().display(),
            std::process::id()
        ),
    ] {
        let o = cylaov(&["render", s(&scene), "-o", &target]);
        assert_eq!(o.status.code(), Some(1), "{target}: {}", text(&o.stderr));
        assert!(
            text(&o.stderr).contains("is inside /dev"),
            "{}",
            text(&o.stderr)
        );
    }
}

/// Files and folders under `dir` (recursively): the empty folders, the number of files,
/// and the unfinished ones (temporary files, lock files) among them.
fn empty_folders(dir: &Path) -> (Vec<std::path::PathBuf>, usize, Vec<std::path::PathBuf>) {
    let mut empty = Vec::new();
    let mut files = 0;
    let mut unfinished = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let entries: Vec<_> = match std::fs::read_dir(&d) {
            Ok(e) => e.filter_map(Result::ok).collect(),
            Err(_) => continue,
        };
        if entries.is_empty() {
            empty.push(d.clone());
        }
        for e in entries {
            if e.file_type().unwrap().is_dir() {
                stack.push(e.path());
            } else {
                files += 1;
                let name = e.file_name().to_string_lossy().into_owned();
                if name.ends_with(".tmp") || name.ends_with(".lock") {
                    unfinished.push(e.path());
                }
            }
        }
    }
    (empty, files, unfinished)
}

/// A batch interrupted early (SIGINT, as `timeout -s INT` sends) removes the output
/// folders it made: no empty `new/deep` is left behind, in either format, and no temporary
/// or lock file. Interrupted after views were written, those stay (the run resumes from
/// them). Every folder and file is made while the signal registry is held, so this holds
/// at any moment, whatever the other threads do between the clean-up and the exit.
#[test]
fn interrupted_batch_leaves_no_empty_folders() {
    let d = tempfile::tempdir().unwrap();
    let data = d.path().join("data");
    let o = cylaov(&[
        "generate",
        "--count",
        "40",
        "--seed",
        "3",
        "--out",
        s(&data),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let mut interrupted = 0;
    // Before, at and after the moment the output folder is made (a few ms in: reading
    // 40 scenes, then the folder, its lock, the first view).
    let delays = [
        "0.002", "0.004", "0.006", "0.008", "0.012", "0.02", "0.04", "0.1",
    ];
    for (k, delay) in delays.iter().enumerate() {
        for format in ["files", "webdataset"] {
            let top = d.path().join(format!("new{k}{format}"));
            let out = top.join("deep");
            let o = Command::new("timeout")
                .args(["--preserve-status", "-s", "INT", delay])
                .args([env!("CARGO_BIN_EXE_cylaov"), "batch"])
                .args([
                    s(&data),
                    "--out",
                    s(&out),
                    "--format",
                    format,
                    "--threads",
                    "1",
                ])
                .output()
                .unwrap();
            if o.status.code() != Some(130) {
                continue;
            }
            interrupted += 1;
            let (empty, files, unfinished) = empty_folders(&top);
            assert!(
                empty.is_empty(),
                "{format} after {delay} s: empty folders left: {empty:?}"
            );
            assert!(
                unfinished.is_empty(),
                "{format} after {delay} s: unfinished files left: {unfinished:?}"
            );
            assert!(
                !top.exists() || files > 0,
                "{format} after {delay} s: {} left with nothing in it",
                top.display()
            );
        }
    }
    assert!(interrupted >= 3, "only {interrupted} runs were interrupted");
}

/// Messages a newcomer met: an unknown field is not "invalid JSON" (the JSON is valid), a
/// syntax error names the file and the line, a missing input is said once, and an AOV
/// mapped twice by `--channels` is refused.
#[test]
fn messages_say_what_is_wrong_once() {
    let d = tempfile::tempdir().unwrap();
    let typo = d.path().join("typo.json");
    std::fs::write(&typo, SCENE.replace("\"radius\"", "\"raduis\"")).unwrap();
    let o = cylaov(&["render", s(&typo), "-o", s(&d.path().join("t.exr"))]);
    assert_eq!(o.status.code(), Some(1));
    let err = text(&o.stderr);
    assert!(
        err.contains("typo.json") && err.contains("unknown field `raduis`"),
        "{err}"
    );
    assert!(!err.contains("invalid JSON"), "{err}");
    let comma = d.path().join("comma.json");
    std::fs::write(
        &comma,
        SCENE.replace("\"up\": [0, 0, 1],", "\"up\": [0, 0, 1,],"),
    )
    .unwrap();
    let o = cylaov(&["render", s(&comma), "-o", s(&d.path().join("c.exr"))]);
    assert_eq!(o.status.code(), Some(1));
    let err = text(&o.stderr);
    assert!(
        err.contains("comma.json") && err.contains("invalid JSON") && err.contains("line 1"),
        "{err}"
    );
    assert!(!err.contains("?:"), "{err}");
    let scene = d.path().join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let exr = d.path().join("a.exr");
    assert!(
        cylaov(&["render", s(&scene), "-o", s(&exr)])
            .status
            .success()
    );
    let missing = d.path().join("missing.exr");
    let o = cylaov(&["compare", s(&exr), s(&missing)]);
    assert_ne!(o.status.code(), Some(0));
    let err = text(&o.stderr);
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    assert!(err.contains("missing.exr"), "{err}");
    let o = cylaov(&[
        "verify",
        s(&scene),
        "--candidate",
        s(&exr),
        "--channels",
        "depth=Z,depth=N.R",
    ]);
    assert_ne!(o.status.code(), Some(0));
    let err = text(&o.stderr);
    assert!(err.contains("depth is mapped twice"), "{err}");
}

/// `batch --help` lists the tar options with the other options, not under the heading of
/// the --verify-fraction bounds; every heading's options belong to it.
#[test]
fn batch_help_groups_options_under_the_right_heading() {
    let o = cylaov(&["batch", "--help"]);
    assert!(o.status.success());
    let help = text(&o.stdout);
    let (before, bounds) = help
        .split_once("Bounds of --verify-fraction:")
        .unwrap_or_else(|| panic!("no bounds heading in {help}"));
    for flag in [
        "--format",
        "--shard-size",
        "--members",
        "--report",
        "--threads",
    ] {
        assert!(
            before.contains(flag),
            "{flag} not among the options:\n{help}"
        );
        assert!(
            !bounds.contains(flag),
            "{flag} under the bounds heading:\n{help}"
        );
    }
    // The bounds themselves are tolerances.
    assert!(
        bounds.contains("--rel-distance") || bounds.contains("--distance"),
        "{bounds}"
    );
}
