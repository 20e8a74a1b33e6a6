//! Helpers shared by the integration tests (each test file uses some of them).
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The reference venv's Python (`$CYLAOV_VENV`, else `.venv`, as `scripts/setup-venv`
/// makes it). `None` (the caller skips, saying so) when it is missing, unless
/// `CYLAOV_REQUIRE_VENV=1` (set by `scripts/test` once it has made the venv): then a missing
/// venv fails the test instead of letting CI pass without it.
pub fn venv_python() -> Option<PathBuf> {
    let venv = std::env::var_os("CYLAOV_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv"));
    let py = venv.join("bin/python");
    if py.exists() {
        return Some(py);
    }
    assert!(
        std::env::var("CYLAOV_REQUIRE_VENV").as_deref() != Ok("1"),
        "CYLAOV_REQUIRE_VENV=1 but {} does not exist (run scripts/setup-venv)",
        py.display()
    );
    eprintln!("SKIPPED: no {} (run scripts/setup-venv)", py.display());
    None
}

/// A new, empty folder `cylaov-SUITE-NAME-RANDOM` in the temp dir, removed when the
/// returned guard drops (also when the test fails).
pub fn fresh_dir(suite: &str, name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("cylaov-{suite}-{name}-"))
        .tempdir()
        .unwrap()
}

/// A folder shared by the tests of one test binary, in Cargo's scratch space for
/// integration tests (`target/tmp`), emptied when the binary first asks for it: a static
/// `TempDir` would never be dropped, and this leaves at most one folder per suite.
pub fn shared_dir(suite: &str) -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("cylaov-{suite}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    })
}

/// Run the cylaov binary without the scheduler variables a batch reads its shard from.
pub fn cylaov(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX")
        .output()
        .unwrap()
}

/// [`cylaov`], which must succeed; its stdout.
pub fn ok(args: &[&str]) -> String {
    let out = cylaov(args);
    assert!(
        out.status.success(),
        "cylaov {args:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Distance from `p` to the surface of a finite cylinder: the tube for axial coordinate
/// in [0, h], plus the two cap disks when it has caps.
pub fn distance_to_surface(c: &cylaov::geometry::Cylinder, p: glam::DVec3) -> f64 {
    let v = p - c.base;
    let a = v.dot(c.axis);
    let rho = (v - c.axis * a).length();
    let tube = ((rho - c.radius).powi(2) + (a - a.clamp(0.0, c.height)).powi(2)).sqrt();
    if !c.caps {
        return tube;
    }
    let outside = (rho - c.radius).max(0.0);
    let disk = |a0: f64| ((a - a0).powi(2) + outside.powi(2)).sqrt();
    tube.min(disk(0.0)).min(disk(c.height))
}

/// An N x 3 little-endian float64 `.npy` (C order), as numpy's `np.save` writes one.
pub fn read_npy(path: &Path) -> Vec<glam::DVec3> {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..6], b"\x93NUMPY");
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(&bytes[10..10 + header_len]).unwrap();
    assert!(
        header.contains("'descr': '<f8'") && header.contains("'fortran_order': False"),
        "{header}"
    );
    bytes[10 + header_len..]
        .chunks_exact(24)
        .map(|c| {
            let f = |k: usize| f64::from_le_bytes(c[8 * k..8 * k + 8].try_into().unwrap());
            glam::DVec3::new(f(0), f(1), f(2))
        })
        .collect()
}

/// Every file under `dir` (relative path → bytes).
pub fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}
