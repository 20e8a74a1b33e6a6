//! Every scene in `scenes/` rendered by cylaov (stable kernel, f64 and f32) against its
//! committed Mitsuba 3.9.1 `scalar_rgb` reference in `reference/`, through the check that
//! `cylaov verify` and `batch --verify-fraction` run (`verify::reference::check_against`:
//! identity by cylinder and part, the exact answer as arbiter), at tighter bounds.
//!
//! **What the bounds measure.** At every worst pixel we checked against an independent
//! float64 evaluation of the same pixel ray, cylaov (f64) agrees with it to the float32
//! storage rounding (≤ 3e-8 relative distance, < 1e-4 degrees), and Mitsuba is the side that
//! is off: it builds its camera frame and rays in float32 and moves them into each shape's
//! object space in float32, so its hit carries an input error of about
//! ε₃₂·|ray origin - shape| (ε₃₂ = 6e-8), which grazing incidence amplifies by the
//! condition number κ ≈ 1/cos(incidence). The maximum over a scene's pixels is therefore
//! set by its most grazing pixel, while the median and p99 sit at a few float32 ulps.
//! Mitsuba's floor measured on a 200-cylinder scene is 8e-6 relative distance and 0.031°;
//! the scenes here reach (f64 / f32 kernels, max; references re-rendered with the `part`
//! channel on this machine):
//!
//! | scene | rel distance | rel depth | normal ° | mismatches |
//! |---|---|---|---|---|
//! | asymmetric | 6.5e-7 / 6.3e-7 | 5.8e-7 / 6.8e-7 | 0.0010 / 0.0011 | 0 |
//! | axis_view | 1.0e-5 / 9.3e-6 | 1.0e-5 / 9.4e-6 | 0.0020 / 0.0018 | 0 |
//! | cluster | 5.0e-6 / 9.1e-6 | 5.2e-6 / 9.2e-6 | 0.029 / 0.051 | 0 |
//! | far_camera | 1.7e-6 / 1.9e-6 | 1.7e-6 / 1.9e-6 | 0.037 / 0.041 | 0 |
//! | fov_diagonal | 3.7e-6 / 4.2e-6 | 3.6e-6 / 4.2e-6 | 0.0080 / 0.0092 | 0 |
//! | fov_smaller_portrait | 4.4e-6 / 6.7e-6 | 4.4e-6 / 6.7e-6 | 0.0033 / 0.0050 | 0 |
//! | grazing_fence | 8.2e-6 / 8.2e-6 | 8.2e-6 / 8.2e-6 | 0.034 / 0.033 | 0 |
//! | grazing_steep | 5.9e-5 / 2.1e-5 | 5.9e-5 / 2.1e-5 | 0.037 / 0.013 | 0 |
//! | mixed_caps | 4.3e-6 / 5.7e-6 | 4.3e-6 / 5.6e-6 | 0.0042 / 0.0041 | 0 |
//! | near_clip | 1.6e-5 / 1.8e-5 | 1.6e-5 / 1.8e-5 | 0.0018 / 0.0023 | 0 |
//! | orthographic | 5.6e-6 / 8.5e-6 | 5.6e-6 / 8.5e-6 | 0.0086 / 0.0081 | 0 |
//! | portrait_fov_y | 5.1e-6 / 1.1e-5 | 5.1e-6 / 1.1e-5 | 0.0052 / 0.011 | 0 |
//! | rim_seam | 2.7e-6 / 4.0e-6 | 2.7e-6 / 4.0e-6 | 0.031 / 0.045 | 1 seam |
//! | rims | 7.9e-6 / 8.8e-6 | 8.0e-6 / 8.8e-6 | 0.010 / 0.013 | 0 |
//! | single | 4.2e-6 / 3.2e-6 | 4.3e-6 / 3.3e-6 | 0.0029 / 0.0022 | 0 |
//! | tube_inside | 8.0e-7 / 8.7e-7 | 7.3e-7 / 8.9e-7 | 0.000025 / 0.000027 | 0 |
//!
//! `rims` (48 short cylinders and open tubes seen from above: thousands of cap and tube
//! rim pixels) has no seam mismatch; `rim_seam` (a generated view) has one pixel where
//! cylaov takes a cap and Mitsuba the side of the same rim. Where cylaov and Mitsuba
//! disagree beyond the bounds, the exact answer (double-double, the reference camera's f64
//! ray) decides, as in `cylaov verify`: cylaov must be on it within its f32 storage, and
//! Mitsuba's misses must be reference errors within its float32 bound. Two pixels of the
//! committed scenes are: `grazing_steep`'s most grazing pixel (5.9e-5 relative distance,
//! bound 1.2e-4) and `rim_seam`'s rim pixel; every other scene has none, and the test fails
//! if that changes.
//!
//! Bounds: one set for every scene, [`BOUNDS`]: the default 0.05% / 3e-5 / 0.1° tightened
//! to about 1.5× the largest measurement, plus p99 bounds at about 2× the largest p99
//! (which catch a systematic error, e.g. a half-pixel shift, long before the max does).
//! Scenes where Mitsuba's float32 is worse than that (a camera thousands of units away,
//! rods so thin that κ ≈ 100) do not belong here: they live in `scenes/stress/` and are
//! checked against the oracle (`tests/stress.rs`). `far_camera` and `grazing_fence` are the
//! milder versions kept here: a camera 300 units away with a 1° fov, and rods of radius 0.1
//! to 0.13 seen edge-on.

use cylaov::geometry::{FormulaKind, Precision};
use cylaov::image::AovImage;
use cylaov::scene;
use cylaov::verify::arbiter::Bound;
use cylaov::verify::compare::{Identity, Tolerances};
use cylaov::verify::reference::{check_against_with, check_render};
use std::path::{Path, PathBuf};

/// Pass/fail bounds of one scene: the max bounds of [`Tolerances`] and p99 bounds.
#[derive(Clone, Copy, Debug)]
struct Bounds {
    max: Tolerances,
    p99_rel: f64,
    p99_normal_deg: f64,
}

const BOUNDS: Bounds = Bounds {
    max: Tolerances {
        // Measured: no mismatch on this machine. Silhouette samples at a float32 ulp from
        // tangency may flip on another CPU: allow a few (7 of 76 800), all on silhouettes.
        max_mismatch_fraction: 1e-4,
        // Measured: no seam mismatch (cap rims seen at an angle are few pixels); the same
        // room as silhouettes.
        max_seam_fraction: 1e-4,
        // Measured max 1.8e-5 (near_clip, f32 kernel).
        rel_distance: 2.5e-5,
        rel_depth: 2.5e-5,
        // Measured max 0.051° (cluster, f32 kernel); Mitsuba's float32 floor 0.031°.
        normal_deg: 0.08,
    },
    // Measured p99 at most 7.8e-7 (grazing_fence) and 0.0077° (far_camera), f32 kernel.
    p99_rel: 1.5e-6,
    p99_normal_deg: 0.02,
};

/// Mitsuba's reference errors at [`BOUNDS`] with cylaov's f64 kernel, measured (every other
/// scene has none): `grazing_steep`'s one grazing pixel (5.9e-5 relative distance, cylaov
/// on the exact answer, see `tests/verify.rs`) and `rim_seam`'s one rim pixel, where
/// Mitsuba's ray slips between the top cap and the tube and hits the inner wall.
const REFERENCE_ERRORS: &[(&str, usize)] = &[("grazing_steep", 1), ("rim_seam", 1)];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The stems of `dir/*.EXT`, sorted.
fn stems(dir: &Path, ext: &str) -> Vec<String> {
    let mut out: Vec<String> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("reading {}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == ext))
        .filter_map(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    out.sort();
    out
}

fn check(stem: &str, precision: Precision, reference: &AovImage) -> Vec<String> {
    let scene_path = root().join("scenes").join(format!("{stem}.json"));
    let scene = scene::load(&scene_path).unwrap_or_else(|e| panic!("{stem}: {e}"));
    let img = check_render(&scene, precision, FormulaKind::Stable);
    let b = BOUNDS;
    let checked = check_against_with(&scene, &img, reference, &b.max, Bound::cylaov(precision))
        .unwrap_or_else(|e| panic!("{stem}: {e:#}"));
    let r = &checked.report;
    let tag = format!("{stem} ({precision:?})");
    let mut fails: Vec<String> = checked
        .failures
        .iter()
        .map(|f| format!("{tag}: {f}"))
        .collect();
    // The exact answer decides where the two disagree beyond the bounds: no candidate error,
    // no unexplained reference error (above), no tie, and Mitsuba's reference errors only
    // where they were measured ([`REFERENCE_ERRORS`]; the f32 kernel's own f32 storage may
    // sit a little nearer Mitsuba, so at most as many).
    let a = &checked.arbitration;
    let expected = REFERENCE_ERRORS
        .iter()
        .find(|(s, _)| *s == stem)
        .map_or(0, |e| e.1);
    let counted = a.reference_errors;
    if a.ties > 0 || counted > expected || (precision == Precision::F64 && counted != expected) {
        fails.push(format!(
            "{tag}: {counted} reference errors, {} ties (expected {expected}, 0): {:?}",
            a.ties, checked.accepted
        ));
    }
    // The reference carries shape_id and part, and so does our render: identity is exact.
    if r.identity != Identity::ShapeIdPart {
        fails.push(format!("{tag}: compared without shape_id and part"));
    }
    for (name, stat, limit) in [
        ("distance", &r.rel_distance, b.p99_rel),
        ("depth", &r.rel_depth, b.p99_rel),
        ("normal", &r.normal_deg, b.p99_normal_deg),
    ] {
        match stat.as_ref().map(|m| &m.all) {
            None => fails.push(format!("{tag}: {name} not compared")),
            Some(s) if s.p99 > limit => {
                fails.push(format!("{tag}: {name} p99 {:.3e} > {limit:.3e}", s.p99))
            }
            Some(s) if s.count == 0 || s.count != r.same => fails.push(format!(
                "{tag}: {name} measured on {} of {} pixels",
                s.count, r.same
            )),
            Some(_) => {}
        }
    }
    if r.same == 0 {
        fails.push(format!("{tag}: no pixel hits in both images"));
    }
    let max =
        |m: &Option<cylaov::verify::compare::Metric>| m.as_ref().map_or(f64::NAN, |m| m.all.max);
    let p99 =
        |m: &Option<cylaov::verify::compare::Metric>| m.as_ref().map_or(f64::NAN, |m| m.all.p99);
    let a = &checked.arbitration;
    println!(
        "{tag}: reference errors {} ({}), ties {}",
        a.reference_errors,
        a.kinds(cylaov::verify::arbiter::PixelClass::ReferenceError),
        a.ties
    );
    println!(
        "{tag}: same {} mismatches {} seams {} | rel distance max {:.2e} p99 {:.2e} | rel depth max {:.2e} | normal max {:.4}° p99 {:.4}°",
        r.same,
        r.silhouette_mismatches,
        r.seams,
        max(&r.rel_distance),
        p99(&r.rel_distance),
        max(&r.rel_depth),
        max(&r.normal_deg),
        p99(&r.normal_deg),
    );
    fails
}

#[test]
fn every_scene_matches_its_mitsuba_reference() {
    let scenes = stems(&root().join("scenes"), "json");
    let refs = stems(&root().join("reference"), "exr");
    assert!(
        scenes.len() >= 9,
        "expected the reference scenes, found {scenes:?}"
    );
    let mut fails = Vec::new();
    for stem in &scenes {
        if !refs.contains(stem) {
            fails.push(format!(
                "{stem}: no reference/{stem}.exr (render it with scripts/reference scenes/{stem}.json)"
            ));
            continue;
        }
        let path = root().join("reference").join(format!("{stem}.exr"));
        let reference = AovImage::read_exr(&path).unwrap_or_else(|e| panic!("{e:#}"));
        for precision in [Precision::F64, Precision::F32] {
            fails.extend(check(stem, precision, &reference));
        }
    }
    for stem in refs.iter().filter(|r| !scenes.contains(r)) {
        fails.push(format!("reference/{stem}.exr has no scenes/{stem}.json"));
    }
    assert!(fails.is_empty(), "\n{}", fails.join("\n"));
}

#[test]
fn references_are_small_and_complete() {
    // The whole folder stays under 10 MB; every reference has our channel names.
    let dir = root().join("reference");
    let mut total = 0;
    for stem in stems(&dir, "exr") {
        let path = dir.join(format!("{stem}.exr"));
        total += std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        let img = AovImage::read_exr(&path).unwrap_or_else(|e| panic!("{e:#}"));
        let mut names: Vec<&str> = img.names();
        names.sort();
        assert_eq!(
            names,
            [
                "depth",
                "distance",
                "normal.X",
                "normal.Y",
                "normal.Z",
                "part",
                "position.X",
                "position.Y",
                "position.Z",
                "shape_id"
            ],
            "{stem}"
        );
    }
    assert!(total < 10_000_000, "reference/ holds {total} bytes");
}
