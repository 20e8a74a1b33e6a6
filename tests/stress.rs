//! The accuracy bar (backward stability, `error ≤ 4ε·max(1, κ)`), asserted on the stress
//! families and on the image-level stress scenes in `scenes/stress/`. Every failure prints the offending rays' inputs.

use cylaov::geometry::Kernel;
use cylaov::geometry::{Formula, Literal, Real, Stable};
use cylaov::render::{Accel, RenderOptions, Tracer, render};
use cylaov::scene::{self, Aov, Scene};
use cylaov::verify::oracle::{self, DD, Problem};
use cylaov::verify::stress::{self, Family, Record, Summary, TABLE_ORDER};
use std::path::Path;

/// Rays per parameter value: ~2 800 rays per kernel over the 7 families, ~1 s.
const RAYS: usize = 32;

fn run(families: &[Family], kernels: &[Kernel]) -> Vec<Record> {
    families
        .iter()
        .flat_map(|&f| stress::run_family(f, RAYS, kernels))
        .collect()
}

fn table(records: &[Record]) -> Vec<Summary> {
    let s = stress::summarise(records);
    println!("{}", stress::TABLE_HEADER);
    for row in &s {
        println!("{row}");
    }
    s
}

/// The first few records that break a rule, with their inputs, for the failure message.
fn offenders(records: &[Record], bad: impl Fn(&Record) -> bool) -> String {
    let bad: Vec<&Record> = records.iter().filter(|r| bad(r)).collect();
    let mut s = format!("{} offending rays; first ones:\n", bad.len());
    for r in bad.iter().take(5) {
        s.push_str(&format!(
            "  {} {} param={:e}\n    cylinder={:?}\n    origin={:?} dir={:?} tmin={}\n    oracle={:?}\n    got={:?}\n    kappa_t={:e} kappa_n={:e} band_hit={} band_branch={} err_t/eps={:e} err_n={:e}\n",
            r.case.family,
            r.kernel,
            r.case.param,
            r.case.cyl,
            r.case.origin,
            r.case.dir,
            r.case.tmin,
            r.oracle.map(|h| (h.t.to_f64(), h.surface)),
            r.got,
            r.analysis.kappa_t,
            r.analysis.kappa_n,
            r.analysis.band_hit,
            r.analysis.band_branch,
            r.err_t,
            r.err_n,
        ));
    }
    s
}

/// Zero NaN/inf, no wrong hit/miss outside the band, distance ≤ 4ε·max(1, κ), normal
/// ≤ max(16ε·max(1, t/r), 4ε·κ_n) (the `viol_*` flags of `stress::measure`).
fn assert_bar(records: &[Record]) {
    let nonfinite = |r: &Record| r.nonfinite;
    assert!(
        !records.iter().any(nonfinite),
        "NaN/inf: {}",
        offenders(records, nonfinite)
    );
    let wrong = |r: &Record| r.wrong;
    assert!(
        !records.iter().any(wrong),
        "wrong hit/miss outside the tangency band: {}",
        offenders(records, wrong)
    );
    let vt = |r: &Record| r.viol_t;
    assert!(
        !records.iter().any(vt),
        "distance error > 4 eps max(1, kappa): {}",
        offenders(records, vt)
    );
    let vn = |r: &Record| r.viol_n;
    assert!(
        !records.iter().any(vn),
        "normal error > max(16 eps max(1, t/r), 4 eps kappa_n): {}",
        offenders(records, vn)
    );
}

#[test]
fn stable_f64_meets_the_bar_in_every_family() {
    let records = run(&Family::ALL, &[Kernel::STABLE_F64]);
    let summary = table(&records);
    assert_bar(&records);
    // Away from tangency the bar is the plain 4-ulp bound. Our κ is a worst case summed
    // over the inputs (≥ 2 for any hit: |d| alone moves t by ε·t, and |oc| ≥ t - r - h), so
    // the bar's "well-conditioned: κ ≤ 2" is our κ ≤ 3. Check it is met on many rays, so the κ-widened bound is
    // not what carries the test.
    let well: Vec<&Record> = records
        .iter()
        .filter(|r| !r.analysis.band() && r.err_t.is_finite() && r.analysis.kappa_t <= 3.0)
        .collect();
    assert!(
        well.len() > 200,
        "only {} well-conditioned hits",
        well.len()
    );
    let over = |r: &Record| !r.analysis.band() && r.analysis.kappa_t <= 3.0 && r.err_ulps > 4.0;
    assert!(
        !records.iter().any(over),
        "over 4 ulps at kappa <= 3: {}",
        offenders(&records, over)
    );
    // The band is a sliver in f64, not a hiding place.
    for s in &summary {
        assert!(
            (s.band as f64) < 0.2 * s.rays as f64,
            "{}: {} of {} rays in the band",
            s.family,
            s.band,
            s.rays
        );
    }
}

#[test]
fn stable_f32_meets_the_bar_in_grazing_near_axis_inside_rims_input() {
    let families = [
        Family::Grazing,
        Family::NearAxis,
        Family::Inside,
        Family::Rims,
        Family::Input,
    ];
    let records = run(&families, &[Kernel::STABLE_F32]);
    table(&records);
    assert_bar(&records);
}

/// f32 far/scale: the κ bar holds too, but its meaning changes with distance: the band
/// (rays whose hit/miss f32 inputs cannot decide) grows like 8·ε₃₂·D/r, and the normal
/// error like ε₃₂·D/r. These are the measured numbers docs/accuracy.md quotes.
#[test]
fn stable_f32_far_and_scale_measured_bounds() {
    let records = run(&[Family::Far, Family::Scale], &[Kernel::STABLE_F32]);
    let summary = table(&records);
    assert_bar(&records);
    // Measured (seeded, so the same every run): far 33 eps32 of distance at kappa 32, and
    // normals up to 42 eps32·t/r (2.5 rad at D = 1e6: the hit point's offset from the axis,
    // ou + t·du, is resolved to eps32·D, here 0.06 r); scale 21 eps32 at kappa 86 (a grazing
    // hit), 20 eps32 of normal at kappa_n. The bar holds (assert_bar above); these pin the
    // measured sizes so a regression shows.
    let (far, scale) = (&summary[0], &summary[1]);
    assert!(far.t_max <= 64.0, "far: distance error {} eps32", far.t_max);
    assert!(far.n_units_max <= 64.0, "far normal {}", far.n_units_max);
    assert!(far.t_ratio_max <= 2.0, "far: err/kappa {}", far.t_ratio_max);
    assert!(
        scale.t_ratio_max <= 2.0,
        "scale: err/kappa {}",
        scale.t_ratio_max
    );
    assert!(
        scale.n_units_max <= 32.0,
        "scale normal {}",
        scale.n_units_max
    );
    // Scale is benign in f32 (floats are scale invariant, the frame is centred): no band.
    assert_eq!(scale.band, 0);
    // Far: at D = 1e7 radii most rays are in the f32 band (8·6e-8·1e7 ≈ 5 radii); at
    // D ≤ 1e3 almost none. This is the cause docs/accuracy.md explains (remedy: f64).
    let band_at = |d: f64| {
        let rs: Vec<&Record> = records
            .iter()
            .filter(|r| r.case.family == Family::Far && r.case.param == d)
            .collect();
        rs.iter().filter(|r| r.analysis.band()).count() as f64 / rs.len() as f64
    };
    assert!(band_at(1e7) > 0.5, "band at 1e7: {}", band_at(1e7));
    assert!(band_at(1e3) < 0.1, "band at 1e3: {}", band_at(1e3));
}

/// The table must not be vacuous: the literal kernels' known failures show up.
#[test]
fn literal_failures_are_reported() {
    let records = run(&[Family::Far, Family::Grazing], &TABLE_ORDER);
    let summary = table(&records);
    let get = |f: Family, k: Kernel| {
        summary
            .iter()
            .find(|s| s.family == f && s.kernel == k)
            .expect("row")
    };
    let (lit, stab) = (
        get(Family::Far, Kernel::LITERAL_F32),
        get(Family::Far, Kernel::STABLE_F32),
    );
    // Literal f32 forms o - c in f32: at 1e7 radii the cylinder is lost.
    assert!(lit.wrong > 10, "literal f32 far wrong = {}", lit.wrong);
    assert!(
        lit.t_max > 100.0 * stab.t_max,
        "literal {} vs stable {}",
        lit.t_max,
        stab.t_max
    );
    assert!(lit.viol_t > 0 && lit.viol_n > 0);
    // The axis-point normal quadratic of the textbook formulas has a double root: NaN normals.
    assert!(get(Family::Grazing, Kernel::LITERAL_F64).nonfinite > 0);
    assert!(get(Family::Grazing, Kernel::LITERAL_F32).nonfinite > 0);
    assert_eq!(get(Family::Grazing, Kernel::STABLE_F64).nonfinite, 0);
}

/// Scene files are read exactly (serde_json's `float_roundtrip`): a one-ulp misread of a
/// coordinate at 1e12 would be an error of 1e-4 world units before any kernel runs.
#[test]
fn scene_numbers_are_read_exactly() {
    // Every binade from 2^-20 to 2^38 (up to ~5.5e11) and just below 1e12, both signs, random
    // mantissas: all 53 bits matter, and most so at the large magnitudes.
    let mut rng = cylaov::rng::SplitMix64::new(7);
    let (mut read, mut large) = (0, 0);
    for k in 0..20_000 {
        let bits = rng.next_u64();
        let mantissa = 1.0 + (bits >> 12) as f64 / (1u64 << 52) as f64;
        let x = if k % 10 == 0 {
            1e12 - mantissa * 1e3 // the top of the accepted range
        } else {
            mantissa * 2f64.powi((bits % 59) as i32 - 20)
        };
        let x = if bits & (1 << 11) != 0 { -x } else { x };
        let text = format!(
            "{{\"camera\": {{\"origin\": [{x:?}, 0, 0], \"target\": [0, 1, 0], \"up\": [0, 0, 1], \
             \"fov_deg\": 40, \"width\": 4, \"height\": 4}}, \"cylinders\": [{{\"p0\": [0, 0, 0], \"p1\": [0, 0, 1], \"radius\": 1}}]}}"
        );
        let s = scene::parse(&text).unwrap_or_else(|e| panic!("{x:?} rejected: {e}"));
        assert_eq!(
            s.camera.origin.x, x,
            "{x:?} read as {:?}",
            s.camera.origin.x
        );
        read += 1;
        large += usize::from(x.abs() > 1e9);
    }
    assert_eq!(read, 20_000);
    assert!(large > 2_000, "only {large} values above 1e9");
}

// ---- image-level stress scenes --------------------------------------------------------------

/// Every scene in `scenes/stress/` (`stress_scene_list_is_complete` checks): the first five
/// were made for the stability issue; `far_narrow` and `grazing` moved here from `scenes/`
/// because Mitsuba's float32 is the inaccurate side on them (far from the origin, or radius ≫ 1e3).
const SCENES: [&str; 7] = [
    "far_tiny_fov",
    "inside_tube",
    "along_axis",
    "far_offset",
    "huge_radius",
    "far_narrow",
    "grazing",
];

#[test]
fn stress_scene_list_is_complete() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/stress");
    let mut found: Vec<String> = std::fs::read_dir(&dir)
        .expect("scenes/stress")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .filter_map(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    found.sort();
    let mut listed: Vec<String> = SCENES.iter().map(|s| s.to_string()).collect();
    listed.sort();
    assert_eq!(
        found, listed,
        "every scenes/stress/*.json must be in SCENES"
    );
}

fn load(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/stress")
        .join(format!("{name}.json"));
    scene::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Speckle: a pixel whose 8 neighbours all agree on one id (0 = miss) different from its
/// own. An isolated miss inside a surface is a hole; an isolated hit or other id, a speckle.
fn speckles(ids: &[u32], w: usize, h: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let me = ids[y * w + x];
            let n0 = ids[(y - 1) * w + x - 1];
            let all_same = (0..9)
                .filter(|&k| k != 4)
                .all(|k| ids[(y + k / 3 - 1) * w + x + k % 3 - 1] == n0);
            if all_same && n0 != me {
                out.push((x, y));
            }
        }
    }
    out
}

/// Render `name` with kernel `F` in `T`; return every broken rule: NaN, hole or speckle,
/// and per pixel a different hit from the oracle's (except on silhouettes, as in `cylaov compare`) or an
/// error over the bar.
fn scene_failures<T: Real, F: Formula>(name: &str) -> Vec<String> {
    let sc = load(name);
    let kernel = Kernel::of::<T, F>();
    let opts = RenderOptions {
        precision: kernel.precision,
        formula: kernel.formula,
        ..RenderOptions::new(vec![Aov::Distance, Aov::Normal, Aov::ShapeId])
    };
    let img = render(&sc, &opts).image;
    let (w, h) = (img.width, img.height);
    let mut failures = Vec::new();
    if img.non_finite_count() > 0 {
        failures.push(format!("{} NaN/inf values", img.non_finite_count()));
    }
    let ids = img.u32_channel("shape_id").expect("ids");
    for (x, y) in speckles(&ids.to_vec(), w, h) {
        failures.push(format!("({x},{y}) speckle/hole"));
    }
    let hits = ids.iter().filter(|&&i| i != 0).count();
    assert!(
        hits > w * h / 20,
        "{name}: only {hits} hits, scene not exercised"
    );

    // Per pixel against the oracle, with the rays the renderer uses.
    let tracer = Tracer::<T, F>::new(&sc, Accel::Bvh);
    let cam = tracer.camera;
    let eps = kernel.eps();
    let mut oracle_ids = vec![0u32; w * h];
    let mut checks = Vec::new();
    for j in 0..h {
        for i in 0..w {
            let d = cam.ray_dir(i as u32, j as u32);
            let cos = d.dot(cam.forward);
            let (tmin, tmax) = (sc.camera.near_clip / cos, sc.camera.far_clip / cos);
            let seen = stress::dir_seen(kernel, d);
            let best = sc
                .cylinders
                .iter()
                .enumerate()
                .filter_map(|(k, c)| {
                    let p = Problem::new(c, cam.origin, seen);
                    oracle::intersect(&p, DD::new(tmin), DD::new(tmax)).map(|hit| (k, p, hit))
                })
                .min_by(|a, b| a.2.t.partial_cmp(&b.2.t).expect("finite t"));
            if let Some((k, _, _)) = best {
                oracle_ids[j * w + i] = sc.cylinders[k].id;
            }
            checks.push((i, j, d, tmin, tmax, best, tracer.trace(d)));
        }
    }
    let silhouette = |x: usize, y: usize| {
        let c = (ids[y * w + x], oracle_ids[y * w + x]);
        (y.saturating_sub(1)..(y + 2).min(h)).any(|yy| {
            (x.saturating_sub(1)..(x + 2).min(w))
                .any(|xx| ids[yy * w + xx] != c.0 || oracle_ids[yy * w + xx] != c.1)
        })
    };
    for (i, j, d, tmin, tmax, best, got) in checks {
        let got_id = got.map_or(0, |g| sc.cylinders[g.index as usize].id);
        if got_id != oracle_ids[j * w + i] {
            if !silhouette(i, j) {
                failures.push(format!(
                    "({i},{j}) id {got_id} vs oracle {}",
                    oracle_ids[j * w + i]
                ));
            }
            continue;
        }
        let (Some((_, p, o)), Some(g)) = (best, got) else {
            continue;
        };
        let t = g.hit.t.to_f64();
        let err_t = (DD::new(t) - o.t).abs().to_f64() / (eps * o.t.to_f64());
        let n = tracer.normal(d, &g);
        let want = if g.hit.surface == o.surface {
            o.normal
        } else {
            oracle::normal_at(&p, o.t, g.hit.surface)
        };
        let err_n = oracle::angle(n, want.to_f64());
        let r = sc.cylinders[g.index as usize].radius;
        let n_bound = 16.0 * eps * (o.t.to_f64() / r).max(1.0);
        if err_t <= 4.0 && err_n <= n_bound && g.hit.surface == o.surface {
            continue;
        }
        // Only now pay for κ and the band.
        let a = oracle::analyse(&p, tmin, tmax, eps);
        let ok = a.band()
            || (err_t <= 4.0 * a.kappa_t.max(1.0)
                && err_n <= n_bound.max(4.0 * eps * a.kappa_n)
                && g.hit.surface == o.surface);
        if !ok {
            failures.push(format!(
                "({i},{j}) d={d:?} t={t} oracle={:?} err_t/eps={err_t:e} kappa={:e} err_n={err_n:e} kappa_n={:e}",
                (o.t.to_f64(), o.surface),
                a.kappa_t,
                a.kappa_n
            ));
        }
    }
    failures
}

fn assert_clean<T: Real>() {
    for name in SCENES {
        let f = scene_failures::<T, Stable>(name);
        assert!(
            f.is_empty(),
            "{name} stable/{}: {} failures, e.g. {:#?}",
            T::NAME,
            f.len(),
            &f[..f.len().min(5)]
        );
    }
}

#[test]
fn stress_scenes_stable_f64() {
    assert_clean::<f64>();
}

#[test]
fn stress_scenes_stable_f32() {
    assert_clean::<f32>();
}

/// The scene check can fail: the literal kernels break on these scenes.
#[test]
fn stress_scenes_catch_the_literal_kernel() {
    for (name, min) in [("far_offset", 100), ("huge_radius", 100), ("along_axis", 1)] {
        let f = scene_failures::<f32, Literal>(name);
        println!("{name} literal-f32: {} failures", f.len());
        assert!(
            f.len() >= min,
            "{name}: literal f32 only {} failures",
            f.len()
        );
    }
    let f = scene_failures::<f64, Literal>("along_axis");
    println!("along_axis literal-f64: {} failures", f.len());
    assert!(!f.is_empty());
}

/// The speckle detector itself: an isolated miss and an isolated foreign id are caught, a
/// clean edge is not.
#[test]
fn speckle_detector_finds_holes() {
    let (w, h) = (6, 5);
    let mut ids = vec![1u32; w * h];
    for y in 0..h {
        ids[y * w + 5] = 0;
    }
    assert!(speckles(&ids, w, h).is_empty());
    ids[2 * w + 2] = 0;
    assert_eq!(speckles(&ids, w, h), vec![(2, 2)]);
    ids[2 * w + 2] = 7;
    assert_eq!(speckles(&ids, w, h), vec![(2, 2)]);
}
