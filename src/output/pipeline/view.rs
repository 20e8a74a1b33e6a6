//! One view writer: a view's outputs as a [`ViewPlan`] (which files, which EXR layout,
//! which pictures, which metadata), executed into a [`ViewSink`] that stages every member
//! and then commits them all, so an error at any point leaves nothing half-written.
//!
//! `cylaov render` and `batch` both build a plan and run [`ViewPlan::execute`]; they differ
//! only in their [`FileSink`]: the names (`OUT.*` beside `-o`, or `NAME.*` in a dataset
//! folder), where members wait (beside their targets, or in a shard's partial folder) and
//! which older files a commit removes first.
//!
//! How another container plugs in:
//! - **A tar shard** implements [`ViewSink`] over memory, like [`MemorySink`]: each
//!   [`ViewSink::add`] fills an in-memory buffer (seekable: the EXR encoder needs it),
//!   named by [`Member::suffix`] after the view's name; [`ViewSink::commit`] appends the
//!   buffered `(name, bytes)` pairs to the tar, EXRs last, or nothing on an error. A sink
//!   without files leaves [`ViewSink::stream_file`] at its default (`None`), so the view is
//!   traced whole and then encoded; [`ViewSink::image`] hands it the traced image for
//!   arrays, and a member it does not keep is one whose `fill` it never calls (nothing is
//!   encoded). `crate::dataset::batch::shards` is that sink.
//! - **The Python package** wants arrays, not files: it takes the AOVs to trace from
//!   [`ViewPlan::traced_aovs`] and the camera record from [`ViewPlan::member_bytes`] (or
//!   `camera_json`) and hands out the traced image itself; it needs no sink.

use crate::image::AovImage;
use crate::output::format::camera_files::{camera_json, open3d_json};
use crate::output::format::depth_png::{self, OutOfRange};
use crate::output::format::exr::{
    Compression, ExrBands, ExrLayout, channel_names, exr_attributes, per_aov_image,
};
use crate::output::format::preview;
use crate::output::pipeline::memory::{render_memory, streams};
use crate::output::store::atomic::{Staged, commit_replacing, explain, stage, stage_in};
use crate::render::{RenderOptions, render, render_bands};
use crate::scene::camera::Camera;
use crate::scene::{Aov, Scene};
use anyhow::{Context, Result};
use std::fs::File;
use std::io::{self, Cursor, Seek, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// One file of a view.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Member {
    /// The layered EXR (every AOV as named channels).
    Exr,
    /// One AOV's EXR of the per-AOV layout.
    AovExr(Aov),
    /// Camera metadata JSON.
    Camera,
    /// Open3D's `PinholeCameraParameters`.
    Open3d,
    /// 16-bit planar depth × scale.
    DepthPng,
    /// 8-bit hit mask.
    MaskPng,
    /// The 8-bit normal picture of a dataset (no key).
    NormalPicture,
    /// The normal preview for people (with its key).
    NormalPreview,
    /// The depth (or distance) colour map with its legend: the AOV it shows.
    DepthPreview(Aov),
    /// What made the files (a batch's render stamp).
    Stamp,
    /// The hit points as a PLY point cloud ([`crate::output::format::ply`]).
    Ply,
}

impl Member {
    /// What follows `NAME.` in the member's file name.
    pub fn suffix(self) -> String {
        match self {
            Member::Exr => "exr".into(),
            Member::AovExr(a) => format!("{}.exr", a.name()),
            Member::Camera => "camera.json".into(),
            Member::Open3d => "open3d.json".into(),
            Member::DepthPng => "depth.png".into(),
            Member::MaskPng => "mask.png".into(),
            Member::NormalPicture | Member::NormalPreview => "normal.preview.png".into(),
            Member::DepthPreview(a) => format!("{}.preview.png", a.name()),
            Member::Stamp => "render.json".into(),
            Member::Ply => "ply".into(),
        }
    }

    /// EXRs are a view's "done" marker: they are committed last.
    pub fn is_exr(self) -> bool {
        matches!(self, Member::Exr | Member::AovExr(_))
    }
}

/// The 16-bit depth PNG of a plan.
#[derive(Clone, Copy, Debug)]
pub struct DepthPngPlan {
    /// Depth values per world unit.
    pub scale: f64,
    /// What a hit whose depth × scale does not fit 16 bits does.
    pub out_of_range: OutOfRange,
}

/// What one view writes. Members follow from the fields (see [`ViewPlan::members`]).
#[derive(Clone, Debug)]
pub struct ViewPlan {
    /// The view's camera.
    pub camera: Camera,
    /// The AOVs the EXR (or EXRs) store, in order.
    pub exr_aovs: Vec<Aov>,
    /// One layered EXR or one per AOV.
    pub layout: ExrLayout,
    /// EXR compression.
    pub compression: Compression,
    /// The 16-bit depth PNG, if any.
    pub depth_png: Option<DepthPngPlan>,
    /// The hit mask PNG.
    pub mask: bool,
    /// The dataset normal picture.
    pub normal_picture: bool,
    /// The previews for people (normal with key, depth or distance with legend).
    pub previews: bool,
    /// Extra metadata written as it is (a batch's render stamp).
    pub stamp: Option<String>,
    /// The hit points as a PLY point cloud (traced with the point cloud's AOVs, whatever
    /// the EXR stores).
    pub ply: bool,
}

/// A depth PNG that cannot hold the view's depths ([`OutOfRange::Fail`]): the message
/// names the depth range and the largest scale that fits.
#[derive(Debug)]
pub struct DepthOutOfRange(pub String);

impl std::fmt::Display for DepthOutOfRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for DepthOutOfRange {}

/// What executing a plan cost and found.
#[derive(Clone, Copy, Debug, Default)]
pub struct Written {
    /// Pixels that hit a cylinder.
    pub hits: usize,
    /// BVH build and tracing; streamed, the EXR too.
    pub trace: Duration,
    /// Encoding, staging and committing the members (streamed: all but the EXR).
    pub write: Duration,
    /// Hit pixels stored as 0 in the depth PNG ([`OutOfRange::Zero`]).
    pub depth_zeroed: usize,
    /// Whether the EXR was written band by band during the trace.
    pub streamed: bool,
}

/// A seekable byte sink (a file or a `Cursor<Vec<u8>>`): the EXR encoder seeks back to
/// write its offset table.
pub trait WriteSeek: Write + Seek {}
impl<T: Write + Seek> WriteSeek for T {}

/// The fill of one member: writes its bytes.
pub type Fill<'a> = &'a mut dyn FnMut(&mut dyn WriteSeek) -> io::Result<()>;

/// Where a plan's members go: staged one by one, then committed together.
pub trait ViewSink {
    /// Stage `member`, its bytes written by `fill` (called once).
    fn add(&mut self, member: Member, fill: Fill) -> Result<()>;
    /// A file staged for `member` that the EXR is written into in place while the view is
    /// traced ([`ExrBands`], positional writes); `None` (the default) has the view traced
    /// whole and encoded through [`ViewSink::add`].
    fn stream_file(&mut self, member: Member) -> Result<Option<&File>> {
        let _ = member;
        Ok(None)
    }
    /// How errors name `member` (its path, for files).
    fn label(&self, member: Member) -> String {
        member.suffix()
    }
    /// The traced image, once every member is staged from it, holding the EXR's channels
    /// (never called when the EXR streams): a sink that stores arrays rather than files (a
    /// tar shard's `.npy` members) takes their buffers here, without a copy. The default
    /// takes nothing.
    fn image(&mut self, image: AovImage) -> Result<()> {
        let _ = image;
        Ok(())
    }
    /// Put every staged member in place, EXRs last; on an error none stays.
    fn commit(&mut self) -> Result<()>;
}

/// The AOVs a view is traced with: its EXR's `exr_aovs`, then depth when `depth` (a depth
/// PNG or mask reads it), normal when `normal` (the normal picture) and what a PLY reads
/// when `ply`, each added once, in that order. Also what a view's memory is estimated from
/// before its plan exists.
pub fn traced_aovs(exr_aovs: &[Aov], depth: bool, normal: bool, ply: bool) -> Vec<Aov> {
    let mut aovs = exr_aovs.to_vec();
    let mut need = |a: Aov| {
        if !aovs.contains(&a) {
            aovs.push(a);
        }
    };
    if depth {
        need(Aov::Depth);
    }
    if normal {
        need(Aov::Normal);
    }
    if ply {
        crate::output::format::ply::PLY_AOVS
            .into_iter()
            .for_each(need);
    }
    aovs
}

impl ViewPlan {
    /// The AOVs the view is traced with: the EXR's, plus depth for the depth PNG, mask and
    /// previews' needs, and normal for the normal picture.
    pub fn traced_aovs(&self) -> Vec<Aov> {
        traced_aovs(
            &self.exr_aovs,
            self.depth_png.is_some() || self.mask,
            self.normal_picture,
            self.ply,
        )
    }

    /// Whether any PNG is written (then the whole image is needed).
    pub fn pictures(&self) -> bool {
        self.depth_png.is_some() || self.mask || self.normal_picture || self.previews || self.ply
    }

    /// Whether the EXR is written band by band while the view is traced (see [`streams`]).
    pub fn streams(&self) -> bool {
        streams(self.layout, self.compression, self.pictures())
    }

    /// Bytes rendering and writing the view holds at its peak (see [`render_memory`]).
    pub fn memory(&self) -> u64 {
        render_memory(
            (self.camera.width(), self.camera.height()),
            &self.traced_aovs(),
            self.layout,
            self.compression,
            self.pictures(),
        )
    }

    /// Every member the plan may write (both preview kinds when previews are on: which one
    /// appears depends on the AOVs), named before any work so each target can be checked.
    pub fn members(&self) -> Vec<Member> {
        let mut m: Vec<Member> = match self.layout {
            ExrLayout::Layers => vec![Member::Exr],
            ExrLayout::PerAov => self.exr_aovs.iter().map(|&a| Member::AovExr(a)).collect(),
        };
        m.push(Member::Camera);
        // Open3D's camera file is a pinhole's: no other model has one.
        if self.camera.is_pinhole() {
            m.push(Member::Open3d);
        }
        if self.stamp.is_some() {
            m.push(Member::Stamp);
        }
        if self.depth_png.is_some() {
            m.push(Member::DepthPng);
        }
        if self.mask {
            m.push(Member::MaskPng);
        }
        if self.normal_picture {
            m.push(Member::NormalPicture);
        }
        if self.ply {
            m.push(Member::Ply);
        }
        if self.previews {
            m.extend([
                Member::NormalPreview,
                Member::DepthPreview(Aov::Depth),
                Member::DepthPreview(Aov::Distance),
            ]);
        }
        m
    }

    /// The bytes of a metadata member (camera JSON, Open3D JSON, stamp), which need no
    /// image.
    pub fn member_bytes(&self, member: Member) -> Option<Vec<u8>> {
        match member {
            Member::Camera => Some(camera_json(&self.camera, &self.exr_aovs).into_bytes()),
            Member::Open3d => self
                .camera
                .is_pinhole()
                .then(|| open3d_json(&self.camera).into_bytes()),
            Member::Stamp => self.stamp.as_ref().map(|s| s.clone().into_bytes()),
            _ => None,
        }
    }

    /// Trace `scene` with `opts` (its AOVs replaced by [`ViewPlan::traced_aovs`]), stage
    /// every member into `sink` and commit them. A depth PNG that cannot hold the view's
    /// depths fails before anything is staged.
    pub fn execute(
        &self,
        scene: &Scene,
        opts: &RenderOptions,
        sink: &mut dyn ViewSink,
    ) -> Result<Written> {
        let opts = RenderOptions {
            aovs: self.traced_aovs(),
            ..opts.clone()
        };
        let t0 = Instant::now();
        if self.streams()
            && let Some(file) = sink.stream_file(Member::Exr)?
        {
            let attrs = exr_attributes(&self.camera, &self.exr_aovs);
            let exr = ExrBands::new(file, self.camera.height() as usize, &attrs);
            let hits = render_bands(scene, &opts, &|y0, band| exr.write_band(y0, band))
                .and_then(|(hits, _)| exr.finish().map(|()| hits))
                .map_err(explain)
                .with_context(|| format!("writing {}", sink.label(Member::Exr)))?;
            let trace = t0.elapsed();
            let t1 = Instant::now();
            self.add_metadata(sink)?;
            sink.commit()?;
            return Ok(Written {
                hits,
                trace,
                write: t1.elapsed(),
                depth_zeroed: 0,
                streamed: true,
            });
        }
        let r = render(scene, &opts);
        let trace = t0.elapsed();
        let t1 = Instant::now();
        let depth_zeroed = self.add_image_members(r.image, sink)?;
        sink.commit()?;
        Ok(Written {
            hits: r.hits,
            trace,
            write: t1.elapsed(),
            depth_zeroed,
            streamed: false,
        })
    }

    /// Camera JSON, Open3D JSON and the stamp.
    fn add_metadata(&self, sink: &mut dyn ViewSink) -> Result<()> {
        for m in [Member::Camera, Member::Open3d, Member::Stamp] {
            if let Some(bytes) = self.member_bytes(m) {
                sink.add(m, &mut |w| w.write_all(&bytes))?;
            }
        }
        Ok(())
    }

    /// Every member of a whole traced image, then the image itself (the EXR's channels) to
    /// the sink; returns the depth PNG's zeroed pixels.
    fn add_image_members(&self, mut image: AovImage, sink: &mut dyn ViewSink) -> Result<usize> {
        // The depth PNG first: a view whose depths do not fit fails before any write.
        let depth = match self.depth_png {
            Some(d) => Some(
                depth_png::encode(&image, d.scale, d.out_of_range)
                    .context("no depth AOV")?
                    .map_err(DepthOutOfRange)?,
            ),
            None => None,
        };
        let depth_zeroed = depth.as_ref().map_or(0, |d| d.zeroed);
        // The dataset pictures use AOVs the EXR may not store.
        let normal = match self.normal_picture {
            true => Some(preview::normal_rgb(&image).context("no normal AOV")?),
            false => None,
        };
        let mask = match self.mask {
            true => Some(depth_png::mask(&image).context("no depth AOV")?),
            false => None,
        };
        let ply = match self.ply {
            true => {
                let hits =
                    crate::output::format::ply::hits(&image).context("no point-cloud AOV")?;
                let comment = format!("cylaov {} hit points", env!("CARGO_PKG_VERSION"));
                Some(crate::output::format::ply::encode(&hits, &comment))
            }
            false => None,
        };
        let keep: Vec<&str> = self
            .exr_aovs
            .iter()
            .flat_map(|&a| channel_names(a).iter().copied())
            .collect();
        image.retain_channels(|c| keep.contains(&c));
        // Staged in the order of the streamed path: EXRs, metadata, pictures.
        match self.layout {
            ExrLayout::Layers => {
                let attrs = exr_attributes(&self.camera, &self.exr_aovs);
                add_exr(sink, Member::Exr, &image, self.compression, &attrs)?;
            }
            ExrLayout::PerAov => {
                for &a in &self.exr_aovs {
                    let one = per_aov_image(&image, a)?;
                    let attrs = exr_attributes(&self.camera, &[a]);
                    add_exr(sink, Member::AovExr(a), &one, self.compression, &attrs)?;
                }
            }
        }
        self.add_metadata(sink)?;
        if let Some(normal) = &normal {
            add_png(sink, Member::NormalPicture, normal)?;
        }
        if let Some(d) = &depth {
            add_png(sink, Member::DepthPng, &d.png)?;
        }
        if let Some(mask) = &mask {
            add_png(sink, Member::MaskPng, mask)?;
        }
        if let Some(ply) = &ply {
            sink.add(Member::Ply, &mut |w| w.write_all(ply))?;
        }
        // The previews show what the EXR stores.
        if self.previews {
            if let Some(p) = preview::normal_preview(&image) {
                add_png(sink, Member::NormalPreview, &p)?;
            }
            let shown = [Aov::Depth, Aov::Distance]
                .into_iter()
                .find(|a| image.f32_channel(a.name()).is_some());
            if let Some(a) = shown
                && let Some(p) = preview::depth_colormap(&image, a.name())
            {
                add_png(sink, Member::DepthPreview(a), &p)?;
            }
        }
        sink.image(image)?;
        Ok(depth_zeroed)
    }
}

fn add_exr(
    sink: &mut dyn ViewSink,
    member: Member,
    image: &AovImage,
    compression: Compression,
    attrs: &[crate::output::format::exr::ExrAttr],
) -> Result<()> {
    sink.add(member, &mut |w| {
        let mut out = io::BufWriter::with_capacity(1 << 20, w);
        image
            .write_exr_with(&mut out, compression, attrs)
            .map_err(|e| io::Error::other(format!("{e:#}")))?;
        out.flush()
    })
}

fn add_png<P, C>(
    sink: &mut dyn ViewSink,
    member: Member,
    img: &image::ImageBuffer<P, C>,
) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    sink.add(member, &mut |w| {
        let mut out = io::BufWriter::new(w);
        // The encoder's IO error as it is, so a full disk gets its advice.
        img.write_to(&mut out, image::ImageFormat::Png)
            .map_err(|e| match e {
                image::ImageError::IoError(e) => e,
                e => io::Error::other(e.to_string()),
            })?;
        out.flush()
    })
}

/// Where a [`FileSink`] stages its members.
enum Staging {
    /// Beside each target, under its hidden temporary name.
    Beside,
    /// In a work folder of cylaov's own, as `PREFIX.SUFFIX.*.tmp`.
    In { work: PathBuf, prefix: String },
}

/// A view's members as files: staged under temporary names, then renamed into place
/// together (see [`commit_replacing`]); dropped uncommitted, the staged files are removed.
pub struct FileSink {
    name: Box<dyn Fn(Member) -> PathBuf>,
    staging: Staging,
    staged: Vec<(Member, Staged)>,
    /// Files staged outside the view's members (`render --ply`'s point cloud), committed
    /// with them.
    extra: Vec<Staged>,
    stale: Vec<PathBuf>,
}

impl FileSink {
    /// Members named by `name`, staged beside their targets.
    pub fn beside(name: impl Fn(Member) -> PathBuf + 'static) -> FileSink {
        FileSink {
            name: Box::new(name),
            staging: Staging::Beside,
            staged: Vec::new(),
            extra: Vec::new(),
            stale: Vec::new(),
        }
    }

    /// Members named by `name`, staged in `work` (same file system) as
    /// `PREFIX.SUFFIX.*.tmp`.
    pub fn in_work_folder(
        name: impl Fn(Member) -> PathBuf + 'static,
        work: &Path,
        prefix: &str,
    ) -> FileSink {
        FileSink {
            staging: Staging::In {
                work: work.to_path_buf(),
                prefix: prefix.to_string(),
            },
            ..FileSink::beside(name)
        }
    }

    /// Files the commit removes before it renames anything (an older run's files the new
    /// ones would contradict); a missing one is fine.
    pub fn replacing(mut self, stale: Vec<PathBuf>) -> FileSink {
        self.stale = stale;
        self
    }

    /// Commit `staged` (a file of the command's own) with the members, in one
    /// [`commit_replacing`].
    pub fn with_staged(mut self, staged: Staged) -> FileSink {
        self.extra.push(staged);
        self
    }

    fn stage(&self, member: Member, fill: Fill) -> Result<Staged> {
        let path = (self.name)(member);
        let mut fill = |f: &mut File| fill(f);
        match &self.staging {
            Staging::Beside => stage(&path, &mut fill),
            Staging::In { work, prefix } => stage_in(
                &path,
                work,
                &format!("{prefix}.{}.", member.suffix()),
                &mut fill,
            ),
        }
        .with_context(|| format!("writing {}", path.display()))
    }
}

impl ViewSink for FileSink {
    fn add(&mut self, member: Member, fill: Fill) -> Result<()> {
        let staged = self.stage(member, fill)?;
        self.staged.push((member, staged));
        Ok(())
    }

    fn stream_file(&mut self, member: Member) -> Result<Option<&File>> {
        let staged = self.stage(member, &mut |_| Ok(()))?;
        self.staged.push((member, staged));
        Ok(self.staged.last().map(|(_, s)| s.file()))
    }

    fn label(&self, member: Member) -> String {
        (self.name)(member).display().to_string()
    }

    fn commit(&mut self) -> Result<()> {
        // EXRs last: an EXR in place says the view is complete.
        let (exrs, others): (Vec<_>, Vec<_>) = std::mem::take(&mut self.staged)
            .into_iter()
            .partition(|(m, _)| m.is_exr());
        let ordered = std::mem::take(&mut self.extra)
            .into_iter()
            .chain(others.into_iter().chain(exrs).map(|(_, s)| s))
            .collect();
        commit_replacing(&self.stale, ordered).context("putting the outputs in place")
    }
}

/// A view's members as in-memory `(file name, bytes)` pairs, EXRs last: the shape a tar
/// shard appends, and what tests compare with the files.
#[derive(Default)]
pub struct MemorySink {
    name: String,
    staged: Vec<(Member, Vec<u8>)>,
    /// The committed members: `NAME.SUFFIX` and the bytes.
    pub members: Vec<(String, Vec<u8>)>,
}

impl MemorySink {
    /// Members named `NAME.SUFFIX`.
    pub fn new(name: &str) -> MemorySink {
        MemorySink {
            name: name.to_string(),
            ..MemorySink::default()
        }
    }
}

impl ViewSink for MemorySink {
    fn add(&mut self, member: Member, fill: Fill) -> Result<()> {
        let mut buf = Cursor::new(Vec::new());
        fill(&mut buf).with_context(|| format!("writing {}", self.label(member)))?;
        self.staged.push((member, buf.into_inner()));
        Ok(())
    }

    fn label(&self, member: Member) -> String {
        format!("{}.{}", self.name, member.suffix())
    }

    fn commit(&mut self) -> Result<()> {
        let (exrs, others): (Vec<_>, Vec<_>) = std::mem::take(&mut self.staged)
            .into_iter()
            .partition(|(m, _)| m.is_exr());
        for (m, bytes) in others.into_iter().chain(exrs) {
            self.members.push((self.label(m), bytes));
        }
        Ok(())
    }
}
