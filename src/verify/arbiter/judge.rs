//! One pixel judged: where the candidate and the reference disagree beyond the flat
//! tolerances, or the candidate is off the exact answer, each side is held against the
//! exact answer on the camera's own pixel ray, within its own error bound (see the parent
//! module's docs for the classes).

use super::{
    Bound, Exact, Kind, Pixel, PixelClass, Sample, Side, Tracer, angle, rel, reproduce,
    same_identity, t_bound, values_off,
};
use crate::geometry::Cylinder;
use crate::scene::Scene;
use crate::scene::camera::{PixelRay, Projection};
use crate::verify::compare::{Tolerances, ray_origin_size};
use glam::DVec3;

/// How far a cylinder reaches from the world origin: the coordinate size of its inputs.
pub(super) fn reach(c: &Cylinder) -> f64 {
    c.base.length().max(c.top().length())
}

/// What judging a pixel reads: both images, the tolerances and bounds, and the exact
/// answer traced on the scene's cylinders and on Mitsuba's float32 inputs (`rounded`).
pub(super) struct Judge<'a> {
    pub(super) scene: &'a Scene,
    pub(super) a: Side<'a>,
    pub(super) b: Side<'a>,
    pub(super) tol: &'a Tolerances,
    pub(super) candidate_bound: Bound,
    pub(super) reference_bound: Bound,
    pub(super) tracer: Tracer<'a>,
    pub(super) tracer32: Tracer<'a>,
    pub(super) rounded: &'a [Cylinder],
    /// The camera's axes in OpenCV's order (right, down, forward), for `normal_camera`.
    pub(super) axes: [DVec3; 3],
    pub(super) w: usize,
}

impl Judge<'_> {
    /// How the two sides' samples at `k` differ beyond the flat tolerances, if they do:
    /// identity first (hit, cylinder, part), then the values.
    fn flat_disagreement(&self, k: usize, sa: &Sample, sb: &Sample) -> Option<Kind> {
        let (ha, hb) = (self.a.hit(k), self.b.hit(k));
        let tol = self.tol;
        if self.a.non_finite(k) || self.b.non_finite(k) {
            Some(Kind::NonFinite)
        } else if ha != hb || (ha && sa.id.zip(sb.id).is_some_and(|(p, q)| p != q)) {
            Some(Kind::Silhouette)
        } else if ha && sa.part.zip(sb.part).is_some_and(|(p, q)| p != q) {
            Some(Kind::Seam)
        } else if !ha {
            None
        } else if sa
            .distance
            .zip(sb.distance)
            .is_some_and(|(p, q)| rel(p, q) > tol.rel_distance)
        {
            Some(Kind::Distance)
        } else if sa
            .depth
            .zip(sb.depth)
            .is_some_and(|(p, q)| rel(p, q) > tol.rel_depth)
        {
            Some(Kind::Depth)
        } else if sa.normal.zip(sb.normal).is_some_and(|(p, q)| {
            angle(DVec3::from_array(p), DVec3::from_array(q)) > tol.normal_deg.to_radians()
        }) {
            Some(Kind::Normal)
        } else {
            None
        }
    }

    /// The exact answer as a sample: ids 0 and no values on a miss.
    fn exact_sample(&self, e: Option<&Exact>) -> Sample {
        match e {
            None => Sample {
                id: Some(0),
                part: Some(0),
                distance: None,
                depth: None,
                normal: None,
                position: None,
                normal_camera: None,
            },
            Some(e) => Sample {
                id: Some(self.scene.cylinders[e.index].id),
                part: Some(e.part),
                distance: Some(e.t),
                depth: Some(e.depth),
                normal: Some(e.normal.to_array()),
                position: Some(e.position.to_array()),
                normal_camera: Some(self.axes.map(|a| a.dot(e.normal))),
            },
        }
    }

    /// Coordinate size of the rounded inputs at pixel `(x, y)`: the camera, the cylinders
    /// involved (either side's and the exact answer's), and the run of the ray.
    fn coordinate_size(
        &self,
        (x, y): (usize, usize),
        samples: [&Sample; 3],
        e: Option<&Exact>,
    ) -> f64 {
        let cylinders = &self.scene.cylinders;
        let mut l_reach: f64 = 0.0;
        let mut l_t: f64 = 0.0;
        for id in samples.iter().filter_map(|s| s.id.filter(|&i| i != 0)) {
            for c in cylinders.iter().filter(|c| c.id == id) {
                l_reach = l_reach.max(reach(c));
            }
        }
        if let Some(e) = e {
            l_reach = l_reach.max(reach(&cylinders[e.index]));
            l_t = e.t;
        }
        for v in [samples[0].distance, samples[1].distance]
            .into_iter()
            .flatten()
        {
            if v.is_finite() {
                l_t = l_t.max(v);
            }
        }
        ray_origin_size(&self.tracer.cam, x as u32, y as u32) + l_reach + l_t
    }

    /// One side's sample `s` against the exact answer `e` on `ray`: identity first, then
    /// values. Gives the error in units of the side's `bound` (`l` the coordinate size,
    /// `delta` the bound there), whether the identity is the exact one, what is off most,
    /// and whether the identity is another surface at the exact answer's distance.
    #[allow(clippy::too_many_arguments)]
    fn judge(
        &self,
        s: &Sample,
        hit: bool,
        non_finite: bool,
        bound: &Bound,
        (l, delta): (f64, f64),
        ray: &PixelRay,
        e: Option<&Exact>,
    ) -> (f64, bool, Kind, bool) {
        let cylinders = &self.scene.cylinders;
        if non_finite {
            return (f64::INFINITY, false, Kind::NonFinite, false);
        }
        if same_identity(cylinders, s, hit, e) {
            let (off, kind) = e.map_or((0.0, Kind::Distance), |e| {
                values_off(s, e, &cylinders[e.index], bound, l, &self.axes)
            });
            return (off, true, kind, false);
        }
        // Another cylinder with the side's id whose surface (of the side's part) lies at
        // the exact answer's distance, within the side's bound: coincident surfaces, where
        // the exact answer's choice is only the first in file order. The side's values are
        // judged against that surface.
        if let (Some(e), true, Some(id)) = (e, hit, s.id) {
            let coincident = self
                .tracer
                .trace_where(ray, |k| k != e.index && cylinders[k].id == id)
                .filter(|o| {
                    s.part.is_none_or(|p| p == o.part)
                        && rel(o.t, e.t) <= t_bound(e, &cylinders[e.index], bound, l)
                });
            if let Some(o) = coincident {
                let (off, kind) = values_off(s, &o, &cylinders[o.index], bound, l, &self.axes);
                return (off, false, kind, true);
            }
        }
        let nearby = self.tracer.nearby(ray, delta);
        // Another part of the exact answer's cylinder (a rim): within δ when the exact ray
        // passes within δ of a part boundary of what it hits. Another cylinder or hit vs
        // miss: when a ray within δ sees that identity.
        let seam = e.is_some_and(|e| hit && s.id.is_none_or(|id| id == cylinders[e.index].id));
        let within = if seam {
            let key = |x: Option<&Exact>| x.map(|x| (x.index, x.part));
            nearby.iter().any(|n| key(n.as_ref()) != key(e))
        } else {
            let cylinder = Sample { part: None, ..*s };
            nearby
                .iter()
                .any(|n| same_identity(cylinders, &cylinder, hit, n.as_ref()))
        };
        let kind = if seam { Kind::Seam } else { Kind::Silhouette };
        (if within { 0.0 } else { f64::INFINITY }, false, kind, false)
    }

    /// Whether Mitsuba's sample `sb` (a hit when `hb`) is on the exact answer for its own
    /// float32 inputs along `ray`, within its bound at coordinate size `l`.
    fn on_its_inputs(&self, ray: &PixelRay, sb: &Sample, hb: bool, l: f64) -> bool {
        let cam = &self.tracer.cam;
        let round = |v: DVec3| v.as_vec3().as_dvec3();
        // Mitsuba's orthographic ray starts on the near plane (the float32 point there is
        // its input) and its `t` from there; the reference script adds `near` back.
        let shift = match cam.projection {
            Projection::Orthographic { .. } => cam.spec.near_clip,
            _ => 0.0,
        };
        let r = self
            .tracer32
            .trace(&PixelRay {
                origin: round(ray.origin + ray.dir * shift),
                dir: round(ray.dir),
                tmin: ray.tmin - shift,
                tmax: ray.tmax - shift,
                ..*ray
            })
            .map(|mut r| {
                r.t += shift;
                r.depth += shift;
                r
            });
        same_identity(self.rounded, sb, hb, r.as_ref())
            && r.as_ref().is_none_or(|r| {
                let cylinder = &self.rounded[r.index];
                values_off(sb, r, cylinder, &self.reference_bound, l, &self.axes).0 <= 1.0
            })
    }

    /// Pixel `(x, y)` judged (see the module docs), or `None` when there is nothing to
    /// report: both miss, or Mitsuba agrees within the flat tolerances and the candidate is
    /// within its bound of the exact answer.
    pub(super) fn pixel(&self, x: usize, y: usize) -> Option<Pixel> {
        let (a, b) = (&self.a, &self.b);
        let k = y * self.w + x;
        let (sa, sb) = (a.sample(k), b.sample(k));
        let (ha, hb) = (a.hit(k), b.hit(k));
        let kind = self.flat_disagreement(k, &sa, &sb);
        // Both miss: nothing to judge. Otherwise the exact answer is evaluated: at a
        // disagreement to classify it, at a hit of the candidate where Mitsuba agrees to
        // catch a candidate off the exact answer by less than the flat tolerances.
        if kind.is_none() && !ha {
            return None;
        }
        let ray = self.tracer.cam.pixel_ray(x as u32, y as u32);
        let e = self.tracer.trace(&ray);
        let exact = self.exact_sample(e.as_ref());
        let l = self.coordinate_size((x, y), [&sa, &sb, &exact], e.as_ref());
        let delta_a = self.candidate_bound.delta(l);
        let delta_b = self.reference_bound.delta(l);
        let (off_a, exact_a, worst_a, tied_a) = self.judge(
            &sa,
            ha,
            a.non_finite(k),
            &self.candidate_bound,
            (l, delta_a),
            &ray,
            e.as_ref(),
        );
        let disagrees = kind.is_some();
        let kind = match kind {
            Some(kind) => kind,
            // Mitsuba agrees within the flat tolerances: only a candidate error is news.
            None if off_a > 1.0 => worst_a,
            None => return None,
        };
        let (off_b, _, _, tied_b) = self.judge(
            &sb,
            hb,
            b.non_finite(k),
            &self.reference_bound,
            (l, delta_b),
            &ray,
            e.as_ref(),
        );
        // Mitsuba off beyond δ: is it on the exact answer for its own float32 inputs?
        let class = if off_a > 1.0 {
            PixelClass::CandidateError
        } else if off_b > 1.0 && !b.non_finite(k) && self.on_its_inputs(&ray, &sb, hb, l) {
            PixelClass::InputRounding
        } else if off_b > 1.0 {
            PixelClass::UnexplainedReferenceError
        } else if exact_a && !tied_b {
            PixelClass::ReferenceError
        } else {
            PixelClass::Tie
        };
        let repro = matches!(
            class,
            PixelClass::ReferenceError | PixelClass::UnexplainedReferenceError
        )
        .then(|| reproduce(self.scene, self.rounded, &self.tracer32, &ray, &sb, hb))
        .flatten();
        Some(Pixel {
            at: [x, y],
            class,
            kind,
            disagrees,
            candidate: sa,
            reference: sb,
            exact,
            delta: delta_b,
            candidate_off: off_a,
            reference_off: off_b,
            coincident: class == PixelClass::Tie && (tied_a || tied_b),
            repro,
        })
    }
}
