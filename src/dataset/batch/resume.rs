//! Resume: the output paths of a view, the render stamp that says what made them, and the
//! cheap checks that tell a complete view from a partial or stale one.

use super::options::BatchOptions;
use crate::output::format::exr::{Compression, ExrLayout, channel_names, per_aov_channel_names};
use crate::output::pipeline::view::{DepthPngPlan, Member, ViewPlan};
use crate::output::store::files::{open_regular, read_regular};
use crate::scene::camera::Camera;
use crate::scene::camera::Projection;
use crate::scene::{Aov, Scene};
use exr::meta::MetaData;
use exr::meta::attribute::SampleType;
use serde::Serialize;
use std::io::{Cursor, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// The output paths of view `name` in `dir` (the names of `crate::dataset::names`).
pub struct ViewFiles {
    /// The view's EXR (`NAME.exr`; the layered layout).
    pub exr: PathBuf,
    /// Camera metadata (`NAME.camera.json`).
    pub camera: PathBuf,
    /// Open3D `PinholeCameraParameters`.
    pub open3d: PathBuf,
    /// The 8-bit normal picture (`NAME.normal.preview.png`).
    pub normal_png: PathBuf,
    /// 16-bit planar depth × scale: data.
    pub depth_png: PathBuf,
    /// 8-bit hit mask.
    pub mask_png: PathBuf,
    /// The [`render_stamp`].
    pub stamp: PathBuf,
    /// The hit points (`NAME.ply`, with `--ply`).
    pub ply: PathBuf,
    /// Where versions before 0.2 put the normal picture; removed when the view is rendered.
    pub legacy_normal_png: PathBuf,
    dir: PathBuf,
    name: String,
}

impl ViewFiles {
    /// The output paths of view `name` in folder `dir`.
    pub fn new(dir: &Path, name: &str) -> ViewFiles {
        ViewFiles {
            exr: dir.join(format!("{name}.exr")),
            camera: dir.join(format!("{name}.camera.json")),
            open3d: dir.join(format!("{name}.open3d.json")),
            normal_png: dir.join(format!("{name}.normal.preview.png")),
            depth_png: dir.join(format!("{name}.depth.png")),
            mask_png: dir.join(format!("{name}.mask.png")),
            stamp: dir.join(format!("{name}.render.json")),
            ply: dir.join(format!("{name}.ply")),
            legacy_normal_png: dir.join(format!("{name}.normal.png")),
            dir: dir.to_path_buf(),
            name: name.to_string(),
        }
    }

    /// `NAME.<aov>.exr` of the per-AOV layout.
    pub fn per_aov(&self, aov: Aov) -> PathBuf {
        self.dir.join(format!("{}.{}.exr", self.name, aov.name()))
    }

    /// Every path a run may write, replace or remove for this view (both layouts, the
    /// pictures, the stamp and the cached verdict `NAME.verify.json`).
    pub fn all(&self) -> Vec<PathBuf> {
        let mut v = vec![
            self.exr.clone(),
            self.camera.clone(),
            self.open3d.clone(),
            self.normal_png.clone(),
            self.depth_png.clone(),
            self.mask_png.clone(),
            self.stamp.clone(),
            self.legacy_normal_png.clone(),
            self.dir.join(format!("{}.verify.json", self.name)),
        ];
        v.extend(Aov::ALL.iter().map(|&a| self.per_aov(a)));
        v
    }
}

/// What follows `NAME.` in the name of a file batch writes for view `NAME` (besides the
/// per-AOV EXRs `NAME.AOV.exr`), in any layout and with any options, with its verdict
/// (`--verify-fraction`) and the normal picture's name before 0.2.
const VIEW_SUFFIXES: &[&str] = &[
    "exr",
    "camera.json",
    "open3d.json",
    "normal.preview.png",
    "depth.png",
    "mask.png",
    "render.json",
    "verify.json",
    "normal.png",
];

/// Every file name view `name` may have in its folder: what goes when the view does.
pub fn view_file_names(name: &str) -> Vec<String> {
    VIEW_SUFFIXES
        .iter()
        .map(|s| format!("{name}.{s}"))
        .chain(Aov::ALL.iter().map(|a| format!("{name}.{}.exr", a.name())))
        .collect()
}

/// The per-AOV EXR channels of `aov`, sorted as the file stores them: all float32.
fn per_aov_channels(aov: Aov) -> Vec<(&'static str, SampleType)> {
    let mut v: Vec<_> = per_aov_channel_names(aov)
        .iter()
        .map(|&c| (c, SampleType::F32))
        .collect();
    v.sort_by(|a, b| a.0.cmp(b.0));
    v
}

/// EXR channels of `aovs`, sorted as the file stores them, with their sample types.
pub fn expected_channels(aovs: &[Aov]) -> Vec<(&'static str, SampleType)> {
    let mut v: Vec<_> = aovs
        .iter()
        .flat_map(|&a| {
            let ty = if a.is_u32() {
                SampleType::U32
            } else {
                SampleType::F32
            };
            channel_names(a).iter().map(move |&c| (c, ty))
        })
        .collect();
    v.sort_by(|a, b| a.0.cmp(b.0));
    v
}

/// Cheap completeness check of an EXR written by us: the header has the expected size,
/// channels and compression, every offset of the offset table lies inside the file, and the
/// chunk at the largest offset ends (by the byte count in its 8-byte chunk header) exactly
/// at the end of the file. A truncated file fails; a file damaged inside, with its length
/// unchanged, passes (the pixels are not read: that is what the atomic renames are for).
/// Reads the header, the offset table and 8 bytes.
pub fn exr_is_complete(
    path: &Path,
    width: usize,
    height: usize,
    channels: &[(&str, SampleType)],
    compression: Compression,
) -> Result<(), String> {
    let mut f = open_regular(path).map_err(|e| e.to_string())?;
    let len = f.metadata().map_err(|e| e.to_string())?.len();
    // Header + offset table: a few hundred bytes + 8 per chunk (16384 rows: 128 KiB).
    let mut prefix = Vec::new();
    (&mut f)
        .take(len.min(1 << 20))
        .read_to_end(&mut prefix)
        .map_err(|e| e.to_string())?;
    let mut cur = Cursor::new(&prefix[..]);
    let meta = MetaData::read_from_buffered(&mut cur, false).map_err(|e| e.to_string())?;
    let [header] = &meta.headers[..] else {
        return Err("expected one layer".into());
    };
    if header.layer_size.0 != width || header.layer_size.1 != height {
        return Err(format!(
            "size {}x{}, expected {width}x{height}",
            header.layer_size.0, header.layer_size.1
        ));
    }
    let got: Vec<(String, SampleType)> = header
        .channels
        .list
        .iter()
        .map(|c| (c.name.to_string(), c.sample_type))
        .collect();
    let same = got.len() == channels.len()
        && got
            .iter()
            .zip(channels)
            .all(|(g, e)| g.0 == e.0 && g.1 == e.1);
    if !same {
        return Err(format!("channels {got:?}, expected {channels:?}"));
    }
    let want = compression.to_exr();
    if header.compression != want {
        return Err(format!(
            "compression {:?}, expected {want:?}",
            header.compression
        ));
    }
    // The offset table follows the header directly.
    let table_start = cur.position() as usize;
    let table_end = table_start + header.chunk_count * 8;
    let table = prefix
        .get(table_start..table_end)
        .ok_or("file ends inside the offset table")?;
    let offsets: Vec<u64> = table
        .chunks_exact(8)
        .map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()))
        .collect();
    let last = offsets.iter().copied().max().ok_or("no chunks")?;
    if offsets.iter().any(|&o| o < table_end as u64 || o + 8 > len) {
        return Err("chunk offset outside the file".into());
    }
    // A scanline chunk: i32 y, i32 byte count, the bytes.
    let mut head = [0u8; 8];
    f.seek(SeekFrom::Start(last)).map_err(|e| e.to_string())?;
    f.read_exact(&mut head).map_err(|e| e.to_string())?;
    let size = i32::from_le_bytes([head[4], head[5], head[6], head[7]]);
    if size < 0 || last + 8 + size as u64 != len {
        return Err(format!(
            "last chunk ends at {}, file has {len} bytes",
            last + 8 + size.max(0) as u64
        ));
    }
    Ok(())
}

/// Whether the file exists and ends with `tail` (a PNG's IEND chunk).
fn file_ends_with(path: &Path, tail: &[u8]) -> bool {
    let read = || -> std::io::Result<bool> {
        let mut f = open_regular(path)?;
        let len = f.metadata()?.len();
        if len < tail.len() as u64 {
            return Ok(false);
        }
        f.seek(SeekFrom::Start(len - tail.len() as u64))?;
        let mut buf = vec![0; tail.len()];
        f.read_exact(&mut buf)?;
        Ok(buf == tail)
    };
    read().unwrap_or(false)
}

/// FNV-1a, 64 bits: a fixed, dependency-free hash for stamps and the verify choice.
pub(super) struct Fnv1a(pub(super) u64);

impl Fnv1a {
    pub(super) fn new() -> Fnv1a {
        Fnv1a(0xcbf2_9ce4_8422_2325)
    }
    pub(super) fn bytes(&mut self, bytes: &[u8]) -> &mut Fnv1a {
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }
    fn f64s(&mut self, xs: &[f64]) -> &mut Fnv1a {
        xs.iter().for_each(|x| {
            self.bytes(&x.to_bits().to_le_bytes());
        });
        self
    }
}

/// A hash of everything in `scene` that reaches the output files (every field of the
/// validated camera and cylinders, exact bits; the AOV list is in the stamp itself).
fn scene_hash(scene: &Scene) -> u64 {
    let mut h = Fnv1a::new();
    let c = &scene.camera;
    h.f64s(&c.origin.to_array())
        .f64s(&c.target.to_array())
        .f64s(&c.up.to_array())
        .f64s(&[c.fov_deg, c.near_clip, c.far_clip])
        .bytes(c.fov_axis.name().as_bytes())
        .bytes(&c.width.to_le_bytes())
        .bytes(&c.height.to_le_bytes());
    // Another model and its parameters (nothing for the pinhole, whose hash is unchanged).
    if !matches!(c.projection, Projection::Perspective) {
        h.bytes(c.projection.model().name().as_bytes());
        for (name, v) in c.projection.named_params() {
            h.bytes(name.as_bytes())
                .f64s(&[v.as_f64().unwrap_or(f64::NAN)]);
        }
    }
    for y in &scene.cylinders {
        h.f64s(&y.base.to_array())
            .f64s(&y.axis.to_array())
            .f64s(&[y.height, y.radius])
            .bytes(&[y.caps as u8])
            .bytes(&y.id.to_le_bytes());
        // Only when set, so the stamps of scenes without labels keep their value.
        if y.label != 0 {
            h.bytes(b"label").bytes(&y.label.to_le_bytes());
        }
    }
    h.0
}

/// What made a view's files: `NAME.render.json`.
#[derive(Serialize)]
struct RenderStamp {
    /// The cylaov that rendered the view: a new release may change output bits, so its
    /// views render again on resume.
    cylaov: &'static str,
    /// [`scene_hash`], hex.
    scene_fnv1a64: String,
    /// AOVs in the EXR.
    aovs: Vec<&'static str>,
    precision: String,
    formula: String,
    compression: String,
    /// `layers` or `per-aov`; only when not `layers` (older stamps stay valid).
    #[serde(skip_serializing_if = "Option::is_none")]
    exr_layout: Option<String>,
    png: bool,
    /// PNG depth value per world unit; only with PNGs (otherwise it changes nothing).
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_scale: Option<f64>,
    /// What the depth PNG does with depths beyond 16 bits; only with PNGs.
    #[serde(skip_serializing_if = "Option::is_none")]
    depth_out_of_range: Option<String>,
    /// Whether the view has its PLY; only when it has (older stamps stay valid).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    ply: bool,
}

/// The `NAME.render.json` this run writes for `scene`: the scene's hash and every option
/// that changes the view's output bytes. Resume compares it byte for byte, so a view made
/// with other options (or from another scene under the same name) is rendered again.
pub fn render_stamp(scene: &Scene, opts: &BatchOptions) -> String {
    fn name(v: impl crate::choice::Choice) -> String {
        v.choice_name().to_string()
    }
    let stamp = RenderStamp {
        cylaov: env!("CARGO_PKG_VERSION"),
        scene_fnv1a64: format!("{:016x}", scene_hash(scene)),
        aovs: opts.exr_aovs(scene).iter().map(|a| a.name()).collect(),
        precision: name(opts.precision),
        formula: name(opts.formula),
        compression: name(opts.compression),
        exr_layout: (opts.exr_layout != ExrLayout::Layers).then(|| name(opts.exr_layout)),
        png: opts.png,
        depth_scale: opts.png.then_some(opts.depth_scale),
        depth_out_of_range: opts.png.then(|| name(opts.depth_out_of_range)),
        ply: opts.ply,
    };
    let mut s = crate::output::format::camera_files::record_json(&stamp);
    s.push('\n');
    s
}

/// The plan of one view of a batch: the EXR (or EXRs), camera and Open3D JSON, the render
/// stamp and, with PNGs, the normal picture, the depth PNG and the mask.
pub fn view_plan(scene: &Scene, opts: &BatchOptions) -> ViewPlan {
    ViewPlan {
        camera: Camera::new(scene.camera),
        exr_aovs: opts.exr_aovs(scene),
        layout: opts.exr_layout,
        compression: opts.compression,
        depth_png: opts.png.then_some(DepthPngPlan {
            scale: opts.depth_scale,
            out_of_range: opts.depth_out_of_range,
        }),
        mask: opts.png,
        normal_picture: opts.png,
        previews: false,
        stamp: Some(render_stamp(scene, opts)),
        ply: opts.ply,
    }
}

/// Bytes rendering and writing a view holds at its peak (see
/// [`crate::output::pipeline::memory::render_memory`]).
pub fn view_memory(scene: &Scene, opts: &BatchOptions) -> u64 {
    view_plan(scene, opts).memory()
}

/// [`view_memory`] of a view of `size` whose EXR holds `aovs`, known before its scene is
/// read again: the AOVs its plan traces are those, plus depth and normal for the
/// pictures and what a PLY reads.
pub fn view_memory_at(size: (u32, u32), aovs: &[Aov], opts: &BatchOptions) -> u64 {
    // The pictures of `view_plan`: with PNGs the depth PNG, mask and normal picture.
    let traced = crate::output::pipeline::view::traced_aovs(aovs, opts.png, opts.png, opts.ply);
    crate::output::pipeline::memory::render_memory(
        size,
        &traced,
        opts.exr_layout,
        opts.compression,
        // As `ViewPlan::pictures`: a PLY reads the whole image too.
        opts.png || opts.ply,
    )
}

/// Whether view `name` of `scene` is already complete in `dir`.
pub fn view_is_complete(dir: &Path, name: &str, scene: &Scene, opts: &BatchOptions) -> bool {
    let files = ViewFiles::new(dir, name);
    const PNG_END: &[u8] = b"\0\0\0\0IEND\xae\x42\x60\x82";
    // The camera file and the stamp must be the ones this run would write: a changed scene
    // (e.g. regenerated under the same names), AOV list or output option renders the view
    // again.
    let plan = view_plan(scene, opts);
    let same = |path: &Path, member: Member| {
        read_regular(path).is_ok_and(|b| plan.member_bytes(member).is_some_and(|want| b == want))
    };
    let others = same(&files.camera, Member::Camera)
        // Only a pinhole view has an Open3D camera file.
        && (!scene.camera.projection.is_pinhole() || same(&files.open3d, Member::Open3d))
        && same(&files.stamp, Member::Stamp)
        && (!opts.png
            || [&files.normal_png, &files.depth_png, &files.mask_png]
                .iter()
                .all(|p| file_ends_with(p, PNG_END)))
        // Committed before the EXR, so whole when the EXR is.
        && (!opts.ply || files.ply.is_file());
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    others
        && match opts.exr_layout {
            ExrLayout::Layers => exr_is_complete(
                &files.exr,
                w,
                h,
                &expected_channels(&opts.exr_aovs(scene)),
                opts.compression,
            )
            .is_ok(),
            ExrLayout::PerAov => opts.exr_aovs(scene).iter().all(|&a| {
                exr_is_complete(
                    &files.per_aov(a),
                    w,
                    h,
                    &per_aov_channels(a),
                    opts.compression,
                )
                .is_ok()
            }),
        }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name a view's clean-up removes is one of cylaov's own (`dataset::names`), or
    /// the normal picture's name before 0.2 that its module docs give.
    #[test]
    fn view_file_names_are_cylaov_names() {
        let patterns: Vec<&str> = crate::dataset::names::OUTPUT_NAMES
            .iter()
            .map(|n| n.pattern)
            .collect();
        for name in view_file_names("NAME") {
            let listed = patterns.contains(&name.as_str())
                || Aov::ALL
                    .iter()
                    .any(|a| name == format!("NAME.{}.exr", a.name()))
                    && patterns.contains(&"NAME.AOV.exr");
            assert!(listed || name == "NAME.normal.png", "{name}");
        }
        assert_eq!(
            view_file_names("a").len(),
            VIEW_SUFFIXES.len() + Aov::ALL.len()
        );
    }

    /// The estimate from a view's size and AOVs (before its scene is read again) is the
    /// plan's, for every option that changes what the view holds.
    #[test]
    fn view_memory_at_is_the_plans_estimate() {
        use crate::output::format::exr::Compression;
        let scene = crate::bench::random_scene(3, 5, 640, 480);
        let aovs: Vec<Aov> = [Aov::Depth, Aov::ShapeId, Aov::Uv].to_vec();
        for png in [false, true] {
            for ply in [false, true] {
                for layout in [ExrLayout::Layers, ExrLayout::PerAov] {
                    for compression in [Compression::None, Compression::Zip] {
                        let opts = BatchOptions {
                            aovs: Some(aovs.clone()),
                            png,
                            ply,
                            exr_layout: layout,
                            compression,
                            ..BatchOptions::default()
                        };
                        assert_eq!(
                            view_memory_at((640, 480), &aovs, &opts),
                            view_memory(&scene, &opts),
                            "png {png} ply {ply} {layout:?} {compression:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn stamp_names_the_version_and_options() {
        let scene = crate::bench::random_scene(3, 1, 8, 8);
        let stamp = render_stamp(&scene, &BatchOptions::default());
        let v: serde_json::Value = serde_json::from_str(&stamp).unwrap();
        assert_eq!(v["cylaov"], env!("CARGO_PKG_VERSION"));
        assert_eq!(v["precision"], "f64");
        let mut other = scene.clone();
        other.cylinders[1].radius *= 1.0 + f64::EPSILON;
        assert_ne!(render_stamp(&other, &BatchOptions::default()), stamp);
    }
}
