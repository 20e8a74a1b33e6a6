//! The `cylaov` command line: parses arguments, calls the library, reports errors.

use clap::{Args, Parser, Subcommand};
use cylaov::aov::Compression;
use cylaov::commands;
use cylaov::render::{Accel, FormulaKind, Precision, RenderOptions};
use cylaov::scene::Aov;
use std::path::PathBuf;
use std::process::ExitCode;

/// Compile cylinder scenes into per-pixel AOVs (depth, distance, normal, position,
/// shape id) as OpenEXR, and verify them against Mitsuba 3.
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene file to a multi-channel EXR (+ OUT.camera.json, optional PNG previews).
    ///
    /// Example: cylaov render scenes/single.json -o out/single.exr --preview out
    Render(RenderCli),
}

/// Kernel choice shared by every command that traces rays.
#[derive(Args, Clone, Debug)]
struct KernelCli {
    /// Kernel precision; f32 is faster, f64 is the accuracy reference.
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    precision: Precision,
    /// Kernel formulation: `stable` (default) or the SPEC §1 formulas as written.
    #[arg(long, value_enum, default_value_t = FormulaKind::Stable)]
    formula: FormulaKind,
    /// How primary rays find candidates: screen tiles (fast) or the BVH.
    #[arg(long, value_enum, default_value_t = Accel::Tiles)]
    accel: Accel,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Args)]
struct RenderCli {
    /// Scene file (JSON, see README "Scene format").
    scene: PathBuf,
    /// Output EXR; the camera metadata goes to OUT.camera.json beside it.
    #[arg(short, long)]
    out: PathBuf,
    /// AOVs to compute and store, comma-separated (e.g. depth,normal,shape_id).
    /// Default: the scene's `aovs`, else depth,normal.
    #[arg(long, value_enum, value_delimiter = ',')]
    aov: Vec<Aov>,
    #[command(flatten)]
    kernel: KernelCli,
    /// Also write PNG previews (NAME.normal.png, NAME.depth.png with a legend) into DIR.
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    /// EXR compression.
    #[arg(long, value_enum, default_value_t = Compression::None)]
    compression: Compression,
}

fn set_threads(threads: Option<usize>) -> anyhow::Result<()> {
    if let Some(n) = threads {
        if n == 0 {
            anyhow::bail!("--threads: must be >= 1, got 0");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()?;
    }
    Ok(())
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Render(a) => {
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
            };
            println!("{}", commands::render::run(&args)?);
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
