//! Screen-space binning of cylinders for primary rays: the fast path of `render`.
//!
//! Every primary ray leaves the one camera origin, so a cylinder can only be hit by the
//! pixels inside the projection of a bound of it. Each cylinder is projected once (see
//! [`project`]: the boxes of its end disks, or its oriented box clipped at the near plane
//! when it reaches nearer) to a pixel rectangle, a band around its projected axis and a
//! nearest camera-space z; it is listed in every screen tile that rectangle and band
//! reach, sorted by that z. `render` then walks a tile's candidates nearest first, each
//! over just the pixels it can cover, like a rasteriser with a depth test: a pixel whose
//! best hit is nearer than the candidate's nearest z is skipped (`t ≥ z` for any point,
//! so it cannot be improved).
//!
//! The rectangle of a long, thin, slanted cylinder is mostly empty, so each row of it is
//! also cut to the band around the projected axis that holds the projected capsule: the cylinder lies within `r` of its axis
//! segment, and a point within `r` of a point `c` projects within
//! `f·r·sqrt(1 + tx² + ty²) / (z - r)` pixels of `c`'s projection (`f` focal length in
//! pixels, `tx = x/z`, `ty = y/z`: the norm of the projection's Jacobian, bounded exactly
//! for the finite step since `z` falls by at most `r`). Along the segment `tx`, `ty` are
//! monotone and `z` linear, so their worst values are at its ends.

use crate::geometry::{Cylinder, cylinder::orthonormal_basis};
use crate::scene::camera::Camera;
use glam::DVec3;
use rayon::prelude::*;

/// Tile side in pixels.
pub const TILE: u32 = 16;

/// Average candidates per tile above which `render` walks the BVH tile by tile instead
/// (the lists would be long and cost memory, and most of a crowded list is hidden behind
/// its first few cylinders, which the walk's occlusion culling never visits).
pub const CROWDED: usize = 64;

/// A candidate in a tile: cylinder index, inclusive pixel rectangle, lower bound on `t`.
#[derive(Clone, Copy, Debug)]
pub struct Candidate {
    /// The cylinder's index in the scene.
    pub index: u32,
    /// Where the renderer keeps this cylinder's prepared form (see [`Tiles::assign_slots`]).
    pub slot: u32,
    /// First pixel column the candidate may cover.
    pub x0: u32,
    /// First pixel row it may cover.
    pub y0: u32,
    /// Last pixel column (inclusive).
    pub x1: u32,
    /// Last pixel row (inclusive).
    pub y1: u32,
    /// No hit on this cylinder has a ray parameter below this.
    pub t_min: f64,
    /// The band around the projected axis that holds the projected capsule, per row:
    /// row `j`'s visible pixel centres `x + 0.5` lie within `half` of
    /// `centre + slope·j + 0.5`, i.e. columns in `[centre + slope·j ± half]`. `half` is
    /// infinite when the bound does not apply (the rectangle alone bounds the cylinder).
    pub centre: f64,
    /// Columns the band's centre moves per row.
    pub slope: f64,
    /// Half width of the band, in pixels (infinite: no band).
    pub half: f64,
}

/// The whole columns in `[lo, hi]` ∩ `[x0, x1]`, if any. `max`/`min` against the finite
/// `x0`, `x1` keep the bounds finite (an infinite band keeps `[x0, x1]`), and they lie in
/// `[0, 2^14]`: truncation is floor, and ceil is one compare away (no libm).
#[inline(always)]
fn columns(lo: f64, hi: f64, x0: u32, x1: u32) -> Option<(u32, u32)> {
    let (u, v) = (lo.max(x0 as f64), hi.min(x1 as f64));
    if u > v {
        return None;
    }
    let (a, b) = (u as u32, v as u32);
    let a = a + ((a as f64) < u) as u32;
    (a <= b).then_some((a, b))
}

impl Candidate {
    /// Whether the cylinder lies wholly outside the view (an empty rectangle).
    #[inline(always)]
    pub fn is_culled(&self) -> bool {
        self.x0 > self.x1
    }

    /// The columns of row `j` that can see the cylinder, as an inclusive range within
    /// `[lo, hi]`: the rectangle, cut to the band around the projected axis (the band
    /// holds the capsule, the rectangle its ends). Two multiply-adds, no division: this
    /// runs for every candidate on every row of its tiles.
    #[inline(always)]
    pub fn row_span(&self, j: u32, lo: u32, hi: u32) -> Option<(u32, u32)> {
        let c = self.line(j);
        columns(
            c - self.half,
            c + self.half,
            self.x0.max(lo),
            self.x1.min(hi),
        )
    }

    /// The band's centre column on row `j`. Rounding is monotone, so for `j0 <= j <= j1`
    /// the computed value lies between those of `j0` and `j1`: binning relies on it.
    #[inline(always)]
    fn line(&self, j: u32) -> f64 {
        self.centre + self.slope * j as f64
    }

    /// The tile columns `row_span` can reach on any row `j0..=j1` (within `y0..=y1`): the
    /// band's extreme columns over those rows are at `j0` or `j1` (the line is linear and
    /// its rounding monotone), cut to the rectangle, as in `row_span`.
    #[inline]
    fn tile_columns(&self, j0: u32, j1: u32) -> Option<(u32, u32)> {
        let (c0, c1) = (self.line(j0), self.line(j1));
        let (lo, hi) = (c0.min(c1) - self.half, c0.max(c1) + self.half);
        columns(lo, hi, self.x0, self.x1).map(|(a, b)| (a / TILE, b / TILE))
    }

    /// Call `f(ty, tx0, tx1)` for each tile row the candidate reaches, with the tile
    /// columns its band reaches there.
    #[inline]
    fn for_tile_rows(&self, mut f: impl FnMut(u32, u32, u32)) {
        for ty in self.y0 / TILE..=self.y1 / TILE {
            let j0 = (ty * TILE).max(self.y0);
            let j1 = (ty * TILE + TILE - 1).min(self.y1);
            if let Some((a, b)) = self.tile_columns(j0, j1) {
                f(ty, a, b);
            }
        }
    }

    /// How many tile lists the candidate goes in.
    fn tile_entries(&self) -> usize {
        let mut n = 0;
        self.for_tile_rows(|_, a, b| n += (b - a + 1) as usize);
        n
    }
}

const EMPTY: Candidate = Candidate {
    index: 0,
    slot: 0,
    x0: 0,
    y0: 0,
    x1: 0,
    y1: 0,
    t_min: 0.0,
    centre: 0.0,
    slope: 0.0,
    half: f64::INFINITY,
};

/// The slot of a culled cylinder while binning: an empty rectangle.
const CULLED: Candidate = Candidate {
    x0: 1,
    x1: 0,
    ..EMPTY
};

/// Candidates per tile, stored per tile row (CSR within the row): tile `(tx, ty)` owns
/// `rows[ty][start[ty·(tiles_x + 1) + tx]..start[ty·(tiles_x + 1) + tx + 1]]`.
#[derive(Clone, Debug)]
pub struct Tiles {
    /// Tiles across the image (the last may be partial).
    pub tiles_x: u32,
    /// Tiles down the image.
    pub tiles_y: u32,
    start: Vec<u32>,
    rows: Vec<Vec<Candidate>>,
}

/// A candidate's visit to one tile row while binning: its sort key (`t_min` in total
/// order, then its position in the candidates, which is index order) and the tile
/// columns its band reaches there.
#[derive(Clone, Copy)]
struct Visit {
    key: u64,
    pos: u32,
    tx0: u16,
    tx1: u16,
}

/// `f64::total_cmp` order as an unsigned key.
fn order_key(x: f64) -> u64 {
    let b = x.to_bits();
    if b >> 63 == 1 { !b } else { b | 1 << 63 }
}

/// What [`project`] needs of the camera, derived once per build.
struct View {
    origin: DVec3,
    /// Camera axes: x right, y up, z forward.
    right: DVec3,
    up: DVec3,
    forward: DVec3,
    /// Focal lengths in pixels, their maximum, and the principal point `(W/2, H/2)`.
    fx: f64,
    fy: f64,
    f: f64,
    cx: f64,
    cy: f64,
    width: u32,
    height: u32,
    near: f64,
    far: f64,
    /// A hair nearer than the near plane: nothing nearer can be hit.
    zc: f64,
}

impl View {
    fn new(cam: &Camera) -> View {
        let (fx, fy) = cam.focal_px();
        View {
            origin: cam.origin,
            right: -cam.left,
            up: cam.true_up,
            forward: cam.forward,
            fx,
            fy,
            f: fx.max(fy),
            cx: cam.width() as f64 / 2.0,
            cy: cam.height() as f64 / 2.0,
            width: cam.width(),
            height: cam.height(),
            near: cam.spec.near_clip,
            far: cam.spec.far_clip,
            zc: cam.spec.near_clip * (1.0 - 1e-6),
        }
    }

    /// World vector `p` in camera axes.
    #[inline(always)]
    fn camera(&self, p: DVec3) -> DVec3 {
        DVec3::new(p.dot(self.right), p.dot(self.up), p.dot(self.forward))
    }
}

/// The pixel rectangle, nearest z and axis band of a cylinder (see [`Candidate`]), or
/// `None` when it lies wholly outside the view or the clip range.
///
/// Bounds: each end disk (radius `r`, unit normal `a` in camera axes) lies in the box
/// reaching `r·sqrt(1 - a_k²)` from its centre along camera axis `k`, and the cylinder is
/// the convex hull of its two disks. So its camera z lies within the two boxes' z range,
/// and when that is all in front of the near plane its projection is the hull of the
/// disks' projections, within the union of the two boxes' projected rectangles (2
/// reciprocals each: `x/z` over a box is extreme at its corners). A cylinder reaching
/// nearer than the near plane instead gets the part of its oriented box (axis × 2r × 2r)
/// in front of the plane projected: the corners there, and where the 12 edges cross it.
pub fn project(cam: &Camera, cyl: &Cylinder) -> Option<Candidate> {
    project_in(&View::new(cam), cyl)
}

fn project_in(view: &View, cyl: &Cylinder) -> Option<Candidate> {
    let (w, h) = (view.width, view.height);
    let r = cyl.radius;
    let b = view.camera(cyl.base - view.origin);
    let a = view.camera(cyl.axis);
    let t = b + a * cyl.height;
    let a2 = a * a;
    let ext = DVec3::new(
        (a2.y + a2.z).sqrt(),
        (a2.x + a2.z).sqrt(),
        (a2.x + a2.y).sqrt(),
    ) * r;
    let (zmin, zmax) = (b.z.min(t.z) - ext.z, b.z.max(t.z) + ext.z);
    // Pad for rounding in the bounds (relative 1e-9 of their size) and the projection.
    let pad = 1e-9 * (b.length_squared().max(t.length_squared()).sqrt() + r) + 1e-12;
    if zmax + pad < view.near || zmin - pad > view.far {
        return None;
    }
    let t_min = (zmin - pad).max(view.near * (1.0 - 1e-12));
    // The rectangle in image-plane units (x/z, y/z).
    let (xmin, xmax, ymin, ymax) = if zmin >= view.zc {
        rect_in_front(b, t, ext)
    } else {
        rect_of_clipped_box(view, cyl, b, t)
    };
    // Continuous pixel coordinates: pixel i spans [i, i + 1], centre i + 0.5.
    let (xmin, xmax) = (xmin * view.fx + view.cx, xmax * view.fx + view.cx);
    let (ymin, ymax) = (view.cy - ymax * view.fy, view.cy - ymin * view.fy);
    if !(xmin.is_finite() && xmax.is_finite() && ymin.is_finite() && ymax.is_finite()) {
        // Degenerate projection (should not happen past the checks above): whole screen.
        return Some(Candidate {
            x1: w - 1,
            y1: h - 1,
            t_min,
            ..EMPTY
        });
    }
    let (centre, slope, half, rows) = axis_band(view, b, t, r);
    // Pixel i is covered when its centre i + 0.5 lies in [min, max]; one pixel of slack.
    let x0 = ceil_in(xmin - 0.5, w) - 1;
    let x1 = floor_in(xmax - 0.5, w) + 1;
    let y0 = (ceil_in(ymin - 0.5, h) - 1).max(ceil_in(rows.0, h));
    let y1 = (floor_in(ymax - 0.5, h) + 1).min(floor_in(rows.1, h));
    if x1 < 0 || y1 < 0 || x0 > w as i64 - 1 || y0 > h as i64 - 1 || y0 > y1 {
        return None;
    }
    let clamp = |a: i64, n: u32| a.clamp(0, n as i64 - 1) as u32;
    Some(Candidate {
        index: 0,
        slot: 0,
        x0: clamp(x0, w),
        y0: clamp(y0, h),
        x1: clamp(x1, w),
        y1: clamp(y1, h),
        t_min,
        centre,
        slope,
        half,
    })
}

/// The image-plane rectangle (x/z, y/z bounds) of a cylinder wholly in front of the near
/// plane: the union of its two end boxes' projections (`x/z` over a box is extreme at its
/// corners, so 2 reciprocals each).
fn rect_in_front(b: DVec3, t: DVec3, ext: DVec3) -> (f64, f64, f64, f64) {
    let (mut xmin, mut xmax, mut ymin, mut ymax) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in [b, t] {
        let (i0, i1) = (1.0 / (p.z - ext.z), 1.0 / (p.z + ext.z));
        let (xl, xh, yl, yh) = (p.x - ext.x, p.x + ext.x, p.y - ext.y, p.y + ext.y);
        xmin = xmin.min((xl * i0).min(xl * i1));
        xmax = xmax.max((xh * i0).max(xh * i1));
        ymin = ymin.min((yl * i0).min(yl * i1));
        ymax = ymax.max((yh * i0).max(yh * i1));
    }
    (xmin, xmax, ymin, ymax)
}

/// The image-plane rectangle of a cylinder that reaches nearer than the near plane (or has a
/// NaN bound): its oriented box (axis × 2r × 2r) clipped at the plane `z = zc`, from the
/// corners in front and the points where the 12 edges cross the plane.
fn rect_of_clipped_box(view: &View, cyl: &Cylinder, b: DVec3, t: DVec3) -> (f64, f64, f64, f64) {
    let r = cyl.radius;
    let (mut xmin, mut xmax, mut ymin, mut ymax) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    let (u, v) = orthonormal_basis(cyl.axis);
    let (u, v) = (view.camera(u) * r, view.camera(v) * r);
    // Bit 2 picks the end, bits 1 and 0 the sign along u and v.
    let corners: [DVec3; 8] = std::array::from_fn(|k| {
        let end = if k & 4 == 0 { b } else { t };
        let su = if k & 2 == 0 { -u } else { u };
        let sv = if k & 1 == 0 { -v } else { v };
        end + su + sv
    });
    let zc = view.zc;
    let mut add = |x: f64, y: f64, z: f64| {
        let iz = 1.0 / z;
        xmin = xmin.min(x * iz);
        xmax = xmax.max(x * iz);
        ymin = ymin.min(y * iz);
        ymax = ymax.max(y * iz);
    };
    for (k, c) in corners.iter().enumerate() {
        if c.z >= zc {
            add(c.x, c.y, c.z);
        }
        for bit in [1, 2, 4] {
            let o = &corners[k | bit];
            if k & bit == 0 && (c.z < zc) != (o.z < zc) {
                let s = (zc - c.z) / (o.z - c.z);
                add(c.x + s * (o.x - c.x), c.y + s * (o.y - c.y), zc);
            }
        }
    }
    (xmin, xmax, ymin, ymax)
}

/// The capsule around the projected axis (see the module doc), with 1.5 px of slack:
/// `(centre, slope, half, rows)` of [`Candidate`], or `half = ∞` and unbounded `rows` where
/// the bound does not apply. The band is `|n·(p - pa)| <= rad` around the axis line through
/// `pa` along `e`, with unit normal `n = (-e_y, e_x)/len`. For a pixel centre
/// p = (x + 0.5, j + 0.5) it is the column interval
/// `x + 0.5 = pa_x + (e_x/e_y)(j + 0.5 - pa_y) ± rad·len/|e_y|`; a line within 1e-9 of
/// horizontal bounds rows instead (the columns term is then < 2e-5 px, inside the slack),
/// so it trims `y0..y1` and leaves the columns to the rectangle. A point-like projection
/// (view along the axis) has no line: the rectangle bounds it.
fn axis_band(view: &View, b: DVec3, t: DVec3, r: f64) -> (f64, f64, f64, (f64, f64)) {
    let (mut centre, mut slope, mut half) = (0.0, 0.0, f64::INFINITY);
    let mut rows = (f64::NEG_INFINITY, f64::INFINITY);
    let z_axis = b.z.min(t.z);
    if z_axis - r > 0.0 {
        let (ib, it) = (1.0 / b.z, 1.0 / t.z);
        let (txb, tyb, txt, tyt) = (b.x * ib, b.y * ib, t.x * it, t.y * it);
        let slope2 = (txb * txb).max(txt * txt) + (tyb * tyb).max(tyt * tyt);
        let pa = [txb * view.fx + view.cx, view.cy - tyb * view.fy];
        let pb = [txt * view.fx + view.cx, view.cy - tyt * view.fy];
        let far_off = pa[0]
            .abs()
            .max(pa[1].abs())
            .max(pb[0].abs().max(pb[1].abs()))
            > 1e7;
        let e = [pb[0] - pa[0], pb[1] - pa[1]];
        let len = (e[0] * e[0] + e[1] * e[1]).sqrt();
        let rad = view.f * r * (1.0 + slope2).sqrt() / (z_axis - r) + 1.5;
        if !far_off && rad.is_finite() && len >= 1e-9 {
            if e[1].abs() > 1e-9 * len {
                let ie = 1.0 / e[1];
                slope = e[0] * ie;
                centre = pa[0] - 0.5 + slope * (0.5 - pa[1]);
                half = rad * len * ie.abs();
            } else {
                let reach = rad * len / e[0].abs();
                rows = (pa[1] - reach - 0.5, pa[1] + reach - 0.5);
            }
        }
    }
    (centre, slope, half, rows)
}

/// `ceil(a)` for `a` in `[-4, n + 4]`, and a value beyond that range (same side) for
/// `a` outside it (±inf included): pixel bounds only compare with `[0, n - 1]`. No libm.
#[inline(always)]
fn ceil_in(a: f64, n: u32) -> i64 {
    let a = a.clamp(-4.0, n as f64 + 4.0);
    let t = a as i64;
    t + ((t as f64) < a) as i64
}

/// `floor(a)`, as [`ceil_in`].
#[inline(always)]
fn floor_in(a: f64, n: u32) -> i64 {
    let a = a.clamp(-4.0, n as f64 + 4.0);
    let t = a as i64;
    t - ((t as f64) > a) as i64
}

/// [`project`] for one camera, its set-up done once: for projecting cylinders as a
/// walk meets them, when there are far fewer pixels than cylinders.
pub struct Projector(View);

impl Projector {
    /// The projection set-up of camera `cam`.
    pub fn new(cam: &Camera) -> Self {
        Projector(View::new(cam))
    }

    /// The candidate of `cyl` (scene index `index`, kept in `slot`); an empty rectangle
    /// when it is culled ([`Candidate::is_culled`]).
    #[inline]
    pub fn project(&self, cyl: &Cylinder, index: u32, slot: u32) -> Candidate {
        let c = project_in(&self.0, cyl).unwrap_or(CULLED);
        Candidate { index, slot, ..c }
    }
}

/// The projections of `cylinders[order[s]]` in slot `s` (index and slot set), for walking a
/// hierarchy tile by tile instead of binning: a culled cylinder gets an empty rectangle
/// ([`Candidate::is_culled`]).
pub fn project_slots(cam: &Camera, cylinders: &[Cylinder], order: &[u32]) -> Vec<Candidate> {
    let view = View::new(cam);
    order
        .par_iter()
        .enumerate()
        .map(|(s, &i)| {
            let c = project_in(&view, &cylinders[i as usize]).unwrap_or(CULLED);
            Candidate {
                index: i,
                slot: s as u32,
                ..c
            }
        })
        .collect()
}

/// Whether the candidates' tile entries ([`Candidate::tile_entries`]) add up to more than
/// `limit`: summed in chunks on every thread, into a running total that stops the count
/// once it passes the limit. The terms are not negative, so the answer is the whole sum's,
/// whichever chunks were counted: a crowded view stops after a fraction of its candidates
/// (dense 100 000 at 1920×1080 has 2.1 million entries against a limit of 522 240, so
/// after about a quarter).
fn entries_exceed(cands: &[Candidate], limit: usize) -> bool {
    let total = std::sync::atomic::AtomicUsize::new(0);
    cands.par_chunks(4096).any(|part| {
        let n: usize = part.iter().map(Candidate::tile_entries).sum();
        total.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n > limit
    })
}

/// The candidates that reach the image's one tile, ordered by (`t_min`, index) as the
/// general binning orders a tile's list, in a bucket sort on every thread: the sort of a
/// tiny view's 100 000 candidates was most of its binning, and a comparison sort splits
/// its first passes poorly over the threads.
///
/// Buckets are runs of the `t_min` keys' range (a key's high bits past the range's low
/// end, about 32 candidates a bucket). Each chunk of candidates counts its own per bucket;
/// the counts place every (bucket, chunk) pair in the list, bucket-major, so each chunk
/// writes its candidates, in order, to slices no other chunk holds. Then each bucket is
/// sorted on its own. The list does not depend on the chunking: a bucket's members and
/// their final order are the key's.
fn nearest_first(cands: &[Candidate]) -> Vec<Candidate> {
    let key = |c: &Candidate| order_key(c.t_min);
    // Whether each candidate reaches the tile, found once (the later passes read it).
    let reaches: Vec<bool> = cands.par_iter().map(|c| c.tile_entries() > 0).collect();
    let Some((lo, hi)) = cands
        .par_iter()
        .zip(&reaches)
        .filter(|(_, r)| **r)
        .map(|(c, _)| (key(c), key(c)))
        .reduce_with(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    else {
        return Vec::new();
    };
    // The fewest high bits of `key - lo` that leave at most `buckets` values.
    let buckets = (cands.len() / 32).next_power_of_two();
    let bits = u64::BITS - (hi - lo).leading_zeros();
    let shift = bits.saturating_sub(buckets.trailing_zeros());
    let bucket = |k: u64| (k - lo).checked_shr(shift).unwrap_or(0) as usize;
    let nb = bucket(hi) + 1;
    let chunk = cands
        .len()
        .div_ceil(4 * rayon::current_num_threads())
        .max(4096);
    let counts: Vec<Vec<usize>> = cands
        .par_chunks(chunk)
        .zip(reaches.par_chunks(chunk))
        .map(|(part, reach)| {
            let mut count = vec![0; nb];
            for (c, _) in part.iter().zip(reach).filter(|(_, r)| **r) {
                count[bucket(key(c))] += 1;
            }
            count
        })
        .collect();
    let total = counts.iter().flatten().sum();
    let mut list = Vec::with_capacity(total);
    let mut rest = &mut list.spare_capacity_mut()[..total];
    let mut places: Vec<Vec<&mut [std::mem::MaybeUninit<Candidate>]>> =
        counts.iter().map(|_| Vec::with_capacity(nb)).collect();
    for b in 0..nb {
        for (place, count) in places.iter_mut().zip(&counts) {
            let (mine, after) = rest.split_at_mut(count[b]);
            place.push(mine);
            rest = after;
        }
    }
    cands
        .par_chunks(chunk)
        .zip(reaches.par_chunks(chunk))
        .zip(places)
        .for_each(|((part, reach), mut place)| {
            let mut filled = vec![0; nb];
            for (c, _) in part.iter().zip(reach).filter(|(_, r)| **r) {
                let b = bucket(key(c));
                place[b][filled[b]].write(*c);
                filled[b] += 1;
            }
        });
    // SAFETY: the places cut the first `total` slots into one slice per (bucket, chunk),
    // each as long as the chunk's count of candidates in the bucket, and each chunk wrote
    // exactly those candidates to its slices: every slot was written.
    unsafe { list.set_len(total) };
    let mut rest = &mut list[..];
    let mut runs = Vec::with_capacity(nb);
    for b in 0..nb {
        let (run, after) = rest.split_at_mut(counts.iter().map(|c| c[b]).sum());
        runs.push(run);
        rest = after;
    }
    runs.into_par_iter()
        .with_min_len(16)
        .for_each(|run| run.sort_unstable_by_key(|c| (key(c), c.index)));
    list
}

impl Tiles {
    /// Bin `cylinders` for `cam`, or `None` when the lists would average more than
    /// [`CROWDED`] candidates per tile (a dense scene, or many cylinders reaching past the
    /// camera): `render` then walks the BVH tile by tile.
    pub fn build(cam: &Camera, cylinders: &[Cylinder]) -> Option<Tiles> {
        Self::build_or_projections(cam, cylinders).ok()
    }

    /// [`Tiles::build`], or, when crowded, the projections it made (in index order, as
    /// [`project_slots`] with the identity order makes them), for the cone walk to reuse.
    pub fn build_or_projections(
        cam: &Camera,
        cylinders: &[Cylinder],
    ) -> Result<Tiles, Vec<Candidate>> {
        Self::build_within(cam, cylinders, CROWDED)
    }

    /// [`Tiles::build_or_projections`] with the crowding limit `crowded` candidates a tile
    /// on average (`usize::MAX`: never crowded).
    pub fn build_within(
        cam: &Camera,
        cylinders: &[Cylinder],
        crowded: usize,
    ) -> Result<Tiles, Vec<Candidate>> {
        let (tiles_x, tiles_y) = (cam.width().div_ceil(TILE), cam.height().div_ceil(TILE));
        assert!(tiles_x <= 1 << 16, "image too wide for tiles");
        let view = View::new(cam);
        // One slot per cylinder (an indexed collect writes each once, in place), culled
        // ones with an empty rectangle: they reach no tile.
        let cands: Vec<Candidate> = cylinders
            .par_iter()
            .enumerate()
            .map(|(i, c)| {
                project_in(&view, c).map_or(CULLED, |mut k| {
                    k.index = i as u32;
                    k
                })
            })
            .collect();
        let ntiles = (tiles_x * tiles_y) as usize;
        // The rectangles bound the entries cheaply; only past the limit count exactly
        // (the decision is the exact count's either way), before listing any visits.
        let rect = |c: &Candidate| match c.x0 <= c.x1 {
            true => {
                (c.x1 / TILE - c.x0 / TILE + 1) as usize * (c.y1 / TILE - c.y0 / TILE + 1) as usize
            }
            false => 0,
        };
        let limit = crowded.saturating_mul(ntiles);
        if cands.par_iter().map(rect).sum::<usize>() > limit && entries_exceed(&cands, limit) {
            return Err(cands);
        }
        if tiles_x == 1 && tiles_y == 1 {
            // One tile (a tiny view): its list is every candidate that reaches it.
            let list = nearest_first(&cands);
            return Ok(Tiles {
                tiles_x,
                tiles_y,
                start: vec![0, list.len() as u32],
                rows: vec![list],
            });
        }
        // Each chunk of candidates lists its visits per tile row; then each tile row
        // gathers its visits, sorts them by (t_min, index) and fills its tiles' lists. The
        // sort makes the output independent of the chunking and the thread count.
        let chunk = cands
            .len()
            .div_ceil(4 * rayon::current_num_threads())
            .max(1024);
        let visits: Vec<Vec<Vec<Visit>>> = cands
            .par_chunks(chunk)
            .enumerate()
            .map(|(ci, part)| {
                let mut rows = vec![Vec::new(); tiles_y as usize];
                for (k, c) in part.iter().enumerate().filter(|(_, c)| c.x0 <= c.x1) {
                    let (key, pos) = (order_key(c.t_min), (ci * chunk + k) as u32);
                    c.for_tile_rows(|ty, a, b| {
                        rows[ty as usize].push(Visit {
                            key,
                            pos,
                            tx0: a as u16,
                            tx1: b as u16,
                        })
                    });
                }
                rows
            })
            .collect();
        let nx = tiles_x as usize;
        let (starts, rows): (Vec<Vec<u32>>, Vec<Vec<Candidate>>) = (0..tiles_y as usize)
            .into_par_iter()
            .map(|ty| {
                let mut row: Vec<Visit> =
                    Vec::with_capacity(visits.iter().map(|v| v[ty].len()).sum());
                for v in &visits {
                    row.extend_from_slice(&v[ty]);
                }
                // (key, pos) is unique, so any sort gives the one order; a long row (a
                // tiny view's single row of tiles) sorts on every thread.
                if row.len() > 1 << 14 {
                    row.par_sort_unstable_by_key(|v| (v.key, v.pos));
                } else {
                    row.sort_unstable_by_key(|v| (v.key, v.pos));
                }
                let gather = |k: usize, v: &Visit| {
                    if let Some(ahead) = row.get(k + crate::mem::PREFETCH_AHEAD) {
                        crate::mem::prefetch(&cands[ahead.pos as usize]);
                    }
                    cands[v.pos as usize]
                };
                if nx == 1 {
                    // One tile a row (a tiny view): its list is the row, gathered on every
                    // thread.
                    let list = row.par_iter().enumerate().map(|(k, v)| gather(k, v));
                    return (vec![0, row.len() as u32], list.collect());
                }
                let mut start = vec![0u32; nx + 1];
                for v in &row {
                    for tx in v.tx0..=v.tx1 {
                        start[tx as usize + 1] += 1;
                    }
                }
                for k in 1..=nx {
                    start[k] += start[k - 1];
                }
                let mut fill = start.clone();
                let mut list = vec![EMPTY; start[nx] as usize];
                for (k, v) in row.iter().enumerate() {
                    let c = gather(k, v);
                    for tx in v.tx0..=v.tx1 {
                        let f = &mut fill[tx as usize];
                        list[*f as usize] = c;
                        *f += 1;
                    }
                }
                (start, list)
            })
            .unzip();
        Ok(Tiles {
            tiles_x,
            tiles_y,
            start: starts.concat(),
            rows,
        })
    }

    /// Candidates of the tile holding pixel column block `tx`, row block `ty`.
    #[inline]
    pub fn tile(&self, tx: u32, ty: u32) -> &[Candidate] {
        let k = (ty * (self.tiles_x + 1) + tx) as usize;
        &self.rows[ty as usize][self.start[k] as usize..self.start[k + 1] as usize]
    }

    /// Number the cylinders in the order the renderer first meets them (tile rows top to
    /// bottom, tiles left to right, each list nearest first), set every candidate's `slot`,
    /// and return the cylinder index of each slot; cylinders in no tile come last, in
    /// index order. Kept in slot order, a tile's cylinders lie close together in memory:
    /// at 100 000 cylinders, index order would scatter them over megabytes.
    pub fn assign_slots(&mut self, cylinders: usize) -> Vec<u32> {
        if let [list] = &mut self.rows[..]
            && self.tiles_x == 1
        {
            // One tile (a tiny view): each cylinder is listed once, and its slot is its
            // place in the list, numbered on every thread.
            let mut listed = vec![false; cylinders];
            for c in list.iter() {
                listed[c.index as usize] = true;
            }
            list.par_iter_mut()
                .enumerate()
                .for_each(|(s, c)| c.slot = s as u32);
            let mut order: Vec<u32> = list.par_iter().map(|c| c.index).collect();
            order.extend((0..cylinders as u32).filter(|&i| !listed[i as usize]));
            return order;
        }
        let mut slot_of = vec![u32::MAX; cylinders];
        let mut order = Vec::with_capacity(cylinders);
        for c in self.rows.iter_mut().flatten() {
            let s = &mut slot_of[c.index as usize];
            if *s == u32::MAX {
                *s = order.len() as u32;
                order.push(c.index);
            }
            c.slot = *s;
        }
        order.extend((0..cylinders as u32).filter(|&i| slot_of[i as usize] == u32::MAX));
        order
    }

    /// Total candidate entries (for statistics).
    pub fn entries(&self) -> usize {
        self.rows.iter().map(Vec::len).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::scene::camera::{CameraSpec, FovAxis};

    /// A pool of `n` threads: the chunking of the parallel passes follows the count.
    fn pool(n: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    }

    /// Random cameras over generated scenes: some outside the cloud of cylinders, some
    /// among them (boxes straddling the camera plane), various fields of view and sizes.
    fn cases() -> Vec<(Camera, Vec<Cylinder>)> {
        let mut rng = SplitMix64::new(7);
        (0..40)
            .map(|k| {
                let (w, h) = (rng.int_in(40, 300), rng.int_in(30, 200));
                let n = [1, 20, 200, 600][k % 4];
                let sc = crate::bench::random_scene(n, 100 + k as u64, w, h);
                let origin = if k % 3 == 0 {
                    DVec3::new(
                        rng.range(-4.0, 4.0),
                        rng.range(-4.0, 4.0),
                        rng.range(-4.0, 4.0),
                    )
                } else {
                    rng.unit_vector() * rng.range(8.0, 25.0)
                };
                let target = DVec3::new(
                    rng.range(-3.0, 3.0),
                    rng.range(-3.0, 3.0),
                    rng.range(-3.0, 3.0),
                );
                let fov_axis = [FovAxis::X, FovAxis::Y, FovAxis::Diagonal][k % 3];
                let cam = Camera::new(CameraSpec {
                    origin,
                    target,
                    up: rng.unit_vector(),
                    fov_deg: rng.range(15.0, 110.0),
                    fov_axis,
                    width: w,
                    height: h,
                    near_clip: rng.range(0.001, 0.5),
                    far_clip: rng.range(10.0, 40.0),
                    projection: crate::scene::camera::Projection::Perspective,
                });
                (cam, sc.cylinders)
            })
            .collect()
    }

    /// Every pixel a candidate's `row_span` admits lies in a tile whose list holds it.
    #[test]
    fn binning_covers_every_row_span() {
        let mut checked = 0usize;
        for (cam, cyls) in cases() {
            let Some(tiles) = Tiles::build(&cam, &cyls) else {
                continue;
            };
            let (w, h) = (cam.width(), cam.height());
            for (i, cyl) in cyls.iter().enumerate() {
                let Some(c) = project(&cam, cyl) else {
                    continue;
                };
                assert!(c.x1 < w && c.y1 < h && c.x0 <= c.x1 && c.y0 <= c.y1);
                for j in c.y0..=c.y1 {
                    for tx in 0..tiles.tiles_x {
                        let xs = (tx * TILE, ((tx + 1) * TILE).min(w) - 1);
                        if c.row_span(j, xs.0, xs.1).is_some() {
                            checked += 1;
                            assert!(
                                tiles.tile(tx, j / TILE).iter().any(|k| k.index == i as u32),
                                "cylinder {i} row {j} tile column {tx} not listed"
                            );
                        }
                    }
                }
            }
            // Every list is sorted by (t_min, index).
            for ty in 0..tiles.tiles_y {
                for tx in 0..tiles.tiles_x {
                    let l = tiles.tile(tx, ty);
                    assert!(l.windows(2).all(|p| {
                        p[0].t_min
                            .total_cmp(&p[1].t_min)
                            .then(p[0].index.cmp(&p[1].index))
                            == std::cmp::Ordering::Less
                    }));
                }
            }
        }
        assert!(checked > 10_000, "{checked}");
    }

    /// A tiny view's one list (the bucket sort) holds the candidates the general binning
    /// would list, ordered by (`t_min`, index), whatever the thread count: on views from
    /// outside a crowd and inside one (keys bunched at the near plane).
    #[test]
    fn one_tile_lists_every_reaching_candidate_nearest_first() {
        let mut inside = crate::bench::dense_scene(20_000, 9, 16, 12);
        inside.camera.origin = DVec3::new(0.3, -0.2, 0.1);
        inside.camera.near_clip = 0.5;
        for sc in [crate::bench::dense_scene(20_000, 9, 16, 12), inside] {
            let cam = Camera::new(sc.camera);
            let view = View::new(&cam);
            let mut want: Vec<(u64, u32)> = sc
                .cylinders
                .iter()
                .enumerate()
                .filter_map(|(i, c)| project_in(&view, c).map(|k| (k, i)))
                .filter(|(k, _)| k.tile_entries() > 0)
                .map(|(k, i)| (order_key(k.t_min), i as u32))
                .collect();
            want.sort_unstable();
            assert!(want.len() > 1_000, "{}", want.len());
            for threads in [1, 2, 3, 7] {
                let pool = pool(threads);
                let t = pool
                    .install(|| Tiles::build_within(&cam, &sc.cylinders, usize::MAX))
                    .unwrap();
                assert_eq!((t.tiles_x, t.tiles_y), (1, 1));
                let got: Vec<(u64, u32)> = t
                    .tile(0, 0)
                    .iter()
                    .map(|c| (order_key(c.t_min), c.index))
                    .collect();
                assert!(got == want, "{threads} threads");
            }
        }
    }

    /// The lists do not depend on the thread count (the chunking follows it).
    #[test]
    fn lists_are_independent_of_thread_count() {
        let sc = crate::bench::random_scene(5000, 3, 640, 360);
        let cam = Camera::new(sc.camera);
        let with = |threads: usize| {
            let pool = pool(threads);
            let t = pool.install(|| Tiles::build(&cam, &sc.cylinders)).unwrap();
            let mut out = Vec::new();
            for ty in 0..t.tiles_y {
                for tx in 0..t.tiles_x {
                    out.push(u64::MAX);
                    for c in t.tile(tx, ty) {
                        out.extend([c.index, c.x0, c.y0, c.x1, c.y1].map(u64::from));
                        out.extend([c.t_min, c.centre, c.slope, c.half].map(f64::to_bits));
                    }
                }
            }
            (t.entries(), out)
        };
        let one = with(1);
        assert!(one.0 > 5000);
        for threads in [2, 3, 7] {
            assert!(with(threads) == one, "{threads} threads");
        }
    }

    /// The count that stops once past its limit answers as the whole sum does, at the
    /// sum and on either side of it, whichever thread counts the chunks: on 20 000
    /// candidates (5 chunks).
    #[test]
    fn entries_exceed_is_the_whole_sums_answer() {
        let sc = crate::bench::random_scene(20_000, 5, 640, 360);
        let view = View::new(&Camera::new(sc.camera));
        let cands: Vec<Candidate> = sc
            .cylinders
            .iter()
            .map(|c| project_in(&view, c).unwrap_or(CULLED))
            .collect();
        let total: usize = cands.iter().map(Candidate::tile_entries).sum();
        assert!(total > 20_000, "{total} entries");
        for threads in [1, 2, 5] {
            let pool = pool(threads);
            for limit in [0, total / 3, total - 1, total, total + 1, usize::MAX] {
                let exceed = pool.install(|| entries_exceed(&cands, limit));
                assert_eq!(
                    exceed,
                    total > limit,
                    "{limit} of {total}, {threads} threads"
                );
            }
        }
    }

    /// Points on the cylinders (sides and caps) in the clip range project into a pixel
    /// that their candidate's rectangle, band and tile list admit, at `z >= t_min`.
    #[test]
    fn projection_covers_sampled_surface_points() {
        let mut rng = SplitMix64::new(8);
        let mut checked = 0usize;
        for (cam, cyls) in cases() {
            let tiles = Tiles::build(&cam, &cyls);
            let (w, h) = (cam.width() as f64, cam.height() as f64);
            for (i, cyl) in cyls.iter().enumerate() {
                let c = project(&cam, cyl);
                let (u, v) = orthonormal_basis(cyl.axis);
                for _ in 0..300 {
                    let (cs, sn) = rng.unit_circle();
                    let (s, rho) = match rng.int_in(0, 3) {
                        0 => (0.0, rng.unit().sqrt()),
                        1 => (1.0, rng.unit().sqrt()),
                        _ => (rng.unit(), 1.0),
                    };
                    let p = cyl.base
                        + cyl.axis * (cyl.height * s)
                        + (u * cs + v * sn) * (cyl.radius * rho);
                    let d = p - cam.origin;
                    let (x, y, z) = (-d.dot(cam.left), d.dot(cam.true_up), d.dot(cam.forward));
                    if z < cam.spec.near_clip || z > cam.spec.far_clip {
                        continue;
                    }
                    let px = (x / z / cam.tan_half_x + 1.0) * 0.5 * w;
                    let py = (1.0 - y / z / cam.tan_half_y) * 0.5 * h;
                    if !(px >= 0.0 && px < w && py >= 0.0 && py < h) {
                        continue;
                    }
                    let (pi, pj) = (px as u32, py as u32);
                    checked += 1;
                    let c = c.unwrap_or_else(|| panic!("cylinder {i} culled, sees {pi},{pj}"));
                    assert!(c.t_min <= z, "cylinder {i}: t_min {} > z {z}", c.t_min);
                    assert!(
                        (c.y0..=c.y1).contains(&pj) && c.row_span(pj, pi, pi).is_some(),
                        "cylinder {i}: pixel {pi},{pj} outside {c:?}"
                    );
                    if let Some(t) = &tiles {
                        assert!(
                            t.tile(pi / TILE, pj / TILE)
                                .iter()
                                .any(|k| k.index == i as u32)
                        );
                    }
                }
            }
        }
        assert!(checked > 100_000, "{checked}");
    }
}
