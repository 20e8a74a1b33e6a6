//! A scan's points as files: LAS 1.4, binary PLY or NumPy `.npz`, chosen by the output's
//! extension. Each encoder returns the file's bytes; the command stages them
//! ([`crate::output::store::atomic`]). `docs/scan.md` lists the fields of each format.

use crate::npy::{self, Dtype};
use crate::scan::{Column, Scan};
use std::path::Path;

/// The point-file formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanFormat {
    /// ASPRS LAS 1.4, point format 6 with extra bytes.
    Las,
    /// Binary little-endian PLY.
    Ply,
    /// NumPy `.npz` (stored zip of `.npy`).
    Npz,
}

impl ScanFormat {
    /// The extensions accepted.
    pub const EXTENSIONS: &str = ".las, .ply, .npz";

    /// The format of `path` by its extension (any case), or an error naming it.
    pub fn of(path: &Path) -> Result<ScanFormat, String> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("las") => Ok(ScanFormat::Las),
            Some("ply") => Ok(ScanFormat::Ply),
            Some("npz") => Ok(ScanFormat::Npz),
            _ => Err(format!(
                "{}: unknown point-file extension; expected one of {}",
                path.display(),
                Self::EXTENSIONS
            )),
        }
    }

    /// The bytes of `scan` in this format; `comment` (one line) goes into the header
    /// where the format has one.
    pub fn encode(self, scan: &Scan, comment: &str) -> Result<Vec<u8>, String> {
        match self {
            ScanFormat::Las => las(scan),
            ScanFormat::Ply => Ok(ply(scan, comment)),
            ScanFormat::Npz => npz(scan),
        }
    }
}

/// The `.npz`: one `.npy` per column of [`Scan::columns`], shape `(N,)` or `(N, 3)`.
pub fn npz(scan: &Scan) -> Result<Vec<u8>, String> {
    let n = scan.len();
    let members: Vec<(String, Vec<u8>)> = scan
        .columns()
        .into_iter()
        .map(|(name, col)| {
            let bytes = match col {
                Column::F64(v) => npy::array(Dtype::F64, &[n], v),
                Column::U32(v) => npy::array(Dtype::U32, &[n], v),
                Column::F32x3(v) => npy::array(Dtype::F32, &[n, 3], v.as_flattened()),
            };
            (format!("{name}.npy"), bytes)
        })
        .collect();
    crate::output::format::npz::zip_stored(&members)
}

/// The binary little-endian PLY: `x y z` (double), `nx ny nz` (float), then the other
/// columns as properties of their own (double or uint).
pub fn ply(scan: &Scan, comment: &str) -> Vec<u8> {
    let comment: String = comment
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    let cols = scan.columns();
    let mut head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\n",
        scan.len()
    );
    for (name, col) in &cols {
        match col {
            Column::F64(_) => head += &format!("property double {name}\n"),
            Column::U32(_) => head += &format!("property uint {name}\n"),
            Column::F32x3(_) => head += "property float nx\nproperty float ny\nproperty float nz\n",
        }
    }
    head += "end_header\n";
    let mut out = head.into_bytes();
    out.reserve(scan.len() * 100);
    for i in 0..scan.len() {
        for (_, col) in &cols {
            match col {
                Column::F64(v) => out.extend_from_slice(&v[i].to_le_bytes()),
                Column::U32(v) => out.extend_from_slice(&v[i].to_le_bytes()),
                Column::F32x3(v) => {
                    for c in v[i] {
                        out.extend_from_slice(&c.to_le_bytes());
                    }
                }
            }
        }
    }
    out
}

/// The extra bytes of each LAS point, in order: `(name, LAS data type, size, description)`.
/// Data types (LAS 1.4 table 24): 3 = u16, 5 = u32, 9 = f32, 10 = f64. Names and
/// descriptions fit the descriptor's 32 bytes (a test checks).
const LAS_EXTRA: [(&str, u8, usize, &str); 10] = [
    ("ring", 3, 2, "beam sorted by elevation"),
    ("shape_id", 5, 4, "cylinder id"),
    ("part", 3, 2, "1 side out,2 in,3 bottom,4 top"),
    ("label", 5, 4, "cylinder label (unclipped)"),
    ("range", 10, 8, "range along the beam, noisy"),
    ("range_exact", 10, 8, "range without noise"),
    ("azimuth", 10, 8, "degrees, sensor axes"),
    ("normal_x", 9, 4, "world unit normal x"),
    ("normal_y", 9, 4, "world unit normal y"),
    ("normal_z", 9, 4, "world unit normal z"),
];

/// Whether every value of `v` (one axis of the points) fits LAS's 32-bit integer steps
/// under `t` (the `las` crate rounds `(value - offset) / scale` and refuses what falls
/// outside `i32`): at 0.1 mm steps about 429 km in all, centred on the offset.
fn check_las_span(axis: &str, v: &[f64], t: &las::Transform) -> Result<(), String> {
    let steps = |x: f64| ((x - t.offset) / t.scale).round();
    let fits = |x: f64| (f64::from(i32::MIN)..=f64::from(i32::MAX)).contains(&steps(x));
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    if v.is_empty() || (fits(lo) && fits(hi)) {
        return Ok(());
    }
    let most = (f64::from(i32::MAX) - f64::from(i32::MIN)) * t.scale;
    Err(format!(
        "LAS: the points span {lo} to {hi} along {axis} ({} world units); LAS stores a \
         coordinate as a 32-bit count of {} steps, {most:.0} world units at most: write \
         .npz or .ply instead",
        hi - lo,
        t.scale
    ))
}

/// The beam's elevation as the `las` crate's scan angle, which it stores as
/// `(angle / 0.006) as i16`, truncating toward zero: half a step (0.003 degrees) added
/// away from zero first makes that the nearest step (a truncated -13 degrees would read
/// back as -12.996). LAS 1.4 allows -180..180 degrees; elevations are within -90..90.
fn scan_angle(elevation_deg: f64) -> f32 {
    (elevation_deg + 0.003f64.copysign(elevation_deg)) as f32
}

/// The LAS "extra bytes" VLR (LASF_Spec record 4): one 192-byte descriptor per extra field.
fn extra_bytes_vlr() -> las::Vlr {
    let mut data = Vec::with_capacity(192 * LAS_EXTRA.len());
    for (name, ty, _, description) in LAS_EXTRA {
        let mut d = [0u8; 192];
        d[2] = ty; // after two reserved bytes; options 0: no no_data, min, max, scale, offset
        d[4..4 + name.len()].copy_from_slice(name.as_bytes());
        d[160..160 + description.len()].copy_from_slice(description.as_bytes());
        data.extend_from_slice(&d);
    }
    las::Vlr {
        user_id: "LASF_Spec".to_string(),
        record_id: 4,
        description: "cylaov scan fields".to_string(),
        data,
    }
}

/// LAS 1.4, point format 6: x y z at 0.1 mm (offset: the points' box's centre, whole
/// units), GPS time = `time`, return number and count, scan angle = the beam's elevation
/// (degrees; LAS stores 0.006 degree steps), classification = label clipped to 255 (label
/// 12, which LAS 1.4 reserves for the overlap flag, is written as class 1 with the overlap
/// bit set: the `las` crate's rule), point source id = ring, and every other field as
/// extra bytes (ring, shape_id, part, label, range, range_exact, azimuth, normal_x/y/z).
pub fn las(scan: &Scan) -> Result<Vec<u8>, String> {
    use las::point::{Classification, Format};
    use las::{Builder, Point, Transform, Vector, Writer};
    let e = |e: las::Error| format!("LAS: {e}");
    let mut builder = Builder::from((1, 4));
    let mut format = Format::new(6).map_err(e)?;
    format.extra_bytes = LAS_EXTRA.iter().map(|f| f.2 as u16).sum();
    builder.point_format = format;
    builder.generating_software = "cylaov scan".to_string();
    builder.system_identifier = "cylaov".to_string();
    builder.vlrs.push(extra_bytes_vlr());
    // 0.1 mm steps from an offset at the box's centre: i32 then spans +-214 km around it.
    let centre = |v: &[f64]| {
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        if lo.is_finite() {
            ((lo + hi) / 2.0).round()
        } else {
            0.0
        }
    };
    let t = |v: &[f64]| Transform {
        scale: 1e-4,
        offset: centre(v),
    };
    let transforms = Vector {
        x: t(&scan.x),
        y: t(&scan.y),
        z: t(&scan.z),
    };
    // Checked before the writer exists: a point it cannot store is an error of
    // `write_point`, and the writer dropped unclosed after one panics.
    for (axis, v, t) in [
        ("x", &scan.x, &transforms.x),
        ("y", &scan.y, &transforms.y),
        ("z", &scan.z, &transforms.z),
    ] {
        check_las_span(axis, v, t)?;
    }
    builder.transforms = transforms;
    let header = builder.into_header().map_err(e)?;
    let mut w = Writer::new(std::io::Cursor::new(Vec::new()), header).map_err(e)?;
    for i in 0..scan.len() {
        let label = scan.label[i].min(255) as u8;
        let (classification, is_overlap) = match Classification::new(label) {
            Ok(c) => (c, false),
            Err(_) => (Classification::Unclassified, true),
        };
        let mut extra = Vec::with_capacity(format.extra_bytes as usize);
        extra.extend_from_slice(&(scan.ring[i] as u16).to_le_bytes());
        extra.extend_from_slice(&scan.shape_id[i].to_le_bytes());
        extra.extend_from_slice(&(scan.part[i] as u16).to_le_bytes());
        extra.extend_from_slice(&scan.label[i].to_le_bytes());
        extra.extend_from_slice(&scan.range[i].to_le_bytes());
        extra.extend_from_slice(&scan.range_exact[i].to_le_bytes());
        extra.extend_from_slice(&scan.azimuth[i].to_le_bytes());
        for c in scan.normal[i] {
            extra.extend_from_slice(&c.to_le_bytes());
        }
        let p = Point {
            x: scan.x[i],
            y: scan.y[i],
            z: scan.z[i],
            return_number: scan.return_index[i] as u8,
            number_of_returns: scan.num_returns[i] as u8,
            classification,
            is_overlap,
            scan_angle: scan_angle(scan.elevation[i]),
            point_source_id: scan.ring[i] as u16,
            gps_time: Some(scan.time[i]),
            extra_bytes: extra,
            ..Default::default()
        };
        w.write_point(p).map_err(e)?;
    }
    let mut bytes = w.into_inner().map_err(e)?.into_inner();
    if scan.x.is_empty() {
        // No points: the writer's running bounds stay at +inf and -inf. A box of zeros is
        // what readers take for empty. The LAS 1.4 header holds max x, min x, max y, min y,
        // max z, min z as six little-endian f64 from byte 179.
        for field in bytes[179..227].chunks_exact_mut(8) {
            field.copy_from_slice(&0f64.to_le_bytes());
        }
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scan of `xs` along x (every other column zero or one), as the scan module fills it.
    fn points_along_x(xs: &[f64]) -> Scan {
        let n = xs.len();
        Scan {
            x: xs.to_vec(),
            y: vec![0.0; n],
            z: vec![0.0; n],
            range: vec![1.0; n],
            range_exact: vec![1.0; n],
            ring: vec![0; n],
            azimuth: vec![0.0; n],
            elevation: vec![0.0; n],
            time: vec![0.0; n],
            return_index: vec![1; n],
            num_returns: vec![1; n],
            shape_id: vec![1; n],
            part: vec![1; n],
            label: vec![0; n],
            normal: vec![[1.0, 0.0, 0.0]; n],
        }
    }

    /// 0.1 mm steps in an i32 span 429 496.7295 units: points 400 km apart are written,
    /// 600 km apart are refused with the axis and the span named (the `las` writer would
    /// panic on its drop after refusing the point).
    #[test]
    fn las_refuses_points_beyond_its_integer_span() {
        let bytes = las(&points_along_x(&[-200_000.0, 200_000.0])).expect("400 km fits");
        assert!(bytes.len() > 375, "{}", bytes.len());
        let e = las(&points_along_x(&[-300_000.0, 300_000.0])).unwrap_err();
        assert!(
            e.contains("-300000 to 300000 along x (600000 world units)") && e.contains(".npz"),
            "{e}"
        );
        assert!(las(&points_along_x(&[])).is_ok());
    }

    #[test]
    fn extra_byte_names_fit_their_fields() {
        for (name, _, _, description) in LAS_EXTRA {
            assert!(name.len() <= 32 && description.len() <= 32, "{name}");
        }
        assert_eq!(extra_bytes_vlr().data.len(), 192 * LAS_EXTRA.len());
    }
}
