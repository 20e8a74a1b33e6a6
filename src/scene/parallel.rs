//! Reading a plain scene file's cylinders on every core.
//!
//! `serde_json` reads a document on one thread, and at 100 000 cylinders nearly all of a
//! scene file's 18 MB is its `"cylinders"` array. [`load`] finds where the array starts
//! with a scan that follows strings, escapes and nesting (only up to the array: the camera
//! comes first in the files `generate` and `bench` write), then cuts the rest of the text
//! into chunks, one task each, and each task reads and validates the elements that start
//! in its chunk straight into [`Cylinder`]s (no list of [`CylinderFile`]s is held beside
//! the text), written to their place in the one list: a first pass counts each chunk's
//! `{` (in a valid array, its elements), which places the chunks, so the list is in file
//! order whatever the threads do. The rest of the file, the *skeleton* (the text with the
//! array written `[]`), is read with `serde_json` as before.
//!
//! It is a fast path only: it returns a scene or nothing. Whatever it does not accept (an
//! error anywhere, a key written with escapes, `"cylinders"` twice, a table reference) the
//! caller reads again the one-thread way, which names the field in its message; so every
//! message, and which of several errors is reported, stays what it was.
//!
//! Why a scene it returns is the one-thread read's, bit for bit, whatever the threads do:
//! - the start scan agrees with `serde_json` on every string's extent (a `"` opens and
//!   closes one, `\` takes the next byte with it) and so on the nesting; it takes the array
//!   only as the value of a key spelled exactly `"cylinders"` directly in the top-level
//!   object;
//! - a task starts at the first `{` of its chunk; in a valid array that opens an element (a
//!   [`CylinderFile`] nests no object, and its only strings are keys, whose raw bytes hold
//!   no brace: a key with one is an unknown field). Each element is read from its first
//!   byte by [`plain`] when it is written plainly (as `generate` and `bench` write them;
//!   its numbers correctly rounded, by Clinger's exact fast path where it applies, by
//!   integer arithmetic for up to 19 digits past it, else by `str::parse`, like
//!   `serde_json`'s with `float_roundtrip`; the unit tests hold it to `serde_json` on
//!   20 000 numbers and to `str::parse` on 400 000 and 10 000 exact ties), else by the same
//!   `serde_json` code as before ([`strict::Object`] of [`CylinderFile`]); either says
//!   where the element ends;
//! - the elements are then chained in text order: each must be followed by whitespace and
//!   a comma and whitespace and the next element's `{` (the first of the next chunk's, for
//!   a chunk's last), or by whitespace and the array's `]`. Elements that each read as a
//!   whole object, so joined, are exactly a JSON array of them (JSON's grammar composes),
//!   so a wrong guess in a task (a `{` inside a string of an invalid file) breaks the chain
//!   and the fast path gives up. So does a chunk before the array's end whose `{` are not
//!   all elements (which only an invalid file has): every place before the end is filled;
//! - the skeleton is the same text before the array and after it, so `serde_json`
//!   accepting it means it accepts the whole file with the same structure, and a second
//!   `"cylinders"` key (however spelled) is still its "duplicate field" error;
//! - validation is [`CylinderFile`]'s own; a cylinder without an `id` gets its 1-based
//!   index in the file, its chunk's place plus its rank there, which the chain confirms
//!   (every chunk before it full), as the one-thread read gives it.

use super::{Cylinder, CylinderFile, Scene, SceneFile, strict, validate_scene};
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// The scene in `bytes`, read with its cylinders in parallel; `None` when it is not a
/// plain, valid scene file (the caller reads it again for the message).
pub fn load(bytes: &[u8]) -> Option<Scene> {
    let (start, end, cylinders) = cylinders(bytes)?;
    let mut skeleton = Vec::with_capacity(bytes.len() - (end - start) + 2);
    skeleton.extend_from_slice(&bytes[..start]);
    skeleton.extend_from_slice(b"[]");
    skeleton.extend_from_slice(&bytes[end..]);
    let file = serde_json::from_slice::<strict::Object<SceneFile>>(&skeleton)
        .ok()?
        .0;
    validate_scene(&file.camera, &file.cameras, &file.aovs, || Ok(cylinders)).ok()
}

/// JSON's whitespace (RFC 8259: space, tab, line feed, carriage return).
fn is_ws(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | b'\r')
}

fn skip_ws(bytes: &[u8], mut i: usize) -> usize {
    while i < bytes.len() && is_ws(bytes[i]) {
        i += 1;
    }
    i
}

/// The index just past the string whose opening `"` is at `i`.
fn string_end(bytes: &[u8], mut i: usize) -> Option<usize> {
    i += 1;
    while i < bytes.len() {
        match bytes[i] {
            b'"' => return Some(i + 1),
            b'\\' => i += 2,
            _ => i += 1,
        }
    }
    None
}

/// The index just past the value starting at `i` (not whitespace): a string, an object or
/// array with everything nested in it, or a number or literal up to the next delimiter.
/// Only extents are found; `serde_json` judges the contents.
fn value_end(bytes: &[u8], i: usize) -> Option<usize> {
    match bytes.get(i)? {
        b'"' => string_end(bytes, i),
        b'{' | b'[' => nested_end(bytes, i),
        _ => {
            let mut j = i;
            while j < bytes.len() && !matches!(bytes[j], b',' | b'}' | b']') && !is_ws(bytes[j]) {
                j += 1;
            }
            (j > i).then_some(j)
        }
    }
}

/// The index just past the object or array whose opening bracket is at `i`. Brackets are
/// counted, not matched by kind: a span `serde_json` then accepts has them matched.
fn nested_end(bytes: &[u8], mut i: usize) -> Option<usize> {
    let mut depth = 0usize;
    while i < bytes.len() {
        match bytes[i] {
            b'"' => {
                i = string_end(bytes, i)?;
                continue;
            }
            b'{' | b'[' => depth += 1,
            b'}' | b']' => {
                depth -= 1;
                if depth == 0 {
                    return Some(i + 1);
                }
            }
            _ => {}
        }
        i += 1;
    }
    None
}

/// The top-level `"cylinders"` array's extent (its `[` to just past its `]`) and its
/// elements, read and validated; `None` for any other shape or any refusal.
fn cylinders(bytes: &[u8]) -> Option<(usize, usize, Vec<Cylinder>)> {
    let mut i = skip_ws(bytes, 0);
    if bytes.get(i) != Some(&b'{') {
        return None;
    }
    i += 1;
    loop {
        i = skip_ws(bytes, i);
        if bytes.get(i) != Some(&b'"') {
            return None;
        }
        let key_end = string_end(bytes, i)?;
        let key = &bytes[i..key_end];
        i = skip_ws(bytes, key_end);
        if bytes.get(i) != Some(&b':') {
            return None;
        }
        i = skip_ws(bytes, i + 1);
        if key == b"\"cylinders\"" {
            let (end, list) = array(bytes, i)?;
            return Some((i, end, list));
        }
        i = value_end(bytes, i)?;
        i = skip_ws(bytes, i);
        match bytes.get(i) {
            Some(b',') => i += 1,
            _ => return None,
        }
    }
}

/// Where a chunk's last element says the array goes on.
#[derive(Clone, Copy)]
enum Next {
    /// The next element's `{` is here.
    Element(usize),
    /// The array's `]` ends just before here.
    End(usize),
}

/// What one task read of its chunk.
enum Read {
    /// No `{` in the chunk.
    Empty,
    /// An element that does not read or validate, or something else than whitespace and a
    /// comma after one, or more elements than the chunk has `{`: fatal only if the chain
    /// reaches the chunk.
    Failed,
    /// The text position of the chunk's first `{`, how many elements from there on were
    /// written to the chunk's place, and what follows the last.
    Elements(usize, usize, Next),
}

/// The elements of the array whose `[` is at `i`, read and validated, and the index just
/// past its `]`.
fn array(bytes: &[u8], i: usize) -> Option<(usize, Vec<Cylinder>)> {
    if bytes.get(i) != Some(&b'[') {
        return None;
    }
    let first = skip_ws(bytes, i + 1);
    if bytes.get(first) == Some(&b']') {
        return Some((first + 1, Vec::new()));
    }
    // Chunks of the text from the first element on (what follows the array is small); a
    // few per thread, so one slow thread does not hold the rest up.
    let rest = bytes.len() - first;
    let size = rest.div_ceil(8 * rayon::current_num_threads()).max(1 << 16);
    let chunk = |k: usize| {
        let lo = first + k * size;
        (lo, (lo + size).min(bytes.len()))
    };
    // Each chunk's `{`: in a valid array, one per element that starts in it. Their sums
    // place each chunk's elements in the list, so every task writes its own straight to
    // their place (no per-chunk lists copied together after).
    let counts: Vec<usize> = (0..rest.div_ceil(size))
        .into_par_iter()
        .map(|k| {
            let (lo, hi) = chunk(k);
            count(&bytes[lo..hi], b'{')
        })
        .collect();
    let total = counts.iter().sum();
    let mut cylinders = Vec::with_capacity(total);
    crate::mem::huge_pages(&cylinders);
    let mut spare = &mut cylinders.spare_capacity_mut()[..total];
    let mut places = Vec::with_capacity(counts.len());
    let mut offset = 0;
    for &count in &counts {
        let (place, after) = spare.split_at_mut(count);
        places.push((offset, place));
        offset += count;
        spare = after;
    }
    let chunks: Vec<(usize, Read)> = places
        .into_par_iter()
        .enumerate()
        .map(|(k, (offset, place))| {
            let (lo, hi) = chunk(k);
            (offset, read_chunk(bytes, lo, hi, place, offset))
        })
        .collect();
    // The chain, in text order; chunks past the array's end are not looked at.
    let mut next = Next::Element(first);
    let mut len = 0;
    for ((offset, chunk), count) in chunks.into_iter().zip(counts) {
        let Next::Element(at) = next else { break };
        match chunk {
            Read::Empty => {}
            // Before the array's end, every `{` of a chunk opens an element: one read
            // otherwise would leave its place in the list a hole.
            Read::Elements(start, written, after)
                if start == at && (written == count || matches!(after, Next::End(_))) =>
            {
                len = offset + written;
                next = after;
            }
            _ => return None,
        }
    }
    let Next::End(end) = next else {
        return None;
    };
    // SAFETY: the chained chunks are consecutive, each filled its place from its start
    // (all of it but for the last, whose elements end the list), and `Empty` ones have
    // none: the first `len` elements were all written.
    unsafe { cylinders.set_len(len) };
    Some((end, cylinders))
}

/// How many bytes of `bytes` are `needle`. Counted in 64 one-byte lanes, added up every
/// 255 blocks (before a lane could wrap): whole-vector compares and adds, where
/// `filter().count()` widens every byte to a 64-bit sum. The block is a fixed-size array,
/// whose known length lets the compiler vectorize the loop (over slices it did not: 6×
/// slower).
fn count(bytes: &[u8], needle: u8) -> usize {
    const LANES: usize = 64;
    let mut total = 0;
    for group in bytes.chunks(LANES * 255) {
        let mut lanes = [0u8; LANES];
        let mut blocks = group.chunks_exact(LANES);
        for block in &mut blocks {
            let Some(block) = block.first_chunk::<LANES>() else {
                break;
            };
            for (lane, &b) in lanes.iter_mut().zip(block) {
                *lane += u8::from(b == needle);
            }
        }
        total += lanes.iter().map(|&n| usize::from(n)).sum::<usize>();
        total += blocks.remainder().iter().filter(|&&b| b == needle).count();
    }
    total
}

/// The elements that start in `bytes[lo..hi]`, the last one read to its end wherever that
/// is, written in order to `place`; the first is the file's element `offset` (0-based),
/// which names a cylinder without an `id`, as the one-thread read numbers it.
fn read_chunk(
    bytes: &[u8],
    lo: usize,
    hi: usize,
    place: &mut [MaybeUninit<Cylinder>],
    offset: usize,
) -> Read {
    let Some(first) = bytes[lo..hi].iter().position(|&b| b == b'{') else {
        return Read::Empty;
    };
    let first = lo + first;
    let mut at = first;
    // One element's fields at a time, filled in place.
    let mut file = CylinderFile::default();
    let mut written = 0;
    loop {
        let Some(end) = element(bytes, at, &mut file) else {
            return Read::Failed;
        };
        let (Ok(c), Some(slot)) = (file.validate(offset + written), place.get_mut(written)) else {
            return Read::Failed;
        };
        slot.write(c);
        written += 1;
        let after = skip_ws(bytes, end);
        let next = match bytes.get(after) {
            Some(b',') => {
                let open = skip_ws(bytes, after + 1);
                if bytes.get(open) != Some(&b'{') {
                    return Read::Failed;
                }
                Next::Element(open)
            }
            Some(b']') => Next::End(after + 1),
            _ => return Read::Failed,
        };
        match next {
            Next::Element(open) if open < hi => at = open,
            _ => return Read::Elements(first, written, next),
        }
    }
}

/// The element whose `{` is at `at`, read into `file`, and the index just past its `}`:
/// read by [`plain`] when it is written plainly, else by `serde_json` (which then also
/// says where it ended).
fn element(bytes: &[u8], at: usize, file: &mut CylinderFile) -> Option<usize> {
    if let Some(end) = plain(bytes, at, file) {
        return Some(end);
    }
    let mut stream = serde_json::Deserializer::from_slice(&bytes[at..])
        .into_iter::<strict::Object<CylinderFile>>();
    *file = stream.next()?.ok()?.0;
    Some(at + stream.byte_offset())
}

/// A cylinder object written plainly, as `generate` and `bench` write them: keys without
/// escapes, each once, vectors of three numbers, `radius` and `height` numbers, `caps` a
/// literal, `id` and `label` plain integers. `None` for anything else, which `serde_json`
/// then reads (and refuses with its message where it must).
///
/// What it returns is what `serde_json` gives for the same text: a number is correctly
/// rounded ([`number`]), as `serde_json` with `float_roundtrip` is (and
/// an integer it keeps as u64 or i64 converts to the nearest f64, the same value; `-0` is
/// -0.0 in both); a value out of f64's range (which `serde_json` refuses) is left to it.
///
/// The element whose `{` is at `at` goes into `file` (every field set); the return is the
/// index just past its `}`. Every byte it accepts is ASCII (whitespace, the keys, numbers,
/// literals, punctuation), so the text it reads needs no UTF-8 check.
fn plain(bytes: &[u8], at: usize, file: &mut CylinderFile) -> Option<usize> {
    *file = CylinderFile {
        caps: true,
        ..CylinderFile::default()
    };
    // Bit k: key k of KEYS seen (serde refuses a repeat; so does this, by giving up).
    const KEYS: [&[u8]; 9] = [
        b"p0", b"p1", b"center", b"axis", b"height", b"radius", b"caps", b"id", b"label",
    ];
    let mut seen = 0u32;
    let mut i = skip_ws(bytes, at + 1);
    if bytes.get(i) == Some(&b'}') {
        return None;
    }
    loop {
        if bytes.get(i) != Some(&b'"') {
            return None;
        }
        let close = i
            + 1
            + bytes
                .get(i + 1..)?
                .iter()
                .take(8)
                .position(|&b| b == b'"')?;
        let key = KEYS.iter().position(|k| *k == &bytes[i + 1..close])?;
        if seen & (1 << key) != 0 {
            return None;
        }
        seen |= 1 << key;
        i = skip_ws(bytes, close + 1);
        if bytes.get(i) != Some(&b':') {
            return None;
        }
        i = skip_ws(bytes, i + 1);
        match key {
            0..=3 => {
                let (v, next) = vec3(bytes, i)?;
                *[&mut file.p0, &mut file.p1, &mut file.center, &mut file.axis][key] = Some(v);
                i = next;
            }
            4 | 5 => {
                let (x, next) = number(bytes, i)?;
                if key == 4 {
                    file.height = Some(x);
                } else {
                    file.radius = x;
                }
                i = next;
            }
            6 => {
                let rest = bytes.get(i..)?;
                (file.caps, i) = if rest.starts_with(b"true") {
                    (true, i + 4)
                } else if rest.starts_with(b"false") {
                    (false, i + 5)
                } else {
                    return None;
                };
                if !bytes.get(i).is_some_and(|&b| is_delimiter(b)) {
                    return None;
                }
            }
            _ => {
                let (n, next) = integer(bytes, i)?;
                if key == 7 {
                    file.id = Some(n);
                } else {
                    file.label = n;
                }
                i = next;
            }
        }
        i = skip_ws(bytes, i);
        match bytes.get(i) {
            Some(b',') => i = skip_ws(bytes, i + 1),
            // `radius` has no default: without it serde refuses the element.
            Some(b'}') if seen & (1 << 5) != 0 => return Some(i + 1),
            _ => return None,
        }
    }
}

/// What may follow a number or literal in a valid text.
fn is_delimiter(b: u8) -> bool {
    is_ws(b) || matches!(b, b',' | b']' | b'}')
}

/// `[x, y, z]` at `i`, and the index past its `]`.
fn vec3(bytes: &[u8], mut i: usize) -> Option<([f64; 3], usize)> {
    if bytes.get(i) != Some(&b'[') {
        return None;
    }
    let mut v = [0.0; 3];
    for (k, x) in v.iter_mut().enumerate() {
        i = skip_ws(bytes, i + 1);
        (*x, i) = number(bytes, i)?;
        i = skip_ws(bytes, i);
        let want = if k == 2 { b']' } else { b',' };
        if bytes.get(i) != Some(&want) {
            return None;
        }
    }
    Some((v, i + 1))
}

/// A JSON number at `i` (`-?(0|[1-9][0-9]*)(.[0-9]+)?([eE][+-]?[0-9]+)?`), finite as an
/// f64, and the index past it. The scan that checks the grammar also gathers the digits
/// as one integer `m` and the power of ten `e` they are scaled by (`1.25e1` is 125·10⁻¹).
fn number(bytes: &[u8], i: usize) -> Option<(f64, usize)> {
    let neg = bytes.get(i) == Some(&b'-');
    let start = i + usize::from(neg);
    let mut m = 0u64;
    let mut j = match bytes.get(start)? {
        b'0' => start + 1,
        b'1'..=b'9' => digits(bytes, start, &mut m),
        _ => return None,
    };
    // Digits in `m`: past 19 it may have wrapped, and only `str::parse` reads the number.
    let mut count = j - start;
    let mut e = 0i64;
    if bytes.get(j) == Some(&b'.') {
        let end = digits(bytes, j + 1, &mut m);
        let fraction = end - (j + 1);
        if fraction == 0 {
            return None;
        }
        count += fraction;
        e = -(fraction as i64);
        j = end;
    }
    if matches!(bytes.get(j), Some(b'e' | b'E')) {
        j += 1;
        let minus = bytes.get(j) == Some(&b'-');
        j += usize::from(matches!(bytes.get(j), Some(b'+' | b'-')));
        let mut k = 0u64;
        let end = digits(bytes, j, &mut k);
        if end == j {
            return None;
        }
        // At most 18 digits fit an i64 unwrapped; a longer exponent is far past ±22.
        let k = if end - j <= 18 {
            k as i64
        } else {
            i64::MAX / 2
        };
        e += if minus { -k } else { k };
        j = end;
    }
    if !bytes.get(j).is_some_and(|&b| is_delimiter(b)) {
        return None;
    }
    // Clinger's fast path: `m` ≤ 2^53 is exact as an f64, and so is 10^|e| for |e| ≤ 22
    // (5^22 < 2^53); one IEEE multiplication or division of the two rounds the exact
    // m·10^e once, to nearest: the correctly rounded value `str::parse` gives. Its results
    // lie in [1e-22, 2^53·1e22] or are ±0, so never subnormal or infinite.
    if count <= 19 && m <= 1 << 53 && (-22..=22).contains(&e) {
        let x = m as f64;
        let x = if e >= 0 {
            x * POW10[e as usize]
        } else {
            x / POW10[(-e) as usize]
        };
        return Some((if neg { -x } else { x }, j));
    }
    if count <= 19
        && let Some(x) = exact_wide(m, e)
    {
        return Some((if neg { -x } else { x }, j));
    }
    // SAFETY: every byte of `i..j` is one the grammar above accepted (`-+.eE0-9`), ASCII,
    // so the bytes are UTF-8 (checking them again costs a twentieth of reading a scene).
    let text = unsafe { std::str::from_utf8_unchecked(&bytes[i..j]) };
    let x: f64 = text.parse().ok()?;
    // Subnormal results and underflows to zero are left to serde_json too: rare, and
    // where the two readers' handling is least alike in code (not in the value it must be).
    let underflow = x == 0.0 && text.bytes().any(|b| matches!(b, b'1'..=b'9'));
    (x.is_finite() && !x.is_subnormal() && !underflow).then_some((x, j))
}

/// m·10^e correctly rounded, for the digits Clinger's fast path leaves (m > 2^53, as the
/// 17 significant digits of a shortest round-trip f64 often are), done in integers:
/// - `0 ≤ e ≤ 22`: m·5^e < 2^64·2^52 is exact in a u128, whose conversion rounds once to
///   nearest-even; the 2^e after it is exact (the result is normal, below 2^139);
/// - `-19 ≤ e < 0`: m/10^-e by [`quotient_by_reciprocal`] where its product decides the
///   rounding, else by [`quotient_by_division`].
///
/// `None` elsewhere (a longer fraction, a larger exponent), which `str::parse` reads.
fn exact_wide(m: u64, e: i64) -> Option<f64> {
    match e {
        0..=22 => Some((u128::from(m) * u128::from(POW5[e as usize])) as f64 * pow2(e)),
        -19..=-1 if m != 0 => {
            let k = (-e) as usize;
            Some(quotient_by_reciprocal(m, k).unwrap_or_else(|| quotient_by_division(m, k)))
        }
        _ => None,
    }
}

/// 2^k as an f64, for k within the normal exponents.
fn pow2(k: i64) -> f64 {
    f64::from_bits(((1023 + k) as u64) << 52)
}

/// m/10^k correctly rounded, for 0 < m < 2^64 and 1 ≤ k ≤ 19: with m shifted up to its top
/// bit, N = m·2^(64+z) lies in [2^127, 2^128), and its quotient q by 10^k (< 2^64) is at
/// least 2^63.8: 64 bits or more. The remainder, non-zero or not, is or-ed into q's bit 0,
/// well below the bit that decides the rounding (bit 10 or higher), so converting q rounds
/// as the exact N/10^k would. The scaling by 2^-(64+z) is exact: the result is at least
/// 2^-64, normal.
fn quotient_by_division(m: u64, k: usize) -> f64 {
    let z = m.leading_zeros();
    let n = u128::from(m << z) << 64;
    let d = u128::from(POW10_INT[k]);
    let (q, r) = (n / d, n % d);
    (q | u128::from(r != 0)) as f64 * pow2(-64 - i64::from(z))
}

/// m/10^k correctly rounded, for 2^53 < m < 2^64 and 1 ≤ k ≤ 19, by one multiplication
/// (the division of [`quotient_by_division`] costs several times more), or `None` in the
/// rare cases where the product cannot decide (then the division does):
/// - M = m·2^z lies in [2^63, 2^64) and R = ⌊2^(127+b)/10^k⌋ (10^k in (2^(b-1), 2^b)) in
///   [2^127, 2^128). The exact E = M·2^(127+b)/10^k exceeds P = M·R by less than M < 2^64,
///   and m/10^k = E·2^-(127+b+z).
/// - When bits 64..128 of P are not all ones, adding that difference carries nothing
///   into H = P's top 64 bits, so H is E's; and when P's low 128 bits are not all zero,
///   neither are E's. Then everything below H's rounding bit is non-zero and not exactly a
///   half: the value rounds up exactly when that bit is set (no tie to break).
/// - H ≥ 2^62 (E ≥ 2^190), so its top 53 bits start at bit 63 or 62; rounded, they are the
///   significand, 2^53 at most (exact as an f64), scaled by a power of two exactly: the
///   result, above 2^53/10^19 > 2^-10, is normal.
fn quotient_by_reciprocal(m: u64, k: usize) -> Option<f64> {
    let (r, b) = RECIPROCALS[k];
    let z = m.leading_zeros();
    let mm = u128::from(m << z);
    // P = M·R in 192 bits: `high` is P >> 64, `low`'s low half P's low 64 bits.
    let low = mm * (r & u128::from(u64::MAX));
    let high = mm * (r >> 64) + (low >> 64);
    let (h, middle) = ((high >> 64) as u64, high as u64);
    if middle == u64::MAX || (middle == 0 && low as u64 == 0) {
        return None;
    }
    let shift = if h >> 63 == 1 { 11 } else { 10 };
    let significand = (h >> shift) + ((h >> (shift - 1)) & 1);
    Some(significand as f64 * pow2(shift + 1 - b - i64::from(z)))
}

/// For k in 1..=19: R = ⌊2^(127+b)/10^k⌋ and b, where 10^k lies in (2^(b-1), 2^b), so R
/// lies in [2^127, 2^128). Long division of a one followed by 127+b zeros, at compile time.
const RECIPROCALS: [(u128, i64); 20] = {
    let mut table = [(0u128, 0i64); 20];
    let mut k = 1;
    while k < 20 {
        let d = POW10_INT[k] as u128;
        let b = 128 - d.leading_zeros() as i64;
        let (mut rem, mut q, mut i) = (1u128, 0u128, 0);
        while i < 127 + b {
            rem *= 2;
            q = (q << 1) | (rem >= d) as u128;
            if rem >= d {
                rem -= d;
            }
            i += 1;
        }
        table[k] = (q, b);
        k += 1;
    }
    table
};

/// `base`^k for k in 0..N, at compile time (an overflow is a compile error).
const fn powers<const N: usize>(base: u64) -> [u64; N] {
    let mut p = [1u64; N];
    let mut k = 1;
    while k < N {
        p[k] = p[k - 1] * base;
        k += 1;
    }
    p
}

/// 5^k for k in 0..=22 (5^22 < 2^52).
const POW5: [u64; 23] = powers(5);

/// 10^k for k in 0..=19 (10^19 < 2^64).
const POW10_INT: [u64; 20] = powers(10);

/// 10^k for k in 0..=22, each exact as an f64.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// The index past the ASCII digits from `j` on, each appended to `m` (`m·10 + digit`,
/// wrapping: callers count the digits); eight at a time while eight follow.
fn digits(bytes: &[u8], mut j: usize, m: &mut u64) -> usize {
    while let Some(&eight) = bytes.get(j..).and_then(<[u8]>::first_chunk::<8>)
        && let Some(n) = eight_digits(u64::from_le_bytes(eight))
    {
        *m = m.wrapping_mul(100_000_000).wrapping_add(n);
        j += 8;
    }
    while let Some(&b) = bytes.get(j)
        && b.is_ascii_digit()
    {
        *m = m.wrapping_mul(10).wrapping_add(u64::from(b - b'0'));
        j += 1;
    }
    j
}

/// The value of eight ASCII digits read as one little-endian word (the first digit in the
/// low byte), or `None` if a byte is not a digit; in three multiplications rather than
/// eight (the SWAR form of Lemire's fast_float).
fn eight_digits(v: u64) -> Option<u64> {
    const NIBBLES: u64 = 0xF0F0_F0F0_F0F0_F0F0;
    const ZEROS: u64 = 0x3030_3030_3030_3030;
    // Each byte 0x30..=0x39: its high nibble 3, and still 3 with 6 added (no byte carries
    // into the next once every high nibble is 3).
    if v & NIBBLES != ZEROS || v.wrapping_add(0x0606_0606_0606_0606) & NIBBLES != ZEROS {
        return None;
    }
    let v = v - ZEROS;
    // Pairs of digits (10·first + second) in every other byte, then pairs of pairs,
    // gathered in the high half.
    let v = v.wrapping_mul(10) + (v >> 8);
    const MASK: u64 = 0x0000_00FF_0000_00FF;
    let v = (v & MASK)
        .wrapping_mul(100 + (1_000_000 << 32))
        .wrapping_add(((v >> 16) & MASK).wrapping_mul(1 + (10_000 << 32)));
    Some(v >> 32)
}

/// A non-negative JSON integer at `i` that fits a u32, and the index past it.
fn integer(bytes: &[u8], i: usize) -> Option<(u32, usize)> {
    let mut j = i;
    while bytes.get(j).is_some_and(u8::is_ascii_digit) {
        j += 1;
    }
    if j == i || (bytes[i] == b'0' && j > i + 1) || !bytes.get(j).is_some_and(|&b| is_delimiter(b))
    {
        return None;
    }
    let mut n = 0u64;
    for &b in &bytes[i..j] {
        n = n * 10 + u64::from(b - b'0');
        if n > u64::from(u32::MAX) {
            return None;
        }
    }
    Some((n as u32, j))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// What serde_json reads from `text`, one cylinder object.
    fn serde(text: &str) -> Option<CylinderFile> {
        serde_json::from_str::<strict::Object<CylinderFile>>(text)
            .ok()
            .map(|o| o.0)
    }

    fn same(a: &CylinderFile, b: &CylinderFile) -> bool {
        let bits = |v: Option<[f64; 3]>| v.map(|v| v.map(f64::to_bits));
        bits(a.p0) == bits(b.p0)
            && bits(a.p1) == bits(b.p1)
            && bits(a.center) == bits(b.center)
            && bits(a.axis) == bits(b.axis)
            && a.height.map(f64::to_bits) == b.height.map(f64::to_bits)
            && a.radius.to_bits() == b.radius.to_bits()
            && (a.caps, a.id, a.label) == (b.caps, b.id, b.label)
    }

    /// Every text the plain reader accepts, serde_json reads to the same bits and ends at
    /// the same byte; whatever serde_json refuses, the plain reader refuses.
    fn check(text: &str) -> bool {
        let mut a = CylinderFile::default();
        let mine = plain(text.as_bytes(), 0, &mut a);
        match (mine, serde(text)) {
            (Some(end), Some(b)) => {
                assert!(same(&a, &b), "{text}");
                assert_eq!(end, text.len(), "{text}");
                true
            }
            (Some(_), None) => panic!("plain reader accepts what serde_json refuses: {text}"),
            (None, _) => false,
        }
    }

    #[test]
    fn plain_numbers_are_serde_json_numbers() {
        let mut rng = SplitMix64::new(7);
        let mut accepted = 0;
        for k in 0..20_000 {
            // Shortest round-trip forms, long digit strings, integers, exponents, signs.
            let x = (rng.unit() - 0.5) * 10f64.powi((rng.unit() * 40.0) as i32 - 20);
            let lit = match k % 6 {
                0 => format!("{x:?}"),
                1 => format!("{x:.25}"),
                2 => format!("{}", (x * 1e6) as i64),
                3 => format!("{x:e}"),
                4 => format!("{:E}", x * 1e280),
                _ => format!("-{}", format!("{x:.3}").trim_start_matches('-')),
            };
            let text = format!(
                "{{ \"p0\": [{lit}, 0, -0], \"p1\":[1,2,{lit}],\n\"radius\" : {lit}, \"caps\": false, \"id\": {}, \"label\": 4294967295 }}",
                k + 1
            );
            accepted += check(&text) as usize;
        }
        assert!(accepted > 19_000, "{accepted}");
    }

    #[test]
    fn count_is_filter_count() {
        let mut rng = SplitMix64::new(5);
        let bytes: Vec<u8> = (0..40_000)
            .map(|_| b"{}a"[(rng.unit() * 3.0) as usize])
            .collect();
        for (lo, hi) in [(0, 0), (0, 63), (3, 16_320), (1, 16_321), (7, 40_000)] {
            let want = bytes[lo..hi].iter().filter(|&&b| b == b'{').count();
            assert_eq!(count(&bytes[lo..hi], b'{'), want, "{lo}..{hi}");
        }
    }

    /// `number` is `str::parse` at the edges of its fast path (2^53, 10^±22, 19 and 20
    /// digits, zeros) and on random digit strings and exponents about them.
    #[test]
    fn number_is_str_parse() {
        let same = |lit: &str| {
            let text = format!("{lit},");
            let (x, end) = number(text.as_bytes(), 0).expect(lit);
            assert_eq!(end, lit.len(), "{lit}");
            assert_eq!(x.to_bits(), lit.parse::<f64>().unwrap().to_bits(), "{lit}");
        };
        for lit in [
            "9007199254740992",
            "9007199254740993",
            "-9007199254740992e22",
            "9007199254740993e-22",
            "9007199254740991e-23",
            "1e22",
            "1e23",
            "1e-22",
            "1e-23",
            "1234567890123456789",
            "12345678901234567890",
            "1844674407370955161.5",
            "0.0000000000000000000001",
            "0.1",
            "-0",
            "-0.0e5",
            "0e22",
            "1.7976931348623157e308",
        ] {
            same(lit);
        }
        // Exact ties between two f64 (54 significant bits) written with 17 to 19 digits:
        // (2^53 + odd)·5^k / 10^k is halfway; so is it times 2^j written as an integer.
        let mut rng = SplitMix64::new(13);
        for _ in 0..2_000 {
            let odd = 2 * (rng.unit() * 1e6) as u64 + 1;
            for k in 1..=4u32 {
                let m = ((1u64 << 53) + odd) * 5u64.pow(k);
                let digits = m.to_string();
                let p = digits.len() - k as usize;
                same(&format!("{}.{}", &digits[..p], &digits[p..]));
            }
            same(&format!(
                "{}",
                ((1u64 << 53) + odd) << (rng.unit() * 10.0) as u32
            ));
        }
        // Shortest round-trip forms (17 digits about a third of the time), as scenes hold.
        for _ in 0..200_000 {
            let x = (rng.unit() - 0.5) * 10f64.powi((rng.unit() * 12.0) as i32 - 4);
            same(&format!("{x:?}"));
        }
        let mut rng = SplitMix64::new(11);
        for _ in 0..200_000 {
            let m = ((rng.unit() * 2f64.powi((rng.unit() * 64.0) as i32)) as u64).max(1);
            let e = (rng.unit() * 60.0) as i32 - 30;
            let digits = m.to_string();
            let point = (rng.unit() * digits.len() as f64) as usize;
            let lit = match (point, e % 3) {
                (0, _) => format!("{m}e{e}"),
                (p, 0) => format!("{}.{}", &digits[..p], &digits[p..]),
                (p, _) => format!("-{}.{}E{e:+}", &digits[..p], &digits[p..]),
            };
            same(&lit);
        }
    }

    /// The reciprocal path gives the division's bits wherever it decides, which is nearly
    /// always; where it declines (exact ties among them), the division reads the number.
    #[test]
    fn quotient_by_reciprocal_is_the_division() {
        let mut rng = SplitMix64::new(17);
        let (mut decided, mut declined) = (0, 0);
        for n in 0..400_000u64 {
            let m = match n % 4 {
                // Multiples of 5^k: quotients with short binary tails, and exact ties.
                0 => {
                    ((1u64 << 53) + 2 * (rng.unit() * 1e9) as u64 + 1) * 5u64.pow(1 + n as u32 % 8)
                }
                _ => (1u64 << 53) + (rng.unit() * (u64::MAX - (1 << 53)) as f64) as u64,
            };
            for k in [1 + (n % 19) as usize, 1 + (rng.unit() * 19.0) as usize] {
                let exact = quotient_by_division(m, k);
                assert_eq!(
                    exact.to_bits(),
                    format!("{m}e-{k}").parse::<f64>().unwrap().to_bits()
                );
                match quotient_by_reciprocal(m, k) {
                    Some(x) => {
                        assert_eq!(x.to_bits(), exact.to_bits(), "{m}e-{k}");
                        decided += 1;
                    }
                    None => declined += 1,
                }
            }
        }
        // A quarter of the cases are multiples of 5^k, whose quotients may end in zeros
        // or be exact ties: the ones it may decline (1.8% of all when measured).
        assert!(
            declined > 0 && decided > 780_000,
            "{decided} decided, {declined} declined"
        );
        // The table: R·10^k ≤ 2^(127+b) < (R+1)·10^k, R in [2^127, 2^128), 10^k in
        // (2^(b-1), 2^b); 256-bit numbers as (high, low) pairs, compared in that order.
        for (k, &(r, b)) in RECIPROCALS.iter().enumerate().skip(1) {
            let d = u128::from(POW10_INT[k]);
            assert!(r >> 127 == 1 && d < 1 << b && d > 1 << (b - 1), "{k}");
            let power = (1u128 << (127 + b - 128), 0u128);
            let below = wide_mul(r, d);
            let (lo, carry) = below.1.overflowing_add(d);
            let above = (below.0 + u128::from(carry), lo);
            assert!(below <= power && power < above, "{k}");
        }
    }

    /// The 256-bit product of two u128, as (high, low).
    fn wide_mul(a: u128, b: u128) -> (u128, u128) {
        let mask = u128::from(u64::MAX);
        let (a1, a0, b1, b0) = (a >> 64, a & mask, b >> 64, b & mask);
        let (p00, p01, p10, p11) = (a0 * b0, a0 * b1, a1 * b0, a1 * b1);
        let mid = (p00 >> 64) + (p01 & mask) + (p10 & mask);
        let low = (p00 & mask) | (mid << 64);
        let high = p11 + (p01 >> 64) + (p10 >> 64) + (mid >> 64);
        (high, low)
    }

    #[test]
    fn plain_refuses_what_it_does_not_read_as_serde_does() {
        for text in [
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"center":[1,2,3],"axis":[0,0,1],"height":2,"radius":0.5,"caps":true}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"radius":2}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4]}"#,
            r#"{"p0":[1,2,3,4],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1,2],"p1":[1,2,4],"radius":1}"#,
            r#"{"p\u0030":[1,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[01,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1.,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[.5,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1e400,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1e-400,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[5e-324,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"id":1.0}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"id":-1}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"id":4294967296}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"label":null}"#,
            r#"{"p0":null,"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"caps":1}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"caps":truex}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,"colour":2}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1,}"#,
            r#"{"p0":[1,2,3] "p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":1e5x}"#,
            r#"{"p0":[+1,2,3],"p1":[1,2,4],"radius":1}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":-0}"#,
            r#"{"p0":[1,2,3],"p1":[1,2,4],"radius":12345678901234567890123}"#,
            r#"{}"#,
        ] {
            check(text);
        }
    }

    /// The whole fast path against the one-thread read: chunks as small as the element
    /// count allows, elements with and without ids, odd whitespace.
    #[test]
    fn parallel_load_is_the_serde_json_load() {
        let mut rng = SplitMix64::new(3);
        let mut text = String::from(
            r#"{"camera":{"origin":[0,0,10],"target":[0,0,0],"up":[0,1,0],"fov_deg":40,"width":8,"height":6},"cylinders": [ "#,
        );
        for k in 0..3000 {
            if k > 0 {
                text.push_str(if k % 7 == 0 { " ,\n\t" } else { "," });
            }
            let (a, b, r) = (rng.unit(), rng.unit(), rng.unit() + 0.01);
            text.push_str(&match k % 3 {
                0 => format!(r#"{{"p0":[{a},{b},0],"p1":[{b},{a},1],"radius":{r},"id":{}}}"#, 5 * k + 1),
                1 => format!(r#"{{"center":[{a},{b},0],"axis":[0,{a},1],"height":{b},"radius":{r}, "label": 3}}"#),
                // Escaped key: serde_json reads it.
                _ => format!(r#"{{"p\u0030":[{a},{b},0],"p1":[{b},{a},1],"radius":{r},"caps":false}}"#),
            });
        }
        text.push_str("] , \"aovs\": [\"depth\"]}");
        let fast = load(text.as_bytes()).expect("fast path");
        let file = serde_json::from_str::<strict::Object<SceneFile>>(&text)
            .unwrap()
            .0;
        assert_eq!(fast, file.validate().unwrap());
        // A second "cylinders" key, an error in the last element, text after the object:
        // the fast path gives up.
        let twice = text.replacen("\"aovs\"", "\"cylinders\": [], \"aovs\"", 1);
        assert!(load(twice.as_bytes()).is_none());
        let bad = text.replacen("] , \"aovs\"", ",{\"radius\":1}] , \"aovs\"", 1);
        assert!(load(bad.as_bytes()).is_none());
        assert!(load(format!("{text} {{}}").as_bytes()).is_none());
        // The camera after the cylinders: the chunk where the array ends has `{` past it.
        let (camera, rest) = text[1..].split_once(",\"cylinders\"").unwrap();
        let (cylinders, aovs) = rest.split_once(" , ").unwrap();
        let moved = format!("{{\"cylinders\"{cylinders} , {camera}, {aovs}");
        let fast = load(moved.as_bytes()).expect("fast path, camera last");
        assert_eq!(fast, file.validate().unwrap());
    }
}
