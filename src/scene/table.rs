//! Cylinder tables: the cylinders of a quantitative structure model (QSM) of a tree, or of
//! any plain CSV, read into scene cylinders. `cylaov import`, `Scene.from_table` and a
//! scene's `"cylinders": {"file": ...}` read tables through [`read_table`].
//!
//! | format | how it is recognised | start → `p0` | `p1` | radius | `id` |
//! |---|---|---|---|---|---|
//! | `csv` | header with `x0,y0,z0,x1,y1,z1,radius` | `x0,y0,z0` | `x1,y1,z1` | `radius` | `id`, else the row number |
//! | `treeqsm` | header with `parent, extension, branch, BranchOrder`, or no header and 14 or 15 columns | `start` | `start + length · axis` | `radius` | the row number (TreeQSM's `parent` counts rows) |
//! | `simpleforest` | header with `ID, parentID, branchID, branchOrder` | `startX..Z` | `endX..Z` | `radius` | `ID` |
//! | `archi` | header with `cyl_ID, parent_ID, branching_order` | `startX..Z` | `endX..Z` | `radius_cyl` | `cyl_ID` |
//! | `npz` | a zip archive (NumPy's `savez`), see [`npz`] | array `p0` | array `p1` | array `radius` | array `id`, else the row number |
//!
//! Header names match whatever their case and punctuation (`start.x`, `start_x`, `startX`;
//! a unit in brackets, `radius (m)`, is dropped). A format with axis and length but no end
//! columns (or the other way round) is read either way. Ids of a table that counts from 0
//! are all moved up by one (0 is a miss in `shape_id`).
//!
//! Every rejected row names its line (1-based, as an editor counts) and column.

pub mod npz;

use crate::scene::{CylinderFile, MAX_COORD, SceneFile, num};
use glam::DVec3;
use std::borrow::Cow;
use std::fmt;

/// A table layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TableFormat {
    /// Named columns `x0,y0,z0,x1,y1,z1,radius`, optional `id`, `label`, `caps`.
    Csv,
    /// TreeQSM's `cyl_data`: radius, length, start, axis, parent, extension, branch,
    /// BranchOrder, PositionInBranch, added, UnmodRadius.
    TreeQsm,
    /// SimpleForest's cylinder CSV.
    SimpleForest,
    /// aRchi's cylinder CSV.
    Archi,
    /// NumPy's `.npz` of arrays `p0`, `p1`, `radius`, optional `id`, `label`, `caps`
    /// ([`npz`]).
    Npz,
}

impl TableFormat {
    /// Every format, as `--format` lists them.
    pub const ALL: [TableFormat; 5] = [
        TableFormat::Csv,
        TableFormat::Npz,
        TableFormat::TreeQsm,
        TableFormat::SimpleForest,
        TableFormat::Archi,
    ];

    /// The name `--format` and `format=` take.
    pub fn name(self) -> &'static str {
        match self {
            TableFormat::Csv => "csv",
            TableFormat::TreeQsm => "treeqsm",
            TableFormat::SimpleForest => "simpleforest",
            TableFormat::Archi => "archi",
            TableFormat::Npz => "npz",
        }
    }

    /// The format named `s`, or `None`.
    pub fn parse(s: &str) -> Option<TableFormat> {
        TableFormat::ALL.into_iter().find(|f| f.name() == s)
    }
}

/// What a cylinder's `label` (the `label` AOV) is made of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LabelRule {
    /// No label (0).
    None,
    /// Branch order + 1: the stem is 1, its branches 2, ... (0 stays "no hit").
    BranchOrder,
    /// Branch id + 1.
    Branch,
    /// The cylinder's own id (the `shape_id` it renders to).
    Segment,
}

impl LabelRule {
    /// Every rule, as `--label` lists them.
    pub const ALL: [LabelRule; 4] = [
        LabelRule::None,
        LabelRule::BranchOrder,
        LabelRule::Branch,
        LabelRule::Segment,
    ];

    /// The name `--label` and `label=` take.
    pub fn name(self) -> &'static str {
        match self {
            LabelRule::None => "none",
            LabelRule::BranchOrder => "branch_order",
            LabelRule::Branch => "branch",
            LabelRule::Segment => "segment",
        }
    }

    /// The rule named `s`, or `None`.
    pub fn parse(s: &str) -> Option<LabelRule> {
        LabelRule::ALL.into_iter().find(|f| f.name() == s)
    }
}

/// How to read a table; `None` fields take the defaults.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TableOptions {
    /// The layout; default: told from the header or the column count.
    pub format: Option<TableFormat>,
    /// The label rule; default: a `csv` table's `label` column, else no label.
    pub label: Option<LabelRule>,
    /// Caps on every cylinder (a `csv` table's `caps` column wins); default on.
    pub caps: Option<bool>,
}

/// A table read into cylinders.
#[derive(Clone, Debug)]
pub struct Table {
    /// The layout it was read as.
    pub format: TableFormat,
    /// One cylinder per row, in row order, `p0`/`p1` form.
    pub cylinders: Vec<CylinderFile>,
    /// Whether the table counted ids from 0, so every id was moved up by one.
    pub ids_shifted: bool,
}

/// A table that could not be read: where and why.
#[derive(Clone, Debug, PartialEq)]
pub struct TableError {
    /// 1-based line of the file; 0 for the whole file.
    pub line: usize,
    /// 1-based column and its name, when one column is at fault.
    pub column: Option<(usize, String)>,
    /// Why, naming the value.
    pub message: String,
    /// The option at fault, when the table lacks what one asks for (`label`): the message
    /// names its value, and whoever reports it names the option as its user set it (a
    /// flag, a keyword, a scene file's key).
    pub option: Option<&'static str>,
}

impl fmt::Display for TableError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let message = match self.option {
            Some(key) => format!("{} {}", crate::spelling::opt(key), self.message),
            None => self.message.clone(),
        };
        match (&self.column, self.line) {
            (_, 0) => f.write_str(&message),
            (Some((k, name)), line) => write!(f, "line {line}, column {k} ({name}): {message}"),
            (None, line) => write!(f, "line {line}: {message}"),
        }
    }
}

impl std::error::Error for TableError {}

fn line_err(line: usize, message: impl Into<String>) -> TableError {
    TableError {
        line,
        column: None,
        message: message.into(),
        option: None,
    }
}

/// A header name as matched: lower case, letters and digits only, a bracketed unit
/// dropped (`"Radius (m)"` → `radius`, `start.x` → `startx`).
fn normalise(name: &str) -> String {
    let name = name.trim().trim_matches('"');
    let name = name.split('(').next().unwrap_or("");
    name.chars()
        .filter(|c| c.is_ascii_alphanumeric())
        .map(|c| c.to_ascii_lowercase())
        .collect()
}

/// TreeQSM's columns in file order, for tables without a header.
const TREEQSM_COLUMNS: [&str; 15] = [
    "radius",
    "length",
    "start.x",
    "start.y",
    "start.z",
    "axis.x",
    "axis.y",
    "axis.z",
    "parent",
    "extension",
    "branch",
    "BranchOrder",
    "PositionInBranch",
    "added",
    "UnmodRadius",
];

/// The columns each role may have, by normalised name, first match wins.
struct Names {
    start: [&'static [&'static str]; 3],
    end: [&'static [&'static str]; 3],
    axis: [&'static [&'static str]; 3],
    length: &'static [&'static str],
    radius: &'static [&'static str],
    id: &'static [&'static str],
    branch: &'static [&'static str],
    order: &'static [&'static str],
}

const QSM_NAMES: Names = Names {
    start: [
        &["startx", "startpointx", "sx"],
        &["starty", "startpointy", "sy"],
        &["startz", "startpointz", "sz"],
    ],
    end: [
        &["endx", "endpointx", "ex"],
        &["endy", "endpointy", "ey"],
        &["endz", "endpointz", "ez"],
    ],
    axis: [
        &["axisx", "axisdirectionx", "ax"],
        &["axisy", "axisdirectiony", "ay"],
        &["axisz", "axisdirectionz", "az"],
    ],
    length: &["length"],
    radius: &["radius"],
    id: &[],
    branch: &["branch"],
    order: &["branchorder"],
};

fn names(format: TableFormat) -> Names {
    match format {
        // An `.npz` never reaches the text reader; its arrays are named like the csv columns.
        TableFormat::Csv | TableFormat::Npz => Names {
            start: [&["x0"], &["y0"], &["z0"]],
            end: [&["x1"], &["y1"], &["z1"]],
            axis: [&[], &[], &[]],
            length: &[],
            radius: &["radius"],
            id: &["id"],
            branch: &[],
            order: &[],
        },
        TableFormat::TreeQsm => QSM_NAMES,
        TableFormat::SimpleForest => Names {
            id: &["id"],
            branch: &["branchid"],
            order: &["branchorder"],
            ..QSM_NAMES
        },
        TableFormat::Archi => Names {
            radius: &["radiuscyl", "radius"],
            id: &["cylid"],
            branch: &["branchid"],
            order: &["branchingorder"],
            ..QSM_NAMES
        },
    }
}

/// The format a header's normalised names say, as rTwig's signatures tell them apart.
fn detect(names: &[String]) -> Option<TableFormat> {
    let has = |list: &[&str]| list.iter().all(|n| names.iter().any(|h| h == n));
    if has(&["x0", "y0", "z0", "x1", "y1", "z1", "radius"]) {
        Some(TableFormat::Csv)
    } else if has(&["cylid", "parentid", "branchingorder"]) {
        Some(TableFormat::Archi)
    } else if has(&["id", "parentid", "branchid", "branchorder"]) {
        Some(TableFormat::SimpleForest)
    } else if has(&["parent", "extension", "branch", "branchorder"]) {
        Some(TableFormat::TreeQsm)
    } else {
        None
    }
}

/// How a file separates its fields, told from its first line: commas when it has one,
/// else tabs when it has one (each comma or tab ends a field, so an empty field stays a
/// field), else runs of spaces (TreeQSM's text export).
#[derive(Clone, Copy, PartialEq)]
enum Separator {
    Comma,
    Tab,
    Space,
}

impl Separator {
    fn of(first: &str) -> Separator {
        if first.contains(',') {
            Separator::Comma
        } else if first.contains('\t') {
            Separator::Tab
        } else {
            Separator::Space
        }
    }
}

/// Most columns a table may have (TreeQSM writes 15, SimpleForest about 30): a line of
/// 20 million empty names would otherwise take gigabytes as names.
const MAX_COLUMNS: usize = 10_000;

/// The first `keep` fields of a line and how many it has. Between commas or tabs a field is
/// trimmed, and one that starts with `"` runs to its closing quote (RFC 4180: it may hold
/// the separator, and `""` is a quote), which only spaces may follow; a quoted field does
/// not span lines. The error says which field is at fault and why.
fn split(line: &str, sep: Separator, keep: usize) -> Result<(Vec<Cow<'_, str>>, usize), String> {
    let sep = match sep {
        Separator::Space => {
            let fields = line
                .split_whitespace()
                .take(keep)
                .map(Cow::Borrowed)
                .collect();
            return Ok((fields, line.split_whitespace().count()));
        }
        Separator::Comma => ',',
        Separator::Tab => '\t',
    };
    let blank = |c: char| c != sep && c.is_whitespace();
    let mut fields = Vec::new();
    let mut count = 0;
    let mut rest = line;
    loop {
        let field = rest.trim_start_matches(blank);
        let after = if let Some(quoted) = field.strip_prefix('"') {
            let mut value = Cow::Borrowed("");
            let mut inner = quoted;
            loop {
                let Some(k) = inner.find('"') else {
                    return Err(format!(
                        "field {} opens a quote that does not close on this line",
                        count + 1
                    ));
                };
                match value {
                    Cow::Borrowed(_) if inner[k + 1..].starts_with('"') => {
                        value = Cow::Owned(format!("{}{}", &inner[..k], '"'));
                    }
                    Cow::Borrowed(_) => value = Cow::Borrowed(&inner[..k]),
                    Cow::Owned(ref mut v) => {
                        v.push_str(&inner[..k]);
                        if inner[k + 1..].starts_with('"') {
                            v.push('"');
                        }
                    }
                }
                if inner[k + 1..].starts_with('"') {
                    inner = &inner[k + 2..];
                } else {
                    inner = &inner[k + 1..];
                    break;
                }
            }
            count += 1;
            if fields.len() < keep {
                fields.push(value);
            }
            let after = inner.trim_start_matches(blank);
            if !after.is_empty() && !after.starts_with(sep) {
                return Err(format!(
                    "field {count} has {:?} after its closing quote",
                    crate::scene::strict::shorten(after.split(sep).next().unwrap_or(after))
                ));
            }
            after
        } else {
            let end = field.find(sep).unwrap_or(field.len());
            count += 1;
            if fields.len() < keep {
                fields.push(Cow::Borrowed(field[..end].trim()));
            }
            &field[end..]
        };
        match after.strip_prefix(sep) {
            Some(next) => rest = next,
            None => return Ok((fields, count)),
        }
    }
}

/// A header's names, one per field. Separated by runs of spaces, a bracketed unit
/// (`radius (m)`, `length (in m)`) is its own words and is dropped.
fn header_names(line: &str, sep: Separator) -> Result<Vec<Cow<'_, str>>, String> {
    if sep != Separator::Space {
        return Ok(split(line, sep, MAX_COLUMNS)?.0);
    }
    let mut names = Vec::new();
    let mut in_unit = false;
    for word in line.split_whitespace() {
        if word.starts_with('(') {
            in_unit = true;
        }
        if !in_unit {
            names.push(Cow::Borrowed(word));
        }
        if in_unit && word.ends_with(')') {
            in_unit = false;
        }
    }
    Ok(names)
}

/// At most this many names of a list go into a message.
const NAMES_SHOWN: usize = 12;

/// `names` for a message, comma-separated: the first [`NAMES_SHOWN`], each shortened, and
/// how many more (a header of 20 million names makes one line, not 60 MB).
pub(crate) fn list_names(names: &[impl AsRef<str>]) -> String {
    let mut out: Vec<String> = names
        .iter()
        .take(NAMES_SHOWN)
        .map(|n| crate::scene::strict::shorten(n.as_ref()))
        .collect();
    if names.len() > NAMES_SHOWN {
        out.push(format!("… {} more", names.len() - NAMES_SHOWN));
    }
    out.join(", ")
}

/// Room for `n` cylinders in `v`, or an error saying how much memory they need: checked
/// against what the system leaves before anything is reserved.
pub(crate) fn reserve_cylinders(v: &mut Vec<CylinderFile>, n: usize) -> Result<(), TableError> {
    let what = format!("reading the table's {n} cylinders");
    let bytes = (n as u64).saturating_mul(size_of::<CylinderFile>() as u64);
    crate::mem::check_memory(&what, bytes)
        .and_then(|()| crate::mem::try_reserve(v, n, &what))
        .map_err(|e| line_err(0, e.to_string()))
}

/// Where each role's value sits in a row (0-based field index).
#[derive(Default)]
struct Columns {
    /// Field names for messages, one per field.
    names: Vec<String>,
    /// Fields every row has: the header's, or the first row's without a header.
    width: usize,
    start: [usize; 3],
    end: Option<[usize; 3]>,
    axis: Option<[usize; 3]>,
    length: Option<usize>,
    radius: usize,
    id: Option<usize>,
    branch: Option<usize>,
    order: Option<usize>,
    label: Option<usize>,
    caps: Option<usize>,
}

/// The header's names with a bare vector name (`start_point`, `axis`) spread over the
/// three columns it heads, as TreeQSM writes them.
fn spread(header: &[Cow<str>]) -> (Vec<String>, Vec<String>) {
    let mut norm = Vec::new();
    let mut shown = Vec::new();
    for h in header {
        let n = normalise(h);
        match n.as_str() {
            "start" | "startpoint" | "end" | "endpoint" | "axis" | "axisdirection" => {
                for c in ["x", "y", "z"] {
                    norm.push(format!("{n}{c}"));
                    shown.push(format!("{}.{c}", h.trim()));
                }
            }
            _ => {
                norm.push(n);
                shown.push(match h.trim() {
                    "" => "unnamed".to_string(),
                    h => h.to_string(),
                });
            }
        }
    }
    (norm, shown)
}

fn columns_from_header(
    format: TableFormat,
    norm: &[String],
    shown: Vec<String>,
    line: usize,
) -> Result<Columns, TableError> {
    // The one column whose normalised name is in `list`; two are refused, naming both:
    // `radius` and `radius (mm)` read the same, and neither may silently win.
    let find = |list: &[&str]| -> Result<Option<usize>, TableError> {
        let mut hits = norm
            .iter()
            .enumerate()
            .filter(|(_, h)| list.contains(&h.as_str()))
            .map(|(k, _)| k);
        let first = hits.next();
        match (first, hits.next()) {
            (Some(a), Some(b)) => Err(line_err(
                line,
                format!(
                    "columns {} ({}) and {} ({}) are both {}; keep one, or rename the other",
                    a + 1,
                    crate::scene::strict::shorten(&shown[a]),
                    b + 1,
                    crate::scene::strict::shorten(&shown[b]),
                    list.first().copied().unwrap_or("")
                ),
            )),
            _ => Ok(first),
        }
    };
    let n = names(format);
    let missing = |what: &str| {
        line_err(
            line,
            format!(
                "the header of this {} table has no {what} column (columns: {})",
                format.name(),
                list_names(&shown)
            ),
        )
    };
    let triple = |lists: [&[&str]; 3]| -> Result<Option<[usize; 3]>, TableError> {
        Ok(match (find(lists[0])?, find(lists[1])?, find(lists[2])?) {
            (Some(x), Some(y), Some(z)) => Some([x, y, z]),
            _ => None,
        })
    };
    let start = triple(n.start)?.ok_or_else(|| {
        missing(&format!(
            "start ({})",
            n.start.map(|l| l.first().copied().unwrap_or("")).join(", ")
        ))
    })?;
    let radius = find(n.radius)?.ok_or_else(|| missing(n.radius[0]))?;
    let end = triple(n.end)?;
    let axis = triple(n.axis)?;
    let length = find(n.length)?;
    if end.is_none() && (axis.is_none() || length.is_none()) {
        return Err(missing(&format!(
            "end ({}) and no axis and length",
            n.end.map(|l| l.first().copied().unwrap_or("")).join(", ")
        )));
    }
    let csv = format == TableFormat::Csv;
    let (id, branch, order) = (find(n.id)?, find(n.branch)?, find(n.order)?);
    let label = if csv { find(&["label"])? } else { None };
    let caps = if csv { find(&["caps"])? } else { None };
    Ok(Columns {
        width: shown.len(),
        names: shown,
        start,
        end,
        axis,
        length,
        radius,
        id,
        branch,
        order,
        label,
        caps,
    })
}

/// TreeQSM without a header: the columns by position, `width` of them (14 or 15).
fn treeqsm_positional(width: usize) -> Columns {
    Columns {
        names: TREEQSM_COLUMNS.iter().map(|s| s.to_string()).collect(),
        width,
        start: [2, 3, 4],
        end: None,
        axis: Some([5, 6, 7]),
        length: Some(1),
        radius: 0,
        id: None,
        branch: Some(10),
        order: Some(11),
        label: None,
        caps: None,
    }
}

/// One data row being read: its line and fields, for values and messages.
struct Row<'a> {
    line: usize,
    fields: Vec<Cow<'a, str>>,
    names: &'a [String],
}

impl Row<'_> {
    fn fail(&self, k: usize, message: impl Into<String>) -> TableError {
        TableError {
            line: self.line,
            column: Some((
                k + 1,
                self.names.get(k).cloned().unwrap_or_else(|| "?".into()),
            )),
            message: message.into(),
            option: None,
        }
    }

    /// Field `k` as a finite number of magnitude at most [`MAX_COORD`].
    fn number(&self, k: usize) -> Result<f64, TableError> {
        let text = self.fields[k].trim();
        if text.is_empty() {
            return Err(self.fail(k, "is empty; a number is needed"));
        }
        let x: f64 = text.parse().map_err(|_| {
            self.fail(
                k,
                format!(
                    "not a number, got {:?}",
                    crate::scene::strict::shorten(text)
                ),
            )
        })?;
        if !x.is_finite() || x.abs() > MAX_COORD {
            return Err(self.fail(
                k,
                format!(
                    "must be finite with magnitude <= {MAX_COORD:e}, got {}",
                    num(x)
                ),
            ));
        }
        Ok(x)
    }

    fn point(&self, ks: [usize; 3]) -> Result<DVec3, TableError> {
        Ok(DVec3::new(
            self.number(ks[0])?,
            self.number(ks[1])?,
            self.number(ks[2])?,
        ))
    }

    /// Field `k` as a whole number in `0..=max`.
    fn whole(&self, k: usize, max: u32) -> Result<u32, TableError> {
        let x = self.number(k)?;
        if x < 0.0 || x.fract() != 0.0 || x > max as f64 {
            return Err(self.fail(
                k,
                format!("must be a whole number in 0..={max}, got {}", num(x)),
            ));
        }
        Ok(x as u32)
    }

    fn flag(&self, k: usize) -> Result<bool, TableError> {
        match self.fields[k].trim().to_ascii_lowercase().as_str() {
            "1" | "true" | "yes" | "on" => Ok(true),
            "0" | "false" | "no" | "off" => Ok(false),
            other => Err(self.fail(
                k,
                format!(
                    "must be 1/0, true/false, yes/no or on/off, got {:?}",
                    crate::scene::strict::shorten(other)
                ),
            )),
        }
    }
}

/// Read a table's text into cylinders (see the module's table for the formats).
pub fn read_table(text: &str, opts: &TableOptions) -> Result<Table, TableError> {
    if opts.format == Some(TableFormat::Npz) {
        return Err(line_err(
            0,
            "an npz table is a zip archive of NumPy arrays (numpy.savez), this is text",
        ));
    }
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .peekable();
    let Some(&(first_line, first)) = lines.peek() else {
        return Err(line_err(0, "the table has no rows"));
    };
    let sep = Separator::of(first);
    let (format, cols, is_header) = table_layout(first_line, first, sep, opts)?;
    if is_header {
        lines.next();
    }

    let label = opts.label.unwrap_or(LabelRule::None);
    let label_source = match label {
        LabelRule::BranchOrder => Some(cols.order.ok_or((
            "branch order",
            "BranchOrder, branchOrder or branching_order",
        ))),
        LabelRule::Branch => Some(
            cols.branch
                .ok_or(("branch", "branch, branchID or branch_ID")),
        ),
        _ => None,
    };
    if let Some(Err((what, names))) = label_source {
        return Err(TableError {
            option: Some("label"),
            ..line_err(
                first_line,
                format!(
                    "{}: this {} table has no {what} column ({names})",
                    label.name(),
                    format.name()
                ),
            )
        });
    }
    let default_caps = opts.caps.unwrap_or(true);
    let mut cylinders = Vec::new();
    // The rows left, not the lines: blank and comment lines take no room.
    reserve_cylinders(&mut cylinders, lines.clone().count())?;
    let what_sets_width = if is_header {
        format!("the header (line {first_line}) has")
    } else {
        format!("the first row (line {first_line}) has")
    };
    for (line, text) in lines {
        let (fields, count) = split(text, sep, cols.width).map_err(|e| line_err(line, e))?;
        let row = Row {
            line,
            fields,
            names: &cols.names,
        };
        // A row of more or fewer fields than the header would shift every value after
        // the odd one into the next column's role: refused, whatever the columns read.
        if count != cols.width {
            let hint = match sep {
                _ if count < cols.width => "",
                Separator::Comma => " (a field holding a comma goes in double quotes)",
                Separator::Tab => " (a field holding a tab goes in double quotes)",
                Separator::Space => "",
            };
            return Err(line_err(
                line,
                format!("has {count} fields, {what_sets_width} {}{hint}", cols.width),
            ));
        }
        cylinders.push(row_cylinder(
            &row,
            cylinders.len(),
            &cols,
            opts,
            label,
            label_source.and_then(Result::ok),
            default_caps,
        )?);
    }
    if cylinders.is_empty() {
        return Err(line_err(0, "the table has no cylinder rows"));
    }
    Ok(finish(format, cylinders, label))
}

/// The format and columns of a table whose first row (line `first_line`) is `first`, and
/// whether that row is a header: named columns tell the format, or `opts.format`; without a
/// header only TreeQSM's 14 or 15 positional columns are known.
fn table_layout(
    first_line: usize,
    first: &str,
    sep: Separator,
    opts: &TableOptions,
) -> Result<(TableFormat, Columns, bool), TableError> {
    let (first_fields, count) =
        split(first, sep, MAX_COLUMNS).map_err(|e| line_err(first_line, e))?;
    if count > MAX_COLUMNS {
        return Err(line_err(
            first_line,
            format!("has {count} fields; a table may have at most {MAX_COLUMNS} columns"),
        ));
    }
    let is_header = first_fields
        .iter()
        .any(|f| !f.is_empty() && f.parse::<f64>().is_err());
    let (format, cols) = if is_header {
        let names = header_names(first, sep).map_err(|e| line_err(first_line, e))?;
        let (norm, shown) = spread(&names);
        drop(names);
        let format = match opts.format {
            Some(f) => f,
            None => detect(&norm).ok_or_else(|| {
                line_err(
                    first_line,
                    format!(
                        "cannot tell the table format from the header ({}): expected x0,y0,z0,x1,y1,z1,radius (csv), \
                         parent, extension, branch, BranchOrder (treeqsm), ID, parentID, branchID, branchOrder \
                         (simpleforest) or cyl_ID, parent_ID, branching_order (archi); give {}",
                        list_names(&shown),
                        crate::spelling::opt("format")
                    ),
                )
            })?,
        };
        (
            format,
            columns_from_header(format, &norm, shown, first_line)?,
        )
    } else {
        let n = first_fields.len();
        match opts.format {
            Some(TableFormat::TreeQsm) | None if n >= 14 && (opts.format.is_some() || n <= 15) => {
                (TableFormat::TreeQsm, treeqsm_positional(n))
            }
            Some(TableFormat::TreeQsm) => {
                return Err(line_err(
                    first_line,
                    format!("a TreeQSM table without a header has 14 or 15 columns, got {n}"),
                ));
            }
            Some(f) => {
                return Err(line_err(
                    first_line,
                    format!(
                        "a {} table starts with a header naming its columns, got numbers",
                        f.name()
                    ),
                ));
            }
            None => {
                return Err(line_err(
                    first_line,
                    format!(
                        "cannot tell the table format: no header and {n} columns (a TreeQSM cyl_data file without a \
                         header has 14 or 15); give the table a header or {}",
                        crate::spelling::opt("format")
                    ),
                ));
            }
        }
    };
    Ok((format, cols, is_header))
}

/// The cylinder of table row `row`, the `index`-th (its id when the table has none):
/// start, radius and end (or axis and length), checked; its id, label (by the `label`
/// rule from `rule_column`, else its own) and caps (`default_caps` when the table has no
/// caps column).
fn row_cylinder(
    row: &Row,
    index: usize,
    cols: &Columns,
    opts: &TableOptions,
    label: LabelRule,
    rule_column: Option<usize>,
    default_caps: bool,
) -> Result<CylinderFile, TableError> {
    let p0 = row.point(cols.start)?;
    let radius = row.number(cols.radius)?;
    if radius <= 0.0 {
        return Err(row.fail(cols.radius, format!("must be > 0, got {}", num(radius))));
    }
    let p1 = match (cols.end, cols.axis, cols.length) {
        (Some(end), ..) => {
            let p1 = row.point(end)?;
            if p1 == p0 {
                return Err(row.fail(
                    end[0],
                    format!("zero length: the end equals the start {:?}", p0.to_array()),
                ));
            }
            p1
        }
        (None, Some(axis), Some(length)) => {
            let h = row.number(length)?;
            if h <= 0.0 {
                return Err(row.fail(length, format!("must be > 0, got {}", num(h))));
            }
            let a = row.point(axis)?;
            // Divided by its largest component first, the axis is normalised whatever its
            // scale: the square of 1e-162 is subnormal and of 1e-200 is 0.
            let m = a.abs().max_element();
            if m == 0.0 {
                return Err(row.fail(
                    axis[0],
                    format!("the axis must be non-zero, got {:?}", a.to_array()),
                ));
            }
            let p1 = p0 + (a / m).normalize() * h;
            if p1 == p0 {
                return Err(row.fail(
                    length,
                    format!(
                        "{} is too short to move the end away from the start {:?}",
                        num(h),
                        p0.to_array()
                    ),
                ));
            }
            p1
        }
        _ => unreachable!("columns_from_header requires end, or axis and length"),
    };
    if p1.abs().max_element() > MAX_COORD {
        return Err(row.fail(
            cols.length.unwrap_or(cols.start[0]),
            format!("puts the end at {:?}, beyond {MAX_COORD:e}", p1.to_array()),
        ));
    }
    let id = match cols.id {
        Some(k) => row.whole(k, u32::MAX - 1)?,
        None => {
            u32::try_from(index + 1).map_err(|_| line_err(row.line, "more than 4294967295 rows"))?
        }
    };
    let own_label = match (opts.label, cols.label) {
        (None, Some(k)) => row.whole(k, u32::MAX)?,
        _ => 0,
    };
    let by_rule = match (label, rule_column) {
        (LabelRule::BranchOrder | LabelRule::Branch, Some(k)) => row.whole(k, u32::MAX - 1)? + 1,
        _ => own_label,
    };
    let caps = match cols.caps {
        Some(k) => row.flag(k)?,
        None => default_caps,
    };
    Ok(CylinderFile {
        p0: Some(p0.to_array()),
        p1: Some(p1.to_array()),
        radius,
        caps,
        id: Some(id),
        label: by_rule,
        ..CylinderFile::default()
    })
}

/// The table of these rows: ids moved up by one if the table counted from 0 (0 is a miss
/// in `shape_id`), then the `segment` label rule applied to the final ids.
pub(super) fn finish(
    format: TableFormat,
    mut cylinders: Vec<CylinderFile>,
    label: LabelRule,
) -> Table {
    let ids_shifted = cylinders.iter().any(|c| c.id == Some(0));
    for c in &mut cylinders {
        if ids_shifted {
            c.id = c.id.map(|i| i + 1);
        }
        if label == LabelRule::Segment {
            c.label = c.id.unwrap_or(0);
        }
    }
    Table {
        format,
        cylinders,
        ids_shifted,
    }
}

/// Read the table file at `path` (a regular file of at most
/// [`MAX_SCENE_BYTES`](crate::scene::MAX_SCENE_BYTES)): an `.npz` when it is a zip
/// archive, else UTF-8 text.
pub fn load_table(path: &std::path::Path, opts: &TableOptions) -> Result<Table, TableError> {
    let bytes = crate::scene::read_bounded(path).map_err(|e| line_err(0, e.to_string()))?;
    if npz::is_zip(&bytes) {
        return npz::read_npz(&bytes, opts);
    }
    // Binary, so before the text's checks: their "not UTF-8" would not say what is wrong.
    if bytes.starts_with(b"\x93NUMPY") {
        return Err(line_err(
            0,
            "one NumPy array (.npy); a table of arrays is an .npz archive (numpy.savez)",
        ));
    }
    if opts.format == Some(TableFormat::Npz) {
        return Err(line_err(
            0,
            "an npz table is a zip archive of NumPy arrays (numpy.savez); this file is not one",
        ));
    }
    let text = std::str::from_utf8(&bytes)
        .map_err(|e| line_err(0, format!("not UTF-8 text (byte {})", e.valid_up_to())))?;
    read_table(text, opts)
}

impl Table {
    /// A complete scene file of these cylinders with one camera framing all of them
    /// ([`crate::scene::framing::frame_all`]); the AOVs are depth, normal and shape_id,
    /// and label when any cylinder has one.
    pub fn scene_file(&self, frame: crate::scene::framing::Frame) -> SceneFile {
        self.clone().into_scene_file(frame)
    }

    /// [`Table::scene_file`] without a copy of the cylinders (millions of them take
    /// hundreds of MB).
    pub fn into_scene_file(self, frame: crate::scene::framing::Frame) -> SceneFile {
        use crate::scene::Aov;
        let mut aovs = vec![Aov::Depth, Aov::Normal, Aov::ShapeId];
        if self.cylinders.iter().any(|c| c.label != 0) {
            aovs.push(Aov::Label);
        }
        SceneFile {
            camera: Some(crate::scene::framing::frame_all(&self.cylinders, frame)),
            cameras: None,
            cylinders: self.cylinders,
            aovs: Some(aovs),
        }
    }
}
