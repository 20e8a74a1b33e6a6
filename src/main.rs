//! The `cylaov` command line: parses arguments, calls the library, reports errors.

use clap::{Args, Parser, Subcommand};
use cylaov::aov::Compression;
use cylaov::batch::{BatchOptions, ProgressMode, Schedule, Shard};
use cylaov::commands;
use cylaov::generate::{Range, Volume};
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
    /// Generate procedural scenes: OUT/scenes/NNNNNN.json and OUT/manifest.jsonl.
    ///
    /// Same options and seed, same bytes. Example:
    /// cylaov generate --count 1000 --seed 1 --out data --cylinders 100
    Generate(GenerateCli),
    /// Render every view of a folder of scene files or a .jsonl manifest: resumable,
    /// shardable, with transforms.json for nerfstudio / instant-ngp.
    ///
    /// Example: cylaov batch data --out data/render --shard 0/4
    Batch(BatchCli),
}

#[derive(Args)]
struct GenerateCli {
    /// Number of views (scenes) to generate.
    #[arg(long)]
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
}

#[derive(Args)]
struct BatchCli {
    /// A folder of scene files (*.json, recursively; through its manifest.jsonl if it has
    /// one) or a .jsonl manifest.
    input: PathBuf,
    /// Output folder: NAME.exr, NAME.camera.json, NAME.normal.png, NAME.depth.png,
    /// transforms.json, failures.K-of-N.jsonl.
    #[arg(long)]
    out: PathBuf,
    /// AOVs in each EXR, comma-separated. Default: each scene's `aovs`.
    // `std::vec::Vec`: one comma-separated value, not clap's repeated-values `Vec`.
    #[arg(long, value_parser = Aov::parse_list)]
    aov: Option<std::vec::Vec<Aov>>,
    #[command(flatten)]
    kernel: KernelCli,
    /// Render shard K of N (0-based): the views whose list position i has i % N == K.
    /// Default: from SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN of SLURM_ARRAY_TASK_COUNT.
    #[arg(long, value_parser = Shard::parse, value_name = "K/N")]
    shard: Option<Shard>,
    /// Shard count N, the index coming from JOB_COMPLETION_INDEX (Kubernetes Indexed Job)
    /// or SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN.
    #[arg(long, value_name = "N")]
    shards: Option<u32>,
    /// 16-bit depth PNG value per world unit (1000: millimetres for metres).
    #[arg(long, default_value_t = 1000.0, allow_hyphen_values = true)]
    depth_scale: f64,
    /// Skip the PNGs (transforms.json then points at the EXRs).
    #[arg(long)]
    no_png: bool,
    /// EXR compression.
    #[arg(long, value_enum, default_value_t = Compression::None)]
    compression: Compression,
    /// Also render this fraction of the views (chosen from --verify-seed and the view
    /// names) with Mitsuba, when the reference venv exists, and fail views that disagree.
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "F",
        allow_hyphen_values = true
    )]
    verify_fraction: f64,
    /// Seed of the --verify-fraction choice.
    #[arg(long, default_value_t = 0)]
    verify_seed: u64,
    /// Parallelise over views (default) or within one view at a time.
    #[arg(long, value_enum, default_value_t = Schedule::Views, hide = true)]
    schedule: Schedule,
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
    aov: Option<std::vec::Vec<Aov>>,
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
        Command::Generate(a) => {
            let args = commands::generate::GenerateArgs {
                out: a.out,
                count: a.count,
                seed: a.seed,
                config: a.config,
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
            };
            println!("{}", commands::generate::run(&args)?);
        }
        Command::Batch(a) => {
            set_threads(a.kernel.threads)?;
            let args = commands::batch::BatchArgs {
                input: a.input,
                out: a.out,
                shard: a.shard,
                shards: a.shards,
                options: BatchOptions {
                    aovs: a.aov,
                    precision: a.kernel.precision,
                    formula: a.kernel.formula,
                    depth_scale: a.depth_scale,
                    png: !a.no_png,
                    compression: a.compression,
                    schedule: a.schedule,
                    verify_fraction: a.verify_fraction,
                    verify_seed: a.verify_seed,
                },
                progress: ProgressMode::auto(),
            };
            let summary = commands::batch::run(&args)?;
            println!("{summary}");
            if summary.counts.failed > 0 {
                anyhow::bail!(
                    "{} of {} views failed (see {})",
                    summary.counts.failed,
                    summary.in_shard,
                    summary.failures_path.display()
                );
            }
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
