//! A compact bounding-volume hierarchy over cylinder boxes: binned SAH build, f32 boxes.
//!
//! Boxes are stored relative to the ray origin of the render (the camera), rounded outward
//! and padded, so the f32 slab test stays conservative even for scenes far from the world
//! origin, and rays start at 0. A scene of at most [`LEAF_SIZE`] cylinders is one leaf:
//! one box test per ray, no tree to pay for.

use glam::{DVec3, Vec3A};

/// Most primitives in a leaf.
pub const LEAF_SIZE: usize = 4;
const BINS: usize = 16;

#[derive(Clone, Copy, Debug)]
struct Node {
    min: Vec3A,
    max: Vec3A,
    /// Leaf: first index into `order`. Interior: index of the left child (right = +1).
    offset: u32,
    /// Primitives in a leaf; 0 for an interior node.
    count: u32,
}

/// The hierarchy: nodes (root first) and the primitive order its leaves index.
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

/// Round `x - o` to f32 toward -inf (`down`) or +inf and pad by a relative 1e-6, so the box
/// in f32 contains the exact one and no ray lies exactly in a face plane by accident.
fn outward(x: DVec3, o: DVec3, down: bool) -> Vec3A {
    let rel = x - o;
    let pad = rel.abs() * 1e-6 + DVec3::splat(1e-30);
    let v = if down { rel - pad } else { rel + pad };
    let f = |a: f64| {
        let r = a as f32;
        match (down, (r as f64) > a, (r as f64) < a) {
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

fn area(min: Vec3A, max: Vec3A) -> f32 {
    let e = (max - min).max(Vec3A::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl Bvh {
    /// Build over world-space boxes, stored relative to `origin`.
    pub fn build(bounds: &[(DVec3, DVec3)], origin: DVec3) -> Bvh {
        let mut items: Vec<Item> = bounds
            .iter()
            .enumerate()
            .map(|(i, &(lo, hi))| {
                let (min, max) = (outward(lo, origin, true), outward(hi, origin, false));
                Item {
                    min,
                    max,
                    centroid: (min + max) * 0.5,
                    index: i as u32,
                }
            })
            .collect();
        let mut nodes = Vec::with_capacity(2 * items.len().max(1));
        nodes.push(Node {
            min: Vec3A::ZERO,
            max: Vec3A::ZERO,
            offset: 0,
            count: 0,
        });
        let len = items.len();
        Self::build_node(&mut nodes, 0, &mut items, 0, len);
        Bvh {
            nodes,
            order: items.iter().map(|it| it.index).collect(),
        }
    }

    fn build_node(
        nodes: &mut Vec<Node>,
        node: usize,
        items: &mut [Item],
        start: usize,
        end: usize,
    ) {
        let slice = &mut items[start..end];
        let (mut min, mut max) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
        let (mut cmin, mut cmax) = (min, max);
        for it in slice.iter() {
            min = min.min(it.min);
            max = max.max(it.max);
            cmin = cmin.min(it.centroid);
            cmax = cmax.max(it.centroid);
        }
        let make_leaf = |nodes: &mut Vec<Node>| {
            nodes[node] = Node {
                min,
                max,
                offset: start as u32,
                count: (end - start) as u32,
            };
        };
        let n = slice.len();
        if n <= LEAF_SIZE {
            return make_leaf(nodes);
        }
        // Binned SAH along the axis of largest centroid extent.
        let extent = cmax - cmin;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let mid = if extent[axis] <= 0.0 {
            // All centroids coincide: split in the middle of the list.
            n / 2
        } else {
            let scale = BINS as f32 / extent[axis];
            let bin_of = |c: Vec3A| (((c[axis] - cmin[axis]) * scale) as usize).min(BINS - 1);
            let mut bins = [(
                0usize,
                Vec3A::splat(f32::INFINITY),
                Vec3A::splat(f32::NEG_INFINITY),
            ); BINS];
            for it in slice.iter() {
                let b = &mut bins[bin_of(it.centroid)];
                b.0 += 1;
                b.1 = b.1.min(it.min);
                b.2 = b.2.max(it.max);
            }
            // Sweep from the right to get suffix areas, then from the left to find the best cut.
            let mut right_cost = [0f32; BINS];
            let (mut c, mut lo, mut hi) = (
                0usize,
                Vec3A::splat(f32::INFINITY),
                Vec3A::splat(f32::NEG_INFINITY),
            );
            for k in (1..BINS).rev() {
                c += bins[k].0;
                lo = lo.min(bins[k].1);
                hi = hi.max(bins[k].2);
                right_cost[k] = c as f32 * area(lo, hi);
            }
            let (mut best, mut best_cost) = (0usize, f32::INFINITY);
            let (mut c, mut lo, mut hi) = (
                0usize,
                Vec3A::splat(f32::INFINITY),
                Vec3A::splat(f32::NEG_INFINITY),
            );
            for k in 0..BINS - 1 {
                c += bins[k].0;
                lo = lo.min(bins[k].1);
                hi = hi.max(bins[k].2);
                let cost = c as f32 * area(lo, hi) + right_cost[k + 1];
                if c > 0 && c < n && cost < best_cost {
                    best_cost = cost;
                    best = k;
                }
            }
            // Leaf when splitting costs more than testing everything (box test ≈ 1/2 a cylinder).
            if n <= 2 * LEAF_SIZE && best_cost >= (n as f32 - 0.5) * area(min, max) {
                return make_leaf(nodes);
            }
            let mut left = 0;
            for k in 0..n {
                if bin_of(slice[k].centroid) <= best {
                    slice.swap(k, left);
                    left += 1;
                }
            }
            if left == 0 || left == n { n / 2 } else { left }
        };
        let child = nodes.len();
        nodes[node] = Node {
            min,
            max,
            offset: child as u32,
            count: 0,
        };
        let blank = nodes[node];
        nodes.push(blank);
        nodes.push(blank);
        Self::build_node(nodes, child, items, start, start + mid);
        Self::build_node(nodes, child + 1, items, start + mid, end);
    }

    /// Number of nodes (for statistics).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Visit the primitives whose boxes the ray `t·d` (origin at the build origin) meets
    /// within `[tmin, tmax]`, nearest box first. `visit(index)` returns a new, smaller
    /// `tmax` when it found a closer hit, which prunes the rest.
    #[inline]
    pub fn traverse(
        &self,
        d: Vec3A,
        tmin: f32,
        mut tmax: f32,
        mut visit: impl FnMut(u32) -> Option<f32>,
    ) {
        // A zero component would make 0·inf = NaN on a face plane; clamp to a huge slope.
        let safe = |x: f32| {
            if x.abs() < 1e-30 {
                1e-30f32.copysign(x)
            } else {
                x
            }
        };
        let inv = Vec3A::new(1.0 / safe(d.x), 1.0 / safe(d.y), 1.0 / safe(d.z));
        // pbrt's 1 + 2γ₃ keeps the f32 slab test conservative.
        const GROW: f32 = 1.0 + 2.0 * 3.0 * f32::EPSILON;
        let hit = |n: &Node, tmax: f32| -> Option<f32> {
            let t1 = n.min * inv;
            let t2 = n.max * inv;
            let near = t1.min(t2).max_element().max(tmin);
            let far = (t1.max(t2).min_element() * GROW).min(tmax);
            (near <= far).then_some(near)
        };
        // An empty scene is one leaf of nothing (read as interior below, so stop here).
        if self.order.is_empty() || hit(&self.nodes[0], tmax).is_none() {
            return;
        }
        let mut stack = [0u32; 64];
        let mut sp = 0usize;
        let mut current = 0u32;
        loop {
            let node = &self.nodes[current as usize];
            if node.count > 0 {
                let start = node.offset as usize;
                for &prim in &self.order[start..start + node.count as usize] {
                    if let Some(t) = visit(prim) {
                        tmax = tmax.min(t);
                    }
                }
            } else {
                let (l, r) = (node.offset, node.offset + 1);
                let hl = hit(&self.nodes[l as usize], tmax);
                let hr = hit(&self.nodes[r as usize], tmax);
                match (hl, hr) {
                    (Some(a), Some(b)) => {
                        let (first, second) = if a <= b { (l, r) } else { (r, l) };
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
            // Pop, skipping nodes a closer hit has since made unreachable.
            loop {
                if sp == 0 {
                    return;
                }
                sp -= 1;
                let n = stack[sp];
                if hit(&self.nodes[n as usize], tmax).is_some() {
                    current = n;
                    break;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        for _ in 0..2000 {
            let d = (DVec3::new(rnd(), rnd(), rnd()) * 2.0 - 1.0).normalize();
            let mut found = vec![];
            bvh.traverse(d.as_vec3().into(), 0.0, f32::INFINITY, |i| {
                found.push(i);
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
}
