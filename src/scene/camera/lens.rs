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
//! when projecting it back lands within [`INVERSE_TOLERANCE_PX`] of the centre; where that
//! fails (a fold of the distortion, a non-increasing fisheye polynomial) the model is
//! refused with the field named.

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
        let (p, jac) = distort(d, ab.x, ab.y);
        let r = p - goal;
        let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
        if !positive(det) {
            break;
        }
        let step = DVec2::new(
            (jac[1][1] * r.x - jac[0][1] * r.y) / det,
            (jac[0][0] * r.y - jac[1][0] * r.x) / det,
        );
        ab -= step;
        if step.length() <= 1e-16 * (1.0 + ab.length()) {
            break;
        }
    }
    ab
}

/// Whether the distortion's Jacobian at `ab` has a positive determinant (false for NaN).
fn jacobian_positive(d: &[f64; 5], ab: DVec2) -> bool {
    let (_, jac) = distort(d, ab.x, ab.y);
    positive(jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0])
}

/// Sub-goals a root is followed through from the axis when Newton from the undistorted
/// point lands past the radial fold.
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
                let mut ab = undistort(&dist, goal, goal);
                // Newton from the undistorted point may leap past a fold onto a mirrored
                // sheet, where the Jacobian is positive again (the radial factor and its
                // slope both negative) and the root projects back exactly: a ray pointing
                // the other way. Such a root lies past the radial fold; then the root is
                // followed out from the axis instead, the goal moved there in small steps.
                if !radial_rising(&dist, ab.length_squared()) {
                    ab = DVec2::ZERO;
                    for s in 1..=CONTINUATION_STEPS {
                        let sub = goal * (s as f64 / CONTINUATION_STEPS as f64);
                        ab = undistort(&dist, sub, ab);
                        if !(jacobian_positive(&dist, ab) && ab.is_finite()) {
                            break;
                        }
                    }
                }
                if !jacobian_positive(&dist, ab) || !ab.is_finite() {
                    let field = first_nonzero(&["k1", "k2", "p1", "p2", "k3"], &dist);
                    return Err(lens_err(
                        field,
                        format!(
                            "the distortion (k1, k2, p1, p2, k3) = {dist:?} folds over at pixel \
                             ({i}, {j}): no single ray projects there"
                        ),
                    ));
                }
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
                    if !(t > 0.0 && t.is_finite() && theta_d(&k, t).1 > 0.0) {
                        return Err(lens_err(
                            first_nonzero(&["k1", "k2", "k3", "k4"], &k),
                            format!(
                                "the fisheye polynomial with k = {k:?} does not reach \
                                 θ_d = {want} (pixel ({i}, {j})) while increasing"
                            ),
                        ));
                    }
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
    /// pixel needs (refused naming the angle where it stops), and every pixel centre
    /// invertible within [`INVERSE_TOLERANCE_PX`].
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
                // The widest θ_d any pixel centre asks for is at a corner.
                let mut need = 0.0f64;
                for (x, y) in [
                    (0.0, 0.0),
                    ((width - 1) as f64, 0.0),
                    (0.0, (height - 1) as f64),
                    ((width - 1) as f64, (height - 1) as f64),
                ] {
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
        for j in 0..height {
            for i in 0..width {
                self.unproject(i, j)?;
            }
        }
        Ok(())
    }
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
