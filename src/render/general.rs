//! The general pixel path: one ray per pixel from [`Camera::pixel_ray`], for every camera
//! model other than the pinhole (whose screen tiles assume rays through one image plane).
//! Rays from the camera centre (the lens models) go through the tracer's BVH as any ray
//! does; the parallel rays of an orthographic camera start on its image plane, so their
//! cylinders are prepared for each ray's own origin as the BVH meets them.
//!
//! Depth is camera-space z where the ray's [`PixelRay::planar_depth`] says so, else the
//! Euclidean distance; `distance` is always the Euclidean distance from the ray's origin.

use super::planes::{Band, BandInputs, part_of};
use super::tracer::{PixelHit, Tracer, f32_down, f32_up};
use crate::accel::wide_bvh::Stack;
use crate::geometry::packet::nearer;
use crate::geometry::wide::Slabs8;
use crate::geometry::{BasicHit, Formula, Prepared, Real};
use crate::scene::camera::{PixelRay, Projection};
use glam::{DVec3, Vec3A};

/// Trace and shade the `rows` rows from `row0` of a non-pinhole camera, returning the hit
/// count.
pub(super) fn render_rows<T: Real, F: Formula, S: Slabs8>(
    slabs: S,
    fr: &BandInputs<T, F>,
    row0: usize,
    rows: usize,
    band: &mut Band,
) -> usize {
    let (tracer, cam) = (fr.tracer, &fr.tracer.camera);
    let w = cam.width() as usize;
    let parallel = matches!(cam.projection, Projection::Orthographic { .. });
    let mut stack = Stack::default();
    let mut last = None;
    let mut hits = 0;
    for k in 0..rows * w {
        let ray = cam.pixel_ray((k % w) as u32, (row0 + k / w) as u32);
        if !(ray.tmin <= ray.tmax) {
            continue;
        }
        if parallel {
            if let Some((hit, prepared)) = trace_from(fr, &ray) {
                let d = T::v3(ray.dir);
                let nrm = T::v3_to_f64(F::normal(&prepared, d, hit.hit));
                write(fr, band, k, &ray, hit, nrm);
                hits += 1;
            }
        } else if let Some(hit) =
            tracer.trace_with(slabs, &mut stack, last, ray.dir, ray.tmin, ray.tmax)
        {
            last = Some(hit.slot);
            write(fr, band, k, &ray, hit, tracer.normal(ray.dir, &hit));
            hits += 1;
        }
    }
    hits
}

/// The nearest hit of a ray that does not start at the tracer's origin, through its
/// binary BVH, each met cylinder prepared for the ray's origin; ties to the lower index.
fn trace_from<T: Real, F: Formula>(
    fr: &BandInputs<T, F>,
    ray: &PixelRay,
) -> Option<(PixelHit<T>, Prepared<T>)> {
    let tracer: &Tracer<T, F> = fr.tracer;
    let rel = ray.origin - tracer.camera.origin;
    let dt = T::v3(ray.dir);
    let (tmin, tmax) = (T::from_f64(ray.tmin), T::from_f64(ray.tmax));
    let mut best: Option<(PixelHit<T>, Prepared<T>)> = None;
    let mut visit = |slot: u32| {
        let index = tracer.order[slot as usize];
        let p = Prepared::new(&fr.cylinders[index as usize], ray.origin, F::CENTRED);
        let limit = best.as_ref().map_or(tmax, |b| b.0.hit.t);
        let hit: BasicHit<T> = F::intersect(&p, dt, tmin, limit)?;
        let closer = best
            .as_ref()
            .is_none_or(|b| nearer(hit.t, index, b.0.hit.t, b.0.index));
        if !closer {
            return None;
        }
        best = Some((PixelHit { index, slot, hit }, p));
        Some(f32_up(hit.t.to_f64()))
    };
    match &tracer.bvh {
        Some(bvh) => {
            let o = Vec3A::new(rel.x as f32, rel.y as f32, rel.z as f32);
            let d = Vec3A::new(ray.dir.x as f32, ray.dir.y as f32, ray.dir.z as f32);
            bvh.traverse_from(
                o,
                bvh.pad_for(rel),
                d,
                f32_down(ray.tmin),
                f32_up(ray.tmax),
                visit,
            );
        }
        None => {
            for slot in 0..tracer.order.len() as u32 {
                visit(slot);
            }
        }
    }
    best
}

/// Write the requested AOVs of `hit` along `ray` (world normal `nrm`) into sample `k`.
fn write<T: Real, F: Formula>(
    fr: &BandInputs<T, F>,
    band: &mut Band,
    k: usize,
    ray: &PixelRay,
    hit: PixelHit<T>,
    nrm: DVec3,
) {
    let cam = &fr.tracer.camera;
    let t = hit.hit.t.to_f64();
    let f = &mut band.f;
    if let Some(s) = f.distance.as_deref_mut() {
        s[k] = t as f32;
    }
    if let Some(s) = f.depth.as_deref_mut() {
        let z = if ray.planar_depth {
            (ray.origin - cam.origin).dot(cam.forward) + t * ray.dir.dot(cam.forward)
        } else {
            t
        };
        s[k] = z as f32;
    }
    if let Some(s) = f.normal.as_deref_mut() {
        s[3 * k..3 * k + 3].copy_from_slice(&[nrm.x as f32, nrm.y as f32, nrm.z as f32]);
    }
    if let Some(s) = f.position.as_deref_mut() {
        let p = ray.origin + ray.dir * t;
        s[3 * k..3 * k + 3].copy_from_slice(&[p.x as f32, p.y as f32, p.z as f32]);
    }
    if let Some(s) = band.id.as_deref_mut() {
        s[k] = fr.ids[hit.index as usize];
    }
    if let Some(s) = band.part.as_deref_mut() {
        s[k] = part_of(hit.hit.surface, nrm, ray.dir);
    }
    if let Some(s) = band.label.as_deref_mut() {
        s[k] = fr.labels[hit.index as usize];
    }
}
