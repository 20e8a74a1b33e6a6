//! A ray–finite-cylinder oracle in double-double arithmetic (~104 significant bits), and the
//! condition number κ of its answer. Used only by `stress` and the tests: it is ~50× slower
//! than the kernels.
//!
//! **Why a hand-written double-double and not a crate.** The oracle needs `+ − × ÷ √` and
//! comparisons at ≥ 100 bits, and `stress` calls it ~100 times per ray (κ and the tangency band
//! are finite differences of the oracle). A double-double (`hi + lo`, Dekker/Knuth two-sum and
//! an FMA two-product) gives 2·53 = 106 bits in ~100 lines with no dependency and is fast
//! enough that `cylaov stress` makes ~1e6 oracle calls in under a second. `rug`/MPFR would pull a C build (GMP) onto the shared 2-core builders
//! for precision we do not need; the pure-Rust big-float crates are heavier and slower; the
//! existing double-double crates add little over the algorithms below (they are the QD
//! library's `dd_real`, Hida–Li–Bailey 2000) and we want their error behaviour in view.
//! The unit tests check the arithmetic (√2² = 2, (1/3)·3 = 1, … to < 1e-30) and the oracle
//! against exact answers, including a ray 1.8e-12 relative from tangency.
//!
//! The geometry is that of [`crate::geometry::cylinder`]'s module doc, solved with the cancellation-free forms (Lagrange
//! discriminant, citardauq roots, `C = (ρ − r)(ρ + r)`) but organised differently from the
//! `Stable` kernel on purpose: every candidate (two side roots that lie between the cap
//! planes, two cap-disk hits) is tested on its own and the nearest in `[tmin, tmax]` wins, so
//! a shared mistake in the slab/interval logic cannot hide.

use crate::geometry::{Cylinder, Surface};
use glam::DVec3;
use std::ops::{Add, Div, Mul, Neg, Sub};

// ---- double-double arithmetic -----------------------------------------------------------

/// An unevaluated sum `hi + lo` with `|lo| ≤ ulp(hi)/2`: ~106 significant bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, PartialOrd)]
pub struct DD {
    /// The leading f64 (the sum rounded to nearest).
    pub hi: f64,
    /// The rounding error of `hi`.
    pub lo: f64,
}

/// `a + b = s + e` exactly (Knuth).
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// `a + b = s + e` exactly, given `|a| ≥ |b|` (Dekker).
#[inline]
fn quick_two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    (s, b - (s - a))
}

/// `a · b = p + e` exactly, via one fused multiply-add.
#[inline]
fn two_prod(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    (p, a.mul_add(b, -p))
}

impl DD {
    /// Zero.
    pub const ZERO: DD = DD { hi: 0.0, lo: 0.0 };
    /// One.
    pub const ONE: DD = DD { hi: 1.0, lo: 0.0 };

    /// An f64 value, exactly.
    pub fn new(x: f64) -> DD {
        DD { hi: x, lo: 0.0 }
    }

    /// Nearest f64.
    pub fn to_f64(self) -> f64 {
        self.hi + self.lo
    }

    /// Absolute value.
    pub fn abs(self) -> DD {
        if self.hi < 0.0 { -self } else { self }
    }

    /// +1 or -1, never 0 (as the stable root formula needs).
    pub fn sign(self) -> DD {
        DD::new(1f64.copysign(self.hi))
    }

    /// Whether the value is exactly zero.
    pub fn is_zero(self) -> bool {
        self.hi == 0.0
    }

    /// Square root (QD's Karp–Markstein step: one Newton correction of the f64 root).
    pub fn sqrt(self) -> DD {
        if self.hi <= 0.0 {
            return if self.hi == 0.0 {
                DD::ZERO
            } else {
                DD::new(f64::NAN)
            };
        }
        let x = 1.0 / self.hi.sqrt();
        let ax = self.hi * x;
        let (p, e) = two_prod(ax, ax);
        let resid = (self - DD { hi: p, lo: e }).hi;
        let (s, l) = two_sum(ax, resid * (x * 0.5));
        let (s, l) = quick_two_sum(s, l);
        DD { hi: s, lo: l }
    }
}

impl From<f64> for DD {
    fn from(x: f64) -> DD {
        DD::new(x)
    }
}

impl Add for DD {
    type Output = DD;
    /// QD's IEEE-style addition (error ≤ 2·2⁻¹⁰⁶ relative, even under cancellation).
    #[inline]
    fn add(self, b: DD) -> DD {
        let (s1, s2) = two_sum(self.hi, b.hi);
        let (t1, t2) = two_sum(self.lo, b.lo);
        let (s1, s2) = quick_two_sum(s1, s2 + t1);
        let (hi, lo) = quick_two_sum(s1, s2 + t2);
        DD { hi, lo }
    }
}

impl Neg for DD {
    type Output = DD;
    #[inline]
    fn neg(self) -> DD {
        DD {
            hi: -self.hi,
            lo: -self.lo,
        }
    }
}

impl Sub for DD {
    type Output = DD;
    #[inline]
    fn sub(self, b: DD) -> DD {
        self + (-b)
    }
}

impl Mul for DD {
    type Output = DD;
    #[inline]
    fn mul(self, b: DD) -> DD {
        let (p1, p2) = two_prod(self.hi, b.hi);
        let p2 = p2 + (self.hi * b.lo + self.lo * b.hi);
        let (hi, lo) = quick_two_sum(p1, p2);
        DD { hi, lo }
    }
}

impl Div for DD {
    type Output = DD;
    /// Long division with three f64 quotient digits (QD's accurate division).
    #[inline]
    fn div(self, b: DD) -> DD {
        let q1 = self.hi / b.hi;
        let r = self - b * DD::new(q1);
        let q2 = r.hi / b.hi;
        let r = r - b * DD::new(q2);
        let q3 = r.hi / b.hi;
        let (q1, q2) = quick_two_sum(q1, q2);
        DD { hi: q1, lo: q2 } + DD::new(q3)
    }
}

/// A 3-vector of double-doubles.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DV3 {
    /// x component.
    pub x: DD,
    /// y component.
    pub y: DD,
    /// z component.
    pub z: DD,
}

impl DV3 {
    /// A vector from its components.
    pub fn new(x: DD, y: DD, z: DD) -> DV3 {
        DV3 { x, y, z }
    }

    /// An f64 vector, exactly.
    pub fn from_f64(v: DVec3) -> DV3 {
        DV3::new(v.x.into(), v.y.into(), v.z.into())
    }

    /// `a - b` exactly (each component is a two-sum of two f64).
    pub fn diff(a: DVec3, b: DVec3) -> DV3 {
        let c = |x: f64, y: f64| {
            let (s, e) = two_sum(x, -y);
            DD { hi: s, lo: e }
        };
        DV3::new(c(a.x, b.x), c(a.y, b.y), c(a.z, b.z))
    }

    /// Round each component to the nearest f64.
    pub fn to_f64(self) -> DVec3 {
        DVec3::new(self.x.to_f64(), self.y.to_f64(), self.z.to_f64())
    }

    /// Dot product.
    pub fn dot(self, b: DV3) -> DD {
        self.x * b.x + self.y * b.y + self.z * b.z
    }

    /// Cross product.
    pub fn cross(self, b: DV3) -> DV3 {
        DV3::new(
            self.y * b.z - self.z * b.y,
            self.z * b.x - self.x * b.z,
            self.x * b.y - self.y * b.x,
        )
    }

    /// Euclidean length.
    pub fn length(self) -> DD {
        self.dot(self).sqrt()
    }

    /// Scaled by `s`.
    pub fn scale(self, s: DD) -> DV3 {
        DV3::new(self.x * s, self.y * s, self.z * s)
    }

    /// Unit vector along `self`.
    pub fn normalize(self) -> DV3 {
        self.scale(DD::ONE / self.length())
    }

    fn get(self, k: usize) -> DD {
        [self.x, self.y, self.z][k]
    }

    fn with(self, k: usize, v: DD) -> DV3 {
        let mut a = [self.x, self.y, self.z];
        a[k] = v;
        DV3::new(a[0], a[1], a[2])
    }
}

impl Add for DV3 {
    type Output = DV3;
    fn add(self, b: DV3) -> DV3 {
        DV3::new(self.x + b.x, self.y + b.y, self.z + b.z)
    }
}

impl Sub for DV3 {
    type Output = DV3;
    fn sub(self, b: DV3) -> DV3 {
        DV3::new(self.x - b.x, self.y - b.y, self.z - b.z)
    }
}

// ---- the oracle -------------------------------------------------------------------------

/// Everything the answer depends on, in double-double: the ray from the cylinder's base
/// (`oc = o - c`, exact), its direction `d` (any length: `t` is the ray parameter), the axis
/// (normalised inside, so a non-unit axis is its direction), radius and height.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Problem {
    /// Ray origin minus the cylinder's base centre.
    pub oc: DV3,
    /// Ray direction.
    pub d: DV3,
    /// Axis direction from base to top.
    pub axis: DV3,
    /// Radius.
    pub r: DD,
    /// Height.
    pub h: DD,
    /// Closed (two cap disks) or an open tube.
    pub caps: bool,
}

impl Problem {
    /// The ray `origin + t·dir` against a validated cylinder. `oc` is formed exactly; the
    /// f64 axis (unit to within rounding) is renormalised in double-double.
    pub fn new(cyl: &Cylinder, origin: DVec3, dir: DVec3) -> Problem {
        Problem {
            oc: DV3::diff(origin, cyl.base),
            d: DV3::from_f64(dir),
            axis: DV3::from_f64(cyl.axis),
            r: cyl.radius.into(),
            h: cyl.height.into(),
            caps: cyl.caps,
        }
    }

    /// The ray against the cylinder as a user wrote it, from `p0` to `p1` (exact axis and
    /// height, before the f64 normalisation that scene validation does).
    pub fn from_endpoints(
        p0: DVec3,
        p1: DVec3,
        radius: f64,
        caps: bool,
        origin: DVec3,
        dir: DVec3,
    ) -> Problem {
        let axis = DV3::diff(p1, p0);
        Problem {
            oc: DV3::diff(origin, p0),
            d: DV3::from_f64(dir),
            axis,
            r: radius.into(),
            h: axis.length(),
            caps,
        }
    }
}

/// The oracle's nearest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter (a distance when `|d| = 1`).
    pub t: DD,
    /// Which part of the cylinder was hit.
    pub surface: Surface,
    /// Unit outward normal.
    pub normal: DV3,
}

/// Per-problem quantities shared by the hit and the normal.
struct AxisParts {
    n: DV3,
    on: DD,
    dn: DD,
    oc_perp: DV3,
    d_perp: DV3,
}

fn axis_parts(p: &Problem) -> AxisParts {
    let n = p.axis.normalize();
    let on = p.oc.dot(n);
    let dn = p.d.dot(n);
    AxisParts {
        n,
        on,
        dn,
        oc_perp: p.oc - n.scale(on),
        d_perp: p.d - n.scale(dn),
    }
}

/// Outward unit normal of `surface` at ray parameter `t` (side: the projection of the hit
/// point off the axis, normalised; caps: ∓axis).
pub fn normal_at(p: &Problem, t: DD, surface: Surface) -> DV3 {
    let f = axis_parts(p);
    normal_in(&f, t, surface)
}

fn normal_in(f: &AxisParts, t: DD, surface: Surface) -> DV3 {
    match surface {
        Surface::Bottom => DV3::default() - f.n,
        Surface::Top => f.n,
        Surface::Side => (f.oc_perp + f.d_perp.scale(t)).normalize(),
    }
}

/// Nearest hit with `tmin ≤ t ≤ tmax`, or `None`. Edge policy: a hit exactly on a cap
/// plane or the rim counts (closed intervals everywhere); at equal `t` the side wins.
pub fn intersect(p: &Problem, tmin: DD, tmax: DD) -> Option<Hit> {
    let f = axis_parts(p);
    let mut best: Option<(DD, Surface)> = None;
    let mut take = |t: DD, s: Surface| {
        if t >= tmin && t <= tmax && best.is_none_or(|(b, _)| t < b) {
            best = Some((t, s));
        }
    };
    // Side: A t² + 2b t + C = 0 with the Lagrange discriminant and citardauq roots.
    let a = f.d_perp.dot(f.d_perp);
    if !a.is_zero() {
        let b = f.d_perp.dot(f.oc_perp);
        let rho = f.oc_perp.length();
        let c = (rho - p.r) * (rho + p.r);
        let x = f.d_perp.cross(f.oc_perp);
        let disc = p.r * p.r * a - x.dot(x);
        if disc >= DD::ZERO {
            let q = -(b + b.sign() * disc.sqrt());
            let roots = if q.is_zero() {
                [DD::ZERO; 2]
            } else {
                [q / a, c / q]
            };
            for t in roots {
                let along = f.on + t * f.dn;
                if along >= DD::ZERO && along <= p.h {
                    take(t, Surface::Side);
                }
            }
        }
    }
    // Caps: the disks in the planes n·x = 0 and n·x = h.
    if p.caps && !f.dn.is_zero() {
        for (k, s) in [(DD::ZERO, Surface::Bottom), (p.h, Surface::Top)] {
            let t = (k - f.on) / f.dn;
            let x = f.oc_perp + f.d_perp.scale(t);
            if x.dot(x) <= p.r * p.r {
                take(t, s);
            }
        }
    }
    best.map(|(t, surface)| Hit {
        t,
        surface,
        normal: normal_in(&f, t, surface),
    })
}

/// Angle between two unit vectors, accurate for tiny angles (`2·asin(|a−b|/2)`).
pub fn angle(a: DVec3, b: DVec3) -> f64 {
    2.0 * ((a - b).length() / 2.0).min(1.0).asin()
}

// ---- condition number and tangency band -------------------------------------------------

/// The oracle's answer with its sensitivity, for kernels of unit roundoff `eps`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Analysis {
    /// The nearest hit, or `None` for a miss.
    pub hit: Option<Hit>,
    /// κ of `t`: the largest `|Δt| / (ε |t|)` over input perturbations of relative size ε
    /// (see [`analyse`]); `inf` when an ε perturbation changes the surface or hit/miss.
    pub kappa_t: f64,
    /// κ of the normal: the largest angle change (radians) per ε of relative perturbation.
    pub kappa_n: f64,
    /// Hit/miss changes when the origin moves by up to `BAND_ULPS·ε·(|oc| + r + h)` or the
    /// direction turns by `BAND_ULPS·ε` (see `in_band`): the ray is within the tangency band
    /// (silhouette or clip boundary), where hit/miss is not determined by the inputs at
    /// this precision.
    pub band_hit: bool,
    /// The same moves change the surface hit (rim seam) or make `t` jump by more than
    /// `JUMP·(r + h)` (another root, e.g. past an open rim to the far wall): the branch of
    /// the answer is not determined by the inputs.
    pub band_branch: bool,
}

impl Analysis {
    /// In either band.
    pub fn band(&self) -> bool {
        self.band_hit || self.band_branch
    }
}

/// A `t` change under a band move larger than this fraction of `r + h` (plus 16 times the
/// move) is a jump to another root, not the steep-but-continuous change of a grazing ray.
pub const JUMP: f64 = 1e-2;

/// Width of the tangency band in units of `ε·(|oc| + r + h)`.
pub const BAND_ULPS: f64 = 8.0;

/// Relative step of the finite-difference gradient (far above the oracle's 1e-31 and far
/// below any ε we measure).
const FD_STEP: f64 = 1e-13;

/// Number of scalar inputs: `oc` (3), `d` (3), axis (3), `r`, `h`.
const NIN: usize = 11;

/// Input `k` perturbed by `delta` (absolute).
fn perturbed(p: &Problem, k: usize, delta: DD) -> Problem {
    let mut q = *p;
    match k {
        0..=2 => q.oc = p.oc.with(k, p.oc.get(k) + delta),
        3..=5 => q.d = p.d.with(k - 3, p.d.get(k - 3) + delta),
        6..=8 => q.axis = p.axis.with(k - 6, p.axis.get(k - 6) + delta),
        9 => q.r = p.r + delta,
        _ => q.h = p.h + delta,
    }
    q
}

/// The scale of each input for a normwise relative perturbation: `|oc|`, `|d|`, `|axis|`,
/// `r`, `h` (a vector moves by δ times its length in any direction).
fn scales(p: &Problem) -> [f64; NIN] {
    let (o, d, a) = (
        p.oc.length().to_f64(),
        p.d.length().to_f64(),
        p.axis.length().to_f64(),
    );
    [o, o, o, d, d, d, a, a, a, p.r.to_f64(), p.h.to_f64()]
}

/// The oracle's answer, κ of `t` and of the normal, and whether the ray is in the tangency
/// band, for a kernel of unit roundoff `eps`.
///
/// κ is the condition number of the exact answer: the largest relative change of `t` (or of
/// the normal angle) when the inputs are perturbed by `ε` relative, in a normwise model: `oc` may move by
/// `ε|oc|`, `d` by `ε|d|`, the axis by `ε` (a tilt), `r` by `εr`, `h` by `εh`. We take the
/// larger of (a) the linearised worst case, from a finite-difference gradient (11 oracle
/// calls; for a vector input the worst perturbation is along its gradient block), and (b)
/// the secant: the oracle re-run at ±ε along that worst direction, which catches the
/// non-linear (square-root) behaviour near tangency. If the secant changes the surface or
/// hit/miss, κ is `inf`.
pub fn analyse(p: &Problem, tmin: f64, tmax: f64, eps: f64) -> Analysis {
    let (lo, hi) = (DD::new(tmin), DD::new(tmax));
    let hit = intersect(p, lo, hi);
    let (band_hit, band_branch) = in_band(p, hit, lo, hi, eps);
    let Some(h0) = hit else {
        return Analysis {
            hit,
            kappa_t: 0.0,
            kappa_n: 0.0,
            band_hit,
            band_branch,
        };
    };
    let sc = scales(p);
    let t0 = h0.t;
    let tabs = t0.to_f64().abs().max(f64::MIN_POSITIVE);
    let n0 = h0.normal.to_f64();
    // Gradient of t and Jacobian of the normal, per unit of relative perturbation.
    let mut gt = [0.0; NIN];
    let mut jn = [DVec3::ZERO; NIN];
    let mut jump = false;
    for k in 0..NIN {
        if sc[k] == 0.0 {
            continue;
        }
        let step = FD_STEP * sc[k];
        match intersect(&perturbed(p, k, DD::new(step)), lo, hi) {
            Some(h1) if h1.surface == h0.surface => {
                gt[k] = (h1.t - t0).to_f64() / FD_STEP;
                jn[k] = (h1.normal - h0.normal).to_f64() / FD_STEP;
            }
            _ => jump = true,
        }
    }
    if jump {
        return Analysis {
            hit,
            kappa_t: f64::INFINITY,
            kappa_n: f64::INFINITY,
            band_hit,
            band_branch,
        };
    }
    // Linearised worst case: blockwise Euclidean norms (Frobenius for the normal).
    let blocks = [0..3, 3..6, 6..9, 9..10, 10..11];
    let mut lin_t = 0.0;
    let mut lin_n = 0.0;
    for b in blocks.clone() {
        lin_t += b.clone().map(|k| gt[k] * gt[k]).sum::<f64>().sqrt();
        lin_n += b.map(|k| jn[k].length_squared()).sum::<f64>().sqrt();
    }
    let mut kappa_t = lin_t / tabs;
    let mut kappa_n = lin_n;
    // Secant at ±ε along the worst direction for t.
    for sgn in [1.0, -1.0] {
        let mut q = *p;
        for b in blocks.clone() {
            let norm = b.clone().map(|k| gt[k] * gt[k]).sum::<f64>().sqrt();
            if norm == 0.0 {
                continue;
            }
            for k in b {
                let delta = sgn * eps * sc[k] * gt[k] / norm;
                q = perturbed(&q, k, DD::new(delta));
            }
        }
        match intersect(&q, lo, hi) {
            Some(h1) if h1.surface == h0.surface => {
                kappa_t = kappa_t.max((h1.t - t0).to_f64().abs() / (eps * tabs));
                kappa_n = kappa_n.max(angle(h1.normal.to_f64(), n0) / eps);
            }
            _ => {
                kappa_t = f64::INFINITY;
                kappa_n = f64::INFINITY;
            }
        }
    }
    Analysis {
        hit,
        kappa_t,
        kappa_n,
        band_hit,
        band_branch,
    }
}

/// Whether a move of the ray within the band changes hit/miss, and whether it changes the
/// branch (surface, or a jump of `t`). Returns `(band_hit, band_branch)`.
///
/// The moves: the origin by `w·f` (`w = BAND_ULPS·ε·(|oc| + r + h)`, `f` in 1, 1/4, 1/16,
/// 1/64 so a thin miss is not jumped over) along ±d and in 8 directions perpendicular to
/// `d`, and the direction turned by `BAND_ULPS·ε` radians in 4 directions (a long ray's
/// hit/miss can hinge on the sign of a tiny angle, which no origin move reproduces).
fn in_band(p: &Problem, hit: Option<Hit>, lo: DD, hi: DD, eps: f64) -> (bool, bool) {
    let w = BAND_ULPS * eps * (p.oc.length() + p.r + p.h).to_f64();
    // A sideways move of w changes t by w/cos(incidence): continuous, not a jump.
    let jump = JUMP * (p.r + p.h).to_f64() + 16.0 * w;
    let dlen = p.d.length().to_f64();
    let d = p.d.to_f64() / dlen;
    let sideways = sideways(d);
    // (problem, shift of t the move itself causes: a move along d by s shifts t by -s/|d|)
    let mut moved: Vec<(Problem, f64)> = Vec::with_capacity(44);
    for f in [1.0, 0.25, 0.0625, 0.015625] {
        for dir in &sideways {
            let mut q = *p;
            q.oc = p.oc + DV3::from_f64(*dir * (w * f));
            moved.push((q, 0.0));
        }
        for sgn in [1.0, -1.0] {
            let mut q = *p;
            q.oc = p.oc + DV3::from_f64(d * (sgn * w * f));
            moved.push((q, -sgn * w * f / dlen));
        }
    }
    for dir in &sideways[..4] {
        let mut q = *p;
        q.d = p.d + DV3::from_f64(*dir * (BAND_ULPS * eps * dlen));
        moved.push((q, 0.0));
    }
    let (mut band_hit, mut band_branch) = (false, false);
    for (q, shift) in &moved {
        match (intersect(q, lo, hi), hit) {
            (Some(a), Some(b)) => {
                let dt = (a.t - b.t - DD::new(*shift)).abs().to_f64();
                band_branch |= a.surface != b.surface || dt > jump;
            }
            (None, None) => {}
            _ => band_hit = true,
        }
    }
    (band_hit, band_branch)
}

/// Eight unit directions perpendicular to the unit vector `d`, 45° apart: the four axes of
/// an orthonormal frame first, then the four diagonals. Probing a ray moved sideways along
/// each finds a boundary in any direction (the first four are the axes alone).
pub fn sideways(d: DVec3) -> [DVec3; 8] {
    let e1 = d.any_orthonormal_vector();
    let e2 = d.cross(e1);
    let s = std::f64::consts::FRAC_1_SQRT_2;
    [
        e1,
        -e1,
        e2,
        -e2,
        (e1 + e2) * s,
        (e1 - e2) * s,
        (-e1 + e2) * s,
        (-e1 - e2) * s,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: DD, b: DD, tol: f64) -> bool {
        (a - b).abs().to_f64() <= tol * b.abs().to_f64().max(1e-300)
    }

    #[test]
    fn dd_arithmetic_has_over_100_bits() {
        let two = DD::new(2.0);
        let s = two.sqrt();
        let back = s * s;
        assert!(close(back, two, 1e-31), "sqrt(2)^2 = {back:?}");
        let third = DD::ONE / DD::new(3.0);
        assert!(close(third * DD::new(3.0), DD::ONE, 1e-31), "{third:?}");
        // 1/3 to 32 digits: the low part must carry the digits f64 drops.
        let err = (third - DD::new(1.0 / 3.0)).to_f64();
        assert!((err - 1.850371707708594e-17).abs() < 1e-30, "{err:e}");
        // Cancellation: (1 + 2^-80) - 1 = 2^-80 exactly.
        let tiny = (DD::ONE + DD::new(2f64.powi(-80))) - DD::ONE;
        assert_eq!(tiny.to_f64(), 2f64.powi(-80));
        // Division residual.
        let (a, b) = (DD::new(std::f64::consts::PI), DD::new(std::f64::consts::E));
        let q = a / b;
        assert!(close(q * b, a, 2e-31), "{q:?}");
    }

    fn z_cylinder(r: f64, h: f64, caps: bool) -> Cylinder {
        Cylinder {
            base: DVec3::ZERO,
            axis: DVec3::Z,
            height: h,
            radius: r,
            caps,
            id: 1,
            label: 0,
        }
    }

    #[test]
    fn camera_on_x_axis_hits_at_x_minus_r() {
        for &(x, r) in &[(5.0, 1.0), (1e6, 0.25), (3.0, 2.5)] {
            let cyl = z_cylinder(r, 2.0, true);
            let p = Problem::new(&cyl, DVec3::new(x, 0.0, 1.0), DVec3::NEG_X);
            let h = intersect(&p, DD::ZERO, DD::new(f64::INFINITY)).expect("hit");
            assert_eq!(h.t, DD::new(x - r), "x={x} r={r}");
            assert_eq!(h.surface, Surface::Side);
            assert_eq!(h.normal.to_f64(), DVec3::X, "x={x} r={r}");
        }
    }

    #[test]
    fn cap_hit_down_the_axis() {
        let cyl = z_cylinder(0.5, 2.0, true);
        let p = Problem::new(&cyl, DVec3::new(0.1, 0.0, 10.0), DVec3::NEG_Z);
        let h = intersect(&p, DD::ZERO, DD::new(1e300)).expect("hit");
        assert_eq!((h.t, h.surface), (DD::new(8.0), Surface::Top));
        assert_eq!(h.normal.to_f64(), DVec3::Z);
        // Open tube: the same ray passes through to nothing (it is inside the tube, parallel).
        let open = Problem::new(&z_cylinder(0.5, 2.0, false), p.oc.to_f64(), DVec3::NEG_Z);
        assert!(intersect(&open, DD::ZERO, DD::new(1e300)).is_none());
        // From inside a closed cylinder the exit through the bottom cap.
        let inside = Problem::new(&cyl, DVec3::new(0.0, 0.2, 1.5), DVec3::NEG_Z);
        let h = intersect(&inside, DD::ZERO, DD::new(1e300)).expect("hit");
        assert_eq!((h.t, h.surface), (DD::new(1.5), Surface::Bottom));
    }

    /// Pythagorean triple (m²+1, m²−1, 2m) with m = 2²⁰: a ray at distance p = m²−1 from the
    /// axis of a cylinder of radius r = m²+1 (relative gap 1.8e-12) has half-chord s = 2m,
    /// all exact integers, so t = L − s exactly.
    #[test]
    fn near_grazing_ray_matches_exact_triple() {
        let m = 2f64.powi(20);
        let (r, p, s) = (m * m + 1.0, m * m - 1.0, 2.0 * m);
        let l = 3.0 * r;
        let cyl = z_cylinder(r, 10.0, false);
        let prob = Problem::new(&cyl, DVec3::new(p, -l, 5.0), DVec3::Y);
        let h = intersect(&prob, DD::ZERO, DD::new(1e300)).expect("hit");
        assert_eq!(h.t, DD::new(l - s), "t = {:?}", h.t);
        let want = DV3::new(DD::new(p) / DD::new(r), DD::new(-s) / DD::new(r), DD::ZERO);
        let err = (h.normal - want).length().to_f64();
        assert!(err < 1e-30, "normal error {err:e}");
        // A ray just outside (p = r + 2^-12) misses.
        let miss = Problem::new(&cyl, DVec3::new(r + 2f64.powi(-12), -l, 5.0), DVec3::Y);
        assert!(intersect(&miss, DD::ZERO, DD::new(1e300)).is_none());
    }

    #[test]
    fn kappa_is_small_when_well_conditioned_and_large_near_tangency() {
        let cyl = z_cylinder(1.0, 2.0, true);
        let eps = f64::EPSILON / 2.0;
        let head_on = Problem::new(&cyl, DVec3::new(5.0, 0.0, 1.0), DVec3::NEG_X);
        let a = analyse(&head_on, 0.0, f64::INFINITY, eps);
        assert!(!a.band());
        // t = x - r = 4: |oc| = √26 moves t by ≤ 5.1ε, |d| by 4ε (t scales with 1/|d|), the
        // axis tilt by 1ε (hit at height 1), r by 1ε: κ ≈ 11.1/4 = 2.8.
        assert!((a.kappa_t - 2.77).abs() < 0.05, "{a:?}");
        let graze = Problem::new(&cyl, DVec3::new(1.0 - 1e-10, -5.0, 1.0), DVec3::Y);
        let g = analyse(&graze, 0.0, f64::INFINITY, eps);
        assert!(g.kappa_t > 1e3 && g.kappa_t.is_finite(), "{g:?}");
        let tangent = Problem::new(&cyl, DVec3::new(1.0 - 1e-17, -5.0, 1.0), DVec3::Y);
        assert!(analyse(&tangent, 0.0, f64::INFINITY, eps).band_hit);
    }
}
