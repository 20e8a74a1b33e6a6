//! Edges of the input space: rays lying in the faces of BVH boxes (every acceleration
//! against the double-double oracle), axes too short or too long to square, cameras whose
//! focal length overflows.

mod common;

use cylaov::geometry::{Cylinder, FormulaKind, Precision};
use cylaov::image::{AovImage, ChannelData, ChannelRef};
use cylaov::output::format::mitsuba::to_xml;
use cylaov::render::{Accel, RenderOptions, render};
use cylaov::rng::SplitMix64;
use cylaov::scene::camera::Camera;
use cylaov::scene::{self, Aov, Scene};
use cylaov::verify::oracle::{DD, Problem, intersect};

fn scene(json: &str) -> Scene {
    match scene::parse(json) {
        Ok(s) => s,
        Err(e) => panic!("test scene rejected: {e}\n{json}"),
    }
}

fn traced(scene: &Scene, accel: Accel) -> AovImage {
    let opts = RenderOptions {
        aovs: vec![Aov::Depth, Aov::ShapeId],
        precision: Precision::F64,
        formula: FormulaKind::Stable,
        accel,
    };
    render(scene, &opts).image
}

/// The ids of the cylinders the double-double oracle hits first along pixel (i, j)'s ray
/// within its clip range, each cylinder widened by `grow` (radius, and height at both
/// ends): the nearest, and any other within 1e-9 relative of it (coincident surfaces of
/// overlapping cylinders, where an f64 kernel may pick either); empty for a miss.
fn oracle_ids(scene: &Scene, cam: &Camera, (i, j): (u32, u32), grow: f64) -> Vec<u32> {
    let (d, len) = cam.dir_and_length(cam.column_offset(i), cam.row_offset(j));
    let (tmin, tmax) = cam.clip_range(len);
    let mut hits: Vec<(f64, u32)> = scene
        .cylinders
        .iter()
        .filter_map(|c| {
            let c = Cylinder {
                base: c.base - c.axis * grow,
                height: c.height + 2.0 * grow,
                radius: c.radius + grow,
                ..*c
            };
            let p = Problem::new(&c, cam.origin, d);
            let h = intersect(&p, DD::new(tmin), DD::new(tmax))?;
            Some((h.t.to_f64(), c.id))
        })
        .collect();
    hits.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let near = hits.first().map_or(0.0, |h| h.0);
    hits.iter()
        .take_while(|h| h.0 <= near * (1.0 + 1e-9))
        .map(|h| h.1)
        .collect()
}

/// Every acceleration finds the tiles' hits, bit for bit, and those are the oracle's: at
/// each pixel the oracle's nearest cylinder, or a miss where it misses, unless a change
/// of the cylinders by 1e-9 (an f64 kernel's rounding at a rim or a tangent) changes the
/// oracle's answer to the tiles'. Returns the hit count and the number of pixels whose
/// answer was that close.
fn agree(scene: &Scene, what: &str) -> (usize, usize) {
    let cam = Camera::new(scene.camera);
    let tiles = traced(scene, Accel::Tiles);
    let ids = tiles.u32_channel("shape_id").expect("shape_id");
    let mut close = 0;
    for (k, &id) in ids.iter().enumerate() {
        let px = (k as u32 % cam.width(), k as u32 / cam.width());
        let fits = |grow: f64| {
            let want = oracle_ids(scene, &cam, px, grow);
            if id == 0 {
                want.is_empty()
            } else {
                want.contains(&id)
            }
        };
        if !fits(0.0) {
            assert!(
                fits(1e-9) || fits(-1e-9),
                "{what}: pixel {px:?}: the tiles' {id} against the oracle's {:?}",
                oracle_ids(scene, &cam, px, 0.0)
            );
            close += 1;
        }
    }
    let bits = |im: &AovImage| -> Vec<u32> {
        im.f32_channel("depth")
            .expect("depth")
            .iter()
            .map(|v| v.to_bits())
            .collect()
    };
    for accel in [Accel::Frustum, Accel::Bvh] {
        let img = traced(scene, accel);
        let other = img.u32_channel("shape_id").expect("shape_id");
        let differ = (0..ids.len()).filter(|&k| other[k] != ids[k]).count();
        assert_eq!(
            differ, 0,
            "{what}, {accel:?}: pixels that differ from the tiles"
        );
        assert_eq!(bits(&img), bits(&tiles), "{what}, {accel:?}: depth bits");
    }
    (ids.iter().filter(|&&id| id != 0).count(), close)
}

/// A capped cylinder seen by a camera level with its top cap: the centre row's rays lie in
/// the top face of the cylinder's box.
#[test]
fn camera_level_with_a_cap_sees_the_cap_row() {
    let s = scene(
        r#"{"camera": {"origin": [3, 0, 1], "target": [0, 0, 1], "up": [0, 0, 1],
            "fov_deg": 40, "width": 32, "height": 9},
          "cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.5, "caps": true}]}"#,
    );
    let (hits, close) = agree(&s, "level with the cap");
    assert_eq!(close, 0);
    let row = |img: &AovImage| {
        let ids = img.u32_channel("shape_id").expect("shape_id");
        ids.range(4 * 32..5 * 32).filter(|&&id| id != 0).count()
    };
    // The centre row crosses the cap edge-on, over the cylinder's 0.5 m half-width.
    assert_eq!(row(&traced(&s, Accel::Bvh)), 14);
    assert_eq!(hits, 70);
}

/// An axis-aligned cylinder's box, `[lo, hi]`, from its base, axis index, height and radius.
fn aligned_box(base: [f64; 3], axis: usize, h: f64, r: f64) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = (base, base);
    for a in 0..3 {
        if a == axis {
            hi[a] += h;
        } else {
            lo[a] -= r;
            hi[a] += r;
        }
    }
    (lo, hi)
}

/// Random scenes of axis-aligned cylinders on a half-unit grid, each seen by cameras
/// looking along an axis from a point level with a face plane, an edge or a corner of
/// one cylinder's box (odd image sides: the centre row and column hold rays with zero
/// components, lying in those planes). Some views have fewer pixels than a quarter of
/// the cylinders (the binary tree), the others the eight-wide tree.
#[test]
fn face_grazing_and_corner_rays_agree_with_the_oracle() {
    let mut rng = SplitMix64::new(25);
    let (mut views, mut hits, mut close) = (0, 0, 0);
    for k in 0..24 {
        let n = [1, 3, 9, 40, 120][k % 5];
        let mut cyls = Vec::new();
        let mut boxes = Vec::new();
        for _ in 0..n {
            let axis = rng.int_in(0, 2) as usize;
            let base = [0; 3].map(|_| rng.int_in(0, 8) as f64 * 0.5 - 2.0);
            let h = rng.int_in(1, 3) as f64 * 0.5;
            let r = [0.25, 0.5][rng.int_in(0, 1) as usize];
            let mut top = base;
            top[axis] += h;
            let caps = rng.unit() < 0.7;
            cyls.push(format!(
                r#"{{"p0": {base:?}, "p1": {top:?}, "radius": {r}, "caps": {caps}}}"#
            ));
            boxes.push(aligned_box(base, axis, h, r));
        }
        for v in 0..4 {
            // The point the centre ray passes through: per axis the box's min, max or
            // centre (a face, an edge or a corner of the box).
            let (lo, hi) = boxes[rng.int_in(0, n as u32 - 1) as usize];
            let p: [f64; 3] = std::array::from_fn(|a| match rng.int_in(0, 2) {
                0 => lo[a],
                1 => hi[a],
                _ => (lo[a] + hi[a]) * 0.5,
            });
            let look = rng.int_in(0, 2) as usize;
            let sign = if rng.unit() < 0.5 { 1.0 } else { -1.0 };
            let mut origin = p;
            origin[look] -= sign * 6.0;
            let mut up = [0.0; 3];
            up[(look + 1 + (v % 2)) % 3] = 1.0;
            let (w, h) = if v == 3 { (3, 3) } else { (33, 17) };
            let json = format!(
                r#"{{"camera": {{"origin": {origin:?}, "target": {p:?}, "up": {up:?},
                    "fov_deg": 50, "width": {w}, "height": {h}}},
                  "cylinders": [{}]}}"#,
                cyls.join(",")
            );
            let (h, c) = agree(&scene(&json), &json);
            (hits, close) = (hits + h, close + c);
            views += 1;
        }
    }
    assert_eq!(views, 96);
    assert!(hits > 10_000, "{hits} hit pixels");
    assert!(
        close < hits / 1000,
        "{close} of {hits} pixels at a rim or tangent"
    );
}

/// Every channel's samples, as bits (f32 and u32 alike), by name.
fn channel_bits(img: &AovImage) -> Vec<(String, Vec<u32>)> {
    let mut out: Vec<(String, Vec<u32>)> = img
        .to_channels()
        .iter()
        .map(|c| {
            let bits = match &c.data {
                ChannelData::F32(v) => v.iter().map(|x| x.to_bits()).collect(),
                ChannelData::U32(v) => v.clone(),
            };
            (c.name.clone(), bits)
        })
        .collect();
    out.sort();
    out
}

/// The samples of channel `name` as f64 (f32 and u32 alike).
fn samples(img: &AovImage, name: &str) -> Vec<f64> {
    match img.channel(name).expect(name) {
        ChannelRef::F32(v) => v.iter().map(|&x| x as f64).collect(),
        ChannelRef::U32(v) => v.iter().map(|&x| x as f64).collect(),
    }
}

/// Two scene texts give the same cylinders, the same image (every AOV) and the same
/// Mitsuba XML: bit for bit when `exact`, else to 1e-14 in the axis and 1e-6 in the
/// image (a tiny axis whose direction has no exact f64 unit vector at both scales). The
/// image's normals are unit vectors. Returns the hit count.
fn same_geometry(tiny: &str, unit: &str, exact: bool) -> usize {
    let (a, b) = (scene(tiny), scene(unit));
    let opts = RenderOptions::new(Aov::ALL.to_vec());
    let (ia, ib) = (render(&a, &opts).image, render(&b, &opts).image);
    if exact {
        assert_eq!(a.cylinders, b.cylinders, "{tiny}");
        assert_eq!(channel_bits(&ia), channel_bits(&ib), "{tiny}");
        assert_eq!(
            to_xml(&a, "s.json").unwrap(),
            to_xml(&b, "s.json").unwrap(),
            "{tiny}"
        );
    } else {
        let (ca, cb) = (&a.cylinders[0], &b.cylinders[0]);
        assert!((ca.axis - cb.axis).length() < 1e-14, "{tiny}: {ca:?}");
        assert_eq!(
            (ca.base, ca.height, ca.radius),
            (cb.base, cb.height, cb.radius)
        );
        for name in ia.names() {
            let (x, y) = (samples(&ia, name), samples(&ib, name));
            let off = (0..x.len()).filter(|&k| (x[k] - y[k]).abs() > 1e-6 * y[k].abs().max(1.0));
            assert_eq!(off.count(), 0, "{tiny}: channel {name}");
        }
    }
    let n = ia.vec3_channel("normal").expect("normal");
    let ids = ia.u32_channel("shape_id").expect("shape_id");
    let mut hits = 0;
    for k in (0..ids.len()).filter(|&k| ids[k] != 0) {
        let len = (0..3).map(|a| (n[a][k] as f64).powi(2)).sum::<f64>().sqrt();
        assert!(
            (len - 1.0).abs() < 1e-6,
            "{tiny}: pixel {k}: |normal| = {len}"
        );
        hits += 1;
    }
    hits
}

const TINY_CAMERA: &str = r#""camera": {"origin": [3, 2, 1], "target": [0, 0, 0.4],
    "up": [0, 0, 1], "fov_deg": 50, "width": 48, "height": 32}"#;

/// An axis whose squared length underflows is normalised as the unit axis of the same
/// direction is: the same height, image and export (bit for bit when the tiny axis is
/// the other scaled by a power of two).
#[test]
fn tiny_axis_is_the_unit_axis() {
    let p = 2f64.powi(-540);
    let scaled = |v: [f64; 3]| format!("{:?}", v.map(|x| x * p));
    for (tiny, unit, exact) in [
        ("[1.6e-162, 1.6e-162, 0]".to_string(), "[1, 1, 0]", false),
        ("[0, 0, 1e-200]".to_string(), "[0, 0, 1]", true),
        (scaled([1.0, 1.0, 0.0]), "[1, 1, 0]", true),
        (scaled([3.0, -4.0, 5.0]), "[3, -4, 5]", true),
        (scaled([0.1, 0.7, -0.3]), "[0.1, 0.7, -0.3]", true),
    ] {
        let cyl = |axis: &str| {
            format!(
                r#"{{ {TINY_CAMERA}, "cylinders": [{{"center": [0, 0, 0], "axis": {axis},
                    "height": 1.5, "radius": 0.5, "caps": true}}]}}"#
            )
        };
        assert_eq!(scene(&cyl(&tiny)).cylinders[0].height, 1.5);
        assert!(
            same_geometry(&cyl(&tiny), &cyl(unit), exact) > 100,
            "{tiny}"
        );
    }
}

/// End points 1e-162 apart: a disk of that thickness whose axis is the direction from p0
/// to p1, as the same direction given as an axis makes it, and whose normals are unit
/// vectors.
#[test]
fn end_points_a_tiny_length_apart_give_a_unit_axis() {
    let p = 2f64.powi(-540);
    for dir in [[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [-0.2, 1.0, 0.4]] {
        let p1 = format!("{:?}", dir.map(|x| x * p));
        let tiny = format!(
            r#"{{ {TINY_CAMERA}, "cylinders": [{{"p0": [0, 0, 0], "p1": {p1},
                "radius": 0.5, "caps": true}}]}}"#
        );
        let h = scene(&tiny).cylinders[0].height;
        let want = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt() * p;
        assert_eq!(h, want, "{p1}");
        let unit = format!(
            r#"{{ {TINY_CAMERA}, "cylinders": [{{"center": [0, 0, 0], "axis": {dir:?},
                "height": {h:e}, "radius": 0.5, "caps": true}}]}}"#
        );
        assert!(same_geometry(&tiny, &unit, true) > 50, "{p1}");
    }
}

/// A field of view whose focal length overflows is refused by name and value, and
/// nothing is written (`render`, `export-mitsuba`).
#[test]
fn a_field_of_view_without_a_finite_focal_length_is_refused() {
    for (fov, axis) in [("5e-324", "x"), ("1e-310", "y"), ("4e-40", "diagonal")] {
        let dir = common::fresh_dir("edges", "fov");
        let path = dir.path().join("s.json");
        let text = format!(
            r#"{{"camera": {{"origin": [3, 0, 1], "target": [0, 0, 1], "up": [0, 0, 1],
                "fov_deg": {fov}, "fov_axis": "{axis}", "width": 64, "height": 48}},
              "cylinders": [{{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.5}}]}}"#
        );
        std::fs::write(&path, &text).unwrap();
        let s = path.to_str().unwrap();
        let out = dir.path().join("out.exr");
        let xml = dir.path().join("out.xml");
        for args in [
            vec!["render", s, "-o", out.to_str().unwrap()],
            vec!["export-mitsuba", s, "-o", xml.to_str().unwrap()],
        ] {
            let run = common::cylaov(&args);
            let err = String::from_utf8_lossy(&run.stderr);
            assert_eq!(run.status.code(), Some(1), "{fov} {args:?}: {err}");
            assert_eq!(err.lines().count(), 1, "{fov}: {err}");
            assert!(
                err.contains("camera.fov_deg") && err.contains(fov),
                "{fov}: {err}"
            );
            let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
            assert_eq!(left.len(), 1, "{fov} {args:?}: files written");
        }
    }
    // A field of view of 1e-30 degrees has a finite focal length: rendered.
    let dir = common::fresh_dir("edges", "fov-ok");
    let path = dir.path().join("s.json");
    std::fs::write(
        &path,
        r#"{"camera": {"origin": [3, 0, 1], "target": [0, 0, 1], "up": [0, 0, 1],
            "fov_deg": 1e-30, "width": 64, "height": 48},
          "cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.5}]}"#,
    )
    .unwrap();
    let out = dir.path().join("out.exr");
    common::ok(&[
        "render",
        path.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(out.exists());
}
