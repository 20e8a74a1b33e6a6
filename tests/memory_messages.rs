//! Memory and messages: the memory estimates hold what the code really allocates (heap
//! peaks counted by the allocator at several sizes, every compression); a refused
//! allocation is one error line and exit 1, never an abort; and the one-line messages name
//! the real cause (identity, `--depth-scale`, a full disk, the pixel cap, the heatmap
//! legend, `--help`).

mod common;
use common::{cylaov, fresh_dir};

use cylaov::commands::compare::{CompareArgs, memory_needed};
use cylaov::commands::render::RenderArgs;
use cylaov::mem::{Guarded, heap_live, heap_peak, reset_heap_peak};
use cylaov::output::aov::{Compression, ExrLayout, render_memory};
use cylaov::output::depth_png::OutOfRange;
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
