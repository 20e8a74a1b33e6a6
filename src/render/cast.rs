//! Rays from anywhere: the nearest hit of any ray (origin, direction, parameter range)
//! through the same tracer, kernels and shading a render uses, in f64 or f32 as the kernel
//! says. Directions need not be unit vectors: `t` is in units of the direction's length.
//!
//! Rays are grouped by origin, and each distinct origin prepares the scene once, as a
//! render prepares it for its camera (cylinders in the frame of that origin, a BVH when the
//! group has enough rays to repay one): the kernels take rays that start at the origin of
//! their frame. A ray from the camera along [`Camera::pixel_vector`] with `t` in
//! `[near_clip, far_clip]` is therefore the render's pixel ray, bit for bit, and its hit
//! parameter times the direction's length is the render's `distance` before rounding.
//!
//! Continuing from a hit (a bounce, a shadow ray) as pbrt-v4 does: [`RayHit::position`] is
//! the hit moved onto its surface, [`RayHit::position_error`] bounds its distance from it
//! per axis ([`surface_point`] derives the bound), and [`RayHit::spawn`] gives the origin
//! past that bound on the side the new direction leaves by. Cast from there with
//! `t_min = 0` and the same kernel precision, a ray leaving outward never re-hits the
//! surface, and one going inward finds the far wall (`tests/exact.rs`).
//!
//! [`Camera::pixel_vector`]: crate::scene::camera::Camera::pixel_vector

use super::planes::part_code;
use super::{PixelHit, Tracer};
use crate::accel::bvh::{Bvh, LEAF_SIZE};
use crate::accel::wide_bvh::WideBvh;
use crate::geometry::cylinder::orthonormal_basis;
use crate::geometry::kernel::KernelFn;
use crate::geometry::packet::PacketFormula;
use crate::geometry::wide::Simd;
use crate::geometry::{Cylinder, Formula, Kernel, Prepared, Real, Surface};
use crate::scene::camera::Camera;
use crate::scene::{MAX_COORD, Scene};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// One ray: the points `origin + t·dir` with `t_min <= t <= t_max`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Where the ray starts, world units.
    pub origin: DVec3,
    /// Direction, any non-zero finite length.
    pub dir: DVec3,
    /// Smallest ray parameter counted, `>= 0`, in units of `|dir|`.
    pub t_min: f64,
    /// Largest ray parameter counted (may be infinite), `>= t_min`.
    pub t_max: f64,
}

/// The nearest hit of a [`Ray`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit {
    /// Ray parameter in units of `|dir|`: the hit is at `origin + t·dir`.
    pub t: f64,
    /// World-space unit outward normal (the `normal` AOV).
    pub normal: DVec3,
    /// The cylinder's index in the scene.
    pub index: u32,
    /// The cylinder's id (the `shape_id` AOV).
    pub id: u32,
    /// The part hit, as the `part` AOV codes it (1-4).
    pub part: u32,
    /// The hit point on the surface: `origin + t·dir` moved along the normal onto the
    /// surface it hit (pbrt-v4's reprojection), in world units.
    pub position: DVec3,
    /// Per world axis, a bound on how far `position` may lie off that surface, and on how
    /// far the stable kernels may misjudge which side of it a point near it is: see
    /// [`surface_point`]. [`RayHit::spawn`] starts continuing rays past it.
    pub position_error: DVec3,
}

impl RayHit {
    /// Origin for a ray continuing from this hit in direction `dir`: [`offset_origin`].
    pub fn spawn(&self, dir: DVec3) -> DVec3 {
        offset_origin(self.position, self.position_error, self.normal, dir)
    }
}

/// The hit at ray parameter `t` of `origin + t·dir` on `surface` of `cyl`, moved onto that
/// surface, the per-axis bound on its distance from it (see the derivation inside), and
/// the outward normal at that very point. `normal` is the kernel's outward normal (used
/// only when the side hit lies on the axis in f64, where the point carries no direction);
/// `roundoff` is the unit roundoff of the kernel that found the hit and will trace rays
/// spawned from it.
///
/// Why the normal is recomputed: far from the cylinder, `o + t·d` is off along the surface
/// by ~ε·|o - c|, so the kernel's normal (of its own point) and the normal at `position`
/// can differ by that over `r`: up to 1e-6 rad seen from 1e8 radii away. A direction
/// within that of the tangent plane would then leave by one normal and enter by the other.
/// For a side hit the normal is the radial direction of the same `(x, y)` the position is
/// built from, so the two agree to a few ε; in f64 that is the kernel's normal, bit for bit
/// (the same operations on the same values).
///
/// Why reproject rather than bound `origin + t·dir`: the error of `t` grows as the ray
/// grazes the surface (the problem's conditioning), and bounding it would need the
/// kernel's forward error. Moving the point along the normal onto the surface leaves only
/// an error along the surface (harmless: a ray continuing from there does not re-hit the
/// surface for being slid along it) and the few roundings below, whatever the ray.
pub fn surface_point(
    cyl: &Cylinder,
    origin: DVec3,
    dir: DVec3,
    t: f64,
    surface: Surface,
    normal: DVec3,
    roundoff: f64,
) -> (DVec3, DVec3, DVec3) {
    let n = cyl.axis;
    let (u, v) = orthonormal_basis(n);
    let (r, h) = (cyl.radius, cyl.height);
    // The hit in the cylinder's (u, v, n) frame, as the kernels see it.
    let oc = origin - cyl.base;
    let x0 = oc.dot(u) + t * dir.dot(u);
    let y0 = oc.dot(v) + t * dir.dot(v);
    let z0 = oc.dot(n) + t * dir.dot(n);
    let rho = (x0 * x0 + y0 * y0).sqrt();
    let (x, y, z, normal) = match surface {
        // Radially onto ρ = r; along the axis only into [0, h] (a slide along the side).
        // The normal as `Stable::normal` forms it: u·(x/ρ) + v·(y/ρ).
        Surface::Side if rho > 0.0 => {
            let (nx, ny) = (x0 / rho, y0 / rho);
            (r * nx, r * ny, z0.clamp(0.0, h), u * nx + v * ny)
        }
        Surface::Side => {
            let (nx, ny) = (normal.dot(u), normal.dot(v));
            (r * nx, r * ny, z0.clamp(0.0, h), normal)
        }
        // Onto the cap's plane exactly, and into its disk.
        Surface::Top | Surface::Bottom => {
            let s = if rho > r { r / rho } else { 1.0 };
            let (z, nrm) = if surface == Surface::Top {
                (h, n)
            } else {
                (0.0, -n)
            };
            (x0 * s, y0 * s, z, nrm)
        }
    };
    let position = cyl.base + (u * x + v * y + n * z);
    // The bound, per world axis k, with u = 2⁻⁵³ and γ_m = m·u/(1 - m·u):
    // - world from local: p_k = b_k + (u_k·x + v_k·y + n_k·z), three products and three
    //   sums, off the exact value of the same expression by at most
    //   γ_4·(|b_k| + |u_k·x| + |v_k·y| + |n_k·z|) (Higham's bound for a dot product; b_k
    //   as a fourth term with factor 1). Taken as γ_5 for margin.
    // - local point off the surface: on a cap z is the plane exactly; on the side
    //   |(x, y)| = r(1 ± 5u) (ρ: two squares, a sum and a root, 2u; x0/ρ, u; times r,
    //   u; the error of x0, y0 themselves only turns the direction).
    // - frame: u, v, n are orthonormal to within a few u, and the stored axis is a unit
    //   vector to within 2u, so the exact b + u·x + v·y + n·z is within ~6u·(r + |z|) of
    //   the exact surface.
    // - the kernel reading a point near the surface: `o - c` rounded (u per component of
    //   the result), its dots with u, v, n (γ_3 of |o - c| ≤ r + |z|), so ρ and the
    //   axial coordinate are off by ~6u·(r + |z|) in f64; an f32 kernel then rounds the
    //   local coordinates and forms its discriminant in f32: a few u₃₂·r.
    // The last three together are below 16u·(r + |z|) + 16u_T·r, added to every axis:
    // the offset along the normal is at least that, whatever the normal's direction.
    let u64 = f64::EPSILON / 2.0;
    let gamma5 = 5.0 * u64 / (1.0 - 5.0 * u64);
    let terms = cyl.base.abs() + (u * x).abs() + (v * y).abs() + (n * z).abs();
    let iso = 16.0 * u64 * (r + z.abs()) + 16.0 * roundoff * r;
    (position, terms * gamma5 + DVec3::splat(iso), normal)
}

/// Origin for a ray continuing from a hit at `position` (with per-axis error bound
/// `error` and outward unit normal `normal`) in direction `dir`: `position` moved by
/// `|normal|·error` along `normal`, toward the side `dir` leaves by (`dir·normal >= 0`:
/// outward; `< 0`: into the solid), each coordinate then rounded one float further away
/// so the rounding of the sum cannot bring it back into the error box (pbrt-v4's
/// `OffsetRayOrigin`). A zero normal (a miss) gives NaN.
pub fn offset_origin(position: DVec3, error: DVec3, normal: DVec3, dir: DVec3) -> DVec3 {
    if normal == DVec3::ZERO {
        return DVec3::NAN;
    }
    // The error box's extent along the normal: the largest |n·e| over the box's corners.
    let reach = normal.abs().dot(error);
    let mut offset = normal * reach;
    if dir.dot(normal) < 0.0 {
        offset = -offset;
    }
    let p = position + offset;
    DVec3::from_array(std::array::from_fn(|k| {
        if offset[k] > 0.0 {
            p[k].next_up()
        } else if offset[k] < 0.0 {
            p[k].next_down()
        } else {
            p[k]
        }
    }))
}

/// Rays of a group with fewer than this many rays test every cylinder: a BVH costs more to
/// build than it saves them.
const BVH_MIN_RAYS: usize = 8;

/// The nearest hit of every ray with the kernel `kernel`, on the current rayon pool; the
/// error names the first bad ray (`rays[3].dir: ...`).
pub fn cast(scene: &Scene, kernel: Kernel, rays: &[Ray]) -> Result<Vec<Option<RayHit>>, String> {
    let never = AtomicBool::new(false);
    Ok(cast_until(scene, kernel, rays, &never)?.unwrap_or_default())
}

/// [`cast`], given up once `stop` is set (by another thread: the Python package on
/// Ctrl-C): rays not cast by then are not, and the result is `None`.
pub fn cast_until(
    scene: &Scene,
    kernel: Kernel,
    rays: &[Ray],
    stop: &AtomicBool,
) -> Result<Option<Vec<Option<RayHit>>>, String> {
    for (i, r) in rays.iter().enumerate() {
        check_ray(i, r)?;
    }
    struct Run<'a>(&'a Scene, &'a [Ray], &'a AtomicBool);
    impl KernelFn for Run<'_> {
        type Output = Option<Vec<Option<RayHit>>>;
        fn call<T: Simd, F: PacketFormula>(self) -> Self::Output {
            cast_with::<T, F>(self.0, self.1, self.2)
        }
    }
    Ok(kernel.dispatch(Run(scene, rays, stop)))
}

fn check_ray(i: usize, r: &Ray) -> Result<(), String> {
    use crate::scene::num;
    let v = |x: DVec3| format!("[{}, {}, {}]", num(x.x), num(x.y), num(x.z));
    if !r.origin.is_finite() || r.origin.abs().max_element() > MAX_COORD {
        return Err(format!(
            "rays[{i}].origin: must be finite with magnitude <= {MAX_COORD:e}, got {}",
            v(r.origin)
        ));
    }
    let (len, _) = length_and_unit(r.dir);
    if !(r.dir.is_finite() && len > 0.0) {
        return Err(format!(
            "rays[{i}].direction: must be finite and non-zero, got {}",
            v(r.dir)
        ));
    }
    if !len.is_finite() {
        return Err(format!(
            "rays[{i}].direction: its length must be at most {:e}, got {}",
            f64::MAX,
            v(r.dir)
        ));
    }
    if !(r.t_min >= 0.0 && r.t_min.is_finite()) {
        return Err(format!(
            "rays[{i}].t_min: must be finite and >= 0, got {}",
            num(r.t_min)
        ));
    }
    if r.t_max.is_nan() || r.t_max < r.t_min {
        return Err(format!(
            "rays[{i}].t_max: must be >= t_min ({}), got {}",
            num(r.t_min),
            num(r.t_max)
        ));
    }
    Ok(())
}

/// `dir`'s length and unit vector: `length()` and `dir * (1 / len)`, a render's own
/// arithmetic for its pixel rays (so a cast of them matches it bit for bit), where those
/// are finite and non-zero; else, for a finite non-zero direction whose squared length
/// leaves f64's range (`[1e300, 0, 0]`, `[1e-300, 0, 0]`), taken from `dir` divided by its
/// largest component. A zero or non-finite direction gives a length of 0 or NaN.
fn length_and_unit(dir: DVec3) -> (f64, DVec3) {
    let len = dir.length();
    let d = dir * (1.0 / len);
    if len.is_finite() && len > 0.0 && d.is_finite() {
        return (len, d);
    }
    let scale = dir.abs().max_element();
    if !(scale.is_finite() && scale > 0.0) {
        return (if dir.is_finite() { 0.0 } else { f64::NAN }, d);
    }
    let u = dir / scale;
    let n = u.length();
    (scale * n, u * (1.0 / n))
}

/// The hits of `rays`, or `None` once `stop` is set: the rays in flight finish, and then
/// nothing more is cast or gathered.
///
/// Hits are found in chunks of [`CAST_CHUNK`] rays, each its own `Vec`: after a stop,
/// rayon's `Option` collect (which still gathers every item it saw before the `None`)
/// moves only those chunks' handles. Collecting each ray's hit instead copied every hit
/// found so far, a third of a second after 3 s of 8 million rays.
fn cast_with<T: Real, F: Formula>(
    scene: &Scene,
    rays: &[Ray],
    stop: &AtomicBool,
) -> Option<Vec<Option<RayHit>>> {
    // Group by origin, bit for bit: rays of one group share one prepared scene. The sort
    // is stable, so rays from one origin (a scan) keep their order and need no scatter.
    let key = |r: &Ray| r.origin.to_array().map(f64::to_bits);
    let mut by_origin: Vec<u32> = (0..rays.len() as u32).collect();
    by_origin.par_sort_by_key(|&i| key(&rays[i as usize]));
    let groups: Vec<&[u32]> = by_origin
        .chunk_by(|&a, &b| key(&rays[a as usize]) == key(&rays[b as usize]))
        .collect();
    let bounds: Vec<_> = scene.cylinders.par_iter().map(|c| c.bounds()).collect();
    // A `None` item ends the collection into an `Option` as soon as rayon sees it.
    let running = || (!stop.load(Ordering::Relaxed)).then_some(());
    let found: Vec<Vec<Vec<Option<RayHit>>>> = groups
        .par_iter()
        .map(|group| {
            running()?;
            let origin = rays[group[0] as usize].origin;
            let tracer = tracer_at::<T, F>(scene, &bounds, origin, group.len());
            group
                .par_chunks(CAST_CHUNK)
                .map(|chunk| {
                    running()?;
                    let hit = |&i: &u32| cast_one(scene, &tracer, &rays[i as usize]);
                    Some(chunk.iter().map(hit).collect::<Vec<_>>())
                })
                .collect::<Option<Vec<_>>>()
        })
        .collect::<Option<Vec<_>>>()?;
    running()?;
    // The hits in `by_origin`'s order.
    let hits = found.into_iter().flatten().flatten();
    if by_origin.iter().enumerate().all(|(k, &i)| k == i as usize) {
        let mut out = Vec::with_capacity(rays.len());
        out.extend(hits);
        return Some(out);
    }
    let mut out = vec![None; rays.len()];
    for (&i, hit) in by_origin.iter().zip(hits) {
        out[i as usize] = hit;
    }
    Some(out)
}

/// Rays cast between two looks at the stop flag, and the hits of one `Vec`: about a
/// millisecond of work, and few enough `Vec`s that their handles cost nothing.
const CAST_CHUNK: usize = 1024;

/// The scene prepared for rays from `origin`: cylinders in its frame, and the BVH (eight
/// wide when there are rays enough to repay collapsing it, as [`Tracer::new`] decides)
/// built there, unless `rays` are too few or the scene one leaf.
fn tracer_at<'s, T: Real, F: Formula>(
    scene: &'s Scene,
    bounds: &[(DVec3, DVec3)],
    origin: DVec3,
    rays: usize,
) -> Tracer<'s, T, F> {
    let cylinders = &scene.cylinders;
    let bvh =
        (rays >= BVH_MIN_RAYS && cylinders.len() > LEAF_SIZE).then(|| Bvh::build(bounds, origin));
    let wide = bvh
        .as_ref()
        .filter(|_| rays * 4 >= cylinders.len())
        .map(WideBvh::new);
    let order: Vec<u32> = match &bvh {
        Some(b) => b.order().to_vec(),
        None => (0..cylinders.len() as u32).collect(),
    };
    let prepared = order
        .par_iter()
        .map(|&i| Prepared::new(&cylinders[i as usize], origin, F::CENTRED))
        .collect();
    Tracer {
        camera: Camera::new(scene.camera),
        cylinders,
        prepared,
        order,
        bvh: bvh.filter(|_| wide.is_none()),
        wide,
        tiles: None,
        cone_cands: None,
        _formula: std::marker::PhantomData,
    }
}

/// One ray through `tracer`, normalised as a render normalises its pixel rays.
fn cast_one<T: Real, F: Formula>(scene: &Scene, tracer: &Tracer<T, F>, r: &Ray) -> Option<RayHit> {
    let (len, d) = length_and_unit(r.dir);
    let ph: PixelHit<T> = tracer.trace_within(d, r.t_min * len, r.t_max * len)?;
    let index = ph.index;
    let cyl = &scene.cylinders[index as usize];
    // Dividing by `len` can round one ulp past a bound the scaled interval met exactly;
    // the answer stays inside the interval the caller gave.
    let t = (ph.hit.t.to_f64() / len).clamp(r.t_min, r.t_max);
    // The point from the unit direction and its distance, as the kernel formed them, so
    // that in f64 the side's normal below is the kernel's, bit for bit.
    let (position, position_error, normal) = surface_point(
        cyl,
        r.origin,
        d,
        ph.hit.t.to_f64(),
        ph.hit.surface,
        tracer.normal(d, &ph),
        T::UNIT_ROUNDOFF,
    );
    Some(RayHit {
        t,
        normal,
        index,
        id: cyl.id,
        part: part_code(tracer, d, &ph),
        position,
        position_error,
    })
}

/// The scene prepared once for rays from anywhere: one BVH over the cylinders' boxes,
/// built around `centre`, that every ray walks from its own origin
/// ([`Bvh::traverse_from`]), each cylinder it reaches prepared for that origin as it is
/// met. What a scan needs: every beam of a moving sensor, and every ray continued past a
/// hit, starts somewhere new, and [`cast`]'s grouping by origin would prepare the whole
/// scene for each (a loop over every cylinder per ray). In f64 with the stable kernel:
/// the same cylinder as [`cast`] with [`Kernel::STABLE_F64`] (a tie goes to the lower
/// index in both), and `t` to a few ulp ([`cast`] divides the direction by its length,
/// which moves a unit direction by an ulp).
pub struct AnyOrigin<'a> {
    scene: &'a Scene,
    bvh: Bvh,
    centre: DVec3,
}

impl<'a> AnyOrigin<'a> {
    /// The BVH of `scene`, around the centre of its cylinders' bounds (box coordinates
    /// relative to it stay small, so their f32 rounding is small).
    pub fn new(scene: &'a Scene) -> Self {
        let bounds: Vec<_> = scene.cylinders.par_iter().map(|c| c.bounds()).collect();
        let (lo, hi) = bounds.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), (a, b)| (lo.min(*a), hi.max(*b)),
        );
        let centre = if lo.is_finite() && hi.is_finite() {
            (lo + hi) * 0.5
        } else {
            DVec3::ZERO
        };
        AnyOrigin {
            scene,
            bvh: Bvh::build(&bounds, centre),
            centre,
        }
    }

    /// The nearest hit of `origin + t·dir` with `t` in `[t_min, t_max]`; `dir` must be a
    /// unit vector (so `t` is a distance) and the ray valid as [`cast`] checks it.
    pub fn nearest(&self, origin: DVec3, dir: DVec3, t_min: f64, t_max: f64) -> Option<RayHit> {
        use super::tracer::{f32_down, f32_up};
        use crate::geometry::{BasicHit, Stable};
        let cylinders = &self.scene.cylinders;
        let order = self.bvh.order();
        let rel = origin - self.centre;
        let o32 = glam::Vec3A::new(rel.x as f32, rel.y as f32, rel.z as f32);
        let pad = self.bvh.pad_for(rel);
        let d32 = glam::Vec3A::new(dir.x as f32, dir.y as f32, dir.z as f32);
        let mut best: Option<(BasicHit<f64>, u32, Prepared<f64>)> = None;
        // Each cylinder met is prepared for this origin, as `tracer_at` prepares all of
        // them for a camera; a closer hit (ties: lower index) prunes the walk, the bound
        // rounded up so a tie is still visited.
        self.bvh
            .traverse_from(o32, pad, d32, f32_down(t_min), f32_up(t_max), |pos| {
                let index = order[pos as usize];
                let p = Prepared::<f64>::new(&cylinders[index as usize], origin, Stable::CENTRED);
                let limit = best.map_or(t_max, |b| b.0.t);
                let hit = Stable::intersect(&p, dir, t_min, limit)?;
                let closer =
                    best.is_none_or(|(b, i, _)| hit.t < b.t || (hit.t == b.t && index < i));
                if !closer {
                    return None;
                }
                best = Some((hit, index, p));
                Some(f32_up(hit.t))
            });
        let (hit, index, p) = best?;
        let cyl = &cylinders[index as usize];
        let kernel_normal = Stable::normal(&p, dir, hit);
        let (position, position_error, normal) = surface_point(
            cyl,
            origin,
            dir,
            hit.t,
            hit.surface,
            kernel_normal,
            f64::UNIT_ROUNDOFF,
        );
        Some(RayHit {
            t: hit.t,
            normal,
            index,
            id: cyl.id,
            part: super::planes::part_of(hit.surface, kernel_normal, dir),
            position,
            position_error,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{RenderOptions, render};
    use crate::rng::SplitMix64;
    use crate::scene::Aov;
    use crate::verify::oracle::{self, DD, Problem};

    /// Pixel rays cast from the camera are the render's: distance, normal, id and part,
    /// bit for bit, hits and misses alike.
    #[test]
    fn camera_rays_are_the_render() {
        let mut sc = crate::bench::dense_scene(300, 5, 211, 117);
        (sc.camera.width, sc.camera.height) = (61, 43);
        let aovs = vec![Aov::Distance, Aov::Normal, Aov::ShapeId, Aov::Part];
        let img = render(&sc, &RenderOptions::new(aovs)).image;
        let cam = Camera::new(sc.camera);
        let rays: Vec<Ray> = (0..43)
            .flat_map(|j| (0..61).map(move |i| (i, j)))
            .map(|(i, j)| Ray {
                origin: cam.origin,
                dir: cam.pixel_vector(cam.column_offset(i), cam.row_offset(j)),
                t_min: sc.camera.near_clip,
                t_max: sc.camera.far_clip,
            })
            .collect();
        let hits = cast(&sc, Kernel::STABLE_F64, &rays).unwrap();
        let dist = img.f32_channel("distance").unwrap();
        let [nx, _, nz] = img.vec3_channel("normal").unwrap();
        let ids = img.u32_channel("shape_id").unwrap();
        let parts = img.u32_channel("part").unwrap();
        let mut n_hits = 0;
        for (k, (h, r)) in hits.iter().zip(&rays).enumerate() {
            let got = h.map_or((0.0, 0.0, 0.0, 0, 0), |h| {
                let dist = (h.t * r.dir.length()) as f32;
                (dist, h.normal.x as f32, h.normal.z as f32, h.id, h.part)
            });
            let want = (dist[k], nx[k], nz[k], ids[k], parts[k]);
            assert_eq!(got, want, "pixel {k}");
            n_hits += h.is_some() as usize;
        }
        assert!(n_hits > 500, "{n_hits} hits");
    }

    /// Random rays from random origins, of random lengths, some inside the scene's
    /// boxes: the nearest cylinder is the oracle's and `t` within 1e-9 relative, when the
    /// oracle's next candidate is not a near tie.
    #[test]
    fn random_rays_match_the_oracle() {
        let sc = crate::bench::dense_scene(60, 3, 9, 9);
        let mut rng = SplitMix64::new(41);
        let mut u = |a: f64, b: f64| rng.range(a, b);
        let mut rays = Vec::new();
        for _ in 0..400 {
            let origin = DVec3::new(u(-4.0, 4.0), u(-4.0, 4.0), u(-2.0, 3.0));
            // Toward a random cylinder's middle, so most rays hit something.
            let c = &sc.cylinders[(u(0.0, 59.99)) as usize];
            let aim = c.base + c.axis * (c.height * u(0.0, 1.0));
            let dir = (aim - origin) * u(0.1, 10.0);
            rays.push(Ray {
                origin,
                dir,
                t_min: 0.0,
                t_max: f64::INFINITY,
            });
        }
        // Twenty rays from one origin take the BVH.
        for k in 0..20 {
            let c = &sc.cylinders[k];
            rays.push(Ray {
                origin: DVec3::new(0.5, -6.0, 1.0),
                dir: c.base + c.axis * (c.height / 2.0) - DVec3::new(0.5, -6.0, 1.0),
                t_min: 0.0,
                t_max: f64::INFINITY,
            });
        }
        let hits = cast(&sc, Kernel::STABLE_F64, &rays).unwrap();
        let mut compared = 0;
        for (k, (h, r)) in hits.iter().zip(&rays).enumerate() {
            let mut all: Vec<(f64, u32)> = sc
                .cylinders
                .iter()
                .enumerate()
                .filter_map(|(i, c)| {
                    let p = Problem::new(c, r.origin, r.dir);
                    oracle::intersect(&p, DD::ZERO, DD::new(f64::INFINITY))
                        .map(|x| (x.t.to_f64(), i as u32))
                })
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0));
            let tie = all.len() > 1 && (all[1].0 - all[0].0) < 1e-6 * all[0].0;
            if tie {
                continue;
            }
            match (h, all.first()) {
                (None, None) => {}
                (Some(h), Some(&(t, i))) => {
                    assert_eq!(h.index, i, "ray {k}: {r:?}");
                    assert!((h.t - t).abs() <= 1e-9 * t, "ray {k}: t {} vs {t}", h.t);
                }
                (h, o) => panic!("ray {k} {r:?}: cast {h:?}, oracle {o:?}"),
            }
            compared += 1;
        }
        assert!(compared > 380, "{compared} compared");
        assert!(hits.iter().filter(|h| h.is_some()).count() > 300);
    }

    /// [`AnyOrigin`] finds what [`cast`] finds (stable f64): the same cylinder and part,
    /// `t` to 4 ulp, and the same point and normal to 1e-14, from random origins in
    /// and around the scene.
    #[test]
    fn any_origin_is_cast() {
        let sc = crate::bench::dense_scene(200, 7, 9, 9);
        let walker = AnyOrigin::new(&sc);
        let mut rng = SplitMix64::new(5);
        let mut hits = 0;
        for _ in 0..300 {
            let origin = DVec3::new(
                rng.range(-12.0, 12.0),
                rng.range(-12.0, 12.0),
                rng.range(-12.0, 12.0),
            );
            let dir = rng.unit_vector();
            let ray = Ray {
                origin,
                dir,
                t_min: 0.0,
                t_max: f64::INFINITY,
            };
            let want = cast(&sc, Kernel::STABLE_F64, &[ray]).unwrap()[0];
            let got = walker.nearest(origin, dir, 0.0, f64::INFINITY);
            // `cast` divides the direction by its length (1 to an ulp here), so the
            // derived vectors may differ in the last bit; `t`, cylinder and part may not.
            match (got, want) {
                (None, None) => {}
                (Some(g), Some(w)) => {
                    assert_eq!((g.index, g.part), (w.index, w.part), "{ray:?}");
                    assert!((g.t - w.t).abs() <= 4.0 * f64::EPSILON * w.t, "{ray:?}");
                    assert!((g.position - w.position).length() < 1e-14, "{ray:?}");
                    assert!((g.normal - w.normal).length() < 1e-14, "{ray:?}");
                    let e = (g.position_error - w.position_error).abs().max_element();
                    assert!(e <= 1e-3 * w.position_error.min_element(), "{ray:?}");
                    hits += 1;
                }
                (g, w) => panic!("{ray:?}: any origin {g:?}, cast {w:?}"),
            }
        }
        assert!(hits > 30, "{hits} hits");
    }

    /// A direction whose squared length leaves f64's range (huge or tiny) is a direction
    /// all the same: the hit of its unit direction, `t` in units of its length.
    #[test]
    fn directions_of_any_finite_length_are_cast() {
        let sc = crate::bench::dense_scene(300, 5, 211, 117);
        let origin = Camera::new(sc.camera).origin;
        let to = sc.cylinders[0].base + sc.cylinders[0].axis * (0.5 * sc.cylinders[0].height);
        let unit = (to - origin).normalize();
        let ray = |scale: f64| Ray {
            origin,
            dir: unit * scale,
            t_min: 0.0,
            t_max: f64::INFINITY,
        };
        let want = cast(&sc, Kernel::STABLE_F64, &[ray(1.0)]).unwrap()[0].unwrap();
        for scale in [1e300, 1e-300, 1e-150] {
            let got = cast(&sc, Kernel::STABLE_F64, &[ray(scale)]).unwrap()[0]
                .unwrap_or_else(|| panic!("no hit at scale {scale:e}"));
            assert_eq!(got.index, want.index, "scale {scale:e}");
            let rel = (got.t * scale - want.t).abs() / want.t;
            assert!(
                rel < 1e-12,
                "scale {scale:e}: t {} x {scale:e} vs {}",
                got.t,
                want.t
            );
        }
    }

    /// Bad rays are refused with the ray's index and field.
    #[test]
    fn bad_rays_name_the_ray() {
        let sc = crate::bench::dense_scene(3, 3, 4, 4);
        let good = Ray {
            origin: DVec3::ZERO,
            dir: DVec3::X,
            t_min: 0.0,
            t_max: f64::INFINITY,
        };
        let cases = [
            (
                Ray {
                    dir: DVec3::ZERO,
                    ..good
                },
                "rays[1].direction: must be finite and non-zero, got [0, 0, 0]",
            ),
            (
                // Its length overflows; the numbers read as numbers, not 300 digits.
                Ray {
                    dir: DVec3::new(1.5e308, 1.5e308, 0.0),
                    ..good
                },
                "rays[1].direction: its length must be at most 1.7976931348623157e308, got [1.5e308, 1.5e308, 0]",
            ),
            (
                Ray {
                    origin: DVec3::new(f64::NAN, 0.0, 0.0),
                    ..good
                },
                "rays[1].origin",
            ),
            (
                Ray {
                    t_min: -1.0,
                    ..good
                },
                "rays[1].t_min: must be finite and >= 0, got -1",
            ),
            (
                Ray {
                    t_max: 0.5,
                    t_min: 1.0,
                    ..good
                },
                "rays[1].t_max: must be >= t_min (1), got 0.5",
            ),
        ];
        for (bad, want) in cases {
            let e = cast(&sc, Kernel::STABLE_F64, &[good, bad]).unwrap_err();
            assert!(e.starts_with(want), "{e}");
        }
    }
}
