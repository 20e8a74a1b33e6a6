//! Drawing for the PNG figures (depth legend, `stress --plot`, `bench --plot`): a 3×5 pixel
//! font, a few clipped primitives, and a log/lin axis panel. Drawn by hand so that `image`
//! (PNG only) stays the one graphics dependency: no font or plotting crate.
//!
//! Coordinates are pixels, `i64` so that shapes may hang off any edge: every primitive
//! clips through [`put`].

use image::{Rgb, RgbImage};

/// Frames, ticks and text.
pub const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
/// Figure background (and text on dark images).
pub const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
/// The dotted grid lines at the ticks of a panel.
pub const GRID: Rgb<u8> = Rgb([200, 200, 200]);
/// Secondary text: axis names and notes under a panel.
pub const NOTE: Rgb<u8> = Rgb([90, 90, 90]);
/// Bound lines (the dashed "must stay under" line of a panel).
pub const BOUND: Rgb<u8> = Rgb([0, 150, 0]);

/// One colour per kernel, shared by the stress and bench figures so a kernel reads the same
/// in both: literal warm, stable cool, f64 the darker shade.
pub fn kernel_colour(literal: bool, f64: bool) -> Rgb<u8> {
    match (literal, f64) {
        (true, false) => Rgb([240, 150, 40]),
        (true, true) => Rgb([200, 30, 30]),
        (false, false) => Rgb([60, 170, 230]),
        (false, true) => Rgb([20, 40, 150]),
    }
}

// ---- pixels -----------------------------------------------------------------------------

/// One pixel; outside the image it is dropped.
pub fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// A filled `w`×`h` rectangle with its top-left pixel at (x, y).
pub fn fill(img: &mut RgbImage, x: i64, y: i64, w: u32, h: u32, c: Rgb<u8>) {
    for j in y..y + h as i64 {
        for i in x..x + w as i64 {
            put(img, i, j, c);
        }
    }
}

/// A one-pixel outline.
pub fn rect(img: &mut RgbImage, x: i64, y: i64, w: u32, h: u32, c: Rgb<u8>) {
    let (x1, y1) = (x + w as i64 - 1, y + h as i64 - 1);
    for i in x..=x1 {
        put(img, i, y, c);
        put(img, i, y1, c);
    }
    for j in y..=y1 {
        put(img, x, j, c);
        put(img, x1, j, c);
    }
}

/// Bresenham from `a` to `b`, both ends included, dashed: `on` pixels drawn, `off`
/// skipped, starting with a dash at `a` (`(1, 0)` is a solid line).
pub fn dashed_line(
    img: &mut RgbImage,
    a: (i64, i64),
    b: (i64, i64),
    (on, off): (u64, u64),
    c: Rgb<u8>,
) {
    let ((mut x0, mut y0), (x1, y1)) = (a, b);
    let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
    let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
    let mut err = dx + dy;
    for k in 0u64.. {
        if k % (on + off) < on {
            put(img, x0, y0, c);
        }
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

/// A two-pixel-high line (the data lines of a panel), solid or `(on, off)` dashed.
pub fn thick_line(
    img: &mut RgbImage,
    a: (i64, i64),
    b: (i64, i64),
    dash: Option<(u64, u64)>,
    c: Rgb<u8>,
) {
    let dash = dash.unwrap_or((1, 0));
    dashed_line(img, a, b, dash, c);
    dashed_line(img, (a.0, a.1 + 1), (b.0, b.1 + 1), dash, c);
}

/// Point markers, 5×5 around the point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    /// A filled square.
    Square,
    /// An outline: a second value at the same point (e.g. the median beside the max).
    Open,
}

/// A marker of kind `m` centred on pixel (x, y).
pub fn marker(img: &mut RgbImage, (x, y): (i64, i64), m: Marker, c: Rgb<u8>) {
    match m {
        Marker::Square => fill(img, x - 2, y - 2, 5, 5, c),
        Marker::Open => rect(img, x - 2, y - 2, 5, 5, c),
    }
}

// ---- text -------------------------------------------------------------------------------

/// 3×5 glyphs, rows top to bottom, bit 2 = left column. Lowercase draws as capitals except
/// `e`, which has a small glyph so exponents (`1.5e-3`) read as numbers.
pub fn glyph(ch: char) -> [u8; 5] {
    if ch == 'e' {
        return [0, 7, 7, 4, 7];
    }
    match ch.to_ascii_uppercase() {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        // A rounded top, so `2` is not read as the flat-topped `Z`.
        '2' => [2, 5, 1, 2, 7],
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
        '_' => [0, 0, 0, 0, 7],
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

/// Width of `s` drawn at `scale`: 4 columns per glyph (3 + a gap).
pub fn text_width(s: &str, scale: u32) -> i64 {
    4 * scale as i64 * s.chars().count() as i64
}

/// `s` with its top-left corner at (x, y), each font pixel a `scale`×`scale` square.
pub fn text(img: &mut RgbImage, x: i64, y: i64, scale: u32, s: &str, c: Rgb<u8>) {
    let k = scale as i64;
    for (n, ch) in s.chars().enumerate() {
        let gx = x + 4 * k * n as i64;
        for (row, bits) in glyph(ch).iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    fill(img, gx + k * col, y + k * row as i64, scale, scale, c);
                }
            }
        }
    }
}

/// Scale of all figure text (6×10 px glyphs).
const S: u32 = 2;

/// A legend entry at (x, y): a colour swatch and its label; returns the x just past it.
pub fn legend_entry(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>, label: &str) -> i64 {
    fill(img, x, y, 14, 10, c);
    text(img, x + 20, y, S, label, BLACK);
    x + 20 + text_width(label, S)
}

// ---- panels -----------------------------------------------------------------------------

/// One axis of a [`Panel`], in axis units: decades (log10 of the value) on a log axis, the
/// value itself on a linear one. Ticks every `step` units from the first whole unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Axis {
    /// Low end of the range, axis units (left or bottom of the panel).
    pub lo: f64,
    /// High end of the range, axis units (right or top of the panel).
    pub hi: f64,
    /// Logarithmic (axis units are decades) rather than linear.
    pub log: bool,
    /// Distance between ticks, axis units.
    pub step: f64,
}

impl Axis {
    /// Decades `lo..hi`, a tick every `ceil(span / 6)` decades.
    pub fn log(lo: f64, hi: f64) -> Axis {
        let step = ((hi - lo) / 6.0).ceil().max(1.0);
        Axis {
            lo,
            hi,
            log: true,
            step,
        }
    }

    /// The whole decades around `values` (positive, finite ones; zeros and NaN are left to
    /// the caller's floor), with at least one decade of span.
    pub fn log_fit(values: impl IntoIterator<Item = f64>) -> Axis {
        let (lo, hi) = values
            .into_iter()
            .filter(|v| *v > 0.0 && v.is_finite())
            .map(f64::log10)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            });
        if !lo.is_finite() {
            return Axis::log(0.0, 1.0);
        }
        // A tenth of a decade of air so no point sits on the frame.
        let (lo, hi) = ((lo - 0.1).floor(), (hi + 0.1).ceil());
        Axis::log(lo, hi.max(lo + 1.0))
    }

    /// Values `lo..hi`, a tick every `step`.
    pub fn lin(lo: f64, hi: f64, step: f64) -> Axis {
        Axis {
            lo,
            hi,
            log: false,
            step,
        }
    }

    /// The same axis with a tick every `step` axis units.
    pub fn with_step(self, step: f64) -> Axis {
        Axis { step, ..self }
    }

    /// A data value in axis units; on a log axis, non-positive values go far below the range
    /// (and are clamped onto its floor when drawn).
    pub fn to_axis(&self, v: f64) -> f64 {
        if self.log { v.max(1e-300).log10() } else { v }
    }

    /// Tick positions in axis units.
    fn ticks(&self) -> Vec<f64> {
        let first = if self.log {
            self.lo.ceil()
        } else {
            (self.lo / self.step).ceil() * self.step
        };
        let mut t = Vec::new();
        let mut k = 0.0;
        while first + k * self.step <= self.hi + 1e-9 * self.step {
            t.push(first + k * self.step);
            k += 1.0;
        }
        t
    }

    fn label(&self, u: f64) -> String {
        if self.log {
            format!("1E{}", u.round() as i64)
        } else {
            format!("{}", (u / self.step).round() * self.step)
        }
    }
}

/// A figure laid out as a grid of equal cells under a legend band: each cell is a panel with
/// room around it for its title (top), tick labels (left, bottom) and some air (right).
#[derive(Clone, Copy, Debug)]
pub struct Grid {
    /// Plot area of every panel, pixels.
    pub panel: (u32, u32),
    /// Around each panel: left, top, right, bottom.
    pub margin: [u32; 4],
    /// The legend band above the cells.
    pub legend_h: u32,
}

impl Grid {
    /// Size of one cell in pixels: the panel plus its margins.
    pub fn cell(&self) -> (u32, u32) {
        let [l, t, r, b] = self.margin;
        (l + self.panel.0 + r, t + self.panel.1 + b)
    }

    /// A white image of `cols`×`rows` cells and the legend band.
    pub fn image(&self, cols: u32, rows: u32) -> RgbImage {
        let (w, h) = self.cell();
        RgbImage::from_pixel(cols * w, self.legend_h + rows * h, WHITE)
    }

    /// The panel of cell (`col`, `row`) with these axes.
    pub fn panel(&self, col: u32, row: u32, xa: Axis, ya: Axis) -> Panel {
        let (w, h) = self.cell();
        Panel {
            x: (col * w + self.margin[0]) as i64,
            y: (self.legend_h + row * h + self.margin[1]) as i64,
            w: self.panel.0,
            h: self.panel.1,
            xa,
            ya,
        }
    }
}

/// A plot area: its top-left pixel, size and two axes. Draw the frame with [`Panel::axes`],
/// then data with [`Panel::pos`] (data values) or [`Panel::at`] (axis units).
#[derive(Clone, Copy, Debug)]
pub struct Panel {
    /// Left column of the plot area, pixels.
    pub x: i64,
    /// Top row of the plot area, pixels.
    pub y: i64,
    /// Width of the plot area (frame included), pixels.
    pub w: u32,
    /// Height of the plot area (frame included), pixels.
    pub h: u32,
    /// Horizontal axis.
    pub xa: Axis,
    /// Vertical axis (its `lo` at the bottom).
    pub ya: Axis,
}

impl Panel {
    /// Axis units to pixels; clamped onto the frame, so a floor value sits on the bottom edge.
    pub fn at(&self, u: f64, v: f64) -> (i64, i64) {
        let fx = (u.clamp(self.xa.lo, self.xa.hi) - self.xa.lo) / (self.xa.hi - self.xa.lo);
        let fy = (v.clamp(self.ya.lo, self.ya.hi) - self.ya.lo) / (self.ya.hi - self.ya.lo);
        (
            self.x + (fx * (self.w - 1) as f64).round() as i64,
            self.y + ((1.0 - fy) * (self.h - 1) as f64).round() as i64,
        )
    }

    /// Data values to pixels.
    pub fn pos(&self, x: f64, y: f64) -> (i64, i64) {
        self.at(self.xa.to_axis(x), self.ya.to_axis(y))
    }

    /// Frame, dotted grid at the ticks, tick marks and labels (below and left of the frame).
    pub fn axes(&self, img: &mut RgbImage) {
        let (x0, y0, w, h) = (self.x, self.y, self.w as i64, self.h as i64);
        rect(img, x0, y0, self.w, self.h, BLACK);
        for u in self.xa.ticks() {
            let (x, _) = self.at(u, self.ya.lo);
            for y in (y0 + 1..y0 + h - 1).filter(|y| y % 3 == 0) {
                put(img, x, y, GRID);
            }
            for k in 0..4 {
                put(img, x, y0 + h + k, BLACK);
            }
            let label = self.xa.label(u);
            let lw = text_width(&label, S);
            text(img, (x - lw / 2).max(0), y0 + h + 6, S, &label, BLACK);
        }
        for v in self.ya.ticks() {
            let (_, y) = self.at(self.xa.lo, v);
            for x in (x0 + 1..x0 + w - 1).filter(|x| x % 3 == 0) {
                put(img, x, y, GRID);
            }
            for k in 0..4 {
                put(img, x0 - 1 - k, y, BLACK);
            }
            let label = self.ya.label(v);
            let lw = text_width(&label, S);
            text(img, (x0 - lw - 6).max(0), (y - 5).max(0), S, &label, BLACK);
        }
    }

    /// The title, above the frame.
    pub fn title(&self, img: &mut RgbImage, s: &str) {
        text(img, self.x, self.y - 16, S, s, BLACK);
    }

    /// The x-axis name, right-aligned under the tick labels.
    pub fn x_label(&self, img: &mut RgbImage, s: &str) {
        let x = self.x + self.w as i64 - text_width(s, S);
        text(img, x, self.y + self.h as i64 + 20, S, s, NOTE);
    }

    /// A dashed horizontal line across the panel at data value `y` (a bound).
    pub fn bound(&self, img: &mut RgbImage, y: f64, c: Rgb<u8>) {
        let (_, yb) = self.pos(self.xa.hi, y);
        let (x0, x1) = (self.x, self.x + self.w as i64 - 1);
        dashed_line(img, (x0, yb), (x1, yb), (3, 3), c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// How many of the 15 font pixels two glyphs differ in.
    fn differ(a: char, b: char) -> u32 {
        glyph(a)
            .iter()
            .zip(glyph(b))
            .map(|(x, y)| (x ^ y).count_ones())
            .sum()
    }

    #[test]
    fn every_digit_and_letter_has_its_own_glyph() {
        let chars: Vec<char> = ('0'..='9').chain('A'..='Z').collect();
        for (i, &a) in chars.iter().enumerate() {
            assert_ne!(glyph(a), [0; 5], "{a} has no glyph");
            for &b in &chars[i + 1..] {
                assert!(differ(a, b) >= 1, "{a} and {b} share a glyph");
            }
        }
        // `Z` beside a digit (the depth preview's "DEPTH Z") must not read as `2`: they
        // differ in the top row's shape and the middle, 4 pixels.
        assert!(differ('2', 'Z') >= 4, "{}", differ('2', 'Z'));
    }

    #[test]
    fn log_ticks_start_at_the_first_decade() {
        let a = Axis::log(-16.5, -0.5).with_step(2.0);
        assert_eq!(
            a.ticks(),
            vec![-16.0, -14.0, -12.0, -10.0, -8.0, -6.0, -4.0, -2.0]
        );
        assert_eq!(a.label(-16.0), "1E-16");
    }

    #[test]
    fn log_fit_spans_a_decade_and_skips_zeros() {
        let a = Axis::log_fit([0.0, 2.0, 3.0]);
        assert_eq!((a.lo, a.hi), (0.0, 1.0));
        let b = Axis::log_fit([1e-3, 5e2]);
        assert_eq!((b.lo, b.hi), (-4.0, 3.0));
    }

    #[test]
    fn lin_ticks_and_labels() {
        let a = Axis::lin(-0.5, 10.0, 2.5);
        assert_eq!(a.ticks(), vec![0.0, 2.5, 5.0, 7.5, 10.0]);
        assert_eq!(a.label(7.5), "7.5");
    }

    #[test]
    fn panel_maps_corners_and_clamps() {
        let p = Panel {
            x: 10,
            y: 20,
            w: 101,
            h: 51,
            xa: Axis::log(0.0, 2.0),
            ya: Axis::lin(0.0, 1.0, 0.5),
        };
        assert_eq!(p.pos(1.0, 0.0), (10, 70));
        assert_eq!(p.pos(100.0, 1.0), (110, 20));
        assert_eq!(p.pos(0.0, 5.0), (10, 20));
    }

    #[test]
    fn dashes_and_clipping() {
        let mut img = RgbImage::from_pixel(12, 3, WHITE);
        // Pixels k = 0, 1, 2 of the first dash fall at x = -2, -1, 0.
        dashed_line(&mut img, (-2, 1), (13, 1), (3, 3), BLACK);
        let row: Vec<bool> = (0..12).map(|x| img.get_pixel(x, 1) == &BLACK).collect();
        assert_eq!(&row[..7], &[true, false, false, false, true, true, true]);
        // The bottom-right font pixel of "8" at (-5, -9), scale 2, covers x, y in -1..=0.
        text(&mut img, -5, -9, 2, "8", BLACK);
        assert_eq!(img.get_pixel(0, 0), &BLACK);
    }
}
