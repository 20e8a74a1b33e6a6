//! The data PNGs of a view: the 16-bit depth PNG (`NAME.depth.png`, the format Open3D, TUM
//! RGB-D and nerfstudio read) and the 8-bit hit mask (`NAME.mask.png`).
//!
//! **Depth PNG.** Pixel value `round(depth × scale)` with `depth` the planar depth (the
//! camera-space z of the hit, the `depth` AOV) and `scale` the value per world unit
//! (`--depth-scale`, 1000 = millimetres for metre scenes); 0 means "no depth". A hit whose
//! value does not fit `1..=65535` cannot be stored: by default ([`OutOfRange::Fail`]) the
//! view fails with its depth range and the largest scale that fits, and nothing is written;
//! with [`OutOfRange::Zero`] such pixels are stored as 0 (no depth) and counted.
//!
//! **Mask PNG.** 255 where the pixel's ray hits a cylinder, 0 where it misses: the
//! `mask_path` of nerfstudio's `transforms.json`.

use crate::image::AovImage;
use crate::scene::Aov;
use image::{GrayImage, ImageBuffer, Luma};

/// A 16-bit grey image.
pub type DepthPng = ImageBuffer<Luma<u16>, Vec<u16>>;

crate::choice_enum! {
    /// What to do with a hit whose depth does not fit the 16-bit PNG at the chosen scale.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum OutOfRange default Fail {
        /// Fail the view, naming its depth range and the largest scale that fits.
        Fail = "fail",
        /// Store 0 (no depth) and count the pixels.
        Zero = "zero",
    }
}

/// A depth PNG and how many hits it could not hold (always 0 under [`OutOfRange::Fail`]).
pub struct Encoded {
    /// The image: `round(depth × scale)` per pixel, 0 = no depth (a miss or a zeroed hit).
    pub png: DepthPng,
    /// Hits stored as 0 because `round(depth × scale)` is outside `1..=65535`.
    pub zeroed: usize,
}

/// Encode the `depth` channel of `img` at `scale` values per world unit; `None` without a
/// depth channel. The error says why the view cannot be stored and what would fit.
pub fn encode(img: &AovImage, scale: f64, policy: OutOfRange) -> Option<Result<Encoded, String>> {
    let v = img.f32_channel(Aov::Depth.name())?;
    let fits = |s: f64| (1.0..=u16::MAX as f64).contains(&s);
    let mut zeroed = 0;
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    let mut data: Vec<u16> = Vec::new();
    if let Err(e) = crate::mem::try_reserve(&mut data, v.len(), "depth PNG") {
        return Some(Err(e.to_string()));
    }
    data.extend(v.iter().map(|&z| {
        if z <= 0.0 {
            return 0; // a miss
        }
        let z = z as f64;
        lo = lo.min(z);
        hi = hi.max(z);
        let s = (z * scale).round();
        if fits(s) {
            s as u16
        } else {
            zeroed += 1;
            0
        }
    }));
    if zeroed > 0 && policy == OutOfRange::Fail {
        // round(hi × s) <= 65535 needs hi × s < 65535.5; the scale is printed with six
        // decimals, so it is rounded down to them (and stays below the bound). A scale below
        // 0.5 / lo rounds the nearest hit to 0.
        let largest = ((65535.5 / hi) * 1e6 * (1.0 - 1e-12)).floor() / 1e6;
        let smallest = 0.5 / lo;
        let depth_scale = crate::spelling::opt("depth_scale");
        let hint = if largest >= smallest {
            format!("the largest {depth_scale} that fits is {largest:.6}")
        } else {
            format!("no single {depth_scale} fits both ends")
        };
        return Some(Err(format!(
            "depth PNG: {zeroed} hit pixels do not fit 16 bits at {depth_scale} {scale} \
             (planar depth {lo:.6} to {hi:.6} world units, stored as round(depth × scale) in \
             1..=65535); {hint}, or pass {} zero to store them as 0",
            crate::spelling::opt("depth_out_of_range")
        )));
    }
    let png = ImageBuffer::from_raw(img.width as u32, img.height as u32, data)?;
    Some(Ok(Encoded { png, zeroed }))
}

/// The hit mask of `img`: 255 where the `depth` channel holds a hit, 0 on a miss; `None`
/// without a depth channel. (Every hit has depth >= near_clip > 0; a miss stores 0.)
pub fn mask(img: &AovImage) -> Option<GrayImage> {
    let v = img.f32_channel(Aov::Depth.name())?;
    let mut data = crate::mem::zeroed_or_exit::<u8>(v.len(), "the mask PNG");
    for (m, &z) in data.iter_mut().zip(v) {
        if z > 0.0 {
            *m = 255;
        }
    }
    ImageBuffer::from_raw(img.width as u32, img.height as u32, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{Channel, ChannelData};

    fn depth_image(values: &[f32]) -> AovImage {
        AovImage::from_channels(
            values.len(),
            1,
            vec![Channel {
                name: "depth".into(),
                data: ChannelData::F32(values.to_vec()),
            }],
        )
    }

    #[test]
    fn out_of_range_fails_with_the_scale_that_fits_or_zeroes_with_a_count() {
        let img = depth_image(&[0.0, 1.5, 80.0]);
        let e = encode(&img, 1000.0, OutOfRange::Fail)
            .unwrap()
            .err()
            .unwrap();
        assert!(
            e.contains("1 hit pixels") && e.contains("1.500000 to 80.000000"),
            "{e}"
        );
        // 65535.5 / 80 = 819.19375: the hint must be a scale that stores 80 in 16 bits.
        assert!(e.contains("819.193749"), "{e}");
        let ok = encode(&img, 819.193, OutOfRange::Fail).unwrap().unwrap();
        assert_eq!(ok.png.as_raw(), &[0, 1229, 65535]);
        let z = encode(&img, 1000.0, OutOfRange::Zero).unwrap().unwrap();
        assert_eq!((z.zeroed, z.png.as_raw().clone()), (1, vec![0, 1500, 0]));
        assert_eq!(mask(&img).unwrap().as_raw(), &[0, 255, 255]);
    }
}
