//! Rendering one view: its [`ViewPlan`] executed into a [`FileSink`] that stages every
//! file in the shard's partial folder, then renames them into place with the EXR last.

use super::options::BatchOptions;
use super::resume::{ViewFiles, view_plan};
use crate::output::pipeline::view::{FileSink, Member};
use crate::render::RenderOptions;
use crate::scene::{Aov, Scene};
use anyhow::Result;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Time spent on one rendered view, and what its depth PNG could not hold.
#[derive(Clone, Copy, Debug, Default)]
pub struct ViewCost {
    /// BVH build + tracing into the in-memory AOV image; with one uncompressed EXR and
    /// no PNGs, the EXR too (written band by band during the trace).
    pub trace: Duration,
    /// PNG encoding, EXR encoding (unless streamed), camera JSON, all writes and renames.
    pub write: Duration,
    /// Hit pixels stored as 0 in the depth PNG (`--depth-out-of-range zero`).
    pub depth_zeroed: usize,
}

/// Where a batch puts `member` of view `NAME`: `DIR/NAME.SUFFIX`.
fn member_path(dir: &Path, name: &str, member: Member) -> PathBuf {
    dir.join(format!("{name}.{}", member.suffix()))
}

/// What a commit of view `done` removes before renaming: every EXR of either layout (each
/// is a "done" marker), the normal picture under its pre-0.2 name and, without PNGs (or
/// without `--ply`), the pictures (or point cloud) already there (they would not match
/// the stamp).
///
/// An EXR in place is the view's "done" marker, so an older one goes before any new file
/// of the view replaces its sibling: a re-render killed between the renames leaves no
/// EXR (the view is rendered again), never a new camera beside old PNGs and an old EXR.
fn stale(done: &ViewFiles, png: bool, ply: bool) -> Vec<PathBuf> {
    let mut stale: Vec<PathBuf> = vec![done.exr.clone()];
    stale.extend(Aov::ALL.iter().map(|&a| done.per_aov(a)));
    stale.push(done.legacy_normal_png.clone());
    if !png {
        stale.extend([
            done.normal_png.clone(),
            done.depth_png.clone(),
            done.mask_png.clone(),
        ]);
    }
    if !ply {
        stale.push(done.ply.clone());
    }
    stale
}

/// Render one view into `partial` (temporary names `TMP_STEM.*.tmp`) and move its files
/// into `dir` as `NAME.*`, the EXR last. A depth PNG that cannot hold the view's depths
/// (under [`OutOfRange::Fail`](crate::output::format::depth_png::OutOfRange::Fail)) fails the view
/// before anything is staged.
pub fn render_view(
    dir: &Path,
    partial: &Path,
    name: &str,
    tmp_stem: &str,
    scene: &Scene,
    opts: &BatchOptions,
) -> Result<ViewCost> {
    let plan = view_plan(scene, opts);
    let render_opts = RenderOptions {
        precision: opts.precision,
        formula: opts.formula,
        ..RenderOptions::new(plan.traced_aovs())
    };
    let (d, n) = (dir.to_path_buf(), name.to_string());
    let mut sink = FileSink::in_work_folder(move |m| member_path(&d, &n, m), partial, tmp_stem)
        .replacing(stale(&ViewFiles::new(dir, name), opts.png, opts.ply));
    let written = plan.execute(scene, &render_opts, &mut sink)?;
    Ok(ViewCost {
        trace: written.trace,
        write: written.write,
        depth_zeroed: written.depth_zeroed,
    })
}
