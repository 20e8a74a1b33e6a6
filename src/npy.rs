//! NumPy `.npy` (format 1.0) encoding of the arrays of a tar shard: `(H, W)` or
//! `(H, W, C)`, C order, little-endian float32, uint32 or bool (and float64, for a scan's
//! `.npz`), which `numpy.load` and
//! `webdataset`'s decoder read as they are; and the reading of such arrays ([`parse`]) and
//! of any numeric array `numpy.save` writes ([`parse_raw`], for cylinder tables).
//!
//! A file is the magic `\x93NUMPY`, version 1.0, a little-endian u16 header length, the
//! header (a Python dict literal padded with spaces and ending in a newline so the data
//! starts at a multiple of 64 bytes), then the samples.

/// The element types a shard stores.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    /// `<f4`.
    F32,
    /// `<u4`.
    U32,
    /// `|b1`: one byte, 0 or 1.
    Bool,
    /// `<f8` (a scan's coordinates and ranges).
    F64,
}

impl Dtype {
    fn descr(self) -> &'static str {
        match self {
            Dtype::F32 => "<f4",
            Dtype::U32 => "<u4",
            Dtype::Bool => "|b1",
            Dtype::F64 => "<f8",
        }
    }

    /// Bytes of one element.
    pub fn size(self) -> usize {
        match self {
            Dtype::F32 | Dtype::U32 => 4,
            Dtype::Bool => 1,
            Dtype::F64 => 8,
        }
    }
}

/// The magic, version, header length and header of an array of `shape`: a multiple of
/// 64 bytes.
pub fn header(dtype: Dtype, shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    // A one-element tuple needs its trailing comma.
    let tuple = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut dict = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {tuple}, }}",
        dtype.descr()
    );
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    dict.push('\n');
    let mut out = Vec::with_capacity(10 + dict.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// Bytes of the `.npy` file of an array of `shape`.
pub fn file_size(dtype: Dtype, shape: &[usize]) -> usize {
    header(dtype, shape).len() + shape.iter().product::<usize>() * dtype.size()
}

/// An array of `shape` from its samples in C order (an AOV buffer as the render holds
/// it: `(H, W)`, or `(H, W, C)` with a pixel's channels side by side): the header, then the
/// samples' bytes as they lie in memory on a little-endian machine.
pub fn array<X: bytemuck::Pod>(dtype: Dtype, shape: &[usize], samples: &[X]) -> Vec<u8> {
    debug_assert_eq!(std::mem::size_of::<X>(), dtype.size());
    debug_assert_eq!(shape.iter().product::<usize>(), samples.len());
    let mut out = header(dtype, shape);
    let bytes: &[u8] = bytemuck::cast_slice(samples);
    if cfg!(target_endian = "little") {
        out.extend_from_slice(bytes);
    } else {
        out.reserve_exact(bytes.len());
        for w in bytes.chunks_exact(dtype.size()) {
            out.extend(w.iter().rev());
        }
    }
    out
}

/// A `(H, W)` bool array: `true` where `hit`.
pub fn bool_plane(height: usize, width: usize, hit: impl Iterator<Item = bool>) -> Vec<u8> {
    let mut out = header(Dtype::Bool, &[height, width]);
    out.extend(hit.map(u8::from));
    out
}

/// An array read from `.npy` bytes: its element type, shape and samples' bytes (C order,
/// little-endian).
#[derive(Debug, PartialEq)]
pub struct Array<'a> {
    /// The element type.
    pub dtype: Dtype,
    /// The shape.
    pub shape: Vec<usize>,
    /// The samples' bytes, `shape.product() * dtype.size()` of them.
    pub data: &'a [u8],
}

/// Parse `.npy` (format 1.0 or 2.0) bytes of one of the [`Dtype`]s in C order, as
/// [`array()`] writes them and `numpy.save` writes such arrays; anything else (another
/// dtype, Fortran order, a size that does not match the shape) is an error saying what.
pub fn parse(bytes: &[u8]) -> Result<Array<'_>, String> {
    let raw = parse_raw(bytes)?;
    let dtype = [Dtype::F32, Dtype::U32, Dtype::Bool]
        .into_iter()
        .find(|d| raw.descr == d.descr())
        .ok_or(format!(
            "a .npy array of dtype '{}', not float32, uint32 or bool",
            raw.descr
        ))?;
    if raw.fortran_order {
        return Err("a .npy array in Fortran order".into());
    }
    Ok(Array {
        dtype,
        shape: raw.shape,
        data: raw.data,
    })
}

/// An array of any numeric dtype read from `.npy` bytes, as `numpy.save` writes whatever
/// array it is given: what reading a user's arrays needs (a cylinder table from NumPy holds
/// float64 or float32 points and int64 ids, in either order).
#[derive(Debug, PartialEq)]
pub struct RawArray<'a> {
    /// numpy's `descr`: byte order (`<`, `>`, `|` or `=`), kind (`f`, `i`, `u`, `b`) and
    /// size in bytes, e.g. `<f8`, `|u1`.
    pub descr: String,
    /// Whether the first index varies fastest (numpy's `fortran_order`).
    pub fortran_order: bool,
    /// The shape.
    pub shape: Vec<usize>,
    /// The samples' bytes, `shape.product()` elements of the `descr`'s size.
    pub data: &'a [u8],
    /// Bytes of one element, read from the `descr` once (not for each element).
    size: usize,
}

/// At most the first 200 characters of `text`, for a message about a header that may be
/// megabytes long.
fn clip(text: &str) -> String {
    match text.char_indices().nth(200) {
        Some((at, _)) => format!("{:?}… ({} bytes)", &text[..at], text.len()),
        None => format!("{text:?}"),
    }
}

/// Bytes of one element of numpy dtype `descr`: its digits, for numpy's number kinds
/// (`f`, `i`, `u`, `b`, `c`); any other kind (strings `<U1`, bytes `|S3`, dates, objects)
/// is an error naming the dtype, as a size read from its digits would not be its size.
fn element_size(descr: &str) -> Result<usize, String> {
    let kind = descr.as_bytes().get(1).copied();
    descr
        .get(2..)
        .filter(|_| matches!(kind, Some(b'f' | b'i' | b'u' | b'b' | b'c')))
        .and_then(|d| d.parse::<usize>().ok())
        .filter(|&n| n > 0)
        .ok_or(format!("an array of dtype {descr:?}; {READABLE}"))
}

/// Parse `.npy` (format 1.0, 2.0 or 3.0) bytes of a plain numeric dtype (no structured or
/// object arrays); the size of the samples must match the shape.
pub fn parse_raw(bytes: &[u8]) -> Result<RawArray<'_>, String> {
    let (len, start) = match bytes {
        [0x93, b'N', b'U', b'M', b'P', b'Y', 1, _, a, b, ..] => {
            (u16::from_le_bytes([*a, *b]) as usize, 10)
        }
        [0x93, b'N', b'U', b'M', b'P', b'Y', 2 | 3, _, a, b, c, d, ..] => {
            (u32::from_le_bytes([*a, *b, *c, *d]) as usize, 12)
        }
        _ => return Err("not a .npy array (no \\x93NUMPY magic of version 1, 2 or 3)".into()),
    };
    let dict = bytes
        .get(start..start + len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or("a .npy header cut short or not text")?;
    // The header is a Python dict literal with three keys; read each value's text.
    let value = |key: &str| -> Result<&str, String> {
        let at = dict
            .find(&format!("'{key}':"))
            .ok_or_else(|| format!("a .npy header without '{key}': {}", clip(dict)))?;
        Ok(dict[at + key.len() + 3..].trim_start())
    };
    let descr = value("descr")?;
    let descr = descr
        .strip_prefix('\'')
        .and_then(|d| d.split_once('\''))
        .map(|(d, _)| d.to_string())
        .ok_or_else(|| {
            format!(
                "a .npy array of dtype {}, not a plain number type",
                clip(descr.split(", '").next().unwrap_or(descr))
            )
        })?;
    let fortran_order = value("fortran_order")?.starts_with("True");
    let shape_text = value("shape")?;
    let shape_text = shape_text
        .strip_prefix('(')
        .and_then(|t| t.split_once(')'))
        .map(|(inner, _)| inner)
        .ok_or_else(|| format!("a .npy header's shape reads {}", clip(shape_text)))?;
    let shape = shape_text
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| {
            t.parse::<usize>()
                .map_err(|_| format!("a .npy shape of {}", clip(shape_text)))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let size = element_size(&descr)?;
    let raw = RawArray {
        descr,
        fortran_order,
        shape,
        data: &bytes[(start + len).min(bytes.len())..],
        size,
    };
    let want = raw
        .shape
        .iter()
        .try_fold(size, |n, &d| n.checked_mul(d))
        .ok_or(format!("a .npy shape of {:?} overflows", raw.shape))?;
    if raw.data.len() != want {
        return Err(format!(
            "a .npy array of shape {:?} holds {} bytes of samples, not {want}",
            raw.shape,
            raw.data.len()
        ));
    }
    Ok(raw)
}

/// What [`RawArray::element`] reads, as an error names them.
const READABLE: &str = "readable are float32, float64, (u)int8 to (u)int64 and bool";

impl RawArray<'_> {
    /// How many elements the array holds.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    /// Whether the array holds no element.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether the elements are floats (`f` kind), not integers or bools.
    pub fn is_float(&self) -> bool {
        self.descr.as_bytes().get(1) == Some(&b'f')
    }

    /// An error naming the dtype unless [`RawArray::get`] reads its elements (float32,
    /// float64, integers of 1 to 8 bytes, bool).
    pub fn check_readable(&self) -> Result<(), String> {
        match (self.descr.as_bytes().get(1), self.size) {
            (Some(b'f'), 4 | 8) | (Some(b'i' | b'u' | b'b'), 1 | 2 | 4 | 8) => Ok(()),
            _ => Err(format!("an array of dtype {:?}; {READABLE}", self.descr)),
        }
    }

    /// The element at byte offset `at` as a number, for the kinds and sizes numpy's
    /// numeric arrays use (`f4`, `f8`, `i1`..`i8`, `u1`..`u8`, `b1`); `None` for any other.
    fn element(&self, at: usize) -> Option<Element> {
        let b = self.descr.as_bytes();
        let (order, kind) = (*b.first()?, *b.get(1)?);
        let n = Some(self.size).filter(|&n| n <= 8)?;
        let mut bytes = [0u8; 8];
        bytes[..n].copy_from_slice(self.data.get(at..at + n)?);
        if order == b'>' {
            bytes[..n].reverse();
        }
        // Sign-extend a signed integer shorter than 8 bytes.
        let fill = if kind == b'i' && bytes[n - 1] & 0x80 != 0 {
            0xFF
        } else {
            0
        };
        bytes[n..].fill(fill);
        match (kind, n) {
            (b'f', 4) => {
                Some(Element::Float(
                    f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as f64,
                ))
            }
            (b'f', 8) => Some(Element::Float(f64::from_le_bytes(bytes))),
            (b'i', 1 | 2 | 4 | 8) => Some(Element::Int(i64::from_le_bytes(bytes) as i128)),
            (b'u' | b'b', 1 | 2 | 4 | 8) => Some(Element::Int(u64::from_le_bytes(bytes) as i128)),
            _ => None,
        }
    }

    /// The element of C-order index `c` (the last index fastest, whatever the file's
    /// order), read from the samples' bytes when asked: an array is never copied into a
    /// list of values, so reading one takes no memory beyond its bytes. `None` past the
    /// end or for a dtype [`RawArray::check_readable`] refuses.
    pub fn get(&self, c: usize) -> Option<Element> {
        let size = self.size;
        if c >= self.len() {
            return None;
        }
        let at = if self.fortran_order {
            // Index (i, j, ...) lies at i + n_i (j + n_j ...) elements: split `c` into its
            // indices, last first, and weigh each by the product of the dimensions before it.
            let total = self.len();
            let (mut rest, mut tail, mut at) = (c, 1usize, 0usize);
            for &n in self.shape.iter().rev() {
                let i = rest % n;
                rest /= n;
                tail *= n;
                at += i * (total / tail);
            }
            at * size
        } else {
            c * size
        };
        self.element(at)
    }
}

/// One element of a [`RawArray`]: integers (and bools) exactly, floats widened to f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Element {
    /// An integer or bool element.
    Int(i128),
    /// A float element.
    Float(f64),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The headers numpy 2.4 `np.save` writes for these arrays: 128 bytes each, the same
    /// dict text.
    #[test]
    fn headers_are_numpys() {
        let h = header(Dtype::F32, &[240, 320]);
        assert_eq!(h.len(), 128);
        let text = std::str::from_utf8(&h[10..]).unwrap();
        assert_eq!(
            text.trim_end(),
            "{'descr': '<f4', 'fortran_order': False, 'shape': (240, 320), }"
        );
        assert!(text.ends_with(" \n"));
        assert_eq!(u16::from_le_bytes([h[8], h[9]]) as usize, h.len() - 10);
        for shape in [&[2, 3][..], &[1, 2, 3], &[5]] {
            assert_eq!(header(Dtype::Bool, shape).len(), 128, "{shape:?}");
        }
        assert!(
            std::str::from_utf8(&header(Dtype::U32, &[5])[10..])
                .unwrap()
                .contains("'shape': (5,), ")
        );
    }

    /// Samples go out in their order, little-endian; the sizes match `file_size`.
    #[test]
    fn samples_keep_their_order() {
        let xyz = [1.0f32, 3.0, 5.0, 2.0, 4.0, -0.0];
        let b = array(Dtype::F32, &[1, 2, 3], &xyz);
        assert_eq!(b.len(), file_size(Dtype::F32, &[1, 2, 3]));
        let data: Vec<f32> = b[128..]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(data, xyz);
        assert_eq!(data[5].to_bits(), (-0.0f32).to_bits());
        let one = array(Dtype::F32, &[1, 2], &[1.5f32, -2.0]);
        assert_eq!(one.len(), file_size(Dtype::F32, &[1, 2]));
        assert_eq!(&one[128..132], &1.5f32.to_le_bytes());
        assert_eq!(&one[132..], &(-2.0f32).to_le_bytes());
        let m = bool_plane(1, 3, [true, false, true].into_iter());
        assert_eq!(&m[128..], &[1, 0, 1]);
        let u = array(Dtype::U32, &[1, 1], &[0x0102_0304u32]);
        assert_eq!(&u[128..], &[4, 3, 2, 1]);
    }

    /// What [`array()`] writes, [`parse`] reads back; damaged arrays are refused saying how.
    #[test]
    fn parse_reads_what_array_writes() {
        let samples = [1.5f32, -2.0, 0.0, 7.25, 1e-30, 3.0];
        let bytes = array(Dtype::F32, &[2, 3], &samples);
        let a = parse(&bytes).unwrap();
        assert_eq!((a.dtype, a.shape.clone()), (Dtype::F32, vec![2, 3]));
        assert_eq!(a.data, bytemuck::cast_slice::<f32, u8>(&samples));
        let v = array(Dtype::U32, &[4], &[1u32, 2, 3, 4]);
        assert_eq!(parse(&v).unwrap().shape, [4]);
        let b = bool_plane(1, 2, [true, false].into_iter());
        assert_eq!(parse(&b).unwrap().data, [1, 0]);
        let e = parse(&bytes[..bytes.len() - 1]).unwrap_err();
        assert!(e.contains("holds 23 bytes of samples, not 24"), "{e}");
        let mut other = bytes.clone();
        let at = other.windows(3).position(|w| w == b"<f4").unwrap();
        other[at + 1] = b'i';
        assert!(parse(&other).unwrap_err().contains("dtype '<i4'"));
        assert!(parse(b"PK\x03\x04").unwrap_err().contains("magic"));
    }

    /// A header as numpy writes it for any array: the dict text padded to 64 bytes.
    fn npy_of(descr: &str, fortran: bool, shape: &str, data: &[u8]) -> Vec<u8> {
        let mut dict = format!(
            "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape}, }}",
            if fortran { "True" } else { "False" }
        );
        while (10 + dict.len() + 1) % 64 != 0 {
            dict.push(' ');
        }
        dict.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend((dict.len() as u16).to_le_bytes());
        out.extend(dict.as_bytes());
        out.extend(data);
        out
    }

    /// Every element in C order, as a table reads them one by one.
    fn elements(raw: &RawArray) -> Result<Vec<Element>, String> {
        raw.check_readable()?;
        Ok((0..raw.len()).map(|c| raw.get(c).unwrap()).collect())
    }

    /// Any numeric dtype reads to its values in C order: Fortran order transposed,
    /// big-endian swapped, short signed integers sign-extended, float32 widened exactly.
    #[test]
    fn raw_arrays_read_in_c_order() {
        // [[1, 2, 3], [4, 5, 6]] stored column by column as big-endian int16.
        let fortran: Vec<u8> = [1i16, 4, 2, 5, 3, 6]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let a = npy_of(">i2", true, "(2, 3)", &fortran);
        let raw = parse_raw(&a).unwrap();
        assert_eq!(raw.shape, [2, 3]);
        let ints: Vec<Element> = (1..=6).map(Element::Int).collect();
        assert_eq!(elements(&raw).unwrap(), ints);
        let neg = npy_of("|i1", false, "(2,)", &[0xFF, 0x80]);
        assert_eq!(
            elements(&parse_raw(&neg).unwrap()).unwrap(),
            [Element::Int(-1), Element::Int(-128)]
        );
        let big = npy_of("<u8", false, "(1,)", &u64::MAX.to_le_bytes());
        assert_eq!(
            elements(&parse_raw(&big).unwrap()).unwrap(),
            [Element::Int(u64::MAX as i128)]
        );
        let f = npy_of("<f4", false, "(1,)", &0.1f32.to_le_bytes());
        assert_eq!(
            elements(&parse_raw(&f).unwrap()).unwrap(),
            [Element::Float(0.1f32 as f64)]
        );
        // Not a number type, or a size that does not match the shape.
        let c = npy_of("<c16", false, "(1,)", &[0; 16]);
        assert!(
            elements(&parse_raw(&c).unwrap())
                .unwrap_err()
                .contains("<c16")
        );
        // Strings: refused by their dtype, not by a size read from its digits.
        let u = npy_of("<U1", false, "(3,)", &[0; 12]);
        assert_eq!(
            parse_raw(&u).unwrap_err(),
            "an array of dtype \"<U1\"; readable are float32, float64, (u)int8 to (u)int64 and bool"
        );
        // A (2, 2, 2) array in Fortran order: element (i, j, k) at i + 2 j + 4 k.
        let f3: Vec<u8> = (0u8..8).collect();
        let f3 = npy_of("|u1", true, "(2, 2, 2)", &f3);
        let want: Vec<Element> = [0, 4, 2, 6, 1, 5, 3, 7].map(Element::Int).to_vec();
        assert_eq!(elements(&parse_raw(&f3).unwrap()).unwrap(), want);
        assert_eq!(parse_raw(&f3).unwrap().get(8), None);
        let short = npy_of("<f8", false, "(2,)", &[0; 8]);
        assert!(
            parse_raw(&short)
                .unwrap_err()
                .contains("holds 8 bytes of samples, not 16")
        );
    }
}
