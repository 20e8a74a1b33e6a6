//! Rendering: one ray per pixel through the BVH and a cylinder kernel, in parallel bands
//! of rows, filling only the requested AOVs. A render is a pure function of scene + options.

use crate::aov::{AovImage, Channel, ChannelData};
use crate::bvh::Bvh;
use crate::camera::Camera;
use crate::geometry::{BasicHit, Formula, Literal, Prepared, Real, Stable};
use crate::scene::{Aov, Scene};
use crate::tiles::{Candidate, TILE, Tiles};
use glam::{DVec3, Vec3A};
use rayon::prelude::*;

/// Kernel precision.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Precision {
    F32,
    #[default]
    F64,
}

/// Kernel formulation (see `geometry::cylinder`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum FormulaKind {
    /// SPEC §1 as written: textbook roots, axis-point normal quadratic.
    Literal,
    /// Lagrange discriminant, citardauq roots, projected normal, gap-free rims.
    #[default]
    Stable,
}

/// How primary rays find their candidate cylinders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Accel {
    /// Screen tiles of projected cylinder boxes, nearest first (primary rays only).
    #[default]
    Tiles,
    /// The BVH, one traversal per ray (works for any ray; kept to compare).
    Bvh,
}

/// What to render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    pub aovs: Vec<Aov>,
    pub precision: Precision,
    pub formula: FormulaKind,
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
    pub image: AovImage,
    /// Pixels that hit a cylinder.
    pub hits: usize,
}

/// Render `scene` with `opts` on the current rayon pool.
pub fn render(scene: &Scene, opts: &RenderOptions) -> Render {
    render_timed(scene, opts).0
}

/// Time spent preparing the scene (kernel form, BVH or tiles) and tracing it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Timing {
    pub build: std::time::Duration,
    pub trace: std::time::Duration,
}

/// [`render`], also reporting how long the build and the trace took.
pub fn render_timed(scene: &Scene, opts: &RenderOptions) -> (Render, Timing) {
    match (opts.precision, opts.formula) {
        (Precision::F32, FormulaKind::Stable) => render_with::<f32, Stable>(scene, opts),
        (Precision::F64, FormulaKind::Stable) => render_with::<f64, Stable>(scene, opts),
        (Precision::F32, FormulaKind::Literal) => render_with::<f32, Literal>(scene, opts),
        (Precision::F64, FormulaKind::Literal) => render_with::<f64, Literal>(scene, opts),
    }
}

/// The scene prepared for one camera: cylinders in kernel form and the BVH over them.
pub struct Tracer<T: Real, F: Formula> {
    pub camera: Camera,
    prepared: Vec<Prepared<T>>,
    bvh: Option<Bvh>,
    tiles: Option<Tiles>,
    _formula: std::marker::PhantomData<F>,
}

/// The nearest hit of a ray: cylinder index and the cheap hit record.
#[derive(Clone, Copy, Debug)]
pub struct PixelHit<T> {
    pub index: u32,
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

impl<T: Real, F: Formula> Tracer<T, F> {
    /// Prepare `scene` for its camera, building the structure `accel` needs.
    pub fn new(scene: &Scene, accel: Accel) -> Self {
        let camera = Camera::new(scene.camera);
        let origin = camera.origin;
        let prepared = scene
            .cylinders
            .iter()
            .map(|c| Prepared::new(c, origin, F::CENTRED))
            .collect();
        let bvh = || {
            let bounds: Vec<_> = scene.cylinders.iter().map(|c| c.bounds()).collect();
            Bvh::build(&bounds, origin)
        };
        let (bvh, tiles) = match accel {
            Accel::Bvh => (Some(bvh()), None),
            Accel::Tiles => match Tiles::build(&camera, &scene.cylinders) {
                Some(tiles) => (None, Some(tiles)),
                None => (Some(bvh()), None),
            },
        };
        Tracer {
            camera,
            prepared,
            bvh,
            tiles,
            _formula: std::marker::PhantomData,
        }
    }

    /// The ray parameter range of camera-space z in `[near_clip, far_clip]` along `d`.
    #[inline(always)]
    fn clip(&self, d: DVec3) -> (f64, f64) {
        let spec = &self.camera.spec;
        let inv_cos = 1.0 / d.dot(self.camera.forward);
        (spec.near_clip * inv_cos, spec.far_clip * inv_cos)
    }

    /// Test cylinder `index`; keep it in `best` when nearer (ties: lower index wins, so the
    /// answer does not depend on visiting order). True when `best` changed.
    #[inline(always)]
    fn consider(
        &self,
        index: u32,
        dt: T::V3,
        tmin: T,
        tmax: T,
        best: &mut Option<PixelHit<T>>,
    ) -> bool {
        let limit = best.map_or(tmax, |b| b.hit.t);
        let Some(hit) = F::intersect(&self.prepared[index as usize], dt, tmin, limit) else {
            return false;
        };
        let closer = best.is_none_or(|b| hit.t < b.hit.t || (hit.t == b.hit.t && index < b.index));
        if closer {
            *best = Some(PixelHit { index, hit });
        }
        closer
    }

    /// Nearest hit along unit direction `d` from the camera origin whose camera-space z lies
    /// in `[near_clip, far_clip]`, through the BVH (any direction; no tiles needed).
    #[inline]
    pub fn trace(&self, d: DVec3) -> Option<PixelHit<T>> {
        let (tmin, tmax) = self.clip(d);
        let (tmin_t, tmax_t) = (T::from_f64(tmin), T::from_f64(tmax));
        let dt = T::v3(d);
        let mut best = None;
        match &self.bvh {
            Some(bvh) => {
                let d32 = Vec3A::new(d.x as f32, d.y as f32, d.z as f32);
                bvh.traverse(d32, f32_down(tmin), f32_up(tmax), |index| {
                    self.consider(index, dt, tmin_t, tmax_t, &mut best)
                        .then(|| f32_up(best.map_or(tmax, |b| b.hit.t.to_f64())))
                });
            }
            None => {
                for index in 0..self.prepared.len() as u32 {
                    self.consider(index, dt, tmin_t, tmax_t, &mut best);
                }
            }
        }
        best
    }

    /// Nearest hits for the pixels `xs × ys` (inclusive) of one tile from its candidates,
    /// rasterised nearest first: each candidate visits only the pixels of its row spans,
    /// and skips those whose best hit is nearer than its `t_min`.
    pub fn trace_tile(
        &self,
        cands: &[Candidate],
        xs: (u32, u32),
        ys: (u32, u32),
        offsets: (&[f64], &[f64]),
        rays: &mut TileRays<T>,
    ) {
        let tw = (xs.1 - xs.0 + 1) as usize;
        // Rays are set up lazily: a pixel no candidate covers costs nothing.
        rays.ready = [0; TILE as usize];
        let setup = |rays: &mut TileRays<T>, i: u32, j: u32, k: usize| {
            let (d, len) = self
                .camera
                .dir_and_length(offsets.0[i as usize], offsets.1[j as usize]);
            // cos θ = forward·d = 1/len (the image plane sits at unit distance along
            // forward), so the clip range needs no second division.
            let spec = &self.camera.spec;
            let (tmin, tmax) = (spec.near_clip * len, spec.far_clip * len);
            rays.d[k] = d;
            rays.dt[k] = T::v3(d);
            rays.tmin[k] = T::from_f64(tmin);
            rays.tmax[k] = T::from_f64(tmax);
            rays.reach[k] = tmax;
            rays.best[k] = None;
            rays.ready[(j - ys.0) as usize] |= 1 << (i - xs.0);
        };
        for c in cands {
            for j in c.y0.max(ys.0)..=c.y1.min(ys.1) {
                let Some((a, b)) = c.row_span(j, xs.0, xs.1) else {
                    continue;
                };
                let row = (j - ys.0) as usize * tw;
                // Set up the span's new rays first, in a loop of their own: their square
                // roots and divisions are independent and overlap in the pipeline.
                let span_bits = ((1u32 << (b - a + 1)) - 1) << (a - xs.0);
                let fresh = span_bits & !(rays.ready[(j - ys.0) as usize] as u32);
                if fresh != 0 {
                    for i in a..=b {
                        if fresh & (1 << (i - xs.0)) != 0 {
                            setup(rays, i, j, row + (i - xs.0) as usize);
                        }
                    }
                }
                for i in a..=b {
                    let k = row + (i - xs.0) as usize;
                    if c.t_min > rays.reach[k] {
                        continue;
                    }
                    if self.consider(
                        c.index,
                        rays.dt[k],
                        rays.tmin[k],
                        rays.tmax[k],
                        &mut rays.best[k],
                    ) {
                        // Padded by 8ε of the kernel: a candidate whose t rounds just
                        // below this hit's must still be tested (ties decide by index).
                        rays.reach[k] = rays.best[k].map_or(f64::INFINITY, |h| {
                            h.hit.t.to_f64() * (1.0 + 8.0 * T::UNIT_ROUNDOFF)
                        });
                    }
                }
            }
        }
    }

    /// World-space unit outward normal of a hit along `d`.
    #[inline]
    pub fn normal(&self, d: DVec3, h: &PixelHit<T>) -> DVec3 {
        T::v3_to_f64(F::normal(&self.prepared[h.index as usize], T::v3(d), h.hit))
    }
}

const TILE_PIXELS: usize = (TILE * TILE) as usize;

/// Per-pixel rays and best hits of one tile, reused from tile to tile (no allocation per
/// ray). Pixel `k` of a tile `tw` wide is `(x0 + k % tw, y0 + k / tw)`.
pub struct TileRays<T: Real> {
    pub d: [DVec3; TILE_PIXELS],
    dt: [T::V3; TILE_PIXELS],
    tmin: [T; TILE_PIXELS],
    tmax: [T; TILE_PIXELS],
    /// Ray parameter beyond which nothing can improve the pixel: its best hit, else tmax.
    reach: [f64; TILE_PIXELS],
    pub best: [Option<PixelHit<T>>; TILE_PIXELS],
    /// Per tile row, a bit per column: that pixel's ray is set up (and `best` valid).
    pub ready: [u16; TILE as usize],
}

impl<T: Real> TileRays<T> {
    fn boxed() -> Box<Self> {
        let zero = T::v3(DVec3::ZERO);
        Box::new(TileRays {
            d: [DVec3::ZERO; TILE_PIXELS],
            dt: [zero; TILE_PIXELS],
            tmin: [T::ZERO; TILE_PIXELS],
            tmax: [T::ZERO; TILE_PIXELS],
            reach: [0.0; TILE_PIXELS],
            best: [None; TILE_PIXELS],
            ready: [0; TILE as usize],
        })
    }
}

/// Output planes of the requested AOVs; `None` for the rest.
struct Planes<P> {
    distance: Option<P>,
    depth: Option<P>,
    normal: Option<[P; 3]>,
    position: Option<[P; 3]>,
}

/// One band's slices of every requested plane (`shape_id` as u32).
struct Band<'a> {
    f: Planes<&'a mut [f32]>,
    id: Option<&'a mut [u32]>,
}

/// Cut each requested plane into bands of `len` samples.
fn bands<'a>(
    f: &'a mut Planes<Vec<f32>>,
    id: &'a mut Option<Vec<u32>>,
    len: usize,
    count: usize,
) -> Vec<Band<'a>> {
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
        })
        .collect()
}

fn render_with<T: Real, F: Formula>(scene: &Scene, opts: &RenderOptions) -> (Render, Timing) {
    let start = std::time::Instant::now();
    let tracer = Tracer::<T, F>::new(scene, opts.accel);
    let build = start.elapsed();
    let cam = &tracer.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let n = w * h;
    let want = |a: Aov| opts.aovs.contains(&a);
    let plane = || vec![0f32; n];
    let mut planes = Planes {
        distance: want(Aov::Distance).then(plane),
        depth: want(Aov::Depth).then(plane),
        normal: want(Aov::Normal).then(|| [plane(), plane(), plane()]),
        position: want(Aov::Position).then(|| [plane(), plane(), plane()]),
    };
    let mut id = want(Aov::ShapeId).then(|| vec![0u32; n]);
    let band_rows = TILE as usize;
    let count = h.div_ceil(band_rows);
    let ids: Vec<u32> = scene.cylinders.iter().map(|c| c.id).collect();
    let cols_off: Vec<f64> = (0..w as u32).map(|i| cam.column_offset(i)).collect();
    let rows_off: Vec<f64> = (0..h as u32).map(|j| cam.row_offset(j)).collect();
    let hits: usize = bands(&mut planes, &mut id, band_rows * w, count)
        .into_par_iter()
        .enumerate()
        .map(|(b, mut band)| {
            let row0 = b * band_rows;
            let rows = band_rows.min(h - row0);
            let mut hits = 0;
            let mut shade = |k: usize, d: DVec3, ph: PixelHit<T>| {
                hits += 1;
                let t = ph.hit.t.to_f64();
                let f = &mut band.f;
                if let Some(s) = f.distance.as_deref_mut() {
                    s[k] = t as f32;
                }
                if let Some(s) = f.depth.as_deref_mut() {
                    s[k] = (t * d.dot(cam.forward)) as f32;
                }
                if let Some(s) = f.normal.as_mut() {
                    let nrm = tracer.normal(d, &ph);
                    (s[0][k], s[1][k], s[2][k]) = (nrm.x as f32, nrm.y as f32, nrm.z as f32);
                }
                if let Some(s) = f.position.as_mut() {
                    let p = cam.origin + d * t;
                    (s[0][k], s[1][k], s[2][k]) = (p.x as f32, p.y as f32, p.z as f32);
                }
                if let Some(s) = band.id.as_deref_mut() {
                    s[k] = ids[ph.index as usize];
                }
            };
            match &tracer.tiles {
                Some(tiles) => {
                    let mut rays = TileRays::<T>::boxed();
                    let ys = (row0 as u32, (row0 + rows - 1) as u32);
                    for tx in 0..tiles.tiles_x {
                        let cands = tiles.tile(tx, b as u32);
                        if cands.is_empty() {
                            continue; // every AOV of a miss is 0 already
                        }
                        let xs = (tx * TILE, ((tx + 1) * TILE).min(w as u32) - 1);
                        tracer.trace_tile(cands, xs, ys, (&cols_off, &rows_off), &mut rays);
                        let tw = (xs.1 - xs.0 + 1) as usize;
                        for dj in 0..rows {
                            for di in 0..tw {
                                let k = dj * tw + di;
                                if rays.ready[dj] & (1 << di) == 0 {
                                    continue;
                                }
                                if let Some(hit) = rays.best[k] {
                                    shade(dj * w + xs.0 as usize + di, rays.d[k], hit);
                                }
                            }
                        }
                    }
                }
                None => {
                    for k in 0..rows * w {
                        let (i, j) = (k % w, row0 + k / w);
                        let d = cam.dir_from_offsets(cols_off[i], rows_off[j]);
                        if let Some(hit) = tracer.trace(d) {
                            shade(k, d, hit);
                        }
                    }
                }
            }
            hits
        })
        .sum();

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
    let timing = Timing {
        build,
        trace: start.elapsed() - build,
    };
    let image = AovImage {
        width: w,
        height: h,
        channels,
    };
    (Render { image, hits }, timing)
}
