//! `cylaov render`: one scene's view to an EXR and its side files.

use crate::cli;
use crate::cli::common::{KernelCli, say, set_threads};
use clap::Args;
use cylaov::commands;
use cylaov::output::format::depth_png::OutOfRange;
use cylaov::output::format::exr::{Compression, ExrLayout};
use cylaov::render::RenderOptions;
use cylaov::scene::Aov;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct RenderCli {
    /// Scene file (JSON, see docs/scene-format.md).
    scene: PathBuf,
    /// Output EXR; the camera metadata goes to OUT.camera.json beside it.
    #[arg(short, long)]
    out: PathBuf,
    /// AOVs to compute and store, comma-separated (e.g. depth,normal,shape_id).
    /// Default: the scene's `aovs`, else depth,normal.
    #[arg(long, value_parser = cli::choice::<Aov>(), value_delimiter = ',')]
    aov: Vec<Aov>,
    #[command(flatten)]
    kernel: KernelCli,
    /// Also write PNG previews (NAME.normal.preview.png, NAME.depth.preview.png with a
    /// legend) into DIR.
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    /// EXR compression.
    #[arg(long, value_parser = cli::choice::<Compression>(), default_value_t = Compression::None)]
    compression: Compression,
    /// Which camera of a `"cameras"` scene to render (0-based, file order).
    #[arg(long, value_name = "K", default_value_t = 0)]
    camera: usize,
    /// Also write OUT.depth.png: 16-bit round(depth × --depth-scale), 0 = no depth (depth
    /// is planar, except where the camera model's depth_kind says Euclidean).
    #[arg(long)]
    depth_png: bool,
    /// Depth PNG value per world unit (with --depth-png).
    #[arg(
        long,
        default_value_t = 1000.0,
        allow_hyphen_values = true,
        requires = "depth_png"
    )]
    depth_scale: f64,
    /// With --depth-png, a hit whose depth × scale does not fit 16 bits: fail (default) or
    /// store 0 and count.
    #[arg(long, value_parser = cli::choice::<OutOfRange>(), default_value_t = OutOfRange::Fail, value_name = "fail|zero")]
    depth_out_of_range: OutOfRange,
    /// `layers`: one OUT.exr with every AOV; `per-aov`: OUT.<aov>.exr each, channels Y or
    /// R,G,B in float32, which OpenCV and imageio read.
    #[arg(long, value_parser = cli::choice::<ExrLayout>(), default_value_t = ExrLayout::Layers)]
    exr_layout: ExrLayout,
    /// Also write the view's hit points as a point cloud: binary little-endian PLY with
    /// x y z nx ny nz (float32, world axes) and shape_id, part, label (uint), one point per
    /// pixel that hit a cylinder, row by row.
    #[arg(long, value_name = "OUT.ply")]
    ply: Option<PathBuf>,
}

pub fn run(a: RenderCli) -> anyhow::Result<ExitCode> {
    set_threads(a.kernel.threads)?;
    let args = commands::render::RenderArgs {
        scene: a.scene,
        out: a.out,
        aovs: (!a.aov.is_empty()).then_some(a.aov),
        options: RenderOptions {
            aovs: Vec::new(),
            precision: a.kernel.precision,
            formula: a.kernel.formula,
            accel: a.kernel.accel,
        },
        preview: a.preview,
        compression: a.compression,
        camera: a.camera,
        depth_png: a.depth_png.then_some(a.depth_scale),
        depth_out_of_range: a.depth_out_of_range,
        exr_layout: a.exr_layout,
        ply: a.ply,
    };
    say(&commands::render::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}
