//! Eight rays at a time: the packet form of [`Formula::intersect`].
//!
//! Primary rays of neighbouring pixels meet the same cylinders, so `render` tests a
//! cylinder against the eight pixels of a tile row at once. The stable kernel is written
//! once over [`Wide`] and runs branch-free on eight lanes: in AVX registers (one of f32
//! lanes or two of f64, so f32 does twice the rays per instruction) or, portably, on
//! arrays. Each lane performs exactly the IEEE operations of the scalar kernel in the same
//! order (no fused multiply-add, no reassociation), so a packet gives the scalar kernel's
//! results bit for bit; tests check it.

use super::cylinder::{Formula, Literal, Prepared, Stable, Surface};
use super::real::Real;
use super::wide::{LANES, Wide};

/// Lane value of "no hit yet" in [`Packet::index`].
pub(crate) const NO_HIT: u32 = u32::MAX;

/// Eight rays from the camera origin and the nearest hit each has found so far.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Packet<T: Real> {
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

/// The keep rule of every path: a hit on cylinder `index` replaces the best one if it is
/// nearer, or as near and on a lower scene index, so the answer does not depend on the
/// order cylinders are visited in. A lane with no hit yet has `best_t` = its tmax, which
/// bounds every hit it is offered, and `best_index` = [`NO_HIT`], above every index.
#[inline(always)]
pub(crate) fn nearer<T: PartialOrd>(t: T, index: u32, best_t: T, best_index: u32) -> bool {
    t < best_t || (t == best_t && index < best_index)
}

/// A formula's packet form: [`Formula::intersect`] for the lanes of a packet in `mask`,
/// keeping each lane's nearer hit on cylinder `index.0` (kept by its caller in slot
/// `index.1`); returns the lanes that changed. By default lane by lane; a formula may use
/// the SIMD form `W`.
pub(crate) trait PacketFormula: Formula {
    /// Whether it has a SIMD form (else its packets run the scalar kernel lane by lane).
    const SIMD: bool = false;

    #[inline(always)]
    fn intersect_packet<T: Real, W: Wide<T>>(
        _tok: W::Token,
        p: &Prepared<T>,
        index: (u32, u32),
        pk: &mut Packet<T>,
        mask: u8,
    ) -> u8 {
        intersect_lanes::<T, Self>(p, index, pk, mask)
    }
}

/// The literal formulas stay as written: no SIMD form.
impl PacketFormula for Literal {}

impl PacketFormula for Stable {
    const SIMD: bool = true;

    #[inline(always)]
    fn intersect_packet<T: Real, W: Wide<T>>(
        tok: W::Token,
        p: &Prepared<T>,
        index: (u32, u32),
        pk: &mut Packet<T>,
        mask: u8,
    ) -> u8 {
        stable_lanes::<T, W>(tok, p, index, pk, mask)
    }
}

/// Any formula: the scalar kernel lane by lane (the literal form stays as written).
#[inline(always)]
pub(crate) fn intersect_lanes<T: Real, F: Formula>(
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
        let Some(h) = F::intersect(p, pk.dir(l), pk.tmin[l], pk.t[l]) else {
            continue;
        };
        if nearer(h.t, index, pk.t[l], pk.index[l]) {
            (pk.t[l], pk.index[l], pk.slot[l]) = (h.t, index, slot);
            pk.surface[l] = h.surface as u32;
            changed |= 1 << l;
        }
    }
    changed
}

/// `a · d` per lane, summed in the order of glam's `dot` (x, then y, then z).
#[inline(always)]
fn dot<T: Real, W: Wide<T>>(tok: W::Token, a: [T; 3], d: [W; 3]) -> W {
    W::splat(tok, a[0]) * d[0] + W::splat(tok, a[1]) * d[1] + W::splat(tok, a[2]) * d[2]
}

/// [`Stable::intersect`] on eight lanes at once, step for step (see there for the maths),
/// in the SIMD form `W`.
#[inline(always)]
pub(crate) fn stable_lanes<T: Real, W: Wide<T>>(
    tok: W::Token,
    p: &Prepared<T>,
    (index, slot): (u32, u32),
    pk: &mut Packet<T>,
    mask: u8,
) -> u8 {
    let [ou, ov, on] = p.oc_local;
    let (u, v, n) = (T::v3_parts(p.u), T::v3_parts(p.v), T::v3_parts(p.n));
    let s = |x: T| W::splat(tok, x);
    let d = [
        W::load(tok, &pk.d[0]),
        W::load(tok, &pk.d[1]),
        W::load(tok, &pk.d[2]),
    ];
    let (zero, inf) = (s(T::ZERO), s(T::INFINITY));
    let (du, dv) = (dot(tok, u, d), dot(tok, v, d));
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
    let dn = dot(tok, n, d);
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
    let side = (parallel & W::all(tok, p.c_side <= T::ZERO)) | (!parallel & !disc.lt(zero));
    let (tmin, limit) = (W::load(tok, &pk.tmin), W::load(tok, &pk.t));
    // Every hit lies at or past the side's entry `s0` (on the side, or through a cap
    // after it): a lane whose entry is past its best hit cannot improve. In dense views
    // most tests end here, before the caps' two divisions.
    if mask & W::bits(side & !s0.gt(limit)) == 0 {
        return 0;
    }
    // The hit per lane, and its surface as bits: on the side, else on the bottom cap.
    let (hit, t, on_side, on_bottom) = if p.caps {
        // Slab between the cap planes (a ray parallel to them: all or nothing).
        let flat = dn.eq(zero);
        let (ta, tb) = (s(-on) / dn, s(-p.on_top) / dn);
        let up = dn.gt(zero);
        let c0 = W::select(flat, -inf, W::select(up, ta, tb));
        let c1 = W::select(flat, inf, W::select(up, tb, ta));
        let slab = !flat | W::all(tok, !(on < T::ZERO || p.on_top > T::ZERO));
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
    // Keep the nearer hits; few lanes hit, so lane by lane.
    let mut ts = [T::ZERO; LANES];
    t.store(&mut ts);
    let mut changed = 0;
    for l in (0..LANES).filter(|l| hits & (1 << l) != 0) {
        if nearer(ts[l], index, pk.t[l], pk.index[l]) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Cylinder;
    use crate::geometry::wide::{Lanes, Simd};
    use glam::DVec3;

    /// Eight rays from the origin fanned along a cylinder lying across the view, five units
    /// ahead: lane 0 enters a closed one through its near cap (past the side's entry, which
    /// lies outside the cap planes) and an open one from inside, the others through the
    /// side.
    fn fan<T: Real>(caps: bool) -> (Prepared<T>, Packet<T>) {
        let cyl = Cylinder {
            base: DVec3::new(0.2, 0.1, 5.0),
            axis: DVec3::X,
            height: 2.0,
            radius: 0.5,
            caps,
            id: 1,
            label: 0,
        };
        let p = Prepared::new(&cyl, DVec3::ZERO, Stable::CENTRED);
        let mut pk = Packet::EMPTY;
        for l in 0..LANES {
            let d = DVec3::new(0.04 + 0.04 * l as f64, 0.03, 1.0).normalize();
            for (c, x) in d.to_array().into_iter().enumerate() {
                pk.d[c][l] = T::from_f64(x);
            }
            (pk.tmin[l], pk.t[l]) = (T::ZERO, T::INFINITY);
        }
        (p, pk)
    }

    /// The side-entry early exit keeps the keep rule exactly: with each lane's best hit at
    /// the cylinder's own hit `t` (a tie, on a higher index) every lane still changes, and
    /// with the best hit one step nearer none does and the packet is left as it was.
    fn ties_survive_the_early_exit<T: Real, W: Wide<T>>(tok: W::Token, below: fn(T) -> T) {
        for caps in [true, false] {
            let (p, pk) = fan::<T>(caps);
            let mut open = pk;
            let all = stable_lanes::<T, W>(tok, &p, (7, 3), &mut open, u8::MAX);
            assert_eq!(all, u8::MAX, "caps {caps}: every lane meets the cylinder");
            for l in 0..LANES {
                let scalar = Stable::intersect(&p, pk.dir(l), T::ZERO, T::INFINITY);
                assert_eq!(
                    scalar.map(|h| h.t),
                    Some(open.t[l]),
                    "caps {caps}, lane {l}"
                );
            }
            let wanted = if caps { Surface::Bottom } else { Surface::Side };
            assert_eq!(
                open.surface[0], wanted as u32,
                "caps {caps}: lane 0's surface"
            );
            assert!((1..LANES).all(|l| open.surface[l] == Surface::Side as u32));
            let mut tie = pk;
            (tie.t, tie.index) = (open.t, [9; LANES]);
            let changed = stable_lanes::<T, W>(tok, &p, (7, 3), &mut tie, u8::MAX);
            assert_eq!(changed, u8::MAX, "caps {caps}: ties go to the lower index");
            assert_eq!(tie.index, [7; LANES]);
            let mut nearer = pk;
            (nearer.t, nearer.index) = (open.t.map(below), [9; LANES]);
            let before = nearer;
            let changed = stable_lanes::<T, W>(tok, &p, (7, 3), &mut nearer, u8::MAX);
            assert_eq!(changed, 0, "caps {caps}: nothing is nearer");
            assert_eq!((nearer.t, nearer.index), (before.t, before.index));
        }
    }

    #[test]
    fn the_keep_rule_holds_at_the_side_entry() {
        fn run<T: Simd>(below: fn(T) -> T) {
            ties_survive_the_early_exit::<T, Lanes<T>>((), below);
            #[cfg(target_arch = "x86_64")]
            if let Some(tok) = crate::geometry::wide::Avx2::detect() {
                ties_survive_the_early_exit::<T, T::Avx>(tok, below);
            }
        }
        run::<f32>(f32::next_down);
        run::<f64>(f64::next_down);
    }
}
