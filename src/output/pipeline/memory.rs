//! The memory a view holds at its peak while it renders and its files are written: what
//! every command checks against what the machine leaves before it allocates, and what
//! bounds the views a batch renders at once.

use crate::image::BAND_ROWS;
use crate::output::format::exr::{Compression, ExrLayout, channel_names};
use crate::scene::Aov;

/// Whether a render going to `layout` with `compression`, and `pictures` (PNGs) or not,
/// is written band by band while it is traced (see `render::render_bands`): one
/// uncompressed layered EXR and no pictures, since nothing then needs the whole image.
pub fn streams(layout: ExrLayout, compression: Compression, pictures: bool) -> bool {
    layout == ExrLayout::Layers && compression == Compression::None && !pictures
}

/// Bytes a render of `width × height` with `aovs` holds at its peak (see [`streams`] for
/// which renders are written band by band), the image's share: the scene, its prepared
/// cylinders and the BVH come on top.
///
/// - Written band by band: each worker thread holds one band (16 rows) of every channel
///   and the band's encoded copy.
/// - Else one buffer per AOV (4 bytes a sample); the per-AOV layout copies one AOV at
///   a time into its file's channels; a compressed file is copied once more, since the
///   `exr` crate encodes from its own copy, and its encoder holds blocks in flight (about
///   a sixth of the file, a third for PIZ, plus 2 MiB a thread, 5 MiB for PIZ); the
///   pictures (PNGs) hold up to 6 bytes a pixel at once (the normal picture, the depth PNG
///   and the mask of a batch view).
/// - 1 MiB of write buffer, and 1 MiB for headers, offset tables and the rest.
///
/// `tests/memory_messages.rs` counts what the allocator hands out at 128², 512² and 1024²,
/// every compression and both layouts: the peaks lie within this estimate, which is at
/// most a quarter above them plus 8 MiB.
pub fn render_memory(
    (width, height): (u32, u32),
    aovs: &[Aov],
    layout: ExrLayout,
    compression: Compression,
    pictures: bool,
) -> u64 {
    const MIB: u64 = 1 << 20;
    let channels: u64 = aovs.iter().map(|&a| channel_names(a).len() as u64).sum();
    if streams(layout, compression, pictures) {
        let rows = (BAND_ROWS as u64).min(height as u64);
        let threads = rayon::current_num_threads() as u64;
        return 2 * threads * rows * width as u64 * 4 * channels + MIB;
    }
    let pixels = width as u64 * height as u64;
    let planes = pixels * 4 * channels;
    // The channels one EXR file is encoded from.
    let file_channels = match layout {
        ExrLayout::Layers => channels,
        ExrLayout::PerAov => aovs
            .iter()
            .map(|&a| channel_names(a).len() as u64)
            .max()
            .unwrap_or(0),
    };
    let file = pixels * 4 * file_channels;
    let copies =
        u64::from(layout == ExrLayout::PerAov) + u64::from(compression != Compression::None);
    let threads = rayon::current_num_threads()
        .max(std::thread::available_parallelism().map_or(1, |n| n.get())) as u64;
    let encoder = match compression {
        Compression::None => 0,
        Compression::Piz => file * 3 / 10 + threads * 5 * MIB,
        _ => file / 6 + threads * 2 * MIB,
    };
    let pngs = if pictures { pixels * 6 } else { 0 };
    planes + copies * file + encoder + pngs + 2 * MIB
}

/// Bytes the planes of a render of `width × height` with `aovs` hold when they are kept in
/// memory as they are, with no file written (the Python package hands them to numpy
/// without a copy): one buffer per AOV, 4 bytes a sample; and for `normal_camera` without
/// `normal`, the world normals it is rotated from, alive until the rotation is done. What
/// a caller adds of its own comes on top, as do the scene, its prepared cylinders and the
/// BVH (see [`render_memory`]).
pub fn planes_memory((width, height): (u32, u32), aovs: &[Aov]) -> u64 {
    let channels: u64 = aovs.iter().map(|&a| channel_names(a).len() as u64).sum();
    let rotated_from = if aovs.contains(&Aov::NormalCamera) && !aovs.contains(&Aov::Normal) {
        channel_names(Aov::Normal).len() as u64
    } else {
        0
    };
    width as u64 * height as u64 * 4 * (channels + rotated_from)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Planes kept in memory: 4 bytes a channel a pixel, and the world normals beside a
    /// `normal_camera` asked for alone (the render fills them first, then rotates them).
    #[test]
    fn the_planes_estimate_counts_channels_and_the_rotated_normals() {
        let px = 640 * 480;
        let est = |aovs: &[Aov]| planes_memory((640, 480), aovs);
        assert_eq!(est(&[Aov::Depth]), px * 4);
        assert_eq!(est(&[Aov::Depth, Aov::Normal, Aov::ShapeId]), px * 4 * 5);
        assert_eq!(est(&[Aov::Uv, Aov::Label]), px * 4 * 3);
        assert_eq!(est(&[Aov::NormalCamera]), px * 4 * 6);
        assert_eq!(est(&[Aov::Normal, Aov::NormalCamera]), px * 4 * 6);
        // 8192² with every AOV: 16 channels, 4 GiB.
        assert_eq!(planes_memory((8192, 8192), &Aov::ALL), 4 << 30);
    }

    /// A render written band by band is estimated at its bands (two copies of 16 rows
    /// per thread); one holding the whole image at its planes, with a second copy when
    /// compressed, the per-AOV copy of the largest AOV, and the pictures.
    #[test]
    fn the_memory_estimate_follows_what_the_render_holds() {
        let all = [
            Aov::Distance,
            Aov::Depth,
            Aov::Normal,
            Aov::Position,
            Aov::ShapeId,
        ];
        let size = (16384, 4096);
        let px = 16384 * 4096;
        let planes = px * 4 * 9;
        let est = |layout, compression, pictures| {
            render_memory(size, &all, layout, compression, pictures)
        };
        let fixed = 2 << 20;
        assert_eq!(
            est(ExrLayout::PerAov, Compression::None, false),
            planes + px * 4 * 3 + fixed
        );
        let zip = est(ExrLayout::Layers, Compression::Zip, false);
        assert!(
            zip > 2 * planes + planes / 6 && zip < 2 * planes + planes / 5,
            "{zip}"
        );
        let piz = est(ExrLayout::Layers, Compression::Piz, false);
        assert!(piz > zip + planes / 10, "{piz} {zip}");
        assert_eq!(
            est(ExrLayout::Layers, Compression::None, true),
            planes + px * 6 + fixed
        );
        let threads = rayon::current_num_threads() as u64;
        assert_eq!(
            est(ExrLayout::Layers, Compression::None, false),
            2 * threads * 16 * 16384 * 4 * 9 + (1 << 20)
        );
    }
}
