//! Camera models beyond the pinhole, in the camera's own OpenCV axes (x right, y down,
//! z forward): each maps a camera-space direction to a pixel and a pixel back to a unit
//! direction, following the definers' conventions exactly.
//!
//! - [`Lens::OpenCv`]: `cv2.projectPoints`' radial–tangential model, pixel centres at
//!   integers.
//! - [`Lens::OpenCvFisheye`]: `cv2.fisheye.projectPoints`' Kannala–Brandt model (no skew),
//!   pixel centres at integers; the angle from the axis may reach 180° and beyond while
//!   `θ_d(θ)` stays increasing.
//! - [`Lens::Equirectangular`]: the full sphere; column centre `i + 0.5` maps to
//!   longitude `((i + 0.5) / W - 1/2) · 2π` (zero longitude along +z, growing toward +x),
//!   row centre `j + 0.5` to latitude `(1/2 - (j + 0.5) / H) · π` (positive toward -y, up).
//!
//! A pixel's direction is the inverse of the projection at its centre. The distortion
//! models have no closed-form inverse, so it is found by Newton's method and accepted only
//! when projecting it back lands within [`INVERSE_TOLERANCE_PX`] of the centre. The root
//! must be the one reached continuously from the principal axis: for `opencv` the map is
//! followed out from the axis (and, at validation, over a lattice of pixel corners, so
//! a fold between pixel centres or beyond them up to the image's edges is caught), for the
//! fisheye `θ_d` must rise all the way from 0. Where that fails (a fold of the distortion,
//! a non-increasing fisheye polynomial) the model is refused with the field named.

use glam::{DVec2, DVec3};

/// How far, in pixels, a pixel's direction may project back from the pixel centre.
pub const INVERSE_TOLERANCE_PX: f64 = 1e-6;

/// Newton steps tried before an inversion is declared failed; the iterations converge
/// quadratically from the undistorted start for any invertible model, in under ten.
const NEWTON_STEPS: usize = 50;

/// A non-pinhole camera model's intrinsics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lens {
    /// OpenCV's pinhole with radial–tangential distortion.
    OpenCv {
        /// Focal lengths in pixels.
        fx: f64,
        /// Focal length in pixels, y.
        fy: f64,
        /// Principal point, pixels (centres at integers).
        cx: f64,
        /// Principal point y, pixels (centres at integers).
        cy: f64,
        /// Radial and tangential coefficients `[k1, k2, p1, p2, k3]` (OpenCV's order).
        dist: [f64; 5],
    },
    /// OpenCV's fisheye (Kannala–Brandt) model.
    OpenCvFisheye {
        /// Focal length in pixels, x.
        fx: f64,
        /// Focal length in pixels, y.
        fy: f64,
        /// Principal point, pixels (centres at integers).
        cx: f64,
        /// Principal point y, pixels (centres at integers).
        cy: f64,
        /// `[k1, k2, k3, k4]`.
        k: [f64; 4],
    },
    /// The full sphere over a `width` × `height` image.
    Equirectangular {
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
    },
}

/// Why a model cannot serve as a camera: the field at fault and what is wrong.
#[derive(Clone, Debug, PartialEq)]
pub struct LensError {
    /// The scene-file field at fault (`k1`, `fx`, ...).
    pub field: &'static str,
    /// What is wrong, with the values.
    pub message: String,
}

fn lens_err(field: &'static str, message: String) -> LensError {
    LensError { field, message }
}

/// OpenCV's distortion of normalised coordinates `(a, b)` and its Jacobian.
fn distort(d: &[f64; 5], a: f64, b: f64) -> (DVec2, [[f64; 2]; 2]) {
    let [k1, k2, p1, p2, k3] = *d;
    let r2 = a * a + b * b;
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    // d(radial)/d(r2)
    let dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
    let x = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a);
    let y = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b;
    let dxda = radial + a * dradial * 2.0 * a + 2.0 * p1 * b + 6.0 * p2 * a;
    let dxdb = a * dradial * 2.0 * b + 2.0 * p1 * a + 2.0 * p2 * b;
    let dyda = b * dradial * 2.0 * a + 2.0 * p1 * a + 2.0 * p2 * b;
    let dydb = radial + b * dradial * 2.0 * b + 6.0 * p1 * b + 2.0 * p2 * a;
    (DVec2::new(x, y), [[dxda, dxdb], [dyda, dydb]])
}

/// Newton's method for the normalised point whose distortion is `goal`, from `start`:
/// the last iterate (stopped early where the Jacobian is not positive: a fold).
fn undistort(d: &[f64; 5], goal: DVec2, start: DVec2) -> DVec2 {
    let mut ab = start;
    for _ in 0..NEWTON_STEPS {
        let (step, det) = newton_step(d, ab, goal);
        if !positive(det) {
            break;
        }
        ab += step;
        if step.length() <= 1e-16 * (1.0 + ab.length()) {
            break;
        }
    }
    ab
}

/// Newton's step from `ab` toward the point the distortion maps to `goal`:
/// `J⁻¹ (goal − distort(ab))` by Cramer's rule on the 2×2 Jacobian `J` at `ab`, with `J`'s
/// determinant, which each caller checks is positive before it trusts the step.
fn newton_step(d: &[f64; 5], ab: DVec2, goal: DVec2) -> (DVec2, f64) {
    let (p, jac) = distort(d, ab.x, ab.y);
    let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
    let r = goal - p;
    let step = DVec2::new(
        (jac[1][1] * r.x - jac[0][1] * r.y) / det,
        (jac[0][0] * r.y - jac[1][0] * r.x) / det,
    );
    (step, det)
}

/// Whether the distortion's Jacobian at `ab` has a positive determinant (false for NaN).
fn jacobian_positive(d: &[f64; 5], ab: DVec2) -> bool {
    let (_, jac) = distort(d, ab.x, ab.y);
    positive(jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0])
}

/// Sub-goals the earlier versions followed a root through from the axis when Newton from
/// the undistorted point landed past the radial fold (kept for their bits).
const CONTINUATION_STEPS: usize = 64;

/// Whether the radial distortion `ρ (1 + k1 ρ² + k2 ρ⁴ + k3 ρ⁶)` rises all the way from
/// the axis to `ρ² = u0`: its slope `g(u) = 1 + 3 k1 u + 5 k2 u² + 7 k3 u³` (in `u = ρ²`)
/// is positive on `[0, u0]`. `g(0) = 1`, so it suffices that `g` is positive at `u0` and
/// at its turning points inside (the roots of `g'(u) = 3 k1 + 10 k2 u + 21 k3 u²`).
fn radial_rising(d: &[f64; 5], u0: f64) -> bool {
    let [k1, k2, _, _, k3] = *d;
    let g = |u: f64| 1.0 + u * (3.0 * k1 + u * (5.0 * k2 + u * 7.0 * k3));
    let inside = |u: f64| u > 0.0 && u < u0;
    let turning: [Option<f64>; 2] = if k3 == 0.0 {
        [(k2 != 0.0).then(|| -3.0 * k1 / (10.0 * k2)), None]
    } else {
        let disc = 100.0 * k2 * k2 - 252.0 * k1 * k3;
        if disc < 0.0 {
            [None, None]
        } else {
            let q = disc.sqrt();
            [
                Some((-10.0 * k2 + q) / (42.0 * k3)),
                Some((-10.0 * k2 - q) / (42.0 * k3)),
            ]
        }
    };
    positive(g(u0))
        && turning
            .into_iter()
            .flatten()
            .filter(|&u| inside(u))
            .all(|u| positive(g(u)))
}

/// How far, as a fraction of a continuation step, Newton's root may lie from the tangent
/// predictor (the first Newton iterate) for the step to count as staying on one branch.
/// The gap is second order in the step, so halving the step shrinks it fourfold on a
/// smooth branch; across a fold it does not shrink, and the step is refused.
const PREDICTOR_GAP: f64 = 0.25;

/// The smallest continuation step, as a fraction of the path, before the path is declared
/// to cross a fold; and the most steps tried on one path.
const MIN_FRACTION: f64 = 1.0 / (1u64 << 30) as f64;
const MAX_TRIES: usize = 4096;

/// One continuation step: Newton from `ab` (a root for a nearby goal) to the root for
/// `goal`, accepted only while the Jacobian stays positive at every iterate, the
/// iteration converges within a few steps, and the root lies within [`PREDICTOR_GAP`] of
/// the tangent predictor: then it is the root on `ab`'s branch.
fn branch_step(d: &[f64; 5], ab: DVec2, goal: DVec2) -> Option<DVec2> {
    let mut x = ab;
    let mut predictor = None;
    for _ in 0..12 {
        let (dx, det) = newton_step(d, x, goal);
        if !positive(det) {
            return None;
        }
        x += dx;
        let first = *predictor.get_or_insert(x);
        if !x.is_finite() {
            return None;
        }
        // Quadratic convergence: once a correction is under 1e-3 of the step, what is
        // left is of the order of its square (1e-6 of the step, times the curvature),
        // enough to start the next step from; [`follow`] polishes its last root.
        if dx.length() <= 1e-3 * (x - ab).length() + 1e-15 * (1.0 + x.length()) {
            return ((x - first).length() <= PREDICTOR_GAP * (x - ab).length() || x == first)
                .then_some(x);
        }
    }
    None
}

/// The root for `to` on the branch through `ab` (the root for `from`), followed along the
/// straight segment `from → to` in the distorted plane in adaptive steps (doubled after
/// each accepted step, halved after each refused one; the first is `first` of the path;
/// the root is left within about 1e-6 of a step of exact, see [`polish`]);
/// `None` where the branch ends on the way (a fold: the steps shrink below
/// [`MIN_FRACTION`]).
fn follow(d: &[f64; 5], from: DVec2, ab: DVec2, to: DVec2, first: f64) -> Option<DVec2> {
    let (mut t, mut h, mut ab) = (0.0f64, first, ab);
    for _ in 0..MAX_TRIES {
        if t >= 1.0 {
            return Some(ab);
        }
        let t1 = (t + h).min(1.0);
        let sub = if t1 == 1.0 {
            to
        } else {
            from + (to - from) * t1
        };
        match branch_step(d, ab, sub) {
            Some(next) => {
                (t, ab, h) = (t1, next, (2.0 * h).min(1.0));
            }
            None if h > MIN_FRACTION => h *= 0.5,
            None => return None,
        }
    }
    None
}

/// Newton to full precision for `goal` from `ab`, a root [`follow`] left within about
/// 1e-6 of a step of it, which the polished root must not leave.
fn polish(d: &[f64; 5], goal: DVec2, ab: DVec2) -> Option<DVec2> {
    let root = undistort(d, goal, ab);
    ((root - ab).length() <= 1e-6 * (1.0 + ab.length()) && jacobian_positive(d, root))
        .then_some(root)
}

/// The root of `distort = goal` on the principal branch (followed out from the axis),
/// `None` where that branch folds before reaching `goal`. When Newton from the
/// undistorted point lands on that root (as it does for every pixel of a mild lens) its
/// bits are kept, and so are those of the 64-step continuation that earlier versions used
/// past the radial fold: renders of lenses accepted before do not change.
fn principal_root(d: &[f64; 5], goal: DVec2) -> Option<DVec2> {
    let ab0 = undistort(d, goal, goal);
    let rising = radial_rising(d, ab0.length_squared());
    // Newton from `goal` is a single continuation step from the axis (where the
    // Jacobian is the identity, so `goal` is the tangent predictor): the same test
    // accepts it.
    if rising
        && ab0.is_finite()
        && jacobian_positive(d, ab0)
        && (ab0 - goal).length() <= PREDICTOR_GAP * ab0.length()
    {
        return Some(ab0);
    }
    // The single step just failed: start the continuation at half of it.
    let principal = polish(d, goal, follow(d, DVec2::ZERO, DVec2::ZERO, goal, 0.5)?)?;
    let old = if rising {
        ab0
    } else {
        let mut ab = DVec2::ZERO;
        for s in 1..=CONTINUATION_STEPS {
            let sub = goal * (s as f64 / CONTINUATION_STEPS as f64);
            ab = undistort(d, sub, ab);
            if !(jacobian_positive(d, ab) && ab.is_finite()) {
                break;
            }
        }
        ab
    };
    let same = (old - principal).length() <= 1e-9 * (1.0 + principal.length());
    Some(if same && jacobian_positive(d, old) {
        old
    } else {
        principal
    })
}

/// Whether the fisheye slope `dθ_d/dθ = 1 + 3 k1 u + 5 k2 u² + 7 k3 u³ + 9 k4 u⁴`
/// (`u = θ²`) is positive on `[0, u0]`: certified when the quartic's Bernstein
/// coefficients on the interval are all positive (they bound it from below), halving the
/// interval (de Casteljau) where they are not; a slope within rounding of zero somewhere
/// reads as not positive.
fn fisheye_rising(k: &[f64; 4], u0: f64) -> bool {
    let a = [
        1.0,
        3.0 * k[0] * u0,
        5.0 * k[1] * u0 * u0,
        7.0 * k[2] * u0 * u0 * u0,
        9.0 * k[3] * u0 * u0 * u0 * u0,
    ];
    // Power basis on s ∈ [0, 1] to Bernstein: b_j = Σ_{i≤j} C(j,i)/C(4,i) a_i.
    let b = [
        a[0],
        a[0] + a[1] / 4.0,
        a[0] + a[1] / 2.0 + a[2] / 6.0,
        a[0] + 0.75 * a[1] + 0.5 * a[2] + a[3] / 4.0,
        a[0] + a[1] + a[2] + a[3] + a[4],
    ];
    let mut stack = vec![(b, 0u32)];
    while let Some((b, depth)) = stack.pop() {
        if !(positive(b[0]) && positive(b[4])) {
            return false;
        }
        if b.iter().all(|&v| positive(v)) {
            continue;
        }
        if depth == 24 {
            return false;
        }
        // De Casteljau at s = 1/2: the left half's coefficients are the first of each
        // level, the right half's the last.
        let mut lvl = b;
        let (mut left, mut right) = ([0.0; 5], [0.0; 5]);
        for n in 0..5 {
            left[n] = lvl[0];
            right[4 - n] = lvl[4 - n];
            for m in 0..4 - n {
                lvl[m] = 0.5 * (lvl[m] + lvl[m + 1]);
            }
        }
        stack.push((left, depth + 1));
        stack.push((right, depth + 1));
    }
    true
}

/// The fisheye angle with `θ_d(θ) = want` on the rising branch from 0, by marching θ up
/// (4096 steps to 180°, the slope positive at each) to a bracket and bisecting it; `None`
/// where the slope stops being positive first or 180° is not enough. The slow path, for
/// when Newton from `want` does not land on that branch.
fn fisheye_march(k: &[f64; 4], want: f64) -> Option<f64> {
    let steps = 4096;
    let top = std::f64::consts::PI;
    let mut lo = 0.0;
    for s in 1..=steps {
        let hi = top * s as f64 / steps as f64;
        let (td, dtd) = theta_d(k, hi);
        if !positive(dtd) {
            return None;
        }
        if td >= want {
            let (mut lo, mut hi) = (lo, hi);
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                if theta_d(k, mid).0 < want {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return Some(hi);
        }
        lo = hi;
    }
    None
}

/// Kannala–Brandt `θ_d(θ) = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)` and its derivative.
fn theta_d(k: &[f64; 4], t: f64) -> (f64, f64) {
    let t2 = t * t;
    let poly = 1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])));
    let dpoly = t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
    (t * poly, poly + dpoly)
}

/// `x > 0`, false for NaN: the Newton steps stop on a zero, negative or NaN slope.
fn positive(x: f64) -> bool {
    x > 0.0
}

/// The first coefficient that is non-zero, to name in a refusal (`k1` when all are zero).
fn first_nonzero(names: &[&'static str], values: &[f64]) -> &'static str {
    names
        .iter()
        .zip(values)
        .find(|(_, v)| **v != 0.0)
        .map_or(names[0], |(n, _)| n)
}

impl Lens {
    /// Whether `depth` is camera-space z for a ray along `dir` (unit, camera axes): so for
    /// the pinhole-like models and for fisheye rays short of 90° from the axis; else
    /// (equirectangular, fisheye rays at or beyond 90°) `depth` is the Euclidean distance.
    pub fn planar_depth(&self, dir: DVec3) -> bool {
        match self {
            Lens::OpenCv { .. } => true,
            Lens::OpenCvFisheye { .. } => dir.z > 0.0,
            Lens::Equirectangular { .. } => false,
        }
    }

    /// The pixel (continuous coordinates, the model's own pixel convention) a camera-space
    /// point or direction `v` projects to; `None` where the model has no image of it
    /// (behind a pinhole, the zero vector).
    pub fn project(&self, v: DVec3) -> Option<DVec2> {
        match *self {
            Lens::OpenCv {
                fx,
                fy,
                cx,
                cy,
                dist,
            } => {
                if v.z <= 0.0 {
                    return None;
                }
                let (p, _) = distort(&dist, v.x / v.z, v.y / v.z);
                Some(DVec2::new(fx * p.x + cx, fy * p.y + cy))
            }
            Lens::OpenCvFisheye { fx, fy, cx, cy, k } => {
                let rxy = (v.x * v.x + v.y * v.y).sqrt();
                if rxy == 0.0 {
                    return (v.z > 0.0).then_some(DVec2::new(cx, cy));
                }
                // OpenCV computes θ = atan(r) from a = x/z; atan2 is the same angle for
                // z > 0 and carries it on past 90°.
                let (td, _) = theta_d(&k, rxy.atan2(v.z));
                Some(DVec2::new(
                    fx * td * v.x / rxy + cx,
                    fy * td * v.y / rxy + cy,
                ))
            }
            Lens::Equirectangular { width, height } => {
                let len = v.length();
                if len == 0.0 {
                    return None;
                }
                let lon = v.x.atan2(v.z);
                let lat = (-v.y / len).clamp(-1.0, 1.0).asin();
                let u = (lon / std::f64::consts::TAU + 0.5) * width as f64;
                let w = (0.5 - lat / std::f64::consts::PI) * height as f64;
                Some(DVec2::new(u, w))
            }
        }
    }

    /// The unit camera-space direction whose projection is pixel `(i, j)`'s centre
    /// (integers for the OpenCV models, `+ 0.5` for equirectangular), verified to project
    /// back within [`INVERSE_TOLERANCE_PX`].
    pub fn unproject(&self, i: u32, j: u32) -> Result<DVec3, LensError> {
        let (dir, target) = match *self {
            Lens::OpenCv {
                fx,
                fy,
                cx,
                cy,
                dist,
            } => {
                let target = DVec2::new(i as f64, j as f64);
                let goal = DVec2::new((target.x - cx) / fx, (target.y - cy) / fy);
                // The root on the branch reached from the axis; Newton from the
                // undistorted point alone may land past a fold, on a mirrored sheet or an
                // outer root (see [`principal_root`]).
                let root = principal_root(&dist, goal);
                let Some(ab) = root else {
                    return Err(fold_error(&dist, i, j));
                };
                (DVec3::new(ab.x, ab.y, 1.0).normalize(), target)
            }
            Lens::OpenCvFisheye { fx, fy, cx, cy, k } => {
                let target = DVec2::new(i as f64, j as f64);
                let q = DVec2::new((target.x - cx) / fx, (target.y - cy) / fy);
                let want = q.length();
                if want == 0.0 {
                    (DVec3::Z, target)
                } else {
                    let mut t = want;
                    for _ in 0..NEWTON_STEPS {
                        let (td, dtd) = theta_d(&k, t);
                        if !positive(dtd) {
                            break;
                        }
                        let step = (td - want) / dtd;
                        t -= step;
                        if step.abs() <= 1e-16 * (1.0 + t) {
                            break;
                        }
                    }
                    // Newton may also land on a later rising branch (past a maximum
                    // and a minimum of θ_d); the root must lie where θ_d rose all the
                    // way from 0, else it is found by the slow march.
                    let newton_ok = t > 0.0 && t.is_finite() && theta_d(&k, t).1 > 0.0;
                    let root = if newton_ok && fisheye_rising(&k, t * t) {
                        Some(t)
                    } else {
                        fisheye_march(&k, want)
                    };
                    let Some(t) = root else {
                        return Err(lens_err(
                            first_nonzero(&["k1", "k2", "k3", "k4"], &k),
                            format!(
                                "the fisheye polynomial with k = {k:?} does not reach \
                                 θ_d = {want} (pixel ({i}, {j})) while increasing"
                            ),
                        ));
                    };
                    let s = t.sin() / want;
                    (DVec3::new(q.x * s, q.y * s, t.cos()), target)
                }
            }
            Lens::Equirectangular { width, height } => {
                let lon = ((i as f64 + 0.5) / width as f64 - 0.5) * std::f64::consts::TAU;
                let lat = (0.5 - (j as f64 + 0.5) / height as f64) * std::f64::consts::PI;
                let dir = DVec3::new(lat.cos() * lon.sin(), -lat.sin(), lat.cos() * lon.cos());
                (dir, DVec2::new(i as f64 + 0.5, j as f64 + 0.5))
            }
        };
        let back = self.project(dir);
        match back {
            Some(p) if (p - target).length() <= INVERSE_TOLERANCE_PX => Ok(dir),
            _ => Err(lens_err(
                self.lead_field(),
                format!(
                    "pixel ({i}, {j}) has no ray that projects back within \
                     {INVERSE_TOLERANCE_PX} px of its centre (got {back:?})"
                ),
            )),
        }
    }

    fn lead_field(&self) -> &'static str {
        match self {
            Lens::OpenCv { dist, .. } => first_nonzero(&["k1", "k2", "p1", "p2", "k3"], dist),
            Lens::OpenCvFisheye { k, .. } => first_nonzero(&["k1", "k2", "k3", "k4"], k),
            Lens::Equirectangular { .. } => "width",
        }
    }

    /// Check the model over a `width` × `height` image: finite positive focal lengths,
    /// finite coefficients, a fisheye polynomial increasing up to the widest angle any
    /// pixel needs, to the image's edges (refused naming the angle where it stops), every
    /// pixel centre invertible within [`INVERSE_TOLERANCE_PX`], and for `opencv` one
    /// branch of the distortion over the whole pixel rectangle (see
    /// `validate_opencv_branch`).
    pub fn validate(&self, width: u32, height: u32) -> Result<(), LensError> {
        match *self {
            Lens::OpenCv {
                fx,
                fy,
                cx,
                cy,
                dist,
            } => {
                check_intrinsics(fx, fy, cx, cy, width, height)?;
                for (n, v) in ["k1", "k2", "p1", "p2", "k3"].iter().zip(dist) {
                    if !v.is_finite() {
                        return Err(lens_err(n, format!("must be finite, got {v}")));
                    }
                }
            }
            Lens::OpenCvFisheye { fx, fy, cx, cy, k } => {
                check_intrinsics(fx, fy, cx, cy, width, height)?;
                for (n, v) in ["k1", "k2", "k3", "k4"].iter().zip(k) {
                    if !v.is_finite() {
                        return Err(lens_err(n, format!("must be finite, got {v}")));
                    }
                }
                // θ_d must rise over the whole image, to its edges and not only to the
                // outer pixel centres (else a polynomial that turns between them maps two
                // angles into one corner pixel); the widest θ_d is at a corner of the
                // pixel rectangle, half a pixel beyond the corner centres.
                let (right, bottom) = (width as f64 - 0.5, height as f64 - 0.5);
                let mut need = 0.0f64;
                for (x, y) in [(-0.5, -0.5), (right, -0.5), (-0.5, bottom), (right, bottom)] {
                    need = need.max(DVec2::new((x - cx) / fx, (y - cy) / fy).length());
                }
                // Walk θ up in fine steps until θ_d reaches `need`; the derivative must stay
                // positive on the way, and θ (the angle from the axis) stays below 180°.
                let steps = 100_000;
                let top = std::f64::consts::PI;
                for s in 1..=steps {
                    let t = top * s as f64 / steps as f64;
                    let (td, dtd) = theta_d(&k, t);
                    if !positive(dtd) {
                        return Err(lens_err(
                            first_nonzero(&["k1", "k2", "k3", "k4"], &k),
                            format!(
                                "the fisheye polynomial with k = {k:?} stops increasing at \
                                 θ = {:.3}° (θ_d = {td:.6}), short of the θ_d = {need:.6} \
                                 the image corners need",
                                t.to_degrees()
                            ),
                        ));
                    }
                    if td >= need {
                        break;
                    }
                    if s == steps {
                        return Err(lens_err(
                            "fx",
                            format!(
                                "the image corners need θ_d = {need:.6}, more than the \
                                 θ_d = {:.6} of a ray straight back (180°)",
                                theta_d(&k, top).0
                            ),
                        ));
                    }
                }
            }
            Lens::Equirectangular { .. } => {}
        }
        if let Lens::OpenCv {
            fx,
            fy,
            cx,
            cy,
            dist,
        } = *self
        {
            return self.validate_opencv_branch([fx, fy, cx, cy], &dist, width, height);
        }
        for j in 0..height {
            for i in 0..width {
                self.unproject(i, j)?;
            }
        }
        Ok(())
    }

    /// Every pixel's ray (from [`Lens::unproject`]) on one branch of the distortion over
    /// the whole pixel rectangle: the roots at the pixel corners (edges included) are
    /// followed along each row of corners, and down the left edge from the axis, with the
    /// Jacobian positive throughout; each centre's root must then be the continuation of
    /// its top-left corner's. A fold anywhere in the image, between pixel centres too,
    /// stops the lattice or splits the two paths, and is refused naming the pixel.
    fn validate_opencv_branch(
        &self,
        [fx, fy, cx, cy]: [f64; 4],
        d: &[f64; 5],
        width: u32,
        height: u32,
    ) -> Result<(), LensError> {
        let norm = |x: f64, y: f64| DVec2::new((x - cx) / fx, (y - cy) / fy);
        let corner = |i: u32, j: u32| norm(i as f64 - 0.5, j as f64 - 0.5);
        // Corner (i, j) is pixel (i, j)'s top-left; the last row and column name the
        // last pixel.
        let fold = |i: u32, j: u32| fold_error(d, i.min(width - 1), j.min(height - 1));
        let mut left =
            follow(d, DVec2::ZERO, DVec2::ZERO, corner(0, 0), 1.0).ok_or_else(|| fold(0, 0))?;
        let mut row = Vec::with_capacity(width as usize + 1);
        for j in 0..=height {
            if j > 0 {
                left = follow(d, corner(0, j - 1), left, corner(0, j), 1.0)
                    .ok_or_else(|| fold(0, j))?;
            }
            row.clear();
            row.push(left);
            for i in 1..=width {
                let prev = row[row.len() - 1];
                let next = follow(d, corner(i - 1, j), prev, corner(i, j), 1.0)
                    .ok_or_else(|| fold(i, j))?;
                row.push(next);
            }
            if j == height {
                break;
            }
            for (i, &ab_corner) in (0..width).zip(&row) {
                let v = self.unproject(i, j)?;
                let ab = DVec2::new(v.x / v.z, v.y / v.z);
                let goal = norm(i as f64, j as f64);
                // Cheap first: the centre's root within [`PREDICTOR_GAP`] of the tangent
                // step from the corner is on the corner's branch; else the branch is
                // followed there, and must arrive at the same root.
                let pred = ab_corner + newton_step(d, ab_corner, goal).0;
                if (ab - pred).length() <= PREDICTOR_GAP * (ab - ab_corner).length() {
                    continue;
                }
                let same = follow(d, corner(i, j), ab_corner, goal, 1.0)
                    .and_then(|c| polish(d, goal, c))
                    .is_some_and(|c| (c - ab).length() <= 1e-9 * (1.0 + ab.length()));
                if !same {
                    return Err(fold(i, j));
                }
            }
        }
        Ok(())
    }
}

/// A distortion that folds over at pixel `(i, j)`, named by its first non-zero coefficient.
fn fold_error(dist: &[f64; 5], i: u32, j: u32) -> LensError {
    lens_err(
        first_nonzero(&["k1", "k2", "p1", "p2", "k3"], dist),
        format!(
            "the distortion (k1, k2, p1, p2, k3) = {dist:?} folds over at pixel ({i}, {j}): \
             no single ray projects there"
        ),
    )
}

/// Focal lengths finite, positive and at most `f32::MAX` pixels (as a perspective
/// camera's: beyond, every pixel's ray is the axis to f64 precision), a finite principal
/// point, and the image corners a finite number of focal lengths from it (their squared
/// normalised radius finite: else the distortion's polynomial overflows, and the fault is
/// the focal length when it is under a pixel, else the principal point).
fn check_intrinsics(
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    width: u32,
    height: u32,
) -> Result<(), LensError> {
    for (n, v) in [("fx", fx), ("fy", fy)] {
        if !(v.is_finite() && v > 0.0 && v <= f64::from(f32::MAX)) {
            return Err(lens_err(
                n,
                format!(
                    "must be finite, > 0 and <= {:e} pixels, got {}",
                    f32::MAX,
                    crate::scene::num(v)
                ),
            ));
        }
    }
    for (n, v) in [("cx", cx), ("cy", cy)] {
        if !v.is_finite() {
            return Err(lens_err(n, format!("must be finite, got {v}")));
        }
    }
    for (f, c, side, names) in [
        (fx, cx, width, ("fx", "cx")),
        (fy, cy, height, ("fy", "cy")),
    ] {
        let reach = (c.abs() + f64::from(side)) / f;
        if !(reach * reach).is_finite() {
            let field = if f < 1.0 { names.0 } else { names.1 };
            return Err(lens_err(
                field,
                format!(
                    "the image edge lies {reach:e} focal lengths from the principal point \
                     ({} = {}, {} = {}): too far for any ray",
                    names.0,
                    crate::scene::num(f),
                    names.1,
                    crate::scene::num(c)
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The root for `goal` followed from the axis in 2000 fixed steps of a few Newton
    /// iterations each, with the smallest Jacobian determinant met on the way: an
    /// independent, slow reference for the principal branch.
    /// Pixel `(i, j)`'s ray of the `opencv` lens `lens` in normalised coordinates, and the
    /// reference's root for it with its smallest Jacobian determinant ([`reference_root`]).
    fn ray_and_reference(lens: &Lens, i: u32, j: u32) -> (DVec2, DVec2, f64) {
        let Lens::OpenCv {
            fx,
            fy,
            cx,
            cy,
            dist,
        } = *lens
        else {
            panic!("not an opencv lens: {lens:?}")
        };
        let v = lens.unproject(i, j).unwrap();
        let goal = DVec2::new((i as f64 - cx) / fx, (j as f64 - cy) / fy);
        let (want, min_det) = reference_root(&dist, goal);
        (DVec2::new(v.x / v.z, v.y / v.z), want, min_det)
    }

    fn reference_root(d: &[f64; 5], goal: DVec2) -> (DVec2, f64) {
        let (mut ab, mut min_det) = (DVec2::ZERO, f64::INFINITY);
        for s in 1..=2000 {
            let sub = goal * (s as f64 / 2000.0);
            for _ in 0..6 {
                let (p, jac) = distort(d, ab.x, ab.y);
                let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
                min_det = min_det.min(det);
                let r = p - sub;
                ab -= DVec2::new(
                    (jac[1][1] * r.x - jac[0][1] * r.y) / det,
                    (jac[0][0] * r.y - jac[1][0] * r.x) / det,
                );
            }
        }
        (ab, min_det)
    }

    /// A reviewer's lens (24×18 at scale 1) whose distortion folds between pixel centres:
    /// every centre has a root, yet neighbouring pixels (6, 17) and (7, 17) looked ~20°
    /// apart. It is refused at both samplings, as a fold.
    #[test]
    fn opencv_fold_between_pixel_centres_is_refused() {
        for s in [1.0, 2.0] {
            let lens = Lens::OpenCv {
                fx: 22.606775448273737 * s,
                fy: 26.249912971221985 * s,
                cx: (13.656421663833438 + 0.5) * s - 0.5,
                cy: (14.683551294149199 + 0.5) * s - 0.5,
                dist: [
                    -0.8505992338339688,
                    0.5070054425949125,
                    -0.19398769097788116,
                    0.04105087632472034,
                    0.2325159377246211,
                ],
            };
            let e = lens
                .validate(24 * s as u32, 18 * s as u32)
                .expect_err("a fold inside the image");
            assert_eq!(e.field, "k1");
            assert!(e.message.contains("folds over at pixel"), "{}", e.message);
        }
    }

    /// A reviewer's valid lens that was refused as folding at pixel (1, 1): Newton from
    /// the undistorted point reached an outer root. Every pixel's ray now projects back
    /// onto its centre and is the root followed out from the axis.
    #[test]
    fn opencv_valid_lens_with_outer_roots_is_accepted_on_the_axis_branch() {
        let dist = [
            -0.2168036633789909,
            0.40917281535053873,
            0.05463057654642988,
            0.0976527097352643,
            -0.07105824679739868,
        ];
        let (fx, fy, cx, cy) = (
            7.586646205757268,
            6.1537287402903,
            14.987003488722378,
            5.083257675593132,
        );
        let lens = Lens::OpenCv {
            fx,
            fy,
            cx,
            cy,
            dist,
        };
        lens.validate(24, 18).unwrap();
        for j in 0..18 {
            for i in 0..24 {
                let back = lens.project(lens.unproject(i, j).unwrap()).unwrap();
                assert!((back - DVec2::new(i as f64, j as f64)).length() < 1e-9);
                let (got, want, min_det) = ray_and_reference(&lens, i, j);
                assert!(min_det > 0.0);
                assert!((got - want).length() < 1e-9, "({i}, {j}): {got} vs {want}");
            }
        }
    }

    /// Random strong lenses on small images: whatever `validate` accepts has every
    /// pixel's ray on the branch reached from the axis with a positive Jacobian.
    #[test]
    fn accepted_random_lenses_are_on_the_axis_branch() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut uniform = |lo: f64, hi: f64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            lo + (hi - lo) * (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut accepted = 0;
        for _ in 0..300 {
            let dist = [
                uniform(-1.0, 1.0),
                uniform(-0.6, 0.6),
                uniform(-0.2, 0.2),
                uniform(-0.2, 0.2),
                uniform(-0.3, 0.3),
            ];
            let (fx, fy) = (uniform(5.0, 30.0), uniform(5.0, 30.0));
            let (cx, cy) = (uniform(0.0, 23.0), uniform(0.0, 17.0));
            let lens = Lens::OpenCv {
                fx,
                fy,
                cx,
                cy,
                dist,
            };
            if lens.validate(24, 18).is_err() {
                continue;
            }
            accepted += 1;
            for j in 0..18 {
                for i in 0..24 {
                    let (got, want, min_det) = ray_and_reference(&lens, i, j);
                    assert!(min_det > 0.0, "{lens:?} ({i}, {j})");
                    assert!((got - want).length() < 1e-8, "{lens:?} ({i}, {j})");
                }
            }
        }
        assert!(accepted > 30, "{accepted}");
    }

    /// θ_d = θ (1 - 0.3 θ²) peaks at 0.685 (θ = 52.3°): the 2×2 image's corner centres
    /// need θ_d = 0.6, its corners (half a pixel out) 1.2, so it is refused.
    #[test]
    fn fisheye_must_rise_to_the_image_edges() {
        let f = 0.5f64.sqrt() / 0.6;
        let lens = Lens::OpenCvFisheye {
            fx: f,
            fy: f,
            cx: 0.5,
            cy: 0.5,
            k: [-0.3, 0.0, 0.0, 0.0],
        };
        for (i, j) in [(0, 0), (1, 1)] {
            lens.unproject(i, j).unwrap();
        }
        let e = lens.validate(2, 2).unwrap_err();
        assert!(
            e.message.contains("stops increasing at θ = 52.304°"),
            "{}",
            e.message
        );
    }

    #[test]
    fn bernstein_certificate_matches_the_slope() {
        // 1 - 3u + ... : slope 1 + 3 k1 u with k1 = -0.1 vanishes at u = 10/3.
        let k = [-0.1, 0.0, 0.0, 0.0];
        assert!(fisheye_rising(&k, 3.3));
        assert!(!fisheye_rising(&k, 3.4));
        // A dip that touches below zero inside the interval only.
        let k = [-0.5, 0.1, 0.0, 0.0];
        // g(u) = 1 - 1.5u + 0.5u²: zero at u = 1 and 2, positive beyond.
        assert!(fisheye_rising(&k, 0.99));
        assert!(!fisheye_rising(&k, 3.0));
    }
}
