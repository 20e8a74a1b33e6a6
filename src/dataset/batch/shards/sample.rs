//! One view as the members of its tar sample (see the parent module for the layout): its
//! [`ViewPlan`] executed into a [`TarSink`], the arrays taken from the traced image, and
//! what a view holds and takes in a tar, known from its size before it renders.

use super::Member;
use crate::dataset::batch::options::BatchOptions;
use crate::dataset::batch::views::ViewSource;
use crate::image::{AovImage, ChannelData};
use crate::npy;
use crate::output::format::camera_files::record_json;
use crate::output::format::exr::{ExrLayout, channel_names};
use crate::output::format::tar;
use crate::output::pipeline::view::{DepthPngPlan, Fill, Member as ViewMember, ViewPlan, ViewSink};
use crate::render::RenderOptions;
use crate::scene::camera::Camera;
use crate::scene::{Aov, Scene};
use anyhow::{Context, Result, anyhow, bail};
use serde::Serialize;
use std::path::Path;

/// The arrays of a view besides the mask, in member order: depth, normal, then the other
/// AOVs of `aovs` in `Aov::ALL` order.
pub(super) fn array_aovs(aovs: &[Aov]) -> Vec<Aov> {
    let mut v = vec![Aov::Depth, Aov::Normal];
    v.extend(
        Aov::ALL
            .iter()
            .filter(|a| aovs.contains(a) && !matches!(a, Aov::Depth | Aov::Normal)),
    );
    v
}

/// The array of `aov` as a `.npy` member: its header, then its buffer as the render left
/// it, taken out of `image` (no copy where the machine's byte order is the file's).
pub(super) fn aov_npy(image: &mut AovImage, aov: Aov) -> Result<MemberBytes> {
    let shape = aov_shape(aov, image.width, image.height);
    let buffer = image
        .take_aov_buffer(aov)
        .ok_or_else(|| anyhow!("no {} AOV", aov.name()))?;
    let dtype = match &buffer.data {
        ChannelData::F32(_) => npy::Dtype::F32,
        ChannelData::U32(_) => npy::Dtype::U32,
    };
    Ok(if cfg!(target_endian = "little") {
        MemberBytes::Array {
            header: npy::header(dtype, &shape),
            data: buffer.data,
        }
    } else {
        MemberBytes::Whole(match &buffer.data {
            ChannelData::F32(v) => npy::array(dtype, &shape, v),
            ChannelData::U32(v) => npy::array(dtype, &shape, v),
        })
    })
}

/// The shape of `aov`'s array at `w`×`h`.
pub(super) fn aov_shape(aov: Aov, w: usize, h: usize) -> Vec<usize> {
    match channel_names(aov).len() {
        1 => vec![h, w],
        c => vec![h, w, c],
    }
}

/// What `KEY.json` adds to the camera JSON.
#[derive(Serialize)]
pub(super) struct SampleMeta<'a> {
    key: &'a str,
    scene: &'a str,
    scene_file: String,
    camera_index: usize,
    depth_kind: String,
    units: &'static str,
    miss_values: serde_json::Map<String, serde_json::Value>,
    arrays: serde_json::Map<String, serde_json::Value>,
    cylaov_version: &'static str,
}

/// A view's tar members: a [`ViewSink`] of the view's [`ViewPlan`]. The arrays come from
/// the traced image ([`ViewSink::image`]); `KEY.json` from the plan's camera member and the
/// sample's fields; `KEY.exr`, `KEY.depth.png` and `KEY.ply` are the plan's own members when asked
/// for (the others are never encoded). Committed in tar order (see the module docs).
pub(super) struct TarSink<'a> {
    key: &'a str,
    arrays: &'a [Aov],
    extra: serde_json::Value,
    keep: &'a [Member],
    /// Encode the plan's EXR even when it is not a member: the verifier reads it.
    exr_for_check: bool,
    npys: Members,
    camera: Option<Vec<u8>>,
    exr: Option<Vec<u8>>,
    depth_png: Option<Vec<u8>>,
    ply: Option<Vec<u8>>,
    members: Members,
}

impl TarSink<'_> {
    fn fill(member: ViewMember, fill: Fill) -> Result<Vec<u8>> {
        let mut buf = std::io::Cursor::new(Vec::new());
        fill(&mut buf).with_context(|| format!("encoding {}", member.suffix()))?;
        Ok(buf.into_inner())
    }
}

impl ViewSink for TarSink<'_> {
    fn add(&mut self, member: ViewMember, fill: Fill) -> Result<()> {
        match member {
            ViewMember::Camera => self.camera = Some(Self::fill(member, fill)?),
            ViewMember::Exr if self.exr_for_check || self.keep.contains(&Member::Exr) => {
                self.exr = Some(Self::fill(member, fill)?)
            }
            ViewMember::DepthPng if self.keep.contains(&Member::DepthPng) => {
                self.depth_png = Some(Self::fill(member, fill)?)
            }
            ViewMember::Ply => self.ply = Some(Self::fill(member, fill)?),
            _ => {}
        }
        Ok(())
    }

    fn image(&mut self, mut image: AovImage) -> Result<()> {
        let (h, w) = (image.height, image.width);
        let Some(ChannelData::F32(depth)) = image.aov_buffer(Aov::Depth).map(|b| &b.data) else {
            bail!("no depth AOV");
        };
        let mask = npy::bool_plane(h, w, depth.iter().map(|&z| z > 0.0));
        for &a in self.arrays {
            self.npys.push((
                format!("{}.{}.npy", self.key, a.name()),
                aov_npy(&mut image, a)?,
            ));
        }
        self.npys
            .push((format!("{}.mask.npy", self.key), MemberBytes::Whole(mask)));
        Ok(())
    }

    fn label(&self, member: ViewMember) -> String {
        format!("{}.{}", self.key, member.suffix())
    }

    fn commit(&mut self) -> Result<()> {
        let camera = self.camera.take().context("the plan gave no camera JSON")?;
        let mut meta: serde_json::Value = serde_json::from_slice(&camera)?;
        if let (Some(m), serde_json::Value::Object(e)) = (meta.as_object_mut(), self.extra.take()) {
            m.extend(e);
        }
        let mut json = record_json(&meta);
        json.push('\n');
        self.members = std::mem::take(&mut self.npys);
        self.members.push((
            format!("{}.json", self.key),
            MemberBytes::Whole(json.into_bytes()),
        ));
        if self.keep.contains(&Member::Exr) {
            // Kept for the check too when it asked for it.
            let exr = if self.exr_for_check {
                self.exr.clone()
            } else {
                self.exr.take()
            };
            if let Some(exr) = exr {
                self.members
                    .push((format!("{}.exr", self.key), MemberBytes::Whole(exr)));
            }
        }
        if let Some(png) = self.depth_png.take() {
            self.members
                .push((format!("{}.depth.png", self.key), MemberBytes::Whole(png)));
        }
        if let Some(ply) = self.ply.take() {
            self.members
                .push((format!("{}.ply", self.key), MemberBytes::Whole(ply)));
        }
        Ok(())
    }
}

/// The AOVs of a shard's view plan: the dataset's, plus depth and normal (always arrays).
pub(super) fn plan_aovs(aovs: &[Aov]) -> Vec<Aov> {
    let mut v = aovs.to_vec();
    for a in [Aov::Depth, Aov::Normal] {
        if !v.contains(&a) {
            v.push(a);
        }
    }
    v
}

/// The suffixes of a view's member names after its key, as [`view_members`] appends them.
pub(super) fn member_suffixes(aovs: &[Aov], members: &[Member]) -> Vec<String> {
    let mut v: Vec<String> = array_aovs(aovs)
        .iter()
        .map(|a| format!(".{}.npy", a.name()))
        .collect();
    v.extend([".mask.npy".to_string(), ".json".to_string()]);
    v.extend(members.iter().map(|m| format!(".{}", m.name())));
    v
}

/// A view's tar members, `(name, bytes)` in the order they are appended.
pub type Members = Vec<(String, MemberBytes)>;

/// A tar member's bytes: whole, or an array's `.npy` header and its samples, kept as the
/// render left them so that appending them copies nothing.
pub enum MemberBytes {
    /// The member's bytes.
    Whole(Vec<u8>),
    /// A `.npy` header, then `data`'s samples in the machine's byte order (little-endian,
    /// as the header says: built only there).
    Array {
        /// The `.npy` header, padded as the format asks.
        header: Vec<u8>,
        /// The samples.
        data: ChannelData,
    },
}

impl MemberBytes {
    /// The member's bytes, in two pieces (the second empty for a whole member).
    pub fn pieces(&self) -> [&[u8]; 2] {
        match self {
            MemberBytes::Whole(v) => [v, &[]],
            MemberBytes::Array { header, data } => [
                header,
                match data {
                    ChannelData::F32(v) => bytemuck::cast_slice(v),
                    ChannelData::U32(v) => bytemuck::cast_slice(v),
                },
            ],
        }
    }
}

/// The members of one view, in tar order (see the module docs): the view's plan executed
/// into a tar sink.
pub fn view_members(
    key: &str,
    view: &ViewSource,
    scene: &Scene,
    input_dir: &Path,
    aovs: &[Aov],
    opts: &BatchOptions,
    members: &[Member],
) -> Result<Members> {
    view_members_and_exr(key, view, scene, input_dir, aovs, opts, members, false).map(|m| m.0)
}

/// [`view_members`], and with `exr` the view's EXR bytes (the plan's, as `KEY.exr` would
/// hold them) for its check. The view's memory estimate is checked before it renders.
#[allow(clippy::too_many_arguments)]
pub(super) fn view_members_and_exr(
    key: &str,
    view: &ViewSource,
    scene: &Scene,
    input_dir: &Path,
    aovs: &[Aov],
    opts: &BatchOptions,
    members: &[Member],
    exr: bool,
) -> Result<(Members, Option<Vec<u8>>)> {
    let arrays = array_aovs(aovs);
    let plan = ViewPlan {
        camera: Camera::new(scene.camera),
        exr_aovs: plan_aovs(aovs),
        layout: ExrLayout::Layers,
        compression: opts.compression,
        depth_png: members.contains(&Member::DepthPng).then_some(DepthPngPlan {
            scale: opts.depth_scale,
            out_of_range: opts.depth_out_of_range,
        }),
        mask: false,
        normal_picture: false,
        previews: false,
        stamp: None,
        ply: members.contains(&Member::Ply),
    };
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let mut miss = serde_json::Map::new();
    let mut shapes = serde_json::Map::new();
    for &a in &arrays {
        let m = a.spec().miss;
        let v = serde_json::from_str(m).unwrap_or_else(|_| serde_json::Value::from(m));
        miss.insert(a.name().into(), v);
        let dtype = if a.is_u32() { "uint32" } else { "float32" };
        shapes.insert(
            a.name().into(),
            serde_json::json!({"shape": aov_shape(a, w, h), "dtype": dtype}),
        );
    }
    miss.insert("mask".into(), false.into());
    shapes.insert(
        "mask".into(),
        serde_json::json!({"shape": [h, w], "dtype": "bool"}),
    );
    let extra = serde_json::to_value(SampleMeta {
        key,
        scene: &view.scene,
        scene_file: view
            .path
            .strip_prefix(input_dir)
            .unwrap_or(&view.path)
            .display()
            .to_string(),
        camera_index: view.camera,
        depth_kind: format!(
            "{}: {}",
            scene.camera.projection.depth_kind(),
            scene.camera.projection.depth_meaning()
        ),
        units: "world units of the scene file",
        miss_values: miss,
        arrays: shapes,
        cylaov_version: env!("CARGO_PKG_VERSION"),
    })?;
    let mut sink = TarSink {
        key,
        arrays: &arrays,
        extra,
        keep: members,
        exr_for_check: exr,
        npys: Vec::new(),
        camera: None,
        exr: None,
        depth_png: None,
        ply: None,
        members: Vec::new(),
    };
    let render_opts = RenderOptions {
        precision: opts.precision,
        formula: opts.formula,
        ..RenderOptions::new(plan.traced_aovs())
    };
    debug_assert_eq!(plan.traced_aovs(), tar_traced_aovs(aovs, members));
    // As the files format does: a view that does not fit fails alone, before it allocates.
    crate::mem::check_memory(
        &format!("rendering {}", view.id()),
        tar_view_memory(
            (plan.camera.width(), plan.camera.height()),
            aovs,
            opts,
            members,
            exr,
        ),
    )?;
    plan.execute(scene, &render_opts, &mut sink)?;
    Ok((sink.members, sink.exr.filter(|_| exr)))
}

/// The AOVs a tar view traces: the dataset's, depth and normal (always arrays), and what
/// a PLY member reads. The plan of [`view_members_and_exr`] traces exactly these (checked
/// there), so the memory of a view is known from its size before its scene is loaded.
pub(super) fn tar_traced_aovs(aovs: &[Aov], members: &[Member]) -> Vec<Aov> {
    crate::output::pipeline::view::traced_aovs(
        &plan_aovs(aovs),
        false,
        false,
        members.contains(&Member::Ply),
    )
}

/// Bytes one view of `w`×`h` in a tar holds at its peak: the whole traced image (a tar's
/// view is never streamed band by band) with what the plan encodes from it (see
/// `crate::output::pipeline::memory::render_memory`), and its encoded members, the EXR counted when it is
/// encoded for the check alone.
pub(super) fn tar_view_memory(
    (w, h): (u32, u32),
    aovs: &[Aov],
    opts: &BatchOptions,
    members: &[Member],
    exr: bool,
) -> u64 {
    let traced = crate::output::pipeline::memory::render_memory(
        (w, h),
        &tar_traced_aovs(aovs, members),
        ExrLayout::Layers,
        opts.compression,
        true,
    );
    let mut encoded: Vec<Member> = members.to_vec();
    if exr && !encoded.contains(&Member::Exr) {
        encoded.push(Member::Exr);
    }
    traced + view_tar_bytes(w as usize, h as usize, aovs, &encoded)
}

/// Bytes a tar of views of `w`×`h` with `aovs` and `members` takes per view, the JSON
/// counted at 4 KiB and optional members at their raw size.
pub fn view_tar_bytes(w: usize, h: usize, aovs: &[Aov], members: &[Member]) -> u64 {
    let mut sizes: Vec<u64> = array_aovs(aovs)
        .iter()
        .map(|&a| {
            let dt = if a.is_u32() {
                npy::Dtype::U32
            } else {
                npy::Dtype::F32
            };
            npy::file_size(dt, &aov_shape(a, w, h)) as u64
        })
        .collect();
    sizes.push(npy::file_size(npy::Dtype::Bool, &[h, w]) as u64);
    sizes.push(4096);
    for m in members {
        let channels: usize = aovs.iter().map(|&a| channel_names(a).len()).sum();
        sizes.push(match m {
            Member::Exr => (w * h * 4 * channels + h * 16 + 2048) as u64,
            Member::DepthPng => (w * h * 2) as u64,
            // At most one 36-byte vertex a pixel, and the header.
            Member::Ply => (w * h * 36 + 1024) as u64,
        });
    }
    tar::archive_size(sizes) - 2 * tar::BLOCK as u64
}
