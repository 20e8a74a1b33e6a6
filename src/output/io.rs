//! File output that never leaves a half-written file, never replaces what it does not own,
//! and fails before allocating what the machine cannot hold; console output that survives a
//! closed pipe; and the camera metadata JSON.
//!
//! Every command checks its output targets with [`check_outputs`] before it reads or
//! computes anything, so a refused target costs nothing and leaves nothing behind.

use super::files::{kind_name, system_folder};
use super::signals::{self, Cleanup, Registration};
use crate::scene::Aov;
use crate::scene::camera::{Camera, rows};
use serde::Serialize;
use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// The start of the temporary name used while `path` is written: `.NAME.HOST.PID.`, to
/// which [`stage`] adds random characters and `.tmp`, in the same folder so the rename is
/// atomic. Hidden and ending in `.tmp`, the suffix every work-in-progress file of cylaov
/// carries; the host (`/proc/sys/kernel/hostname`, else `$HOSTNAME`) and PID say who left a
/// file behind (shards on different nodes of a shared filesystem can have equal PIDs).
/// `NAME` is shortened (at a character boundary) when the whole would pass the 255-byte
/// file name limit: any output name the file system accepts also has a temporary name it
/// accepts.
fn temp_prefix(path: &Path) -> String {
    let host = temp_host();
    let mut name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tail = format!(".{host}.{}.", std::process::id());
    // One byte for the leading dot, the random part and `.tmp`; the tail is at most ~30 bytes.
    let room = NAME_MAX.saturating_sub(1 + tail.len() + TEMP_RANDOM + ".tmp".len());
    if name.len() > room {
        let mut cut = room;
        while !name.is_char_boundary(cut) {
            cut -= 1;
        }
        name.truncate(cut);
    }
    format!(".{name}{tail}")
}

/// The host part of a temporary name (see [`temp_prefix`]).
fn temp_host() -> &'static str {
    use std::sync::OnceLock;
    static HOST: OnceLock<String> = OnceLock::new();
    HOST.get_or_init(|| {
        let host = hostname()
            .or_else(|| std::env::var("HOSTNAME").ok())
            .unwrap_or_default();
        // File-name safe and short: a long name must still fit NAME_MAX with the rest.
        let host: String = host
            .trim()
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '.')
            .take(16)
            .collect();
        if host.is_empty() { "host".into() } else { host }
    })
}

/// This machine's name (`gethostname`, which needs no file handle: a run out of them
/// still names its temporary files like every other run of this host).
#[cfg(target_os = "linux")]
fn hostname() -> Option<String> {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most `buf.len()` bytes into the buffer it is given.
    if unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } != 0 {
        return None;
    }
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    Some(String::from_utf8_lossy(&buf[..end]).into_owned())
}

#[cfg(not(target_os = "linux"))]
fn hostname() -> Option<String> {
    std::fs::read_to_string("/proc/sys/kernel/hostname").ok()
}

/// Random characters in a temporary name; with exclusive creation (`O_EXCL`, retried by
/// `tempfile` on a clash) two threads, two processes or two nodes never share one.
const TEMP_RANDOM: usize = 8;

/// The longest file name (one path component, in bytes) of Linux file systems.
const NAME_MAX: usize = 255;

/// The identity of an existing file, through links: (device, inode).
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

fn refuse(flag: &str, path: &Path, why: String) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{flag} {}: {why}", path.display()),
    )
}

/// Check one output target before anything is written: it may be missing or a regular file,
/// but not a device, FIFO, socket, folder or symbolic link: the write goes to a temporary
/// file that is renamed over the target, which would replace `/dev/null` itself or the
/// user's link (writing through it instead would change a file the link's owner may not
/// expect to change), and sidecar files would litter the device's folder. Nothing is
/// created inside `/dev`, `/proc` or `/sys`, however the path gets there (folders on the
/// way may be links). Nor may the target be any of `inputs` (compared by device and inode,
/// so hard and symbolic links count). The existing part of its folder path must be
/// folders. `flag` names the option in the message (`-o`, `--heatmap`, ...).
pub fn check_output(flag: &str, path: &Path, inputs: &[&Path]) -> io::Result<()> {
    if path.as_os_str().is_empty() {
        return Err(refuse(flag, path, "empty path".into()));
    }
    if let Some(name) = path.file_name()
        && name.len() > NAME_MAX
    {
        return Err(refuse(
            flag,
            path,
            format!("file name is {} bytes, the limit is {NAME_MAX}", name.len()),
        ));
    }
    if let Some(root) = system_folder(path, false) {
        return Err(refuse(flag, path, system_refusal(root)));
    }
    match std::fs::symlink_metadata(path) {
        Ok(link) => {
            let id = file_id(path);
            for input in inputs {
                if id.is_some() && file_id(input) == id {
                    return Err(refuse(
                        flag,
                        path,
                        format!("would overwrite the input {}", input.display()),
                    ));
                }
            }
            if link.file_type().is_symlink() {
                let to = match std::fs::metadata(path) {
                    Ok(m) => kind_name(m.file_type()),
                    Err(_) => "nothing",
                };
                return Err(refuse(
                    flag,
                    path,
                    format!(
                        "is a symbolic link (to {to}), not a regular file: cylaov neither \
                         replaces a link nor writes through one; give the path it points to \
                         or another name"
                    ),
                ));
            }
            if !link.is_file() {
                return Err(refuse(
                    flag,
                    path,
                    format!(
                        "is {}, not a regular file; refusing to replace it",
                        kind_name(link.file_type())
                    ),
                ));
            }
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound || e.raw_os_error() == Some(20) => {
            check_folders(flag, path)?
        }
        Err(e) => return Err(refuse(flag, path, e.to_string())),
    }
    Ok(())
}

/// Why nothing is written under `root`, one of the system folders.
fn system_refusal(root: &str) -> String {
    format!(
        "is inside {root}: cylaov never creates or renames files in /dev, /proc or /sys \
         (write to a regular file and copy it from there)"
    )
}

/// The nearest existing ancestor of a missing `path` must be a folder (else creating the
/// folders says only "File exists" or "Not a directory").
fn check_folders(flag: &str, path: &Path) -> io::Result<()> {
    for dir in path.ancestors().skip(1) {
        if dir.as_os_str().is_empty() {
            return Ok(());
        }
        match std::fs::metadata(dir) {
            Ok(m) if m.is_dir() => return Ok(()),
            Ok(m) => {
                return Err(refuse(
                    flag,
                    path,
                    format!(
                        "{} is {}, not a folder",
                        dir.display(),
                        kind_name(m.file_type())
                    ),
                ));
            }
            // Missing, or below a file (ENOTDIR): look further up.
            Err(e) if e.kind() == io::ErrorKind::NotFound || e.raw_os_error() == Some(20) => {
                continue;
            }
            Err(e) => return Err(refuse(flag, path, format!("{}: {e}", dir.display()))),
        }
    }
    Ok(())
}

/// [`check_output`] for every `(flag, path)` of a command; also refuses two outputs that are
/// one file (the second would silently replace the first).
pub fn check_outputs(outputs: &[(&str, &Path)], inputs: &[&Path]) -> io::Result<()> {
    for (i, (flag, path)) in outputs.iter().enumerate() {
        check_output(flag, path, inputs)?;
        for (flag2, other) in &outputs[..i] {
            if same_target(path, other) {
                return Err(refuse(
                    flag,
                    path,
                    format!("is also the {flag2} output {}", other.display()),
                ));
            }
        }
    }
    Ok(())
}

/// Two output paths that name one file: equal identities if both exist, else equal after
/// resolving their folders.
fn same_target(a: &Path, b: &Path) -> bool {
    if let (Some(x), Some(y)) = (file_id(a), file_id(b)) {
        return x == y;
    }
    let resolve = |p: &Path| -> Option<PathBuf> {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        Some(dir.canonicalize().ok()?.join(p.file_name()?))
    };
    match (resolve(a), resolve(b)) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}

/// Check that a folder target (`--preview DIR`) is a folder or can be made one.
pub fn check_output_dir(flag: &str, dir: &Path) -> io::Result<()> {
    let system = || match system_folder(dir, true) {
        Some(root) => Err(refuse(flag, dir, system_refusal(root))),
        None => Ok(()),
    };
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => system(),
        Ok(m) => Err(refuse(
            flag,
            dir,
            format!("is {}, not a folder", kind_name(m.file_type())),
        )),
        Err(e) if e.kind() == io::ErrorKind::NotFound || e.raw_os_error() == Some(20) => {
            system()?;
            check_folders(flag, dir)
        }
        Err(e) => Err(refuse(flag, dir, e.to_string())),
    }
}

/// The folders a command created, removed again (innermost first, where empty) when it is
/// dropped before [`NewDirs::keep`]: a failed `-o new/sub/x.exr` leaves no `new/`.
#[derive(Default)]
#[must_use = "the folders are removed when this is dropped without keep()"]
pub struct NewDirs {
    made: Vec<PathBuf>,
    /// Each made folder is also removed (if empty) by a signal's clean-up.
    registered: Vec<Registration>,
}

impl NewDirs {
    /// Create `dir` and its missing parents, remembering the ones this call made.
    pub fn create(&mut self, dir: &Path) -> io::Result<()> {
        let mut missing: Vec<PathBuf> = Vec::new();
        for d in dir.ancestors() {
            if d.as_os_str().is_empty() || d.exists() {
                break;
            }
            missing.push(d.to_path_buf());
        }
        std::fs::create_dir_all(dir).map_err(explain)?;
        for d in missing.into_iter().rev() {
            self.registered
                .push(signals::register(Cleanup::EmptyDir, &d));
            self.made.push(d);
        }
        Ok(())
    }

    /// [`NewDirs::create`] for the parent folder of a file target, if it has one.
    pub fn create_parent(&mut self, file: &Path) -> io::Result<()> {
        match file.parent() {
            Some(d) if !d.as_os_str().is_empty() => self.create(d),
            _ => Ok(()),
        }
    }

    /// Whether any folder was made (the target is new: what the command wrote in it is all
    /// its own).
    pub fn made_any(&self) -> bool {
        !self.made.is_empty()
    }

    /// The command succeeded: keep every folder.
    pub fn keep(mut self) {
        self.made.clear();
        self.registered.clear();
    }
}

impl Drop for NewDirs {
    fn drop(&mut self) {
        for d in self.made.iter().rev() {
            let _ = std::fs::remove_dir(d);
        }
    }
}

/// Add the advice a person needs to an IO error: a full disk, the file size limit and
/// the open-file limit say so.
pub fn explain(e: io::Error) -> io::Error {
    let advice = match e.raw_os_error() {
        Some(28) => "the disk is full; free space and run again",
        Some(122) => "the disk quota is exceeded; free space and run again",
        Some(27) => "the file size limit is reached (ulimit -f); raise it and run again",
        Some(24) | Some(23) => {
            "too many open files (ulimit -n); raise the limit or use fewer --threads"
        }
        _ if e.kind() == io::ErrorKind::StorageFull => "the disk is full; free space and run again",
        _ => return e,
    };
    io::Error::new(e.kind(), format!("{e}: {advice}"))
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
/// none of them behind. Dropped uncommitted, the temporary file is removed (`tempfile`'s
/// `NamedTempFile`, which also created it exclusively).
#[must_use = "a staged file is removed unless committed"]
pub struct Staged {
    file: tempfile::NamedTempFile,
    path: PathBuf,
    /// Removed by a signal's clean-up until committed or dropped.
    _registered: Registration,
}

/// Write `path`'s content through `fill` to its temporary name (see [`Staged`]).
pub fn stage(path: &Path, fill: impl FnOnce(&mut File) -> io::Result<()>) -> io::Result<Staged> {
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(dir) => {
            std::fs::create_dir_all(dir)?;
            dir
        }
        None => Path::new("."),
    };
    // What runs killed outright (SIGKILL, a power cut) left here goes first.
    signals::sweep_once(dir, temp_host(), TEMP_RANDOM);
    let (mut file, registered) = signals::create_registered(
        Cleanup::File,
        || {
            tempfile::Builder::new()
                .prefix(&temp_prefix(path))
                .suffix(".tmp")
                .rand_bytes(TEMP_RANDOM)
                // The mode `File::create` gives (0666 less the umask), not tempfile's
                // private 0600: the renamed file is the user's output.
                .permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666))
                .tempfile_in(dir)
                .map_err(explain)
        },
        |f| f.path().to_path_buf(),
    )?;
    if let Some(errno) = injected_failure() {
        return Err(explain(io::Error::from_raw_os_error(errno)));
    }
    fill(file.as_file_mut()).map_err(explain)?;
    file.as_file_mut().flush().map_err(explain)?;
    Ok(Staged {
        file,
        path: path.to_path_buf(),
        _registered: registered,
    })
}

impl Staged {
    /// Where the content waits until [`Staged::commit`].
    pub fn temp_path(&self) -> &Path {
        self.file.path()
    }

    /// The temporary file, for a writer that fills it in place (positional writes).
    pub fn file(&self) -> &File {
        self.file.as_file()
    }

    /// Rename the file into place.
    pub fn commit(self) -> io::Result<()> {
        self.file.persist(&self.path).map_err(|e| e.error)?;
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

/// A write failure injected for tests: `CYLAOV_FAIL_WRITES=ENOSPC` makes every staged write
/// fail as a full disk would, after its temporary file was created (so the clean-up runs).
/// Read once; any other value is ignored.
fn injected_failure() -> Option<i32> {
    use std::sync::OnceLock;
    static FAIL: OnceLock<Option<i32>> = OnceLock::new();
    *FAIL.get_or_init(
        || match std::env::var("CYLAOV_FAIL_WRITES").ok()?.as_str() {
            "ENOSPC" => Some(28),
            _ => None,
        },
    )
}

/// Rows as CSV (the `csv` crate): the header from the row type's serde field names, so a
/// column's name and its value cannot drift apart; nothing at all for no rows.
pub fn csv_bytes<T: Serialize>(rows: impl IntoIterator<Item = T>) -> io::Result<Vec<u8>> {
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        w.serialize(r).map_err(io::Error::other)?;
    }
    w.into_inner().map_err(|e| io::Error::other(e.to_string()))
}

/// Write bytes atomically.
pub fn atomic_write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    atomic_write(path, |f| f.write_all(bytes))
}

/// Where `render -o OUT.exr` puts the camera metadata: `OUT.camera.json` (not `OUT.json`,
/// which could be the scene itself).
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

/// What an AOV means and its miss value, for the metadata file: its row of the AOV table
/// ([`crate::scene::aov::AOV_TABLE`]).
pub fn aov_meaning(aov: Aov) -> (&'static str, &'static str) {
    (aov.spec().meaning, aov.spec().miss)
}

/// Pretty JSON of one of cylaov's own records (camera metadata, stamps, indexes). They are
/// structs of numbers, strings and lists with string keys, which serde_json always serialises
/// (it fails only on non-string map keys or a failing custom `Serialize`), so a failure is a
/// bug in cylaov and is reported as one, never written as an empty file.
pub fn record_json(value: &impl serde::Serialize) -> String {
    serde_json::to_string_pretty(value).expect("cylaov's own records always serialise to JSON")
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
    let mut s = record_json(&meta);
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
    let mut s = record_json(&params);
    s.push('\n');
    s
}

// ---- console -----------------------------------------------------------------------------

static STDOUT_CLOSED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Print `text` and a newline on stdout. A closed pipe (the reader left, as `| head` does)
/// is not an error: this and every later line are dropped quietly, and the command finishes
/// with its own exit status, like other Unix tools. Any other failure (`> /dev/full`) is
/// returned, to be reported as an error. `println!` would panic in both cases.
pub fn say(text: &str) -> io::Result<()> {
    use std::sync::atomic::Ordering;
    if STDOUT_CLOSED.load(Ordering::Relaxed) {
        return Ok(());
    }
    let mut out = io::stdout().lock();
    match writeln!(out, "{text}").and_then(|()| out.flush()) {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => {
            STDOUT_CLOSED.store(true, Ordering::Relaxed);
            Ok(())
        }
        Err(e) => Err(io::Error::new(e.kind(), format!("writing to stdout: {e}"))),
        Ok(()) => Ok(()),
    }
}

/// Print `text` and a newline on stderr; a failure is ignored (there is nowhere left to
/// report it), where `eprintln!` would panic.
pub fn warn(text: &str) {
    let _ = writeln!(io::stderr().lock(), "{text}");
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The header comes from the field names; an absent value is an empty field; a text
    /// with a comma or a quote is quoted, so a kernel or family name can never shift columns.
    #[test]
    fn csv_rows_take_their_header_from_the_fields() {
        #[derive(Serialize)]
        struct Row {
            name: &'static str,
            ms: f64,
            peak: Option<f64>,
        }
        let rows = [
            Row {
                name: "a",
                ms: 1.5,
                peak: None,
            },
            Row {
                name: "b,\"c\"",
                ms: 1.2e-7,
                peak: Some(39.0),
            },
        ];
        let text = String::from_utf8(csv_bytes(&rows).unwrap()).unwrap();
        assert_eq!(text, "name,ms,peak\na,1.5,\n\"b,\"\"c\"\"\",1.2e-7,39.0\n");
        assert!(csv_bytes(Vec::<Row>::new()).unwrap().is_empty());
    }
}
