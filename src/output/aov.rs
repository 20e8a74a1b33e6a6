//! AOV images in memory and as OpenEXR files.
//!
//! Channel names are the contract: `distance`, `depth`, `normal.X/Y/Z`, `position.X/Y/Z`
//! (float32), `shape_id` and `part` (u32). Row 0 is the top row. A missed pixel is 0 everywhere.

use crate::output::io::{Staged, stage};
use crate::scene::Aov;
use anyhow::{Context, Result, bail};
use exr::prelude::*;
use std::io::Write;
use std::path::Path;

/// The samples of one channel, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub enum ChannelData {
    F32(Vec<f32>),
    U32(Vec<u32>),
}

/// One named channel.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    pub name: String,
    pub data: ChannelData,
}

/// A multi-channel image of AOVs.
#[derive(Clone, Debug, PartialEq)]
pub struct AovImage {
    pub width: usize,
    pub height: usize,
    pub channels: Vec<Channel>,
}

/// EXR compression for written files.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Compression {
    /// Uncompressed: fastest to write and read.
    #[default]
    None,
    /// ZIP, 16 scanlines per block: lossless, good for depth.
    Zip,
    /// ZIP, one scanline per block.
    Zips,
    /// PIZ wavelet: lossless, strong on noisy float data.
    Piz,
    /// RLE: cheap, weak.
    Rle,
}

impl Compression {
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

/// The EXR channel names of an AOV, in order.
pub fn channel_names(aov: Aov) -> &'static [&'static str] {
    match aov {
        Aov::Distance => &["distance"],
        Aov::Depth => &["depth"],
        Aov::Normal => &["normal.X", "normal.Y", "normal.Z"],
        Aov::Position => &["position.X", "position.Y", "position.Z"],
        Aov::ShapeId => &["shape_id"],
        Aov::Part => &["part"],
    }
}

impl AovImage {
    pub fn channel(&self, name: &str) -> Option<&ChannelData> {
        self.channels
            .iter()
            .find(|c| c.name == name)
            .map(|c| &c.data)
    }

    pub fn f32_channel(&self, name: &str) -> Option<&[f32]> {
        match self.channel(name)? {
            ChannelData::F32(v) => Some(v),
            ChannelData::U32(_) => None,
        }
    }

    pub fn u32_channel(&self, name: &str) -> Option<&[u32]> {
        match self.channel(name)? {
            ChannelData::U32(v) => Some(v),
            ChannelData::F32(_) => None,
        }
    }

    /// Three f32 channels `NAME.X/Y/Z` as one slice each.
    pub fn vec3_channel(&self, name: &str) -> Option<[&[f32]; 3]> {
        Some([
            self.f32_channel(&format!("{name}.X"))?,
            self.f32_channel(&format!("{name}.Y"))?,
            self.f32_channel(&format!("{name}.Z"))?,
        ])
    }

    /// Count of NaN or infinite samples over all float channels.
    pub fn non_finite_count(&self) -> usize {
        self.channels
            .iter()
            .map(|c| match &c.data {
                ChannelData::F32(v) => v.iter().filter(|x| !x.is_finite()).count(),
                ChannelData::U32(_) => 0,
            })
            .sum()
    }

    /// Write an OpenEXR file atomically (temporary name, then rename).
    pub fn write_exr(&self, path: &Path, compression: Compression) -> Result<()> {
        self.stage_exr(path, compression)?
            .commit()
            .with_context(|| format!("writing {}", path.display()))
    }

    /// Encode an OpenEXR file to `path`'s temporary name, to be committed with others.
    pub fn stage_exr(&self, path: &Path, compression: Compression) -> Result<Staged> {
        stage(path, |file| {
            let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
            self.write_exr_to(&mut out, compression)
                .map_err(|e| std::io::Error::other(format!("{e:#}")))?;
            out.flush()
        })
        .with_context(|| format!("writing {}", path.display()))
    }

    /// Encode as OpenEXR into any seekable writer (a file, or memory). Uncompressed files
    /// are streamed by [`AovImage::write_uncompressed`]; the rest go through the `exr`
    /// crate, which compresses blocks in parallel.
    pub fn write_exr_to(
        &self,
        mut out: impl std::io::Write + std::io::Seek,
        compression: Compression,
    ) -> Result<()> {
        if compression == Compression::None {
            self.write_uncompressed(&mut out)?;
            return Ok(());
        }
        let channels: Vec<AnyChannel<FlatSamples>> = self
            .channels
            .iter()
            .map(|c| {
                let samples = match &c.data {
                    ChannelData::F32(v) => FlatSamples::F32(v.clone()),
                    ChannelData::U32(v) => FlatSamples::U32(v.clone()),
                };
                AnyChannel::new(c.name.as_str(), samples)
            })
            .collect();
        let layer = Layer::new(
            (self.width, self.height),
            LayerAttributes::default(),
            Encoding {
                compression: compression.to_exr(),
                blocks: Blocks::ScanLines,
                line_order: LineOrder::Increasing,
            },
            AnyChannels::sort(channels.into()),
        );
        Image::from_layer(layer).write().to_buffered(out)?;
        Ok(())
    }

    /// Stream an uncompressed single-part scanline OpenEXR straight from the planes (the
    /// `exr` crate copies every sample through its own layout, which costs more than the
    /// render at 1080p). Layout: magic and version, the header attributes, the
    /// offset table (one u64 per line), then per line its `y`, byte count, and each
    /// channel's row in channel-name order. Every row is already contiguous in its plane,
    /// so a line is written as slices, with no per-sample work on little-endian machines.
    pub fn write_uncompressed<W: std::io::Write>(&self, out: &mut W) -> std::io::Result<()> {
        let mut order: Vec<&Channel> = self.channels.iter().collect();
        order.sort_by(|a, b| a.name.as_bytes().cmp(b.name.as_bytes()));
        let (w, h) = (self.width, self.height);
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
        for c in &order {
            chlist.extend_from_slice(c.name.as_bytes());
            chlist.push(0);
            let pixel_type: i32 = match c.data {
                ChannelData::U32(_) => 0,
                ChannelData::F32(_) => 2,
            };
            chlist.extend_from_slice(&pixel_type.to_le_bytes());
            chlist.extend_from_slice(&[0, 0, 0, 0]); // pLinear, reserved
            chlist.extend_from_slice(&1i32.to_le_bytes()); // x sampling
            chlist.extend_from_slice(&1i32.to_le_bytes()); // y sampling
        }
        chlist.push(0);
        let window: Vec<u8> = [0i32, 0, w as i32 - 1, h as i32 - 1]
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
        head.push(0);
        let line_bytes = w * 4 * order.len();
        let data_start = head.len() + 8 * h;
        for y in 0..h {
            head.extend_from_slice(&((data_start + y * (8 + line_bytes)) as u64).to_le_bytes());
        }
        out.write_all(&head)?;
        let mut scratch: Vec<u8> = Vec::new();
        for y in 0..h {
            out.write_all(&(y as i32).to_le_bytes())?;
            out.write_all(&(line_bytes as i32).to_le_bytes())?;
            for c in &order {
                let row = y * w..(y + 1) * w;
                let bytes: &[u8] = match &c.data {
                    ChannelData::F32(v) => bytemuck::cast_slice(&v[row]),
                    ChannelData::U32(v) => bytemuck::cast_slice(&v[row]),
                };
                if cfg!(target_endian = "little") {
                    out.write_all(bytes)?;
                } else {
                    // Samples are stored little-endian: swap each 4-byte word.
                    scratch.clear();
                    scratch.extend(bytes.chunks_exact(4).flat_map(|q| [q[3], q[2], q[1], q[0]]));
                    out.write_all(&scratch)?;
                }
            }
        }
        Ok(())
    }

    /// Read every channel of the first layer of an OpenEXR file. Half channels become f32.
    pub fn read_exr(path: &Path) -> Result<AovImage> {
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_file(path)
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
        Ok(AovImage {
            width: size.0,
            height: size.1,
            channels,
        })
    }
}
