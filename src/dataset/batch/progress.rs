//! Progress on stderr: a redrawn bar on a terminal, plain periodic lines in logs; before
//! the first view, the estimated size of the output ([`SizeEstimate`]).
//!
//! Written by hand, not with a progress-bar crate (`indicatif`): what is needed is one line
//! redrawn with `\r` and, in Slurm or Kubernetes logs, one plain line every period, both
//! fed from the worker threads through one mutex. That is the ~150 lines below; a crate
//! would bring a terminal-handling stack and its own redraw thread for it, and would still
//! need the plain-line mode written here.

use super::write::ViewCost;
use crate::output::format::exr::Compression;
use crate::scene::Aov;
use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// What happened to one view.
#[derive(Clone, Debug)]
pub enum Outcome {
    /// Rendered and written now, with what it cost.
    Done(ViewCost),
    /// Its outputs were already complete (resume): nothing done.
    Skipped,
    /// The view failed: why.
    Failed(String),
}

/// How progress is shown (on stderr).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProgressMode {
    /// A redrawn bar with rate and ETA (a terminal).
    Bar,
    /// One plain line every period (logs, pipes).
    Lines(Duration),
    /// No progress output.
    Off,
}

impl ProgressMode {
    /// Bar on a terminal, a line every 10 s otherwise.
    pub fn auto() -> ProgressMode {
        if std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines(Duration::from_secs(10))
        }
    }
}

/// Counts of one run.
#[derive(Clone, Debug, Default)]
pub struct Counts {
    /// Views rendered and written in this run.
    pub done: usize,
    /// Views skipped because their outputs were already complete (resume).
    pub skipped: usize,
    /// Views that failed.
    pub failed: usize,
}

struct ProgressState {
    counts: Counts,
    last: Option<Instant>,
}

/// Thread-safe progress reporting for a run of `total` views.
pub struct Progress {
    mode: ProgressMode,
    label: String,
    total: usize,
    start: Instant,
    state: Mutex<ProgressState>,
}

fn hms(secs: f64) -> String {
    let s = secs.round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

impl Progress {
    /// Progress for `total` views, its lines prefixed with `label`; the clock starts now.
    pub fn new(mode: ProgressMode, label: String, total: usize) -> Progress {
        Progress {
            mode,
            label,
            total,
            start: Instant::now(),
            state: Mutex::new(ProgressState {
                counts: Counts::default(),
                last: None,
            }),
        }
    }

    fn line(&self, c: &Counts) -> String {
        let finished = c.done + c.skipped + c.failed;
        let secs = self.start.elapsed().as_secs_f64();
        // Rate over rendered views only: skipped ones cost nothing.
        let worked = c.done + c.failed;
        let rate = if secs > 0.0 {
            worked as f64 / secs
        } else {
            0.0
        };
        let eta = if rate > 0.0 {
            hms((self.total - finished) as f64 / rate)
        } else {
            "?".into()
        };
        format!(
            "{} {finished}/{} (done {} skipped {} failed {}) {rate:.1} views/s ETA {eta}",
            self.label, self.total, c.done, c.skipped, c.failed
        )
    }

    /// Record one finished view.
    pub fn record(&self, outcome: &Outcome) {
        let Ok(mut st) = self.state.lock() else {
            return;
        };
        match outcome {
            Outcome::Done(_) => st.counts.done += 1,
            Outcome::Skipped => st.counts.skipped += 1,
            Outcome::Failed(_) => st.counts.failed += 1,
        }
        let now = Instant::now();
        let due = |period: Duration| st.last.is_none_or(|t| now - t >= period);
        let mut err = std::io::stderr().lock();
        match self.mode {
            ProgressMode::Bar if due(Duration::from_millis(100)) => {
                let c = &st.counts;
                let finished = c.done + c.skipped + c.failed;
                let width = 24;
                let filled = (finished * width).checked_div(self.total).unwrap_or(width);
                let bar: String = (0..width)
                    .map(|k| if k < filled { '#' } else { '-' })
                    .collect();
                let _ = write!(err, "\r\x1b[2K[{bar}] {}", self.line(c));
                let _ = err.flush();
                st.last = Some(now);
            }
            ProgressMode::Lines(period) if due(period) => {
                let _ = writeln!(err, "{}", self.line(&st.counts));
                st.last = Some(now);
            }
            _ => {}
        }
    }

    /// Final state: the bar is completed and ended with a newline.
    pub fn finish(&self) {
        let Ok(st) = self.state.lock() else { return };
        let mut err = std::io::stderr().lock();
        match self.mode {
            ProgressMode::Bar => {
                let _ = writeln!(
                    err,
                    "\r\x1b[2K[{}] {}",
                    "#".repeat(24),
                    self.line(&st.counts)
                );
            }
            ProgressMode::Lines(_) => {
                let _ = writeln!(err, "{}", self.line(&st.counts));
            }
            ProgressMode::Off => {}
        }
    }
}

/// Above this estimate `batch` suggests `--compression zip` (when its EXRs are
/// uncompressed): 1 GiB, about 200 views at 640×480 with depth and normal.
pub const LARGE_OUTPUT: u64 = 1 << 30;

/// PNG bytes per pixel of a view (normal picture, 16-bit depth, mask together), as
/// measured on generated scenes (0.32); busier images compress less.
const PNG_BYTES_PER_PIXEL: f64 = 0.35;

/// The JSON files of a view (camera, Open3D, stamp) and its share of the indexes.
const TEXT_BYTES_PER_VIEW: u64 = 5 << 10;

/// What a batch is about to write, estimated before it starts from the views' sizes and
/// AOVs: the EXRs exactly as an uncompressed file holds them (4 bytes a channel a pixel,
/// 16 bytes a scanline for its offset and chunk header, 2 KiB of header), the PNGs at
/// `PNG_BYTES_PER_PIXEL`, the JSON files at `TEXT_BYTES_PER_VIEW`. Compressed EXRs
/// are counted at their uncompressed size, an upper bound.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SizeEstimate {
    /// Views counted.
    pub views: usize,
    /// Bytes of the EXRs, uncompressed.
    pub exr: u64,
    /// Bytes of everything else (PNGs, JSON).
    pub other: u64,
    /// `WxH` when every view has that size.
    pub size: Option<(u32, u32)>,
    /// The AOV names joined by `+` when every view has the same.
    pub aovs: Option<String>,
    /// Whether the views have different sizes or AOV lists.
    pub mixed: bool,
}

impl SizeEstimate {
    /// Add one view of `width`×`height` whose EXRs hold `aovs` (in `layers` EXRs per
    /// view, one file each), with PNGs or not.
    pub fn add(&mut self, (width, height): (u32, u32), aovs: &[Aov], files: u64, png: bool) {
        let (w, h) = (width as u64, height as u64);
        let channels: u64 = aovs
            .iter()
            .map(|&a| crate::output::format::exr::channel_names(a).len() as u64)
            .sum();
        self.exr += files * (2 << 10) + files * h * 16 + w * h * 4 * channels;
        self.other += TEXT_BYTES_PER_VIEW;
        if png {
            self.other += (w as f64 * h as f64 * PNG_BYTES_PER_PIXEL) as u64;
        }
        let names = aovs.iter().map(|a| a.name()).collect::<Vec<_>>().join("+");
        if self.views == 0 {
            self.size = Some((width, height));
            self.aovs = Some(names);
        } else {
            if self.size != Some((width, height)) {
                self.size = None;
                self.mixed = true;
            }
            if self.aovs.as_deref() != Some(names.as_str()) {
                self.aovs = None;
                self.mixed = true;
            }
        }
        self.views += 1;
    }

    /// All bytes.
    pub fn total(&self) -> u64 {
        self.exr + self.other
    }

    /// The line `batch` prints before it starts; with uncompressed EXRs and an estimate
    /// above [`LARGE_OUTPUT`], it suggests `--compression zip`.
    pub fn message(&self, label: &str, compression: Compression) -> String {
        let what = match (&self.size, &self.aovs) {
            (Some((w, h)), Some(a)) => format!(" at {w}x{h}, {a}"),
            (Some((w, h)), None) => format!(" at {w}x{h}"),
            (None, Some(a)) => format!(", {a}"),
            (None, None) => String::new(),
        };
        let views = match self.views {
            1 => "1 view".to_string(),
            n => format!("{n} views"),
        };
        if compression != Compression::None {
            return format!(
                "{label}: {views}{what}: at most {} (EXRs counted uncompressed, {})",
                crate::output::console::bytes(self.total()),
                crate::output::console::bytes(self.exr)
            );
        }
        let mut line = format!(
            "{label}: {views}{what}: about {} of output ({} of it uncompressed EXRs)",
            crate::output::console::bytes(self.total()),
            crate::output::console::bytes(self.exr)
        );
        if self.total() > LARGE_OUTPUT {
            line.push_str(&format!(
                "; {} zip (lossless) stores the EXRs in a fraction of that, at some cost in \
                 write time",
                crate::spelling::opt("compression")
            ));
        }
        line
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 2 000 views at 640×480 with depth and normal and PNGs: 9.2 GiB of EXRs, 9.4 GiB in
    /// all (a generated batch of 20 such views took 100.5 MB, 5.03 MB a view), and the
    /// suggestion; 200 views at 320×240 stay under the threshold.
    #[test]
    fn the_estimate_of_2000_views_at_640x480() {
        let mut e = SizeEstimate::default();
        for _ in 0..2000 {
            e.add((640, 480), &[Aov::Depth, Aov::Normal], 1, true);
        }
        let per_view = e.total() as f64 / 2000.0;
        assert!((per_view - 5.03e6).abs() < 0.05e6, "{per_view}");
        let line = e.message("batch 0-of-1", Compression::None);
        assert_eq!(
            line,
            "batch 0-of-1: 2000 views at 640x480, depth+normal: about 9.4 GiB of output (9.2 \
             GiB of it uncompressed EXRs); compression zip (lossless) stores the EXRs in a \
             fraction of that, at some cost in write time"
        );
        assert!(e.message("b", Compression::Zip).contains("at most 9.4 GiB"));
        let mut small = SizeEstimate::default();
        for _ in 0..200 {
            small.add((320, 240), &[Aov::Depth, Aov::Normal], 1, true);
        }
        assert!(small.total() < LARGE_OUTPUT);
        assert!(
            !small
                .message("b", Compression::None)
                .contains("zip (lossless)")
        );
        small.add((64, 48), &[Aov::Depth], 1, false);
        assert!(small.mixed);
        assert!(
            small
                .message("b", Compression::None)
                .starts_with("b: 201 views: about")
        );
    }
}
