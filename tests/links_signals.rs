//! Files cylaov does not own and runs that do not end normally: planted links, hard links
//! and FIFOs among the outputs, the system folders, SIGINT/SIGTERM/SIGHUP, the file size
//! and open-file limits, a full disk. Runs the real binary.

mod common;

use std::io::Read;
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const SCENE: &str = r#"{ "camera": { "origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1],
    "fov_deg": 40, "width": 64, "height": 48 },
  "cylinders": [ { "p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5 } ],
  "aovs": ["depth", "normal", "shape_id"] }"#;

fn dir(name: &str) -> tempfile::TempDir {
    common::fresh_dir("links", name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn exe() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cylaov"));
    c.env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX");
    c
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Wait for `child` at most `secs`; a run still going then is killed and fails the test
/// (a FIFO must never block cylaov).
fn wait_bounded(mut child: Child, secs: u64, what: &str) -> Output {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut out = Vec::new();
            let mut err = Vec::new();
            if let Some(mut o) = child.stdout.take() {
                o.read_to_end(&mut out).unwrap();
            }
            if let Some(mut e) = child.stderr.take() {
                e.read_to_end(&mut err).unwrap();
            }
            return Output {
                status,
                stdout: out,
                stderr: err,
            };
        }
        if start.elapsed() > Duration::from_secs(secs) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what}: still running after {secs} s");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn run_bounded(args: &[&str], secs: u64) -> Output {
    let child = exe()
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_bounded(child, secs, &format!("cylaov {args:?}"))
}

fn mkfifo(p: &Path) {
    let st = Command::new("mkfifo").arg(p).status().unwrap();
    assert!(st.success(), "mkfifo {}", p.display());
}

fn is_fifo(p: &Path) -> bool {
    std::fs::symlink_metadata(p).is_ok_and(|m| m.file_type().is_fifo())
}

fn is_symlink(p: &Path) -> bool {
    std::fs::symlink_metadata(p).is_ok_and(|m| m.file_type().is_symlink())
}

/// Every `*.tmp` file or folder under `root`, recursively.
fn temps(root: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut todo = vec![root.to_path_buf()];
    while let Some(d) = todo.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if e.file_name().to_string_lossy().ends_with(".tmp") {
                found.push(p.clone());
            }
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                todo.push(p);
            }
        }
    }
    found
}

/// `n` generated scenes of `w`×`h` with `cylinders` cylinders in `d/ds`.
fn generated(d: &Path, n: u32, w: u32, h: u32, cylinders: u32) -> PathBuf {
    let ds = d.join("ds");
    common::ok(&[
        "generate",
        "--count",
        &n.to_string(),
        "--out",
        s(&ds),
        "--width",
        &w.to_string(),
        "--height",
        &h.to_string(),
        "--cylinders",
        &cylinders.to_string(),
    ]);
    ds
}

/// A link or a hard link planted at a shard's lock is refused by name and the file it
/// leads to is left as it was; a FIFO there is named as one (not "Invalid argument").
#[test]
fn shard_locks_that_are_links_or_fifos_are_refused() {
    let tmp = dir("lock");
    let d = tmp.path();
    let ds = generated(d, 2, 16, 12, 3);
    let out = d.join("out");
    let partial = out.join(".partial");
    std::fs::create_dir_all(&partial).unwrap();
    let lock = partial.join("0-of-1.lock");
    let victim = d.join("victim.txt");
    let mut failures = Vec::new();
    for plant in ["symlink", "hardlink", "fifo"] {
        std::fs::write(&victim, "mine\n").unwrap();
        let _ = std::fs::remove_file(&lock);
        match plant {
            "symlink" => std::os::unix::fs::symlink(&victim, &lock).unwrap(),
            "hardlink" => std::fs::hard_link(&victim, &lock).unwrap(),
            _ => mkfifo(&lock),
        }
        let o = run_bounded(&["batch", s(&ds), "--out", s(&out)], 60);
        let err = stderr(&o);
        let want = match plant {
            "symlink" => "is a symbolic link",
            "hardlink" => "has 2 hard links",
            _ => "is a FIFO (named pipe)",
        };
        if o.status.code() != Some(1)
            || !err.contains(&format!("{}: {want}", lock.display()))
            || err.contains("os error 22")
            || err.trim().lines().count() != 1
        {
            failures.push(format!("{plant}: {:?} {err}", o.status));
        }
        if std::fs::read_to_string(&victim).unwrap() != "mine\n" {
            failures.push(format!("{plant}: the linked file was written"));
        }
        if out.join("index.json").exists() {
            failures.push(format!("{plant}: the batch ran"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // With the lock its own file again, the batch runs and removes it.
    std::fs::remove_file(&lock).unwrap();
    let o = run_bounded(&["batch", s(&ds), "--out", s(&out)], 60);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!lock.exists() && !partial.exists());
}

/// An output whose last component is a symbolic link is refused and the link stays a
/// link; nothing is created in /dev, whichever way the path gets there; folders on the
/// way may be links.
#[test]
fn output_links_and_system_folders_are_refused() {
    let tmp = dir("outlinks");
    let d = tmp.path();
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let exr = d.join("s.exr");
    common::ok(&["render", s(&scene), "-o", s(&exr)]);
    let victim = d.join("victim.bin");
    std::fs::write(&victim, "mine").unwrap();
    let link = d.join("link.out");
    std::os::unix::fs::symlink(&victim, &link).unwrap();
    let dangling = d.join("dangling.out");
    std::os::unix::fs::symlink(d.join("nowhere"), &dangling).unwrap();
    let mut failures = Vec::new();
    for target in [&link, &dangling] {
        let t = s(target);
        for (args, code) in [
            (vec!["render", s(&scene), "-o", t], 1),
            (vec!["export-mitsuba", s(&scene), "-o", t], 1),
            (vec!["compare", s(&exr), s(&exr), "--heatmap", t], 2),
            (
                vec!["stress", "--family", "far", "--rays", "1", "--csv", t],
                1,
            ),
        ] {
            let o = run_bounded(&args, 120);
            let err = stderr(&o);
            if o.status.code() != Some(code) || !err.contains(&format!("{t}: is a symbolic link")) {
                failures.push(format!("{args:?}: {:?} {err}", o.status));
            }
            if !is_symlink(target) {
                failures.push(format!("{args:?}: the link was replaced"));
            }
        }
    }
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "mine");

    // Inside /dev: a new name, through a link on the way, and /dev/stdout with stdout a
    // regular file (the case that replaced the machine's /dev/stdout link).
    let new_in_dev = PathBuf::from(format!("/dev/cylaov-links-{}.exr", std::process::id()));
    let to_dev = d.join("to-dev");
    std::os::unix::fs::symlink("/dev", &to_dev).unwrap();
    let via_link = to_dev.join(format!("cylaov-links-{}.exr", std::process::id()));
    for target in [&new_in_dev, &via_link] {
        let o = run_bounded(&["render", s(&scene), "-o", s(target)], 60);
        let err = stderr(&o);
        if o.status.code() != Some(1) || !err.contains("is inside /dev") {
            failures.push(format!("-o {}: {:?} {err}", target.display(), o.status));
        }
        if new_in_dev.exists() || new_in_dev.with_extension("camera.json").exists() {
            let _ = std::fs::remove_file(&new_in_dev);
            let _ = std::fs::remove_file(new_in_dev.with_extension("camera.json"));
            let _ = std::fs::remove_file(new_in_dev.with_extension("open3d.json"));
            failures.push(format!("-o {}: wrote into /dev", target.display()));
        }
    }
    // Inside /proc and /sys: a new name in each, and through a link on the way.
    let to_proc = d.join("to-proc");
    std::os::unix::fs::symlink("/proc", &to_proc).unwrap();
    let pid = std::process::id();
    for (target, root) in [
        (
            PathBuf::from(format!("/proc/cylaov-links-{pid}.exr")),
            "/proc",
        ),
        (to_proc.join(format!("cylaov-links-{pid}.exr")), "/proc"),
        (
            PathBuf::from(format!("/proc/{pid}/cylaov-links.exr")),
            "/proc",
        ),
        (
            PathBuf::from(format!("/sys/cylaov-links-{pid}.exr")),
            "/sys",
        ),
        (
            PathBuf::from(format!("/sys/kernel/cylaov-links-{pid}.exr")),
            "/sys",
        ),
    ] {
        for (args, code) in [
            (vec!["render", s(&scene), "-o", s(&target)], 1),
            (vec!["export-mitsuba", s(&scene), "-o", s(&target)], 1),
            (
                vec!["compare", s(&exr), s(&exr), "--heatmap", s(&target)],
                2,
            ),
        ] {
            let o = run_bounded(&args, 60);
            let err = stderr(&o);
            if o.status.code() != Some(code)
                || err
                    != format!(
                        "error: {}: is inside {root}: cylaov never creates or renames files in /proc, /sys, or in /dev outside a RAM disk such as /dev/shm (write to a regular file and copy it from there)\n",
                        flagged(&args, &target)
                    )
            {
                failures.push(format!("{args:?}: {:?} {err}", o.status));
            }
        }
    }
    let stdout_was_link = is_symlink(Path::new("/dev/stdout"));
    for (args, code) in [
        (vec!["render", s(&scene), "-o", "/dev/stdout"], 1),
        (
            vec!["compare", s(&exr), s(&exr), "--heatmap", "/dev/stdout"],
            2,
        ),
    ] {
        let log = std::fs::File::create(d.join("log")).unwrap();
        let child = exe()
            .args(&args)
            .stdout(log)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let o = wait_bounded(child, 60, "/dev/stdout");
        let err = stderr(&o);
        if o.status.code() != Some(code) || !err.contains("/dev/stdout: is inside /dev") {
            failures.push(format!("{args:?}: {:?} {err}", o.status));
        }
        if is_symlink(Path::new("/dev/stdout")) != stdout_was_link
            || Path::new("/dev/stdout.camera.json").exists()
        {
            failures.push(format!("{args:?}: /dev/stdout was replaced"));
        }
        assert_eq!(std::fs::metadata(d.join("log")).unwrap().len(), 0);
    }
    // A link among the folders on the way is fine.
    let real = d.join("real");
    std::fs::create_dir_all(&real).unwrap();
    let to_real = d.join("to-real");
    std::os::unix::fs::symlink(&real, &to_real).unwrap();
    common::ok(&["render", s(&scene), "-o", s(&to_real.join("x.exr"))]);
    assert!(real.join("x.exr").is_file() && real.join("x.camera.json").is_file());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// `FLAG PATH` as a refusal names the output `target` of `args` (the option before it).
fn flagged(args: &[&str], target: &Path) -> String {
    let k = args.iter().position(|a| *a == s(target)).unwrap();
    format!("{} {}", args[k - 1], target.display())
}

/// A FIFO among a batch's outputs (a view's EXR, index.json, the failures file) is named
/// in one line at once: the batch neither blocks on it nor replaces it.
#[test]
fn fifos_among_batch_outputs_are_refused_without_blocking() {
    let tmp = dir("fifos");
    let d = tmp.path();
    let ds = generated(d, 3, 16, 12, 3);
    let out = d.join("out");
    let o = run_bounded(&["batch", s(&ds), "--out", s(&out)], 60);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut failures = Vec::new();
    for name in [
        "000000.exr",
        "000001.depth.png",
        "index.json",
        "failures.0-of-1.jsonl",
    ] {
        let path = out.join(name);
        let _ = std::fs::remove_file(&path);
        mkfifo(&path);
        let o = run_bounded(&["batch", s(&ds), "--out", s(&out)], 30);
        let err = stderr(&o);
        if o.status.code() != Some(1)
            || !err.contains(&format!("{}: is a FIFO (named pipe)", path.display()))
            || err.trim().lines().count() != 1
        {
            failures.push(format!("{name}: {:?} {err}", o.status));
        }
        if !is_fifo(&path) {
            failures.push(format!("{name}: the FIFO was replaced"));
        }
        std::fs::remove_file(&path).unwrap();
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A symbolic link planted at a view's output (`OUT/000000.exr`, `OUT/000001.depth.png`)
/// to a file elsewhere is refused by name, in one line, before any view is rendered: in a
/// new `--out` and in one a finished batch wrote. The link stays a link and the file it
/// leads to is left as it was.
#[test]
fn links_at_batch_view_outputs_are_refused() {
    let tmp = dir("viewlinks");
    let d = tmp.path();
    let ds = generated(d, 2, 16, 12, 3);
    let victim = d.join("victim.bin");
    let mut failures = Vec::new();
    for (out, name) in [
        (d.join("new"), "000000.exr"),
        (d.join("done"), "000000.exr"),
        (d.join("done"), "000001.depth.png"),
    ] {
        if name == "000000.exr" && out.ends_with("done") {
            let o = run_bounded(&["batch", s(&ds), "--out", s(&out)], 60);
            assert!(o.status.success(), "{}", stderr(&o));
        }
        std::fs::create_dir_all(&out).unwrap();
        let link = out.join(name);
        let _ = std::fs::remove_file(&link);
        std::fs::write(&victim, "mine\n").unwrap();
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        let before = std::fs::read_dir(&out).unwrap().count();
        let o = run_bounded(&["batch", s(&ds), "--out", s(&out)], 60);
        let err = stderr(&o);
        let what = format!("{}", link.display());
        if o.status.code() != Some(1)
            || err
                != format!(
                    "error: {what}: is a symbolic link, not a regular file; refusing to replace it (remove it and run again)\n"
                )
        {
            failures.push(format!("{what}: {:?} {err}", o.status));
        }
        if !is_symlink(&link) {
            failures.push(format!("{what}: the link was replaced"));
        }
        if std::fs::read_to_string(&victim).unwrap() != "mine\n" {
            failures.push(format!("{what}: the linked file was written"));
        }
        if std::fs::read_dir(&out).unwrap().count() != before {
            failures.push(format!("{what}: the batch wrote into {}", out.display()));
        }
        std::fs::remove_file(&link).unwrap();
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// `generate` into a folder whose `manifest.jsonl`, `generate.json` or a scene file it would
/// write is a link to a file elsewhere or a FIFO: refused at once in one line naming the
/// path and what it is, whether the run would do nothing, extend the dataset or replace it
/// (`--force`); the link or FIFO stays and the linked file is left as it was.
#[test]
fn generate_refuses_links_and_fifos_among_its_files() {
    let tmp = dir("generate");
    let d = tmp.path();
    let ds = generated(d, 2, 16, 12, 3);
    let victim = d.join("victim.txt");
    let base = [
        "generate",
        "--out",
        s(&ds),
        "--width",
        "16",
        "--height",
        "12",
        "--cylinders",
        "3",
    ];
    let runs: [&[&str]; 3] = [
        &["--count", "2"],
        &["--count", "3"],
        &["--count", "3", "--force"],
    ];
    let mut failures = Vec::new();
    for (name, plant) in [
        ("manifest.jsonl", "symlink"),
        ("generate.json", "symlink"),
        ("scenes/000002.json", "symlink"),
        ("generate.json", "fifo"),
        ("manifest.jsonl", "fifo"),
    ] {
        let path = ds.join(name);
        let saved = std::fs::read(&path).ok();
        let _ = std::fs::remove_file(&path);
        match plant {
            "symlink" => std::os::unix::fs::symlink(&victim, &path).unwrap(),
            _ => mkfifo(&path),
        }
        let want = match plant {
            "symlink" => format!(
                "error: --out {}: is a symbolic link (to a regular file), not a regular file: cylaov neither replaces a link nor writes through one; give the path it points to or another name\n",
                path.display()
            ),
            _ => format!(
                "error: --out {}: is a FIFO (named pipe), not a regular file; refusing to replace it\n",
                path.display()
            ),
        };
        for extra in runs {
            // The scene past the count of 2 is only written by a run of 3.
            if name.starts_with("scenes/") && extra == ["--count", "2"] {
                continue;
            }
            std::fs::write(&victim, "mine\n").unwrap();
            let args: Vec<&str> = base.iter().chain(extra).copied().collect();
            let o = run_bounded(&args, 10);
            let err = stderr(&o);
            let what = format!("{plant} at {name}, {extra:?}");
            if o.status.code() != Some(1) || err != want {
                failures.push(format!("{what}: {:?} {err}", o.status));
            }
            let kept = match plant {
                "symlink" => is_symlink(&path),
                _ => is_fifo(&path),
            };
            if !kept {
                failures.push(format!("{what}: the {plant} was replaced"));
            }
            if std::fs::read_to_string(&victim).unwrap() != "mine\n" {
                failures.push(format!("{what}: the linked file was written"));
            }
            if ds.join("scenes/000002.json").is_file() && name != "scenes/000002.json" {
                failures.push(format!("{what}: the dataset was extended"));
                let _ = std::fs::remove_file(ds.join("scenes/000002.json"));
            }
        }
        std::fs::remove_file(&path).unwrap();
        if let Some(bytes) = saved {
            std::fs::write(&path, bytes).unwrap();
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // Its own files back, the same command does nothing.
    let o = run_bounded(
        &base
            .iter()
            .chain(&["--count", "2"])
            .copied()
            .collect::<Vec<_>>(),
        10,
    );
    assert!(
        o.status.success() && stdout(&o).starts_with("nothing to do"),
        "{}{}",
        stdout(&o),
        stderr(&o)
    );
}

/// Start `args`, wait until `ready` holds (polling), send `sig`, and return the output.
fn signal_when(
    args: &[&str],
    sig: i32,
    ready: &dyn Fn(u32) -> bool,
    env: &[(&str, &Path)],
) -> Output {
    let mut cmd = exe();
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let child = cmd.spawn().unwrap();
    let pid = child.id();
    let start = Instant::now();
    while !ready(pid) {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "{args:?}: never got ready"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    // SAFETY: signals our own child.
    unsafe { libc::kill(pid as i32, sig) };
    wait_bounded(child, 60, &format!("{args:?} after signal {sig}"))
}

/// Whether the last line on stderr of a run stopped by `sig` is the clean-up's report,
/// `cylaov: stopped by SIGINT: N unfinished files and folders removed (exit 130)`, with N
/// at least 1 (the run was caught with a file staged).
fn stopped_line(o: &Output, sig: i32) -> bool {
    let name = match sig {
        libc::SIGHUP => "SIGHUP",
        libc::SIGINT => "SIGINT",
        _ => "SIGTERM",
    };
    let err = stderr(o);
    let Some(last) = err.lines().last() else {
        return false;
    };
    let n = last
        .strip_prefix(&format!("cylaov: stopped by {name}: "))
        .and_then(|rest| {
            rest.strip_suffix(&format!(
                " unfinished files and folders removed (exit {})",
                128 + sig
            ))
        })
        .and_then(|n| n.parse::<u32>().ok());
    err.ends_with('\n') && n.is_some_and(|n| n >= 1)
}

/// SIGINT, SIGTERM and SIGHUP during a render remove its staged EXR and exit 130, 143,
/// 129, saying so on stderr; a SIGTERM during a batch removes its partial folder and
/// every temporary file.
#[test]
fn signals_remove_staged_files_and_exit_128_plus_n() {
    let tmp = dir("signals");
    let d = tmp.path();
    // A render long enough to be caught with its EXR staged (about a second).
    let ds = generated(d, 1, 4096, 4096, 200);
    let scene = ds.join("scenes/000000.json");
    let outdir = d.join("o");
    std::fs::create_dir_all(&outdir).unwrap();
    let exr = outdir.join("x.exr");
    let mut failures = Vec::new();
    for (sig, code) in [
        (libc::SIGINT, 130),
        (libc::SIGTERM, 143),
        (libc::SIGHUP, 129),
    ] {
        let staged = |_pid: u32| !temps(&outdir).is_empty();
        let o = signal_when(
            &["render", s(&scene), "-o", s(&exr), "--aov", "depth"],
            sig,
            &staged,
            &[],
        );
        let left: Vec<_> = std::fs::read_dir(&outdir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        if o.status.code() != Some(code) || !left.is_empty() || !stopped_line(&o, sig) {
            failures.push(format!(
                "render, signal {sig}: {:?}, left {left:?}, {}",
                o.status,
                stderr(&o)
            ));
        }
    }
    // A batch: its partial folder and the lock go too.
    let many = d.join("many");
    std::fs::create_dir_all(&many).unwrap();
    let ds = generated(&many, 40, 512, 512, 60);
    let out = d.join("out");
    let partial = out.join(".partial/0-of-1");
    let busy = |_pid: u32| std::fs::read_dir(&partial).is_ok_and(|mut e| e.next().is_some());
    let o = signal_when(
        &["batch", s(&ds), "--out", s(&out)],
        libc::SIGTERM,
        &busy,
        &[],
    );
    if o.status.code() != Some(143)
        || out.join(".partial").exists()
        || !temps(&out).is_empty()
        || !stopped_line(&o, libc::SIGTERM)
    {
        failures.push(format!(
            "batch: {:?}, .partial there: {}, temps {:?}, {}",
            o.status,
            out.join(".partial").exists(),
            temps(&out),
            stderr(&o)
        ));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// `sh -c 'ulimit -f N; exec cylaov ...'`.
fn with_file_limit(blocks: u32, args: &[&str]) -> Output {
    let mut line = format!("ulimit -f {blocks}; exec \"$0\"");
    for (k, _) in args.iter().enumerate() {
        line += &format!(" \"${}\"", k + 1);
    }
    Command::new("sh")
        .arg("-c")
        .arg(line)
        .arg(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .output()
        .unwrap()
}

/// A write past `ulimit -f` fails with the file size message (not a silent SIGXFSZ kill),
/// leaves no temporary file, and `generate` removes the folder it made.
#[test]
fn the_file_size_limit_fails_cleanly() {
    let tmp = dir("fsize");
    let d = tmp.path();
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let out = d.join("o");
    std::fs::create_dir_all(&out).unwrap();
    let o = with_file_limit(1, &["render", s(&scene), "-o", s(&out.join("x.exr"))]);
    assert_eq!(o.status.code(), Some(1), "{:?} {}", o.status, stderr(&o));
    assert!(stderr(&o).contains("ulimit -f"), "{}", stderr(&o));
    let left: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert!(left.is_empty(), "{left:?}");
    let new = d.join("new");
    let o = with_file_limit(1, &["generate", "--count", "3", "--out", s(&new)]);
    assert_eq!(o.status.code(), Some(1), "{:?} {}", o.status, stderr(&o));
    assert!(stderr(&o).contains("ulimit -f"), "{}", stderr(&o));
    assert!(!new.exists(), "generate left {}", new.display());
}

/// This machine's name as temporary names carry it.
fn temp_host() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    let host: String = host
        .trim()
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '.')
        .take(16)
        .collect();
    if host.is_empty() { "host".into() } else { host }
}

/// The next run in a folder removes the temporary files of dead processes of this host;
/// those of live processes and of other hosts stay.
#[test]
fn stale_temps_of_dead_processes_are_removed() {
    let tmp = dir("stale");
    let d = tmp.path();
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let mut gone = Command::new("true").spawn().unwrap();
    gone.wait().unwrap();
    let host = temp_host();
    let dead = d.join(format!(".x.exr.{host}.{}.aB3dE6gH.tmp", gone.id()));
    let live = d.join(format!(".x.exr.{host}.{}.aB3dE6gH.tmp", std::process::id()));
    let other = d.join(format!(".x.exr.zz-other-node.{}.aB3dE6gH.tmp", gone.id()));
    for p in [&dead, &live, &other] {
        std::fs::write(p, "partial").unwrap();
    }
    common::ok(&["render", s(&scene), "-o", s(&d.join("x.exr"))]);
    assert!(!dead.exists(), "the dead process's temporary file stayed");
    assert!(live.exists() && other.exists());
}

/// A signal during `verify` kills the Mitsuba process group it started (the interpreter and
/// anything it spawned) and removes its scratch folder. The interpreter is a stand-in that
/// starts a grandchild and waits: real Mitsuba can finish a small scene in a few hundred
/// milliseconds, before any signal could arrive, so only a process that waits makes the
/// test decide the same way on every machine.
#[test]
fn a_signal_during_verify_stops_mitsuba_and_removes_its_folder() {
    let tmp = dir("verify");
    let d = tmp.path();
    let scene = d.join("s.json");
    std::fs::write(&scene, SCENE).unwrap();
    let scratch = d.join("tmp");
    std::fs::create_dir_all(&scratch).unwrap();
    let venv = d.join("venv");
    std::fs::create_dir_all(venv.join("bin")).unwrap();
    let pids = d.join("pids");
    let python = venv.join("bin/python");
    std::fs::write(
        &python,
        format!(
            "#!/bin/sh\nsleep 60 &\necho $$ $! > {}.tmp\nmv {0}.tmp {0}\nwait\n",
            pids.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&python, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let started = |_pid: u32| pids.exists();
    let o = signal_when(
        &["verify", s(&scene)],
        libc::SIGTERM,
        &started,
        &[("TMPDIR", &scratch), ("CYLAOV_VENV", &venv)],
    );
    assert_eq!(o.status.code(), Some(143), "{:?} {}", o.status, stderr(&o));
    let recorded = std::fs::read_to_string(&pids).unwrap();
    let started: Vec<u32> = recorded
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    assert_eq!(started.len(), 2, "{recorded}");
    let deadline = Instant::now() + Duration::from_secs(10);
    for pid in started {
        loop {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            if stat.is_empty() || stat.contains(") Z ") {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "Mitsuba's process {pid} still runs: {stat}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let left: Vec<_> = std::fs::read_dir(&scratch)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert!(left.is_empty(), "left in TMPDIR: {left:?}");
}

/// A tmpfs of `size` mounted at `at`, unmounted when dropped; `None` (the caller skips)
/// when mounting is not permitted, unless CI=true.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(at: &Path, size: &str) -> Option<Tmpfs> {
        std::fs::create_dir_all(at).unwrap();
        let st = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs", s(at)])
            .stderr(Stdio::null())
            .status();
        if st.is_ok_and(|s| s.success()) {
            return Some(Tmpfs(at.to_path_buf()));
        }
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but a tmpfs cannot be mounted at {}",
            at.display()
        );
        eprintln!("SKIPPED: cannot mount a tmpfs (needs root)");
        None
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// A full disk during a batch: the temporary files go, the summary names the reason, the
/// views not started are counted, the exit status is 1, and the failures file is written.
#[test]
fn a_full_disk_stops_a_batch_with_its_summary() {
    let tmp = dir("full");
    let d = tmp.path();
    let ds = generated(d, 16, 128, 128, 8);
    let Some(mnt) = Tmpfs::mount(&d.join("mnt"), "2m") else {
        return;
    };
    let out = mnt.0.join("out");
    let o = run_bounded(&["batch", s(&ds), "--out", s(&out), "--threads", "1"], 120);
    let (so, se) = (stdout(&o), stderr(&o));
    assert_eq!(o.status.code(), Some(1), "{so}\n{se}");
    assert!(
        so.contains("stopped") && so.contains("the disk is full"),
        "{so}"
    );
    assert!(se.contains("views not started"), "{se}");
    assert!(temps(&out).is_empty(), "{:?}", temps(&out));
    assert!(!out.join(".partial").exists());
    let failures = std::fs::read_to_string(out.join("failures.0-of-1.jsonl")).unwrap();
    assert!(failures.contains("os error 28"), "{failures}");
    let done = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".exr"))
        .count();
    assert!((1..16).contains(&done), "{done} views done: {so}");
}

/// Out of file handles (`ulimit -n 4`): the batch says so, it does not count scenes as bad.
#[test]
fn too_many_open_files_is_reported_as_that() {
    let tmp = dir("nofile");
    let d = tmp.path();
    let ds = generated(d, 4, 16, 12, 3);
    let out = d.join("out");
    let o = Command::new("sh")
        .arg("-c")
        .arg("ulimit -n 4; exec \"$0\" batch \"$1\" --out \"$2\"")
        .arg(env!("CARGO_BIN_EXE_cylaov"))
        .args([s(&ds), s(&out)])
        .output()
        .unwrap();
    let (so, se) = (stdout(&o), stderr(&o));
    assert_eq!(o.status.code(), Some(1), "{so}\n{se}");
    assert!(se.contains("too many open files (ulimit -n)"), "{so}\n{se}");
    assert!(temps(&out).is_empty());
}

/// A SIGINT that arrives while a render's files are being renamed into place waits for the
/// renames (they run under the clean-up's lock): the files are all the new render's, never
/// a new camera file beside the previous render's EXR. `SLOW_COMMIT` spaces the renames
/// 0.3 s apart; the signal goes once the first new file is in place.
#[test]
fn a_signal_during_the_commit_leaves_all_files_new() {
    let tmp = dir("commit-signal");
    let d = tmp.path();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let (old, new) = (scenes.join("single.json"), scenes.join("cluster.json"));
    let render = |scene: &Path, out: &Path| {
        let o = exe()
            .args(["render", s(scene), "-o", s(out), "--depth-png"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
    };
    // What the new render writes, for comparison.
    let reference = d.join("reference");
    render(&new, &reference.join("v.exr"));
    let out = d.join("out");
    render(&old, &out.join("v.exr"));
    let names = ["v.exr", "v.camera.json", "v.open3d.json", "v.depth.png"];
    let read = |dir: &Path, n: &str| std::fs::read(dir.join(n)).unwrap();
    let old_camera = read(&out, "v.camera.json");
    let first_in_place = |_pid: u32| {
        names[1..]
            .iter()
            .any(|n| std::fs::read(out.join(n)).is_ok_and(|b| b == read(&reference, n)))
    };
    let o = signal_when(
        &[
            "render",
            s(&new),
            "-o",
            s(&out.join("v.exr")),
            "--depth-png",
        ],
        libc::SIGINT,
        &first_in_place,
        &[("CYLAOV_FAIL_WRITES", Path::new("SLOW_COMMIT"))],
    );
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    assert_ne!(old_camera, read(&reference, "v.camera.json"));
    let old_files: Vec<&str> = names
        .iter()
        .copied()
        .filter(|n| read(&out, n) != read(&reference, n))
        .collect();
    assert!(old_files.is_empty(), "not the new render's: {old_files:?}");
    assert!(temps(&out).is_empty(), "{:?}", temps(&out));
}

/// A batch whose `OUT/.partial` cannot be made (a folder it may not write to) says so and
/// exits 1 at once, in both formats; it never waits on itself. Run as an unprivileged user
/// (`setpriv` to `nobody` when the tests run as root, for whom every folder is writable),
/// with the binary and the scenes copied where that user can read them.
#[test]
fn a_batch_that_cannot_make_its_work_folder_fails_at_once() {
    let tmp = dir("no-partial");
    let d = tmp.path();
    let ds = generated(d, 2, 32, 24, 5);
    let bin = d.join("cylaov");
    std::fs::copy(env!("CARGO_BIN_EXE_cylaov"), &bin).unwrap();
    let out = d.join("out");
    std::fs::create_dir(&out).unwrap();
    let chmod = |mode: &str, p: &Path| {
        let st = Command::new("chmod")
            .args(["-R", mode, s(p)])
            .status()
            .unwrap();
        assert!(st.success());
    };
    chmod("a+rX", d);
    chmod("a-w", &out);
    // SAFETY: geteuid has no preconditions and cannot fail.
    let root = unsafe { libc::geteuid() } == 0;
    for format in ["files", "webdataset"] {
        let mut cmd = if root {
            let mut c = Command::new("setpriv");
            c.args(["--reuid=65534", "--regid=65534", "--clear-groups"])
                .arg(&bin);
            c
        } else {
            Command::new(&bin)
        };
        let child = cmd
            .args(["batch", s(&ds), "--out", s(&out), "--format", format])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let o = wait_bounded(
            child,
            30,
            &format!("batch --format {format} into a read-only folder"),
        );
        assert_eq!(o.status.code(), Some(1), "{format}: {}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!("creating {}", out.join(".partial").display()))
                && stderr(&o).contains("Permission denied"),
            "{format}: {}",
            stderr(&o)
        );
    }
    chmod("u+w", &out);
}
