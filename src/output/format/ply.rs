//! One view's hit points as a point cloud: binary little-endian PLY with `x y z nx ny nz`
//! (float32, world axes: the `position` and `normal` AOVs) and `shape_id part label`
//! (uint32), one vertex per pixel that hit a cylinder, in pixel order (row by row). Open3D,
//! CloudCompare, MeshLab and plyfile read it; the ids ride along as extra properties.

use crate::image::AovImage;
use crate::scene::Aov;

/// The AOVs a point cloud is made of.
pub const PLY_AOVS: [Aov; 5] = [
    Aov::Position,
    Aov::Normal,
    Aov::ShapeId,
    Aov::Part,
    Aov::Label,
];

/// One hit pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Hit {
    /// World-space hit point.
    pub position: [f32; 3],
    /// World-space unit outward normal.
    pub normal: [f32; 3],
    /// The hit cylinder's id.
    pub shape_id: u32,
    /// Which part of it (1 side outside, 2 side inside, 3 bottom cap, 4 top cap).
    pub part: u32,
    /// Its label.
    pub label: u32,
}

/// The hit pixels of `image`, which must hold [`PLY_AOVS`] (`None` when one is missing):
/// pixels whose `shape_id` is not 0, in pixel order.
pub fn hits(image: &AovImage) -> Option<Vec<Hit>> {
    let p = image.vec3_channel("position")?;
    let n = image.vec3_channel("normal")?;
    let id = image.u32_channel("shape_id")?.to_vec();
    let part = image.u32_channel("part")?.to_vec();
    let label = image.u32_channel("label")?.to_vec();
    let [px, py, pz] = p.map(|c| c.to_vec());
    let [nx, ny, nz] = n.map(|c| c.to_vec());
    Some(
        (0..id.len())
            .filter(|&i| id[i] != 0)
            .map(|i| Hit {
                position: [px[i], py[i], pz[i]],
                normal: [nx[i], ny[i], nz[i]],
                shape_id: id[i],
                part: part[i],
                label: label[i],
            })
            .collect(),
    )
}

/// The PLY file of `hits`; `comment` (one line, e.g. where the points come from) goes
/// into the header.
pub fn encode(hits: &[Hit], comment: &str) -> Vec<u8> {
    let comment: String = comment
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uint shape_id\nproperty uint part\nproperty uint label\nend_header\n",
        hits.len()
    )
    .into_bytes();
    out.reserve(hits.len() * 36);
    for h in hits {
        for x in h.position.iter().chain(&h.normal) {
            out.extend_from_slice(&x.to_le_bytes());
        }
        for v in [h.shape_id, h.part, h.label] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_point_is_36_bytes_after_the_header() {
        let h = Hit {
            position: [1.0, -2.0, 0.5],
            normal: [0.0, 0.0, 1.0],
            shape_id: 7,
            part: 4,
            label: 3,
        };
        let b = encode(&[h, h], "test");
        let text = String::from_utf8_lossy(&b);
        let end = text.find("end_header\n").unwrap() + "end_header\n".len();
        assert!(text.contains("element vertex 2\n"));
        assert_eq!(b.len() - end, 72);
        assert_eq!(&b[end..end + 4], &1.0f32.to_le_bytes());
        assert_eq!(&b[end + 24..end + 28], &7u32.to_le_bytes());
        assert_eq!(&b[end + 32..end + 36], &3u32.to_le_bytes());
    }
}
