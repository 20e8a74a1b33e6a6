//! batch never destroys what it does not own, through the binary: a symlinked
//! `OUT/.partial` is refused (not followed), two batches on one shard cannot clear each
//! other's work (a per-shard lock naming the holder), and a folder scan skips cylaov's own
//! outputs, the `--out` folder, dangling links, linked folders and special files, saying so.

mod common;
use common::cylaov;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn fresh_dir(name: &str) -> tempfile::TempDir {
    common::fresh_dir("files", name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn generate(out: &Path, count: &str, extra: &[&str]) {
    let mut args = vec!["generate", "--count", count, "--seed", "2", "--out", s(out)];
    args.extend_from_slice(extra);
    let o = cylaov(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Every file under `dir`, relative.
fn files(dir: &Path) -> Vec<String> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                out.push(p.strip_prefix(root).unwrap().to_string_lossy().into_owned());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

#[test]
fn a_symlinked_partial_folder_is_refused_not_followed() {
    let tmp = fresh_dir("partial");
    let dir = tmp.path();
    let data = dir.join("data");
    generate(&data, "2", &["--width", "32", "--height", "24"]);
    let victim = dir.join("victim");
    std::fs::create_dir_all(victim.join("0-of-1")).unwrap();
    std::fs::write(victim.join("0-of-1/keep.txt"), "mine").unwrap();
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    std::os::unix::fs::symlink(&victim, out.join(".partial")).unwrap();
    let o = cylaov(&["batch", s(&data), "--out", s(&out)]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(".partial is a symbolic link") && err.contains("real folder inside --out"),
        "{err}"
    );
    assert_eq!(
        files(&victim),
        vec!["0-of-1/keep.txt"],
        "the link's target was touched"
    );
    assert!(!out.join("000000.exr").exists());
    // With the link gone the batch runs, and leaves no partial folder behind.
    std::fs::remove_file(out.join(".partial")).unwrap();
    let o = cylaov(&["batch", s(&data), "--out", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!out.join(".partial").exists());
}

/// Two batches on the same shard into one --out: the second fails at once, naming the
/// first's host and pid; the first finishes with every view done.
#[test]
fn a_second_batch_on_the_same_shard_fails_at_once() {
    let tmp = fresh_dir("lock");
    let dir = tmp.path();
    let data = dir.join("data");
    // Slow enough on one thread that the second starts while the first runs.
    generate(&data, "60", &["--cylinders", "200"]);
    let out = dir.join("out");
    let mut first = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(["batch", s(&data), "--out", s(&out), "--threads", "1"])
        .env_remove("SLURM_ARRAY_TASK_ID")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let lock = out.join(".partial/0-of-1.lock");
    let t0 = Instant::now();
    while !std::fs::read_to_string(&lock).is_ok_and(|t| t.contains("pid"))
        && t0.elapsed() < Duration::from_secs(30)
    {
        std::thread::sleep(Duration::from_millis(2));
    }
    let t1 = Instant::now();
    let second = cylaov(&["batch", s(&data), "--out", s(&out)]);
    let waited = t1.elapsed();
    assert!(
        first.try_wait().unwrap().is_none(),
        "the first batch ended before the second started: make it slower"
    );
    assert!(!second.status.success());
    let err = String::from_utf8_lossy(&second.stderr);
    let want = format!(
        "another batch is writing shard 0 of 1 in {} (host ",
        out.display()
    );
    assert!(err.contains(&want), "{err}");
    assert!(err.contains(&format!("pid {})", first.id())), "{err}");
    // "At once": it did not render the 60 views (which takes the first several seconds).
    assert!(waited < Duration::from_secs(5), "{waited:?}");
    let status = first.wait().unwrap();
    let mut stdout = String::new();
    std::io::Read::read_to_string(&mut first.stdout.take().unwrap(), &mut stdout).unwrap();
    assert!(status.success(), "{stdout}");
    assert!(
        stdout.contains("done 60 / skipped 0 / failed 0"),
        "{stdout}"
    );
    assert!(
        !out.join(".partial").exists(),
        "lock and partial folder removed"
    );
}

/// A folder holding an earlier batch's outputs, a dangling link, a linked folder and a FIFO
/// named like a scene: only the scenes are read, and the skipped entries are reported.
#[test]
fn folder_scans_skip_outputs_links_and_special_files_and_say_so() {
    let tmp = fresh_dir("scan");
    let dir = tmp.path();
    let data = dir.join("data");
    generate(&data, "3", &["--width", "32", "--height", "24"]);
    let input = data.join("scenes");
    // An earlier batch's outputs inside the input (its --out excluded it then).
    let o = cylaov(&["batch", s(&input), "--out", s(&input.join("render"))]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::os::unix::fs::symlink(dir.join("nowhere.json"), input.join("gone.json")).unwrap();
    std::os::unix::fs::symlink(&data, input.join("loop")).unwrap();
    let fifo = input.join("pipe.json");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());

    let out = dir.join("out");
    let o = cylaov(&["batch", s(&input), "--out", s(&out)]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stdout}\n{err}");
    assert!(
        stdout.contains("done 3 / skipped 0 / failed 0 of 3 views"),
        "{stdout}"
    );
    // render/: 3 camera, 3 open3d, 3 stamps and index.json.
    assert!(err.contains("10 of cylaov's own output files"), "{err}");
    assert!(err.contains("1 dangling symbolic links"), "{err}");
    assert!(
        err.contains("1 symbolic links to folders, not followed"),
        "{err}"
    );
    assert!(err.contains("1 special files"), "{err}");
}
