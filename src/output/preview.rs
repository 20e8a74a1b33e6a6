//! PNG previews a person can look at: normals as RGB, depth through a colour map with a
//! legend bar labelled with its range. Also the 16-bit depth PNG of datasets.

use crate::output::aov::AovImage;
use crate::output::io::{Staged, stage};
use crate::output::plot;
use anyhow::{Context, Result};
use image::{ImageBuffer, Luma, Rgb, RgbImage};
use std::path::Path;

/// Normals mapped `n * 0.5 + 0.5` to RGB; a miss is black.
pub fn normal_rgb(img: &AovImage) -> Option<RgbImage> {
    let [x, y, z] = img.vec3_channel("normal")?;
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

/// Depth (or any float channel) through the colour map, near = dark, with a legend strip
/// under the image: the ramp and the min and max values. Misses (0) are black.
pub fn depth_colormap(img: &AovImage, channel: &str) -> Option<RgbImage> {
    let v = img.f32_channel(channel)?;
    let hits = v.iter().copied().filter(|x| *x > 0.0 && x.is_finite());
    let (lo, hi) = hits.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let (w, h) = (img.width as u32, img.height as u32);
    let scale = (w / 160).clamp(1, 4);
    let legend = 10 * scale + 4;
    let mut out = RgbImage::new(w, h + legend);
    for j in 0..h {
        for i in 0..w {
            let x = v[(j * w + i) as usize];
            if x > 0.0 && x.is_finite() {
                out.put_pixel(i, j, Rgb(colormap((x - lo) / span)));
            }
        }
    }
    for i in 0..w {
        let c = colormap(i as f32 / (w.max(2) - 1) as f32);
        for j in h + 2..h + 2 + 3 * scale {
            out.put_pixel(i, j, Rgb(c));
        }
    }
    if lo.is_finite() {
        let y = h + 3 * scale + 3;
        let (a, b) = (format!("{lo:.4e}"), format!("{hi:.4e}"));
        plot::text(&mut out, 1, y as i64, scale, &a, plot::WHITE);
        let bx = (w as i64 - plot::text_width(&b, scale) - 1).max(0);
        plot::text(&mut out, bx, y as i64, scale, &b, plot::WHITE);
    }
    Some(out)
}

/// 16-bit depth PNG (Open3D/TUM): `round(depth * scale)`, 0 for a miss or a value out of
/// the u16 range.
pub fn depth_u16(img: &AovImage, scale: f64) -> Option<ImageBuffer<Luma<u16>, Vec<u16>>> {
    let v = img.f32_channel("depth")?;
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

/// Encode any PNG-able image atomically.
pub fn write_png<P, C>(img: &ImageBuffer<P, C>, path: &Path) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    stage_png(img, path)?
        .commit()
        .with_context(|| format!("writing {}", path.display()))
}

/// Encode a PNG to `path`'s temporary name, to be committed with others.
pub fn stage_png<P, C>(img: &ImageBuffer<P, C>, path: &Path) -> Result<Staged>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    stage(path, |f| {
        let mut w = std::io::BufWriter::new(f);
        img.write_to(&mut w, image::ImageFormat::Png)
            .map_err(|e| std::io::Error::other(e.to_string()))
    })
    .with_context(|| format!("writing {}", path.display()))
}
