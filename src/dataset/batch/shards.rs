//! Tar shards (`batch --format webdataset`): the batch's views as POSIX ustar archives that
//! webdataset, Hugging Face `datasets` and Ray Data read as they are.
//!
//! **Layout.** With shard size S, tar `j` (`OUT/shard-00000j.tar`) holds the views
//! `[jS, (j+1)S)` of the batch's view list (the list the files format renders). A view's
//! key is its view name without dots: the scene's name (`000123`), or `SCENE_cNN` for
//! camera NN of a several-camera scene (`000123_c04`); a scene name with a dot (webdataset
//! cuts a member's name at its first dot) or two views with one key are refused before
//! anything renders. Per view, in this order: `KEY.depth.npy` (`(H,W)` float32, planar
//! depth, 0 on a miss), `KEY.normal.npy` (`(H,W,3)` float32), one `KEY.<aov>.npy` per
//! other AOV of the dataset's one AOV set (float32, `shape_id`/`part` uint32),
//! `KEY.mask.npy` (`(H,W)` bool, true on a hit), `KEY.json` (the camera JSON's fields named
//! as there, with the key, scene, scene file, camera index, depth kind, units, miss values,
//! array shapes and the cylaov version); with `--members exr,depth.png`, `KEY.exr` and
//! `KEY.depth.png`, the bytes the files format writes. A view that fails keeps its slot: it
//! is absent from its tar and listed in the sidecar and the failures file.
//!
//! A view's members come from its `crate::output::pipeline::view::ViewPlan`, executed into a tar
//! sink (`TarSink`, behind [`view_members`]): the arrays from the traced image, `KEY.json`
//! from the plan's camera member, `KEY.exr` and `KEY.depth.png` from the plan's own members
//! (not encoded unless asked for).
//!
//! **Determinism.** Members in that fixed order, every header fixed (see
//! `crate::output::format::tar`), scene files named relative to the input folder: a tar is a pure
//! function of the input and the options, whichever process or engine writes it.
//!
//! **Writing and resume.** Each tar is a unit of the batch driver (`super::driver`),
//! which the files format runs on too. A tar is written under
//! `OUT/.partial/J-of-T/shard-00000j.tar.tmp` and renamed into place; then its sidecar `OUT/shard-00000j.json` (sample count, byte count,
//! sha256, the stamp of its inputs and options, its failures) is written, so a sidecar on
//! disk vouches for a whole tar. A rerun skips a tar whose sidecar has this run's stamp and
//! whose file has the recorded size and sha256, and writes the others again. Each tar is
//! written under its own lock (`OUT/.partial/J-of-T.lock`, T the tar count); `--shard K/N`
//! assigns the tars with `j % N == K`. Whichever process finds every sidecar in place
//! writes `OUT/shards.json` from them under the lock `OUT/.partial/shards.json.lock`.
//!
//! **Verification.** With a [`Verifier`], the views [`view_selected`](super::view_selected) are checked as the
//! files format checks them: the view's EXR (the plan's own, encoded whether or not
//! `KEY.exr` is a member) goes to a private file under `OUT/.partial` that the verifier
//! reads. A view that disagrees fails as a render failure does; the others' members are
//! those of an unverified run. The views of a tar already on disk and kept are checked
//! too, from an EXR rendered again (the tar is a pure function of the same inputs): one
//! that disagrees is listed with the failures, and the tar stays as it is.
//!
//! **Parallelism and memory.** Within a tar the pool renders a window of views at once;
//! each rendered view is laid out at the tar's end and hashed in view order, by whichever
//! worker finds it next in line, and that worker then writes it at its offset (a
//! positional write) while another lays out and hashes the views after it. So only the
//! hash is in line; the render and the write of a view overlap others'. One worker
//! writes a tar at a time: one that finds the tar being written hands its view to the
//! writer and goes back to rendering (the kernel would make it spin on the file's lock
//! instead), and at most one view a tar waits so. Several tars are written at once, each
//! lane taking the next tar when it finishes one. How many tars and how large a window
//! come from the largest view's estimate (its whole image, which a tar's view holds until
//! it is written, and its encoded members) and half of what the machine leaves, so the
//! views held (at most two windows and the one waiting view a tar) stay within it. Each
//! view's estimate is also checked before it renders, as in the files format: a view that
//! does not fit fails alone.

mod sample;
mod tar_file;

use super::driver::{self, Container, Rendered, Run, Start, Unit};
use super::failures::write_failures;
use super::input::{expand_views, input_dir, read_views};
use super::lock::{lock_named, partial_root};
use super::options::BatchOptions;
use super::progress::{Outcome, Progress, ProgressMode, SizeEstimate};
use super::resume::render_stamp;
use super::shard::Shard;
use super::shard_settings;
use super::verify::Verifier;
use super::views::{ViewSource, list_views};
use crate::output::console::{self, count};
use crate::output::format::camera_files::record_json;
use crate::output::format::tar;
use crate::output::store::atomic::atomic_write_bytes;
use crate::output::store::files::{create_new, open_regular, read_regular};
use crate::output::store::targets::check_outputs;
use crate::scene::{Aov, Scene};
use crate::spelling::opt;
use anyhow::{Context, Result, bail};
pub use sample::{MemberBytes, Members, view_members, view_tar_bytes};
use sample::{array_aovs, member_suffixes, tar_view_memory, view_members_and_exr};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};
use tar_file::{TarFile, ViewBytes};

/// Views a tar holds unless told otherwise.
pub const DEFAULT_SHARD_SIZE: usize = 1000;

crate::choice_enum! {
    /// An optional member of each view.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
    pub enum Member {
        /// `KEY.exr`: the layered EXR the files format writes.
        Exr = "exr",
        /// `KEY.depth.png`: the 16-bit depth PNG the files format writes.
        DepthPng = "depth.png",
        /// `KEY.ply`: the view's hit points as a PLY point cloud (position, normal, ids),
        /// as `render --ply` writes it.
        Ply = "ply",
    }
}

impl Member {
    fn name(self) -> &'static str {
        match self {
            Member::Exr => "exr",
            Member::DepthPng => "depth.png",
            Member::Ply => "ply",
        }
    }
}

/// What a sharded batch writes besides the views' options.
#[derive(Clone, Debug)]
pub struct ShardOptions {
    /// Views per tar, >= 1.
    pub shard_size: usize,
    /// Optional members of each view.
    pub members: Vec<Member>,
    /// Replace a dataset the output folder holds with other settings (its tar-shard files
    /// are removed first) instead of refusing (see [`super::shard_settings`]).
    pub force: bool,
}

impl Default for ShardOptions {
    fn default() -> Self {
        ShardOptions {
            shard_size: DEFAULT_SHARD_SIZE,
            members: Vec::new(),
            force: false,
        }
    }
}

/// Which tars this process writes.
#[derive(Clone, Debug)]
pub enum TarSelection {
    /// The tars `j` with `j % count == index`.
    Shard(Shard),
    /// These tars.
    List(Vec<usize>),
}

/// What happened to one tar.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TarOutcome {
    /// Written now.
    Written,
    /// Its sidecar vouched for it: untouched.
    Skipped,
}

/// The result of a sharded run.
#[derive(Clone, Debug)]
pub struct ShardSummary {
    /// Views in the whole input.
    pub views: usize,
    /// Tars of the whole dataset.
    pub tars: usize,
    /// The tars this process handled and what happened to each.
    pub outcomes: Vec<(usize, TarOutcome)>,
    /// Views rendered now (in the tars written now).
    pub rendered: usize,
    /// Failed views of this process's tars (now or recorded by their sidecars).
    pub failures: Vec<ShardFailure>,
    /// Where they are listed.
    pub failures_path: PathBuf,
    /// Views checked by the verifier in this run (all agreed unless among the failures).
    pub verified: usize,
    /// Whether this process wrote `shards.json` (every sidecar was in place).
    pub index_written: bool,
    /// What could not be cleaned up after the tars were written (a tar's work folder).
    pub problems: Vec<String>,
    /// Wall time.
    pub elapsed: Duration,
}

impl std::fmt::Display for ShardSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let written = self
            .outcomes
            .iter()
            .filter(|o| o.1 == TarOutcome::Written)
            .count();
        let secs = self.elapsed.as_secs_f64();
        write!(
            f,
            "webdataset: {} written, {} skipped, of {} ({} in the input); {} rendered in \
             {secs:.2} s",
            count(written, "tar"),
            self.outcomes.len() - written,
            self.tars,
            count(self.views, "view"),
            count(self.rendered, "view")
        )?;
        if self.rendered > 0 && secs > 0.0 {
            write!(f, "; {:.1} views/s", self.rendered as f64 / secs)?;
        }
        if self.verified > 0 {
            write!(
                f,
                "; {} views verified against the reference",
                self.verified
            )?;
        }
        if !self.failures.is_empty() {
            write!(
                f,
                "; {} views failed (see {})",
                self.failures.len(),
                self.failures_path.display()
            )?;
        }
        if self.index_written {
            write!(f, "; shards.json written")?;
        }
        Ok(())
    }
}

/// A failed view of a tar.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ShardFailure {
    /// The view's key.
    pub key: String,
    /// The view's id in the files format (`scene` or `scene/00`).
    pub name: String,
    /// The scene file, relative to the input folder.
    pub scene: String,
    /// Why it failed.
    pub error: String,
}

/// `OUT/shard-00000j.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
struct Sidecar {
    name: String,
    samples: usize,
    bytes: u64,
    sha256: String,
    stamp: String,
    first_view: usize,
    end_view: usize,
    failures: Vec<ShardFailure>,
}

/// `shard-00000j` (without extension).
pub fn shard_stem(j: usize) -> String {
    format!("shard-{j:06}")
}

/// The key of `view`: its view name without dots (see the module docs).
pub fn view_key(view: &ViewSource) -> String {
    match &view.folder {
        Some(scene) => format!("{scene}_c{}", view.name),
        None => view.name.clone(),
    }
}

/// The keys of `views`, each checked against the member names it will have (`suffixes`,
/// such as `.depth.npy`): a dotted scene name, a name a tar header cannot hold (not ASCII,
/// or too long) and two views with one key are refused, every one of them listed, before
/// anything renders.
fn keys(views: &[ViewSource], suffixes: &[String]) -> Result<Vec<String>> {
    /// Problems listed in full before "and N more".
    const LISTED: usize = 20;
    let mut seen: HashMap<String, &ViewSource> = HashMap::new();
    let mut keys = Vec::with_capacity(views.len());
    let mut problems: Vec<String> = Vec::new();
    // A scene's problem is listed once, not once for each of its cameras.
    let mut listed: std::collections::HashSet<String> = Default::default();
    let mut problem = |p: String| {
        if listed.insert(p.clone()) {
            problems.push(p);
        }
    };
    for v in views {
        let key = view_key(v);
        if key.contains('.') {
            problem(format!(
                "{}: scene name {:?} has a '.' (readers cut a member name at its first dot)",
                v.path.display(),
                v.scene
            ));
        } else if let Some(Err(why)) = suffixes
            .iter()
            .map(|s| tar::header(&format!("{key}{s}"), 0).map(|_| ()))
            .find(Result::is_err)
        {
            problem(format!("{}: {why}", v.path.display()));
        }
        if let Some(other) = seen.get(&key) {
            problem(format!(
                "views {:?} ({}) and {:?} ({}) would both have the key {key:?}",
                other.id(),
                other.path.display(),
                v.id(),
                v.path.display()
            ));
        }
        seen.insert(key.clone(), v);
        keys.push(key);
    }
    if !problems.is_empty() {
        let n = problems.len();
        let mut text = problems
            .iter()
            .take(LISTED)
            .map(|p| format!("\n  {p}"))
            .collect::<String>();
        if n > LISTED {
            text += &format!("\n  and {} more", n - LISTED);
        }
        bail!(
            "the view names cannot all be tar shard keys ({}; a key is the view name, SCENE \
             or SCENE_cNN: ASCII, without dots, unique, short enough for its longest member \
             name to fit 100 bytes); rename the scene files or give them manifest names:{text}",
            console::count(n, "problem")
        );
    }
    Ok(keys)
}

/// The name of the failures file of a call that writes the tars `list` (sorted, without
/// repeats): `tar-000003` for one, `tars-000001-000003` for a few, and for many the first,
/// the last, the count and a hash of the list, so two calls with other tars never share
/// (and overwrite) one record.
fn failures_label(list: &[usize]) -> String {
    /// Tars named one by one, at most (a name stays under 80 bytes).
    const NAMED: usize = 8;
    match list {
        [j] => format!("tar-{j:06}"),
        l if l.len() <= NAMED => {
            let ids: Vec<String> = l.iter().map(|j| format!("{j:06}")).collect();
            format!("tars-{}", ids.join("-"))
        }
        l => {
            let mut h = Sha256::new();
            for j in l {
                h.update(format!("{j}\n").as_bytes());
            }
            let hash: String = h.finalize()[..4]
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect();
            format!(
                "tars-{:06}-to-{:06}-{}-{hash}",
                l[0],
                l[l.len() - 1],
                l.len()
            )
        }
    }
}

/// `dir` made absolute for a record (`""`, a scene file's folder given bare, is `.`).
fn absolute_dir(dir: &Path) -> String {
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    std::path::absolute(dir)
        .unwrap_or_else(|_| dir.to_path_buf())
        .display()
        .to_string()
}

/// The number of tars `input` makes at `shard_size` views a tar.
pub fn shard_count(input: &Path, shard_size: usize) -> Result<usize> {
    if shard_size == 0 {
        bail!("{}: must be >= 1, got 0", opt("shard_size"));
    }
    let (scenes, _) = list_views(input, None)?;
    let (views, _) = expand_views(&scenes, &BatchOptions::default());
    Ok(views.len().div_ceil(shard_size))
}

/// The one AOV set of the dataset: `--aov`, else the scenes' own when all agree; in
/// the arrays' order ([`array_aovs`]), without repeats, so the order they are given in changes neither
/// the settings nor a byte of the tars.
fn dataset_aovs(
    opts: &BatchOptions,
    views: &[ViewSource],
    cameras: &[Result<super::FrameCamera, String>],
) -> Result<Vec<Aov>> {
    // The arrays' order (depth, normal, then the rest in `Aov::ALL`'s), less those not asked.
    let canonical = |aovs: &[Aov]| -> Vec<Aov> {
        array_aovs(aovs)
            .into_iter()
            .filter(|a| aovs.contains(a))
            .collect()
    };
    if let Some(a) = &opts.aovs {
        return Ok(canonical(a));
    }
    let mut found: Option<(Vec<Aov>, &ViewSource)> = None;
    for (v, c) in views.iter().zip(cameras) {
        let Ok(c) = c else { continue };
        let aovs = canonical(&c.aovs().collect::<Vec<_>>());
        match &found {
            None => found = Some((aovs, v)),
            Some((first, fv)) if *first != aovs => bail!(
                "{} webdataset stores one AOV set for every view, but {} lists {} and \
                 {} lists {}: give {}",
                opt("format"),
                fv.path.display(),
                names(first),
                v.path.display(),
                names(&aovs),
                opt("aov")
            ),
            Some(_) => {}
        }
    }
    Ok(found
        .map(|f| f.0)
        .unwrap_or_else(|| vec![Aov::Depth, Aov::Normal]))
}

fn names(aovs: &[Aov]) -> String {
    aovs.iter().map(|a| a.name()).collect::<Vec<_>>().join(",")
}

/// An option value's name as the record files spell it (`f64`, `stable`).
fn value_name(v: impl crate::choice::Choice) -> String {
    v.choice_name().to_string()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The sha256 and length of the regular file at `path`.
fn file_sha256(path: &Path) -> std::io::Result<(String, u64)> {
    let mut f = open_regular(path)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut len = 0u64;
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
        len += n as u64;
    }
    Ok((hex(&h.finalize()), len))
}

/// The views of tar `j`, `shard_size` a tar, of `n` views in all.
fn tar_views(j: usize, shard_size: usize, n: usize) -> std::ops::Range<usize> {
    j * shard_size..((j + 1) * shard_size).min(n)
}

/// Everything a sharded run shares: the tar container of the batch driver.
struct Plan<'a> {
    out: &'a Path,
    root: PathBuf,
    input_dir: PathBuf,
    views: Vec<ViewSource>,
    cameras: Vec<Result<super::FrameCamera, String>>,
    keys: Vec<String>,
    aovs: Vec<Aov>,
    opts: BatchOptions,
    sopts: &'a ShardOptions,
    tars: usize,
    /// Whether the files format would write PNGs (for its size estimate).
    files_png: bool,
    /// [`Plan::settings`], made once: every commit checks the record against it.
    settings: std::sync::OnceLock<shard_settings::Settings>,
}

/// A tar being written under `OUT/.partial/J-of-T/`: laid out and hashed in view order,
/// each view's bytes then written at their offset ([`TarFile`]), so one view's write
/// overlaps the next one's hash.
struct OpenTar {
    file: Arc<TarFile>,
    /// Where the next member goes: the bytes laid out so far.
    at: u64,
    hash: Sha256,
    stamp: String,
    samples: usize,
}

/// A view laid out in its tar, to be written there.
struct PlacedView {
    file: Arc<TarFile>,
    bytes: ViewBytes,
}

impl Plan<'_> {
    fn range(&self, j: usize) -> std::ops::Range<usize> {
        tar_views(j, self.sopts.shard_size, self.views.len())
    }

    fn tar_path(&self, j: usize) -> PathBuf {
        self.out.join(format!("{}.tar", shard_stem(j)))
    }

    fn sidecar_path(&self, j: usize) -> PathBuf {
        self.out.join(format!("{}.json", shard_stem(j)))
    }

    fn failure(&self, i: usize, error: String) -> ShardFailure {
        let v = &self.views[i];
        ShardFailure {
            key: self.keys[i].clone(),
            name: v.id(),
            scene: v
                .path
                .strip_prefix(&self.input_dir)
                .unwrap_or(&v.path)
                .display()
                .to_string(),
            error,
        }
    }

    /// The stamp of tar `j`: a hash of the options and, per view, its key, camera and
    /// render stamp (or why its scene does not load).
    fn stamp(&self, scenes: &[Result<Scene, String>], j: usize) -> String {
        let mut h = Sha256::new();
        let members: Vec<&str> = self.sopts.members.iter().map(|m| m.name()).collect();
        h.update(
            format!(
                "cylaov {} webdataset size {} members {:?} aovs {}\n",
                env!("CARGO_PKG_VERSION"),
                self.sopts.shard_size,
                members,
                names(&self.aovs)
            )
            .as_bytes(),
        );
        for (i, s) in self.range(j).zip(scenes) {
            h.update(format!("{} {}\n", self.keys[i], self.views[i].camera).as_bytes());
            match s {
                Ok(s) => h.update(render_stamp(s, &self.opts).as_bytes()),
                Err(e) => h.update(format!("unreadable: {e}\n").as_bytes()),
            }
        }
        hex(&h.finalize())
    }

    /// What every tar of the dataset is written with (see [`shard_settings`]).
    fn settings(&self) -> &shard_settings::Settings {
        self.settings.get_or_init(|| self.make_settings())
    }

    fn make_settings(&self) -> shard_settings::Settings {
        let mut inputs = Sha256::new();
        for k in &self.keys {
            inputs.update(k.as_bytes());
            inputs.update(b"\n");
        }
        shard_settings::Settings {
            shard_size: self.sopts.shard_size,
            tars: self.tars,
            views: self.views.len(),
            inputs: hex(&inputs.finalize()),
            // As asked (the sample's JSON and `exr` member list them), not the arrays,
            // which always add depth and normal.
            aovs: self.aovs.iter().map(|a| a.name().to_string()).collect(),
            members: self
                .sopts
                .members
                .iter()
                .map(|m| m.name().to_string())
                .collect(),
            precision: value_name(self.opts.precision),
            formula: value_name(self.opts.formula),
            compression: self
                .sopts
                .members
                .contains(&Member::Exr)
                .then(|| value_name(self.opts.compression)),
            depth_scale: self.depth_png().then_some(self.opts.depth_scale),
            depth_out_of_range: self
                .depth_png()
                .then(|| value_name(self.opts.depth_out_of_range)),
        }
    }

    /// Whether each view has the `depth.png` member.
    fn depth_png(&self) -> bool {
        self.sopts.members.contains(&Member::DepthPng)
    }

    /// The sidecar of tar `j` if it vouches for the tar on disk with this `stamp`.
    fn vouched(&self, j: usize, stamp: &str) -> Option<Sidecar> {
        let bytes = read_regular(&self.sidecar_path(j)).ok()?;
        let car: Sidecar = serde_json::from_slice(&bytes).ok()?;
        if car.stamp != stamp {
            return None;
        }
        let meta = self.tar_path(j).symlink_metadata().ok()?;
        if !meta.is_file() || meta.len() != car.bytes {
            return None;
        }
        let (sha, _) = file_sha256(&self.tar_path(j)).ok()?;
        (sha == car.sha256).then_some(car)
    }

    /// Write `shards.json` from the sidecars if every one is in place; whether it was.
    fn merge_index(&self) -> Result<bool> {
        let _lock = lock_named(self.out, &self.root, "shards.json")?;
        // Only while the folder still records this run's dataset: its sidecars are then
        // all of this dataset's (a run with other settings replaces them all first).
        let _settings = shard_settings::still_held(self.out, &self.root, self.settings())?;
        let mut cars = Vec::with_capacity(self.tars);
        for j in 0..self.tars {
            let Some(car) = read_regular(&self.sidecar_path(j))
                .ok()
                .and_then(|b| serde_json::from_slice::<Sidecar>(&b).ok())
            else {
                return Ok(false);
            };
            let in_place = self
                .tar_path(j)
                .symlink_metadata()
                .is_ok_and(|m| m.is_file() && m.len() == car.bytes);
            if !in_place || car.first_view != self.range(j).start {
                return Ok(false);
            }
            cars.push(car);
        }
        #[derive(Serialize)]
        struct Entry<'a> {
            name: &'a str,
            samples: usize,
            bytes: u64,
            sha256: &'a str,
            failed: usize,
        }
        #[derive(Serialize)]
        struct Index<'a> {
            format: &'static str,
            cylaov_version: &'static str,
            views: usize,
            samples: usize,
            shard_size: usize,
            aovs: Vec<&'static str>,
            members: Vec<String>,
            precision: String,
            formula: String,
            #[serde(skip_serializing_if = "Option::is_none")]
            compression: Option<&'a str>,
            #[serde(skip_serializing_if = "Option::is_none")]
            depth_scale: Option<f64>,
            #[serde(skip_serializing_if = "Option::is_none")]
            depth_out_of_range: Option<&'a str>,
            keys_note: &'static str,
            scenes_dir: String,
            shards: Vec<Entry<'a>>,
        }
        let mut members: Vec<String> = array_aovs(&self.aovs)
            .iter()
            .map(|a| format!("{}.npy", a.name()))
            .collect();
        members.extend(["mask.npy".to_string(), "json".to_string()]);
        members.extend(self.sopts.members.iter().map(|m| m.name().to_string()));
        let index = Index {
            format: "webdataset",
            cylaov_version: env!("CARGO_PKG_VERSION"),
            views: self.views.len(),
            samples: cars.iter().map(|c| c.samples).sum(),
            shard_size: self.sopts.shard_size,
            // What the tars hold: depth and normal are always among the arrays.
            aovs: array_aovs(&self.aovs).iter().map(|a| a.name()).collect(),
            members,
            precision: value_name(self.opts.precision),
            formula: value_name(self.opts.formula),
            compression: self.settings().compression.as_deref(),
            depth_scale: self.settings().depth_scale,
            depth_out_of_range: self.settings().depth_out_of_range.as_deref(),
            keys_note: "a sample's key is its view name without dots: SCENE, or SCENE_cNN for camera NN of a several-camera scene",
            // Where the samples' `scene_file` paths start (`cylaov verify OUT` reads the
            // scenes from there); absolute, so the record holds wherever OUT is read from.
            scenes_dir: absolute_dir(&self.input_dir),
            shards: cars
                .iter()
                .map(|c| Entry {
                    name: &c.name,
                    samples: c.samples,
                    bytes: c.bytes,
                    sha256: &c.sha256,
                    failed: c.failures.len(),
                })
                .collect(),
        };
        let path = self.out.join("shards.json");
        let mut text = record_json(&index);
        text.push('\n');
        atomic_write_bytes(&path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(true)
    }
}

impl Container for Plan<'_> {
    type View = Members;
    type Open = OpenTar;
    type Record = Sidecar;
    type Placed = PlacedView;
    const SCENES_AHEAD: bool = true;

    /// Keep tar `j` if its sidecar vouches for it with this run's stamp; else start it
    /// afresh under `work`, its old sidecar removed first.
    fn start(
        &self,
        unit: &Unit,
        scenes: &[Result<Scene, String>],
        work: &Path,
    ) -> Result<Start<OpenTar, Sidecar>> {
        let j = unit.name.index as usize;
        let stamp = self.stamp(scenes, j);
        if let Some(car) = self.vouched(j, &stamp) {
            return Ok(Start::Kept(car));
        }
        let sidecar = self.sidecar_path(j);
        match std::fs::remove_file(&sidecar) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("removing the old {}", sidecar.display()));
            }
            _ => {}
        }
        let tmp = work.join(format!("{}.tar.tmp", shard_stem(j)));
        let file = create_new(&tmp)
            .map_err(crate::output::store::atomic::explain)
            .with_context(|| format!("creating {}", tmp.display()))?;
        Ok(Start::Open(OpenTar {
            file: Arc::new(TarFile::new(file, tmp)),
            at: 0,
            hash: Sha256::new(),
            stamp,
            samples: 0,
        }))
    }

    fn render(
        &self,
        i: usize,
        scene: &Scene,
        _work: &Path,
        exr: bool,
    ) -> Result<Rendered<Members>, String> {
        let view = &self.views[i];
        let (members, exr) = view_members_and_exr(
            &self.keys[i],
            view,
            scene,
            &self.input_dir,
            &self.aovs,
            &self.opts,
            &self.sopts.members,
            exr,
        )
        .map_err(|e| format!("{}: {e:#}", view.path.display()))?;
        Ok(Rendered {
            view: members,
            cost: Default::default(),
            exr,
        })
    }

    fn exr_path(&self, i: usize, check_work: &Path) -> PathBuf {
        check_work.join(format!("{}.exr", self.keys[i]))
    }

    /// Lay the view's members out at the tar's end and hash them.
    fn accept(&self, open: &mut OpenTar, _i: usize, members: Members) -> Result<PlacedView> {
        let bytes = ViewBytes::new(open.at, members, open.file.path())?;
        for b in bytes.pieces() {
            open.hash.update(b);
            open.at += b.len() as u64;
        }
        open.samples += 1;
        Ok(PlacedView {
            file: open.file.clone(),
            bytes,
        })
    }

    /// Write a view's bytes where [`Plan::accept`] laid them out.
    fn place(&self, view: PlacedView) -> Result<()> {
        view.file.write(view.bytes)
    }

    /// Finish the tar, move it into place, then write the sidecar that vouches for it.
    fn commit(&self, unit: &Unit, open: OpenTar, failed: &[(usize, &str)]) -> Result<Sidecar> {
        let OpenTar {
            file,
            at,
            mut hash,
            stamp,
            samples,
        } = open;
        file.close(at)?;
        hash.update(tar::CLOSING);
        let bytes = at + tar::CLOSING.len() as u64;
        let tmp = file.path().to_path_buf();
        drop(file);
        let j = unit.name.index as usize;
        let dest = self.tar_path(j);
        // The tar and its sidecar land only while the folder records this run's dataset.
        let _settings = shard_settings::still_held(self.out, &self.root, self.settings())?;
        std::fs::rename(&tmp, &dest)
            .with_context(|| format!("moving {} to {}", tmp.display(), dest.display()))?;
        let range = self.range(j);
        let car = Sidecar {
            name: format!("{}.tar", shard_stem(j)),
            samples,
            bytes,
            sha256: hex(&hash.finalize()),
            stamp,
            first_view: range.start,
            end_view: range.end,
            failures: failed
                .iter()
                .map(|&(i, e)| self.failure(i, e.to_string()))
                .collect(),
        };
        let sidecar = self.sidecar_path(j);
        let mut text = record_json(&car);
        text.push('\n');
        atomic_write_bytes(&sidecar, text.as_bytes())
            .with_context(|| format!("writing {}", sidecar.display()))?;
        Ok(car)
    }
}

/// Bytes of the tar shards of views of these sizes and AOV sets (no optional members), in
/// tars of [`DEFAULT_SHARD_SIZE`]: what the files format's size line adds.
pub(super) fn tar_estimate(views: impl Iterator<Item = ((u32, u32), Vec<Aov>)>) -> u64 {
    let mut n = 0u64;
    let mut bytes = 0u64;
    for ((w, h), aovs) in views {
        bytes += view_tar_bytes(w as usize, h as usize, &aovs, &[]);
        n += 1;
    }
    bytes + n.div_ceil(DEFAULT_SHARD_SIZE as u64) * 2 * tar::BLOCK as u64
}

/// The size line printed before a sharded run: the tars', and what the files format
/// would write for the same views.
fn estimate_line(plan: &Plan, mine: &[usize]) -> String {
    let mut files = SizeEstimate::default();
    let mut shards = 0u64;
    let mut views = 0usize;
    for &j in mine {
        for i in plan.range(j) {
            let Ok(cam) = &plan.cameras[i] else { continue };
            let (w, h) = cam.size();
            files.add((w, h), &plan.aovs, 1, plan.files_png);
            shards += view_tar_bytes(w as usize, h as usize, &plan.aovs, &plan.sopts.members);
            views += 1;
        }
    }
    shards += mine.len() as u64 * 2 * tar::BLOCK as u64;
    format!(
        "batch webdataset: {}, {}: about {} of tar shards (the files format: about {})",
        count(mine.len(), "tar"),
        count(views, "view"),
        crate::output::console::bytes(shards),
        crate::output::console::bytes(files.total())
    )
}

/// Write the tars `selection` names of the views of `input` into `out` (see the module
/// docs). Bad input, a dotted scene name or colliding keys are errors before anything
/// renders; failed views (a `verifier`'s disagreement included) are counted in the summary.
pub fn write_shards(
    input: &Path,
    out: &Path,
    selection: &TarSelection,
    opts: &BatchOptions,
    sopts: &ShardOptions,
    progress: ProgressMode,
    verifier: Option<&dyn Verifier>,
) -> Result<ShardSummary> {
    let never = AtomicBool::new(false);
    write_shards_until(
        input, out, selection, opts, sopts, progress, &never, verifier,
    )
}

/// [`write_shards`], ended early with an error once `stop` is set (by another thread: the
/// Python package on Ctrl-C). It stops as an interrupted command does: the tars finished by
/// then stay with their sidecars (a rerun skips them), the one in progress and its
/// temporary file go, and so does `OUT/.partial` when no other process uses it.
#[allow(clippy::too_many_arguments)]
pub fn write_shards_until(
    input: &Path,
    out: &Path,
    selection: &TarSelection,
    opts: &BatchOptions,
    sopts: &ShardOptions,
    progress: ProgressMode,
    stop: &AtomicBool,
    verifier: Option<&dyn Verifier>,
) -> Result<ShardSummary> {
    let start = Instant::now();
    opts.validate().map_err(anyhow::Error::msg)?;
    // Members in one order, without repeats: how they are listed changes nothing.
    let mut members = sopts.members.clone();
    members.sort_unstable();
    members.dedup();
    let sopts = &ShardOptions {
        members,
        ..sopts.clone()
    };
    if sopts.shard_size == 0 {
        bail!("{}: must be >= 1, got 0", opt("shard_size"));
    }
    let out_opt = opt("out");
    crate::output::store::targets::check_output_dir(&out_opt, out)?;
    let announce = progress != ProgressMode::Off;
    let (views, cameras) = read_views(input, out, opts, announce)?;
    let aovs = dataset_aovs(opts, &views, &cameras)?;
    let keys = keys(&views, &member_suffixes(&aovs, &sopts.members))?;
    let tars = views.len().div_ceil(sopts.shard_size);
    let mine: Vec<usize> = match selection {
        TarSelection::Shard(s) => (0..tars).filter(|&j| s.contains(j)).collect(),
        TarSelection::List(list) => {
            if list.is_empty() {
                bail!("shards: an empty list (give at least one tar)");
            }
            if let Some(&j) = list.iter().find(|&&j| j >= tars) {
                bail!(
                    "shards: tar {j} does not exist ({tars} tars of {} views)",
                    views.len()
                );
            }
            let mut l = list.clone();
            l.sort_unstable();
            l.dedup();
            l
        }
    };
    let label = match selection {
        TarSelection::Shard(s) => s.to_string(),
        TarSelection::List(_) => failures_label(&mine),
    };
    let failures_path = out.join(format!("failures.{label}.jsonl"));
    let my_views: usize = mine
        .iter()
        .map(|&j| tar_views(j, sopts.shard_size, views.len()).len())
        .sum();
    let exr_checked = verifier.is_some() && opts.verify_fraction > 0.0;
    let each = mine
        .iter()
        .flat_map(|&j| tar_views(j, sopts.shard_size, views.len()))
        .filter_map(|i| cameras[i].as_ref().ok())
        .map(|c| tar_view_memory(c.size(), &aovs, opts, &sopts.members, exr_checked))
        .max()
        .unwrap_or(0);
    // A tar's view is held from its render until it is written: two windows at most (no
    // view renders two windows ahead of the views done with), and one view done with but
    // waiting for the tar's writer; 2 w + 1 <= 3 w.
    let (lanes, window) = driver::in_flight(
        each.saturating_mul(3),
        mine.len(),
        rayon::current_num_threads(),
        None,
    );
    let mut shard_opts = opts.clone();
    shard_opts.aovs = Some(aovs.clone());
    shard_opts.png = sopts.members.contains(&Member::DepthPng);
    // Without the `exr` member no tar byte depends on the EXR compression: left out of the
    // tars' stamps (as the depth scale is without `depth.png`), so changing it rewrites none.
    if !sopts.members.contains(&Member::Exr) {
        shard_opts.compression = Default::default();
    }
    let plan = Plan {
        out,
        root: PathBuf::new(),
        input_dir: input_dir(input),
        views,
        cameras,
        keys,
        aovs,
        opts: shard_opts,
        sopts,
        tars,
        files_png: opts.png,
        settings: Default::default(),
    };
    let mut targets: Vec<(&str, PathBuf)> = vec![
        (&out_opt, out.join("shards.json")),
        (&out_opt, out.join(shard_settings::FILE)),
        (&out_opt, failures_path.clone()),
    ];
    for &j in &mine {
        targets.push((&out_opt, plan.tar_path(j)));
        targets.push((&out_opt, plan.sidecar_path(j)));
    }
    let refs: Vec<(&str, &Path)> = targets.iter().map(|(f, p)| (*f, p.as_path())).collect();
    check_outputs(&refs, &[])?;
    // The folders made here go again if the run fails or is interrupted before writing.
    let mut dirs = crate::output::store::atomic::NewDirs::default();
    dirs.create(out)
        .with_context(|| format!("creating {}", out.display()))?;
    let (root, _root_reg) = partial_root(out)?;
    let plan = Plan { root, ..plan };
    shard_settings::hold(out, &plan.root, plan.settings(), sopts.force)?;
    if announce {
        eprintln!("{}", estimate_line(&plan, &mine));
    }
    let run = Run {
        out,
        root: &plan.root,
        views: &plan.views,
        cameras: &plan.cameras,
        opts: &plan.opts,
        verifier,
        stop,
        progress: Progress::new(progress, format!("batch {label}"), my_views),
        lanes,
        window,
    };
    let summary = write_planned(&plan, &run, &mine, failures_path, start);
    // Other processes may still be using `.partial`; it goes when the last one leaves.
    let _ = std::fs::remove_dir(out.join(".partial"));
    if summary.is_ok() {
        dirs.keep();
    }
    summary
}

/// The tars `mine` of `plan` through the batch driver, the failures file and, when every
/// tar is in place, the index.
fn write_planned(
    plan: &Plan,
    run: &Run,
    mine: &[usize],
    failures_path: PathBuf,
    start: Instant,
) -> Result<ShardSummary> {
    let mut summary = ShardSummary {
        views: plan.views.len(),
        tars: plan.tars,
        outcomes: Vec::new(),
        rendered: 0,
        failures: Vec::new(),
        failures_path,
        verified: 0,
        index_written: false,
        problems: Vec::new(),
        elapsed: Duration::ZERO,
    };
    let units = mine
        .iter()
        .map(|&j| {
            Ok(Unit {
                name: Shard::new(j as u32, plan.tars as u32).map_err(anyhow::Error::msg)?,
                views: plan.range(j).collect(),
                held: None,
            })
        })
        .collect::<Result<Vec<Unit>>>()?;
    let driven = match driver::drive(run, plan, &units) {
        Ok(d) => d,
        Err(e) => {
            // A tar another run holds (two runs of one dataset at once) fails this one,
            // but its tars in place still count: whichever run finishes last writes the
            // index once every tar is in place.
            if !run.stop.load(std::sync::atomic::Ordering::Relaxed) {
                let _ = plan.merge_index();
            }
            return Err(e);
        }
    };
    run.progress.finish();
    if let Some(why) = driven.stopped {
        bail!("{why}");
    }
    for (unit, result) in units.iter().zip(driven.units) {
        let Some(car) = result.record else {
            continue;
        };
        let j = unit.name.index as usize;
        if result.kept {
            summary.outcomes.push((j, TarOutcome::Skipped));
            // A kept tar's views checked again now and found to disagree, besides those
            // its sidecar lists.
            let rechecked: Vec<ShardFailure> = unit
                .views
                .iter()
                .zip(&result.outcomes)
                .filter_map(|(&i, o)| match o {
                    Some(Outcome::Failed(e))
                        if !car.failures.iter().any(|f| f.key == plan.keys[i]) =>
                    {
                        Some(plan.failure(i, e.clone()))
                    }
                    _ => None,
                })
                .collect();
            summary.failures.extend(car.failures);
            summary.failures.extend(rechecked);
        } else {
            summary.outcomes.push((j, TarOutcome::Written));
            summary.rendered += car.samples + car.failures.len();
            summary.failures.extend(car.failures);
        }
    }
    {
        // As a tar lands: only while the folder still records this run's dataset.
        let _held = shard_settings::still_held(plan.out, &plan.root, plan.settings())?;
        write_failures(&summary.failures_path, &summary.failures)?;
    }
    summary.problems = driven.problems;
    summary.verified = driven.verified;
    summary.index_written = plan.merge_index()?;
    summary.elapsed = start.elapsed();
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(scene: &str, folder: bool, name: &str) -> ViewSource {
        ViewSource {
            name: name.into(),
            path: PathBuf::from(format!("{scene}.json")),
            scene: scene.into(),
            camera: name.parse().unwrap_or(0),
            folder: folder.then(|| scene.to_string()),
        }
    }

    /// One-camera scenes are keyed by name, several-camera views as `SCENE_cNN`; a dot or
    /// a shared key is refused naming both views.
    #[test]
    fn keys_are_view_names_without_dots() {
        let sfx = member_suffixes(&[Aov::Depth, Aov::Normal, Aov::ShapeId], &[]);
        let views = [view("000123", false, "000123"), view("000124", true, "04")];
        assert_eq!(keys(&views, &sfx).unwrap(), ["000123", "000124_c04"]);
        let e = keys(&[view("a.b", false, "a.b")], &sfx)
            .unwrap_err()
            .to_string();
        assert!(e.contains("\"a.b\" has a '.'"), "{e}");
        // A dotted scene of two cameras is one problem, listed once.
        let e = keys(&[view("t.", true, "00"), view("t.", true, "01")], &sfx)
            .unwrap_err()
            .to_string();
        assert!(e.contains("(1 problem;"), "{e}");
        assert_eq!(e.matches("has a '.'").count(), 1, "{e}");
        let clash = [view("s", true, "01"), view("s_c01", false, "s_c01")];
        let e = keys(&clash, &sfx).unwrap_err().to_string();
        assert!(e.contains("\"s_c01\""), "{e}");
        assert!(e.contains("\"s/01\""), "{e}");
        // Every bad name is listed at once: non-ASCII, and too long for its longest member
        // (87 + ".shape_id.npy" = 100 bytes fits, 88 does not).
        let fits = "x".repeat(87);
        let long = "y".repeat(88);
        let bad = [
            view("caf\u{e9}", false, "caf\u{e9}"),
            view(&fits, false, &fits),
            view(&long, false, &long),
            view("ok", false, "ok"),
        ];
        let e = keys(&bad, &sfx).unwrap_err().to_string();
        assert!(
            e.contains("cannot all be tar shard keys (2 problems;"),
            "{e}"
        );
        assert!(e.contains("caf\u{e9}") && e.contains(&long), "{e}");
        assert!(!e.contains(&format!("{fits}.")), "{e}");
        assert_eq!(keys(&bad[1..2], &sfx).unwrap(), [fits]);
    }

    /// Calls with other tar lists keep other failures files.
    #[test]
    fn failures_files_are_named_by_their_tars() {
        assert_eq!(failures_label(&[3]), "tar-000003");
        assert_eq!(failures_label(&[1, 3]), "tars-000001-000003");
        assert_ne!(failures_label(&[1, 3]), failures_label(&[1, 2]));
        let many: Vec<usize> = (0..20).collect();
        let other: Vec<usize> = (0..19).chain([21]).collect();
        let a = failures_label(&many);
        assert!(a.starts_with("tars-000000-to-000019-20-"), "{a}");
        assert_ne!(a, failures_label(&other));
        assert_eq!(a.len(), "tars-000000-to-000019-20-".len() + 8);
    }

    /// The raw arrays of a 320x240 depth+normal view are within 2% of its tar bytes.
    #[test]
    fn tar_bytes_are_the_arrays_plus_headers() {
        let per = view_tar_bytes(320, 240, &[Aov::Depth, Aov::Normal], &[]);
        let raw = 320 * 240 * (4 + 12 + 1);
        assert!(
            per > raw && (per - raw) as f64 / (raw as f64) < 0.02,
            "{per} vs {raw}"
        );
    }
}
