//! The dataset read by the tools that use it, with their own loaders, in the test venv
//! (`scripts/setup-venv`): the "Loading a view" blocks of `docs/datasets.md` for OpenEXR,
//! numpy, Open3D, OpenCV and nerfstudio's conventions are taken from the page and run as
//! written (only the dataset path is replaced), and what they load is checked against the
//! exact hits.
//!
//! Without the venv's packages the tests are skipped, saying so; with
//! `CYLAOV_REQUIRE_VENV=1` they fail instead.

mod common;
use common::{distance_to_surface, read_npy};

use cylaov::image::AovImage;
use cylaov::scene;
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");
/// The batch's `--depth-scale` (the default) and the page's blocks' scale.
const SCALE: f64 = 1000.0;

/// The venv's Python if it has numpy, OpenCV, Open3D and OpenEXR.
fn python() -> Option<PathBuf> {
    let py = common::venv_python()?;
    let ok = Command::new(&py)
        .args(["-c", "import numpy, cv2, open3d, OpenEXR"])
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        assert!(
            std::env::var("CYLAOV_REQUIRE_VENV").as_deref() != Ok("1"),
            "{} lacks numpy, cv2, open3d or OpenEXR (run scripts/setup-venv)",
            py.display()
        );
        eprintln!(
            "SKIPPED: {} lacks numpy, cv2, open3d or OpenEXR (run scripts/setup-venv)",
            py.display()
        );
        return None;
    }
    Some(py)
}

/// The shared dataset's scenes rendered again into a sibling folder `name` with the same
/// AOVs and `extra` options.
fn rebatch(name: &str, extra: &[&str]) -> PathBuf {
    let dir = dataset().parent().unwrap();
    let out = dir.join(name);
    let data = dir.join("data");
    let mut args = vec![
        "batch",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--aov",
        "depth,normal,position,shape_id",
    ];
    args.extend(extra);
    common::ok(&args);
    out
}

/// One dataset for every test: 2 scenes × 3 cameras, with positions for the checks.
fn dataset() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = common::shared_dir("consumers").to_path_buf();
        let run = |args: &[&str]| {
            common::ok(args);
        };
        let data = dir.join("data");
        let render = dir.join("render");
        run(&[
            "generate",
            "--count",
            "2",
            "--views-per-scene",
            "3",
            "--seed",
            "3",
            "--width",
            "96",
            "--height",
            "72",
            "--cylinders",
            "4..8",
            "--out",
            data.to_str().unwrap(),
        ]);
        run(&[
            "batch",
            data.to_str().unwrap(),
            "--out",
            render.to_str().unwrap(),
            "--aov",
            "depth,normal,position,shape_id",
        ]);
        render
    })
}

/// The block of `docs/datasets.md` after `<!-- snippet: NAME -->`, with its dataset path
/// made `dir`. Nothing else is replaced: the block runs from any folder as written.
fn snippet(name: &str, dir: &Path) -> String {
    let page = std::fs::read_to_string(Path::new(ROOT).join("docs/datasets.md")).unwrap();
    let marker = format!("<!-- snippet: {name} -->\n```python\n");
    let start = page
        .find(&marker)
        .unwrap_or_else(|| panic!("docs/datasets.md: no {marker:?}"))
        + marker.len();
    let end = start + page[start..].find("```").unwrap();
    let code = &page[start..end];
    let path = format!("Path(r\"{}\")", dir.display());
    assert!(code.contains("Path(\"data/render\")"), "{name}: {code}");
    code.replace("Path(\"data/render\")", &path)
}

/// Run `code` and then `tail` (which saves what the test checks); panics with the output.
fn run_python(py: &Path, code: &str, tail: &str) {
    let o = Command::new(py)
        .arg("-c")
        .arg(format!("{code}\n{tail}\n"))
        .env("OPENCV_IO_ENABLE_OPENEXR", "1")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{code}\n{tail}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Run the page's block `name` on the shared dataset, then `check` (Python statements on
/// its variables), and return the N x 3 array the Python expression `array` gives, through
/// a float64 `.npy` file.
fn block_array(py: &Path, name: &str, check: &str, array: &str) -> Vec<DVec3> {
    let dir = dataset();
    let npy = dir.join(format!("{name}.npy"));
    run_python(
        py,
        &snippet(name, dir),
        &format!(
            "import numpy as np\n{check}\n\
             np.save(r\"{}\", np.ascontiguousarray({array}, dtype=np.float64))",
            npy.display()
        ),
    );
    read_npy(&npy)
}

/// The exact hit points (the `position` AOV) of the view's hit pixels, row-major.
fn hits(exr: &Path) -> Vec<DVec3> {
    let img = AovImage::read_exr(exr).unwrap();
    let depth = img.f32_channel("depth").unwrap();
    let [x, y, z] = img.vec3_channel("position").unwrap();
    (0..depth.len())
        .filter(|&k| depth[k] > 0.0)
        .map(|k| DVec3::new(x[k] as f64, y[k] as f64, z[k] as f64))
        .collect()
}

/// How far a point from a 16-bit depth PNG can be from the exact hit: half a depth step
/// along the pixel ray, which is 1/cos θ times longer than its z, θ at most the corner's.
fn png_bound(camera_json: &Path) -> f64 {
    let cam: serde_json::Value =
        serde_json::from_slice(&std::fs::read(camera_json).unwrap()).unwrap();
    let f = |k: &str| cam[k].as_f64().unwrap();
    let (tx, ty) = (f("cx") / f("fl_x"), f("cy") / f("fl_y"));
    let inv_cos = (1.0 + tx * tx + ty * ty).sqrt();
    0.5 / SCALE * inv_cos * (1.0 + 1e-6) + 1e-9
}

fn max_error(got: &[DVec3], want: &[DVec3]) -> f64 {
    assert_eq!(got.len(), want.len());
    assert!(got.len() > 200, "{} hits", got.len());
    got.iter()
        .zip(want)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max)
}

/// The OpenEXR package reads the layered EXR as written: the block's `normal` (stacked from
/// `normal.X/Y/Z`), `depth` and `shape_id` are bitwise the file's channels.
#[test]
fn openexr_block_reads_every_channel_of_the_layered_exr() {
    let Some(py) = python() else { return };
    let dir = dataset();
    let normal = block_array(
        &py,
        "openexr",
        "assert normal.shape == depth.shape + (3,) and ids.dtype == np.uint32, (normal.shape, ids.dtype)\n\
         assert header[\"cylaov:channel:depth\"].startswith(\"depth: planar depth\")",
        "normal.reshape(-1, 3)",
    );
    let img = AovImage::read_exr(&dir.join("000000/00.exr")).unwrap();
    let [x, y, z] = img.vec3_channel("normal").unwrap();
    assert_eq!(normal.len(), x.len());
    for (k, n) in normal.iter().enumerate() {
        let want = DVec3::new(x[k] as f64, y[k] as f64, z[k] as f64);
        assert_eq!(*n, want, "pixel {k}");
    }
    let other = block_array(
        &py,
        "openexr",
        "",
        "np.stack([depth.ravel(), ids.ravel(), np.zeros(ids.size)], 1)",
    );
    let depth = img.f32_channel("depth").unwrap();
    let ids = img.u32_channel("shape_id").unwrap();
    assert!(ids.iter().any(|&id| id > 1));
    for (k, g) in other.iter().enumerate() {
        assert_eq!((g.x, g.y), (depth[k] as f64, ids[k] as f64), "pixel {k}");
    }
}

#[test]
fn numpy_block_gives_the_exact_hit_points() {
    let Some(py) = python() else { return };
    let dir = dataset();
    let points = block_array(&py, "numpy", "", "points");
    let err = max_error(&points, &hits(&dir.join("000000/00.exr")));
    // float32 depth against float32 position of the same ray: coordinates up to ~10 have
    // float32 steps of ~1e-6; measured 5.0e-7.
    assert!(err < 5e-6, "{err:e}");
    eprintln!("numpy: largest distance to the exact hit {err:.2e}");
}

#[test]
fn open3d_reads_the_camera_and_depth_png_within_the_16_bit_rounding() {
    let Some(py) = python() else { return };
    let dir = dataset();
    let points = block_array(&py, "open3d", "", "pcd.points");
    let bound = png_bound(&dir.join("000000/00.camera.json"));
    let err = max_error(&points, &hits(&dir.join("000000/00.exr")));
    eprintln!("Open3D: largest distance to the exact hit {err:.2e} (bound {bound:.2e})");
    assert!(err <= bound, "{err:e} > {bound:e}");
    // The bound is tight enough to see a half-pixel principal point error (cx = W/2 in
    // Open3D's integer-centre convention puts points ~1e-2 off at these distances).
    assert!(bound < 6e-4);
}

#[test]
fn opencv_reads_the_depth_png_and_mask_as_written() {
    let Some(py) = python() else { return };
    let dir = dataset();
    let got = block_array(
        &py,
        "opencv",
        "assert depth_mm.dtype == np.uint16, depth_mm.dtype",
        "np.stack([depth_mm.ravel(), mask.ravel(), np.zeros(mask.size)], 1)",
    );
    let img = AovImage::read_exr(&dir.join("000000/00.exr")).unwrap();
    let depth = img.f32_channel("depth").unwrap();
    assert_eq!(got.len(), depth.len());
    for (k, (g, &z)) in got.iter().zip(depth).enumerate() {
        let want = (z as f64 * SCALE).round();
        assert_eq!((g.x, g.y), (want, (z > 0.0) as u8 as f64), "pixel {k}");
    }
}

#[test]
fn nerfstudio_reading_puts_every_view_of_a_scene_on_its_cylinders() {
    let Some(py) = python() else { return };
    let dir = dataset();
    let points = block_array(&py, "nerfstudio", "", "np.concatenate(world)");
    let scene_file = std::fs::read_dir(dir.parent().unwrap().join("data/scenes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.ends_with("000000.json"))
        .unwrap();
    let scene = scene::load(&scene_file).unwrap();
    assert_eq!(scene.cameras.len(), 3);
    let hits: usize = (0..3)
        .map(|k| hits(&dir.join(format!("000000/{k:02}.exr"))).len())
        .sum();
    assert_eq!(
        points.len(),
        hits,
        "one point per hit pixel of the three views"
    );
    let bound = png_bound(&dir.join("000000/00.camera.json"));
    let worst = points
        .iter()
        .map(|&p| {
            scene
                .cylinders
                .iter()
                .map(|c| distance_to_surface(c, p))
                .fold(f64::INFINITY, f64::min)
        })
        .fold(0.0, f64::max);
    eprintln!("nerfstudio: largest distance to the cylinders {worst:.2e} (bound {bound:.2e})");
    assert!(worst <= bound, "{worst:e} > {bound:e}");
}

/// Python OpenEXR reads the header: the standard `worldToCamera` and `worldToNDC` in
/// OpenEXR's conventions (Imath row vectors; camera z forward; NDC (0, 0) top-left) map the
/// view's own hit points to their planar depth and their pixel centres, and the cylaov
/// attributes name what each channel means, for compressed and uncompressed files.
#[test]
fn openexr_header_says_what_the_file_holds() {
    let Some(py) = python() else { return };
    let dir = dataset();
    let zip = rebatch("zip", &["--compression", "zip"]);
    for exr in [dir.join("000001/02.exr"), zip.join("000001/02.exr")] {
        let out = Command::new(&py)
            .arg("-c")
            .arg(
                r#"
import sys, numpy as np, OpenEXR
f = OpenEXR.File(sys.argv[1])
h, ch = f.header(), f.channels()
for k in ["cylaov:units", "cylaov:miss", "cylaov:channel:depth", "cylaov:channel:normal"]:
    print(k, "=", h[k])
print("cx", h["cylaov:cx"], "cx_opencv", h["cylaov:cx_opencv"])
depth = ch["depth"].pixels.astype(np.float64)
p = np.stack([ch[f"position.{a}"].pixels for a in "XYZ"], -1).astype(np.float64)
j, i = np.nonzero(depth)
P = np.concatenate([p[j, i], np.ones((len(i), 1))], 1)
cam = P @ np.array(h["worldToCamera"], dtype=np.float64)
ndc = P @ np.array(h["worldToNDC"], dtype=np.float64)
H, W = depth.shape
print("z", np.max(np.abs(cam[:, 2] - depth[j, i]) / depth[j, i]))
print("ndc_px", max(np.max(np.abs(ndc[:, 0] / ndc[:, 3] * W - (i + 0.5))),
                    np.max(np.abs(ndc[:, 1] / ndc[:, 3] * H - (j + 0.5)))))
print("hits", len(i))
"#,
            )
            .arg(&exr)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = String::from_utf8_lossy(&out.stdout);
        let value = |key: &str| -> f64 {
            text.lines()
                .find_map(|l| l.strip_prefix(&format!("{key} ")))
                .unwrap_or_else(|| panic!("{key}: {text}"))
                .parse()
                .unwrap()
        };
        assert!(
            text.contains("cylaov:channel:depth = depth: planar depth"),
            "{text}"
        );
        assert!(
            text.contains("cylaov:channel:normal = normal.X, normal.Y, normal.Z: world-space"),
            "{text}"
        );
        assert!(
            text.contains("cylaov:miss = a pixel whose ray hits nothing is 0"),
            "{text}"
        );
        assert!(text.contains("cx 48.0 cx_opencv 47.5"), "{text}");
        assert!(value("hits") > 200.0, "{text}");
        // float32 matrices applied in float64 to float32 points: measured z relative
        // 6.7e-8 and 1.6e-6 pixels; the bounds leave 15x and 60x of room, far below the
        // half pixel or the 1/W-relative NDC error that a wrong convention would give.
        let (z, px) = (value("z"), value("ndc_px"));
        eprintln!(
            "{}: worldToCamera z rel {z:.1e}, worldToNDC {px:.1e} px",
            exr.display()
        );
        assert!(z < 1e-6, "{text}");
        assert!(px < 1e-4, "{text}");
    }
}

/// OpenCV 4 reads the per-AOV EXRs (`OPENCV_IO_ENABLE_OPENEXR=1`, `IMREAD_UNCHANGED`): the
/// samples are bitwise those of the layered EXR (normals and positions as B, G, R: OpenCV's
/// channel order), ids as exact float32. The page's block loads one.
#[test]
fn opencv_reads_per_aov_exrs_bitwise_equal_to_the_layered_file() {
    let Some(py) = python() else { return };
    let dir = dataset();
    let per = rebatch("per-aov", &["--exr-layout", "per-aov"]);
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(per.join("index.json")).unwrap()).unwrap();
    assert_eq!(
        index["views"][0]["exr_file_paths"]["normal"],
        "000000/00.normal.exr"
    );
    assert!(!per.join("000000/00.exr").exists());
    run_python(&py, &snippet("opencv-exr", &per), "");
    for view in ["000000/00", "000001/02"] {
        let layered = AovImage::read_exr(&dir.join(format!("{view}.exr"))).unwrap();
        let out = Command::new(&py)
            .arg("-c")
            .arg(
                r#"
import sys, cv2, numpy as np
for aov in ["depth", "normal", "position", "shape_id"]:
    a = cv2.imread(f"{sys.argv[1]}.{aov}.exr", cv2.IMREAD_UNCHANGED)
    assert a.dtype == np.float32, (aov, a.dtype)
    a = a.reshape(a.shape[0] * a.shape[1], -1)[:, ::-1]  # BGR -> RGB = X, Y, Z
    for k in range(a.shape[1]):
        sys.stdout.buffer.write(np.ascontiguousarray(a[:, k]).tobytes())
"#,
            )
            .arg(per.join(view))
            .env("OPENCV_IO_ENABLE_OPENEXR", "1")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let got: Vec<u32> = out
            .stdout
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let mut want: Vec<u32> = Vec::new();
        for name in [
            "depth",
            "normal.X",
            "normal.Y",
            "normal.Z",
            "position.X",
            "position.Y",
            "position.Z",
        ] {
            want.extend(
                layered
                    .f32_channel(name)
                    .unwrap()
                    .iter()
                    .map(|x| x.to_bits()),
            );
        }
        let ids = layered.u32_channel("shape_id").unwrap();
        want.extend(ids.iter().map(|&id| (id as f32).to_bits()));
        assert!(ids.iter().any(|&id| id > 1));
        assert_eq!(got.len(), want.len(), "{view}");
        assert!(
            got == want,
            "{view}: OpenCV's samples differ from the layered EXR"
        );
    }
}
