//! The general pixel path: one ray per pixel from [`Camera::pixel_ray`], for every camera
//! model other than the pinhole (whose screen tiles assume rays through one image plane).
//! Rays from the camera centre (the lens models) go through the tracer's BVH as any ray
//! does; the parallel rays of an orthographic camera start on its image plane, so their
//! cylinders are prepared for each ray's own origin as the BVH meets them.
//!
//! Depth is camera-space z where the ray's [`PixelRay::planar_depth`] says so, else the
//! Euclidean distance; `distance` is always the Euclidean distance from the ray's origin.

use super::planes::{Band, BandInputs, Shaded, fill};
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
        // A pixel without a ray (never so for a validated camera) stays a miss.
        if ray.tmin > ray.tmax || ray.tmin.is_nan() {
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

/// Write the requested AOVs of `hit` along `ray` (world normal `nrm`) into sample `k`:
/// depth as the ray's model says (planar or Euclidean).
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
    let shaded = Shaded {
        origin: ray.origin,
        dir: ray.dir,
        t,
        index: hit.index,
        surface: hit.hit.surface,
    };
    let depth = if ray.planar_depth {
        (ray.origin - cam.origin).dot(cam.forward) + t * ray.dir.dot(cam.forward)
    } else {
        t
    };
    fill(fr, band, k, &shaded, depth, nrm);
}

#[cfg(test)]
mod tests {
    use crate::geometry::{Formula, Prepared, Stable};
    use crate::image::ChannelData;
    use crate::render::{Accel, RenderOptions, render};
    use crate::scene::Aov;
    use crate::scene::camera::{Camera, Projection};

    /// The orthographic path through the BVH (rays off its build origin, boxes padded)
    /// finds, for every pixel, the hit that testing every cylinder finds: the same
    /// cylinder and the same distance to the bit, on a dense tangle, seen from outside and
    /// with the image plane cutting through it.
    #[test]
    fn orthographic_bvh_matches_testing_every_cylinder() {
        let mut hits = 0;
        for (n, dist_scale) in [(1500, 1.0), (1500, 0.3)] {
            let mut sc = crate::bench::dense_scene(n, 9, 48, 36);
            let c = &mut sc.camera;
            c.origin = c.target + (c.origin - c.target) * dist_scale;
            let reach = (c.target - c.origin).length();
            c.projection = Projection::Orthographic {
                half_width: 0.4 * reach,
                half_height: 0.4 * reach * 36.0 / 48.0,
            };
            sc.cameras = vec![sc.camera];
            let o = RenderOptions {
                accel: Accel::Tiles,
                ..RenderOptions::new(vec![Aov::Distance, Aov::ShapeId])
            };
            let img = render(&sc, &o).image;
            let (ChannelData::F32(dist), ChannelData::U32(ids)) =
                (&img.buffers[0].data, &img.buffers[1].data)
            else {
                panic!("distance, then shape_id");
            };
            let cam = Camera::new(sc.camera);
            for j in 0..36u32 {
                for i in 0..48u32 {
                    let ray = cam.pixel_ray(i, j);
                    let mut best: Option<(f64, u32)> = None;
                    for (k, cyl) in sc.cylinders.iter().enumerate() {
                        let p = Prepared::<f64>::new(cyl, ray.origin, Stable::CENTRED);
                        let limit = best.map_or(ray.tmax, |b| b.0);
                        if let Some(h) = Stable::intersect(&p, ray.dir, ray.tmin, limit)
                            && best.is_none_or(|b| h.t < b.0)
                        {
                            best = Some((h.t, k as u32));
                        }
                    }
                    let px = (j * 48 + i) as usize;
                    let want = best.map_or((0.0f32, 0), |(t, k)| {
                        (t as f32, sc.cylinders[k as usize].id)
                    });
                    assert_eq!((dist[px], ids[px]), want, "pixel ({i}, {j})");
                    hits += best.is_some() as usize;
                }
            }
        }
        eprintln!("{hits} of 3456 pixels hit");
        assert!(hits > 1000, "{hits} of 3456 pixels hit");
    }
}
