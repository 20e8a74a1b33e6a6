//! A fast reader for well-formed scene files: the cylinder list parsed by hand, in
//! parallel, with correctly rounded numbers.
//!
//! A 100 000-cylinder scene is 15 MB of JSON, and `serde_json` (with path tracking for its
//! error messages) spent about as long reading it as the render took. This reader accepts
//! only what the file schema accepts, in its plain form: the top-level object's keys
//! `camera` or `cameras`, `cylinders` and `aovs`, each cylinder an object of the known keys with
//! numbers, arrays of three numbers, `true`/`false` and an unsigned integer `id`. Anything
//! else (an unknown or repeated key, `null`, an escaped key, a number out of range, a
//! syntax error) makes it give up, and the caller parses the text again with `serde_json`,
//! whose messages name the field. So a file either reads the same through both, or only
//! `serde_json` reads it, with today's errors.
//!
//! Numbers go through `str::parse::<f64>`, which is correctly rounded, as `serde_json`'s
//! `float_roundtrip` parsing is: both give the same bits for every number. The camera and
//! the AOV list are small and go through `serde_json` as they are.

use super::strict::Object;
use super::{CameraFile, CylinderFile, SceneFile};
use crate::scene::Aov;
use rayon::prelude::*;

/// The scene file in `text`, or `None` when it is not in the plain form this reader
/// handles (the caller then uses `serde_json`, which also reports any error).
pub fn scene_file(text: &str) -> Option<SceneFile> {
    let b = text.as_bytes();
    let mut p = Cursor { text, b, i: 0 };
    p.expect(b'{')?;
    let (mut camera, mut cameras, mut cylinders, mut aovs) = (None, None, None, None);
    loop {
        let key = p.key()?.to_vec();
        let start = p.i;
        match key.as_slice() {
            b"camera" if camera.is_none() => {
                let end = skip_value(b, start)?;
                // Through `strict::Object`: a camera must be an object, as in the schema.
                let c = serde_json::from_str::<Object<CameraFile>>(&text[start..end]).ok()?;
                camera = Some(c.0);
                p.i = end;
            }
            b"cameras" if cameras.is_none() => {
                let end = skip_value(b, start)?;
                let list =
                    serde_json::from_str::<Vec<Object<CameraFile>>>(&text[start..end]).ok()?;
                cameras = Some(list.into_iter().map(|c| c.0).collect());
                p.i = end;
            }
            b"aovs" if aovs.is_none() => {
                let end = skip_value(b, start)?;
                aovs = Some(serde_json::from_str::<Option<Vec<Aov>>>(&text[start..end]).ok()?);
                p.i = end;
            }
            b"cylinders" if cylinders.is_none() => {
                let (list, end) = cylinder_list(text, start)?;
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
    Some(SceneFile {
        camera,
        cameras,
        cylinders: cylinders?,
        aovs: aovs.flatten(),
    })
}

/// A position in the text.
struct Cursor<'a> {
    text: &'a str,
    b: &'a [u8],
    i: usize,
}

impl Cursor<'_> {
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
    fn key(&mut self) -> Option<&[u8]> {
        self.expect(b'"')?;
        let start = self.i;
        let len = self.b[start..].iter().position(|&c| c == b'"')?;
        let name = &self.b[start..start + len];
        if name.contains(&b'\\') {
            return None;
        }
        self.i = start + len + 1;
        self.expect(b':')?;
        self.ws();
        Some(name)
    }

    /// A JSON number as an f64 (finite: an overflow is left to `serde_json`'s message).
    #[inline(always)]
    fn number(&mut self) -> Option<f64> {
        self.ws();
        let start = self.i;
        let b = self.b;
        let mut i = start;
        if b.get(i) == Some(&b'-') {
            i += 1;
        }
        let int = digits(b, &mut i);
        // No leading zeros (JSON), at least one digit.
        if int == 0 || (int > 1 && b[i - int] == b'0') {
            return None;
        }
        if b.get(i) == Some(&b'.') {
            i += 1;
            if digits(b, &mut i) == 0 {
                return None;
            }
        }
        if matches!(b.get(i), Some(b'e' | b'E')) {
            i += 1;
            if matches!(b.get(i), Some(b'+' | b'-')) {
                i += 1;
            }
            if digits(b, &mut i) == 0 {
                return None;
            }
        }
        // ASCII from `start` to `i`, so both are character boundaries.
        let x: f64 = self.text.get(start..i)?.parse().ok()?;
        self.i = i;
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
        let mut end = start;
        let n = digits(self.b, &mut end);
        if n == 0 || (n > 1 && self.b[start] == b'0') {
            return None;
        }
        // A fraction or exponent makes it a float, which a u32 field rejects.
        if matches!(self.b.get(start + n), Some(b'.' | b'e' | b'E')) {
            return None;
        }
        let v = self.text.get(start..start + n)?.parse().ok()?;
        self.i = start + n;
        Some(v)
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
    fn cylinder(&mut self) -> Option<CylinderFile> {
        self.expect(b'{')?;
        let mut c = CylinderFile {
            caps: true,
            ..CylinderFile::default()
        };
        let (mut seen, mut radius) = (0u32, None);
        loop {
            let key = self.key()?;
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

/// Advance `i` past ASCII digits; how many.
#[inline(always)]
fn digits(b: &[u8], i: &mut usize) -> usize {
    let start = *i;
    while *i < b.len() && b[*i].is_ascii_digit() {
        *i += 1;
    }
    *i - start
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

/// The cylinder array starting at `start`, and the position after it. The array is cut
/// into runs of objects at `}` bytes followed by `,` (no cylinder object holds a `}` but
/// its last; if a key string did, that run fails to parse and so does the whole file), and
/// the runs parse in parallel.
fn cylinder_list(text: &str, start: usize) -> Option<(Vec<CylinderFile>, usize)> {
    let b = text.as_bytes();
    let mut p = Cursor { text, b, i: start };
    p.expect(b'[')?;
    p.ws();
    if b.get(p.i) == Some(&b']') {
        return Some((Vec::new(), p.i + 1));
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
    let runs: Vec<Option<Vec<CylinderFile>>> = runs
        .into_par_iter()
        .map(|(from, to)| {
            let mut p = Cursor {
                text: text.get(..to)?,
                b: &b[..to],
                i: from,
            };
            let mut out = Vec::new();
            loop {
                out.push(p.cylinder()?);
                match p.next() {
                    Some(b',') => continue,
                    None => break,
                    Some(_) => return None,
                }
            }
            Some(out)
        })
        .collect();
    let mut list = Vec::new();
    for r in runs {
        list.extend(r?);
    }
    Some((list, end + 1))
}

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

    fn serde(text: &str) -> Option<SceneFile> {
        serde_json::from_str(text).ok()
    }

    fn same(a: &SceneFile, b: &SceneFile) -> bool {
        // The derived Debug form shows every field, f64s to the last bit (shortest
        // round-trip form).
        format!("{a:?}") == format!("{b:?}")
    }

    /// Every committed scene and a generated one read the same through both parsers.
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
        let mut fast = 0;
        for t in &texts {
            let reference = serde(t).expect("committed scenes parse");
            if let Some(f) = scene_file(t) {
                assert!(
                    same(&f, &reference),
                    "differs on {}",
                    &t[..t.len().min(200)]
                );
                fast += 1;
            }
        }
        // The generated ones (and the plain committed ones) take the fast path.
        assert!(fast >= 10, "{fast} of {} read fast", texts.len());
    }

    /// Numbers that are hard to round, in every JSON form, give serde_json's bits.
    #[test]
    fn numbers_round_as_serde_json_rounds_them() {
        let nums = [
            "0",
            "-0",
            "1",
            "0.1",
            "2.2250738585072011e-308",
            "4.9e-324",
            "1e-400",
            "1.7976931348623157e308",
            "9007199254740993",
            "0.30000000000000004",
            "123456789012345678901234567890",
            "1E5",
            "1e+5",
            "-1.5e-7",
            "2.00000000000000011102230246251565404236316680908203125",
            "0.000000000000000000000000000000000000000000001",
        ];
        for n in nums {
            let text = format!(
                r#"{{"camera": {{"origin": [0, 0, 0], "target": [0, 0, 1], "up": [0, 1, 0],
                    "fov_deg": 40, "width": 4, "height": 4}},
                  "cylinders": [{{"p0": [{n}, 1, 2], "p1": [0, 0, {n}], "radius": {n}}}]}}"#
            );
            let (f, s) = (scene_file(&text).expect(n), serde(&text).unwrap());
            assert!(same(&f, &s), "{n}");
        }
    }

    /// What the fast reader does not handle it leaves to serde_json: the same files fail,
    /// or read the same.
    #[test]
    fn anything_unusual_is_left_to_serde_json() {
        let cam = r#""camera": {"origin": [0, 0, 0], "target": [0, 0, 1], "up": [0, 1, 0], "fov_deg": 40, "width": 4, "height": 4}"#;
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
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": -1}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2]}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "r\u0061dius": 1}"#),
            cyl(r#"{"p0": [0, 0, 1, 4], "p1": [0, 0, 2], "radius": 1}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1},"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "caps": "yes"}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "caps": false}"#),
            cyl(r#"{"p0": [0, 0, 1], "p1": [0, 0, 2], "radius": 1, "id": 7}"#),
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
        let mut fast = 0;
        for t in &cases {
            match (scene_file(t), serde(t)) {
                (Some(f), Some(s)) => {
                    assert!(same(&f, &s), "{t}");
                    fast += 1;
                }
                (Some(_), None) => panic!("read fast what serde_json rejects: {t}"),
                _ => {}
            }
        }
        assert_eq!(fast, 6, "the six plain cases read fast");
    }
}
