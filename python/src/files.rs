//! Files: cylaov's EXRs read into arrays, and hit points written as PLY.

use crate::arrays::image_to_dict;
use crate::convert::{parse_aov, shorten};
use crate::errors::os_error;
use crate::pool::run;
use cylaov::image::{AovImage, ChannelData};
use cylaov::output::format::exr::{channel_names, per_aov_channel_names};
use cylaov::scene::Aov;
use numpy::PyReadonlyArray1;
use pyo3::exceptions::{PyIsADirectoryError, PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};

/// Which AOV a per-AOV file holds: the header's `cylaov:channel:NAME` attribute.
fn header_dict<'py>(py: Python<'py>, path: &Path) -> PyResult<(Bound<'py, PyDict>, Vec<String>)> {
    use exr::meta::attribute::AttributeValue;
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| PyOSError::new_err(format!("{}: {e}", path.display())))?;
    let d = PyDict::new(py);
    let mut aovs = Vec::new();
    let Some(h) = meta.headers.first() else {
        return Ok((d, aovs));
    };
    let m44 = |m: &[f32; 16]| -> Vec<Vec<f32>> { m.chunks(4).map(|r| r.to_vec()).collect() };
    if let Some(m) = &h.own_attributes.world_to_camera {
        d.set_item("worldToCamera", m44(m))?;
    }
    if let Some(m) = &h.own_attributes.world_to_normalized_device {
        d.set_item("worldToNDC", m44(m))?;
    }
    for (k, v) in h
        .own_attributes
        .other
        .iter()
        .chain(&h.shared_attributes.other)
    {
        let key = k.to_string();
        if let Some(a) = key.strip_prefix("cylaov:channel:") {
            aovs.push(a.to_string());
        }
        match v {
            AttributeValue::Text(t) => d.set_item(key, t.to_string())?,
            AttributeValue::F32(x) => d.set_item(key, *x)?,
            AttributeValue::F64(x) => d.set_item(key, *x)?,
            AttributeValue::I32(x) => d.set_item(key, *x)?,
            AttributeValue::Matrix4x4(m) => d.set_item(key, m44(m))?,
            _ => {}
        }
    }
    Ok((d, aovs))
}

/// Read one of cylaov's EXRs (layered, or one AOV of the per-AOV layout) into arrays keyed
/// by AOV, as `render` returns them (`mask` included), and the header's attributes under
/// `"header"`. Raises FileNotFoundError (OSError) when the file cannot be read.
#[pyfunction]
pub(crate) fn read<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    exr_input(&path)?;
    let (header, named) = header_dict(py, &path)?;
    let mut image = run(py, None, || AovImage::read_exr(&path))?
        .map_err(|e| PyOSError::new_err(format!("{e:#}")))?;
    // Per-AOV files name their channels Y; R, G; or R, G, B: rename to the AOV's channels.
    let per_aov = image
        .names()
        .iter()
        .all(|c| ["Y", "R", "G", "B"].contains(c));
    let mut aovs: Vec<Aov> = Vec::new();
    if per_aov && named.len() == 1 {
        let a = parse_aov(&named[0], "header cylaov:channel")?;
        let want = per_aov_channel_names(a);
        let mut have = image.names();
        have.sort_unstable();
        let mut sorted = want.to_vec();
        sorted.sort_unstable();
        if have != sorted {
            return Err(PyValueError::new_err(format!(
                "{}: its channels [{}] are not those of the AOV {} its header names \
                 (cylaov:channel:{}): [{}]",
                path.display(),
                image.names().join(", "),
                a.name(),
                a.name(),
                want.join(", ")
            )));
        }
        for (from, to) in want.iter().zip(channel_names(a)) {
            image.rename_channel(from, to);
        }
        image = image.regrouped();
        aovs.push(a);
    } else {
        aovs.extend(
            Aov::ALL
                .into_iter()
                .filter(|&a| image.aov_buffer(a).is_some()),
        );
    }
    if aovs.is_empty() {
        let want: Vec<String> = Aov::ALL
            .iter()
            .map(|&a| channel_names(a).join(", "))
            .collect();
        return Err(PyValueError::new_err(format!(
            "{}: not one of cylaov's EXRs: its channels are [{}]; expected the channels of at \
             least one AOV ({}), or a per-AOV file (Y; R, G; or R, G, B) with a cylaov:channel:NAME \
             attribute",
            path.display(),
            image.names().join(", "),
            want.join("; ")
        )));
    }
    // A channel of no AOV read (an `A`, a lone `normal.X`), or an AOV stored in a type
    // that is not its own (float32; ids float32 or uint32), is refused: dropped or passed
    // on, the arrays would not be what `render` returns.
    let used: Vec<&str> = aovs
        .iter()
        .flat_map(|&a| channel_names(a).iter().copied())
        .collect();
    let other: Vec<&str> = image
        .names()
        .into_iter()
        .filter(|c| !used.contains(c))
        .collect();
    if !other.is_empty() {
        return Err(PyValueError::new_err(format!(
            "{}: channels [{}] are of no whole AOV (a vector AOV needs all its channels, \
             as normal.X, normal.Y, normal.Z): read takes cylaov's EXRs",
            path.display(),
            shorten(&other.join(", "))
        )));
    }
    for &a in &aovs {
        if let Some(b) = image.aov_buffer(a)
            && matches!(b.data, ChannelData::U32(_))
            && !a.is_u32()
        {
            return Err(PyValueError::new_err(format!(
                "{}: {} is stored as uint32; cylaov writes it as float32",
                path.display(),
                a.name()
            )));
        }
    }
    let d = image_to_dict(py, image, &aovs)?;
    d.set_item("header", header)?;
    Ok(d)
}

/// Refuse what is not a regular EXR file that fits in memory, before reading a sample:
/// a FIFO or a device would block with the GIL held, and a header may claim any size
/// (the memory check of `cylaov compare`, a `MemoryError` instead of an abort).
pub(crate) fn exr_input(path: &Path) -> PyResult<()> {
    let m = std::fs::metadata(path).map_err(|e| os_error(path, &e))?;
    if m.is_dir() {
        return Err(PyIsADirectoryError::new_err(format!(
            "{}: is a directory, not an EXR file",
            path.display()
        )));
    }
    if !m.is_file() {
        return Err(PyOSError::new_err(format!(
            "{}: not a regular file",
            path.display()
        )));
    }
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| PyOSError::new_err(format!("{}: {e}", path.display())))?;
    let Some(h) = meta.headers.first() else {
        return Err(PyOSError::new_err(format!(
            "{}: no image in the file",
            path.display()
        )));
    };
    let pixels = h.layer_size.0 as u64 * h.layer_size.1 as u64;
    // 4 bytes a sample as it is read, 2 MiB for the read buffers.
    let bytes = 4 * pixels * h.channels.list.len() as u64 + (2 << 20);
    crate::pool::check_memory(None, &format!("reading {}", path.display()), bytes)
}

/// Write hit points as a PLY point cloud (`cylaov.to_ply` prepares the flat arrays): the
/// file is refused where `render --ply` refuses it (a link, a FIFO) and written whole or
/// not at all. Returns the number of points.
#[pyfunction]
pub(crate) fn _write_ply(
    py: Python<'_>,
    position: PyReadonlyArray1<'_, f32>,
    normal: PyReadonlyArray1<'_, f32>,
    ids: PyReadonlyArray1<'_, u32>,
    path: PathBuf,
) -> PyResult<usize> {
    use cylaov::output::format::ply::{Hit, encode};
    let (p, n, ids) = (position.as_slice()?, normal.as_slice()?, ids.as_slice()?);
    let count = ids.len() / 3;
    if p.len() != 3 * count || n.len() != 3 * count || ids.len() != 3 * count {
        return Err(PyValueError::new_err(
            "to_ply: position, normal and the ids must describe the same points",
        ));
    }
    let hits: Vec<Hit> = (0..count)
        .map(|i| Hit {
            position: [p[3 * i], p[3 * i + 1], p[3 * i + 2]],
            normal: [n[3 * i], n[3 * i + 1], n[3 * i + 2]],
            shape_id: ids[3 * i],
            part: ids[3 * i + 1],
            label: ids[3 * i + 2],
        })
        .collect();
    py.detach(|| {
        cylaov::output::store::targets::check_output("path", &path, &[])?;
        let bytes = encode(
            &hits,
            &format!("cylaov {} hit points", env!("CARGO_PKG_VERSION")),
        );
        cylaov::output::store::atomic::atomic_write_bytes(&path, &bytes)
    })
    .map_err(|e| os_error(&path, &e))?;
    Ok(count)
}
