//! File output that never leaves a half-written file, and the camera metadata JSON.

use crate::scene::Aov;
use crate::scene::camera::{Camera, rows};
use serde::Serialize;
use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// The temporary name used while `path` is written: `.NAME.HOST.PID.NONCE.tmp` in the same
/// folder, so the rename is atomic. Hidden and ending in `.tmp` (SPEC §7). Distinct for
/// every call: the host (`/proc/sys/kernel/hostname`, else `$HOSTNAME`; shards on different
/// nodes of a shared filesystem can have equal PIDs), the PID, and a nonce made of a
/// per-process value (the start time, taken once) and a per-call counter (two threads, or
/// two writes of one path, never share a name).
pub fn temp_path(path: &Path) -> PathBuf {
    use std::sync::OnceLock;
    use std::sync::atomic::{AtomicU64, Ordering};
    static PROCESS: OnceLock<(String, u64)> = OnceLock::new();
    static CALLS: AtomicU64 = AtomicU64::new(0);
    let (host, start) = PROCESS.get_or_init(|| {
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .ok()
            .or_else(|| std::env::var("HOSTNAME").ok())
            .unwrap_or_default();
        // File-name safe and short: a long name must still fit NAME_MAX with the rest.
        let mut host: String = host
            .trim()
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '.')
            .take(16)
            .collect();
        if host.is_empty() {
            host.push_str("host");
        }
        let start = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64);
        (host, start)
    });
    let call = CALLS.fetch_add(1, Ordering::Relaxed);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(
        ".{name}.{host}.{}.{start:x}-{call}.tmp",
        std::process::id()
    ))
}

/// Write `path` through `fill` into a temporary file, then rename it into place. On any
/// error the temporary file is removed and `path` is untouched. A killed process leaves at
/// most a `.tmp` file, never a partial `path`. No fsync: that guards against power loss,
/// not process death, and costs more than encoding a 1080p EXR.
pub fn atomic_write(path: &Path, fill: impl FnOnce(&mut File) -> io::Result<()>) -> io::Result<()> {
    stage(path, fill)?.commit()
}

/// A file written under its temporary name and not yet renamed into place: a command that
/// writes several files stages them all, then commits them, so a failure half-way leaves
/// none of them behind. Dropped uncommitted, the temporary file is removed.
#[must_use = "a staged file is removed unless committed"]
pub struct Staged {
    tmp: PathBuf,
    path: PathBuf,
}

/// Write `path`'s content through `fill` to its temporary name (see [`Staged`]).
pub fn stage(path: &Path, fill: impl FnOnce(&mut File) -> io::Result<()>) -> io::Result<Staged> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    let staged = Staged {
        tmp: temp_path(path),
        path: path.to_path_buf(),
    };
    let mut f = File::create(&staged.tmp)?;
    fill(&mut f)?;
    f.flush()?;
    Ok(staged)
}

impl Staged {
    /// Rename the file into place.
    pub fn commit(self) -> io::Result<()> {
        std::fs::rename(&self.tmp, &self.path)?;
        std::mem::forget(self);
        Ok(())
    }
}

/// Commit staged files together: none is renamed while any destination is a folder, and
/// if a rename still fails, the files this call already put in place are removed again.
pub fn commit_all(staged: Vec<Staged>) -> io::Result<()> {
    if let Some(s) = staged.iter().find(|s| s.path.is_dir()) {
        return Err(io::Error::other(format!(
            "{} is a folder",
            s.path.display()
        )));
    }
    let mut done: Vec<PathBuf> = Vec::new();
    for s in staged {
        let path = s.path.clone();
        if let Err(e) = s.commit() {
            for p in &done {
                let _ = std::fs::remove_file(p);
            }
            return Err(io::Error::other(format!("{}: {e}", path.display())));
        }
        done.push(path);
    }
    Ok(())
}

impl Drop for Staged {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.tmp);
    }
}

/// Write bytes atomically.
pub fn atomic_write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    atomic_write(path, |f| f.write_all(bytes))
}

/// Where `render -o OUT.exr` puts the camera metadata: `OUT.camera.json` (SPEC §7).
pub fn camera_json_path(exr: &Path) -> PathBuf {
    exr.with_extension("camera.json")
}

#[derive(Serialize)]
struct AovMeaning {
    name: &'static str,
    channels: &'static [&'static str],
    meaning: &'static str,
    miss: &'static str,
}

#[derive(Serialize)]
struct CameraMeta {
    width: u32,
    height: u32,
    fov_deg: f64,
    fov_axis: &'static str,
    near_clip: f64,
    far_clip: f64,
    /// Intrinsics in pixels, row-major, pixel centres at `i + 0.5`.
    #[serde(rename = "K")]
    k: [[f64; 3]; 3],
    principal_point_note: &'static str,
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
    /// The same intrinsics with pixel centres at integers.
    #[serde(rename = "K_opencv")]
    k_opencv: [[f64; 3]; 3],
    principal_point_note_opencv: &'static str,
    cx_opencv: f64,
    cy_opencv: f64,
    camera_to_world_opencv: [[f64; 4]; 4],
    world_to_camera_opencv: [[f64; 4]; 4],
    camera_to_world_opengl: [[f64; 4]; 4],
    world_to_camera_opengl: [[f64; 4]; 4],
    conventions: &'static str,
    aovs: Vec<AovMeaning>,
}

/// What an AOV means, for the metadata file (SPEC §4).
pub fn aov_meaning(aov: Aov) -> (&'static str, &'static str) {
    match aov {
        Aov::Distance => (
            "Euclidean distance from the camera origin to the hit, world units",
            "0",
        ),
        Aov::Depth => (
            "planar depth: camera-space z of the hit (distance * cos theta), world units",
            "0",
        ),
        Aov::Normal => (
            "world-space unit outward normal, not flipped toward the camera",
            "[0,0,0]",
        ),
        Aov::Position => ("world-space hit point", "[0,0,0]"),
        Aov::NormalCamera => (
            "camera-space unit outward normal, OpenCV axes (x right, y down, z forward), not flipped toward the camera",
            "[0,0,0]",
        ),
        Aov::ShapeId => (
            "u32 id of the hit cylinder (scene 'id', default 1-based index)",
            "0",
        ),
    }
}

/// The camera metadata JSON for a render: intrinsics, both pose conventions, AOV meanings.
pub fn camera_json(cam: &Camera, aovs: &[Aov]) -> String {
    let (fx, fy) = cam.focal_px();
    let k = cam.k_matrix();
    let k_cv = cam.k_matrix_opencv();
    let cv = cam.world_from_camera_opencv();
    let gl = cam.world_from_camera_opengl();
    let meta = CameraMeta {
        width: cam.width(),
        height: cam.height(),
        fov_deg: cam.spec.fov_deg,
        fov_axis: cam.spec.fov_axis.name(),
        near_clip: cam.spec.near_clip,
        far_clip: cam.spec.far_clip,
        k,
        principal_point_note: "K, cx, cy: cx = W/2, cy = H/2, pixel (i, j) has its centre at (i + 0.5, j + 0.5): nerfstudio, Mitsuba",
        fl_x: fx,
        fl_y: fy,
        cx: k[0][2],
        cy: k[1][2],
        k_opencv: k_cv,
        principal_point_note_opencv: "K_opencv, cx_opencv, cy_opencv: cx = W/2 - 0.5, cy = H/2 - 0.5, pixel (i, j) has its centre at (i, j): OpenCV, Open3D, COLMAP",
        cx_opencv: k_cv[0][2],
        cy_opencv: k_cv[1][2],
        camera_to_world_opencv: rows(cv),
        world_to_camera_opencv: rows(cv.inverse()),
        camera_to_world_opengl: rows(gl),
        world_to_camera_opengl: rows(gl.inverse()),
        conventions: "OpenCV camera axes: x right, y down, z forward. OpenGL: x right, y up, z backward. Matrices row-major; image row 0 is the top row.",
        aovs: aovs
            .iter()
            .map(|&a| {
                let (meaning, miss) = aov_meaning(a);
                AovMeaning {
                    name: a.name(),
                    channels: crate::output::aov::channel_names(a),
                    meaning,
                    miss,
                }
            })
            .collect(),
    };
    let mut s = serde_json::to_string_pretty(&meta).unwrap_or_default();
    s.push('\n');
    s
}

/// Open3D's `PinholeCameraParameters` file (`NAME.open3d.json`), which
/// `o3d.io.read_pinhole_camera_parameters` loads as it is: the intrinsic matrix with the
/// integer-centre principal point (`W/2 - 0.5`) and the extrinsic world-to-camera in OpenCV
/// axes (x right, y down, z forward), both column-major as Open3D (Eigen) stores them.
pub fn open3d_json(cam: &Camera) -> String {
    #[derive(Serialize)]
    struct Intrinsic {
        width: u32,
        height: u32,
        intrinsic_matrix: [f64; 9],
    }
    #[derive(Serialize)]
    struct Params {
        class_name: &'static str,
        version_major: u32,
        version_minor: u32,
        intrinsic: Intrinsic,
        extrinsic: [f64; 16],
    }
    let k = cam.k_matrix_opencv();
    let mut k_cols = [0.0; 9];
    for (c, col) in k_cols.chunks_exact_mut(3).enumerate() {
        for (r, x) in col.iter_mut().enumerate() {
            *x = k[r][c];
        }
    }
    let params = Params {
        class_name: "PinholeCameraParameters",
        version_major: 1,
        version_minor: 0,
        intrinsic: Intrinsic {
            width: cam.width(),
            height: cam.height(),
            intrinsic_matrix: k_cols,
        },
        // glam matrices are column-major already.
        extrinsic: cam.world_from_camera_opencv().inverse().to_cols_array(),
    };
    let mut s = serde_json::to_string_pretty(&params).unwrap_or_default();
    s.push('\n');
    s
}

/// Peak resident memory of this process in MiB (Linux `VmHWM`), if the OS tells.
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}
