//! `cylaov cameras`: cameras around any scene.

use crate::cli::common::{say, shorten};
use clap::Args;
use cylaov::commands;
use cylaov::commands::{Usage, usage};
use cylaov::dataset::generate::Range;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct CamerasCli {
    /// Scene file (JSON, docs/scene-format.md).
    scene: PathBuf,
    /// The scene file to write.
    #[arg(short, long)]
    out: PathBuf,
    /// N cameras on one orbit about +z.
    #[arg(long, value_name = "N", conflicts_with = "sphere")]
    orbit: Option<u32>,
    /// N cameras in directions drawn area-uniformly from the elevation band.
    #[arg(long, value_name = "N")]
    sphere: Option<u32>,
    /// Elevation band above the xy plane, degrees: LOW..HIGH or one number.
    #[arg(long, value_parser = Range::parse, allow_hyphen_values = true, value_name = "A..B", default_value = "-20..60")]
    elevation: Range,
    /// "fit" (the bounding sphere fills the smaller field of view) or a factor of that
    /// distance.
    #[arg(long, default_value = "fit")]
    distance: String,
    /// Seed of the drawn directions.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Image width; default: the scene's first camera's.
    #[arg(long)]
    width: Option<u32>,
    /// Image height; default: the scene's first camera's.
    #[arg(long)]
    height: Option<u32>,
    /// Horizontal field of view, degrees (the cameras are pinholes); default: the scene's
    /// first camera's when it is a pinhole, else 50.
    #[arg(long)]
    fov: Option<f64>,
}

pub fn run(a: CamerasCli) -> anyhow::Result<ExitCode> {
    use cylaov::scene::rig::{CameraRig, Distance, RigSpec};
    let count = a.orbit.or(a.sphere);
    let flag = if a.orbit.is_some() {
        "--orbit"
    } else {
        "--sphere"
    };
    let max = cylaov::scene::rig::MAX_RIG_CAMERAS;
    if let Some(n) = count
        && (n == 0 || n > max)
    {
        return usage(format!("{flag}: must be in 1..={max}, got {n}"));
    }
    let e = a.elevation;
    if e.min < -85.0 || e.max > 85.0 {
        return usage(format!(
            "--elevation: must lie in -85..85 degrees (the camera's up is +z), got {e}"
        ));
    }
    if let Some(f) = a.fov
        && !(f > 0.0 && f < 180.0)
    {
        return usage(format!("--fov: must be in (0, 180), got {f}"));
    }
    let rig = match count {
        None => None,
        Some(n) => {
            // Defaults from the scene's first camera: its size whatever its model, its
            // field of view when it is a pinhole with one across x.
            let first = cylaov::scene::load(&a.scene).ok().map(|s| s.camera);
            let distance = match a.distance.as_str() {
                "fit" => Distance::default(),
                d => match d.parse::<f64>() {
                    Ok(x) if x.is_finite() && x > 0.0 && x <= 1e6 => Distance::Factor(x),
                    _ => {
                        return usage(format!(
                            "--distance: expected fit or a factor of the fit distance in (0, 1e6], got {:?}",
                            shorten(d)
                        ));
                    }
                },
            };
            let spec = RigSpec {
                elevation_deg: [a.elevation.min, a.elevation.max],
                distance,
                seed: a.seed,
                width: a.width.or(first.map(|c| c.width)).unwrap_or(640),
                height: a.height.or(first.map(|c| c.height)).unwrap_or(480),
                fov_deg: a
                    .fov
                    .or(first
                        .filter(|c| {
                            c.fov_axis == cylaov::scene::camera::FovAxis::X
                                && c.projection == cylaov::scene::camera::Projection::Perspective
                        })
                        .map(|c| c.fov_deg))
                    .unwrap_or(50.0),
                ..RigSpec::new(n)
            };
            Some(if a.orbit.is_some() {
                CameraRig {
                    orbit: Some(spec),
                    sphere: None,
                }
            } else {
                CameraRig {
                    orbit: None,
                    sphere: Some(spec),
                }
            })
        }
    };
    let args = commands::cameras::CamerasArgs {
        scene: a.scene,
        out: a.out,
        rig,
    };
    let from_flags = args.rig.is_some();
    let summary = commands::cameras::run(&args).map_err(|e| {
        // The rig's fields spelled as the flags that set them.
        let flag = e
            .downcast_ref::<cylaov::scene::SceneError>()
            .filter(|_| from_flags)
            .and_then(|se| Some((rig_flag(&se.field)?, se.message.clone())));
        match flag {
            Some((flag, message)) => Usage(format!("{flag}: {message}")).into(),
            None => e,
        }
    })?;
    say(&summary)?;
    Ok(ExitCode::SUCCESS)
}

/// The flag that sets the rig field `field` (`cameras.orbit.fov_deg` → `--fov`).
fn rig_flag(field: &str) -> Option<&'static str> {
    let (kind, name) = field.strip_prefix("cameras.")?.split_once('.')?;
    Some(match (kind, name) {
        ("orbit", "count") => "--orbit",
        ("sphere", "count") => "--sphere",
        (_, "fov_deg") => "--fov",
        (_, "distance") => "--distance",
        (_, "elevation_deg") => "--elevation",
        (_, "width") => "--width",
        (_, "height") => "--height",
        _ => return None,
    })
}
