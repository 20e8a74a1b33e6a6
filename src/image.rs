//! The image a render fills: one buffer per AOV ([`AovBuffer`], `(H, W)` or `(H, W, C)`,
//! row-major, a pixel's channels side by side, the layout numpy arrays and `.npy` members
//! take as they are), read channel by channel through [`Strided`] views, and named by the
//! AOV table's channel names. It knows no file format: `output` writes it (EXR, PNG, npy,
//! PLY) and reads it back, and `render` fills it without knowing who writes it.

use crate::scene::Aov;

/// Samples of one buffer, row-major, row 0 at the top, a pixel's channels side by side.
#[derive(Clone, Debug, PartialEq)]
pub enum ChannelData {
    /// float32 samples: every channel but the layered layout's `shape_id` and `part` (and
    /// all of a Mitsuba reference, ids included).
    F32(Vec<f32>),
    /// u32 samples (`shape_id`, `part` in the layered layout).
    U32(Vec<u32>),
}

impl ChannelData {
    /// Every `stride`-th sample from `offset`: one channel of an interleaved buffer.
    fn pick(&self, offset: usize, stride: usize) -> ChannelData {
        fn every<X: Copy>(v: &[X], offset: usize, stride: usize) -> Vec<X> {
            v.iter().skip(offset).step_by(stride).copied().collect()
        }
        match self {
            ChannelData::F32(v) => ChannelData::F32(every(v, offset, stride)),
            ChannelData::U32(v) => ChannelData::U32(every(v, offset, stride)),
        }
    }
}

/// One named channel on its own (a plane of `width × height` samples): how images are
/// built from, and taken apart into, their file channels ([`AovImage::from_channels`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// The EXR channel name, e.g. `depth` or `normal.X` (the AOV table's, [`crate::scene::aov::AOV_TABLE`]).
    pub name: String,
    /// The samples: `width × height` of them, row-major, row 0 at the top.
    pub data: ChannelData,
}

/// The samples of one AOV in one buffer: `(H, W)` for one channel, `(H, W, C)` for `C`,
/// row-major and pixel-interleaved, the layout numpy and the `.npy` members of tar shards
/// hand out as is (no copy, no reordering). Files read from elsewhere keep each channel
/// that is not an AOV of the table as a buffer of its own.
#[derive(Clone, Debug, PartialEq)]
pub struct AovBuffer {
    /// The EXR channel names of its components, in interleaved order (`normal.X`,
    /// `normal.Y`, `normal.Z`; one name for a one-channel AOV).
    pub names: Vec<String>,
    /// `width × height × names.len()` samples.
    pub data: ChannelData,
}

impl AovBuffer {
    /// A buffer of `names` over `data` (`names.len()` samples a pixel).
    pub fn new(names: &[&str], data: ChannelData) -> AovBuffer {
        AovBuffer {
            names: names.iter().map(|n| n.to_string()).collect(),
            data,
        }
    }

    /// Channels a pixel.
    pub fn stride(&self) -> usize {
        self.names.len()
    }

    /// Where channel `name` lies in a pixel, if it is one of this buffer's.
    fn position(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The samples of its component `k`.
    fn component(&self, k: usize) -> ChannelRef<'_> {
        let s = self.stride();
        match &self.data {
            ChannelData::F32(v) => ChannelRef::F32(Strided::new(v, k, s)),
            ChannelData::U32(v) => ChannelRef::U32(Strided::new(v, k, s)),
        }
    }
}

/// One channel of a buffer: every `stride`-th sample from `offset` (a slice when the
/// buffer has one channel). Indexed by pixel.
#[derive(Clone, Copy, Debug)]
pub struct Strided<'a, X> {
    data: &'a [X],
    offset: usize,
    stride: usize,
}

impl<'a, X: Copy> Strided<'a, X> {
    fn new(data: &'a [X], offset: usize, stride: usize) -> Self {
        Strided {
            data,
            offset,
            stride,
        }
    }

    /// Pixels (samples of this channel).
    pub fn len(&self) -> usize {
        self.data.len() / self.stride
    }

    /// Whether it has no sample.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The samples in pixel order.
    pub fn iter(&self) -> std::iter::StepBy<std::iter::Skip<std::slice::Iter<'a, X>>> {
        self.data.iter().skip(self.offset).step_by(self.stride)
    }

    /// The samples of pixels `range`, in order.
    pub fn range(
        &self,
        range: std::ops::Range<usize>,
    ) -> std::iter::StepBy<std::iter::Skip<std::slice::Iter<'a, X>>> {
        let s = self.stride;
        let end = (range.end * s).min(self.data.len());
        self.data[range.start * s..end]
            .iter()
            .skip(self.offset)
            .step_by(s)
    }

    /// The samples as a vector of their own.
    pub fn to_vec(&self) -> Vec<X> {
        self.iter().copied().collect()
    }
}

impl<'a, X: Copy> IntoIterator for Strided<'a, X> {
    type Item = &'a X;
    type IntoIter = std::iter::StepBy<std::iter::Skip<std::slice::Iter<'a, X>>>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

impl<X> std::ops::Index<usize> for Strided<'_, X> {
    type Output = X;
    #[inline(always)]
    fn index(&self, k: usize) -> &X {
        &self.data[k * self.stride + self.offset]
    }
}

impl<X: PartialEq + Copy> PartialEq for Strided<'_, X> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}

/// One channel's samples, of either type (see [`AovImage::channel`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ChannelRef<'a> {
    /// float32 samples.
    F32(Strided<'a, f32>),
    /// u32 samples.
    U32(Strided<'a, u32>),
}

/// One channel of a buffer, writable in place (see [`AovImage::channel_mut`]).
#[derive(Debug)]
pub struct StridedMut<'a, X> {
    data: &'a mut [X],
    offset: usize,
    stride: usize,
}

impl<X> StridedMut<'_, X> {
    /// Pixels (samples of this channel).
    pub fn len(&self) -> usize {
        self.data.len() / self.stride
    }

    /// Whether it has no sample.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl<X> std::ops::Index<usize> for StridedMut<'_, X> {
    type Output = X;
    fn index(&self, k: usize) -> &X {
        &self.data[k * self.stride + self.offset]
    }
}

impl<X> std::ops::IndexMut<usize> for StridedMut<'_, X> {
    fn index_mut(&mut self, k: usize) -> &mut X {
        &mut self.data[k * self.stride + self.offset]
    }
}

/// One channel's samples, writable, of either type.
#[derive(Debug)]
pub enum ChannelMut<'a> {
    /// float32 samples.
    F32(StridedMut<'a, f32>),
    /// u32 samples.
    U32(StridedMut<'a, u32>),
}

/// A multi-channel image of AOVs: one buffer an AOV (see [`AovBuffer`]). Two images are
/// equal when they hold the same buffers, in whatever order.
#[derive(Clone, Debug)]
pub struct AovImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// The buffers; any order (files sort their channels by name).
    pub buffers: Vec<AovBuffer>,
}

impl PartialEq for AovImage {
    fn eq(&self, other: &Self) -> bool {
        (self.width, self.height, self.buffers.len())
            == (other.width, other.height, other.buffers.len())
            && self.buffers.iter().all(|b| other.buffers.contains(b))
    }
}

impl AovImage {
    /// An image of `channels`, each a plane: the channels of each AOV of the table that
    /// has several (all present, all float32) become that AOV's one interleaved buffer, in
    /// the table's order, where its first channel was; every other channel is a buffer of
    /// its own.
    pub fn from_channels(width: usize, height: usize, channels: Vec<Channel>) -> AovImage {
        let mut slots: Vec<Option<Channel>> = channels.into_iter().map(Some).collect();
        let mut buffers = Vec::new();
        for k in 0..slots.len() {
            let Some(first) = &slots[k] else { continue };
            let group = Aov::of_channel(&first.name)
                .map(|a| a.spec().channels)
                .filter(|names| names.len() > 1)
                .and_then(|names| {
                    let at: Vec<usize> = names
                        .iter()
                        .map(|n| {
                            slots.iter().position(|s| {
                                s.as_ref().is_some_and(|c| {
                                    c.name == *n && matches!(c.data, ChannelData::F32(_))
                                })
                            })
                        })
                        .collect::<Option<_>>()?;
                    Some((names, at))
                });
            match group {
                Some((names, at)) => {
                    let planes: Vec<Vec<f32>> = at
                        .iter()
                        .map(|&i| match slots[i].take().map(|c| c.data) {
                            Some(ChannelData::F32(v)) => v,
                            _ => unreachable!("checked float32 above"),
                        })
                        .collect();
                    let n = planes.iter().map(Vec::len).min().unwrap_or(0);
                    // Exactly the samples' size (a collected iterator would grow by
                    // doubling and keep up to twice that).
                    let mut data = Vec::with_capacity(n * planes.len());
                    for p in 0..n {
                        data.extend(planes.iter().map(|v| v[p]));
                    }
                    buffers.push(AovBuffer::new(names, ChannelData::F32(data)));
                }
                None => {
                    if let Some(c) = slots[k].take() {
                        buffers.push(AovBuffer {
                            names: vec![c.name],
                            data: c.data,
                        });
                    }
                }
            }
        }
        AovImage {
            width,
            height,
            buffers,
        }
    }

    /// Its channels, each a plane of its own (copies), in buffer order.
    pub fn to_channels(&self) -> Vec<Channel> {
        self.buffers
            .iter()
            .flat_map(|b| {
                b.names.iter().enumerate().map(|(k, name)| Channel {
                    name: name.clone(),
                    data: b.data.pick(k, b.stride()),
                })
            })
            .collect()
    }

    /// Every channel's name, in buffer order.
    pub fn names(&self) -> Vec<&str> {
        self.buffers
            .iter()
            .flat_map(|b| b.names.iter().map(String::as_str))
            .collect()
    }

    /// Whether it has a channel named `name`.
    pub fn has_channel(&self, name: &str) -> bool {
        self.find(name).is_some()
    }

    /// The buffer holding channel `name` and the channel's place in a pixel.
    fn find(&self, name: &str) -> Option<(usize, usize)> {
        self.buffers
            .iter()
            .enumerate()
            .find_map(|(b, buf)| Some((b, buf.position(name)?)))
    }

    /// The samples of the channel named `name`, if there is one.
    pub fn channel(&self, name: &str) -> Option<ChannelRef<'_>> {
        let (b, k) = self.find(name)?;
        Some(self.buffers[b].component(k))
    }

    /// The samples of the channel named `name`, writable in place.
    pub fn channel_mut(&mut self, name: &str) -> Option<ChannelMut<'_>> {
        let (b, offset) = self.find(name)?;
        let buf = &mut self.buffers[b];
        let stride = buf.names.len();
        Some(match &mut buf.data {
            ChannelData::F32(v) => ChannelMut::F32(StridedMut {
                data: v,
                offset,
                stride,
            }),
            ChannelData::U32(v) => ChannelMut::U32(StridedMut {
                data: v,
                offset,
                stride,
            }),
        })
    }

    /// The float32 channel named `name`, writable; `None` if absent or u32.
    pub fn f32_channel_mut(&mut self, name: &str) -> Option<StridedMut<'_, f32>> {
        match self.channel_mut(name)? {
            ChannelMut::F32(v) => Some(v),
            ChannelMut::U32(_) => None,
        }
    }

    /// The u32 channel named `name`, writable; `None` if absent or float32.
    pub fn u32_channel_mut(&mut self, name: &str) -> Option<StridedMut<'_, u32>> {
        match self.channel_mut(name)? {
            ChannelMut::U32(v) => Some(v),
            ChannelMut::F32(_) => None,
        }
    }

    /// The samples of the float32 channel named `name`; `None` if absent or u32.
    pub fn f32_channel(&self, name: &str) -> Option<Strided<'_, f32>> {
        match self.channel(name)? {
            ChannelRef::F32(v) => Some(v),
            ChannelRef::U32(_) => None,
        }
    }

    /// The samples of the u32 channel named `name`; `None` if absent or float32.
    pub fn u32_channel(&self, name: &str) -> Option<Strided<'_, u32>> {
        match self.channel(name)? {
            ChannelRef::U32(v) => Some(v),
            ChannelRef::F32(_) => None,
        }
    }

    /// Three f32 channels `NAME.X/Y/Z`.
    pub fn vec3_channel(&self, name: &str) -> Option<[Strided<'_, f32>; 3]> {
        Some([
            self.f32_channel(&format!("{name}.X"))?,
            self.f32_channel(&format!("{name}.Y"))?,
            self.f32_channel(&format!("{name}.Z"))?,
        ])
    }

    /// Where the buffer of `aov` is: the one holding its channels of the table, in the
    /// table's order.
    fn aov_position(&self, aov: Aov) -> Option<usize> {
        let names = aov.spec().channels;
        self.buffers
            .iter()
            .position(|b| b.names.iter().map(String::as_str).eq(names.iter().copied()))
    }

    /// The buffer of `aov`: its channels of the table, in the table's order.
    pub fn aov_buffer(&self, aov: Aov) -> Option<&AovBuffer> {
        Some(&self.buffers[self.aov_position(aov)?])
    }

    /// Take the buffer of `aov` out of the image (see [`AovImage::aov_buffer`]).
    pub fn take_aov_buffer(&mut self, aov: Aov) -> Option<AovBuffer> {
        let at = self.aov_position(aov)?;
        Some(self.buffers.remove(at))
    }

    /// The same image with the table's vector AOVs each in one buffer again, after their
    /// channels were renamed into place (a candidate's `N.R`, a per-AOV file's `R, G, B`).
    pub fn regrouped(self) -> AovImage {
        AovImage::from_channels(self.width, self.height, self.to_channels())
    }

    /// Keep the channels whose name `keep` accepts. A buffer losing some of its channels
    /// but not all is split into one buffer per kept channel.
    pub fn retain_channels(&mut self, keep: impl Fn(&str) -> bool) {
        let mut out = Vec::with_capacity(self.buffers.len());
        for b in std::mem::take(&mut self.buffers) {
            let kept = b.names.iter().filter(|n| keep(n)).count();
            if kept == b.names.len() {
                out.push(b);
            } else if kept > 0 {
                for (k, name) in b.names.iter().enumerate().filter(|(_, n)| keep(n)) {
                    out.push(AovBuffer {
                        names: vec![name.clone()],
                        data: b.data.pick(k, b.stride()),
                    });
                }
            }
        }
        self.buffers = out;
    }

    /// Add `channel` as a buffer of its own (after removing any channel of its name).
    pub fn push_channel(&mut self, channel: Channel) {
        self.retain_channels(|n| n != channel.name);
        self.buffers.push(AovBuffer {
            names: vec![channel.name],
            data: channel.data,
        });
    }

    /// Rename channel `from` to `to` (a channel already named `to` goes first).
    pub fn rename_channel(&mut self, from: &str, to: &str) {
        if from == to || !self.has_channel(from) {
            return;
        }
        self.retain_channels(|n| n != to);
        if let Some((b, k)) = self.find(from) {
            self.buffers[b].names[k] = to.to_string();
        }
    }

    /// Count of NaN or infinite samples over all float channels.
    pub fn non_finite_count(&self) -> usize {
        self.buffers
            .iter()
            .map(|b| match &b.data {
                ChannelData::F32(v) => v.iter().filter(|x| !x.is_finite()).count(),
                ChannelData::U32(_) => 0,
            })
            .sum()
    }
}

/// Rows in one band of a render written band by band (see `output::pipeline::memory::streams`): the tracer's tile
/// side, which `render` checks at compile time, so that `output` needs nothing of `accel`.
pub const BAND_ROWS: usize = 16;
