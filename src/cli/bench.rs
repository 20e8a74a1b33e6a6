//! `cylaov bench`: the benchmarks, by the table they print.

use crate::cli;
use crate::cli::common::{say, set_threads, threads};
use clap::Args;
use cylaov::geometry::Kernel;
use cylaov::render::Accel;
use cylaov::scene::Aov;
use cylaov::{bench, commands};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct BenchCli {
    /// Scene families, comma-separated: `sparse` (sizes shrink as the count grows, the
    /// same depth complexity at every count) and `dense` (the same sizes at every count).
    #[arg(long, value_parser = cli::choice::<bench::Family>(), value_delimiter = ',', default_values_t = [bench::Family::Sparse, bench::Family::Dense])]
    family: Vec<bench::Family>,
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
    /// How rays find their cylinders in the timed renders: `bvh` shows what the screen
    /// tiles save (both give the same image, bit for bit).
    #[arg(long, value_parser = cli::choice::<Accel>(), default_value_t = Accel::Tiles)]
    accel: Accel,
    /// Also write the table as CSV (the kernel-alone rows to OUT.kernel.csv, Mitsuba's and
    /// Open3D's to OUT.anchors.csv); with --batch-formats, its rows; with --python, its
    /// measures (measure,value,unit).
    #[arg(long, value_name = "OUT.csv")]
    csv: Option<PathBuf>,
    /// Also keep each generated scene as DIR/FAMILY-N.json (an existing folder), to time or
    /// profile `cylaov render` on it by hand.
    #[arg(long, value_name = "DIR")]
    keep_scenes: Option<PathBuf>,
    /// Also draw the figure: error against time per kernel (Pareto view) and time against
    /// cylinder count, log-log, with Mitsuba's and Open3D's times when they ran.
    #[arg(long, value_name = "OUT.png")]
    plot: Option<PathBuf>,
    /// Also render the same scenes with Mitsuba 3 (needs the reference venv: run from the
    /// repository root after scripts/setup-venv) and print the speed ratios.
    #[arg(long)]
    mitsuba: bool,
    /// Largest cylinder count rendered with Mitsuba's scalar_rgb (it renders once; ~5 min at
    /// 1 000 bench cylinders, so the default stops at 100 to keep the run under 10 minutes).
    #[arg(long, default_value_t = 100)]
    mitsuba_scalar_max: usize,
    /// Largest cylinder count rendered with Mitsuba's llvm_ad_rgb.
    #[arg(long, default_value_t = 10000)]
    mitsuba_llvm_max: usize,
    /// Also time Open3D's ray caster (Embree) on the same scenes as 16-segment triangle
    /// meshes (open3d-cpu from the reference venv): what a general triangle ray tracer does
    /// with the same cylinders.
    #[arg(long)]
    open3d: bool,
    /// Largest cylinder count timed with Open3D.
    #[arg(long, default_value_t = 100000)]
    open3d_max: usize,
    /// Only the Python package's comparison (the reference venv, with `pip install .`
    /// done): `Dataset[i]` views/s against OpenEXR reading the same views' EXRs, 320x240
    /// depth+normal, 100 cylinders, and `render()`'s overhead on a 16x16 view.
    #[arg(long)]
    python: bool,
    /// Only the LiDAR scan: a VLP-16 rotation at 0.2 degrees (28 800 beams), three returns,
    /// 10 000 cylinders, in beams/s; with --open3d also Open3D's cast_rays of the same beams
    /// on 16-segment meshes (first hits only), warm, and the ratio.
    #[arg(long)]
    scan: bool,
    /// Only the dataset formats side by side: `batch` of one generated dataset (320x240,
    /// depth+normal, 100 cylinders a scene) in the files format with pictures, EXR-only,
    /// and as webdataset tar shards, in views/s, on the --threads given, the fastest of
    /// --repeats passes (each pass starts one format later, so none always runs after the
    /// others' writes); then the tar shards' ceilings on the same tar bytes: writing them
    /// alone, hashing them alone.
    #[arg(long)]
    batch_formats: bool,
    /// Only the EXR writer: an uncompressed file of a 1080p render (depth+normal, and every
    /// AOV) encoded into memory from the render's AOV buffers, and from the same image held
    /// one plane per channel (the same bytes), fastest of --repeats (at least 5); `--csv`
    /// keeps the rows.
    #[arg(long)]
    exr_writer: bool,
    /// Only scaling with the threads: views/s of `render` (in memory, a view at a time),
    /// `batch` to files (--no-png) and as tar shards (25 views a tar; each format the faster
    /// of two runs, one in each order), and, when the
    /// reference venv has the package and torch, `Dataset` through a PyTorch DataLoader
    /// (that many workers, threads=1 each, batches of 32), at 1, 2, 4, ... threads up to
    /// the cores (or --threads), with the parallel efficiency of each; 320x240,
    /// depth+normal, 100 cylinders a scene, --batch-views views.
    #[arg(long)]
    scaling: bool,
    /// Views of the --batch-formats and --scaling datasets.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..))]
    batch_views: u64,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, value_parser = threads)]
    threads: Option<usize>,
}

pub fn run(b: BenchCli) -> anyhow::Result<ExitCode> {
    set_threads(b.threads)?;
    if b.exr_writer {
        if let Some(p) = &b.csv {
            cylaov::output::store::targets::check_outputs(&[("--csv", p)], &[])?;
        }
        let rows = bench::exr_writer::run(1000, b.width, b.height, b.repeats.max(5))?;
        say(&bench::exr_writer::table(&rows))?;
        if let Some(p) = &b.csv {
            cylaov::output::store::atomic::atomic_write_bytes(
                p,
                &cylaov::output::format::camera_files::csv_bytes(&rows)?,
            )?;
        }
        return Ok(ExitCode::SUCCESS);
    }
    if b.scan {
        let python = if b.open3d {
            let found = cylaov::verify::reference::Mitsuba::find()
                .map_err(|why| anyhow::anyhow!("--open3d: {why}"))?;
            Some(found.python)
        } else {
            None
        };
        let r = bench::scan::run(python.as_deref())?;
        let rate = r.beams as f64 / r.seconds;
        say(&format!(
            "scan: vlp16 0.2 deg, {} beams, 10000 cylinders, 3 returns: {} points in {:.4} s, {:.0} beams/s ({} threads)",
            r.beams,
            r.points,
            r.seconds,
            rate,
            rayon::current_num_threads()
        ))?;
        if let Some(o) = r.open3d_seconds {
            let o3d = r.beams as f64 / o;
            say(&format!(
                "open3d cast_rays (first hits, warm): {o:.4} s, {o3d:.0} rays/s; cylaov / open3d = {:.2}",
                rate / o3d
            ))?;
        }
        return Ok(ExitCode::SUCCESS);
    }
    if b.batch_formats {
        commands::bench::batch_formats(b.batch_views, b.repeats, b.csv.as_deref())?;
        return Ok(ExitCode::SUCCESS);
    }
    if b.scaling {
        let cores = b.threads.unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
        });
        commands::bench::scaling(b.batch_views, cores, b.csv.as_deref())?;
        return Ok(ExitCode::SUCCESS);
    }
    if b.python {
        let python = cylaov::verify::reference::Mitsuba::find()
            .map_err(|why| anyhow::anyhow!("--python: {why}"))?
            .python;
        say(&commands::bench::python(
            &python,
            &std::env::current_exe()?,
            b.csv.as_deref(),
        )?)?;
        return Ok(ExitCode::SUCCESS);
    }
    let (kernels, aov_sets) = if b.quick {
        (
            vec![Kernel::STABLE_F64],
            vec![vec![Aov::Depth, Aov::Normal]],
        )
    } else {
        (Kernel::ALL.to_vec(), bench::default_aov_sets())
    };
    let opts = bench::BenchOptions {
        families: b.family,
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
        accel: b.accel,
        keep_scenes: b.keep_scenes,
    };
    let anchors = match (b.mitsuba, b.open3d) {
        (false, false) => None,
        (mitsuba, open3d) => Some(bench::Anchors {
            python: cylaov::verify::reference::Mitsuba::find()
                .map_err(|why| {
                    let flag = if mitsuba { "--mitsuba" } else { "--open3d" };
                    anyhow::anyhow!("{flag}: {why}")
                })?
                .python,
            mitsuba_scalar_max: if mitsuba { b.mitsuba_scalar_max } else { 0 },
            mitsuba_llvm_max: if mitsuba { b.mitsuba_llvm_max } else { 0 },
            open3d_max: if open3d { b.open3d_max } else { 0 },
        }),
    };
    commands::bench::run(&opts, anchors, b.csv, b.plot)?;
    Ok(ExitCode::SUCCESS)
}
