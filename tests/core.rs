//! End-to-end checks of the core renderer against analytic answers.

use cylaov::geometry::{FormulaKind, Precision};
use cylaov::image::AovImage;
use cylaov::render::{Accel, RenderOptions, render};
use cylaov::scene::{self, Aov, Scene};

fn scene(json: &str) -> Scene {
    match scene::parse(json) {
        Ok(s) => s,
        Err(e) => panic!("test scene rejected: {e}\n{json}"),
    }
}

fn opts(precision: Precision, formula: FormulaKind) -> RenderOptions {
    RenderOptions {
        aovs: Aov::ALL.to_vec(),
        precision,
        formula,
        accel: Accel::Tiles,
    }
}

fn all(scene: &Scene) -> AovImage {
    render(scene, &opts(Precision::F64, FormulaKind::Stable)).image
}

/// Value of an f32 channel at pixel (i, j).
fn at(img: &AovImage, ch: &str, i: usize, j: usize) -> f32 {
    img.f32_channel(ch).expect(ch)[j * img.width + i]
}

fn camera(origin: [f64; 3], target: [f64; 3], up: [f64; 3], extra: &str) -> String {
    format!(
        r#""camera": {{"origin": {origin:?}, "target": {target:?}, "up": {up:?},
            "fov_deg": 30, "width": 101, "height": 101 {extra}}}"#
    )
}

#[test]
fn camera_on_x_axis_hits_at_x_minus_r_with_normal_x() {
    for (x, r) in [(5.0, 0.5), (-7.0, 2.0), (3.0, 1e-3)] {
        let json = format!(
            r#"{{ {}, "cylinders": [{{"p0": [0,0,-1], "p1": [0,0,1], "radius": {r}}}] }}"#,
            camera([x, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "")
        );
        let img = all(&scene(&json));
        // 101 px: pixel 50's centre is exactly on the optical axis.
        let d = at(&img, "distance", 50, 50) as f64;
        assert!(
            (d - (f64::abs(x) - r)).abs() <= 1e-6 * d,
            "x={x} r={r}: distance {d}"
        );
        assert_eq!(at(&img, "depth", 50, 50), at(&img, "distance", 50, 50));
        let n = [
            at(&img, "normal.X", 50, 50),
            at(&img, "normal.Y", 50, 50),
            at(&img, "normal.Z", 50, 50),
        ];
        assert_eq!(n, [x.signum() as f32, 0.0, 0.0], "x={x}");
        let px = at(&img, "position.X", 50, 50) as f64;
        assert!(
            (px - r * x.signum()).abs() <= 1e-6 * x.abs(),
            "position {px}"
        );
        assert_eq!(img.u32_channel("shape_id").unwrap()[50 * 101 + 50], 1);
    }
}

#[test]
fn ray_down_the_axis_hits_the_cap_at_its_exact_distance() {
    let json = format!(
        r#"{{ {}, "cylinders": [{{"center": [0,0,0], "axis": [0,0,3], "height": 1.25, "radius": 0.5, "id": 7}}] }}"#,
        camera([0.0, 0.0, 10.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], "")
    );
    let img = all(&scene(&json));
    assert_eq!(at(&img, "distance", 50, 50), 8.75);
    assert_eq!(at(&img, "normal.Z", 50, 50), 1.0);
    assert_eq!(img.u32_channel("shape_id").unwrap()[50 * 101 + 50], 7);
}

#[test]
fn inside_a_tube_the_far_wall_is_hit_with_outward_normal() {
    let json = format!(
        r#"{{ {}, "cylinders": [{{"p0": [0,0,0], "p1": [0,0,1], "radius": 1, "caps": false}}] }}"#,
        camera([0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 0.0, 1.0], "")
    );
    let img = all(&scene(&json));
    assert!((at(&img, "distance", 50, 50) - 1.0).abs() < 1e-7);
    assert_eq!(
        at(&img, "normal.X", 50, 50),
        1.0,
        "outward, not flipped toward the camera"
    );
    // Every pixel of a 30° view from the axis of a unit tube of height 1 sees the wall.
    let hits = img
        .u32_channel("shape_id")
        .unwrap()
        .iter()
        .filter(|&&i| i > 0)
        .count();
    assert_eq!(hits, 101 * 101);
}

#[test]
fn near_and_far_clip_cut_on_camera_space_z() {
    let base = |extra: &str| {
        format!(
            r#"{{ {}, "cylinders": [{{"p0": [0,0,-1], "p1": [0,0,1], "radius": 1}}] }}"#,
            camera([5.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], extra)
        )
    };
    // Default clip: the front wall at 4.
    assert!((at(&all(&scene(&base(""))), "distance", 50, 50) - 4.0).abs() < 1e-6);
    // Near plane inside the solid cylinder: we see its back wall from inside, at 6.
    let img = all(&scene(&base(r#", "near_clip": 4.5"#)));
    assert!((at(&img, "distance", 50, 50) - 6.0).abs() < 1e-6);
    assert_eq!(at(&img, "normal.X", 50, 50), -1.0);
    // Far plane before the front wall: nothing.
    let img = all(&scene(&base(r#", "far_clip": 3.9"#)));
    assert_eq!(
        img.u32_channel("shape_id")
            .unwrap()
            .iter()
            .filter(|&&i| i > 0)
            .count(),
        0
    );
    // Clipping is on z, not distance: a pixel off-axis whose hit has z < far < distance is kept.
    let img = all(&scene(&base(r#", "far_clip": 4.01"#)));
    let (z, d) = (at(&img, "depth", 50, 30), at(&img, "distance", 50, 30));
    assert!(z > 0.0 && z <= 4.01 && d > z, "z {z}, distance {d}");
}

#[test]
fn image_is_not_mirrored_or_flipped() {
    // Looking along +y with z up: image right is +x, image top is +z (Mitsuba's look-at frame).
    let json = format!(
        r#"{{ {}, "cylinders": [
            {{"p0": [3,0,2], "p1": [3,0,3], "radius": 0.5, "id": 1}},
            {{"p0": [-3,0,-3], "p1": [-3,0,-2], "radius": 0.5, "id": 2}}
        ] }}"#,
        camera([0.0, -20.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "")
    );
    let img = all(&scene(&json));
    let ids = img.u32_channel("shape_id").unwrap();
    let quadrant = |id: u32| {
        let (mut right, mut top, mut n) = (0, 0, 0);
        for (k, _) in ids.iter().enumerate().filter(|(_, v)| **v == id) {
            n += 1;
            right += (k % 101 > 50) as usize;
            top += (k / 101 < 50) as usize;
        }
        (n, right, top)
    };
    let (n1, r1, t1) = quadrant(1);
    assert!(
        n1 > 20 && r1 == n1 && t1 == n1,
        "id 1 (+x, +z) must be top right: {n1} {r1} {t1}"
    );
    let (n2, r2, t2) = quadrant(2);
    assert!(
        n2 > 20 && r2 == 0 && t2 == 0,
        "id 2 (-x, -z) must be bottom left: {n2} {r2} {t2}"
    );
}

/// Seeded scene of `n` random cylinders seen from outside.
fn random_scene(n: usize, seed: u64) -> Scene {
    let mut rng = cylaov::rng::SplitMix64::new(seed);
    let mut rnd = move || rng.unit();
    let cyl: Vec<String> = (0..n)
        .map(|_| {
            let c = [rnd() * 8.0 - 4.0, rnd() * 8.0 - 4.0, rnd() * 8.0 - 4.0];
            let a = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5];
            format!(
                r#"{{"center": {c:?}, "axis": {a:?}, "height": {}, "radius": {}, "caps": {}}}"#,
                0.2 + rnd() * 2.0,
                0.05 + rnd() * 0.4,
                rnd() < 0.7
            )
        })
        .collect();
    scene(&format!(
        r#"{{"camera": {{"origin": [9, -12, 6], "target": [0, 0, 0], "up": [0, 0, 1], "fov_deg": 45,
            "width": 160, "height": 120}}, "cylinders": [{}]}}"#,
        cyl.join(",")
    ))
}

/// Per-pixel comparison where both hit the same cylinder; returns (max rel distance error,
/// the same away from silhouettes, max normal difference away from silhouettes in units of max(1, distance/r), pixels compared, id mismatches).
fn diff(a: &AovImage, b: &AovImage, sc: &Scene) -> (f64, f64, f64, usize, usize) {
    let (ia, ib) = (
        a.u32_channel("shape_id").unwrap(),
        b.u32_channel("shape_id").unwrap(),
    );
    let (da, db) = (
        a.f32_channel("distance").unwrap(),
        b.f32_channel("distance").unwrap(),
    );
    let (na, nb) = (
        a.vec3_channel("normal").unwrap(),
        b.vec3_channel("normal").unwrap(),
    );
    let (mut rel, mut rel_inner, mut nrm, mut n, mut mism) = (0f64, 0f64, 0f64, 0, 0);
    for k in 0..ia.len() {
        if ia[k] != ib[k] {
            mism += 1;
            continue;
        }
        if ia[k] == 0 {
            continue;
        }
        n += 1;
        // Silhouette pixels graze the surface: there `t` is ill-conditioned (the accuracy bar
        // bounds them by backward stability, tested in tests/stress.rs); skip them for normals.
        let (w, h) = (a.width as i64, a.height as i64);
        let (x, y) = ((k as i64) % w, (k as i64) / w);
        let silhouette = (-1..=1)
            .flat_map(|dy| (-1..=1).map(move |dx| (x + dx, y + dy)))
            .any(|(u, v)| u < 0 || v < 0 || u >= w || v >= h || ib[(v * w + u) as usize] != ib[k]);
        let e = ((da[k] - db[k]) as f64 / db[k] as f64).abs();
        rel = rel.max(e);
        let r = sc.cylinders[ia[k] as usize - 1].radius;
        let scale = f64::max(1.0, db[k] as f64 / r);
        if !silhouette {
            rel_inner = rel_inner.max(e);
        }
        for c in (0..3).filter(|_| !silhouette) {
            nrm = nrm.max((na[c][k] - nb[c][k]).abs() as f64 / scale);
        }
    }
    (rel, rel_inner, nrm, n, mism)
}

#[test]
fn literal_and_stable_agree_and_f32_matches_f64_on_ordinary_scenes() {
    for seed in [1, 2, 3] {
        let sc = random_scene(60, seed);
        let reference = render(&sc, &opts(Precision::F64, FormulaKind::Stable)).image;
        assert_eq!(reference.non_finite_count(), 0);
        // f64 literal: same answers to 1e-9 relative distance; the literal
        // normal quadratic has a double root, so its normal is only good to ~sqrt(ε).
        let lit = render(&sc, &opts(Precision::F64, FormulaKind::Literal)).image;
        let (rel, _, _, n, mism) = diff(&lit, &reference, &sc);
        assert!(n > 3000, "seed {seed}: too few hits ({n}) to mean anything");
        assert!(
            rel <= 1e-9,
            "seed {seed}: literal vs stable f64 distance {rel:e}"
        );
        assert!(mism <= n / 1000, "seed {seed}: {mism} id mismatches");
        // f32 stable: 1e-5 everywhere, silhouettes included. The literal f32
        // kernel cancels catastrophically (2e-5 inside, 2e-4 on silhouettes here): that is
        // what it is kept to show, in `cylaov stress` and `cylaov bench`.
        let img = render(&sc, &opts(Precision::F32, FormulaKind::Stable)).image;
        let (rel, _, nrm, _, mism) = diff(&img, &reference, &sc);
        assert!(rel <= 1e-5, "seed {seed}: stable f32 distance {rel:e}");
        assert_eq!(img.non_finite_count(), 0, "stable f32 produced NaN/inf");
        // The normal's bound: 16ε·max(1, distance/r) with f32's ε.
        let bound = 16.0 * f32::EPSILON as f64 / 2.0;
        assert!(
            nrm <= bound,
            "seed {seed}: stable f32 normal diff {nrm:e} (scaled)"
        );
        assert!(mism <= n / 1000, "seed {seed}: {mism} id mismatches");
    }
}

#[test]
fn only_requested_aovs_are_stored() {
    let sc = random_scene(5, 9);
    let img = render(&sc, &RenderOptions::new(vec![Aov::Depth])).image;
    let names: Vec<&str> = img.names();
    assert_eq!(names, ["depth"]);
    let img = render(&sc, &RenderOptions::new(vec![Aov::ShapeId, Aov::Normal])).image;
    let names: Vec<&str> = img.names();
    assert_eq!(names, ["normal.X", "normal.Y", "normal.Z", "shape_id"]);
}

#[test]
fn exr_round_trip_keeps_names_types_and_bits() {
    let sc = random_scene(20, 4);
    let img = render(&sc, &opts(Precision::F64, FormulaKind::Stable)).image;
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-core-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let path = dir.join("rt.exr");
    img.write_exr(&path, cylaov::output::format::exr::Compression::Zip)
        .unwrap();
    let back = AovImage::read_exr(&path).unwrap();
    assert_eq!((back.width, back.height), (160, 120));
    for name in img.names() {
        assert_eq!(back.channel(name), img.channel(name), "channel {name}");
    }
}

#[test]
fn direct_uncompressed_writer_reads_back_bit_exact_with_the_exr_crate() {
    let sc = random_scene(30, 5);
    let img = render(&sc, &opts(Precision::F32, FormulaKind::Stable)).image;
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-raw-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let path = dir.join("raw.exr");
    img.write_exr(&path, cylaov::output::format::exr::Compression::None)
        .unwrap();
    let back = AovImage::read_exr(&path).unwrap();
    assert_eq!((back.width, back.height), (img.width, img.height));
    assert_eq!(back.names().len(), img.names().len());
    for name in img.names() {
        assert_eq!(back.channel(name), img.channel(name), "channel {name}");
    }
}

#[test]
fn tiles_and_bvh_give_identical_images_across_thread_counts() {
    for (n, seed, inside, far_cut) in [
        (1, 11, false, false),
        (40, 12, false, false),
        (400, 13, false, false),
        (400, 14, true, false),
        (400, 15, false, true),
    ] {
        let mut sc = random_scene(n, seed);
        if inside {
            // Camera among the cylinders: boxes reach behind it and span the whole screen.
            sc.camera.origin = glam::DVec3::new(0.3, -0.2, 0.1);
            sc.camera.target = glam::DVec3::new(1.0, 2.0, 0.5);
        }
        if far_cut {
            // The far plane through the middle of the scene: hits at the clip range's end,
            // where tiles and BVH must round the same range the same way.
            sc.camera.far_clip = sc.camera.origin.distance(sc.camera.target);
        }
        for precision in [Precision::F32, Precision::F64] {
            // Tiles trace packets of eight rays (AVX where the CPU has it), the BVH one ray
            // at a time through the scalar kernel: the same bits either way.
            let with = |accel: Accel, threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let o = RenderOptions {
                    accel,
                    ..opts(precision, FormulaKind::Stable)
                };
                pool.install(|| render(&sc, &o).image)
            };
            let reference = with(Accel::Bvh, 1);
            if far_cut {
                // The cut matters: many hits lie just in front of the far plane, where
                // the clip range's rounding decides hit or miss.
                let far = sc.camera.far_clip as f32;
                let depth = reference.f32_channel("depth").unwrap();
                let at_plane = depth.iter().filter(|&&z| z > 0.9 * far).count();
                assert!(at_plane > 100, "{at_plane} pixels near the far plane");
            }
            assert!(
                n == 1
                    || reference
                        .u32_channel("shape_id")
                        .unwrap()
                        .iter()
                        .any(|&i| i > 0)
            );
            for (accel, threads) in [
                (Accel::Bvh, 2),
                (Accel::Tiles, 1),
                (Accel::Tiles, 2),
                (Accel::Tiles, 3),
                (Accel::Frustum, 1),
                (Accel::Frustum, 3),
            ] {
                let img = with(accel, threads);
                for name in reference.names() {
                    assert!(
                        img.channel(name) == reference.channel(name),
                        "{n} cylinders, {precision:?}, {accel:?}, {threads} threads: {name} differs",
                    );
                }
            }
        }
    }
}

#[test]
fn cylinders_straddling_the_camera_plane_and_empty_scenes() {
    // Pipes running along the view direction past the camera: their boxes reach behind it,
    // so the tile path clips them at the near plane; the answer must equal the BVH's.
    let mut pipes = Vec::new();
    for k in 0..60 {
        let (x, y) = (((k % 8) as f64 - 3.5) * 0.7, ((k / 8) as f64 - 3.5) * 0.6);
        pipes.push(format!(
            r#"{{"p0": [{x}, -5, {y}], "p1": [{x}, 30, {}], "radius": 0.2, "caps": {}}}"#,
            y * 0.5,
            k % 2 == 0
        ));
    }
    let json = format!(
        r#"{{"camera": {{"origin": [0.1, 0, 0.05], "target": [0, 1, 0], "up": [0, 0, 1],
            "fov_deg": 90, "width": 96, "height": 64, "near_clip": 0.05}},
            "cylinders": [{}] }}"#,
        pipes.join(",")
    );
    let sc = scene(&json);
    let with = |accel: Accel| {
        render(
            &sc,
            &RenderOptions {
                accel,
                ..opts(Precision::F64, FormulaKind::Stable)
            },
        )
        .image
    };
    let (tiles, bvh) = (with(Accel::Tiles), with(Accel::Bvh));
    assert_eq!(tiles, with(Accel::Frustum));
    assert!(
        tiles
            .u32_channel("shape_id")
            .unwrap()
            .iter()
            .filter(|&&i| i > 0)
            .count()
            > 96 * 64 / 2
    );
    assert_eq!(tiles, bvh);
    // No cylinders at all: every pixel a miss, with either structure.
    let empty = scene(&format!(
        r#"{{ {}, "cylinders": [] }}"#,
        camera([0.0, -5.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "")
    ));
    for accel in [Accel::Tiles, Accel::Bvh, Accel::Frustum] {
        let img = render(
            &empty,
            &RenderOptions {
                accel,
                ..opts(Precision::F32, FormulaKind::Stable)
            },
        )
        .image;
        assert!(img.u32_channel("shape_id").unwrap().iter().all(|&i| i == 0));
    }
}
