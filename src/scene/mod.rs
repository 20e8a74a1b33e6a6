//! Scene files (the README's "Scene format"): the serde schema, defaults, and validation
//! into a [`Scene`].
//!
//! A scene file has exactly one of `"camera": {…}` (one view) and `"cameras": [{…}, …]`
//! (several views of the same cylinders, in order: camera 0, 1, …); giving both or neither
//! is an error. Its `"cylinders"` is a list, or `{"file": "tree.csv"}`: a table file
//! ([`table`]) beside the scene file.
//!
//! Serde types live here only; everything past [`Scene`] is plain validated data. Every
//! rejection names the field and the value: `cylinders[3].radius: must be > 0, got -1`.

pub mod aov;
pub mod camera;
pub mod framing;
mod parallel;
pub mod rig;
pub mod strict;
pub mod table;

use crate::geometry::Cylinder;
use crate::scene::camera::model::{CameraModel, ModelFields};
use crate::scene::camera::{Camera, CameraSpec, FovAxis, Projection};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};

/// Largest coordinate, radius or height accepted: f32 squares overflow near 1.8e19.
pub const MAX_COORD: f64 = 1e12;
/// Largest image side accepted.
pub const MAX_SIDE: u32 = 16384;
/// Largest image accepted, in pixels (8192 × 8192): with every AOV that is 2.4 GB of
/// buffers; 16384 × 16384 would be 9.7 GB.
pub const MAX_PIXELS: u64 = 1 << 26;

pub use aov::Aov;

/// The default AOV set, when neither the scene nor the command line names one.
pub fn default_aovs() -> Vec<Aov> {
    vec![Aov::Depth, Aov::Normal]
}

/// A validated scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// The camera a render uses: camera 0 when loaded, another after [`Scene::select_camera`].
    pub camera: CameraSpec,
    /// Every camera of the file, in file order (one for a `"camera"` file).
    pub cameras: Vec<CameraSpec>,
    /// The cylinders, in file order.
    pub cylinders: Vec<Cylinder>,
    /// Requested AOVs, in file order, without repeats.
    pub aovs: Vec<Aov>,
}

/// A scene that could not be read: the field path (empty for whole-file errors) and why.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    /// Field path of the offending value, e.g. `cylinders[3].radius`; empty for whole-file errors.
    pub field: String,
    /// Why the value was rejected, naming the value.
    pub message: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.field.is_empty() {
            f.write_str(&self.message)
        } else {
            write!(f, "{}: {}", self.field, self.message)
        }
    }
}

impl std::error::Error for SceneError {}

pub(crate) fn err(field: impl Into<String>, message: impl Into<String>) -> SceneError {
    SceneError {
        field: field.into(),
        message: message.into(),
    }
}

// ---- the file schema -------------------------------------------------------------------

/// The camera as written in a scene file: the frame and image size every model shares,
/// `model` (default `perspective`) and that model's parameters as flat fields.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    /// Camera centre, world units.
    #[serde(deserialize_with = "strict::vec3")]
    pub origin: [f64; 3],
    /// Point looked at, world units; must differ from `origin`.
    #[serde(deserialize_with = "strict::vec3")]
    pub target: [f64; 3],
    /// Up hint, any non-zero length, not parallel to `target - origin`.
    #[serde(deserialize_with = "strict::vec3")]
    pub up: [f64; 3],
    /// Field of view in degrees, in (0, 180), spanning the extent `fov_axis` names; the
    /// `perspective` model only (required there).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov_deg: Option<f64>,
    /// Which image extent `fov_deg` spans; default `x`; the `perspective` model only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov_axis: Option<FovAxis>,
    /// Image width in pixels, 1..=[`MAX_SIDE`].
    pub width: u32,
    /// Image height in pixels, 1..=[`MAX_SIDE`].
    pub height: u32,
    /// Near clip plane: smallest camera-space z counted, > 0; default 0.01.
    #[serde(default = "default_near")]
    pub near_clip: f64,
    /// Far clip plane: largest camera-space z counted, > `near_clip`; default 10000.
    #[serde(default = "default_far")]
    pub far_clip: f64,
    /// How pixels map to rays; default `perspective`.
    #[serde(default, skip_serializing_if = "is_perspective")]
    pub model: CameraModel,
    /// `orthographic`: the image width in world units (height by the aspect ratio).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ortho_width: Option<f64>,
    /// `opencv`, `opencv_fisheye`: focal length in pixels, x.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx: Option<f64>,
    /// `opencv`, `opencv_fisheye`: focal length in pixels, y.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy: Option<f64>,
    /// `opencv`, `opencv_fisheye`: principal point x, pixels (centres at integers).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    /// `opencv`, `opencv_fisheye`: principal point y, pixels (centres at integers).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    /// `opencv`, `opencv_fisheye`: first radial coefficient; default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k1: Option<f64>,
    /// `opencv`, `opencv_fisheye`: second radial coefficient; default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k2: Option<f64>,
    /// `opencv`, `opencv_fisheye`: third radial coefficient; default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k3: Option<f64>,
    /// `opencv_fisheye`: fourth radial coefficient; default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k4: Option<f64>,
    /// `opencv`: first tangential coefficient; default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p1: Option<f64>,
    /// `opencv`: second tangential coefficient; default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p2: Option<f64>,
}

fn is_perspective(m: &CameraModel) -> bool {
    *m == CameraModel::Perspective
}

fn default_near() -> f64 {
    0.01
}
fn default_far() -> f64 {
    10000.0
}
fn default_caps() -> bool {
    true
}

/// A cylinder as written: `p0`/`p1`, or the seed's `center`/`axis`/`height`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CylinderFile {
    /// Centre of the bottom end (world units); given with `p1`.
    #[serde(
        default,
        deserialize_with = "strict::opt_vec3",
        skip_serializing_if = "Option::is_none"
    )]
    pub p0: Option<[f64; 3]>,
    /// Centre of the top end (world units); given with `p0`.
    #[serde(
        default,
        deserialize_with = "strict::opt_vec3",
        skip_serializing_if = "Option::is_none"
    )]
    pub p1: Option<[f64; 3]>,
    /// The base (bottom end centre, world units); given with `axis` and `height`.
    #[serde(
        default,
        deserialize_with = "strict::opt_vec3",
        skip_serializing_if = "Option::is_none"
    )]
    pub center: Option<[f64; 3]>,
    /// Axis direction from the base, any non-zero length (normalised on load).
    #[serde(
        default,
        deserialize_with = "strict::opt_vec3",
        skip_serializing_if = "Option::is_none"
    )]
    pub axis: Option<[f64; 3]>,
    /// Length along `axis` from the base, world units, > 0.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub height: Option<f64>,
    /// Radius in world units, > 0.
    pub radius: f64,
    /// Whether the ends are closed by caps (`false`: an open tube); default `true`.
    #[serde(default = "default_caps")]
    pub caps: bool,
    /// What `shape_id` stores, > 0 (0 means miss); default the 1-based index in the file.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<u32>,
    /// The cylinder's class, any u32; default 0. Written only when non-zero, so files
    /// without labels keep their bytes.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub label: u32,
}

fn is_zero(v: &u32) -> bool {
    *v == 0
}

/// A whole scene file: exactly one of `camera` and `cameras` is given.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// The single view, when the file has one.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "strict::opt_object"
    )]
    pub camera: Option<CameraFile>,
    /// Several views of the same cylinders, camera 0, 1, … in order.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "strict::opt_objects"
    )]
    pub cameras: Option<Vec<CameraFile>>,
    /// The cylinders, in order.
    #[serde(deserialize_with = "strict::objects")]
    pub cylinders: Vec<CylinderFile>,
    /// Requested AOVs; default `["depth", "normal"]`, repeats dropped on load.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aovs: Option<Vec<Aov>>,
}

/// `"cylinders": {"file": "tree.csv", ...}`: the cylinders are a table file (see
/// [`table`]), its path relative to the scene file's folder.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableRef {
    /// The table, relative to the scene file's folder (or absolute).
    pub file: String,
    /// `csv`, `treeqsm`, `simpleforest` or `archi`; default: told from the table.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub format: Option<String>,
    /// `none`, `branch_order`, `branch` or `segment`; default: a csv table's `label`
    /// column, else none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// Caps on every cylinder; default `true` (a csv table's `caps` column wins).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub caps: Option<bool>,
}

impl TableRef {
    /// The table's path: `file` taken relative to `base`, the scene file's folder.
    pub fn path(&self, base: &Path) -> PathBuf {
        base.join(&self.file)
    }
}

/// A scene file whose cylinders are a [`TableRef`] or whose cameras are a
/// [`rig::CameraRig`] (either or both), read only when the plain [`SceneFile`] is not.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFileRef {
    #[serde(default, deserialize_with = "strict::opt_object")]
    camera: Option<CameraFile>,
    #[serde(default)]
    cameras: Option<strict::ListOr<CameraFile, rig::CameraRig>>,
    cylinders: strict::ListOr<CylinderFile, TableRef>,
    #[serde(default)]
    aovs: Option<Vec<Aov>>,
}

impl SceneFileRef {
    /// The scene file with the table's cylinders (its path taken relative to `base`) and
    /// the rig's cameras.
    fn resolve_file(self, base: &Path) -> Result<SceneFile, SceneError> {
        let cylinders = match self.cylinders {
            strict::ListOr::List(list) => list,
            strict::ListOr::Object(r) => read_table_ref(&r, base)?,
        };
        let cameras = match self.cameras {
            None => None,
            Some(strict::ListOr::List(list)) => Some(list),
            Some(strict::ListOr::Object(rig)) => {
                if self.camera.is_some() {
                    return Err(err(
                        "",
                        "give exactly one of \"camera\" and \"cameras\", got both",
                    ));
                }
                Some(rig.resolve(&cylinders, "cameras")?)
            }
        };
        Ok(SceneFile {
            camera: self.camera,
            cameras,
            cylinders,
            aovs: self.aovs,
        })
    }

    /// [`SceneFileRef::resolve_file`], validated.
    fn resolve(self, base: &Path) -> Result<Scene, SceneError> {
        self.resolve_file(base)?.validate()
    }

    /// The table file `cylinders` names, if it names one.
    fn table(&self, base: &Path) -> Option<PathBuf> {
        match &self.cylinders {
            strict::ListOr::Object(r) => Some(r.path(base)),
            strict::ListOr::List(_) => None,
        }
    }
}

/// The cylinders of the table `r` names, relative to `base`.
fn read_table_ref(r: &TableRef, base: &Path) -> Result<Vec<CylinderFile>, SceneError> {
    use table::{LabelRule, TableFormat, TableOptions};
    let format = match &r.format {
        Some(f) => Some(TableFormat::parse(f).ok_or_else(|| {
            err(
                "cylinders.format",
                format!(
                    "must be one of {}, got {f:?}",
                    TableFormat::ALL.map(|f| f.name()).join(", ")
                ),
            )
        })?),
        None => None,
    };
    let label = match &r.label {
        Some(l) => Some(LabelRule::parse(l).ok_or_else(|| {
            err(
                "cylinders.label",
                format!(
                    "must be one of {}, got {l:?}",
                    LabelRule::ALL.map(|f| f.name()).join(", ")
                ),
            )
        })?),
        None => None,
    };
    let path = r.path(base);
    let opts = TableOptions {
        format,
        label,
        caps: r.caps,
    };
    let table = table::load_table(&path, &opts).map_err(|e| match e.option {
        // The scene's own key, not the front end's spelling of the option.
        Some(key) => err(
            format!("cylinders.{key}"),
            format!(
                "{}: {}",
                path.display(),
                table::TableError { option: None, ..e }
            ),
        ),
        None => err("cylinders.file", format!("{}: {e}", path.display())),
    })?;
    Ok(table.cylinders)
}

/// The scene file `text` describes with its table and rig resolved (cylinders inline, every
/// camera listed), tables relative to `base`, and the table file it read; `None` when it
/// uses neither a table nor a rig.
pub fn resolve_file(
    text: &[u8],
    base: &Path,
) -> Option<Result<(SceneFile, Option<PathBuf>), SceneError>> {
    let file = serde_json::from_slice::<strict::Object<SceneFileRef>>(text).ok()?;
    let plain = matches!(file.0.cylinders, strict::ListOr::List(_))
        && !matches!(file.0.cameras, Some(strict::ListOr::Object(_)));
    let table = file.0.table(base);
    (!plain).then(|| file.0.resolve_file(base).map(|f| (f, table)))
}

/// Whether `text` is a scene whose `cylinders` is an object (a [`TableRef`]), read as
/// such, with the table's path; `None` for every other text.
fn table_scene(text: &[u8], base: &Path) -> Option<Result<(Scene, Option<PathBuf>), SceneError>> {
    if let Ok(file) = serde_json::from_slice::<strict::Object<SceneFileRef>>(text) {
        let table = file.0.table(base);
        return Some(file.0.resolve(base).map(|s| (s, table)));
    }
    // A table reference with a mistake: the message names the field inside it.
    let mut de = serde_json::Deserializer::from_slice(text);
    match serde_path_to_error::deserialize::<_, strict::Object<SceneFileRef>>(&mut de) {
        Err(e) => {
            let field = e.path().to_string();
            let message = e.into_inner().to_string();
            // Inside the reference, or the reference object itself missing or repeating a
            // key (an error at `cylinders` otherwise says a list was expected).
            let inside = field.starts_with("cylinders.") || field.starts_with("cameras.");
            let object = (field == "cylinders" || field == "cameras")
                && (message.starts_with("missing field") || message.starts_with("duplicate field"));
            (inside || object).then(|| Err(err(strict::shorten(&field), strict::shorten(&message))))
        }
        Ok(_) => None,
    }
}

// ---- loading and validation ------------------------------------------------------------

/// Largest scene file read, in bytes: 512 MiB admits a million cylinders with room to spare
/// (110 MB of compact JSON; 220 MB as `generate` writes them, measured), and stops
/// `/dev/zero`-like inputs from growing memory without bound.
pub const MAX_SCENE_BYTES: u64 = 512 << 20;

/// Read and validate a scene file. It must be a regular file (through links; a FIFO would
/// block, a device never end) of at most [`MAX_SCENE_BYTES`].
pub fn load(path: &Path) -> Result<Scene, SceneError> {
    load_with_table(path).map(|(scene, _)| scene)
}

/// [`load`], with the table file the scene's `cylinders` names (if it names one): an input
/// as much as the scene file, which no output may overwrite.
pub fn load_with_table(path: &Path) -> Result<(Scene, Option<PathBuf>), SceneError> {
    let bytes = read_bounded(path)?;
    let bytes = bytes.as_slice();
    // A plain scene with its cylinders read on every core; then plain serde_json; only a
    // file both refuse is read again with path tracking (and checked for UTF-8), for the
    // message that names the field.
    if let Some(scene) = parallel::load(bytes) {
        return Ok((scene, None));
    }
    if let Ok(file) = serde_json::from_slice::<strict::Object<SceneFile>>(bytes) {
        return file.0.validate().map(|s| (s, None));
    }
    let base = path.parent().unwrap_or(Path::new(""));
    if let Some(scene) = table_scene(bytes, base) {
        return scene;
    }
    let text = std::str::from_utf8(bytes)
        .map_err(|e| err("", format!("not UTF-8 text (byte {})", e.valid_up_to())))?;
    parse_serde(text).map(|s| (s, None))
}

/// Read the scene file at `path` with its table and rig resolved (cylinders inline, every
/// camera listed), validated: the file `cylaov cameras` writes; with the table file it
/// read, as [`load_with_table`].
pub fn load_resolved(path: &Path) -> Result<(SceneFile, Option<PathBuf>), SceneError> {
    let bytes = read_bounded(path)?;
    let base = path.parent().unwrap_or(Path::new(""));
    let (file, table) = match serde_json::from_slice::<strict::Object<SceneFile>>(&bytes) {
        Ok(file) => (file.0, None),
        Err(_) => match resolve_file(&bytes, base) {
            Some(file) => file?,
            None => {
                // Not a scene: the loader's message names the field.
                let e = load(path).err();
                return Err(e.unwrap_or_else(|| err("", "not a scene file")));
            }
        },
    };
    file.validate()?;
    Ok((file, table))
}

/// The bytes of `path`, a regular file (through links) of at most [`MAX_SCENE_BYTES`]:
/// scene files and the tables they name are read the same way.
pub(crate) fn read_bounded(path: &Path) -> Result<Vec<u8>, SceneError> {
    // Messages leave the path out: every caller prefixes it.
    let cannot = |e: std::io::Error| err("", format!("cannot read: {e}"));
    let meta = std::fs::metadata(path).map_err(cannot)?;
    if !meta.is_file() {
        let kind = if meta.is_dir() {
            "a folder"
        } else {
            "a device, FIFO or socket"
        };
        return Err(err("", format!("not a regular file but {kind}")));
    }
    let too_big = |n: u64| {
        err(
            "",
            format!(
                "{n} bytes, more than the {MAX_SCENE_BYTES} bytes (512 MiB) a scene file may have"
            ),
        )
    };
    if meta.len() > MAX_SCENE_BYTES {
        return Err(too_big(meta.len()));
    }
    // Read, not mapped: a mapping would turn a file truncated by another process during
    // the parse into a SIGBUS, and the bytes under a `&[u8]` could change. Bounded even
    // when the size was wrong (files in /proc report 0).
    if meta.len() >= PARALLEL_READ_MIN
        && let Some(bytes) = read_parallel(path, meta.len())
    {
        return Ok(bytes);
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    crate::mem::huge_pages(&bytes);
    std::fs::File::open(path)
        .and_then(|f| {
            use std::io::Read;
            f.take(MAX_SCENE_BYTES + 1).read_to_end(&mut bytes)
        })
        .map_err(cannot)?;
    if bytes.len() as u64 > MAX_SCENE_BYTES {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// Files from this size on are read in parallel pieces ([`read_parallel`]).
const PARALLEL_READ_MIN: u64 = 4 << 20;

/// The `len` bytes of the regular file at `path`, read in 1 MiB pieces on every core, each
/// to its own offset of the buffer (`pread`): the copy out of the page cache and the first
/// touch of the buffer's fresh pages, a fifth of a 16×16 render of 100 000 cylinders, are
/// then shared. The bytes are a sequential read's; `None` (the caller reads sequentially)
/// when a piece comes back short or the file has more than `len` bytes: it changed, or its
/// size was not its length.
#[cfg(unix)]
fn read_parallel(path: &Path, len: u64) -> Option<Vec<u8>> {
    use std::os::fd::AsRawFd;
    use std::os::unix::fs::FileExt;
    const PIECE: usize = 1 << 20;
    let file = std::fs::File::open(path).ok()?;
    let len = usize::try_from(len).ok()?;
    // Not zeroed first: a zeroed buffer of this size comes from the heap, which the
    // allocator clears on this one thread while the pool waits (18 MB: under perf, a tenth
    // of that render's CPU time and all of it serial). Unwritten, each page is first
    // touched by the thread that reads into it.
    let mut bytes = Vec::<u8>::with_capacity(len);
    crate::mem::huge_pages(&bytes);
    let fd = file.as_raw_fd();
    let read = bytes.spare_capacity_mut()[..len]
        .par_chunks_mut(PIECE)
        .enumerate()
        .all(|(k, piece)| read_piece(fd, piece, (k * PIECE) as u64));
    if !read {
        return None;
    }
    // SAFETY: every piece of the first `len` bytes was filled by `read_piece`.
    unsafe { bytes.set_len(len) };
    let mut past = [0u8; 1];
    (file.read_at(&mut past, len as u64).ok()? == 0).then_some(bytes)
}

/// Fill `piece` with the file's bytes from `offset` (`pread`, again after a short read or
/// an interrupt, as `read_exact_at`, but into memory not yet written); false when the file
/// ends first or the read fails.
#[cfg(unix)]
fn read_piece(
    fd: std::os::fd::RawFd,
    piece: &mut [std::mem::MaybeUninit<u8>],
    offset: u64,
) -> bool {
    let mut done = 0;
    while done < piece.len() {
        let Ok(at) = libc::off_t::try_from(offset + done as u64) else {
            return false;
        };
        let rest = &mut piece[done..];
        // SAFETY: `rest` is valid for writes of `rest.len()` bytes, which is all `pread`
        // writes; it never reads them, so their being unwritten does not matter.
        let n = unsafe { libc::pread(fd, rest.as_mut_ptr().cast(), rest.len(), at) };
        match n {
            1.. => done += n as usize,
            0 => return false,
            _ if std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted => {}
            _ => return false,
        }
    }
    true
}

#[cfg(not(unix))]
fn read_parallel(_: &Path, _: u64) -> Option<Vec<u8>> {
    None
}

/// Parse and validate scene JSON: one JSON object and nothing after it. Plain
/// `serde_json` reads it; only when that fails, `parse_serde` reads it again with path
/// tracking, whose message names the field.
///
/// A `"cylinders": {"file": ...}` table is read relative to the current folder.
pub fn parse(text: &str) -> Result<Scene, SceneError> {
    if let Some(scene) = parallel::load(text.as_bytes()) {
        return Ok(scene);
    }
    match serde_json::from_str::<strict::Object<SceneFile>>(text) {
        Ok(file) => file.0.validate(),
        Err(_) => match table_scene(text.as_bytes(), Path::new("")) {
            Some(scene) => scene.map(|(s, _)| s),
            None => parse_serde(text),
        },
    }
}

/// [`parse`] through `serde_json` alone.
fn parse_serde(text: &str) -> Result<Scene, SceneError> {
    if text.starts_with('\u{feff}') {
        return Err(err(
            "",
            "invalid JSON: the file starts with a UTF-8 byte order mark (EF BB BF), which JSON does not allow; save it without one",
        ));
    }
    // A syntax error is invalid JSON; a data error (an unknown field, a wrong type) is valid
    // JSON that is not a scene, and says so in its own words. Both name the line.
    let invalid = |field: String, e: serde_json::Error| {
        let what = match e.classify() {
            serde_json::error::Category::Data => e.to_string(),
            _ => format!("invalid JSON: {e}"),
        };
        err(strict::shorten(&field), strict::shorten(&what))
    };
    let mut de = serde_json::Deserializer::from_str(text);
    let file: strict::Object<SceneFile> =
        serde_path_to_error::deserialize(&mut de).map_err(|e| {
            let path = e.path().to_string();
            // "." is the whole file, "?" a place the tracker could not name.
            let field = if path == "." || path == "?" {
                String::new()
            } else {
                path
            };
            invalid(field, e.into_inner())
        })?;
    de.end().map_err(|e| {
        err(
            "",
            format!(
                "text after the end of the scene's JSON object at line {} column {} (two scenes in one file?)",
                e.line(),
                e.column()
            ),
        )
    })?;
    file.0.validate()
}

/// A number as a person reads it in a message: plain, or in exponent form when plain would
/// be a wall of digits (1e300) or zeros (1e-300).
pub(crate) fn num(x: f64) -> String {
    if x.is_finite() && x != 0.0 && !(1e-6..1e16).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// A field path, formatted only when an error names it (validating a cylinder would
/// otherwise format three paths per cylinder: most of the time validation took).
trait FieldPath {
    fn path(&self) -> String;
}

impl FieldPath for String {
    fn path(&self) -> String {
        self.clone()
    }
}

/// `cylinders[index].name`.
#[derive(Clone, Copy)]
struct CylinderField {
    index: usize,
    name: &'static str,
}

impl FieldPath for CylinderField {
    fn path(&self) -> String {
        format!("cylinders[{}].{}", self.index, self.name)
    }
}

fn check_vec(field: impl FieldPath, v: [f64; 3]) -> Result<DVec3, SceneError> {
    for (k, x) in v.iter().enumerate() {
        if !x.is_finite() || x.abs() > MAX_COORD {
            return Err(err(
                format!("{}[{k}]", field.path()),
                format!(
                    "must be finite with magnitude <= {MAX_COORD:e}, got {}",
                    num(*x)
                ),
            ));
        }
    }
    Ok(DVec3::from_array(v))
}

fn check_positive(field: impl FieldPath, x: f64) -> Result<f64, SceneError> {
    if !x.is_finite() || x <= 0.0 || x > MAX_COORD {
        return Err(err(
            field.path(),
            format!("must be > 0 and <= {MAX_COORD:e}, got {}", num(x)),
        ));
    }
    Ok(x)
}

impl SceneFile {
    /// The file form of a validated scene (cylinders as `p0`/`p1`, every field explicit),
    /// for writing generated scenes.
    pub fn from_scene(scene: &Scene) -> SceneFile {
        let files: Vec<CameraFile> = scene.cameras.iter().map(CameraFile::from_spec).collect();
        let (camera, cameras) = match &files[..] {
            [one] => (Some(one.clone()), None),
            _ => (None, Some(files)),
        };
        SceneFile {
            camera,
            cameras,
            cylinders: scene
                .cylinders
                .iter()
                .map(|y| CylinderFile {
                    p0: Some(y.base.to_array()),
                    p1: Some(y.top().to_array()),
                    radius: y.radius,
                    caps: y.caps,
                    id: Some(y.id),
                    label: y.label,
                    ..CylinderFile::default()
                })
                .collect(),
            aovs: Some(scene.aovs.clone()),
        }
    }

    /// Check every field and build the validated scene.
    pub fn validate(&self) -> Result<Scene, SceneError> {
        validate_scene(&self.camera, &self.cameras, &self.aovs, || {
            // In parallel; on an error, again in order, to report the first one.
            match self
                .cylinders
                .par_iter()
                .enumerate()
                .map(|(i, c)| c.validate(i))
                .collect::<Result<Vec<_>, _>>()
            {
                Ok(list) => Ok(list),
                Err(_) => self
                    .cylinders
                    .iter()
                    .enumerate()
                    .map(|(i, c)| c.validate(i))
                    .collect(),
            }
        })
    }
}

/// Check the cameras, then the cylinders (`cylinders` validates them), then the AOVs, and
/// build the validated scene: the first error in that order is the one reported.
fn validate_scene(
    camera: &Option<CameraFile>,
    cameras: &Option<Vec<CameraFile>>,
    aovs: &Option<Vec<Aov>>,
    cylinders: impl FnOnce() -> Result<Vec<Cylinder>, SceneError>,
) -> Result<Scene, SceneError> {
    let cameras = match (camera, cameras) {
        (Some(c), None) => vec![c.validate("camera")?],
        (None, Some(list)) if list.is_empty() => {
            return Err(err("cameras", "must list at least one camera, got []"));
        }
        (None, Some(list)) => list
            .iter()
            .enumerate()
            .map(|(k, c)| c.validate(&format!("cameras[{k}]")))
            .collect::<Result<Vec<_>, _>>()?,
        (Some(_), Some(_)) => {
            return Err(err(
                "",
                "give exactly one of \"camera\" and \"cameras\", got both",
            ));
        }
        (None, None) => {
            return Err(err(
                "",
                "missing the camera: give \"camera\": {...} or \"cameras\": [{...}, ...]",
            ));
        }
    };
    let cylinders = cylinders()?;
    let aovs = match aovs {
        None => default_aovs(),
        Some(list) if list.is_empty() => {
            return Err(err("aovs", "must list at least one AOV, got []"));
        }
        Some(list) => Aov::without_repeats(list),
    };
    Ok(Scene {
        camera: cameras[0],
        cameras,
        cylinders,
        aovs,
    })
}

impl Scene {
    /// Make camera `k` (0-based, file order) the one a render uses.
    pub fn select_camera(&mut self, k: usize) -> Result<(), SceneError> {
        let n = self.cameras.len();
        self.camera = *self.cameras.get(k).ok_or_else(|| {
            err(
                "",
                format!(
                    "the scene has {n} camera(s), numbered 0..={}, got {k}",
                    n - 1
                ),
            )
        })?;
        Ok(())
    }
}

impl CameraFile {
    /// The file form of a validated camera, every field explicit.
    pub fn from_spec(c: &CameraSpec) -> CameraFile {
        let pinhole = c.projection == Projection::Perspective;
        let f = c.projection.fields();
        CameraFile {
            origin: c.origin.to_array(),
            target: c.target.to_array(),
            up: c.up.to_array(),
            fov_deg: pinhole.then_some(c.fov_deg),
            fov_axis: pinhole.then_some(c.fov_axis),
            width: c.width,
            height: c.height,
            near_clip: c.near_clip,
            far_clip: c.far_clip,
            ..CameraFile::default()
        }
        .with_model(c.projection.model(), &f)
    }

    /// This camera with `model` and the parameters `f` gives it (every model field
    /// replaced; `fov_deg` and `fov_axis` are the caller's).
    pub fn with_model(self, model: CameraModel, f: &ModelFields) -> CameraFile {
        CameraFile {
            model,
            ortho_width: f.ortho_width,
            fx: f.intrinsics[0],
            fy: f.intrinsics[1],
            cx: f.intrinsics[2],
            cy: f.intrinsics[3],
            k1: f.k[0],
            k2: f.k[1],
            k3: f.k[2],
            k4: f.k[3],
            p1: f.p[0],
            p2: f.p[1],
            ..self
        }
    }

    /// This camera's model parameters as the model table reads them.
    fn model_fields(&self) -> ModelFields {
        ModelFields {
            fov_deg: self.fov_deg,
            ortho_width: self.ortho_width,
            intrinsics: [self.fx, self.fy, self.cx, self.cy],
            k: [self.k1, self.k2, self.k3, self.k4],
            p: [self.p1, self.p2],
        }
    }

    /// Check every field; `at` is the camera's field path (`camera` or `cameras[K]`).
    fn validate(&self, at: &str) -> Result<CameraSpec, SceneError> {
        let origin = check_vec(format!("{at}.origin"), self.origin)?;
        let target = check_vec(format!("{at}.target"), self.target)?;
        let up = check_vec(format!("{at}.up"), self.up)?;
        if let Some(fov) = self.fov_deg
            && !(fov.is_finite() && fov > 0.0 && fov < 180.0)
        {
            return Err(err(
                format!("{at}.fov_deg"),
                format!("must be in (0, 180), got {}", num(fov)),
            ));
        }
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_SIDE {
                return Err(err(
                    format!("{at}.{name}"),
                    format!("must be in 1..={MAX_SIDE}, got {v}"),
                ));
            }
        }
        let pixels = self.width as u64 * self.height as u64;
        if pixels > MAX_PIXELS {
            return Err(err(
                format!("{at}.height"),
                format!(
                    "width × height must be <= {MAX_PIXELS} pixels (64 megapixels, e.g. 8192 × 8192; each side <= {MAX_SIDE}), got {} × {} = {pixels}",
                    self.width, self.height
                ),
            ));
        }
        let (near, far) = (self.near_clip, self.far_clip);
        if !(near.is_finite() && near > 0.0) {
            return Err(err(
                format!("{at}.near_clip"),
                format!("must be > 0, got {}", num(near)),
            ));
        }
        if !(far.is_finite() && far > near) {
            return Err(err(
                format!("{at}.far_clip"),
                format!(
                    "must be finite and > near_clip ({}), got {}",
                    num(near),
                    num(far)
                ),
            ));
        }
        let projection = self
            .model
            .projection(
                &self.model_fields(),
                self.fov_axis.is_some(),
                self.width,
                self.height,
            )
            .map_err(|(field, message)| err(format!("{at}.{field}"), message))?;
        // Models with their own intrinsics have no field of view; the pinhole frame the
        // camera still carries is a 90° one, never used for their rays.
        let fov = self.fov_deg.unwrap_or(90.0);
        let forward = target - origin;
        if forward.length() == 0.0 {
            return Err(err(
                format!("{at}.target"),
                format!("must differ from {at}.origin, got {:?}", self.target),
            ));
        }
        if up.length() == 0.0 {
            return Err(err(
                format!("{at}.up"),
                format!("must be non-zero, got {:?}", self.up),
            ));
        }
        // Same test as the frame construction: up × forward must be a usable direction.
        let sin = up.normalize().cross(forward.normalize()).length();
        if sin < 1e-9 {
            return Err(err(
                format!("{at}.up"),
                format!(
                    "must not be parallel to the view direction (target - origin), got {:?}",
                    self.up
                ),
            ));
        }
        let spec = CameraSpec {
            origin,
            target,
            up,
            fov_deg: fov,
            fov_axis: self.fov_axis.unwrap_or_default(),
            width: self.width,
            height: self.height,
            near_clip: near,
            far_clip: far,
            projection,
        };
        // A field of view so small that its tangent underflows leaves no focal length
        // (an infinite one) and a pixel footprint of 0: the camera files and the EXR
        // header (f32) could not state the camera.
        let cam = Camera::new(spec);
        let (fx, fy) = cam.focal_px();
        let foot = 2.0 * cam.tan_half_x / self.width as f64;
        let fits = |x: f64| x > 0.0 && x <= f32::MAX as f64;
        if !(fits(fx) && fits(fy) && foot > 0.0 && foot.is_finite()) {
            return Err(err(
                format!("{at}.fov_deg"),
                format!(
                    "is too small for a finite focal length in pixels (at most {:e}), got {} (focal length {} px)",
                    f32::MAX,
                    num(fov),
                    num(fx.max(fy))
                ),
            ));
        }
        // An orthographic pixel is a step of the ray origin across the view: below the
        // spacing of f64 values at the camera's origin (or a subnormal half width, which
        // the camera file's `ortho_width` would not give back), every pixel casts the
        // same ray.
        if let Projection::Orthographic {
            half_width,
            half_height,
        } = projection
        {
            let step =
                (2.0 * half_width / self.width as f64).min(2.0 * half_height / self.height as f64);
            let spacing = 4.0 * f64::EPSILON * origin.abs().max_element();
            if !(half_height.is_normal() && step > spacing) {
                return Err(err(
                    format!("{at}.ortho_width"),
                    format!(
                        "is too small: {} over {}x{} pixels is a pixel {} wide, not more \
                         than the spacing of coordinates at the camera's origin ({}): \
                         every pixel would cast the same ray",
                        num(self.ortho_width.unwrap_or(2.0 * half_width)),
                        self.width,
                        self.height,
                        num(step),
                        num(spacing)
                    ),
                ));
            }
        }
        Ok(spec)
    }
}

/// The length of `v` and `v` divided by it. When the squared length leaves the normal
/// range (a component near 1e-162 squares to a subnormal or to 0, near 1e155 to inf),
/// `v` is first scaled by the power of two that brings its largest component to [1, 2)
/// (exactly: a scaled copy, normalised as that copy is), so any finite non-zero `v` gets
/// its true length and a unit direction. Every other `v` gets `length()` and
/// `v / length` as they are.
fn length_and_unit(v: DVec3) -> (f64, DVec3) {
    let sq = v.length_squared();
    if sq >= f64::MIN_POSITIVE && sq.is_finite() {
        let len = sq.sqrt();
        return (len, v / len);
    }
    let m = v.abs().max_element();
    if m == 0.0 || !m.is_finite() {
        return (m, v);
    }
    // Two exact steps of at most 2^600 each: a subnormal's exponent field is 0.
    let pre = if m < 1.0 {
        2f64.powi(600)
    } else {
        2f64.powi(-600)
    };
    let (v, m, back) = if !(2f64.powi(-400)..2f64.powi(400)).contains(&m) {
        (v * pre, m * pre, 1.0 / pre)
    } else {
        (v, m, 1.0)
    };
    let exp = ((m.to_bits() >> 52) & 0x7ff) as i32 - 1023;
    let s = v * 2f64.powi(-exp);
    let len = s.length();
    (len * 2f64.powi(exp) * back, s / len)
}

impl CylinderFile {
    fn validate(&self, index: usize) -> Result<Cylinder, SceneError> {
        let f = |name: &'static str| CylinderField { index, name };
        let radius = check_positive(f("radius"), self.radius)?;
        let (base, axis, height) = match (self.p0, self.p1, self.center, self.axis, self.height) {
            (Some(p0), Some(p1), None, None, None) => {
                let (p0, p1) = (check_vec(f("p0"), p0)?, check_vec(f("p1"), p1)?);
                let (h, axis) = length_and_unit(p1 - p0);
                if h == 0.0 {
                    return Err(err(
                        f("p1").path(),
                        format!(
                            "must differ from p0 by a length > 0, got {:?}",
                            self.p1.unwrap_or_default()
                        ),
                    ));
                }
                (p0, axis, h)
            }
            (None, None, Some(c), Some(a), Some(h)) => {
                let c = check_vec(f("center"), c)?;
                let a = check_vec(f("axis"), a)?;
                let h = check_positive(f("height"), h)?;
                let (len, unit) = length_and_unit(a);
                if len == 0.0 || !len.is_finite() {
                    return Err(err(
                        f("axis").path(),
                        format!("must be non-zero, got {:?}", a.to_array()),
                    ));
                }
                (c, unit, h)
            }
            _ => {
                return Err(err(
                    format!("cylinders[{index}]"),
                    "give either p0 and p1, or center, axis and height (not a mix)",
                ));
            }
        };
        let top = base + axis * height;
        if top.abs().max_element() > MAX_COORD {
            return Err(err(
                f("height").path(),
                format!("puts the top at {:?}, beyond {MAX_COORD:e}", top.to_array()),
            ));
        }
        let id = match self.id {
            Some(0) => return Err(err(f("id").path(), "must be > 0 (0 means miss), got 0")),
            Some(id) => id,
            None => {
                u32::try_from(index + 1).map_err(|_| err(f("id").path(), "too many cylinders"))?
            }
        };
        Ok(Cylinder {
            base,
            axis,
            height,
            radius,
            caps: self.caps,
            id,
            label: self.label,
        })
    }
}
