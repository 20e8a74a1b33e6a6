//! The `cylaov` command line: parses arguments, calls the library, reports errors.

use clap::{Args, Parser, Subcommand};
use cylaov::aov::Compression;
use cylaov::commands;
use cylaov::render::{FormulaKind, Precision, RenderOptions};
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
    /// Measure every kernel (literal/stable x f32/f64) against a double-double oracle on
    /// the stress families (grazing, near-axis, far, scale, inside, rims, input).
    ///
    /// Example: cylaov stress --family grazing --csv out/grazing.csv --plot out/stress.png
    Stress(StressCli),
}

#[derive(Args)]
struct StressCli {
    /// Run one family only: grazing, near-axis, far, scale, inside, rims, input.
    #[arg(long)]
    family: Option<String>,
    /// Seeded rays per value of the difficulty parameter.
    #[arg(long, default_value_t = 64)]
    rays: usize,
    /// Write one CSV line per ray and kernel (inputs included, to reproduce a ray).
    #[arg(long, value_name = "OUT")]
    csv: Option<PathBuf>,
    /// Write a log-log PNG of error against the difficulty parameter.
    #[arg(long, value_name = "OUT.png")]
    plot: Option<PathBuf>,
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
    /// AOVs to compute and store, comma-separated: distance,depth,normal,position,shape_id.
    /// Default: the scene's `aovs`, else depth,normal.
    #[arg(long, value_parser = Aov::parse_list)]
    aov: Option<Vec<Aov>>,
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
                aovs: a.aov,
                options: RenderOptions {
                    aovs: Vec::new(),
                    precision: a.kernel.precision,
                    formula: a.kernel.formula,
                },
                preview: a.preview,
                compression: a.compression,
            };
            println!("{}", commands::render::run(&args)?);
        }
        Command::Stress(a) => {
            let args = commands::stress::StressArgs {
                family: a.family,
                rays: a.rays,
                csv: a.csv,
                plot: a.plot,
            };
            println!("{}", commands::stress::run(&args)?);
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
