//! Rendering: one ray per pixel through the BVH and a cylinder kernel, in parallel bands
//! of rows, filling only the requested AOVs. A render is a pure function of scene + options.

use crate::aov::{AovImage, Channel, ChannelData};
use crate::bvh::Bvh;
use crate::camera::Camera;
use crate::geometry::{BasicHit, Formula, Literal, Prepared, Real, Stable};
use crate::scene::{Aov, Scene};
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

/// What to render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    pub aovs: Vec<Aov>,
    pub precision: Precision,
    pub formula: FormulaKind,
}

impl RenderOptions {
    /// The default kernel (stable, f64) with the given AOVs.
    pub fn new(aovs: Vec<Aov>) -> Self {
        RenderOptions {
            aovs,
            precision: Precision::default(),
            formula: FormulaKind::default(),
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
    match (opts.precision, opts.formula) {
        (Precision::F32, FormulaKind::Stable) => render_with::<f32, Stable>(scene, &opts.aovs),
        (Precision::F64, FormulaKind::Stable) => render_with::<f64, Stable>(scene, &opts.aovs),
        (Precision::F32, FormulaKind::Literal) => render_with::<f32, Literal>(scene, &opts.aovs),
        (Precision::F64, FormulaKind::Literal) => render_with::<f64, Literal>(scene, &opts.aovs),
    }
}

/// The scene prepared for one camera: cylinders in kernel form and the BVH over them.
pub struct Tracer<T: Real, F: Formula> {
    pub camera: Camera,
    prepared: Vec<Prepared<T>>,
    bvh: Bvh,
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
    pub fn new(scene: &Scene) -> Self {
        let camera = Camera::new(scene.camera);
        let origin = camera.origin;
        let prepared = scene
            .cylinders
            .iter()
            .map(|c| Prepared::new(c, origin, F::CENTRED))
            .collect();
        let bounds: Vec<_> = scene.cylinders.iter().map(|c| c.bounds()).collect();
        Tracer {
            camera,
            prepared,
            bvh: Bvh::build(&bounds, origin),
            _formula: std::marker::PhantomData,
        }
    }

    /// Nearest hit along unit direction `d` from the camera origin whose camera-space z lies
    /// in `[near_clip, far_clip]`. Ties go to the lower cylinder index (deterministic).
    #[inline]
    pub fn trace(&self, d: DVec3) -> Option<PixelHit<T>> {
        let spec = &self.camera.spec;
        let cos = d.dot(self.camera.forward);
        let (tmin, tmax) = (spec.near_clip / cos, spec.far_clip / cos);
        let (tmin_t, tmax_t) = (T::from_f64(tmin), T::from_f64(tmax));
        let dt = T::v3(d);
        let mut best: Option<PixelHit<T>> = None;
        let d32 = Vec3A::new(d.x as f32, d.y as f32, d.z as f32);
        self.bvh
            .traverse(d32, f32_down(tmin), f32_up(tmax), |index| {
                let limit = best.map_or(tmax_t, |b| b.hit.t);
                let hit = F::intersect(&self.prepared[index as usize], dt, tmin_t, limit)?;
                let closer =
                    best.is_none_or(|b| hit.t < b.hit.t || (hit.t == b.hit.t && index < b.index));
                if closer {
                    best = Some(PixelHit { index, hit });
                    Some(f32_up(hit.t.to_f64()))
                } else {
                    None
                }
            });
        best
    }

    /// World-space unit outward normal of a hit along `d`.
    #[inline]
    pub fn normal(&self, d: DVec3, h: &PixelHit<T>) -> DVec3 {
        T::v3_to_f64(F::normal(&self.prepared[h.index as usize], T::v3(d), h.hit))
    }
}

/// Output slices of one band of rows; `None` for AOVs not requested.
struct Band<'a> {
    distance: Option<&'a mut [f32]>,
    depth: Option<&'a mut [f32]>,
    normal: Option<[&'a mut [f32]; 3]>,
    position: Option<[&'a mut [f32]; 3]>,
    id: Option<&'a mut [u32]>,
}

/// Rows per parallel task: small enough to balance two cores, large enough to amortise.
const BAND_ROWS: usize = 4;

fn split<T>(v: &mut Option<Vec<T>>, len: usize) -> Vec<Option<&mut [T]>> {
    match v {
        Some(v) => v.chunks_mut(len).map(Some).collect(),
        None => Vec::new(),
    }
}

fn render_with<T: Real, F: Formula>(scene: &Scene, aovs: &[Aov]) -> Render {
    let tracer = Tracer::<T, F>::new(scene);
    let (w, h) = (
        tracer.camera.width() as usize,
        tracer.camera.height() as usize,
    );
    let n = w * h;
    let want = |a: Aov| aovs.contains(&a);
    let plane = |on: bool| on.then(|| vec![0f32; n]);
    let mut distance = plane(want(Aov::Distance));
    let mut depth = plane(want(Aov::Depth));
    let mut normal = [0; 3].map(|_| plane(want(Aov::Normal)));
    let mut position = [0; 3].map(|_| plane(want(Aov::Position)));
    let mut id = want(Aov::ShapeId).then(|| vec![0u32; n]);

    let chunk = BAND_ROWS * w;
    let bands_count = h.div_ceil(BAND_ROWS);
    let mut d_bands = split(&mut distance, chunk).into_iter();
    let mut z_bands = split(&mut depth, chunk).into_iter();
    let [n0, n1, n2] = &mut normal;
    let mut n_bands = (
        split(n0, chunk).into_iter(),
        split(n1, chunk).into_iter(),
        split(n2, chunk).into_iter(),
    );
    let [p0, p1, p2] = &mut position;
    let mut p_bands = (
        split(p0, chunk).into_iter(),
        split(p1, chunk).into_iter(),
        split(p2, chunk).into_iter(),
    );
    let mut id_bands = split(&mut id, chunk).into_iter();
    let bands: Vec<Band> = (0..bands_count)
        .map(|_| Band {
            distance: d_bands.next().flatten(),
            depth: z_bands.next().flatten(),
            normal: match (n_bands.0.next(), n_bands.1.next(), n_bands.2.next()) {
                (Some(Some(x)), Some(Some(y)), Some(Some(z))) => Some([x, y, z]),
                _ => None,
            },
            position: match (p_bands.0.next(), p_bands.1.next(), p_bands.2.next()) {
                (Some(Some(x)), Some(Some(y)), Some(Some(z))) => Some([x, y, z]),
                _ => None,
            },
            id: id_bands.next().flatten(),
        })
        .collect();

    let cam = &tracer.camera;
    let ids: Vec<u32> = scene.cylinders.iter().map(|c| c.id).collect();
    let hits: usize = bands
        .into_par_iter()
        .enumerate()
        .map(|(b, mut band)| {
            let row0 = b * BAND_ROWS;
            let rows = BAND_ROWS.min(h - row0);
            let mut hits = 0;
            for k in 0..rows * w {
                let (i, j) = ((k % w) as u32, (row0 + k / w) as u32);
                let d = cam.ray_dir(i, j);
                let Some(ph) = tracer.trace(d) else { continue };
                hits += 1;
                let t = ph.hit.t.to_f64();
                if let Some(s) = band.distance.as_deref_mut() {
                    s[k] = t as f32;
                }
                if let Some(s) = band.depth.as_deref_mut() {
                    s[k] = (t * d.dot(cam.forward)) as f32;
                }
                if let Some(s) = band.normal.as_mut() {
                    let nrm = tracer.normal(d, &ph);
                    (s[0][k], s[1][k], s[2][k]) = (nrm.x as f32, nrm.y as f32, nrm.z as f32);
                }
                if let Some(s) = band.position.as_mut() {
                    let p = cam.origin + d * t;
                    (s[0][k], s[1][k], s[2][k]) = (p.x as f32, p.y as f32, p.z as f32);
                }
                if let Some(s) = band.id.as_deref_mut() {
                    s[k] = ids[ph.index as usize];
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
    push("distance", distance.map(ChannelData::F32));
    push("depth", depth.map(ChannelData::F32));
    for (c, v) in ["normal.X", "normal.Y", "normal.Z"].iter().zip(normal) {
        push(c, v.map(ChannelData::F32));
    }
    for (c, v) in ["position.X", "position.Y", "position.Z"]
        .iter()
        .zip(position)
    {
        push(c, v.map(ChannelData::F32));
    }
    push("shape_id", id.map(ChannelData::U32));
    Render {
        image: AovImage {
            width: w,
            height: h,
            channels,
        },
        hits,
    }
}
