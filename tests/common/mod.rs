//! Helpers shared by the integration tests (each test file uses some of them).
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The reference venv's Python (`$CYLAOV_VENV`, else `.venv`, as `scripts/setup-venv`
/// makes it). `None` (the caller skips, saying so) when it is missing, unless
/// `CYLAOV_REQUIRE_VENV=1` (set by `scripts/test` once it has made the venv) or `CI=true`:
/// then a missing venv fails the test instead of letting CI pass without it.
pub fn venv_python() -> Option<PathBuf> {
    let venv = std::env::var_os("CYLAOV_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv"));
    let py = venv.join("bin/python");
    if py.exists() {
        return Some(py);
    }
    assert!(
        std::env::var("CYLAOV_REQUIRE_VENV").as_deref() != Ok("1")
            && std::env::var("CI").as_deref() != Ok("true"),
        "CYLAOV_REQUIRE_VENV=1 or CI=true, but {} does not exist (run scripts/setup-venv)",
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

/// `cylaov ARGS` with the venv of `python` (`.../bin/python`) as its Mitsuba.
pub fn cylaov_with_venv(python: &Path, args: &[&str]) -> Output {
    let venv = python.parent().and_then(Path::parent).expect("venv dir");
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .env("CYLAOV_VENV", venv)
        .output()
        .expect("running cylaov")
}

/// A run's stdout then stderr, as one text.
pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
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

/// The scene the camera-model tests render: a closed tube of radius 6 around the camera
/// (every ray of every model hits its inner wall or a cap) with a ring of twelve closed
/// cylinders inside it and a crossbar (hits at many depths, angles and parts), seen by a
/// 64×48 camera at `[0.2, -0.4, 0.3]` looking at `[1, 3, 0]` with `model`'s fields
/// (`{"model": "opencv", "fx": ...}`) merged into it.
pub fn lens_test_scene(model: &serde_json::Value) -> serde_json::Value {
    use serde_json::json;
    let mut cyl = vec![json!({
        "p0": [0, 0, -4], "p1": [0, 0, 4], "radius": 6, "id": 100
    })];
    for k in 0..12 {
        let a = std::f64::consts::TAU * k as f64 / 12.0;
        let (s, c) = a.sin_cos();
        cyl.push(json!({
            "p0": [3.0 * c, 3.0 * s, -1.5 + 0.1 * k as f64],
            "p1": [3.0 * c, 3.0 * s, 1.0 + 0.1 * k as f64],
            "radius": 0.35 + 0.03 * k as f64,
            "id": k + 1
        }));
    }
    cyl.push(json!({"p0": [-2, 1.2, 0.6], "p1": [2, 1.5, 0.4], "radius": 0.25, "id": 50}));
    let mut cam = json!({
        "origin": [0.2, -0.4, 0.3], "target": [1.0, 3.0, 0.0], "up": [0, 0, 1],
        "width": 64, "height": 48, "near_clip": 0.01
    });
    if let Some(fields) = model.as_object() {
        for (k, v) in fields {
            cam[k] = v.clone();
        }
    }
    json!({"camera": cam, "cylinders": cyl})
}

/// The lens models with the parameters the camera-model tests use: `(name, fields)`.
pub fn lens_models() -> [(&'static str, serde_json::Value); 3] {
    use serde_json::json;
    [
        (
            "opencv",
            json!({"model": "opencv", "fx": 40, "fy": 42, "cx": 31.2, "cy": 23.7,
                "k1": -0.21, "k2": 0.04, "p1": 0.0012, "p2": -0.0017, "k3": 0.005}),
        ),
        (
            "opencv_fisheye",
            // fx = 18 on 64 px: the corners ask for θ_d = 2.2, rays about 125° off the axis.
            json!({"model": "opencv_fisheye", "fx": 18, "fy": 18.5, "cx": 31.6,
                "cy": 23.4, "k1": 0.03, "k2": -0.004, "k3": 0.0006, "k4": -0.00003}),
        ),
        ("equirectangular", json!({"model": "equirectangular"})),
    ]
}
