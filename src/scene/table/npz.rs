//! Cylinder tables from NumPy: an `.npz` (`numpy.savez` or `numpy.savez_compressed`) of
//! arrays `p0 (N, 3)`, `p1 (N, 3)`, `radius (N,)` and optionally `id`, `label`, `caps`
//! `(N,)`, and for the label rules `branch_order` and `branch` `(N,)`. Points and radii may
//! be any float or integer dtype, in C or Fortran order; ids, labels, orders and caps are
//! integers or bools. Other arrays are ignored.
//!
//! A rejected value names its array and 0-based index as numpy prints it (`radius[16]`).

use super::{LabelRule, Table, TableError, TableFormat, TableOptions};
use crate::npy::{Element, RawArray};
use crate::scene::{CylinderFile, MAX_COORD, num};
use glam::DVec3;
use std::io::Read;

/// Most bytes the arrays of one table may take once decompressed: a zip member that
/// claims more is refused before it is inflated (a 10^6-cylinder table of float64 points
/// takes 56 MB).
const MAX_ARRAY_BYTES: u64 = 4 << 30;

/// Whether `bytes` start like a zip archive (an `.npz`), whatever the file's name.
pub fn is_zip(bytes: &[u8]) -> bool {
    bytes.starts_with(b"PK\x03\x04") || bytes.starts_with(b"PK\x05\x06")
}

fn whole_err(message: impl Into<String>) -> TableError {
    TableError {
        line: 0,
        column: None,
        message: message.into(),
        option: None,
    }
}

/// The arrays a table reads, by name; any other member is left packed.
const READ: [&str; 8] = [
    "p0",
    "p1",
    "radius",
    "id",
    "label",
    "caps",
    "branch_order",
    "branch",
];

/// The archive's arrays: the names of all its `.npy` members (for messages) and the
/// unpacked bytes of those a table reads ([`READ`]), each checked against the memory left
/// before it is inflated.
type Members = (Vec<String>, Vec<(String, Vec<u8>)>);

fn members(bytes: &[u8]) -> Result<Members, TableError> {
    let bad =
        |e: zip::result::ZipError| whole_err(format!("not a readable .npz (zip) archive: {e}"));
    let mut archive = zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(bad)?;
    let mut names = Vec::new();
    let mut out = Vec::new();
    let mut budget = MAX_ARRAY_BYTES;
    for k in 0..archive.len() {
        let mut member = archive.by_index(k).map_err(bad)?;
        let name = member.name().map_err(bad)?;
        let Some(name) = name.strip_suffix(".npy").map(str::to_string) else {
            continue;
        };
        names.push(name.clone());
        if !READ.contains(&name.as_str()) || out.iter().any(|(m, _)| *m == name) {
            continue;
        }
        let size = member.size();
        if size > budget {
            return Err(whole_err(format!(
                "array {name} takes {size} bytes unpacked; a table's arrays may take {MAX_ARRAY_BYTES} in all"
            )));
        }
        budget -= size;
        crate::mem::check_memory(&format!("unpacking array {name} ({size} bytes)"), size)
            .map_err(|e| whole_err(e.to_string()))?;
        let mut data = Vec::new();
        crate::mem::try_reserve(&mut data, size as usize, &format!("array {name}"))
            .map_err(|e| whole_err(e.to_string()))?;
        (&mut member)
            .take(size)
            .read_to_end(&mut data)
            .map_err(|e| whole_err(format!("array {name}: cannot unpack: {e}")))?;
        out.push((name, data));
    }
    Ok((names, out))
}

/// One named array of the table. Its elements are read from the unpacked bytes as each
/// is needed: a list of decoded values would take up to 8 times the bytes (a uint8 array
/// of 60 MB, 137 KB packed, would take 480 MB as f64).
struct Column<'a> {
    name: &'static str,
    raw: RawArray<'a>,
}

impl<'a> Column<'a> {
    fn read(
        members: &'a [(String, Vec<u8>)],
        name: &'static str,
        n: Option<usize>,
        width: usize,
    ) -> Result<Option<Column<'a>>, TableError> {
        let Some((_, bytes)) = members.iter().find(|(m, _)| m == name) else {
            return Ok(None);
        };
        let raw: RawArray =
            crate::npy::parse_raw(bytes).map_err(|e| whole_err(format!("array {name}: {e}")))?;
        let rows = raw.shape.first().copied().unwrap_or(0);
        let want_shape = if width == 1 {
            vec![n.unwrap_or(rows)]
        } else {
            vec![n.unwrap_or(rows), width]
        };
        if raw.shape != want_shape {
            let want = if width == 1 {
                "(N,)".to_string()
            } else {
                format!("(N, {width})")
            };
            let n = n
                .map(|n| format!(" with N = {n}, the rows of p0"))
                .unwrap_or_default();
            let got: Vec<String> = raw.shape.iter().map(usize::to_string).collect();
            let got = match got.len() {
                1 => format!("({},)", got[0]),
                _ => format!("({})", got.join(", ")),
            };
            return Err(whole_err(format!(
                "array {name} must have shape {want}{n}, got {got}"
            )));
        }
        raw.check_readable()
            .map_err(|e| whole_err(format!("array {name}: {e}")))?;
        Ok(Some(Column { name, raw }))
    }

    /// The element at `at` (C order); `label` names it if it cannot be read.
    fn element(&self, at: usize, label: &str) -> Result<Element, TableError> {
        self.raw.get(at).ok_or_else(|| {
            whole_err(format!(
                "{label}: cannot be read from array {} of dtype {}",
                self.name, self.raw.descr
            ))
        })
    }

    /// The element at `at` (C order) as a finite number within the scene's coordinates.
    fn number(&self, at: usize, label: &str) -> Result<f64, TableError> {
        let v = match self.element(at, label)? {
            Element::Float(v) => v,
            Element::Int(i) => i as f64,
        };
        if !v.is_finite() || v.abs() > MAX_COORD {
            return Err(whole_err(format!(
                "{label}: must be finite and within ±{MAX_COORD:e}, got {}",
                num(v)
            )));
        }
        Ok(v)
    }

    fn point(&self, row: usize) -> Result<DVec3, TableError> {
        let mut p = [0.0; 3];
        for (j, v) in p.iter_mut().enumerate() {
            *v = self.number(row * 3 + j, &format!("{}[{row}, {j}]", self.name))?;
        }
        Ok(DVec3::from_array(p))
    }

    /// The element at `row` as a whole number in `0..=max`.
    fn whole(&self, row: usize, max: u64) -> Result<u64, TableError> {
        let label = format!("{}[{row}]", self.name);
        if self.raw.is_float() {
            return Err(whole_err(format!(
                "array {}: must hold integers or bools, got dtype {}",
                self.name, self.raw.descr
            )));
        }
        match self.element(row, &label)? {
            Element::Int(i) if (0..=max as i128).contains(&i) => Ok(i as u64),
            Element::Int(i) => Err(whole_err(format!("{label}: must be in 0..={max}, got {i}"))),
            Element::Float(_) => Err(whole_err(format!(
                "array {}: must hold integers or bools, got dtype {}",
                self.name, self.raw.descr
            ))),
        }
    }
}

/// Read an `.npz` table (see the module's doc) into cylinders.
pub fn read_npz(bytes: &[u8], opts: &TableOptions) -> Result<Table, TableError> {
    if let Some(f) = opts.format.filter(|&f| f != TableFormat::Npz) {
        return Err(whole_err(format!(
            "this is an .npz (zip) archive of arrays, not a {} text table; give format npz or leave it out",
            f.name()
        )));
    }
    let (names, members) = members(bytes)?;
    let need = |name: &'static str, n: Option<usize>, width: usize| {
        Column::read(&members, name, n, width)?.ok_or_else(|| {
            whole_err(format!(
                "the .npz has no array {name}; a table needs p0 (N, 3), p1 (N, 3) and radius (N,), it holds [{}]",
                super::list_names(&names)
            ))
        })
    };
    let p0 = need("p0", None, 3)?;
    let n = p0.raw.len() / 3;
    if n == 0 {
        return Err(whole_err(
            "the table has no cylinder rows (p0 has shape (0, 3))",
        ));
    }
    if u32::try_from(n).is_err() {
        return Err(whole_err(format!("{n} rows: more than 4294967295")));
    }
    let p1 = need("p1", Some(n), 3)?;
    let radius = need("radius", Some(n), 1)?;
    let id = Column::read(&members, "id", Some(n), 1)?;
    let own_label = Column::read(&members, "label", Some(n), 1)?;
    let caps = Column::read(&members, "caps", Some(n), 1)?;
    let rule = opts.label.unwrap_or(LabelRule::None);
    let by_rule = match rule {
        LabelRule::BranchOrder | LabelRule::Branch => {
            let name = if rule == LabelRule::BranchOrder {
                "branch_order"
            } else {
                "branch"
            };
            Some(Column::read(&members, name, Some(n), 1)?.ok_or_else(|| {
                whole_err(format!(
                    "label {}: this npz table has no array {name}",
                    rule.name()
                ))
            })?)
        }
        _ => None,
    };

    let cylinder = |row: usize| -> Result<CylinderFile, TableError> {
        let a = p0.point(row)?;
        let b = p1.point(row)?;
        if a == b {
            return Err(whole_err(format!(
                "p1[{row}]: zero length: the end equals the start {:?}",
                a.to_array()
            )));
        }
        let r = radius.number(row, &format!("radius[{row}]"))?;
        if r <= 0.0 {
            return Err(whole_err(format!(
                "radius[{row}]: must be > 0, got {}",
                num(r)
            )));
        }
        let id = match &id {
            Some(c) => c.whole(row, u32::MAX as u64 - 1)? as u32,
            None => row as u32 + 1,
        };
        let label = match (&by_rule, &own_label, opts.label) {
            (Some(c), _, _) => c.whole(row, u32::MAX as u64 - 1)? as u32 + 1,
            (None, Some(c), None) => c.whole(row, u32::MAX as u64)? as u32,
            _ => 0,
        };
        let caps = match &caps {
            Some(c) => c.whole(row, 1)? == 1,
            None => opts.caps.unwrap_or(true),
        };
        Ok(CylinderFile {
            p0: Some(a.to_array()),
            p1: Some(b.to_array()),
            radius: r,
            caps,
            id: Some(id),
            label,
            ..CylinderFile::default()
        })
    };
    // Every row is checked before room for the cylinders is asked for: a bad row is
    // named whatever memory the whole table would need.
    for row in 0..n {
        cylinder(row)?;
    }
    let mut cylinders = Vec::new();
    super::reserve_cylinders(&mut cylinders, n)?;
    for row in 0..n {
        cylinders.push(cylinder(row)?);
    }
    Ok(super::finish(TableFormat::Npz, cylinders, rule))
}
