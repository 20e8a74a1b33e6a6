//! Per-pixel comparison of two AOV images: the rule that `cylaov compare`, `cylaov verify`,
//! `batch --verify-fraction` and the reference tests all use.
//!
//! # Identity
//!
//! Each pixel gets an *identity* in each image: the hit cylinder's `shape_id` (0 = miss) and
//! the `part` it hit (1 side seen from outside, 2 side seen from inside, 3 bottom cap at
//! `p0`, 4 top cap at `p1`; 0 = miss). Without `part` in both images only the cylinder is
//! compared; without `shape_id` in both, only hit (1) / miss (0) from `distance` (else
//! `depth`) > 0, and a note says that different-cylinder errors go undetected. Then:
//!
//! - **same**: same cylinder and same part, not a miss. Error statistics (median, p99, max)
//!   are taken over these pixels only, for every channel both images have: relative
//!   distance and depth error `|a - b| / max(|a|, |b|)`, normal angle in degrees
//!   (`atan2(|a × b|, a · b)`, so tiny angles are exact), and the position error (absolute,
//!   and relative to the distance when a `distance` channel exists; informational, no
//!   tolerance).
//! - **silhouette mismatch**: different cylinders, or hit vs miss. Allowed only where the
//!   pixel has an 8-neighbour of another cylinder label (cylinder or miss) in either image,
//!   and at most [`Tolerances::max_mismatch_fraction`] of the pixels.
//! - **seam mismatch**: the same cylinder but another part (the rim of a cap, where one
//!   renderer takes the cap and the other the side, or the rim of an open tube, where one
//!   takes the outer wall and the other the inner wall behind it). Allowed only where the
//!   pixel has an 8-neighbour of another (cylinder, part) in either image, and at most
//!   [`Tolerances::max_seam_fraction`] of the pixels. Counted apart from silhouettes.
//! - Every other disagreement is an **interior mismatch** and fails, however rare.
//!   Mismatched pixels (of any kind) are left out of the error statistics.
//! - Non-finite samples (NaN, ±inf) in any compared float channel always fail.
//!
//! # Flat bounds, and the float32 conditioning bound at grazing pixels
//!
//! [`Tolerances::default()`] is the bar: 0.05% silhouette mismatches, 0.1% seam mismatches,
//! 3e-5 relative distance and depth, 0.1° of normal. Those bounds hold on every pixel
//! unless the comparison is given a [`Conditioning`], the per-pixel bound of what float32
//! inputs can explain, which matters at grazing incidence only:
//!
//! Mitsuba builds its rays in float32 and moves them into each shape's object space in
//! float32, so its ray is displaced sideways by `δ ≈ K·ε₃₂·L`, with `ε₃₂ = 2⁻²⁴`,
//! `L = |o| + max(|p0|, |p1|) + t` the size of the coordinates that are rounded (camera
//! origin `o`, the shape's placement, the run `t` of a float32 direction) and `K` =
//! [`CONDITIONING_ULPS`]. A sideways shift `δ` moves the hit along the surface by
//! `δ / cos i` (`i`: angle between the ray and the normal), so the distance changes by up
//! to `δ / cos i` and, on the side of radius `r`, the normal turns by `δ / (r cos i)`
//! radians. Where the ray is so close to tangent that this linear model breaks
//! (`cos i < √(δ/r)`), the change is at most `√(δ r)`, so `cos i` is clamped there. The
//! pixel's bound is then the larger of the flat bound and this one, in relative distance
//! (and depth) `δ / (t cos i)` and in normal angle `δ / (r cos i)` (on the side only: a
//! cap's normal does not depend on where the ray meets it); on ordinary pixels it is
//! far below the flat bounds (at `L = 10`, `cos i = 0.5`, `t = 5`: 9.5e-7 against 3e-5), so
//! it changes nothing there. Pixels whose error is within their conditioning bound but above
//! the flat bound are *explained*; [`Report::explained_lines`] says how many, the largest
//! and its bound, so a reader sees what the rule accepted. `tests/verify.rs` checks with
//! the double-double oracle that on such pixels cylaov agrees with the exact answer and
//! Mitsuba does not.
//!
//! The same bound covers Mitsuba's `orthographic` sensor, whose rays start on the near plane
//! at the pixel's lateral offset `(x, y)` instead of at the camera centre: the rounded
//! origin coordinates are then of size `|o| + |x| + |y| + near` in place of `|o|`, and the
//! direction, the same for every pixel, is the look-at's forward axis rounded to float32
//! ([`ray_origin_size`] derives it). The lens models (`opencv`, `opencv_fisheye`,
//! `equirectangular`) have no Mitsuba sensor: no conditioning; they are checked against the
//! exact answer alone ([`crate::verify::reference`]).
//!
//! `shape_id` and `part` may be u32 (cylaov) or float32 (Mitsuba references: one component
//! type per bitmap), in either image and mixed: they are compared as ids, and float ids
//! must be whole numbers below 2^24. Any other channel both images have with different
//! sample types (u32 in one, float32 in the other) is not compared: it is listed in
//! [`Report::type_clashes`] and a note says so.

use crate::image::{AovImage, ChannelRef};
use crate::scene::Scene;
use crate::scene::camera::{Camera, Projection};
use anyhow::{Result, bail};
use glam::DVec3;
use image::{Rgb, RgbImage};
use serde::Serialize;
use std::fmt;

mod heatmap;
mod report;
mod rule;

pub use heatmap::*;
pub use report::*;
pub use rule::*;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{Channel, ChannelData, ChannelMut, StridedMut};

    /// A 6x5 image: cylinder 1 fills columns 1..=3 of rows 1..=3, the rest misses.
    fn image() -> AovImage {
        let (w, h) = (6, 5);
        let mut dist = vec![0f32; w * h];
        let mut ids = vec![0u32; w * h];
        let mut nz = vec![0f32; w * h];
        for y in 1..=3 {
            for x in 1..=3 {
                let k = y * w + x;
                dist[k] = 2.0 + x as f32 * 0.125;
                ids[k] = 1;
                nz[k] = 1.0;
            }
        }
        let channel = |name: &str, data| Channel {
            name: name.into(),
            data,
        };
        AovImage::from_channels(
            w,
            h,
            vec![
                channel("distance", ChannelData::F32(dist)),
                channel("normal.X", ChannelData::F32(vec![0.0; w * h])),
                channel("normal.Y", ChannelData::F32(vec![0.0; w * h])),
                channel("normal.Z", ChannelData::F32(nz)),
                channel("shape_id", ChannelData::U32(ids.clone())),
                channel("part", ChannelData::U32(ids)),
            ],
        )
    }

    fn f32_mut<'a>(img: &'a mut AovImage, name: &str) -> StridedMut<'a, f32> {
        img.f32_channel_mut(name).expect(name)
    }

    fn u32_mut<'a>(img: &'a mut AovImage, name: &str) -> StridedMut<'a, u32> {
        img.u32_channel_mut(name).expect(name)
    }

    fn ids_mut(img: &mut AovImage) -> StridedMut<'_, u32> {
        u32_mut(img, "shape_id")
    }

    #[test]
    fn identical_images_have_zero_error() {
        let a = image();
        let r = compare(&a, &a).expect("same size");
        assert_eq!(r.identity, Identity::ShapeIdPart);
        assert_eq!(
            (r.hits_a, r.hits_b, r.same, r.silhouette_mismatches),
            (9, 9, 9, 0)
        );
        let d = &r.rel_distance.as_ref().expect("distance compared").all;
        assert_eq!((d.count, d.median, d.p99, d.max), (9, 0.0, 0.0, 0.0));
        assert_eq!(r.normal_deg.as_ref().expect("normal").all.max, 0.0);
        assert!(r.rel_depth.is_none());
        assert!(r.passes(&Tolerances::default()));
        assert!(
            r.to_string()
                .contains("mismatches: 0 (0.0000%) silhouette, 0 (0.0000%) seam"),
            "{r}"
        );
    }

    #[test]
    fn errors_are_relative_and_located() {
        let a = image();
        let mut b = image();
        // Pixel (2, 2): distance 2.25 → 2.25·(1 + 1e-5); normal tilted by 0.05°.
        let k = 2 * 6 + 2;
        f32_mut(&mut b, "distance")[k] = 2.25 * (1.0 + 1e-5);
        let tilt = 0.05f64.to_radians();
        f32_mut(&mut b, "normal.X")[k] = tilt.sin() as f32;
        f32_mut(&mut b, "normal.Z")[k] = tilt.cos() as f32;
        let r = compare(&a, &b).expect("same size");
        let d = r.rel_distance.expect("distance").all;
        assert!((d.max - 1e-5).abs() < 1e-7, "{}", d.max);
        assert_eq!(d.worst_pixel, Some([2, 2]));
        assert_eq!(d.median, 0.0);
        let n = r.normal_deg.expect("normal").all;
        assert!((n.max - 0.05).abs() < 1e-5, "{}", n.max);
        assert_eq!(n.worst_pixel, Some([2, 2]));
        // Inside the defaults (3e-5, 0.1°), outside tighter ones.
        let r = compare(&a, &b).expect("same size");
        assert!(r.passes(&Tolerances::default()));
        let tight = Tolerances {
            rel_distance: 5e-6,
            normal_deg: 0.01,
            ..Tolerances::default()
        };
        let f = r.failures(&tight);
        assert_eq!(f.len(), 2, "{f:?}");
        // The heatmap colours against the tolerances it is given: (2, 2) is within the
        // defaults (half of 0.1°) but magenta under the tight ones; untouched pixels are not.
        let magenta = Rgb([255, 0, 255]);
        let hm = heatmap(&a, &b, &r, &Tolerances::default(), None);
        assert_eq!(*hm.get_pixel(2, 2), error_colour(0.5));
        assert_ne!(*hm.get_pixel(2, 2), magenta);
        let hm = heatmap(&a, &b, &r, &tight, None);
        assert_eq!(*hm.get_pixel(2, 2), magenta);
        assert_eq!(*hm.get_pixel(1, 1), error_colour(0.0));
        // 2.25·(1 + 1e-5) rounds to f32 at 9.96e-6 relative.
        assert!(
            f[0].starts_with("relative distance error max 9.96"),
            "{}",
            f[0]
        );
        assert!(f[1].starts_with("normal angle error (deg) max"));
    }

    #[test]
    fn shifted_edge_is_a_silhouette_mismatch() {
        let a = image();
        let mut b = image();
        // B's cylinder also covers (4, 2): a hit vs miss next to A's edge.
        let k = 2 * 6 + 4;
        ids_mut(&mut b)[k] = 1;
        f32_mut(&mut b, "distance")[k] = 2.5;
        f32_mut(&mut b, "normal.Z")[k] = 1.0;
        let r = compare(&a, &b).expect("same size");
        assert_eq!(
            (
                r.silhouette_mismatches,
                r.silhouette_on_boundary,
                r.mismatches_interior
            ),
            (1, 1, 0)
        );
        assert_eq!(r.same, 9);
        assert!((r.silhouette_fraction - 1.0 / 30.0).abs() < 1e-12);
        // 1 of 30 pixels breaks the 0.05% bound but nothing else.
        let f = r.failures(&Tolerances::default());
        assert_eq!(f.len(), 1, "{f:?}");
        assert!(f[0].starts_with("silhouette mismatch fraction"), "{}", f[0]);
        let loose = Tolerances {
            max_mismatch_fraction: 0.1,
            ..Tolerances::default()
        };
        assert!(r.passes(&loose));
        let hm = heatmap(&a, &b, &r, &Tolerances::default(), None);
        assert_eq!(*hm.get_pixel(4, 2), Rgb([255, 140, 0]));
        assert_eq!(*hm.get_pixel(0, 0), Rgb([28, 28, 28]));
        assert_eq!(*hm.get_pixel(2, 2), error_colour(0.0));
    }

    #[test]
    fn interior_mismatch_fails_even_when_rare() {
        let a = image();
        let mut b = image();
        // Centre pixel (2, 2) is cylinder 5 in B: its 8 neighbours are all cylinder 1 in A,
        // but in B they differ from it, so by the either-image rule it is a silhouette.
        ids_mut(&mut b)[2 * 6 + 2] = 5;
        let r = compare(&a, &b).expect("same size");
        assert_eq!((r.silhouette_mismatches, r.silhouette_on_boundary), (1, 1));
        // A true interior mismatch needs both neighbourhoods uniform: B relabels A's whole
        // 3x3 cylinder, so the centre (2, 2) is 1 in A and 4 in B with no edge in either.
        let a3 = image();
        let mut b3 = image();
        for y in 1..=3 {
            for x in 1..=3 {
                ids_mut(&mut b3)[y * 6 + x] = 4;
            }
        }
        let r = compare(&a3, &b3).expect("same size");
        assert_eq!(r.silhouette_mismatches, 9);
        assert_eq!(r.mismatches_interior, 1);
        assert_eq!(r.interior_examples, vec![[2, 2]]);
        assert!(!r.passes(&Tolerances::default()));
        let hm = heatmap(&a3, &b3, &r, &Tolerances::default(), None);
        assert_eq!(*hm.get_pixel(2, 2), Rgb([255, 0, 0]));
    }

    fn part_mut(img: &mut AovImage) -> StridedMut<'_, u32> {
        u32_mut(img, "part")
    }

    #[test]
    fn seam_mismatch_is_counted_apart_and_left_out_of_the_errors() {
        // Column 1 of the cylinder is its top cap (4) in both images; B also calls (2, 2)
        // the cap, a pixel next to that seam, and puts a 90° normal and 1% distance there.
        let mut a = image();
        for y in 1..=3 {
            part_mut(&mut a)[y * 6 + 1] = 4;
        }
        let mut b = a.clone();
        let k = 2 * 6 + 2;
        part_mut(&mut b)[k] = 4;
        f32_mut(&mut b, "distance")[k] *= 1.01;
        f32_mut(&mut b, "normal.X")[k] = 1.0;
        f32_mut(&mut b, "normal.Z")[k] = 0.0;
        let r = compare(&a, &b).expect("same size");
        assert_eq!(r.identity, Identity::ShapeIdPart);
        assert_eq!(
            (
                r.seams,
                r.seams_on_boundary,
                r.silhouette_mismatches,
                r.mismatches_interior
            ),
            (1, 1, 0, 0)
        );
        assert_eq!(r.same, 8);
        assert_eq!(r.rel_distance.as_ref().expect("distance").all.max, 0.0);
        assert_eq!(r.normal_deg.as_ref().expect("normal").all.max, 0.0);
        // 1 of 30 pixels is above the 0.1% seam bound, and only that fails.
        let f = r.failures(&Tolerances::default());
        assert_eq!(f.len(), 1, "{f:?}");
        assert!(
            f[0].starts_with("seam mismatch fraction 3.333e-2 (1 px)"),
            "{}",
            f[0]
        );
        let loose = Tolerances {
            max_seam_fraction: 0.05,
            ..Tolerances::default()
        };
        assert!(r.passes(&loose));
        let hm = heatmap(&a, &b, &r, &loose, None);
        assert_eq!(*hm.get_pixel(2, 2), Rgb([0, 200, 230]));
        // Without part in B the same pixel is a same-cylinder pixel with a 90° normal.
        let mut c = b.clone();
        c.retain_channels(|c| c != "part");
        let r = compare(&a, &c).expect("same size");
        assert_eq!((r.identity, r.seams, r.same), (Identity::ShapeId, 0, 9));
        assert!(r.notes[0].starts_with("B lacks part"), "{:?}", r.notes);
        assert!((r.normal_deg.expect("normal").all.max - 90.0).abs() < 1e-9);
    }

    #[test]
    fn seam_mismatch_away_from_any_part_boundary_fails() {
        // B calls the whole cylinder its inner wall (2): the centre (2, 2) then has the
        // same (cylinder, part) all around it in both images, so no seam excuses it.
        let a = image();
        let mut b = image();
        for y in 1..=3 {
            for x in 1..=3 {
                part_mut(&mut b)[y * 6 + x] = 2;
            }
        }
        let r = compare(&a, &b).expect("same size");
        assert_eq!(
            (r.seams, r.seams_on_boundary, r.silhouette_mismatches),
            (9, 8, 0)
        );
        assert_eq!(r.mismatches_interior, 1);
        assert_eq!(r.interior_examples, vec![[2, 2]]);
        let loose = Tolerances {
            max_seam_fraction: 1.0,
            ..Tolerances::default()
        };
        let f = r.failures(&loose);
        assert_eq!(
            f,
            vec!["1 mismatches off silhouettes and seams, e.g. at [[2, 2]]".to_string()]
        );
        let hm = heatmap(&a, &b, &r, &loose, None);
        assert_eq!(*hm.get_pixel(2, 2), Rgb([255, 0, 0]));
        assert_eq!(*hm.get_pixel(1, 1), Rgb([0, 200, 230]));
    }

    #[test]
    fn conditioning_bounds_only_the_pixels_they_explain() {
        // Distance errors of 5e-5 at (2, 2) and (3, 3); only (2, 2) has a conditioning
        // bound (1e-4) that covers it.
        let a = image();
        let mut b = image();
        for k in [2 * 6 + 2, 3 * 6 + 3] {
            let d = &mut f32_mut(&mut b, "distance")[k];
            *d = (f64::from(*d) * (1.0 + 5e-5)) as f32;
        }
        let mut cond = Conditioning {
            width: 6,
            height: 5,
            rel: vec![1e-7; 30],
            normal_deg: vec![1e-4; 30],
        };
        cond.rel[2 * 6 + 2] = 1e-4;
        let r = compare_with(&a, &b, Some(&cond)).expect("same size");
        let m = r.rel_distance.as_ref().expect("distance");
        assert_eq!(m.all.count, 9);
        let u = m.unexplained.as_ref().expect("conditioned");
        assert_eq!((u.count, u.worst_pixel), (1, Some([3, 3])));
        let (n, top) = m.explained_above(3e-5);
        let (e, at, bound) = top.expect("one explained");
        assert!(
            (e - 5e-5).abs() < 1e-7 && at == [2, 2] && bound == 1e-4,
            "{e} {at:?}"
        );
        assert_eq!(n, 1);
        let lines = r.explained_lines(&Tolerances::default());
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            lines[0].starts_with("relative distance: 1 px above 3.000e-5"),
            "{}",
            lines[0]
        );
        let f = r.failures(&Tolerances::default());
        assert_eq!(f.len(), 1, "{f:?}");
        assert!(
            f[0].contains("at [3, 3] (beyond its float32 conditioning bound)"),
            "{}",
            f[0]
        );
        // With (3, 3) covered too, it passes; without conditioning both fail the flat 3e-5.
        cond.rel[3 * 6 + 3] = 1e-4;
        assert!(
            compare_with(&a, &b, Some(&cond))
                .expect("same size")
                .passes(&Tolerances::default())
        );
        assert!(
            !compare(&a, &b)
                .expect("same size")
                .passes(&Tolerances::default())
        );
        cond.width = 5;
        assert!(compare_with(&a, &b, Some(&cond)).is_err());
    }

    #[test]
    fn float_shape_id_and_fallback() {
        let a = image();
        // B: shape_id as float32, as Mitsuba references store it.
        let mut b = image();
        let ids: Vec<f32> = b
            .u32_channel("shape_id")
            .unwrap()
            .iter()
            .map(|&i| i as f32)
            .collect();
        b.push_channel(Channel {
            name: "shape_id".into(),
            data: ChannelData::F32(ids),
        });
        let r = compare(&a, &b).expect("float ids");
        assert_eq!(
            (r.identity, r.same, r.silhouette_mismatches),
            (Identity::ShapeIdPart, 9, 0)
        );
        // u32 against float32 shape_id is the Mitsuba reference case: compared, as ids.
        assert!(r.channels.contains(&"shape_id".to_string()));
        assert!(r.type_clashes.is_empty() && r.notes.is_empty(), "{r:?}");
        // ... and a wrong id in the float image is caught.
        let mut b2 = b.clone();
        if let Some(ChannelMut::F32(mut v)) = b2.channel_mut("shape_id") {
            for y in 1..=3 {
                for x in 1..=3 {
                    v[y * 6 + x] = 2.0;
                }
            }
        }
        let r2 = compare(&a, &b2).expect("float ids");
        assert_eq!(
            (r2.same, r2.silhouette_mismatches, r2.mismatches_interior),
            (0, 9, 1)
        );
        // A fractional id is an error naming the pixel.
        if let Some(ChannelMut::F32(mut v)) = b.channel_mut("shape_id") {
            v[3] = 0.5;
        }
        let e = compare(&a, &b).expect_err("fractional id");
        assert!(e.to_string().contains("pixel [3, 0] is 0.5"), "{e}");
        // Without shape_id in B: hit/miss from distance, and a note says so.
        let mut c = image();
        c.retain_channels(|c| c != "shape_id" && c != "part");
        let r = compare(&a, &c).expect("fallback");
        assert_eq!(r.identity, Identity::HitMiss);
        assert_eq!((r.same, r.silhouette_mismatches), (9, 0));
        assert!(r.notes[0].starts_with("B lacks shape_id"));
        assert_eq!(
            r.only_in_a,
            vec!["shape_id".to_string(), "part".to_string()]
        );
    }

    #[test]
    fn other_type_clash_is_reported_not_silently_skipped() {
        let a = image();
        let mut b = image();
        // B stores distance as u32: not comparable, so not "compared", and a note says so.
        let d: Vec<u32> = b
            .f32_channel("distance")
            .unwrap()
            .iter()
            .map(|&x| x as u32)
            .collect();
        b.push_channel(Channel {
            name: "distance".into(),
            data: ChannelData::U32(d),
        });
        let r = compare(&a, &b).expect("same size");
        assert_eq!(r.type_clashes, vec!["distance".to_string()]);
        assert!(
            !r.channels.contains(&"distance".to_string()),
            "{:?}",
            r.channels
        );
        assert!(r.rel_distance.is_none());
        assert!(r.normal_deg.is_some());
        assert_eq!(
            r.notes,
            vec!["distance not compared: it is float32 in A but u32 in B".to_string()]
        );
        assert!(r.to_string().contains("note: distance not compared"));
        let r = compare(&b, &a).expect("same size");
        assert_eq!(
            r.notes,
            vec!["distance not compared: it is u32 in A but float32 in B".to_string()]
        );
    }

    #[test]
    fn nan_fails_and_size_mismatch_errors() {
        let a = image();
        let mut b = image();
        f32_mut(&mut b, "distance")[7] = f32::NAN;
        let r = compare(&a, &b).expect("same size");
        assert_eq!(r.non_finite_b, 1);
        assert_eq!(r.rel_distance.as_ref().expect("distance").all.count, 8);
        assert!(!r.passes(&Tolerances::default()));
        let mut small = image();
        small.width = 5;
        small.height = 6;
        let e = compare(&a, &small).expect_err("size");
        assert_eq!(e.to_string(), "image sizes differ: A is 6x5, B is 5x6");
    }

    /// The orthographic ray origin's rounded coordinates add the pixel's lateral offset and
    /// the near distance to `|o|`; the pinhole's and the lens models' are `|o|`. Conditioning
    /// follows Mitsuba's two sensors and is absent for a lens model.
    #[test]
    fn orthographic_rays_widen_the_origin_term() {
        use crate::geometry::{FormulaKind, Precision};
        let scene = |camera: &str| {
            crate::scene::parse(&format!(
                r#"{{"camera": {{"origin": [3, -4, 0], "target": [0, 0, 0], "up": [0, 0, 1],
                    "width": 4, "height": 2, "near_clip": 0.5, {camera}}},
                    "cylinders": [{{"p0": [0, 0, -2], "p1": [0, 0, 2], "radius": 1.5}}]}}"#
            ))
            .expect("valid scene")
        };
        let ortho = scene(r#""model": "orthographic", "ortho_width": 8"#);
        let cam = Camera::new(ortho.camera);
        // |o| = 5; half extents 4 × 2; pixel (0, 0) is at x = -3, y = 1; (1, 1) at -1, -1.
        assert_eq!(ray_origin_size(&cam, 0, 0), 5.0 + 3.0 + 1.0 + 0.5);
        assert_eq!(ray_origin_size(&cam, 1, 1), 5.0 + 1.0 + 1.0 + 0.5);
        for other in [r#""fov_deg": 40"#, r#""model": "equirectangular""#] {
            let cam = Camera::new(scene(other).camera);
            assert_eq!(ray_origin_size(&cam, 0, 0), 5.0, "{other}");
        }
        let render = |s: &Scene| {
            crate::verify::reference::check_render(s, Precision::F64, FormulaKind::Stable)
        };
        let cond = Conditioning::new(&ortho, &render(&ortho)).expect("orthographic");
        // The cylinder (radius 1.5) fills the two middle columns (at x = ±1): hit pixels
        // get a bound, the outer columns (x = ±3) miss and get none.
        assert!(cond.rel.iter().any(|&b| b > 0.0) && cond.rel.contains(&0.0));
        let lens = scene(r#""model": "equirectangular""#);
        assert!(Conditioning::new(&lens, &render(&lens)).is_none());
    }

    #[test]
    fn angle_is_accurate_for_tiny_angles() {
        let t = 1e-7f64;
        let a = angle_deg([1.0, 0.0, 0.0], [t.cos(), t.sin(), 0.0]);
        assert!((a - t.to_degrees()).abs() < 1e-15);
        assert_eq!(angle_deg([0.0; 3], [1.0, 0.0, 0.0]), 180.0);
    }
}
