//! Rendering: one ray per pixel through the BVH and a cylinder kernel, in parallel bands
//! of rows, filling only the requested AOVs. A render is a pure function of scene + options.
//! The image comes whole ([`render`]) or band by band ([`render_bands`]: each band of 16
//! rows handed to the caller's sink as soon as it is traced, the same bits), so that a
//! writer puts each band in its file while the others trace, and no whole image is held.
//!
//! Primary rays go tile by tile (16×16 pixels). A tile finds its cylinders one of two
//! ways: from its screen-tile list ([`Tiles`](crate::accel::tiles::Tiles), binned before the trace), or, when the
//! lists would be crowded, by walking the BVH with the tile's view cone, nearest node
//! first, and stopping once every pixel's best hit is nearer than the next node
//! ([`ConeWalk`](crate::accel::bvh::ConeWalk)): the cost then follows what is visible, not what is listed. Either
//! way each candidate is rasterised over just the pixels its projection can cover. A tiny
//! view (under one pixel per 16 cylinders) takes the lists however crowded: its few tiles
//! cost less to list than any BVH costs to build.
//!
//! One traversal per ray (`--accel bvh`, and a tiny view whose lists would pass their
//! memory bound) goes through the eight-wide tree ([`WideBvh`](crate::accel::wide_bvh::WideBvh); the binary one when there
//! are fewer than a quarter as many pixels as cylinders, too few rays to repay collapsing
//! it), [`IN_TURN`](crate::accel::wide_bvh::IN_TURN) pixels at a time, each after testing the cylinder of the last hit,
//! whose hit bounds its traversal.

use crate::accel::tiles::{self, TILE};
use crate::geometry::kernel::KernelFn;
use crate::geometry::packet::PacketFormula;
use crate::geometry::wide::Simd;
use crate::geometry::{Formula, Kernel, Real};
use crate::geometry::{FormulaKind, Precision};
use crate::image::AovImage;
use crate::scene::{Aov, Scene};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

pub mod cast;
mod general;
mod planes;
mod tracer;
mod walk;

use planes::{BandInputs, bands, buffers_of, output_planes, uninit_planes};
pub use tracer::{PixelHit, Tracer};
use walk::band_renderer;

// A band the writer receives is one row of tiles.
const _: () = assert!(crate::image::BAND_ROWS == TILE as usize);

crate::choice_enum! {
    /// How primary rays find their candidate cylinders.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Accel default Tiles {
        /// Screen tiles of projected cylinder boxes, nearest first (primary rays only); when
        /// the tile lists would be crowded, the BVH walked tile by tile (`frustum`), unless the
        /// view is tiny (under one pixel per 16 cylinders): then the lists however crowded.
        Tiles = "tiles",
        /// The BVH walked once per tile with the tile's view cone, nearest first, stopping
        /// when everything left is behind the tile's hits (primary rays only).
        Frustum = "frustum",
        /// The BVH, one traversal per ray through its eight-wide form (works for any ray;
        /// kept to compare).
        Bvh = "bvh",
    }
}

/// What to render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// AOVs to compute and store; nothing else is computed.
    pub aovs: Vec<Aov>,
    /// Precision of the kernel.
    pub precision: Precision,
    /// Formulation of the kernel.
    pub formula: FormulaKind,
    /// How primary rays find their candidates.
    pub accel: Accel,
}

impl RenderOptions {
    /// The default kernel (stable, f64) with the given AOVs.
    pub fn new(aovs: Vec<Aov>) -> Self {
        RenderOptions {
            aovs,
            precision: Precision::default(),
            formula: FormulaKind::default(),
            accel: Accel::default(),
        }
    }
}

/// A render's image and counts.
#[derive(Clone, Debug)]
pub struct Render {
    /// The requested AOVs.
    pub image: AovImage,
    /// Pixels that hit a cylinder.
    pub hits: usize,
}

/// Render `scene` with `opts` on the current rayon pool.
pub fn render(scene: &Scene, opts: &RenderOptions) -> Render {
    render_timed(scene, opts).0
}

/// [`render`], given up once `stop` is set (by another thread: a caller that must end a
/// long render early, as the Python package on Ctrl-C): bands not started by then are not
/// traced, and the result is `None`. Unstopped, the same bits as [`render`].
pub fn render_until(scene: &Scene, opts: &RenderOptions, stop: &AtomicBool) -> Option<Render> {
    struct Run<'a>(&'a Scene, &'a RenderOptions, &'a AtomicBool);
    impl KernelFn for Run<'_> {
        type Output = Render;
        fn call<T: Simd, F: PacketFormula>(self) -> Self::Output {
            render_simd::<T, F>(self.0, self.1, true, Some(self.2)).0
        }
    }
    let r = Kernel::new(opts.formula, opts.precision).dispatch(Run(scene, opts, stop));
    (!stop.load(Ordering::Relaxed)).then_some(r)
}

/// Time spent preparing the scene: the acceleration structure (`build`: tiles or BVH,
/// and the projections a cone walk reads), the kernel form of every cylinder (`prepare`),
/// and tracing it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Timing {
    /// Building the acceleration structure (tiles or BVH).
    pub build: std::time::Duration,
    /// Preparing every cylinder's kernel form.
    pub prepare: std::time::Duration,
    /// Tracing every pixel.
    pub trace: std::time::Duration,
}

/// [`render`], also reporting how long the build and the trace took.
pub fn render_timed(scene: &Scene, opts: &RenderOptions) -> (Render, Timing) {
    struct Run<'a>(&'a Scene, &'a RenderOptions);
    impl KernelFn for Run<'_> {
        type Output = (Render, Timing);
        fn call<T: Simd, F: PacketFormula>(self) -> Self::Output {
            render_with::<T, F>(self.0, self.1)
        }
    }
    Kernel::new(opts.formula, opts.precision).dispatch(Run(scene, opts))
}

/// How a render finds each ray's candidate cylinders: what [`strategy`] chose for a view
/// and a scene, and what the tracer builds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strategy {
    /// A tiny view: one list per screen tile of every cylinder it meets, however long, up
    /// to `max_entries` entries in all; past them, one traversal of the binary BVH per ray.
    TinyTiles {
        /// The lists' bound, [`TINY_VIEW_ENTRIES`] per cylinder spread over the tiles.
        max_entries: usize,
    },
    /// Screen-tile lists, or the cone walk where they would be crowded.
    Tiles,
    /// The BVH walked tile by tile with each tile's view cone ([`ConeWalk`](crate::accel::bvh::ConeWalk)).
    ConeWalk,
    /// One BVH traversal per ray, through the eight-wide tree (`wide`) or the binary one.
    PerRay {
        /// Whether the binary tree is collapsed to the eight-wide one first.
        wide: bool,
    },
}

/// The strategy for a `width × height` view of `cylinders` cylinders under `accel`: a
/// pure function of the three, so a view's structure (and its bits) never depends on
/// the machine.
///
/// - A tiny view (more than [`TINY_VIEW`] cylinders per pixel) takes
///   [`Strategy::TinyTiles`] under `tiles`.
/// - Under `tiles`, more than `8 · CROWDED` cylinders per tile are crowded lists unless
///   nearly all lie outside the view, so they go to the cone walk without projecting.
/// - `frustum` is the cone walk; `bvh` is per-ray traversal, through the wide tree unless
///   the view has fewer pixels than cylinders per [`WIDE_COLLAPSE`].
pub fn strategy(accel: Accel, (width, height): (u32, u32), cylinders: usize) -> Strategy {
    let ntiles = width.div_ceil(TILE) as usize * height.div_ceil(TILE) as usize;
    let pixels = width as usize * height as usize;
    let tiny = pixels * TINY_VIEW < cylinders;
    match accel {
        Accel::Tiles if tiny => Strategy::TinyTiles {
            max_entries: TINY_VIEW_ENTRIES * cylinders / ntiles,
        },
        Accel::Tiles if cylinders <= 8 * tiles::CROWDED * ntiles => Strategy::Tiles,
        Accel::Tiles | Accel::Frustum => Strategy::ConeWalk,
        Accel::Bvh => Strategy::PerRay {
            wide: pixels * WIDE_COLLAPSE >= cylinders,
        },
    }
}

/// A view with more than this many cylinders per pixel is tiny: its tile lists, however
/// crowded, cost less than building any BVH, and the cone walk (a per-tile structure on a
/// BVH) more still. Backed by `cylaov bench --family dense --counts 100000 --width 16
/// --height 16` against the same run with `--accel frustum`.
pub const TINY_VIEW: usize = 16;

/// A tiny view's tile lists may hold this many entries per cylinder in all (each entry a
/// cylinder listed in one tile): past it, one BVH traversal per pixel instead, as lists
/// that long cost more to sort than a BVH costs to build. Backed by `cylaov bench
/// --family dense --counts 100000 --width 16 --height 16` against the same run with
/// `--accel bvh`.
pub const TINY_VIEW_ENTRIES: usize = 16;

/// Per-ray traversal collapses the binary tree to the eight-wide one when the view has at
/// least one pixel per this many cylinders: the collapse costs a fixed amount per cylinder
/// and saves a multiple of it per ray, which fewer rays cannot repay. Backed by `cylaov
/// bench --accel bvh --family dense --counts 100000` at `--width 16 --height 16` (binary)
/// and at the default size (wide).
pub const WIDE_COLLAPSE: usize = 4;

fn render_with<T: Simd, F: PacketFormula>(scene: &Scene, opts: &RenderOptions) -> (Render, Timing) {
    render_simd::<T, F>(scene, opts, true, None)
}

/// What every band of one render reads, kept while the bands are traced.
struct Setup<'s, T: Real, F: Formula> {
    tracer: Tracer<'s, T, F>,
    ids: Vec<u32>,
    labels: Vec<u32>,
    cols_off: Vec<f64>,
    rows_off: Vec<f64>,
    build: std::time::Duration,
    prepare: std::time::Duration,
}

impl<'s, T: Real, F: Formula> Setup<'s, T, F> {
    fn new(scene: &'s Scene, opts: &RenderOptions) -> Self {
        let start = std::time::Instant::now();
        let (tracer, prepare) = Tracer::<T, F>::new_timed(scene, opts.accel);
        let build = start.elapsed() - prepare;
        let cam = &tracer.camera;
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let padded = w.div_ceil(TILE as usize) * TILE as usize;
        let cols_off = (0..padded as u32).map(|i| cam.column_offset(i)).collect();
        let rows_off = (0..h as u32).map(|j| cam.row_offset(j)).collect();
        let ids_for = |aov: Aov, f: fn(&crate::geometry::Cylinder) -> u32| -> Vec<u32> {
            match opts.aovs.contains(&aov) {
                true => scene.cylinders.par_iter().map(f).collect(),
                false => Vec::new(),
            }
        };
        Setup {
            // Only for the planes that read them (`shade` writes a hit's id or label there),
            // on every thread: at 100 000 cylinders each is a pass over 8 MB.
            ids: ids_for(Aov::ShapeId, |c| c.id),
            labels: ids_for(Aov::Label, |c| c.label),
            tracer,
            cols_off,
            rows_off,
            build,
            prepare,
        }
    }

    fn inputs(&self) -> BandInputs<'_, T, F> {
        BandInputs {
            tracer: &self.tracer,
            ids: &self.ids,
            labels: &self.labels,
            cols_off: &self.cols_off,
            rows_off: &self.rows_off,
            cylinders: self.tracer.cylinders,
        }
    }

    fn timing(&self, start: std::time::Instant) -> Timing {
        Timing {
            build: self.build,
            prepare: self.prepare,
            trace: start.elapsed() - self.build - self.prepare,
        }
    }
}

/// [`render_with`], with the AVX2 path allowed or not (the test of their agreement); with
/// `stop`, bands that start after it is set are left untraced.
fn render_simd<T: Simd, F: PacketFormula>(
    scene: &Scene,
    opts: &RenderOptions,
    simd: bool,
    stop: Option<&AtomicBool>,
) -> (Render, Timing) {
    let start = std::time::Instant::now();
    let setup = Setup::<T, F>::new(scene, opts);
    let cam = &setup.tracer.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let part = part_rows(h);
    // The planes are zeroed part by part by the threads that trace them: zeroed up front,
    // memory the allocator reuses would be cleared by this one thread while the pool waits.
    let mut samples = uninit_planes(opts, w * h);
    let inputs = setup.inputs();
    let band_fn = band_renderer::<T, F>(simd);
    // A stopped render skips its remaining parts, zeroing included (a large view's pages
    // would take longer to fault in than the caller wants to wait), and so has no image.
    let skipped = AtomicBool::new(false);
    let hits: usize = bands(&mut samples, part * w, h.div_ceil(part))
        .into_par_iter()
        .enumerate()
        .map(|(k, piece)| match stop {
            Some(s) if s.load(Ordering::Relaxed) => {
                skipped.store(true, Ordering::Relaxed);
                0
            }
            _ => {
                // `part` divides a band's rows, so no piece straddles two bands.
                let (row0, rows) = (k * part, part.min(h - k * part));
                let (b, at) = (row0 / TILE as usize, row0 % TILE as usize);
                band_fn(&inputs, b, at..at + rows, &mut piece.zeroed())
            }
        })
        .sum();
    if skipped.into_inner() {
        let image = AovImage {
            width: 0,
            height: 0,
            buffers: Vec::new(),
        };
        return (Render { image, hits }, setup.timing(start));
    }
    // SAFETY: the bands cover every sample of every plane (`bands` cuts each whole) and,
    // none skipped, each was zeroed above; a panic in a band never reaches here.
    let samples = unsafe { samples.assume_init() };
    let image = AovImage {
        width: w,
        height: h,
        buffers: buffers_of(opts, cam, samples),
    };
    (Render { image, hits }, setup.timing(start))
}

/// Rows traced as one task: a band's 16, or for an image of fewer bands than threads (a
/// tiny view, where one band of 100 000 candidates is most of the trace) the largest
/// power of two that gives every thread a part. A power of two divides the band.
fn part_rows(height: usize) -> usize {
    let threads = rayon::current_num_threads();
    let mut rows = TILE as usize;
    while rows > 1 && height.div_ceil(rows) < threads {
        rows /= 2;
    }
    rows
}

/// Where [`render_bands`] hands each band: its first row and the band as an image of its
/// rows (every channel a whole render has, in the same order).
pub type BandSink<'a> = dyn Fn(usize, &AovImage) -> std::io::Result<()> + Sync + 'a;

/// [`render_timed`], handing each band of 16 rows to `sink` as soon as it is traced
/// instead of keeping the whole image; returns the hit count. A band's samples are the
/// bits the whole render has at those rows. Bands arrive in any order, on any thread; the
/// first error stops the render and is returned.
///
/// Why: on a virtual machine whose host reclaims freed memory (a balloon), the first write
/// to a fresh page costs about a millisecond per MiB, so the planes of a 1080p depth +
/// normal render (33 MB) cost more than tracing them (dense 1 000); a band's buffers are
/// small and reused by the allocator, and writing each band out while others trace
/// spreads the file's own page-cache work over every core.
pub fn render_bands(
    scene: &Scene,
    opts: &RenderOptions,
    sink: &BandSink,
) -> std::io::Result<(usize, Timing)> {
    struct Run<'a, 'b>(&'a Scene, &'a RenderOptions, &'a BandSink<'b>);
    impl KernelFn for Run<'_, '_> {
        type Output = std::io::Result<(usize, Timing)>;
        fn call<T: Simd, F: PacketFormula>(self) -> Self::Output {
            bands_simd::<T, F>(self.0, self.1, self.2)
        }
    }
    Kernel::new(opts.formula, opts.precision).dispatch(Run(scene, opts, sink))
}

fn bands_simd<T: Simd, F: PacketFormula>(
    scene: &Scene,
    opts: &RenderOptions,
    sink: &BandSink,
) -> std::io::Result<(usize, Timing)> {
    let start = std::time::Instant::now();
    let setup = Setup::<T, F>::new(scene, opts);
    let cam = &setup.tracer.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let band_rows = TILE as usize;
    let part = part_rows(h);
    let inputs = setup.inputs();
    let band_fn = band_renderer::<T, F>(true);
    let hits = (0..h.div_ceil(band_rows))
        .into_par_iter()
        .map(|b| {
            let rows = band_rows.min(h - b * band_rows);
            let mut samples = output_planes(opts, rows * w);
            let pieces = bands(&mut samples, part * w, rows.div_ceil(part));
            let hits: usize = pieces
                .into_par_iter()
                .enumerate()
                .map(|(k, mut piece)| {
                    let at = k * part;
                    band_fn(&inputs, b, at..at + part.min(rows - at), &mut piece)
                })
                .sum();
            let image = AovImage {
                width: w,
                height: rows,
                buffers: buffers_of(opts, cam, samples),
            };
            sink(b * band_rows, &image).map(|()| hits)
        })
        .try_reduce(|| 0, |a, b| Ok(a + b))?;
    Ok((hits, setup.timing(start)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::wide_bvh::Stack;
    use crate::geometry::Stable;
    use crate::geometry::wide::Avx2;
    use crate::image::ChannelData;
    use glam::DVec3;

    /// A pool of `n` threads, for renders whose parts follow the thread count.
    fn pool(n: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    }

    /// The names of the first channel of `band` (rows from `y0` of the image) whose bits
    /// differ from `whole`'s at those rows, if any.
    fn band_differs(whole: &AovImage, y0: usize, band: &AovImage) -> Option<Vec<String>> {
        let w = whole.width;
        band.buffers
            .iter()
            .zip(&whole.buffers)
            .find(|(c, a)| {
                let s = c.stride();
                let rows = y0 * w * s..(y0 + band.height) * w * s;
                let same = match (&c.data, &a.data) {
                    (ChannelData::F32(b), ChannelData::F32(a)) => b
                        .iter()
                        .map(|x| x.to_bits())
                        .eq(a[rows].iter().map(|x| x.to_bits())),
                    (ChannelData::U32(b), ChannelData::U32(a)) => b[..] == a[rows],
                    _ => false,
                };
                !same
            })
            .map(|(c, _)| c.names.clone())
    }

    /// Each threshold of the strategy, on both sides: the tiny view (16 cylinders per
    /// pixel), the crowded lists (`8 · CROWDED` cylinders per tile, partial tiles counted
    /// whole), the tiny lists' bound, and the wide collapse (4 cylinders per pixel).
    #[test]
    fn strategy_switches_at_its_thresholds() {
        use Strategy::*;
        let s = strategy;
        let crowd = 8 * tiles::CROWDED;
        // A 16×16 view: one tile, 256 pixels.
        assert_eq!(s(Accel::Tiles, (16, 16), 0), Tiles);
        assert_eq!(s(Accel::Tiles, (16, 16), crowd), Tiles);
        assert_eq!(s(Accel::Tiles, (16, 16), crowd + 1), ConeWalk);
        assert_eq!(s(Accel::Tiles, (16, 16), 256 * 16), ConeWalk);
        let tiny = |n: usize, tiles: usize| TinyTiles {
            max_entries: 16 * n / tiles,
        };
        assert_eq!(s(Accel::Tiles, (16, 16), 256 * 16 + 1), tiny(4097, 1));
        assert_eq!(s(Accel::Tiles, (16, 16), 100_000), tiny(100_000, 1));
        // 17×16 and 32×16: two tiles.
        assert_eq!(s(Accel::Tiles, (17, 16), 2 * crowd), Tiles);
        assert_eq!(s(Accel::Tiles, (17, 16), 2 * crowd + 1), ConeWalk);
        assert_eq!(s(Accel::Tiles, (32, 16), 100_000), tiny(100_000, 2));
        // 1920×1080: 120 × 68 tiles (the last row partial).
        assert_eq!(s(Accel::Tiles, (1920, 1080), 8160 * crowd), Tiles);
        assert_eq!(s(Accel::Tiles, (1920, 1080), 8160 * crowd + 1), ConeWalk);
        // The cone walk when asked for, tiny or not.
        for n in [0, 1, 100_000, 10_000_000] {
            assert_eq!(s(Accel::Frustum, (16, 16), n), ConeWalk);
            assert_eq!(s(Accel::Frustum, (1920, 1080), n), ConeWalk);
        }
        // Per ray: wide down to one pixel per 4 cylinders.
        assert_eq!(s(Accel::Bvh, (16, 16), 1024), PerRay { wide: true });
        assert_eq!(s(Accel::Bvh, (16, 16), 1025), PerRay { wide: false });
        assert_eq!(s(Accel::Bvh, (1, 1), 0), PerRay { wide: true });
        assert_eq!(s(Accel::Bvh, (1, 1), 5), PerRay { wide: false });
        assert_eq!(s(Accel::Bvh, (8192, 8192), 1 << 28), PerRay { wide: true });
    }

    /// Unstopped, `render_until` gives `render`'s bits; stopped (here before it starts),
    /// nothing.
    #[test]
    fn render_until_gives_up_when_stopped() {
        let sc = crate::bench::dense_scene(300, 5, 67, 45);
        let o = RenderOptions::new(Aov::ALL.to_vec());
        let whole = render(&sc, &o);
        assert!(whole.hits > 0);
        let go = render_until(&sc, &o, &AtomicBool::new(false)).expect("not stopped");
        assert_eq!(go.hits, whole.hits);
        assert_eq!(go.image.buffers, whole.image.buffers);
        assert!(render_until(&sc, &o, &AtomicBool::new(true)).is_none());
    }

    /// Rendered band by band, every AOV is the whole render's bits at the band's rows (an
    /// odd size: a last band of 97 mod 16 = 1 row, partial tiles), through each structure;
    /// the bands cover the image once; an error from the sink ends the render with it. The
    /// whole render is traced a band a task (one thread), the bands in parts of 4 rows (16
    /// threads, more than the 7 bands).
    #[test]
    fn bands_are_the_whole_render() {
        let mut sc = crate::bench::dense_scene(2000, 5, 211, 117);
        (sc.camera.width, sc.camera.height) = (173, 97);
        let (one, many) = (pool(1), pool(16));
        assert_eq!(
            (
                one.install(|| part_rows(97)),
                many.install(|| part_rows(97))
            ),
            (16, 4)
        );
        for accel in [Accel::Tiles, Accel::Frustum, Accel::Bvh] {
            let o = RenderOptions {
                accel,
                ..RenderOptions::new(Aov::ALL.to_vec())
            };
            let whole = one.install(|| render(&sc, &o));
            let seen = std::sync::Mutex::new(vec![0u32; 97]);
            let (hits, _) = many
                .install(|| {
                    render_bands(&sc, &o, &|y0, band| {
                        assert_eq!(band.width, 173);
                        assert_eq!(
                            band.names(),
                            whole.image.names(),
                            "same channels, same order"
                        );
                        if let Some(names) = band_differs(&whole.image, y0, band) {
                            panic!("{accel:?}: {names:?} differs in the band at row {y0}");
                        }
                        for n in &mut seen.lock().unwrap()[y0..y0 + band.height] {
                            *n += 1;
                        }
                        Ok(())
                    })
                })
                .unwrap();
            assert_eq!(hits, whole.hits);
            assert!(hits > 1000, "{hits} hits");
            assert!(seen.into_inner().unwrap().iter().all(|&n| n == 1));
        }
        let o = RenderOptions::new(vec![Aov::Depth]);
        let err = render_bands(&sc, &o, &|y0, _| {
            if y0 == 48 {
                Err(std::io::Error::other("disk full at 48"))
            } else {
                Ok(())
            }
        });
        assert_eq!(err.unwrap_err().to_string(), "disk full at 48");
    }

    /// The AVX2 band renderer and the portable one give the same bits, on every committed
    /// scene (grazing, inside, far, huge, axis-parallel views among them) and a crowd,
    /// through the screen tiles, the cone walk of the BVH and the per-ray wide BVH.
    #[test]
    fn avx2_and_portable_paths_agree() {
        // Without AVX2 both renders take the portable path and the comparison proves
        // nothing: say so, and under CI fail rather than pass vacuously.
        if Avx2::detect().is_none() {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "this CI machine has no AVX2: the AVX2 path cannot be checked"
            );
            eprintln!("SKIPPED: this CPU has no AVX2, so there is no AVX2 path to compare");
            return;
        }
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
        let mut scenes = vec![
            crate::bench::random_scene(700, 5, 211, 117),
            crate::bench::dense_scene(3000, 5, 211, 117),
        ];
        for sub in [dir.clone(), dir.join("stress")] {
            for e in std::fs::read_dir(sub).unwrap() {
                let path = e.unwrap().path();
                if path.extension().is_some_and(|x| x == "json") {
                    let mut sc = crate::scene::load(&path).unwrap();
                    // Small and odd-sized: partial tiles and packets at the edges.
                    (sc.camera.width, sc.camera.height) = (173, 97);
                    scenes.push(sc);
                }
            }
        }
        assert!(scenes.len() > 10);
        let mut hits = 0;
        for (sc, accel) in scenes
            .iter()
            .flat_map(|sc| [Accel::Tiles, Accel::Frustum, Accel::Bvh].map(|a| (sc, a)))
        {
            let o = RenderOptions {
                accel,
                ..RenderOptions::new(Aov::ALL.to_vec())
            };
            let (a, b) = (
                render_simd::<f32, Stable>(sc, &o, true, None).0,
                render_simd::<f32, Stable>(sc, &o, false, None).0,
            );
            let (c, d) = (
                render_simd::<f64, Stable>(sc, &o, true, None).0,
                render_simd::<f64, Stable>(sc, &o, false, None).0,
            );
            for (x, y) in [(&a, &b), (&c, &d)] {
                assert_eq!(x.hits, y.hits);
                for b in &x.image.buffers {
                    assert!(y.image.buffers.contains(b), "{:?} differs", b.names);
                }
            }
            hits += a.hits;
        }
        assert!(hits > 20_000, "the scenes hit something ({hits})");
    }

    /// A view of fewer bands than threads is traced in parts of a band (here 1 or 4 rows at
    /// 5 threads): every camera model and structure gives the bits it gives traced a band
    /// a task on one thread, in memory and band by band.
    #[test]
    fn parts_of_a_band_are_the_band() {
        let (one, five) = (pool(1), pool(5));
        assert_eq!(five.install(|| part_rows(5)), 1);
        assert_eq!(five.install(|| part_rows(27)), 4);
        let base =
            r#""origin": [0.2, -9, 3], "target": [0, 0, 0], "up": [0, 0, 1], "near_clip": 0.01"#;
        let cameras = [
            r#""fov_deg": 50"#,
            r#""model": "orthographic", "ortho_width": 9"#,
            r#""model": "opencv", "fx": 20, "fy": 21, "cx": 15.2, "cy": 5.7, "k1": -0.21, "k2": 0.04"#,
            r#""model": "opencv_fisheye", "fx": 9, "fy": 9.5, "cx": 15.6, "cy": 5.4, "k1": 0.03"#,
            r#""model": "equirectangular""#,
        ];
        let mut hits = 0;
        for (cam, (w, h)) in cameras.iter().flat_map(|c| [(c, (31, 5)), (c, (17, 27))]) {
            let mut sc = crate::bench::dense_scene(600, 4, w, h);
            let text = format!(
                r#"{{"camera": {{{base}, {cam}, "width": {w}, "height": {h}}}, "cylinders": []}}"#
            );
            sc.camera = crate::scene::parse(&text).unwrap().camera;
            for accel in [Accel::Tiles, Accel::Frustum, Accel::Bvh] {
                let o = RenderOptions {
                    accel,
                    ..RenderOptions::new(Aov::ALL.to_vec())
                };
                let whole = one.install(|| render(&sc, &o));
                let parts = five.install(|| render(&sc, &o));
                assert_eq!(parts.hits, whole.hits, "{cam}, {accel:?}");
                assert!(parts.image == whole.image, "{cam}, {w}×{h}, {accel:?}");
                let banded = std::sync::Mutex::new(0);
                five.install(|| {
                    render_bands(&sc, &o, &|y0, band| {
                        let differs = band_differs(&whole.image, y0, band);
                        assert!(
                            differs.is_none(),
                            "{cam}, {accel:?}: {differs:?} at row {y0}"
                        );
                        *banded.lock().unwrap() += band.height;
                        Ok(())
                    })
                })
                .unwrap();
                assert_eq!(banded.into_inner().unwrap(), h as usize);
                hits += whole.hits;
            }
        }
        assert!(hits > 2_000, "{hits} hits");
    }

    /// The cone walk gives the per-ray BVH's bits, whether it projects every cylinder
    /// first or (fewer pixels than cylinders) each as it meets it, at 1 and 2 threads; so
    /// do the tiles, crowded lists and all, on a tiny view, where they prepare no
    /// cylinder up front but make each kernel as they test it.
    #[test]
    fn cone_walk_matches_the_per_ray_bvh() {
        let scenes = [
            crate::bench::dense_scene(3000, 6, 40, 30),
            crate::bench::dense_scene(3000, 6, 150, 90),
            crate::bench::random_scene(2000, 7, 30, 20),
            // Fewer than a quarter as many pixels as cylinders: the per-ray path keeps the
            // binary tree.
            crate::bench::dense_scene(3000, 6, 24, 16),
            // A tiny view (under one pixel per 16 cylinders): the tiles take every
            // cylinder in their lists, however crowded.
            crate::bench::dense_scene(3000, 6, 8, 6),
        ];
        let mut hits = 0;
        for sc in &scenes {
            let with = |accel: Accel, threads: usize| {
                let o = RenderOptions {
                    accel,
                    ..RenderOptions::new(Aov::ALL.to_vec())
                };
                pool(threads).install(|| render(sc, &o))
            };
            let reference = with(Accel::Bvh, 1);
            // At 2 and 5 threads, the 16- and 6-row views are traced in parts of a band.
            for (accel, threads) in [
                (Accel::Frustum, 1),
                (Accel::Frustum, 2),
                (Accel::Tiles, 2),
                (Accel::Tiles, 5),
                (Accel::Bvh, 5),
            ] {
                let r = with(accel, threads);
                assert_eq!(r.hits, reference.hits);
                assert!(r.image == reference.image, "{accel:?}, {threads} threads");
            }
            hits += reference.hits;
        }
        assert!(hits > 5_000, "{hits} of 15 732 pixels hit");
        let tiny = Tracer::<f64, Stable>::new(&scenes[4], Accel::Tiles);
        assert!(tiny.tiles.is_some() && tiny.bvh.is_none() && tiny.wide.is_none());
        assert!(tiny.prepared.is_empty());
        // Lists that are not a tiny view's: every cylinder prepared up front.
        let sparse = crate::bench::random_scene(300, 7, 64, 48);
        let listed = Tracer::<f64, Stable>::new(&sparse, Accel::Tiles);
        assert!(listed.tiles.is_some() && listed.prepared.len() == 300);
    }

    /// Rays of any direction from the camera find the same nearest hit (cylinder, ray
    /// parameter to the bit, surface) through the wide tree, portable and AVX2, with and
    /// without a hint (the previous ray's hit, or an arbitrary cylinder), as through the
    /// binary tree and by testing every cylinder: on a dense tangle seen from outside
    /// and from inside it.
    #[test]
    fn wide_and_binary_per_ray_paths_agree() {
        let mut outside = crate::bench::dense_scene(4000, 3, 64, 48);
        let mut inside = outside.clone();
        inside.camera.origin = DVec3::new(0.5, -0.3, 0.2);
        inside.camera.target = DVec3::new(3.0, 2.0, 1.0);
        for sc in [&mut outside, &mut inside] {
            sc.camera.near_clip = 1e-3;
        }
        let mut rng = crate::rng::SplitMix64::new(21);
        let (mut hits, mut rays) = (0, 0);
        for sc in [&outside, &inside] {
            let wide = Tracer::<f64, Stable>::new(sc, Accel::Bvh);
            assert!(
                wide.wide.is_some() && wide.bvh.is_none(),
                "64×48 pixels: wide"
            );
            // The same camera with 8×6 pixels keeps the binary tree (the same tree and slot
            // order: it depends on the boxes and the origin only); without it, every slot
            // is tested.
            let mut small = sc.clone();
            (small.camera.width, small.camera.height) = (8, 6);
            let binary = Tracer::<f64, Stable>::new(&small, Accel::Bvh);
            assert!(
                binary.wide.is_none() && binary.bvh.is_some(),
                "8×6 pixels: binary"
            );
            let mut brute = Tracer::<f64, Stable>::new(&small, Accel::Bvh);
            brute.bvh = None;
            assert_eq!(binary.order, wide.order);
            let key =
                |h: Option<PixelHit<f64>>| h.map(|h| (h.index, h.hit.t.to_bits(), h.hit.surface));
            let mut stack = Stack::default();
            let mut last = None;
            for k in 0..3000u32 {
                let d = rng.unit_vector();
                let (tmin, tmax) = (1e-3, 1e3);
                let reference = binary.trace_within(d, tmin, tmax);
                assert_eq!(key(brute.trace_within(d, tmin, tmax)), key(reference));
                let hint = if k % 2 == 0 { last } else { Some(k % 4000) };
                let portable = wide.trace_with((), &mut stack, hint, d, tmin, tmax);
                assert_eq!(key(portable), key(reference), "d = {d:?}, hint {hint:?}");
                assert_eq!(key(wide.trace_within(d, tmin, tmax)), key(reference));
                if let Some(tok) = Avx2::detect() {
                    let avx = wide.trace_with(tok, &mut stack, hint, d, tmin, tmax);
                    assert_eq!(key(avx), key(reference), "AVX2, d = {d:?}, hint {hint:?}");
                }
                last = reference.map(|h| h.slot);
                hits += reference.is_some() as usize;
                rays += 1;
            }
        }
        assert_eq!(rays, 6000);
        assert!(hits > 3000, "{hits} of 6000 rays hit");
    }
}
