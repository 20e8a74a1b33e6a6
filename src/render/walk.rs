//! The tile walk: a band (one row of 16×16 tiles) traced tile by tile, each tile's
//! candidates from its screen-tile list or a cone walk of the BVH, rasterised over just
//! the pixels each candidate can cover, then shaded into the band's planes.

use super::planes::{Band, BandInputs, shade};
use super::tracer::{ConeCands, PixelHit, Tracer, f32_up};
use crate::accel::bvh::{Bvh, Cone, ConeWalk};
use crate::accel::tiles::{Candidate, TILE};
use crate::accel::wide_bvh::{IN_TURN, Stack};
use crate::geometry::packet::{NO_HIT, Packet, PacketFormula};
use crate::geometry::wide::LANES;
use crate::geometry::wide::{Avx2, Lanes, Simd, Wide};
use crate::geometry::{BasicHit, Real, Surface};
use crate::scene::camera::Camera;
use glam::{DVec3, Vec3A};
use std::ops::Range;

/// Nearest hits for the pixels `xs × ys` (inclusive) of one tile from its candidates,
/// rasterised nearest first (see [`rasterise`]). `offsets` are the image-plane offsets per
/// column (padded to whole tiles) and per row.
#[inline(always)]
pub(super) fn trace_tile<T: Real, F: PacketFormula, W: Wide<T>>(
    tok: W::Token,
    tracer: &Tracer<T, F>,
    cands: &[Candidate],
    xs: (u32, u32),
    ys: (u32, u32),
    offsets: (&[f64], &[f64]),
    rays: &mut TileRays<T>,
) {
    rays.ready = 0;
    // A tracer that prepared no kernels makes one from the scene's cylinder at the first
    // test, and the list visits those cylinders in no order memory's follows: prefetched.
    let lazy = tracer.prepared.is_empty();
    for (k, c) in cands.iter().enumerate() {
        if lazy && let Some(ahead) = cands.get(k + crate::mem::PREFETCH_AHEAD) {
            crate::mem::prefetch(&tracer.cylinders[ahead.index as usize]);
        }
        rasterise::<T, F, W, false>(tok, tracer, c, xs, ys, offsets, rays);
    }
}

/// [`trace_tile`] with the candidates found by walking `bvh` with the tile's view cone,
/// nearest node first, until every pixel of the tile has a hit nearer than the next node
/// (or no node is left): occlusion culling. `cands` gives each slot's projection.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn trace_cone<T: Real, F: PacketFormula, W: Wide<T>>(
    tok: W::Token,
    tracer: &Tracer<T, F>,
    bvh: &Bvh,
    cands: &ConeCands,
    xs: (u32, u32),
    ys: (u32, u32),
    offsets: (&[f64], &[f64]),
    rays: &mut TileRays<T>,
) {
    rays.ready = 0;
    let cone = tile_cone(&tracer.camera, xs, ys, offsets);
    // The packets holding image pixels: every row of the tile, the groups of eight
    // columns up to the tile's last (lanes past the image's edge are not counted in the
    // reach: their rays exist, but no pixel needs them).
    let (tw, rows) = ((xs.1 - xs.0 + 1) as usize, (ys.1 - ys.0 + 1) as usize);
    let groups = tw.div_ceil(LANES);
    let row_mask = (1u32 << groups) - 1;
    let valid = (0..rows).fold(0u32, |m, r| m | row_mask << (r * PACKETS_PER_ROW));
    rays.lanes = [LANES as u8; PACKETS];
    for r in 0..rows {
        rays.lanes[r * PACKETS_PER_ROW + groups - 1] = (tw - (groups - 1) * LANES) as u8;
    }
    let mut walk = ConeWalk::new(bvh, cone);
    let mut reach = f32::INFINITY;
    while let Some(range) = walk.next_leaf(reach) {
        for slot in range {
            let c = cands.get(slot, &tracer.order);
            if !c.is_culled() {
                rasterise::<T, F, W, true>(tok, tracer, &c, xs, ys, offsets, rays);
            }
        }
        // Until every pixel has had a candidate, some ray still reaches its tmax.
        if rays.ready & valid == valid {
            let mut far = 0.0f64;
            for k in 0..PACKETS {
                if valid & (1 << k) != 0 {
                    far = far.max(rays.far[k]);
                }
            }
            reach = f32_up(far);
        }
    }
}

/// The view cone of the pixels `xs × ys`, widened by a pixel on every side (the walk must
/// not lose a box to rounding; the candidates' own bounds decide which pixels it covers).
/// A pixel ray is `forward − left·x + up·y` (then normalised), so the rays with column
/// offset `x >= a` satisfy `v·(−left − a·forward) >= 0`, and so on for the other sides.
pub(super) fn tile_cone(
    cam: &Camera,
    xs: (u32, u32),
    ys: (u32, u32),
    (cols, rows): (&[f64], &[f64]),
) -> Cone {
    let step_x = (cols[1] - cols[0]).abs();
    let step_y = if rows.len() > 1 {
        (rows[1] - rows[0]).abs()
    } else {
        2.0 * cam.tan_half_y
    };
    let (x0, x1) = (cols[xs.0 as usize], cols[xs.1 as usize]);
    let (y0, y1) = (rows[ys.0 as usize], rows[ys.1 as usize]);
    let (a, b) = (x0.min(x1) - step_x, x0.max(x1) + step_x);
    let (c, d) = (y0.min(y1) - step_y, y0.max(y1) + step_y);
    let (f, l, u) = (cam.forward, cam.left, cam.true_up);
    let v = |p: DVec3| Vec3A::new(p.x as f32, p.y as f32, p.z as f32);
    Cone::new([-l - f * a, l + f * b, u - f * c, -u + f * d].map(v), v(f))
}

/// Test candidate `c` against the pixels of tile `xs × ys` it can cover: it visits only
/// its row spans, eight pixels at a time ([`Packet`]), and skips pixels whose best hit is
/// nearer than its `t_min`. Packets are set up on first use. With `CONE`, each touched
/// packet's farthest reach is kept up to date (the cone walk's stopping rule reads it).
#[inline(always)]
pub(super) fn rasterise<T: Real, F: PacketFormula, W: Wide<T>, const CONE: bool>(
    tok: W::Token,
    tracer: &Tracer<T, F>,
    c: &Candidate,
    xs: (u32, u32),
    ys: (u32, u32),
    offsets: (&[f64], &[f64]),
    rays: &mut TileRays<T>,
) {
    if CONE && (c.x1 < xs.0 || c.x0 > xs.1 || c.y1 < ys.0 || c.y0 > ys.1) {
        return;
    }
    // The prepared kernel, or for a tracer that prepares none, one made at the first
    // test (most candidates of a tiny view's list are skipped untested).
    let prepared = tracer.prepared.get(c.slot as usize);
    let mut made = None;
    for j in c.y0.max(ys.0)..=c.y1.min(ys.1) {
        let Some((a, b)) = c.row_span(j, xs.0, xs.1) else {
            continue;
        };
        let (a, b) = ((a - xs.0) as usize, (b - xs.0) as usize);
        for g in a / LANES..=b / LANES {
            let k = (j - ys.0) as usize * PACKETS_PER_ROW + g;
            if rays.ready & (1 << k) == 0 {
                let x0 = xs.0 as usize + g * LANES;
                let cols = &offsets.0[x0..x0 + LANES];
                setup(
                    &tracer.camera,
                    &mut rays.packets[k],
                    &mut rays.dirs[k],
                    cols,
                    offsets.1[j as usize],
                );
                // tmax padded as a best hit is (below): a hit the kernel keeps at
                // its rounded tmax must not be skipped.
                rays.reach[k] = rays.packets[k]
                    .t
                    .map(|t| t.to_f64() * (1.0 + 8.0 * T::UNIT_ROUNDOFF));
                rays.ready |= 1 << k;
                if CONE {
                    rays.far[k] = farthest(&rays.reach[k], rays.lanes[k]);
                }
            }
            // Lanes of the span whose best hit is not nearer than the candidate.
            let (lo, hi) = (
                a.max(g * LANES) - g * LANES,
                b.min(g * LANES + LANES - 1) - g * LANES,
            );
            let span = ((1u32 << (hi + 1)) - (1 << lo)) as u8;
            let mask = span & W::le_bits(tok, c.t_min, &rays.reach[k]);
            if mask == 0 {
                continue;
            }
            let prepared = match prepared {
                Some(p) => p,
                None => made.get_or_insert_with(|| tracer.kernel(c.index)),
            };
            let pk = &mut rays.packets[k];
            let changed = F::intersect_packet::<T, W>(tok, prepared, (c.index, c.slot), pk, mask);
            if changed != 0 {
                for l in 0..LANES {
                    // Padded by 8ε of the kernel: a candidate whose t rounds just
                    // below this hit's must still be tested (ties decide by index).
                    if changed & (1 << l) != 0 {
                        rays.reach[k][l] = pk.t[l].to_f64() * (1.0 + 8.0 * T::UNIT_ROUNDOFF);
                    }
                }
                if CONE {
                    rays.far[k] = farthest(&rays.reach[k], rays.lanes[k]);
                }
            }
        }
    }
}

/// The largest of the first `n` reaches.
#[inline(always)]
pub(super) fn farthest(reach: &[f64; LANES], n: u8) -> f64 {
    let mut m = 0.0f64;
    for &r in &reach[..n as usize] {
        m = m.max(r);
    }
    m
}

/// Eight rays through columns `cols` of the row at offset `y`: [`Camera::dir_and_length`]
/// and [`Camera::clip_range`] step for step (so the same bits as the BVH path's pixel
/// rays), written lane-wise so it vectorises.
#[inline(always)]
pub(super) fn setup<T: Real>(
    cam: &Camera,
    pk: &mut Packet<T>,
    dirs: &mut [[f64; LANES]; 3],
    cols: &[f64],
    y: f64,
) {
    let (f, left, up) = (
        cam.forward.to_array(),
        cam.left.to_array(),
        cam.true_up.to_array(),
    );
    for l in 0..LANES {
        let x = cols[l];
        let v: [f64; 3] = std::array::from_fn(|c| f[c] - left[c] * x + up[c] * y);
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let inv = 1.0 / len;
        for c in 0..3 {
            dirs[c][l] = v[c] * inv;
            pk.d[c][l] = T::from_f64(dirs[c][l]);
        }
        let (tmin, tmax) = cam.clip_range(len);
        pk.tmin[l] = T::from_f64(tmin);
        pk.t[l] = T::from_f64(tmax);
        pk.index[l] = NO_HIT;
    }
}

/// Packets per tile row and per tile.
const PACKETS_PER_ROW: usize = TILE as usize / LANES;
const PACKETS: usize = PACKETS_PER_ROW * TILE as usize;
// `TileRays::ready` has a bit per packet.
const _: () = assert!(PACKETS <= 32);

/// Per-pixel rays and best hits of one tile, reused from tile to tile (no allocation per
/// ray). Packet `k` holds the `LANES` columns from `x0 + (k % PACKETS_PER_ROW)·LANES` of
/// row `y0 + k / PACKETS_PER_ROW`.
pub(crate) struct TileRays<T: Real> {
    pub(super) packets: [Packet<T>; PACKETS],
    /// The same directions in f64, for shading.
    pub(super) dirs: [[[f64; LANES]; 3]; PACKETS],
    /// Per lane, the ray parameter beyond which nothing can improve it: its best hit
    /// (padded), else tmax.
    pub(super) reach: [[f64; LANES]; PACKETS],
    /// A bit per packet: set up (and its hits valid).
    pub(super) ready: u32,
    /// Cone walks only: per packet, the lanes holding image pixels and their largest reach.
    pub(super) lanes: [u8; PACKETS],
    pub(super) far: [f64; PACKETS],
}

impl<T: Real> TileRays<T> {
    pub(super) fn boxed() -> Box<Self> {
        Box::new(TileRays {
            packets: [Packet::EMPTY; PACKETS],
            dirs: [[[0.0; LANES]; 3]; PACKETS],
            reach: [[0.0; LANES]; PACKETS],
            ready: 0,
            lanes: [LANES as u8; PACKETS],
            far: [0.0; PACKETS],
        })
    }

    /// Lane `l` of packet `k`: its direction and nearest hit, if it has one.
    #[inline(always)]
    pub(super) fn hit(&self, k: usize, l: usize) -> Option<(DVec3, PixelHit<T>)> {
        let pk = &self.packets[k];
        (pk.index[l] != NO_HIT).then(|| {
            let dirs = &self.dirs[k];
            let hit = BasicHit {
                t: pk.t[l],
                surface: Surface::from_code(pk.surface[l]),
            };
            let d = DVec3::new(dirs[0][l], dirs[1][l], dirs[2][l]);
            (
                d,
                PixelHit {
                    index: pk.index[l],
                    slot: pk.slot[l],
                    hit,
                },
            )
        })
    }
}

/// Trace and shade rows `part` (counted from the band's first row) of band `b` (one row of
/// tiles) into `band`, which holds just those rows; returns their hit count. Each pixel's
/// answer is its own ray's, so a band traced in parts is the band traced whole.
#[inline(always)]
pub(super) fn render_band<T: Real, F: PacketFormula, W: Wide<T>>(
    tok: W::Token,
    fr: &BandInputs<T, F>,
    b: usize,
    part: Range<usize>,
    band: &mut Band,
) -> usize {
    let (tracer, cam) = (fr.tracer, &fr.tracer.camera);
    let w = cam.width() as usize;
    let row0 = b * TILE as usize + part.start;
    let rows = part.len();
    let mut hits = 0;
    let offsets = (fr.cols_off, fr.rows_off);
    match (&tracer.tiles, &tracer.bvh, &tracer.cone_cands) {
        (Some(_), _, _) | (None, Some(_), Some(_)) => {
            let mut rays = TileRays::<T>::boxed();
            let ys = (row0 as u32, (row0 + rows - 1) as u32);
            for tx in 0..(w as u32).div_ceil(TILE) {
                let xs = (tx * TILE, ((tx + 1) * TILE).min(w as u32) - 1);
                match (&tracer.tiles, &tracer.bvh, &tracer.cone_cands) {
                    (Some(tiles), _, _) => {
                        let cands = tiles.tile(tx, b as u32);
                        if cands.is_empty() {
                            continue; // every AOV of a miss is 0 already
                        }
                        trace_tile::<T, F, W>(tok, tracer, cands, xs, ys, offsets, &mut rays);
                    }
                    (None, Some(bvh), Some(cands)) => {
                        trace_cone::<T, F, W>(tok, tracer, bvh, cands, xs, ys, offsets, &mut rays);
                    }
                    _ => unreachable!("matched above"),
                }
                let tw = (xs.1 - xs.0 + 1) as usize;
                for k in (0..PACKETS).filter(|&k| rays.ready & (1 << k) != 0) {
                    let x0 = (k % PACKETS_PER_ROW) * LANES;
                    let row = (k / PACKETS_PER_ROW) * w + xs.0 as usize + x0;
                    for l in 0..LANES.min(tw.saturating_sub(x0)) {
                        if let Some((d, hit)) = rays.hit(k, l) {
                            shade(fr, band, row + l, d, hit);
                            hits += 1;
                        }
                    }
                }
            }
        }
        _ if !cam.is_pinhole() => {
            hits = super::general::render_rows(tok, fr, row0, rows, band);
        }
        _ => {
            // Pixels in groups of four, traced together; the last few of the band one
            // by one. The hint is the last hit found (through misses too: the next hit is
            // most likely on the same cylinder or near it).
            let mut stacks: [Stack; IN_TURN] = Default::default();
            let mut last = None;
            let n = rows * w;
            let ray = |k: usize| fr.pixel_ray(k % w, row0 + k / w);
            let grouped = n / IN_TURN * IN_TURN;
            for k in (0..grouped).step_by(IN_TURN) {
                // Written out: `array::from_fn` left the ray's set-up out of line, a call
                // per pixel compiled without AVX.
                let rays = [ray(k), ray(k + 1), ray(k + 2), ray(k + 3)];
                let found = tracer.trace_in_turn(tok, &mut stacks, last, rays);
                for (i, hit) in found.into_iter().enumerate() {
                    if let Some(hit) = hit {
                        last = Some(hit.slot);
                        shade(fr, band, k + i, rays[i].0, hit);
                        hits += 1;
                    }
                }
            }
            for k in grouped..n {
                let (d, tmin, tmax) = ray(k);
                if let Some(hit) = tracer.trace_with(tok, &mut stacks[0], last, d, tmin, tmax) {
                    last = Some(hit.slot);
                    shade(fr, band, k, d, hit);
                    hits += 1;
                }
            }
        }
    }
    hits
}

/// [`render_band`] compiled for AVX2, with packets in AVX registers (eight f32 lanes fill
/// one, f64 two). No FMA: the results are the same bits as the portable form. Taking the
/// [`Avx2`] token means it can only be reached after the CPU was checked (for AVX2 and
/// the bit counts the traversal uses).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt,lzcnt,bmi1")]
pub(super) fn render_band_avx2<T: Simd, F: PacketFormula>(
    tok: Avx2,
    fr: &BandInputs<T, F>,
    b: usize,
    part: Range<usize>,
    band: &mut Band,
) -> usize {
    render_band::<T, F, T::Avx>(tok, fr, b, part, band)
}

/// Traces rows of a band: [`render_band`]'s arguments but the token.
pub(super) type BandFn<T, F> = fn(&BandInputs<T, F>, usize, Range<usize>, &mut Band) -> usize;

/// The band renderer for this CPU: AVX2 when it has it (and `simd`), else the baseline.
pub(super) fn band_renderer<T: Simd, F: PacketFormula>(simd: bool) -> BandFn<T, F> {
    #[cfg(target_arch = "x86_64")]
    if simd && Avx2::detect().is_some() {
        return |fr, b, part, band| {
            // SAFETY: this closure is returned only after `Avx2::detect` succeeded, so the
            // CPU has AVX2, POPCNT, LZCNT and BMI1, which both the token and the target
            // features require.
            unsafe { render_band_avx2(Avx2::new_unchecked(), fr, b, part, band) }
        };
    }
    let _ = simd;
    |fr, b, part, band| render_band::<T, F, Lanes<T>>((), fr, b, part, band)
}
