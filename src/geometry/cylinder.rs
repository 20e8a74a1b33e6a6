//! Ray–cylinder kernels: the textbook formulas as written (`Literal`) and a numerically
//! stable form of the same surface (`Stable`), both generic over f32/f64.
//!
//! # The surface and the textbook formulas
//!
//! A finite cylinder has radius `r`, an axis through `c` (centre of its base disk) with unit
//! direction `n`, and height `h`: its side is every point `x` with
//! `|(x−c) − n((x−c)·n)|² = r²` and `0 ≤ (x−c)·n ≤ h`. Caps (optional) are the disks of
//! radius `r` at `c` (outward normal `−n`) and at `c + h·n` (outward normal `+n`).
//! For the ray `o + t·d` and `oc = o − c`:
//!
//! ```text
//! A = d·d − (n·d)²          = |d − n(n·d)|²
//! B = 2 d·oc − 2 (n·d)(n·oc)
//! C = oc·oc − (n·oc)² − r²  = |oc − n(n·oc)|² − r²
//! A t² + B t + C = 0
//! ```
//!
//! and the normal at `I = o + t·d` is `(I − T)/r`, where the axis point `T = c + a·n` solves
//! `a² − 2 n·(I−c) a + |I−c|² − r² = 0`.
//!
//! # Their traps, and what [`Stable`] does instead
//!
//! - `B² − 4AC` cancels catastrophically for grazing rays and far cameras. With `d⊥`, `oc⊥`
//!   the parts of `d`, `oc` perpendicular to `n` and `b = B/2 = d⊥·oc⊥`, the Lagrange identity
//!   `b² − AC = r²|d⊥|² − |d⊥ × oc⊥|²` has no such cancellation.
//! - `C` cancels for a camera near the surface (use `(|oc⊥| − r)(|oc⊥| + r)`), and the literal
//!   `oc·oc − (n·oc)²` cancels for a camera far along the axis (use `|oc⊥|²` directly).
//! - The roots as `q = −(b + sign(b)√disc)`, `t0 = q/A`, `t1 = C/q` subtract nothing
//!   near-equal, but are not ordered (for `b < 0`, `t0` is the far one), `sign(0)` must be ±1,
//!   and `q = 0` (camera on the surface, tangent ray) makes `C/q` 0/0: its own branch.
//! - `A → 0` for rays parallel to the axis: no side hit, caps only.
//! - The normal quadratic has a double root (`a = n·(I−c)` exactly), so its computed
//!   discriminant is ±rounding noise: NaN or a tilted normal. Project (`a = n·(I−c)`) and
//!   normalise `I − T` instead of dividing by `r`.
//! - f32 far from the world origin loses bits: the f32 kernels work in a frame centred on
//!   the cylinder (`oc` formed in f64, see [`Prepared`]).
//!
//! As in pbrt-v4, a hit is two steps: [`Formula::intersect`] finds the ray parameter and
//! the surface only (cheap; run for every BVH candidate), [`Formula::normal`] computes the
//! normal for the one winning hit. A depth-only render never calls `normal`.
//!
//! Rays are `o + t·d` with `d` of unit length in f64 before rounding, so `t` is a distance.
//! Everything is relative to the cylinder's base `c`: callers pass `oc = o - c` through
//! [`Prepared`], which is built once per cylinder and ray origin (one camera = one origin).

use super::real::Real;
use glam::DVec3;

/// A validated finite cylinder (see the module doc): base centre `base`, unit `axis`, `height`, `radius`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder {
    /// Centre of the bottom disk (`p0`).
    pub base: DVec3,
    /// Unit direction from the base disk to the top disk.
    pub axis: DVec3,
    /// Distance from the base to the top disk along the axis (> 0).
    pub height: f64,
    /// Radius (> 0).
    pub radius: f64,
    /// Closed (solid, two cap disks) or an open tube.
    pub caps: bool,
    /// Value written to the `shape_id` AOV (> 0).
    pub id: u32,
    /// The user's class of this cylinder (0 when the scene gives none): what the `label`
    /// AOV stores, so class masks come from `label` and instance masks from `shape_id`.
    pub label: u32,
}

impl Cylinder {
    /// Centre of the top disk, `base + height·axis`.
    pub fn top(&self) -> DVec3 {
        self.base + self.axis * self.height
    }

    /// Tight axis-aligned bounds: the boxes of the two end circles. Along world axis k a
    /// circle of radius r with normal n reaches `r·sqrt(1 - n_k²)` from its centre.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let ext = self.radius * (DVec3::ONE - self.axis * self.axis).max(DVec3::ZERO).sqrt();
        let (a, b) = (self.base, self.top());
        (a.min(b) - ext, a.max(b) + ext)
    }
}

/// The surface a hit lies on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Surface {
    /// The curved wall.
    Side = 0,
    /// The disk at `base`, outward normal `-axis`.
    Bottom,
    /// The disk at `base + height·axis`, outward normal `+axis`.
    Top,
}

impl Surface {
    /// The surface of code `Surface as u32` (as packets store it).
    #[inline(always)]
    pub fn from_code(code: u32) -> Surface {
        match code {
            1 => Surface::Bottom,
            2 => Surface::Top,
            _ => Surface::Side,
        }
    }
}

/// Result of the cheap intersection step: ray parameter (= distance) and surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BasicHit<T> {
    /// Ray parameter of the hit (a distance: directions are unit vectors).
    pub t: T,
    /// Which surface was hit.
    pub surface: Surface,
}

/// A cylinder ready for rays from one origin, in precision `T`.
#[derive(Clone, Copy, Debug)]
pub struct Prepared<T: Real> {
    /// Unit axis `n` and an orthonormal pair `u`, `v` perpendicular to it.
    pub n: T::V3,
    /// First unit vector perpendicular to the axis.
    pub u: T::V3,
    /// Second one: `u × v = n`.
    pub v: T::V3,
    /// `o - c` in world axes (the literal kernel's input).
    pub oc: T::V3,
    /// `o - c` in the (u, v, n) frame, computed in f64 before rounding to `T`.
    pub oc_local: [T; 3],
    /// `|oc⊥|² - r²` as `(|oc⊥| - r)(|oc⊥| + r)`, from f64 (the module doc's traps: no cancellation near
    /// the surface).
    pub c_side: T,
    /// `(o - p1)·n`, from f64: the top cap's plane measured from `p1` itself, so its `t` is
    /// exact to the rounding of this one value rather than of `h - (o - p0)·n`.
    pub on_top: T,
    /// Radius in `T`.
    pub r: T,
    /// Height in `T`.
    pub h: T,
    /// Closed (caps tested) or an open tube.
    pub caps: bool,
}

impl<T: Real> Prepared<T> {
    /// Prepare `cyl` for rays leaving `origin`. With `centred`, `oc` is formed in f64 and
    /// rounded once (a frame centred on the cylinder); without, it is `T(o) - T(c)`
    /// as the literal formulas would compute it in `T`.
    pub fn new(cyl: &Cylinder, origin: DVec3, centred: bool) -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU has FMA.
            return unsafe { Self::new_fma(cyl, origin, centred) };
        }
        Self::new_any(cyl, origin, centred)
    }

    /// [`Prepared::new`] with FMA instructions: `mul_add` is one instruction where it is
    /// otherwise a call (whose spills were most of `axial_from_top`'s time). An FMA rounds
    /// once, in hardware as in the call: the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn new_fma(cyl: &Cylinder, origin: DVec3, centred: bool) -> Self {
        Self::new_any(cyl, origin, centred)
    }

    #[inline(always)]
    fn new_any(cyl: &Cylinder, origin: DVec3, centred: bool) -> Self {
        let n = cyl.axis;
        let (u, v) = orthonormal_basis(n);
        let oc64 = origin - cyl.base;
        let oc = if centred {
            T::v3(oc64)
        } else {
            T::v3(origin) - T::v3(cyl.base)
        };
        // |oc⊥|: coordinates are below 1e12 (validated), so the squares cannot overflow, and
        // libm's `hypot` was a tenth of building 100 000 cylinders.
        let (x, y) = (oc64.dot(u), oc64.dot(v));
        let rho = (x * x + y * y).sqrt();
        Prepared {
            n: T::v3(n),
            u: T::v3(u),
            v: T::v3(v),
            oc,
            oc_local: [
                T::from_f64(oc64.dot(u)),
                T::from_f64(oc64.dot(v)),
                T::from_f64(oc64.dot(n)),
            ],
            c_side: T::from_f64((rho - cyl.radius) * (rho + cyl.radius)),
            on_top: T::from_f64(axial_from_top(cyl, origin)),
            r: T::from_f64(cyl.radius),
            h: T::from_f64(cyl.height),
            caps: cyl.caps,
        }
    }
}

/// `(o - p1)·n` with `p1 = base + height·axis`, correctly rounded up to a few ulp of the
/// result itself: `o - base`, its dot with `n` and the subtraction of `height` are carried
/// exactly (two-sum, fused products) and rounded once. The plain `(o - base)·n - height` is
/// off by ε·|o - base|, which near the top of a tall cylinder is many ulp of the cap's `t`.
#[inline(always)]
fn axial_from_top(cyl: &Cylinder, origin: DVec3) -> f64 {
    // Error-free transforms: a + b = s + e and a·b = p + e exactly.
    let two_sum = |a: f64, b: f64| {
        let s = a + b;
        let bb = s - a;
        (s, (a - (s - bb)) + (b - bb))
    };
    let two_prod = |a: f64, b: f64| {
        let p = a * b;
        (p, a.mul_add(b, -p))
    };
    let (o, c, n) = (origin.to_array(), cyl.base.to_array(), cyl.axis.to_array());
    // Sum of hi parts with compensation; low parts (each ≤ ε of its term) summed plainly.
    // `nn` is |n|² - 1 the same way: the stored axis is a unit vector only to within
    // rounding, |n| = 1 + e with |e| ≲ 2ε, and the cap's plane lies at `h` along the exact
    // unit axis n/|n|. Left in, `e` would move the plane by e·h: for a tall cylinder seen
    // from just above its top that is again ε·|o - p0|, not ε·|o - p1|.
    let (mut hi, mut lo) = (-cyl.height, 0.0);
    let (mut nn, mut nn_lo) = (-1.0, 0.0);
    for k in 0..3 {
        let (dh, dl) = two_sum(o[k], -c[k]);
        let (p, pe) = two_prod(dh, n[k]);
        let (s, e) = two_sum(hi, p);
        hi = s;
        lo += e + pe + dl * n[k];
        let (q, qe) = two_prod(n[k], n[k]);
        let (s, e) = two_sum(nn, q);
        nn = s;
        nn_lo += e + qe;
    }
    // (o - p0)·n/|n| - h = ((o - p0)·n - h·|n|)/|n| with |n| = 1 + e, e = (|n|² - 1)/2 to
    // first order (e² ≲ 4ε² is far below the result's rounding). The final division by
    // |n| changes the result by |e| relative, under one ulp: left out.
    let e = (nn + nn_lo) / 2.0;
    hi + (lo - cyl.height * e)
}

/// Orthonormal `u`, `v` with `u × v = n` (Duff et al. 2017, branchless).
pub fn orthonormal_basis(n: DVec3) -> (DVec3, DVec3) {
    let s = 1f64.copysign(n.z);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x),
        DVec3::new(b, s + n.y * n.y * a, -n.y),
    )
}

crate::choice_enum! {
    /// Kernel formulation (see [`crate::geometry::cylinder`]).
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
    pub enum FormulaKind default Stable {
        /// The textbook formulas as written: textbook roots, axis-point normal quadratic.
        Literal = "literal",
        /// Lagrange discriminant, citardauq roots, projected normal, gap-free rims.
        Stable = "stable",
    }
}

impl FormulaKind {
    /// `literal` or `stable`.
    pub fn name(self) -> &'static str {
        match self {
            FormulaKind::Literal => "literal",
            FormulaKind::Stable => "stable",
        }
    }
}

/// A formulation of the ray–cylinder hit: [`Literal`] or [`Stable`].
pub trait Formula: Copy + Send + Sync + 'static {
    /// Name for tables: `literal` or `stable`.
    const NAME: &'static str;
    /// The same, as the kernel choice names it.
    const KIND: FormulaKind;
    /// Whether [`Prepared::new`] should form `oc` in f64 (see there).
    const CENTRED: bool;
    /// Nearest hit with `t` in `[tmin, tmax]`, or `None`. Computes no normal.
    fn intersect<T: Real>(p: &Prepared<T>, d: T::V3, tmin: T, tmax: T) -> Option<BasicHit<T>>;
    /// World-space outward unit normal at `hit` (not flipped toward the ray).
    fn normal<T: Real>(p: &Prepared<T>, d: T::V3, hit: BasicHit<T>) -> T::V3;
}

/// The textbook formulas of the module doc, as written: `A`, `B`, `C`, `B² - 4AC`, the textbook
/// roots, and the normal from the axis-point quadratic divided by `r`. Caps are separate
/// disk tests. Nothing is guarded beyond what keeps it from crashing (NaN compares false
/// and so never hits), so its failures stay visible in the stress table.
#[derive(Clone, Copy, Debug, Default)]
pub struct Literal;

impl Formula for Literal {
    const NAME: &'static str = "literal";
    const KIND: FormulaKind = FormulaKind::Literal;
    const CENTRED: bool = false;

    fn intersect<T: Real>(p: &Prepared<T>, d: T::V3, tmin: T, tmax: T) -> Option<BasicHit<T>> {
        let (n, oc, two) = (p.n, p.oc, T::TWO);
        let nd = T::dot(n, d);
        let noc = T::dot(n, oc);
        let mut best: Option<BasicHit<T>> = None;
        let mut take = |t: T, surface: Surface| {
            if t >= tmin && t <= tmax && best.is_none_or(|b| t < b.t) {
                best = Some(BasicHit { t, surface });
            }
        };
        // Side: A t² + B t + C = 0.
        let a = T::dot(d, d) - nd * nd;
        let b = two * T::dot(d, oc) - two * nd * noc;
        let c = T::dot(oc, oc) - noc * noc - p.r * p.r;
        let disc = b * b - T::from_f64(4.0) * a * c;
        if disc >= T::ZERO {
            let s = disc.sqrt();
            for t in [(-b - s) / (two * a), (-b + s) / (two * a)] {
                let along = noc + t * nd;
                if along >= T::ZERO && along <= p.h {
                    take(t, Surface::Side);
                }
            }
        }
        // Caps: disks in the planes n·(x - c) = 0 and = h.
        if p.caps {
            for (k, surface) in [(T::ZERO, Surface::Bottom), (p.h, Surface::Top)] {
                let t = (k - noc) / nd;
                let x = oc + d * t - n * k;
                if T::dot(x, x) <= p.r * p.r {
                    take(t, surface);
                }
            }
        }
        best
    }

    fn normal<T: Real>(p: &Prepared<T>, d: T::V3, hit: BasicHit<T>) -> T::V3 {
        match hit.surface {
            Surface::Bottom => -p.n,
            Surface::Top => p.n,
            Surface::Side => {
                // Axis point T = c + a n with a² - 2 n·(I-c) a + |I-c|² - r² = 0; N = (I-T)/r.
                let i = p.oc + d * hit.t;
                let m = T::dot(p.n, i);
                let two = T::TWO;
                let disc = two * two * m * m - two * two * (T::dot(i, i) - p.r * p.r);
                let a = (two * m - disc.sqrt()) / two;
                (i - p.n * a) * (T::ONE / p.r)
            }
        }
    }
}

/// The stable form. In the cylinder's (u, v, n) frame, with `d⊥`, `oc⊥` the parts
/// perpendicular to the axis (the module doc's traps):
/// - `A = |d⊥|²`, half-coefficient `b = d⊥·oc⊥`, `C = (|oc⊥| - r)(|oc⊥| + r)` (from f64);
/// - discriminant by the Lagrange identity `b² - AC = r²A - (d⊥ × oc⊥)²`, factored as
///   `(r√A - |X|)(r√A + |X|)` so no large terms cancel;
/// - roots `q = -(b + sign(b)√disc)`, `q/A` and `C/q` (no subtraction of near-equal terms;
///   `sign(0) = +1`; `q = 0` only for a tangent ray from the surface: double root at 0);
/// - closed cylinders are the intersection of the side interval with the cap slab, so the
///   rim has no gap: the entry parameter is `max(side entry, slab entry)` and the surface is
///   whichever bound it was. A ray parallel to the axis (`A = 0`) is inside the side
///   interval everywhere or nowhere, so it reaches the caps only.
/// - the normal is the projection `normalize(I⊥)`, not the axis-point quadratic (whose
///   double root makes its discriminant pure rounding noise).
///
/// Backward error: each step is a few roundings of inputs that carry no cancellation, so
/// `t` has the error of perturbing the inputs by a few ε; tests and `stress` measure it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stable;

impl Stable {
    /// Parameter interval where the ray is inside the infinite cylinder, or `None`.
    #[inline(always)]
    fn side_interval<T: Real>(p: &Prepared<T>, du: T, dv: T) -> Option<(T, T)> {
        let [ou, ov, _] = p.oc_local;
        let a = du * du + dv * dv;
        if a == T::ZERO {
            // Parallel to the axis: inside everywhere or nowhere.
            return (p.c_side <= T::ZERO).then_some((-T::INFINITY, T::INFINITY));
        }
        let x = (du * ov - dv * ou).abs();
        // Cheap reject before the square root: the ray misses by a clear margin. 8ε covers
        // the roundings in which the two forms of the test differ (r², ×a, x², √a, ×r).
        let r2a = p.r * p.r * a;
        if x * x > r2a + r2a * T::from_f64(8.0 * T::UNIT_ROUNDOFF) {
            return None;
        }
        let b = du * ou + dv * ov;
        let ra = p.r * a.sqrt();
        let disc = (ra - x) * (ra + x);
        if disc < T::ZERO {
            return None;
        }
        let q = -(b + b.sign() * disc.sqrt());
        if q == T::ZERO {
            // b = 0 and disc = 0, so C = 0: tangent ray starting on the surface.
            return Some((T::ZERO, T::ZERO));
        }
        let (t0, t1) = (q / a, p.c_side / q);
        Some((t0.min(t1), t0.max(t1)))
    }
}

impl Formula for Stable {
    const NAME: &'static str = "stable";
    const KIND: FormulaKind = FormulaKind::Stable;
    const CENTRED: bool = true;

    #[inline(always)]
    fn intersect<T: Real>(p: &Prepared<T>, d: T::V3, tmin: T, tmax: T) -> Option<BasicHit<T>> {
        let (du, dv, dn) = (T::dot(d, p.u), T::dot(d, p.v), T::dot(d, p.n));
        let on = p.oc_local[2];
        let (s0, s1) = Self::side_interval(p, du, dv)?;
        // Every hit is at or past the side's entry (on the side, or through a cap after
        // it), so an entry past `tmax` ends the test before the caps' divisions.
        if s0 > tmax {
            return None;
        }
        let in_range = |t: T| t >= tmin && t <= tmax;
        if !p.caps {
            // Open tube: each side root counts if it lies between the cap planes.
            return [s0, s1].into_iter().find_map(|t| {
                let along = on + t * dn;
                (in_range(t) && along >= T::ZERO && along <= p.h).then_some(BasicHit {
                    t,
                    surface: Surface::Side,
                })
            });
        }
        // Slab between the cap planes; a ray parallel to them is inside it or not at all.
        let (c0, c1, enter_cap, exit_cap) = if dn == T::ZERO {
            // Each plane judged from itself: `on > h` would read the top plane to within
            // the rounding of `(o - p0)·n`, which in f32 near the top of a long cylinder is
            // far more than a spawned ray's offset above the cap.
            if on < T::ZERO || p.on_top > T::ZERO {
                return None;
            }
            let inf = T::INFINITY;
            (-inf, inf, Surface::Bottom, Surface::Top)
        } else {
            let (ta, tb) = (-on / dn, -p.on_top / dn);
            if dn > T::ZERO {
                (ta, tb, Surface::Bottom, Surface::Top)
            } else {
                (tb, ta, Surface::Top, Surface::Bottom)
            }
        };
        let enter = if s0 >= c0 {
            BasicHit {
                t: s0,
                surface: Surface::Side,
            }
        } else {
            BasicHit {
                t: c0,
                surface: enter_cap,
            }
        };
        let exit = if s1 <= c1 {
            BasicHit {
                t: s1,
                surface: Surface::Side,
            }
        } else {
            BasicHit {
                t: c1,
                surface: exit_cap,
            }
        };
        if enter.t > exit.t {
            return None;
        }
        // From outside the entry is nearest; from inside (entry behind tmin) the exit.
        [enter, exit].into_iter().find(|h| in_range(h.t))
    }

    #[inline(always)]
    fn normal<T: Real>(p: &Prepared<T>, d: T::V3, hit: BasicHit<T>) -> T::V3 {
        match hit.surface {
            Surface::Bottom => -p.n,
            Surface::Top => p.n,
            Surface::Side => {
                let [ou, ov, _] = p.oc_local;
                let (du, dv) = (T::dot(d, p.u), T::dot(d, p.v));
                let x = ou + hit.t * du;
                let y = ov + hit.t * dv;
                let len = (x * x + y * y).sqrt();
                if len > T::ZERO {
                    return p.u * (x / len) + p.v * (y / len);
                }
                // Edge policy: the hit point's offset from the axis rounded to exactly zero.
                // This happens only when the spacing of T at the hit's coordinates exceeds r
                // (f32 with the camera ≳ 1e7 radii away: `ou + t·du` cancels to 0 in both
                // components), so the point carries no direction; answer the side facing the
                // ray (-d⊥), the normal at the middle of the silhouette, instead of 0/0 = NaN.
                let a = (du * du + dv * dv).sqrt();
                p.u * (-du / a) + p.v * (-dv / a)
            }
        }
    }
}
