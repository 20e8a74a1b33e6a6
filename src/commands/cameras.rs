//! `cylaov cameras`: a scene with many cameras around its cylinders (an orbit or
//! directions over the sphere, [`crate::scene::rig`]), written resolved: every camera
//! listed and the cylinders inline, a scene file any tool reads.

use crate::output::store::targets::check_outputs;
use crate::scene::rig::CameraRig;
use crate::scene::{self, SceneFile};
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Everything `cameras` needs from the command line.
#[derive(Clone, Debug)]
pub struct CamerasArgs {
    /// The scene file.
    pub scene: PathBuf,
    /// The scene file to write (`-o`).
    pub out: PathBuf,
    /// The rig replacing the scene's cameras; `None` keeps them (a rig in the file is
    /// resolved).
    pub rig: Option<CameraRig>,
}

/// Write the resolved scene and return the one-line summary.
pub fn run(args: &CamerasArgs) -> Result<String> {
    let (input, out) = (&args.scene, &args.out);
    let (mut file, table) =
        scene::load_resolved(input).with_context(|| format!("{}", input.display()))?;
    let inputs: Vec<&Path> = std::iter::once(input.as_path())
        .chain(table.as_deref())
        .collect();
    check_outputs(&[("-o", out)], &inputs)?;
    if let Some(rig) = &args.rig {
        let cameras = rig
            .resolve(&file.cylinders, "cameras")
            .with_context(|| format!("{}", input.display()))?;
        file = SceneFile {
            camera: None,
            cameras: Some(cameras),
            ..file
        };
    }
    // One camera is written as "camera", several as "cameras".
    let scene = file
        .validate()
        .with_context(|| format!("{}", input.display()))?;
    let n = scene.cameras.len();
    if let (None, Some(mut list)) = (&file.camera, file.cameras.clone())
        && list.len() == 1
    {
        file.camera = list.pop();
        file.cameras = None;
    }
    super::write_scene_file(out, &file)?;
    Ok(format!(
        "{}: {} and {}",
        out.display(),
        crate::output::console::count(n, "camera"),
        crate::output::console::count(scene.cylinders.len(), "cylinder"),
    ))
}
