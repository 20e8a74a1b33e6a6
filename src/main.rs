//! The `cylaov` command line: parses arguments, calls the library, reports errors.

use clap::{Parser, Subcommand};
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
tolerances, a batch view); 2 = usage error (unknown option, a flag's bad value, flags that do not go together) or a check that could \
not be made (compare: a missing or unreadable image, too little memory; verify: a view it \
could not check, too little memory); 129, 130, 143 = \
stopped by SIGHUP, SIGINT, SIGTERM (128 + the signal number; unfinished files removed). A \
closed stdout (`| head`) is not an error.";

#[derive(Subcommand)]
enum Command {
    /// Render a scene file to a multi-channel EXR (+ OUT.camera.json, optional PNG previews).
    ///
    /// Example: cylaov render scenes/single.json -o out/single.exr --preview out
    Render(cli::render::RenderCli),
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
    Bench(cli::bench::BenchCli),
    /// Generate procedural scenes: OUT/scenes/NNNNNN.json and OUT/manifest.jsonl.
    ///
    /// Same options and seed, same bytes. Example:
    /// cylaov generate --count 1000 --seed 1 --out data --cylinders 100
    Generate(cli::generate::GenerateCli),
    /// Render every view of a folder of scene files or a .jsonl manifest: resumable,
    /// shardable, with transforms.json for nerfstudio / instant-ngp.
    ///
    /// Example: cylaov batch data --out data/render --shard 0/4
    Batch(cli::batch::BatchCli),
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
    Import(cli::import::ImportCli),
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
    Scan(cli::scan::ScanCli),
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
    Cameras(cli::cameras::CamerasCli),
    /// Write the Mitsuba 3 XML of a scene (the reference renderer's input).
    ///
    /// Example: cylaov export-mitsuba scenes/single.json -o single.xml
    ExportMitsuba(cli::export_mitsuba::ExportCli),
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
    Verify(cli::verify::VerifyCli),
    /// Compare two AOV EXRs pixel by pixel (docs/verification.md, "Comparing two renders"); exit 1 if a
    /// tolerance is broken.
    ///
    /// Exit status: 0 when every tolerance holds, 1 when one is broken (the report says
    /// which), 2 when the comparison could not be made (a missing or unreadable file, images
    /// of different sizes, a bad shape_id, an unwritable heatmap, too little memory) or the
    /// arguments are wrong.
    ///
    /// Example: cylaov compare out/single.exr reference/single.exr --heatmap diff.png
    Compare(cli::compare::CompareCli),
    /// Measure every kernel (literal/stable x f32/f64) against a double-double oracle on
    /// the stress families (grazing, near-axis, far, scale, inside, rims, input).
    ///
    /// Example: cylaov stress --family grazing --csv out/grazing.csv --plot out/stress.png
    Stress(cli::stress::StressCli),
    /// Print the AOV table: each AOV's EXR channels, per-AOV file channels, sample type,
    /// meaning (the text the EXR header carries), miss value and how `compare` judges it.
    ///
    /// Example: cylaov aovs
    Aovs,
}

/// Run the command and return its exit code: an `Err` is reported by `main` (exit 1).
fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Render(a) => cli::render::run(a),
        Command::Generate(a) => cli::generate::run(a),
        Command::Batch(a) => cli::batch::run(a),
        Command::Bench(b) => cli::bench::run(b),
        Command::Stress(a) => cli::stress::run(a),
        Command::Import(a) => cli::import::run(a),
        Command::Scan(a) => cli::scan::run(a),
        Command::Cameras(a) => cli::cameras::run(a),
        Command::ExportMitsuba(a) => cli::export_mitsuba::run(a),
        Command::Compare(a) => Ok(cli::compare::run(a)),
        Command::Verify(a) => Ok(cli::verify::run(a)),
        Command::Aovs => {
            print!("{}", cylaov::scene::aov::markdown_table());
            Ok(ExitCode::SUCCESS)
        }
    }
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
    // First, before any thread starts: see `output::store::signals`.
    cylaov::output::store::signals::install();
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
    let code = match run(cli) {
        Ok(code) => code,
        Err(e) => {
            cli::report(&e);
            // A flag's bad value found after parsing is a usage error, as clap's are.
            if e.is::<cylaov::commands::Usage>() {
                ExitCode::from(2)
            } else {
                ExitCode::FAILURE
            }
        }
    };
    cylaov::output::store::signals::settle();
    code
}
