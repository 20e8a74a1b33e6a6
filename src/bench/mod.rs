//! `cylaov bench`: run time against error, per kernel, AOV set and cylinder count.
//!
//! Scenes are generated from a fixed seed, in two families ([`Family`]):
//! - *sparse* ([`random_scene`]): `n` cylinders in a fixed cube, their size scaled by
//!   `(1000/n)^(1/2)`, so their total projected area, and so the depth complexity of the
//!   image, stays about the same at every count: the time-vs-count curve then measures the
//!   acceleration, not a scene that grows denser;
//! - *dense* ([`dense_scene`]): the same sizes at every count, so the scene does grow
//!   denser, as real clutter does (bin picking, pipe racks, forests): 100 000 cylinders
//!   hide all but a few thousand.
//!
//! Every number in a row comes from one run on this machine; compare ratios within a
//! table, not across runs.

pub mod batch_formats;
pub mod exr_writer;
pub mod load;
pub mod scaling;
pub mod scan;

use crate::accel::tiles;
use crate::geometry::Kernel;
use crate::geometry::kernel::KernelFn;
use crate::geometry::packet::{Packet, PacketFormula};
use crate::geometry::wide::LANES;
use crate::geometry::wide::{Avx2, Simd};
use crate::geometry::wide::{Lanes, Wide};
use crate::geometry::{Cylinder, Prepared, Real};
use crate::image::AovImage;
use crate::output::format::exr::Compression;
use crate::output::store::atomic::atomic_write_bytes;
use crate::render::{Accel, RenderOptions, render, render_timed};
use crate::rng::SplitMix64;
use crate::scene::camera::Camera;
use crate::scene::camera::{CameraSpec, FovAxis, Projection};
use crate::scene::{Aov, Scene, SceneFile};
use anyhow::{Context, Result, bail};
use glam::DVec3;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// `n` random cylinders at `width`×`height`, the bench's standard scene.
pub fn random_scene(n: usize, seed: u64, width: u32, height: u32) -> Scene {
    let mut rng = SplitMix64::new(seed);
    let size = (1000.0 / n.max(1) as f64).sqrt().min(4.0);
    let cylinders = (0..n)
        .map(|i| {
            let base = DVec3::new(
                rng.range(-5.0, 5.0),
                rng.range(-5.0, 5.0),
                rng.range(-5.0, 5.0),
            );
            let axis = loop {
                let a = DVec3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                );
                if a.length() > 0.1 && a.length() <= 1.0 {
                    break a.normalize();
                }
            };
            Cylinder {
                base,
                axis,
                height: rng.range(0.3, 1.5) * size,
                radius: rng.range(0.03, 0.15) * size,
                caps: rng.unit() < 0.7,
                id: i as u32 + 1,
                label: 0,
            }
        })
        .collect();
    bench_scene(DVec3::new(12.0, -16.0, 8.0), 45.0, width, height, cylinders)
}

/// A bench scene: the camera at `origin` looking at the world origin, up +z, horizontal
/// field of view `fov_deg`, Mitsuba's default clip range, depth and normal.
fn bench_scene(
    origin: DVec3,
    fov_deg: f64,
    width: u32,
    height: u32,
    cylinders: Vec<Cylinder>,
) -> Scene {
    let camera = CameraSpec {
        origin,
        target: DVec3::ZERO,
        up: DVec3::Z,
        fov_deg,
        fov_axis: FovAxis::X,
        width,
        height,
        near_clip: 0.01,
        far_clip: 10000.0,
        projection: Projection::Perspective,
    };
    Scene {
        camera,
        cameras: vec![camera],
        cylinders,
        aovs: vec![Aov::Depth, Aov::Normal],
    }
}

/// `n` cylinders of the dense family at `width`×`height`: `p0` uniform in [−10, 10]³,
/// direction uniform on the sphere, length U(0.3, 3), radius U(0.05, 0.6), 70% capped,
/// seen from (26, −30, 18) looking at the origin, up +z, 50° horizontal field of view.
pub fn dense_scene(n: usize, seed: u64, width: u32, height: u32) -> Scene {
    let mut rng = SplitMix64::new(seed);
    let cylinders = (0..n)
        .map(|i| {
            let base = DVec3::new(
                rng.range(-10.0, 10.0),
                rng.range(-10.0, 10.0),
                rng.range(-10.0, 10.0),
            );
            Cylinder {
                base,
                axis: rng.unit_vector(),
                height: rng.range(0.3, 3.0),
                radius: rng.range(0.05, 0.6),
                caps: rng.unit() < 0.7,
                id: i as u32 + 1,
                label: 0,
            }
        })
        .collect();
    bench_scene(
        DVec3::new(26.0, -30.0, 18.0),
        50.0,
        width,
        height,
        cylinders,
    )
}

crate::choice_enum! {
    /// A bench scene family (see the module doc).
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Family {
        /// Sizes shrink as the count grows: the same depth complexity at every count.
        Sparse = "sparse",
        /// The same sizes at every count: denser and denser.
        Dense = "dense",
    }
}

impl Family {
    /// `sparse` or `dense`, as `--family` spells it.
    pub fn name(self) -> &'static str {
        match self {
            Family::Sparse => "sparse",
            Family::Dense => "dense",
        }
    }

    /// The family's scene of `n` cylinders.
    pub fn scene(self, n: usize, seed: u64, width: u32, height: u32) -> Scene {
        match self {
            Family::Sparse => random_scene(n, seed, width, height),
            Family::Dense => dense_scene(n, seed, width, height),
        }
    }
}

/// Throughput of the kernel alone: one thread testing the rays of packets against their
/// cylinders, with no ray set-up, tiles, shading or output around it. It isolates what
/// f32 buys (the render as a whole also pays for memory and per-pixel work that do not
/// depend on the kernel's precision).
#[derive(Clone, Debug, Serialize)]
pub struct KernelRow {
    /// The kernel's name, e.g. `stable-f64`.
    pub kernel: String,
    /// `scalar` (one ray at a time, the BVH path; all a formula without a SIMD form has),
    /// `lanes` (packets of eight, portable code) or `avx2` (packets in AVX registers, the
    /// tile path on this CPU).
    pub form: &'static str,
    /// Million ray–cylinder tests per second.
    pub mtests_per_s: f64,
}

/// Packets of eight pixel rays across each cylinder of `scene` (four rows through its
/// projected band, eight columns around the band's centre): rays that graze, hit and miss,
/// as the renderer sees them.
fn kernel_workload<T: Real>(scene: &Scene) -> Vec<(usize, Packet<T>)> {
    let cam = Camera::new(scene.camera);
    let (w, h) = (cam.width() as i64, cam.height() as i64);
    let mut work = Vec::new();
    for (i, c) in scene.cylinders.iter().enumerate() {
        let Some(k) = tiles::project(&cam, c) else {
            continue;
        };
        for r in 0..4 {
            let j = k.y0 + (k.y1 - k.y0) * r / 3;
            let centre = if k.half.is_finite() {
                k.centre + k.slope * j as f64
            } else {
                (k.x0 + k.x1) as f64 / 2.0
            };
            let x0 = (centre as i64 - 3).clamp(0, (w - LANES as i64).max(0));
            let mut pk = Packet::<T>::EMPTY;
            for l in 0..LANES {
                let i = (x0 + l as i64).min(w - 1) as u32;
                let d = cam.ray_dir(i, j.min(h as u32 - 1));
                let len = 1.0 / d.dot(cam.forward);
                for (a, x) in pk.d.iter_mut().zip(d.to_array()) {
                    a[l] = T::from_f64(x);
                }
                pk.tmin[l] = T::from_f64(cam.spec.near_clip * len);
                pk.t[l] = T::from_f64(cam.spec.far_clip * len);
            }
            work.push((i, pk));
        }
    }
    work
}

/// Seconds for `reps` passes of `work` through form `form` of kernel `F`; returns the
/// hit count too, so the work cannot be optimised away.
#[inline(always)]
fn kernel_pass<T: Real, F: PacketFormula, W: Wide<T>>(
    tok: W::Token,
    prepared: &[Prepared<T>],
    work: &[(usize, Packet<T>)],
    reps: usize,
    scalar: bool,
) -> (f64, u64) {
    let start = Instant::now();
    let mut hits = 0u64;
    for _ in 0..reps {
        for (i, pk) in work {
            let (p, mut pk) = (&prepared[*i], *pk);
            if scalar {
                for l in 0..LANES {
                    hits += F::intersect(p, pk.dir(l), pk.tmin[l], pk.t[l]).is_some() as u64;
                }
            } else {
                hits += F::intersect_packet::<T, W>(tok, p, (*i as u32, 0), &mut pk, u8::MAX)
                    .count_ones() as u64;
            }
        }
    }
    (start.elapsed().as_secs_f64(), std::hint::black_box(hits))
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn kernel_pass_avx2<T: Simd, F: PacketFormula>(
    tok: Avx2,
    prepared: &[Prepared<T>],
    work: &[(usize, Packet<T>)],
    reps: usize,
) -> (f64, u64) {
    kernel_pass::<T, F, T::Avx>(tok, prepared, work, reps, false)
}

/// [`KernelRow`]s of kernel `F` in precision `T` on `scene`, one timing each.
fn kernel_rows_for<T: Simd, F: PacketFormula>(scene: &Scene) -> Vec<KernelRow> {
    let origin = Camera::new(scene.camera).origin;
    let prepared: Vec<Prepared<T>> = scene
        .cylinders
        .iter()
        .map(|c| Prepared::new(c, origin, F::CENTRED))
        .collect();
    let work = kernel_workload::<T>(scene);
    // A few hundredths of a second per form: passes enough to dwarf the timer and the
    // first, cold one.
    let reps = (2_000_000 / (work.len() * LANES).max(1)).max(1);
    let avx2 = Avx2::detect();
    let run = |form: &str| match (form, avx2) {
        ("scalar", _) => kernel_pass::<T, F, Lanes<T>>((), &prepared, &work, reps, true).0,
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the token says the CPU has AVX2, which the target feature requires.
        ("avx2", Some(tok)) => unsafe { kernel_pass_avx2::<T, F>(tok, &prepared, &work, reps).0 },
        _ => kernel_pass::<T, F, Lanes<T>>((), &prepared, &work, reps, false).0,
    };
    // A formula without a SIMD form runs its packets lane by lane: that is the scalar row.
    let mut forms = vec!["scalar"];
    if F::SIMD {
        forms.push("lanes");
    }
    if F::SIMD && avx2.is_some() {
        forms.push("avx2");
    }
    let tests = (work.len() * LANES * reps) as f64;
    let name = Kernel::of::<T, F>().to_string();
    forms
        .iter()
        .map(|&form| {
            let secs = run(form);
            KernelRow {
                kernel: name.clone(),
                form,
                mtests_per_s: tests / secs / 1e6,
            }
        })
        .collect()
}

/// The kernel throughput table for `kernels` on the bench's 1 000-cylinder scene. Each
/// round times every kernel and form once, and each row keeps its best round (at least
/// five): interleaved, so a slow spell of this shared machine hits all rows alike and the
/// ratios between them hold.
pub fn kernel_rows(opts: &BenchOptions) -> Vec<KernelRow> {
    let scene = random_scene(1000, opts.seed, opts.width, opts.height);
    struct Rows<'a>(&'a Scene);
    impl KernelFn for Rows<'_> {
        type Output = Vec<KernelRow>;
        fn call<T: Simd, F: PacketFormula>(self) -> Vec<KernelRow> {
            kernel_rows_for::<T, F>(self.0)
        }
    }
    let round = || -> Vec<KernelRow> {
        opts.kernels
            .iter()
            .flat_map(|&k| k.dispatch(Rows(&scene)))
            .collect()
    };
    let mut best = round();
    for _ in 1..opts.repeats.max(5) {
        for (b, r) in best.iter_mut().zip(round()) {
            b.mtests_per_s = b.mtests_per_s.max(r.mtests_per_s);
        }
    }
    best
}

/// What `bench` runs.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Scene families, each run over every count.
    pub families: Vec<Family>,
    /// Cylinder counts, each a row group.
    pub counts: Vec<usize>,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// AOV sets, each a row.
    pub aov_sets: Vec<Vec<Aov>>,
    /// Kernels, each a row.
    pub kernels: Vec<Kernel>,
    /// Timed repetitions per row; the minimum is reported (the machine is noisy).
    pub repeats: usize,
    /// Also time whole `cylaov render` processes with this executable (and read their
    /// peak memory).
    pub exe: Option<PathBuf>,
    /// Seed of the generated scenes.
    pub seed: u64,
    /// How the timed renders find their candidates (the error reference always uses tiles;
    /// both give the same bits).
    pub accel: Accel,
    /// Also keep each generated scene as `DIR/FAMILY-N.json`, to time or profile a render
    /// of it by hand.
    pub keep_scenes: Option<PathBuf>,
}

/// The AOV sets of the table: depth only, depth + normal, all.
pub fn default_aov_sets() -> Vec<Vec<Aov>> {
    vec![
        vec![Aov::Depth],
        vec![Aov::Depth, Aov::Normal],
        Aov::ALL.to_vec(),
    ]
}

/// One line of the table.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// The scene family's name.
    pub family: String,
    /// Cylinders in the scene.
    pub cylinders: usize,
    /// The kernel's name, e.g. `stable-f64`.
    pub kernel: String,
    /// The AOVs rendered, e.g. `depth+normal`.
    pub aovs: String,
    /// Parsing the scene's JSON text into a validated scene (in process).
    pub parse_ms: f64,
    /// The kernel form of every cylinder (part of the in-memory render).
    pub prepare_ms: f64,
    /// The acceleration structure: tiles or BVH (part of the in-memory render).
    pub build_ms: f64,
    /// Tracing every pixel (in-memory render), ms.
    pub trace_ms: f64,
    /// Encoding the uncompressed EXR and writing it to a file.
    pub write_ms: f64,
    /// Prepare, build, trace and write, ms (parse not included).
    pub total_ms: f64,
    /// Million primary rays per second of trace time.
    pub mrays_per_s: f64,
    /// Whole `cylaov render` process (parse, build, trace, write), when measured.
    pub process_ms: Option<f64>,
    /// Peak resident memory of that process, MiB.
    pub peak_mib: Option<f64>,
    /// Relative distance error against stable f64 where both hit the same cylinder.
    pub err_median: f64,
    /// Largest relative distance error against stable f64.
    pub err_max: f64,
    /// Pixels where this kernel and stable f64 disagree on hit/miss or cylinder.
    pub mismatches: usize,
}

impl Row {
    /// A depth+normal row: the AOV set of the Mitsuba comparison and of the figure.
    pub fn is_depth_normal(&self) -> bool {
        self.aovs == aov_names(&[Aov::Depth, Aov::Normal])
    }

    /// Prepare + build + trace: the time to the image in memory.
    pub fn render_ms(&self) -> f64 {
        self.prepare_ms + self.build_ms + self.trace_ms
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Relative distance error of `img` against `reference` (both with distance + shape_id):
/// (median, max, mismatched pixels).
pub fn distance_error(img: &AovImage, reference: &AovImage) -> (f64, f64, usize) {
    let (Some(ia), Some(ib), Some(da), Some(db)) = (
        img.u32_channel("shape_id"),
        reference.u32_channel("shape_id"),
        img.f32_channel("distance"),
        reference.f32_channel("distance"),
    ) else {
        return (f64::NAN, f64::NAN, 0);
    };
    let mut errs = Vec::new();
    let mut mismatches = 0;
    for k in 0..ia.len() {
        if ia[k] != ib[k] {
            mismatches += 1;
        } else if ia[k] != 0 {
            let e = ((da[k] as f64 - db[k] as f64) / db[k] as f64).abs();
            errs.push(if e.is_nan() { f64::INFINITY } else { e });
        }
    }
    if errs.is_empty() {
        return (0.0, 0.0, mismatches);
    }
    errs.sort_by(f64::total_cmp);
    (errs[errs.len() / 2], errs[errs.len() - 1], mismatches)
}

fn aov_names(aovs: &[Aov]) -> String {
    aovs.iter().map(|a| a.name()).collect::<Vec<_>>().join("+")
}

/// How the command line spells `v` (its listed name, not a guess from `Debug`).
fn cli_value<V: crate::choice::Choice>(v: V) -> String {
    v.choice_name().to_owned()
}

/// Time a whole `cylaov render` process; parse `peak N MiB` from its summary line.
fn time_process(
    exe: &Path,
    scene: &Path,
    out: &Path,
    kernel: Kernel,
    aovs: &[Aov],
    accel: Accel,
) -> Result<(f64, Option<f64>)> {
    // Each process writes a new file, as a render into a fresh dataset folder does:
    // replacing a large file would add the kernel's release of the old one to the
    // render's time.
    match std::fs::remove_file(out) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e)?,
        _ => {}
    }
    let start = Instant::now();
    let o = Command::new(exe)
        .arg("render")
        .arg(scene)
        .arg("-o")
        .arg(out)
        .arg("--aov")
        .arg(aovs.iter().map(|a| a.name()).collect::<Vec<_>>().join(","))
        .args(["--precision", &cli_value(kernel.precision)])
        .args(["--formula", &cli_value(kernel.formula)])
        .args(["--accel", &cli_value(accel)])
        .output()
        .with_context(|| format!("running {}", exe.display()))?;
    let elapsed = ms(start.elapsed());
    if !o.status.success() {
        bail!(
            "{} render failed: {}",
            exe.display(),
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let text = String::from_utf8_lossy(&o.stdout);
    let peak = text.trim().split(", ").find_map(|part| {
        part.strip_prefix("peak ")?
            .strip_suffix(" MiB")?
            .trim()
            .parse()
            .ok()
    });
    Ok((elapsed, peak))
}

/// Run the benchmark, calling `progress` with each finished row.
pub fn run(opts: &BenchOptions, mut progress: impl FnMut(&Row)) -> Result<Vec<Row>> {
    // Scratch files (scene JSON, EXRs), removed when `scratch` drops, also on an error.
    let scratch = tempfile::Builder::new().prefix("cylaov-bench-").tempdir()?;
    let dir = scratch.path();
    let mut rows = Vec::new();
    for (&family, &n) in opts
        .families
        .iter()
        .flat_map(|f| opts.counts.iter().map(move |n| (f, n)))
    {
        let mut scene = family.scene(n, opts.seed, opts.width, opts.height);
        let scene_path = dir.join(format!("scene-{}-{n}.json", family.name()));
        let text = serde_json::to_string(&SceneFile::from_scene(&scene))?;
        if opts.exe.is_some() {
            std::fs::write(&scene_path, &text)?;
        }
        if let Some(keep) = &opts.keep_scenes {
            let path = keep.join(format!("{}-{n}.json", family.name()));
            atomic_write_bytes(&path, text.as_bytes())
                .with_context(|| format!("writing {}", path.display()))?;
        }
        let mut parse = f64::INFINITY;
        for _ in 0..opts.repeats.max(1) {
            let t0 = Instant::now();
            let parsed = crate::scene::parse(&text)?;
            parse = parse.min(ms(t0.elapsed()));
            std::hint::black_box(parsed);
        }
        // Accuracy reference: stable f64 with distance + shape_id.
        scene.aovs = vec![Aov::Distance, Aov::ShapeId];
        let err_opts = |k: Kernel| RenderOptions {
            aovs: vec![Aov::Distance, Aov::ShapeId],
            precision: k.precision,
            formula: k.formula,
            accel: Accel::Tiles,
        };
        let reference = render(&scene, &err_opts(Kernel::STABLE_F64)).image;
        for &kernel in &opts.kernels {
            let (err_median, err_max, mismatches) =
                distance_error(&render(&scene, &err_opts(kernel)).image, &reference);
            for aovs in &opts.aov_sets {
                let ro = RenderOptions {
                    aovs: aovs.clone(),
                    precision: kernel.precision,
                    formula: kernel.formula,
                    accel: opts.accel,
                };
                let (mut prepare, mut build, mut trace, mut write) =
                    (f64::INFINITY, f64::INFINITY, f64::INFINITY, f64::INFINITY);
                for _ in 0..opts.repeats.max(1) {
                    let (r, t) = render_timed(&scene, &ro);
                    let w0 = Instant::now();
                    r.image
                        .write_exr(&dir.join("bench.exr"), Compression::None)?;
                    write = write.min(ms(w0.elapsed()));
                    prepare = prepare.min(ms(t.prepare));
                    build = build.min(ms(t.build));
                    trace = trace.min(ms(t.trace));
                }
                let (process_ms, peak_mib) = match &opts.exe {
                    Some(exe) => {
                        let mut best = (f64::INFINITY, None);
                        for _ in 0..opts.repeats.max(1) {
                            let (t, p) = time_process(
                                exe,
                                &scene_path,
                                &dir.join("proc.exr"),
                                kernel,
                                aovs,
                                opts.accel,
                            )?;
                            if t < best.0 {
                                best = (t, p);
                            }
                        }
                        (Some(best.0), best.1)
                    }
                    None => (None, None),
                };
                let row = Row {
                    family: family.name().to_string(),
                    cylinders: n,
                    kernel: kernel.to_string(),
                    aovs: aov_names(aovs),
                    parse_ms: parse,
                    prepare_ms: prepare,
                    build_ms: build,
                    trace_ms: trace,
                    write_ms: write,
                    total_ms: prepare + build + trace + write,
                    mrays_per_s: (opts.width as f64 * opts.height as f64) / (trace * 1e3),
                    process_ms,
                    peak_mib,
                    err_median,
                    err_max,
                    mismatches,
                };
                progress(&row);
                rows.push(row);
            }
        }
    }
    Ok(rows)
}

/// The table header, aligned with [`format_row`].
pub fn header() -> String {
    format!(
        "{:<6} {:>7} {:<14} {:<38} {:>7} {:>7} {:>7} {:>8} {:>8} {:>8} {:>7} {:>9} {:>8} {:>9} {:>9} {:>6}",
        "family",
        "cyl",
        "kernel",
        "aovs",
        "parse",
        "prep",
        "build",
        "trace",
        "write",
        "total",
        "Mray/s",
        "process",
        "peakMiB",
        "err_med",
        "err_max",
        "mism"
    )
}

/// One aligned table line (times in ms).
pub fn format_row(r: &Row) -> String {
    let opt = |x: Option<f64>, p: usize| x.map_or("-".to_string(), |v| format!("{v:.p$}"));
    format!(
        "{:<6} {:>7} {:<14} {:<38} {:>7.1} {:>7.1} {:>7.1} {:>8.1} {:>8.1} {:>8.1} {:>7.1} {:>9} {:>8} {:>9.1e} {:>9.1e} {:>6}",
        r.family,
        r.cylinders,
        r.kernel,
        r.aovs,
        r.parse_ms,
        r.prepare_ms,
        r.build_ms,
        r.trace_ms,
        r.write_ms,
        r.total_ms,
        r.mrays_per_s,
        opt(r.process_ms, 1),
        opt(r.peak_mib, 0),
        r.err_median,
        r.err_max,
        r.mismatches
    )
}

/// `scripts/bench_mitsuba.py`, written into the bench's scratch folder when it runs, so an
/// installed binary needs no source tree.
pub const MITSUBA_SCRIPT: &str = include_str!("../../scripts/bench_mitsuba.py");

/// `scripts/bench_open3d.py`, likewise.
pub const OPEN3D_SCRIPT: &str = include_str!("../../scripts/bench_open3d.py");

/// Other renderers timed on the same scenes in the same run, and how far: Mitsuba 3 (the
/// renderer cylaov is verified against) and Open3D's Embree ray caster on 16-segment
/// meshes (what a general triangle ray tracer does with the same cylinders). A largest
/// count of 0 leaves that renderer out.
#[derive(Clone, Debug)]
pub struct Anchors {
    /// The reference venv's python (mitsuba 3.9.1, open3d-cpu, numpy).
    pub python: PathBuf,
    /// Largest count for Mitsuba's `scalar_rgb` (slow: ~75 s at 1 000 cylinders on 2 cores).
    pub mitsuba_scalar_max: usize,
    /// Largest count for Mitsuba's `llvm_ad_rgb`.
    pub mitsuba_llvm_max: usize,
    /// Largest count for Open3D.
    pub open3d_max: usize,
}

/// One anchor renderer's times on one generated scene, seconds.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct AnchorRow {
    #[serde(default)]
    /// The scene family's name.
    pub family: String,
    #[serde(default)]
    /// Cylinders in the scene.
    pub cylinders: usize,
    /// Mitsuba's variant (`scalar_rgb`, `llvm_ad_rgb`) or `open3d_embree`.
    pub variant: String,
    /// `import mitsuba` and `set_variant`, or `import open3d`.
    pub import_s: f64,
    /// Mitsuba's `load_file` of the exported XML; Open3D: reading the scene JSON, making the
    /// meshes and adding them.
    pub load_s: f64,
    /// The first `render()` (with the JIT's compilation for llvm) or `cast_rays` (with
    /// Embree's BVH build).
    pub render1_s: f64,
    /// Writing the image (EXR; Open3D: the distances as `.npy`).
    pub write_s: f64,
    /// A second `render()` or `cast_rays` of the same scene: the warm time.
    pub render2_s: f64,
    /// The whole cold process (Python start, import, load, first render, write).
    #[serde(default)]
    pub process_s: f64,
    /// Pixels whose ray hit something (Open3D only): a check that the anchor traced the
    /// same scene through the same camera (its facets move silhouettes by a fraction of a
    /// percent of the hits).
    #[serde(default)]
    pub hits: Option<u64>,
}

/// The anchor variants, each with the largest count it runs at.
fn anchor_variants(a: &Anchors) -> [(&'static str, usize); 3] {
    [
        ("llvm_ad_rgb", a.mitsuba_llvm_max),
        ("scalar_rgb", a.mitsuba_scalar_max),
        (OPEN3D, a.open3d_max),
    ]
}

/// The variant name of the Open3D anchor.
pub const OPEN3D: &str = "open3d_embree";

/// Time `variant` (`llvm_ad_rgb`, `scalar_rgb` or [`OPEN3D`]) on `scene` through its script.
pub fn time_anchor(a: &Anchors, scene: &Scene, variant: &str, dir: &Path) -> Result<AnchorRow> {
    let n = scene.cylinders.len();
    let mut cmd = Command::new(&a.python);
    if variant == OPEN3D {
        let json = dir.join(format!("open3d-{n}.json"));
        std::fs::write(&json, serde_json::to_string(&SceneFile::from_scene(scene))?)?;
        let script = dir.join("bench_open3d.py");
        std::fs::write(&script, OPEN3D_SCRIPT)?;
        cmd.arg(&script).arg(&json).arg(dir.join("open3d.npy"));
    } else {
        let xml = dir.join(format!("mitsuba-{n}.xml"));
        std::fs::write(
            &xml,
            crate::output::format::mitsuba::to_xml(scene, "cylaov bench random scene")
                .map_err(std::io::Error::other)?,
        )?;
        let script = dir.join("bench_mitsuba.py");
        std::fs::write(&script, MITSUBA_SCRIPT)?;
        cmd.arg(&script)
            .arg(&xml)
            .arg(dir.join("mitsuba.exr"))
            .arg(variant)
            .args(variant.starts_with("scalar").then_some("--once"));
    }
    let start = Instant::now();
    let o = cmd
        .output()
        .with_context(|| format!("running {}", a.python.display()))?;
    let wall = start.elapsed().as_secs_f64();
    if !o.status.success() {
        bail!("{variant} failed: {}", String::from_utf8_lossy(&o.stderr));
    }
    let text = String::from_utf8_lossy(&o.stdout);
    let line = text.lines().last().unwrap_or_default();
    // Mitsuba's logger may leave a terminal colour reset in front of the JSON.
    let json = line.find('{').map_or(line, |k| &line[k..]);
    let mut row: AnchorRow = serde_json::from_str(json)
        .with_context(|| format!("the {variant} script printed {line:?}"))?;
    row.cylinders = n;
    // The cold process: everything but the warm second render (none for scalar variants).
    row.process_s = if variant.starts_with("scalar") {
        wall
    } else {
        wall - row.render2_s
    };
    Ok(row)
}

/// Run the anchors on the bench scenes, printing each row with three ratios against
/// cylaov's stable-f64 depth+normal row of the same count: (a) whole process vs whole
/// process, (b) the anchor's warm render vs cylaov's whole process, (c) the anchor's warm
/// render vs cylaov's in-memory build + trace.
pub fn run_anchors(
    opts: &BenchOptions,
    a: &Anchors,
    rows: &[Row],
    mut progress: impl FnMut(&str),
) -> Result<Vec<AnchorRow>> {
    let scratch = tempfile::Builder::new()
        .prefix("cylaov-bench-mi-")
        .tempdir()?;
    let dir = scratch.path();
    progress(&format!(
        "{:<6} {:>7} {:<13} {:>8} {:>8} {:>9} {:>9} {:>9} {:>10} {:>10} {:>10}",
        "family",
        "cyl",
        "variant",
        "load s",
        "render1",
        "render2",
        "write s",
        "process",
        "(a) proc",
        "(b) warm",
        "(c) trace"
    ));
    let mut out = Vec::new();
    for (&family, &n) in opts
        .families
        .iter()
        .flat_map(|f| opts.counts.iter().map(move |n| (f, n)))
    {
        let ours = rows.iter().find(|r| {
            r.family == family.name()
                && r.cylinders == n
                && r.kernel == Kernel::STABLE_F64.to_string()
                && r.is_depth_normal()
        });
        let scene = family.scene(n, opts.seed, opts.width, opts.height);
        for (variant, max) in anchor_variants(a) {
            if n > max {
                continue;
            }
            let mut r = time_anchor(a, &scene, variant, dir)?;
            r.family = family.name().to_string();
            let ratio = |num: f64, den: Option<f64>| {
                den.map_or("-".to_string(), |d| format!("{:.1}x", num * 1e3 / d))
            };
            progress(&format!(
                "{:<6} {:>7} {:<13} {:>8.3} {:>8.3} {:>9.3} {:>9.3} {:>9.3} {:>10} {:>10} {:>10}",
                family.name(),
                n,
                variant,
                r.load_s,
                r.render1_s,
                r.render2_s,
                r.write_s,
                r.process_s,
                ratio(r.process_s, ours.and_then(|o| o.process_ms)),
                ratio(r.render2_s, ours.and_then(|o| o.process_ms)),
                ratio(r.render2_s, ours.map(Row::render_ms)),
            ));
            out.push(r);
        }
    }
    Ok(out)
}
