//! The stress plot: per family, three log-log panels (distance error in ε, the same over
//! max(1, κ) — the backward-error ratio the bar holds at 4 — and normal angle error in
//! ε·max(1, t/r)) against the difficulty parameter, one colour per kernel. Every
//! ray is a dot; the line joins the worst ray per parameter value; the dashed line is the
//! bound (4, 4 and 16). Drawn with [`crate::output::format::plot`].

use crate::geometry::{FormulaKind, Kernel};
use crate::output::format::plot::{self, Axis, BOUND, Grid, Marker, NOTE};
use crate::verify::stress::{Family, Record, TABLE_ORDER};
use image::{Rgb, RgbImage};

/// Three panels a row, one row a family, under a one-line legend.
const GRID: Grid = Grid {
    panel: (360, 190),
    margin: [56, 22, 14, 36],
    legend_h: 26,
};

fn colour(k: Kernel) -> Rgb<u8> {
    plot::kernel_colour(k.formula == FormulaKind::Literal, !k.is_f32())
}

/// Draw the figure for `families` from `records`.
pub fn plot(records: &[Record], families: &[Family]) -> RgbImage {
    let mut img = GRID.image(3, families.len() as u32);
    let mut x = 10;
    for k in TABLE_ORDER {
        let label = k.to_string().replace('-', " ").to_uppercase();
        plot::legend_entry(&mut img, x, 8, colour(k), &label);
        x += 150;
    }
    plot::text(
        &mut img,
        x,
        8,
        2,
        "DOTS: RAYS  LINE: WORST PER PARAM  DASHED: BOUND",
        NOTE,
    );
    for (row, &fam) in families.iter().enumerate() {
        let rs: Vec<&Record> = records.iter().filter(|r| r.case.family == fam).collect();
        let value_t = |r: &Record| r.err_t;
        let value_n = |r: &Record| r.err_n_units;
        panel(
            &mut img,
            (0, row as u32),
            fam,
            &rs,
            &value_t,
            4.0,
            "DISTANCE ERR / EPS",
        );
        let value_b = |r: &Record| r.err_t / r.analysis.kappa_t.max(1.0);
        panel(
            &mut img,
            (1, row as u32),
            fam,
            &rs,
            &value_b,
            4.0,
            "DIST ERR / (EPS MAX(1,KAPPA))",
        );
        panel(
            &mut img,
            (2, row as u32),
            fam,
            &rs,
            &value_n,
            16.0,
            "NORMAL ERR / (EPS MAX(1,T/R))",
        );
    }
    img
}

fn panel(
    img: &mut RgbImage,
    (col, row): (u32, u32),
    fam: Family,
    rs: &[&Record],
    value: &dyn Fn(&Record) -> f64,
    bound: f64,
    title: &str,
) {
    let params = fam.params();
    let lx0 = params.first().copied().unwrap_or(1.0).log10().floor() - 0.5;
    let lx1 = params.last().copied().unwrap_or(10.0).log10().ceil() + 0.5;
    // Values out of the band where both hit; zeros plot on the floor.
    let floor = -2.0f64;
    let vals: Vec<(f64, f64, Kernel)> = rs
        .iter()
        .filter(|r| !r.analysis.band() && value(r).is_finite())
        .map(|r| (r.case.param, value(r), r.kernel))
        .collect();
    let top = vals
        .iter()
        .map(|v| v.1.max(1e-300).log10())
        .fold(3.0f64, f64::max)
        .ceil()
        .min(18.0);
    let xa = Axis::log(lx0, lx1).with_step(if lx1 - lx0 > 12.0 { 2.0 } else { 1.0 });
    let p = GRID.panel(col, row, xa, Axis::log(floor, top));
    p.axes(img);
    // The bound on well-conditioned rays.
    p.bound(img, bound, BOUND);
    // Dots (kernels side by side within a decade), then the worst-per-param lines.
    for (ki, &k) in Kernel::ALL.iter().enumerate() {
        let shift = (ki as f64 - 1.5) * 0.08;
        let c = colour(k);
        let mut worst: Vec<(f64, f64)> = Vec::new();
        for &param in &params {
            let m = vals
                .iter()
                .filter(|v| v.2 == k && v.0 == param)
                .map(|v| v.1)
                .fold(f64::NAN, f64::max);
            if m.is_finite() {
                worst.push((param.log10() + shift, m.max(1e-300).log10()));
            }
        }
        for v in vals.iter().filter(|v| v.2 == k) {
            let (x, y) = p.at(v.0.log10() + shift, v.1.max(1e-300).log10());
            plot::put(img, x, y, c);
        }
        for w in worst.windows(2) {
            plot::thick_line(img, p.at(w[0].0, w[0].1), p.at(w[1].0, w[1].1), None, c);
        }
        for &(lx, ly) in &worst {
            plot::marker(img, p.at(lx, ly), Marker::Square, c);
        }
    }
    p.title(img, &format!("{}: {}", fam.name().to_uppercase(), title));
    p.x_label(img, x_name(fam));
}

/// The difficulty parameter on each family's x axis, short enough for a panel (the CSV's
/// `param` column; `Family::param_name` says it in full).
fn x_name(fam: Family) -> &'static str {
    match fam {
        Family::Grazing => "X: GAP FROM TANGENCY (P-R)/R",
        Family::NearAxis => "X: RAY-AXIS ANGLE (RAD)",
        Family::Far => "X: DISTANCE IN RADII",
        Family::Scale => "X: RADIUS (CAMERA AT 5 RADII)",
        Family::Inside => "X: CAMERA-SURFACE GAP (RHO-R)/R",
        Family::Rims => "X: AIM OFFSET FROM RIM, RADII",
        Family::Input => "X: COORDINATE MAGNITUDE",
    }
}
