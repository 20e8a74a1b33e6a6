//! The layers stay apart: `output` (files and pictures) never reaches into `accel` (how
//! rays find cylinders), and `verify` (the check against Mitsuba) never calls up into
//! `commands` (the CLI). A lower layer that imports a higher one makes every change to the
//! higher one a change to the lower one's tests.

use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// Every `.rs` file under `dir`, recursively.
fn sources(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The lines of the sources under `src/<layer>` (and `src/<layer>.rs`) that name
/// `crate::<forbidden>`, as `path:line: text`.
fn uses(layer: &str, forbidden: &str) -> Vec<String> {
    let src = Path::new(ROOT).join("src");
    let mut files = sources(&src.join(layer));
    let flat = src.join(format!("{layer}.rs"));
    if flat.is_file() {
        files.push(flat);
    }
    assert!(!files.is_empty(), "no sources under src/{layer}");
    let needle = format!("crate::{forbidden}");
    let mut hits = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        for (k, l) in text.lines().enumerate() {
            if l.contains(&needle) {
                let rel = f.strip_prefix(ROOT).unwrap_or(&f).display().to_string();
                hits.push(format!("{rel}:{}: {}", k + 1, l.trim()));
            }
        }
    }
    hits
}

#[test]
fn output_never_imports_accel() {
    let hits = uses("output", "accel");
    assert!(
        hits.is_empty(),
        "output reaches into accel:\n{}",
        hits.join("\n")
    );
}

#[test]
fn verify_never_imports_commands() {
    let hits = uses("verify", "commands");
    assert!(
        hits.is_empty(),
        "verify calls up into commands:\n{}",
        hits.join("\n")
    );
}

/// The scan finds what it looks for: the CLI's own sources name `crate::` paths of the
/// library (`main.rs` is outside `src/commands`, so `commands` itself is the probe).
#[test]
fn the_scan_sees_imports() {
    assert!(!uses("commands", "output").is_empty());
    assert!(!uses("render", "accel").is_empty());
}
