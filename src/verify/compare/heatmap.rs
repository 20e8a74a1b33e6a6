//! The heatmap: where two images differ, with its legend and colour bar.

use super::*;

/// Colour for an error `e` in units of its tolerance: log scale from 1e-4 (dark blue)
/// through 1e-2 (green) to 1 (yellow); above the tolerance, magenta.
pub fn error_colour(e: f64) -> Rgb<u8> {
    if e > 1.0 {
        return OVER_TOLERANCE;
    }
    let s = ((e.max(1e-4).log10() + 4.0) / 4.0).clamp(0.0, 1.0);
    let lerp =
        |a: u8, b: u8, t: f64| (f64::from(a) + (f64::from(b) - f64::from(a)) * t).round() as u8;
    if s < 0.5 {
        let t = s / 0.5;
        Rgb([0, lerp(20, 170, t), lerp(90, 60, t)])
    } else {
        let t = (s - 0.5) / 0.5;
        Rgb([lerp(0, 255, t), lerp(170, 230, t), lerp(60, 0, t)])
    }
}

/// Heatmap colour of a pixel both images miss.
pub const BOTH_MISS: Rgb<u8> = Rgb([28, 28, 28]);
/// Heatmap colour of a silhouette mismatch (allowed up to its fraction).
pub const SILHOUETTE: Rgb<u8> = Rgb([255, 140, 0]);
/// Heatmap colour of a seam mismatch (allowed up to its fraction).
pub const SEAM: Rgb<u8> = Rgb([0, 200, 230]);
/// Heatmap colour of an interior mismatch (always a failure).
pub const INTERIOR: Rgb<u8> = Rgb([255, 0, 0]);
/// Heatmap colour of an error above its bound (always a failure).
pub const OVER_TOLERANCE: Rgb<u8> = Rgb([255, 0, 255]);

/// [`heatmap`] as the PNG `compare --heatmap` and `verify --heatmap` write: every failing
/// pixel ringed in white (one such pixel is invisible at a glance), and under the image a
/// legend of every colour in the words of the text report (silhouette, seam, interior,
/// tolerance), and `title` (which files, and the verdict) under that. Wider than the
/// image when the legend needs it.
pub fn heatmap_figure(
    a: &AovImage,
    b: &AovImage,
    report: &Report,
    tol: &Tolerances,
    cond: Option<&Conditioning>,
    title: &str,
) -> RgbImage {
    with_legend(&heatmap(a, b, report, tol, cond), title)
}

/// The legend's entries, top to bottom: colour and label.
pub const LEGEND: [(Rgb<u8>, &str); 6] = [
    (BOTH_MISS, "BOTH MISS"),
    (SILHOUETTE, "SILHOUETTE MISMATCH"),
    (SEAM, "SEAM MISMATCH"),
    (INTERIOR, "INTERIOR MISMATCH (FAIL)"),
    (OVER_TOLERANCE, "OVER TOLERANCE (FAIL)"),
    (crate::output::format::plot::WHITE, "RING: FAILING PIXEL"),
];

pub(super) fn with_legend(heat: &RgbImage, title: &str) -> RgbImage {
    use crate::output::format::plot;
    let (w, h) = heat.dimensions();
    let scale = (w / 160).clamp(1, 4);
    let s = scale as i64;
    let row = 8 * s;
    let ramp_label = "ERROR/TOLERANCE 1E-4";
    let widest = LEGEND
        .iter()
        .map(|(_, l)| 6 * s + plot::text_width(l, scale))
        .chain([plot::text_width(ramp_label, scale) + 40 * s])
        .chain([plot::text_width(title, scale)])
        .max()
        .unwrap_or(0)
        + 2;
    let fig_w = w.max(widest as u32);
    // The legend's rows, the ramp and the title.
    let rows = LEGEND.len() as i64 + 2;
    let mut out = RgbImage::new(fig_w, h + 2 + (rows * row) as u32);
    image::imageops::replace(&mut out, heat, 0, 0);
    let failing = |p: &Rgb<u8>| *p == INTERIOR || *p == OVER_TOLERANCE;
    let ringed: Vec<(i64, i64)> = heat
        .enumerate_pixels()
        .filter(|(_, _, p)| failing(p))
        .map(|(x, y, _)| (x as i64, y as i64))
        .collect();
    // Rings only where they can be told apart: beyond a few thousand the failing area is
    // itself visible.
    if ringed.len() <= 4000 {
        let r = 3 + s;
        for &(x, y) in &ringed {
            for d in -r..=r {
                for (px, py) in [
                    (x + d, y - r),
                    (x + d, y + r),
                    (x - r, y + d),
                    (x + r, y + d),
                ] {
                    if px >= 0
                        && py >= 0
                        && px < w as i64
                        && py < h as i64
                        && !failing(heat.get_pixel(px as u32, py as u32))
                    {
                        out.put_pixel(px as u32, py as u32, plot::WHITE);
                    }
                }
            }
        }
    }
    let mut y = h as i64 + 3;
    for (c, label) in LEGEND {
        plot::fill(&mut out, 1, y, 5 * scale, 5 * scale, c);
        // A grey frame, so the near-black "both miss" swatch shows on the black ground.
        plot::rect(&mut out, 1, y, 5 * scale, 5 * scale, plot::GRID);
        if c == plot::WHITE {
            plot::fill(&mut out, 1 + s, y + s, 3 * scale, 3 * scale, plot::BLACK);
        }
        plot::text(&mut out, 1 + 6 * s, y, scale, label, plot::WHITE);
        y += row;
    }
    // The error ramp of same-part pixels, in units of the tolerance, log scale 1e-4 .. 1.
    plot::text(&mut out, 1, y, scale, ramp_label, plot::WHITE);
    let x0 = 1 + plot::text_width(ramp_label, scale) + 2 * s;
    let x1 = (fig_w as i64 - plot::text_width("1", scale) - 3 * s).max(x0 + 10);
    for px in x0..x1 {
        let e = 10f64.powf(-4.0 + 4.0 * (px - x0) as f64 / (x1 - x0 - 1).max(1) as f64);
        plot::fill(&mut out, px, y, 1, 5 * scale, error_colour(e));
    }
    plot::text(&mut out, x1 + 2 * s, y, scale, "1", plot::WHITE);
    plot::text(&mut out, 1, y + row, scale, title, plot::WHITE);
    out
}

/// Where `a` and `b` differ, as an image (row 0 at the top):
/// - dark grey: both miss;
/// - red: mismatch off silhouettes and seams (always a failure); orange: silhouette
///   mismatch; cyan: seam mismatch (same cylinder, another part);
/// - pixels where both hit the same part of the same cylinder: the largest of the relative
///   distance, relative depth and normal angle errors, each divided by its bound (the
///   run's flat tolerance in `tol`, or the pixel's float32 conditioning bound in `cond`
///   where that is larger), on the log colour scale of blue (≤ 1e-4 of the bound) → green
///   (1e-2) → yellow (the bound); magenta above the bound, so magenta marks exactly the
///   pixels that fail.
///
/// `report` must come from comparing `a` with `b`; it names the channels to use.
pub fn heatmap(
    a: &AovImage,
    b: &AovImage,
    report: &Report,
    tol: &Tolerances,
    cond: Option<&Conditioning>,
) -> RgbImage {
    let (w, h) = (a.width, a.height);
    let mut img = RgbImage::new(w as u32, h as u32);
    let Ok(c) = classify(a, b) else {
        return img;
    };
    let has = |name: &str| report.channels.iter().any(|c| c == name);
    let dist = has("distance")
        .then(|| Some((a.f32_channel("distance")?, b.f32_channel("distance")?)))
        .flatten();
    let depth = has("depth")
        .then(|| Some((a.f32_channel("depth")?, b.f32_channel("depth")?)))
        .flatten();
    let normal = has(crate::scene::Aov::Normal.spec().channels[0])
        .then(|| Some((a.vec3_channel("normal")?, b.vec3_channel("normal")?)))
        .flatten();
    let cond = cond.filter(|c| (c.width, c.height) == (w, h));
    let bound = |flat: f64, per_pixel: Option<f64>| per_pixel.map_or(flat, |p| p.max(flat));
    for (k, class) in c.classes.iter().enumerate() {
        let px = match class {
            Class::BothMiss => BOTH_MISS,
            Class::Interior => INTERIOR,
            Class::Silhouette => SILHOUETTE,
            Class::Seam => SEAM,
            Class::Same => {
                let rel_b = cond.map(|c| c.rel[k]);
                let mut e: f64 = 0.0;
                if let Some((x, y)) = dist {
                    e = e.max(rel(x[k], y[k]) / bound(tol.rel_distance, rel_b));
                }
                if let Some((x, y)) = depth {
                    e = e.max(rel(x[k], y[k]) / bound(tol.rel_depth, rel_b));
                }
                if let Some((x, y)) = &normal {
                    let nb = bound(tol.normal_deg, cond.map(|c| c.normal_deg[k]));
                    e = e.max(angle_deg(vec3_at(x, k), vec3_at(y, k)) / nb);
                }
                if e.is_nan() {
                    OVER_TOLERANCE
                } else {
                    error_colour(e)
                }
            }
        };
        img.put_pixel((k % w) as u32, (k / w) as u32, px);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::format::plot;

    /// The figure ends with its title (files and verdict) drawn in full, and the near-black
    /// "both miss" swatch has a light frame on the black ground.
    #[test]
    fn the_figure_names_files_and_verdict_and_frames_dark_swatches() {
        let (w, h) = (40, 30);
        let title = "A.EXR VS B.EXR: FAIL";
        let fig = with_legend(&RgbImage::new(w, h), title);
        let mut want = RgbImage::new(plot::text_width(title, 1) as u32, 5);
        plot::text(&mut want, 0, 0, 1, title, plot::WHITE);
        // Scale 1: 8-pixel rows; six legend rows and the ramp come first.
        let y0 = h + 3 + 7 * 8;
        assert!(fig.width() > want.width() && fig.height() >= y0 + 5);
        for (x, y, p) in want.enumerate_pixels() {
            assert_eq!(fig.get_pixel(1 + x, y0 + y), p, "title pixel ({x}, {y})");
        }
        assert_eq!(*fig.get_pixel(1, h + 3), plot::GRID);
        assert_eq!(*fig.get_pixel(3, h + 5), BOTH_MISS);
    }
}
