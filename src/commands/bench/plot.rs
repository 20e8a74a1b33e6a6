//! The bench figure, two log-log panels drawn with [`crate::output::format::plot`]:
//! (a) the Pareto view: error against build + trace time at one cylinder count (1 000, or
//! the nearest count run), one point per kernel: filled = max error, open = median;
//! (b) build + trace time against cylinder count, one line per kernel, with Mitsuba's warm
//! (second) render and whole process as extra lines when it was run; dashed lines are whole
//! processes (cylaov's default kernel and Mitsuba), the numbers the speed targets compare;
//! (c) the same for the dense scene family, when it was run. Panels (a) and (b) show the
//! first family run.

use crate::bench::{AnchorRow, Row};
use crate::geometry::{FormulaKind, Kernel, Precision};
use crate::output::format::plot::{self, Axis, BLACK, Grid, Marker, NOTE};
use image::{Rgb, RgbImage};

/// Two panels side by side; the legend band is sized in [`plot`].
const GRID: Grid = Grid {
    panel: (440, 300),
    margin: [64, 26, 24, 40],
    legend_h: 0,
};
/// One legend row: 10 px glyphs and swatches plus the gap to the next.
const LEGEND_ROW: u32 = 20;

/// Where an error of exactly 0 (the reference kernel against itself) is drawn: below any
/// f64 rounding error, so it reads as "at the bottom" without breaking the log axis.
const ERR_FLOOR: f64 = 1e-17;
const ERR_FLOOR_NOTE: &str = "ERROR 0 DRAWN AT 1E-17";

/// The count of the Pareto panel: the 1 000-cylinder scene.
const PARETO_COUNT: usize = 1000;

fn colour(k: Kernel) -> Rgb<u8> {
    plot::kernel_colour(
        k.formula == FormulaKind::Literal,
        k.precision == Precision::F64,
    )
}

/// Anchor renderers get their own colours (not a kernel's).
fn anchor_colour(variant: &str) -> Rgb<u8> {
    if variant.starts_with("llvm") {
        Rgb([150, 60, 170])
    } else if variant == crate::bench::OPEN3D {
        Rgb([200, 130, 0])
    } else {
        Rgb([110, 110, 110])
    }
}

/// An anchor's legend label: `MITSUBA LLVM_AD_RGB`, `OPEN3D EMBREE (16-SEGMENT MESHES)`.
fn anchor_label(variant: &str) -> String {
    if variant == crate::bench::OPEN3D {
        "OPEN3D EMBREE (16-SEGMENT MESHES)".into()
    } else {
        format!("MITSUBA {}", variant.to_uppercase())
    }
}

/// Draw the figure from the table's rows (the depth+normal ones are used) and Mitsuba's.
pub fn plot(rows: &[Row], mitsuba: &[AnchorRow], kernels: &[Kernel]) -> RgbImage {
    let first = rows.first().map(|r| r.family.clone()).unwrap_or_default();
    let dense = "dense";
    let dn: Vec<&Row> = rows
        .iter()
        .filter(|r| r.is_depth_normal() && r.family == first)
        .collect();
    let dense_rows: Vec<&Row> = rows
        .iter()
        .filter(|r| r.is_depth_normal() && r.family == dense && first != dense)
        .collect();
    let kernels: Vec<(Kernel, String)> = kernels
        .iter()
        .map(|&k| (k, k.to_string()))
        .filter(|(_, name)| dn.iter().any(|r| &r.kernel == name))
        .collect();
    let mut variants: Vec<&str> = Vec::new();
    for m in mitsuba {
        if !variants.contains(&m.variant.as_str()) {
            variants.push(&m.variant);
        }
    }
    // Legend rows: kernels, Mitsuba's variants (if run), the key to markers and dashes.
    let legend_rows = if variants.is_empty() { 2 } else { 3 };
    let legend_h = 8 + legend_rows * LEGEND_ROW;
    let grid = Grid { legend_h, ..GRID };
    // Time against error compares kernels: with one (`--quick`) there is nothing to
    // compare, and the figure is the scaling panels alone.
    let compare = kernels.len() >= 2;
    let first_col = u32::from(compare);
    let mut img = grid.image(first_col + if dense_rows.is_empty() { 1 } else { 2 }, 1);
    legend_row(
        &mut img,
        8,
        kernels.iter().map(|(k, n)| (colour(*k), n.to_uppercase())),
    );
    legend_row(
        &mut img,
        8 + LEGEND_ROW as i64,
        variants.iter().map(|v| (anchor_colour(v), anchor_label(v))),
    );
    let key = "SOLID: BUILD+TRACE (MITSUBA, OPEN3D: WARM RENDER), DASHED: WHOLE PROCESS";
    let key = if compare {
        format!("(A) FILLED: MAX, OPEN: MEDIAN   (B), (C) {key}")
    } else {
        key.to_string()
    };
    plot::text(
        &mut img,
        10,
        8 + (legend_rows - 1) as i64 * LEGEND_ROW as i64,
        2,
        &key,
        NOTE,
    );

    if compare {
        pareto(&mut img, &grid, &dn, &kernels);
    }
    let of = |f: &str| -> Vec<AnchorRow> {
        // Rows from before families were recorded read as the first family.
        let f = f.to_string();
        mitsuba
            .iter()
            .filter(|m| m.family == f || (m.family.is_empty() && f == first))
            .cloned()
            .collect()
    };
    let title = |f: &str| match f {
        "" => String::new(),
        f => format!("{}: ", f.to_uppercase()),
    };
    let panels = [(&dn, first.as_str()), (&dense_rows, dense)];
    for (k, (rows, family)) in panels.into_iter().enumerate() {
        if !rows.is_empty() || k == 0 {
            let col = first_col + k as u32;
            let tag = ["(A)", "(B)", "(C)"][col as usize];
            let title = format!("{tag} {}MS VS CYLINDER COUNT, DEPTH+NORMAL", title(family));
            scaling(
                &mut img,
                &grid,
                col,
                &title,
                rows,
                &of(family),
                &kernels,
                &variants,
            );
        }
    }
    img
}

/// Swatch-and-label entries left to right at height `y`.
fn legend_row(img: &mut RgbImage, y: i64, entries: impl Iterator<Item = (Rgb<u8>, String)>) {
    let mut x = 10;
    for (c, label) in entries {
        x = plot::legend_entry(img, x, y, c, &label) + 24;
    }
}

/// (a) Error against time at [`PARETO_COUNT`] cylinders (or the nearest count run).
fn pareto(img: &mut RgbImage, grid: &Grid, dn: &[&Row], kernels: &[(Kernel, String)]) {
    let log_distance = |n: usize| ((n.max(1) as f64) / PARETO_COUNT as f64).log10().abs();
    let Some(n) = dn
        .iter()
        .map(|r| r.cylinders)
        .min_by(|a, b| log_distance(*a).total_cmp(&log_distance(*b)))
    else {
        return;
    };
    let pts: Vec<(&Row, Rgb<u8>)> = kernels
        .iter()
        .filter_map(|(k, name)| {
            let r = dn.iter().find(|r| r.cylinders == n && &r.kernel == name)?;
            Some((*r, colour(*k)))
        })
        .filter(|(r, _)| r.err_max.is_finite() && r.err_median.is_finite())
        .collect();
    let err = |e: f64| e.max(ERR_FLOOR);
    let p = grid.panel(
        0,
        0,
        Axis::log_fit(pts.iter().map(|(r, _)| r.render_ms())),
        Axis::log_fit(
            pts.iter()
                .flat_map(|(r, _)| [err(r.err_max), err(r.err_median)]),
        ),
    );
    p.axes(img);
    let reference = Kernel::STABLE_F64.to_string();
    // Label boxes placed so far (x, y, width): a label that would overlap one moves up.
    let mut placed: Vec<(i64, i64, i64)> = Vec::new();
    for (r, _) in &pts {
        let hi = p.pos(r.render_ms(), err(r.err_max));
        let mut label = r.kernel.to_uppercase();
        if r.kernel == reference {
            label += " (REFERENCE)";
        } else if r.err_max == 0.0 {
            // Not exact: its distances round to the reference's f32 values.
            label += " (ERR 0)";
        }
        // Right of the point, or left of it where the frame would cut the label.
        let w = plot::text_width(&label, 2);
        let lx = if hi.0 + 6 + w < p.x + p.w as i64 {
            hi.0 + 6
        } else {
            hi.0 - 6 - w
        };
        let mut ly = hi.1 - 5;
        while placed
            .iter()
            .any(|&(x, y, pw)| lx < x + pw && x < lx + w && (ly - y).abs() < 12)
        {
            ly -= 12;
        }
        placed.push((lx, ly, w));
        plot::text(img, lx, ly, 2, &label, BLACK);
    }
    // Markers over the labels: a label may cross another kernel's point.
    for (r, c) in &pts {
        let x = r.render_ms();
        plot::marker(img, p.pos(x, err(r.err_median)), Marker::Open, *c);
        plot::marker(img, p.pos(x, err(r.err_max)), Marker::Square, *c);
    }
    if pts.len() < 2 {
        // Kernels were run, but fewer than two have finite errors at this count.
        let lines = [
            "FEWER THAN TWO KERNELS HAVE",
            "ERRORS AT THIS COUNT: NOTHING",
            "TO COMPARE.",
        ];
        let y0 = p.y + p.h as i64 / 2 + 14;
        for (i, l) in lines.iter().enumerate() {
            plot::text(img, p.x + 10, y0 + 12 * i as i64, 2, l, NOTE);
        }
    }
    // Under the tick labels, left; the axis name is on the right.
    plot::text(img, p.x, p.y + p.h as i64 + 20, 2, ERR_FLOOR_NOTE, NOTE);
    p.title(
        img,
        &format!("(A) DISTANCE ERROR VS TIME, {n} CYL., DEPTH+NORMAL"),
    );
    p.x_label(img, "BUILD+TRACE MS");
}

/// One line of panel (b): (cylinders, ms) points in count order.
struct Line {
    pts: Vec<(f64, f64)>,
    colour: Rgb<u8>,
    /// A whole process (as opposed to build + trace, or Mitsuba's warm render).
    dashed: bool,
}

impl Line {
    /// Times that were not measured (Mitsuba's `process_s` of 0 in an old CSV) are dropped.
    fn new(pts: impl Iterator<Item = (f64, f64)>, colour: Rgb<u8>, dashed: bool) -> Line {
        let mut pts: Vec<(f64, f64)> = pts.filter(|q| q.1 > 0.0 && q.1.is_finite()).collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        Line {
            pts,
            colour,
            dashed,
        }
    }
}

/// (b), (c): time against cylinder count, one line per kernel, plus Mitsuba and whole
/// processes, in panel column `col`.
#[allow(clippy::too_many_arguments)]
fn scaling(
    img: &mut RgbImage,
    grid: &Grid,
    col: u32,
    title: &str,
    dn: &[&Row],
    mitsuba: &[AnchorRow],
    kernels: &[(Kernel, String)],
    variants: &[&str],
) {
    let of_kernel = |name: String| dn.iter().filter(move |r| r.kernel == name);
    let of_variant = |v: String| mitsuba.iter().filter(move |m| m.variant == v);
    let mut lines = Vec::new();
    for (k, name) in kernels {
        let pts = of_kernel(name.clone()).map(|r| (r.cylinders as f64, r.render_ms()));
        lines.push(Line::new(pts, colour(*k), false));
    }
    let default = Kernel::STABLE_F64.to_string();
    if kernels.iter().any(|(_, name)| *name == default) {
        let pts = of_kernel(default).filter_map(|r| Some((r.cylinders as f64, r.process_ms?)));
        lines.push(Line::new(pts, colour(Kernel::ALL[0]), true));
    }
    for v in variants {
        let c = anchor_colour(v);
        let warm = of_variant(v.to_string()).map(|m| (m.cylinders as f64, m.render2_s * 1e3));
        lines.push(Line::new(warm, c, false));
        let process = of_variant(v.to_string()).map(|m| (m.cylinders as f64, m.process_s * 1e3));
        lines.push(Line::new(process, c, true));
    }
    let all = || lines.iter().flat_map(|l| l.pts.iter());
    let p = grid.panel(
        col,
        0,
        Axis::log_fit(all().map(|q| q.0)),
        Axis::log_fit(all().map(|q| q.1)),
    );
    p.axes(img);
    for Line {
        pts,
        colour: c,
        dashed,
    } in &lines
    {
        let px: Vec<(i64, i64)> = pts.iter().map(|q| p.pos(q.0, q.1)).collect();
        for w in px.windows(2) {
            plot::thick_line(img, w[0], w[1], dashed.then_some((6, 4)), *c);
        }
        let m = if *dashed {
            Marker::Open
        } else {
            Marker::Square
        };
        for &q in &px {
            plot::marker(img, q, m, *c);
        }
    }
    p.title(img, title);
    p.x_label(img, "CYLINDERS");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(n: usize, k: Kernel, aovs: &str, ms: f64, err: f64) -> Row {
        Row {
            family: "sparse".into(),
            cylinders: n,
            kernel: k.to_string(),
            aovs: aovs.into(),
            parse_ms: ms / 20.0,
            prepare_ms: ms / 20.0,
            build_ms: ms / 10.0,
            trace_ms: ms,
            write_ms: 1.0,
            total_ms: ms + 1.0,
            mrays_per_s: 1.0,
            process_ms: Some(ms * 3.0),
            peak_mib: None,
            err_median: err / 10.0,
            err_max: err,
            mismatches: 0,
        }
    }

    fn count(img: &RgbImage, c: Rgb<u8>) -> usize {
        img.pixels().filter(|p| **p == c).count()
    }

    #[test]
    fn draws_kernels_and_anchors_and_survives_empty_input() {
        let mut rows = Vec::new();
        for n in [1, 100, 1000] {
            rows.push(row(n, Kernel::ALL[0], "depth+normal", n as f64, 0.0));
            rows.push(row(n, Kernel::ALL[1], "depth+normal", n as f64 / 2.0, 1e-6));
            // Other AOV sets are not drawn.
            rows.push(row(n, Kernel::ALL[3], "depth", 1.0, 1e-3));
        }
        let mi = AnchorRow {
            family: "sparse".into(),
            cylinders: 100,
            variant: "llvm_ad_rgb".into(),
            import_s: 0.1,
            load_s: 0.1,
            render1_s: 0.5,
            write_s: 0.1,
            render2_s: 0.3,
            process_s: 1.0,
            hits: None,
        };
        let img = plot(
            &rows,
            &[
                mi.clone(),
                AnchorRow {
                    cylinders: 1000,
                    ..mi.clone()
                },
                AnchorRow {
                    variant: crate::bench::OPEN3D.into(),
                    render2_s: 0.05,
                    ..mi.clone()
                },
                AnchorRow {
                    variant: crate::bench::OPEN3D.into(),
                    cylinders: 1000,
                    render2_s: 0.1,
                    ..mi
                },
            ],
            &Kernel::ALL,
        );
        assert!(count(&img, colour(Kernel::ALL[0])) > 100);
        assert!(count(&img, colour(Kernel::ALL[1])) > 100);
        assert_eq!(count(&img, colour(Kernel::ALL[3])), 0);
        assert!(count(&img, anchor_colour("llvm_ad_rgb")) > 100);
        assert!(count(&img, anchor_colour(crate::bench::OPEN3D)) > 100);

        let empty = plot(&[], &[], &Kernel::ALL);
        assert_eq!(count(&empty, colour(Kernel::ALL[0])), 0);
        // One kernel (`--quick`): no empty time-against-error panel, the scaling one alone.
        let one: Vec<Row> = rows
            .iter()
            .filter(|r| r.kernel == Kernel::ALL[0].to_string())
            .cloned()
            .collect();
        let (cell_w, _) = GRID.cell();
        assert_eq!(img.width(), 2 * cell_w);
        assert_eq!(plot(&one, &[], &Kernel::ALL).width(), cell_w);
    }
}
