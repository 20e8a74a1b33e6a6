//! The rule: tolerances, conditioning bounds, identity labels, and the comparison.

use super::*;

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

/// The size of the coordinates a float32 renderer rounds when it builds pixel `(i, j)`'s ray
/// origin: the `|o|` term of `L` in `δ = K·ε₃₂·L` (see the module docs).
///
/// - **Perspective** (Mitsuba's `perspective` sensor): every ray starts at the camera centre,
///   the translation of `to_world`, rounded once to float32: `|o|`.
/// - **Orthographic** (Mitsuba's `orthographic` sensor, `src/sensors/orthographic.cpp`):
///   the film sample goes through the float32 inverse of the orthographic projection to the
///   near-plane point `p = (x', y', near)` of the sensor's own frame (x', y' in
///   [-1, 1] × [-1/aspect, 1/aspect]), and `ray.o = to_world · p`, with `to_world` the
///   look-at times the export's `scale(ortho_width / 2)`. Each output coordinate is a
///   float32 dot product of a `to_world` row with `(p, 1)`, whose rounding error is a few
///   ulps of `Σ |M_ij p_j| + |o|`; the terms are the lateral offsets `|x|`, `|y|` in world
///   units (the half-width scale is in the matrix), the near distance and the translation,
///   so the origin is off by `K·ε₃₂·(|o| + |x| + |y| + near)`. `ray.d = normalize(to_world ·
///   (0, 0, 1))` is the look-at's forward column, rounded as the pinhole's frame is (a few
///   ulps of angle, the same for every pixel; no projection inverse amplifies it, unlike the
///   pinhole's), and it moves the hit sideways by those ulps times the run `t`: the `t` term
///   of `L`. Mitsuba's `t` starts on the near plane, `near` short of ours, so ours bounds it.
///   Measured against Mitsuba 3.9.1's own `sample_ray` at all 76 800 pixel centres of
///   `scenes/orthographic.json` (`tests/verify_models.rs`): its ray origins lie within
///   2.2e-6 of our rays, at most 0.59 of this origin term at K = 4 (2.3 ulps), and its
///   direction is 2.4e-8 rad (0.4 ulp) off ours; along the ray its origin sits `near`
///   ahead of ours to 1.1e-6.
/// - **Lens models** (no Mitsuba sensor): rays from the camera centre, `|o|` as the pinhole.
pub fn ray_origin_size(cam: &Camera, i: u32, j: u32) -> f64 {
    match cam.projection {
        Projection::Orthographic {
            half_width,
            half_height,
        } => {
            let (w, h) = (f64::from(cam.width()), f64::from(cam.height()));
            let x = ((f64::from(i) + 0.5) / w * 2.0 - 1.0) * half_width;
            let y = (1.0 - (f64::from(j) + 0.5) / h * 2.0) * half_height;
            cam.origin.length() + x.abs() + y.abs() + cam.spec.near_clip
        }
        Projection::Perspective | Projection::Lens(_) => cam.origin.length(),
    }
}

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
    /// [`CONDITIONING_ULPS`]. `None` if a channel is missing, the size differs or the camera
    /// is not one Mitsuba has a sensor for (the pinhole and the orthographic camera).
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
        // The bounds follow the pixel rays of Mitsuba's two sensors; the lens models, which
        // Mitsuba has no sensor for, get none.
        let mitsuba_sensor = matches!(
            cam.projection,
            Projection::Perspective | Projection::Orthographic { .. }
        );
        if (w, h) != (cam.width() as usize, cam.height() as usize) || !mitsuba_sensor {
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
        let what = "the conditioning bounds";
        let mut rel = crate::mem::zeroed_or_exit::<f64>(w * h, what);
        let mut normal_deg = crate::mem::zeroed_or_exit::<f64>(w * h, what);
        for j in 0..h {
            for i in 0..w {
                let k = j * w + i;
                let (Some(&(reach, r)), t) = (by_id.get(&ids[k]), f64::from(dist[k])) else {
                    continue;
                };
                if !t.is_finite() || t <= 0.0 {
                    continue;
                }
                let d = cam.pixel_ray(i as u32, j as u32).dir;
                let origin = ray_origin_size(&cam, i as u32, j as u32);
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

/// The per-pixel classes behind a report (internal; the heatmap draws them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Class {
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
pub(super) fn is_id_channel(name: &str) -> bool {
    crate::scene::Aov::of_channel(name)
        .is_some_and(|a| a.spec().metric == crate::scene::aov::CompareMetric::Identity)
}

/// An id channel as u32 labels, from a u32 or a float32 channel.
pub(super) fn id_labels(img: &AovImage, name: &str, which: &str) -> Result<Option<Vec<u32>>> {
    match img.channel(name) {
        None => Ok(None),
        Some(ChannelRef::U32(v)) => {
            let mut out = Vec::new();
            crate::mem::try_reserve(&mut out, v.len(), LABELS)?;
            out.extend(v.iter());
            Ok(Some(out))
        }
        Some(ChannelRef::F32(v)) => {
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
pub(super) const LABELS: &str = "comparing: the per-pixel labels";

/// An id channel (`shape_id` or `part`) of `img` as u32 labels, whether stored as u32 or
/// as float32 (Mitsuba); `None` when absent. `which` names the image in the error.
pub fn id_channel(img: &AovImage, name: &str, which: &str) -> Result<Option<Vec<u32>>> {
    id_labels(img, name, which)
}

/// Hit (1) / miss (0) from `distance`, else `depth`.
pub(super) fn hit_labels(img: &AovImage, which: &str) -> Result<(Vec<u32>, &'static str)> {
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

pub(super) fn names(img: &AovImage) -> Vec<String> {
    img.names().into_iter().map(String::from).collect()
}

/// Per-pixel identities of one image: cylinder label (0 = miss) and the (cylinder, part)
/// key (equal to the cylinder label when parts are not compared).
pub(super) struct Labels {
    cylinder: Vec<u32>,
    key: Vec<u64>,
}

pub(super) struct Classified {
    a: Labels,
    b: Labels,
    pub(super) classes: Vec<Class>,
    identity: Identity,
    notes: Vec<String>,
}

/// Both images' identities, and how they were decided.
pub(super) fn labels(
    a: &AovImage,
    b: &AovImage,
) -> Result<(Labels, Labels, Identity, Vec<String>)> {
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
pub(super) fn on_boundary<L: PartialEq>(
    labels: &[L],
    w: usize,
    h: usize,
    x: usize,
    y: usize,
) -> bool {
    let l = &labels[y * w + x];
    (y.saturating_sub(1)..=(y + 1).min(h - 1))
        .any(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).any(|xx| labels[yy * w + xx] != *l))
}

pub(super) fn classify(a: &AovImage, b: &AovImage) -> Result<Classified> {
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

pub(super) fn rel(a: f32, b: f32) -> f64 {
    let (a, b) = (f64::from(a), f64::from(b));
    let scale = a.abs().max(b.abs());
    if scale == 0.0 {
        0.0
    } else {
        (a - b).abs() / scale
    }
}

pub(super) fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
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

pub(super) fn vec3_at(v: &[crate::image::Strided<f32>; 3], k: usize) -> [f64; 3] {
    [f64::from(v[0][k]), f64::from(v[1][k]), f64::from(v[2][k])]
}

pub(super) fn finite3(p: [f64; 3]) -> bool {
    p.iter().all(|x| x.is_finite())
}

pub(super) fn same_sample_type(a: &AovImage, b: &AovImage, name: &str) -> bool {
    matches!(
        (a.channel(name), b.channel(name)),
        (Some(ChannelRef::F32(_)), Some(ChannelRef::F32(_)))
            | (Some(ChannelRef::U32(_)), Some(ChannelRef::U32(_)))
    )
}

/// Which channels are compared, which clash in type, which only one image has.
pub(super) struct ChannelSets {
    compared: Vec<String>,
    type_clashes: Vec<String>,
    only_in_a: Vec<String>,
    only_in_b: Vec<String>,
    notes: Vec<String>,
}

pub(super) fn channel_sets(a: &AovImage, b: &AovImage) -> ChannelSets {
    let (names_a, names_b) = (names(a), names(b));
    let (compared, type_clashes): (Vec<String>, Vec<String>) = names_a
        .iter()
        .filter(|x| names_b.contains(x))
        .cloned()
        .partition(|name| is_id_channel(name) || same_sample_type(a, b, name));
    let kind = |img: &AovImage, name: &str| match img.channel(name) {
        Some(ChannelRef::U32(_)) => "u32",
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
pub(super) struct Errors {
    rel_distance: Option<Metric>,
    rel_depth: Option<Metric>,
    normal_deg: Option<Metric>,
    position_abs: Option<Stat>,
    position_rel: Option<Stat>,
    uv_side: Option<Stat>,
}

pub(super) fn errors(
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
    let [u_name, v_name] = crate::scene::Aov::Uv.spec().channels else {
        unreachable!("uv has two channels")
    };
    let uv_side = match (both_f32(u_name), both_f32(v_name)) {
        (Some((ua, ub)), Some((va, vb))) => {
            // Side pixels only (part 1 or 2 in A; `same` pixels have B's part too): a
            // cap's uv is cylaov's own, Mitsuba's disk has another.
            let side: Vec<u32> = id_labels(a, "part", "A")?.unwrap_or_default();
            let mut vals = room()?;
            vals.extend(
                same.iter()
                    .filter(|&&k| matches!(side.get(k), Some(1 | 2)))
                    .map(|&k| {
                        // u is a turn: 0.999 and 0.001 are 0.002 apart.
                        let du = (f64::from(ua[k]) - f64::from(ub[k])).rem_euclid(1.0);
                        let du = du.min(1.0 - du);
                        let dv = (f64::from(va[k]) - f64::from(vb[k])).abs();
                        (du.max(dv), k)
                    })
                    .filter(|(e, _)| e.is_finite()),
            );
            Some(Stat::from_values(vals, w))
        }
        _ => None,
    };
    Ok(Errors {
        uv_side,
        rel_distance: scalar("distance")?,
        rel_depth: scalar("depth")?,
        normal_deg,
        position_abs: position_pairs.map(|v| Stat::from_values(v, w)),
        position_rel,
    })
}

/// Non-finite samples in `img`'s compared float channels.
pub(super) fn non_finite(img: &AovImage, compared: &[String]) -> usize {
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
        uv_side: e.uv_side,
        non_finite_a: non_finite(a, &sets.compared),
        non_finite_b: non_finite(b, &sets.compared),
        channels: sets.compared,
        type_clashes: sets.type_clashes,
        only_in_a: sets.only_in_a,
        only_in_b: sets.only_in_b,
        notes,
    })
}
