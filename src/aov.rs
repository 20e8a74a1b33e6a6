//! AOV images in memory and as OpenEXR files (SPEC §4).
//!
//! Channel names are the contract: `distance`, `depth`, `normal.X/Y/Z`, `position.X/Y/Z`
//! (float32) and `shape_id` (u32). Row 0 is the top row. A missed pixel is 0 everywhere.

use crate::io::atomic_write;
use crate::scene::Aov;
use anyhow::{Context, Result, bail};
use exr::prelude::*;
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
        atomic_write(path, |file| {
            self.write_exr_to(std::io::BufWriter::new(file), compression)
                .map_err(|e| std::io::Error::other(e.to_string()))
        })
        .with_context(|| format!("writing {}", path.display()))
    }

    /// Encode as OpenEXR into any seekable writer (a file, or memory).
    pub fn write_exr_to(
        &self,
        out: impl std::io::Write + std::io::Seek,
        compression: Compression,
    ) -> Result<()> {
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
        Image::from_layer(layer)
            .write()
            .non_parallel()
            .to_buffered(out)?;
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
