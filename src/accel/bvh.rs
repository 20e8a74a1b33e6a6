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

use glam::{DVec3, Vec3A};
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
    let f = |a: f64| {
        let r = a as f32;
        match (down, (r as f64) > a, (r as f64) < a) {
            (true, _, _) if r == 0.0 => -f32::MIN_POSITIVE,
            (false, _, _) if r == 0.0 => f32::MIN_POSITIVE,
            (true, true, _) => r.next_down(),
            (false, _, true) => r.next_up(),
            _ => r,
        }
    };
    Vec3A::new(f(v.x), f(v.y), f(v.z))
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
        let nodes = Self::build_tree(&mut items, (0, sah_depth), all);
        Bvh {
            nodes,
            order: items.par_iter().map(|it| it.index).collect(),
            boxes: items.par_iter().map(|it| [it.min, it.max]).collect(),
        }
    }

    /// The tree over `items` (bounded by `bounds`), root first, laid out as the sequential
    /// build lays it out: large subtrees are split here and their halves built in
    /// parallel ([`Part`]), then every node is written once to its place in one list.
    fn build_tree(items: &mut [Item], depth: (usize, usize), bounds: Bounds) -> Vec<Node> {
        let part = Self::build_part(items, 0, depth, bounds);
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
    fn build_part(items: &mut [Item], start: usize, depth: (usize, usize), bounds: Bounds) -> Part {
        let n = items.len();
        let split = (n > PARALLEL_MIN)
            .then(|| Self::split(items, &bounds, depth.0, depth.1))
            .flatten();
        let Some((mid, [lb, rb])) = split else {
            let mut nodes = Vec::with_capacity(2 * n.max(1));
            nodes.push(BLANK);
            Self::build_node(&mut nodes, 0, items, 0, n, depth, bounds);
            // Leaves index the slice; shift them to positions in the whole order.
            for node in nodes.iter_mut().filter(|k| k.count > 0) {
                node.offset += start as u32;
            }
            return Part::Nodes(nodes);
        };
        let (left, right) = items.split_at_mut(mid);
        let next = (depth.0 + 1, depth.1);
        let (l, r) = rayon::join(
            || Self::build_part(left, start, next, lb),
            || Self::build_part(right, start + mid, next, rb),
        );
        Part::Split(bounds, Box::new([l, r]))
    }

    fn build_node(
        nodes: &mut Vec<Node>,
        node: usize,
        items: &mut [Item],
        start: usize,
        end: usize,
        (depth, sah_depth): (usize, usize),
        bounds: Bounds,
    ) {
        let slice = &mut items[start..end];
        let Some((mid, [lb, rb])) = Self::split(slice, &bounds, depth, sah_depth) else {
            nodes[node] = Node {
                min: bounds.min,
                max: bounds.max,
                offset: start as u32,
                count: (end - start) as u32,
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
        Self::build_node(nodes, child, items, start, start + mid, next, lb);
        Self::build_node(nodes, child + 1, items, start + mid, end, next, rb);
    }

    /// Partition `slice` (bounded by `bounds`) for an interior node: the size of the left
    /// part and the bounds of both parts; `None` when it should be a leaf.
    fn split(
        slice: &mut [Item],
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
            0 => Self::sah_cut::<0>(slice, bounds),
            1 => Self::sah_cut::<1>(slice, bounds),
            _ => Self::sah_cut::<2>(slice, bounds),
        };
        match cut {
            Cut::Leaf => None,
            Cut::At(left, parts) => Some((left, parts)),
            // Defensive: SAH found no cut that keeps both sides non-empty.
            Cut::Unusable => halves(slice, n / 2),
        }
    }

    /// The binned SAH cut of `slice` across `AXIS` (whose centroid extent is positive),
    /// the slice partitioned at it.
    fn sah_cut<const AXIS: usize>(slice: &mut [Item], bounds: &Bounds) -> Cut {
        let n = slice.len();
        let at = |v: Vec3A| match AXIS {
            0 => v.x,
            1 => v.y,
            _ => v.z,
        };
        let low = at(bounds.cmin);
        let scale = BINS as f32 / (at(bounds.cmax) - low);
        let bin_of = |c: Vec3A| (((at(c) - low) * scale) as usize).min(BINS - 1);
        let mut bins = [(0usize, Bounds::EMPTY); BINS];
        for it in slice.iter() {
            let b = &mut bins[bin_of(it.centroid)];
            b.0 += 1;
            b.1.add(it);
        }
        // Sweep from the right to get suffix areas, then from the left to find the best cut.
        let mut right = [(0f32, Bounds::EMPTY); BINS];
        let (mut c, mut acc) = (0usize, Bounds::EMPTY);
        for k in (1..BINS).rev() {
            c += bins[k].0;
            acc = acc.union(&bins[k].1);
            right[k] = (c as f32 * area(acc.min, acc.max), acc);
        }
        let (mut best, mut best_cost, mut best_left) = (0usize, f32::INFINITY, Bounds::EMPTY);
        let (mut c, mut acc) = (0usize, Bounds::EMPTY);
        for k in 0..BINS - 1 {
            c += bins[k].0;
            acc = acc.union(&bins[k].1);
            let cost = c as f32 * area(acc.min, acc.max) + right[k + 1].0;
            if c > 0 && c < n && cost < best_cost {
                best_cost = cost;
                best = k;
                best_left = acc;
            }
        }
        // Leaf when splitting costs more than testing everything (box test ≈ 1/2 a cylinder).
        if n <= 2 * LEAF_SIZE && best_cost >= (n as f32 - 0.5) * area(bounds.min, bounds.max) {
            return Cut::Leaf;
        }
        let mut left = 0;
        for k in 0..n {
            if bin_of(slice[k].centroid) <= best {
                slice.swap(k, left);
                left += 1;
            }
        }
        if left == 0 || left == n {
            return Cut::Unusable;
        }
        Cut::At(left, [best_left, right[best + 1].1])
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
    /// Inward normals of the left, right, top and bottom planes.
    pub planes: [Vec3A; 4],
    /// The camera's unit forward axis.
    pub forward: Vec3A,
}

impl Cone {
    /// Whether the f32 box `[min, max]` may meet the cone. Conservative: a box is rejected
    /// only when its farthest corner along some plane normal is behind that plane by more
    /// than the f32 rounding of the dot product (relative 1e-6 of its terms, 4 ulps of
    /// three products and two sums, plus the normal's own rounding).
    #[inline(always)]
    fn meets(&self, min: Vec3A, max: Vec3A) -> bool {
        self.planes.iter().all(|&n| {
            let (a, b) = (n * min, n * max);
            let far = a.max(b);
            far.element_sum() >= -1e-6 * a.abs().max(b.abs()).element_sum()
        })
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
            let n = items.len();
            let all = Bounds::of(&items);
            Bvh::build_node(&mut nodes, 0, &mut items, 0, n, (0, SAH_DEPTH), all);
            (nodes, items.iter().map(|it| it.index).collect::<Vec<u32>>())
        };
        assert!(seq.0.len() > 10_000);
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let bvh = pool.install(|| Bvh::build(&boxes, origin));
            assert!(bvh.nodes == seq.0, "{threads} threads: nodes differ");
            assert!(bvh.order == seq.1, "{threads} threads: order differs");
        }
    }
}
