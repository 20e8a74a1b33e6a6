//! Per-pixel comparison of two AOV images: the rule that `cylaov compare`, `cylaov verify`,
//! `batch --verify-fraction` and the reference tests all use.
//!
//! # Identity
//!
//! Each pixel gets an *identity* in each image: the hit cylinder's `shape_id` (0 = miss) and
//! the `part` it hit (1 side seen from outside, 2 side seen from inside, 3 bottom cap at
//! `p0`, 4 top cap at `p1`; 0 = miss). Without `part` in both images only the cylinder is
//! compared; without `shape_id` in both, only hit (1) / miss (0) from `distance` (else
//! `depth`) > 0, and a note says that different-cylinder errors go undetected. Then:
//!
//! - **same**: same cylinder and same part, not a miss. Error statistics (median, p99, max)
//!   are taken over these pixels only, for every channel both images have: relative
//!   distance and depth error `|a - b| / max(|a|, |b|)`, normal angle in degrees
//!   (`atan2(|a × b|, a · b)`, so tiny angles are exact), and the position error (absolute,
//!   and relative to the distance when a `distance` channel exists; informational, no
//!   tolerance).
//! - **silhouette mismatch**: different cylinders, or hit vs miss. Allowed only where the
//!   pixel has an 8-neighbour of another cylinder label (cylinder or miss) in either image,
//!   and at most [`Tolerances::max_mismatch_fraction`] of the pixels.
//! - **seam mismatch**: the same cylinder but another part (the rim of a cap, where one
//!   renderer takes the cap and the other the side, or the rim of an open tube, where one
//!   takes the outer wall and the other the inner wall behind it). Allowed only where the
//!   pixel has an 8-neighbour of another (cylinder, part) in either image, and at most
//!   [`Tolerances::max_seam_fraction`] of the pixels. Counted apart from silhouettes.
//! - Every other disagreement is an **interior mismatch** and fails, however rare.
//!   Mismatched pixels (of any kind) are left out of the error statistics.
//! - Non-finite samples (NaN, ±inf) in any compared float channel always fail.
//!
//! # Flat bounds, and the float32 conditioning bound at grazing pixels
//!
//! [`Tolerances::default()`] is the bar: 0.05% silhouette mismatches, 0.1% seam mismatches,
//! 3e-5 relative distance and depth, 0.1° of normal. Those bounds hold on every pixel
//! unless the comparison is given a [`Conditioning`], the per-pixel bound of what float32
//! inputs can explain, which matters at grazing incidence only:
//!
//! Mitsuba builds its rays in float32 and moves them into each shape's object space in
//! float32, so its ray is displaced sideways by `δ ≈ K·ε₃₂·L`, with `ε₃₂ = 2⁻²⁴`,
//! `L = |o| + max(|p0|, |p1|) + t` the size of the coordinates that are rounded (camera
//! origin `o`, the shape's placement, the run `t` of a float32 direction) and `K` =
//! [`CONDITIONING_ULPS`]. A sideways shift `δ` moves the hit along the surface by
//! `δ / cos i` (`i`: angle between the ray and the normal), so the distance changes by up
//! to `δ / cos i` and, on the side of radius `r`, the normal turns by `δ / (r cos i)`
//! radians. Where the ray is so close to tangent that this linear model breaks
//! (`cos i < √(δ/r)`), the change is at most `√(δ r)`, so `cos i` is clamped there. The
//! pixel's bound is then the larger of the flat bound and this one, in relative distance
//! (and depth) `δ / (t cos i)` and in normal angle `δ / (r cos i)` (on the side only: a
//! cap's normal does not depend on where the ray meets it); on ordinary pixels it is
//! far below the flat bounds (at `L = 10`, `cos i = 0.5`, `t = 5`: 9.5e-7 against 3e-5), so
//! it changes nothing there. Pixels whose error is within their conditioning bound but above
//! the flat bound are *explained*; [`Report::explained_lines`] says how many, the largest
//! and its bound, so a reader sees what the rule accepted. `tests/verify.rs` checks with
//! the double-double oracle that on such pixels cylaov agrees with the exact answer and
//! Mitsuba does not.
//!
//! `shape_id` and `part` may be u32 (cylaov) or float32 (Mitsuba references: one component
//! type per bitmap), in either image and mixed: they are compared as ids, and float ids
//! must be whole numbers below 2^24. Any other channel both images have with different
//! sample types (u32 in one, float32 in the other) is not compared: it is listed in
//! [`Report::type_clashes`] and a note says so.

use crate::output::aov::{AovImage, ChannelData};
use crate::scene::Scene;
use crate::scene::camera::Camera;
use anyhow::{Result, bail};
use glam::DVec3;
use image::{Rgb, RgbImage};
use serde::Serialize;
use std::fmt;

/// Pass/fail bounds for a [`Report`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Tolerances {
    /// Largest allowed fraction of silhouette-mismatched pixels (different cylinder or hit
    /// vs miss; all must be on silhouettes).
    pub max_mismatch_fraction: f64,
    /// Largest allowed fraction of seam-mismatched pixels (same cylinder, another part; all
    /// must be on a part boundary).
    pub max_seam_fraction: f64,
    /// Largest allowed relative distance error.
    pub rel_distance: f64,
    /// Largest allowed relative planar-depth error.
    pub rel_depth: f64,
    /// Largest allowed normal angle error, degrees.
    pub normal_deg: f64,
}

impl Default for Tolerances {
    /// What "agrees with Mitsuba" means: 0.05% silhouette mismatches, 0.1% seam
    /// mismatches, 3e-5 relative distance and depth, 0.1° of normal. They sit above
    /// Mitsuba's own float32 floor (measured on a 200-cylinder 320×240 scene: 8e-6 relative
    /// distance, 0.031°); `tests/reference.rs` holds tighter measured bounds.
    fn default() -> Self {
        Tolerances {
            max_mismatch_fraction: 5e-4,
            max_seam_fraction: 1e-3,
            rel_distance: 3e-5,
            rel_depth: 3e-5,
            normal_deg: 0.1,
        }
    }
}

/// How pixel identity was decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Identity {
    /// Both images carry `shape_id` and `part`: identity is (cylinder, part).
    ShapeIdPart,
    /// Both carry `shape_id`, not both `part`: identity is the cylinder.
    ShapeId,
    /// At least one lacks `shape_id`: labels are hit/miss from distance or depth > 0.
    HitMiss,
}

/// The float32 ulps `K` of the sideways ray error `δ = K·ε₃₂·L` (see the module docs).
/// Mitsuba rounds the camera origin, the look-at frame, the direction and the
/// world-to-object transform, each about one ulp. Measured against Mitsuba 3.9.1: the
/// most grazing pixel of the committed scenes (`grazing_steep`, cos i = 7e-4) differs by
/// half its bound at K = 4 (5.9e-5 against 1.2e-4); the worst pixels of the other scenes
/// sit at most at a quarter of it; of 427 generated views the most demanding passes at
/// K = 2 and fails at K = 1. 4 leaves a margin of 2 or more, room for another CPU.
pub const CONDITIONING_ULPS: f64 = 4.0;

/// Per-pixel bounds of what float32 inputs can explain (see the module docs), from the
/// scene and one image's own hits. 0 where that image misses.
#[derive(Clone, Debug, PartialEq)]
pub struct Conditioning {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Relative distance (and depth) error float32 inputs can explain, per pixel,
    /// row-major, row 0 at the top.
    pub rel: Vec<f64>,
    /// Normal angle error float32 inputs can explain, degrees, per pixel, row-major (0 on
    /// caps when the image has `part`).
    pub normal_deg: Vec<f64>,
}

impl Conditioning {
    /// The bounds of `scene`'s pixels from `img`'s `shape_id`, `distance` and `normal`
    /// (a render of `scene` with those AOVs, cylaov's or Mitsuba's), at
    /// [`CONDITIONING_ULPS`]. `None` if a channel is missing or the size differs.
    pub fn new(scene: &Scene, img: &AovImage) -> Option<Conditioning> {
        Conditioning::with_ulps(scene, img, CONDITIONING_ULPS)
    }

    /// [`Conditioning::new`] with a sideways ray error of `ulps` float32 ulps. The
    /// reference drift check uses 2: two runs of the same float32 renderer whose inputs
    /// differ in the last bit (another CPU or numpy) are each about 1 ulp off.
    pub fn with_ulps(scene: &Scene, img: &AovImage, ulps: f64) -> Option<Conditioning> {
        let ids = id_labels(img, "shape_id", "conditioning").ok()??;
        let dist = img.f32_channel("distance")?;
        let normal = img.vec3_channel("normal")?;
        // A cap's normal does not depend on where the ray meets the plane: no normal
        // allowance there (when the image tells caps apart).
        let parts = id_labels(img, "part", "conditioning").ok().flatten();
        let cam = Camera::new(scene.camera);
        let (w, h) = (img.width, img.height);
        if (w, h) != (cam.width() as usize, cam.height() as usize) {
            return None;
        }
        // Per id: the largest |p| of its cylinders' end points and the smallest radius
        // (ids are usually unique; with repeats the looser bound is kept).
        let mut by_id: std::collections::HashMap<u32, (f64, f64)> = Default::default();
        for c in &scene.cylinders {
            let reach = c.base.length().max(c.top().length());
            let e = by_id.entry(c.id).or_insert((0.0, f64::INFINITY));
            *e = (e.0.max(reach), e.1.min(c.radius));
        }
        let eps32 = f64::from(f32::EPSILON) / 2.0;
        let origin = cam.origin.length();
        let what = "the conditioning bounds";
        let mut rel = crate::mem::zeroed_or_exit::<f64>(w * h, what);
        let mut normal_deg = crate::mem::zeroed_or_exit::<f64>(w * h, what);
        for j in 0..h {
            let y = cam.row_offset(j as u32);
            for i in 0..w {
                let k = j * w + i;
                let (Some(&(reach, r)), t) = (by_id.get(&ids[k]), f64::from(dist[k])) else {
                    continue;
                };
                if !t.is_finite() || t <= 0.0 {
                    continue;
                }
                let d = cam.dir_from_offsets(cam.column_offset(i as u32), y);
                let n = DVec3::new(
                    f64::from(normal[0][k]),
                    f64::from(normal[1][k]),
                    f64::from(normal[2][k]),
                );
                let Some(n) = n.try_normalize() else {
                    continue;
                };
                let delta = ulps * eps32 * (origin + reach + t);
                // Linear in δ down to cos i = √(δ/r); nearer tangency the change is √(δr).
                let cos = n.dot(d).abs().max((delta / r).sqrt());
                rel[k] = delta / (t * cos);
                let on_cap = parts.as_ref().is_some_and(|p| p[k] >= 3);
                if !on_cap {
                    normal_deg[k] = (delta / (r * cos)).to_degrees();
                }
            }
        }
        Some(Conditioning {
            width: w,
            height: h,
            rel,
            normal_deg,
        })
    }
}

/// Summary of one error metric over the pixels where both images hit the same part of the
/// same cylinder.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Stat {
    /// Pixels measured (finite samples in both images).
    pub count: usize,
    /// Median (nearest rank; 0 when `count` is 0).
    pub median: f64,
    /// 99th percentile (nearest rank; 0 when `count` is 0).
    pub p99: f64,
    /// Largest value (0 when `count` is 0).
    pub max: f64,
    /// `[x, y]` of the largest error (row 0 at the top).
    pub worst_pixel: Option<[usize; 2]>,
}

impl Stat {
    fn from_values(mut v: Vec<(f64, usize)>, width: usize) -> Stat {
        if v.is_empty() {
            return Stat {
                count: 0,
                median: 0.0,
                p99: 0.0,
                max: 0.0,
                worst_pixel: None,
            };
        }
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = v.len();
        // Nearest-rank percentiles.
        let rank = |p: f64| v[((p * n as f64).ceil() as usize).clamp(1, n) - 1].0;
        let (max, at) = v[n - 1];
        Stat {
            count: n,
            median: rank(0.5),
            p99: rank(0.99),
            max,
            worst_pixel: Some([at % width, at / width]),
        }
    }
}

/// One checked metric: its statistics over every compared pixel and, with a
/// [`Conditioning`], the split into pixels its per-pixel bound explains and the rest.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Metric {
    /// Statistics over every measured pixel, explained or not.
    pub all: Stat,
    /// The pixels whose error exceeds their conditioning bound: the flat bound applies to
    /// these (`None` without conditioning: then it applies to `all`).
    pub unexplained: Option<Stat>,
    /// The largest errors within their pixel's conditioning bound, largest first, at most
    /// [`EXPLAINED_KEPT`]: `(error, [x, y], bound)`.
    pub explained: Vec<(f64, [usize; 2], f64)>,
}

/// How many of the largest explained errors a [`Metric`] keeps.
pub const EXPLAINED_KEPT: usize = 100;

impl Metric {
    /// What the flat bound is checked against.
    pub fn checked(&self) -> &Stat {
        self.unexplained.as_ref().unwrap_or(&self.all)
    }

    /// The explained pixels above `flat`: how many (a lower bound when all
    /// [`EXPLAINED_KEPT`] kept ones are), and the largest.
    pub fn explained_above(&self, flat: f64) -> (usize, Option<(f64, [usize; 2], f64)>) {
        let n = self.explained.iter().take_while(|x| x.0 > flat).count();
        (n, self.explained.first().copied().filter(|x| x.0 > flat))
    }

    fn new(vals: Vec<(f64, usize)>, bound: Option<&[f64]>, width: usize) -> Metric {
        let Some(bound) = bound else {
            return Metric {
                all: Stat::from_values(vals, width),
                unexplained: None,
                explained: Vec::new(),
            };
        };
        type Pixels = Vec<(f64, usize)>;
        let (mut within, beyond): (Pixels, Pixels) =
            vals.iter().partition(|(e, k)| *e <= bound[*k]);
        within.sort_by(|a, b| b.0.total_cmp(&a.0));
        let explained = within
            .iter()
            .take(EXPLAINED_KEPT)
            .map(|&(e, k)| (e, [k % width, k / width], bound[k]))
            .collect();
        Metric {
            all: Stat::from_values(vals, width),
            unexplained: Some(Stat::from_values(beyond, width)),
            explained,
        }
    }
}

/// The result of [`compare`]: counts, error statistics, notes. `Serialize` for `--json`,
/// `Display` for a person.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    /// Image width in pixels (both images have the same size).
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// `width × height`: the denominator of the mismatch fractions.
    pub pixels: usize,
    /// How pixel identity was decided (what "same" means below).
    pub identity: Identity,
    /// Whether per-pixel float32 conditioning bounds were applied.
    pub conditioned: bool,
    /// Channels present in both images with compatible sample types (compared).
    pub channels: Vec<String>,
    /// Channels present in both images but not compared because their sample types differ
    /// (u32 in one, float32 in the other; `shape_id` and `part` never land here: they are
    /// compared as ids whatever their type).
    pub type_clashes: Vec<String>,
    /// Channels only one image has (not compared).
    pub only_in_a: Vec<String>,
    /// Channels only B has (not compared).
    pub only_in_b: Vec<String>,
    /// Pixels where A hits (non-zero `shape_id`, or hit by `distance`/`depth` > 0 under
    /// [`Identity::HitMiss`]).
    pub hits_a: usize,
    /// Pixels where B hits, by the same rule.
    pub hits_b: usize,
    /// Pixels where both hit the same part of the same cylinder (the same cylinder, or just
    /// both hit, under a coarser [`Identity`]): the statistics' population.
    pub same: usize,
    /// Pixels of different cylinders or hit vs miss.
    pub silhouette_mismatches: usize,
    /// Those of `silhouette_mismatches` next to a cylinder boundary in either image (the kind
    /// that may be allowed).
    pub silhouette_on_boundary: usize,
    /// Silhouette mismatches over all pixels (what `max_mismatch_fraction` bounds).
    pub silhouette_fraction: f64,
    /// Pixels of the same cylinder but another part.
    pub seams: usize,
    /// Those of `seams` next to a (cylinder, part) boundary in either image (the
    /// kind that may be allowed).
    pub seams_on_boundary: usize,
    /// Seam mismatches over all pixels (what `max_seam_fraction` bounds).
    pub seam_fraction: f64,
    /// Up to 10 seam mismatches on a part boundary, `[x, y]`.
    pub seam_examples: Vec<[usize; 2]>,
    /// Mismatches of either kind, silhouette and seam, away from any boundary (always a
    /// failure).
    pub mismatches_interior: usize,
    /// Up to 10 interior mismatches, `[x, y]`.
    pub interior_examples: Vec<[usize; 2]>,
    /// Relative distance error `|a - b| / max(|a|, |b|)` (needs `distance` in both).
    pub rel_distance: Option<Metric>,
    /// Relative planar-depth error, same formula (needs `depth` in both).
    pub rel_depth: Option<Metric>,
    /// Normal angle error in degrees (needs `normal` in both).
    pub normal_deg: Option<Metric>,
    /// `|Δposition|` in world units.
    pub position_abs: Option<Stat>,
    /// `|Δposition| / distance` (needs `distance` in both).
    pub position_rel: Option<Stat>,
    /// Non-finite samples in A's compared float channels (any is a failure).
    pub non_finite_a: usize,
    /// Non-finite samples in B's compared float channels (any is a failure).
    pub non_finite_b: usize,
    /// What the comparison could not do or check (missing identity channels, type clashes,
    /// no error channel), one sentence each.
    pub notes: Vec<String>,
}

/// The per-pixel classes behind a report (internal; the heatmap draws them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Class {
    BothMiss,
    Same,
    /// Different cylinder or hit vs miss, next to a cylinder boundary.
    Silhouette,
    /// Same cylinder, another part, next to a part boundary.
    Seam,
    /// Either kind of disagreement with no boundary near.
    Interior,
}

/// Whether `name` is an id channel (compared as ids whatever its sample type).
fn is_id_channel(name: &str) -> bool {
    name == "shape_id" || name == "part"
}

/// An id channel as u32 labels, from a u32 or a float32 channel.
fn id_labels(img: &AovImage, name: &str, which: &str) -> Result<Option<Vec<u32>>> {
    match img.channel(name) {
        None => Ok(None),
        Some(ChannelData::U32(v)) => Ok(Some(crate::mem::try_copy(v, LABELS)?)),
        Some(ChannelData::F32(v)) => {
            let mut out = Vec::new();
            crate::mem::try_reserve(&mut out, v.len(), LABELS)?;
            for (k, &x) in v.iter().enumerate() {
                if !(x.is_finite() && x >= 0.0 && x.fract() == 0.0 && x <= 16_777_216.0) {
                    bail!(
                        "{which}: {name} at pixel [{}, {}] is {x}; a float {name} must be a whole number in [0, 2^24]",
                        k % img.width,
                        k / img.width
                    );
                }
                out.push(x as u32);
            }
            Ok(Some(out))
        }
    }
}

/// What the per-pixel buffers of a comparison are called in an out-of-memory error.
const LABELS: &str = "comparing: the per-pixel labels";

/// An id channel (`shape_id` or `part`) of `img` as u32 labels, whether stored as u32 or
/// as float32 (Mitsuba); `None` when absent. `which` names the image in the error.
pub fn id_channel(img: &AovImage, name: &str, which: &str) -> Result<Option<Vec<u32>>> {
    id_labels(img, name, which)
}

/// Hit (1) / miss (0) from `distance`, else `depth`.
fn hit_labels(img: &AovImage, which: &str) -> Result<(Vec<u32>, &'static str)> {
    for name in ["distance", "depth"] {
        if let Some(v) = img.f32_channel(name) {
            let mut out = Vec::new();
            crate::mem::try_reserve(&mut out, v.len(), LABELS)?;
            out.extend(v.iter().map(|&x| u32::from(x > 0.0)));
            return Ok((out, name));
        }
    }
    bail!("{which}: cannot tell hits from misses: no shape_id, distance or depth channel")
}

fn names(img: &AovImage) -> Vec<String> {
    img.channels.iter().map(|c| c.name.clone()).collect()
}

/// Per-pixel identities of one image: cylinder label (0 = miss) and the (cylinder, part)
/// key (equal to the cylinder label when parts are not compared).
struct Labels {
    cylinder: Vec<u32>,
    key: Vec<u64>,
}

struct Classified {
    a: Labels,
    b: Labels,
    classes: Vec<Class>,
    identity: Identity,
    notes: Vec<String>,
}

/// Both images' identities, and how they were decided.
fn labels(a: &AovImage, b: &AovImage) -> Result<(Labels, Labels, Identity, Vec<String>)> {
    let mut notes = Vec::new();
    let (cyl_a, cyl_b, identity) = match (
        id_labels(a, "shape_id", "A")?,
        id_labels(b, "shape_id", "B")?,
    ) {
        (Some(la), Some(lb)) => (la, lb, Identity::ShapeId),
        (ia, ib) => {
            // An image with shape_id tells its hits by it (0 = miss), the other by depth.
            let hits = |ids: Option<Vec<u32>>, img: &AovImage, which: &str| match ids {
                Some(mut ids) => {
                    ids.iter_mut().for_each(|l| *l = u32::from(*l != 0));
                    Ok((ids, "shape_id"))
                }
                None => hit_labels(img, which),
            };
            let missing_a = ia.is_none();
            let missing_b = ib.is_none();
            let (la, ca) = hits(ia, a, "A")?;
            let (lb, cb) = hits(ib, b, "B")?;
            let missing = match (missing_a, missing_b) {
                (true, true) => "both images lack",
                (false, true) => "B lacks",
                _ => "A lacks",
            };
            notes.push(format!(
                "{missing} shape_id: pixels classified by hit/miss only (A from {ca} > 0, B from {cb} > 0); different-cylinder errors are not detected"
            ));
            (la, lb, Identity::HitMiss)
        }
    };
    let parts = match (
        identity,
        id_labels(a, "part", "A")?,
        id_labels(b, "part", "B")?,
    ) {
        (Identity::ShapeId, Some(pa), Some(pb)) => Some((pa, pb)),
        (Identity::ShapeId, pa, pb) => {
            notes.push(format!(
                "{} part: cylinder identity only; cap/side seams are not told apart",
                if pa.is_none() && pb.is_none() {
                    "both images lack"
                } else if pa.is_none() {
                    "A lacks"
                } else {
                    "B lacks"
                }
            ));
            None
        }
        _ => None,
    };
    let key = |cyl: &[u32], part: Option<&[u32]>| -> Result<Vec<u64>> {
        let mut out = Vec::new();
        crate::mem::try_reserve(&mut out, cyl.len(), LABELS)?;
        match part {
            Some(p) => out.extend(
                cyl.iter()
                    .zip(p)
                    .map(|(&c, &p)| u64::from(c) << 32 | u64::from(p)),
            ),
            None => out.extend(cyl.iter().map(|&c| u64::from(c) << 32)),
        }
        Ok(out)
    };
    let identity = if parts.is_some() {
        Identity::ShapeIdPart
    } else {
        identity
    };
    let (pa, pb) = match &parts {
        Some((pa, pb)) => (Some(pa.as_slice()), Some(pb.as_slice())),
        None => (None, None),
    };
    let la = Labels {
        key: key(&cyl_a, pa)?,
        cylinder: cyl_a,
    };
    let lb = Labels {
        key: key(&cyl_b, pb)?,
        cylinder: cyl_b,
    };
    Ok((la, lb, identity, notes))
}

/// Whether pixel `(x, y)` of a `w × h` label image has an 8-neighbour with another label.
fn on_boundary<L: PartialEq>(labels: &[L], w: usize, h: usize, x: usize, y: usize) -> bool {
    let l = &labels[y * w + x];
    (y.saturating_sub(1)..=(y + 1).min(h - 1))
        .any(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).any(|xx| labels[yy * w + xx] != *l))
}

fn classify(a: &AovImage, b: &AovImage) -> Result<Classified> {
    if (a.width, a.height) != (b.width, b.height) {
        bail!(
            "image sizes differ: A is {}x{}, B is {}x{}",
            a.width,
            a.height,
            b.width,
            b.height
        );
    }
    let (la, lb, identity, notes) = labels(a, b)?;
    let (w, h) = (a.width, a.height);
    let mut classes = Vec::new();
    crate::mem::try_reserve(&mut classes, w * h, LABELS)?;
    for y in 0..h {
        for x in 0..w {
            let k = y * w + x;
            let (ca, cb) = (la.cylinder[k], lb.cylinder[k]);
            classes.push(if ca != cb {
                if on_boundary(&la.cylinder, w, h, x, y) || on_boundary(&lb.cylinder, w, h, x, y) {
                    Class::Silhouette
                } else {
                    Class::Interior
                }
            } else if la.key[k] != lb.key[k] {
                if on_boundary(&la.key, w, h, x, y) || on_boundary(&lb.key, w, h, x, y) {
                    Class::Seam
                } else {
                    Class::Interior
                }
            } else if ca == 0 {
                Class::BothMiss
            } else {
                Class::Same
            });
        }
    }
    Ok(Classified {
        a: la,
        b: lb,
        classes,
        identity,
        notes,
    })
}

fn rel(a: f32, b: f32) -> f64 {
    let (a, b) = (f64::from(a), f64::from(b));
    let scale = a.abs().max(b.abs());
    if scale == 0.0 {
        0.0
    } else {
        (a - b).abs() / scale
    }
}

fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let (na, nb) = (
        (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt(),
        (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt(),
    );
    if na == 0.0 || nb == 0.0 {
        // A hit without a normal: the worst possible answer.
        return 180.0;
    }
    let cross = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let c = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    c.atan2(d).to_degrees()
}

fn vec3_at(v: &[&[f32]; 3], k: usize) -> [f64; 3] {
    [f64::from(v[0][k]), f64::from(v[1][k]), f64::from(v[2][k])]
}

fn finite3(p: [f64; 3]) -> bool {
    p.iter().all(|x| x.is_finite())
}

fn same_sample_type(a: &AovImage, b: &AovImage, name: &str) -> bool {
    matches!(
        (a.channel(name), b.channel(name)),
        (Some(ChannelData::F32(_)), Some(ChannelData::F32(_)))
            | (Some(ChannelData::U32(_)), Some(ChannelData::U32(_)))
    )
}

/// Which channels are compared, which clash in type, which only one image has.
struct ChannelSets {
    compared: Vec<String>,
    type_clashes: Vec<String>,
    only_in_a: Vec<String>,
    only_in_b: Vec<String>,
    notes: Vec<String>,
}

fn channel_sets(a: &AovImage, b: &AovImage) -> ChannelSets {
    let (names_a, names_b) = (names(a), names(b));
    let (compared, type_clashes): (Vec<String>, Vec<String>) = names_a
        .iter()
        .filter(|x| names_b.contains(x))
        .cloned()
        .partition(|name| is_id_channel(name) || same_sample_type(a, b, name));
    let kind = |img: &AovImage, name: &str| match img.channel(name) {
        Some(ChannelData::U32(_)) => "u32",
        _ => "float32",
    };
    let notes = type_clashes
        .iter()
        .map(|name| {
            format!(
                "{name} not compared: it is {} in A but {} in B",
                kind(a, name),
                kind(b, name)
            )
        })
        .collect();
    let only = |x: &[String], y: &[String]| x.iter().filter(|n| !y.contains(n)).cloned().collect();
    ChannelSets {
        only_in_a: only(&names_a, &names_b),
        only_in_b: only(&names_b, &names_a),
        compared,
        type_clashes,
        notes,
    }
}

/// The error statistics over the `same` pixels.
struct Errors {
    rel_distance: Option<Metric>,
    rel_depth: Option<Metric>,
    normal_deg: Option<Metric>,
    position_abs: Option<Stat>,
    position_rel: Option<Stat>,
}

fn errors(
    a: &AovImage,
    b: &AovImage,
    same: &[usize],
    cond: Option<&Conditioning>,
) -> Result<Errors> {
    let w = a.width;
    // Every metric is taken over `same`: reserve that much up front, fallibly.
    let room = || -> Result<Vec<(f64, usize)>> {
        let mut v = Vec::new();
        crate::mem::try_reserve(&mut v, same.len(), "comparing: the per-pixel errors")?;
        Ok(v)
    };
    let both_f32 = |name: &str| Some((a.f32_channel(name)?, b.f32_channel(name)?));
    let both_vec3 = |name: &str| Some((a.vec3_channel(name)?, b.vec3_channel(name)?));
    let scalar = |name: &str| -> Result<Option<Metric>> {
        let Some((va, vb)) = both_f32(name) else {
            return Ok(None);
        };
        let mut vals = room()?;
        vals.extend(
            same.iter()
                .filter(|&&k| va[k].is_finite() && vb[k].is_finite())
                .map(|&k| (rel(va[k], vb[k]), k)),
        );
        Ok(Some(Metric::new(vals, cond.map(|c| c.rel.as_slice()), w)))
    };
    let normal_deg = match both_vec3("normal") {
        None => None,
        Some((na, nb)) => {
            let mut vals = room()?;
            vals.extend(
                same.iter()
                    .map(|&k| (vec3_at(&na, k), vec3_at(&nb, k), k))
                    .filter(|(x, y, _)| finite3(*x) && finite3(*y))
                    .map(|(x, y, k)| (angle_deg(x, y), k)),
            );
            Some(Metric::new(vals, cond.map(|c| c.normal_deg.as_slice()), w))
        }
    };
    let position_pairs = match both_vec3("position") {
        None => None,
        Some((pa, pb)) => {
            let mut vals = room()?;
            vals.extend(
                same.iter()
                    .map(|&k| (vec3_at(&pa, k), vec3_at(&pb, k), k))
                    .filter(|(x, y, _)| finite3(*x) && finite3(*y))
                    .map(|(x, y, k)| {
                        let d = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
                        ((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(), k)
                    }),
            );
            Some(vals)
        }
    };
    let position_rel = match (&position_pairs, both_f32("distance")) {
        (Some(p), Some((da, db))) => {
            let mut vals = room()?;
            vals.extend(
                p.iter()
                    .filter(|&&(_, k)| da[k].is_finite() && db[k].is_finite())
                    .map(|&(e, k)| {
                        let s = f64::from(da[k].abs().max(db[k].abs()));
                        (if s > 0.0 { e / s } else { e }, k)
                    }),
            );
            Some(Stat::from_values(vals, w))
        }
        _ => None,
    };
    Ok(Errors {
        rel_distance: scalar("distance")?,
        rel_depth: scalar("depth")?,
        normal_deg,
        position_abs: position_pairs.map(|v| Stat::from_values(v, w)),
        position_rel,
    })
}

/// Non-finite samples in `img`'s compared float channels.
fn non_finite(img: &AovImage, compared: &[String]) -> usize {
    compared
        .iter()
        .filter(|n| !is_id_channel(n))
        .filter_map(|n| img.f32_channel(n))
        .map(|v| v.iter().filter(|x| !x.is_finite()).count())
        .sum()
}

/// Compare `a` with `b` pixel by pixel with flat bounds only (see the module docs). Errors
/// if the sizes differ or a float id is not a whole number.
pub fn compare(a: &AovImage, b: &AovImage) -> Result<Report> {
    compare_with(a, b, None)
}

/// [`compare`], with per-pixel float32 conditioning bounds where `cond` is given (it must
/// have the images' size).
pub fn compare_with(a: &AovImage, b: &AovImage, cond: Option<&Conditioning>) -> Result<Report> {
    let c = classify(a, b)?;
    let (w, h) = (a.width, a.height);
    let n = w * h;
    if let Some(cond) = cond
        && (cond.width, cond.height) != (w, h)
    {
        bail!(
            "conditioning bounds are {}x{}, the images {w}x{h}",
            cond.width,
            cond.height
        );
    }
    let sets = channel_sets(a, b);
    let mut notes = c.notes;
    notes.extend(sets.notes);
    let count = |cl: Class| c.classes.iter().filter(|&&x| x == cl).count();
    let mut same = Vec::new();
    crate::mem::try_reserve(&mut same, count(Class::Same), LABELS)?;
    same.extend((0..n).filter(|&k| c.classes[k] == Class::Same));
    let e = errors(a, b, &same, cond)?;
    if e.rel_distance.is_none() && e.rel_depth.is_none() && e.normal_deg.is_none() {
        notes.push("no distance, depth or normal channel in both images: only hit/miss and identity compared".into());
    }
    let cylinders_differ = |k: usize| c.a.cylinder[k] != c.b.cylinder[k];
    let interior: Vec<usize> = (0..n)
        .filter(|&k| c.classes[k] == Class::Interior)
        .collect();
    let interior_cylinders = interior.iter().filter(|&&k| cylinders_differ(k)).count();
    let on_sil = count(Class::Silhouette);
    let on_seam = count(Class::Seam);
    let mismatches = on_sil + interior_cylinders;
    let seams = on_seam + interior.len() - interior_cylinders;
    Ok(Report {
        width: w,
        height: h,
        pixels: n,
        identity: c.identity,
        conditioned: cond.is_some(),
        hits_a: c.a.cylinder.iter().filter(|&&l| l != 0).count(),
        hits_b: c.b.cylinder.iter().filter(|&&l| l != 0).count(),
        same: same.len(),
        silhouette_mismatches: mismatches,
        silhouette_on_boundary: on_sil,
        silhouette_fraction: mismatches as f64 / n as f64,
        seams,
        seams_on_boundary: on_seam,
        seam_fraction: seams as f64 / n as f64,
        seam_examples: (0..n)
            .filter(|&k| c.classes[k] == Class::Seam)
            .take(10)
            .map(|k| [k % w, k / w])
            .collect(),
        mismatches_interior: interior.len(),
        interior_examples: interior.iter().take(10).map(|&k| [k % w, k / w]).collect(),
        rel_distance: e.rel_distance,
        rel_depth: e.rel_depth,
        normal_deg: e.normal_deg,
        position_abs: e.position_abs,
        position_rel: e.position_rel,
        non_finite_a: non_finite(a, &sets.compared),
        non_finite_b: non_finite(b, &sets.compared),
        channels: sets.compared,
        type_clashes: sets.type_clashes,
        only_in_a: sets.only_in_a,
        only_in_b: sets.only_in_b,
        notes,
    })
}

impl Report {
    /// One line per metric that has pixels above its flat bound which their float32
    /// conditioning bound explains (what the grazing rule accepted; empty without
    /// conditioning or when the flat bounds hold everywhere).
    pub fn explained_lines(&self, tol: &Tolerances) -> Vec<String> {
        let mut out = Vec::new();
        for (name, m, flat) in [
            ("relative distance", &self.rel_distance, tol.rel_distance),
            ("relative depth", &self.rel_depth, tol.rel_depth),
            ("normal angle (deg)", &self.normal_deg, tol.normal_deg),
        ] {
            let Some(m) = m else { continue };
            if let (n, Some((e, at, bound))) = m.explained_above(flat) {
                let more = if n == EXPLAINED_KEPT { "at least " } else { "" };
                out.push(format!(
                    "{name}: {more}{n} px above {flat:.3e}, each within its float32 conditioning bound (largest {e:.3e} at {at:?}, bound {bound:.3e})"
                ));
            }
        }
        out
    }

    /// Whether every tolerance holds.
    pub fn passes(&self, tol: &Tolerances) -> bool {
        self.failures(tol).is_empty()
    }

    /// One line per broken tolerance (empty when the comparison passes): which bound, by
    /// how much, and where.
    pub fn failures(&self, tol: &Tolerances) -> Vec<String> {
        let mut out = Vec::new();
        if self.silhouette_fraction > tol.max_mismatch_fraction {
            out.push(format!(
                "silhouette mismatch fraction {:.3e} ({} px) > {:.3e}",
                self.silhouette_fraction, self.silhouette_mismatches, tol.max_mismatch_fraction
            ));
        }
        if self.seam_fraction > tol.max_seam_fraction {
            out.push(format!(
                "seam mismatch fraction {:.3e} ({} px) > {:.3e}",
                self.seam_fraction, self.seams, tol.max_seam_fraction
            ));
        }
        if self.mismatches_interior > 0 {
            out.push(format!(
                "{} mismatches off silhouettes and seams, e.g. at {:?}",
                self.mismatches_interior, self.interior_examples
            ));
        }
        let beyond = if self.conditioned {
            " (beyond its float32 conditioning bound)"
        } else {
            ""
        };
        let mut check = |name: &str, m: &Option<Metric>, limit: f64| {
            if let Some(m) = m
                && m.checked().max > limit
            {
                let s = m.checked();
                out.push(format!(
                    "{name} max {:.3e} > {limit:.3e} at {:?}{beyond}",
                    s.max,
                    s.worst_pixel.unwrap_or_default()
                ));
            }
        };
        check(
            "relative distance error",
            &self.rel_distance,
            tol.rel_distance,
        );
        check("relative depth error", &self.rel_depth, tol.rel_depth);
        check("normal angle error (deg)", &self.normal_deg, tol.normal_deg);
        if self.non_finite_a + self.non_finite_b > 0 {
            out.push(format!(
                "non-finite samples: A {}, B {}",
                self.non_finite_a, self.non_finite_b
            ));
        }
        out
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let identity = match self.identity {
            Identity::ShapeIdPart => "by shape_id and part",
            Identity::ShapeId => "by shape_id",
            Identity::HitMiss => "by hit/miss only",
        };
        writeln!(
            f,
            "{}x{} pixels, identity {identity}; compared: {}",
            self.width,
            self.height,
            self.channels.join(" ")
        )?;
        if !self.only_in_a.is_empty() || !self.only_in_b.is_empty() {
            writeln!(
                f,
                "not compared: only in A [{}], only in B [{}]",
                self.only_in_a.join(" "),
                self.only_in_b.join(" ")
            )?;
        }
        let same = match self.identity {
            Identity::ShapeIdPart => "same cylinder and part",
            Identity::ShapeId => "same cylinder",
            Identity::HitMiss => "both hit",
        };
        writeln!(
            f,
            "hits: A {}, B {}, {same} {}",
            self.hits_a, self.hits_b, self.same
        )?;
        writeln!(
            f,
            "mismatches: {} ({:.4}%) silhouette, {} ({:.4}%) seam; {} of them interior",
            self.silhouette_mismatches,
            100.0 * self.silhouette_fraction,
            self.seams,
            100.0 * self.seam_fraction,
            self.mismatches_interior
        )?;
        writeln!(
            f,
            "{:<22} {:>11} {:>11} {:>11}  worst [x, y]",
            "error", "median", "p99", "max"
        )?;
        let row = |f: &mut fmt::Formatter<'_>, name: &str, s: &Stat| {
            let at = s
                .worst_pixel
                .map_or("-".to_string(), |p| format!("[{}, {}]", p[0], p[1]));
            writeln!(
                f,
                "{name:<22} {:>11.3e} {:>11.3e} {:>11.3e}  {at}",
                s.median, s.p99, s.max
            )
        };
        for (name, m) in [
            ("relative distance", &self.rel_distance),
            ("relative depth", &self.rel_depth),
            ("normal angle (deg)", &self.normal_deg),
        ] {
            if let Some(m) = m {
                row(f, name, &m.all)?;
            }
        }
        for (name, s) in [
            ("position (abs)", &self.position_abs),
            ("position / distance", &self.position_rel),
        ] {
            if let Some(s) = s {
                row(f, name, s)?;
            }
        }
        if self.conditioned {
            writeln!(
                f,
                "float32 conditioning bounds applied (ray error {CONDITIONING_ULPS} ulps)"
            )?;
        }
        write!(
            f,
            "non-finite samples: A {}, B {}",
            self.non_finite_a, self.non_finite_b
        )?;
        for n in &self.notes {
            write!(f, "\nnote: {n}")?;
        }
        Ok(())
    }
}

/// The tolerance line of a text report.
pub fn tolerance_line(t: &Tolerances) -> String {
    format!(
        "tolerances: silhouette mismatches <= {:.2e}, seam mismatches <= {:.2e}, rel distance <= {:.1e}, rel depth <= {:.1e}, normal <= {} deg",
        t.max_mismatch_fraction, t.max_seam_fraction, t.rel_distance, t.rel_depth, t.normal_deg
    )
}

/// `PASS`, or `FAIL:` and one indented line per broken tolerance.
pub fn verdict_lines(failures: &[String]) -> String {
    if failures.is_empty() {
        return "PASS".into();
    }
    let mut s = String::from("FAIL:");
    for f in failures {
        s += &format!("\n  {f}");
    }
    s
}

/// Colour for an error `e` in units of its tolerance: log scale from 1e-4 (dark blue)
/// through 1e-2 (green) to 1 (yellow); above the tolerance, magenta.
pub fn error_colour(e: f64) -> Rgb<u8> {
    if e > 1.0 {
        return OVER_TOLERANCE;
    }
    let s = ((e.max(1e-4).log10() + 4.0) / 4.0).clamp(0.0, 1.0);
    let lerp =
        |a: u8, b: u8, t: f64| (f64::from(a) + (f64::from(b) - f64::from(a)) * t).round() as u8;
    if s < 0.5 {
        let t = s / 0.5;
        Rgb([0, lerp(20, 170, t), lerp(90, 60, t)])
    } else {
        let t = (s - 0.5) / 0.5;
        Rgb([lerp(0, 255, t), lerp(170, 230, t), lerp(60, 0, t)])
    }
}

/// Heatmap colour of a pixel both images miss.
pub const BOTH_MISS: Rgb<u8> = Rgb([28, 28, 28]);
/// Heatmap colour of a silhouette mismatch (allowed up to its fraction).
pub const SILHOUETTE: Rgb<u8> = Rgb([255, 140, 0]);
/// Heatmap colour of a seam mismatch (allowed up to its fraction).
pub const SEAM: Rgb<u8> = Rgb([0, 200, 230]);
/// Heatmap colour of an interior mismatch (always a failure).
pub const INTERIOR: Rgb<u8> = Rgb([255, 0, 0]);
/// Heatmap colour of an error above its bound (always a failure).
pub const OVER_TOLERANCE: Rgb<u8> = Rgb([255, 0, 255]);

/// [`heatmap`] as the PNG `compare --heatmap` and `verify --heatmap` write: every failing
/// pixel ringed in white (one such pixel is invisible at a glance), and under the image a
/// legend of every colour in the words of the text report (silhouette, seam, interior,
/// tolerance). Wider than the image when the legend needs it.
pub fn heatmap_figure(
    a: &AovImage,
    b: &AovImage,
    report: &Report,
    tol: &Tolerances,
    cond: Option<&Conditioning>,
) -> RgbImage {
    with_legend(&heatmap(a, b, report, tol, cond))
}

/// The legend's entries, top to bottom: colour and label.
pub const LEGEND: [(Rgb<u8>, &str); 6] = [
    (BOTH_MISS, "BOTH MISS"),
    (SILHOUETTE, "SILHOUETTE MISMATCH"),
    (SEAM, "SEAM MISMATCH"),
    (INTERIOR, "INTERIOR MISMATCH (FAIL)"),
    (OVER_TOLERANCE, "OVER TOLERANCE (FAIL)"),
    (crate::output::plot::WHITE, "RING: FAILING PIXEL"),
];

fn with_legend(heat: &RgbImage) -> RgbImage {
    use crate::output::plot;
    let (w, h) = heat.dimensions();
    let scale = (w / 160).clamp(1, 4);
    let s = scale as i64;
    let row = 8 * s;
    let ramp_label = "ERROR/TOLERANCE 1E-4";
    let widest = LEGEND
        .iter()
        .map(|(_, l)| 6 * s + plot::text_width(l, scale))
        .chain([plot::text_width(ramp_label, scale) + 40 * s])
        .max()
        .unwrap_or(0)
        + 2;
    let fig_w = w.max(widest as u32);
    let rows = LEGEND.len() as i64 + 1;
    let mut out = RgbImage::new(fig_w, h + 2 + (rows * row) as u32);
    image::imageops::replace(&mut out, heat, 0, 0);
    let failing = |p: &Rgb<u8>| *p == INTERIOR || *p == OVER_TOLERANCE;
    let ringed: Vec<(i64, i64)> = heat
        .enumerate_pixels()
        .filter(|(_, _, p)| failing(p))
        .map(|(x, y, _)| (x as i64, y as i64))
        .collect();
    // Rings only where they can be told apart: beyond a few thousand the failing area is
    // itself visible.
    if ringed.len() <= 4000 {
        let r = 3 + s;
        for &(x, y) in &ringed {
            for d in -r..=r {
                for (px, py) in [
                    (x + d, y - r),
                    (x + d, y + r),
                    (x - r, y + d),
                    (x + r, y + d),
                ] {
                    if px >= 0
                        && py >= 0
                        && px < w as i64
                        && py < h as i64
                        && !failing(heat.get_pixel(px as u32, py as u32))
                    {
                        out.put_pixel(px as u32, py as u32, plot::WHITE);
                    }
                }
            }
        }
    }
    let mut y = h as i64 + 3;
    for (c, label) in LEGEND {
        plot::fill(&mut out, 1, y, 5 * scale, 5 * scale, c);
        if c == plot::WHITE {
            plot::fill(&mut out, 1 + s, y + s, 3 * scale, 3 * scale, plot::BLACK);
        }
        plot::text(&mut out, 1 + 6 * s, y, scale, label, plot::WHITE);
        y += row;
    }
    // The error ramp of same-part pixels, in units of the tolerance, log scale 1e-4 .. 1.
    plot::text(&mut out, 1, y, scale, ramp_label, plot::WHITE);
    let x0 = 1 + plot::text_width(ramp_label, scale) + 2 * s;
    let x1 = (fig_w as i64 - plot::text_width("1", scale) - 3 * s).max(x0 + 10);
    for px in x0..x1 {
        let e = 10f64.powf(-4.0 + 4.0 * (px - x0) as f64 / (x1 - x0 - 1).max(1) as f64);
        plot::fill(&mut out, px, y, 1, 5 * scale, error_colour(e));
    }
    plot::text(&mut out, x1 + 2 * s, y, scale, "1", plot::WHITE);
    out
}

/// Where `a` and `b` differ, as an image (row 0 at the top):
/// - dark grey: both miss;
/// - red: mismatch off silhouettes and seams (always a failure); orange: silhouette
///   mismatch; cyan: seam mismatch (same cylinder, another part);
/// - pixels where both hit the same part of the same cylinder: the largest of the relative
///   distance, relative depth and normal angle errors, each divided by its bound (the
///   run's flat tolerance in `tol`, or the pixel's float32 conditioning bound in `cond`
///   where that is larger), on the log colour scale of blue (≤ 1e-4 of the bound) → green
///   (1e-2) → yellow (the bound); magenta above the bound, so magenta marks exactly the
///   pixels that fail.
///
/// `report` must come from comparing `a` with `b`; it names the channels to use.
pub fn heatmap(
    a: &AovImage,
    b: &AovImage,
    report: &Report,
    tol: &Tolerances,
    cond: Option<&Conditioning>,
) -> RgbImage {
    let (w, h) = (a.width, a.height);
    let mut img = RgbImage::new(w as u32, h as u32);
    let Ok(c) = classify(a, b) else {
        return img;
    };
    let has = |name: &str| report.channels.iter().any(|c| c == name);
    let dist = has("distance")
        .then(|| Some((a.f32_channel("distance")?, b.f32_channel("distance")?)))
        .flatten();
    let depth = has("depth")
        .then(|| Some((a.f32_channel("depth")?, b.f32_channel("depth")?)))
        .flatten();
    let normal = has("normal.X")
        .then(|| Some((a.vec3_channel("normal")?, b.vec3_channel("normal")?)))
        .flatten();
    let cond = cond.filter(|c| (c.width, c.height) == (w, h));
    let bound = |flat: f64, per_pixel: Option<f64>| per_pixel.map_or(flat, |p| p.max(flat));
    for (k, class) in c.classes.iter().enumerate() {
        let px = match class {
            Class::BothMiss => BOTH_MISS,
            Class::Interior => INTERIOR,
            Class::Silhouette => SILHOUETTE,
            Class::Seam => SEAM,
            Class::Same => {
                let rel_b = cond.map(|c| c.rel[k]);
                let mut e: f64 = 0.0;
                if let Some((x, y)) = dist {
                    e = e.max(rel(x[k], y[k]) / bound(tol.rel_distance, rel_b));
                }
                if let Some((x, y)) = depth {
                    e = e.max(rel(x[k], y[k]) / bound(tol.rel_depth, rel_b));
                }
                if let Some((x, y)) = &normal {
                    let nb = bound(tol.normal_deg, cond.map(|c| c.normal_deg[k]));
                    e = e.max(angle_deg(vec3_at(x, k), vec3_at(y, k)) / nb);
                }
                if e.is_nan() {
                    OVER_TOLERANCE
                } else {
                    error_colour(e)
                }
            }
        };
        img.put_pixel((k % w) as u32, (k / w) as u32, px);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::aov::Channel;

    /// A 6x5 image: cylinder 1 fills columns 1..=3 of rows 1..=3, the rest misses.
    fn image() -> AovImage {
        let (w, h) = (6, 5);
        let mut dist = vec![0f32; w * h];
        let mut ids = vec![0u32; w * h];
        let mut nz = vec![0f32; w * h];
        for y in 1..=3 {
            for x in 1..=3 {
                let k = y * w + x;
                dist[k] = 2.0 + x as f32 * 0.125;
                ids[k] = 1;
                nz[k] = 1.0;
            }
        }
        AovImage {
            width: w,
            height: h,
            channels: vec![
                Channel {
                    name: "distance".into(),
                    data: ChannelData::F32(dist),
                },
                Channel {
                    name: "normal.X".into(),
                    data: ChannelData::F32(vec![0.0; w * h]),
                },
                Channel {
                    name: "normal.Y".into(),
                    data: ChannelData::F32(vec![0.0; w * h]),
                },
                Channel {
                    name: "normal.Z".into(),
                    data: ChannelData::F32(nz),
                },
                Channel {
                    name: "shape_id".into(),
                    data: ChannelData::U32(ids.clone()),
                },
                Channel {
                    name: "part".into(),
                    data: ChannelData::U32(ids),
                },
            ],
        }
    }

    fn f32_mut<'a>(img: &'a mut AovImage, name: &str) -> &'a mut Vec<f32> {
        match &mut img
            .channels
            .iter_mut()
            .find(|c| c.name == name)
            .expect("channel")
            .data
        {
            ChannelData::F32(v) => v,
            ChannelData::U32(_) => panic!("{name} is u32"),
        }
    }

    fn ids_mut(img: &mut AovImage) -> &mut Vec<u32> {
        match &mut img
            .channels
            .iter_mut()
            .find(|c| c.name == "shape_id")
            .expect("ids")
            .data
        {
            ChannelData::U32(v) => v,
            ChannelData::F32(_) => panic!("shape_id is f32"),
        }
    }

    #[test]
    fn identical_images_have_zero_error() {
        let a = image();
        let r = compare(&a, &a).expect("same size");
        assert_eq!(r.identity, Identity::ShapeIdPart);
        assert_eq!(
            (r.hits_a, r.hits_b, r.same, r.silhouette_mismatches),
            (9, 9, 9, 0)
        );
        let d = &r.rel_distance.as_ref().expect("distance compared").all;
        assert_eq!((d.count, d.median, d.p99, d.max), (9, 0.0, 0.0, 0.0));
        assert_eq!(r.normal_deg.as_ref().expect("normal").all.max, 0.0);
        assert!(r.rel_depth.is_none());
        assert!(r.passes(&Tolerances::default()));
        assert!(
            r.to_string()
                .contains("mismatches: 0 (0.0000%) silhouette, 0 (0.0000%) seam"),
            "{r}"
        );
    }

    #[test]
    fn errors_are_relative_and_located() {
        let a = image();
        let mut b = image();
        // Pixel (2, 2): distance 2.25 → 2.25·(1 + 1e-5); normal tilted by 0.05°.
        let k = 2 * 6 + 2;
        f32_mut(&mut b, "distance")[k] = 2.25 * (1.0 + 1e-5);
        let tilt = 0.05f64.to_radians();
        f32_mut(&mut b, "normal.X")[k] = tilt.sin() as f32;
        f32_mut(&mut b, "normal.Z")[k] = tilt.cos() as f32;
        let r = compare(&a, &b).expect("same size");
        let d = r.rel_distance.expect("distance").all;
        assert!((d.max - 1e-5).abs() < 1e-7, "{}", d.max);
        assert_eq!(d.worst_pixel, Some([2, 2]));
        assert_eq!(d.median, 0.0);
        let n = r.normal_deg.expect("normal").all;
        assert!((n.max - 0.05).abs() < 1e-5, "{}", n.max);
        assert_eq!(n.worst_pixel, Some([2, 2]));
        // Inside the defaults (3e-5, 0.1°), outside tighter ones.
        let r = compare(&a, &b).expect("same size");
        assert!(r.passes(&Tolerances::default()));
        let tight = Tolerances {
            rel_distance: 5e-6,
            normal_deg: 0.01,
            ..Tolerances::default()
        };
        let f = r.failures(&tight);
        assert_eq!(f.len(), 2, "{f:?}");
        // The heatmap colours against the tolerances it is given: (2, 2) is within the
        // defaults (half of 0.1°) but magenta under the tight ones; untouched pixels are not.
        let magenta = Rgb([255, 0, 255]);
        let hm = heatmap(&a, &b, &r, &Tolerances::default(), None);
        assert_eq!(*hm.get_pixel(2, 2), error_colour(0.5));
        assert_ne!(*hm.get_pixel(2, 2), magenta);
        let hm = heatmap(&a, &b, &r, &tight, None);
        assert_eq!(*hm.get_pixel(2, 2), magenta);
        assert_eq!(*hm.get_pixel(1, 1), error_colour(0.0));
        // 2.25·(1 + 1e-5) rounds to f32 at 9.96e-6 relative.
        assert!(
            f[0].starts_with("relative distance error max 9.96"),
            "{}",
            f[0]
        );
        assert!(f[1].starts_with("normal angle error (deg) max"));
    }

    #[test]
    fn shifted_edge_is_a_silhouette_mismatch() {
        let a = image();
        let mut b = image();
        // B's cylinder also covers (4, 2): a hit vs miss next to A's edge.
        let k = 2 * 6 + 4;
        ids_mut(&mut b)[k] = 1;
        f32_mut(&mut b, "distance")[k] = 2.5;
        f32_mut(&mut b, "normal.Z")[k] = 1.0;
        let r = compare(&a, &b).expect("same size");
        assert_eq!(
            (
                r.silhouette_mismatches,
                r.silhouette_on_boundary,
                r.mismatches_interior
            ),
            (1, 1, 0)
        );
        assert_eq!(r.same, 9);
        assert!((r.silhouette_fraction - 1.0 / 30.0).abs() < 1e-12);
        // 1 of 30 pixels breaks the 0.05% bound but nothing else.
        let f = r.failures(&Tolerances::default());
        assert_eq!(f.len(), 1, "{f:?}");
        assert!(f[0].starts_with("silhouette mismatch fraction"), "{}", f[0]);
        let loose = Tolerances {
            max_mismatch_fraction: 0.1,
            ..Tolerances::default()
        };
        assert!(r.passes(&loose));
        let hm = heatmap(&a, &b, &r, &Tolerances::default(), None);
        assert_eq!(*hm.get_pixel(4, 2), Rgb([255, 140, 0]));
        assert_eq!(*hm.get_pixel(0, 0), Rgb([28, 28, 28]));
        assert_eq!(*hm.get_pixel(2, 2), error_colour(0.0));
    }

    #[test]
    fn interior_mismatch_fails_even_when_rare() {
        let a = image();
        let mut b = image();
        // Centre pixel (2, 2) is cylinder 5 in B: its 8 neighbours are all cylinder 1 in A,
        // but in B they differ from it, so by the either-image rule it is a silhouette.
        ids_mut(&mut b)[2 * 6 + 2] = 5;
        let r = compare(&a, &b).expect("same size");
        assert_eq!((r.silhouette_mismatches, r.silhouette_on_boundary), (1, 1));
        // A true interior mismatch needs both neighbourhoods uniform: B relabels A's whole
        // 3x3 cylinder, so the centre (2, 2) is 1 in A and 4 in B with no edge in either.
        let a3 = image();
        let mut b3 = image();
        for y in 1..=3 {
            for x in 1..=3 {
                ids_mut(&mut b3)[y * 6 + x] = 4;
            }
        }
        let r = compare(&a3, &b3).expect("same size");
        assert_eq!(r.silhouette_mismatches, 9);
        assert_eq!(r.mismatches_interior, 1);
        assert_eq!(r.interior_examples, vec![[2, 2]]);
        assert!(!r.passes(&Tolerances::default()));
        let hm = heatmap(&a3, &b3, &r, &Tolerances::default(), None);
        assert_eq!(*hm.get_pixel(2, 2), Rgb([255, 0, 0]));
    }

    fn part_mut(img: &mut AovImage) -> &mut Vec<u32> {
        match &mut img
            .channels
            .iter_mut()
            .find(|c| c.name == "part")
            .expect("part")
            .data
        {
            ChannelData::U32(v) => v,
            ChannelData::F32(_) => panic!("part is f32"),
        }
    }

    #[test]
    fn seam_mismatch_is_counted_apart_and_left_out_of_the_errors() {
        // Column 1 of the cylinder is its top cap (4) in both images; B also calls (2, 2)
        // the cap, a pixel next to that seam, and puts a 90° normal and 1% distance there.
        let mut a = image();
        for y in 1..=3 {
            part_mut(&mut a)[y * 6 + 1] = 4;
        }
        let mut b = a.clone();
        let k = 2 * 6 + 2;
        part_mut(&mut b)[k] = 4;
        f32_mut(&mut b, "distance")[k] *= 1.01;
        f32_mut(&mut b, "normal.X")[k] = 1.0;
        f32_mut(&mut b, "normal.Z")[k] = 0.0;
        let r = compare(&a, &b).expect("same size");
        assert_eq!(r.identity, Identity::ShapeIdPart);
        assert_eq!(
            (
                r.seams,
                r.seams_on_boundary,
                r.silhouette_mismatches,
                r.mismatches_interior
            ),
            (1, 1, 0, 0)
        );
        assert_eq!(r.same, 8);
        assert_eq!(r.rel_distance.as_ref().expect("distance").all.max, 0.0);
        assert_eq!(r.normal_deg.as_ref().expect("normal").all.max, 0.0);
        // 1 of 30 pixels is above the 0.1% seam bound, and only that fails.
        let f = r.failures(&Tolerances::default());
        assert_eq!(f.len(), 1, "{f:?}");
        assert!(
            f[0].starts_with("seam mismatch fraction 3.333e-2 (1 px)"),
            "{}",
            f[0]
        );
        let loose = Tolerances {
            max_seam_fraction: 0.05,
            ..Tolerances::default()
        };
        assert!(r.passes(&loose));
        let hm = heatmap(&a, &b, &r, &loose, None);
        assert_eq!(*hm.get_pixel(2, 2), Rgb([0, 200, 230]));
        // Without part in B the same pixel is a same-cylinder pixel with a 90° normal.
        let mut c = b.clone();
        c.channels.retain(|c| c.name != "part");
        let r = compare(&a, &c).expect("same size");
        assert_eq!((r.identity, r.seams, r.same), (Identity::ShapeId, 0, 9));
        assert!(r.notes[0].starts_with("B lacks part"), "{:?}", r.notes);
        assert!((r.normal_deg.expect("normal").all.max - 90.0).abs() < 1e-9);
    }

    #[test]
    fn seam_mismatch_away_from_any_part_boundary_fails() {
        // B calls the whole cylinder its inner wall (2): the centre (2, 2) then has the
        // same (cylinder, part) all around it in both images, so no seam excuses it.
        let a = image();
        let mut b = image();
        for y in 1..=3 {
            for x in 1..=3 {
                part_mut(&mut b)[y * 6 + x] = 2;
            }
        }
        let r = compare(&a, &b).expect("same size");
        assert_eq!(
            (r.seams, r.seams_on_boundary, r.silhouette_mismatches),
            (9, 8, 0)
        );
        assert_eq!(r.mismatches_interior, 1);
        assert_eq!(r.interior_examples, vec![[2, 2]]);
        let loose = Tolerances {
            max_seam_fraction: 1.0,
            ..Tolerances::default()
        };
        let f = r.failures(&loose);
        assert_eq!(
            f,
            vec!["1 mismatches off silhouettes and seams, e.g. at [[2, 2]]".to_string()]
        );
        let hm = heatmap(&a, &b, &r, &loose, None);
        assert_eq!(*hm.get_pixel(2, 2), Rgb([255, 0, 0]));
        assert_eq!(*hm.get_pixel(1, 1), Rgb([0, 200, 230]));
    }

    #[test]
    fn conditioning_bounds_only_the_pixels_they_explain() {
        // Distance errors of 5e-5 at (2, 2) and (3, 3); only (2, 2) has a conditioning
        // bound (1e-4) that covers it.
        let a = image();
        let mut b = image();
        for k in [2 * 6 + 2, 3 * 6 + 3] {
            let d = &mut f32_mut(&mut b, "distance")[k];
            *d = (f64::from(*d) * (1.0 + 5e-5)) as f32;
        }
        let mut cond = Conditioning {
            width: 6,
            height: 5,
            rel: vec![1e-7; 30],
            normal_deg: vec![1e-4; 30],
        };
        cond.rel[2 * 6 + 2] = 1e-4;
        let r = compare_with(&a, &b, Some(&cond)).expect("same size");
        let m = r.rel_distance.as_ref().expect("distance");
        assert_eq!(m.all.count, 9);
        let u = m.unexplained.as_ref().expect("conditioned");
        assert_eq!((u.count, u.worst_pixel), (1, Some([3, 3])));
        let (n, top) = m.explained_above(3e-5);
        let (e, at, bound) = top.expect("one explained");
        assert!(
            (e - 5e-5).abs() < 1e-7 && at == [2, 2] && bound == 1e-4,
            "{e} {at:?}"
        );
        assert_eq!(n, 1);
        let lines = r.explained_lines(&Tolerances::default());
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            lines[0].starts_with("relative distance: 1 px above 3.000e-5"),
            "{}",
            lines[0]
        );
        let f = r.failures(&Tolerances::default());
        assert_eq!(f.len(), 1, "{f:?}");
        assert!(
            f[0].contains("at [3, 3] (beyond its float32 conditioning bound)"),
            "{}",
            f[0]
        );
        // With (3, 3) covered too, it passes; without conditioning both fail the flat 3e-5.
        cond.rel[3 * 6 + 3] = 1e-4;
        assert!(
            compare_with(&a, &b, Some(&cond))
                .expect("same size")
                .passes(&Tolerances::default())
        );
        assert!(
            !compare(&a, &b)
                .expect("same size")
                .passes(&Tolerances::default())
        );
        cond.width = 5;
        assert!(compare_with(&a, &b, Some(&cond)).is_err());
    }

    #[test]
    fn float_shape_id_and_fallback() {
        let a = image();
        // B: shape_id as float32, as Mitsuba references store it.
        let mut b = image();
        let ids: Vec<f32> = ids_mut(&mut b).iter().map(|&i| i as f32).collect();
        b.channels.retain(|c| c.name != "shape_id");
        b.channels.push(Channel {
            name: "shape_id".into(),
            data: ChannelData::F32(ids),
        });
        let r = compare(&a, &b).expect("float ids");
        assert_eq!(
            (r.identity, r.same, r.silhouette_mismatches),
            (Identity::ShapeIdPart, 9, 0)
        );
        // u32 against float32 shape_id is the Mitsuba reference case: compared, as ids.
        assert!(r.channels.contains(&"shape_id".to_string()));
        assert!(r.type_clashes.is_empty() && r.notes.is_empty(), "{r:?}");
        // ... and a wrong id in the float image is caught.
        let mut b2 = b.clone();
        if let Some(ChannelData::F32(v)) = b2
            .channels
            .iter_mut()
            .find(|c| c.name == "shape_id")
            .map(|c| &mut c.data)
        {
            for y in 1..=3 {
                for x in 1..=3 {
                    v[y * 6 + x] = 2.0;
                }
            }
        }
        let r2 = compare(&a, &b2).expect("float ids");
        assert_eq!(
            (r2.same, r2.silhouette_mismatches, r2.mismatches_interior),
            (0, 9, 1)
        );
        // A fractional id is an error naming the pixel.
        if let Some(ChannelData::F32(v)) = b
            .channels
            .iter_mut()
            .find(|c| c.name == "shape_id")
            .map(|c| &mut c.data)
        {
            v[3] = 0.5;
        }
        let e = compare(&a, &b).expect_err("fractional id");
        assert!(e.to_string().contains("pixel [3, 0] is 0.5"), "{e}");
        // Without shape_id in B: hit/miss from distance, and a note says so.
        let mut c = image();
        c.channels
            .retain(|c| c.name != "shape_id" && c.name != "part");
        let r = compare(&a, &c).expect("fallback");
        assert_eq!(r.identity, Identity::HitMiss);
        assert_eq!((r.same, r.silhouette_mismatches), (9, 0));
        assert!(r.notes[0].starts_with("B lacks shape_id"));
        assert_eq!(
            r.only_in_a,
            vec!["shape_id".to_string(), "part".to_string()]
        );
    }

    #[test]
    fn other_type_clash_is_reported_not_silently_skipped() {
        let a = image();
        let mut b = image();
        // B stores distance as u32: not comparable, so not "compared", and a note says so.
        let d: Vec<u32> = f32_mut(&mut b, "distance")
            .iter()
            .map(|&x| x as u32)
            .collect();
        b.channels
            .iter_mut()
            .find(|c| c.name == "distance")
            .expect("distance")
            .data = ChannelData::U32(d);
        let r = compare(&a, &b).expect("same size");
        assert_eq!(r.type_clashes, vec!["distance".to_string()]);
        assert!(
            !r.channels.contains(&"distance".to_string()),
            "{:?}",
            r.channels
        );
        assert!(r.rel_distance.is_none());
        assert!(r.normal_deg.is_some());
        assert_eq!(
            r.notes,
            vec!["distance not compared: it is float32 in A but u32 in B".to_string()]
        );
        assert!(r.to_string().contains("note: distance not compared"));
        let r = compare(&b, &a).expect("same size");
        assert_eq!(
            r.notes,
            vec!["distance not compared: it is u32 in A but float32 in B".to_string()]
        );
    }

    #[test]
    fn nan_fails_and_size_mismatch_errors() {
        let a = image();
        let mut b = image();
        f32_mut(&mut b, "distance")[7] = f32::NAN;
        let r = compare(&a, &b).expect("same size");
        assert_eq!(r.non_finite_b, 1);
        assert_eq!(r.rel_distance.as_ref().expect("distance").all.count, 8);
        assert!(!r.passes(&Tolerances::default()));
        let mut small = image();
        small.width = 5;
        small.height = 6;
        let e = compare(&a, &small).expect_err("size");
        assert_eq!(e.to_string(), "image sizes differ: A is 6x5, B is 5x6");
    }

    #[test]
    fn angle_is_accurate_for_tiny_angles() {
        let t = 1e-7f64;
        let a = angle_deg([1.0, 0.0, 0.0], [t.cos(), t.sin(), 0.0]);
        assert!((a - t.to_degrees()).abs() < 1e-15);
        assert_eq!(angle_deg([0.0; 3], [1.0, 0.0, 0.0]), 180.0);
    }
}
