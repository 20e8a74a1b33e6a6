//! AOV images as OpenEXR files: the image model ([`crate::image`], re-exported here)
//! written and read back, its header and the per-AOV layout.
//!
//! Channel names are the contract: the AOV table's (`distance`, `depth`, `normal.X/Y/Z`,
//! `uv.U/V`, …; float32, ids u32). Row 0 is the top row. A missed pixel is 0 everywhere.
//!
//! **Self-describing files.** `render` and `batch` write header attributes
//! ([`exr_attributes`]) so a file separated from its JSON still says what it holds:
//!
//! | attribute | type | content |
//! |---|---|---|
//! | `worldToCamera` | m44f | OpenEXR's standard attribute, in its convention: camera x right, y up, z forward (the view direction; points in front have z > 0); an Imath matrix for row vectors, `p_cam = p_world · M` (translation in the last row) |
//! | `worldToNDC` | m44f | standard too: `(x, y, _, w) = (p_world, 1) · M`, NDC `(x/w, y/w)` with (0, 0) the top-left and (1, 1) the bottom-right corner of the image, y down |
//! | `cylaov:version` | string | the cylaov that wrote it |
//! | `cylaov:units` | string | world units: those of the scene file |
//! | `cylaov:miss` | string | a pixel whose ray hits nothing is 0 in every channel |
//! | `cylaov:channel:NAME` | string | per AOV: meaning, frame and miss value (e.g. `depth`: planar, camera-space z; `distance`: along the ray) |
//! | `cylaov:fl_x`, `cylaov:fl_y` | float | focal lengths in pixels |
//! | `cylaov:cx`, `cylaov:cy` | float | principal point, pixel centres at `i + 0.5` (W/2, H/2: nerfstudio, Mitsuba) |
//! | `cylaov:cx_opencv`, `cylaov:cy_opencv` | float | principal point, pixel centres at integers (W/2 − 0.5: OpenCV, Open3D, COLMAP) |
//!
//! **Two writers.** Compressed files go through the `exr` crate. Uncompressed files (the
//! default) are streamed by hand from the buffers ([`AovImage::write_uncompressed`]): the
//! crate copies every sample through its own layout, which at 1080p cost more than the
//! render, while the uncompressed scanline format is a header, an offset table and rows:
//! a one-channel AOV's row lies contiguous in its buffer, a three-channel AOV's channel is
//! gathered from its row (`cylaov bench --exr-writer` times that against planes). Since every line has the same size, where
//! each line goes is known before any is written: [`ExrBands`] writes an image band by band,
//! in any order, while the render is still tracing the rest (what `cylaov render` and
//! `batch` do for one uncompressed EXR), the same bytes. The tests read these files back
//! bit for bit with the `exr` crate, OpenEXR's own Python binding and OpenCV.
//!
//! **Per-AOV layout** (`--exr-layout per-aov`, [`per_aov_image`]): one file per AOV with
//! the channel names OpenCV and imageio understand: `depth`, `distance`, `shape_id` and `part` as
//! `Y` (all float32; ids are exact up to 2^24 and larger ones are refused), `normal` and
//! `position` as `R, G, B` (= X, Y, Z). The samples are bitwise those of the layered file.

use crate::scene::Aov;
use crate::scene::camera::Camera;
use anyhow::{Context, Result, bail};
use exr::prelude::*;
use std::path::Path;

pub use crate::image::{
    AovBuffer, AovImage, BAND_ROWS, Channel, ChannelData, ChannelMut, ChannelRef, Strided,
    StridedMut,
};

crate::choice_enum! {
    /// EXR compression for written files.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Compression default None {
        /// Uncompressed: fastest to write and read.
        None = "none",
        /// ZIP, 16 scanlines per block: lossless, good for depth.
        Zip = "zip",
        /// ZIP, one scanline per block.
        Zips = "zips",
        /// PIZ wavelet: lossless, strong on noisy float data.
        Piz = "piz",
        /// RLE: cheap, weak.
        Rle = "rle",
    }
}

impl Compression {
    /// The `exr` crate's compression method for this choice.
    pub fn to_exr(self) -> exr::compression::Compression {
        use exr::compression::Compression as C;
        match self {
            Compression::None => C::Uncompressed,
            Compression::Zip => C::ZIP16,
            Compression::Zips => C::ZIP1,
            Compression::Piz => C::PIZ,
            Compression::Rle => C::RLE,
        }
    }
}

/// The EXR channel names of an AOV, in order (its row of the AOV table).
pub fn channel_names(aov: Aov) -> &'static [&'static str] {
    aov.spec().channels
}

/// One header attribute beyond the required ones.
#[derive(Clone, Debug, PartialEq)]
pub enum ExrAttr {
    /// A 4×4 float matrix (`m44f`), stored row by row as Imath does.
    M44f(&'static str, [f32; 16]),
    /// A `string` attribute: name, value.
    Text(String, String),
    /// A `float` attribute: name, value.
    Float(&'static str, f32),
}

crate::choice_enum! {
    /// How the AOVs of a render go to disk.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum ExrLayout default Layers {
        /// One EXR with every AOV as named channels (`depth`, `normal.X`, …).
        Layers = "layers",
        /// One EXR per AOV (`OUT.<aov>.exr`), channels `Y` or `R, G, B`, float32.
        PerAov = "per-aov",
    }
}

/// The header attributes of a view rendered from `cam` holding `aovs` (see the module
/// docs for their meanings and conventions).
pub fn exr_attributes(cam: &Camera, aovs: &[Aov]) -> Vec<ExrAttr> {
    use glam::DMat4;
    // Camera frame of OpenEXR: x right (= -left), y up, z forward, as column-vector rows.
    let (right, up, fwd, o) = (-cam.left, cam.true_up, cam.forward, cam.origin);
    let world_to_camera = DMat4::from_cols(
        glam::DVec4::new(right.x, up.x, fwd.x, 0.0),
        glam::DVec4::new(right.y, up.y, fwd.y, 0.0),
        glam::DVec4::new(right.z, up.z, fwd.z, 0.0),
        glam::DVec4::new(-right.dot(o), -up.dot(o), -fwd.dot(o), 1.0),
    );
    // Camera to NDC: x/z at unit distance spans [-tan, tan] over the image width; NDC x =
    // (x / (z tan_x) + 1) / 2, NDC y = (1 - y / (z tan_y)) / 2 (y down); w = z.
    let (tx, ty) = (cam.tan_half_x, cam.tan_half_y);
    let camera_to_ndc = DMat4::from_cols(
        glam::DVec4::new(0.5 / tx, 0.0, 0.0, 0.0),
        glam::DVec4::new(0.0, -0.5 / ty, 0.0, 0.0),
        glam::DVec4::new(0.5, 0.5, 1.0, 1.0),
        glam::DVec4::ZERO,
    );
    // Imath multiplies row vectors (p · M): its M is the transpose of the column-vector
    // matrix, i.e. the column-major array read row by row.
    let imath = |m: DMat4| m.to_cols_array().map(|x| x as f32);
    let k = cam.k_matrix();
    let k_cv = cam.k_matrix_opencv();
    let mut attrs = vec![
        ExrAttr::M44f("worldToCamera", imath(world_to_camera)),
        ExrAttr::M44f("worldToNDC", imath(camera_to_ndc * world_to_camera)),
        ExrAttr::Text("cylaov:version".into(), env!("CARGO_PKG_VERSION").into()),
        ExrAttr::Text(
            "cylaov:units".into(),
            "world units: those of the scene file (distance, depth, position)".into(),
        ),
        ExrAttr::Text(
            "cylaov:miss".into(),
            "a pixel whose ray hits nothing is 0 in every channel".into(),
        ),
        ExrAttr::Float("cylaov:fl_x", k[0][0] as f32),
        ExrAttr::Float("cylaov:fl_y", k[1][1] as f32),
        ExrAttr::Float("cylaov:cx", k[0][2] as f32),
        ExrAttr::Float("cylaov:cy", k[1][2] as f32),
        ExrAttr::Float("cylaov:cx_opencv", k_cv[0][2] as f32),
        ExrAttr::Float("cylaov:cy_opencv", k_cv[1][2] as f32),
    ];
    if !cam.is_pinhole() {
        // The NDC matrix and the intrinsics above are a pinhole's: another model states its
        // name, its parameters (in the camera file) and what its depth holds instead.
        let p = &cam.projection;
        attrs.retain(|a| {
            matches!(a, ExrAttr::Text(..)) || matches!(a, ExrAttr::M44f("worldToCamera", _))
        });
        attrs.push(ExrAttr::Text(
            "cylaov:camera_model".into(),
            p.model().name().into(),
        ));
        attrs.push(ExrAttr::Text(
            "cylaov:depth_kind".into(),
            format!("{}: {}", p.depth_kind(), depth_kind_text(p.depth_kind())),
        ));
    }
    for &a in aovs {
        attrs.push(ExrAttr::Text(
            format!("cylaov:channel:{}", a.name()),
            a.spec().header_text_under(&cam.projection),
        ));
    }
    attrs
}

/// What a `depth_kind` means, in words.
pub fn depth_kind_text(kind: &str) -> &'static str {
    match kind {
        "planar" => "depth is camera-space z, along forward from the camera's image plane",
        "planar_in_front" => {
            "depth is camera-space z for rays less than 90 degrees from forward, else the Euclidean distance from the camera centre"
        }
        _ => "depth is the Euclidean distance from the camera centre (as distance)",
    }
}

/// The channel names of `aov` in the per-AOV layout, in order (`Y`, or `R, G, B`).
pub fn per_aov_channel_names(aov: Aov) -> &'static [&'static str] {
    aov.spec().per_aov_channels()
}

/// Largest shape id a float32 `Y` channel holds exactly.
pub const MAX_FLOAT_ID: u32 = 1 << 24;

/// The per-AOV image of `aov` from `img`: its channels renamed (`Y` or `R, G, B`) and, for
/// `shape_id`, converted to float32 (exact up to 2^24; larger ids are an error naming the
/// id, since a float32 cannot tell them apart).
pub fn per_aov_image(img: &AovImage, aov: Aov) -> Result<AovImage> {
    let names = channel_names(aov);
    let data = match img.aov_buffer(aov).map(|b| &b.data) {
        Some(ChannelData::F32(v)) => {
            ChannelData::F32(crate::mem::try_copy(v, "the per-AOV image")?)
        }
        Some(ChannelData::U32(v)) => {
            if let Some(&big) = v.iter().find(|&&id| id > MAX_FLOAT_ID) {
                let layout = crate::spelling::opt("exr_layout");
                bail!(
                    "{layout} per-aov: {} {big} does not fit a float32 channel \
                     exactly (ids up to 2^24 = {MAX_FLOAT_ID} do); use {layout} layers, \
                     which stores ids as u32",
                    names[0]
                );
            }
            ChannelData::F32(v.iter().map(|&id| id as f32).collect())
        }
        None => bail!("no {} channel", names.join(", ")),
    };
    Ok(AovImage {
        width: img.width,
        height: img.height,
        buffers: vec![AovBuffer::new(per_aov_channel_names(aov), data)],
    })
}

impl AovImage {
    /// Encode as OpenEXR into any seekable writer (a file, or memory). Uncompressed files
    /// are streamed by [`AovImage::write_uncompressed`]; the rest go through the `exr`
    /// crate, which compresses blocks in parallel.
    pub fn write_exr_to(
        &self,
        out: impl std::io::Write + std::io::Seek,
        compression: Compression,
    ) -> Result<()> {
        self.write_exr_with(out, compression, &[])
    }

    /// [`AovImage::write_exr_to`] with extra header attributes.
    pub fn write_exr_with(
        &self,
        mut out: impl std::io::Write + std::io::Seek,
        compression: Compression,
        attrs: &[ExrAttr],
    ) -> Result<()> {
        if compression == Compression::None {
            self.write_uncompressed_with(&mut out, attrs)?;
            return Ok(());
        }
        let mut layer_attrs = LayerAttributes::default();
        for a in attrs {
            match a {
                ExrAttr::M44f("worldToCamera", m) => layer_attrs.world_to_camera = Some(*m),
                ExrAttr::M44f("worldToNDC", m) => layer_attrs.world_to_normalized_device = Some(*m),
                ExrAttr::M44f(name, m) => {
                    layer_attrs
                        .other
                        .insert(Text::from(*name), AttributeValue::Matrix4x4(*m));
                }
                ExrAttr::Text(name, s) => {
                    layer_attrs.other.insert(
                        Text::from(name.as_str()),
                        AttributeValue::Text(Text::from(s.as_str())),
                    );
                }
                ExrAttr::Float(name, x) => {
                    layer_attrs
                        .other
                        .insert(Text::from(*name), AttributeValue::F32(*x));
                }
            }
        }
        // The crate encodes from its own copy of every plane: reserved fallibly, since it
        // doubles the image (see `render_memory`).
        let what = "the copy of the image the EXR encoder needs";
        let mut channels = Vec::new();
        for b in &self.buffers {
            let planes = match &b.data {
                ChannelData::F32(v) => planes_of(v, b.stride(), what)?
                    .into_iter()
                    .map(FlatSamples::F32)
                    .collect::<Vec<_>>(),
                ChannelData::U32(v) => planes_of(v, b.stride(), what)?
                    .into_iter()
                    .map(FlatSamples::U32)
                    .collect(),
            };
            for (name, samples) in b.names.iter().zip(planes) {
                channels.push(AnyChannel::new(name.as_str(), samples));
            }
        }
        let layer = Layer::new(
            (self.width, self.height),
            layer_attrs,
            Encoding {
                compression: compression.to_exr(),
                blocks: Blocks::ScanLines,
                line_order: LineOrder::Increasing,
            },
            AnyChannels::sort(channels.into_iter().collect()),
        );
        let mut canonical = SortedHeader::new(out);
        Image::from_layer(layer)
            .write()
            .to_buffered(&mut canonical)?;
        canonical.finish()?;
        Ok(())
    }

    /// Stream an uncompressed single-part scanline OpenEXR straight from the buffers (the
    /// `exr` crate copies every sample through its own layout, which costs more than the
    /// render at 1080p). Layout: magic and version, the header attributes, the
    /// offset table (one u64 per line), then per line its `y`, byte count, and each
    /// channel's row in channel-name order.
    pub fn write_uncompressed<W: std::io::Write>(&self, out: &mut W) -> std::io::Result<()> {
        self.write_uncompressed_with(out, &[])
    }

    /// [`AovImage::write_uncompressed`] with extra header attributes (after the required
    /// ones, in the given order).
    pub fn write_uncompressed_with<W: std::io::Write>(
        &self,
        out: &mut W,
        attrs: &[ExrAttr],
    ) -> std::io::Result<()> {
        let layout = Uncompressed::new(self, self.height, attrs);
        out.write_all(&layout.head)?;
        let mut scratch: Vec<u32> = Vec::new();
        for y in 0..self.height {
            layout.write_line(out, self, y, y, &mut scratch)?;
        }
        Ok(())
    }

    /// Read every channel of the first layer of an OpenEXR stream (`what` names it in
    /// errors). Half channels become f32.
    pub fn read_exr_from(
        input: impl std::io::Read + std::io::Seek + Send,
        what: &Path,
    ) -> Result<AovImage> {
        let path = what;
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_buffered(input)
            .with_context(|| format!("reading {}", path.display()))?;
        let layer = image.layer_data;
        let size = layer.size;
        let mut channels = Vec::new();
        for c in layer.channel_data.list {
            let data = match c.sample_data {
                FlatSamples::F32(v) => ChannelData::F32(v),
                FlatSamples::U32(v) => ChannelData::U32(v),
                FlatSamples::F16(v) => ChannelData::F32(v.iter().map(|h| h.to_f32()).collect()),
            };
            channels.push(Channel {
                name: c.name.to_string(),
                data,
            });
        }
        if size.0 == 0 || size.1 == 0 {
            bail!("{}: empty image", path.display());
        }
        Ok(AovImage::from_channels(size.0, size.1, channels))
    }
}

/// The channels of a buffer of `stride` channels, each as a plane of its own, reserved
/// fallibly (a three-channel buffer taken apart in one pass, see [`split3`]).
fn planes_of<X: bytemuck::Pod + bytemuck::Zeroable>(
    v: &[X],
    stride: usize,
    what: &str,
) -> std::io::Result<Vec<Vec<X>>> {
    if stride == 1 {
        return Ok(vec![crate::mem::try_copy(v, what)?]);
    }
    let n = v.len() / stride;
    let mut planes = (0..stride)
        .map(|_| crate::mem::try_zeroed::<X>(n, what))
        .collect::<std::io::Result<Vec<_>>>()?;
    if let ([x, y, z], Ok(words)) = (&mut planes[..], bytemuck::try_cast_slice::<X, u32>(v)) {
        fn cast<X: bytemuck::Pod>(p: &mut [X]) -> &mut [u32] {
            bytemuck::cast_slice_mut(p)
        }
        split3(words, cast(x), cast(y), cast(z));
        // split3 stores little-endian words; samples in memory are native.
        if cfg!(target_endian = "big") {
            for p in [x, y, z] {
                cast(p).iter_mut().for_each(|w| *w = u32::from_le(*w));
            }
        }
        return Ok(planes);
    }
    for (k, p) in planes.iter_mut().enumerate() {
        for (o, px) in p.iter_mut().zip(v.chunks_exact(stride)) {
            *o = px[k];
        }
    }
    Ok(planes)
}

/// The layout of an uncompressed single-part scanline OpenEXR: magic and version, the
/// header attributes, the offset table (one u64 per line), then per line its `y`, byte
/// count, and each channel's row in channel-name order. Every line has the same size, so
/// where each line lies is known before any is written (what lets bands be written in any
/// order, see [`ExrBands`]).
struct Uncompressed {
    /// Everything before the first line: magic, attributes, offset table.
    head: Vec<u8>,
    /// Each channel's buffer and place in a pixel, in file (name) order.
    order: Vec<(usize, usize)>,
    /// Bytes of one line after its `y` and byte count.
    line_bytes: usize,
}

impl Uncompressed {
    /// The layout of an image `height` rows tall with the channels (names, types, width)
    /// of `img`, which may be a band of it.
    fn new(img: &AovImage, height: usize, attrs: &[ExrAttr]) -> Uncompressed {
        let mut order: Vec<(usize, usize)> = (img.buffers.iter().enumerate())
            .flat_map(|(b, buf)| (0..buf.stride()).map(move |k| (b, k)))
            .collect();
        let name = |&(b, k): &(usize, usize)| img.buffers[b].names[k].as_bytes();
        order.sort_by(|a, b| name(a).cmp(name(b)));
        let w = img.width;
        let mut head = Vec::with_capacity(512);
        head.extend_from_slice(&20000630i32.to_le_bytes());
        head.extend_from_slice(&2i32.to_le_bytes());
        let mut attr = |name: &str, ty: &str, value: &[u8]| {
            for s in [name, ty] {
                head.extend_from_slice(s.as_bytes());
                head.push(0);
            }
            head.extend_from_slice(&(value.len() as i32).to_le_bytes());
            head.extend_from_slice(value);
        };
        let mut chlist = Vec::new();
        for &(b, k) in &order {
            let buf = &img.buffers[b];
            chlist.extend_from_slice(buf.names[k].as_bytes());
            chlist.push(0);
            let pixel_type: i32 = match buf.data {
                ChannelData::U32(_) => 0,
                ChannelData::F32(_) => 2,
            };
            chlist.extend_from_slice(&pixel_type.to_le_bytes());
            chlist.extend_from_slice(&[0, 0, 0, 0]); // pLinear, reserved
            chlist.extend_from_slice(&1i32.to_le_bytes()); // x sampling
            chlist.extend_from_slice(&1i32.to_le_bytes()); // y sampling
        }
        chlist.push(0);
        let window: Vec<u8> = [0i32, 0, w as i32 - 1, height as i32 - 1]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        attr("channels", "chlist", &chlist);
        attr("compression", "compression", &[0]);
        attr("dataWindow", "box2i", &window);
        attr("displayWindow", "box2i", &window);
        attr("lineOrder", "lineOrder", &[0]);
        attr("pixelAspectRatio", "float", &1f32.to_le_bytes());
        attr("screenWindowCenter", "v2f", &[0u8; 8]);
        attr("screenWindowWidth", "float", &1f32.to_le_bytes());
        for a in attrs {
            match a {
                ExrAttr::M44f(name, m) => {
                    let bytes: Vec<u8> = m.iter().flat_map(|x| x.to_le_bytes()).collect();
                    attr(name, "m44f", &bytes);
                }
                ExrAttr::Text(name, s) => attr(name, "string", s.as_bytes()),
                ExrAttr::Float(name, x) => attr(name, "float", &x.to_le_bytes()),
            }
        }
        head.push(0);
        let line_bytes = w * 4 * order.len();
        let data_start = head.len() + 8 * height;
        for y in 0..height {
            head.extend_from_slice(&((data_start + y * (8 + line_bytes)) as u64).to_le_bytes());
        }
        Uncompressed {
            head,
            order,
            line_bytes,
        }
    }

    /// Where line `y` starts in the file.
    fn line_offset(&self, y: usize) -> u64 {
        (self.head.len() + y * (8 + self.line_bytes)) as u64
    }

    /// Write row `row` of `img` as the file's line `y`: each channel's row in name order.
    /// A one-channel buffer's row is contiguous and goes out as a slice on little-endian
    /// machines. The channels of an interleaved buffer that follow one another in name
    /// order (`normal.X`, `normal.Y`, `normal.Z`) are taken apart in one pass over the row
    /// into `scratch`, then written together.
    fn write_line<W: std::io::Write>(
        &self,
        out: &mut W,
        img: &AovImage,
        row: usize,
        y: usize,
        scratch: &mut Vec<u32>,
    ) -> std::io::Result<()> {
        let w = img.width;
        out.write_all(&(y as i32).to_le_bytes())?;
        out.write_all(&(self.line_bytes as i32).to_le_bytes())?;
        let mut i = 0;
        while i < self.order.len() {
            let (b, k) = self.order[i];
            let buf = &img.buffers[b];
            let s = buf.stride();
            let samples = row * w * s..(row + 1) * w * s;
            // Every sample as its 4 bytes (float32 bits or u32).
            let words: &[u32] = match &buf.data {
                ChannelData::F32(v) => bytemuck::cast_slice(&v[samples]),
                ChannelData::U32(v) => &v[samples],
            };
            // The run of this buffer's channels, in their order, starting here.
            let run = (0..s - k)
                .take_while(|&j| self.order.get(i + j) == Some(&(b, k + j)))
                .count();
            if s == 1 && cfg!(target_endian = "little") {
                out.write_all(bytemuck::cast_slice(words))?;
            } else {
                // Every element is written below: no need to clear what a row before left.
                scratch.resize(run * w, 0);
                let pixels = words.chunks_exact(s);
                if run == 3 && s == 3 {
                    let (x, rest) = scratch.split_at_mut(w);
                    let (y, z) = rest.split_at_mut(w);
                    split3(words, x, y, z);
                } else {
                    for (p, px) in pixels.enumerate() {
                        for j in 0..run {
                            scratch[j * w + p] = px[k + j].to_le();
                        }
                    }
                }
                out.write_all(bytemuck::cast_slice(scratch))?;
            }
            i += run;
        }
        Ok(())
    }
}

/// A row of `[x, y, z]` triples taken apart into the rows `x`, `y`, `z` (each at least
/// `words.len() / 3` long), little-endian: four pixels at a time in SSE2 registers on
/// x86-64 (five shuffles), so a vector AOV's channels leave its buffer at close to the
/// speed of a plane's contiguous row; lane by lane elsewhere and for the last pixels.
fn split3(words: &[u32], x: &mut [u32], y: &mut [u32], z: &mut [u32]) {
    let w = words.len() / 3;
    let (x, y, z) = (&mut x[..w], &mut y[..w], &mut z[..w]);
    #[cfg(all(target_arch = "x86_64", target_endian = "little"))]
    let done = {
        use std::arch::x86_64::{_mm_loadu_ps, _mm_shuffle_ps, _mm_storeu_ps};
        let whole = w / 4 * 4;
        for (((px, x), y), z) in words[..3 * whole]
            .chunks_exact(12)
            .zip(x.chunks_exact_mut(4))
            .zip(y.chunks_exact_mut(4))
            .zip(z.chunks_exact_mut(4))
        {
            // SAFETY: `px` holds 12 u32 and `x`, `y`, `z` 4 each (the chunk sizes), so the
            // three 16-byte loads and the three stores stay inside them; unaligned loads
            // and stores need no alignment, and u32 and f32 share size, so the float
            // registers carry the bits unchanged (moves and shuffles never touch a value).
            unsafe {
                let p = px.as_ptr().cast::<f32>();
                let (a, b, c) = (
                    _mm_loadu_ps(p),
                    _mm_loadu_ps(p.add(4)),
                    _mm_loadu_ps(p.add(8)),
                );
                // a = x0 y0 z0 x1, b = y1 z1 x2 y2, c = z2 x3 y3 z3. The immediate of
                // `_mm_shuffle_ps(u, v)` picks lanes u[i0] u[i1] v[i2] v[i3], two bits
                // each from the lowest: 158 = (2, 3 | 1, 2), 73 = (1, 2 | 0, 1),
                // 140 = (0, 3 | 0, 2), 216 = (0, 2 | 1, 3), 205 = (1, 3 | 0, 3).
                let s1 = _mm_shuffle_ps::<158>(b, c); // x2 y2 x3 y3
                let s2 = _mm_shuffle_ps::<73>(a, b); // y0 z0 y1 z1
                let vx = _mm_shuffle_ps::<140>(a, s1);
                let vy = _mm_shuffle_ps::<216>(s2, s1);
                let vz = _mm_shuffle_ps::<205>(s2, c);
                _mm_storeu_ps(x.as_mut_ptr().cast::<f32>(), vx);
                _mm_storeu_ps(y.as_mut_ptr().cast::<f32>(), vy);
                _mm_storeu_ps(z.as_mut_ptr().cast::<f32>(), vz);
            }
        }
        whole
    };
    #[cfg(not(all(target_arch = "x86_64", target_endian = "little")))]
    let done = 0;
    for p in done..w {
        x[p] = words[3 * p].to_le();
        y[p] = words[3 * p + 1].to_le();
        z[p] = words[3 * p + 2].to_le();
    }
}

#[cfg(test)]
#[test]
fn split3_takes_every_row_length_apart() {
    for w in 0..20 {
        let words: Vec<u32> = (0..3 * w as u32).map(|i| i * 7 + 1).collect();
        let mut out = vec![0; 3 * w];
        let (x, rest) = out.split_at_mut(w);
        let (y, z) = rest.split_at_mut(w);
        split3(&words, x, y, z);
        for p in 0..w {
            assert_eq!(
                [out[p], out[w + p], out[2 * w + p]],
                [words[3 * p], words[3 * p + 1], words[3 * p + 2]],
                "{w} pixels, pixel {p}"
            );
        }
    }
}

/// An uncompressed OpenEXR written band by band, in any order and from any thread, while
/// the rest of the image is still being traced (see [`crate::render::render_bands`]): each
/// band's lines go straight to their place in the file (positional writes), the header
/// last, once the first band has shown the channels. The file is the same bytes
/// [`AovImage::write_uncompressed_with`] writes for the whole image (tested).
pub struct ExrBands<'f> {
    file: &'f std::fs::File,
    height: usize,
    attrs: &'f [ExrAttr],
    layout: std::sync::OnceLock<Uncompressed>,
}

impl<'f> ExrBands<'f> {
    /// A writer of an image `height` rows tall into `file` (empty, e.g. staged), with the
    /// extra header attributes `attrs`.
    pub fn new(file: &'f std::fs::File, height: usize, attrs: &'f [ExrAttr]) -> Self {
        ExrBands {
            file,
            height,
            attrs,
            layout: std::sync::OnceLock::new(),
        }
    }

    /// Write `band`, the image's rows from `y0`.
    pub fn write_band(&self, y0: usize, band: &AovImage) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        let layout = self
            .layout
            .get_or_init(|| Uncompressed::new(band, self.height, self.attrs));
        let mut bytes = Vec::with_capacity(band.height * (8 + layout.line_bytes));
        let mut scratch: Vec<u32> = Vec::new();
        for row in 0..band.height {
            layout.write_line(&mut bytes, band, row, y0 + row, &mut scratch)?;
        }
        self.file.write_all_at(&bytes, layout.line_offset(y0))
    }

    /// Write the header and offset table: after every band.
    pub fn finish(self) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        match self.layout.get() {
            Some(layout) => self.file.write_all_at(&layout.head, 0),
            None => Err(std::io::Error::other("no band was written")),
        }
    }
}

/// A writer that puts a single-part OpenEXR header's attributes in name order before they
/// reach `inner`. The `exr` crate keeps custom attributes in a `HashMap`, so their order, and
/// with it the file's bytes, would change from one process to the next; sorted, a compressed
/// EXR is a pure function of its image and options, as an uncompressed one is. (OpenEXR's
/// own writer also emits attributes in name order: its header is a `std::map`.) The header's
/// length does not depend on the order, so the offsets the crate writes later stay right.
///
/// Bytes are held until the header is complete (magic, version, then `name\0 type\0 size
/// value` records up to a lone `\0`); from then on writes and seeks pass through. The crate
/// writes the header in one go before it first seeks (to fill in the offset table), so a seek
/// with the header still incomplete is a bug and is refused.
struct SortedHeader<W: std::io::Write + std::io::Seek> {
    inner: W,
    held: Option<Vec<u8>>,
}

impl<W: std::io::Write + std::io::Seek> SortedHeader<W> {
    fn new(inner: W) -> Self {
        SortedHeader {
            inner,
            held: Some(Vec::new()),
        }
    }

    /// The byte ranges of the header's attribute records, and the header's end (one past its
    /// terminating `\0`); `None` while the header is incomplete.
    fn records(bytes: &[u8]) -> Option<(Vec<std::ops::Range<usize>>, usize)> {
        let mut at = 8; // magic number and version
        let mut records = Vec::new();
        loop {
            if *bytes.get(at)? == 0 {
                return Some((records, at + 1));
            }
            let start = at;
            let name_end = at + bytes.get(at..)?.iter().position(|&b| b == 0)?;
            let type_end =
                name_end + 1 + bytes.get(name_end + 1..)?.iter().position(|&b| b == 0)?;
            let size: [u8; 4] = bytes.get(type_end + 1..type_end + 5)?.try_into().ok()?;
            let size = usize::try_from(i32::from_le_bytes(size)).ok()?;
            at = type_end + 5 + size;
            bytes.get(..at)?;
            records.push(start..at);
        }
    }

    /// Write out a held header once it is complete; return whether it was.
    fn release(&mut self) -> std::io::Result<bool> {
        let Some(held) = &self.held else {
            return Ok(true);
        };
        let Some((mut records, end)) = Self::records(held) else {
            return Ok(false);
        };
        let name = |r: &std::ops::Range<usize>| {
            let b = &held[r.clone()];
            &b[..b.iter().position(|&c| c == 0).unwrap_or(b.len())]
        };
        records.sort_by(|a, b| name(a).cmp(name(b)));
        let mut out = Vec::with_capacity(held.len());
        out.extend_from_slice(&held[..8]);
        for r in &records {
            out.extend_from_slice(&held[r.clone()]);
        }
        out.extend_from_slice(&held[end - 1..]);
        self.inner.write_all(&out)?;
        self.held = None;
        Ok(true)
    }

    /// Flush what is held and the writer; an incomplete header is an error.
    fn finish(mut self) -> std::io::Result<()> {
        if !self.release()? {
            return Err(std::io::Error::other(
                "the EXR encoder wrote an incomplete header",
            ));
        }
        self.inner.flush()
    }
}

impl<W: std::io::Write + std::io::Seek> std::io::Write for SortedHeader<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match &mut self.held {
            Some(held) => {
                held.extend_from_slice(buf);
                self.release()?;
                Ok(buf.len())
            }
            None => self.inner.write(buf),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.held.is_none() {
            self.inner.flush()?;
        }
        Ok(())
    }
}

impl<W: std::io::Write + std::io::Seek> std::io::Seek for SortedHeader<W> {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        if !self.release()? {
            return Err(std::io::Error::other(
                "the EXR encoder sought before its header was complete",
            ));
        }
        self.inner.seek(pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mixed f32 and u32 channels, names out of order, an interleaved three-channel
    /// buffer and a last band of one row.
    fn sample_image() -> AovImage {
        let (w, h) = (37, 33);
        let ramp = |k: f32| (0..w * h).map(|i| i as f32 * k - 5.0).collect::<Vec<f32>>();
        let channel = |name: &str, data| Channel {
            name: name.into(),
            data,
        };
        AovImage::from_channels(
            w,
            h,
            vec![
                channel("normal.Z", ChannelData::F32(ramp(0.25))),
                channel("depth", ChannelData::F32(ramp(1.5))),
                channel("shape_id", ChannelData::U32((0..(w * h) as u32).collect())),
                channel("normal.X", ChannelData::F32(ramp(-0.5))),
                channel("normal.Y", ChannelData::F32(ramp(2.0))),
            ],
        )
    }

    /// Written band by band in scrambled order through positional writes, the file is the
    /// bytes of the whole image's streamed write (mixed f32 and u32 channels, names out of
    /// order, a last band of one row), and the `exr` crate reads it back.
    /// The three normal planes become one buffer of `(x, y, z)` triples in the table's
    /// order; each channel reads back as its plane; taken apart, the same planes.
    #[test]
    fn vector_channels_share_one_interleaved_buffer() {
        let img = sample_image();
        assert_eq!(img.buffers.len(), 3);
        let n = img.aov_buffer(Aov::Normal).expect("one normal buffer");
        let ChannelData::F32(v) = &n.data else {
            panic!("normal is f32")
        };
        assert_eq!(v.len(), 3 * 37 * 33);
        let k = 100;
        assert_eq!(
            v[3 * k..3 * k + 3],
            [
                k as f32 * -0.5 - 5.0,
                k as f32 * 2.0 - 5.0,
                k as f32 * 0.25 - 5.0
            ]
        );
        let [x, _, z] = img.vec3_channel("normal").unwrap();
        assert_eq!((x[k], z[k]), (v[3 * k], v[3 * k + 2]));
        assert_eq!(z.len(), 37 * 33);
        let back = AovImage::from_channels(img.width, img.height, img.to_channels());
        assert_eq!(back, img);
        let mut one = img.clone();
        one.retain_channels(|c| c != "normal.Y");
        assert_eq!(one.names(), ["normal.X", "normal.Z", "depth", "shape_id"]);
        assert_eq!(one.f32_channel("normal.Z"), img.f32_channel("normal.Z"));
    }

    /// Written band by band in scrambled order through positional writes, the file is the
    /// bytes of the whole image's streamed write, and the `exr` crate reads it back.
    #[test]
    fn band_writes_make_the_whole_file() {
        let img = sample_image();
        let (w, h) = (img.width, img.height);
        let attrs = [ExrAttr::Text("cylaov:units".into(), "m".into())];
        let mut whole = Vec::new();
        img.write_uncompressed_with(&mut whole, &attrs).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bands.exr");
        let file = std::fs::File::create(&path).unwrap();
        let bands = ExrBands::new(&file, h, &attrs);
        for y0 in [32, 16, 0] {
            let rows = y0..(y0 + 16).min(h);
            let band = AovImage {
                width: w,
                height: rows.len(),
                buffers: img
                    .buffers
                    .iter()
                    .map(|b| {
                        let s = rows.start * w * b.stride()..rows.end * w * b.stride();
                        AovBuffer {
                            names: b.names.clone(),
                            data: match &b.data {
                                ChannelData::F32(v) => ChannelData::F32(v[s].to_vec()),
                                ChannelData::U32(v) => ChannelData::U32(v[s].to_vec()),
                            },
                        }
                    })
                    .collect(),
            };
            bands.write_band(y0, &band).unwrap();
        }
        bands.finish().unwrap();
        drop(file);
        assert!(std::fs::read(&path).unwrap() == whole, "the same bytes");
        let back = AovImage::read_exr(&path).unwrap();
        assert_eq!(back, img);
        // The exr crate's own writer (compressed) holds the same samples.
        let zip = dir.path().join("zip.exr");
        img.write_exr(&zip, Compression::Zip).unwrap();
        assert_eq!(AovImage::read_exr(&zip).unwrap(), img);
    }
}
