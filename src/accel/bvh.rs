//! A compact bounding-volume hierarchy over cylinder boxes: binned SAH build, f32 boxes.
//! The cone walk reads it as it is; per-ray traversal reads its eight-wide collapse
//! ([`WideBvh`](super::wide_bvh::WideBvh)) except in views of very few pixels.
//!
//! Boxes are stored relative to the ray origin of the render (the camera), rounded outward
//! and padded, so the f32 slab test stays conservative even for scenes far from the world
//! origin, and rays start at 0. A scene of at most [`LEAF_SIZE`] cylinders is one leaf:
//! one box test per ray, no tree to pay for.
//!
//! Depth is bounded: traversal keeps its pending nodes on a fixed stack of [`MAX_DEPTH`]
//! entries (one per level at most), and SAH on a skewed scene (sizes or positions in
//! geometric progression) can peel one box off per level. Below [`SAH_DEPTH`] levels the
//! build therefore splits at the object median, which halves the count, so no leaf lies
//! deeper than `SAH_DEPTH + log2(n)` < [`MAX_DEPTH`] for any `n` below 2³².

use glam::{DVec3, Vec3A, Vec4};
use rayon::prelude::*;
use std::mem::MaybeUninit;
use std::ops::Range;

/// Most primitives in a leaf (below [`SAH_DEPTH`]; a median-split leaf may hold more only
/// when its boxes cannot be told apart).
pub const LEAF_SIZE: usize = 4;
const BINS: usize = 16;
/// Levels split by SAH; deeper nodes split at the object median.
pub const SAH_DEPTH: usize = 30;
/// Entries of the traversal stack: more than any leaf's depth.
pub const MAX_DEPTH: usize = 64;
/// Subtrees of more primitives than this build their two halves in parallel. A count,
/// not a thread count: the tree is the same on any machine.
const PARALLEL_MIN: usize = 8192;
/// Interleaved sets of bins in a node's binning ([`Bvh::bin`]), and the fewest items for
/// which more than one pays for clearing and merging the others.
const SETS: usize = 4;
const SETS_MIN: usize = 64;

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Node {
    pub(super) min: Vec3A,
    pub(super) max: Vec3A,
    /// Leaf: first index into `order`. Interior: index of the left child (right = +1).
    pub(super) offset: u32,
    /// Primitives in a leaf; 0 for an interior node.
    pub(super) count: u32,
}

/// The hierarchy: nodes (root first) and the primitive order its leaves index.
#[derive(Clone, Debug)]
pub struct Bvh {
    pub(super) nodes: Vec<Node>,
    order: Vec<u32>,
    /// Each position's own box (min, max): a ray tests it before the cylinder, as a leaf's
    /// box bounds its cylinders loosely in a tangle of tilted ones.
    pub(super) boxes: Vec<[Vec3A; 2]>,
}

/// Round `x - o` to f32 toward -inf (`down`) or +inf and pad by a relative 1e-6, so the box
/// in f32 contains the exact one and no ray lies exactly in a face plane by accident. A
/// plane is never ±0: a ray parallel to it (direction component ±0, reciprocal ±inf)
/// then gets ±inf from the slab test, never 0·inf = NaN.
fn outward(x: DVec3, o: DVec3, down: bool) -> Vec3A {
    let rel = x - o;
    let pad = rel.abs() * 1e-6 + DVec3::splat(1e-30);
    let v = if down { rel - pad } else { rel + pad };
    let f = |a: f64| round_out(a, down);
    Vec3A::new(f(v.x), f(v.y), f(v.z))
}

/// `a` rounded to f32 toward -inf (`down`) or +inf, never to ±0 (the smallest normal on
/// the outer side instead). Without branches, as the rounding's direction is a coin toss
/// per coordinate: round to nearest, then, where that went the wrong way, step one f32:
/// the bit pattern ± 1, +1 where the step is away from 0 (a negative number going down, a
/// positive one going up). That is `next_down` / `next_up` for every `r` that needs a step
/// (-inf never steps down, +inf never up, NaN never steps).
#[inline(always)]
fn round_out(a: f64, down: bool) -> f32 {
    let r = a as f32;
    let wrong = if down { (r as f64) > a } else { (r as f64) < a };
    let step = wrong as u32;
    let bits = if r.is_sign_negative() == down {
        r.to_bits().wrapping_add(step)
    } else {
        r.to_bits().wrapping_sub(step)
    };
    let s = f32::from_bits(bits);
    let tiny = if down {
        -f32::MIN_POSITIVE
    } else {
        f32::MIN_POSITIVE
    };
    if r == 0.0 || s == 0.0 { tiny } else { s }
}

#[derive(Clone, Copy)]
struct Item {
    min: Vec3A,
    max: Vec3A,
    centroid: Vec3A,
    index: u32,
}

impl Item {
    /// Box `index`, `[lo, hi]` in world coordinates, relative to `origin` and rounded
    /// outward to f32 (see the module doc).
    fn new(index: usize, (lo, hi): (DVec3, DVec3), origin: DVec3) -> Item {
        let (min, max) = (outward(lo, origin, true), outward(hi, origin, false));
        Item {
            min,
            max,
            centroid: (min + max) * 0.5,
            index: index as u32,
        }
    }
}

pub(super) fn area(min: Vec3A, max: Vec3A) -> f32 {
    let e = (max - min).max(Vec3A::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// The box around some items' boxes and the box around their centroids: what a node's
/// split needs. A node's SAH binning yields both for its two parts (a union of bins), so
/// each level reads its items twice (bin, partition), not three times.
#[derive(Clone, Copy)]
struct Bounds {
    min: Vec3A,
    max: Vec3A,
    cmin: Vec3A,
    cmax: Vec3A,
}

impl Bounds {
    const EMPTY: Bounds = Bounds {
        min: Vec3A::INFINITY,
        max: Vec3A::NEG_INFINITY,
        cmin: Vec3A::INFINITY,
        cmax: Vec3A::NEG_INFINITY,
    };

    #[inline(always)]
    fn add(&mut self, it: &Item) {
        self.min = self.min.min(it.min);
        self.max = self.max.max(it.max);
        self.cmin = self.cmin.min(it.centroid);
        self.cmax = self.cmax.max(it.centroid);
    }

    #[inline(always)]
    fn union(&self, o: &Bounds) -> Bounds {
        Bounds {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
            cmin: self.cmin.min(o.cmin),
            cmax: self.cmax.max(o.cmax),
        }
    }

    fn of(items: &[Item]) -> Bounds {
        let mut b = Bounds::EMPTY;
        for it in items {
            b.add(it);
        }
        b
    }
}

/// A node's SAH bins: items and bounds of each.
struct Bins {
    count: [usize; BINS],
    bounds: [Bounds; BINS],
}

impl Bins {
    const EMPTY: Bins = Bins {
        count: [0; BINS],
        bounds: [Bounds::EMPTY; BINS],
    };

    /// Add `o`'s items to these bins.
    #[inline(always)]
    fn merge(&mut self, o: &Bins) {
        for k in 0..BINS {
            self.count[k] += o.count[k];
            self.bounds[k] = self.bounds[k].union(&o.bounds[k]);
        }
    }
}

/// What a node's SAH binning decided.
enum Cut {
    /// Testing every cylinder costs less than any split.
    Leaf,
    /// The items are partitioned: this many on the left; the bounds of both parts.
    At(usize, [Bounds; 2]),
    /// No bin boundary leaves both sides non-empty.
    Unusable,
}

const BLANK: Node = Node {
    min: Vec3A::ZERO,
    max: Vec3A::ZERO,
    offset: 0,
    count: 0,
};

/// A subtree of a parallel build, before its nodes are placed. Laid out as the
/// sequential build lays it out, a subtree is its root, then the roots of its two halves,
/// then the rest of the left half, then the rest of the right, each half the same way.
enum Part {
    /// Built by one task: its nodes, root first; an interior node's `offset` is the local
    /// index of its left child.
    Nodes(Vec<Node>),
    /// Split here, at these bounds; the halves built in parallel.
    Split(Bounds, Box<[Part; 2]>),
}

impl Part {
    /// Nodes in the subtree.
    fn len(&self) -> usize {
        match self {
            Part::Nodes(nodes) => nodes.len(),
            Part::Split(_, halves) => 1 + halves[0].len() + halves[1].len(),
        }
    }

    /// Write the subtree's root to `root` and its other nodes to `rest` (the node of local
    /// index `i ≥ 1` goes to `rest[i - 1]`, at index `shift + i` of the whole list), child
    /// offsets made indices of the whole list. The halves of a split are placed in parallel.
    fn place(&self, root: &mut MaybeUninit<Node>, rest: &mut [MaybeUninit<Node>], shift: u32) {
        match self {
            Part::Nodes(nodes) => {
                let moved = |k: &Node| Node {
                    offset: if k.count > 0 {
                        k.offset
                    } else {
                        k.offset + shift
                    },
                    ..*k
                };
                assert_eq!(rest.len() + 1, nodes.len(), "a part fills its place");
                root.write(moved(&nodes[0]));
                for (slot, k) in rest.iter_mut().zip(&nodes[1..]) {
                    slot.write(moved(k));
                }
            }
            Part::Split(bounds, halves) => {
                // Local layout: 1 and 2 the halves' roots, then the left's rest (its local
                // i ≥ 1 at i + 2), then the right's (at i + 1 + nl).
                let nl = halves[0].len() as u32;
                root.write(Node {
                    min: bounds.min,
                    max: bounds.max,
                    offset: shift + 1,
                    count: 0,
                });
                let (roots, rest) = rest.split_at_mut(2);
                let (lroot, rroot) = roots.split_at_mut(1);
                let (lrest, rrest) = rest.split_at_mut(nl as usize - 1);
                rayon::join(
                    || halves[0].place(&mut lroot[0], lrest, shift + 2),
                    || halves[1].place(&mut rroot[0], rrest, shift + 1 + nl),
                );
            }
        }
    }
}

impl Bvh {
    /// Build over world-space boxes, stored relative to `origin`.
    pub fn build(bounds: &[(DVec3, DVec3)], origin: DVec3) -> Bvh {
        Self::build_capped(bounds, origin, SAH_DEPTH)
    }

    /// [`Bvh::build`] with SAH down to `sah_depth` levels (the test of the cap builds
    /// without it to show the scene needs it).
    fn build_capped(bounds: &[(DVec3, DVec3)], origin: DVec3, sah_depth: usize) -> Bvh {
        let mut items: Vec<Item> = bounds
            .par_iter()
            .enumerate()
            .map(|(i, &b)| Item::new(i, b, origin))
            .collect();
        let all = items
            .par_chunks(4096)
            .map(Bounds::of)
            .reduce(|| Bounds::EMPTY, |a, b| a.union(&b));
        let mut keys = vec![0u32; items.len()];
        let nodes = Self::build_tree(&mut items, &mut keys, (0, sah_depth), all);
        Bvh {
            nodes,
            order: items.par_iter().map(|it| it.index).collect(),
            boxes: items.par_iter().map(|it| [it.min, it.max]).collect(),
        }
    }

    /// The tree over `items` (bounded by `bounds`; `keys` scratch of the same length), root
    /// first, laid out as the sequential build lays it out: large subtrees are split here
    /// and their halves built in parallel ([`Part`]), then every node is written once to
    /// its place in one list.
    fn build_tree(
        items: &mut [Item],
        keys: &mut [u32],
        depth: (usize, usize),
        bounds: Bounds,
    ) -> Vec<Node> {
        let part = Self::build_part(items, keys, 0, depth, bounds);
        let len = part.len();
        // Not filled first: each node's memory is first touched by the thread placing it.
        let mut nodes = Vec::with_capacity(len);
        let (root, rest) = nodes.spare_capacity_mut()[..len].split_at_mut(1);
        part.place(&mut root[0], rest, 0);
        // SAFETY: `place` writes its root and all of `rest` (checked where a part's own
        // nodes are copied; a split hands its halves their roots and exactly their rests).
        unsafe { nodes.set_len(len) };
        nodes
    }

    /// The subtree over `items` (positions `start..` of the final order, bounded by
    /// `bounds`): split, with its halves built in parallel, when it is large.
    fn build_part(
        items: &mut [Item],
        keys: &mut [u32],
        start: usize,
        depth: (usize, usize),
        bounds: Bounds,
    ) -> Part {
        let n = items.len();
        let split = (n > PARALLEL_MIN)
            .then(|| Self::split(items, keys, &bounds, depth.0, depth.1))
            .flatten();
        let Some((mid, [lb, rb])) = split else {
            let mut nodes = Vec::with_capacity(2 * n.max(1));
            nodes.push(BLANK);
            Self::build_node(&mut nodes, 0, items, keys, 0, depth, bounds);
            // Leaves index the slice; shift them to positions in the whole order.
            for node in nodes.iter_mut().filter(|k| k.count > 0) {
                node.offset += start as u32;
            }
            return Part::Nodes(nodes);
        };
        let (left, right) = items.split_at_mut(mid);
        let (lkeys, rkeys) = keys.split_at_mut(mid);
        let next = (depth.0 + 1, depth.1);
        let (l, r) = rayon::join(
            || Self::build_part(left, lkeys, start, next, lb),
            || Self::build_part(right, rkeys, start + mid, next, rb),
        );
        Part::Split(bounds, Box::new([l, r]))
    }

    /// Node `node` (already pushed) over `items`, which lie at positions `start..` of the
    /// order `nodes` indexes; `keys` is scratch as long as `items`.
    fn build_node(
        nodes: &mut Vec<Node>,
        node: usize,
        items: &mut [Item],
        keys: &mut [u32],
        start: usize,
        (depth, sah_depth): (usize, usize),
        bounds: Bounds,
    ) {
        let n = items.len();
        let Some((mid, [lb, rb])) = Self::split(items, keys, &bounds, depth, sah_depth) else {
            nodes[node] = Node {
                min: bounds.min,
                max: bounds.max,
                offset: start as u32,
                count: n as u32,
            };
            return;
        };
        let child = nodes.len();
        nodes[node] = Node {
            min: bounds.min,
            max: bounds.max,
            offset: child as u32,
            count: 0,
        };
        let blank = nodes[node];
        nodes.push(blank);
        nodes.push(blank);
        let next = (depth + 1, sah_depth);
        let (left, right) = items.split_at_mut(mid);
        let (lkeys, rkeys) = keys.split_at_mut(mid);
        Self::build_node(nodes, child, left, lkeys, start, next, lb);
        Self::build_node(nodes, child + 1, right, rkeys, start + mid, next, rb);
    }

    /// Partition `slice` (bounded by `bounds`; `keys` scratch of the same length) for an
    /// interior node: the size of the left part and the bounds of both parts; `None` when
    /// it should be a leaf.
    fn split(
        slice: &mut [Item],
        keys: &mut [u32],
        bounds: &Bounds,
        depth: usize,
        sah_depth: usize,
    ) -> Option<(usize, [Bounds; 2])> {
        let n = slice.len();
        if n <= LEAF_SIZE {
            return None;
        }
        // Binned SAH along the axis of largest centroid extent.
        let extent = bounds.cmax - bounds.cmin;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let halves = |slice: &[Item], mid: usize| {
            let (l, r) = slice.split_at(mid);
            Some((mid, [Bounds::of(l), Bounds::of(r)]))
        };
        if extent[axis] <= 0.0 {
            // All centroids coincide: split in the middle of the list.
            return halves(slice, n / 2);
        }
        if depth >= sah_depth {
            // Deep: the object median (ties by index, so the tree does not depend on the
            // input order's accidents), which halves the count at every level.
            slice.select_nth_unstable_by(n / 2, |p, q| {
                p.centroid[axis]
                    .total_cmp(&q.centroid[axis])
                    .then(p.index.cmp(&q.index))
            });
            return halves(slice, n / 2);
        }
        // One copy of the binning per axis, so the centroid's coordinate is a field
        // read rather than an index chosen at run time (half the cost of a bin).
        let cut = match axis {
            0 => Self::sah_cut::<0>(slice, keys, bounds),
            1 => Self::sah_cut::<1>(slice, keys, bounds),
            _ => Self::sah_cut::<2>(slice, keys, bounds),
        };
        match cut {
            Cut::Leaf => None,
            Cut::At(left, parts) => Some((left, parts)),
            // Defensive: SAH found no cut that keeps both sides non-empty.
            Cut::Unusable => halves(slice, n / 2),
        }
    }

    /// The binned SAH cut of `slice` across `AXIS` (whose centroid extent is positive),
    /// the slice partitioned at it; `keys` (as long as `slice`) is scratch.
    fn sah_cut<const AXIS: usize>(slice: &mut [Item], keys: &mut [u32], bounds: &Bounds) -> Cut {
        let n = slice.len();
        let mut bins = Bins::EMPTY;
        if n > 4 * PARALLEL_MIN {
            // The few largest nodes (the root's first levels), whose binning would
            // otherwise leave a core idle: in parallel, merged as the sets are.
            bins = slice
                .par_chunks(PARALLEL_MIN)
                .zip(keys.par_chunks_mut(PARALLEL_MIN))
                .map(|(items, keys)| {
                    let mut bins = Bins::EMPTY;
                    Self::bin::<AXIS, SETS>(items, keys, bounds, &mut bins);
                    bins
                })
                .reduce(
                    || Bins::EMPTY,
                    |mut a, b| {
                        a.merge(&b);
                        a
                    },
                );
        } else if n >= SETS_MIN {
            Self::bin::<AXIS, SETS>(slice, keys, bounds, &mut bins);
        } else {
            Self::bin::<AXIS, 1>(slice, keys, bounds, &mut bins);
        }
        // Only the non-empty bins, in order. A cut inside a run of empty bins has the
        // same two sides, hence the same cost, as the cut right after the run's last
        // non-empty bin, which comes first and so wins the ties (`<`): skipping the run
        // gives the cut the sweep over all bins gives, for a fraction of the work on the
        // small nodes that are most of the tree. Cuts leaving a side empty (before the
        // first or after the last) are no candidates.
        let mut used = [0usize; BINS];
        let mut m = 0;
        for (k, &c) in bins.count.iter().enumerate() {
            used[m] = k;
            m += (c > 0) as usize;
        }
        let used = &used[..m];
        // Sweep from the right to get suffix costs, then from the left to find the best cut
        // (after bin `used[j]`, j < m - 1).
        let mut right = [0f32; BINS];
        let (mut c, mut acc) = (0usize, Bounds::EMPTY);
        for j in (1..m).rev() {
            c += bins.count[used[j]];
            acc = acc.union(&bins.bounds[used[j]]);
            right[j] = c as f32 * area(acc.min, acc.max);
        }
        let (mut best, mut best_cost) = (0usize, f32::INFINITY);
        let (mut c, mut acc) = (0usize, Bounds::EMPTY);
        for j in 0..m.saturating_sub(1) {
            c += bins.count[used[j]];
            acc = acc.union(&bins.bounds[used[j]]);
            let cost = c as f32 * area(acc.min, acc.max) + right[j + 1];
            if cost < best_cost {
                best_cost = cost;
                best = j;
            }
        }
        // Leaf when splitting costs more than testing everything (box test ≈ 1/2 a cylinder).
        if n <= 2 * LEAF_SIZE && best_cost >= (n as f32 - 0.5) * area(bounds.min, bounds.max) {
            return Cut::Leaf;
        }
        if best_cost == f32::INFINITY {
            // No cut keeps both sides non-empty, or every cost overflowed (boxes of
            // extents past 1e19, beyond any scene's coordinates).
            return Cut::Unusable;
        }
        // The parts' bounds, unions of their bins (in any order: see `bin`).
        let mut left = 0;
        let mut parts = [Bounds::EMPTY; 2];
        for (j, &k) in used.iter().enumerate() {
            let side = (j > best) as usize;
            left += if side == 0 { bins.count[k] } else { 0 };
            parts[side] = parts[side].union(&bins.bounds[k]);
        }
        Self::partition(slice, keys, used[best] as u32, left);
        Cut::At(left, parts)
    }

    /// SAH bins of `slice` across `AXIS` (whose centroid extent is positive), added to
    /// `bins`; each item's bin to `keys`. `S` interleaved sets
    /// of bins, merged after: consecutive items often fall in the same bin, and one set
    /// would make each update wait for the last one's store. Counts, mins and maxes do not
    /// depend on the order they are taken in but for NaN and the sign of a zero (`min(+0,
    /// -0)` keeps either). Box corners are never 0 ([`round_out`]) nor NaN for finite
    /// boxes, so the merged box bounds are exactly those of one pass. A centroid can be -0
    /// (half a subnormal sum), and a centroid bound's zero may then differ in sign, but no
    /// choice sees it: the axis, the extent and the bins compare and subtract it, where +0
    /// and -0 agree.
    #[inline(always)]
    fn bin<const AXIS: usize, const S: usize>(
        slice: &[Item],
        keys: &mut [u32],
        bounds: &Bounds,
        bins: &mut Bins,
    ) {
        let at = |v: Vec3A| match AXIS {
            0 => v.x,
            1 => v.y,
            _ => v.z,
        };
        let low = at(bounds.cmin);
        let scale = BINS as f32 / (at(bounds.cmax) - low);
        // `(x as usize).min(BINS - 1)` without the saturating cast's fix-ups: NaN (0·inf
        // when the extent is subnormal) and negatives fail `x > 0` and go to bin 0 as
        // there; `x < 15` keeps the rest in range, so the cast is exact.
        let bin_of = |c: Vec3A| {
            let x = (at(c) - low) * scale;
            let x = if x > 0.0 { x } else { 0.0 };
            let x = if x < (BINS - 1) as f32 {
                x
            } else {
                (BINS - 1) as f32
            };
            // SAFETY: `x` is finite and in [0, BINS - 1] (clamped above).
            unsafe { x.to_int_unchecked::<u32>() }
        };
        // Set 0 is `bins` itself.
        let mut others = [Bins::EMPTY; S];
        let (items, items_tail) = slice.as_chunks::<S>();
        let (ks, keys_tail) = keys.as_chunks_mut::<S>();
        for (its, ks) in items.iter().zip(ks) {
            for s in 0..S {
                let k = bin_of(its[s].centroid);
                ks[s] = k;
                let b = if s == 0 { &mut *bins } else { &mut others[s] };
                b.count[k as usize] += 1;
                b.bounds[k as usize].add(&its[s]);
            }
        }
        for (it, k) in items_tail.iter().zip(keys_tail) {
            *k = bin_of(it.centroid);
            bins.count[*k as usize] += 1;
            bins.bounds[*k as usize].add(it);
        }
        for set in &others[1..] {
            bins.merge(set);
        }
    }

    /// Move the items whose key (bin) is at most `best`, `left` of them, to the front of
    /// `slice`, each swapped with one of the others that lie there. Branch-free: the
    /// positions of the misplaced items on either side are listed first (over the keys, in
    /// place), then swapped pairwise, so a side's unpredictable choice costs no mispredict.
    /// The result is a function of the keys alone.
    fn partition(slice: &mut [Item], keys: &mut [u32], best: u32, left: usize) {
        // Positions (relative to the part) of the items in the wrong part, listed over the
        // keys already read: the m-th is written at m ≤ the position being read.
        fn list(keys: &mut [u32], misplaced: impl Fn(u32) -> bool) -> usize {
            let mut m = 0;
            for i in 0..keys.len() {
                let k = keys[i];
                keys[m] = i as u32;
                m += misplaced(k) as usize;
            }
            m
        }
        let (lkeys, rkeys) = keys.split_at_mut(left);
        let ml = list(lkeys, |k| k > best);
        let mr = list(rkeys, |k| k <= best);
        // As many of one part's items lie in the other's as the other way round.
        assert_eq!(ml, mr, "a partition swaps pairs");
        let (l, r) = slice.split_at_mut(left);
        for (&i, &j) in lkeys[..ml].iter().zip(&rkeys[..mr]) {
            std::mem::swap(&mut l[i as usize], &mut r[j as usize]);
        }
    }

    /// Levels below the root of the deepest leaf.
    pub fn depth(&self) -> usize {
        let mut deepest = 0;
        let mut todo = vec![(0usize, 0usize)];
        while let Some((k, d)) = todo.pop() {
            let n = &self.nodes[k];
            deepest = deepest.max(d);
            if n.count == 0 && !self.order.is_empty() {
                todo.extend([(n.offset as usize, d + 1), (n.offset as usize + 1, d + 1)]);
            }
        }
        deepest
    }

    /// The primitive order of the leaves: a leaf covers positions `offset..offset + count`
    /// of it, and traversal reports positions, so whoever keeps per-primitive data in this
    /// order reads a leaf's primitives from consecutive memory.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// The padding [`Bvh::traverse_from`] needs for ray origins `o` (relative to the build
    /// origin, f64): four f32 roundings of the largest coordinate among `o` and the boxes.
    pub fn pad_for(&self, o: glam::DVec3) -> f32 {
        let root = match self.nodes.first() {
            Some(n) => n.min.abs().max(n.max.abs()).max_element(),
            None => 0.0,
        };
        let root = if root.is_finite() { root } else { 0.0 };
        let m = root.max(o.abs().max_element() as f32);
        4.0 * f32::EPSILON * m + f32::MIN_POSITIVE
    }

    /// Number of nodes (for statistics).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Visit the primitives whose boxes the ray `t·d` (origin at the build origin) meets
    /// within `[tmin, tmax]`, nearest box first. `visit(position)` gets the primitive's
    /// position in [`Bvh::order`] and returns a new, smaller `tmax` when it found a closer
    /// hit, which prunes the rest.
    #[inline]
    pub fn traverse(&self, d: Vec3A, tmin: f32, tmax: f32, visit: impl FnMut(u32) -> Option<f32>) {
        self.traverse_from(Vec3A::ZERO, 0.0, d, tmin, tmax, visit);
    }

    /// [`Bvh::traverse`] for the ray `o + t·d`, `o` relative to the build origin (parallel
    /// rays of an orthographic camera start off it). Every box is widened by `pad` world
    /// units on each side, which must cover the rounding of `o` to f32 and of the box
    /// corners minus `o` (see [`Bvh::pad_for`]); with `o = 0` and `pad = 0` the same visits,
    /// bit for bit, as [`Bvh::traverse`].
    #[inline]
    pub fn traverse_from(
        &self,
        o: Vec3A,
        pad: f32,
        d: Vec3A,
        tmin: f32,
        mut tmax: f32,
        mut visit: impl FnMut(u32) -> Option<f32>,
    ) {
        // 1/±0 = ±inf: a ray parallel to a slab is in it for every t or for none. Each axis
        // is entered by its near face (max when the ray goes towards -axis), so a face in
        // the ray's own plane (0·inf = NaN) drops out of the max and min below, which keep
        // their second operand on NaN: the ray is in that slab (faces are inclusive).
        let inv = Vec3A::ONE / d;
        let neg = inv.cmplt(Vec3A::ZERO);
        // pbrt's 1 + 2γ₃ keeps the f32 slab test conservative (see `SlabRay::new` for the
        // exit's three roundings).
        const GROW: f32 = 1.0 + 2.0 * 3.0 * f32::EPSILON;
        let inv_far = inv * GROW;
        let tmin_v = Vec3A::splat(tmin);
        let (lo_shift, hi_shift) = (o + Vec3A::splat(pad), o - Vec3A::splat(pad));
        let slab = |min: Vec3A, max: Vec3A, tmax: f32| -> Option<f32> {
            let (min, max) = (min - lo_shift, max - hi_shift);
            let near = (Vec3A::select(neg, max, min) * inv)
                .max(tmin_v)
                .max_element();
            let far = (Vec3A::select(neg, min, max) * inv_far)
                .min(Vec3A::splat(tmax))
                .min_element();
            (near <= far).then_some(near)
        };
        let hit = |n: &Node, tmax: f32| slab(n.min, n.max, tmax);
        // An empty scene is one leaf of nothing (read as interior below, so stop here).
        if self.order.is_empty() || hit(&self.nodes[0], tmax).is_none() {
            return;
        }
        // Pending far children and their entry distance.
        let mut stack = [(0u32, 0f32); MAX_DEPTH];
        let mut sp = 0usize;
        let mut current = 0u32;
        loop {
            let node = &self.nodes[current as usize];
            if node.count > 0 {
                let start = node.offset;
                for pos in start..start + node.count {
                    let [lo, hi] = self.boxes[pos as usize];
                    if slab(lo, hi, tmax).is_some()
                        && let Some(t) = visit(pos)
                    {
                        tmax = tmax.min(t);
                    }
                }
            } else {
                let (l, r) = (node.offset, node.offset + 1);
                let hl = hit(&self.nodes[l as usize], tmax);
                let hr = hit(&self.nodes[r as usize], tmax);
                match (hl, hr) {
                    (Some(a), Some(b)) => {
                        let (first, second) = if a <= b { (l, (r, b)) } else { (r, (l, a)) };
                        stack[sp] = second;
                        sp += 1;
                        current = first;
                        continue;
                    }
                    (Some(_), None) => {
                        current = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        current = r;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop, skipping nodes a closer hit has since made unreachable (the box's far
            // end was past its entry when pushed; only tmax has moved).
            loop {
                if sp == 0 {
                    return;
                }
                sp -= 1;
                let (n, near) = stack[sp];
                if near <= tmax {
                    current = n;
                    break;
                }
            }
        }
    }
}

/// The view cone of a block of pixel rays from the build origin: four planes through the
/// origin with inward normals (a point `p` is inside when `n·p >= 0` for all four), and the
/// camera's forward axis, along which a box's nearest camera-space z is measured.
#[derive(Clone, Copy, Debug)]
pub struct Cone {
    /// The four inward normals by axis: `x` holds the x components of the left, right,
    /// top and bottom planes' normals, and so on, so one box is tested against all four
    /// planes at once.
    x: Vec4,
    y: Vec4,
    z: Vec4,
    /// The camera's unit forward axis.
    forward: Vec3A,
}

impl Cone {
    /// The cone bounded by the planes with inward normals `planes` (left, right, top,
    /// bottom) along the unit axis `forward`.
    pub fn new(planes: [Vec3A; 4], forward: Vec3A) -> Self {
        let axis = |a: usize| Vec4::from_array(planes.map(|n| n[a]));
        Cone {
            x: axis(0),
            y: axis(1),
            z: axis(2),
            forward,
        }
    }

    /// Whether the f32 box `[min, max]` may meet the cone. Conservative: a box is rejected
    /// only when its farthest corner along some plane normal is behind that plane by more
    /// than the f32 rounding of the dot product (relative 1e-6 of its terms, 4 ulps of
    /// three products and two sums, plus the normal's own rounding). One lane per plane.
    #[inline(always)]
    fn meets(&self, min: Vec3A, max: Vec3A) -> bool {
        let (ax, bx) = (self.x * min.x, self.x * max.x);
        let (ay, by) = (self.y * min.y, self.y * max.y);
        let (az, bz) = (self.z * min.z, self.z * max.z);
        let far = ax.max(bx) + ay.max(by) + az.max(bz);
        let size = ax.abs().max(bx.abs()) + ay.abs().max(by.abs()) + az.abs().max(bz.abs());
        far.cmpge(size * -1e-6).all()
    }

    /// A lower bound on the camera-space z of the points of the box `[min, max]` (its
    /// nearest corner along `forward`, less the same rounding allowance). For a unit ray
    /// direction z = t·cos θ ≤ t, so it also bounds the ray parameter of any hit inside.
    #[inline(always)]
    fn z_min(&self, min: Vec3A, max: Vec3A) -> f32 {
        let (a, b) = (self.forward * min, self.forward * max);
        a.min(b).element_sum() - 1e-6 * a.abs().max(b.abs()).element_sum()
    }
}

/// A walk of the leaves of a [`Bvh`] whose boxes meet a [`Cone`], nearest first (children
/// in order of their nearest z), skipping every node whose nearest z lies beyond the reach
/// given to [`ConeWalk::next_leaf`]: no point in it can improve a ray whose best hit is
/// nearer. The caller passes the farthest best hit (or tmax) over all the cone's rays, so a
/// block of rays stops as soon as everything left is behind what it has found: occlusion
/// culling. (A loop the caller drives rather than a callback, so the caller's leaf code is
/// compiled into its own function, AVX and all.)
pub struct ConeWalk<'a> {
    bvh: &'a Bvh,
    cone: Cone,
    /// Pending far children and their nearest z.
    stack: [(u32, f32); MAX_DEPTH],
    sp: usize,
    /// The node to open next, if not the top of the stack.
    current: Option<u32>,
}

impl<'a> ConeWalk<'a> {
    /// Start at the root (an empty scene or a root outside the cone gives no leaf).
    #[inline(always)]
    pub fn new(bvh: &'a Bvh, cone: Cone) -> Self {
        let root = &bvh.nodes[0];
        let open = !bvh.order.is_empty() && cone.meets(root.min, root.max);
        ConeWalk {
            bvh,
            cone,
            stack: [(0, 0.0); MAX_DEPTH],
            sp: 0,
            current: open.then_some(0),
        }
    }

    /// The next leaf's range of positions in [`Bvh::order`], or `None` when no node left
    /// meets the cone at or before `reach`.
    #[inline(always)]
    pub fn next_leaf(&mut self, reach: f32) -> Option<Range<u32>> {
        let (nodes, cone) = (&self.bvh.nodes, &self.cone);
        loop {
            let current = match self.current.take() {
                Some(c) => c,
                None => loop {
                    if self.sp == 0 {
                        return None;
                    }
                    self.sp -= 1;
                    let (n, z) = self.stack[self.sp];
                    if z <= reach {
                        break n;
                    }
                },
            };
            let node = &nodes[current as usize];
            if node.count > 0 {
                return Some(node.offset..node.offset + node.count);
            }
            let (l, r) = (node.offset, node.offset + 1);
            let z = |k: u32| {
                let n = &nodes[k as usize];
                let z = cone.z_min(n.min, n.max);
                (z <= reach && cone.meets(n.min, n.max)).then_some(z)
            };
            match (z(l), z(r)) {
                (Some(a), Some(b)) => {
                    let (first, second) = if a <= b { (l, (r, b)) } else { (r, (l, a)) };
                    self.stack[self.sp] = second;
                    self.sp += 1;
                    self.current = Some(first);
                }
                (Some(_), None) => self.current = Some(l),
                (None, Some(_)) => self.current = Some(r),
                (None, None) => {}
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Every box a brute-force f64 slab test finds along each direction (clearly, not at
    /// a touching corner), the BVH reports.
    fn assert_finds_what_brute_force_does(bvh: &Bvh, boxes: &[(DVec3, DVec3)], dirs: &[DVec3]) {
        for &d in dirs {
            let mut found = vec![];
            bvh.traverse(d.as_vec3().into(), 0.0, f32::INFINITY, |i| {
                found.push(bvh.order()[i as usize]);
                None
            });
            for (i, &(lo, hi)) in boxes.iter().enumerate() {
                let t1 = lo / d;
                let t2 = hi / d;
                let near = t1.min(t2).max_element().max(0.0);
                let far = t1.max(t2).min_element();
                if near < far * (1.0 - 1e-9) {
                    assert!(found.contains(&(i as u32)), "box {i} missed for d = {d:?}");
                }
            }
        }
    }

    /// Differential test: the BVH reports every box a brute-force slab test finds.
    #[test]
    fn traversal_finds_every_box_brute_force_does() {
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64) / ((1u64 << 53) as f64)
        };
        let boxes: Vec<(DVec3, DVec3)> = (0..500)
            .map(|_| {
                let c = DVec3::new(rnd(), rnd(), rnd()) * 20.0 - 10.0;
                let e = DVec3::new(rnd(), rnd(), rnd()) * 0.5 + 0.01;
                (c - e, c + e)
            })
            .collect();
        let bvh = Bvh::build(&boxes, DVec3::ZERO);
        let dirs: Vec<DVec3> = (0..2000)
            .map(|_| (DVec3::new(rnd(), rnd(), rnd()) * 2.0 - 1.0).normalize())
            .collect();
        assert_finds_what_brute_force_does(&bvh, &boxes, &dirs);
    }

    /// Boxes at ±2^k along x (k from -120 to 80), a quarter as wide as they are far out:
    /// the scene binned SAH builds too deep (also used by the wide tree's tests).
    pub(crate) fn skewed_boxes() -> Vec<(DVec3, DVec3)> {
        (-120..=80)
            .flat_map(|k| {
                [1.0, -1.0].map(|s| {
                    let x = s * 2f64.powi(k);
                    let e = DVec3::new(0.25 * x.abs(), 1.0, 1.0);
                    (DVec3::new(x, 0.0, 0.0) - e, DVec3::new(x, 0.0, 0.0) + e)
                })
            })
            .collect()
    }

    /// Boxes at ±2^k along x (k from -120 to 80): binned SAH peels off the few boxes
    /// outside the first bin per level, so without the cap the tree is 99 levels deep, past
    /// the 64-entry traversal stack. With it the depth stays bounded and traversal still
    /// finds every box.
    #[test]
    fn skewed_scene_stays_within_the_stack() {
        let boxes = skewed_boxes();
        let uncapped = Bvh::build_capped(&boxes, DVec3::ZERO, usize::MAX).depth();
        assert!(
            uncapped > MAX_DEPTH,
            "the scene is skewed: depth {uncapped}"
        );
        let bvh = Bvh::build(&boxes, DVec3::ZERO);
        let depth = bvh.depth();
        // 30 SAH levels, then halving at most 402 boxes down to leaves of 4: 7 more.
        assert!(depth <= SAH_DEPTH + 7, "depth {depth}");
        let mut dirs = vec![DVec3::X, -DVec3::X];
        for k in 0..200 {
            let a = k as f64 * 0.0314;
            let tilt = 10f64.powi(-(k % 7));
            let d = DVec3::new(
                if k % 2 == 0 { 1.0 } else { -1.0 },
                tilt * a.cos(),
                tilt * a.sin(),
            );
            dirs.push(d.normalize());
        }
        assert_finds_what_brute_force_does(&bvh, &boxes, &dirs);
        let mut along_x = vec![];
        bvh.traverse(Vec3A::X, 0.0, f32::INFINITY, |i| {
            along_x.push(i);
            None
        });
        assert!(along_x.len() > 220, "{} boxes along +x", along_x.len());
    }

    /// The parallel build lays out exactly the tree the sequential one does (same nodes,
    /// same order), whatever the thread count.
    #[test]
    fn parallel_build_lays_out_the_sequential_tree() {
        let mut rng = crate::rng::SplitMix64::new(9);
        let boxes: Vec<(DVec3, DVec3)> = (0..40_000)
            .map(|_| {
                let c = rng.unit_vector() * rng.range(0.0, 30.0);
                let e = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 0.4 + 0.01;
                (c - e, c + e)
            })
            .collect();
        let origin = DVec3::new(40.0, -3.0, 7.0);
        // The sequential build: one call of the recursive builder over everything.
        let seq = {
            let mut items: Vec<Item> = boxes
                .iter()
                .enumerate()
                .map(|(i, &b)| Item::new(i, b, origin))
                .collect();
            let mut nodes = vec![Node {
                min: Vec3A::ZERO,
                max: Vec3A::ZERO,
                offset: 0,
                count: 0,
            }];
            let mut keys = vec![0; items.len()];
            let all = Bounds::of(&items);
            Bvh::build_node(&mut nodes, 0, &mut items, &mut keys, 0, (0, SAH_DEPTH), all);
            (nodes, items.iter().map(|it| it.index).collect::<Vec<u32>>())
        };
        assert!(seq.0.len() > 10_000);
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let bvh = pool.install(|| Bvh::build(&boxes, origin));
            assert!(bvh.nodes == seq.0, "{threads} threads: nodes differ");
            assert!(bvh.order == seq.1, "{threads} threads: order differs");
        }
    }

    /// The branch-free rounding of `round_out` agrees with rounding to nearest and stepping
    /// by `next_down` / `next_up`, except that it never gives ±0.
    #[test]
    fn round_out_rounds_as_next_down_and_next_up() {
        let reference = |a: f64, down: bool| {
            let r = a as f32;
            let tiny = if down {
                -f32::MIN_POSITIVE
            } else {
                f32::MIN_POSITIVE
            };
            let s = match (down, (r as f64) > a, (r as f64) < a) {
                _ if r == 0.0 => tiny,
                (true, true, _) => r.next_down(),
                (false, _, true) => r.next_up(),
                _ => r,
            };
            if s == 0.0 { tiny } else { s }
        };
        let mut rng = crate::rng::SplitMix64::new(3);
        let tiny = f32::from_bits(1) as f64;
        let mut values = vec![
            0.0,
            f64::MAX,
            f64::INFINITY,
            f64::NAN,
            f32::MAX as f64,
            f32::MAX as f64 * (1.0 + 1e-9),
            f32::MIN_POSITIVE as f64,
            tiny,
            tiny * 0.5,
            tiny * 0.75,
            tiny * 1.5,
            1.0,
            1.0 + 1e-12,
            0.1,
        ];
        for _ in 0..20_000 {
            let e = rng.range(-160.0, 140.0);
            let x = rng.range(-1.0, 1.0) * 2f64.powf(e);
            let f = x as f32 as f64;
            // Arbitrary values, exact f32 ones and their neighbours in f64.
            values.extend([x, f, f * (1.0 + 1e-12), f * (1.0 - 1e-12)]);
        }
        for a in values.iter().flat_map(|&a| [a, -a]) {
            for down in [true, false] {
                let (got, want) = (round_out(a, down), reference(a, down));
                assert_eq!(got.to_bits(), want.to_bits(), "{a:e} down {down}");
            }
        }
    }

    /// `Cone::meets` against the planes one corner at a time, in f64: a box with a corner
    /// clearly inside every plane meets the cone, and a box whose corners all lie clearly
    /// behind one plane does not. Boxes of all sizes straddle the planes.
    #[test]
    fn cone_meets_the_boxes_its_planes_admit() {
        let mut rng = crate::rng::SplitMix64::new(99);
        let mut rnd = || rng.unit();
        // A narrow view down +z, slightly turned: 0.05 wide, 0.03 tall at unit depth.
        let (f, l, u) = (
            DVec3::new(0.1, 0.05, 1.0).normalize(),
            DVec3::new(1.0, 0.0, -0.1).normalize(),
            DVec3::Y,
        );
        let planes = [-l - f * -0.02, l + f * 0.03, u - f * -0.01, -u + f * 0.02];
        let cone = Cone::new(planes.map(|n| n.as_vec3().into()), f.as_vec3().into());
        let (mut inside, mut outside) = (0, 0);
        for _ in 0..20_000 {
            // Around the cone: up to twice its width off its axis either way.
            let z = rnd() * 40.0;
            let c = f * z + (l * (rnd() - 0.5) + u * (rnd() - 0.5)) * 0.2 * z;
            let e = DVec3::new(rnd(), rnd(), rnd()) * 10f64.powf(rnd() * 3.0 - 2.0);
            let (lo, hi) = ((c - e).as_vec3(), (c + e).as_vec3());
            let corners = (0..8).map(|k| {
                let pick =
                    |bit: usize, a: f32, b: f32| f64::from(if k >> bit & 1 == 0 { a } else { b });
                DVec3::new(
                    pick(0, lo.x, hi.x),
                    pick(1, lo.y, hi.y),
                    pick(2, lo.z, hi.z),
                )
            });
            let margin = |p: DVec3| 1e-4 * p.length();
            let meets = cone.meets(lo.into(), hi.into());
            // The same answer as the plane-at-a-time form, with its rounding allowance.
            let one_by_one = planes.iter().all(|n| {
                let n: Vec3A = n.as_vec3().into();
                let (a, b) = (n * Vec3A::from(lo), n * Vec3A::from(hi));
                a.max(b).element_sum() >= -1e-6 * a.abs().max(b.abs()).element_sum()
            });
            assert_eq!(meets, one_by_one, "box {lo} {hi}");
            if corners
                .clone()
                .any(|p| planes.iter().all(|n| n.dot(p) > margin(p)))
            {
                assert!(meets, "box {lo} {hi} has a corner inside");
                inside += 1;
            }
            if planes
                .iter()
                .any(|n| corners.clone().all(|p| n.dot(p) < -margin(p)))
            {
                assert!(!meets, "box {lo} {hi} lies behind a plane");
                outside += 1;
            }
        }
        assert!(
            inside > 1_000 && outside > 5_000,
            "{inside} inside, {outside} outside"
        );
    }
}
