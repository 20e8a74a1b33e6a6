//! Rendering: one ray per pixel through the BVH and a cylinder kernel, in parallel bands
//! of rows, filling only the requested AOVs. A render is a pure function of scene + options.
//! The image comes whole ([`render`]) or band by band ([`render_bands`]: each band of 16
//! rows handed to the caller's sink as soon as it is traced, the same bits), so that a
//! writer puts each band in its file while the others trace, and no whole image is held.
//!
//! Primary rays go tile by tile (16×16 pixels). A tile finds its cylinders one of two
//! ways: from its screen-tile list ([`Tiles`], binned before the trace), or, when the
//! lists would be crowded, by walking the BVH with the tile's view cone, nearest node
//! first, and stopping once every pixel's best hit is nearer than the next node
//! ([`ConeWalk`]): the cost then follows what is visible, not what is listed. Either
//! way each candidate is rasterised over just the pixels its projection can cover. A tiny
//! view (under one pixel per 16 cylinders) takes the lists however crowded: its few tiles
//! cost less to list than any BVH costs to build.
//!
//! One traversal per ray (`--accel bvh`, and a tiny view whose lists would pass their
//! memory bound) goes through the eight-wide tree ([`WideBvh`]; the binary one when there
//! are fewer than a quarter as many pixels as cylinders, too few rays to repay collapsing
//! it), [`IN_TURN`] pixels at a time, each after testing the cylinder of the last hit,
//! whose hit bounds its traversal.

use crate::accel::bvh::{Bvh, Cone, ConeWalk};
use crate::accel::tiles::{self, Candidate, TILE, Tiles};
use crate::accel::wide_bvh::{IN_TURN, Stack, Visit, WideBvh};
use crate::geometry::kernel::KernelFn;
use crate::geometry::packet::{self, LANES, NO_HIT, Packet, PacketFormula};
use crate::geometry::wide::{Avx2, Lanes, Simd, Slabs8, Wide};
use crate::geometry::{BasicHit, Cylinder, Formula, Kernel, Prepared, Real, Surface};
use crate::geometry::{FormulaKind, Precision};
use crate::output::aov::{AovImage, Channel, ChannelData};
use crate::scene::camera::Camera;
use crate::scene::{Aov, Scene};
use glam::{DVec3, Vec3A};
use rayon::prelude::*;

pub mod cast;

/// How primary rays find their candidate cylinders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Accel {
    /// Screen tiles of projected cylinder boxes, nearest first (primary rays only); when
    /// the tile lists would be crowded, the BVH walked tile by tile (`frustum`), unless the
    /// view is tiny (under one pixel per 16 cylinders): then the lists however crowded.
    #[default]
    Tiles,
    /// The BVH walked once per tile with the tile's view cone, nearest first, stopping
    /// when everything left is behind the tile's hits (primary rays only).
    Frustum,
    /// The BVH, one traversal per ray through its eight-wide form (works for any ray;
    /// kept to compare).
    Bvh,
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

/// The scene prepared for one camera: cylinders in kernel form and the BVH over them.
pub struct Tracer<T: Real, F: Formula> {
    /// The camera the rays leave from.
    pub camera: Camera,
    /// Cylinders in kernel form, in slot order: `prepared[s]` is cylinder `order[s]`
    /// (index order for the BVH, the tiles' visiting order for tiles).
    prepared: Vec<Prepared<T>>,
    order: Vec<u32>,
    bvh: Option<Bvh>,
    /// The BVH collapsed to eight-wide nodes, for one traversal per ray.
    wide: Option<WideBvh>,
    tiles: Option<Tiles>,
    /// For walking the BVH tile by tile: each slot's projection.
    cone_cands: Option<ConeCands>,
    _formula: std::marker::PhantomData<F>,
}

/// What a cone walk reads of the cylinders it meets.
enum ConeCands {
    /// Every slot's projection, made before the trace (a cylinder is met by many tiles).
    Projected(Vec<Candidate>),
    /// The cylinders in slot order, projected as they are met: with far fewer pixels than
    /// cylinders (a 16×16 view of 100 000), most are never met, and a projection costs
    /// as much as a dozen visits.
    Lazy(tiles::Projector, Vec<Cylinder>),
}

impl ConeCands {
    /// For the slots `order`: the tiles' projections (in index order) when they were
    /// made, else all projected now, or none yet when there are fewer pixels than
    /// cylinders.
    fn new(
        camera: &Camera,
        cylinders: &[Cylinder],
        order: &[u32],
        projected: Option<Vec<Candidate>>,
    ) -> Self {
        let pixels = camera.width() as usize * camera.height() as usize;
        if let Some(p) = projected {
            let slots = order.par_iter().enumerate().map(|(s, &i)| Candidate {
                slot: s as u32,
                ..p[i as usize]
            });
            ConeCands::Projected(slots.collect())
        } else if pixels >= cylinders.len() {
            ConeCands::Projected(tiles::project_slots(camera, cylinders, order))
        } else {
            let cyls = order.par_iter().map(|&i| cylinders[i as usize]).collect();
            ConeCands::Lazy(tiles::Projector::new(camera), cyls)
        }
    }

    #[inline(always)]
    fn get(&self, slot: u32, order: &[u32]) -> Candidate {
        match self {
            ConeCands::Projected(v) => v[slot as usize],
            ConeCands::Lazy(p, cyls) => p.project(&cyls[slot as usize], order[slot as usize], slot),
        }
    }
}

/// The nearest hit of a ray: cylinder index and the cheap hit record.
#[derive(Clone, Copy, Debug)]
pub struct PixelHit<T> {
    /// The cylinder's index in the scene, and its slot in the tracer.
    pub index: u32,
    /// Where the tracer keeps the cylinder's prepared form.
    pub slot: u32,
    /// Ray parameter and surface of the hit.
    pub hit: BasicHit<T>,
}

/// f64 → f32 rounded toward +inf, for BVH pruning bounds that must not cut a hit off.
fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { f.next_up() } else { f }
}

fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) > x { f.next_down() } else { f }
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
    /// The BVH walked tile by tile with each tile's view cone ([`ConeWalk`]).
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

impl<T: Real, F: Formula> Tracer<T, F> {
    /// Prepare `scene` for its camera, building the structure `accel` needs.
    pub fn new(scene: &Scene, accel: Accel) -> Self {
        Self::new_timed(scene, accel).0
    }

    /// [`Tracer::new`], also reporting how long the kernel forms took.
    fn new_timed(scene: &Scene, accel: Accel) -> (Self, std::time::Duration) {
        let camera = Camera::new(scene.camera);
        let origin = camera.origin;
        let cylinders = &scene.cylinders;
        let bvh = || {
            let bounds: Vec<_> = cylinders.par_iter().map(|c| c.bounds()).collect();
            Bvh::build(&bounds, origin)
        };
        let view = (camera.width(), camera.height());
        let plan = strategy(accel, view, cylinders.len());
        let (bvh, mut tiles, projected, wide) = match plan {
            Strategy::TinyTiles { max_entries } => {
                match Tiles::build_within(&camera, cylinders, max_entries) {
                    Ok(tiles) => (None, Some(tiles), None, false),
                    // A tiny view has fewer pixels than a quarter of the cylinders.
                    Err(_) => (Some(bvh()), None, None, false),
                }
            }
            Strategy::Tiles => match Tiles::build_or_projections(&camera, cylinders) {
                Ok(tiles) => (None, Some(tiles), None, false),
                Err(projected) => (Some(bvh()), None, Some(projected), false),
            },
            Strategy::ConeWalk => (Some(bvh()), None, None, false),
            Strategy::PerRay { wide } => (Some(bvh()), None, None, wide),
        };
        let per_ray = matches!(plan, Strategy::PerRay { .. } | Strategy::TinyTiles { .. });
        // Slots follow the order the trace meets cylinders in: the tiles' lists, or the
        // BVH's leaves (a leaf's cylinders then lie together in memory).
        let order = match (&mut tiles, &bvh) {
            (Some(tiles), _) => tiles.assign_slots(cylinders.len()),
            (None, Some(bvh)) => bvh.order().to_vec(),
            (None, None) => (0..cylinders.len() as u32).collect(),
        };
        let cone_cands = (bvh.is_some() && !per_ray)
            .then(|| ConeCands::new(&camera, cylinders, &order, projected));
        let wide = bvh.as_ref().filter(|_| wide).map(WideBvh::new);
        // Once collapsed, the binary tree is not read again (its order is the slots'):
        // free it (53 MB at a million cylinders).
        let bvh = bvh.filter(|_| wide.is_none());
        let t0 = std::time::Instant::now();
        let mut prepared = Vec::with_capacity(order.len());
        crate::mem::huge_pages(&prepared);
        prepared.par_extend(
            order
                .par_iter()
                .map(|&i| Prepared::new(&cylinders[i as usize], origin, F::CENTRED)),
        );
        let prepare = t0.elapsed();
        let tracer = Tracer {
            camera,
            prepared,
            order,
            bvh,
            wide,
            tiles,
            cone_cands,
            _formula: std::marker::PhantomData,
        };
        (tracer, prepare)
    }

    /// The ray parameter range of camera-space z in `[near_clip, far_clip]` along `d`.
    #[inline(always)]
    fn clip(&self, d: DVec3) -> (f64, f64) {
        let spec = &self.camera.spec;
        let inv_cos = 1.0 / d.dot(self.camera.forward);
        (spec.near_clip * inv_cos, spec.far_clip * inv_cos)
    }

    /// Test the cylinder in `slot`; keep it in `best` when nearer (ties: lower scene index
    /// wins, so the answer does not depend on visiting order). True when `best` changed.
    #[inline(always)]
    fn consider(
        &self,
        slot: u32,
        dt: T::V3,
        tmin: T,
        tmax: T,
        best: &mut Option<PixelHit<T>>,
    ) -> bool {
        let limit = best.map_or(tmax, |b| b.hit.t);
        let Some(hit) = F::intersect(&self.prepared[slot as usize], dt, tmin, limit) else {
            return false;
        };
        let index = self.order[slot as usize];
        let closer = best.is_none_or(|b| packet::nearer(hit.t, index, b.hit.t, b.index));
        if closer {
            *best = Some(PixelHit { index, slot, hit });
        }
        closer
    }

    /// Nearest hit along unit direction `d` from the camera origin whose camera-space z lies
    /// in `[near_clip, far_clip]`, through the BVH (any direction; no tiles needed).
    #[inline]
    pub fn trace(&self, d: DVec3) -> Option<PixelHit<T>> {
        let (tmin, tmax) = self.clip(d);
        self.trace_within(d, tmin, tmax)
    }

    /// [`Tracer::trace`] with the ray parameter range given: a pixel ray's, from
    /// [`Camera::dir_and_length`] and [`Camera::clip_range`], the same bits as the tiles'.
    #[inline]
    pub fn trace_within(&self, d: DVec3, tmin: f64, tmax: f64) -> Option<PixelHit<T>> {
        self.trace_with((), &mut Stack::default(), None, d, tmin, tmax)
    }

    /// [`Tracer::trace_within`] with the box test `slabs` (portable or AVX2: the same
    /// answer), a traversal stack the caller reuses from ray to ray, and a `hint`: a slot
    /// tested before the traversal (the previous pixel's hit: neighbours mostly hit the
    /// same cylinder), whose hit, if any, bounds the traversal from the start. The answer
    /// is the same with any hint or none: the nearest hit, ties to the lower index, and
    /// every box reaching the bound is still visited.
    #[inline(always)]
    fn trace_with<S: Slabs8>(
        &self,
        slabs: S,
        stack: &mut Stack,
        hint: Option<u32>,
        d: DVec3,
        tmin: f64,
        tmax: f64,
    ) -> Option<PixelHit<T>> {
        let (tmin_t, tmax_t) = (T::from_f64(tmin), T::from_f64(tmax));
        let dt = T::v3(d);
        let mut best = None;
        if let Some(h) = hint {
            self.consider(h, dt, tmin_t, tmax_t, &mut best);
        }
        let tmax = best.map_or(tmax, |b: PixelHit<T>| b.hit.t.to_f64());
        let d32 = Vec3A::new(d.x as f32, d.y as f32, d.z as f32);
        // Visit a slot (with a BVH, slots are its positions); a closer hit returns the
        // new pruning bound, rounded up so a tie is still visited. The hint is tested
        // already: again it would give the same hit, not nearer than itself, or none.
        let mut visit = |slot| {
            (hint != Some(slot) && self.consider(slot, dt, tmin_t, tmax_t, &mut best))
                .then(|| f32_up(best.map_or(tmax, |b| b.hit.t.to_f64())))
        };
        match (&self.wide, &self.bvh) {
            (Some(wide), _) => {
                debug_assert!(self.tiles.is_none());
                wide.traverse(slabs, stack, d32, f32_down(tmin), f32_up(tmax), visit);
            }
            (None, Some(bvh)) => {
                debug_assert!(self.tiles.is_none());
                bvh.traverse(d32, f32_down(tmin), f32_up(tmax), visit);
            }
            (None, None) => {
                for slot in 0..self.prepared.len() as u32 {
                    visit(slot);
                }
            }
        }
        best
    }

    /// [`Tracer::trace_with`] for [`IN_TURN`] rays `(d, tmin, tmax)` with one hint:
    /// through the wide tree all at once (see [`WideBvh::traverse_in_turn`]), else one
    /// after the other. The same answers as one call each.
    #[inline(always)]
    fn trace_in_turn<S: Slabs8>(
        &self,
        slabs: S,
        stacks: &mut [Stack; IN_TURN],
        hint: Option<u32>,
        rays: [(DVec3, f64, f64); IN_TURN],
    ) -> [Option<PixelHit<T>>; IN_TURN] {
        let Some(wide) = &self.wide else {
            return std::array::from_fn(|i| {
                let (d, tmin, tmax) = rays[i];
                self.trace_with(slabs, &mut stacks[i], hint, d, tmin, tmax)
            });
        };
        let mut group = GroupVisit {
            tracer: self,
            hint,
            dt: rays.map(|(d, _, _)| T::v3(d)),
            lims: rays.map(|(_, tmin, tmax)| (T::from_f64(tmin), T::from_f64(tmax))),
            tmax: rays.map(|(_, _, tmax)| tmax),
            best: [None; IN_TURN],
        };
        if let Some(h) = hint {
            for i in 0..IN_TURN {
                let (tmin, tmax) = group.lims[i];
                self.consider(h, group.dt[i], tmin, tmax, &mut group.best[i]);
            }
        }
        let wide_ray = |i: usize| {
            let d = rays[i].0;
            let d32 = Vec3A::new(d.x as f32, d.y as f32, d.z as f32);
            (d32, f32_down(rays[i].1), f32_up(group.bound(i)))
        };
        let wide_rays = [wide_ray(0), wide_ray(1), wide_ray(2), wide_ray(3)];
        wide.traverse_in_turn(slabs, stacks, wide_rays, &mut group);
        group.best
    }

    /// World-space unit outward normal of a hit along `d`.
    #[inline(always)]
    pub fn normal(&self, d: DVec3, h: &PixelHit<T>) -> DVec3 {
        T::v3_to_f64(F::normal(&self.prepared[h.slot as usize], T::v3(d), h.hit))
    }
}

/// The cylinder tests of the rays walking the wide tree together
/// ([`Tracer::trace_in_turn`]): each ray's best hit so far, the hint already tested.
struct GroupVisit<'a, T: Real, F: Formula> {
    tracer: &'a Tracer<T, F>,
    hint: Option<u32>,
    /// Per ray: direction, ray parameter range, and the range's end in f64.
    dt: [T::V3; IN_TURN],
    lims: [(T, T); IN_TURN],
    tmax: [f64; IN_TURN],
    best: [Option<PixelHit<T>>; IN_TURN],
}

impl<T: Real, F: Formula> GroupVisit<'_, T, F> {
    /// Ray `i`'s pruning bound: its best hit's distance, else the end of its range.
    #[inline(always)]
    fn bound(&self, i: usize) -> f64 {
        self.best[i].map_or(self.tmax[i], |b| b.hit.t.to_f64())
    }
}

impl<T: Real, F: Formula> Visit for GroupVisit<'_, T, F> {
    /// As in [`Tracer::trace_with`]: the hint is tested already; a closer hit returns the
    /// new bound rounded up, so a tie is still visited.
    #[inline(always)]
    fn visit(&mut self, i: usize, slot: u32) -> Option<f32> {
        let (tmin, tmax) = self.lims[i];
        (self.hint != Some(slot)
            && self
                .tracer
                .consider(slot, self.dt[i], tmin, tmax, &mut self.best[i]))
        .then(|| f32_up(self.bound(i)))
    }
}

/// Nearest hits for the pixels `xs × ys` (inclusive) of one tile from its candidates,
/// rasterised nearest first (see [`rasterise`]). `offsets` are the image-plane offsets per
/// column (padded to whole tiles) and per row.
#[inline(always)]
fn trace_tile<T: Real, F: PacketFormula, W: Wide<T>>(
    tok: W::Token,
    tracer: &Tracer<T, F>,
    cands: &[Candidate],
    xs: (u32, u32),
    ys: (u32, u32),
    offsets: (&[f64], &[f64]),
    rays: &mut TileRays<T>,
) {
    rays.ready = 0;
    for c in cands {
        rasterise::<T, F, W, false>(tok, tracer, c, xs, ys, offsets, rays);
    }
}

/// [`trace_tile`] with the candidates found by walking `bvh` with the tile's view cone,
/// nearest node first, until every pixel of the tile has a hit nearer than the next node
/// (or no node is left): occlusion culling. `cands` gives each slot's projection.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn trace_cone<T: Real, F: PacketFormula, W: Wide<T>>(
    tok: W::Token,
    tracer: &Tracer<T, F>,
    bvh: &Bvh,
    cands: &ConeCands,
    xs: (u32, u32),
    ys: (u32, u32),
    offsets: (&[f64], &[f64]),
    rays: &mut TileRays<T>,
) {
    rays.ready = 0;
    let cone = tile_cone(&tracer.camera, xs, ys, offsets);
    // The packets holding image pixels: every row of the tile, the groups of eight
    // columns up to the tile's last (lanes past the image's edge are not counted in the
    // reach: their rays exist, but no pixel needs them).
    let (tw, rows) = ((xs.1 - xs.0 + 1) as usize, (ys.1 - ys.0 + 1) as usize);
    let groups = tw.div_ceil(LANES);
    let row_mask = (1u32 << groups) - 1;
    let valid = (0..rows).fold(0u32, |m, r| m | row_mask << (r * PACKETS_PER_ROW));
    rays.lanes = [LANES as u8; PACKETS];
    for r in 0..rows {
        rays.lanes[r * PACKETS_PER_ROW + groups - 1] = (tw - (groups - 1) * LANES) as u8;
    }
    let mut walk = ConeWalk::new(bvh, cone);
    let mut reach = f32::INFINITY;
    while let Some(range) = walk.next_leaf(reach) {
        for slot in range {
            let c = cands.get(slot, &tracer.order);
            if !c.is_culled() {
                rasterise::<T, F, W, true>(tok, tracer, &c, xs, ys, offsets, rays);
            }
        }
        // Until every pixel has had a candidate, some ray still reaches its tmax.
        if rays.ready & valid == valid {
            let mut far = 0.0f64;
            for k in 0..PACKETS {
                if valid & (1 << k) != 0 {
                    far = far.max(rays.far[k]);
                }
            }
            reach = f32_up(far);
        }
    }
}

/// The view cone of the pixels `xs × ys`, widened by a pixel on every side (the walk must
/// not lose a box to rounding; the candidates' own bounds decide which pixels it covers).
/// A pixel ray is `forward − left·x + up·y` (then normalised), so the rays with column
/// offset `x >= a` satisfy `v·(−left − a·forward) >= 0`, and so on for the other sides.
fn tile_cone(cam: &Camera, xs: (u32, u32), ys: (u32, u32), (cols, rows): (&[f64], &[f64])) -> Cone {
    let step_x = (cols[1] - cols[0]).abs();
    let step_y = if rows.len() > 1 {
        (rows[1] - rows[0]).abs()
    } else {
        2.0 * cam.tan_half_y
    };
    let (x0, x1) = (cols[xs.0 as usize], cols[xs.1 as usize]);
    let (y0, y1) = (rows[ys.0 as usize], rows[ys.1 as usize]);
    let (a, b) = (x0.min(x1) - step_x, x0.max(x1) + step_x);
    let (c, d) = (y0.min(y1) - step_y, y0.max(y1) + step_y);
    let (f, l, u) = (cam.forward, cam.left, cam.true_up);
    let v = |p: DVec3| Vec3A::new(p.x as f32, p.y as f32, p.z as f32);
    Cone {
        planes: [-l - f * a, l + f * b, u - f * c, -u + f * d].map(v),
        forward: v(f),
    }
}

/// Test candidate `c` against the pixels of tile `xs × ys` it can cover: it visits only
/// its row spans, eight pixels at a time ([`Packet`]), and skips pixels whose best hit is
/// nearer than its `t_min`. Packets are set up on first use. With `CONE`, each touched
/// packet's farthest reach is kept up to date (the cone walk's stopping rule reads it).
#[inline(always)]
fn rasterise<T: Real, F: PacketFormula, W: Wide<T>, const CONE: bool>(
    tok: W::Token,
    tracer: &Tracer<T, F>,
    c: &Candidate,
    xs: (u32, u32),
    ys: (u32, u32),
    offsets: (&[f64], &[f64]),
    rays: &mut TileRays<T>,
) {
    if CONE && (c.x1 < xs.0 || c.x0 > xs.1 || c.y1 < ys.0 || c.y0 > ys.1) {
        return;
    }
    let prepared = &tracer.prepared[c.slot as usize];
    for j in c.y0.max(ys.0)..=c.y1.min(ys.1) {
        let Some((a, b)) = c.row_span(j, xs.0, xs.1) else {
            continue;
        };
        let (a, b) = ((a - xs.0) as usize, (b - xs.0) as usize);
        for g in a / LANES..=b / LANES {
            let k = (j - ys.0) as usize * PACKETS_PER_ROW + g;
            if rays.ready & (1 << k) == 0 {
                let x0 = xs.0 as usize + g * LANES;
                let cols = &offsets.0[x0..x0 + LANES];
                setup(
                    &tracer.camera,
                    &mut rays.packets[k],
                    &mut rays.dirs[k],
                    cols,
                    offsets.1[j as usize],
                );
                // tmax padded as a best hit is (below): a hit the kernel keeps at
                // its rounded tmax must not be skipped.
                rays.reach[k] = rays.packets[k]
                    .t
                    .map(|t| t.to_f64() * (1.0 + 8.0 * T::UNIT_ROUNDOFF));
                rays.ready |= 1 << k;
                if CONE {
                    rays.far[k] = farthest(&rays.reach[k], rays.lanes[k]);
                }
            }
            // Lanes of the span whose best hit is not nearer than the candidate.
            let (lo, hi) = (
                a.max(g * LANES) - g * LANES,
                b.min(g * LANES + LANES - 1) - g * LANES,
            );
            let span = ((1u32 << (hi + 1)) - (1 << lo)) as u8;
            let mask = span & W::le_bits(tok, c.t_min, &rays.reach[k]);
            if mask == 0 {
                continue;
            }
            let pk = &mut rays.packets[k];
            let changed = F::intersect_packet::<T, W>(tok, prepared, (c.index, c.slot), pk, mask);
            if changed != 0 {
                for l in 0..LANES {
                    // Padded by 8ε of the kernel: a candidate whose t rounds just
                    // below this hit's must still be tested (ties decide by index).
                    if changed & (1 << l) != 0 {
                        rays.reach[k][l] = pk.t[l].to_f64() * (1.0 + 8.0 * T::UNIT_ROUNDOFF);
                    }
                }
                if CONE {
                    rays.far[k] = farthest(&rays.reach[k], rays.lanes[k]);
                }
            }
        }
    }
}

/// The largest of the first `n` reaches.
#[inline(always)]
fn farthest(reach: &[f64; LANES], n: u8) -> f64 {
    let mut m = 0.0f64;
    for &r in &reach[..n as usize] {
        m = m.max(r);
    }
    m
}

/// Eight rays through columns `cols` of the row at offset `y`: [`Camera::dir_and_length`]
/// and [`Camera::clip_range`] step for step (so the same bits as the BVH path's pixel
/// rays), written lane-wise so it vectorises.
#[inline(always)]
fn setup<T: Real>(
    cam: &Camera,
    pk: &mut Packet<T>,
    dirs: &mut [[f64; LANES]; 3],
    cols: &[f64],
    y: f64,
) {
    let (f, left, up) = (
        cam.forward.to_array(),
        cam.left.to_array(),
        cam.true_up.to_array(),
    );
    for l in 0..LANES {
        let x = cols[l];
        let v: [f64; 3] = std::array::from_fn(|c| f[c] - left[c] * x + up[c] * y);
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let inv = 1.0 / len;
        for c in 0..3 {
            dirs[c][l] = v[c] * inv;
            pk.d[c][l] = T::from_f64(dirs[c][l]);
        }
        let (tmin, tmax) = cam.clip_range(len);
        pk.tmin[l] = T::from_f64(tmin);
        pk.t[l] = T::from_f64(tmax);
        pk.index[l] = NO_HIT;
    }
}

/// Packets per tile row and per tile.
const PACKETS_PER_ROW: usize = TILE as usize / LANES;
const PACKETS: usize = PACKETS_PER_ROW * TILE as usize;
// `TileRays::ready` has a bit per packet.
const _: () = assert!(PACKETS <= 32);

/// Per-pixel rays and best hits of one tile, reused from tile to tile (no allocation per
/// ray). Packet `k` holds the `LANES` columns from `x0 + (k % PACKETS_PER_ROW)·LANES` of
/// row `y0 + k / PACKETS_PER_ROW`.
pub(crate) struct TileRays<T: Real> {
    packets: [Packet<T>; PACKETS],
    /// The same directions in f64, for shading.
    dirs: [[[f64; LANES]; 3]; PACKETS],
    /// Per lane, the ray parameter beyond which nothing can improve it: its best hit
    /// (padded), else tmax.
    reach: [[f64; LANES]; PACKETS],
    /// A bit per packet: set up (and its hits valid).
    ready: u32,
    /// Cone walks only: per packet, the lanes holding image pixels and their largest reach.
    lanes: [u8; PACKETS],
    far: [f64; PACKETS],
}

impl<T: Real> TileRays<T> {
    fn boxed() -> Box<Self> {
        Box::new(TileRays {
            packets: [Packet::EMPTY; PACKETS],
            dirs: [[[0.0; LANES]; 3]; PACKETS],
            reach: [[0.0; LANES]; PACKETS],
            ready: 0,
            lanes: [LANES as u8; PACKETS],
            far: [0.0; PACKETS],
        })
    }

    /// Lane `l` of packet `k`: its direction and nearest hit, if it has one.
    #[inline(always)]
    fn hit(&self, k: usize, l: usize) -> Option<(DVec3, PixelHit<T>)> {
        let pk = &self.packets[k];
        (pk.index[l] != NO_HIT).then(|| {
            let dirs = &self.dirs[k];
            let hit = BasicHit {
                t: pk.t[l],
                surface: Surface::from_code(pk.surface[l]),
            };
            let d = DVec3::new(dirs[0][l], dirs[1][l], dirs[2][l]);
            (
                d,
                PixelHit {
                    index: pk.index[l],
                    slot: pk.slot[l],
                    hit,
                },
            )
        })
    }
}

/// A zeroed output plane of `n` samples, in huge pages where the system has them (the
/// hint covers whole 2 MiB pages inside the plane only, so a band's few rows stay in
/// ordinary pages that the allocator reuses). Reserved fallibly: a refusal is the one-line
/// out-of-memory error and exit 1 (the callers' memory check has passed by then).
fn zeroed<X: bytemuck::Zeroable>(n: usize) -> Vec<X> {
    let v = crate::mem::zeroed_or_exit(n, "an output plane of the render");
    crate::mem::huge_pages(&v);
    v
}

/// Output planes of the requested AOVs; `None` for the rest.
struct Planes<P> {
    distance: Option<P>,
    depth: Option<P>,
    normal: Option<[P; 3]>,
    position: Option<[P; 3]>,
}

/// The requested planes of an image or a band (`shape_id` and `part` as u32).
struct Samples {
    f: Planes<Vec<f32>>,
    id: Option<Vec<u32>>,
    part: Option<Vec<u32>>,
}

/// One band's slices of every requested plane (`shape_id` and `part` as u32).
struct Band<'a> {
    f: Planes<&'a mut [f32]>,
    id: Option<&'a mut [u32]>,
    part: Option<&'a mut [u32]>,
}

/// Cut each requested plane into bands of `len` samples.
fn bands<'a>(samples: &'a mut Samples, len: usize, count: usize) -> Vec<Band<'a>> {
    let Samples { f, id, part } = samples;
    fn cut<X>(v: Option<&mut Vec<X>>, len: usize, count: usize) -> Vec<Option<&mut [X]>> {
        match v {
            Some(v) => v.chunks_mut(len).map(Some).collect(),
            None => (0..count).map(|_| None).collect(),
        }
    }
    let mut d = cut(f.distance.as_mut(), len, count).into_iter();
    let mut z = cut(f.depth.as_mut(), len, count).into_iter();
    let [n0, n1, n2] = f
        .normal
        .as_mut()
        .map(|[a, b, c]| [Some(a), Some(b), Some(c)])
        .unwrap_or_default();
    let mut n = [
        cut(n0, len, count).into_iter(),
        cut(n1, len, count).into_iter(),
        cut(n2, len, count).into_iter(),
    ];
    let [p0, p1, p2] = f
        .position
        .as_mut()
        .map(|[a, b, c]| [Some(a), Some(b), Some(c)])
        .unwrap_or_default();
    let mut p = [
        cut(p0, len, count).into_iter(),
        cut(p1, len, count).into_iter(),
        cut(p2, len, count).into_iter(),
    ];
    let mut ids = cut(id.as_mut(), len, count).into_iter();
    let mut parts = cut(part.as_mut(), len, count).into_iter();
    let three =
        |it: &mut [std::vec::IntoIter<Option<&'a mut [f32]>>; 3]| -> Option<[&'a mut [f32]; 3]> {
            match (
                it[0].next().flatten(),
                it[1].next().flatten(),
                it[2].next().flatten(),
            ) {
                (Some(x), Some(y), Some(z)) => Some([x, y, z]),
                _ => None,
            }
        };
    (0..count)
        .map(|_| Band {
            f: Planes {
                distance: d.next().flatten(),
                depth: z.next().flatten(),
                normal: three(&mut n),
                position: three(&mut p),
            },
            id: ids.next().flatten(),
            part: parts.next().flatten(),
        })
        .collect()
}

/// What every band of a render shares.
struct BandInputs<'a, T: Real, F: Formula> {
    tracer: &'a Tracer<T, F>,
    /// `shape_id` per cylinder.
    ids: &'a [u32],
    /// Image-plane offset per column (padded to whole tiles) and per row.
    cols_off: &'a [f64],
    rows_off: &'a [f64],
}

impl<T: Real, F: Formula> BandInputs<'_, T, F> {
    /// Pixel `(x, y)`'s ray: unit direction and ray parameter range, the same bits as the
    /// tiles' (see [`Camera::dir_and_length`] and [`Camera::clip_range`]).
    #[inline(always)]
    fn pixel_ray(&self, x: usize, y: usize) -> (DVec3, f64, f64) {
        let cam = &self.tracer.camera;
        let (d, len) = cam.dir_and_length(self.cols_off[x], self.rows_off[y]);
        let (tmin, tmax) = cam.clip_range(len);
        (d, tmin, tmax)
    }
}

/// Write the requested AOVs of a hit along `d` into sample `k` of `band`.
#[inline(always)]
fn shade<T: Real, F: Formula>(
    fr: &BandInputs<T, F>,
    band: &mut Band,
    k: usize,
    d: DVec3,
    ph: PixelHit<T>,
) {
    let cam = &fr.tracer.camera;
    let t = ph.hit.t.to_f64();
    let f = &mut band.f;
    if let Some(s) = f.distance.as_deref_mut() {
        s[k] = t as f32;
    }
    if let Some(s) = f.depth.as_deref_mut() {
        s[k] = (t * d.dot(cam.forward)) as f32;
    }
    if let Some(s) = f.normal.as_mut() {
        let nrm = fr.tracer.normal(d, &ph);
        (s[0][k], s[1][k], s[2][k]) = (nrm.x as f32, nrm.y as f32, nrm.z as f32);
    }
    if let Some(s) = f.position.as_mut() {
        let p = cam.origin + d * t;
        (s[0][k], s[1][k], s[2][k]) = (p.x as f32, p.y as f32, p.z as f32);
    }
    if let Some(s) = band.id.as_deref_mut() {
        s[k] = fr.ids[ph.index as usize];
    }
    if let Some(s) = band.part.as_deref_mut() {
        s[k] = part_code(fr.tracer, d, &ph);
    }
}

/// The `part` AOV of a hit: 1 side from outside, 2 side from inside, 3 bottom cap, 4 top
/// cap. The side's facing is the sign of `normal · d`, as the Mitsuba reference decides it
/// (the outward normal points away from the camera on the wall's inner face).
#[inline(always)]
fn part_code<T: Real, F: Formula>(tracer: &Tracer<T, F>, d: DVec3, ph: &PixelHit<T>) -> u32 {
    match ph.hit.surface {
        Surface::Side if tracer.normal(d, ph).dot(d) > 0.0 => 2,
        Surface::Side => 1,
        Surface::Bottom => 3,
        Surface::Top => 4,
    }
}

/// Trace and shade band `b` (one row of tiles), returning its hit count.
#[inline(always)]
fn render_band<T: Real, F: PacketFormula, W: Wide<T>>(
    tok: W::Token,
    fr: &BandInputs<T, F>,
    b: usize,
    band: &mut Band,
) -> usize {
    let (tracer, cam) = (fr.tracer, &fr.tracer.camera);
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let band_rows = TILE as usize;
    let row0 = b * band_rows;
    let rows = band_rows.min(h - row0);
    let mut hits = 0;
    let offsets = (fr.cols_off, fr.rows_off);
    match (&tracer.tiles, &tracer.bvh, &tracer.cone_cands) {
        (Some(_), _, _) | (None, Some(_), Some(_)) => {
            let mut rays = TileRays::<T>::boxed();
            let ys = (row0 as u32, (row0 + rows - 1) as u32);
            for tx in 0..(w as u32).div_ceil(TILE) {
                let xs = (tx * TILE, ((tx + 1) * TILE).min(w as u32) - 1);
                match (&tracer.tiles, &tracer.bvh, &tracer.cone_cands) {
                    (Some(tiles), _, _) => {
                        let cands = tiles.tile(tx, b as u32);
                        if cands.is_empty() {
                            continue; // every AOV of a miss is 0 already
                        }
                        trace_tile::<T, F, W>(tok, tracer, cands, xs, ys, offsets, &mut rays);
                    }
                    (None, Some(bvh), Some(cands)) => {
                        trace_cone::<T, F, W>(tok, tracer, bvh, cands, xs, ys, offsets, &mut rays);
                    }
                    _ => unreachable!("matched above"),
                }
                let tw = (xs.1 - xs.0 + 1) as usize;
                for k in (0..PACKETS).filter(|&k| rays.ready & (1 << k) != 0) {
                    let x0 = (k % PACKETS_PER_ROW) * LANES;
                    let row = (k / PACKETS_PER_ROW) * w + xs.0 as usize + x0;
                    for l in 0..LANES.min(tw.saturating_sub(x0)) {
                        if let Some((d, hit)) = rays.hit(k, l) {
                            shade(fr, band, row + l, d, hit);
                            hits += 1;
                        }
                    }
                }
            }
        }
        _ => {
            // Pixels in groups of four, traced together; the last few of the band one
            // by one. The hint is the last hit found (through misses too: the next hit is
            // most likely on the same cylinder or near it).
            let mut stacks: [Stack; IN_TURN] = Default::default();
            let mut last = None;
            let n = rows * w;
            let ray = |k: usize| fr.pixel_ray(k % w, row0 + k / w);
            let grouped = n / IN_TURN * IN_TURN;
            for k in (0..grouped).step_by(IN_TURN) {
                // Written out: `array::from_fn` left the ray's set-up out of line, a call
                // per pixel compiled without AVX.
                let rays = [ray(k), ray(k + 1), ray(k + 2), ray(k + 3)];
                let found = tracer.trace_in_turn(tok, &mut stacks, last, rays);
                for (i, hit) in found.into_iter().enumerate() {
                    if let Some(hit) = hit {
                        last = Some(hit.slot);
                        shade(fr, band, k + i, rays[i].0, hit);
                        hits += 1;
                    }
                }
            }
            for k in grouped..n {
                let (d, tmin, tmax) = ray(k);
                if let Some(hit) = tracer.trace_with(tok, &mut stacks[0], last, d, tmin, tmax) {
                    last = Some(hit.slot);
                    shade(fr, band, k, d, hit);
                    hits += 1;
                }
            }
        }
    }
    hits
}

/// [`render_band`] compiled for AVX2, with packets in AVX registers (eight f32 lanes fill
/// one, f64 two). No FMA: the results are the same bits as the portable form. Taking the
/// [`Avx2`] token means it can only be reached after the CPU was checked (for AVX2 and
/// the bit counts the traversal uses).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt,lzcnt,bmi1")]
fn render_band_avx2<T: Simd, F: PacketFormula>(
    tok: Avx2,
    fr: &BandInputs<T, F>,
    b: usize,
    band: &mut Band,
) -> usize {
    render_band::<T, F, T::Avx>(tok, fr, b, band)
}

/// The band renderer for this CPU: AVX2 when it has it (and `simd`), else the baseline.
fn band_renderer<T: Simd, F: PacketFormula>(
    simd: bool,
) -> fn(&BandInputs<T, F>, usize, &mut Band) -> usize {
    #[cfg(target_arch = "x86_64")]
    if simd && Avx2::detect().is_some() {
        return |fr, b, band| {
            // SAFETY: this closure is returned only after `Avx2::detect` succeeded, so the
            // CPU has AVX2, POPCNT, LZCNT and BMI1, which both the token and the target
            // features require.
            unsafe { render_band_avx2(Avx2::new_unchecked(), fr, b, band) }
        };
    }
    let _ = simd;
    |fr, b, band| render_band::<T, F, Lanes<T>>((), fr, b, band)
}

/// The `normal_camera` planes: each stored world normal rotated into OpenCV camera axes
/// (x right = -left, y down = -true_up, z forward) in f64 and rounded once to f32; a miss
/// (0, 0, 0) stays 0. Rotating the stored f32 normal adds at most an ulp or so to its error.
fn normals_in_camera(cam: &crate::scene::camera::Camera, n: &[Vec<f32>; 3]) -> [Vec<f32>; 3] {
    let axes = [-cam.left, -cam.true_up, cam.forward];
    let len = n[0].len();
    let plane = || crate::mem::zeroed_or_exit::<f32>(len, "the normal_camera planes");
    let mut out = [plane(), plane(), plane()];
    for k in 0..len {
        let v = DVec3::new(n[0][k] as f64, n[1][k] as f64, n[2][k] as f64);
        if v == DVec3::ZERO {
            continue;
        }
        for (o, a) in out.iter_mut().zip(axes) {
            o[k] = a.dot(v) as f32;
        }
    }
    out
}

fn render_with<T: Simd, F: PacketFormula>(scene: &Scene, opts: &RenderOptions) -> (Render, Timing) {
    render_simd::<T, F>(scene, opts, true)
}

/// The output planes of `n` samples for the requested AOVs, zeroed (a miss is 0
/// everywhere): a whole image's, or one band's.
fn output_planes(opts: &RenderOptions, n: usize) -> Samples {
    let want = |a: Aov| opts.aovs.contains(&a);
    let plane = || zeroed::<f32>(n);
    let ids = || zeroed::<u32>(n);
    let planes = Planes {
        distance: want(Aov::Distance).then(plane),
        depth: want(Aov::Depth).then(plane),
        // Camera-frame normals are the world normals rotated: both need these planes.
        normal: (want(Aov::Normal) || want(Aov::NormalCamera)).then(|| [plane(), plane(), plane()]),
        position: want(Aov::Position).then(|| [plane(), plane(), plane()]),
    };
    Samples {
        f: planes,
        id: want(Aov::ShapeId).then(ids),
        part: want(Aov::Part).then(ids),
    }
}

/// The channels of filled planes, in the order every image of a render has them (a whole
/// image and each of its bands alike): the requested AOVs, `normal_camera` rotated from
/// the world normals here.
fn channels_of(opts: &RenderOptions, cam: &Camera, samples: Samples) -> Vec<Channel> {
    let Samples {
        f: mut planes,
        id,
        part,
    } = samples;
    let want = |a: Aov| opts.aovs.contains(&a);
    let mut channels = Vec::new();
    let mut push = |name: &str, data: Option<ChannelData>| {
        if let Some(data) = data {
            channels.push(Channel {
                name: name.to_string(),
                data,
            });
        }
    };
    push("distance", planes.distance.map(ChannelData::F32));
    push("depth", planes.depth.map(ChannelData::F32));
    let normal_camera = want(Aov::NormalCamera)
        .then(|| planes.normal.as_ref().map(|n| normals_in_camera(cam, n)))
        .flatten();
    if !want(Aov::Normal) {
        planes.normal = None;
    }
    let [nx, ny, nz] = planes.normal.map(|v| v.map(Some)).unwrap_or_default();
    for (c, v) in ["normal.X", "normal.Y", "normal.Z"]
        .iter()
        .zip([nx, ny, nz])
    {
        push(c, v.map(ChannelData::F32));
    }
    let [px, py, pz] = planes.position.map(|v| v.map(Some)).unwrap_or_default();
    for (c, v) in ["position.X", "position.Y", "position.Z"]
        .iter()
        .zip([px, py, pz])
    {
        push(c, v.map(ChannelData::F32));
    }
    push("shape_id", id.map(ChannelData::U32));
    push("part", part.map(ChannelData::U32));
    let [cx, cy, cz] = normal_camera.map(|v| v.map(Some)).unwrap_or_default();
    for (c, v) in ["normal_camera.X", "normal_camera.Y", "normal_camera.Z"]
        .iter()
        .zip([cx, cy, cz])
    {
        push(c, v.map(ChannelData::F32));
    }
    channels
}

/// What every band of one render reads, kept while the bands are traced.
struct Setup<T: Real, F: Formula> {
    tracer: Tracer<T, F>,
    ids: Vec<u32>,
    cols_off: Vec<f64>,
    rows_off: Vec<f64>,
    build: std::time::Duration,
    prepare: std::time::Duration,
}

impl<T: Real, F: Formula> Setup<T, F> {
    fn new(scene: &Scene, opts: &RenderOptions) -> Self {
        let start = std::time::Instant::now();
        let (tracer, prepare) = Tracer::<T, F>::new_timed(scene, opts.accel);
        let build = start.elapsed() - prepare;
        let cam = &tracer.camera;
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let padded = w.div_ceil(TILE as usize) * TILE as usize;
        let cols_off = (0..padded as u32).map(|i| cam.column_offset(i)).collect();
        let rows_off = (0..h as u32).map(|j| cam.row_offset(j)).collect();
        Setup {
            ids: scene.cylinders.iter().map(|c| c.id).collect(),
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
            cols_off: &self.cols_off,
            rows_off: &self.rows_off,
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

/// [`render_with`], with the AVX2 path allowed or not (the test of their agreement).
fn render_simd<T: Simd, F: PacketFormula>(
    scene: &Scene,
    opts: &RenderOptions,
    simd: bool,
) -> (Render, Timing) {
    let start = std::time::Instant::now();
    let setup = Setup::<T, F>::new(scene, opts);
    let cam = &setup.tracer.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let band_rows = TILE as usize;
    let mut samples = output_planes(opts, w * h);
    let inputs = setup.inputs();
    let band_fn = band_renderer::<T, F>(simd);
    let hits: usize = bands(&mut samples, band_rows * w, h.div_ceil(band_rows))
        .into_par_iter()
        .enumerate()
        .map(|(b, mut band)| band_fn(&inputs, b, &mut band))
        .sum();
    let channels = channels_of(opts, cam, samples);
    let image = AovImage {
        width: w,
        height: h,
        channels,
    };
    (Render { image, hits }, setup.timing(start))
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
    let inputs = setup.inputs();
    let band_fn = band_renderer::<T, F>(true);
    let hits = (0..h.div_ceil(band_rows))
        .into_par_iter()
        .map(|b| {
            let rows = band_rows.min(h - b * band_rows);
            let mut samples = output_planes(opts, rows * w);
            let mut band = bands(&mut samples, rows * w, 1);
            let hits = band_fn(&inputs, b, &mut band[0]);
            drop(band);
            let image = AovImage {
                width: w,
                height: rows,
                channels: channels_of(opts, cam, samples),
            };
            sink(b * band_rows, &image).map(|()| hits)
        })
        .try_reduce(|| 0, |a, b| Ok(a + b))?;
    Ok((hits, setup.timing(start)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Stable;

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

    /// Rendered band by band, every AOV is the whole render's bits at the band's rows (an
    /// odd size: a last band of 97 mod 16 = 1 row, partial tiles), through each structure;
    /// the bands cover the image once; an error from the sink ends the render with it.
    #[test]
    fn bands_are_the_whole_render() {
        let mut sc = crate::bench::dense_scene(2000, 5, 211, 117);
        (sc.camera.width, sc.camera.height) = (173, 97);
        for accel in [Accel::Tiles, Accel::Frustum, Accel::Bvh] {
            let o = RenderOptions {
                accel,
                ..RenderOptions::new(Aov::ALL.to_vec())
            };
            let whole = render(&sc, &o);
            let seen = std::sync::Mutex::new(vec![0u32; 97]);
            let (hits, _) = render_bands(&sc, &o, &|y0, band| {
                assert_eq!(band.width, 173);
                let names: Vec<_> = band.channels.iter().map(|c| &c.name).collect();
                let want: Vec<_> = whole.image.channels.iter().map(|c| &c.name).collect();
                assert_eq!(names, want, "same channels, same order");
                let rows = y0 * 173..(y0 + band.height) * 173;
                for (c, w) in band.channels.iter().zip(&whole.image.channels) {
                    let same = match (&c.data, &w.data) {
                        (ChannelData::F32(a), ChannelData::F32(b)) => a
                            .iter()
                            .map(|x| x.to_bits())
                            .eq(b[rows.clone()].iter().map(|x| x.to_bits())),
                        (ChannelData::U32(a), ChannelData::U32(b)) => a[..] == b[rows.clone()],
                        _ => false,
                    };
                    assert!(
                        same,
                        "{accel:?}: {} differs in the band at row {y0}",
                        c.name
                    );
                }
                for n in &mut seen.lock().unwrap()[y0..y0 + band.height] {
                    *n += 1;
                }
                Ok(())
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
                render_simd::<f32, Stable>(sc, &o, true).0,
                render_simd::<f32, Stable>(sc, &o, false).0,
            );
            let (c, d) = (
                render_simd::<f64, Stable>(sc, &o, true).0,
                render_simd::<f64, Stable>(sc, &o, false).0,
            );
            for (x, y) in [(&a, &b), (&c, &d)] {
                assert_eq!(x.hits, y.hits);
                for ch in &x.image.channels {
                    assert!(
                        y.image.channel(&ch.name) == Some(&ch.data),
                        "{} differs",
                        ch.name
                    );
                }
            }
            hits += a.hits;
        }
        assert!(hits > 20_000, "the scenes hit something ({hits})");
    }

    /// The cone walk gives the per-ray BVH's bits, whether it projects every cylinder
    /// first or (fewer pixels than cylinders) each as it meets it, at 1 and 2 threads; so
    /// do the tiles, crowded lists and all, on a tiny view.
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
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                pool.install(|| render(sc, &o))
            };
            let reference = with(Accel::Bvh, 1);
            for (accel, threads) in [(Accel::Frustum, 1), (Accel::Frustum, 2), (Accel::Tiles, 2)] {
                let r = with(accel, threads);
                assert_eq!(r.hits, reference.hits);
                assert!(r.image == reference.image, "{accel:?}, {threads} threads");
            }
            hits += reference.hits;
        }
        assert!(hits > 5_000, "{hits} of 15 732 pixels hit");
        let tiny = Tracer::<f64, Stable>::new(&scenes[4], Accel::Tiles);
        assert!(tiny.tiles.is_some() && tiny.bvh.is_none() && tiny.wide.is_none());
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
