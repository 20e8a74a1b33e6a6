//! The eight-wide BVH that rays of any direction traverse one at a time.
//!
//! Collapsed from the binary tree of [`Bvh`]: each wide node takes up to eight of the
//! binary tree's nodes below it, chosen to minimise the surface-area cost of the whole
//! tree (`Plan`), and opens leaves down to their cylinders, so a lane holds either a
//! subtree or one cylinder's own box. A node stores its eight boxes as six rows of eight
//! f32 (min x, y, z, max x, y, z), so one ray meets all eight in a handful of vector
//! operations (in AVX registers when the run-time check found AVX2, else the same
//! operations lane by lane: the same lanes either way).
//!
//! A node's lanes are ordered at build from far to near by their box's distance from the
//! origin, where every ray starts (a lower bound on any ray's entry into the box). A ray
//! opens a node, visits the cylinders it meets there at once, nearest lane first, packs
//! the met subtrees onto its stack with one shuffle and one store (no branch on how many),
//! and goes on to the nearest of them, or to the top of the stack when none is met. No
//! sort and no test on the way out of the stack (a subtree entered beyond a hit found
//! since it was kept costs one more box test): the branches on counts and distances a
//! sorted traversal takes follow no pattern, and mispredicted twice as often.
//!
//! One ray's nodes follow one another (the next address is known only when the boxes of
//! its parent are tested), so that chain's latency, not the work, bounds a traversal:
//! `WideBvh::traverse_in_turn` walks [`IN_TURN`] rays in turn, the processor working
//! on the others while one waits, which a mispredicted branch, flushing them all, would
//! undo. Alone, this walk is slower than a sorted one (its chain is longer); in turn it is
//! faster, most with four rays (see [`IN_TURN`]).
//!
//! The boxes are the binary tree's: relative to the render's origin, rounded outward to
//! f32 and padded (see [`bvh`](super::bvh)), and the exit distance is widened by pbrt's
//! `1 + 2γ₃`, so the test stays conservative: a cylinder whose exact box the ray meets
//! within `[tmin, tmax]` is visited.

use super::bvh::{Bvh, MAX_DEPTH, area};
use crate::geometry::wide::{ANY_OCTANT, Met8, SlabRay, Slabs8};
use glam::Vec3A;
use rayon::prelude::*;

/// Lanes of a node.
pub const WIDTH: usize = 8;
/// A binary leaf holds at most `2 · LEAF_SIZE` cylinders (the build's SAH leaf rule), so
/// one wide node can always open it down to its cylinders.
const _: () = assert!(2 * super::bvh::LEAF_SIZE <= WIDTH);
/// A lane's child with this bit set is a cylinder (its position in [`Bvh::order`]),
/// else a node index. Positions and node indices stay below 2³¹ for any scene that fits
/// in memory (a node takes 224 bytes, a cylinder more than 64).
const PRIM: u32 = 1 << 31;
/// Entries of the traversal stack. A node at wide depth `k` is opened with at most `7k`
/// entries pending (each ancestor packed at most eight lanes and took one of them), and
/// writes eight above them, over the sentinel entry at the bottom, so `1 + 7·D + 8`
/// entries suffice for a tree of depth `D`. Each wide level descends at least one binary
/// level and the binary tree's leaves lie less than [`MAX_DEPTH`] levels down, so
/// `D < MAX_DEPTH` and `8 · MAX_DEPTH` is enough.
pub const STACK: usize = 8 * MAX_DEPTH;
/// Rays the per-ray walk takes in turn (`WideBvh::traverse_in_turn`): fewer leave the
/// latency of each ray's chain of nodes uncovered, more no longer keep the walks' state in
/// registers. Backed by the trace column of `cylaov bench --accel bvh --family dense
/// --counts 100000`.
pub const IN_TURN: usize = 4;

/// pbrt's 1 + 2γ₃: the f32 slab test's exit distance widened by its rounding.
const GROW: f32 = 1.0 + 2.0 * 3.0 * f32::EPSILON;

/// Eight child boxes and what they hold. An empty lane's box is `+inf..-inf`: every ray
/// enters it at +inf or later than it leaves, so it is never met.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
struct Node8 {
    /// Rows min x, min y, min z, max x, max y, max z; lane `l` is child `l`'s box.
    planes: [[f32; WIDTH]; 6],
    /// Per lane: a node index, or [`PRIM`] | a position in [`Bvh::order`].
    child: [u32; WIDTH],
}

const EMPTY: Node8 = Node8 {
    planes: [
        [f32::INFINITY; WIDTH],
        [f32::INFINITY; WIDTH],
        [f32::INFINITY; WIDTH],
        [f32::NEG_INFINITY; WIDTH],
        [f32::NEG_INFINITY; WIDTH],
        [f32::NEG_INFINITY; WIDTH],
    ],
    child: [0; WIDTH],
};

/// The wide tree over a [`Bvh`]'s boxes: root first, positions as in [`Bvh::order`].
#[derive(Clone, Debug)]
pub struct WideBvh {
    nodes: Vec<Node8>,
    /// Wide levels below the root of the deepest node.
    depth: usize,
}

/// The traversal stack of a [`WideBvh`]: the nodes still to open. Kept by the caller and
/// reused from ray to ray (2 KiB: clearing one per ray would cost more than many a ray's
/// traversal).
pub struct Stack(Box<[u32; STACK]>);

impl Default for Stack {
    fn default() -> Self {
        Stack(Box::new([0; STACK]))
    }
}

/// What a traversal does with each cylinder it meets: `visit(ray, position)` tests ray
/// `ray`'s cylinder at `position` in [`Bvh::order`] and returns a new, smaller `tmax` when
/// it found a closer hit. A trait rather than a closure so that an implementation marked
/// `#[inline(always)]` is compiled into the traversal (with its target features): a call
/// would spill the walk's registers around every cylinder test (any closure does).
pub(crate) trait Visit {
    /// Test the cylinder at `position` for ray `ray`; a closer hit's distance, if any.
    fn visit(&mut self, ray: usize, position: u32) -> Option<f32>;
}

impl<F: FnMut(usize, u32) -> Option<f32>> Visit for F {
    #[inline(always)]
    fn visit(&mut self, ray: usize, position: u32) -> Option<f32> {
        self(ray, position)
    }
}

/// What a wide node's lane takes from the binary tree while the node is being filled.
#[derive(Clone, Copy)]
enum Slot {
    /// A binary node, opened later into a wide node of its own.
    Node(u32),
    /// One cylinder, by position.
    Prim(u32),
}

/// Wide levels whose subtrees collapse in parallel: 8² = 64 tasks, enough for any core
/// count this runs on, and each below them collapses sequentially into its own list.
const PARALLEL_LEVELS: usize = 2;

/// A node's lanes as [`WideBvh::lanes`] picks them: what each holds and its box, far to
/// near, and how many are used.
type Lanes = ([(Slot, Vec3A, Vec3A); WIDTH], usize);

/// How the collapse spreads each binary subtree over a wide node's lanes: the choice of
/// least surface-area cost (the optimal collapse of Ylitie, Karras and Laine, "Efficient
/// incoherent ray traversal on GPUs through compressed wide BVHs", 2017), found bottom-up
/// for every node and lane budget, then read top-down by [`Plan::open`].
///
/// A ray that meets a wide node's box opens it (eight box tests), with a probability its
/// surface area measures; every cylinder takes one lane in any collapse, so the cylinder
/// tests cost the same whatever is chosen, and the cost to minimise is the sum of the wide
/// nodes' areas. `lanes(n, j)`, the least cost of binary node `n`'s subtree in at most `j`
/// lanes of its parent, is the smaller of `n` whole in one lane (its own wide node:
/// `area(n) + split(n, 8)`) and `split(n, j)`: a leaf's cylinders in a lane each (0 when
/// they fit), or an interior node's two children sharing the lanes, the least over `k`
/// of `lanes(left, k) + lanes(right, j − k)`. It makes fewer wide nodes than the greedy
/// rule (open the largest node that still fits, as Embree's wide builders do), and primary
/// rays open fewer of them (`plan_collapses_at_least_cost` checks that no collapse costs
/// less).
struct Plan {
    /// Per binary node, per budget `j` (index `j − 1`): the lanes `split(n, j)` gives its
    /// left child (0 for a leaf, whose cylinders take a lane each).
    left: Vec<[u8; WIDTH]>,
    /// Per binary node: bit `j − 1` set where `lanes(n, j)` keeps `n` whole.
    whole: Vec<u8>,
}

impl Plan {
    fn new(bvh: &Bvh) -> Plan {
        let nodes = &bvh.nodes;
        let count = nodes.len();
        let (mut left, mut whole) = (vec![[0u8; WIDTH]; count], vec![0u8; count]);
        // `lanes(n, j)` per node; children lie after their parent in `nodes` (both builds
        // push a node's children after it), so a pass from the end meets them first.
        let mut cost = vec![[0f32; WIDTH]; count];
        for k in (0..count).rev() {
            let n = &nodes[k];
            let mut split = [f32::INFINITY; WIDTH];
            if n.count > 0 {
                split[n.count as usize - 1..].fill(0.0);
            } else {
                debug_assert!(n.offset as usize > k, "children after their parent");
                let (l, r) = (&cost[n.offset as usize], &cost[n.offset as usize + 1]);
                for j in 2..=WIDTH {
                    // Picked without a branch: which share wins follows no pattern.
                    let (mut best, mut at) = (f32::INFINITY, 0u8);
                    for kl in 1..j {
                        let c = l[kl - 1] + r[j - kl - 1];
                        let better = c < best;
                        best = std::hint::select_unpredictable(better, c, best);
                        at = std::hint::select_unpredictable(better, kl as u8, at);
                    }
                    (split[j - 1], left[k][j - 1]) = (best, at);
                }
            }
            let one = area(n.min, n.max) + split[WIDTH - 1];
            for j in 0..WIDTH {
                cost[k][j] = if one < split[j] {
                    whole[k] |= 1 << j;
                    one
                } else {
                    split[j]
                };
            }
        }
        Plan { left, whole }
    }

    /// Append to `slots` the lanes of binary node `b`'s own wide node: its subtree spread
    /// over at most `budget` lanes, `b` itself never whole.
    fn open(&self, bvh: &Bvh, b: u32, budget: usize, slots: &mut [Slot; WIDTH], len: &mut usize) {
        let n = bvh.nodes[b as usize];
        if n.count > 0 {
            for p in n.offset..n.offset + n.count {
                slots[*len] = Slot::Prim(p);
                *len += 1;
            }
            return;
        }
        let kl = self.left[b as usize][budget - 1] as usize;
        self.place(bvh, n.offset, kl, slots, len);
        self.place(bvh, n.offset + 1, budget - kl, slots, len);
    }

    /// Append binary node `b` in at most `budget` lanes: whole, or opened.
    fn place(&self, bvh: &Bvh, b: u32, budget: usize, slots: &mut [Slot; WIDTH], len: &mut usize) {
        if self.whole[b as usize] & (1 << (budget - 1)) != 0 {
            slots[*len] = Slot::Node(b);
            *len += 1;
        } else {
            self.open(bvh, b, budget, slots, len);
        }
    }
}

impl WideBvh {
    /// Collapse `bvh` into eight-wide nodes.
    pub fn new(bvh: &Bvh) -> WideBvh {
        let (nodes, depth) = if bvh.order().is_empty() {
            (Vec::new(), 0)
        } else {
            Self::collapse_parallel(bvh, &Plan::new(bvh), 0, 0)
        };
        // The stack bound above: the binary build guarantees it; a failure is a bug here.
        assert!(depth < MAX_DEPTH, "wide depth {depth}");
        WideBvh { nodes, depth }
    }

    /// The lanes of the wide node of binary node `b`, as `plan` spreads its subtree.
    fn lanes(bvh: &Bvh, plan: &Plan, b: u32) -> Lanes {
        let nodes = &bvh.nodes;
        let mut slots = [Slot::Node(b); WIDTH];
        let mut len = 0;
        plan.open(bvh, b, WIDTH, &mut slots, &mut len);
        let boxed = |s: Slot| match s {
            Slot::Node(k) => (nodes[k as usize].min, nodes[k as usize].max),
            Slot::Prim(p) => (bvh.boxes[p as usize][0], bvh.boxes[p as usize][1]),
        };
        // Lanes from far to near: by the distance from the origin (where every ray starts)
        // to the box, a lower bound on any ray's entry, then to its centre (boxes around
        // the origin); the traversal takes the highest met lane first.
        let mut keyed = [(0.0, 0.0, Slot::Node(b)); WIDTH];
        for (lane, &s) in keyed.iter_mut().zip(&slots[..len]) {
            let (min, max) = boxed(s);
            let gap = min.max(Vec3A::ZERO) - max.min(Vec3A::ZERO);
            *lane = (
                gap.length_squared(),
                ((min + max) * 0.5).length_squared(),
                s,
            );
        }
        let keyed = &mut keyed[..len];
        keyed.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(b.1.total_cmp(&a.1)));
        let mut lanes = [(Slot::Node(b), Vec3A::ZERO, Vec3A::ZERO); WIDTH];
        for (lane, &(_, _, s)) in lanes.iter_mut().zip(keyed.iter()) {
            let (min, max) = boxed(s);
            *lane = (s, min, max);
        }
        (lanes, len)
    }

    /// The wide node of `lanes`, lane `l` holding `child[l]`.
    fn node(lanes: &Lanes, child: &[u32; WIDTH]) -> Node8 {
        let mut node = EMPTY;
        for (l, &(_, min, max)) in lanes.0[..lanes.1].iter().enumerate() {
            for a in 0..3 {
                node.planes[a][l] = min[a];
                node.planes[a + 3][l] = max[a];
            }
            node.child[l] = child[l];
        }
        node
    }

    /// Append the wide node of binary node `b` (at wide depth `depth`) and its subtrees to
    /// `out`: root first, then each subtree in lane order, indices into `out`. Returns
    /// the deepest wide depth.
    fn collapse(out: &mut Vec<Node8>, bvh: &Bvh, plan: &Plan, b: u32, depth: usize) -> usize {
        let lanes = Self::lanes(bvh, plan, b);
        let at = out.len();
        out.push(EMPTY);
        let (mut deepest, mut child) = (depth, [0u32; WIDTH]);
        for (l, &(s, _, _)) in lanes.0[..lanes.1].iter().enumerate() {
            child[l] = match s {
                Slot::Node(k) => {
                    let c = out.len() as u32;
                    deepest = deepest.max(Self::collapse(out, bvh, plan, k, depth + 1));
                    c
                }
                Slot::Prim(p) => PRIM | p,
            };
        }
        out[at] = Self::node(&lanes, &child);
        deepest
    }

    /// [`WideBvh::collapse`] into a list of its own, the subtrees of the top
    /// [`PARALLEL_LEVELS`] collapsed in parallel and laid out as the sequential collapse
    /// lays them out, so the tree is the same on any number of threads.
    fn collapse_parallel(bvh: &Bvh, plan: &Plan, b: u32, depth: usize) -> (Vec<Node8>, usize) {
        if depth >= PARALLEL_LEVELS {
            // About one wide node for every 5 cylinders (5.4 in a tangle of 100 000):
            // with a third reserved, the list is not copied to grow (untouched capacity
            // costs no memory).
            let mut out = Vec::with_capacity(Self::cylinders_under(bvh, b) / 3 + 1);
            let deepest = Self::collapse(&mut out, bvh, plan, b, depth);
            return (out, deepest);
        }
        let lanes = Self::lanes(bvh, plan, b);
        let subtrees: Vec<(Vec<Node8>, usize)> = lanes.0[..lanes.1]
            .par_iter()
            .map(|&(s, _, _)| match s {
                Slot::Node(k) => Self::collapse_parallel(bvh, plan, k, depth + 1),
                Slot::Prim(_) => (Vec::new(), depth),
            })
            .collect();
        let mut out = Vec::with_capacity(1 + subtrees.iter().map(|t| t.0.len()).sum::<usize>());
        out.push(EMPTY);
        let (mut deepest, mut child) = (depth, [0u32; WIDTH]);
        for (l, ((sub, d), &(s, _, _))) in subtrees.into_iter().zip(&lanes.0).enumerate() {
            deepest = deepest.max(d);
            child[l] = match s {
                Slot::Node(_) => {
                    // The subtree's node indices were into its own list (0, its root,
                    // is no node's child: it marks an empty lane).
                    let base = out.len() as u32;
                    out.extend(sub.into_iter().map(|mut n| {
                        for c in n.child.iter_mut().filter(|c| **c != 0 && **c & PRIM == 0) {
                            *c += base;
                        }
                        n
                    }));
                    base
                }
                Slot::Prim(p) => PRIM | p,
            };
        }
        out[0] = Self::node(&lanes, &child);
        (out, deepest)
    }

    /// How many cylinders lie under binary node `b`: a subtree's leaves hold consecutive
    /// positions, from its leftmost leaf's first to its rightmost leaf's last.
    fn cylinders_under(bvh: &Bvh, b: u32) -> usize {
        let leaf = |right: u32| {
            let mut k = b as usize;
            while bvh.nodes[k].count == 0 {
                k = (bvh.nodes[k].offset + right) as usize;
            }
            bvh.nodes[k]
        };
        let (first, last) = (leaf(0), leaf(1));
        (last.offset + last.count - first.offset) as usize
    }

    /// Wide levels below the root of the deepest node.
    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Number of nodes (for statistics).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Visit the cylinders whose boxes the ray `t·d` (origin at the build origin) meets
    /// within `[tmin, tmax]`, as [`Bvh::traverse`] does: `visit(position)`
    /// gets the position in [`Bvh::order`] and returns a new, smaller `tmax` when it found
    /// a closer hit. `slabs` is `()` or an AVX2 token: the same lanes either way.
    #[inline(always)]
    pub(crate) fn traverse<S: Slabs8>(
        &self,
        slabs: S,
        stack: &mut Stack,
        d: Vec3A,
        tmin: f32,
        tmax: f32,
        mut visit: impl FnMut(u32) -> Option<f32>,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let mut walk = Walk::new(d, tmin, tmax);
        let mut visit = |_, p| visit(p);
        while self.step::<S, ANY_OCTANT>(slabs, &mut walk, &mut stack.0, &mut visit, 0) {}
    }

    /// [`WideBvh::traverse`] for [`IN_TURN`] rays at once, a node of each in turn, so the
    /// processor works on the others while one waits: a ray's nodes follow one another
    /// (the next one's address is known only when its parent's boxes are tested), and the
    /// latency of that chain, not the work, bounds one ray's traversal. When one ray is
    /// done the others go on in turn. `visit.visit(i, position)` is ray `i`'s visit.
    /// Written out ray by ray: walks kept in an array and stepped in a loop stay in
    /// memory, and were slower than two written out.
    #[inline(always)]
    pub(crate) fn traverse_in_turn<S: Slabs8>(
        &self,
        slabs: S,
        stacks: &mut [Stack; IN_TURN],
        rays: [(Vec3A, f32, f32); IN_TURN],
        visit: &mut impl Visit,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let walk = |i: usize| Walk::new(rays[i].0, rays[i].1, rays[i].2);
        let walks = [walk(0), walk(1), walk(2), walk(3)];
        // Rays of neighbouring pixels nearly always share an octant: then the walk reads
        // its near and far rows at fixed offsets (one copy of it per octant), which takes
        // six loads off every node.
        let o = walks[0].ray.octant();
        if walks.iter().any(|w| w.ray.octant() != o) {
            return self.in_turn::<S, ANY_OCTANT>(slabs, stacks, walks, visit);
        }
        match o {
            0 => self.in_turn::<S, 0>(slabs, stacks, walks, visit),
            1 => self.in_turn::<S, 1>(slabs, stacks, walks, visit),
            2 => self.in_turn::<S, 2>(slabs, stacks, walks, visit),
            3 => self.in_turn::<S, 3>(slabs, stacks, walks, visit),
            4 => self.in_turn::<S, 4>(slabs, stacks, walks, visit),
            5 => self.in_turn::<S, 5>(slabs, stacks, walks, visit),
            6 => self.in_turn::<S, 6>(slabs, stacks, walks, visit),
            _ => self.in_turn::<S, 7>(slabs, stacks, walks, visit),
        }
    }

    /// The walks of [`WideBvh::traverse_in_turn`], all of octant `OCT` (or any).
    #[inline(always)]
    fn in_turn<S: Slabs8, const OCT: usize>(
        &self,
        slabs: S,
        stacks: &mut [Stack; IN_TURN],
        [mut w0, mut w1, mut w2, mut w3]: [Walk; IN_TURN],
        visit: &mut impl Visit,
    ) {
        let [s0, s1, s2, s3] = stacks;
        let mut live = [true; IN_TURN];
        while live == [true; IN_TURN] {
            live[0] = self.step::<S, OCT>(slabs, &mut w0, &mut s0.0, visit, 0);
            live[1] = self.step::<S, OCT>(slabs, &mut w1, &mut s1.0, visit, 1);
            live[2] = self.step::<S, OCT>(slabs, &mut w2, &mut s2.0, visit, 2);
            live[3] = self.step::<S, OCT>(slabs, &mut w3, &mut s3.0, visit, 3);
        }
        while live != [false; IN_TURN] {
            if live[0] {
                live[0] = self.step::<S, OCT>(slabs, &mut w0, &mut s0.0, visit, 0);
            }
            if live[1] {
                live[1] = self.step::<S, OCT>(slabs, &mut w1, &mut s1.0, visit, 1);
            }
            if live[2] {
                live[2] = self.step::<S, OCT>(slabs, &mut w2, &mut s2.0, visit, 2);
            }
            if live[3] {
                live[3] = self.step::<S, OCT>(slabs, &mut w3, &mut s3.0, visit, 3);
            }
        }
    }

    /// Open the walk's current node: visit the cylinders it meets (as ray `ray`), keep the
    /// subtrees and move to the next node. False when none is left.
    #[inline(always)]
    fn step<S: Slabs8, const OCT: usize>(
        &self,
        slabs: S,
        w: &mut Walk,
        st: &mut [u32; STACK],
        visit: &mut impl Visit,
        ray: usize,
    ) -> bool {
        let sp = w.sp;
        debug_assert!((w.current as usize) < self.nodes.len() && sp >= 1 && sp + WIDTH <= STACK);
        // SAFETY: `current` is the root, a child a node's lane holds, or a stack entry
        // below `sp`, which the lanes' children wrote (or `stack[0]`, never written: 0,
        // the root); the collapse writes only indices of its nodes, and no node is added
        // after. `sp` is at least 1 (a walk stops at 0) and stays below `1 + 7·depth`
        // (the bound at [`STACK`]: `new` asserts the depth), so `sp + WIDTH` entries fit.
        // Unchecked: the checks were 7.5% of the trace's instructions (as below).
        let (node, out) = unsafe {
            (
                self.nodes.get_unchecked(w.current as usize),
                &mut *(st.as_mut_ptr().add(sp) as *mut [u32; WIDTH]),
            )
        };
        // The met subtrees go above the top, nearest last.
        let Met8 { met, packed } =
            slabs.slabs8::<OCT>(&node.planes, &node.child, &w.ray, w.tmax, out);
        // Cylinders met: visited now, nearest box first.
        let mut prims = met & !packed;
        while prims != 0 {
            let l = 7 - prims.leading_zeros() as usize;
            prims ^= 1 << l;
            if let Some(t) = visit.visit(ray, node.child[l] & !PRIM) {
                w.tmax = w.tmax.min(t);
            }
        }
        // Next: the nearest subtree met, else the top of the stack (picked without a
        // branch: a quarter of the nodes meet no subtree, in no pattern); the others
        // stay. A subtree whose box starts beyond a hit found since it was kept is still
        // opened: it meets nothing, at the cost of one box test, less than a mispredicted
        // branch to skip it often costs.
        let n = packed.count_ones() as usize;
        let nearest = node.child[7 - (packed | 1).leading_zeros() as usize];
        // SAFETY: `1 <= sp < STACK`, as above.
        let top = unsafe { *st.get_unchecked(sp - 1) };
        w.current = std::hint::select_unpredictable(n > 0, nearest, top);
        w.sp = sp + n - 1;
        w.sp != 0
    }
}

/// One ray's traversal state.
struct Walk {
    ray: SlabRay,
    tmax: f32,
    /// Pending nodes are `stack[1..sp]`, the top last; `stack[0]` is read, never used,
    /// when none is left.
    sp: usize,
    /// The node to open next.
    current: u32,
}

impl Walk {
    #[inline(always)]
    fn new(d: Vec3A, tmin: f32, tmax: f32) -> Walk {
        Walk {
            ray: SlabRay::new(d.to_array(), tmin, GROW),
            tmax,
            sp: 1,
            current: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::wide::Avx2;
    use crate::rng::SplitMix64;
    use glam::DVec3;

    /// What a traversal visits along `d` (positions, sorted), with no pruning.
    fn wide_visits<S: Slabs8>(w: &WideBvh, s: S, d: Vec3A, tmin: f32, tmax: f32) -> Vec<u32> {
        let mut found = vec![];
        w.traverse(s, &mut Stack::default(), d, tmin, tmax, |p| {
            found.push(p);
            None
        });
        found.sort();
        found
    }

    /// [`wide_visits`] of [`IN_TURN`] rays traversed together.
    fn group_visits<S: Slabs8>(
        w: &WideBvh,
        s: S,
        rays: [(Vec3A, f32, f32); IN_TURN],
    ) -> [Vec<u32>; IN_TURN] {
        let mut found: [Vec<u32>; IN_TURN] = Default::default();
        let mut stacks: [Stack; IN_TURN] = Default::default();
        w.traverse_in_turn(s, &mut stacks, rays, &mut |i: usize, p| {
            found[i].push(p);
            None
        });
        found.map(|mut f| {
            f.sort();
            f
        })
    }

    fn binary_visits(b: &Bvh, d: Vec3A, tmin: f32, tmax: f32) -> Vec<u32> {
        let mut found = vec![];
        b.traverse(d, tmin, tmax, |p| {
            found.push(p);
            None
        });
        found.sort();
        found
    }

    /// The exact boxes of cylinders shaped as the dense bench family's (lengths 0.3–3,
    /// radii 0.05–0.6, any direction) in a 20-unit cube: a tangle of overlapping boxes.
    fn tangle(n: usize, seed: u64) -> Vec<(DVec3, DVec3)> {
        let mut rng = SplitMix64::new(seed);
        (0..n)
            .map(|_| {
                let p = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 20.0 - 10.0;
                let a = rng.unit_vector();
                let q = p + a * rng.range(0.3, 3.0);
                let r = rng.range(0.05, 0.6);
                let ext = r * (DVec3::ONE - a * a).max(DVec3::ZERO).sqrt();
                (p.min(q) - ext, p.max(q) + ext)
            })
            .collect()
    }

    /// The positions of the boxes a brute-force f64 slab test finds along `d` from
    /// `origin` within `range`, clearly (not at a touching corner: every traversal must
    /// report these).
    fn clearly_met(
        bvh: &Bvh,
        boxes: &[(DVec3, DVec3)],
        origin: DVec3,
        d: DVec3,
        (tmin, tmax): (f64, f64),
    ) -> Vec<u32> {
        let mut met = vec![];
        for (pos, &i) in bvh.order().iter().enumerate() {
            let (lo, hi) = boxes[i as usize];
            let (t1, t2) = ((lo - origin) / d, (hi - origin) / d);
            let near = t1.min(t2).max_element().max(tmin);
            let far = t1.max(t2).min_element().min(tmax);
            if near < far * (1.0 - 1e-9) {
                met.push(pos as u32);
            }
        }
        met
    }

    /// Every box a brute-force f64 slab test finds clearly (not at a touching corner), the
    /// wide traversal visits, portable and AVX2 alike; and it visits exactly what the
    /// binary tree's traversal visits (the same f32 test on the same leaf boxes), for rays
    /// from outside the cloud and from inside it (many start inside boxes), with and
    /// without a segment limit.
    /// The parallel collapse lays out the sequential collapse's tree, on any number of
    /// threads; the cylinders it counts under a node are its leaves' cylinders.
    #[test]
    fn parallel_collapse_lays_out_the_sequential_tree() {
        let boxes = tangle(20_000, 5);
        let bvh = Bvh::build(&boxes, DVec3::new(30.0, -20.0, 12.0));
        assert_eq!(WideBvh::cylinders_under(&bvh, 0), 20_000);
        for k in 0..bvh.nodes.len() as u32 {
            let n = bvh.nodes[k as usize];
            let want = if n.count > 0 {
                n.count as usize
            } else {
                let kids = [n.offset, n.offset + 1];
                kids.map(|c| WideBvh::cylinders_under(&bvh, c)).iter().sum()
            };
            assert_eq!(WideBvh::cylinders_under(&bvh, k), want, "node {k}");
        }
        let mut seq = Vec::new();
        let depth = WideBvh::collapse(&mut seq, &bvh, &Plan::new(&bvh), 0, 0);
        assert!(
            depth >= PARALLEL_LEVELS + 2,
            "depth {depth}: too shallow to test"
        );
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let wide = pool.install(|| WideBvh::new(&bvh));
            assert!(wide.nodes == seq, "{threads} threads: nodes differ");
            assert_eq!(wide.depth, depth);
        }
    }

    /// Every way to put binary node `n`'s subtree in lanes (`opened`: not whole): lanes
    /// taken and surface-area cost, listed one by one, up to eight lanes.
    fn fills(bvh: &Bvh, n: u32, opened: bool) -> Vec<(usize, f64)> {
        let node = bvh.nodes[n as usize];
        let mut ways = if opened {
            vec![]
        } else {
            vec![(1, least(bvh, n))]
        };
        if node.count > 0 {
            ways.push((node.count as usize, 0.0));
        } else {
            for (a, ca) in fills(bvh, node.offset, false) {
                for (b, cb) in fills(bvh, node.offset + 1, false) {
                    if a + b <= WIDTH {
                        ways.push((a + b, ca + cb));
                    }
                }
            }
        }
        ways
    }

    /// The least cost of binary node `n` as a wide node, by trying every way to fill it.
    fn least(bvh: &Bvh, n: u32) -> f64 {
        let node = bvh.nodes[n as usize];
        let best = fills(bvh, n, true).into_iter().map(|w| w.1);
        area(node.min, node.max) as f64 + best.reduce(f64::min).unwrap()
    }

    /// The plan's collapse costs the least of all collapses: the summed area of its wide
    /// nodes (each the union of its lanes' boxes) is the least that trying every way to
    /// fill every node finds, on small tangles two or three wide levels deep (the greedy
    /// rule fails here: 2 503 against 2 431 on the first).
    #[test]
    fn plan_collapses_at_least_cost() {
        let mut deep = 0;
        for seed in 0..24 {
            let boxes = tangle(30 + seed as usize, seed);
            let bvh = Bvh::build(&boxes, DVec3::new(26.0, -30.0, 18.0));
            let wide = WideBvh::new(&bvh);
            let built: f64 = wide
                .nodes
                .iter()
                .map(|n| {
                    let lo =
                        std::array::from_fn(|a| n.planes[a].into_iter().reduce(f32::min).unwrap());
                    let hi = std::array::from_fn(|a| {
                        n.planes[a + 3].into_iter().reduce(f32::max).unwrap()
                    });
                    area(Vec3A::from_array(lo), Vec3A::from_array(hi)) as f64
                })
                .sum();
            let best = least(&bvh, 0);
            assert!(
                (built - best).abs() <= 1e-5 * best,
                "seed {seed}: {built} against {best}"
            );
            deep += (wide.depth() >= 2) as usize;
        }
        assert!(deep >= 12, "{deep} of 24 trees two wide levels deep");
    }

    #[test]
    fn wide_traversal_finds_what_brute_force_and_the_binary_tree_do() {
        let boxes = tangle(3000, 5);
        let mut rng = SplitMix64::new(77);
        let mut rays = 0;
        // From outside the cloud, and from the centres of two boxes (inside a few).
        let centre = |(lo, hi): (DVec3, DVec3)| (lo + hi) * 0.5;
        for origin in [
            DVec3::new(26.0, -30.0, 18.0),
            centre(boxes[0]),
            centre(boxes[1]),
        ] {
            let bvh = Bvh::build(&boxes, origin);
            let wide = WideBvh::new(&bvh);
            let mut group = [(Vec3A::X, 0.0, f32::INFINITY); IN_TURN];
            for k in 0..1500 {
                let d = rng.unit_vector();
                let (tmin, tmax) = if k % 3 == 0 {
                    (0.5, 12.0)
                } else {
                    (0.0, f32::INFINITY)
                };
                let d32 = d.as_vec3().into();
                let w = wide_visits(&wide, (), d32, tmin, tmax);
                assert_eq!(w, binary_visits(&bvh, d32, tmin, tmax), "d = {d:?}");
                if let Some(tok) = Avx2::detect() {
                    assert_eq!(
                        w,
                        wide_visits(&wide, tok, d32, tmin, tmax),
                        "AVX2, d = {d:?}"
                    );
                }
                for pos in clearly_met(&bvh, &boxes, origin, d, (tmin as f64, tmax as f64)) {
                    assert!(w.binary_search(&pos).is_ok(), "position {pos}, d = {d:?}");
                }
                // Together with the three rays before (another range every third ray),
                // each visits what it visits alone.
                group.rotate_left(1);
                group[IN_TURN - 1] = (d32, tmin, tmax);
                // Mixed octants, then the same rays turned into this ray's octant (the
                // walk of one octant reads its rows at fixed offsets).
                let same = group.map(|(g, lo, hi)| (g.abs() * d32.signum(), lo, hi));
                for set in [group, same] {
                    let alone = set.map(|(d, lo, hi)| wide_visits(&wide, (), d, lo, hi));
                    assert_eq!(group_visits(&wide, (), set), alone, "d = {d:?}");
                    if let Some(tok) = Avx2::detect() {
                        assert_eq!(group_visits(&wide, tok, set), alone, "AVX2, d = {d:?}");
                    }
                }
                rays += 1;
            }
        }
        assert_eq!(rays, 4500);
    }

    /// With pruning (each visit reports a hit at the box's entry), the nearest box the
    /// wide traversal settles on is the binary tree's and brute force's.
    #[test]
    fn pruned_traversal_keeps_the_nearest() {
        let boxes = tangle(2000, 8);
        let origin = DVec3::new(20.0, 4.0, -9.0);
        let bvh = Bvh::build(&boxes, origin);
        let wide = WideBvh::new(&bvh);
        let mut rng = SplitMix64::new(3);
        let mut hits = 0;
        for _ in 0..2000 {
            // Towards the cloud, so most rays meet boxes.
            let aim = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 16.0 - 8.0;
            let d = (aim - origin).normalize();
            let d32: Vec3A = d.as_vec3().into();
            // Nearest box entry by brute force, in the same f32 arithmetic.
            let entry = |p: u32| {
                let [lo, hi] = bvh.boxes[p as usize];
                let inv = Vec3A::ONE / d32;
                let (t1, t2) = (lo * inv, hi * inv);
                let (near, far) = (t1.min(t2).max_element().max(0.0), t1.max(t2).min_element());
                (near <= far * GROW).then_some(near)
            };
            let brute = (0..boxes.len() as u32).filter_map(entry).reduce(f32::min);
            // Each visit reports a hit at the box's entry when it is the nearest so far.
            let (mut w, mut b) = (None::<f32>, None::<f32>);
            let closer = |best: &mut Option<f32>, p: u32| {
                let t = entry(p)?;
                best.is_none_or(|b| t < b).then(|| *best.insert(t))
            };
            wide.traverse((), &mut Stack::default(), d32, 0.0, f32::INFINITY, |p| {
                closer(&mut w, p)
            });
            bvh.traverse(d32, 0.0, f32::INFINITY, |p| closer(&mut b, p));
            assert_eq!(w, brute, "d = {d:?}");
            assert_eq!(b, brute, "d = {d:?}");
            // Four rays at once (this ray again, from bounds just and well past its
            // nearest box): all settle on it.
            let mut group = [None::<f32>; IN_TURN];
            let mut stacks: [Stack; IN_TURN] = Default::default();
            let bound = |f: f32| brute.map_or(f32::INFINITY, |t| t * f + 1e-3);
            let rays = [bound(1.0), bound(1.01), bound(2.0), f32::INFINITY].map(|b| (d32, 0.0, b));
            wide.traverse_in_turn((), &mut stacks, rays, &mut |i: usize, p| {
                closer(&mut group[i], p)
            });
            assert_eq!(group, [brute; IN_TURN], "group, d = {d:?}");
            hits += w.is_some() as usize;
        }
        assert!(hits > 1000, "{hits} of 2000 rays meet a box");
    }

    /// The skewed scene of the binary tree's depth-cap test (boxes at ±2^k along x): the
    /// wide tree is no deeper than the binary one, so it stays within its stack.
    #[test]
    fn skewed_scene_stays_within_the_wide_stack() {
        let boxes = crate::accel::bvh::tests::skewed_boxes();
        let bvh = Bvh::build(&boxes, DVec3::ZERO);
        let wide = WideBvh::new(&bvh);
        assert!(bvh.depth() > 30, "binary depth {}", bvh.depth());
        assert!(
            wide.depth() <= bvh.depth(),
            "wide {} binary {}",
            wide.depth(),
            bvh.depth()
        );
        // Along ±x every box of that side lies on the ray; tilted by 1e-7 the ray leaves
        // the boxes' |y| <= 1 near x = 1e7, past 165 of them.
        for (d, least) in [
            (DVec3::X, 220),
            (-DVec3::X, 220),
            (DVec3::new(1.0, 1e-7, 0.0), 160),
        ] {
            let d = d.normalize();
            let d32: Vec3A = d.as_vec3().into();
            let w = wide_visits(&wide, (), d32, 0.0, f32::INFINITY);
            assert_eq!(w, binary_visits(&bvh, d32, 0.0, f32::INFINITY));
            assert!(w.len() > least, "{} boxes along {d}", w.len());
            for pos in clearly_met(&bvh, &boxes, DVec3::ZERO, d, (0.0, f64::INFINITY)) {
                assert!(w.binary_search(&pos).is_ok(), "position {pos}, d = {d:?}");
            }
        }
    }

    /// Each node's box test, portable and AVX2: the same lanes met and the same children
    /// packed, in lane order; and the lanes are ordered far to near from the origin.
    #[test]
    fn box_tests_agree_and_lanes_run_far_to_near() {
        let boxes = tangle(3000, 9);
        let origin = DVec3::new(26.0, -30.0, 18.0);
        let wide = WideBvh::new(&Bvh::build(&boxes, origin));
        let mut rng = SplitMix64::new(4);
        let (mut met, mut packed) = (0, 0);
        for node in &wide.nodes {
            // Box distance from the origin, per filled lane: never increasing.
            let gaps: Vec<f32> = (0..WIDTH)
                .filter(|&l| node.planes[0][l] <= node.planes[3][l])
                .map(|l| {
                    let lo = Vec3A::from_array(std::array::from_fn(|a| node.planes[a][l]));
                    let hi = Vec3A::from_array(std::array::from_fn(|a| node.planes[a + 3][l]));
                    (lo.max(Vec3A::ZERO) - hi.min(Vec3A::ZERO)).length_squared()
                })
                .collect();
            assert!(gaps.windows(2).all(|g| g[0] >= g[1]), "{gaps:?}");
            let Some(tok) = Avx2::detect() else { continue };
            for _ in 0..20 {
                // Towards the cloud, so that many lanes are met.
                let aim = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 20.0 - 10.0;
                let d: Vec3A = (aim - origin).normalize().as_vec3().into();
                let ray = SlabRay::new(d.to_array(), 0.0, GROW);
                let tmax = if rng.unit() < 0.5 {
                    f32::INFINITY
                } else {
                    40.0
                };
                let (mut a, mut b) = ([0; WIDTH], [0; WIDTH]);
                let p = ().slabs8::<ANY_OCTANT>(&node.planes, &node.child, &ray, tmax, &mut a);
                let v = tok.slabs8::<ANY_OCTANT>(&node.planes, &node.child, &ray, tmax, &mut b);
                let n = p.packed.count_ones() as usize;
                assert_eq!((p, &a[..n]), (v, &b[..n]), "d = {d:?}");
                let lanes = (0..WIDTH).filter(|&l| p.packed & (1 << l) != 0);
                assert!(lanes.zip(&a[..n]).all(|(l, &c)| node.child[l] == c));
                assert_eq!(p.packed & !p.met, 0);
                (met, packed) = (met + p.met.count_ones(), packed + n as u32);
            }
        }
        // Measured: 774 lanes met, 484 of them subtrees (the rest cylinders).
        if Avx2::detect().is_some() {
            assert!(
                met > packed && packed > 300,
                "{met} lanes met, {packed} packed"
            );
        }
    }

    /// A ray lying in faces of boxes (direction components ±0, faces level with the
    /// origin: on an edge or a corner of each box) is in them: the binary traversal and
    /// the wide one, portable and AVX2, visit every box ahead and none behind.
    #[test]
    fn rays_in_a_face_plane_meet_the_box() {
        // Boxes along +x, each with y and z ranges that end or start at 0.
        let sides = [(-1.0, 0.0), (0.0, 1.0), (-0.5, 0.0), (0.0, 0.25)];
        let boxes: Vec<(DVec3, DVec3)> = (0..40)
            .map(|i| {
                let (y, z) = (sides[i % 4], sides[(i / 4) % 4]);
                let x = 2.0 + i as f64 * 0.5;
                (DVec3::new(x, y.0, z.0), DVec3::new(x + 0.4, y.1, z.1))
            })
            .collect();
        for n in [1, 3, 40] {
            let bvh = Bvh::build(&boxes[..n], DVec3::ZERO);
            let wide = WideBvh::new(&bvh);
            let all: Vec<u32> = (0..n as u32).collect();
            for (y, z) in [(0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -0.0)] {
                for (x, want) in [(1.0f32, &all[..]), (-1.0, &[][..])] {
                    let d = Vec3A::new(x, y, z);
                    let inf = f32::INFINITY;
                    assert_eq!(binary_visits(&bvh, d, 0.0, inf), want, "{n}: d = {d:?}");
                    assert_eq!(wide_visits(&wide, (), d, 0.0, inf), want, "{n}: d = {d:?}");
                    if let Some(tok) = Avx2::detect() {
                        let w = wide_visits(&wide, tok, d, 0.0, inf);
                        assert_eq!(w, want, "AVX2, {n}: d = {d:?}");
                    }
                }
            }
        }
    }

    /// Empty and one-box scenes: nothing visited, and the one box visited once.
    #[test]
    fn tiny_scenes() {
        let none = WideBvh::new(&Bvh::build(&[], DVec3::ZERO));
        assert!(wide_visits(&none, (), Vec3A::X, 0.0, f32::INFINITY).is_empty());
        let one = [(DVec3::new(2.0, -1.0, -1.0), DVec3::new(3.0, 1.0, 1.0))];
        let w = WideBvh::new(&Bvh::build(&one, DVec3::ZERO));
        assert_eq!(wide_visits(&w, (), Vec3A::X, 0.0, f32::INFINITY), vec![0]);
        assert!(wide_visits(&w, (), -Vec3A::X, 0.0, f32::INFINITY).is_empty());
        assert!(wide_visits(&w, (), Vec3A::X, 0.0, 1.5).is_empty());
    }
}
