//! The `cylaov` command line: parses arguments, calls the library, reports errors.

use clap::{Args, Parser, Subcommand};
use cylaov::aov::Compression;
use cylaov::compare::Tolerances;
use cylaov::render::{Accel, FormulaKind, Precision, RenderOptions};
use cylaov::scene::Aov;
use cylaov::{bench, commands};
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
    /// Time against error for every kernel, AOV set and cylinder count (generated scenes).
    ///
    /// Prints one row per (cylinders, kernel, AOVs): build, trace and write times, Mrays/s,
    /// the whole `cylaov render` process time and its peak memory, and the relative distance
    /// error against the stable f64 kernel. Rows are the minimum of --repeats runs.
    Bench(BenchCli),
    /// Write the Mitsuba 3 XML of a scene (the reference renderer's input).
    ///
    /// Example: cylaov export-mitsuba scenes/single.json -o single.xml
    ExportMitsuba(ExportCli),
    /// Compare two AOV EXRs pixel by pixel (SPEC §7); exit 1 if a tolerance is broken.
    ///
    /// Example: cylaov compare out/single.exr reference/single.exr --heatmap diff.png
    Compare(CompareCli),
    /// Measure every kernel (literal/stable x f32/f64) against a double-double oracle on
    /// the stress families (grazing, near-axis, far, scale, inside, rims, input).
    ///
    /// Example: cylaov stress --family grazing --csv out/grazing.csv --plot out/stress.png
    Stress(StressCli),
}

#[derive(Args)]
struct BenchCli {
    /// Cylinder counts, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 100, 1000, 10000, 100000])]
    counts: Vec<usize>,
    #[arg(long, default_value_t = 1920)]
    width: u32,
    #[arg(long, default_value_t = 1080)]
    height: u32,
    /// Timed runs per row (the minimum is kept).
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Only the default kernel (stable f64) and depth+normal: a quick look.
    #[arg(long)]
    quick: bool,
    /// Skip timing whole `cylaov render` processes.
    #[arg(long)]
    no_process: bool,
    /// Scene generator seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Also write the table as CSV (and Mitsuba's rows to OUT.mitsuba.csv).
    #[arg(long, value_name = "OUT.csv")]
    csv: Option<PathBuf>,
    /// Also draw the figure: error against time per kernel (Pareto view) and time against
    /// cylinder count, log-log, with Mitsuba's times when `--mitsuba` ran.
    #[arg(long, value_name = "OUT.png")]
    plot: Option<PathBuf>,
    /// Also render the same scenes with Mitsuba 3 (needs the reference venv: run from the
    /// repository root after scripts/setup-venv) and print the speed ratios.
    #[arg(long)]
    mitsuba: bool,
    /// Largest cylinder count rendered with Mitsuba's scalar_rgb (~75 s at 1 000).
    #[arg(long, default_value_t = 1000)]
    mitsuba_scalar_max: usize,
    /// Largest cylinder count rendered with Mitsuba's llvm_ad_rgb.
    #[arg(long, default_value_t = 10000)]
    mitsuba_llvm_max: usize,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
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

#[derive(Args)]
struct ExportCli {
    /// Scene file (JSON).
    scene: PathBuf,
    /// Output XML.
    #[arg(short, long)]
    out: PathBuf,
}

#[derive(Args)]
struct CompareCli {
    /// First image (usually cylaov's render).
    a: PathBuf,
    /// Second image (usually the Mitsuba reference).
    b: PathBuf,
    /// Write a PNG showing where the images differ (see `compare::heatmap`).
    #[arg(long, value_name = "OUT.png")]
    heatmap: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// Largest allowed fraction of mismatched pixels (all must lie on silhouettes).
    #[arg(long, default_value_t = Tolerances::default().max_mismatch_fraction, value_parser = non_negative)]
    max_mismatch_fraction: f64,
    /// Largest allowed relative distance error.
    #[arg(long, default_value_t = Tolerances::default().rel_distance, value_parser = non_negative)]
    rel_distance: f64,
    /// Largest allowed relative depth error.
    #[arg(long, default_value_t = Tolerances::default().rel_depth, value_parser = non_negative)]
    rel_depth: f64,
    /// Largest allowed normal angle error, degrees.
    #[arg(long, default_value_t = Tolerances::default().normal_deg, value_parser = non_negative)]
    normal_deg: f64,
}

fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
        _ => Err(format!("must be a finite number >= 0, got {s:?}")),
    }
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

/// Run the command; `Ok(false)` means it ran but found a failure (exit code 1).
fn run(cli: Cli) -> anyhow::Result<bool> {
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
        Command::Bench(b) => {
            set_threads(b.threads)?;
            let (kernels, aov_sets) = if b.quick {
                (vec![bench::KERNELS[0]], vec![vec![Aov::Depth, Aov::Normal]])
            } else {
                (bench::KERNELS.to_vec(), bench::default_aov_sets())
            };
            let opts = bench::BenchOptions {
                counts: b.counts,
                width: b.width,
                height: b.height,
                aov_sets,
                kernels,
                repeats: b.repeats,
                exe: if b.no_process {
                    None
                } else {
                    Some(std::env::current_exe()?)
                },
                seed: b.seed,
            };
            let mitsuba = b.mitsuba.then(|| bench::MitsubaBench {
                python: PathBuf::from(".venv/bin/python"),
                script: PathBuf::from("scripts/bench_mitsuba.py"),
                scalar_max: b.mitsuba_scalar_max,
                llvm_max: b.mitsuba_llvm_max,
            });
            if let Some(m) = &mitsuba
                && !(m.python.exists() && m.script.exists())
            {
                anyhow::bail!(
                    "--mitsuba: needs {} and {} (run from the repository root after scripts/setup-venv)",
                    m.python.display(),
                    m.script.display()
                );
            }
            commands::bench::run(&opts, mitsuba, b.csv, b.plot)?;
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
        Command::ExportMitsuba(a) => {
            println!("{}", commands::export_mitsuba::run(&a.scene, &a.out)?);
        }
        Command::Compare(a) => {
            let args = commands::compare::CompareArgs {
                a: a.a,
                b: a.b,
                heatmap: a.heatmap,
                json: a.json,
                tolerances: Tolerances {
                    max_mismatch_fraction: a.max_mismatch_fraction,
                    rel_distance: a.rel_distance,
                    rel_depth: a.rel_depth,
                    normal_deg: a.normal_deg,
                },
            };
            let out = commands::compare::run(&args)?;
            println!("{}", out.text);
            return Ok(out.passed);
        }
    }
    Ok(true)
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
