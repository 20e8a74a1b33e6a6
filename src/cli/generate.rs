//! `cylaov generate`: seeded procedural scenes and their manifest.

use crate::cli::common::say;
use clap::Args;
use cylaov::commands;
use cylaov::dataset::generate::{Range, Volume};
use cylaov::scene::camera::model::CameraModel;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct GenerateCli {
    /// Number of views (scenes) to generate.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=commands::generate::MAX_COUNT))]
    count: Option<u64>,
    /// Random seed (default 0).
    #[arg(long)]
    seed: Option<u64>,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// JSON file with any of these options (same names, `caps_prob` for --caps-prob);
    /// flags override it.
    #[arg(long, value_name = "FILE.json")]
    config: Option<PathBuf>,
    /// Cylinders per scene: MIN..MAX or N [default: 8..32].
    #[arg(long, value_parser = Range::parse, allow_hyphen_values = true, value_name = "MIN..MAX")]
    cylinders: Option<Range>,
    /// Radius range [default: 0.05..0.3].
    #[arg(long, value_parser = Range::parse, allow_hyphen_values = true, value_name = "A..B")]
    radius: Option<Range>,
    /// Length (height) range [default: 0.2..2].
    #[arg(long, value_parser = Range::parse, allow_hyphen_values = true, value_name = "A..B")]
    length: Option<Range>,
    /// Half extents of the box (centred at the origin) holding the cylinder midpoints:
    /// S or X,Y,Z [default: 2,2,1].
    #[arg(long, value_parser = Volume::parse, allow_hyphen_values = true, value_name = "X,Y,Z")]
    volume: Option<Volume>,
    /// Probability that a cylinder has caps [default: 0.8].
    #[arg(long, allow_hyphen_values = true)]
    caps_prob: Option<f64>,
    /// Image width [default: 320].
    #[arg(long)]
    width: Option<u32>,
    /// Image height [default: 240].
    #[arg(long)]
    height: Option<u32>,
    /// Horizontal field of view, degrees [default: 50].
    #[arg(long)]
    fov: Option<f64>,
    /// Camera elevation range, degrees [default: -20..60].
    #[arg(long, value_parser = Range::parse, allow_hyphen_values = true, value_name = "A..B")]
    elevation: Option<Range>,
    /// Camera distance range, in units of the distance at which the scene's bounding
    /// sphere just fills the view [default: 0.55..0.9].
    #[arg(long, value_parser = Range::parse, allow_hyphen_values = true, value_name = "A..B")]
    distance: Option<Range>,
    /// Cameras per scene, around the same cylinders (camera 0 is the one a one-camera
    /// scene gets) [default: 1].
    #[arg(long, value_name = "V")]
    views_per_scene: Option<u32>,
    /// Put cameras 1.. on camera 0's orbit (same target, distance and height, azimuth
    /// stepped by 360°/V) instead of drawing them at random.
    #[arg(long)]
    orbit: bool,
    /// Camera model of every view: perspective, orthographic, opencv, opencv_fisheye or
    /// equirectangular [default: perspective]. Its parameters are drawn per
    /// scene from the seed (one lens for all of a scene's cameras): `opencv` has the --fov
    /// focal length with barrel distortion k1 in -0.25..0.05, |k2| <= 0.02, |p1|, |p2| <=
    /// 1e-3; `opencv_fisheye` spans 180° across the diagonal (fx = diagonal/π) with
    /// |k1| <= 0.02, |k2| <= 2e-3, |k3| <= 2e-4, |k4| <= 2e-5; `orthographic` spans the scene's bounding sphere times a --distance factor
    /// across its smaller side; `equirectangular` (the full sphere; give --width 2×
    /// --height) has none. The cylinders and camera directions are those of the same seed
    /// with the perspective model; the fisheye camera moves closer (by the ratio of the
    /// fit distances), the panorama to a fifth of the distance (among the cylinders) and
    /// the orthographic camera back to clear the scene.
    #[arg(long, value_name = "MODEL", value_parser = camera_model)]
    camera_model: Option<CameraModel>,
    /// Replace a dataset already in --out that has other settings or more scenes: removes
    /// generate's own files (generate.json, manifest.jsonl, scenes/NNNNNN.json) and nothing
    /// else. Without it such an --out is refused; the same settings are kept (nothing to
    /// do) and a larger --count extends the dataset.
    #[arg(long)]
    force: bool,
}

/// A `--camera-model` value, by the scene file's model names.
pub fn camera_model(s: &str) -> Result<CameraModel, String> {
    CameraModel::from_name(s).ok_or_else(|| {
        let names: Vec<&str> = CameraModel::ALL.iter().map(|m| m.name()).collect();
        format!("expected one of {}", names.join(", "))
    })
}

pub fn run(a: GenerateCli) -> anyhow::Result<ExitCode> {
    let args = commands::generate::GenerateArgs {
        out: a.out,
        config: a.config,
        flags: cylaov::dataset::generate::ConfigFile {
            count: a.count,
            seed: a.seed,
            cylinders: a.cylinders,
            radius: a.radius,
            length: a.length,
            volume: a.volume,
            caps_prob: a.caps_prob,
            width: a.width,
            height: a.height,
            fov: a.fov,
            elevation: a.elevation,
            distance: a.distance,
            views_per_scene: a.views_per_scene,
            orbit: a.orbit.then_some(true),
            camera_model: a.camera_model,
        },
        force: a.force,
    };
    say(&commands::generate::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}
