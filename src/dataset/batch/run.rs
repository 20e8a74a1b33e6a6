//! The files format: read every scene's cameras (a scene with several becomes several
//! views), render this shard's views as one unit of the batch driver (`super::driver`:
//! resuming what is complete, verifying the selected ones), each view's files committed
//! on their own, then write the failures file, `OUT/index.json` and each several-camera
//! scene's `OUT/<scene>/transforms.json`.
//!
//! Before anything is rendered, every path the shard may replace (the views' files,
//! `index.json`, the failures file, `transforms.json`) must be missing or a regular file
//! (or, for a view's file, a folder, which fails that view's rename): a FIFO, a link or a
//! device there is refused by name, never opened or renamed over. A
//! view that fails because the machine ran out of something every view needs (a full disk
//! or quota, the file size limit, the open-file limit) stops the shard: the views not yet
//! started are left for the next run, and the summary says why. The shard's partial folder
//! goes on every exit, a signal's included (see `crate::output::store::signals`).

use super::driver::{self, Container, Rendered, Run, Start, Unit};
use super::failures::write_failures;
use super::input::{input_dir, read_views};
use super::lock::{lock_shard, partial_root};
use super::options::{BatchOptions, Schedule};
use super::progress::Outcome;
use super::progress::{Counts, Progress, ProgressMode, SizeEstimate};
use super::resume::{ViewFiles, view_file_names, view_is_complete, view_memory, view_memory_at};
use super::shard::Shard;
use super::transforms::{FrameCamera, index_json, transforms_json};
use super::verify::Verifier;
use super::views::ViewSource;
use super::write::render_view;
use crate::output::format::exr::ExrLayout;
use crate::output::store::atomic::atomic_write_bytes;
use crate::output::store::files::refuse_non_regular;
use crate::output::store::targets::check_outputs;
use crate::scene::Scene;
use anyhow::{Context, Result, bail};
use serde::Serialize;
use std::collections::HashSet;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

/// One line of `failures.K-of-N.jsonl`.
#[derive(Clone, Debug, Serialize)]
pub struct Failure {
    /// The view's id relative to `OUT` (`scene` or `scene/00`).
    pub name: String,
    /// The scene file's path.
    pub scene: String,
    /// Why the view failed.
    pub error: String,
}

/// The result of a run.
#[derive(Clone, Debug)]
pub struct Summary {
    /// The shard this run rendered.
    pub shard: Shard,
    /// Views in the whole input.
    pub total: usize,
    /// Views in this shard.
    pub in_shard: usize,
    /// Done, skipped and failed views.
    pub counts: Counts,
    /// Every failed view, in view-list order.
    pub failures: Vec<Failure>,
    /// Wall time of the whole run.
    pub elapsed: Duration,
    /// Build and trace time, summed over the views rendered in this run.
    pub trace: Duration,
    /// Encoding and writing time, summed over the views rendered in this run.
    pub write: Duration,
    /// Where this shard's failures went: `OUT/failures.K-of-N.jsonl`.
    pub failures_path: PathBuf,
    /// Views checked against the verifier in this run (all agreed unless counted failed).
    pub verified: usize,
    /// Views rendered now whose depth PNG stores some hits as 0
    /// (`--depth-out-of-range zero`).
    pub depth_zeroed_views: usize,
    /// Hits stored as 0 in those views, in all.
    pub depth_zeroed: usize,
    /// Why the shard stopped before its last view (a full disk, the file size or open-file
    /// limit: the resources every view needs), if it did.
    pub stopped: Option<String>,
    /// Views of this shard not started because the shard stopped.
    pub not_started: usize,
    /// Whether the failures file was written.
    pub failures_written: bool,
    /// What could not be written after the views ran (the failures file, the indexes).
    pub problems: Vec<String>,
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
        if self.depth_zeroed > 0 {
            write!(
                f,
                "; depth PNG: {} hit pixels beyond 16 bits stored as 0 in {} views",
                self.depth_zeroed, self.depth_zeroed_views
            )?;
        }
        if c.failed > 0 && self.failures_written {
            write!(f, "; failures in {}", self.failures_path.display())?;
        }
        if let Some(why) = &self.stopped {
            write!(
                f,
                "; stopped, {} views not started: {why}",
                self.not_started
            )?;
        }
        Ok(())
    }
}

/// Render `shard` of the views of `input` into `out`; see the module docs. With a
/// `verifier`, the views [`view_selected`](super::view_selected) (rendered now or earlier) are checked, and
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
    // A folder holds one dataset: files beside a tar-shard dataset would overwrite its
    // failures file and sit beside an index that does not know them.
    let record = out.join(super::shard_settings::FILE);
    if record.symlink_metadata().is_ok() {
        bail!(
            "{} holds a tar-shard dataset ({} is there): give the files format another {}",
            out.display(),
            record.display(),
            crate::spelling::opt("out")
        );
    }
    let (views, cameras) = read_views(input, out, opts, true)?;
    let mine: Vec<usize> = (0..views.len()).filter(|&i| shard.contains(i)).collect();
    let failures_path = out.join(format!("failures.{shard}.jsonl"));
    check_targets(out, &views, &mine, &failures_path)?;
    // The folders made here go again if the run fails or is interrupted before writing.
    let mut dirs = crate::output::store::atomic::NewDirs::default();
    dirs.create(out)
        .with_context(|| format!("creating {}", out.display()))?;
    let (root, _root_registered) = partial_root(out)?;
    let lock = lock_shard(out, &root, shard)?;

    if progress != ProgressMode::Off {
        let estimate = estimate(&mine, &cameras, opts);
        eprintln!(
            "{}; as {} webdataset tar shards: about {}",
            estimate.message(&format!("batch {shard}"), opts.compression),
            crate::spelling::opt("format"),
            crate::output::console::bytes(super::shards::tar_estimate(
                mine.iter()
                    .filter_map(|&i| cameras[i].as_ref().ok())
                    .map(|c| (c.size(), c.aovs().collect::<Vec<_>>()))
            ))
        );
    }
    // The views held at once: every view of the shard when memory allows (no barrier
    // between views), else as many as fit; one at a time when each view's pixels use
    // the pool instead.
    let window = match opts.schedule {
        Schedule::Views => {
            let each = mine
                .iter()
                .filter_map(|&i| cameras[i].as_ref().ok())
                .map(|c| view_memory_at(c.size(), &c.aovs().collect::<Vec<_>>(), opts))
                .max()
                .unwrap_or(0);
            driver::in_flight(each, 1, rayon::current_num_threads(), Some(mine.len())).1
        }
        Schedule::Pixels => 1,
    };
    let never = AtomicBool::new(false);
    let run = Run {
        out,
        root: &root,
        views: &views,
        cameras: &cameras,
        opts,
        verifier,
        stop: &never,
        progress: Progress::new(progress, format!("batch {shard}"), mine.len()),
        lanes: 1,
        window,
    };
    let files = Files {
        views: &views,
        out,
        opts,
    };
    let unit = Unit {
        name: shard,
        views: mine.clone(),
        held: Some(lock),
    };
    let driven = driver::drive(&run, &files, std::slice::from_ref(&unit))?;
    run.progress.finish();
    let outcomes = driven
        .units
        .into_iter()
        .next()
        .map_or_else(Vec::new, |u| u.outcomes);

    let mut summary = summarize(shard, &views, &mine, &outcomes, out);
    summary.verified = driven.verified;
    summary.stopped = driven.stopped;
    summary.problems.extend(driven.problems);
    match write_failures(&summary.failures_path, &summary.failures) {
        Ok(()) => summary.failures_written = true,
        Err(e) => summary.problems.push(format!("{e:#}")),
    }
    if let Err(e) = write_index(out, input, &input_dir(input), &views, &cameras, opts) {
        summary.problems.push(format!("{e:#}"));
    }
    if let Err(e) = remove_stale_views(out, &views, &cameras, &mine) {
        summary.problems.push(format!("{e:#}"));
    }
    drop(unit);
    // Other shards may still be using `.partial`; it goes when the last one leaves.
    let _ = std::fs::remove_dir(out.join(".partial"));
    dirs.keep();
    summary.elapsed = start.elapsed();
    Ok(summary)
}

/// Refuse, before anything is written, a path the shard would replace that is not a
/// regular file: each view's files (see [`ViewFiles::all`]), `index.json`, the failures
/// file and the `transforms.json` of several-camera scenes.
fn check_targets(
    out: &Path,
    views: &[ViewSource],
    mine: &[usize],
    failures_path: &Path,
) -> Result<()> {
    let index = out.join("index.json");
    let out_opt = crate::spelling::opt("out");
    check_outputs(&[(&out_opt, &index), (&out_opt, failures_path)], &[])?;
    // A folder in a file's place cannot block or be written through: the rename onto it
    // fails, and so does that view alone.
    let check = |path: &Path| match path.symlink_metadata() {
        Ok(m) if m.is_dir() => Ok(()),
        _ => refuse_non_regular(path),
    };
    for &i in mine {
        let v = &views[i];
        for path in ViewFiles::new(&v.dir(out), &v.name).all() {
            check(&path)?;
        }
    }
    for v in views {
        if let Some(folder) = &v.folder {
            check(&out.join(folder).join("transforms.json"))?;
        }
    }
    Ok(())
}

/// The files format: one unit, this process's shard, whose views each commit on their
/// own (see the module docs of `super` for the crash invariant).
struct Files<'a> {
    views: &'a [ViewSource],
    out: &'a Path,
    opts: &'a BatchOptions,
}

impl Container for Files<'_> {
    type View = ();
    type Open = ();
    type Record = ();
    type Placed = ();
    const SCENES_AHEAD: bool = false;

    fn start(&self, _: &Unit, _: &[Result<Scene, String>], _: &Path) -> Result<Start<(), ()>> {
        Ok(Start::Open(()))
    }

    fn view_kept(&self, i: usize, scene: &Scene) -> bool {
        let view = &self.views[i];
        view_is_complete(&view.dir(self.out), &view.name, scene, self.opts)
    }

    fn render(
        &self,
        i: usize,
        scene: &Scene,
        partial: &Path,
        _exr: bool,
    ) -> Result<Rendered<()>, String> {
        let view = &self.views[i];
        let dir = view.dir(self.out);
        // Temporary files are named by the view's position: names repeat across the
        // folders of several-camera scenes.
        let tmp_stem = format!("{i:06}");
        let bytes = view_memory(scene, self.opts);
        // A view that does not fit what is left fails alone, before it allocates. The
        // scene's folder, if this view makes it, stays registered for a signal's clean-up
        // until the view's files are in it; kept either way after (other views of the
        // scene may be writing into it).
        let mut dirs = crate::output::store::atomic::NewDirs::default();
        let rendered = crate::mem::check_memory(&format!("rendering {}", view.id()), bytes)
            .map_err(anyhow::Error::from)
            .and_then(|()| {
                dirs.create(&dir)
                    .with_context(|| format!("creating {}", dir.display()))
            })
            .and_then(|()| render_view(&dir, partial, &view.name, &tmp_stem, scene, self.opts));
        dirs.keep();
        match rendered {
            Ok(cost) => {
                if cost.depth_zeroed > 0 {
                    crate::output::console::warn(&format!(
                        "{}: depth PNG: {} hit pixels beyond 16 bits at {} {} stored as 0",
                        view.id(),
                        cost.depth_zeroed,
                        crate::spelling::opt("depth_scale"),
                        self.opts.depth_scale
                    ));
                }
                Ok(Rendered {
                    view: (),
                    cost,
                    exr: None,
                })
            }
            Err(e) => {
                // Its temporary files go now, not at the end: on a full disk the other
                // views need the room.
                remove_temps(partial, &tmp_stem);
                Err(format!("{}: {e:#}", view.path.display()))
            }
        }
    }

    fn exr_path(&self, i: usize, _: &Path) -> PathBuf {
        let view = &self.views[i];
        ViewFiles::new(&view.dir(self.out), &view.name).exr
    }

    fn accept(&self, _: &mut (), _: usize, _: ()) -> Result<()> {
        Ok(())
    }

    fn place(&self, _: ()) -> Result<()> {
        Ok(())
    }

    fn commit(&self, _: &Unit, _: (), _: &[(usize, &str)]) -> Result<()> {
        Ok(())
    }
}

/// Remove the temporary files `STEM.*` of one view from the partial folder.
fn remove_temps(partial: &Path, stem: &str) {
    let prefix = format!("{stem}.");
    if let Ok(entries) = std::fs::read_dir(partial) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(&prefix)
                && e.file_type().is_ok_and(|t| t.is_file())
            {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// Count the outcomes of this shard's views (`mine`, indices into `views`) and collect the
/// failures.
fn summarize(
    shard: Shard,
    views: &[ViewSource],
    mine: &[usize],
    outcomes: &[Option<Outcome>],
    out: &Path,
) -> Summary {
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
        verified: 0,
        depth_zeroed_views: 0,
        depth_zeroed: 0,
        stopped: None,
        not_started: 0,
        failures_written: false,
        problems: Vec::new(),
    };
    for (&i, o) in mine.iter().zip(outcomes) {
        let Some(o) = o else {
            summary.not_started += 1;
            continue;
        };
        match o {
            Outcome::Done(cost) => {
                summary.counts.done += 1;
                summary.trace += cost.trace;
                summary.write += cost.write;
                if cost.depth_zeroed > 0 {
                    summary.depth_zeroed_views += 1;
                    summary.depth_zeroed += cost.depth_zeroed;
                }
            }
            Outcome::Skipped => summary.counts.skipped += 1,
            Outcome::Failed(e) => {
                summary.counts.failed += 1;
                summary.failures.push(Failure {
                    name: views[i].id(),
                    scene: views[i].path.display().to_string(),
                    error: e.clone(),
                });
            }
        }
    }
    summary
}

/// Write `OUT/index.json` (every view whose scene loads) and the `transforms.json` of each
/// several-camera scene in its folder; remove the `OUT/transforms.json` of older versions,
/// which listed unrelated scenes as one (a resumed old dataset must not keep it). `input`
/// (the batch's scene folder or manifest, as given) is recorded made absolute, for
/// `cylaov verify OUT`.
fn write_index(
    out: &Path,
    input: &Path,
    input_dir: &Path,
    views: &[ViewSource],
    cameras: &[Result<FrameCamera, String>],
    opts: &BatchOptions,
) -> Result<()> {
    let valid: Vec<(&ViewSource, FrameCamera)> = views
        .iter()
        .zip(cameras)
        .filter_map(|(v, c)| c.as_ref().ok().map(|c| (v, *c)))
        .collect();
    let index = out.join("index.json");
    let input = std::path::absolute(input).unwrap_or_else(|_| input.to_path_buf());
    atomic_write_bytes(
        &index,
        index_json(&valid, &input, input_dir, opts).as_bytes(),
    )
    .with_context(|| format!("writing {}", index.display()))?;
    for scene in valid.chunk_by(|a, b| a.0.folder == b.0.folder && a.0.path == b.0.path) {
        let Some(folder) = &scene[0].0.folder else {
            continue;
        };
        let frames: Vec<(&str, FrameCamera)> =
            scene.iter().map(|(v, c)| (v.name.as_str(), *c)).collect();
        let dir = out.join(folder);
        crate::output::store::atomic::make_dir_all(&dir)
            .with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("transforms.json");
        atomic_write_bytes(&path, transforms_json(&frames, opts).as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let old = out.join("transforms.json");
    if old.symlink_metadata().is_ok_and(|m| m.is_file()) {
        std::fs::remove_file(&old)
            .with_context(|| format!("removing the old {}", old.display()))?;
    }
    Ok(())
}

/// The size of what the views `mine` write (those whose scene loads).
fn estimate(
    mine: &[usize],
    cameras: &[Result<FrameCamera, String>],
    opts: &BatchOptions,
) -> SizeEstimate {
    let mut e = SizeEstimate::default();
    for cam in mine.iter().filter_map(|&i| cameras[i].as_ref().ok()) {
        let aovs: Vec<_> = cam.aovs().collect();
        let files = match opts.exr_layout {
            ExrLayout::Layers => 1,
            ExrLayout::PerAov => aovs.len() as u64,
        };
        e.add(cam.size(), &aovs, files, opts.png);
    }
    e
}

/// A view's files belong to its scene: for each scene with a view in this shard whose
/// file loads, remove the files of views it no longer has. A scene with one camera (flat,
/// `OUT/NAME.*`) loses the folder `OUT/NAME/` of an earlier several-camera version: the
/// view files in it (numbered names) and its `transforms.json`, then the folder if that
/// leaves it empty. A scene with several cameras loses the flat `OUT/NAME.*` files of an
/// earlier one-camera version, and in `OUT/NAME/` the files of camera numbers it no longer
/// has (its `transforms.json` was just rewritten). Only the file names a view writes
/// ([`view_file_names`]) are removed, never a folder's other contents, never a file of
/// another current view, and a folder that is a link is left alone. Every shard does this
/// for the scenes it renders; the files removed are no view's in the current list, so
/// shards running at once do not step on each other.
fn remove_stale_views(
    out: &Path,
    views: &[ViewSource],
    cameras: &[Result<FrameCamera, String>],
    mine: &[usize],
) -> Result<()> {
    let mine: HashSet<usize> = mine.iter().copied().collect();
    let flat: HashSet<&str> = views
        .iter()
        .filter(|v| v.folder.is_none())
        .map(|v| v.name.as_str())
        .collect();
    // Whether a file in `OUT` is one of a current flat view other than `scene`'s.
    let owned_by_other = |file: &str, scene: &str| {
        file.match_indices('.').any(|(at, _)| {
            let stem = &file[..at];
            stem != scene
                && flat.contains(stem)
                && view_file_names(stem).contains(&file.to_string())
        })
    };
    let indices: Vec<usize> = (0..views.len()).collect();
    for group in indices.chunk_by(|&a, &b| views[a].scene == views[b].scene) {
        let loaded = group.iter().all(|&i| cameras[i].is_ok());
        if !loaded || !group.iter().any(|i| mine.contains(i)) {
            continue;
        }
        let first = &views[group[0]];
        let folder = out.join(&first.scene);
        if first.folder.is_none() {
            remove_numbered_views(&folder, &HashSet::new(), true)?;
            // Left in place when something else is in it.
            let _ = std::fs::remove_dir(&folder);
        } else {
            for name in view_file_names(&first.scene) {
                if !owned_by_other(&name, &first.scene) {
                    remove_file_if_there(&out.join(name))?;
                }
            }
            let keep: HashSet<&str> = group.iter().map(|&i| views[i].name.as_str()).collect();
            remove_numbered_views(&folder, &keep, false)?;
        }
    }
    Ok(())
}

/// In a scene's folder `dir` (a real folder, not a link), remove the files of the views
/// with numbered names (`00`, `01`, …) not in `keep`, and `transforms.json` when
/// `with_index`.
fn remove_numbered_views(dir: &Path, keep: &HashSet<&str>, with_index: bool) -> Result<()> {
    if !dir.symlink_metadata().is_ok_and(|m| m.is_dir()) {
        return Ok(());
    }
    let entries = std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))?;
    for entry in entries {
        let entry = entry.with_context(|| format!("listing {}", dir.display()))?;
        if entry.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        let Some(name) = entry.file_name().to_str().map(str::to_owned) else {
            continue;
        };
        let stem = name.split('.').next().unwrap_or_default();
        let numbered = !stem.is_empty() && stem.bytes().all(|b| b.is_ascii_digit());
        let stale = if name == "transforms.json" {
            with_index
        } else {
            numbered && !keep.contains(stem) && view_file_names(stem).contains(&name)
        };
        if stale {
            remove_file_if_there(&entry.path())?;
        }
    }
    Ok(())
}

/// Remove a file (or a link itself); a missing one is fine.
fn remove_file_if_there(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("removing the stale {}", path.display()))
        }
        _ => Ok(()),
    }
}
