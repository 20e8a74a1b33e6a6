//! Batches of views (`cylaov batch`, SPEC §7): the view list, sharding, resumable rendering
//! through one rayon pool, and the dataset index `transforms.json`.
//!
//! Per view `NAME` the output folder gets `NAME.exr`, `NAME.camera.json`,
//! `NAME.normal.png` (8-bit), `NAME.depth.png` (16-bit, planar depth × `depth_scale`) and
//! `NAME.render.json`, the stamp of what made the files ([`render_stamp`]: a hash of the
//! scene and every option that changes output bytes).
//!
//! **Crash invariant**: every file is first written whole under
//! `OUT/.partial/K-of-N/` (names ending in `.tmp`) and then renamed into place. The EXR is
//! the view's "done" marker: an existing `NAME.exr` is removed before the first rename and
//! the new one is renamed last, so an EXR on disk means its siblings come from the same
//! render. A kill at any moment leaves only whole files in `OUT`; the partial folder of a
//! shard is cleared when that shard starts. A view counts as done when its EXR header has
//! the expected size, channels and compression and the chunk at the largest offset of its
//! offset table ends exactly at the end of the file ([`exr_is_complete`]: a truncated file
//! fails; the pixels are not read), its PNGs end with an `IEND` chunk, and its camera JSON
//! and render stamp are byte for byte the ones this run would write (so a changed scene,
//! AOV list, `--precision`, `--formula`, `--compression`, `--no-png` or, with PNGs,
//! `--depth-scale` renders the view again). A view rendered with `--no-png` loses PNGs an
//! earlier run left, so the folder is what a fresh run would write.
//!
//! **Determinism invariant**: the view list, the shard of each view (`index % N`) and
//! `transforms.json` are pure functions of the input files and the options, so every shard
//! computes the same list and writes the same `transforms.json` bytes.

use crate::output::aov::{Compression, channel_names};
use crate::output::io::{atomic_write_bytes, camera_json};
use crate::rng::mix64;
use crate::scene::camera::{Camera, rows};

use crate::output::preview;
use crate::render::{FormulaKind, Precision, RenderOptions, render};
use crate::scene::{self, Aov, Scene};
use anyhow::{Context, Result, bail};
use exr::meta::MetaData;
use exr::meta::attribute::SampleType;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Cursor, IsTerminal, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};

// ---- the view list ---------------------------------------------------------------------

/// One view of the input: its name and where its scene file is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ViewSource {
    /// Output file stem: the scene file's stem, or the manifest's `name`.
    pub name: String,
    /// The scene file to read.
    pub path: PathBuf,
}

/// A manifest line: `{"name": ..., "scene": ...}`; the scene path is relative to the
/// manifest's folder; `name` defaults to the scene file's stem. Other keys are ignored.
#[derive(Deserialize)]
struct ManifestLine {
    name: Option<String>,
    scene: String,
}

/// Why a view name cannot be an output file stem, if it cannot.
fn check_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.starts_with('.') {
        return Err(format!(
            "view name must be non-empty and not start with '.', got {name:?}"
        ));
    }
    if name
        .chars()
        .any(|c| c == '/' || c == '\\' || c.is_control())
    {
        return Err(format!(
            "view name must not contain '/', '\\' or control characters, got {name:?}"
        ));
    }
    Ok(())
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The views of INPUT: a `.jsonl` manifest, a folder holding `manifest.jsonl` (read through
/// it), or a folder whose `*.json` files are taken recursively in sorted relative-path order
/// (hidden entries and anything under `exclude`, the output folder, skipped).
/// Errors here concern the input as a whole: no view is rendered. An input without views
/// is one (a wrong path or an `--out` that holds the input must not pass as "0 views").
pub fn list_views(input: &Path, exclude: Option<&Path>) -> Result<Vec<ViewSource>> {
    // Entries skipped because they lie under `exclude`: `*.json` files and folders.
    let mut excluded = Excluded::default();
    let views = if input.is_dir() {
        let manifest = input.join("manifest.jsonl");
        if manifest.is_file() {
            read_manifest(&manifest)?
        } else {
            let exclude = exclude.and_then(|p| p.canonicalize().ok());
            let mut files = Vec::new();
            scan(input, exclude.as_deref(), &mut files, &mut excluded)
                .with_context(|| format!("listing {}", input.display()))?;
            files.sort_by(|a, b| a.strip_prefix(input).ok().cmp(&b.strip_prefix(input).ok()));
            files
                .into_iter()
                .map(|path| ViewSource {
                    name: stem(&path),
                    path,
                })
                .collect()
        }
    } else if input.extension().is_some_and(|e| e == "jsonl") {
        read_manifest(input)?
    } else if !input.exists() {
        bail!("INPUT {}: no such file or folder", input.display());
    } else {
        bail!(
            "INPUT {}: expected a folder of scene files or a .jsonl manifest",
            input.display()
        );
    };
    if views.is_empty() {
        if excluded.files + excluded.folders > 0 {
            let count = |n: usize, what: &str| match n {
                0 => None,
                1 => Some(format!("1 {what}")),
                n => Some(format!("{n} {what}s")),
            };
            let what: Vec<String> = [
                count(excluded.files, "*.json file"),
                count(excluded.folders, "folder"),
            ]
            .into_iter()
            .flatten()
            .collect();
            bail!(
                "INPUT {}: no scene files outside --out {}: skipped {} under it (outputs \
                 are not read as input; give an output folder outside the input)",
                input.display(),
                exclude.map_or(String::new(), |p| p.display().to_string()),
                what.join(" and ")
            );
        }
        if input.is_dir() {
            bail!(
                "INPUT {}: no scene files (*.json, hidden entries skipped) and no manifest.jsonl",
                input.display()
            );
        }
        bail!("INPUT {}: the manifest lists no views", input.display());
    }
    let mut seen: HashMap<&str, &Path> = HashMap::new();
    for v in &views {
        check_name(&v.name).map_err(|e| anyhow::anyhow!("{}: {e}", v.path.display()))?;
        if let Some(first) = seen.insert(&v.name, &v.path) {
            bail!(
                "view name {:?} is used twice ({} and {}): outputs would collide; rename one \
                 or use a manifest with distinct names",
                v.name,
                first.display(),
                v.path.display()
            );
        }
    }
    Ok(views)
}

/// What [`scan`] left out because it lies under the output folder (not walked into).
#[derive(Default)]
struct Excluded {
    files: usize,
    folders: usize,
}

/// Collect the `*.json` files under `dir` into `out`; entries under `exclude` are counted
/// in `excluded` instead.
fn scan(
    dir: &Path,
    exclude: Option<&Path>,
    out: &mut Vec<PathBuf>,
    excluded: &mut Excluded,
) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        if entry.file_name().to_string_lossy().starts_with('.') {
            continue;
        }
        let skip = matches!(
            (exclude, path.canonicalize()),
            (Some(ex), Ok(canon)) if canon.starts_with(ex)
        );
        if entry.file_type()?.is_dir() {
            if skip {
                excluded.folders += 1;
            } else {
                scan(&path, exclude, out, excluded)?;
            }
        } else if path.extension().is_some_and(|e| e == "json") && path.is_file() {
            if skip {
                excluded.files += 1;
            } else {
                out.push(path);
            }
        }
    }
    Ok(())
}

fn read_manifest(path: &Path) -> Result<Vec<ViewSource>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let base = path.parent().unwrap_or(Path::new(""));
    let mut views = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let m: ManifestLine = serde_json::from_str(line).map_err(|e| {
            anyhow::anyhow!(
                "{}:{}: expected {{\"name\": ..., \"scene\": ...}}: {e}",
                path.display(),
                k + 1
            )
        })?;
        let scene = base.join(&m.scene);
        let name = m.name.unwrap_or_else(|| stem(&scene));
        check_name(&name).map_err(|e| anyhow::anyhow!("{}:{}: {e}", path.display(), k + 1))?;
        views.push(ViewSource { name, path: scene });
    }
    Ok(views)
}

// ---- shards ----------------------------------------------------------------------------

/// Shard `index` of `count` (0-based) holds the views whose position `i` in the view list
/// has `i % count == index`: deterministic, balanced, and independent of what exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl Shard {
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    pub fn new(index: u32, count: u32) -> Result<Shard, String> {
        if count == 0 {
            return Err("shard count must be >= 1, got 0".into());
        }
        if index >= count {
            return Err(format!(
                "shard index must be < count (0-based), got {index}/{count}"
            ));
        }
        Ok(Shard { index, count })
    }

    /// Parse `K/N`.
    pub fn parse(s: &str) -> Result<Shard, String> {
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| format!("expected K/N (0-based), got {s:?}"))?;
        let num = |t: &str| {
            t.trim()
                .parse::<u32>()
                .map_err(|_| format!("expected K/N with whole numbers, got {s:?}"))
        };
        Shard::new(num(k)?, num(n)?)
    }

    pub fn contains(&self, view_index: usize) -> bool {
        view_index % self.count as usize == self.index as usize
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-of-{}", self.index, self.count)
    }
}

/// The shard to render: `--shard K/N`; else with `--shards N` the index from
/// `JOB_COMPLETION_INDEX` (Kubernetes Indexed Job) or `SLURM_ARRAY_TASK_ID -
/// SLURM_ARRAY_TASK_MIN`; else from Slurm's array variables
/// (`SLURM_ARRAY_TASK_COUNT` shards); else the whole input.
pub fn resolve_shard(
    shard: Option<Shard>,
    shards: Option<u32>,
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<Shard, String> {
    let var = |name: &str| -> Result<Option<u32>, String> {
        match env(name) {
            None => Ok(None),
            Some(v) => v
                .trim()
                .parse::<u32>()
                .map(Some)
                .map_err(|_| format!("{name}: expected a whole number, got {v:?}")),
        }
    };
    let slurm_index = || -> Result<Option<u32>, String> {
        let Some(id) = var("SLURM_ARRAY_TASK_ID")? else {
            return Ok(None);
        };
        let min = var("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
        id.checked_sub(min).map(Some).ok_or_else(|| {
            format!("SLURM_ARRAY_TASK_ID ({id}) is below SLURM_ARRAY_TASK_MIN ({min})")
        })
    };
    match (shard, shards) {
        (Some(_), Some(_)) => Err("give --shard K/N or --shards N, not both".into()),
        (Some(s), None) => Ok(s),
        (None, Some(n)) => {
            let index = match var("JOB_COMPLETION_INDEX")? {
                Some(i) => i,
                None => slurm_index()?.ok_or(
                    "--shards N needs JOB_COMPLETION_INDEX (Kubernetes Indexed Job) or \
                     SLURM_ARRAY_TASK_ID in the environment; or give --shard K/N",
                )?,
            };
            Shard::new(index, n).map_err(|e| format!("--shards {n}: {e}"))
        }
        (None, None) => match slurm_index()? {
            None => Ok(Shard::ALL),
            Some(index) => {
                let count = var("SLURM_ARRAY_TASK_COUNT")?
                    .ok_or("SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not")?;
                Shard::new(index, count).map_err(|e| format!("Slurm array: {e}"))
            }
        },
    }
}

// ---- options and outputs ---------------------------------------------------------------

/// How the pool's threads share the work.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Schedule {
    /// Views in parallel (each view's rows also in parallel): writing one view overlaps
    /// tracing another. Measured faster at 320×240 (see README).
    #[default]
    Views,
    /// One view at a time, its rows in parallel; the pool idles while a view is written.
    Pixels,
}

/// What a batch renders and writes.
#[derive(Clone, Debug)]
pub struct BatchOptions {
    /// AOVs in each EXR; `None`: each scene's own.
    pub aovs: Option<Vec<Aov>>,
    pub precision: Precision,
    pub formula: FormulaKind,
    /// Depth PNG value per world unit (1000: millimetres for metre scenes).
    pub depth_scale: f64,
    /// Write `NAME.normal.png` and `NAME.depth.png`.
    pub png: bool,
    pub compression: Compression,
    pub schedule: Schedule,
    /// Fraction of views also checked against an independent reference (Mitsuba), chosen
    /// by [`selected_for_verify`] from `verify_seed` and the view name.
    pub verify_fraction: f64,
    pub verify_seed: u64,
}

impl Default for BatchOptions {
    fn default() -> Self {
        BatchOptions {
            aovs: None,
            precision: Precision::default(),
            formula: FormulaKind::default(),
            depth_scale: 1000.0,
            png: true,
            compression: Compression::None,
            schedule: Schedule::default(),
            verify_fraction: 0.0,
            verify_seed: 0,
        }
    }
}

impl BatchOptions {
    pub fn validate(&self) -> Result<(), String> {
        let s = self.depth_scale;
        if !(s.is_finite() && s > 0.0) {
            return Err(format!("--depth-scale: must be finite and > 0, got {s}"));
        }
        let f = self.verify_fraction;
        if !(0.0..=1.0).contains(&f) {
            return Err(format!("--verify-fraction: must be in [0, 1], got {f}"));
        }
        Ok(())
    }

    /// The AOVs stored in the EXR of `scene`.
    pub fn exr_aovs(&self, scene: &Scene) -> Vec<Aov> {
        self.aovs.clone().unwrap_or_else(|| scene.aovs.clone())
    }
}

/// The output paths of view `name` in `dir`.
pub struct ViewFiles {
    pub exr: PathBuf,
    pub camera: PathBuf,
    pub normal_png: PathBuf,
    pub depth_png: PathBuf,
    /// The [`render_stamp`].
    pub stamp: PathBuf,
}

impl ViewFiles {
    pub fn new(dir: &Path, name: &str) -> ViewFiles {
        ViewFiles {
            exr: dir.join(format!("{name}.exr")),
            camera: dir.join(format!("{name}.camera.json")),
            normal_png: dir.join(format!("{name}.normal.png")),
            depth_png: dir.join(format!("{name}.depth.png")),
            stamp: dir.join(format!("{name}.render.json")),
        }
    }
}

/// EXR channels of `aovs`, sorted as the file stores them, with their sample types.
pub fn expected_channels(aovs: &[Aov]) -> Vec<(&'static str, SampleType)> {
    let mut v: Vec<_> = aovs
        .iter()
        .flat_map(|&a| {
            let ty = if a.is_u32() {
                SampleType::U32
            } else {
                SampleType::F32
            };
            channel_names(a).iter().map(move |&c| (c, ty))
        })
        .collect();
    v.sort_by(|a, b| a.0.cmp(b.0));
    v
}

/// Cheap completeness check of an EXR written by us: the header has the expected size,
/// channels and compression, every offset of the offset table lies inside the file, and the
/// chunk at the largest offset ends (by the byte count in its 8-byte chunk header) exactly
/// at the end of the file. A truncated file fails; a file damaged inside, with its length
/// unchanged, passes (the pixels are not read: that is what the atomic renames are for).
/// Reads the header, the offset table and 8 bytes.
pub fn exr_is_complete(
    path: &Path,
    width: usize,
    height: usize,
    channels: &[(&str, SampleType)],
    compression: Compression,
) -> Result<(), String> {
    let mut f = File::open(path).map_err(|e| e.to_string())?;
    let len = f.metadata().map_err(|e| e.to_string())?.len();
    // Header + offset table: a few hundred bytes + 8 per chunk (16384 rows: 128 KiB).
    let mut prefix = Vec::new();
    (&mut f)
        .take(len.min(1 << 20))
        .read_to_end(&mut prefix)
        .map_err(|e| e.to_string())?;
    let mut cur = Cursor::new(&prefix[..]);
    let meta = MetaData::read_from_buffered(&mut cur, false).map_err(|e| e.to_string())?;
    let [header] = &meta.headers[..] else {
        return Err("expected one layer".into());
    };
    if header.layer_size.0 != width || header.layer_size.1 != height {
        return Err(format!(
            "size {}x{}, expected {width}x{height}",
            header.layer_size.0, header.layer_size.1
        ));
    }
    let got: Vec<(String, SampleType)> = header
        .channels
        .list
        .iter()
        .map(|c| (c.name.to_string(), c.sample_type))
        .collect();
    let same = got.len() == channels.len()
        && got
            .iter()
            .zip(channels)
            .all(|(g, e)| g.0 == e.0 && g.1 == e.1);
    if !same {
        return Err(format!("channels {got:?}, expected {channels:?}"));
    }
    let want = compression.to_exr();
    if header.compression != want {
        return Err(format!(
            "compression {:?}, expected {want:?}",
            header.compression
        ));
    }
    // The offset table follows the header directly.
    let table_start = cur.position() as usize;
    let table_end = table_start + header.chunk_count * 8;
    let table = prefix
        .get(table_start..table_end)
        .ok_or("file ends inside the offset table")?;
    let offsets: Vec<u64> = table
        .chunks_exact(8)
        .map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()))
        .collect();
    let last = offsets.iter().copied().max().ok_or("no chunks")?;
    if offsets.iter().any(|&o| o < table_end as u64 || o + 8 > len) {
        return Err("chunk offset outside the file".into());
    }
    // A scanline chunk: i32 y, i32 byte count, the bytes.
    let mut head = [0u8; 8];
    f.seek(SeekFrom::Start(last)).map_err(|e| e.to_string())?;
    f.read_exact(&mut head).map_err(|e| e.to_string())?;
    let size = i32::from_le_bytes([head[4], head[5], head[6], head[7]]);
    if size < 0 || last + 8 + size as u64 != len {
        return Err(format!(
            "last chunk ends at {}, file has {len} bytes",
            last + 8 + size.max(0) as u64
        ));
    }
    Ok(())
}

/// Whether the file exists and ends with `tail` (a PNG's IEND chunk).
fn file_ends_with(path: &Path, tail: &[u8]) -> bool {
    let read = || -> std::io::Result<bool> {
        let mut f = File::open(path)?;
        let len = f.metadata()?.len();
        if len < tail.len() as u64 {
            return Ok(false);
        }
        f.seek(SeekFrom::Start(len - tail.len() as u64))?;
        let mut buf = vec![0; tail.len()];
        f.read_exact(&mut buf)?;
        Ok(buf == tail)
    };
    read().unwrap_or(false)
}

/// FNV-1a, 64 bits: a fixed, dependency-free hash for stamps and the verify choice.
struct Fnv1a(u64);

impl Fnv1a {
    fn new() -> Fnv1a {
        Fnv1a(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, bytes: &[u8]) -> &mut Fnv1a {
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }
    fn f64s(&mut self, xs: &[f64]) -> &mut Fnv1a {
        xs.iter().for_each(|x| {
            self.bytes(&x.to_bits().to_le_bytes());
        });
        self
    }
}

/// A hash of everything in `scene` that reaches the output files (every field of the
/// validated camera and cylinders, exact bits; the AOV list is in the stamp itself).
fn scene_hash(scene: &Scene) -> u64 {
    let mut h = Fnv1a::new();
    let c = &scene.camera;
    h.f64s(&c.origin.to_array())
        .f64s(&c.target.to_array())
        .f64s(&c.up.to_array())
        .f64s(&[c.fov_deg, c.near_clip, c.far_clip])
        .bytes(c.fov_axis.name().as_bytes())
        .bytes(&c.width.to_le_bytes())
        .bytes(&c.height.to_le_bytes());
    for y in &scene.cylinders {
        h.f64s(&y.base.to_array())
            .f64s(&y.axis.to_array())
            .f64s(&[y.height, y.radius])
            .bytes(&[y.caps as u8])
            .bytes(&y.id.to_le_bytes());
    }
    h.0
}

/// What made a view's files: `NAME.render.json`.
#[derive(Serialize)]
struct RenderStamp {
    /// The cylaov that rendered the view: a new release may change output bits, so its
    /// views render again on resume.
    cylaov: &'static str,
    /// [`scene_hash`], hex.
    scene_fnv1a64: String,
    /// AOVs in the EXR.
    aovs: Vec<&'static str>,
    precision: String,
    formula: String,
    compression: String,
    png: bool,
    /// PNG depth value per world unit; only with PNGs (otherwise it changes nothing).
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_scale: Option<f64>,
}

/// The `NAME.render.json` this run writes for `scene`: the scene's hash and every option
/// that changes the view's output bytes. Resume compares it byte for byte, so a view made
/// with other options (or from another scene under the same name) is rendered again.
pub fn render_stamp(scene: &Scene, opts: &BatchOptions) -> String {
    fn name(v: impl clap::ValueEnum) -> String {
        v.to_possible_value()
            .map(|p| p.get_name().to_string())
            .unwrap_or_default()
    }
    let stamp = RenderStamp {
        cylaov: env!("CARGO_PKG_VERSION"),
        scene_fnv1a64: format!("{:016x}", scene_hash(scene)),
        aovs: opts.exr_aovs(scene).iter().map(|a| a.name()).collect(),
        precision: name(opts.precision),
        formula: name(opts.formula),
        compression: name(opts.compression),
        png: opts.png,
        depth_scale: opts.png.then_some(opts.depth_scale),
    };
    let mut s = serde_json::to_string_pretty(&stamp).unwrap_or_default();
    s.push('\n');
    s
}

/// Whether view `name` of `scene` is already complete in `dir`.
pub fn view_is_complete(dir: &Path, name: &str, scene: &Scene, opts: &BatchOptions) -> bool {
    let files = ViewFiles::new(dir, name);
    const PNG_END: &[u8] = b"\0\0\0\0IEND\xae\x42\x60\x82";
    // The camera file and the stamp must be the ones this run would write: a changed scene
    // (e.g. regenerated under the same names), AOV list or output option renders the view
    // again.
    let camera = camera_json(&Camera::new(scene.camera), &opts.exr_aovs(scene));
    let same = |path: &Path, want: &str| std::fs::read(path).is_ok_and(|b| b == want.as_bytes());
    let others = same(&files.camera, &camera)
        && same(&files.stamp, &render_stamp(scene, opts))
        && (!opts.png
            || (file_ends_with(&files.normal_png, PNG_END)
                && file_ends_with(&files.depth_png, PNG_END)));
    others
        && exr_is_complete(
            &files.exr,
            scene.camera.width as usize,
            scene.camera.height as usize,
            &expected_channels(&opts.exr_aovs(scene)),
            opts.compression,
        )
        .is_ok()
}

/// Time spent on one rendered view.
#[derive(Clone, Copy, Debug, Default)]
pub struct ViewCost {
    /// BVH build + tracing into the in-memory AOV image.
    pub trace: Duration,
    /// PNG encoding, EXR encoding, camera JSON, all writes and renames.
    pub write: Duration,
}

/// Write a file under `.partial/` through a buffer. No fsync: a rename after a complete
/// write is what makes a kill at any moment safe; fsync would only add power-loss
/// durability, at ~3 ms per file here (four files per view), and the resume check reads
/// every output back (a file emptied by a power cut fails it and is rendered again).
fn write_unsynced(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    let mut w =
        BufWriter::new(File::create(path).with_context(|| format!("creating {}", path.display()))?);
    fill(&mut w)
        .and_then(|()| Ok(w.flush()?))
        .with_context(|| format!("writing {}", path.display()))
}

/// Render one view into `partial` and move its files into `dir`, the EXR last.
pub fn render_view(
    dir: &Path,
    partial: &Path,
    name: &str,
    scene: &Scene,
    opts: &BatchOptions,
) -> Result<ViewCost> {
    let exr_aovs = opts.exr_aovs(scene);
    let mut aovs = exr_aovs.clone();
    if opts.png {
        for a in [Aov::Depth, Aov::Normal] {
            if !aovs.contains(&a) {
                aovs.push(a);
            }
        }
    }
    let t0 = Instant::now();
    let mut image = render(
        scene,
        &RenderOptions {
            precision: opts.precision,
            formula: opts.formula,
            ..RenderOptions::new(aovs.clone())
        },
    )
    .image;
    let trace = t0.elapsed();

    let t1 = Instant::now();
    let tmp = |suffix: &str| partial.join(format!("{name}.{suffix}.tmp"));
    let done = ViewFiles::new(dir, name);
    let mut moves = Vec::new();
    let cam = Camera::new(scene.camera);
    let camera = tmp("camera.json");
    write_unsynced(&camera, |w| {
        Ok(w.write_all(camera_json(&cam, &exr_aovs).as_bytes())?)
    })?;
    moves.push((camera, &done.camera));
    let stamp = tmp("render.json");
    write_unsynced(&stamp, |w| {
        Ok(w.write_all(render_stamp(scene, opts).as_bytes())?)
    })?;
    moves.push((stamp, &done.stamp));
    if opts.png {
        let normal = preview::normal_rgb(&image).context("no normal AOV")?;
        let depth = preview::depth_u16(&image, opts.depth_scale).context("no depth AOV")?;
        let (normal_tmp, depth_tmp) = (tmp("normal.png"), tmp("depth.png"));
        write_unsynced(&normal_tmp, |w| {
            Ok(normal.write_to(w, image::ImageFormat::Png)?)
        })?;
        write_unsynced(&depth_tmp, |w| {
            Ok(depth.write_to(w, image::ImageFormat::Png)?)
        })?;
        moves.push((normal_tmp, &done.normal_png));
        moves.push((depth_tmp, &done.depth_png));
    }
    let keep: Vec<&str> = exr_aovs
        .iter()
        .flat_map(|&a| channel_names(a).iter().copied())
        .collect();
    image.channels.retain(|c| keep.contains(&c.name.as_str()));
    let exr_tmp = tmp("exr");
    write_unsynced(&exr_tmp, |w| image.write_exr_to(w, opts.compression))?;
    moves.push((exr_tmp, &done.exr));
    // An EXR in place is the view's "done" marker, so an older one goes before any new file
    // of the view replaces its sibling: a re-render killed between the renames leaves no
    // EXR (the view is rendered again), never a new camera beside old PNGs and an old EXR.
    // The EXR goes last: once it is in place, so is everything else of the view.
    // Without PNGs, those of an earlier run go too (they would not match the stamp).
    let stale: &[&PathBuf] = if opts.png {
        &[&done.exr]
    } else {
        &[&done.exr, &done.normal_png, &done.depth_png]
    };
    for path in stale {
        match std::fs::remove_file(path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("removing the old {}", path.display()));
            }
            _ => {}
        }
    }
    for (from, to) in moves {
        std::fs::rename(&from, to)
            .with_context(|| format!("moving {} to {}", from.display(), to.display()))?;
    }
    Ok(ViewCost {
        trace,
        write: t1.elapsed(),
    })
}

// ---- transforms.json -------------------------------------------------------------------

#[derive(Serialize, PartialEq, Clone, Copy, Debug)]
struct Intrinsics {
    w: u32,
    h: u32,
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
}

#[derive(Serialize)]
struct Frame {
    file_path: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_file_path: Option<String>,
    exr_file_path: String,
    camera_file_path: String,
    transform_matrix: [[f64; 4]; 4],
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    intrinsics: Option<Intrinsics>,
}

#[derive(Serialize)]
struct Transforms {
    camera_model: &'static str,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    intrinsics: Option<Intrinsics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_unit_scale_factor: Option<f64>,
    principal_point_note: &'static str,
    frames: Vec<Frame>,
}

/// What `transforms.json` needs of a view's camera.
#[derive(Clone, Copy, Debug)]
pub struct FrameCamera {
    intrinsics: Intrinsics,
    /// OpenGL camera-to-world, row-major.
    transform_matrix: [[f64; 4]; 4],
}

impl FrameCamera {
    pub fn new(cam: &Camera) -> FrameCamera {
        FrameCamera {
            intrinsics: intrinsics(cam),
            transform_matrix: rows(cam.world_from_camera_opengl()),
        }
    }
}

fn intrinsics(cam: &Camera) -> Intrinsics {
    let (fl_x, fl_y) = cam.focal_px();
    let (w, h) = (cam.width(), cam.height());
    Intrinsics {
        w,
        h,
        fl_x,
        fl_y,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
    }
}

/// The nerfstudio / instant-ngp index of every valid view, in view-list order. Shared
/// intrinsics go at the top level; if views differ, every frame carries its own.
/// `file_path` is the normal PNG (the EXR when PNGs are off).
pub fn transforms_json(views: &[(&str, FrameCamera)], opts: &BatchOptions) -> String {
    let shared = views
        .first()
        .map(|(_, c)| c.intrinsics)
        .filter(|first| views.iter().all(|(_, c)| c.intrinsics == *first));
    let frames = views
        .iter()
        .map(|(name, cam)| Frame {
            file_path: if opts.png {
                format!("{name}.normal.png")
            } else {
                format!("{name}.exr")
            },
            depth_file_path: opts.png.then(|| format!("{name}.depth.png")),
            exr_file_path: format!("{name}.exr"),
            camera_file_path: format!("{name}.camera.json"),
            transform_matrix: cam.transform_matrix,
            intrinsics: if shared.is_some() {
                None
            } else {
                Some(cam.intrinsics)
            },
        })
        .collect();
    let t = Transforms {
        camera_model: "OPENCV",
        intrinsics: shared,
        depth_unit_scale_factor: opts.png.then(|| 1.0 / opts.depth_scale),
        principal_point_note: "cx = W/2, cy = H/2: pixel (i, j) has its centre at (i + 0.5, j + 0.5); transform_matrix is camera-to-world with OpenGL axes (x right, y up, z backward)",
        frames,
    };
    let mut s = serde_json::to_string_pretty(&t).unwrap_or_default();
    s.push('\n');
    s
}

// ---- progress --------------------------------------------------------------------------

/// How progress is shown (on stderr).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProgressMode {
    /// A redrawn bar with rate and ETA (a terminal).
    Bar,
    /// One plain line every period (logs, pipes).
    Lines(Duration),
    Off,
}

impl ProgressMode {
    /// Bar on a terminal, a line every 10 s otherwise.
    pub fn auto() -> ProgressMode {
        if std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines(Duration::from_secs(10))
        }
    }
}

/// Counts of one run.
#[derive(Clone, Debug, Default)]
pub struct Counts {
    pub done: usize,
    pub skipped: usize,
    pub failed: usize,
}

struct ProgressState {
    counts: Counts,
    last: Option<Instant>,
}

/// Thread-safe progress reporting for a run of `total` views.
pub struct Progress {
    mode: ProgressMode,
    label: String,
    total: usize,
    start: Instant,
    state: Mutex<ProgressState>,
}

fn hms(secs: f64) -> String {
    let s = secs.round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

impl Progress {
    pub fn new(mode: ProgressMode, label: String, total: usize) -> Progress {
        Progress {
            mode,
            label,
            total,
            start: Instant::now(),
            state: Mutex::new(ProgressState {
                counts: Counts::default(),
                last: None,
            }),
        }
    }

    fn line(&self, c: &Counts) -> String {
        let finished = c.done + c.skipped + c.failed;
        let secs = self.start.elapsed().as_secs_f64();
        // Rate over rendered views only: skipped ones cost nothing.
        let worked = c.done + c.failed;
        let rate = if secs > 0.0 {
            worked as f64 / secs
        } else {
            0.0
        };
        let eta = if rate > 0.0 {
            hms((self.total - finished) as f64 / rate)
        } else {
            "?".into()
        };
        format!(
            "{} {finished}/{} (done {} skipped {} failed {}) {rate:.1} views/s ETA {eta}",
            self.label, self.total, c.done, c.skipped, c.failed
        )
    }

    /// Record one finished view.
    pub fn record(&self, outcome: &Outcome) {
        let Ok(mut st) = self.state.lock() else {
            return;
        };
        match outcome {
            Outcome::Done(_) => st.counts.done += 1,
            Outcome::Skipped => st.counts.skipped += 1,
            Outcome::Failed(_) => st.counts.failed += 1,
        }
        let now = Instant::now();
        let due = |period: Duration| st.last.is_none_or(|t| now - t >= period);
        let mut err = std::io::stderr().lock();
        match self.mode {
            ProgressMode::Bar if due(Duration::from_millis(100)) => {
                let c = &st.counts;
                let finished = c.done + c.skipped + c.failed;
                let width = 24;
                let filled = (finished * width).checked_div(self.total).unwrap_or(width);
                let bar: String = (0..width)
                    .map(|k| if k < filled { '#' } else { '-' })
                    .collect();
                let _ = write!(err, "\r\x1b[2K[{bar}] {}", self.line(c));
                let _ = err.flush();
                st.last = Some(now);
            }
            ProgressMode::Lines(period) if due(period) => {
                let _ = writeln!(err, "{}", self.line(&st.counts));
                st.last = Some(now);
            }
            _ => {}
        }
    }

    /// Final state: the bar is completed and ended with a newline.
    pub fn finish(&self) {
        let Ok(st) = self.state.lock() else { return };
        let mut err = std::io::stderr().lock();
        match self.mode {
            ProgressMode::Bar => {
                let _ = writeln!(
                    err,
                    "\r\x1b[2K[{}] {}",
                    "#".repeat(24),
                    self.line(&st.counts)
                );
            }
            ProgressMode::Lines(_) => {
                let _ = writeln!(err, "{}", self.line(&st.counts));
            }
            ProgressMode::Off => {}
        }
    }
}

// ---- the run ---------------------------------------------------------------------------

/// What happened to one view.
#[derive(Clone, Debug)]
pub enum Outcome {
    Done(ViewCost),
    Skipped,
    Failed(String),
}

/// One line of `failures.K-of-N.jsonl`.
#[derive(Clone, Debug, Serialize)]
pub struct Failure {
    pub name: String,
    pub scene: String,
    pub error: String,
}

/// The result of a run.
#[derive(Clone, Debug)]
pub struct Summary {
    pub shard: Shard,
    /// Views in the whole input and in this shard.
    pub total: usize,
    pub in_shard: usize,
    pub counts: Counts,
    pub failures: Vec<Failure>,
    pub elapsed: Duration,
    /// Sums over the views rendered in this run.
    pub trace: Duration,
    pub write: Duration,
    pub failures_path: PathBuf,
    /// Views checked against the verifier in this run (all agreed unless counted failed).
    pub verified: usize,
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.counts;
        let secs = self.elapsed.as_secs_f64();
        write!(
            f,
            "shard {}: done {} / skipped {} / failed {} of {} views ({} in the input) in {secs:.2} s",
            self.shard, c.done, c.skipped, c.failed, self.in_shard, self.total
        )?;
        if c.done > 0 {
            let per = |d: Duration| d.as_secs_f64() * 1e3 / c.done as f64;
            write!(
                f,
                "; {:.2} views/s; per view: trace {:.2} ms, write {:.2} ms",
                c.done as f64 / secs,
                per(self.trace),
                per(self.write)
            )?;
        }
        if self.verified > 0 {
            write!(
                f,
                "; {} views verified against the reference",
                self.verified
            )?;
        }
        if c.failed > 0 {
            write!(f, "; failures in {}", self.failures_path.display())?;
        }
        Ok(())
    }
}

/// Render `shard` of the views of `input` into `out`; see the module docs. With a
/// `verifier`, the views [`selected_for_verify`] (rendered now or earlier) are checked, and
/// one that disagrees counts as failed. Per-view problems are counted in the summary; only
/// whole-batch problems are errors.
pub fn run(
    input: &Path,
    out: &Path,
    shard: Shard,
    opts: &BatchOptions,
    progress: ProgressMode,
    verifier: Option<&dyn Verifier>,
) -> Result<Summary> {
    let start = Instant::now();
    opts.validate().map_err(anyhow::Error::msg)?;
    let views = list_views(input, Some(out))?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;

    let load =
        |v: &ViewSource| scene::load(&v.path).map_err(|e| format!("{}: {e}", v.path.display()));
    // Every shard reads every scene (transforms.json lists every valid view) but keeps only
    // what transforms.json needs: memory is O(views), not O(views x cylinders). The views of
    // this shard are read again, one at a time, when rendered.
    let cameras: Vec<Result<FrameCamera, String>> = views
        .par_iter()
        .map(|v| load(v).map(|s| FrameCamera::new(&Camera::new(s.camera))))
        .collect();

    let partial = out.join(".partial").join(shard.to_string());
    if partial.exists() {
        std::fs::remove_dir_all(&partial)
            .with_context(|| format!("clearing {}", partial.display()))?;
    }
    std::fs::create_dir_all(&partial).with_context(|| format!("creating {}", partial.display()))?;

    let mine: Vec<usize> = (0..views.len()).filter(|&i| shard.contains(i)).collect();
    let progress = Progress::new(progress, format!("batch {shard}"), mine.len());
    let verified = std::sync::atomic::AtomicUsize::new(0);
    let one = |i: usize| -> Outcome {
        let view = &views[i];
        let scene = match &cameras[i] {
            Err(e) => Err(e.clone()),
            Ok(_) => load(view),
        };
        let mut outcome = match &scene {
            Err(e) => Outcome::Failed(e.clone()),
            Ok(scene) if view_is_complete(out, &view.name, scene, opts) => Outcome::Skipped,
            Ok(scene) => match render_view(out, &partial, &view.name, scene, opts) {
                Ok(cost) => Outcome::Done(cost),
                Err(e) => Outcome::Failed(format!("{}: {e:#}", view.path.display())),
            },
        };
        if let (Some(v), Ok(scene)) = (verifier, &scene)
            && !matches!(outcome, Outcome::Failed(_))
            && selected_for_verify(opts.verify_seed, &view.name, opts.verify_fraction)
        {
            let exr = ViewFiles::new(out, &view.name).exr;
            let work = partial.join(format!("{}.verify.tmp", view.name));
            let checked = std::fs::create_dir_all(&work)
                .map_err(anyhow::Error::from)
                .and_then(|()| v.check(view, scene, &exr, &work));
            let _ = std::fs::remove_dir_all(&work);
            verified.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            match checked {
                Ok(verdict) if verdict.passes => {}
                Ok(verdict) => {
                    outcome = Outcome::Failed(format!(
                        "{}: disagrees with the reference: {}",
                        view.path.display(),
                        verdict.report
                    ))
                }
                Err(e) => {
                    outcome = Outcome::Failed(format!(
                        "{}: verification could not run: {e:#}",
                        view.path.display()
                    ))
                }
            }
        }
        progress.record(&outcome);
        outcome
    };
    let outcomes: Vec<Outcome> = match opts.schedule {
        Schedule::Views => mine.par_iter().map(|&i| one(i)).collect(),
        Schedule::Pixels => mine.iter().map(|&i| one(i)).collect(),
    };
    progress.finish();

    let mut summary = Summary {
        shard,
        total: views.len(),
        in_shard: mine.len(),
        counts: Counts::default(),
        failures: Vec::new(),
        elapsed: Duration::ZERO,
        trace: Duration::ZERO,
        write: Duration::ZERO,
        failures_path: out.join(format!("failures.{shard}.jsonl")),
        verified: verified.into_inner(),
    };
    for (&i, o) in mine.iter().zip(&outcomes) {
        match o {
            Outcome::Done(cost) => {
                summary.counts.done += 1;
                summary.trace += cost.trace;
                summary.write += cost.write;
            }
            Outcome::Skipped => summary.counts.skipped += 1,
            Outcome::Failed(e) => {
                summary.counts.failed += 1;
                summary.failures.push(Failure {
                    name: views[i].name.clone(),
                    scene: views[i].path.display().to_string(),
                    error: e.clone(),
                });
            }
        }
    }
    let mut lines = String::new();
    for f in &summary.failures {
        lines.push_str(&serde_json::to_string(f)?);
        lines.push('\n');
    }
    atomic_write_bytes(&summary.failures_path, lines.as_bytes())
        .with_context(|| format!("writing {}", summary.failures_path.display()))?;

    let valid: Vec<(&str, FrameCamera)> = views
        .iter()
        .zip(&cameras)
        .filter_map(|(v, c)| c.as_ref().ok().map(|c| (v.name.as_str(), *c)))
        .collect();
    let transforms = out.join("transforms.json");
    atomic_write_bytes(&transforms, transforms_json(&valid, opts).as_bytes())
        .with_context(|| format!("writing {}", transforms.display()))?;

    std::fs::remove_dir_all(&partial).with_context(|| format!("removing {}", partial.display()))?;
    // Other shards may still be using `.partial`; it goes when the last one leaves.
    let _ = std::fs::remove_dir(out.join(".partial"));
    summary.elapsed = start.elapsed();
    Ok(summary)
}

/// The verdict of a [`Verifier`] on one view.
#[derive(Clone, Debug)]
pub struct Verdict {
    pub passes: bool,
    /// One line for the log or the failures file (error statistics, mismatches).
    pub report: String,
}

/// Checks a rendered view against an independent reference. The Mitsuba implementation is
/// `crate::verify::reference::MitsubaVerifier`; batch only knows this interface.
pub trait Verifier: Sync {
    /// `exr` is the view's finished EXR; `work` a private folder for temporary files.
    fn check(&self, view: &ViewSource, scene: &Scene, exr: &Path, work: &Path) -> Result<Verdict>;
}

/// Whether view `name` is in the seed-determined `fraction` checked against Mitsuba:
/// a hash of (seed, name), so the choice does not depend on sharding or order.
pub fn selected_for_verify(seed: u64, name: &str, fraction: f64) -> bool {
    if fraction <= 0.0 {
        return false;
    }
    if fraction >= 1.0 {
        return true;
    }
    // FNV-1a over the name, then mixed with the seed.
    let h = Fnv1a::new().bytes(name.as_bytes()).0;
    let u = (mix64(h ^ mix64(seed)) >> 11) as f64 / (1u64 << 53) as f64;
    u < fraction
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_partition() {
        assert_eq!(Shard::parse("2/7"), Ok(Shard { index: 2, count: 7 }));
        assert!(Shard::parse("7/7").unwrap_err().contains("must be < count"));
        assert!(Shard::parse("1/0").is_err());
        assert!(Shard::parse("a/2").is_err());
        for n in [1u32, 2, 7] {
            let mut hits = vec![0; 50];
            for k in 0..n {
                let s = Shard::new(k, n).unwrap();
                (0..50)
                    .filter(|&i| s.contains(i))
                    .for_each(|i| hits[i] += 1);
            }
            assert!(hits.iter().all(|&h| h == 1), "N = {n}: {hits:?}");
        }
    }

    #[test]
    fn shard_from_environment() {
        let env = |vars: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                vars.iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| v.to_string())
            }
        };
        let none = env(&[]);
        assert_eq!(resolve_shard(None, None, &none), Ok(Shard::ALL));
        let slurm = env(&[
            ("SLURM_ARRAY_TASK_ID", "12"),
            ("SLURM_ARRAY_TASK_MIN", "10"),
            ("SLURM_ARRAY_TASK_COUNT", "4"),
        ]);
        assert_eq!(
            resolve_shard(None, None, &slurm),
            Ok(Shard::new(2, 4).unwrap())
        );
        let k8s = env(&[("JOB_COMPLETION_INDEX", "3")]);
        assert_eq!(
            resolve_shard(None, Some(5), &k8s),
            Ok(Shard::new(3, 5).unwrap())
        );
        assert!(
            resolve_shard(None, Some(3), &k8s)
                .unwrap_err()
                .contains("must be < count")
        );
        assert!(
            resolve_shard(None, Some(3), &none)
                .unwrap_err()
                .contains("JOB_COMPLETION_INDEX")
        );
        let explicit = Some(Shard::new(1, 2).unwrap());
        assert_eq!(
            resolve_shard(explicit, None, &slurm),
            explicit.ok_or(String::new())
        );
        assert!(resolve_shard(explicit, Some(2), &none).is_err());
        let bad = env(&[("SLURM_ARRAY_TASK_ID", "x")]);
        assert!(
            resolve_shard(None, None, &bad)
                .unwrap_err()
                .contains("SLURM_ARRAY_TASK_ID")
        );
    }

    #[test]
    fn stamp_names_the_version_and_options() {
        let scene = crate::bench::random_scene(3, 1, 8, 8);
        let stamp = render_stamp(&scene, &BatchOptions::default());
        let v: serde_json::Value = serde_json::from_str(&stamp).unwrap();
        assert_eq!(v["cylaov"], env!("CARGO_PKG_VERSION"));
        assert_eq!(v["precision"], "f64");
        let mut other = scene.clone();
        other.cylinders[1].radius *= 1.0 + f64::EPSILON;
        assert_ne!(render_stamp(&other, &BatchOptions::default()), stamp);
    }

    #[test]
    fn names_are_checked() {
        assert!(check_name("000001").is_ok());
        assert!(check_name("a/b").is_err());
        assert!(check_name(".hidden").is_err());
        assert!(check_name("").is_err());
    }

    #[test]
    fn verify_selection_is_a_stable_fraction() {
        let picked = (0..10_000)
            .filter(|i| selected_for_verify(7, &format!("{i:06}"), 0.1))
            .count();
        assert!((900..1100).contains(&picked), "{picked}");
        assert!(!selected_for_verify(7, "a", 0.0));
        assert!(selected_for_verify(7, "a", 1.0));
    }
}
