//! Memory and messages: the memory estimates hold what the code really allocates (heap
//! peaks counted by the allocator at several sizes, every compression); a refused
//! allocation is one error line and the command's status (1; 2 in `compare` and `verify`),
//! never an abort; and the one-line messages name
//! the real cause (identity, `--depth-scale`, a full disk, the pixel cap, the heatmap
//! legend, `--help`).

mod common;
use common::{cylaov, fresh_dir};

use cylaov::commands::compare::{CompareArgs, memory_needed};
use cylaov::commands::render::RenderArgs;
use cylaov::mem::{Guarded, heap_live, heap_peak, reset_heap_peak};
use cylaov::output::format::depth_png::OutOfRange;
use cylaov::output::format::exr::{Compression, ExrLayout};
use cylaov::output::pipeline::memory::render_memory;
use cylaov::render::RenderOptions;
use cylaov::scene::Aov;
use cylaov::verify::compare::Tolerances;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::Mutex;

/// Counts the heap of this test binary, so a test can measure what a command allocates.
#[global_allocator]
static ALLOCATOR: Guarded = Guarded::COUNTING;

/// One test at a time: the heap count is the whole process's.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

const MIB: f64 = (1u64 << 20) as f64;

/// Every AOV: 13 channels.
const ALL: &str =
    r#"["distance", "depth", "normal", "position", "shape_id", "part", "normal_camera"]"#;

/// A scene of `w × h` pixels whose every pixel hits (a wide cylinder right in front of the
/// camera, and three small ones for silhouettes and caps): the most a comparison holds.
fn scene(dir: &Path, name: &str, (w, h): (u32, u32), aovs: &str) -> PathBuf {
    let path = dir.join(format!("{name}.json"));
    std::fs::write(
        &path,
        format!(
            r#"{{
  "camera": {{ "origin": [0, -4, 0], "target": [0, 0, 0], "up": [0, 0, 1],
              "fov_deg": 40, "width": {w}, "height": {h} }},
  "cylinders": [
    {{ "p0": [0, 3, -50], "p1": [0, 3, 50], "radius": 20, "id": 1 }},
    {{ "p0": [-0.6, 0, -0.3], "p1": [-0.6, 0, 0.4], "radius": 0.2, "id": 2 }},
    {{ "p0": [0.5, -0.5, 0.2], "p1": [0.9, -0.2, 0.3], "radius": 0.15, "id": 3 }},
    {{ "p0": [0.1, -1, -0.6], "p1": [0.1, -1, -0.2], "radius": 0.1, "caps": false, "id": 4 }}
  ],
  "aovs": {aovs}
}}"#
        ),
    )
    .unwrap();
    path
}

fn render_args(scene: &Path, out: &Path, compression: Compression) -> RenderArgs {
    RenderArgs {
        scene: scene.to_path_buf(),
        out: out.to_path_buf(),
        aovs: None,
        options: RenderOptions::new(Vec::new()),
        preview: None,
        compression,
        camera: 0,
        depth_png: None,
        depth_out_of_range: OutOfRange::Fail,
        exr_layout: ExrLayout::Layers,
        ply: None,
    }
}

/// The heap peak above what was live before `f`, in bytes.
fn peak_of<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let base = heap_live();
    reset_heap_peak();
    let r = f();
    (r, heap_peak().saturating_sub(base) as u64)
}

/// The margin every estimate keeps: at least what was measured, at most a quarter more
/// plus 8 MiB (write buffers and encoder tables that do not grow with the image). Every case is printed, then the first one out of bounds fails the test.
struct Bounds(Vec<String>);

impl Bounds {
    fn check(&mut self, what: &str, measured: u64, estimate: u64) {
        eprintln!(
            "{what}: measured {:.2} MiB, estimate {:.2} MiB ({:.2}x)",
            measured as f64 / MIB,
            estimate as f64 / MIB,
            estimate as f64 / measured.max(1) as f64
        );
        if measured > estimate {
            self.0.push(format!(
                "{what}: measured {measured} bytes > estimate {estimate}"
            ));
        } else if estimate as f64 > 1.25 * measured as f64 + 8.0 * MIB {
            self.0.push(format!(
                "{what}: estimate {estimate} bytes > 1.25 x the measured {measured} + 8 MiB"
            ));
        }
    }

    fn assert(self) {
        assert!(self.0.is_empty(), "{}", self.0.join("\n"));
    }
}

/// `render` at 128², 512² and 1024² with every compression and both layouts, and with
/// the PNG pictures: the heap peak is within the estimate the memory check uses.
#[test]
fn render_memory_bounds_the_measured_peak() {
    let _one = serial();
    let mut bounds = Bounds(Vec::new());
    let dir = fresh_dir("memory", "render");
    let aovs = [
        Aov::Distance,
        Aov::Depth,
        Aov::Normal,
        Aov::Position,
        Aov::ShapeId,
        Aov::Part,
        Aov::NormalCamera,
    ];
    let compressions = [
        Compression::None,
        Compression::Zip,
        Compression::Zips,
        Compression::Piz,
        Compression::Rle,
    ];
    for side in [128u32, 512, 1024] {
        let s = scene(dir.path(), &format!("s{side}"), (side, side), ALL);
        for compression in compressions {
            for (layout, pictures) in [
                (ExrLayout::Layers, false),
                (ExrLayout::PerAov, false),
                (ExrLayout::Layers, true),
            ] {
                if side == 1024 && (layout, pictures) != (ExrLayout::Layers, false) {
                    continue; // the layouts and pictures scale alike; 512² shows them
                }
                let out = dir.path().join(format!("o{side}.exr"));
                let mut args = render_args(&s, &out, compression);
                args.exr_layout = layout;
                if pictures {
                    args.preview = Some(dir.path().join("preview"));
                    args.depth_png = Some(1000.0);
                }
                let (r, measured) = peak_of(|| cylaov::commands::render::run(&args));
                r.unwrap();
                let estimate = render_memory((side, side), &aovs, layout, compression, pictures);
                bounds.check(
                    &format!("render {side}² {compression:?} {layout:?} pictures {pictures}"),
                    measured,
                    estimate,
                );
            }
        }
    }
    bounds.assert();
}

/// `compare` of two all-hit 13-channel images at 256² and 1024², with and without the
/// heatmap and the scene's conditioning bounds: the heap peak is within the estimate.
#[test]
fn compare_memory_bounds_the_measured_peak() {
    let _one = serial();
    let mut bounds = Bounds(Vec::new());
    let dir = fresh_dir("memory", "compare");
    for side in [256u32, 1024] {
        let s = scene(dir.path(), &format!("c{side}"), (side, side), ALL);
        let a = dir.path().join(format!("a{side}.exr"));
        cylaov::commands::render::run(&render_args(&s, &a, Compression::None)).unwrap();
        for (heatmap, with_scene) in [(false, false), (true, false), (true, true)] {
            let args = CompareArgs {
                a: a.clone(),
                b: a.clone(),
                scene: with_scene.then(|| s.clone()),
                conditioning_ulps: 4.0,
                heatmap: heatmap.then(|| dir.path().join("heat.png")),
                json: false,
                tolerances: Tolerances::default(),
            };
            let (r, measured) = peak_of(|| cylaov::commands::compare::run(&args));
            r.unwrap();
            let px = side as u64 * side as u64;
            let estimate = memory_needed((px, 13), (px, 13), with_scene);
            bounds.check(
                &format!("compare {side}² heatmap {heatmap} scene {with_scene}"),
                measured,
                estimate,
            );
        }
    }
    bounds.assert();
}

/// `cylaov ARGS` under `ulimit -v KIB` (through `sh`), with `envs` set.
fn limited(kib: u64, args: &[&str], envs: &[(&str, &str)]) -> Output {
    let mut script = format!("ulimit -v {kib}; exec \"$0\"");
    for k in 1..=args.len() {
        script += &format!(" \"${{{k}}}\"");
    }
    Command::new("sh")
        .arg("-c")
        .arg(script)
        .arg(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .envs(envs.iter().copied())
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Files anywhere under `dir` whose name ends in `.tmp`.
fn temps(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                todo.push(p);
            } else if p.to_string_lossy().ends_with(".tmp") {
                out.push(p);
            }
        }
    }
    out
}

/// What a run that failed must look like: status 1 (not 134, not a signal), one `error:`
/// line on stderr, no temporary file left.
fn assert_clean_failure(what: &str, o: &Output, dir: &Path) {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{what}: {err}");
    assert_eq!(err.lines().count(), 1, "{what}: one line: {err}");
    assert!(err.starts_with("error: "), "{what}: {err}");
    assert!(
        temps(dir).is_empty(),
        "{what}: temps left: {:?}",
        temps(dir)
    );
}

/// A compressed 1024² render with every AOV under `ulimit -v` from far too little to
/// enough: each run is refused up front (status 1, one line naming the render and its
/// need, nothing written) or writes all of its files; never an abort (status 134) or a
/// partial output. Both ends occur.
#[test]
fn compressed_render_under_ulimit_is_refused_or_done() {
    let _one = serial();
    let dir = fresh_dir("memory", "ulimit-render");
    let s = scene(dir.path(), "m", (1024, 1024), ALL);
    for compression in ["zip", "piz"] {
        let (mut refused, mut done) = (0, 0);
        for kib in (120_000..=220_000).step_by(10_000) {
            let out_dir = dir.path().join(format!("{compression}-{kib}"));
            std::fs::create_dir(&out_dir).unwrap();
            let out = out_dir.join("m.exr");
            let args = [
                "render",
                s.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "--compression",
                compression,
            ];
            let o = limited(kib, &args, &[]);
            let what = format!("{compression} under ulimit -v {kib}");
            if o.status.success() {
                done += 1;
                assert!(
                    out.is_file() && out_dir.join("m.camera.json").is_file(),
                    "{what}"
                );
            } else {
                refused += 1;
                assert_clean_failure(&what, &o, &out_dir);
                let err = stderr(&o);
                assert!(
                    err.contains("rendering 1024x1024") && err.contains("MiB"),
                    "{what}: {err}"
                );
                assert_eq!(std::fs::read_dir(&out_dir).unwrap().count(), 0, "{what}");
            }
        }
        assert!(
            refused > 0 && done > 0,
            "{compression}: {refused} refused, {done} done"
        );
    }
}

/// A batch of two such views with ZIP and PIZ under `ulimit -v`: a view that does not fit
/// fails alone with the memory line in the failures file, the summary is printed, no
/// temporary file is left; never an abort.
#[test]
fn compressed_batch_under_ulimit_fails_views_not_the_process() {
    let _one = serial();
    let dir = fresh_dir("memory", "ulimit-batch");
    let input = dir.path().join("in");
    std::fs::create_dir(&input).unwrap();
    scene(&input, "a", (1024, 1024), ALL);
    scene(&input, "b", (1024, 1024), ALL);
    for compression in ["zip", "piz"] {
        let (mut failed, mut done) = (0, 0);
        for kib in (130_000..=230_000).step_by(10_000) {
            let out = dir.path().join(format!("{compression}-{kib}"));
            let args = [
                "batch",
                input.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--compression",
                compression,
            ];
            let o = limited(kib, &args, &[]);
            let what = format!("batch {compression} under ulimit -v {kib}");
            let err = stderr(&o);
            assert!(temps(&out).is_empty(), "{what}: temps left");
            let summary = format!("{}{err}", String::from_utf8_lossy(&o.stdout));
            assert!(summary.contains("shard 0-of-1: done"), "{what}: {summary}");
            match o.status.code() {
                Some(0) => done += 1,
                Some(1) => {
                    failed += 1;
                    let failures = std::fs::read_to_string(out.join("failures.0-of-1.jsonl"))
                        .unwrap_or_default();
                    assert!(
                        failures.contains("needs about") || failures.contains("out of memory"),
                        "{what}: {failures}"
                    );
                }
                other => panic!("{what}: status {other:?}: {err}"),
            }
        }
        assert!(
            failed > 0 && done > 0,
            "{compression}: {failed} failed, {done} done"
        );
    }
}

/// `compare` of two 1024² 13-channel images under `ulimit -v`: refused up front with
/// its estimate while it does not fit (the check's status, 2), a PASS once it does; never
/// an abort.
#[test]
fn compare_under_ulimit_is_refused_or_done() {
    let _one = serial();
    let dir = fresh_dir("memory", "ulimit-compare");
    let s = scene(dir.path(), "c", (1024, 1024), ALL);
    let a = dir.path().join("a.exr");
    cylaov::commands::render::run(&render_args(&s, &a, Compression::None)).unwrap();
    let a = a.to_str().unwrap();
    let (mut refused, mut done) = (0, 0);
    for kib in (150_000..=400_000).step_by(25_000) {
        let o = limited(kib, &["compare", a, a], &[]);
        let err = stderr(&o);
        match o.status.code() {
            Some(0) => done += 1,
            Some(2) => {
                refused += 1;
                assert_eq!(err.lines().count(), 1, "{err}");
                assert!(
                    err.contains("comparing") && err.contains("needs about"),
                    "{err}"
                );
            }
            other => panic!("compare under ulimit -v {kib}: status {other:?}: {err}"),
        }
    }
    assert!(refused > 0 && done > 0, "{refused} refused, {done} done");
}

/// `cylaov ARGS` with every allocation over 1 MB refused (`CYLAOV_FAIL_ALLOC_OVER`), with
/// `envs` set.
fn refusing(args: &[&str], envs: &[(&str, &Path)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .env("CYLAOV_FAIL_ALLOC_OVER", "1000000")
        .envs(envs.iter().copied())
        .output()
        .unwrap()
}

/// A refused allocation in `render` (one of our own buffers, the render's planes) is one
/// line naming it and status 1, not Rust's abort, with nothing written.
#[test]
fn a_refused_allocation_is_one_line_and_status_1() {
    let _one = serial();
    let dir = fresh_dir("memory", "refused");
    let s = scene(dir.path(), "r", (1024, 1024), ALL);
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let r = out.join("r.exr");
    let o = refusing(
        &[
            "render",
            s.to_str().unwrap(),
            "-o",
            r.to_str().unwrap(),
            "--compression",
            "zip",
        ],
        &[],
    );
    assert_clean_failure("render", &o, &out);
    assert_eq!(
        stderr(&o),
        "error: an output plane of the render: out of memory: 4 MiB could not be allocated (free memory, ulimit -v and the cgroup limit)\n"
    );
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0);
}

/// In `compare` and `verify` status 1 means a broken tolerance, so a refused allocation
/// there is status 2, a check that could not be made: inside a crate (the `exr` reader's
/// sample vectors in `compare`) and in one of our own buffers (the planes of `verify`'s
/// own render, before Mitsuba is started; the stand-in venv is never run). The line is
/// the same and `verify`'s scratch folder goes.
#[test]
fn a_refused_allocation_in_compare_or_verify_is_status_2() {
    let _one = serial();
    let dir = fresh_dir("memory", "refused-check");
    let s = scene(dir.path(), "r", (1024, 1024), ALL);
    let a = dir.path().join("a.exr");
    cylaov::commands::render::run(&render_args(&s, &a, Compression::None)).unwrap();
    let o = refusing(&["compare", a.to_str().unwrap(), a.to_str().unwrap()], &[]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "compare: {err}");
    assert_eq!(
        err,
        "error: out of memory: an allocation of 4 MiB was refused (free memory, ulimit -v or the cgroup limit)\n"
    );

    let venv = dir.path().join("venv");
    std::fs::create_dir_all(venv.join("bin")).unwrap();
    std::fs::write(venv.join("bin/python"), "#!/bin/sh\nexit 3\n").unwrap();
    let scratch = dir.path().join("tmp");
    std::fs::create_dir(&scratch).unwrap();
    let o = refusing(
        &["verify", s.to_str().unwrap()],
        &[("CYLAOV_VENV", &venv), ("TMPDIR", &scratch)],
    );
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "verify: {err}");
    assert_eq!(
        err,
        "error: an output plane of the render: out of memory: 4 MiB could not be allocated (free memory, ulimit -v and the cgroup limit)\n"
    );
    assert_eq!(
        std::fs::read_dir(&scratch).unwrap().count(),
        0,
        "verify's scratch stayed"
    );
}

/// The issue's case scaled by the estimate: two 4096² files of every AOV need the images
/// (1 664 MiB) plus 73 bytes a pixel (1 168 MiB), not the 1 920 MiB once estimated.
#[test]
fn the_compare_estimate_of_two_4096_squared_files() {
    let px = 4096 * 4096;
    let est = memory_needed((px, 13), (px, 13), false);
    assert_eq!(est, 4 * 2 * px * 13 + 73 * px + (2 << 20));
    assert_eq!(est >> 20, 2834);
}

// ---- messages ------------------------------------------------------------------------------

/// A render of `scene` with `aovs` into `dir/NAME.exr`.
fn render_to(dir: &Path, name: &str, aovs: &str) -> PathBuf {
    let s = scene(dir, name, (64, 48), aovs);
    let out = dir.join(format!("{name}.exr"));
    let o = cylaov(&["render", s.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    out
}

/// Depth-only A against shape_id-only B: B's hits come from its shape_id, the images
/// agree on every pixel, and the note says A lacks shape_id (not "B: cannot tell hits
/// from misses: no shape_id").
#[test]
fn compare_takes_hits_from_shape_id_when_the_other_image_has_none() {
    let _one = serial();
    let dir = fresh_dir("memory", "identity");
    let a = render_to(dir.path(), "depth", r#"["depth"]"#);
    let b = render_to(dir.path(), "ids", r#"["shape_id"]"#);
    let o = cylaov(&["compare", a.to_str().unwrap(), b.to_str().unwrap()]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(0), "{out}{}", stderr(&o));
    assert!(
        out.contains("A lacks shape_id: pixels classified by hit/miss only (A from depth > 0, B from shape_id > 0)"),
        "{out}"
    );
    assert!(out.trim_end().ends_with("PASS"), "{out}");
}

/// `batch --depth-scale 0|NaN|inf`: the error alone, no nerfstudio warning quoting the
/// bad value first.
#[test]
fn a_bad_depth_scale_is_the_error_alone() {
    let _one = serial();
    let dir = fresh_dir("memory", "depth-scale");
    let input = dir.path().join("in");
    std::fs::create_dir(&input).unwrap();
    scene(&input, "a", (16, 12), r#"["depth"]"#);
    for bad in ["0", "NaN", "inf"] {
        let out = dir.path().join(format!("out-{bad}"));
        let o = cylaov(&[
            "batch",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--depth-scale",
            bad,
        ]);
        assert_eq!(o.status.code(), Some(2), "{bad}");
        assert_eq!(
            stderr(&o),
            format!("error: --depth-scale: must be finite and > 0, got {bad}\n")
        );
    }
}

/// `render --depth-png --depth-scale 0|NaN|inf`: the error alone, status 2 (a usage
/// error), nothing written.
#[test]
fn a_bad_render_depth_scale_is_the_error_alone() {
    let _one = serial();
    let dir = fresh_dir("memory", "render-depth-scale");
    let s = scene(dir.path(), "a", (16, 12), r#"["depth"]"#);
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    for bad in ["0", "NaN", "inf"] {
        let o = cylaov(&[
            "render",
            s.to_str().unwrap(),
            "-o",
            out.join("a.exr").to_str().unwrap(),
            "--depth-png",
            "--depth-scale",
            bad,
        ]);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", stderr(&o));
        assert_eq!(
            stderr(&o),
            format!("error: --depth-scale: must be finite and > 0, got {bad}\n")
        );
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "{bad}");
    }
}

/// A full disk while the depth PNG is written gives the same advice as the EXR's: a
/// tmpfs with room for the EXR and the two JSON files, in whole pages, and not one page
/// more (the PNG is staged last). Needs root to mount; skipped, saying so, without, except
/// under CI=true, where a run that cannot mount fails.
#[test]
fn a_full_disk_under_the_depth_png_says_so() {
    let _one = serial();
    let dir = fresh_dir("memory", "full");
    let s = scene(dir.path(), "f", (256, 128), r#"["depth"]"#);
    let free = dir.path().join("free");
    let args = |out: &Path| {
        let o = cylaov(&[
            "render",
            s.to_str().unwrap(),
            "-o",
            out.join("f.exr").to_str().unwrap(),
            "--depth-png",
        ]);
        (o.status.code(), stderr(&o))
    };
    std::fs::create_dir(&free).unwrap();
    assert_eq!(args(&free).0, Some(0));
    let pages: u64 = ["f.exr", "f.camera.json", "f.open3d.json"]
        .iter()
        .map(|f| {
            std::fs::metadata(free.join(f))
                .unwrap()
                .len()
                .div_ceil(4096)
        })
        .sum();
    let disk = dir.path().join("disk");
    std::fs::create_dir(&disk).unwrap();
    let mounted = Command::new("mount")
        .args([
            "-t",
            "tmpfs",
            "-o",
            &format!("size={}k", 4 * pages),
            "tmpfs",
        ])
        .arg(&disk)
        .output()
        .is_ok_and(|o| o.status.success());
    if !mounted {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but a tmpfs cannot be mounted at {}",
            disk.display()
        );
        eprintln!("SKIPPED: cannot mount a tmpfs here (needs root)");
        return;
    }
    let (code, err) = args(&disk);
    let left = std::fs::read_dir(&disk).unwrap().count();
    let _ = Command::new("umount").arg(&disk).status();
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("f.depth.png"), "{err}");
    assert!(
        err.contains("the disk is full; free space and run again"),
        "{err}"
    );
    assert_eq!(left, 0, "nothing left on the disk");
}

/// A 16384² camera is within the side limit but over the pixel cap: the message says
/// both limits.
#[test]
fn the_pixel_cap_message_names_both_limits() {
    let _one = serial();
    let dir = fresh_dir("memory", "cap");
    let s = scene(dir.path(), "big", (16384, 16384), r#"["depth"]"#);
    let out = dir.path().join("big.exr");
    let o = cylaov(&["render", s.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("width × height must be <= 67108864 pixels (64 megapixels, e.g. 8192 × 8192; each side <= 16384), got 16384 × 16384 = 268435456"),
        "{err}"
    );
}

/// The heatmap of `compare` carries the one legend: every class colour in its swatch,
/// seam included, under the image.
#[test]
fn the_heatmap_legend_names_every_class() {
    use cylaov::verify::compare::{LEGEND, SEAM, SILHOUETTE};
    let _one = serial();
    let dir = fresh_dir("memory", "legend");
    let a = render_to(dir.path(), "a", ALL);
    let heat = dir.path().join("heat.png");
    let o = cylaov(&[
        "compare",
        a.to_str().unwrap(),
        a.to_str().unwrap(),
        "--heatmap",
        heat.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&heat).unwrap().to_rgb8();
    assert!(
        img.height() > 48 + 8 * LEGEND.len() as u32,
        "{:?}",
        img.dimensions()
    );
    let labels: Vec<&str> = LEGEND.iter().map(|(_, l)| *l).collect();
    assert_eq!(
        labels,
        [
            "BOTH MISS",
            "SILHOUETTE MISMATCH",
            "SEAM MISMATCH",
            "INTERIOR MISMATCH (FAIL)",
            "OVER TOLERANCE (FAIL)",
            "RING: FAILING PIXEL"
        ]
    );
    // Each swatch sits at the left of its legend row, below the 48-row image.
    for (k, (colour, label)) in LEGEND.iter().enumerate().take(5) {
        let y = 48 + 3 + 8 * k as u32 + 2;
        assert_eq!(img.get_pixel(2, y), colour, "{label}");
    }
    assert!(LEGEND.iter().any(|(c, _)| *c == SEAM) && LEGEND.iter().any(|(c, _)| *c == SILHOUETTE));
}

/// `verify --heatmap` writes the same legend under its heatmap (skipped, saying so,
/// without the reference venv).
#[test]
fn verify_heatmaps_carry_the_legend() {
    use cylaov::verify::compare::LEGEND;
    let Some(py) = common::venv_python() else {
        return;
    };
    let _one = serial();
    let dir = fresh_dir("memory", "verify-legend");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/single.json");
    let venv = py.parent().and_then(Path::parent).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(["verify", scene.to_str().unwrap(), "--heatmap"])
        .arg(dir.path())
        .env("CYLAOV_VENV", venv)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let img = image::open(dir.path().join("single.heatmap.png"))
        .unwrap()
        .to_rgb8();
    // 320 x 240: scale 2, rows of 16 pixels under the image: the legend, the ramp and the
    // title (the view, what was compared, the verdict).
    assert_eq!(
        img.dimensions(),
        (320, 240 + 2 + 16 * (LEGEND.len() as u32 + 2))
    );
    for (k, (colour, label)) in LEGEND.iter().enumerate().take(5) {
        let y = 240 + 3 + 16 * k as u32 + 4;
        assert_eq!(img.get_pixel(4, y), colour, "{label}");
    }
}

/// No `--help` text points at the source (`compare::heatmap`, `src/…`).
#[test]
fn help_never_points_at_source_paths() {
    let _one = serial();
    for sub in [
        "render",
        "generate",
        "batch",
        "export-mitsuba",
        "compare",
        "verify",
        "stress",
        "bench",
    ] {
        let o = cylaov(&[sub, "--help"]);
        let help = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success() && help.contains("Usage"),
            "{sub}: {help}"
        );
        for bad in ["::", "src/", ".rs"] {
            assert!(!help.contains(bad), "{sub} --help mentions {bad}: {help}");
        }
    }
}
