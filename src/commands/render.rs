//! `cylaov render`: scene file → EXR (+ camera JSON, Open3D camera, optional 16-bit depth PNG
//! and PNG previews).
//!
//! Beside `OUT.exr` it writes `OUT.camera.json` and `OUT.open3d.json`; `--depth-png` adds
//! `OUT.depth.png` (the same 16-bit depth PNG as `batch`, see [`crate::output::format::depth_png`]);
//! `--preview DIR` writes `DIR/OUT.normal.preview.png` and `DIR/OUT.depth.preview.png`
//! (pictures for people: the names say so).

use crate::mem::check_memory;
use crate::output::format::camera_files::camera_json_path;
use crate::output::format::depth_png::OutOfRange;
use crate::output::format::exr::{Compression, ExrLayout};
use crate::output::format::ply::{PLY_AOVS, encode, hits};
use crate::output::pipeline::view::{DepthOutOfRange, DepthPngPlan, FileSink, Member, ViewPlan};
use crate::output::store::atomic::{NAME_MAX, NewDirs, Staged, stage_bytes};
use crate::output::store::targets::{check_output_dir, check_outputs};
use crate::render::RenderOptions;
use crate::scene::camera::Camera;
use crate::scene::{self, Aov};
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything `render` needs from the command line.
#[derive(Clone, Debug)]
pub struct RenderArgs {
    /// The scene file.
    pub scene: PathBuf,
    /// Output EXR (`-o`); the sidecar files are named after it.
    pub out: PathBuf,
    /// Overrides the scene's AOVs.
    pub aovs: Option<Vec<Aov>>,
    /// Kernel and acceleration choice; its `aovs` are replaced by the resolved AOV list.
    pub options: RenderOptions,
    /// `--preview DIR`: also write the PNG previews into this folder.
    pub preview: Option<PathBuf>,
    /// EXR compression.
    pub compression: Compression,
    /// `--camera K`: the camera of a several-camera scene (0 = the first).
    pub camera: usize,
    /// `--depth-png`: also write `OUT.depth.png` at this many values per world unit.
    pub depth_png: Option<f64>,
    /// With `depth_png`, what a hit whose depth × scale does not fit 16 bits does.
    pub depth_out_of_range: OutOfRange,
    /// One layered `OUT.exr`, or `OUT.<aov>.exr` per AOV.
    pub exr_layout: ExrLayout,
    /// `--ply FILE`: also write the view's hit points as a PLY point cloud.
    pub ply: Option<PathBuf>,
}

/// The view plan of a render.
fn plan(args: &RenderArgs, cam: Camera, aovs: &[Aov]) -> ViewPlan {
    ViewPlan {
        camera: cam,
        exr_aovs: aovs.to_vec(),
        layout: args.exr_layout,
        compression: args.compression,
        depth_png: args.depth_png.map(|scale| DepthPngPlan {
            scale,
            out_of_range: args.depth_out_of_range,
        }),
        mask: false,
        normal_picture: false,
        previews: args.preview.is_some(),
        stamp: None,
        ply: false,
    }
}

/// Where a render puts `member`: the EXR at `-o OUT`, the rest beside it as `OUT.*`, the
/// previews in the preview folder as `STEM.*`.
fn member_path(out: &Path, preview: Option<&Path>, member: Member) -> PathBuf {
    match member {
        Member::Exr => out.to_path_buf(),
        Member::Camera => camera_json_path(out),
        Member::NormalPreview | Member::DepthPreview(_) => preview
            .unwrap_or(Path::new("."))
            .join(format!("{}.{}", stem(out), member.suffix())),
        // `OUT.<aov>.exr`, `OUT.open3d.json`, `OUT.depth.png`.
        _ => out.with_extension(member.suffix()),
    }
}

/// What a render to `-o OUT` removes as it puts its files in place: the files beside `OUT`
/// an earlier render to `OUT` may have written and this one does not (the other EXR
/// layout's files, `OUT.open3d.json` of a pinhole view, `OUT.depth.png`), which would
/// describe another view. Previews and `--ply` are in places the user names each time, and
/// stay.
fn stale(args: &RenderArgs, plan: &ViewPlan) -> Vec<PathBuf> {
    let writes = plan.members();
    let beside = [Member::Exr, Member::Open3d, Member::DepthPng]
        .into_iter()
        .chain(Aov::ALL.iter().map(|&a| Member::AovExr(a)));
    beside
        .filter(|m| !writes.contains(m))
        .map(|m| member_path(&args.out, None, m))
        // A name too long for a file cannot be there.
        .filter(|p| p.file_name().is_some_and(|n| n.len() <= NAME_MAX))
        .collect()
}

/// The flag a member's target is checked under.
fn flag(member: Member) -> &'static str {
    match member {
        Member::DepthPng => "--depth-png",
        Member::NormalPreview | Member::DepthPreview(_) => "--preview",
        _ => "-o",
    }
}

/// `-o` names the EXR: another extension (`out/x.png`) would get EXR bytes under a name
/// that promises something else, so it is refused with the flags that do make PNGs.
fn check_exr_name(out: &Path) -> Result<()> {
    let is_exr = out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if !is_exr {
        bail!(
            "-o {}: the output is an OpenEXR file and its name must end in .exr; \
             PNGs come beside it with --depth-png (16-bit depth, scaled by --depth-scale) \
             and --preview DIR (normal and depth previews)",
            out.display()
        );
    }
    Ok(())
}

/// Run a render and return the one-line summary.
pub fn run(args: &RenderArgs) -> Result<String> {
    let start = Instant::now();
    let (mut scene, table) =
        scene::load_with_table(&args.scene).with_context(|| format!("{}", args.scene.display()))?;
    scene
        .select_camera(args.camera)
        .with_context(|| format!("--camera {}: {}", args.camera, args.scene.display()))?;
    // `--aov`'s repeats dropped, as a scene's are.
    let aovs = args
        .aovs
        .as_deref()
        .map_or_else(|| scene.aovs.clone(), Aov::without_repeats);
    let cam = Camera::new(scene.camera);
    let plan = plan(args, cam, &aovs);
    if let Some(dir) = &args.preview {
        check_output_dir("--preview", dir)?;
        // The previews show what the EXR stores: without one of these there is none.
        let shown = [Aov::Normal, Aov::Depth, Aov::Distance];
        if !aovs.iter().any(|a| shown.contains(a)) {
            bail!(
                "--preview {}: previews show normal, depth or distance, and the AOVs are {}: \
                 add one with --aov",
                dir.display(),
                aovs.iter().map(|a| a.name()).collect::<Vec<_>>().join(",")
            );
        }
    }
    // None may be the scene or a file that is not a regular file (see `io::check_outputs`).
    let targets: Vec<(&str, PathBuf)> = plan
        .members()
        .into_iter()
        .map(|m| (flag(m), member_path(&args.out, args.preview.as_deref(), m)))
        .collect();
    let mut list: Vec<(&str, &Path)> = targets.iter().map(|(f, p)| (*f, p.as_path())).collect();
    // The files an earlier render left that this one removes are checked as its outputs:
    // never an input (a table named `OUT.depth.png`), a link or a folder.
    let stale = stale(args, &plan);
    list.extend(stale.iter().map(|p| ("-o", p.as_path())));
    if let Some(ply) = &args.ply {
        list.push(("--ply", ply.as_path()));
    }
    let inputs: Vec<&Path> = std::iter::once(args.scene.as_path())
        .chain(table.as_deref())
        .collect();
    check_outputs(&list, &inputs)?;
    // After the target checks: a FIFO, a link or the scene itself at -o is refused as that.
    check_exr_name(&args.out)?;
    if let Some(ply) = &args.ply {
        check_ply_name(ply)?;
    }
    if let Some(s) = args.depth_png
        && !(s.is_finite() && s > 0.0)
    {
        return super::usage(format!("--depth-scale: must be finite and > 0, got {s}"));
    }
    check_memory(
        &format!(
            "rendering {}x{} with {}",
            scene.camera.width,
            scene.camera.height,
            plan.traced_aovs()
                .iter()
                .map(|a| a.name())
                .collect::<Vec<_>>()
                .join(",")
        ),
        plan.memory(),
    )?;
    let dirs = make_dirs(args)?;
    // The point cloud waits under a temporary name until the EXR is written too.
    let ply = match &args.ply {
        Some(path) => Some(stage_ply(args, &scene, path)?),
        None => None,
    };
    let (out, preview) = (args.out.clone(), args.preview.clone());
    let mut sink =
        FileSink::beside(move |m| member_path(&out, preview.as_deref(), m)).replacing(stale);
    if let Some(staged) = ply {
        sink = sink.with_staged(staged);
    }
    let written = plan
        .execute(&scene, &args.options, &mut sink)
        .map_err(|e| match e.downcast_ref::<DepthOutOfRange>() {
            Some(_) => e.context(format!("{}", args.scene.display())),
            None => e,
        })?;
    if written.depth_zeroed > 0
        && let Some(scale) = args.depth_png
    {
        crate::output::console::warn(&format!(
            "{}: depth PNG: {} hit pixels beyond 16 bits at --depth-scale {scale} stored as 0",
            args.out.display(),
            written.depth_zeroed
        ));
    }
    dirs.keep();
    let trace_ms = written.trace.as_secs_f64() * 1e3;
    let write_ms = written.write.as_secs_f64() * 1e3;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let peak = crate::mem::peak_rss_mib().map_or(String::new(), |m| format!(", peak {m:.0} MiB"));
    // Streamed, the EXR was written during the trace: say so rather than time it twice.
    let trace = if written.streamed {
        format!("trace and EXR {trace_ms:.1} ms, other files {write_ms:.1} ms")
    } else {
        format!("trace {trace_ms:.1} ms, write {write_ms:.1} ms")
    };
    let hits = written.hits;
    Ok(format!(
        "{}: {w}x{h}, {}, {hits} hits ({:.1}%), {}, {trace}, total {:.1} ms{peak}",
        args.out.display(),
        crate::output::console::count(scene.cylinders.len(), "cylinder"),
        100.0 * hits as f64 / (w * h) as f64,
        crate::geometry::Kernel::new(args.options.formula, args.options.precision),
        start.elapsed().as_secs_f64() * 1e3
    ))
}

/// `--ply` names a PLY file: another extension would promise another format.
fn check_ply_name(ply: &Path) -> Result<()> {
    let is_ply = ply
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"));
    if !is_ply {
        bail!(
            "--ply {}: the point cloud is a PLY file and its name must end in .ply",
            ply.display()
        );
    }
    Ok(())
}

/// Trace the AOVs of a point cloud (position, normal, ids) and stage the PLY of the hits.
fn stage_ply(args: &RenderArgs, scene: &scene::Scene, path: &Path) -> Result<Staged> {
    let options = RenderOptions {
        aovs: PLY_AOVS.to_vec(),
        ..args.options.clone()
    };
    let image = crate::render::render(scene, &options).image;
    let points = hits(&image).context("--ply: the render lacks a point-cloud AOV")?;
    let comment = format!(
        "cylaov {} hit points of {} camera {}",
        env!("CARGO_PKG_VERSION"),
        args.scene.display(),
        args.camera
    );
    let bytes = encode(&points, &comment);
    stage_bytes(path, &bytes).with_context(|| format!("writing {}", path.display()))
}

/// The output's parent folder and the preview folder, made now and removed again unless
/// the render succeeds.
fn make_dirs(args: &RenderArgs) -> Result<NewDirs> {
    let mut dirs = NewDirs::default();
    dirs.create_parent(&args.out)
        .with_context(|| format!("-o {}", args.out.display()))?;
    if let Some(dir) = &args.preview {
        dirs.create(dir)
            .with_context(|| format!("--preview {}", dir.display()))?;
    }
    Ok(dirs)
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "render".into())
}
