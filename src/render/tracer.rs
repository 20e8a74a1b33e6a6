//! The tracer: the scene prepared for one camera (cylinders in kernel form, the BVH or
//! the screen-tile lists the strategy chose) and the nearest hit of each ray, per ray or
//! for a group of rays walking the wide tree together.

use super::{Accel, Strategy, strategy};
use crate::accel::bvh::Bvh;
use crate::accel::tiles::{self, Candidate, Tiles};
use crate::accel::wide_bvh::{IN_TURN, Stack, Visit, WideBvh};
use crate::geometry::packet;
use crate::geometry::wide::Slabs8;
use crate::geometry::{BasicHit, Cylinder, Formula, Prepared, Real};
use crate::scene::Scene;
use crate::scene::camera::{Camera, Projection};
use glam::{DVec3, Vec3A};
use rayon::prelude::*;

/// The scene prepared for one camera: cylinders in kernel form and the BVH over them.
pub struct Tracer<'s, T: Real, F: Formula> {
    /// The camera the rays leave from.
    pub camera: Camera,
    /// The scene's cylinders, by index.
    pub(super) cylinders: &'s [Cylinder],
    /// Cylinders in kernel form, in slot order: `prepared[s]` is cylinder `order[s]`
    /// (index order for the BVH, the tiles' visiting order for tiles). Empty for a tiny
    /// view's tile lists, whose walk makes each kernel as it tests the cylinder
    /// ([`Tracer::kernel`]): it tests about a tenth of them (dense 100 000 at 16×16), and
    /// preparing the rest cost more than its trace.
    pub(super) prepared: Vec<Prepared<T>>,
    pub(super) order: Vec<u32>,
    pub(super) bvh: Option<Bvh>,
    /// The BVH collapsed to eight-wide nodes, for one traversal per ray.
    pub(super) wide: Option<WideBvh>,
    pub(super) tiles: Option<Tiles>,
    /// For walking the BVH tile by tile: each slot's projection.
    pub(super) cone_cands: Option<ConeCands>,
    pub(super) _formula: std::marker::PhantomData<F>,
}

/// What a cone walk reads of the cylinders it meets.
pub(super) enum ConeCands {
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
    pub(super) fn new(
        camera: &Camera,
        cylinders: &[Cylinder],
        order: &[u32],
        projected: Option<Vec<Candidate>>,
    ) -> Self {
        let pixels = camera.width() as usize * camera.height() as usize;
        if let Some(p) = projected {
            let slots = order.par_iter().enumerate().map(|(s, &i)| {
                if let Some(&ahead) = order.get(s + crate::mem::PREFETCH_AHEAD) {
                    crate::mem::prefetch(&p[ahead as usize]);
                }
                Candidate {
                    slot: s as u32,
                    ..p[i as usize]
                }
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
    pub(super) fn get(&self, slot: u32, order: &[u32]) -> Candidate {
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
pub(super) fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { f.next_up() } else { f }
}

/// f64 → f32 rounded toward -inf, for BVH pruning bounds that must not cut a hit off.
pub(super) fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) > x { f.next_down() } else { f }
}
impl<'s, T: Real, F: Formula> Tracer<'s, T, F> {
    /// Prepare `scene` for its camera, building the structure `accel` needs.
    pub fn new(scene: &'s Scene, accel: Accel) -> Self {
        Self::new_timed(scene, accel).0
    }

    /// [`Tracer::new`], also reporting how long the kernel forms took.
    pub(super) fn new_timed(scene: &'s Scene, accel: Accel) -> (Self, std::time::Duration) {
        let camera = Camera::new(scene.camera);
        let origin = camera.origin;
        let cylinders = &scene.cylinders;
        let bvh = || {
            let bounds: Vec<_> = cylinders.par_iter().map(|c| c.bounds()).collect();
            Bvh::build(&bounds, origin)
        };
        let view = (camera.width(), camera.height());
        // Only the pinhole's rays pass through one image plane, as the screen tiles and
        // the cone walk assume: every other model traces each ray through the BVH, the
        // binary one where rays leave from their own origins (orthographic).
        let plan = match camera.projection {
            Projection::Perspective => strategy(accel, view, cylinders.len()),
            Projection::Orthographic { .. } => Strategy::PerRay { wide: false },
            Projection::Lens(_) => strategy(Accel::Bvh, view, cylinders.len()),
        };
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
        let lazy = matches!(plan, Strategy::TinyTiles { .. }) && tiles.is_some();
        let mut prepared = Vec::with_capacity(if lazy { 0 } else { order.len() });
        if !lazy {
            crate::mem::huge_pages(&prepared);
            prepared.par_extend(order.par_iter().enumerate().map(|(k, &i)| {
                if let Some(&ahead) = order.get(k + crate::mem::PREFETCH_AHEAD) {
                    crate::mem::prefetch(&cylinders[ahead as usize]);
                }
                Prepared::new(&cylinders[i as usize], origin, F::CENTRED)
            }));
        }
        let prepare = t0.elapsed();
        let tracer = Tracer {
            camera,
            cylinders,
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
    pub(super) fn clip(&self, d: DVec3) -> (f64, f64) {
        let spec = &self.camera.spec;
        let inv_cos = 1.0 / d.dot(self.camera.forward);
        (spec.near_clip * inv_cos, spec.far_clip * inv_cos)
    }

    /// Test the cylinder in `slot`; keep it in `best` when nearer (ties: lower scene index
    /// wins, so the answer does not depend on visiting order). True when `best` changed.
    #[inline(always)]
    pub(super) fn consider(
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
    pub(super) fn trace_with<S: Slabs8>(
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
    pub(super) fn trace_in_turn<S: Slabs8>(
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
        let made;
        let kernel = match self.prepared.get(h.slot as usize) {
            Some(p) => p,
            None => {
                made = self.kernel(h.index);
                &made
            }
        };
        T::v3_to_f64(F::normal(kernel, T::v3(d), h.hit))
    }

    /// The kernel form of cylinder `index`, made now: the same bits as its prepared one
    /// (a pure function of the cylinder and the camera's origin), for a tracer that
    /// prepares none.
    #[inline]
    pub(super) fn kernel(&self, index: u32) -> Prepared<T> {
        Prepared::new(
            &self.cylinders[index as usize],
            self.camera.origin,
            F::CENTRED,
        )
    }
}

/// The cylinder tests of the rays walking the wide tree together
/// ([`Tracer::trace_in_turn`]): each ray's best hit so far, the hint already tested.
pub(super) struct GroupVisit<'a, T: Real, F: Formula> {
    pub(super) tracer: &'a Tracer<'a, T, F>,
    pub(super) hint: Option<u32>,
    /// Per ray: direction, ray parameter range, and the range's end in f64.
    pub(super) dt: [T::V3; IN_TURN],
    pub(super) lims: [(T, T); IN_TURN],
    pub(super) tmax: [f64; IN_TURN],
    pub(super) best: [Option<PixelHit<T>>; IN_TURN],
}

impl<T: Real, F: Formula> GroupVisit<'_, T, F> {
    /// Ray `i`'s pruning bound: its best hit's distance, else the end of its range.
    #[inline(always)]
    pub(super) fn bound(&self, i: usize) -> f64 {
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
