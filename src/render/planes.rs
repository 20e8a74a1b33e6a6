//! The planes: the AOV buffers a render fills, cut into bands, what a hit writes into
//! them ([`shade`]), and the channels they become.

use super::RenderOptions;
use super::tracer::{PixelHit, Tracer};
use crate::geometry::{Formula, Real, Surface};
use crate::output::aov::{Channel, ChannelData};
use crate::scene::Aov;
use crate::scene::camera::Camera;
use glam::DVec3;

/// A zeroed output plane of `n` samples, in huge pages where the system has them (the
/// hint covers whole 2 MiB pages inside the plane only, so a band's few rows stay in
/// ordinary pages that the allocator reuses). Reserved fallibly: a refusal is the one-line
/// out-of-memory error and exit 1 (the callers' memory check has passed by then).
pub(super) fn zeroed<X: bytemuck::Zeroable>(n: usize) -> Vec<X> {
    let v = crate::mem::zeroed_or_exit(n, "an output plane of the render");
    crate::mem::huge_pages(&v);
    v
}

/// Output planes of the requested AOVs; `None` for the rest.
pub(super) struct Planes<P> {
    pub(super) distance: Option<P>,
    pub(super) depth: Option<P>,
    pub(super) normal: Option<[P; 3]>,
    pub(super) position: Option<[P; 3]>,
}

/// The requested planes of an image or a band (`shape_id` and `part` as u32).
pub(super) struct Samples {
    pub(super) f: Planes<Vec<f32>>,
    pub(super) id: Option<Vec<u32>>,
    pub(super) part: Option<Vec<u32>>,
}

/// One band's slices of every requested plane (`shape_id` and `part` as u32).
pub(super) struct Band<'a> {
    pub(super) f: Planes<&'a mut [f32]>,
    pub(super) id: Option<&'a mut [u32]>,
    pub(super) part: Option<&'a mut [u32]>,
}

/// Cut each requested plane into bands of `len` samples.
pub(super) fn bands<'a>(samples: &'a mut Samples, len: usize, count: usize) -> Vec<Band<'a>> {
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
pub(super) struct BandInputs<'a, T: Real, F: Formula> {
    pub(super) tracer: &'a Tracer<T, F>,
    /// `shape_id` per cylinder.
    pub(super) ids: &'a [u32],
    /// Image-plane offset per column (padded to whole tiles) and per row.
    pub(super) cols_off: &'a [f64],
    pub(super) rows_off: &'a [f64],
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

/// Write the requested AOVs of a hit along `d` into sample `k` of `band`.
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
pub(super) fn part_code<T: Real, F: Formula>(
    tracer: &Tracer<T, F>,
    d: DVec3,
    ph: &PixelHit<T>,
) -> u32 {
    match ph.hit.surface {
        Surface::Side if tracer.normal(d, ph).dot(d) > 0.0 => 2,
        Surface::Side => 1,
        Surface::Bottom => 3,
        Surface::Top => 4,
    }
}

/// The `normal_camera` planes: each stored world normal rotated into OpenCV camera axes
/// (x right = -left, y down = -true_up, z forward) in f64 and rounded once to f32; a miss
/// (0, 0, 0) stays 0. Rotating the stored f32 normal adds at most an ulp or so to its error.
pub(super) fn normals_in_camera(
    cam: &crate::scene::camera::Camera,
    n: &[Vec<f32>; 3],
) -> [Vec<f32>; 3] {
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

/// The output planes of `n` samples for the requested AOVs, zeroed (a miss is 0
/// everywhere): a whole image's, or one band's.
pub(super) fn output_planes(opts: &RenderOptions, n: usize) -> Samples {
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
pub(super) fn channels_of(opts: &RenderOptions, cam: &Camera, samples: Samples) -> Vec<Channel> {
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
    push(Aov::Distance.name(), planes.distance.map(ChannelData::F32));
    push(Aov::Depth.name(), planes.depth.map(ChannelData::F32));
    let normal_camera = want(Aov::NormalCamera)
        .then(|| planes.normal.as_ref().map(|n| normals_in_camera(cam, n)))
        .flatten();
    if !want(Aov::Normal) {
        planes.normal = None;
    }
    let [nx, ny, nz] = planes.normal.map(|v| v.map(Some)).unwrap_or_default();
    for (c, v) in Aov::Normal.spec().channels.iter().zip([nx, ny, nz]) {
        push(c, v.map(ChannelData::F32));
    }
    let [px, py, pz] = planes.position.map(|v| v.map(Some)).unwrap_or_default();
    for (c, v) in Aov::Position.spec().channels.iter().zip([px, py, pz]) {
        push(c, v.map(ChannelData::F32));
    }
    push(Aov::ShapeId.name(), id.map(ChannelData::U32));
    push(Aov::Part.name(), part.map(ChannelData::U32));
    let [cx, cy, cz] = normal_camera.map(|v| v.map(Some)).unwrap_or_default();
    for (c, v) in Aov::NormalCamera.spec().channels.iter().zip([cx, cy, cz]) {
        push(c, v.map(ChannelData::F32));
    }
    channels
}
