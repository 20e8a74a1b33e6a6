//! PNG previews a person can read without the README: normals as RGB with a key of the axis
//! colours, depth through a colour map with a titled legend bar (quantity, unit, ticks).
//! Also the data PNGs of datasets (normals without a key, 16-bit depth).

use crate::image::AovImage;
use crate::output::format::plot;
use crate::scene::Aov;
use image::{ImageBuffer, Luma, Rgb, RgbImage};

/// Normals mapped `n * 0.5 + 0.5` to RGB; a miss is black.
pub fn normal_rgb(img: &AovImage) -> Option<RgbImage> {
    let [x, y, z] = img.vec3_channel(Aov::Normal.name())?;
    let to8 = |v: f32| ((v * 0.5 + 0.5).clamp(0.0, 1.0) * 255.0).round() as u8;
    Some(RgbImage::from_fn(
        img.width as u32,
        img.height as u32,
        |i, j| {
            let k = j as usize * img.width + i as usize;
            if x[k] == 0.0 && y[k] == 0.0 && z[k] == 0.0 {
                Rgb([0, 0, 0])
            } else {
                Rgb([to8(x[k]), to8(y[k]), to8(z[k])])
            }
        },
    ))
}

/// Viridis-like ramp from 5 control points (perceptually ordered, prints in grey).
fn colormap(u: f32) -> [u8; 3] {
    const P: [[f32; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let s = u.clamp(0.0, 1.0) * 4.0;
    let k = (s as usize).min(3);
    let f = s - k as f32;
    [0, 1, 2].map(|c| (P[k][c] + (P[k + 1][c] - P[k][c]) * f).round() as u8)
}

/// Legend text scale for an image `w` pixels wide: 3×5 glyphs at 1 px up to 320 px wide,
/// larger on larger images.
fn legend_scale(w: u32) -> u32 {
    (w / 160).clamp(1, 4)
}

/// A tick label: three significant digits, plain where that is short.
fn tick_label(x: f32) -> String {
    let a = x.abs();
    if a == 0.0 || (0.01..10000.0).contains(&a) {
        let decimals = if a >= 100.0 {
            0
        } else if a >= 10.0 {
            1
        } else if a >= 1.0 {
            2
        } else {
            3
        };
        format!("{x:.decimals$}")
    } else {
        format!("{x:.2e}")
    }
}

/// Depth (or any float channel) through the colour map, near = dark, with a legend strip
/// under the image: the ramp with five labelled ticks (min, quarters, max of the hits) and
/// a title naming the quantity, its unit and the miss colour. Misses (0) are black.
pub fn depth_colormap(img: &AovImage, channel: &str) -> Option<RgbImage> {
    let v = img.f32_channel(channel)?;
    let hits = v.iter().copied().filter(|x| *x > 0.0 && x.is_finite());
    let (lo, hi) = hits.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let (w, h) = (img.width as u32, img.height as u32);
    let scale = legend_scale(w);
    let quantity = if channel == Aov::Depth.name() {
        "DEPTH Z"
    } else {
        channel
    };
    let title = format!("{quantity} (WORLD UNITS), BLACK = MISS");
    let labels: Vec<String> = (0..5)
        .map(|q| tick_label(lo + q as f32 / 4.0 * (hi - lo)))
        .collect();
    // The legend is never clipped: a figure narrower than its title, or than five labels
    // with a gap each, is widened (black beside the image).
    let widest_label = labels
        .iter()
        .map(|l| plot::text_width(l, scale))
        .max()
        .unwrap_or(0);
    let fig_w = (w as i64)
        .max(plot::text_width(&title, scale) + 2)
        .max(5 * (widest_label + 2 * scale as i64)) as u32;
    // Ramp (3), tick marks (2), labels (5), title (5), in glyph rows, plus gaps.
    let (ramp_y, ramp_h) = (h + 2, 3 * scale);
    let tick_y = ramp_y + ramp_h;
    let label_y = tick_y + 2 * scale + 2;
    let title_y = label_y + 5 * scale + 3 * scale;
    let mut out = RgbImage::new(fig_w, title_y + 5 * scale + 3);
    for j in 0..h {
        for i in 0..w {
            let x = v[(j * w + i) as usize];
            if x > 0.0 && x.is_finite() {
                out.put_pixel(i, j, Rgb(colormap((x - lo) / span)));
            }
        }
    }
    for i in 0..fig_w {
        let c = colormap(i as f32 / (fig_w.max(2) - 1) as f32);
        for j in ramp_y..ramp_y + ramp_h {
            out.put_pixel(i, j, Rgb(c));
        }
    }
    plot::text(&mut out, 1, title_y as i64, scale, &title, plot::WHITE);
    if lo.is_finite() {
        for (q, label) in labels.iter().enumerate() {
            let f = q as f32 / 4.0;
            let x = (f * (fig_w.max(2) - 1) as f32).round() as i64;
            plot::fill(
                &mut out,
                x - (scale as i64 / 2),
                tick_y as i64,
                scale,
                2 * scale,
                plot::WHITE,
            );
            let tw = plot::text_width(label, scale);
            let lx = (x - tw / 2).clamp(0, (fig_w as i64 - tw).max(0));
            plot::text(&mut out, lx, label_y as i64, scale, label, plot::WHITE);
        }
    }
    Some(out)
}

/// The normal colours with a key under them: what colour each world axis direction
/// gets (`n * 0.5 + 0.5` as RGB) and that black is a miss. For people; datasets store
/// [`normal_rgb`] without the key.
pub fn normal_preview(img: &AovImage) -> Option<RgbImage> {
    let rgb = normal_rgb(img)?;
    let (w, h) = rgb.dimensions();
    let scale = legend_scale(w);
    let row = 5 * scale + 3 * scale;
    let key = "NORMAL RGB = (N+1)/2, BLACK = MISS";
    let swatches: Vec<(&str, [f32; 3])> = vec![
        ("+X", [1.0, 0.0, 0.0]),
        ("-X", [-1.0, 0.0, 0.0]),
        ("+Y", [0.0, 1.0, 0.0]),
        ("-Y", [0.0, -1.0, 0.0]),
        ("+Z", [0.0, 0.0, 1.0]),
        ("-Z", [0.0, 0.0, -1.0]),
    ];
    // Widened, never clipped, where the key is wider than the image.
    let swatch_w: i64 = swatches
        .iter()
        .map(|(l, _)| 6 * scale as i64 + plot::text_width(l, scale) + 3 * scale as i64)
        .sum();
    let fig_w = (w as i64)
        .max(plot::text_width(key, scale) + 2)
        .max(swatch_w + 2) as u32;
    let mut out = RgbImage::new(fig_w, h + 2 + 2 * row + 2);
    image::imageops::replace(&mut out, &rgb, 0, 0);
    let to8 = |v: f32| ((v * 0.5 + 0.5) * 255.0).round() as u8;
    let mut x = 1i64;
    let y = (h + 3) as i64;
    for (label, n) in swatches {
        let c = Rgb(n.map(to8));
        plot::fill(&mut out, x, y, 5 * scale, 5 * scale, c);
        x += 6 * scale as i64;
        plot::text(&mut out, x, y, scale, label, plot::WHITE);
        x += plot::text_width(label, scale) + 3 * scale as i64;
    }
    plot::text(&mut out, 1, y + row as i64, scale, key, plot::WHITE);
    Some(out)
}

/// 16-bit depth PNG (Open3D/TUM): `round(depth * scale)`, 0 for a miss or a value out of
/// the u16 range.
pub fn depth_u16(img: &AovImage, scale: f64) -> Option<ImageBuffer<Luma<u16>, Vec<u16>>> {
    let v = img.f32_channel(Aov::Depth.name())?;
    let data = v
        .iter()
        .map(|&z| {
            let s = (z as f64 * scale).round();
            if z > 0.0 && s >= 1.0 && s <= u16::MAX as f64 {
                s as u16
            } else {
                0
            }
        })
        .collect();
    ImageBuffer::from_raw(img.width as u32, img.height as u32, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{Channel, ChannelData};

    /// Whether column `x` of `img` has a white (text) pixel below row `from`.
    fn text_in_column(img: &RgbImage, x: u32, from: u32) -> bool {
        (from..img.height()).any(|y| *img.get_pixel(x, y) == plot::WHITE)
    }

    #[test]
    fn a_narrow_preview_is_widened_to_its_legend_never_clipped() {
        let depth: Vec<f32> = (0..128).map(|i| 1.0 + i as f32 * 0.01).collect();
        let img = AovImage::from_channels(
            16,
            8,
            vec![Channel {
                name: "depth".into(),
                data: ChannelData::F32(depth),
            }],
        );
        let p = depth_colormap(&img, "depth").unwrap();
        // The title, 35 glyphs of 4 columns at scale 1, and a column each side.
        let title = "DEPTH Z (WORLD UNITS), BLACK = MISS";
        assert_eq!(p.width() as i64, plot::text_width(title, 1) + 2);
        // Below the ramp (rows 10-12) and its white tick marks (13-14): labels and title.
        assert!(
            !text_in_column(&p, p.width() - 1, 15),
            "text at the right edge"
        );
        let normal: Vec<f32> = [0.0, 0.0, 1.0].repeat(128);
        let img = AovImage::from_channels(
            16,
            8,
            ["normal.X", "normal.Y", "normal.Z"]
                .iter()
                .enumerate()
                .map(|(k, n)| Channel {
                    name: n.to_string(),
                    data: ChannelData::F32(normal.iter().skip(k).step_by(3).copied().collect()),
                })
                .collect(),
        );
        let p = normal_preview(&img).unwrap();
        let key = "NORMAL RGB = (N+1)/2, BLACK = MISS";
        assert_eq!(p.width() as i64, plot::text_width(key, 1) + 2);
        assert!(
            !text_in_column(&p, p.width() - 1, 8),
            "text at the right edge"
        );
    }
}
