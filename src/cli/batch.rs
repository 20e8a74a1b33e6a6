//! `cylaov batch`: every view of a folder or manifest, as files or tar shards.

use crate::cli;
use crate::cli::common::{KernelCli, TolerancesCli, say, set_threads};
use clap::Args;
use cylaov::choice::Choice;
use cylaov::commands;
use cylaov::commands::usage;
use cylaov::dataset::batch::shards::{Member, ShardOptions};
use cylaov::dataset::batch::{BatchOptions, ProgressMode, Schedule, Shard};
use cylaov::output::format::depth_png::OutOfRange;
use cylaov::output::format::exr::{Compression, ExrLayout};
use cylaov::scene::Aov;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct BatchCli {
    /// A folder of scene files (*.json, recursively; through its manifest.jsonl if it has
    /// one) or a .jsonl manifest.
    input: PathBuf,
    /// Output folder: per view NAME.exr, NAME.camera.json, NAME.open3d.json,
    /// NAME.normal.preview.png, NAME.depth.png, NAME.mask.png, NAME.render.json (what made
    /// them, checked on resume); index.json (every view), failures.K-of-N.jsonl. A scene with
    /// several cameras gets a folder SCENE/ with views 00, 01, ... and SCENE/transforms.json.
    #[arg(long)]
    out: PathBuf,
    /// AOVs in each EXR, comma-separated. Default: each scene's `aovs`.
    #[arg(long, value_parser = cli::choice::<Aov>(), value_delimiter = ',')]
    aov: Vec<Aov>,
    #[command(flatten)]
    kernel: KernelCli,
    /// Render shard K of N (0-based): the views whose list position i has i % N == K.
    /// Default: from SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN of SLURM_ARRAY_TASK_COUNT.
    #[arg(long, value_parser = Shard::parse, value_name = "K/N")]
    shard: Option<Shard>,
    /// Shard count N, the index coming from JOB_COMPLETION_INDEX (Kubernetes Indexed Job)
    /// or SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    shards: Option<u32>,
    /// 16-bit depth PNG value per world unit (1000: millimetres for metres; nerfstudio
    /// assumes 1000 unless given its `depth_unit_scale_factor` option).
    #[arg(long, default_value_t = 1000.0, allow_hyphen_values = true)]
    depth_scale: f64,
    /// A view with a hit whose depth × scale does not fit 16 bits: fail it (default; the
    /// message gives the largest scale that fits), or store those pixels as 0 and count them.
    #[arg(long, value_parser = cli::choice::<OutOfRange>(), default_value_t = OutOfRange::Fail, value_name = "fail|zero")]
    depth_out_of_range: OutOfRange,
    /// `layers`: one NAME.exr with every AOV; `per-aov`: NAME.<aov>.exr each, channels Y or
    /// R,G,B in float32, which OpenCV and imageio read.
    #[arg(long, value_parser = cli::choice::<ExrLayout>(), default_value_t = ExrLayout::Layers)]
    exr_layout: ExrLayout,
    /// Skip the PNGs (the indexes then point at the EXRs).
    #[arg(long)]
    no_png: bool,
    /// Also write NAME.ply per view: its hit points as a binary PLY point cloud (position,
    /// normal, shape_id, part, label), as render --ply writes them (with --format
    /// webdataset: --members ply).
    #[arg(long)]
    ply: bool,
    /// EXR compression.
    #[arg(long, value_parser = cli::choice::<Compression>(), default_value_t = Compression::None)]
    compression: Compression,
    /// Also render this fraction of the views (chosen from --verify-seed and the view
    /// names) with Mitsuba, when the reference venv exists, and fail views that disagree
    /// (either --format; views already on disk are checked again, a kept tar's from a
    /// render of their EXR).
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
    /// Write DIR/index.html for the views --verify-fraction checked: the page of
    /// `cylaov verify --report` (either --format).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Parallelise over views (default) or within one view at a time.
    #[arg(long, value_parser = cli::choice::<Schedule>(), default_value_t = Schedule::Views, hide = true)]
    schedule: Schedule,
    /// `files`: the files above per view; `webdataset`: tar shards OUT/shard-000000.tar, ...
    /// (KEY.depth.npy, KEY.normal.npy, one KEY.<aov>.npy per other AOV, KEY.mask.npy,
    /// KEY.json), each with its sidecar shard-000000.json, and OUT/shards.json; --shard K/N
    /// then assigns whole tars (j % N == K).
    #[arg(long, value_enum, default_value_t = Format::Files)]
    format: Format,
    /// Views per tar shard (--format webdataset).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    shard_size: Option<u64>,
    /// Extra members per view in each tar (--format webdataset), comma-separated: `exr`
    /// (KEY.exr), `depth.png` (KEY.depth.png, at --depth-scale), `ply` (KEY.ply, the hit
    /// points with normals and ids, as render --ply writes them).
    #[arg(long, value_parser = cli::choice::<Member>(), value_delimiter = ',')]
    members: Vec<Member>,
    /// With --format webdataset: replace the dataset --out holds when it was written with
    /// other settings (its tars, sidecars, shards.json and failures files are removed
    /// first); without it such a run is refused, naming each difference.
    #[arg(long)]
    force: bool,
    // Last: every option after a heading is listed under it.
    #[command(flatten, next_help_heading = "Bounds of --verify-fraction")]
    tolerances: TolerancesCli,
}

/// What `batch` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Files per view.
    Files,
    /// Tar shards that webdataset, Hugging Face datasets and Ray Data read.
    Webdataset,
}

/// Exit 1 when any view failed (the summary names the failures file).
pub fn run(a: BatchCli) -> anyhow::Result<ExitCode> {
    set_threads(a.kernel.threads)?;
    if a.format == Format::Webdataset && a.ply {
        return usage("--ply: with --format webdataset, ask for --members ply");
    }
    if a.format == Format::Webdataset && a.exr_layout != ExrLayout::Layers {
        return usage(format!(
            "--exr-layout {}: with --format webdataset a view's EXR (--members exr) is one \
             layered file",
            a.exr_layout.choice_name()
        ));
    }
    if a.format == Format::Files {
        if a.shard_size.is_some() {
            return usage("--shard-size: only with --format webdataset");
        }
        if !a.members.is_empty() {
            return usage("--members: only with --format webdataset");
        }
        if a.force {
            return usage("--force: only with --format webdataset");
        }
    }
    let format = a.format;
    let sopts = ShardOptions {
        shard_size: a
            .shard_size
            .map_or(cylaov::dataset::batch::shards::DEFAULT_SHARD_SIZE, |n| {
                n as usize
            }),
        members: a.members.clone(),
        force: a.force,
    };
    let args = commands::batch::BatchArgs {
        input: a.input,
        out: a.out,
        shard: a.shard,
        shards: a.shards,
        options: BatchOptions {
            aovs: (!a.aov.is_empty()).then_some(a.aov),
            precision: a.kernel.precision,
            formula: a.kernel.formula,
            depth_scale: a.depth_scale,
            png: !a.no_png,
            depth_out_of_range: a.depth_out_of_range,
            ply: a.ply,
            compression: a.compression,
            exr_layout: a.exr_layout,
            schedule: a.schedule,
            verify_fraction: a.verify_fraction,
            verify_seed: a.verify_seed,
        },
        progress: ProgressMode::auto(),
        tolerances: a.tolerances.get(),
        report: a.report,
    };
    if format == Format::Webdataset {
        return shards(&args, &sopts);
    }
    let summary = commands::batch::run(&args)?;
    say(&summary.to_string())?;
    let mut why: Vec<String> = Vec::new();
    if let Some(stopped) = &summary.stopped {
        why.push(format!(
            "stopped with {} views not started: {stopped}",
            summary.not_started
        ));
    }
    if summary.counts.failed > 0 {
        let see = if summary.failures_written {
            format!(" (see {})", summary.failures_path.display())
        } else {
            String::new()
        };
        why.push(format!(
            "{} of {} views failed{see}",
            summary.counts.failed, summary.in_shard
        ));
    }
    why.extend(summary.problems.iter().cloned());
    if !why.is_empty() {
        anyhow::bail!("{}", why.join("; "));
    }
    Ok(ExitCode::SUCCESS)
}

/// `batch --format webdataset`: exit 1 when any view of this process's tars failed or a
/// tar's work folder could not be removed.
pub fn shards(args: &commands::batch::BatchArgs, sopts: &ShardOptions) -> anyhow::Result<ExitCode> {
    let summary = commands::batch::shards(args, sopts)?;
    say(&summary.to_string())?;
    let mut why: Vec<String> = Vec::new();
    if !summary.failures.is_empty() {
        why.push(format!(
            "{} views failed (see {})",
            summary.failures.len(),
            summary.failures_path.display()
        ));
    }
    why.extend(summary.problems.iter().cloned());
    if !why.is_empty() {
        anyhow::bail!("{}", why.join("; "));
    }
    Ok(ExitCode::SUCCESS)
}
