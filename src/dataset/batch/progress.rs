//! Progress on stderr: a redrawn bar on a terminal, plain periodic lines in logs.
//!
//! Written by hand, not with a progress-bar crate (`indicatif`): what is needed is one line
//! redrawn with `\r` and, in Slurm or Kubernetes logs, one plain line every period, both
//! fed from the worker threads through one mutex. That is the ~150 lines below; a crate
//! would bring a terminal-handling stack and its own redraw thread for it, and would still
//! need the plain-line mode written here.

use super::run::Outcome;
use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

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
