//! The planes: the AOV buffers a render fills, cut into bands, what a hit writes into
//! them ([`shade`]), and the channels they become.

use super::RenderOptions;
use super::tracer::{PixelHit, Tracer};
use crate::geometry::{Formula, Real, Surface};
use crate::image::{AovBuffer, ChannelData};
use crate::scene::Aov;
use crate::scene::camera::Camera;
use glam::DVec3;
use std::mem::MaybeUninit;

/// A zeroed output plane of `n` samples, in huge pages where the system has them (the
/// hint covers whole 2 MiB pages inside the plane only, so a band's few rows stay in
/// ordinary pages that the allocator reuses). Reserved fallibly: a refusal is the one-line
/// out-of-memory error and exit 1 (the callers' memory check has passed by then).
pub(super) fn zeroed<X: bytemuck::Zeroable>(n: usize) -> Vec<X> {
    let v = crate::mem::zeroed_or_exit(n, "an output plane of the render");
    crate::mem::huge_pages(&v);
    v
}

/// A plane of `n` samples not yet written (see [`UninitSamples`]), in huge pages where the
/// system has them, as [`zeroed`]; reserved fallibly, as [`zeroed`].
fn uninit<X>(n: usize) -> Vec<MaybeUninit<X>> {
    let v = crate::mem::uninit_or_exit(n, "an output plane of the render");
    crate::mem::huge_pages(&v);
    v
}

/// [`output_planes`] not yet written: the whole image's planes, which the bands of the
/// render zero as they start ([`Band::zeroed`]).
pub(super) fn uninit_planes(opts: &RenderOptions, n: usize) -> UninitSamples {
    let want = |a: Aov| opts.aovs.contains(&a);
    Samples {
        f: Planes {
            distance: want(Aov::Distance).then(|| uninit(n)),
            depth: want(Aov::Depth).then(|| uninit(n)),
            normal: (want(Aov::Normal) || want(Aov::NormalCamera)).then(|| uninit(3 * n)),
            position: want(Aov::Position).then(|| uninit(3 * n)),
            uv: want(Aov::Uv).then(|| uninit(2 * n)),
        },
        id: want(Aov::ShapeId).then(|| uninit(n)),
        part: want(Aov::Part).then(|| uninit(n)),
        label: want(Aov::Label).then(|| uninit(n)),
    }
}

/// Output planes of the requested AOVs; `None` for the rest. A vector AOV's plane holds
/// its pixels' `(x, y, z)` side by side (the layout of [`AovBuffer`]).
pub(super) struct Planes<P> {
    pub(super) distance: Option<P>,
    pub(super) depth: Option<P>,
    pub(super) normal: Option<P>,
    pub(super) position: Option<P>,
    pub(super) uv: Option<P>,
}

/// The requested planes of an image or a band (`shape_id` and `part` as u32); with
/// `F`, `U` the [`MaybeUninit`] of those, planes not yet written ([`UninitSamples`]).
pub(super) struct Samples<F = f32, U = u32> {
    pub(super) f: Planes<Vec<F>>,
    pub(super) id: Option<Vec<U>>,
    pub(super) part: Option<Vec<U>>,
    pub(super) label: Option<Vec<U>>,
}

/// Planes allocated but not written: each band zeroes its own slices on the thread that
/// traces it ([`Band::zeroed`]), so the whole image is never zeroed by one thread first.
pub(super) type UninitSamples = Samples<MaybeUninit<f32>, MaybeUninit<u32>>;

/// One band's slices of every requested plane (`shape_id` and `part` as u32).
pub(super) struct Band<'a, F = f32, U = u32> {
    pub(super) f: Planes<&'a mut [F]>,
    pub(super) id: Option<&'a mut [U]>,
    pub(super) part: Option<&'a mut [U]>,
    pub(super) label: Option<&'a mut [U]>,
}

/// `s` with every sample written 0 and read as initialised.
fn zero<X: bytemuck::Zeroable>(s: &mut [MaybeUninit<X>]) -> &mut [X] {
    // SAFETY: the bytes of `s` are all written (zero) before it is reborrowed as `[X]`,
    // and all-zero bytes are a valid `X` (`Zeroable`); `MaybeUninit<X>` has `X`'s layout.
    unsafe {
        std::ptr::write_bytes(s.as_mut_ptr(), 0, s.len());
        std::slice::from_raw_parts_mut(s.as_mut_ptr().cast::<X>(), s.len())
    }
}

impl<'a> Band<'a, MaybeUninit<f32>, MaybeUninit<u32>> {
    /// The band with every sample zero (a miss), ready to be traced.
    pub(super) fn zeroed(self) -> Band<'a> {
        Band {
            f: Planes {
                distance: self.f.distance.map(zero),
                depth: self.f.depth.map(zero),
                normal: self.f.normal.map(zero),
                position: self.f.position.map(zero),
                uv: self.f.uv.map(zero),
            },
            id: self.id.map(zero),
            part: self.part.map(zero),
            label: self.label.map(zero),
        }
    }
}

/// `v` read as initialised.
///
/// # Safety
/// Every element of `v` has been written.
unsafe fn assume_init<X>(v: Vec<MaybeUninit<X>>) -> Vec<X> {
    let mut v = std::mem::ManuallyDrop::new(v);
    // SAFETY: `MaybeUninit<X>` has `X`'s layout, so the allocation is a valid `Vec<X>` of
    // the same length and capacity, and the caller promises every element is written.
    unsafe { Vec::from_raw_parts(v.as_mut_ptr().cast::<X>(), v.len(), v.capacity()) }
}

impl UninitSamples {
    /// The planes, read as written.
    ///
    /// # Safety
    /// Every sample has been written: each band of [`bands`] over all of them made
    /// [`Band::zeroed`] (which writes its whole band).
    pub(super) unsafe fn assume_init(self) -> Samples {
        // SAFETY: the caller's promise, plane by plane.
        let init = |v: Option<Vec<MaybeUninit<f32>>>| v.map(|v| unsafe { assume_init(v) });
        let init_u = |v: Option<Vec<MaybeUninit<u32>>>| v.map(|v| unsafe { assume_init(v) });
        Samples {
            f: Planes {
                distance: init(self.f.distance),
                depth: init(self.f.depth),
                normal: init(self.f.normal),
                position: init(self.f.position),
                uv: init(self.f.uv),
            },
            id: init_u(self.id),
            part: init_u(self.part),
            label: init_u(self.label),
        }
    }
}

/// Cut each requested plane into bands of `len` pixels.
pub(super) fn bands<'a, F, U>(
    samples: &'a mut Samples<F, U>,
    len: usize,
    count: usize,
) -> Vec<Band<'a, F, U>> {
    let Samples { f, id, part, label } = samples;
    fn cut<X>(
        v: Option<&mut Vec<X>>,
        len: usize,
        count: usize,
    ) -> std::vec::IntoIter<Option<&mut [X]>> {
        match v {
            Some(v) => v.chunks_mut(len).map(Some).collect::<Vec<_>>().into_iter(),
            None => (0..count).map(|_| None).collect::<Vec<_>>().into_iter(),
        }
    }
    let mut d = cut(f.distance.as_mut(), len, count);
    let mut z = cut(f.depth.as_mut(), len, count);
    let mut n = cut(f.normal.as_mut(), 3 * len, count);
    let mut p = cut(f.position.as_mut(), 3 * len, count);
    let mut uv = cut(f.uv.as_mut(), 2 * len, count);
    let mut ids = cut(id.as_mut(), len, count);
    let mut parts = cut(part.as_mut(), len, count);
    let mut labels = cut(label.as_mut(), len, count);
    (0..count)
        .map(|_| Band {
            f: Planes {
                distance: d.next().flatten(),
                depth: z.next().flatten(),
                normal: n.next().flatten(),
                position: p.next().flatten(),
                uv: uv.next().flatten(),
            },
            id: ids.next().flatten(),
            part: parts.next().flatten(),
            label: labels.next().flatten(),
        })
        .collect()
}

/// What every band of a render shares.
pub(super) struct BandInputs<'a, T: Real, F: Formula> {
    pub(super) tracer: &'a Tracer<'a, T, F>,
    /// `shape_id` per cylinder, for the `shape_id` AOV; empty otherwise.
    pub(super) ids: &'a [u32],
    /// `label` per cylinder, for the `label` AOV; empty otherwise.
    pub(super) labels: &'a [u32],
    /// Image-plane offset per column (padded to whole tiles) and per row.
    pub(super) cols_off: &'a [f64],
    pub(super) rows_off: &'a [f64],
    /// The cylinders by scene index, for rays that do not start at the camera centre
    /// (orthographic) and for the `uv` AOV.
    pub(super) cylinders: &'a [crate::geometry::Cylinder],
}

impl<T: Real, F: Formula> BandInputs<'_, T, F> {
    /// Pixel `(x, y)`'s ray: unit direction and ray parameter range, the same bits as the
    /// tiles' (see [`Camera::dir_and_length`] and [`Camera::clip_range`]).
    #[inline(always)]
    pub(super) fn pixel_ray(&self, x: usize, y: usize) -> (DVec3, f64, f64) {
        let cam = &self.tracer.camera;
        let (d, len) = cam.dir_and_length(self.cols_off[x], self.rows_off[y]);
        let (tmin, tmax) = cam.clip_range(len);
        (d, tmin, tmax)
    }
}

/// Write the requested AOVs of a pinhole hit along `d` (from the camera centre) into
/// sample `k` of `band`.
#[inline(always)]
pub(super) fn shade<T: Real, F: Formula>(
    fr: &BandInputs<T, F>,
    band: &mut Band,
    k: usize,
    d: DVec3,
    ph: PixelHit<T>,
) {
    let cam = &fr.tracer.camera;
    let t = ph.hit.t.to_f64();
    let hit = Shaded {
        origin: cam.origin,
        dir: d,
        t,
        index: ph.index,
        surface: ph.hit.surface,
    };
    let nrm = if needs_normal(band, ph.hit.surface) {
        fr.tracer.normal(d, &ph)
    } else {
        DVec3::ZERO
    };
    fill(fr, band, k, &hit, t * d.dot(cam.forward), nrm);
}

/// Whether [`fill`] reads the normal of a hit on `surface`: for its plane, or for a side's
/// facing (`part`).
#[inline(always)]
pub(super) fn needs_normal(band: &Band, surface: Surface) -> bool {
    band.f.normal.is_some() || (band.part.is_some() && surface == Surface::Side)
}

/// A hit as every camera path hands it on: the ray's origin and unit direction, the
/// hit's ray parameter, the cylinder (scene index) and the surface.
pub(super) struct Shaded {
    pub(super) origin: DVec3,
    pub(super) dir: DVec3,
    pub(super) t: f64,
    pub(super) index: u32,
    pub(super) surface: Surface,
}

/// Write the requested AOVs of `hit` into sample `k` of `band`: the one place each AOV's
/// value is made from a hit. `depth` is the hit's, as its camera model measures it;
/// `normal` its world normal where [`needs_normal`] says it is read (else anything).
///
/// Plain values, no closures: a closure is a function of its own, compiled without the
/// AVX2 of the tile walk that inlines this, and it slowed the trace by a quarter.
#[inline(always)]
pub(super) fn fill<T: Real, F: Formula>(
    fr: &BandInputs<T, F>,
    band: &mut Band,
    k: usize,
    hit: &Shaded,
    depth: f64,
    normal: DVec3,
) {
    let t = hit.t;
    let f = &mut band.f;
    if let Some(s) = f.distance.as_deref_mut() {
        s[k] = t as f32;
    }
    if let Some(s) = f.depth.as_deref_mut() {
        s[k] = depth as f32;
    }
    if let Some(s) = f.normal.as_deref_mut() {
        let nrm = normal;
        s[3 * k..3 * k + 3].copy_from_slice(&[nrm.x as f32, nrm.y as f32, nrm.z as f32]);
    }
    if let Some(s) = f.position.as_deref_mut() {
        let p = hit.origin + hit.dir * t;
        s[3 * k..3 * k + 3].copy_from_slice(&[p.x as f32, p.y as f32, p.z as f32]);
    }
    if let Some(s) = band.id.as_deref_mut() {
        s[k] = fr.ids[hit.index as usize];
    }
    if let Some(s) = band.part.as_deref_mut() {
        s[k] = part_of(hit.surface, normal, hit.dir);
    }
    if let Some(s) = band.label.as_deref_mut() {
        s[k] = fr.labels[hit.index as usize];
    }
    if let Some(s) = f.uv.as_deref_mut() {
        let p = hit.origin + hit.dir * t;
        s[2 * k..2 * k + 2].copy_from_slice(&uv(&fr.cylinders[hit.index as usize], p, hit.surface));
    }
}

/// The `uv` AOV of a hit at `p` on `surface` of `c`, as Mitsuba 3's `cylinder` reports it
/// on the side: `u = φ / 2π` in `[0, 1)`, φ the angle around the axis in the frame
/// Mitsuba builds for a cylinder from `p0` to `p1`, and `v` the axial fraction from `p0`
/// in `[0, 1]`. On a cap `u` is the same angle and `v` the distance from the axis over the
/// radius.
///
/// Mitsuba's frame is its `coordinate_system(n)` for the unit axis `n` (Duff et al.,
/// "Building an Orthonormal Basis, Revisited", JCGT 2017): with `σ = sign(n.z)`,
/// `a = -1 / (σ + n.z)` and `b = n.x·n.y·a`, the local x axis is
/// `s = (1 + σ·n.x²·a, σ·b, -σ·n.x)` and the local y axis `t = (b, σ + n.y²·a, -n.y)`.
/// Mitsuba computes it in float32 from the exported `p0`, `p1`; this is the same frame in
/// f64, so `u` agrees to float32 rounding except within a rounding of the seam `u = 0`,
/// where one side reads `u ≈ 1` (compare `u` modulo 1).
pub(super) fn uv(c: &crate::geometry::Cylinder, p: DVec3, surface: Surface) -> [f32; 2] {
    let n = c.axis;
    let sign = 1f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let s_axis = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let t_axis = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    let local = p - c.base;
    let (x, y) = (local.dot(s_axis), local.dot(t_axis));
    let turn = y.atan2(x) / std::f64::consts::TAU;
    let turn = if turn < 0.0 { turn + 1.0 } else { turn };
    // A turn just below 1 can round up to 1 in float32: that is the seam, u = 0.
    let u = match turn as f32 {
        u if u >= 1.0 => 0.0,
        u => u,
    };
    let v = match surface {
        Surface::Side => local.dot(n) / c.height,
        Surface::Bottom | Surface::Top => x.hypot(y) / c.radius,
    };
    [u, v.clamp(0.0, 1.0) as f32]
}

/// The `part` AOV of a hit: 1 side from outside, 2 side from inside, 3 bottom cap, 4 top
/// cap. The side's facing is the sign of `normal · d`, as the Mitsuba reference decides it
/// (the outward normal points away from the camera on the wall's inner face).
#[inline(always)]
pub(super) fn part_code<T: Real, F: Formula>(
    tracer: &Tracer<T, F>,
    d: DVec3,
    ph: &PixelHit<T>,
) -> u32 {
    match ph.hit.surface {
        Surface::Side => part_of(Surface::Side, tracer.normal(d, ph), d),
        s => part_of(s, DVec3::ZERO, d),
    }
}

/// [`part_code`] from the surface, the world normal `nrm` (read for the side only) and
/// the ray direction `d`.
#[inline(always)]
pub(super) fn part_of(surface: Surface, nrm: DVec3, d: DVec3) -> u32 {
    match surface {
        Surface::Side if nrm.dot(d) > 0.0 => 2,
        Surface::Side => 1,
        Surface::Bottom => 3,
        Surface::Top => 4,
    }
}

/// The `normal_camera` buffer: each stored world normal rotated into OpenCV camera axes
/// (x right = -left, y down = -true_up, z forward) in f64 and rounded once to f32; a miss
/// (0, 0, 0) stays 0. Rotating the stored f32 normal adds at most an ulp or so to its error.
pub(super) fn normals_in_camera(cam: &crate::scene::camera::Camera, n: &[f32]) -> Vec<f32> {
    let axes = [-cam.left, -cam.true_up, cam.forward];
    let mut out = crate::mem::zeroed_or_exit::<f32>(n.len(), "the normal_camera buffer");
    for (o, v) in out.chunks_exact_mut(3).zip(n.chunks_exact(3)) {
        let v = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
        if v == DVec3::ZERO {
            continue;
        }
        for (o, a) in o.iter_mut().zip(axes) {
            *o = a.dot(v) as f32;
        }
    }
    out
}

/// The output planes of `n` pixels for the requested AOVs, zeroed (a miss is 0
/// everywhere): a whole image's, or one band's.
pub(super) fn output_planes(opts: &RenderOptions, n: usize) -> Samples {
    let want = |a: Aov| opts.aovs.contains(&a);
    let plane = || zeroed::<f32>(n);
    let ids = || zeroed::<u32>(n);
    let planes = Planes {
        distance: want(Aov::Distance).then(plane),
        depth: want(Aov::Depth).then(plane),
        // Camera-frame normals are the world normals rotated: both need these planes.
        normal: (want(Aov::Normal) || want(Aov::NormalCamera)).then(|| zeroed::<f32>(3 * n)),
        position: want(Aov::Position).then(|| zeroed::<f32>(3 * n)),
        uv: want(Aov::Uv).then(|| zeroed::<f32>(2 * n)),
    };
    Samples {
        f: planes,
        id: want(Aov::ShapeId).then(ids),
        part: want(Aov::Part).then(ids),
        label: want(Aov::Label).then(ids),
    }
}

/// The buffers of filled planes, in the order every image of a render has them (a whole
/// image and each of its bands alike): the requested AOVs, `normal_camera` rotated from
/// the world normals here.
pub(super) fn buffers_of(opts: &RenderOptions, cam: &Camera, samples: Samples) -> Vec<AovBuffer> {
    let Samples {
        f: mut planes,
        id,
        part,
        label,
    } = samples;
    let want = |a: Aov| opts.aovs.contains(&a);
    let normal_camera = want(Aov::NormalCamera)
        .then(|| planes.normal.as_deref().map(|n| normals_in_camera(cam, n)))
        .flatten();
    if !want(Aov::Normal) {
        planes.normal = None;
    }
    [
        (Aov::Distance, planes.distance.map(ChannelData::F32)),
        (Aov::Depth, planes.depth.map(ChannelData::F32)),
        (Aov::Normal, planes.normal.map(ChannelData::F32)),
        (Aov::Position, planes.position.map(ChannelData::F32)),
        (Aov::ShapeId, id.map(ChannelData::U32)),
        (Aov::Part, part.map(ChannelData::U32)),
        (Aov::NormalCamera, normal_camera.map(ChannelData::F32)),
        (Aov::Label, label.map(ChannelData::U32)),
        (Aov::Uv, planes.uv.map(ChannelData::F32)),
    ]
    .into_iter()
    .filter_map(|(a, data)| Some(AovBuffer::new(a.spec().channels, data?)))
    .collect()
}
