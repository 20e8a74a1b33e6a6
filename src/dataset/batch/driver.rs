//! The one batch driver: both containers (the files format's views, tar shards) run their
//! work through [`drive`], so locks, resume, the work folders, scene loading, the memory
//! bound, verification, progress, stopping and failures are written once. A container is
//! a plan for a view's members plus how a unit of views is committed ([`Container`]).
//!
//! A run's work is a list of [`Unit`]s: views committed together under one lock. The files
//! format has one unit, this process's shard `K-of-N`, whose views each commit on their
//! own; tar shards have one unit a tar, `J-of-T`, committed whole. Per unit the driver:
//! 1. takes its lock `OUT/.partial/NAME.lock` (another process holding it is an error),
//!    then clears and makes its work folder `OUT/.partial/NAME/`, removed when the unit
//!    ends and by a signal's clean-up;
//! 2. lets the container start it, or keep it when it is already whole on disk (a tar
//!    whose sidecar vouches for it: its views count as skipped, and those the verifier
//!    checks are rendered again for their check, in the same windows);
//! 3. renders its views on the pool, `window` at once, each taken by the container in
//!    view order as soon as it and the ones before it have rendered
//!    ([`Container::accept`], by whichever worker finds it ready: `in_order`), then
//!    finished by that worker out of order ([`Container::place`]), so a tar is laid out,
//!    hashed and written while later views trace, with no barrier between windows; a
//!    view whole on disk already is skipped (the files format's resume); every view
//!    [`view_selected`] is checked by the verifier, kept ones included;
//! 4. commits it ([`Container::commit`]) once every view has run, none of them out of a
//!    resource every view needs.
//!
//! Units run `lanes` at a time, each rendering `window` views at once and holding at most
//! two windows' views until they are done with (a container may hold a view a little
//! longer: a tar's view waiting for its writer), both from the memory a view holds
//! ([`in_flight`], given what a container's view holds), so what the views hold stays
//! within half of what the machine leaves however many cores there are. A view that
//! failed because a resource every view needs ran out (a full disk, see
//! [`resource_exhausted`]) stops the run: no view starts after it, and a unit missing
//! views or holding such a failure is not committed.

use super::in_order::in_order;
use super::input::{resource_exhausted, view_scene};
use super::lock::{ShardLock, lock_shard};
use super::options::BatchOptions;
use super::progress::{Outcome, Progress};
use super::shard::Shard;
use super::transforms::FrameCamera;
use super::verify::{Verifier, check_view, view_selected};
use super::views::ViewSource;
use super::write::ViewCost;
use crate::output::store::signals::{self, Cleanup, Registration};
use crate::scene::Scene;
use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Views committed together under one lock (see the module docs).
pub(super) struct Unit {
    /// Names the lock `OUT/.partial/NAME.lock` and the work folder `OUT/.partial/NAME/`.
    pub name: Shard,
    /// Its views (indices into the view list), in the order the container takes them.
    pub views: Vec<usize>,
    /// Its lock when the caller took it already (the files format takes it before it
    /// prints anything, so a held lock is the one line it prints).
    pub held: Option<ShardLock>,
}

/// How a unit starts.
pub(super) enum Start<O, R> {
    /// Whole on disk already: its record, the unit is skipped.
    Kept(R),
    /// To be written: the container's state while it takes the unit's views.
    Open(O),
}

/// A rendered view.
pub(super) struct Rendered<V> {
    /// What it hands its unit.
    pub view: V,
    /// Its trace and write time.
    pub cost: ViewCost,
    /// Its EXR bytes for its check, when asked for and not on disk.
    pub exr: Option<Vec<u8>>,
}

/// What a view that ran became, before its unit takes it.
enum Ran<V> {
    Done(V, ViewCost),
    Kept,
}

/// What a format does with a unit's views; the driver does the rest (see the module docs).
pub(super) trait Container: Sync {
    /// What a rendered view hands its unit (a tar's members).
    type View: Send;
    /// A unit being written (a tar file being laid out and written).
    type Open: Send;
    /// What a committed or kept unit records (a tar's sidecar).
    type Record: Send;

    /// Whether a unit's scenes are read before it starts (its record depends on them all);
    /// otherwise each view reads its own as it renders, and only two windows' are held.
    const SCENES_AHEAD: bool;

    /// Start `unit` (`scenes` its views' scenes when [`Self::SCENES_AHEAD`], else empty),
    /// its temporary files under `work`, or keep it.
    fn start(
        &self,
        unit: &Unit,
        scenes: &[Result<Scene, String>],
        work: &Path,
    ) -> Result<Start<Self::Open, Self::Record>>;

    /// Whether view `i` is whole on disk already (a rerun skips it).
    fn view_kept(&self, _i: usize, _scene: &Scene) -> bool {
        false
    }

    /// Render view `i` (temporary files under `work`); with `exr`, also the view's EXR
    /// bytes for its check, unless the view's EXR is on disk at [`Self::exr_path`].
    fn render(
        &self,
        i: usize,
        scene: &Scene,
        work: &Path,
        exr: bool,
    ) -> Result<Rendered<Self::View>, String>;

    /// Where view `i`'s EXR is checked from: its file, or one written under `check_work`
    /// from the bytes [`Self::render`] gave.
    fn exr_path(&self, i: usize, check_work: &Path) -> PathBuf;

    /// What a view taken into its unit leaves to do outside the view order (a tar's view:
    /// its bytes, to write at the place [`Self::accept`] gave them).
    type Placed: Send;

    /// Take rendered view `i` into the unit, in view order.
    fn accept(&self, open: &mut Self::Open, i: usize, view: Self::View) -> Result<Self::Placed>;

    /// Finish a view [`Self::accept`] took, on the worker that took it while the next
    /// views are taken: views finish in any order, all before the unit commits.
    fn place(&self, placed: Self::Placed) -> Result<()>;

    /// Commit `unit`, every one of its views run; `failed` its views that failed.
    fn commit(
        &self,
        unit: &Unit,
        open: Self::Open,
        failed: &[(usize, &str)],
    ) -> Result<Self::Record>;
}

/// What a run shares while its units are written.
pub(super) struct Run<'a> {
    /// The output folder.
    pub out: &'a Path,
    /// `OUT/.partial`, made by [`super::lock::partial_root`].
    pub root: &'a Path,
    /// The batch's view list and each view's camera (or why its scene does not load).
    pub views: &'a [ViewSource],
    pub cameras: &'a [Result<FrameCamera, String>],
    pub opts: &'a BatchOptions,
    /// Checks the views [`view_selected`].
    pub verifier: Option<&'a dyn Verifier>,
    /// Set by the caller to end the run early (the Python package on Ctrl-C).
    pub stop: &'a AtomicBool,
    /// Every view of the units: rendered, skipped or failed.
    pub progress: Progress,
    /// Units written at once, and views a unit renders at once; a unit holds at most two
    /// windows' views (see [`in_flight`]).
    pub lanes: usize,
    pub window: usize,
}

/// What became of one unit.
pub(super) struct UnitResult<R> {
    /// Its record; `None` when the run stopped before all its views ran.
    pub record: Option<R>,
    /// Whether it was whole on disk already, and kept.
    pub kept: bool,
    /// Each of its views' outcome, in unit order; `None` for a view not started.
    pub outcomes: Vec<Option<Outcome>>,
}

/// What a run did.
pub(super) struct Driven<R> {
    /// Each unit's result, in the order of the units given.
    pub units: Vec<UnitResult<R>>,
    /// Views checked by the verifier.
    pub verified: usize,
    /// Why the run stopped before its last view (a resource every view needs ran out).
    pub stopped: Option<String>,
    /// What could not be cleaned up (a unit's work folder).
    pub problems: Vec<String>,
}

/// How many units to write at once and how many views each renders at once, so the
/// views held fit the memory budget (`crate::mem::jobs_in_memory`: half of what the
/// machine or `ulimit -v` leaves) and the pool stays busy. `each` is the most one view
/// holds from its render until its unit has written it; `widest` the most views a window
/// may usefully have: by default the lanes share the threads (a tar's windows, so that
/// hashing and writing overlap tracing); the files format's window is its whole unit.
pub(super) fn in_flight(
    each: u64,
    units: usize,
    threads: usize,
    widest: Option<usize>,
) -> (usize, usize) {
    let threads = threads.max(1);
    let lanes = crate::mem::jobs_in_memory(each, threads.min(units.max(1)));
    let widest = widest.unwrap_or_else(|| threads.div_ceil(lanes));
    let window = crate::mem::jobs_in_memory(each.saturating_mul(lanes as u64), widest);
    (lanes, window)
}

/// Write `units` with `container` (see the module docs). An error of a unit (its lock
/// held elsewhere, a write of the container) is the run's, after the other units end;
/// so is the caller's stop.
pub(super) fn drive<C: Container>(
    run: &Run,
    container: &C,
    units: &[Unit],
) -> Result<Driven<C::Record>> {
    let state = State {
        verified: AtomicUsize::new(0),
        stopped: Mutex::new(None),
        problems: Mutex::new(Vec::new()),
    };
    let lanes = run.lanes.clamp(1, units.len().max(1));
    let next = AtomicUsize::new(0);
    let done: UnitResults<C::Record> = Mutex::new(Vec::new());
    // Each lane takes the next unit when it finishes one: lanes stay busy however the
    // units' costs differ.
    (0..lanes).into_par_iter().for_each(|_| {
        loop {
            let k = next.fetch_add(1, Ordering::Relaxed);
            if k >= units.len() {
                break;
            }
            let r = run.unit(container, &units[k], &state);
            done.lock().unwrap_or_else(|e| e.into_inner()).push((k, r));
        }
    });
    let mut done = done.into_inner().unwrap_or_else(|e| e.into_inner());
    done.sort_by_key(|(k, _)| *k);
    let mut results = Vec::with_capacity(done.len());
    for (_, r) in done {
        results.push(r?);
    }
    if run.stop.load(Ordering::Relaxed) {
        bail!("stopped before the run finished");
    }
    Ok(Driven {
        units: results,
        verified: state.verified.into_inner(),
        stopped: state
            .stopped
            .into_inner()
            .unwrap_or_else(|e| e.into_inner()),
        problems: state
            .problems
            .into_inner()
            .unwrap_or_else(|e| e.into_inner()),
    })
}

/// What the units of a run update as they go.
struct State {
    verified: AtomicUsize,
    stopped: Mutex<Option<String>>,
    problems: Mutex<Vec<String>>,
}

impl State {
    fn is_stopped(&self) -> bool {
        self.stopped
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .is_some()
    }
}

/// A unit's work folder: removed with its content when dropped, and by a signal's
/// clean-up meanwhile.
struct WorkFolder {
    path: PathBuf,
    _registered: Registration,
}

impl WorkFolder {
    /// Clear and make `path` (a real folder in `OUT/.partial`: a link there is removed
    /// itself, never what it points to).
    fn new(path: PathBuf) -> Result<WorkFolder> {
        if path.symlink_metadata().is_ok() {
            std::fs::remove_dir_all(&path)
                .or_else(|_| std::fs::remove_file(&path))
                .with_context(|| format!("clearing {}", path.display()))?;
        }
        let ((), registered) = signals::create_registered(
            Cleanup::Tree,
            || std::fs::create_dir(&path),
            |_| path.clone(),
        )
        .with_context(|| format!("creating {}", path.display()))?;
        Ok(WorkFolder {
            path,
            _registered: registered,
        })
    }

    /// Remove the folder now, saying why if it cannot be. Out of file handles,
    /// `remove_dir_all` cannot open the folder to list it; an empty one still goes by
    /// `rmdir`, which needs none.
    fn remove(&self) -> Result<()> {
        match std::fs::remove_dir_all(&self.path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                if std::fs::remove_dir(&self.path).is_ok() {
                    return Ok(());
                }
                Err(e).with_context(|| format!("removing {}", self.path.display()))
            }
            _ => Ok(()),
        }
    }

    fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for WorkFolder {
    fn drop(&mut self) {
        let _ = self.remove();
    }
}

/// A view's result before its unit takes it: `None` when it did not start.
type ViewResult<V> = Option<Result<Ran<V>, String>>;

/// Each unit's result, by its position in the run's list.
type UnitResults<R> = Mutex<Vec<(usize, Result<UnitResult<R>>)>>;

impl Run<'_> {
    fn stopping(&self, state: &State) -> bool {
        self.stop.load(Ordering::Relaxed) || state.is_stopped()
    }

    /// Lock, start, render and commit one unit.
    fn unit<C: Container>(
        &self,
        c: &C,
        unit: &Unit,
        state: &State,
    ) -> Result<UnitResult<C::Record>> {
        let not_started = || UnitResult {
            record: None,
            kept: false,
            outcomes: vec![None; unit.views.len()],
        };
        if self.stopping(state) {
            return Ok(not_started());
        }
        let _lock = match unit.held {
            Some(_) => None,
            None => Some(lock_shard(self.out, self.root, unit.name)?),
        };
        let work = WorkFolder::new(self.root.join(unit.name.to_string()))?;
        let scenes: Vec<Result<Scene, String>> = if C::SCENES_AHEAD {
            unit.views
                .par_iter()
                .map(|&i| view_scene(&self.views[i], &self.cameras[i]))
                .collect()
        } else {
            Vec::new()
        };
        if self.stopping(state) {
            return Ok(not_started());
        }
        // A kept unit's views run too, but only those the verifier checks render (again,
        // for their EXR: the unit is a pure function of the same inputs).
        let (mut open, kept) = match c.start(unit, &scenes, work.path())? {
            Start::Kept(record) => (None, Some(record)),
            Start::Open(open) => (Some(open), None),
        };
        let check_only = kept.is_some();
        // Each view is taken into the unit as soon as it and the ones before it have
        // rendered, by whichever worker finds it ready, then placed by that worker while
        // the next are taken: a tar is hashed and written while later views trace.
        let mut outcomes: Vec<Option<Outcome>> = Vec::with_capacity(unit.views.len());
        let mut target = open.as_mut();
        in_order(
            unit.views.len(),
            self.window,
            |k| {
                let i = unit.views[k];
                let ran = self.view(c, i, scenes.get(k), work.path(), check_only, state);
                (i, ran)
            },
            |_, view| self.accept(c, target.as_deref_mut(), view, &mut outcomes),
            |placed| placed.map_or(Ok(()), |p| c.place(p)),
        )?;
        // A unit is committed only whole: every view ran, and none ran out of what every
        // view needs (a tar missing such a view would be vouched for and never redone).
        let whole = outcomes.iter().all(|o| match o {
            None => false,
            Some(Outcome::Failed(e)) => resource_exhausted(e).is_none(),
            Some(_) => true,
        });
        let record = match (kept, open) {
            (Some(record), _) => Some(record),
            (None, Some(open)) if whole => {
                let failed: Vec<(usize, &str)> = unit
                    .views
                    .iter()
                    .zip(&outcomes)
                    .filter_map(|(&i, o)| match o {
                        Some(Outcome::Failed(e)) => Some((i, e.as_str())),
                        _ => None,
                    })
                    .collect();
                Some(c.commit(unit, open, &failed)?)
            }
            _ => None,
        };
        if let Err(e) = work.remove() {
            let mut problems = state.problems.lock().unwrap_or_else(|e| e.into_inner());
            problems.push(format!("{e:#}"));
        }
        Ok(UnitResult {
            record,
            kept: check_only,
            outcomes,
        })
    }

    /// Hand a rendered view to the container (views come in order), noting its outcome
    /// (and counting it in the progress: a view is done once its unit holds it, so the
    /// progress reaches its end with the last view taken, not rendered); a view's own
    /// failure is kept in its outcome and the view is not handed over.
    fn accept<C: Container>(
        &self,
        c: &C,
        open: Option<&mut C::Open>,
        (i, r): (usize, ViewResult<C::View>),
        outcomes: &mut Vec<Option<Outcome>>,
    ) -> Result<Option<C::Placed>> {
        let mut placed = None;
        let outcome = match r {
            None => None,
            Some(Ok(Ran::Done(view, cost))) => {
                if let Some(open) = open {
                    placed = Some(c.accept(open, i, view)?);
                }
                Some(Outcome::Done(cost))
            }
            Some(Ok(Ran::Kept)) => Some(Outcome::Skipped),
            Some(Err(e)) => Some(Outcome::Failed(e)),
        };
        if let Some(o) = &outcome {
            self.progress.record(o);
        }
        outcomes.push(outcome);
        Ok(placed)
    }

    /// Skip, render or fail view `i` (its scene read `ahead` with its unit, or now), then
    /// check it if it is selected; `None` when the run stopped before it started. In a kept
    /// unit (`check_only`) the view is rendered only for its check.
    fn view<C: Container>(
        &self,
        c: &C,
        i: usize,
        ahead: Option<&Result<Scene, String>>,
        work: &Path,
        check_only: bool,
        state: &State,
    ) -> ViewResult<C::View> {
        if self.stopping(state) {
            return None;
        }
        let checker = self.checker(i);
        if check_only && checker.is_none() {
            return Some(Ok(Ran::Kept));
        }
        let loaded;
        let scene = match ahead {
            Some(s) => s,
            None => {
                loaded = view_scene(&self.views[i], &self.cameras[i]);
                &loaded
            }
        };
        let ran = scene.as_ref().map_err(Clone::clone).and_then(|s| {
            let (ran, exr) = if check_only {
                (Ran::Kept, c.render(i, s, work, true)?.exr)
            } else if c.view_kept(i, s) {
                (Ran::Kept, None)
            } else {
                let r = c.render(i, s, work, checker.is_some())?;
                (Ran::Done(r.view, r.cost), r.exr)
            };
            if let Some(v) = checker {
                self.check(c, v, i, s, exr.as_deref(), work, state)?;
            }
            Ok(ran)
        });
        if let Err(why) = &ran
            && let Some(what) = resource_exhausted(why)
        {
            let mut stopped = state.stopped.lock().unwrap_or_else(|e| e.into_inner());
            stopped.get_or_insert_with(|| format!("{what}: {why}"));
        }
        Some(ran)
    }

    /// The verifier, if view `i` is among those it checks.
    fn checker(&self, i: usize) -> Option<&dyn Verifier> {
        self.verifier.filter(|_| {
            view_selected(
                self.opts.verify_seed,
                &self.views[i],
                self.opts.verify_fraction,
            )
        })
    }

    /// Check view `i`'s EXR (its file, or `exr` written to a private folder under `work`)
    /// with `verifier`; the error is the failure line.
    #[allow(clippy::too_many_arguments)]
    fn check<C: Container>(
        &self,
        c: &C,
        verifier: &dyn Verifier,
        i: usize,
        scene: &Scene,
        exr: Option<&[u8]>,
        work: &Path,
        state: &State,
    ) -> Result<(), String> {
        let view = &self.views[i];
        let check_work = work.join(format!("{}.verify.tmp", view.id().replace('/', ".")));
        let file = c.exr_path(i, &check_work);
        let checked = check_view(verifier, view, scene, &file, exr, &check_work);
        state.verified.fetch_add(1, Ordering::Relaxed);
        checked
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_in_flight_fill_the_pool_within_the_memory_budget() {
        // Nothing to hold: as many units as threads (or units), windows sharing the threads.
        assert_eq!(in_flight(0, 1, 8, None), (1, 8));
        assert_eq!(in_flight(0, 3, 8, None), (3, 3));
        assert_eq!(in_flight(0, 40, 2, None), (2, 1));
        assert_eq!(in_flight(0, 40, 1, None), (1, 1));
        // The files format's one unit: every view at once.
        assert_eq!(in_flight(0, 1, 2, Some(500)), (1, 500));
        // Views too large for any budget: one unit, one view at a time.
        assert_eq!(in_flight(u64::MAX / 8, 40, 16, None), (1, 1));
        assert_eq!(in_flight(u64::MAX / 8, 1, 16, Some(500)), (1, 1));
    }

    /// Eight views of 280 MiB (16384×4096 depth-only) with 600 MiB to spend: two at a
    /// time, whatever the thread count.
    #[test]
    fn the_memory_budget_bounds_the_views_in_flight() {
        let each = 280u64 << 20;
        let avail = crate::mem::memory_available().expect("Linux reports the memory left");
        let fit = ((avail / 2 / each) as usize).max(1);
        assert_eq!(in_flight(each, 1, 64, Some(8)).1, fit.min(8));
        assert_eq!(in_flight(each, 1, 1, Some(1)).1, 1);
    }
}
