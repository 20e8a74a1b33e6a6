//! The stress plot: per family, three log-log panels (distance error in ε, the same over
//! max(1, κ) — the backward-error ratio the bar holds at 4 — and normal angle error in
//! ε·max(1, t/r)) against the difficulty parameter, one colour per kernel. Every
//! ray is a dot; the line joins the worst ray per parameter value; the dashed line is the
//! bound (4, 4 and 16). Drawn by hand (a 3×5 pixel font, no font
//! crate) to keep `image` lean.

use crate::stress::{Family, Kernel, Record};
use image::{Rgb, RgbImage};

const PANEL_W: u32 = 360;
const PANEL_H: u32 = 190;
const MARGIN_L: u32 = 56;
const MARGIN_T: u32 = 22;
const MARGIN_B: u32 = 26;
const MARGIN_R: u32 = 14;
const LEGEND_H: u32 = 26;

fn colour(k: Kernel) -> Rgb<u8> {
    match k {
        Kernel::LiteralF32 => Rgb([240, 150, 40]),
        Kernel::LiteralF64 => Rgb([200, 30, 30]),
        Kernel::StableF32 => Rgb([60, 170, 230]),
        Kernel::StableF64 => Rgb([20, 40, 150]),
    }
}

/// Draw the figure for `families` from `records`.
pub fn plot(records: &[Record], families: &[Family]) -> RgbImage {
    let cell_w = MARGIN_L + PANEL_W + MARGIN_R;
    let cell_h = MARGIN_T + PANEL_H + MARGIN_B;
    let mut img = RgbImage::from_pixel(
        3 * cell_w,
        LEGEND_H + cell_h * families.len() as u32,
        Rgb([255, 255, 255]),
    );
    // Legend.
    let mut x = 10;
    for k in Kernel::ALL {
        fill(&mut img, x, 8, 14, 10, colour(k));
        text(
            &mut img,
            x + 20,
            8,
            &k.name().replace('/', " "),
            Rgb([0, 0, 0]),
        );
        x += 150;
    }
    text(
        &mut img,
        x,
        8,
        "DOTS: RAYS  LINE: WORST PER PARAM  DASHED: BOUND",
        Rgb([90, 90, 90]),
    );
    for (row, &fam) in families.iter().enumerate() {
        let rs: Vec<&Record> = records.iter().filter(|r| r.case.family == fam).collect();
        let y0 = LEGEND_H + row as u32 * cell_h;
        let value_t = |r: &Record| r.err_t;
        let value_n = |r: &Record| r.err_n_units;
        panel(
            &mut img,
            (0, y0),
            fam,
            &rs,
            &value_t,
            4.0,
            "DISTANCE ERR / EPS",
        );
        let value_b = |r: &Record| r.err_t / r.analysis.kappa_t.max(1.0);
        panel(
            &mut img,
            (cell_w, y0),
            fam,
            &rs,
            &value_b,
            4.0,
            "DIST ERR / (EPS MAX(1,KAPPA))",
        );
        panel(
            &mut img,
            (2 * cell_w, y0),
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
    (ox, oy): (u32, u32),
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
    let (ly0, ly1) = (floor, top);
    let (px0, py0) = (ox + MARGIN_L, oy + MARGIN_T);
    let map = |lx: f64, ly: f64| -> (i64, i64) {
        let fx = (lx - lx0) / (lx1 - lx0);
        let fy = (ly.clamp(ly0, ly1) - ly0) / (ly1 - ly0);
        (
            px0 as i64 + (fx * (PANEL_W - 1) as f64).round() as i64,
            py0 as i64 + ((1.0 - fy) * (PANEL_H - 1) as f64).round() as i64,
        )
    };
    let grey = Rgb([200, 200, 200]);
    let black = Rgb([0, 0, 0]);
    // Frame, decade grid and tick labels.
    rect(img, px0, py0, PANEL_W, PANEL_H, black);
    let xstep = if lx1 - lx0 > 12.0 { 2 } else { 1 };
    for d in (lx0.ceil() as i64..=lx1.floor() as i64).filter(|d| d % xstep == 0) {
        let (x, _) = map(d as f64, ly0);
        for y in py0 + 1..py0 + PANEL_H - 1 {
            if y % 3 == 0 {
                put(img, x, y as i64, grey);
            }
        }
        vline(img, x, (py0 + PANEL_H) as i64, 4, black);
        let label = format!("1E{d}");
        let w = 8 * label.len() as i64;
        text(
            img,
            (x - w / 2).max(0) as u32,
            py0 + PANEL_H + 6,
            &label,
            black,
        );
    }
    let ystep = ((ly1 - ly0) / 6.0).ceil().max(1.0) as i64;
    for d in (ly0 as i64..=ly1 as i64).filter(|d| (d - ly0 as i64) % ystep == 0) {
        let (_, y) = map(lx0, d as f64);
        for x in px0 + 1..px0 + PANEL_W - 1 {
            if x % 3 == 0 {
                put(img, x as i64, y, grey);
            }
        }
        for k in 0..4 {
            put(img, px0 as i64 - 1 - k, y, black);
        }
        let label = format!("1E{d}");
        let w = 8 * label.len() as u32;
        text(
            img,
            px0.saturating_sub(w + 6),
            (y - 5).max(0) as u32,
            &label,
            black,
        );
    }
    // The bound on well-conditioned rays.
    let (_, yb) = map(lx0, bound.log10());
    for x in (px0..px0 + PANEL_W).step_by(6) {
        for k in 0..3 {
            put(img, (x + k) as i64, yb, Rgb([0, 150, 0]));
        }
    }
    // Dots (kernels side by side within a decade), then the worst-per-param lines.
    for (ki, &k) in Kernel::ALL.iter().enumerate() {
        let shift = (ki as f64 - 1.5) * 0.08;
        let c = colour(k);
        let mut worst: Vec<(f64, f64)> = Vec::new();
        for &p in &params {
            let m = vals
                .iter()
                .filter(|v| v.2 == k && v.0 == p)
                .map(|v| v.1)
                .fold(f64::NAN, f64::max);
            if m.is_finite() {
                worst.push((p.log10() + shift, m.max(1e-300).log10()));
            }
        }
        for v in vals.iter().filter(|v| v.2 == k) {
            let (x, y) = map(v.0.log10() + shift, v.1.max(1e-300).log10());
            put(img, x, y, c);
        }
        for w in worst.windows(2) {
            let (a, b) = (map(w[0].0, w[0].1), map(w[1].0, w[1].1));
            line(img, a, b, c);
            line(img, (a.0, a.1 + 1), (b.0, b.1 + 1), c);
        }
        for &(lx, ly) in &worst {
            let (x, y) = map(lx, ly);
            fill(img, (x - 2).max(0) as u32, (y - 2).max(0) as u32, 5, 5, c);
        }
    }
    text(
        img,
        px0,
        oy + 6,
        &format!("{}: {}", fam.name().to_uppercase(), title),
        black,
    );
}

// ---- pixels ---------------------------------------------------------------------------

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

fn fill(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, c: Rgb<u8>) {
    for j in y..y + h {
        for i in x..x + w {
            put(img, i as i64, j as i64, c);
        }
    }
}

fn rect(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, c: Rgb<u8>) {
    for i in x..x + w {
        put(img, i as i64, y as i64, c);
        put(img, i as i64, (y + h - 1) as i64, c);
    }
    for j in y..y + h {
        put(img, x as i64, j as i64, c);
        put(img, (x + w - 1) as i64, j as i64, c);
    }
}

fn vline(img: &mut RgbImage, x: i64, y: i64, len: i64, c: Rgb<u8>) {
    for k in 0..len {
        put(img, x, y + k, c);
    }
}

/// Bresenham.
fn line(img: &mut RgbImage, (mut x0, mut y0): (i64, i64), (x1, y1): (i64, i64), c: Rgb<u8>) {
    let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
    let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
    let mut err = dx + dy;
    loop {
        put(img, x0, y0, c);
        if x0 == x1 && y0 == y1 {
            break;
        }
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            x0 += sx;
        }
        if e2 <= dx {
            err += dx;
            y0 += sy;
        }
    }
}

/// 3×5 glyphs, rows top to bottom, bit 2 = left column.
fn glyph(ch: char) -> [u8; 5] {
    match ch.to_ascii_uppercase() {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        '.' => [0, 0, 0, 0, 2],
        ',' => [0, 0, 0, 2, 4],
        ':' => [0, 2, 0, 2, 0],
        '/' => [1, 1, 2, 4, 4],
        '(' => [2, 4, 4, 4, 2],
        ')' => [2, 1, 1, 1, 2],
        '=' => [0, 7, 0, 7, 0],
        'A' => [2, 5, 7, 5, 5],
        'B' => [6, 5, 6, 5, 6],
        'C' => [3, 4, 4, 4, 3],
        'D' => [6, 5, 5, 5, 6],
        'E' => [7, 4, 6, 4, 7],
        'F' => [7, 4, 6, 4, 4],
        'G' => [3, 4, 5, 5, 3],
        'H' => [5, 5, 7, 5, 5],
        'I' => [7, 2, 2, 2, 7],
        'J' => [1, 1, 1, 5, 2],
        'K' => [5, 5, 6, 5, 5],
        'L' => [4, 4, 4, 4, 7],
        'M' => [5, 7, 7, 5, 5],
        'N' => [6, 5, 5, 5, 5],
        'O' => [2, 5, 5, 5, 2],
        'P' => [6, 5, 6, 4, 4],
        'Q' => [2, 5, 5, 6, 3],
        'R' => [6, 5, 6, 5, 5],
        'S' => [3, 4, 2, 1, 6],
        'T' => [7, 2, 2, 2, 2],
        'U' => [5, 5, 5, 5, 7],
        'V' => [5, 5, 5, 5, 2],
        'W' => [5, 5, 7, 7, 5],
        'X' => [5, 5, 2, 5, 5],
        'Y' => [5, 5, 2, 2, 2],
        'Z' => [7, 1, 2, 4, 7],
        _ => [0; 5],
    }
}

/// Text at 2× scale (6×10 px glyphs, 8 px advance).
fn text(img: &mut RgbImage, x: u32, y: u32, s: &str, c: Rgb<u8>) {
    for (i, ch) in s.chars().enumerate() {
        let g = glyph(ch);
        let gx = x + 8 * i as u32;
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    fill(img, gx + 2 * col, y + 2 * row as u32, 2, 2, c);
                }
            }
        }
    }
}
