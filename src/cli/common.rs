//! Arguments and helpers several commands share: the kernel choice, the verification
//! bounds, `--threads` and the value checks behind them.

use crate::cli;
use clap::Args;
use cylaov::geometry::{FormulaKind, Precision};
use cylaov::render::Accel;
use cylaov::verify::compare::Tolerances;

/// The pass/fail bounds of every verifying command (defaults: what "agrees with Mitsuba"
/// means, docs/verification.md).
#[derive(Args, Clone, Copy, Debug)]
pub struct TolerancesCli {
    /// Largest allowed fraction of silhouette-mismatched pixels (different cylinder or hit
    /// vs miss; all must lie on silhouettes).
    #[arg(long, default_value_t = Tolerances::default().max_mismatch_fraction, value_parser = non_negative)]
    pub max_mismatch_fraction: f64,
    /// Largest allowed fraction of seam-mismatched pixels (same cylinder, another part; all
    /// must lie on a part boundary).
    #[arg(long, default_value_t = Tolerances::default().max_seam_fraction, value_parser = non_negative)]
    pub max_seam_fraction: f64,
    /// Largest allowed relative distance error (where a pixel's float32 conditioning bound
    /// is larger, at grazing incidence, that bound applies).
    #[arg(long, default_value_t = Tolerances::default().rel_distance, value_parser = non_negative)]
    pub rel_distance: f64,
    /// Largest allowed relative depth error (or the pixel's float32 bound, if larger).
    #[arg(long, default_value_t = Tolerances::default().rel_depth, value_parser = non_negative)]
    pub rel_depth: f64,
    /// Largest allowed normal angle error, degrees (or the pixel's float32 bound, if larger).
    #[arg(long, default_value_t = Tolerances::default().normal_deg, value_parser = non_negative)]
    pub normal_deg: f64,
}

impl TolerancesCli {
    pub fn get(self) -> Tolerances {
        Tolerances {
            max_mismatch_fraction: self.max_mismatch_fraction,
            max_seam_fraction: self.max_seam_fraction,
            rel_distance: self.rel_distance,
            rel_depth: self.rel_depth,
            normal_deg: self.normal_deg,
        }
    }
}

pub fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
        _ => Err(format!("must be a finite number >= 0, got {s:?}")),
    }
}

/// Kernel choice shared by every command that traces rays.
#[derive(Args, Clone, Debug)]
pub struct KernelCli {
    /// Kernel precision: f64 is the default and the accuracy reference. f32 runs the kernel
    /// about 1.8x faster (eight AVX2 lanes instead of four) but a whole render only about
    /// 1.1x (set-up and writing dominate), and shows what float32 costs (docs/accuracy.md).
    #[arg(long, value_parser = cli::choice::<Precision>(), default_value_t = Precision::F64)]
    pub precision: Precision,
    /// Kernel formulation: `stable` (default) or the textbook quadratic as written
    /// (docs/accuracy.md), kept to show what the stable form fixes.
    #[arg(long, value_parser = cli::choice::<FormulaKind>(), default_value_t = FormulaKind::Stable)]
    pub formula: FormulaKind,
    /// How primary rays find candidates: screen tiles (fast) or the BVH.
    #[arg(long, value_parser = cli::choice::<Accel>(), default_value_t = Accel::Tiles)]
    pub accel: Accel,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, value_parser = threads)]
    pub threads: Option<usize>,
}

/// Largest `--threads`: 1024 is more hardware threads than any single node this runs on
/// has, and the work splits into bands of tiles, so more threads cannot help; each one
/// reserves a stack, and tens of thousands exhaust the process's limits (50 000 aborted,
/// 100 000 spent minutes creating threads).
pub const MAX_THREADS: usize = 1024;

/// `--threads N`: a whole number in 1..=[`MAX_THREADS`].
pub fn threads(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=MAX_THREADS).contains(&n) => Ok(n),
        _ => Err(format!(
            "must be a whole number from 1 to {MAX_THREADS}, got {}",
            shorten(s)
        )),
    }
}

pub fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!("must be a whole number >= 1, got {}", shorten(s))),
    }
}

/// A value as echoed in a message: at most 40 characters.
pub fn shorten(s: &str) -> String {
    cylaov::scene::strict::shorten(s)
}

pub fn set_threads(threads: Option<usize>) -> anyhow::Result<()> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| anyhow::anyhow!("--threads {n}: cannot start the threads: {e}"))?;
    }
    Ok(())
}

/// Print a command's summary line (a closed pipe is not an error; see `io::say`).
pub fn say(text: &str) -> anyhow::Result<()> {
    cylaov::output::console::say(text)?;
    Ok(())
}
