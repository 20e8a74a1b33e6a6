//! Eight rays at a time: the packet form of [`Formula::intersect`].
//!
//! Primary rays of neighbouring pixels meet the same cylinders, so `render` tests a
//! cylinder against the eight pixels of a tile row at once. The lanes are plain arrays
//! and every step is a loop over them without branches (selects instead), which the
//! compiler turns into SIMD: one AVX register of f32 lanes or two of f64, so f32 does
//! twice the rays per instruction. Each lane performs exactly the IEEE operations of the
//! scalar kernel in the same order (no fused multiply-add, no reassociation), so a packet
//! gives the scalar kernel's results bit for bit; a test checks it.

use super::cylinder::{Formula, Prepared, Surface};
use super::real::Real;
use super::wide::Wide;

/// Rays per packet: eight pixels of a tile row.
pub const LANES: usize = 8;

/// Lane value of "no hit yet" in [`Packet::index`].
pub const NO_HIT: u32 = u32::MAX;

/// Eight rays from the camera origin and the nearest hit each has found so far.
#[derive(Clone, Copy, Debug)]
pub struct Packet<T: Real> {
    /// Unit directions, one array per world axis.
    pub d: [[T; LANES]; 3],
    pub tmin: [T; LANES],
    /// The nearest hit's `t`; the ray's `tmax` until it has one.
    pub t: [T; LANES],
    /// The nearest hit's cylinder, or [`NO_HIT`], and where its caller keeps it (its slot).
    pub index: [u32; LANES],
    pub slot: [u32; LANES],
    /// The nearest hit's surface, as `Surface as u32`.
    pub surface: [u32; LANES],
}

impl<T: Real> Packet<T> {
    pub const EMPTY: Self = Packet {
        d: [[T::ZERO; LANES]; 3],
        tmin: [T::ZERO; LANES],
        t: [T::ZERO; LANES],
        index: [NO_HIT; LANES],
        slot: [0; LANES],
        surface: [0; LANES],
    };

    /// Lane `l`'s direction as a vector.
    #[inline(always)]
    pub fn dir(&self, l: usize) -> T::V3 {
        T::v3_new(self.d[0][l], self.d[1][l], self.d[2][l])
    }
}

/// Any formula: the scalar kernel lane by lane (the literal form stays as written).
#[inline(always)]
pub fn intersect_lanes<T: Real, F: Formula>(
    p: &Prepared<T>,
    (index, slot): (u32, u32),
    pk: &mut Packet<T>,
    mask: u8,
) -> u8 {
    let mut changed = 0;
    for l in 0..LANES {
        if mask & (1 << l) == 0 {
            continue;
        }
        // A hit has t <= pk.t[l] (its limit), so a first hit (index NO_HIT) is always kept.
        let Some(h) = F::intersect(p, pk.dir(l), pk.tmin[l], pk.t[l]) else {
            continue;
        };
        if h.t < pk.t[l] || (h.t == pk.t[l] && index < pk.index[l]) {
            (pk.t[l], pk.index[l], pk.slot[l]) = (h.t, index, slot);
            pk.surface[l] = h.surface as u32;
            changed |= 1 << l;
        }
    }
    changed
}

/// `a · d` per lane, summed in the order of glam's `dot` (x, then y, then z).
#[inline(always)]
fn dot<T: Real, W: Wide<T>>(a: [T; 3], d: [W; 3]) -> W {
    W::splat(a[0]) * d[0] + W::splat(a[1]) * d[1] + W::splat(a[2]) * d[2]
}

/// [`Stable::intersect`] on eight lanes at once, step for step (see there for the maths),
/// in the SIMD form `W`.
#[inline(always)]
pub fn stable_lanes<T: Real, W: Wide<T>>(
    p: &Prepared<T>,
    (index, slot): (u32, u32),
    pk: &mut Packet<T>,
    mask: u8,
) -> u8 {
    let [ou, ov, on] = p.oc_local;
    let (u, v, n) = (T::v3_parts(p.u), T::v3_parts(p.v), T::v3_parts(p.n));
    let s = W::splat;
    let d = [W::load(&pk.d[0]), W::load(&pk.d[1]), W::load(&pk.d[2])];
    let (zero, inf) = (s(T::ZERO), s(T::INFINITY));
    let (du, dv) = (dot(u, d), dot(v, d));
    let a = du * du + dv * dv;
    let x = (du * s(ov) - dv * s(ou)).abs();
    let r2a = s(p.r * p.r) * a;
    // The cheap reject (a ray parallel to the axis is decided by `c_side` below).
    let parallel = a.eq(zero);
    let near = !(x * x).gt(r2a + r2a * s(T::from_f64(8.0 * T::UNIT_ROUNDOFF))) | parallel;
    let mask = mask & W::bits(near);
    if mask == 0 {
        return 0;
    }
    // Side interval [s0, s1] (Stable::side_interval).
    let dn = dot(n, d);
    let b = du * s(ou) + dv * s(ov);
    let ra = s(p.r) * a.sqrt();
    let disc = (ra - x) * (ra + x);
    let q = -(b + b.sign() * disc.sqrt());
    let (t0, t1) = (q / a, s(p.c_side) / q);
    let tangent = q.eq(zero);
    let s0 = W::select(
        parallel,
        -inf,
        W::select(tangent, zero, W::select(t0.lt(t1), t0, t1)),
    );
    let s1 = W::select(
        parallel,
        inf,
        W::select(tangent, zero, W::select(t0.gt(t1), t0, t1)),
    );
    let side = (parallel & W::all(p.c_side <= T::ZERO)) | (!parallel & disc.ge(zero));
    let (tmin, limit) = (W::load(&pk.tmin), W::load(&pk.t));
    // The hit per lane, and its surface as bits: on the side, else on the bottom cap.
    let (hit, t, on_side, on_bottom) = if p.caps {
        // Slab between the cap planes (a ray parallel to them: all or nothing).
        let flat = dn.eq(zero);
        let (ta, tb) = (s(-on) / dn, s(p.h - on) / dn);
        let up = dn.gt(zero);
        let c0 = W::select(flat, -inf, W::select(up, ta, tb));
        let c1 = W::select(flat, inf, W::select(up, tb, ta));
        let slab = !flat | W::all(on >= T::ZERO && on <= p.h);
        let (side_in, side_out) = (s0.ge(c0), s1.le(c1));
        let (enter, exit) = (W::select(side_in, s0, c0), W::select(side_out, s1, c1));
        let first = enter.ge(tmin) & enter.le(limit);
        let hit = side & slab & !enter.gt(exit) & (first | (exit.ge(tmin) & exit.le(limit)));
        // Entering through a cap it is the bottom one when going up (or flat); leaving, the top.
        let bottom_in = up | flat;
        let on_side = (first & side_in) | (!first & side_out);
        let on_bottom = (first & bottom_in) | (!first & !bottom_in);
        (
            hit,
            W::select(first, enter, exit),
            W::bits(on_side),
            W::bits(on_bottom),
        )
    } else {
        // Open tube: each side root counts if it lies between the cap planes.
        let (bottom, top) = (s(T::ZERO), s(p.h));
        let (along0, along1) = (s(on) + s0 * dn, s(on) + s1 * dn);
        let first = s0.ge(tmin) & s0.le(limit) & along0.ge(bottom) & along0.le(top);
        let second = s1.ge(tmin) & s1.le(limit) & along1.ge(bottom) & along1.le(top);
        (
            side & (first | second),
            W::select(first, s0, s1),
            u8::MAX,
            0,
        )
    };
    let hits = mask & W::bits(hit);
    if hits == 0 {
        return 0;
    }
    // Keep the nearer hit per lane (ties: the lower index); rare enough to do lane by lane.
    let (lt, eq) = (W::bits(t.lt(limit)), W::bits(t.eq(limit)));
    let mut ts = [T::ZERO; LANES];
    t.store(&mut ts);
    let mut changed = 0;
    for l in (0..LANES).filter(|l| hits & (1 << l) != 0) {
        if lt & (1 << l) != 0 || (eq & (1 << l) != 0 && index < pk.index[l]) {
            (pk.t[l], pk.index[l], pk.slot[l]) = (ts[l], index, slot);
            pk.surface[l] = match (on_side & (1 << l) != 0, on_bottom & (1 << l) != 0) {
                (true, _) => Surface::Side,
                (false, true) => Surface::Bottom,
                (false, false) => Surface::Top,
            } as u32;
            changed |= 1 << l;
        }
    }
    changed
}
