//! `cylaov verify` on every camera model, as a user runs it.
//!
//! - **Orthographic** (Mitsuba's `orthographic` sensor): Mitsuba's own rays are ours within
//!   the float32 bound of `verify::compare::ray_origin_size`; `scenes/orthographic.json`
//!   passes against Mitsuba with the pinhole's rule (identity, conditioning, the exact
//!   answer as arbiter), and a candidate whose distances are 0.1% long fails on every hit.
//!   These need the reference venv (skipped, saying so, without it, unless
//!   `CYLAOV_REQUIRE_VENV=1`); `compare --scene` against the committed reference does not.
//! - **Lens models** (`opencv`, `opencv_fisheye`, `equirectangular`: no Mitsuba camera):
//!   checked against the exact answer alone, with no venv at all, and the verdict says so;
//!   cylaov's f64 and f32 renders pass with measured errors, a planted 0.1% fails.

mod common;

use cylaov::geometry::{FormulaKind, Precision};
use cylaov::output::format::exr::Compression;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// `cylaov ARGS` with `CYLAOV_VENV` set to `venv`.
fn cylaov(venv: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .env("CYLAOV_VENV", venv)
        .output()
        .expect("running cylaov")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// cylaov's f64 render of `scene` with every AOV, its distances scaled by 1.001, written
/// to `out`: a candidate 0.1% off on every hit.
fn planted(scene: &Path, out: &Path) -> usize {
    let sc = cylaov::scene::load(scene).expect("scene");
    let mut img = cylaov::verify::reference::check_render(&sc, Precision::F64, FormulaKind::Stable);
    let n = img.width * img.height;
    let mut hits = 0;
    let mut d = img.f32_channel_mut("distance").expect("distance");
    for k in 0..n {
        if d[k] > 0.0 {
            d[k] = (f64::from(d[k]) * 1.001) as f32;
            hits += 1;
        }
    }
    img.write_exr(out, Compression::None).expect("write");
    hits
}

/// The one view of `verify --json`.
fn json_view(o: &Output) -> Value {
    let v: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", text(o)));
    v["views"][0].clone()
}

fn max(v: &Value, metric: &str) -> f64 {
    v["report"][metric]["all"]["max"]
        .as_f64()
        .unwrap_or_else(|| panic!("{metric} missing in {v}"))
}

/// Mitsuba's orthographic rays, from its own `sample_ray` at every pixel centre, against
/// ours (`camera.rs`: origin on the image plane through the camera origin, direction
/// `forward`): the origin's sideways distance from our ray, over the origin term of the
/// float32 bound (4 ulps of `|o| + |x| + |y| + near`), and the direction's angle.
const RAYS: &str = r#"
import json, sys, numpy as np, mitsuba as mi
mi.set_variant("scalar_rgb")
cam = json.load(open(sys.argv[2]))["camera"]
s = mi.load_file(sys.argv[1]).sensors()[0]
W, H = cam["width"], cam["height"]
o, t, up = (np.array(cam[k], float) for k in ("origin", "target", "up"))
f = (t - o) / np.linalg.norm(t - o)
left = np.cross(up, f); left /= np.linalg.norm(left)
tu = np.cross(f, left)
hw = cam["ortho_width"] / 2; hh = hw * H / W
near = cam["near_clip"]
off = ratio = along = ang = 0.0
for j in range(H):
    for i in range(W):
        r, _ = s.sample_ray(0.0, 0.5, mi.Point2f((i + 0.5) / W, (j + 0.5) / H), mi.Point2f(0.5, 0.5))
        om, dm = np.array(r.o, float), np.array(r.d, float)
        x = ((i + 0.5) / W * 2 - 1) * hw; y = (1 - (j + 0.5) / H * 2) * hh
        v = om - (o - left * x + tu * y)
        side = float(np.linalg.norm(v - v.dot(f) * f))
        off = max(off, side)
        ratio = max(ratio, side / (4 * 2.0**-24 * (np.linalg.norm(o) + abs(x) + abs(y) + near)))
        along = max(along, abs(float(v.dot(f)) - near))
        ang = max(ang, float(np.arctan2(np.linalg.norm(np.cross(dm, f)), dm.dot(f))))
print(json.dumps({"off": off, "ratio": ratio, "along": along, "angle": ang, "rays": W * H}))
"#;

#[test]
fn orthographic_rays_are_mitsubas_within_the_float32_bound() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let dir = common::fresh_dir("verify-models", "rays");
    let scene = root().join("scenes/orthographic.json");
    let xml = dir.path().join("orthographic.xml");
    common::ok(&["export-mitsuba", s(&scene), "-o", s(&xml)]);
    let out = Command::new(&py)
        .args(["-c", RAYS, s(&xml), s(&scene)])
        .output()
        .expect("python");
    assert!(out.status.success(), "{}", text(&out));
    let v: Value = serde_json::from_slice(&out.stdout).expect("json");
    eprintln!("Mitsuba's orthographic rays against ours: {v}");
    assert_eq!(v["rays"], 76_800);
    // Measured: 2.2e-6 sideways, 0.59 of the origin term (2.3 of its 4 ulps); 2.4e-8 rad;
    // the origin sits `near` (1.0) along the ray to 1.1e-6.
    let n = |k: &str| v[k].as_f64().expect(k);
    assert!(n("ratio") < 0.8, "{v}");
    assert!(n("off") < 3e-6, "{v}");
    assert!(n("angle") < 6e-8, "{v}");
    assert!(n("along") < 2e-6, "{v}");
}

#[test]
fn orthographic_scene_verifies_against_mitsuba_and_a_planted_error_fails() {
    let Some(py) = common::venv_python() else {
        return;
    };
    let venv = py.parent().and_then(Path::parent).expect("venv");
    let scene = root().join("scenes/orthographic.json");
    for (precision, dist_max) in [("f64", 8e-6), ("f32", 1.2e-5)] {
        let o = cylaov(
            venv,
            &["verify", s(&scene), "--precision", precision, "--json"],
        );
        assert_eq!(o.status.code(), Some(0), "{}", text(&o));
        let v = json_view(&o);
        eprintln!(
            "orthographic {precision}: rel distance max {:.3e}, normal max {:.4}°",
            max(&v, "rel_distance"),
            max(&v, "normal_deg")
        );
        // Measured: the same 11 333 hits in both, no mismatch; rel distance max 5.6e-6
        // (f64) and 8.5e-6 (f32), normal 0.0086° and 0.0080°: Mitsuba's float32, as on the
        // pinhole scenes (their maxima 6.5e-7 to 5.9e-5).
        let r = &v["report"];
        assert_eq!(
            (r["hits_a"].as_u64(), r["hits_b"].as_u64()),
            (Some(11_333), Some(11_333))
        );
        assert_eq!(r["same"], 11_333);
        assert_eq!(r["silhouette_mismatches"], 0);
        assert_eq!(r["seams"], 0);
        assert!(max(&v, "rel_distance") < dist_max, "{v}");
        assert!(max(&v, "normal_deg") < 0.015, "{v}");
        assert_eq!(r["conditioned"], true);
        let a = &v["arbitration"];
        assert_eq!(a["reference"], "mitsuba");
        assert_eq!(a["checked"], 11_333);
        assert_eq!(a["candidate_errors"], 0);
        assert_eq!(a["unexplained_reference_errors"], 0);
    }
    // A candidate 0.1% long: every hit is a candidate error.
    let dir = common::fresh_dir("verify-models", "ortho-planted");
    let file = dir.path().join("planted.exr");
    let hits = planted(&scene, &file);
    let o = cylaov(venv, &["verify", s(&scene), "--candidate", s(&file)]);
    let out = text(&o);
    assert_eq!(o.status.code(), Some(1), "{out}");
    assert!(
        out.contains(&format!(
            "candidate error: {hits} px off the exact answer beyond the candidate's bound (distance {hits})"
        )),
        "{out}"
    );
    assert!(!out.contains("exact answer alone"), "{out}");
}

/// `compare --scene` against the committed reference applies the float32 bounds to the
/// orthographic camera as to the pinhole (no venv needed: the reference is committed), and
/// the render agrees: the same 11 333 hits, no mismatch, errors as measured.
#[test]
fn orthographic_compare_applies_the_float32_bounds() {
    let dir = common::fresh_dir("verify-models", "ortho-compare");
    let scene = root().join("scenes/orthographic.json");
    let exr = dir.path().join("ortho.exr");
    common::ok(&[
        "render",
        s(&scene),
        "-o",
        s(&exr),
        "--aov",
        "distance,depth,normal,shape_id,part",
    ]);
    let reference = root().join("reference/orthographic.exr");
    let out = common::ok(&["compare", s(&exr), s(&reference), "--scene", s(&scene)]);
    assert!(
        out.contains("float32 conditioning bounds applied (ray error 4 ulps)"),
        "{out}"
    );
    assert!(
        out.contains("hits: A 11333, B 11333, same cylinder and part 11333"),
        "{out}"
    );
    assert!(
        out.contains("mismatches: 0 (0.0000%) silhouette, 0 (0.0000%) seam"),
        "{out}"
    );
    assert!(out.trim_end().ends_with("PASS"), "{out}");
}

/// Each lens model, with no venv at all: cylaov's f64 and f32 renders pass against the
/// exact answer and the verdict says what they were checked against; a planted 0.1% fails
/// on every hit; `--report` says it on the page.
#[test]
fn lens_models_are_checked_against_the_exact_answer_alone() {
    let dir = common::fresh_dir("verify-models", "lens");
    let no_venv = dir.path().join("no-venv");
    // Measured worst errors of the f32 kernel against the exact answer (f64: 0, both are
    // the float32 rounding of the same value): rel distance 7.8e-7 / 3.7e-7 / 2.1e-7, rel
    // depth 8.0e-7 / 3.9e-7 / 2.1e-7, normal 3.3e-4° / 1.6e-4° / 6.4e-5° (opencv,
    // opencv_fisheye, equirectangular); hits 3072 / 3069 / 3072 of 3072 pixels (the
    // fisheye's 3 rays within a hair of 90° meet the tube below the near clip).
    let measured = [
        ("opencv", 3072, 7.8e-7, 8.0e-7, 3.3e-4),
        ("opencv_fisheye", 3069, 3.7e-7, 3.9e-7, 1.6e-4),
        ("equirectangular", 3072, 2.1e-7, 2.1e-7, 6.4e-5),
    ];
    for ((name, model), (mname, hits, dist, depth, normal)) in
        common::lens_models().into_iter().zip(measured)
    {
        assert_eq!(name, mname);
        let scene = dir.path().join(format!("{name}.json"));
        std::fs::write(&scene, common::lens_test_scene(&model).to_string()).unwrap();
        let words = format!("checked against the exact answer alone: Mitsuba has no {name} camera");
        for precision in ["f64", "f32"] {
            let o = cylaov(
                &no_venv,
                &["verify", s(&scene), "--precision", precision, "--json"],
            );
            assert_eq!(o.status.code(), Some(0), "{name} {precision}: {}", text(&o));
            let v = json_view(&o);
            assert_eq!(v["status"], "pass");
            assert_eq!(v["accepted"][0], words.as_str(), "{v}");
            let r = &v["report"];
            assert_eq!(r["hits_a"], hits, "{name}");
            assert_eq!(r["hits_b"], hits, "{name}");
            assert_eq!(r["same"], hits, "{name}");
            let a = &v["arbitration"];
            assert_eq!(a["reference"], "exact");
            assert_eq!(a["checked"], hits);
            assert_eq!(a["candidate_errors"], 0);
            let (d, z, n) = (
                max(&v, "rel_distance"),
                max(&v, "rel_depth"),
                max(&v, "normal_deg"),
            );
            eprintln!(
                "{name} {precision}: rel distance {d:.3e}, rel depth {z:.3e}, normal {n:.3e}°"
            );
            if precision == "f64" {
                assert_eq!((d, z, n), (0.0, 0.0, 0.0), "{name}");
            } else {
                // 1.5× the measurement: a kernel change that loses a bit shows.
                assert!(d > 0.0 && d < 1.5 * dist, "{name}: {d}");
                assert!(z > 0.0 && z < 1.5 * depth, "{name}: {z}");
                assert!(n > 0.0 && n < 1.5 * normal, "{name}: {n}");
            }
        }
        // The table says it too, with no venv needed (nothing "could not be checked").
        let o = cylaov(&no_venv, &["verify", s(&scene)]);
        let out = text(&o);
        assert_eq!(o.status.code(), Some(0), "{out}");
        assert!(out.contains(&format!("{name} accepted: {words}")), "{out}");
        assert!(
            out.contains("candidate errors 0, ties 0 (against the exact answer alone)"),
            "{out}"
        );
        assert!(
            out.contains("1 passed, 0 failed, 0 could not be checked"),
            "{out}"
        );
        // A planted 0.1%: every hit a candidate error, on the page as in the console.
        let file = dir.path().join(format!("{name}.planted.exr"));
        assert_eq!(planted(&scene, &file), hits);
        let page = dir.path().join(format!("{name}-report"));
        let o = cylaov(
            &no_venv,
            &[
                "verify",
                s(&scene),
                "--candidate",
                s(&file),
                "--report",
                s(&page),
            ],
        );
        let out = text(&o);
        assert_eq!(o.status.code(), Some(1), "{out}");
        assert!(
            out.contains(&format!(
                "candidate error: {hits} px off the exact answer beyond the candidate's bound (distance {hits})"
            )),
            "{out}"
        );
        assert!(out.contains(&words), "{out}");
        let html = std::fs::read_to_string(page.join("index.html")).expect("page");
        assert!(html.contains(&words), "{name}: the page lacks {words:?}");
    }
}
