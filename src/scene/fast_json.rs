//! A fast reader for well-formed scene files: the cylinder list parsed and validated by
//! hand, in parallel, with correctly rounded numbers.
//!
//! A 100 000-cylinder scene is 15 MB of JSON, and `serde_json` (with path tracking for its
//! error messages) spent about as long reading it as the render took. This reader accepts
//! only what the file schema accepts, in its plain form: the top-level object's keys
//! `camera` or `cameras`, `cylinders` and `aovs`, each cylinder an object of the known keys with
//! numbers, arrays of three numbers, `true`/`false` and an unsigned integer `id`. Anything
//! else (an unknown or repeated key, `null`, an escaped key, a number out of range, a
//! syntax error, a byte that is not ASCII outside the camera and the AOV list) makes it
//! give up, and the caller parses the text again with `serde_json`, whose messages name the
//! field. So a file either reads the same through both, or only `serde_json` reads it, with
//! today's errors.
//!
//! Each cylinder is validated as soon as it is read, by the same code as the `serde_json`
//! path ([`CylinderFile::validate`]), so the file form of the whole list is never stored.
//! The first invalid cylinder (in file order) is reported only if the rest of the file
//! reads: a syntax error anywhere takes precedence, as it does with `serde_json`.
//!
//! Numbers: digits are gathered into an integer as they are scanned; when it has at most
//! 19 digits, is at most 2^53 and the power of ten is at most 10^22 in size, both are exact
//! f64s and one multiplication or division rounds the exact quotient correctly (Clinger's
//! fast path, the one Rust's own `str::parse` tries first). Longer fractions of at most 19
//! digits (the 17 of a shortest round-trip form, as `generate` writes) take `m / 10^k` in
//! f64 as a guess and settle it with an exact 128-bit comparison against the midpoints to
//! its neighbours ([`nearest`]). Every other number goes through `str::parse::<f64>`,
//! which is correctly rounded, as `serde_json`'s `float_roundtrip` parsing is: all give
//! the same bits for every number (tested on hard cases, exact midpoints and a million
//! random numbers). The camera and the AOV list are small and go through `serde_json` as
//! they are.

use super::strict::Object;
use super::{CameraFile, CylinderFile, SceneError};
use crate::geometry::Cylinder;
use crate::scene::Aov;
use rayon::prelude::*;

/// A scene file as the fast reader leaves it: the cameras and AOVs as written, the
/// cylinders already validated (or the first one's error).
pub struct FastScene {
    /// `"camera"`, when given.
    pub camera: Option<CameraFile>,
    /// `"cameras"`, when given.
    pub cameras: Option<Vec<CameraFile>>,
    /// The validated cylinders, in file order, or the first invalid one's error.
    pub cylinders: Result<Vec<Cylinder>, SceneError>,
    /// `"aovs"`, when given and not `null`.
    pub aovs: Option<Vec<Aov>>,
}

/// The scene file in `b`, or `None` when it is not in the plain form this reader handles
/// (the caller then uses `serde_json`, which also reports any error). `b` need not be
/// UTF-8: what this reader accepts is ASCII but for the camera and AOV values, which are
/// checked before `serde_json` reads them.
pub fn scene_file(b: &[u8]) -> Option<FastScene> {
    let mut p = Cursor { b, i: 0 };
    p.expect(b'{')?;
    let (mut camera, mut cameras, mut cylinders, mut aovs) = (None, None, None, None);
    loop {
        let key = p.key()?;
        let start = p.i;
        match key {
            b"camera" if camera.is_none() => {
                let end = skip_value(b, start)?;
                // Through `strict::Object`: a camera must be an object, as in the schema.
                let c = serde_json::from_str::<Object<CameraFile>>(utf8(b, start, end)?).ok()?;
                camera = Some(c.0);
                p.i = end;
            }
            b"cameras" if cameras.is_none() => {
                let end = skip_value(b, start)?;
                let list =
                    serde_json::from_str::<Vec<Object<CameraFile>>>(utf8(b, start, end)?).ok()?;
                cameras = Some(list.into_iter().map(|c| c.0).collect());
                p.i = end;
            }
            b"aovs" if aovs.is_none() => {
                let end = skip_value(b, start)?;
                aovs = Some(serde_json::from_str::<Option<Vec<Aov>>>(utf8(b, start, end)?).ok()?);
                p.i = end;
            }
            b"cylinders" if cylinders.is_none() => {
                let (list, end) = cylinder_list(b, start)?;
                cylinders = Some(list);
                p.i = end;
            }
            _ => return None,
        }
        match p.next()? {
            b',' => continue,
            b'}' => break,
            _ => return None,
        }
    }
    p.ws();
    if p.i != b.len() {
        return None;
    }
    Some(FastScene {
        camera,
        cameras,
        cylinders: cylinders?,
        aovs: aovs.flatten(),
    })
}

/// `b[start..end]` as text, when it is UTF-8.
fn utf8(b: &[u8], start: usize, end: usize) -> Option<&str> {
    std::str::from_utf8(b.get(start..end)?).ok()
}

/// A position in the text.
struct Cursor<'a> {
    b: &'a [u8],
    i: usize,
}

/// The powers of ten that are exact f64s (5^22 < 2^53).
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

impl<'a> Cursor<'a> {
    /// Skip JSON whitespace.
    #[inline(always)]
    fn ws(&mut self) {
        while let Some(&c) = self.b.get(self.i) {
            if !matches!(c, b' ' | b'\n' | b'\r' | b'\t') {
                break;
            }
            self.i += 1;
        }
    }

    /// The next byte after whitespace.
    #[inline(always)]
    fn next(&mut self) -> Option<u8> {
        self.ws();
        let c = *self.b.get(self.i)?;
        self.i += 1;
        Some(c)
    }

    #[inline(always)]
    fn expect(&mut self, c: u8) -> Option<()> {
        (self.next()? == c).then_some(())
    }

    /// `"name":` (a name without escapes), returning the name.
    #[inline(always)]
    fn key(&mut self) -> Option<&'a [u8]> {
        self.expect(b'"')?;
        let b = self.b;
        let start = self.i;
        let len = b[start..].iter().position(|&c| c == b'"')?;
        let name = &b[start..start + len];
        if name.contains(&b'\\') {
            return None;
        }
        self.i = start + len + 1;
        self.expect(b':')?;
        self.ws();
        Some(name)
    }

    /// `"name":` for one of a cylinder's keys (the name then written without escapes),
    /// returning the name; `None` for any other key, which the caller rejects anyway.
    /// Faster than [`Cursor::key`]: one comparison against the key the first letter names.
    #[inline(always)]
    fn cylinder_key(&mut self) -> Option<&'static [u8]> {
        self.expect(b'"')?;
        let rest = self.b.get(self.i..)?;
        let key: &'static [u8] = match rest.first()? {
            b'p' if rest.starts_with(b"p0\"") => b"p0",
            b'p' if rest.starts_with(b"p1\"") => b"p1",
            b'r' if rest.starts_with(b"radius\"") => b"radius",
            b'c' if rest.starts_with(b"caps\"") => b"caps",
            b'c' if rest.starts_with(b"center\"") => b"center",
            b'a' if rest.starts_with(b"axis\"") => b"axis",
            b'h' if rest.starts_with(b"height\"") => b"height",
            b'i' if rest.starts_with(b"id\"") => b"id",
            _ => return None,
        };
        self.i += key.len() + 1;
        self.expect(b':')?;
        self.ws();
        Some(key)
    }

    /// Digits from `self.i` on, gathered into `acc` (wrapping: the caller counts them).
    /// How many there were.
    #[inline(always)]
    fn digits(&mut self, acc: &mut u64) -> usize {
        let start = self.i;
        // Eight at a time while there are eight (a fraction's digits mostly).
        while let Some(&chunk) = self.b.get(self.i..).and_then(|r| r.first_chunk::<8>()) {
            let v = u64::from_le_bytes(chunk);
            if !eight_digits(v) {
                break;
            }
            *acc = acc.wrapping_mul(100_000_000).wrapping_add(parse_eight(v));
            self.i += 8;
        }
        self.i - start + self.short_digits(acc)
    }

    /// [`Cursor::digits`] one at a time, for the short runs (an integer part, the last
    /// digits of a fraction).
    #[inline(always)]
    fn short_digits(&mut self, acc: &mut u64) -> usize {
        let start = self.i;
        while let Some(&c) = self.b.get(self.i) {
            let d = c.wrapping_sub(b'0');
            if d > 9 {
                break;
            }
            *acc = acc.wrapping_mul(10).wrapping_add(d as u64);
            self.i += 1;
        }
        self.i - start
    }

    /// A JSON number as an f64 (finite: an overflow is left to `serde_json`'s message).
    #[inline(always)]
    fn number(&mut self) -> Option<f64> {
        self.ws();
        let b = self.b;
        let start = self.i;
        let neg = b.get(start) == Some(&b'-');
        self.i += neg as usize;
        let mut m = 0u64;
        // Integer parts are mostly a digit or two: one at a time.
        let int = self.short_digits(&mut m);
        // No leading zeros (JSON), at least one digit.
        if int == 0 || (int > 1 && b[self.i - int] == b'0') {
            return None;
        }
        let mut frac = 0;
        if b.get(self.i) == Some(&b'.') {
            self.i += 1;
            frac = self.digits(&mut m);
            if frac == 0 {
                return None;
            }
        }
        let mut exp = 0i64;
        if matches!(b.get(self.i), Some(b'e' | b'E')) {
            self.i += 1;
            let eneg = b.get(self.i) == Some(&b'-');
            self.i += matches!(b.get(self.i), Some(b'+' | b'-')) as usize;
            let mut e = 0u64;
            let n = self.short_digits(&mut e);
            if n == 0 {
                return None;
            }
            // More than 18 exponent digits may have wrapped: leave them to `str::parse`.
            exp = if n > 18 {
                i64::MAX
            } else if eneg {
                -(e as i64)
            } else {
                e as i64
            };
        }
        // Clinger's fast path: 19 digits cannot wrap a u64 (10^19 < 2^64); m <= 2^53 and
        // 10^|e| <= 10^22 are exact f64s, so one correctly rounded operation gives the
        // correctly rounded value of m × 10^e.
        let e = exp.saturating_sub(frac as i64);
        if int + frac <= 19 && m <= 1 << 53 && (-22..=22).contains(&e) {
            let x = m as f64;
            let v = if e >= 0 {
                x * POW10[e as usize]
            } else {
                x / POW10[(-e) as usize]
            };
            return Some(if neg { -v } else { v });
        }
        if int + frac <= 19
            && (-22..=0).contains(&e)
            && let Some(v) = nearest(m, (-e) as usize)
        {
            return Some(if neg { -v } else { v });
        }
        // ASCII from `start` to `self.i`.
        let x: f64 = std::str::from_utf8(&b[start..self.i]).ok()?.parse().ok()?;
        x.is_finite().then_some(x)
    }

    /// `[x, y, z]`.
    #[inline(always)]
    fn vec3(&mut self) -> Option<[f64; 3]> {
        self.expect(b'[')?;
        let x = self.number()?;
        self.expect(b',')?;
        let y = self.number()?;
        self.expect(b',')?;
        let z = self.number()?;
        self.expect(b']')?;
        Some([x, y, z])
    }

    /// An unsigned integer that fits a u32 (what `serde_json` accepts for one).
    #[inline(always)]
    fn uint(&mut self) -> Option<u32> {
        self.ws();
        let start = self.i;
        let mut v = 0u64;
        let n = self.short_digits(&mut v);
        if n == 0 || (n > 1 && self.b[start] == b'0') || n > 10 {
            return None;
        }
        // A fraction or exponent makes it a float, which a u32 field rejects.
        if matches!(self.b.get(self.i), Some(b'.' | b'e' | b'E')) {
            return None;
        }
        u32::try_from(v).ok()
    }

    /// `true` or `false`.
    #[inline(always)]
    fn bool(&mut self) -> Option<bool> {
        self.ws();
        let rest = &self.b[self.i..];
        let (v, n) = if rest.starts_with(b"true") {
            (true, 4)
        } else if rest.starts_with(b"false") {
            (false, 5)
        } else {
            return None;
        };
        self.i += n;
        Some(v)
    }

    /// One cylinder object.
    #[inline(always)]
    fn cylinder(&mut self) -> Option<CylinderFile> {
        self.expect(b'{')?;
        let mut c = CylinderFile {
            caps: true,
            ..CylinderFile::default()
        };
        let (mut seen, mut radius) = (0u32, None);
        loop {
            let key = self.cylinder_key()?;
            let bit = match key {
                b"p0" => {
                    c.p0 = Some(self.vec3()?);
                    1
                }
                b"p1" => {
                    c.p1 = Some(self.vec3()?);
                    2
                }
                b"center" => {
                    c.center = Some(self.vec3()?);
                    4
                }
                b"axis" => {
                    c.axis = Some(self.vec3()?);
                    8
                }
                b"height" => {
                    c.height = Some(self.number()?);
                    16
                }
                b"radius" => {
                    radius = Some(self.number()?);
                    32
                }
                b"caps" => {
                    c.caps = self.bool()?;
                    64
                }
                b"id" => {
                    c.id = Some(self.uint()?);
                    128
                }
                _ => return None,
            };
            if seen & bit != 0 {
                return None; // a repeated key: serde_json reports it
            }
            seen |= bit;
            match self.next()? {
                b',' => continue,
                b'}' => break,
                _ => return None,
            }
        }
        c.radius = radius?;
        Some(c)
    }
}

/// The f64 nearest to `m / 10^k` (ties to even), for the 17-digit numbers that are too
/// long for Clinger's path (what `generate` writes), or `None` when the exact test below
/// would not fit 128 bits (`str::parse` then decides).
///
/// `m as f64 / 10^k` rounds twice, so it is within about one ulp of the answer: that
/// candidate and its neighbours are tested exactly. A positive double `c = M·2^E`
/// (2^52 <= M < 2^53) is the nearest to `v` when `v` lies between the midpoints to its
/// neighbours, `(2M+1)·2^(E-1)` above and `(2M-1)·2^(E-1)` below (`(4M-1)·2^(E-2)` when
/// `M = 2^52`, whose lower neighbour is half as far), and on a midpoint when `M` is even.
/// Each comparison of `v = m / 10^k` with `X·2^F` (F < 0) is one of integers,
/// `m·2^-F` against `X·10^k`, both below 2^128 for `k <= 22`, checked.
fn nearest(m: u64, k: usize) -> Option<f64> {
    use std::cmp::Ordering;
    if m == 0 {
        return Some(0.0);
    }
    let ten_k = 10u128.pow(k as u32);
    // How `v` compares with `x·2^f`.
    let cmp = |x: u128, f: i32| -> Option<Ordering> {
        if f >= 0 {
            let right = x.checked_mul(ten_k)?.checked_shl(f as u32)?;
            let right_back = right.checked_shr(f as u32)?;
            (right_back == x * ten_k).then(|| (m as u128).cmp(&right))
        } else {
            let s = (-f) as u32;
            if s >= 128 || (m as u128).leading_zeros() < s {
                return None;
            }
            Some(((m as u128) << s).cmp(&x.checked_mul(ten_k)?))
        }
    };
    let mut c = m as f64 / POW10[k];
    for _ in 0..4 {
        if !c.is_normal() {
            return None;
        }
        let bits = c.to_bits();
        let big_m = (bits & ((1 << 52) - 1)) | (1 << 52);
        let e = ((bits >> 52) & 0x7ff) as i32 - 1075;
        let even = big_m.is_multiple_of(2);
        let up = cmp(2 * big_m as u128 + 1, e - 1)?;
        if up == Ordering::Greater || (up == Ordering::Equal && !even) {
            c = c.next_up();
            continue;
        }
        let down = if big_m == 1 << 52 {
            cmp(4 * big_m as u128 - 1, e - 2)?
        } else {
            cmp(2 * big_m as u128 - 1, e - 1)?
        };
        if down == Ordering::Less || (down == Ordering::Equal && !even) {
            c = c.next_down();
            continue;
        }
        return Some(c);
    }
    None
}

/// Whether the eight bytes of `v` (little-endian) are all ASCII digits: a byte below `0`
/// wraps when `0` is subtracted, one above `9` carries into its top bit when 0x46 is added.
#[inline(always)]
fn eight_digits(v: u64) -> bool {
    let below = v.wrapping_sub(0x3030_3030_3030_3030);
    let above = v.wrapping_add(0x4646_4646_4646_4646);
    (below | above) & 0x8080_8080_8080_8080 == 0
}

/// The value of eight ASCII digits, the first in the lowest byte: pairs, then fours, then
/// all eight are combined by multiplications whose partial products do not overlap (the
/// method Rust's own float parser uses).
#[inline(always)]
fn parse_eight(v: u64) -> u64 {
    const MASK: u64 = 0x0000_00FF_0000_00FF;
    const MUL1: u64 = 0x000F_4240_0000_0064; // 100 + (1 000 000 << 32)
    const MUL2: u64 = 0x0000_2710_0000_0001; // 1 + (10 000 << 32)
    let v = v - 0x3030_3030_3030_3030;
    let v = v * 10 + (v >> 8); // each byte pair: 10 × first + second
    ((v & MASK).wrapping_mul(MUL1) + ((v >> 16) & MASK).wrapping_mul(MUL2)) >> 32
}

/// The position after `}` at `k` and any whitespace.
#[inline(always)]
fn after_brace(b: &[u8], k: usize) -> usize {
    let mut j = k + 1;
    while j < b.len() && matches!(b[j], b' ' | b'\n' | b'\r' | b'\t') {
        j += 1;
    }
    j
}

/// What became of one run of the cylinder list.
enum Run {
    /// Every cylinder read and valid.
    Valid,
    /// Every cylinder read; why the first invalid one is.
    Invalid(SceneError),
}

/// Read the cylinders of `b[from..to]` (objects separated by commas) into `out`, validated,
/// `first` being the file index of the first: `None` on anything this reader does not
/// handle, or when the run does not hold exactly `out.len()` cylinders.
fn read_run(b: &[u8], from: usize, to: usize, first: usize, out: &mut [Cylinder]) -> Option<Run> {
    let mut p = Cursor {
        b: &b[..to],
        i: from,
    };
    let mut run = Run::Valid;
    let mut slots = out.iter_mut().enumerate();
    loop {
        let c = p.cylinder()?;
        let (k, slot) = slots.next()?;
        if let Run::Valid = run {
            match c.validate(first + k) {
                Ok(y) => *slot = y,
                Err(e) => run = Run::Invalid(e),
            }
        }
        match p.next() {
            Some(b',') => continue,
            None => break,
            Some(_) => return None,
        }
    }
    slots.next().is_none().then_some(run)
}

/// The cylinder array starting at `start`, validated, and the position after it. The
/// array is cut into runs of objects at `}` bytes followed by `,` (no cylinder object holds
/// a `}` but its last; if a key string did, that run fails to parse and so does the whole
/// file), and the runs are read in parallel.
fn cylinder_list(b: &[u8], start: usize) -> Option<(Result<Vec<Cylinder>, SceneError>, usize)> {
    let mut p = Cursor { b, i: start };
    p.expect(b'[')?;
    p.ws();
    if b.get(p.i) == Some(&b']') {
        return Some((Ok(Vec::new()), p.i + 1));
    }
    // Runs about 64 KiB long, each cut at a `,` that follows a `}`: from a point 64 KiB
    // on, the next `}` ends a cylinder. The array ends at a `}` that a `]` follows; the
    // last run is searched for it from its start. (A jump past the array's end into a
    // later key could cut at the wrong place: that run then fails, and so serde_json
    // reads the file.)
    const RUN: usize = 1 << 16;
    let body = p.i;
    let mut runs = Vec::new();
    let (mut from, mut k) = (body, body + RUN);
    let end = loop {
        let next = b.get(k..).and_then(|r| r.iter().position(|&c| c == b'}'));
        let Some(off) = next else {
            // The rest is one run: find the array's end in it.
            let mut k = from;
            loop {
                let off = b[k..].iter().position(|&c| c == b'}')?;
                let j = after_brace(b, k + off);
                if b.get(j) == Some(&b']') {
                    runs.push((from, j));
                    break;
                }
                k = j;
            }
            break runs.last()?.1;
        };
        let j = after_brace(b, k + off);
        match b.get(j) {
            Some(b',') => {
                runs.push((from, j));
                from = j + 1;
                k = from + RUN;
            }
            Some(b']') => {
                runs.push((from, j));
                break j;
            }
            _ => k = j,
        }
    };
    // Every cylinder holds one `{` (one in a key string fails the read): so many are
    // counted in each run, the scene's list is made that long, and each run validates
    // its cylinders straight into its part of it, in parallel.
    let counts: Vec<usize> = runs
        .par_iter()
        .map(|&(from, to)| count_braces(&b[from..to]))
        .collect();
    let total: usize = counts.iter().sum();
    // Ids are u32; a file within the size limit cannot hold 2^32 cylinders, but if it
    // did, the serde_json path reports it.
    u32::try_from(total).ok()?;
    let mut list = Vec::with_capacity(total);
    crate::mem::huge_pages(&list);
    list.par_extend(rayon::iter::repeat_n(UNREAD, total));
    let mut parts = Vec::with_capacity(runs.len());
    let (mut rest, mut first) = (list.as_mut_slice(), 0);
    for (&run, &n) in runs.iter().zip(&counts) {
        let (part, tail) = rest.split_at_mut(n);
        parts.push((run, first, part));
        (rest, first) = (tail, first + n);
    }
    let read: Vec<Option<Run>> = parts
        .into_par_iter()
        .map(|((from, to), first, part)| read_run(b, from, to, first, part))
        .collect();
    // Every run must read; then the first invalid cylinder, in file order, is the error.
    let mut invalid = None;
    for r in read {
        if let (Run::Invalid(e), None) = (r?, &invalid) {
            invalid = Some(e);
        }
    }
    Some((invalid.map_or(Ok(list), Err), end + 1))
}

/// How many `{` bytes `b` holds, eight bytes at a time: a byte of `v ^ 0x7b…` is zero
/// exactly where `v` has a `{`, and a byte `x` is zero exactly when neither its top bit
/// nor the carry out of `(x & 0x7f) + 0x7f` (which cannot reach the next byte) is set.
fn count_braces(b: &[u8]) -> usize {
    const LOW7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    let chunks = b.chunks_exact(8);
    let tail = chunks.remainder().iter().filter(|&&c| c == b'{').count();
    chunks.fold(tail, |n, c| {
        let mut eight = [0; 8];
        eight.copy_from_slice(c);
        let x = u64::from_le_bytes(eight) ^ 0x7b7b_7b7b_7b7b_7b7b;
        let nonzero = ((x & LOW7) + LOW7) | x;
        n + (!nonzero & !LOW7).count_ones() as usize
    })
}

/// What a slot of the list holds until its cylinder is read (each slot is overwritten, or
/// the list dropped).
const UNREAD: Cylinder = Cylinder {
    base: glam::DVec3::ZERO,
    axis: glam::DVec3::Z,
    height: 0.0,
    radius: 0.0,
    caps: false,
    id: 0,
};

/// The end of the JSON value starting at `i` (after whitespace): objects and arrays by
/// bracket depth, strings with their escapes, anything else up to a delimiter. Only cuts
/// the text: `serde_json` then parses (and checks) the value.
fn skip_value(b: &[u8], mut i: usize) -> Option<usize> {
    let mut depth = 0usize;
    loop {
        let c = *b.get(i)?;
        match c {
            b'"' => {
                i += 1;
                loop {
                    match *b.get(i)? {
                        b'\\' => i += 2,
                        b'"' => break,
                        _ => i += 1,
                    }
                }
            }
            b'{' | b'[' => depth += 1,
            b'}' | b']' => {
                if depth == 0 {
                    return Some(i);
                }
                depth -= 1;
            }
            b',' if depth == 0 => return Some(i),
            _ => {}
        }
        i += 1;
        if depth == 0 && matches!(c, b'"' | b'}' | b']') {
            return Some(i);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Scene, SceneFile};

    /// What `serde_json` and validation make of `text` (`None`: serde_json rejects it).
    fn serde(text: &str) -> Option<Result<Scene, SceneError>> {
        serde_json::from_str::<SceneFile>(text)
            .ok()
            .map(|f| f.validate())
    }

    /// What the fast reader and validation make of `text` (`None`: left to serde_json).
    fn fast(text: &str) -> Option<Result<Scene, SceneError>> {
        scene_file(text.as_bytes()).map(|f| f.validate())
    }

    fn same(a: &Result<Scene, SceneError>, b: &Result<Scene, SceneError>) -> bool {
        // The derived Debug form shows every field, f64s to the last bit (shortest
        // round-trip form), and every error's field and message.
        format!("{a:?}") == format!("{b:?}")
    }

    const CAM: &str = r#""camera": {"origin": [0, 0, 0], "target": [0, 0, 1], "up": [0, 1, 0], "fov_deg": 40, "width": 4, "height": 4}"#;

    /// Every committed scene and generated ones read the same through both parsers.
    #[test]
    fn committed_and_generated_scenes_read_as_serde_json_reads_them() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
        let mut texts = Vec::new();
        for sub in [dir.clone(), dir.join("stress")] {
            for e in std::fs::read_dir(sub).unwrap() {
                let path = e.unwrap().path();
                if path.extension().is_some_and(|x| x == "json") {
                    texts.push(std::fs::read_to_string(&path).unwrap());
                }
            }
        }
        let sc = crate::bench::dense_scene(20_000, 4, 64, 48);
        texts.push(serde_json::to_string(&SceneFile::from_scene(&sc)).unwrap());
        texts.push(serde_json::to_string_pretty(&SceneFile::from_scene(&sc)).unwrap());
        let mut fast_count = 0;
        for t in &texts {
            let reference = serde(t).expect("committed scenes parse");
            if let Some(f) = fast(t) {
                assert!(
                    same(&f, &reference),
                    "differs on {}",
                    &t[..t.len().min(200)]
                );
                fast_count += 1;
            }
        }
        // The generated ones (and the plain committed ones) take the fast path.
        assert!(
            fast_count >= 10,
            "{fast_count} of {} read fast",
            texts.len()
        );
    }

    /// A list of many runs: cylinders without ids are numbered by their place in the
    /// whole file, and the first invalid cylinder is named by it, as serde_json's path
    /// does; a syntax error after an invalid cylinder is left to serde_json.
    #[test]
    fn ids_and_errors_count_across_runs() {
        let sc = crate::bench::dense_scene(5_000, 9, 8, 8);
        let mut file = SceneFile::from_scene(&sc);
        for c in &mut file.cylinders {
            c.id = None;
        }
        let text = serde_json::to_string(&file).unwrap();
        assert!(text.len() > 8 << 16, "several runs");
        let f = fast(&text).expect("plain");
        assert!(same(&f, &serde(&text).unwrap()));
        let ids: Vec<u32> = f.unwrap().cylinders.iter().map(|c| c.id).collect();
        assert_eq!(ids, (1..=5_000).collect::<Vec<u32>>());

        for k in [0, 3_700, 4_999] {
            let mut bad = file.clone();
            bad.cylinders[k].radius = -1.0;
            let later = (k + 2_000).min(4_999);
            if later != k {
                bad.cylinders[later].radius = -2.0;
            }
            let text = serde_json::to_string(&bad).unwrap();
            let e = fast(&text).expect("plain").unwrap_err();
            assert_eq!(
                e.to_string(),
                format!("cylinders[{k}].radius: must be > 0 and <= 1e12, got -1")
            );
            assert!(same(&Err(e), &serde(&text).unwrap()));
            // A camera error comes before any cylinder's.
            let mut cam = bad.clone();
            cam.camera.as_mut().unwrap().fov_deg = 200.0;
            let e = fast(&serde_json::to_string(&cam).unwrap())
                .unwrap()
                .unwrap_err();
            assert_eq!(e.field, "camera.fov_deg");
            // A syntax error anywhere is serde_json's to report.
            let broken = text.replacen("\"radius\":0.", "\"radius\":0..", 1);
            assert_ne!(broken, text);
            assert!(fast(&broken).is_none());
        }
    }

    /// Numbers in cylinder fields that are hard to round, in every JSON form, give
    /// serde_json's bits.
    #[test]
    fn numbers_round_as_serde_json_rounds_them() {
        for n in HARD {
            let text = format!(
                r#"{{{CAM}, "cylinders": [{{"p0": [{n}, 1, 2], "p1": [0, 0, {n}], "radius": {n}}}]}}"#
            );
            let (f, s) = (fast(&text).expect(n), serde(&text).unwrap());
            assert!(same(&f, &s), "{n}");
        }
    }

    const HARD: [&str; 33] = [
        "0",
        "-0",
        "1",
        "0.1",
        "2.2250738585072011e-308",
        "4.9e-324",
        "1e-400",
        "1.7976931348623157e308",
        "9007199254740993",
        "9007199254740995",
        "9007199254740992",
        "4503599627370496.5",
        "4503599627370497.5",
        "0.1000000000000000055511151231257827",
        "0.10000000000000001",
        "12345678901234567e-22",
        "1.2345678901234567e-5",
        "9007199254740991.5",
        "0.30000000000000004",
        "123456789012345678901234567890",
        "1E5",
        "1e+5",
        "-1.5e-7",
        "1e22",
        "1e23",
        "1e-22",
        "1e-23",
        "9999999999999999999",
        "18446744073709551616e-10",
        "2.00000000000000011102230246251565404236316680908203125",
        "0.000000000000000000000000000000000000000000001",
        "1e0000000000000000000000000000000000000001",
        "1e-99999999999999999999",
    ];

    /// The number reader alone against serde_json: the hard cases, and a million random
    /// ones on both sides of every limit of the fast path (digit count, 2^53, 10^22).
    #[test]
    fn every_number_rounds_as_serde_json_rounds_it() {
        let check = |n: &str| {
            let mut c = Cursor {
                b: n.as_bytes(),
                i: 0,
            };
            let got = c.number();
            let want = serde_json::from_str::<f64>(n)
                .ok()
                .filter(|x| x.is_finite());
            assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "{n}");
            if got.is_some() {
                assert_eq!(c.i, n.len(), "{n}");
            }
        };
        for n in HARD {
            check(n);
        }
        let mut rng = crate::rng::SplitMix64::new(17);
        let mut fast_path = 0;
        for k in 0..1_000_000u32 {
            let r = rng.next_u64();
            let n = match k % 4 {
                // Any finite double, shortest and long forms.
                0 => {
                    let x = f64::from_bits(r);
                    if !x.is_finite() {
                        continue;
                    }
                    if r & 1 == 0 {
                        format!("{x:e}")
                    } else {
                        format!("{x:.*e}", (r >> 58) as usize)
                    }
                }
                // Up to 22 digits with a point somewhere and an exponent near the limits.
                _ => {
                    let digits = 1 + (r % 22) as usize;
                    let mut s = String::new();
                    if r >> 63 == 1 {
                        s.push('-');
                    }
                    let mut d = rng.next_u64();
                    for j in 0..digits {
                        let c = (d % 10) as u8;
                        d /= 10;
                        if d == 0 {
                            d = rng.next_u64();
                        }
                        s.push(char::from(
                            b'0' + if j == 0 && digits > 1 { c.max(1) } else { c },
                        ));
                    }
                    let point = (r >> 8) as usize % (digits + 1);
                    if point > 0 && point < digits {
                        s.insert(s.len() - digits + point, '.');
                    }
                    if (r >> 16) & 3 != 0 {
                        let e = ((r >> 20) % 61) as i64 - 30;
                        s.push_str(&format!("e{e}"));
                    }
                    let m: u64 = s
                        .trim_start_matches('-')
                        .split(['e', '.'])
                        .take(2)
                        .collect::<String>()
                        .parse()
                        .unwrap_or(u64::MAX);
                    fast_path += (m <= 1 << 53) as u32;
                    s
                }
            };
            check(&n);
        }
        assert!(
            fast_path > 100_000,
            "{fast_path} numbers within the fast path"
        );

        // What `generate` writes: shortest forms of doubles of every size near 1.
        let mut exact_test = 0;
        for _ in 0..300_000 {
            let r = rng.next_u64();
            let x = f64::from_bits(r >> 12 | (((r % 40) + 1003) << 52));
            let n = format!("{x}");
            let digits = n.bytes().filter(u8::is_ascii_digit).count();
            exact_test += (digits > 16) as u32;
            check(&n);
            check(&format!("-{x:e}"));
        }
        assert!(exact_test > 100_000, "{exact_test} of 17 digits or more");
        // Midpoints between neighbouring doubles, exactly, and a last digit either side:
        // (2M + 1)·2^(E-1) for E = 0, -1, -2 has 17 to 19 digits, 1 - E of them after
        // the point.
        for _ in 0..100_000 {
            let big_m = (1u64 << 52) | (rng.next_u64() >> 12);
            let big_m = if rng.next_u64().is_multiple_of(8) {
                1 << 52
            } else {
                big_m
            };
            for after in 1..=3u32 {
                let tie = (2 * big_m as u128 + 1) * 5u128.pow(after);
                for t in [tie - 1, tie, tie + 1] {
                    let d = t.to_string();
                    let (head, tail) = d.split_at(d.len() - after as usize);
                    check(&format!("{head}.{tail}"));
                }
                // The lower midpoint of a power of two: (4M - 1)·2^(E-2).
                if big_m == 1 << 52 {
                    let tie = (4 * big_m as u128 - 1) * 5u128.pow(after + 1);
                    let d = tie.to_string();
                    let (head, tail) = d.split_at(d.len() - after as usize - 1);
                    check(&format!("{head}.{tail}"));
                }
            }
        }
    }

    /// Eight bytes are digits exactly when each is one (every byte value at every place),
    /// and their value is the decimal one.
    #[test]
    fn eight_digits_at_a_time() {
        for base in [*b"00000000", *b"99999999", *b"31415926"] {
            for at in 0..8 {
                for c in 0..=255u8 {
                    let mut b = base;
                    b[at] = c;
                    let v = u64::from_le_bytes(b);
                    assert_eq!(eight_digits(v), c.is_ascii_digit(), "{b:?}");
                    if c.is_ascii_digit() {
                        let want: u64 = std::str::from_utf8(&b).unwrap().parse().unwrap();
                        assert_eq!(parse_eight(v), want, "{b:?}");
                    }
                }
            }
        }
    }

    /// Braces are counted wherever they are: every byte value at every place of a
    /// chunk and of the tail, among braces or other bytes, and random mixes.
    #[test]
    fn braces_are_counted_exactly() {
        for fill in [b'{', b'x', 0x7b ^ 0x80, 0xff] {
            for at in 0..19 {
                for c in 0..=255u8 {
                    let mut b = [fill; 19];
                    b[at] = c;
                    let want = b.iter().filter(|&&c| c == b'{').count();
                    assert_eq!(count_braces(&b), want, "{b:?}");
                }
            }
        }
        let mut rng = crate::rng::SplitMix64::new(5);
        for len in 0..200 {
            let b: Vec<u8> = (0..len)
                .map(|_| match rng.next_u64() % 4 {
                    0 => b'{',
                    1 => b'{' ^ (1 << (rng.next_u64() % 8)),
                    _ => rng.next_u64() as u8,
                })
                .collect();
            let want = b.iter().filter(|&&c| c == b'{').count();
            assert_eq!(count_braces(&b), want, "{b:?}");
        }
    }

    /// What the fast reader does not handle it leaves to serde_json: the same files fail,
    /// or read the same.
    #[test]
    fn anything_unusual_is_left_to_serde_json() {
        let cam = CAM;
        let cyl = |c: &str| format!(r#"{{{cam}, "cylinders": [{c}]}}"#);
        let cases = [
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "radius": 2}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "colour": 2}"#),
            cyl(
                r#"{"p0": null, "center": [0, 0, 1], "axis": [0, 0, 1], "height": 1, "radius": 1}"#,
            ),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1e400}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 01}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": 1.0}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": 4294967296}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": 04}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": -1}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2]}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "r\u0061dius": 1}"#),
            cyl(r#"{"p0": [0, 0, 1, 4], "p1": [0, 0, 2], "radius": 1}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1},"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "caps": "yes"}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": -.5}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1.}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1e}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": +1}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "caps": false}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": 4294967295}"#),
            // Invalid values read fast, and fail validation as the serde_json path does.
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 1], "radius": 1, "id": 0}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": 0}"#),
            cyl(r#"{"center": [0, 0, 1], "axis": [0, 0, 0], "height": 1, "radius": 1}"#),
            format!(r#"{{{cam}, "cylinders": [], "cylinders": []}}"#),
            format!(r#"{{{cam}, "cylinders": [], "extra": 1}}"#),
            format!(r#"{{{cam}, "cylinders": []}} x"#),
            format!(r#"{{{cam}, "cylinders": [], "aovs": ["depth", "nope"]}}"#),
            format!(r#"{{{cam}, "cylinders": [], "aovs": null}}"#),
            format!(r#"{{{cam}, "cylinders": [], "aovs": ["depth"]}}"#),
            format!(r#"{{{cam}}}"#),
            // No camera: both read it (validation then asks for one).
            r#"{"cylinders": []}"#.to_string(),
            // Several cameras read fast; a positional camera is left to serde_json.
            format!(
                r#"{{"cameras": [{}], "cylinders": []}}"#,
                &cam["\"camera\": ".len()..]
            ),
            r#"{"cameras": [[[0, 0, 0], [0, 0, 1], [0, 1, 0], 40]], "cylinders": []}"#.to_string(),
        ];
        let mut fast_count = 0;
        for t in &cases {
            match (fast(t), serde(t)) {
                (Some(f), Some(s)) => {
                    assert!(same(&f, &s), "{t}");
                    fast_count += 1;
                }
                (Some(_), None) => panic!("read fast what serde_json rejects: {t}"),
                _ => {}
            }
        }
        assert_eq!(fast_count, 9, "the nine plain cases read fast");
    }

    /// Bytes that are not UTF-8 are never read fast (the caller's UTF-8 check reports
    /// them), wherever they are.
    #[test]
    fn bytes_that_are_not_utf8_are_left_to_the_caller() {
        let good = format!(
            r#"{{{CAM}, "cylinders": [{{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1}}], "aovs": ["depth"]}}"#
        );
        assert!(scene_file(good.as_bytes()).is_some());
        for at in ["\"fov_deg\"", "\"radius\"", "\"aovs\"", "\"depth\""] {
            let k = good.find(at).unwrap() + 2;
            let mut b = good.clone().into_bytes();
            b.insert(k, 0xff);
            assert!(scene_file(&b).is_none(), "{at}");
        }
    }
}
