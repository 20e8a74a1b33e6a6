//! The `cylaov` command line: parses arguments, calls the library, reports errors.

use clap::{Args, Parser, Subcommand};
use cylaov::dataset::batch::shards::{Member, ShardOptions, TarSelection};
use cylaov::dataset::batch::{BatchOptions, ProgressMode, Schedule, Shard};
use cylaov::dataset::generate::{Range, Volume};
use cylaov::geometry::{FormulaKind, Kernel, Precision};
use cylaov::output::aov::{Compression, ExrLayout};
use cylaov::output::depth_png::OutOfRange;
use cylaov::render::{Accel, RenderOptions};
use cylaov::scene::Aov;
use cylaov::scene::camera::model::CameraModel;
use cylaov::scene::framing::Frame;
use cylaov::scene::table::{LabelRule, TableFormat, TableOptions};
use cylaov::verify::compare::Tolerances;
use cylaov::{bench, commands};
use std::path::PathBuf;
use std::process::ExitCode;

mod cli;

/// A failed allocation anywhere (inside crates too) is one error line and the command's
/// status for too little memory (1; 2 in `compare` and `verify`), never an abort with
/// status 134.
#[global_allocator]
static ALLOCATOR: cylaov::mem::Guarded = cylaov::mem::Guarded::PLAIN;

/// Compile cylinder scenes into per-pixel AOVs (depth, distance, normal, position,
/// shape id) as OpenEXR, and verify them against Mitsuba 3.
#[derive(Parser)]
#[command(version, about, long_about = None, after_help = EXIT_STATUS)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// The one exit-status rule of every command (also in the README).
const EXIT_STATUS: &str = "Exit status, every command: 0 = done; 1 = input rejected (a bad scene, \
a refused output, a full disk, too little memory) or a check failed (compare's or verify's \
tolerances, a batch view); 2 = usage error (unknown option, bad value) or a check that could \
not be made (compare: a missing or unreadable image, too little memory; verify: a view it \
could not check, too little memory); 129, 130, 143 = \
stopped by SIGHUP, SIGINT, SIGTERM (128 + the signal number; unfinished files removed). A \
closed stdout (`| head`) is not an error.";

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
    /// error against the stable f64 kernel. Rows are the minimum of --repeats runs. Then the
    /// kernel alone (one thread, million ray-cylinder tests per second; scalar, portable
    /// packets and AVX2 packets), which shows what f32 buys where the kernel is all the work.
    ///
    /// Example (about 10 seconds): cylaov bench --counts 1000 --quick --mitsuba --open3d
    ///
    /// Example (what the screen tiles save over the BVH): cylaov bench --quick --accel bvh
    Bench(BenchCli),
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
    /// Turn a table of cylinders (a tree's QSM, any CSV, or NumPy arrays) into a framed scene file.
    ///
    /// The table comes from TreeQSM, SimpleForest, aRchi, any CSV or an .npz; the scene file gets
    /// one camera that frames every cylinder (its bounding sphere fills the smaller field
    /// of view).
    ///
    /// Formats (--format; left out, the header says which, else the column count):
    ///   csv           header with x0,y0,z0,x1,y1,z1,radius and optional id, label, caps;
    ///   npz           numpy.savez or savez_compressed arrays p0 (N, 3), p1 (N, 3),
    ///                 radius (N,), optional id, label, caps (N,) (and branch_order or
    ///                 branch for --label); told by its zip signature, whatever its name;
    ///   treeqsm       TreeQSM cyl_data: radius, length, start x y z, axis x y z, parent,
    ///                 extension, branch, BranchOrder, PositionInBranch, added, UnmodRadius
    ///                 (15 columns without a header in TreeQSM 2.3, 14 in older ones; later
    ///                 versions write a header: parent, extension, branch, BranchOrder);
    ///   simpleforest  header with ID, parentID, startX..endZ, radius, branchOrder, branchID;
    ///   archi         header with startX..endZ, cyl_ID, parent_ID, radius_cyl,
    ///                 branching_order.
    /// Fields are separated by commas, else by spaces or tabs; lines starting with # are
    /// skipped; header names match whatever their case and punctuation (start.x = startX).
    ///
    /// Each row is one cylinder: start → p0, end (or start + length · axis) → p1, radius; its
    /// id is the table's own (ID, cyl_ID, id) or the row number (TreeQSM, whose parent column
    /// counts rows). A bad row (not a number, non-finite, radius <= 0, zero length) is
    /// refused with its line and column (an .npz value with its array and index, radius[16]),
    /// and nothing is written.
    ///
    /// Example: cylaov import tree_cyl_data.txt -o tree.json --label branch_order
    ///
    /// Then: cylaov render tree.json -o tree.exr --aov depth,normal,shape_id,label
    #[command(verbatim_doc_comment)]
    Import(ImportCli),
    /// Simulate a rotating LiDAR: one rotation's points (exact multiple returns) as LAS, PLY or NPZ.
    ///
    /// Every beam of the sensor (a preset or a JSON table: docs/scan.md) is cast from its
    /// pose into the scene; up to --returns surfaces a beam, each the exact next one along it
    /// (a closed cylinder crossed gives 2). Points are in world coordinates; per point: x y z,
    /// range, range_exact, ring, azimuth, time, return_index, num_returns, shape_id, part,
    /// label, normal. The output's extension picks the format: .las (LAS 1.4, point format
    /// 6), .ply (binary, Open3D reads it), .npz (numpy.load).
    ///
    /// Presets: vlp16 (16 beams, -15..15 deg), hdl32 (32, -30.67..10.67), os1-64 (64, +-16.6).
    /// Sensor axes: x forward, z up; azimuth 0 along +x, counter-clockwise seen from above;
    /// pose yaw about world z, then pitch, then roll (degrees).
    ///
    /// Example: cylaov scan scene.json --sensor vlp16 --pose 0,0,1.8 -o scan.las
    ///
    /// Example (three returns, 2 cm noise, 5% dropout):
    /// cylaov scan scene.json --sensor vlp16 --pose 0,0,1.8,90,0,0 --returns 3
    ///     --range-noise 0.02 --dropout 0.05 --seed 7 -o scan.npz
    ///
    /// Example (moving sensor, motion skew): cylaov scan scene.json --sensor os1-64
    ///     --trajectory path.csv -o scan.ply
    ///   where path.csv is `time,x,y,z,yaw,pitch,roll` then one pose a line (seconds from
    ///   the rotation's start, degrees).
    #[command(verbatim_doc_comment)]
    Scan(ScanCli),
    /// Put many cameras around a scene's cylinders and write the scene resolved.
    ///
    /// --orbit N: camera 0's direction drawn area-uniformly from the elevation band, the
    /// others it turned about +z by k·360°/N (as generate --orbit); --sphere N: every
    /// direction drawn area-uniformly from the band. Each camera looks at the centre of the
    /// sphere holding the cylinders from --distance times the distance at which that sphere
    /// fills the smaller field of view. Same options and seed, same cameras. Without
    /// --orbit or --sphere, a scene's own "cameras": {"orbit": {...}} is resolved. The
    /// output lists every camera and the cylinders inline (a table it names is read in).
    ///
    /// Example: cylaov cameras tree.json --orbit 200 -o tree200.json
    Cameras(CamerasCli),
    /// Write the Mitsuba 3 XML of a scene (the reference renderer's input).
    ///
    /// Example: cylaov export-mitsuba scenes/single.json -o single.xml
    ExportMitsuba(ExportCli),
    /// Check scenes against Mitsuba 3: render each view with cylaov and with Mitsuba
    /// (the pinned venv) and compare them pixel by pixel. Where they disagree beyond the
    /// tolerances, the exact answer (double-double, on the camera's f64 ray) decides: a
    /// reference error (Mitsuba off within its float32 bound) passes and is counted; a
    /// candidate error (cylaov off the exact answer) or an unexplained reference error
    /// (Mitsuba off beyond its bound: an export or scene error) fails.
    ///
    /// Exit status: 1 if any view fails, else 2 if any view could not be checked (a bad
    /// scene, no venv, Mitsuba failed, too little memory), else 0.
    ///
    /// Example: cylaov verify scenes/single.json --heatmap out
    ///
    /// Example (a twentieth of a generated dataset): cylaov verify data --fraction 0.05
    Verify(VerifyCli),
    /// Compare two AOV EXRs pixel by pixel (docs/verification.md, "Comparing two renders"); exit 1 if a
    /// tolerance is broken.
    ///
    /// Exit status: 0 when every tolerance holds, 1 when one is broken (the report says
    /// which), 2 when the comparison could not be made (a missing or unreadable file, images
    /// of different sizes, a bad shape_id, an unwritable heatmap, too little memory) or the
    /// arguments are wrong.
    ///
    /// Example: cylaov compare out/single.exr reference/single.exr --heatmap diff.png
    Compare(CompareCli),
    /// Measure every kernel (literal/stable x f32/f64) against a double-double oracle on
    /// the stress families (grazing, near-axis, far, scale, inside, rims, input).
    ///
    /// Example: cylaov stress --family grazing --csv out/grazing.csv --plot out/stress.png
    Stress(StressCli),
    /// Print the AOV table: each AOV's EXR channels, per-AOV file channels, sample type,
    /// meaning (the text the EXR header carries), miss value and how `compare` judges it.
    ///
    /// Example: cylaov aovs
    Aovs,
}

#[derive(Args)]
struct GenerateCli {
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

#[derive(Args)]
struct BatchCli {
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
    /// Write DIR/index.html for the views --verify-fraction checked: the page of
    /// `cylaov verify --report`.
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

/// A `--camera-model` value, by the scene file's model names.
fn camera_model(s: &str) -> Result<CameraModel, String> {
    CameraModel::from_name(s).ok_or_else(|| {
        let names: Vec<&str> = CameraModel::ALL.iter().map(|m| m.name()).collect();
        format!("expected one of {}", names.join(", "))
    })
}

/// What `batch` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Format {
    /// Files per view.
    Files,
    /// Tar shards that webdataset, Hugging Face datasets and Ray Data read.
    Webdataset,
}

#[derive(Args)]
struct BenchCli {
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
    /// and as webdataset tar shards, in views/s, on the --threads given; then the tar
    /// shards' ceilings on the same tar bytes: writing them alone, hashing them alone.
    #[arg(long)]
    batch_formats: bool,
    /// Only the EXR writer: an uncompressed file of a 1080p render (depth+normal, and every
    /// AOV) encoded into memory from the render's AOV buffers, and from the same image held
    /// one plane per channel (the same bytes), fastest of --repeats (at least 5); `--csv`
    /// keeps the rows.
    #[arg(long)]
    exr_writer: bool,
    /// Only scaling with the threads: views/s of `render` (in memory, a view at a time),
    /// `batch` to files (--no-png) and as tar shards (25 views a tar), and, when the
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

#[derive(Args)]
struct StressCli {
    /// Run one family only: grazing, near-axis, far, scale, inside, rims, input.
    #[arg(long, value_parser = family)]
    family: Option<String>,
    /// Seeded rays per value of the difficulty parameter.
    #[arg(long, default_value_t = 64, value_parser = at_least_one)]
    rays: usize,
    /// Write one CSV line per ray and kernel (inputs included, to reproduce a ray).
    #[arg(long, value_name = "OUT")]
    csv: Option<PathBuf>,
    /// Write a log-log PNG of error against the difficulty parameter.
    #[arg(long, value_name = "OUT.png")]
    plot: Option<PathBuf>,
    /// Print the table as Markdown, as in the README (the same bytes on every run).
    #[arg(long)]
    markdown: bool,
}

#[derive(Args)]
struct ScanCli {
    /// Scene file (JSON, see docs/scene-format.md); its cameras are not used.
    scene: PathBuf,
    /// A preset (vlp16, hdl32, os1-64) or a sensor JSON file (docs/scan.md).
    #[arg(long, value_name = "NAME|SENSOR.json")]
    sensor: String,
    /// The point file: .las, .ply or .npz.
    #[arg(short, long, value_name = "OUT.{las,ply,npz}")]
    out: PathBuf,
    /// The sensor's position and (optional) yaw, pitch, roll in degrees.
    #[arg(
        long,
        value_name = "X,Y,Z[,YAW,PITCH,ROLL]",
        default_value = "0,0,0",
        allow_hyphen_values = true
    )]
    pose: String,
    /// Poses over time (CSV: time,x,y,z,yaw,pitch,roll), interpolated at each beam's time
    /// (position linearly, rotation by slerp); replaces --pose.
    #[arg(long, value_name = "FILE", conflicts_with = "pose")]
    trajectory: Option<PathBuf>,
    /// Most returns per beam, 1 to 15.
    #[arg(long, default_value_t = 1, value_name = "N")]
    returns: u32,
    /// Standard deviation of Gaussian noise on the range, world units (along the beam).
    #[arg(long, default_value_t = 0.0, value_name = "SIGMA")]
    range_noise: f64,
    /// Probability that a return is dropped, 0 to 1.
    #[arg(long, default_value_t = 0.0, value_name = "P")]
    dropout: f64,
    /// Seed of the noise and dropout (same seed, same points, any thread count).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, value_parser = threads)]
    threads: Option<usize>,
}

#[derive(Args)]
struct ImportCli {
    /// The table: TreeQSM cyl_data text, SimpleForest or aRchi CSV, or a CSV with
    /// x0,y0,z0,x1,y1,z1,radius columns.
    table: PathBuf,
    /// The scene file to write (JSON, docs/scene-format.md).
    #[arg(short, long)]
    out: PathBuf,
    /// The table's layout; default: from the header's names, or TreeQSM when there is no
    /// header and 14 or 15 columns.
    #[arg(long, value_parser = table_format, value_name = "csv|npz|treeqsm|simpleforest|archi")]
    format: Option<TableFormat>,
    /// Each cylinder's label (the label AOV): branch_order = BranchOrder + 1 (stem 1, its
    /// branches 2, ...; 0 stays "no hit"), branch = branch id + 1, segment = the cylinder's
    /// id, none = 0. Default: a csv table's label column, else none.
    #[arg(long, value_parser = label_rule, value_name = "none|branch_order|branch|segment")]
    label: Option<LabelRule>,
    /// Close the cylinders' ends (default on; a csv table's caps column wins).
    #[arg(long, value_parser = on_off, value_name = "on|off")]
    caps: Option<bool>,
    /// Image width of the camera, pixels.
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Image height of the camera, pixels.
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Horizontal field of view of the camera, degrees.
    #[arg(long, default_value_t = 50.0)]
    fov: f64,
}

fn table_format(s: &str) -> Result<TableFormat, String> {
    TableFormat::parse(s).ok_or_else(|| {
        format!(
            "unknown format {:?}; expected one of {}",
            shorten(s),
            TableFormat::ALL.map(|f| f.name()).join(", ")
        )
    })
}

fn label_rule(s: &str) -> Result<LabelRule, String> {
    LabelRule::parse(s).ok_or_else(|| {
        format!(
            "unknown label rule {:?}; expected one of {}",
            shorten(s),
            LabelRule::ALL.map(|f| f.name()).join(", ")
        )
    })
}

fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("expected on or off, got {:?}", shorten(s))),
    }
}

#[derive(Args)]
struct CamerasCli {
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
    /// Horizontal field of view, degrees; default: the scene's first camera's, else 50.
    #[arg(long)]
    fov: Option<f64>,
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
struct VerifyCli {
    /// A scene file, a folder of scene files (or holding manifest.jsonl), or a .jsonl
    /// manifest.
    input: PathBuf,
    /// Fraction of the views to check, chosen from --seed and each view's batch name
    /// (`scene` or `scene/NN`).
    #[arg(
        long,
        default_value_t = 1.0,
        value_name = "F",
        allow_hyphen_values = true
    )]
    fraction: f64,
    /// Seed of the --fraction choice (the views batch --verify-seed checks).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write DIR/NAME.heatmap.png for every checked view: where cylaov and Mitsuba differ,
    /// explained by the legend under the image.
    #[arg(long, value_name = "DIR")]
    heatmap: Option<PathBuf>,
    /// Print the results as JSON.
    #[arg(long)]
    json: bool,
    /// Kernel precision of cylaov's side.
    #[arg(long, value_parser = cli::choice::<Precision>(), default_value_t = Precision::F64)]
    precision: Precision,
    /// Kernel formulation of cylaov's side.
    #[arg(long, value_parser = cli::choice::<FormulaKind>(), default_value_t = FormulaKind::Stable)]
    formula: FormulaKind,
    /// Check another renderer's AOV EXR of the scene file instead of cylaov's render:
    /// against the exact answer, with Mitsuba as a second opinion.
    #[arg(long, value_name = "THEIR.exr")]
    candidate: Option<PathBuf>,
    /// With --candidate: its channel names, AOV=NAME, comma-separated (normal=N maps
    /// N.X/N.Y/N.Z or N.R/N.G/N.B); unmapped channels are read by cylaov's names.
    #[arg(long, value_delimiter = ',', value_name = "AOV=NAME")]
    channels: Vec<String>,
    /// With --candidate: its bound, in float32 ulps of storage and of sideways ray error.
    #[arg(long, value_name = "K", default_value_t = 4.0)]
    candidate_ulps: f64,
    /// With --candidate: the scene's camera it shows (0-based; needed for a scene with
    /// several cameras).
    #[arg(long, value_name = "K")]
    camera: Option<usize>,
    /// Write DIR/index.html: a self-contained page (images beside it) with the per-view
    /// table, each view's pictures with legends, and its worst pixels' three answers.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// With a batch's output folder (holding index.json) as input: the scene folder or
    /// manifest the batch read, instead of the one index.json records (scenes moved since).
    /// The EXR files on disk are checked, not a fresh render.
    #[arg(long, value_name = "DIR")]
    scenes: Option<PathBuf>,
    #[command(flatten)]
    tolerances: TolerancesCli,
}

#[derive(Args)]
struct CompareCli {
    /// First image (usually cylaov's render).
    a: PathBuf,
    /// Second image (usually the Mitsuba reference).
    b: PathBuf,
    /// Write a PNG showing where the images differ, explained by the legend under the image
    /// (silhouette, seam and interior mismatches, errors against their tolerance).
    #[arg(long, value_name = "OUT.png")]
    heatmap: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// The scene A was rendered from: grazing pixels get their float32 conditioning bound
    /// (A must hold shape_id, distance and normal).
    #[arg(long, value_name = "SCENE.json")]
    scene: Option<PathBuf>,
    /// With --scene: the float32 ulps of sideways ray error the conditioning bound allows
    /// (2: the drift between two runs of one float32 renderer).
    #[arg(long, value_name = "K", default_value_t = cylaov::verify::compare::CONDITIONING_ULPS, value_parser = non_negative)]
    conditioning_ulps: f64,
    #[command(flatten)]
    tolerances: TolerancesCli,
}

/// The pass/fail bounds of every verifying command (defaults: what "agrees with Mitsuba"
/// means, docs/verification.md).
#[derive(Args, Clone, Copy, Debug)]
struct TolerancesCli {
    /// Largest allowed fraction of silhouette-mismatched pixels (different cylinder or hit
    /// vs miss; all must lie on silhouettes).
    #[arg(long, default_value_t = Tolerances::default().max_mismatch_fraction, value_parser = non_negative)]
    max_mismatch_fraction: f64,
    /// Largest allowed fraction of seam-mismatched pixels (same cylinder, another part; all
    /// must lie on a part boundary).
    #[arg(long, default_value_t = Tolerances::default().max_seam_fraction, value_parser = non_negative)]
    max_seam_fraction: f64,
    /// Largest allowed relative distance error (where a pixel's float32 conditioning bound
    /// is larger, at grazing incidence, that bound applies).
    #[arg(long, default_value_t = Tolerances::default().rel_distance, value_parser = non_negative)]
    rel_distance: f64,
    /// Largest allowed relative depth error (or the pixel's float32 bound, if larger).
    #[arg(long, default_value_t = Tolerances::default().rel_depth, value_parser = non_negative)]
    rel_depth: f64,
    /// Largest allowed normal angle error, degrees (or the pixel's float32 bound, if larger).
    #[arg(long, default_value_t = Tolerances::default().normal_deg, value_parser = non_negative)]
    normal_deg: f64,
}

impl TolerancesCli {
    fn get(self) -> Tolerances {
        Tolerances {
            max_mismatch_fraction: self.max_mismatch_fraction,
            max_seam_fraction: self.max_seam_fraction,
            rel_distance: self.rel_distance,
            rel_depth: self.rel_depth,
            normal_deg: self.normal_deg,
        }
    }
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
    /// Kernel precision: f64 is the default and the accuracy reference. f32 runs the kernel
    /// about 1.8x faster (eight AVX2 lanes instead of four) but a whole render only about
    /// 1.1x (set-up and writing dominate), and shows what float32 costs (docs/accuracy.md).
    #[arg(long, value_parser = cli::choice::<Precision>(), default_value_t = Precision::F64)]
    precision: Precision,
    /// Kernel formulation: `stable` (default) or the textbook quadratic as written
    /// (docs/accuracy.md), kept to show what the stable form fixes.
    #[arg(long, value_parser = cli::choice::<FormulaKind>(), default_value_t = FormulaKind::Stable)]
    formula: FormulaKind,
    /// How primary rays find candidates: screen tiles (fast) or the BVH.
    #[arg(long, value_parser = cli::choice::<Accel>(), default_value_t = Accel::Tiles)]
    accel: Accel,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, value_parser = threads)]
    threads: Option<usize>,
}

#[derive(Args)]
struct RenderCli {
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
    /// Also write OUT.depth.png: 16-bit round(planar depth × --depth-scale), 0 = no depth.
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

/// Largest `--threads`: 1024 is more hardware threads than any single node this runs on
/// has, and the work splits into bands of tiles, so more threads cannot help; each one
/// reserves a stack, and tens of thousands exhaust the process's limits (50 000 aborted,
/// 100 000 spent minutes creating threads).
const MAX_THREADS: usize = 1024;

/// `--threads N`: a whole number in 1..=[`MAX_THREADS`].
fn threads(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=MAX_THREADS).contains(&n) => Ok(n),
        _ => Err(format!(
            "must be a whole number from 1 to {MAX_THREADS}, got {}",
            shorten(s)
        )),
    }
}

fn family(s: &str) -> Result<String, String> {
    use cylaov::verify::stress::Family;
    match Family::parse(s) {
        Some(_) => Ok(s.to_string()),
        None => Err(format!(
            "unknown family {:?}; expected one of {}",
            shorten(s),
            Family::ALL.map(|f| f.name()).join(", ")
        )),
    }
}

fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!("must be a whole number >= 1, got {}", shorten(s))),
    }
}

/// A value as echoed in a message: at most 40 characters.
fn shorten(s: &str) -> String {
    cylaov::scene::strict::shorten(s)
}

fn set_threads(threads: Option<usize>) -> anyhow::Result<()> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| anyhow::anyhow!("--threads {n}: cannot start the threads: {e}"))?;
    }
    Ok(())
}

/// Print a command's summary line (a closed pipe is not an error; see `io::say`).
fn say(text: &str) -> anyhow::Result<()> {
    cylaov::output::io::say(text)?;
    Ok(())
}

fn render(a: RenderCli) -> anyhow::Result<ExitCode> {
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

fn generate(a: GenerateCli) -> anyhow::Result<ExitCode> {
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

/// Exit 1 when any view failed (the summary names the failures file).
fn batch(a: BatchCli) -> anyhow::Result<ExitCode> {
    set_threads(a.kernel.threads)?;
    if a.format == Format::Webdataset && a.ply {
        anyhow::bail!("--ply: with --format webdataset, ask for --members ply");
    }
    if a.format == Format::Files {
        if a.shard_size.is_some() {
            anyhow::bail!("--shard-size: only with --format webdataset");
        }
        if !a.members.is_empty() {
            anyhow::bail!("--members: only with --format webdataset");
        }
        if a.force {
            anyhow::bail!("--force: only with --format webdataset");
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

/// `batch --format webdataset`: exit 1 when any view of this process's tars failed.
fn shards(args: &commands::batch::BatchArgs, sopts: &ShardOptions) -> anyhow::Result<ExitCode> {
    let shard =
        cylaov::dataset::batch::resolve_shard(args.shard, args.shards, &|k| std::env::var(k).ok())
            .map_err(anyhow::Error::msg)?;
    let summary = cylaov::dataset::batch::shards::write_shards(
        &args.input,
        &args.out,
        &TarSelection::Shard(shard),
        &args.options,
        sopts,
        args.progress != ProgressMode::Off,
    )?;
    say(&summary.to_string())?;
    if !summary.failures.is_empty() {
        anyhow::bail!(
            "{} views failed (see {})",
            summary.failures.len(),
            summary.failures_path.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn bench(b: BenchCli) -> anyhow::Result<ExitCode> {
    set_threads(b.threads)?;
    if b.exr_writer {
        if let Some(p) = &b.csv {
            cylaov::output::io::check_outputs(&[("--csv", p)], &[])?;
        }
        let rows = bench::exr_writer::run(1000, b.width, b.height, b.repeats.max(5))?;
        say(&bench::exr_writer::table(&rows))?;
        if let Some(p) = &b.csv {
            cylaov::output::io::atomic_write_bytes(p, &cylaov::output::io::csv_bytes(&rows)?)?;
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
        commands::bench::batch_formats(b.batch_views, b.csv.as_deref())?;
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

fn stress(a: StressCli) -> anyhow::Result<ExitCode> {
    let args = commands::stress::StressArgs {
        family: a.family,
        rays: a.rays,
        csv: a.csv,
        plot: a.plot,
        markdown: a.markdown,
    };
    say(&commands::stress::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}

fn scan(a: ScanCli) -> anyhow::Result<ExitCode> {
    set_threads(a.threads)?;
    let pose = cylaov::scan::Pose::parse(&a.pose, "--pose").map_err(|e| anyhow::anyhow!(e))?;
    let args = commands::scan::ScanArgs {
        scene: a.scene,
        sensor: a.sensor,
        out: a.out,
        pose,
        trajectory: a.trajectory,
        returns: a.returns,
        noise: cylaov::scan::Noise {
            range_sigma: a.range_noise,
            dropout: a.dropout,
            seed: a.seed,
        },
    };
    say(&commands::scan::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}

fn import(a: ImportCli) -> anyhow::Result<ExitCode> {
    if a.width == 0 || a.width > cylaov::scene::MAX_SIDE {
        anyhow::bail!(
            "--width: must be in 1..={}, got {}",
            cylaov::scene::MAX_SIDE,
            a.width
        );
    }
    if a.height == 0 || a.height > cylaov::scene::MAX_SIDE {
        anyhow::bail!(
            "--height: must be in 1..={}, got {}",
            cylaov::scene::MAX_SIDE,
            a.height
        );
    }
    if !(a.fov > 0.0 && a.fov < 180.0) {
        anyhow::bail!("--fov: must be in (0, 180), got {}", a.fov);
    }
    let args = commands::import::ImportArgs {
        table: a.table,
        out: a.out,
        options: TableOptions {
            format: a.format,
            label: a.label,
            caps: a.caps,
        },
        frame: Frame {
            width: a.width,
            height: a.height,
            fov_deg: a.fov,
        },
    };
    say(&commands::import::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}

fn cameras(a: CamerasCli) -> anyhow::Result<ExitCode> {
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
        anyhow::bail!("{flag}: must be in 1..={max}, got {n}");
    }
    let e = a.elevation;
    if e.min < -85.0 || e.max > 85.0 {
        anyhow::bail!("--elevation: must lie in -85..85 degrees (the camera's up is +z), got {e}");
    }
    if let Some(f) = a.fov
        && !(f > 0.0 && f < 180.0)
    {
        anyhow::bail!("--fov: must be in (0, 180), got {f}");
    }
    let rig = match count {
        None => None,
        Some(n) => {
            // Defaults from the scene's first camera, when it is a pinhole.
            let first = cylaov::scene::load(&a.scene)
                .ok()
                .map(|s| s.camera)
                .filter(|c| c.projection == cylaov::scene::camera::Projection::Perspective);
            let distance = match a.distance.as_str() {
                "fit" => Distance::default(),
                d => match d.parse::<f64>() {
                    Ok(x) if x.is_finite() && x > 0.0 && x <= 1e6 => Distance::Factor(x),
                    _ => anyhow::bail!(
                        "--distance: expected fit or a factor of the fit distance in (0, 1e6], got {:?}",
                        shorten(d)
                    ),
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
                        .filter(|c| c.fov_axis == cylaov::scene::camera::FovAxis::X)
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
    say(&commands::cameras::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}

fn export_mitsuba(a: ExportCli) -> anyhow::Result<ExitCode> {
    say(&commands::export_mitsuba::run(&a.scene, &a.out)?)?;
    Ok(ExitCode::SUCCESS)
}

/// 0 when every tolerance holds, 1 when one is broken, 2 when the comparison could not be
/// made (its errors, printing the report included, are reported here; a refused
/// allocation ends the process with 2 as well).
fn compare(a: CompareCli) -> ExitCode {
    cylaov::mem::set_out_of_memory_status(2);
    let args = commands::compare::CompareArgs {
        a: a.a,
        b: a.b,
        scene: a.scene,
        conditioning_ulps: a.conditioning_ulps,
        heatmap: a.heatmap,
        json: a.json,
        tolerances: a.tolerances.get(),
    };
    let outcome = commands::compare::run(&args).and_then(|out| {
        say(&out.text)?;
        Ok(out.passed)
    });
    match outcome {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            report(&e);
            ExitCode::from(2)
        }
    }
}

/// 0 when every checked view agrees, 1 when one breaks a tolerance, 2 when a view could
/// not be checked or the check could not start (reported here; a refused allocation ends
/// the process with 2 as well).
fn verify(a: VerifyCli) -> ExitCode {
    cylaov::mem::set_out_of_memory_status(2);
    let args = commands::verify::VerifyArgs {
        input: a.input,
        fraction: a.fraction,
        seed: a.seed,
        heatmap: a.heatmap,
        json: a.json,
        tolerances: a.tolerances.get(),
        precision: a.precision,
        formula: a.formula,
        candidate: a.candidate,
        channels: a.channels,
        candidate_ulps: a.candidate_ulps,
        camera: a.camera,
        report: a.report,
        scenes: a.scenes,
    };
    let outcome = commands::verify::run(&args).and_then(|out| {
        say(&out.text)?;
        Ok(out.code)
    });
    match outcome {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            report(&e);
            ExitCode::from(2)
        }
    }
}

/// Run the command and return its exit code: an `Err` is reported by `main` (exit 1).
fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Render(a) => render(a),
        Command::Generate(a) => generate(a),
        Command::Batch(a) => batch(a),
        Command::Bench(b) => bench(b),
        Command::Stress(a) => stress(a),
        Command::Import(a) => import(a),
        Command::Scan(a) => scan(a),
        Command::Cameras(a) => cameras(a),
        Command::ExportMitsuba(a) => export_mitsuba(a),
        Command::Compare(a) => Ok(compare(a)),
        Command::Verify(a) => Ok(verify(a)),
        Command::Aovs => {
            print!("{}", cylaov::scene::aov::markdown_table());
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn report(e: &anyhow::Error) {
    cylaov::output::io::warn(&format!("error: {e:#}"));
}

/// The command line with `-1` accepted as a value of every option (it is not a flag), so a
/// negative number gets the option's own range message instead of "unexpected argument".
fn command_line() -> clap::Command {
    use clap::CommandFactory;
    Cli::command().mut_subcommands(|sc| {
        sc.mut_args(|arg| {
            if arg.get_action().takes_values() {
                arg.allow_negative_numbers(true)
            } else {
                arg
            }
        })
    })
}

fn main() -> ExitCode {
    use clap::FromArgMatches;
    // First, before any thread starts: see `output::signals`.
    cylaov::output::signals::install();
    cylaov::spelling::set(cylaov::spelling::as_flag);
    cylaov::mem::keep_freed_memory();
    cylaov::mem::init_from_env();
    // Usage errors exit 2 (clap's own code); `--help` and `--version` exit 0.
    let cli = match command_line()
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m))
    {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            report(&e);
            ExitCode::FAILURE
        }
    }
}
