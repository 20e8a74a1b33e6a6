//! The stress suite: families of rays where ray–cylinder arithmetic breaks, each
//! swept over its difficulty parameter, run through every kernel (literal/stable × f32/f64)
//! and measured against the double-double [`oracle`].
//!
//! **What the oracle is fed.** A kernel's inputs are the f64 ray origin, the cylinder in f64,
//! and the ray direction *in the kernel's precision*: the f32 pipeline rounds the f64 camera
//! direction to f32 before the kernel sees it (the f64 pipeline never rounds it). The oracle gets exactly those
//! inputs — the f64 origin and cylinder, and the direction after that rounding — so the
//! error we report is the kernel's own forward error, comparable with its backward-stability
//! bound `4ε·max(1, κ)`. Everything the kernel does after receiving its inputs (forming `oc`
//! and the local frame in `Prepared::new`, rounding them to f32) is counted as kernel error.
//! The rounding of the direction itself is an input error of the f32 *pipeline*: it moves
//! the hit by up to `ε₃₂·t` sideways; see docs/accuracy.md for what that costs.
//!
//! **Tangency band.** Rays whose hit/miss changes when the origin moves by
//! [`BAND_ULPS`](crate::verify::oracle::BAND_ULPS)`·ε·(|oc| + r + h)` are not counted as wrong
//! hit/miss, and rays whose branch (surface, or root) changes are not held to the bounds;
//! both are counted in the `band` column.
//!
//! **Bounds** (the accuracy bar: backward stability, `error ≤ 4ε·max(1, κ)`, which is the
//! 4-ulp bound on well-conditioned rays, κ ≤ 2), for rays outside the band where both oracle
//! and kernel hit: distance `|Δt|/t ≤ 4ε·max(1, κ_t)`; normal angle
//! `≤ max(16ε·max(1, t/r), 4ε·κ_n)` (the normal's own bound, widened by κ_n only where the normal itself is ill-conditioned: a grazing
//! hit's normal turns by `Δp/√(r² − p²)` for a sideways move `Δp`).

use crate::geometry::cylinder::orthonormal_basis;
use crate::geometry::kernel::KernelFn;
use crate::geometry::packet::PacketFormula;
use crate::geometry::wide::Simd;
use crate::geometry::{Cylinder, Formula, Kernel, Prepared, Real, Surface};
use crate::rng::SplitMix64;
use crate::scene;
use crate::verify::oracle::{self, Analysis, DD, DV3, Problem};
use glam::DVec3;
use serde::Serialize;
use std::fmt;

// ---- families ----------------------------------------------------------------------------

/// A stress family; each sweeps one difficulty parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// Rays passing near the side's silhouette (`param`: distance from tangency, in radii).
    Grazing,
    /// Rays at a small angle to the axis (`param`: that angle, radians).
    NearAxis,
    /// A unit cylinder far from the origin and the camera (`param`: the distance, in radii).
    Far,
    /// Everything scaled (`param`: the radius).
    Scale,
    /// Cameras just inside or outside the wall (`param`: distance from it, in radii).
    Inside,
    /// Rays aimed near the cap/side seam (`param`: distance from the rim, in radii).
    Rims,
    /// Cylinders given in either file form and read through scene validation.
    Input,
}

impl Family {
    /// Every family, in table order.
    pub const ALL: [Family; 7] = [
        Family::Grazing,
        Family::NearAxis,
        Family::Far,
        Family::Scale,
        Family::Inside,
        Family::Rims,
        Family::Input,
    ];

    /// The name used on the command line and in tables.
    pub fn name(self) -> &'static str {
        match self {
            Family::Grazing => "grazing",
            Family::NearAxis => "near-axis",
            Family::Far => "far",
            Family::Scale => "scale",
            Family::Inside => "inside",
            Family::Rims => "rims",
            Family::Input => "input",
        }
    }

    /// The family of a command-line name.
    pub fn parse(s: &str) -> Option<Family> {
        Family::ALL.into_iter().find(|f| f.name() == s)
    }

    /// What the difficulty parameter is.
    pub fn param_name(self) -> &'static str {
        match self {
            Family::Grazing => "relative gap of the ray from tangency (p - r)/r",
            Family::NearAxis => "angle between ray and axis (rad)",
            Family::Far => "distance camera-cylinder and cylinder-origin, in radii",
            Family::Scale => "radius (camera at 5 radii)",
            Family::Inside => "relative distance of the camera from the surface |rho - r|/r",
            Family::Rims => "offset of the aim point from the cap/side seam, in radii",
            Family::Input => "coordinate magnitude / 1/axis length",
        }
    }

    /// The parameter values of the sweep.
    pub fn params(self) -> Vec<f64> {
        let decades = |a: i32, b: i32| (a..=b).map(|k| 10f64.powi(k)).collect::<Vec<_>>();
        match self {
            Family::Grazing | Family::Rims | Family::Inside => decades(-16, -1),
            Family::NearAxis => decades(-9, -1),
            Family::Far => decades(1, 7),
            Family::Scale => decades(-6, 6),
            Family::Input => decades(3, 12),
        }
    }
}

impl fmt::Display for Family {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How the oracle sees the cylinder: the validated one, or the user's raw numbers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RawCylinder {
    /// The validated [`Cylinder`] itself.
    Validated,
    /// Written as `p0`, `p1` (oracle: exact axis and height from the two points).
    Endpoints(DVec3, DVec3),
    /// Written as `center`, `axis` (any length), `height` (oracle: axis normalised in DD).
    CenterAxis(DVec3, DVec3, f64),
}

/// One stress ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Case {
    /// The family the ray belongs to.
    pub family: Family,
    /// The difficulty parameter this ray belongs to.
    pub param: f64,
    /// The cylinder, as the renderer gets it after validation.
    pub cyl: Cylinder,
    /// The cylinder as written in the file, for the oracle.
    pub raw: RawCylinder,
    /// Ray origin (f64).
    pub origin: DVec3,
    /// Unit direction in f64 (before any rounding to the kernel's precision).
    pub dir: DVec3,
    /// Smallest accepted `t` (the near clip of a camera ray, else 0).
    pub tmin: f64,
}

impl Case {
    /// The oracle's problem for direction `dir_seen` (the direction as the kernel saw it).
    pub fn problem(&self, dir_seen: DVec3) -> Problem {
        match self.raw {
            RawCylinder::Validated => Problem::new(&self.cyl, self.origin, dir_seen),
            RawCylinder::Endpoints(p0, p1) => Problem::from_endpoints(
                p0,
                p1,
                self.cyl.radius,
                self.cyl.caps,
                self.origin,
                dir_seen,
            ),
            RawCylinder::CenterAxis(c, a, h) => Problem {
                oc: DV3::diff(self.origin, c),
                d: DV3::from_f64(dir_seen),
                axis: DV3::from_f64(a),
                r: self.cyl.radius.into(),
                h: h.into(),
                caps: self.cyl.caps,
            },
        }
    }
}

/// A cylinder with a random frame: base `base`, random unit axis; maps local
/// (x, y, along-axis) coordinates to world.
struct CylinderFrame {
    base: DVec3,
    u: DVec3,
    v: DVec3,
    n: DVec3,
}

impl CylinderFrame {
    fn random(rng: &mut SplitMix64, base: DVec3) -> CylinderFrame {
        let n = rng.sphere();
        let (u, v) = orthonormal_basis(n);
        CylinderFrame { base, u, v, n }
    }
    fn point(&self, l: DVec3) -> DVec3 {
        self.base + self.u * l.x + self.v * l.y + self.n * l.z
    }
    fn vector(&self, l: DVec3) -> DVec3 {
        self.u * l.x + self.v * l.y + self.n * l.z
    }
    fn cylinder(&self, r: f64, h: f64, caps: bool) -> Cylinder {
        Cylinder {
            base: self.base,
            axis: self.n,
            height: h,
            radius: r,
            caps,
            id: 1,
            label: 0,
        }
    }
}

/// Seed of ray `i` at parameter index `k` of `family`: independent of which families run.
fn seed(family: Family, k: usize, i: usize) -> u64 {
    let f = Family::ALL.iter().position(|&g| g == family).unwrap_or(0) as u64;
    (f << 48) ^ ((k as u64) << 24) ^ (i as u64) ^ 0x5EED_C71A_0000_0000
}

/// `rays` seeded rays for every parameter value of `family`.
pub fn cases(family: Family, rays: usize) -> Vec<Case> {
    let mut out = Vec::new();
    for (k, &param) in family.params().iter().enumerate() {
        for i in 0..rays {
            let mut rng = SplitMix64::new(seed(family, k, i));
            if let Some(c) = make_case(family, param, i, &mut rng) {
                out.push(c);
            }
        }
    }
    out
}

fn simple(
    family: Family,
    param: f64,
    frame: &CylinderFrame,
    cyl: Cylinder,
    o: DVec3,
    d: DVec3,
) -> Case {
    Case {
        family,
        param,
        cyl,
        raw: RawCylinder::Validated,
        origin: frame.point(o),
        dir: frame.vector(d).normalize(),
        tmin: 0.0,
    }
}

/// One ray of `family` at difficulty `param`; `i` picks the sub-case.
fn make_case(family: Family, param: f64, i: usize, rng: &mut SplitMix64) -> Option<Case> {
    // Every family draws the base first, so the stream of each case is fixed by `i` alone.
    let base = DVec3::new(
        rng.range(-10.0, 10.0),
        rng.range(-10.0, 10.0),
        rng.range(-10.0, 10.0),
    );
    let caps = i.is_multiple_of(2);
    match family {
        Family::Grazing => grazing_case(param, i, base, caps, rng),
        Family::NearAxis => near_axis_case(param, i, base, caps, rng),
        Family::Far | Family::Scale => far_or_scale_case(family, param, base, caps, rng),
        Family::Inside => inside_case(param, i, base, caps, rng),
        Family::Rims => rims_case(param, i, base, caps, rng),
        Family::Input => input_case(param, i, rng, caps),
    }
}

/// Grazing: rays passing `param` radii inside or outside the side's silhouette.
fn grazing_case(
    param: f64,
    i: usize,
    base: DVec3,
    caps: bool,
    rng: &mut SplitMix64,
) -> Option<Case> {
    let family = Family::Grazing;
    // Camera 3–7 radii from the axis; the ray's distance from the axis is
    // p = r(1 ± param), tilted up to ±0.2 rad so it stays between the caps.
    let f = CylinderFrame::random(rng, base);
    let (r, h) = (1.0, 4.0);
    let rho0 = rng.range(3.0, 7.0);
    let phi0 = rng.range(0.0, std::f64::consts::TAU);
    let p = if (i / 2).is_multiple_of(2) {
        r * (1.0 - param)
    } else {
        r * (1.0 + param)
    };
    let side = if (i / 4).is_multiple_of(2) { 1.0 } else { -1.0 };
    let beta = side * (p / rho0).asin();
    let dir2 = phi0 + std::f64::consts::PI + beta;
    let tilt = rng.range(-0.2, 0.2);
    let o = DVec3::new(rho0 * phi0.cos(), rho0 * phi0.sin(), rng.range(1.5, 2.5));
    let d = DVec3::new(tilt.cos() * dir2.cos(), tilt.cos() * dir2.sin(), tilt.sin());
    Some(simple(family, param, &f, f.cylinder(r, h, caps), o, d))
}

/// Near-axis: rays at angle `param` to the axis, through a cap, inside a tall tube, or
/// converging on the axis from outside.
fn near_axis_case(
    param: f64,
    i: usize,
    base: DVec3,
    caps: bool,
    rng: &mut SplitMix64,
) -> Option<Case> {
    let family = Family::NearAxis;
    let f = CylinderFrame::random(rng, base);
    let az = rng.range(0.0, std::f64::consts::TAU);
    let tilt = |toward: f64| {
        DVec3::new(
            param.sin() * toward.cos(),
            param.sin() * toward.sin(),
            param.cos(),
        )
    };
    match i % 3 {
        0 => {
            // From below, through the bottom cap (a cap hit; open tubes: a miss or
            // the inner wall far away).
            let (rr, a) = (
                0.8 * rng.unit().sqrt(),
                rng.range(0.0, std::f64::consts::TAU),
            );
            let o = DVec3::new(rr * a.cos(), rr * a.sin(), -rng.range(3.0, 4.0));
            Some(simple(
                family,
                param,
                &f,
                f.cylinder(1.0, 2.0, caps),
                o,
                tilt(az),
            ))
        }
        1 => {
            // Inside a tube tall enough that the side is hit at t ≈ 1/θ.
            let h = 20.0 / param;
            let (rr, a) = (
                0.9 * rng.unit().sqrt(),
                rng.range(0.0, std::f64::consts::TAU),
            );
            let o = DVec3::new(rr * a.cos(), rr * a.sin(), 0.05 * h);
            Some(simple(
                family,
                param,
                &f,
                f.cylinder(1.0, h, caps),
                o,
                tilt(az),
            ))
        }
        _ => {
            // Outside (1.5 radii), converging on the axis: side hit at t ≈ 0.5/θ.
            let h = 20.0 / param;
            let o = DVec3::new(1.5 * az.cos(), 1.5 * az.sin(), 0.05 * h);
            let toward = az + std::f64::consts::PI + rng.range(-0.3, 0.3);
            Some(simple(
                family,
                param,
                &f,
                f.cylinder(1.0, h, caps),
                o,
                tilt(toward),
            ))
        }
    }
}

/// Far and scale: the camera `param` radii away, or everything scaled by `param`.
fn far_or_scale_case(
    family: Family,
    param: f64,
    base: DVec3,
    caps: bool,
    rng: &mut SplitMix64,
) -> Option<Case> {
    // Far: a unit cylinder `param` radii from the world origin and from the camera.
    // Scale: radius `param`, everything else proportional.
    let (r, base, dist) = if family == Family::Far {
        (1.0, rng.sphere() * param, param)
    } else {
        (param, base * param * 0.3, 5.0 * param)
    };
    let f = CylinderFrame::random(rng, base);
    let h = 2.0 * r;
    let cam = f.base + rng.sphere() * dist;
    let a = rng.range(0.0, std::f64::consts::TAU);
    let rr = 1.3 * r * rng.unit().sqrt();
    let target = f.point(DVec3::new(
        rr * a.cos(),
        rr * a.sin(),
        rng.range(-0.3, 2.3) * r,
    ));
    Some(Case {
        family,
        param,
        cyl: f.cylinder(r, h, caps),
        raw: RawCylinder::Validated,
        origin: cam,
        dir: (target - cam).normalize(),
        tmin: 0.0,
    })
}

/// Inside: the camera `param` radii inside or outside the wall.
fn inside_case(
    param: f64,
    i: usize,
    base: DVec3,
    caps: bool,
    rng: &mut SplitMix64,
) -> Option<Case> {
    let family = Family::Inside;
    // Camera at rho = r(1 - param) (inside) or r(1 + param) (just outside), random
    // direction.
    let f = CylinderFrame::random(rng, base);
    let rho = if (i / 2).is_multiple_of(2) {
        1.0 - param
    } else {
        1.0 + param
    };
    let a = rng.range(0.0, std::f64::consts::TAU);
    let o = DVec3::new(rho * a.cos(), rho * a.sin(), 2.0);
    let d = rng.sphere();
    Some(simple(family, param, &f, f.cylinder(1.0, 4.0, caps), o, d))
}

/// Rims: aimed `param` radii from the cap/side seam.
fn rims_case(param: f64, i: usize, base: DVec3, caps: bool, rng: &mut SplitMix64) -> Option<Case> {
    let family = Family::Rims;
    // Aim at a point `param` radii from the seam (along the axis or radially, either
    // side), from a camera 2–5 units away where the rim is visible.
    let f = CylinderFrame::random(rng, base);
    let (r, h) = (1.0, 2.0);
    let a = rng.range(0.0, std::f64::consts::TAU);
    let radial = DVec3::new(a.cos(), a.sin(), 0.0);
    let (z, cap_n) = if i % 4 < 2 {
        (0.0, DVec3::NEG_Z)
    } else {
        (h, DVec3::Z)
    };
    let offset = match (i / 4) % 4 {
        0 => DVec3::Z,
        1 => DVec3::NEG_Z,
        2 => radial,
        _ => -radial,
    } * param;
    let target = radial * r + DVec3::new(0.0, 0.0, z) + offset;
    let w = loop {
        let w = rng.sphere();
        if w.dot(radial) > 0.1 || w.dot(cap_n) > 0.1 {
            break w;
        }
    };
    let o = target + w * rng.range(2.0, 5.0);
    Some(simple(
        family,
        param,
        &f,
        f.cylinder(r, h, caps),
        o,
        target - o,
    ))
}

/// Input family: the cylinder goes through scene validation (as a user's file would), the
/// oracle sees the raw numbers.
fn input_case(param: f64, i: usize, rng: &mut SplitMix64, caps: bool) -> Option<Case> {
    let axis_dir = rng.sphere();
    let (json, raw, near) = match i % 3 {
        0 => {
            // Huge coordinates: a unit cylinder `param` from the origin, camera 5 away.
            let p0 = rng.sphere() * param;
            let p1 = p0 + axis_dir * 2.0;
            (
                format!("\"p0\": {}, \"p1\": {}", js(p0), js(p1)),
                RawCylinder::Endpoints(p0, p1),
                p0 + axis_dir,
            )
        }
        1 => {
            // Non-unit axis of length 1/param (tiny), seed form.
            let c = rng.sphere() * 3.0;
            let a = axis_dir / param;
            (
                format!(
                    "\"center\": {}, \"axis\": {}, \"height\": 2.0",
                    js(c),
                    js(a)
                ),
                RawCylinder::CenterAxis(c, a, 2.0),
                c + axis_dir,
            )
        }
        _ => {
            // Nearly coincident end points far out: p1 - p0 is a short difference of huge
            // numbers (the axis is what the two f64 points define, exactly).
            let p0 = rng.sphere() * param;
            let p1 = p0 + axis_dir * (2.0 + rng.unit());
            (
                format!("\"p0\": {}, \"p1\": {}", js(p0), js(p1)),
                RawCylinder::Endpoints(p0, p1),
                (p0 + p1) * 0.5,
            )
        }
    };
    let origin = near + rng.sphere() * 5.0;
    let target = near + rng.sphere() * 1.2;
    let dir = (target - origin).normalize();
    let up = if dir.z.abs() < 0.9 {
        DVec3::Z
    } else {
        DVec3::X
    };
    let text = format!(
        "{{\"camera\": {{\"origin\": {}, \"target\": {}, \"up\": {}, \"fov_deg\": 40, \
         \"width\": 4, \"height\": 4}}, \"cylinders\": [{{{json}, \"radius\": 1.0, \"caps\": {caps}}}]}}",
        js(origin),
        js(origin + dir),
        js(up),
    );
    let scene = scene::parse(&text).ok()?;
    Some(Case {
        family: Family::Input,
        param,
        cyl: *scene.cylinders.first()?,
        raw,
        origin,
        dir,
        tmin: 0.0,
    })
}

/// A JSON array that round-trips the f64 values exactly.
fn js(v: DVec3) -> String {
    format!("[{:?}, {:?}, {:?}]", v.x, v.y, v.z)
}

// ---- kernels and measurements ------------------------------------------------------------

/// The stress table's order of the kernels: the textbook formulas first, so a reader sees
/// each failure and then the stable kernel that has none.
pub const TABLE_ORDER: [Kernel; 4] = [
    Kernel::LITERAL_F32,
    Kernel::LITERAL_F64,
    Kernel::STABLE_F32,
    Kernel::STABLE_F64,
];

/// The ray direction as `kernel` receives it: the f32 pipeline rounds the f64 camera
/// direction to f32 first.
pub fn dir_seen(kernel: Kernel, dir: DVec3) -> DVec3 {
    if kernel.is_f32() {
        f32::v3_to_f64(f32::v3(dir))
    } else {
        dir
    }
}

/// `kernel` on one case, as the renderer calls it.
fn run_kernel(kernel: Kernel, c: &Case) -> Option<KernelHit> {
    struct Run<'a>(&'a Case);
    impl KernelFn for Run<'_> {
        type Output = Option<KernelHit>;
        fn call<T: Simd, F: PacketFormula>(self) -> Option<KernelHit> {
            run::<T, F>(self.0)
        }
    }
    kernel.dispatch(Run(c))
}

/// A kernel's answer, widened to f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelHit {
    /// Ray parameter (a distance: the direction is a unit vector).
    pub t: f64,
    /// Which part of the cylinder was hit.
    pub surface: Surface,
    /// World-space unit outward normal.
    pub normal: DVec3,
}

/// The kernel exactly as the renderer calls it: `Prepared::new`, `intersect`, `normal`.
/// `tmax = ∞` so that an infinite `t` is reported, not clipped.
fn run<T: Real, F: Formula>(c: &Case) -> Option<KernelHit> {
    let p = Prepared::<T>::new(&c.cyl, c.origin, F::CENTRED);
    let d = T::v3(c.dir);
    let h = F::intersect(&p, d, T::from_f64(c.tmin), T::INFINITY)?;
    Some(KernelHit {
        t: h.t.to_f64(),
        surface: h.surface,
        normal: T::v3_to_f64(F::normal(&p, d, h)),
    })
}

/// One ray through one kernel, measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    /// The ray.
    pub case: Case,
    /// The kernel that traced it.
    pub kernel: Kernel,
    /// The oracle's answer.
    pub oracle: Option<oracle::Hit>,
    /// The kernel's answer.
    pub got: Option<KernelHit>,
    /// κ and the tangency band of the ray.
    pub analysis: Analysis,
    /// `t` or the normal is NaN/inf.
    pub nonfinite: bool,
    /// Hit vs miss disagrees with the oracle, outside the tangency band.
    pub wrong: bool,
    /// `|Δt| / (ε t)`, when both hit (NaN otherwise).
    pub err_t: f64,
    /// `|Δt|` in units in the last place of the oracle's `t` in the kernel's precision.
    pub err_ulps: f64,
    /// Normal angle error in radians, when both hit (NaN otherwise).
    pub err_n: f64,
    /// `err_n / (ε·max(1, t/r))`: the issue's normal bound is 16 of these.
    pub err_n_units: f64,
    /// `||n| - 1|`.
    pub len_err: f64,
    /// Outside the band and over `4·max(1, κ_t)` (distance) ...
    pub viol_t: bool,
    /// ... or over `max(16ε·max(1, t/r), 4ε·κ_n)` (normal).
    pub viol_n: bool,
}

/// Measure one case with one kernel, given the oracle's analysis for that kernel's inputs.
pub fn measure(case: &Case, kernel: Kernel, analysis: &Analysis) -> Record {
    let eps = kernel.eps();
    let got = run_kernel(kernel, case);
    let oracle = analysis.hit;
    let nonfinite = got.is_some_and(|g| !g.t.is_finite() || !g.normal.is_finite());
    let wrong = !analysis.band_hit && (got.is_some() != oracle.is_some());
    let (mut err_t, mut err_n, mut err_n_units, mut len_err) = (f64::NAN, f64::NAN, f64::NAN, 0.0);
    let mut err_ulps = f64::NAN;
    let (mut viol_t, mut viol_n) = (false, false);
    if let (Some(g), Some(o)) = (got, oracle) {
        let t0 = o.t.to_f64();
        let dt = (DD::new(g.t) - o.t).abs().to_f64();
        err_t = dt / (eps * t0.abs().max(f64::MIN_POSITIVE));
        err_ulps = dt / ulp(t0, kernel.is_f32());
        // Same surface: the oracle's normal; on another surface (possible only in the
        // band, at the seam) the oracle's normal of the kernel's surface at the same t.
        let want = if g.surface == o.surface {
            o.normal
        } else {
            oracle::normal_at(&case.problem(dir_seen(kernel, case.dir)), o.t, g.surface)
        };
        err_n = oracle::angle(g.normal.normalize_or_zero(), want.to_f64());
        let scale = (t0 / case.cyl.radius).max(1.0);
        err_n_units = err_n / (eps * scale);
        len_err = (g.normal.length() - 1.0).abs();
        if !analysis.band() {
            // NaN errors count as violations.
            viol_t = err_t.is_nan() || err_t > 4.0 * analysis.kappa_t.max(1.0);
            viol_n = err_n.is_nan()
                || err_n > (16.0 * eps * scale).max(4.0 * eps * analysis.kappa_n)
                || g.surface != o.surface;
        }
    }
    Record {
        case: *case,
        kernel,
        oracle,
        got,
        analysis: *analysis,
        nonfinite,
        wrong,
        err_t,
        err_ulps,
        err_n,
        err_n_units,
        len_err,
        viol_t: viol_t || nonfinite,
        viol_n: viol_n || nonfinite,
    }
}

/// Unit in the last place of `t` in f32 or f64 (the spacing above |t|; normal numbers).
pub fn ulp(t: f64, f32: bool) -> f64 {
    let t = t.abs().max(f64::MIN_POSITIVE);
    let e = t.log2().floor();
    // log2 can be off by one right at a power of two; correct it.
    let e = if 2f64.powf(e) > t { e - 1.0 } else { e };
    2f64.powf(e - if f32 { 23.0 } else { 52.0 })
}

/// Every kernel on every case of `family`: the oracle is analysed once per precision.
pub fn run_family(family: Family, rays: usize, kernels: &[Kernel]) -> Vec<Record> {
    let mut out = Vec::new();
    for case in cases(family, rays) {
        let mut cache: [Option<Analysis>; 2] = [None, None];
        for &k in kernels {
            let slot = usize::from(k.is_f32());
            let a = *cache[slot].get_or_insert_with(|| {
                let p = case.problem(dir_seen(k, case.dir));
                oracle::analyse(&p, case.tmin, f64::INFINITY, k.eps())
            });
            out.push(measure(&case, k, &a));
        }
    }
    out
}

// ---- summaries ----------------------------------------------------------------------------

/// One row of the stress table: a family × kernel.
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// The family.
    pub family: Family,
    /// The kernel.
    pub kernel: Kernel,
    /// Rays traced.
    pub rays: usize,
    /// Rays whose `t` or normal was NaN or infinite.
    pub nonfinite: usize,
    /// Rays with the wrong hit or miss, outside the tangency band.
    pub wrong: usize,
    /// Rays in the tangency band (hit/miss or branch undetermined at this precision).
    pub band: usize,
    /// Distance error `|Δt|/(ε t)` over rays out of the band where both hit.
    pub t_median: f64,
    /// p99 of the distance error.
    pub t_p99: f64,
    /// Largest distance error.
    pub t_max: f64,
    /// Largest distance error in ulps of the kernel's precision.
    pub ulps_max: f64,
    /// κ_t of the ray with the largest distance error.
    pub kappa_at_max: f64,
    /// Largest κ_t among the measured rays.
    pub kappa_max: f64,
    /// Largest `err_t / max(1, κ_t)` (the bound is 4).
    pub t_ratio_max: f64,
    /// Rays over the distance bound.
    pub viol_t: usize,
    /// Normal angle error (radians), p99 and max.
    pub n_p99: f64,
    /// Largest normal angle error (radians).
    pub n_max: f64,
    /// Largest `angle / (ε·max(1, t/r))` (the issue's bound is 16).
    pub n_units_max: f64,
    /// Rays over the normal bound.
    pub viol_n: usize,
    /// Largest deviation of the normal's length from 1.
    pub len_max: f64,
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}

/// Summaries per family × kernel, in the order met.
pub fn summarise(records: &[Record]) -> Vec<Summary> {
    let mut keys: Vec<(Family, Kernel)> = Vec::new();
    for r in records {
        if !keys.contains(&(r.case.family, r.kernel)) {
            keys.push((r.case.family, r.kernel));
        }
    }
    keys.into_iter()
        .map(|(family, kernel)| {
            let rs: Vec<&Record> = records
                .iter()
                .filter(|r| r.case.family == family && r.kernel == kernel)
                .collect();
            let measured: Vec<&&Record> = rs
                .iter()
                .filter(|r| !r.analysis.band() && r.err_t.is_finite())
                .collect();
            let mut ts: Vec<f64> = measured.iter().map(|r| r.err_t).collect();
            ts.sort_by(f64::total_cmp);
            let mut ns: Vec<f64> = measured.iter().map(|r| r.err_n).collect();
            ns.sort_by(f64::total_cmp);
            let worst = measured.iter().max_by(|a, b| a.err_t.total_cmp(&b.err_t));
            let fold =
                |f: &dyn Fn(&Record) -> f64| measured.iter().map(|r| f(r)).fold(0.0f64, f64::max);
            Summary {
                family,
                kernel,
                rays: rs.len(),
                nonfinite: rs.iter().filter(|r| r.nonfinite).count(),
                wrong: rs.iter().filter(|r| r.wrong).count(),
                band: rs.iter().filter(|r| r.analysis.band()).count(),
                t_median: quantile(&ts, 0.5),
                t_p99: quantile(&ts, 0.99),
                t_max: ts.last().copied().unwrap_or(f64::NAN),
                ulps_max: fold(&|r| r.err_ulps),
                kappa_at_max: worst.map_or(f64::NAN, |r| r.analysis.kappa_t),
                kappa_max: fold(&|r| r.analysis.kappa_t),
                t_ratio_max: fold(&|r| r.err_t / r.analysis.kappa_t.max(1.0)),
                viol_t: rs.iter().filter(|r| r.viol_t).count(),
                n_p99: quantile(&ns, 0.99),
                n_max: ns.last().copied().unwrap_or(f64::NAN),
                n_units_max: fold(&|r| r.err_n_units),
                viol_n: rs.iter().filter(|r| r.viol_n).count(),
                len_max: fold(&|r| r.len_err),
            }
        })
        .collect()
}

/// The table header matching [`Summary`]'s `Display`.
pub const TABLE_HEADER: &str = "family     kernel       rays  nan wrong band | dist err/eps: median      p99      max  max ulps  kappa@max max(err/k) viol | angle p99   angle max  max(a/eps.t/r) viol | ||n|-1| max";

fn g(x: f64) -> String {
    if x.is_nan() {
        "-".into()
    } else if x == 0.0 {
        "0".into()
    } else if (0.01..1e5).contains(&x.abs()) {
        format!("{x:.2}")
    } else {
        format!("{x:.1e}")
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:<10} {:<11} {:>5} {:>4} {:>5} {:>4} | {:>19} {:>8} {:>8} {:>9} {:>10} {:>10} {:>4} | {:>9} {:>11} {:>15} {:>4} | {:>9}",
            self.family.name(),
            self.kernel,
            self.rays,
            self.nonfinite,
            self.wrong,
            self.band,
            g(self.t_median),
            g(self.t_p99),
            g(self.t_max),
            g(self.ulps_max),
            g(self.kappa_at_max),
            g(self.t_ratio_max),
            self.viol_t,
            g(self.n_p99),
            g(self.n_max),
            g(self.n_units_max),
            self.viol_n,
            g(self.len_max),
        )
    }
}

/// The summaries as the README's Markdown table (header, alignment row, one row per
/// family and kernel); `cylaov stress --markdown` prints it and a test keeps the README
/// equal to it.
pub fn markdown_table(summaries: &[Summary]) -> String {
    let mut out = String::from(
        "| family | kernel | rays | NaN/inf | wrong hit/miss | band | dist err/ε median | p99 | max | max ulps | κ at max | max err/max(1,κ) | viol | normal p99 (rad) | normal max (rad) | max angle/(ε·max(1,t/r)) | viol | max \\|\\|n\\|−1\\| |\n\
         |---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n",
    );
    for s in summaries {
        let cells = [
            s.family.name().to_string(),
            s.kernel.to_string(),
            s.rays.to_string(),
            s.nonfinite.to_string(),
            s.wrong.to_string(),
            s.band.to_string(),
            g(s.t_median),
            g(s.t_p99),
            g(s.t_max),
            g(s.ulps_max),
            g(s.kappa_at_max),
            g(s.t_ratio_max),
            s.viol_t.to_string(),
            g(s.n_p99),
            g(s.n_max),
            g(s.n_units_max),
            s.viol_n.to_string(),
            g(s.len_max),
        ];
        out.push_str(&format!("| {} |\n", cells.join(" | ")));
    }
    out
}

/// One CSV row of `stress --csv`: a ray through one kernel, with the inputs to reproduce
/// it. Errors and parameters are written as `{:e}` (`7.55e2`: a column of magnitudes reads
/// at a glance), ray inputs as the shortest text that reads back to the same bits (`{:?}`).
#[derive(Serialize)]
pub struct CsvRow {
    family: &'static str,
    #[serde(serialize_with = "sci")]
    param: f64,
    kernel: String,
    caps: bool,
    oracle_hit: bool,
    kernel_hit: bool,
    band_hit: bool,
    band_branch: bool,
    #[serde(serialize_with = "sci")]
    t_oracle: f64,
    #[serde(serialize_with = "sci")]
    t_kernel: f64,
    #[serde(serialize_with = "sci")]
    err_t_eps: f64,
    #[serde(serialize_with = "sci")]
    err_ulps: f64,
    #[serde(serialize_with = "sci")]
    kappa_t: f64,
    #[serde(serialize_with = "sci")]
    err_n_rad: f64,
    #[serde(serialize_with = "sci")]
    err_n_units: f64,
    #[serde(serialize_with = "sci")]
    kappa_n: f64,
    #[serde(serialize_with = "sci")]
    len_err: f64,
    wrong: bool,
    viol_t: bool,
    viol_n: bool,
    #[serde(serialize_with = "exact")]
    origin_x: f64,
    #[serde(serialize_with = "exact")]
    origin_y: f64,
    #[serde(serialize_with = "exact")]
    origin_z: f64,
    #[serde(serialize_with = "exact")]
    dir_x: f64,
    #[serde(serialize_with = "exact")]
    dir_y: f64,
    #[serde(serialize_with = "exact")]
    dir_z: f64,
}

fn sci<S: serde::Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{x:e}"))
}

fn exact<S: serde::Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{x:?}"))
}

impl Record {
    /// This record as a row of `stress --csv`.
    pub fn csv_row(&self) -> CsvRow {
        let c = &self.case;
        CsvRow {
            family: c.family.name(),
            param: c.param,
            kernel: self.kernel.to_string(),
            caps: c.cyl.caps,
            oracle_hit: self.oracle.is_some(),
            kernel_hit: self.got.is_some(),
            band_hit: self.analysis.band_hit,
            band_branch: self.analysis.band_branch,
            t_oracle: self.oracle.map_or(f64::NAN, |h| h.t.to_f64()),
            t_kernel: self.got.map_or(f64::NAN, |h| h.t),
            err_t_eps: self.err_t,
            err_ulps: self.err_ulps,
            kappa_t: self.analysis.kappa_t,
            err_n_rad: self.err_n,
            err_n_units: self.err_n_units,
            kappa_n: self.analysis.kappa_n,
            len_err: self.len_err,
            wrong: self.wrong,
            viol_t: self.viol_t,
            viol_n: self.viol_n,
            origin_x: c.origin.x,
            origin_y: c.origin.y,
            origin_z: c.origin.z,
            dir_x: c.dir.x,
            dir_y: c.dir.y,
            dir_z: c.dir.z,
        }
    }
}
