//! Simulated rotating LiDAR: every beam of one rotation of a [`Sensor`] cast into the
//! scene, up to N exact returns per beam, with seeded range noise and dropout. Like a
//! render, a scan is a pure function of scene and options (no IO, no global state), and
//! the same on any number of threads.
//!
//! # Frames
//!
//! Points are in world coordinates (the scene's). The sensor's own axes: x forward, y
//! left, z up; its [`Pose`] (or the [`Trajectory`] at each beam's time) places them in the
//! world. A beam of elevation `el` fired at azimuth `az` leaves along `(cos el·cos az,
//! cos el·sin az, sin el)` in sensor axes: azimuth 0 along +x, increasing
//! counter-clockwise seen from above (+x toward +y), and the head turns that way, so
//! azimuth step `s` (of `S` a rotation at `f` Hz) fires at `time = s / S / f` seconds from
//! the rotation's start, every beam of the step at once. A beam's azimuth is
//! `s·360/S + its offset`, wrapped into `[0, 360)`.
//!
//! # Returns
//!
//! A beam's first return is the nearest surface with range in `[min_range, max_range]`;
//! each further return continues from the last one's surface point through
//! [`RayHit::spawn`] (pbrt-v4's offset past the point's error bound, on the side the beam
//! leaves by), so it never re-hits the surface it left and never skips the next wall: a
//! closed cylinder crossed gives 2 returns (in, out), an open tube entered through its
//! open end 1 (its inside wall: the beam leaves through that same wall), and several
//! surfaces in line give one return each. Every continued ray walks the one BVH
//! ([`AnyOrigin`]), never a loop over the cylinders. Range is the distance along the beam
//! from the sensor's origin.
//!
//! # Noise
//!
//! Each return `k` of beam (ring `b`, step `s`) draws from its own SplitMix64 stream,
//! [`SplitMix64::for_item`]`(seed, (s·beams + b)·16 + k)`: first the dropout (dropped
//! when a uniform draw is below `dropout`), then a standard normal (Marsaglia's polar
//! method) times `range_sigma` added to the range along the beam. So a point's noise
//! depends only on (seed, beam, step, return), not on threads or order. A noisy range
//! outside `[min_range, max_range]` is dropped too: the sensor reports what it measures.
//! `x, y, z` follow the noisy range; `range_exact` keeps the noiseless one. A beam's
//! surviving returns are sorted by their noisy ranges and numbered again from 1
//! (`return_index`), `num_returns` counting them: what the sensor would report.

pub mod pose;
pub mod sensor;

pub use pose::{Pose, Trajectory};
pub use sensor::{Sensor, SensorError};

use crate::render::cast::{AnyOrigin, RayHit};
use crate::rng::SplitMix64;
use crate::scene::Scene;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// Most returns per beam (LAS 1.4 counts returns in 4 bits).
pub const MAX_RETURNS: u32 = 15;

/// Where the sensor is during the rotation.
#[derive(Clone, Debug, PartialEq)]
pub enum Motion {
    /// One pose for the whole rotation.
    Fixed(Pose),
    /// Poses over time, interpolated at each step's time.
    Path(Trajectory),
}

impl Motion {
    /// The pose at time `t` (seconds from the rotation's start).
    pub fn at(&self, t: f64) -> Pose {
        match self {
            Motion::Fixed(p) => *p,
            Motion::Path(tr) => tr.at(t),
        }
    }
}

/// Range noise and dropout (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    /// Standard deviation of the Gaussian range noise, world units (0 = none).
    pub range_sigma: f64,
    /// Probability that a return is dropped, in `[0, 1]`.
    pub dropout: f64,
    /// Seed of every draw.
    pub seed: u64,
}

impl Noise {
    /// No noise, no dropout.
    pub const NONE: Noise = Noise {
        range_sigma: 0.0,
        dropout: 0.0,
        seed: 0,
    };
}

/// Everything a scan needs besides the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanOptions {
    /// The head.
    pub sensor: Sensor,
    /// Its pose or trajectory.
    pub motion: Motion,
    /// Most returns per beam, `1..=`[`MAX_RETURNS`].
    pub returns: u32,
    /// Range noise and dropout.
    pub noise: Noise,
}

impl ScanOptions {
    /// One return, fixed pose, no noise.
    pub fn new(sensor: Sensor, pose: Pose) -> Self {
        ScanOptions {
            sensor,
            motion: Motion::Fixed(pose),
            returns: 1,
            noise: Noise::NONE,
        }
    }

    /// Check the numbers a user gives (the sensor is valid by construction); errors name
    /// the option as the front end spells it ([`crate::spelling`]).
    pub fn validate(&self) -> Result<(), String> {
        use crate::spelling::opt;
        if !(1..=MAX_RETURNS).contains(&self.returns) {
            return Err(format!(
                "{}: must be in 1..={MAX_RETURNS}, got {}",
                opt("returns"),
                self.returns
            ));
        }
        let s = self.noise.range_sigma;
        if !(s >= 0.0 && s.is_finite()) {
            return Err(format!(
                "{}: must be finite and >= 0, got {s}",
                opt("range_noise")
            ));
        }
        let p = self.noise.dropout;
        if !(0.0..=1.0).contains(&p) {
            return Err(format!("{}: must be in [0, 1], got {p}", opt("dropout")));
        }
        Ok(())
    }

    /// The most points a scan can give: every beam of every step with every return.
    pub fn most_points(&self) -> u64 {
        (self.sensor.beams() as u64)
            .saturating_mul(u64::from(self.sensor.steps_per_rotation))
            .saturating_mul(u64::from(self.returns))
    }

    /// The most memory a scan holds at its peak, for its caller to check before it starts
    /// (the scan allocates as it goes and assumes that check made): each step's own scan,
    /// then their points appended into one (its columns growing to twice the points at
    /// most), which the caller copies once (into a point file's bytes, no more than
    /// [`POINT_BYTES`] a point, or into arrays). Three copies of [`Self::most_points`].
    pub fn memory(&self) -> u64 {
        self.most_points()
            .saturating_mul(3 * POINT_BYTES)
            .saturating_add(u64::from(self.sensor.steps_per_rotation) * STEP_BYTES)
    }
}

/// Bytes a point takes in a [`Scan`]'s columns: eight float64, six uint32 and a normal of
/// three float32.
pub const POINT_BYTES: u64 = 8 * 8 + 6 * 4 + 3 * 4;

/// Bytes an azimuth step's own [`Scan`] takes besides its points: fifteen columns, each a
/// vector and its allocation.
const STEP_BYTES: u64 = 15 * (24 + 32);

/// The points of a scan, one entry per point in every column, ordered by azimuth step,
/// then ring, then return.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scan {
    /// World x of the point (on the beam at `range`).
    pub x: Vec<f64>,
    /// World y.
    pub y: Vec<f64>,
    /// World z.
    pub z: Vec<f64>,
    /// Distance along the beam from the sensor's origin, noise included.
    pub range: Vec<f64>,
    /// The same without noise: the exact surface's distance.
    pub range_exact: Vec<f64>,
    /// Beam index sorted by elevation (0 = lowest).
    pub ring: Vec<u32>,
    /// Azimuth in sensor axes, degrees in `[0, 360)`, counter-clockwise from +x.
    pub azimuth: Vec<f64>,
    /// Beam elevation in sensor axes, degrees.
    pub elevation: Vec<f64>,
    /// Seconds from the rotation's start.
    pub time: Vec<f64>,
    /// 1-based among the beam's reported returns.
    pub return_index: Vec<u32>,
    /// Returns the beam reported.
    pub num_returns: Vec<u32>,
    /// The hit cylinder's id.
    pub shape_id: Vec<u32>,
    /// The part hit (the `part` AOV's codes: 1 side outside, 2 side inside, 3 bottom cap,
    /// 4 top cap).
    pub part: Vec<u32>,
    /// The hit cylinder's label.
    pub label: Vec<u32>,
    /// World unit outward normal of the surface hit.
    pub normal: Vec<[f32; 3]>,
}

/// One column of a [`Scan`], for writers that go field by field.
#[derive(Clone, Copy, Debug)]
pub enum Column<'a> {
    /// Float64 values.
    F64(&'a [f64]),
    /// Uint32 values.
    U32(&'a [u32]),
    /// Three float32 per point.
    F32x3(&'a [[f32; 3]]),
}

impl Scan {
    /// Points.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// No points.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Every column by name, in a fixed order: what NPZ and the Python dict hold.
    pub fn columns(&self) -> Vec<(&'static str, Column<'_>)> {
        use Column::*;
        vec![
            ("x", F64(&self.x)),
            ("y", F64(&self.y)),
            ("z", F64(&self.z)),
            ("range", F64(&self.range)),
            ("range_exact", F64(&self.range_exact)),
            ("ring", U32(&self.ring)),
            ("azimuth", F64(&self.azimuth)),
            ("elevation", F64(&self.elevation)),
            ("time", F64(&self.time)),
            ("return_index", U32(&self.return_index)),
            ("num_returns", U32(&self.num_returns)),
            ("shape_id", U32(&self.shape_id)),
            ("part", U32(&self.part)),
            ("label", U32(&self.label)),
            ("normal", F32x3(&self.normal)),
        ]
    }
}

/// One surface along a beam, before noise.
#[derive(Clone, Copy, Debug)]
struct Return {
    range: f64,
    hit: RayHit,
}

/// Scan `scene` (see the module doc).
pub fn scan(scene: &Scene, opts: &ScanOptions) -> Result<Scan, String> {
    let never = AtomicBool::new(false);
    Ok(scan_until(scene, opts, &never)?.unwrap_or_default())
}

/// [`scan`], given up once `stop` is set (the result is then `None`).
pub fn scan_until(
    scene: &Scene,
    opts: &ScanOptions,
    stop: &AtomicBool,
) -> Result<Option<Scan>, String> {
    opts.validate()?;
    let walker = AnyOrigin::new(scene);
    let sensor = &opts.sensor;
    let steps = sensor.steps_per_rotation;
    // Per step, every ring's points: one rayon task per step, concatenated in step order.
    let per_step: Vec<Scan> = (0..steps)
        .into_par_iter()
        .map(|s| {
            let mut out = Scan::default();
            if stop.load(Ordering::Relaxed) {
                return out;
            }
            step(scene, &walker, opts, s, &mut out);
            out
        })
        .collect();
    if stop.load(Ordering::Relaxed) {
        return Ok(None);
    }
    let mut all = Scan::default();
    for p in per_step {
        append(&mut all, p);
    }
    Ok(Some(all))
}

fn append(all: &mut Scan, mut p: Scan) {
    all.x.append(&mut p.x);
    all.y.append(&mut p.y);
    all.z.append(&mut p.z);
    all.range.append(&mut p.range);
    all.range_exact.append(&mut p.range_exact);
    all.ring.append(&mut p.ring);
    all.azimuth.append(&mut p.azimuth);
    all.elevation.append(&mut p.elevation);
    all.time.append(&mut p.time);
    all.return_index.append(&mut p.return_index);
    all.num_returns.append(&mut p.num_returns);
    all.shape_id.append(&mut p.shape_id);
    all.part.append(&mut p.part);
    all.label.append(&mut p.label);
    all.normal.append(&mut p.normal);
}

/// The beam direction in sensor axes for elevation and azimuth in degrees (a unit vector
/// to a few ulp: cos²·(cos² + sin²) + sin²).
pub fn beam_dir(elevation_deg: f64, azimuth_deg: f64) -> DVec3 {
    let (se, ce) = elevation_deg.to_radians().sin_cos();
    let (sa, ca) = azimuth_deg.to_radians().sin_cos();
    DVec3::new(ce * ca, ce * sa, se)
}

/// Every ring of azimuth step `s`, appended to `out`.
fn step(scene: &Scene, walker: &AnyOrigin, opts: &ScanOptions, s: u32, out: &mut Scan) {
    let sensor = &opts.sensor;
    let time = s as f64 * sensor.step_seconds();
    let pose = opts.motion.at(time);
    let head = s as f64 * 360.0 / sensor.steps_per_rotation as f64;
    let mut found: Vec<Return> = Vec::with_capacity(opts.returns as usize);
    let mut kept: Vec<(f64, Return)> = Vec::with_capacity(opts.returns as usize);
    for ring in 0..sensor.beams() {
        let elevation = sensor.elevations_deg[ring];
        let azimuth = wrap_degrees(head + sensor.azimuth_offsets_deg[ring]);
        // The rotation keeps the unit length to a few ulp; normalised again so `t` is a
        // distance to the last bit the kernels assume.
        let dir = (pose.rotation * beam_dir(elevation, azimuth)).normalize();
        trace_beam(walker, pose.position, dir, sensor, opts.returns, &mut found);
        // Noise and dropout, one stream per (step, ring, return).
        kept.clear();
        let beam = s as u64 * sensor.beams() as u64 + ring as u64;
        for (k, r) in found.iter().enumerate() {
            let mut rng = SplitMix64::for_item(opts.noise.seed, beam * 16 + k as u64);
            let dropped = rng.unit() < opts.noise.dropout;
            let g = standard_normal(&mut rng);
            let range = r.range + opts.noise.range_sigma * g;
            // The sensor reports what it measures: a noisy range outside its window is
            // no return, and returns are numbered in the order of their measured ranges.
            if !dropped && (sensor.min_range..=sensor.max_range).contains(&range) {
                kept.push((range, *r));
            }
        }
        kept.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (i, &(range, r)) in kept.iter().enumerate() {
            let p = pose.position + dir * range;
            let cyl = &scene.cylinders[r.hit.index as usize];
            out.x.push(p.x);
            out.y.push(p.y);
            out.z.push(p.z);
            out.range.push(range);
            out.range_exact.push(r.range);
            out.ring.push(ring as u32);
            out.azimuth.push(azimuth);
            out.elevation.push(elevation);
            out.time.push(time);
            out.return_index.push(i as u32 + 1);
            out.num_returns.push(kept.len() as u32);
            out.shape_id.push(cyl.id);
            out.part.push(r.hit.part);
            out.label.push(cyl.label);
            out.normal.push(r.hit.normal.as_vec3().to_array());
        }
    }
}

/// `degrees` wrapped into `[0, 360)`: `rem_euclid` of a tiny negative angle rounds up to
/// 360 itself (`-1e-20 + 360`), which is 0.
fn wrap_degrees(degrees: f64) -> f64 {
    let a = degrees.rem_euclid(360.0);
    if a < 360.0 { a } else { 0.0 }
}

/// Up to `returns` surfaces along the beam `origin + t·dir` (unit `dir`) with range in
/// `[min_range, max_range]`, nearest first, into `found`.
fn trace_beam(
    walker: &AnyOrigin,
    origin: DVec3,
    dir: DVec3,
    sensor: &Sensor,
    returns: u32,
    found: &mut Vec<Return>,
) {
    found.clear();
    let mut from = origin;
    let mut t_min = sensor.min_range;
    while found.len() < returns as usize {
        // Where `from` lies along the beam: 0 for the sensor, else the spawned origin's
        // projection (it is off the beam's line by the offset only, ~1e-15 relative).
        let along = (from - origin).dot(dir);
        let t_max = sensor.max_range - along;
        if t_max < t_min {
            break;
        }
        let Some(hit) = walker.nearest(from, dir, t_min, t_max) else {
            break;
        };
        let range = if found.is_empty() {
            hit.t
        } else {
            along_beam(origin, dir, from, along, &hit).unwrap_or(along + hit.t)
        };
        if range > sensor.max_range {
            break;
        }
        found.push(Return { range, hit });
        from = hit.spawn(dir);
        t_min = 0.0;
    }
}

/// The range at which the beam `origin + s·dir` itself meets the surface `hit` found by
/// a continued ray from `from` (`along` the beam from `origin`), `None` where that cannot
/// be trusted.
///
/// Why: `from` lies off the beam's line by the spawn offset (the previous hit's error
/// bound, tens of ulps of its coordinates), so `along + hit.t` is the range of a parallel
/// line, off by that offset over the cosine of the incidence: 1e-9 relative at a scene
/// 1e6 from the world origin. The beam meets the plane tangent at `hit.position` (on the
/// surface within a few ulps) at `s = (p - origin)·n / (dir·n)`; the plane departs from
/// the surface by the offset squared over the radius between the two lines, far below
/// one ulp. Kept only where it moves the range by no more than the offset can explain
/// (`d / |dir·n|` for the lines' distance `d`, with 2× and a few ulps of slack): a
/// tangent beam (`dir·n` near 0) keeps the parallel line's range.
fn along_beam(origin: DVec3, dir: DVec3, from: DVec3, along: f64, hit: &RayHit) -> Option<f64> {
    let parallel = along + hit.t;
    let cos = dir.dot(hit.normal);
    let s = (hit.position - origin).dot(hit.normal) / cos;
    let apart = ((from - origin) - along * dir).length();
    let explained = 2.0 * apart / cos.abs() + 4.0 * f64::EPSILON * parallel.abs();
    (s.is_finite() && (s - parallel).abs() <= explained).then_some(s)
}

/// A standard normal draw by Marsaglia's polar method (only `+ - * /`, `ln` and `sqrt`).
fn standard_normal(rng: &mut SplitMix64) -> f64 {
    loop {
        let u = 2.0 * rng.unit() - 1.0;
        let v = 2.0 * rng.unit() - 1.0;
        let s = u * u + v * v;
        if s > 0.0 && s < 1.0 {
            return u * (-2.0 * s.ln() / s).sqrt();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn azimuths_wrap_into_0_360() {
        assert_eq!(wrap_degrees(-1e-20), 0.0);
        assert_eq!(wrap_degrees(-90.0), 270.0);
        assert_eq!(wrap_degrees(360.0), 0.0);
        assert_eq!(wrap_degrees(359.5 + 180.0), 179.5);
    }

    #[test]
    fn normal_draws_have_unit_variance() {
        let mut rng = SplitMix64::new(3);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| standard_normal(&mut rng)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        // Standard errors: mean 1/sqrt(n) = 0.0022, variance sqrt(2/n) = 0.0032; 5 of each.
        assert!(mean.abs() < 0.011, "{mean}");
        assert!((var - 1.0).abs() < 0.016, "{var}");
    }
}
