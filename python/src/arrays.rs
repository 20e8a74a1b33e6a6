//! An image's AOV buffers as numpy arrays (no copy), with the hit `mask`.

use crate::pool::on_pool;
use cylaov::image::{AovImage, ChannelData};
use cylaov::output::format::exr::channel_names;
use cylaov::scene::Aov;
use numpy::IntoPyArray;
use numpy::ndarray::{Array2, Array3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

/// The AOVs to trace for `aovs`: depth joins when none of them tells a hit from a miss
/// exactly (`position`'s zero vector is also a hit at the world origin; `label` 0 is also a
/// cylinder without a label; `uv` is (0, 0) on a seam at `p0`), so the mask is exact.
pub(crate) fn traced(aovs: &[Aov]) -> Vec<Aov> {
    let mut t = aovs.to_vec();
    if aovs
        .iter()
        .all(|&a| matches!(a, Aov::Position | Aov::Label | Aov::Uv))
    {
        t.push(Aov::Depth);
    }
    t
}

/// Refuse, as `MemoryError`, rendering `views` views of `width × height` with the `traced`
/// AOVs held at once when they do not fit in the memory left (free memory, `ulimit -v`,
/// the cgroup): the check `cylaov render` makes. The library allocates a render's planes
/// with the promise that this check has passed; refused a plane, all it can do is end the
/// process, which here is the user's interpreter. Checked on the pool of `threads` that
/// will render (see `pool::check_memory`), [`LOOK_AHEAD`] views' worth at a time.
pub(crate) fn check_views_memory(
    (width, height): (u32, u32),
    traced: &[Aov],
    views: usize,
    threads: Option<usize>,
) -> PyResult<()> {
    // The planes, kept as they are, and the mask: a byte a pixel.
    let one = cylaov::output::pipeline::memory::planes_memory((width, height), traced)
        + width as u64 * height as u64;
    let need = one.saturating_mul(views as u64);
    let whose = (std::process::id(), threads);
    {
        let mut ahead = AHEAD.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((who, left)) = ahead.as_mut()
            && *who == whose
            && *left >= need
        {
            *left -= need;
            return Ok(());
        }
    }
    let names: Vec<&str> = traced.iter().map(|a| a.name()).collect();
    let what = match views {
        1 => format!("rendering {width}x{height} with {}", names.join(",")),
        n => format!(
            "rendering {n} views of {width}x{height} with {}",
            names.join(",")
        ),
    };
    let more = need.saturating_mul(LOOK_AHEAD);
    // (`pool::check_memory` drops the allowance: it is set again below.)
    let left = match crate::pool::check_memory(threads, &what, more) {
        Ok(()) => more - need,
        // Too little for that many: this call's own need decides, and the next looks again.
        Err(_) => {
            crate::pool::check_memory(threads, &what, need)?;
            0
        }
    };
    *AHEAD.lock().unwrap_or_else(|e| e.into_inner()) = Some((whose, left));
    Ok(())
}

/// How many times a view's need a look at the memory left asks for: found, the next views
/// spend it without a look until it runs out. A look (reading `/proc/meminfo`, on the
/// pool) took 45 µs, a tenth of a 320x240 depth+normal view's 420 µs; made once in 64
/// views, it is lost in the noise, and a view larger than what was found looks anew.
const LOOK_AHEAD: u64 = 64;

/// Bytes views may take without a look at the memory left ([`LOOK_AHEAD`]), and the
/// process and `threads=` that looked: a forked worker looks for itself, and a call on
/// another pool (which may start threads, each reserving an arena) looks anew. Any other
/// look at the memory ([`crate::pool::check_memory`]: a cast, a scan, ...) drops it.
pub(crate) static AHEAD: std::sync::Mutex<Option<(Looker, u64)>> = std::sync::Mutex::new(None);

/// Who looked at the memory left: the process id and the call's `threads=`.
type Looker = (u32, Option<usize>);

/// AOV name and its array: the AOV's buffer, `(H, W)` or `(H, W, C)` as the render
/// filled it.
enum Plane {
    F32(Vec<f32>),
    U32(Vec<u32>),
    /// `C` float32 channels a pixel, side by side (C from the AOV table: 2 or 3).
    Channels(Vec<f32>, usize),
}

/// An image's arrays before they become Python objects: built with the GIL released, on
/// the call's pool.
pub(crate) struct Arrays {
    width: usize,
    height: usize,
    planes: Vec<(Aov, Plane)>,
    mask: Option<Vec<bool>>,
}

/// The image's requested AOVs (owned: the arrays take the buffers as they are, no copy;
/// float32 ids of a per-AOV file become uint32) and the `mask`.
pub(crate) fn arrays(mut image: AovImage, aovs: &[Aov]) -> Arrays {
    let (w, h) = (image.width, image.height);
    // Depth traced only for the mask (see `traced`).
    let depth_mask = match image.take_aov_buffer(Aov::Depth) {
        Some(b) if !aovs.contains(&Aov::Depth) => match b.data {
            ChannelData::F32(v) if v.len() == w * h => {
                Some(v.par_iter().map(|&x| x > 0.0).collect())
            }
            _ => None,
        },
        Some(b) => {
            image.buffers.push(b);
            None
        }
        None => None,
    };
    let mut planes: Vec<(Aov, Plane)> = Vec::new();
    for &a in aovs {
        let Some(buffer) = image.take_aov_buffer(a) else {
            continue;
        };
        let plane = match (buffer.data, channel_names(a).len()) {
            (ChannelData::F32(v), 1) if a.is_u32() => {
                Plane::U32(v.into_iter().map(|x| x as u32).collect())
            }
            (ChannelData::F32(v), 1) => Plane::F32(v),
            (ChannelData::U32(v), 1) => Plane::U32(v),
            (ChannelData::F32(v), c) if c > 1 => Plane::Channels(v, c),
            _ => continue,
        };
        planes.push((a, plane));
    }
    let mask = depth_mask.or_else(|| mask_of(&planes, w * h));
    Arrays {
        width: w,
        height: h,
        planes,
        mask,
    }
}

impl Arrays {
    /// Each array's bytes in the order of its dict (the AOVs, then `mask`: a bool is one
    /// byte, 0 or 1, as numpy stores it), for copying into a batch's buffer.
    pub(crate) fn bytes(&self) -> Vec<&[u8]> {
        let mut v: Vec<&[u8]> = self
            .planes
            .iter()
            .map(|(_, p)| match p {
                Plane::F32(x) | Plane::Channels(x, _) => as_bytes(x),
                Plane::U32(x) => as_bytes(x),
            })
            .collect();
        if let Some(m) = &self.mask {
            v.push(as_bytes(m));
        }
        v
    }
}

/// Values whose every byte is initialised (no padding): their slices read as bytes.
trait Plain: Copy {}
impl Plain for f32 {}
impl Plain for u32 {}
impl Plain for bool {}

/// A slice's memory as bytes.
fn as_bytes<T: Plain>(x: &[T]) -> &[u8] {
    // SAFETY: a `Plain` value has no padding, so every byte of the slice is initialised; u8
    // has no alignment, and the length is the slice's size in bytes.
    unsafe { std::slice::from_raw_parts(x.as_ptr().cast::<u8>(), std::mem::size_of_val(x)) }
}

/// The arrays as a dict keyed by AOV name, `mask` beside them; numpy takes the buffers.
pub(crate) fn arrays_to_dict<'py>(py: Python<'py>, arrays: Arrays) -> PyResult<Bound<'py, PyDict>> {
    let Arrays {
        width: w,
        height: h,
        planes,
        mask,
    } = arrays;
    let d = PyDict::new(py);
    for (a, plane) in planes {
        let arr = match plane {
            Plane::F32(v) => Array2::from_shape_vec((h, w), v)
                .map_err(shape_err)?
                .into_pyarray(py)
                .into_any(),
            Plane::U32(v) => Array2::from_shape_vec((h, w), v)
                .map_err(shape_err)?
                .into_pyarray(py)
                .into_any(),
            Plane::Channels(v, c) => Array3::from_shape_vec((h, w, c), v)
                .map_err(shape_err)?
                .into_pyarray(py)
                .into_any(),
        };
        d.set_item(a.name(), arr)?;
    }
    if let Some(m) = mask {
        d.set_item(
            "mask",
            Array2::from_shape_vec((h, w), m)
                .map_err(shape_err)?
                .into_pyarray(py),
        )?;
    }
    Ok(d)
}

/// The image's AOVs by name (owned: the arrays take the buffers), the `mask` beside them.
pub(crate) fn image_to_dict<'py>(
    py: Python<'py>,
    image: AovImage,
    aovs: &[Aov],
) -> PyResult<Bound<'py, PyDict>> {
    arrays_to_dict(py, on_pool(None, || arrays(image, aovs))?)
}

pub(crate) fn shape_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(format!("image size: {e}"))
}

/// Hit or miss per pixel, from the first AOV that tells: a miss is 0 in every channel, a
/// hit has depth, distance, id and part > 0 and a unit normal.
fn mask_of(planes: &[(Aov, Plane)], n: usize) -> Option<Vec<bool>> {
    let order = [
        Aov::Depth,
        Aov::Distance,
        Aov::ShapeId,
        Aov::Part,
        Aov::Normal,
        Aov::NormalCamera,
        // Last: a hit exactly at the world origin, or at uv (0, 0) (the seam at `p0`, a
        // cap's centre), reads as a miss. `render` and `Dataset` trace depth beside them;
        // only `read` of a file without a better AOV relies on them. `label` cannot tell
        // (0 is also a cylinder without a label): a lone label file has no mask.
        Aov::Position,
        Aov::Uv,
    ];
    for want in order {
        let Some((_, p)) = planes.iter().find(|(a, _)| *a == want) else {
            continue;
        };
        // On the call's pool: a 1080p mask on one thread is a tenth of a two-thread render.
        return Some(match p {
            Plane::F32(v) => v.par_iter().map(|&x| x > 0.0).collect(),
            Plane::U32(v) => v.par_iter().map(|&x| x != 0).collect(),
            Plane::Channels(v, c) => v
                .par_chunks_exact(*c)
                .map(|p| p.iter().any(|&x| x != 0.0))
                .collect(),
        });
    }
    (n == 0).then(Vec::new)
}
