//! Batches of views (`cylaov batch`): the view list, sharding, resumable rendering through
//! one rayon pool, and the dataset indexes `index.json` and `SCENE/transforms.json`.
//!
//! A view is one (scene, camera) pair: a one-camera scene `NAME` writes `OUT/NAME.*`, a
//! scene with several cameras writes `OUT/NAME/00.*`, `OUT/NAME/01.*`, … and its own
//! `OUT/NAME/transforms.json` (nerfstudio reads one such file as one static scene).
//! Per view the folder gets `NAME.exr` (or `NAME.<aov>.exr` per AOV), `NAME.camera.json`,
//! `NAME.open3d.json`, `NAME.normal.preview.png` (8-bit picture), `NAME.depth.png` (16-bit,
//! planar depth × `depth_scale`; a view that does not fit fails unless told to store 0),
//! `NAME.mask.png` and `NAME.render.json`, the stamp of what made the files
//! ([`render_stamp`]: a hash of the scene and camera and every option that changes output
//! bytes). Every name is in `crate::dataset::names`.
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
//! **Determinism invariant**: the view list, the shard of each view (`index % N`),
//! `index.json` and every `transforms.json` are pure functions of the input files and the
//! options, so every shard computes the same list and writes the same index bytes.
//!
//! **One driver**: both formats run on `driver`, which takes each unit's lock, clears its
//! work folder, resumes, renders windows of views within the memory budget, verifies,
//! counts progress and stops on a full disk; a format is a container that says what a
//! view's members are and how a unit is committed (the files format: this process's
//! shard, each view committed on its own; tar shards: one tar).
//!
//! The pieces, in the order a run uses them: `views` (the view list), `input` (the list
//! read with each view's camera, as both formats read it), `shard` (which views
//! this process renders), `lock` (the locks and the real, unfollowed partial folder),
//! `options`, `resume` (output paths, render stamp, completeness checks), `driver` (the
//! loop over units and views), `in_order` (views rendered at once, taken in order),
//! `write` (one view rendered and moved into place), `verify` (the reference check
//! interface), `transforms` (`transforms.json`), `progress`,
//! `failures`, and `run` (the files format: its container, `index.json`, stale views);
//! `shards` writes the same views as tar shards (`--format webdataset`), and `samples`
//! reads them back (`cylaov verify OUT`).

mod driver;
mod failures;
mod in_order;
mod input;
mod lock;
mod options;
mod progress;
mod resume;
mod run;
pub mod samples;
mod shard;
pub mod shard_settings;
pub mod shards;
mod transforms;
mod verify;
mod views;
mod write;

pub use options::{BatchOptions, Schedule};
pub use progress::{Counts, LARGE_OUTPUT, Outcome, Progress, ProgressMode, SizeEstimate};
pub use resume::{
    ViewFiles, expected_channels, exr_is_complete, render_stamp, view_file_names, view_is_complete,
};
pub use run::{Failure, Summary, run};
pub use shard::{Shard, resolve_shard};
pub use transforms::{FrameCamera, transforms_json};
pub use verify::{Verdict, Verifier, selected_for_verify, view_selected};
pub use views::{Skipped, ViewSource, list_views};
pub use write::{ViewCost, render_view};
