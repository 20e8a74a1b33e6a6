//! The exact answer as arbiter: where the checked file (the *candidate*: cylaov's render or
//! another renderer's EXR) and Mitsuba disagree, the double-double [`oracle`](crate::verify::oracle) decides who is
//! wrong.
//!
//! A pixel *disagrees* when the two differ in identity (another cylinder, hit vs miss, or
//! another part) or beyond the flat [`Tolerances`] in relative distance, relative depth or
//! normal angle. For each such pixel the exact answer is evaluated on the reference camera's
//! f64 pixel ray (nearest hit over every cylinder of the scene), and each side is judged by
//! its own bound:
//!
//! - a value is within its side's bound when its error against the exact value is at most
//!   `ulps` float32 ulps of storage plus the float32-input conditioning term of
//!   [`crate::verify::compare`]: a ray displaced sideways by `δ = K·ε·L` moves the hit by
//!   `δ / cos i`, so distance and depth by `δ / (t cos i)` relative and a side's normal by
//!   `δ / (r cos i)` (with `cos i` clamped at `√(δ/r)`, where the linear model breaks);
//! - an identity is within its side's bound when the exact ray passes within `δ` of the
//!   boundary (the oracle's margin, probed with rays displaced sideways by up to `δ`): for
//!   another cylinder or hit vs miss, some displaced ray sees that side's cylinder (any
//!   part) or misses; for another part of the same cylinder (a rim, where a float32 ray may slip
//!   between a cap disk and the tube), some displaced ray sees another part or cylinder.
//!
//! The classes ([`PixelClass`]): *candidate error* (the candidate is off the exact answer
//! beyond its bound), *unexplained reference error* (the candidate is right, Mitsuba is off
//! beyond its float32 bound: an export or scene error is as likely as Mitsuba's), *reference
//! error* (the candidate is right, Mitsuba is off within its bound), *tie* (both within
//! their bounds, the candidate not exactly on the exact answer either, e.g. a ray through a
//! rim). A view passes when it has no candidate error and no unexplained reference error.
//!
//! The bounds ([`Bound`]): cylaov's f64 render is its f32 storage (one ulp) of an f64 answer
//! (ray error `K·ε₆₄·L`); its f32 kernel has ray error `K·ε₃₂·L`; Mitsuba has `K·ε₃₂·L` with
//! `K` = [`CONDITIONING_ULPS`]; another renderer's file (`--candidate`) is allowed `K` float32
//! ulps of storage and of ray error.
//!
//! **Cameras.** The exact answer is traced along the camera's own pixel ray
//! ([`Camera::pixel_ray`], the ray cylaov renders): from the camera centre for the pinhole,
//! from the image plane along `forward` for the orthographic camera, whose sideways ray
//! error `δ` has the wider origin term of [`ray_origin_size`] (Mitsuba's orthographic rays
//! start on the near plane at the pixel's lateral offset). The lens models have no Mitsuba
//! camera: their reference is the exact answer's own image ([`exact_render`],
//! [`Reference::Exact`]), so every disagreement is the candidate's.
//!
//! **Where Mitsuba cannot discriminate.** When Mitsuba's `δ` is as large as the scene's
//! features (its smallest radius or height), every disagreement is "within δ": the report
//! says so ([`Arbitration::cannot_discriminate`]), and the verdict rests on the candidate
//! against the exact answer alone.

use crate::geometry::{Cylinder, Precision, Surface};
use crate::image::{AovImage, Strided};
use crate::scene::camera::{Camera, PixelRay, Projection};
use crate::scene::{Aov, Scene};
use crate::verify::compare::{CONDITIONING_ULPS, Tolerances, id_channel, ray_origin_size};
use crate::verify::oracle::{DD, intersect};
use crate::verify::oracle::{DV3, Problem};
use crate::verify::repro::{Repro, ReproCylinder, ReproHit, shape_word};
use anyhow::{Result, bail};
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt;

mod judge;
use judge::{Judge, reach};

/// Unit roundoff of float32.
const EPS32: f64 = 5.960_464_477_539_063e-8;
/// Unit roundoff of float64.
const EPS64: f64 = f64::EPSILON / 2.0;

/// How far a side may be from the exact answer: `storage_ulps` float32 ulps of its stored
/// value, plus the conditioning of a ray displaced sideways by `ray_ulps·ray_eps·L`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Bound {
    /// Float32 ulps of storage rounding allowed on every value.
    pub storage_ulps: f64,
    /// Ulps of the sideways ray error.
    pub ray_ulps: f64,
    /// Unit roundoff of the arithmetic that built the ray (ε₆₄ or ε₃₂).
    pub ray_eps: f64,
    /// Ulps of the ray's *direction* error, which moves the hit sideways by
    /// `direction_ulps·ray_eps·t` (0 for cylaov's f64 render; see [`DIRECTION_ULPS`]).
    pub direction_ulps: f64,
}

/// How far a float32 camera ray's direction may be off, in float32 ulps (as an angle).
///
/// A float32 renderer builds the pixel ray through float32 matrices: Mitsuba maps the film
/// sample through the float32 inverse of its perspective projection (whose near and far
/// clip planes, 1e-2 and 1e4 by default, make that inverse ill-conditioned) and then
/// through the float32 camera-to-world transform, and normalises. Each step rounds the
/// direction by a few ulps and the inverse amplifies it, so the ray's *direction* carries
/// an error that the coordinate-size term `K·ε₃₂·L` does not cover: it moves the hit
/// sideways by `direction_ulps·ε₃₂·t`. Distance and depth barely see it (a sideways move
/// changes `t` by `δ·tan i`, inside their bound), the normal sees `δ/r`, and the stored
/// `position` sees all of it. Over the committed references (Mitsuba's own renders judged
/// as a float32 candidate) the largest sideways move is 2.6e-5 at `t` = 12.9 (about 30
/// ulps of `t` with the coordinate term). 32 ulps passes every reference and keeps a
/// position off by 1e-4 outside the bound on most hits at `t` ≈ 10–25 (69–99% of them in
/// `tests/verify_float32.rs`; a slanted hit's bound grows as 1 / cos i).
pub const DIRECTION_ULPS: f64 = 32.0;

impl Bound {
    /// cylaov's own render at `precision`: one float32 ulp of storage of an answer whose ray
    /// carries `CONDITIONING_ULPS` ulps of that precision.
    pub fn cylaov(precision: Precision) -> Bound {
        Bound {
            storage_ulps: 1.0,
            ray_ulps: CONDITIONING_ULPS,
            ray_eps: match precision {
                Precision::F64 => EPS64,
                Precision::F32 => EPS32,
            },
            direction_ulps: match precision {
                Precision::F64 => 0.0,
                Precision::F32 => DIRECTION_ULPS,
            },
        }
    }

    /// Mitsuba 3 (`scalar_rgb`): float32 rays, `CONDITIONING_ULPS` ulps.
    pub fn mitsuba() -> Bound {
        Bound {
            storage_ulps: 1.0,
            ray_ulps: CONDITIONING_ULPS,
            ray_eps: EPS32,
            direction_ulps: DIRECTION_ULPS,
        }
    }

    /// Another renderer's file: `ulps` float32 ulps of storage and of ray error.
    pub fn float32_ulps(ulps: f64) -> Bound {
        Bound {
            storage_ulps: ulps,
            ray_ulps: ulps,
            ray_eps: EPS32,
            direction_ulps: DIRECTION_ULPS,
        }
    }

    /// The sideways ray error at coordinate size `l`.
    fn delta(&self, l: f64) -> f64 {
        self.ray_ulps * self.ray_eps * l
    }
}

/// What a candidate is compared with before the exact answer judges the pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reference {
    /// Mitsuba 3's render: the cameras it has a sensor for (perspective, orthographic).
    Mitsuba,
    /// The exact answer's own image ([`exact_render`]): the lens models, which Mitsuba has
    /// no sensor for. Every candidate hit is still judged against the exact answer; the
    /// image adds the pixels the candidate misses and the statistics of the report.
    Exact,
}

impl Reference {
    /// How the reference is named in the failure and accepted lines.
    pub fn name(self) -> &'static str {
        match self {
            Reference::Mitsuba => "Mitsuba",
            Reference::Exact => "exact image",
        }
    }

    /// The reference's bound: Mitsuba's float32 ([`Bound::mitsuba`]); the exact image is
    /// the double-double answer stored in float32, one ulp ([`Bound::cylaov`] at f64).
    pub fn bound(self) -> Bound {
        match self {
            Reference::Mitsuba => Bound::mitsuba(),
            Reference::Exact => Bound::cylaov(Precision::F64),
        }
    }
}

/// Who is wrong at one disagreeing pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelClass {
    /// The candidate is within its bound of the exact answer; Mitsuba is off it, within its
    /// float32 bound δ.
    ReferenceError,
    /// The candidate is right; Mitsuba is off by more than δ (an export or scene error is
    /// as likely as Mitsuba's). Fails the view.
    UnexplainedReferenceError,
    /// The candidate is off the exact answer beyond its bound. Fails the view.
    CandidateError,
    /// Both within their bounds, neither exactly the exact answer (a ray through a rim or
    /// a silhouette, decided by the last bits).
    Tie,
    /// Mitsuba is off the exact answer beyond δ, but on the exact answer for the inputs it
    /// was given: the scene's `p0`, `p1` and `radius` as float32 (as it parses the exported
    /// XML) and the camera ray's origin and direction as float32. The export's rounding,
    /// not an error of either renderer; passes.
    InputRounding,
}

impl PixelClass {
    /// The words the table and the report use.
    pub fn label(self) -> &'static str {
        match self {
            PixelClass::ReferenceError => "reference error",
            PixelClass::UnexplainedReferenceError => "unexplained reference error",
            PixelClass::CandidateError => "candidate error",
            PixelClass::Tie => "tie",
            PixelClass::InputRounding => "input rounding",
        }
    }
}

/// What made a pixel disagree (the first that applies).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// Another cylinder, or hit vs miss.
    Silhouette,
    /// The same cylinder, another part.
    Seam,
    /// Relative distance beyond the flat bound.
    Distance,
    /// Relative depth beyond the flat bound.
    Depth,
    /// Normal angle beyond the flat bound.
    Normal,
    /// Hit position off the exact answer beyond the candidate's bound (judged against the
    /// exact answer only: the flat tolerances have no position bound).
    Position,
    /// Camera-frame normal off the exact answer beyond the candidate's bound (judged
    /// against the exact answer only).
    NormalCamera,
    /// A non-finite sample.
    NonFinite,
}

/// One side's answer at a pixel (`id` 0: a miss; `None`: not stored).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Sample {
    /// `shape_id` (0 = miss), `None` when the image has none.
    pub id: Option<u32>,
    /// `part` (1 side outside, 2 side inside, 3 bottom cap, 4 top cap, 0 miss).
    pub part: Option<u32>,
    /// Distance along the ray.
    pub distance: Option<f64>,
    /// Camera-space depth.
    pub depth: Option<f64>,
    /// World-space outward normal.
    pub normal: Option<[f64; 3]>,
    /// World-space hit position (the candidate's and the exact answer's; Mitsuba's is not
    /// judged).
    pub position: Option<[f64; 3]>,
    /// Camera-frame (OpenCV axes) normal (the candidate's and the exact answer's).
    pub normal_camera: Option<[f64; 3]>,
}

impl fmt::Display for Sample {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.id, self.distance) {
            (Some(0), _) => return write!(f, "miss"),
            (None, Some(d)) if d <= 0.0 => return write!(f, "miss"),
            _ => {}
        }
        let mut parts = Vec::new();
        if let Some(id) = self.id {
            parts.push(format!("id {id}"));
        }
        if let Some(p) = self.part {
            parts.push(format!("part {p}"));
        }
        if let Some(d) = self.distance {
            parts.push(format!("distance {d:.9}"));
        }
        if let Some(d) = self.depth {
            parts.push(format!("depth {d:.9}"));
        }
        if let Some(n) = self.normal {
            parts.push(format!("normal [{:.6}, {:.6}, {:.6}]", n[0], n[1], n[2]));
        }
        if let Some(p) = self.position {
            parts.push(format!("position [{:.9}, {:.9}, {:.9}]", p[0], p[1], p[2]));
        }
        if let Some(n) = self.normal_camera {
            parts.push(format!(
                "normal_camera [{:.6}, {:.6}, {:.6}]",
                n[0], n[1], n[2]
            ));
        }
        write!(f, "{}", parts.join(" "))
    }
}

/// One disagreeing pixel, its three answers and its class.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Pixel {
    /// `[x, y]`, row 0 at the top.
    pub at: [usize; 2],
    /// Who is wrong.
    pub class: PixelClass,
    /// What disagreed (where Mitsuba agrees: what of the candidate is off the exact answer
    /// most).
    pub kind: Kind,
    /// Whether candidate and Mitsuba disagree here; `false`: Mitsuba agrees within the flat
    /// tolerances and the candidate is off the exact answer beyond its bound.
    pub disagrees: bool,
    /// The checked file's answer.
    pub candidate: Sample,
    /// Mitsuba's answer.
    pub reference: Sample,
    /// The exact answer (double-double oracle on the reference camera's f64 ray).
    pub exact: Sample,
    /// Mitsuba's sideways ray error δ at this pixel (world units).
    pub delta: f64,
    /// The largest error of the candidate against the exact answer, in units of its bound
    /// (0 for an identity within its margin; infinite for an identity beyond it).
    pub candidate_off: f64,
    /// The same for Mitsuba.
    pub reference_off: f64,
    /// Whether a side's identity differs from the exact answer's only because another
    /// surface lies at the same distance (within that side's bound): coincident cylinders,
    /// where either identity is right. Such a pixel is a tie.
    pub coincident: bool,
    /// Where Mitsuba is off (a reference error, explained or not) with another shape than
    /// the exact answer's on its own float32 inputs: the reproduction of that proven
    /// reference error ([`crate::verify::repro`]).
    pub repro: Option<Repro>,
}

/// Every disagreeing pixel of a view, classified.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Arbitration {
    /// The candidate's bound.
    pub candidate_bound: Bound,
    /// Mitsuba's bound.
    pub reference_bound: Bound,
    /// Pixels where candidate and Mitsuba disagree (every one is classified below).
    pub disagreeing: usize,
    /// The candidate's hit pixels, every one judged against the exact answer with the
    /// candidate's bound (a pixel off it is a candidate error even where Mitsuba agrees
    /// within the flat tolerances).
    pub checked: usize,
    /// Pixels of each class.
    pub reference_errors: usize,
    /// See [`PixelClass::UnexplainedReferenceError`].
    pub unexplained_reference_errors: usize,
    /// See [`PixelClass::CandidateError`].
    pub candidate_errors: usize,
    /// See [`PixelClass::Tie`].
    pub ties: usize,
    /// The ties where two surfaces lie at the same distance ([`Pixel::coincident`]).
    pub coincident: usize,
    /// Pixels where Mitsuba is on the exact answer for its float32 inputs
    /// ([`PixelClass::InputRounding`]).
    pub input_rounding: usize,
    /// Reference errors (explained or not) where Mitsuba's shape is not the exact answer's
    /// on its own float32 inputs: each has a reproduction ([`Pixel::repro`]).
    pub proven_reference_errors: usize,
    /// Mitsuba's largest sideways ray error δ over the scene's cylinders.
    pub delta_max: f64,
    /// The scene's smallest feature (radius or height).
    pub feature_min: f64,
    /// The scene's largest radius.
    pub radius_max: f64,
    /// Whether `delta_max` is at least `feature_min`: Mitsuba cannot tell right from wrong
    /// there, the verdict rests on the exact answer alone.
    pub cannot_discriminate: bool,
    /// What the candidate was compared with: Mitsuba, or the exact answer alone.
    pub reference: Reference,
    /// The pixels, in image order.
    pub pixels: Vec<Pixel>,
}

impl Arbitration {
    /// No candidate error and no unexplained reference error.
    pub fn passed(&self) -> bool {
        self.candidate_errors == 0 && self.unexplained_reference_errors == 0
    }

    /// The pixels of `class`.
    pub fn of(&self, class: PixelClass) -> impl Iterator<Item = &Pixel> {
        self.pixels.iter().filter(move |p| p.class == class)
    }

    /// Counts by kind of the pixels of `class`: "silhouette 3, distance 1".
    pub fn kinds(&self, class: PixelClass) -> String {
        let mut out = Vec::new();
        for (kind, name) in [
            (Kind::Silhouette, "silhouette"),
            (Kind::Seam, "seam"),
            (Kind::Distance, "distance"),
            (Kind::Depth, "depth"),
            (Kind::Normal, "normal"),
            (Kind::Position, "position"),
            (Kind::NormalCamera, "normal_camera"),
            (Kind::NonFinite, "non-finite"),
        ] {
            let n = self.of(class).filter(|p| p.kind == kind).count();
            if n > 0 {
                out.push(format!("{name} {n}"));
            }
        }
        out.join(", ")
    }

    /// The failure lines (empty when it passes): each failing class, its count, and the
    /// worst pixel's three answers.
    pub fn failure_lines(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (class, n, why) in [
            (
                PixelClass::CandidateError,
                self.candidate_errors,
                "off the exact answer beyond the candidate's bound",
            ),
            (
                PixelClass::UnexplainedReferenceError,
                self.unexplained_reference_errors,
                "Mitsuba off the exact answer beyond its float32 bound δ while the candidate is on it (an export or scene error is as likely as Mitsuba's)",
            ),
        ] {
            if n > 0 {
                out.push(format!(
                    "{}: {n} px {why} ({}); {}",
                    class.label(),
                    self.kinds(class),
                    self.example(class)
                ));
            }
        }
        out
    }

    /// The lines that say what passed without being exact: reference errors, ties, and the
    /// note where Mitsuba cannot discriminate.
    pub fn accepted_lines(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.reference_errors > 0 {
            out.push(format!(
                "reference error: {} px where Mitsuba is off the exact answer within its float32 bound δ and the candidate is on it ({}); {}",
                self.reference_errors,
                self.kinds(PixelClass::ReferenceError),
                self.example(PixelClass::ReferenceError)
            ));
        }
        if self.proven_reference_errors > 0 {
            out.push(format!(
                "proven reference error: {} px where Mitsuba's shape is not the exact answer's on its own float32 inputs (p0, p1, radius and the ray as float32); the report writes a script reproducing each",
                self.proven_reference_errors
            ));
        }
        if self.ties > 0 {
            let coincident = if self.coincident > 0 {
                format!(
                    ", {} of them where another cylinder's surface lies at the exact answer's distance within the bound (coincident surfaces: either identity is right)",
                    self.coincident
                )
            } else {
                String::new()
            };
            out.push(format!(
                "tie: {} px where both are within their bounds of the exact answer ({}){coincident}; {}",
                self.ties,
                self.kinds(PixelClass::Tie),
                self.example(PixelClass::Tie)
            ));
        }
        if self.input_rounding > 0 {
            out.push(format!(
                "input rounding: {} px where Mitsuba is off the exact answer beyond δ but on the exact answer for its float32 inputs (p0, p1, radius and the camera ray as float32) ({}); {}",
                self.input_rounding,
                self.kinds(PixelClass::InputRounding),
                self.example(PixelClass::InputRounding)
            ));
        }
        if let Some(note) = self.note() {
            out.push(note);
        }
        out
    }

    /// The "Mitsuba cannot discriminate here" note, when it applies.
    pub fn note(&self) -> Option<String> {
        self.cannot_discriminate.then(|| {
            format!(
                "Mitsuba cannot discriminate here: its float32 ray error δ = {} is as large as the scene's features ({} to {}); the verdict rests on the exact answer alone",
                size(self.delta_max),
                size(self.feature_min),
                size(self.radius_max)
            )
        })
    }

    /// The worst pixel of `class` (largest error of the side at fault), as one phrase.
    fn example(&self, class: PixelClass) -> String {
        let key = |p: &Pixel| match class {
            PixelClass::CandidateError => p.candidate_off,
            _ => p.reference_off,
        };
        let Some(p) = self
            .of(class)
            .max_by(|a, b| key(a).total_cmp(&key(b)).then(b.at.cmp(&a.at)))
        else {
            return String::new();
        };
        format!(
            "e.g. at [{}, {}] ({:?}): candidate {}, {} {}, exact {} (δ {:.2e})",
            p.at[0],
            p.at[1],
            p.kind,
            p.candidate,
            self.reference.name(),
            p.reference,
            p.exact,
            p.delta
        )
        .replace("(Silhouette)", "(silhouette)")
        .replace("(Seam)", "(seam)")
        .replace("(Distance)", "(distance)")
        .replace("(Depth)", "(depth)")
        .replace("(NormalCamera)", "(normal_camera)")
        .replace("(Normal)", "(normal)")
        .replace("(Position)", "(position)")
        .replace("(NonFinite)", "(non-finite)")
    }
}

/// A length as the notes print it: three decimals from 0.01 up (`1.093`), three
/// significant digits below (`2.38e-5`), so a small scene's δ does not print as 0.000.
fn size(x: f64) -> String {
    if x == 0.0 || x.abs() >= 0.01 {
        format!("{x:.3}")
    } else {
        format!("{x:.2e}")
    }
}

/// The exact answer at one ray: which cylinder and part, where, and what the bounds need.
#[derive(Clone, Copy, Debug)]
struct Exact {
    index: usize,
    part: u32,
    t: f64,
    depth: f64,
    normal: DVec3,
    /// The hit point `o + t·d`, evaluated in double-double and rounded once.
    position: DVec3,
    /// |cos| of the incidence angle.
    cos: f64,
}

/// The scene's cylinders with what the exact answer needs, and the camera.
struct Tracer<'a> {
    cylinders: &'a [Cylinder],
    /// Per cylinder: its box, for a cheap test before the oracle.
    boxes: Vec<(DVec3, DVec3)>,
    cam: Camera,
}

/// Whether the ray `o + s·d`, `s ∈ [0, tmax]`, meets the box `(lo, hi)` widened by `pad`
/// (inclusive; a zero direction component compares the origin, never 0·∞).
fn meets_box(o: DVec3, d: DVec3, tmax: f64, (lo, hi): (DVec3, DVec3), pad: f64) -> bool {
    let (mut t0, mut t1) = (0.0f64, tmax);
    for k in 0..3 {
        let (lo, hi) = (lo[k] - pad, hi[k] + pad);
        if d[k] == 0.0 {
            if o[k] < lo || o[k] > hi {
                return false;
            }
            continue;
        }
        let (a, b) = ((lo - o[k]) / d[k], (hi - o[k]) / d[k]);
        let (a, b) = if a <= b { (a, b) } else { (b, a) };
        t0 = t0.max(a);
        t1 = t1.min(b);
        if t0 > t1 {
            return false;
        }
    }
    true
}

impl Tracer<'_> {
    /// The nearest exact hit of the pixel ray `r` (`r.dir` unit) with `t` in
    /// `[r.tmin, r.tmax]` (the clip range the render uses along that ray).
    fn trace(&self, r: &PixelRay) -> Option<Exact> {
        self.trace_where(r, |_| true)
    }

    /// [`Tracer::trace`] over the cylinders whose index `keep` accepts.
    fn trace_where(&self, r: &PixelRay, keep: impl Fn(usize) -> bool) -> Option<Exact> {
        let (o, d, tmax) = (r.origin, r.dir, r.tmax);
        if r.tmin > r.tmax || r.tmin.is_nan() || r.tmax.is_nan() {
            // A pixel without a ray (a lens model outside its image): nothing is seen.
            return None;
        }
        let (lo, hi) = (DD::new(r.tmin), DD::new(r.tmax));
        let mut best: Option<(DD, usize, crate::verify::oracle::Hit)> = None;
        for (k, c) in self.cylinders.iter().enumerate().filter(|(k, _)| keep(*k)) {
            // Padded so that rounding in the box test never drops a hit.
            let pad = 1e-9 * (c.radius + c.height + c.base.length());
            if !meets_box(o, d, tmax, self.boxes[k], pad) {
                continue;
            }
            let hit = intersect(&Problem::new(c, o, d), lo, hi);
            if let Some(h) = hit
                && best.as_ref().is_none_or(|(t, _, _)| h.t < *t)
            {
                best = Some((h.t, k, h));
            }
        }
        let (_, index, h) = best?;
        let normal = h.normal.to_f64();
        let part = match h.surface {
            Surface::Side if normal.dot(d) > 0.0 => 2,
            Surface::Side => 1,
            Surface::Bottom => 3,
            Surface::Top => 4,
        };
        let t = h.t.to_f64();
        // Planar depth is camera-space z (`t · d·forward`); where the model says depth is
        // Euclidean (equirectangular, a fisheye at or beyond 90°) it is `t` itself.
        let depth = if r.planar_depth {
            (h.t * DV3::from_f64(d).dot(DV3::from_f64(self.cam.forward))).to_f64()
        } else {
            t
        };
        let position = (DV3::from_f64(o) + DV3::from_f64(d).scale(h.t)).to_f64();
        Some(Exact {
            index,
            part,
            t,
            depth,
            normal,
            position,
            cos: normal.dot(d).abs(),
        })
    }

    /// The exact identities seen by rays displaced sideways by up to `delta` (1, 1/4, 1/16,
    /// 1/64 of it, in 8 directions, so a thin feature is not jumped over).
    fn nearby(&self, r: &PixelRay, delta: f64) -> Vec<Option<Exact>> {
        let dirs = crate::verify::oracle::sideways(r.dir);
        let mut out = Vec::with_capacity(32);
        for f in [1.0, 0.25, 0.0625, 0.015625] {
            for e in &dirs {
                out.push(self.trace(&PixelRay {
                    origin: r.origin + *e * (delta * f),
                    ..*r
                }));
            }
        }
        out
    }
}

/// One side's labels and values.
struct Side<'a> {
    ids: Option<Vec<u32>>,
    parts: Option<Vec<u32>>,
    distance: Option<Strided<'a, f32>>,
    depth: Option<Strided<'a, f32>>,
    normal: Option<[Strided<'a, f32>; 3]>,
    position: Option<[Strided<'a, f32>; 3]>,
    normal_camera: Option<[Strided<'a, f32>; 3]>,
}

impl<'a> Side<'a> {
    /// `every_aov`: read `position` and `normal_camera` too (the candidate's, judged
    /// against the exact answer; Mitsuba's are not).
    fn new(img: &'a AovImage, which: &str, every_aov: bool) -> Result<Side<'a>> {
        let side = Side {
            ids: id_channel(img, "shape_id", which)?,
            parts: id_channel(img, "part", which)?,
            distance: float_channel(img, "distance", which)?,
            depth: float_channel(img, "depth", which)?,
            normal: vec3_float(img, "normal", which)?,
            position: if every_aov {
                vec3_float(img, "position", which)?
            } else {
                None
            },
            normal_camera: if every_aov {
                vec3_float(img, "normal_camera", which)?
            } else {
                None
            },
        };
        if side.ids.is_none() && side.distance.is_none() && side.depth.is_none() {
            bail!("{which}: cannot tell hits from misses: no shape_id, distance or depth channel");
        }
        Ok(side)
    }

    /// Whether pixel `k` is a hit, and the sample there.
    fn hit(&self, k: usize) -> bool {
        match &self.ids {
            Some(ids) => ids[k] != 0,
            None => self.distance.or(self.depth).is_some_and(|v| v[k] > 0.0),
        }
    }

    fn sample(&self, k: usize) -> Sample {
        let hit = self.hit(k);
        let f = |v: Option<Strided<f32>>| v.map(|v| f64::from(v[k]));
        let v3 = |v: Option<[Strided<f32>; 3]>| {
            v.map(|n| [n[0][k], n[1][k], n[2][k]].map(f64::from))
                .filter(|_| hit)
        };
        Sample {
            id: self.ids.as_ref().map(|v| v[k]),
            part: self.parts.as_ref().map(|v| v[k]),
            distance: f(self.distance),
            depth: f(self.depth).filter(|_| hit),
            normal: v3(self.normal),
            position: v3(self.position),
            normal_camera: v3(self.normal_camera),
        }
    }

    fn non_finite(&self, k: usize) -> bool {
        let bad = |v: Option<Strided<f32>>| v.is_some_and(|v| !v[k].is_finite());
        let bad3 =
            |v: Option<[Strided<f32>; 3]>| v.is_some_and(|n| n.iter().any(|c| !c[k].is_finite()));
        bad(self.distance)
            || bad(self.depth)
            || bad3(self.normal)
            || bad3(self.position)
            || bad3(self.normal_camera)
    }
}

/// The float samples of channel `name`, `None` when `img` has no such channel; a channel
/// stored as u32 is refused, naming it (a value the check could not read would go unjudged).
fn float_channel<'a>(
    img: &'a AovImage,
    name: &str,
    which: &str,
) -> Result<Option<Strided<'a, f32>>> {
    match img.channel(name) {
        None => Ok(None),
        Some(crate::image::ChannelRef::F32(v)) => Ok(Some(v)),
        Some(crate::image::ChannelRef::U32(_)) => {
            bail!("{which}: {name} is stored as u32, where the check reads float samples")
        }
    }
}

/// The three float channels `NAME.X/Y/Z`, `None` when `img` has none of them; one or two of
/// them, or one stored as u32, is refused, naming it.
fn vec3_float<'a>(
    img: &'a AovImage,
    name: &str,
    which: &str,
) -> Result<Option<[Strided<'a, f32>; 3]>> {
    let [x, y, z] = ["X", "Y", "Z"].map(|c| format!("{name}.{c}"));
    match (
        float_channel(img, &x, which)?,
        float_channel(img, &y, which)?,
        float_channel(img, &z, which)?,
    ) {
        (Some(x), Some(y), Some(z)) => Ok(Some([x, y, z])),
        (None, None, None) => Ok(None),
        (x0, y0, z0) => {
            let lacks: Vec<&str> = [(&x, x0.is_none()), (&y, y0.is_none()), (&z, z0.is_none())]
                .into_iter()
                .filter(|(_, none)| *none)
                .map(|(n, _)| n.as_str())
                .collect();
            bail!("{which}: {name} lacks {}", lacks.join(" and "))
        }
    }
}

/// The channels of `img` the exact answer does not judge (`label`, `uv.U`, …): a
/// candidate's values there go unchecked, and the verdict says so.
pub fn unjudged_channels(img: &AovImage) -> Vec<String> {
    // The AOVs the exact answer has a value for (label and uv it has not).
    const JUDGED: [Aov; 7] = [
        Aov::ShapeId,
        Aov::Part,
        Aov::Distance,
        Aov::Depth,
        Aov::Normal,
        Aov::Position,
        Aov::NormalCamera,
    ];
    let judged: Vec<&str> = JUDGED
        .iter()
        .flat_map(|a| a.spec().channels.iter().copied())
        .collect();
    img.names()
        .into_iter()
        .filter(|n| !judged.contains(n))
        .map(str::to_string)
        .collect()
}

/// `|a - b| / max(|a|, |b|)`.
fn rel(a: f64, b: f64) -> f64 {
    let s = a.abs().max(b.abs());
    if s == 0.0 { 0.0 } else { (a - b).abs() / s }
}

/// Angle between two vectors, radians (`atan2(|a × b|, a · b)`; π if either is zero).
fn angle(a: DVec3, b: DVec3) -> f64 {
    if a.length_squared() == 0.0 || b.length_squared() == 0.0 {
        return std::f64::consts::PI;
    }
    a.cross(b).length().atan2(a.dot(b))
}

/// Whether `s`'s identity is that of the exact answer `e` (an absent channel matches).
fn same_identity(cyls: &[Cylinder], s: &Sample, hit: bool, e: Option<&Exact>) -> bool {
    match e {
        None => !hit,
        Some(e) => {
            hit && s.id.is_none_or(|id| id == cyls[e.index].id)
                && s.part.is_none_or(|p| p == e.part)
        }
    }
}

/// A side's relative bound on the distance `e.t` (and depth) at coordinate size `l`: its
/// float32 storage plus the sideways ray error `δ / (t cos i)`, `cos i` clamped at
/// `√(δ/r)`.
fn t_bound(e: &Exact, cyl: &Cylinder, bound: &Bound, l: f64) -> f64 {
    let delta = bound.delta(l);
    let cos = e.cos.max((delta / cyl.radius).sqrt()).min(1.0);
    bound.storage_ulps * 2.0 * EPS32 + delta / (e.t * cos)
}

/// How far a side's values are from the exact answer `e` (same identity), in units of its
/// bound (the largest over every value it stores; ≤ 1: within), and which value that is.
/// `axes` are the camera's OpenCV axes (x right, y down, z forward), for `normal_camera`.
fn values_off(
    s: &Sample,
    e: &Exact,
    cyl: &Cylinder,
    bound: &Bound,
    l: f64,
    axes: &[DVec3; 3],
) -> (f64, Kind) {
    let delta = bound.delta(l);
    let cos = e.cos.max((delta / cyl.radius).sqrt()).min(1.0);
    let storage = bound.storage_ulps * 2.0 * EPS32;
    let rel_bound = t_bound(e, cyl, bound, l);
    let mut worst = (0.0f64, Kind::Distance);
    let mut judge = |off: f64, kind: Kind| {
        let off = if off.is_nan() { f64::INFINITY } else { off };
        if off > worst.0 {
            worst = (off, kind);
        }
    };
    if let Some(d) = s.distance {
        judge(rel(d, e.t) / rel_bound, Kind::Distance);
    }
    if let Some(z) = s.depth {
        judge(rel(z, e.depth) / rel_bound, Kind::Depth);
    }
    let on_side = e.part <= 2;
    let n_bound = 2.0 * storage
        + if on_side {
            delta / (cyl.radius * cos)
        } else {
            0.0
        };
    if let Some(n) = s.normal {
        judge(
            angle(DVec3::from_array(n), e.normal) / n_bound,
            Kind::Normal,
        );
    }
    if let Some(p) = s.position {
        // Each component rounded to float32 (`storage` of |p| in all), and the sideways
        // ray error moving the hit by δ / cos i along the surface: the coordinate term δ
        // plus a float32 camera's direction error over the run t (`DIRECTION_ULPS`).
        let sideways = delta + bound.direction_ulps * bound.ray_eps * e.t;
        let p_bound = storage * e.position.length() + sideways / cos;
        judge(
            (DVec3::from_array(p) - e.position).length() / p_bound,
            Kind::Position,
        );
    }
    if let Some(n) = s.normal_camera {
        // The world normal rotated into the camera's axes (an f64 rotation, exact up to
        // f64 rounding) and rounded to float32 once more: the normal's bound plus one
        // more storage rounding.
        let exact = DVec3::new(
            axes[0].dot(e.normal),
            axes[1].dot(e.normal),
            axes[2].dot(e.normal),
        );
        judge(
            angle(DVec3::from_array(n), exact) / (n_bound + storage),
            Kind::NormalCamera,
        );
    }
    worst
}

/// Classify every pixel where `candidate` and `reference` (Mitsuba's render of `scene`'s
/// camera) disagree beyond `tol`, with the exact answer as arbiter (see the module docs).
/// The exact answers are traced along the camera's own pixel rays ([`Camera::pixel_ray`],
/// the rays cylaov renders): the pinhole's from the camera centre, the orthographic
/// camera's parallel rays from its image plane.
pub fn arbitrate(
    scene: &Scene,
    candidate: &AovImage,
    reference: &AovImage,
    tol: &Tolerances,
    candidate_bound: Bound,
) -> Result<Arbitration> {
    arbitrate_against(
        scene,
        candidate,
        reference,
        tol,
        candidate_bound,
        Reference::Mitsuba,
    )
}

/// [`arbitrate`] against `against`: Mitsuba's render, or the exact answer's own image
/// ([`exact_render`]) for a camera Mitsuba has no sensor for. Refused for a lens model
/// against Mitsuba.
pub fn arbitrate_against(
    scene: &Scene,
    candidate: &AovImage,
    reference: &AovImage,
    tol: &Tolerances,
    candidate_bound: Bound,
    against: Reference,
) -> Result<Arbitration> {
    let cam = Camera::new(scene.camera);
    if against == Reference::Mitsuba && !has_mitsuba_sensor(&cam.projection) {
        bail!(
            "camera.model: Mitsuba 3 has no \"{}\" camera to check against",
            cam.projection.model().name()
        );
    }
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    for (img, which) in [(candidate, "candidate"), (reference, "reference")] {
        if (img.width, img.height) != (w, h) {
            bail!(
                "{which} is {}x{}, the scene's camera {w}x{h}",
                img.width,
                img.height
            );
        }
    }
    let (a, b) = (
        Side::new(candidate, "candidate", true)?,
        Side::new(reference, "reference", false)?,
    );
    let reference_bound = against.bound();
    let tracer = Tracer {
        cylinders: &scene.cylinders,
        boxes: scene.cylinders.iter().map(Cylinder::bounds).collect(),
        cam,
    };
    // The inputs Mitsuba was given: every cylinder's end points and radius rounded to
    // float32 (the axis and height follow from the rounded end points, exactly).
    let rounded: Vec<Cylinder> = scene.cylinders.iter().map(float32_inputs).collect();
    let tracer32 = Tracer {
        cylinders: &rounded,
        boxes: rounded.iter().map(Cylinder::bounds).collect(),
        cam: Camera::new(scene.camera),
    };
    let cam = &tracer.cam;
    // The largest ray-origin size over the pixels (a corner's, for the orthographic camera).
    let origin_len = ray_origin_size(cam, 0, 0);
    let (mut delta_max, mut feature_min, mut radius_max) = (0.0f64, f64::INFINITY, 0.0f64);
    for c in &scene.cylinders {
        let l = origin_len + reach(c) + (c.base - cam.origin).length();
        delta_max = delta_max.max(reference_bound.delta(l));
        feature_min = feature_min.min(c.radius.min(c.height));
        radius_max = radius_max.max(c.radius);
    }
    let judge = Judge {
        scene,
        axes: [-cam.left, -cam.true_up, cam.forward],
        a,
        b,
        tol,
        candidate_bound,
        reference_bound,
        tracer,
        tracer32,
        rounded: &rounded,
        w,
    };
    let at = |x: usize, y: usize| judge.pixel(x, y);
    // Rows in parallel, kept in image order.
    let rows: Vec<Vec<Pixel>> = (0..h)
        .into_par_iter()
        .map(|y| (0..w).filter_map(|x| at(x, y)).collect())
        .collect();
    let pixels: Vec<Pixel> = rows.into_iter().flatten().collect();
    let checked = (0..w * h).filter(|&k| judge.a.hit(k)).count();
    let count = |c: PixelClass| pixels.iter().filter(|p| p.class == c).count();
    Ok(Arbitration {
        candidate_bound,
        reference_bound,
        disagreeing: pixels.iter().filter(|p| p.disagrees).count(),
        checked,
        reference_errors: count(PixelClass::ReferenceError),
        unexplained_reference_errors: count(PixelClass::UnexplainedReferenceError),
        candidate_errors: count(PixelClass::CandidateError),
        ties: count(PixelClass::Tie),
        coincident: pixels.iter().filter(|p| p.coincident).count(),
        input_rounding: count(PixelClass::InputRounding),
        proven_reference_errors: pixels.iter().filter(|p| p.repro.is_some()).count(),
        delta_max,
        feature_min,
        radius_max,
        cannot_discriminate: delta_max >= feature_min,
        reference: against,
        pixels,
    })
}

/// Whether Mitsuba 3 has a sensor for this projection: the pinhole (`perspective`) and the
/// `orthographic` camera. The lens models have none.
pub fn has_mitsuba_sensor(p: &Projection) -> bool {
    matches!(p, Projection::Perspective | Projection::Orthographic { .. })
}

/// The exact answer on every pixel ray of `scene`'s camera ([`Camera::pixel_ray`], the rays
/// cylaov renders), as an image with the reference's channels: `distance`, `depth`,
/// `normal`, `position` (each rounded once to float32), `shape_id` and `part` (u32; every
/// channel 0 where the ray misses). The reference of a camera Mitsuba has no sensor for.
pub fn exact_render(scene: &Scene) -> Result<AovImage> {
    use crate::image::{Channel, ChannelData};
    let cam = Camera::new(scene.camera);
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let tracer = Tracer {
        cylinders: &scene.cylinders,
        boxes: scene.cylinders.iter().map(Cylinder::bounds).collect(),
        cam,
    };
    let n = w * h;
    let what = "the exact answer's image";
    let mut f: Vec<Vec<f32>> = (0..8)
        .map(|_| crate::mem::zeroed_or_exit::<f32>(n, what))
        .collect();
    let mut ids = crate::mem::zeroed_or_exit::<u32>(n, what);
    let mut parts = crate::mem::zeroed_or_exit::<u32>(n, what);
    // Bands of rows traced in parallel, so only one band's answers are held at a time.
    const BAND: usize = 32;
    for y0 in (0..h).step_by(BAND) {
        let rows: Vec<Vec<Option<Exact>>> = (y0..(y0 + BAND).min(h))
            .into_par_iter()
            .map(|y| {
                (0..w)
                    .map(|x| tracer.trace(&cam.pixel_ray(x as u32, y as u32)))
                    .collect()
            })
            .collect();
        for (k, e) in rows.iter().flatten().enumerate() {
            let Some(e) = e else { continue };
            let k = y0 * w + k;
            let values = [
                e.t,
                e.depth,
                e.normal.x,
                e.normal.y,
                e.normal.z,
                e.position.x,
                e.position.y,
                e.position.z,
            ];
            for (c, v) in f.iter_mut().zip(values) {
                c[k] = v as f32;
            }
            ids[k] = scene.cylinders[e.index].id;
            parts[k] = e.part;
        }
    }
    let names = [
        "distance",
        "depth",
        "normal.X",
        "normal.Y",
        "normal.Z",
        "position.X",
        "position.Y",
        "position.Z",
    ];
    let mut channels: Vec<Channel> = names
        .iter()
        .zip(f)
        .map(|(name, v)| Channel {
            name: (*name).into(),
            data: ChannelData::F32(v),
        })
        .collect();
    channels.push(Channel {
        name: "shape_id".into(),
        data: ChannelData::U32(ids),
    });
    channels.push(Channel {
        name: "part".into(),
        data: ChannelData::U32(parts),
    });
    Ok(AovImage::from_channels(w, h, channels))
}

/// The reproduction of Mitsuba's answer `sb` (`hb`: a hit) at the pixel ray `ray`, when its
/// shape is not the exact answer's on Mitsuba's own inputs: the cylinders `rounded` (as
/// float32) and the ray rounded to float32 with its origin moved to the near plane (where
/// Mitsuba's camera rays start; `t` then counts from there). `None` when the shapes agree
/// or Mitsuba's shape is not stored.
fn reproduce(
    scene: &Scene,
    rounded: &[Cylinder],
    tracer32: &Tracer,
    ray: &PixelRay,
    sb: &Sample,
    hb: bool,
) -> Option<Repro> {
    let (id, part) = (sb.id?, sb.part?);
    let shift = ray.tmin.max(0.0);
    let origin = (ray.origin + ray.dir * shift).as_vec3();
    let dir = ray.dir.as_vec3();
    let tmax = (ray.tmax - shift) as f32;
    let e = tracer32.trace(&PixelRay {
        origin: origin.as_dvec3(),
        dir: dir.as_dvec3(),
        tmin: 0.0,
        tmax: f64::from(tmax),
        ..*ray
    });
    let exact = e.as_ref().map(|e| ReproHit {
        id: rounded[e.index].id,
        shape: shape_word(e.part),
        t: e.t,
    });
    let reference = hb.then(|| ReproHit {
        id,
        shape: shape_word(part),
        t: sb.distance.unwrap_or(f64::NAN) - shift,
    });
    let same = match (&exact, &reference) {
        (None, None) => true,
        (Some(a), Some(b)) => (a.id, a.shape) == (b.id, b.shape),
        _ => false,
    };
    if same {
        return None;
    }
    // The exact answer's cylinder and every cylinder with Mitsuba's id (ids may repeat).
    let cylinders = scene
        .cylinders
        .iter()
        .enumerate()
        .filter(|(k, c)| e.as_ref().is_some_and(|e| e.index == *k) || (hb && c.id == id))
        .map(|(k, c)| ReproCylinder::new(k, c))
        .collect();
    Some(Repro {
        origin: origin.to_array(),
        dir: dir.to_array(),
        tmax,
        cylinders,
        reference,
        exact,
    })
}

/// `c` as Mitsuba parses the exported XML: `p0`, `p1` and `radius` rounded to float32.
fn float32_inputs(c: &Cylinder) -> Cylinder {
    let round = |v: DVec3| v.as_vec3().as_dvec3();
    let (p0, p1) = (round(c.base), round(c.top()));
    Cylinder {
        base: p0,
        axis: (p1 - p0).normalize(),
        height: (p1 - p0).length(),
        radius: f64::from(c.radius as f32),
        ..*c
    }
}
