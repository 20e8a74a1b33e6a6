//! A format's bytes as a file: an EXR or PNG staged under its temporary name and
//! committed (`crate::output::store::atomic`), alone or with a view's other files, and an
//! EXR read from a path without following a link there. The formats themselves know
//! bytes, not files.

use crate::image::AovImage;
use crate::output::format::exr::{Compression, ExrAttr};
use crate::output::store::atomic::{Staged, stage};
use anyhow::{Context, Result};
use image::ImageBuffer;
use std::io::Write;
use std::path::Path;

impl AovImage {
    /// Write an OpenEXR file atomically (temporary name, then rename).
    pub fn write_exr(&self, path: &Path, compression: Compression) -> Result<()> {
        self.stage_exr(path, compression)?
            .commit()
            .with_context(|| format!("writing {}", path.display()))
    }

    /// Encode an OpenEXR file to `path`'s temporary name, to be committed with others.
    pub fn stage_exr(&self, path: &Path, compression: Compression) -> Result<Staged> {
        self.stage_exr_with(path, compression, &[])
    }

    /// [`AovImage::stage_exr`] with extra header attributes.
    pub fn stage_exr_with(
        &self,
        path: &Path,
        compression: Compression,
        attrs: &[ExrAttr],
    ) -> Result<Staged> {
        stage(path, |file| {
            let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
            self.write_exr_with(&mut out, compression, attrs)
                .map_err(|e| std::io::Error::other(format!("{e:#}")))?;
            out.flush()
        })
        .with_context(|| format!("writing {}", path.display()))
    }

    /// Read every channel of the first layer of the OpenEXR file at `path`.
    pub fn read_exr(path: &Path) -> Result<AovImage> {
        let file = crate::output::store::files::open_input(path)
            .with_context(|| format!("reading {}", path.display()))?;
        AovImage::read_exr_from(std::io::BufReader::new(file), path)
    }
}

/// Encode any PNG-able image atomically.
pub fn write_png<P, C>(img: &ImageBuffer<P, C>, path: &Path) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    stage_png(img, path)?
        .commit()
        .with_context(|| format!("writing {}", path.display()))
}

/// Encode a PNG to `path`'s temporary name, to be committed with others.
pub fn stage_png<P, C>(img: &ImageBuffer<P, C>, path: &Path) -> Result<Staged>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    stage(path, |f| {
        use std::io::Write;
        let mut w = std::io::BufWriter::new(f);
        // The encoder's IO error as it is, so a full disk gets its advice as the EXR's does;
        // and the last buffered bytes flushed here, where a failure is still reported.
        img.write_to(&mut w, image::ImageFormat::Png)
            .map_err(|e| match e {
                image::ImageError::IoError(e) => e,
                e => std::io::Error::other(e.to_string()),
            })?;
        w.flush()
    })
    .with_context(|| format!("writing {}", path.display()))
}
