//! Tar shards read back, sample by sample (`cylaov verify OUT` of a `--format webdataset`
//! folder): a sample is the members sharing a key (`KEY.json`, `KEY.depth.npy`, …), which
//! the writer puts next to each other; its `.npy` arrays of the AOV table become an
//! [`AovImage`] with the channel names of an EXR, so every check of an EXR applies to it.
//! One sample is in memory at a time.

use crate::image::{AovBuffer, AovImage, ChannelData};
use crate::npy::{self, Dtype};
use crate::output::format::exr::channel_names;
use crate::output::format::tar::TarReader;
use crate::scene::Aov;
use std::io::Read;

/// What a sample's JSON says of where it came from.
#[derive(Clone, Debug, serde::Deserialize)]
pub struct SampleInfo {
    /// The sample's key (its view name without dots).
    pub key: String,
    /// The scene's name.
    pub scene: String,
    /// The scene file, relative to the dataset's `scenes_dir` (see `shards.json`).
    pub scene_file: String,
    /// Which camera of the scene.
    pub camera_index: usize,
}

/// One sample: its JSON's fields and its AOV arrays as an image.
#[derive(Debug)]
pub struct Sample {
    /// Where the view came from.
    pub info: SampleInfo,
    /// The arrays of the AOV table the sample holds (the mask and pictures are left out).
    pub image: AovImage,
}

/// The samples of one tar, in order.
pub struct Samples<R: Read> {
    tar: TarReader<R>,
    /// A member already read that starts the next sample.
    next: Option<(String, Vec<u8>)>,
}

impl<R: Read> Samples<R> {
    /// The samples of the tar in `input`.
    pub fn new(input: R) -> Self {
        Samples {
            tar: TarReader::new(input),
            next: None,
        }
    }

    /// The next sample, `None` after the last; a member that does not parse is an error
    /// naming it.
    pub fn next_sample(&mut self) -> Result<Option<Sample>, String> {
        let first = match self.next.take() {
            Some(m) => m,
            None => match self.tar.next_member().map_err(|e| e.to_string())? {
                Some(m) => m,
                None => return Ok(None),
            },
        };
        let key = key_of(&first.0).to_string();
        let mut members = vec![first];
        while let Some(m) = self.tar.next_member().map_err(|e| e.to_string())? {
            if key_of(&m.0) != key {
                self.next = Some(m);
                break;
            }
            members.push(m);
        }
        sample(&key, &members).map(Some)
    }
}

/// The key of member `name`: what comes before its first dot (keys hold no dots).
fn key_of(name: &str) -> &str {
    name.split_once('.').map_or(name, |(k, _)| k)
}

/// A sample from its members.
fn sample(key: &str, members: &[(String, Vec<u8>)]) -> Result<Sample, String> {
    let json = members
        .iter()
        .find(|(n, _)| n.strip_prefix(key) == Some(".json"))
        .ok_or(format!("sample {key:?} has no {key}.json"))?;
    let info: SampleInfo =
        serde_json::from_slice(&json.1).map_err(|e| format!("{key}.json: {e}"))?;
    let mut buffers = Vec::new();
    let (mut width, mut height) = (None, None);
    for aov in Aov::ALL {
        let name = format!("{key}.{}.npy", aov.name());
        let Some((_, bytes)) = members.iter().find(|(n, _)| *n == name) else {
            continue;
        };
        let a = npy::parse(bytes).map_err(|e| format!("{name}: {e}"))?;
        let names = channel_names(aov);
        let (h, w) = match (&a.shape[..], names.len()) {
            ([h, w], 1) => (*h, *w),
            ([h, w, c], n) if *c == n => (*h, *w),
            (s, n) => {
                return Err(format!(
                    "{name}: shape {s:?}, where {} holds {n} channel(s) a pixel",
                    aov.name()
                ));
            }
        };
        if width.is_some_and(|x| x != w) || height.is_some_and(|y| y != h) {
            return Err(format!(
                "{name}: {h} x {w}, the sample's other arrays are {} x {}",
                height.unwrap_or(0),
                width.unwrap_or(0)
            ));
        }
        (width, height) = (Some(w), Some(h));
        let words = a.data.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]);
        let data = match (a.dtype, aov.is_u32()) {
            (Dtype::U32, true) => ChannelData::U32(words.map(u32::from_le_bytes).collect()),
            (Dtype::F32, false) => ChannelData::F32(words.map(f32::from_le_bytes).collect()),
            (d, _) => {
                return Err(format!(
                    "{name}: {d:?} samples, where {} is {}",
                    aov.name(),
                    if aov.is_u32() { "uint32" } else { "float32" }
                ));
            }
        };
        buffers.push(AovBuffer::new(names, data));
    }
    let (Some(width), Some(height)) = (width, height) else {
        return Err(format!("sample {key:?} holds no AOV array"));
    };
    Ok(Sample {
        info,
        image: AovImage {
            width,
            height,
            buffers,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::format::tar::TarWriter;

    fn json(key: &str) -> Vec<u8> {
        format!(r#"{{"key":"{key}","scene":"{key}","scene_file":"{key}.json","camera_index":0}}"#)
            .into_bytes()
    }

    /// Two samples come back as written: their keys, arrays and channel names.
    #[test]
    fn samples_come_back_as_written() {
        let mut t = TarWriter::new(Vec::new());
        let depth = [1.0f32, 2.0, 0.0, 4.0, 5.0, 6.0];
        let ids = [7u32, 0, 0, 1, 2, 3];
        for key in ["a", "b"] {
            t.append(
                &format!("{key}.depth.npy"),
                &npy::array(Dtype::F32, &[2, 3], &depth),
            )
            .unwrap();
            t.append(
                &format!("{key}.shape_id.npy"),
                &npy::array(Dtype::U32, &[2, 3], &ids),
            )
            .unwrap();
            t.append(
                &format!("{key}.mask.npy"),
                &npy::bool_plane(2, 3, [true; 6].into_iter()),
            )
            .unwrap();
            t.append(&format!("{key}.json"), &json(key)).unwrap();
        }
        let (bytes, _) = t.finish().unwrap();
        let mut s = Samples::new(&bytes[..]);
        for key in ["a", "b"] {
            let got = s.next_sample().unwrap().unwrap();
            assert_eq!(got.info.key, key);
            assert_eq!((got.image.width, got.image.height), (3, 2));
            assert_eq!(got.image.f32_channel("depth").unwrap().to_vec(), depth);
            assert_eq!(got.image.u32_channel("shape_id").unwrap().to_vec(), ids);
        }
        assert!(s.next_sample().unwrap().is_none());
    }

    /// A sample without its JSON, or with an array of the wrong type, is refused by name.
    #[test]
    fn bad_samples_are_named() {
        let mut t = TarWriter::new(Vec::new());
        t.append("a.depth.npy", &npy::array(Dtype::U32, &[1, 1], &[1u32]))
            .unwrap();
        t.append("a.json", &json("a")).unwrap();
        t.append("b.depth.npy", &npy::array(Dtype::F32, &[1, 1], &[1f32]))
            .unwrap();
        let (bytes, _) = t.finish().unwrap();
        let mut s = Samples::new(&bytes[..]);
        let e = s.next_sample().unwrap_err();
        assert!(
            e.contains("a.depth.npy: U32 samples, where depth is float32"),
            "{e}"
        );
        let e = s.next_sample().unwrap_err();
        assert!(e.contains("sample \"b\" has no b.json"), "{e}");
    }
}
