//! The batch's input, read the same way by both formats: the view list of a folder or
//! manifest, each view's camera for the indexes (or why its scene does not load), and the
//! errors that stop a run because every later view would fail the same way.

use super::options::BatchOptions;
use super::transforms::FrameCamera;
use super::views::{ViewSource, list_views};
use crate::scene::camera::Camera;
use crate::scene::{self, Scene};
use anyhow::Result;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Read a view's scene, the error naming its file.
pub(super) fn load(view: &ViewSource) -> Result<Scene, String> {
    scene::load(&view.path).map_err(|e| format!("{}: {e}", view.path.display()))
}

/// The scene of `view` with the view's camera selected, as both formats render it, or why
/// not: `camera` is what reading the input found (an error there is the view's failure).
pub(super) fn view_scene<C>(
    view: &ViewSource,
    camera: &Result<C, String>,
) -> Result<Scene, String> {
    if let Err(e) = camera {
        return Err(e.clone());
    }
    let mut s = load(view)?;
    s.select_camera(view.camera)
        .map_err(|e| format!("{}: {e}", view.path.display()))?;
    Ok(s)
}

/// Every view of the listed scenes (one per camera) and what the index needs of its camera,
/// or why its scene does not load (such a scene is one failing view).
/// Every shard reads every scene (the index lists every valid view) but keeps only what the
/// index needs: memory is O(views), not O(views x cylinders). The views of this shard are
/// read again, one at a time, when rendered. The list is a pure function of the input.
/// The batch's view list and each view's camera (or why it has none).
pub(super) type Views = (Vec<ViewSource>, Vec<Result<FrameCamera, String>>);

/// The batch's view list and each view's camera, read from `input` (the folder scan skips
/// `out`'s own files), saying what the scan skipped when `announce`. Out of file handles
/// while reading the scenes is not a bad scene: it stops the run.
pub(super) fn read_views(
    input: &Path,
    out: &Path,
    opts: &BatchOptions,
    announce: bool,
) -> Result<Views> {
    let (scenes, skipped) = list_views(input, Some(out))?;
    if !skipped.is_empty() && announce {
        eprintln!("{}: skipped {skipped}", input.display());
    }
    let (views, cameras) = expand_views(&scenes, opts);
    if let Some((what, e)) = cameras
        .iter()
        .filter_map(|c| c.as_ref().err())
        .find_map(|e| resource_exhausted(e).map(|what| (what, e)))
    {
        anyhow::bail!("reading the scenes: {what}: {e}");
    }
    Ok((views, cameras))
}

/// The folder the scene files' paths are shown relative to: `input` itself when it is a
/// folder, else the folder of the manifest or scene file.
pub(super) fn input_dir(input: &Path) -> PathBuf {
    if input.is_dir() {
        input.to_path_buf()
    } else {
        input.parent().unwrap_or(Path::new("")).to_path_buf()
    }
}

pub(super) fn expand_views(
    scenes: &[ViewSource],
    opts: &BatchOptions,
) -> (Vec<ViewSource>, Vec<Result<FrameCamera, String>>) {
    let read: Vec<Result<Vec<FrameCamera>, String>> = scenes
        .par_iter()
        .map(|v| {
            load(v).map(|s| {
                s.cameras
                    .iter()
                    .map(|&c| FrameCamera::new(&Camera::new(c), &opts.exr_aovs(&s)))
                    .collect()
            })
        })
        .collect();
    let mut views = Vec::new();
    let mut cameras = Vec::new();
    for (scene, cams) in scenes.iter().zip(read) {
        match cams {
            Ok(cams) => {
                views.extend(scene.cameras(cams.len()));
                cameras.extend(cams.into_iter().map(Ok));
            }
            Err(e) => {
                views.push(scene.clone());
                cameras.push(Err(e));
            }
        }
    }
    (views, cameras)
}

/// Which resource ran out, if `error` (a view's failure) says one did that every later
/// view needs as well: then the shard stops rather than fail each of them the same way.
pub fn resource_exhausted(error: &str) -> Option<&'static str> {
    const CODES: [(i32, &str); 5] = [
        (28, "the disk is full"),
        (122, "the disk quota is exceeded"),
        (27, "the file size limit (ulimit -f) is reached"),
        (24, "too many open files (ulimit -n)"),
        (23, "too many open files in the system"),
    ];
    CODES
        .iter()
        .find(|(n, _)| error.contains(&format!("(os error {n})")))
        .map(|c| c.1)
}
