//! What a batch renders and writes, and how its threads share the work.

use crate::geometry::{FormulaKind, Precision};
use crate::output::format::depth_png::OutOfRange;
use crate::output::format::exr::{Compression, ExrLayout};
use crate::scene::{Aov, Scene};

crate::choice_enum! {
    /// How the pool's threads share the work.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Schedule default Views {
        /// Views in parallel (each view's rows also in parallel): writing one view overlaps
        /// tracing another: the faster schedule for small views, whose write is as long as their trace.
        Views = "views",
        /// One view at a time, its rows in parallel; the pool idles while a view is written.
        Pixels = "pixels",
    }
}

/// What a batch renders and writes.
#[derive(Clone, Debug)]
pub struct BatchOptions {
    /// AOVs in each EXR; `None`: each scene's own.
    pub aovs: Option<Vec<Aov>>,
    /// Kernel precision.
    pub precision: Precision,
    /// Kernel formulation.
    pub formula: FormulaKind,
    /// Depth PNG value per world unit (1000: millimetres for metre scenes).
    pub depth_scale: f64,
    /// Write `NAME.normal.preview.png`, `NAME.depth.png` and `NAME.mask.png`.
    pub png: bool,
    /// What the depth PNG does with a hit beyond 16 bits at `depth_scale`.
    pub depth_out_of_range: OutOfRange,
    /// Write `NAME.ply`, the view's hit points (files format).
    pub ply: bool,
    /// EXR compression.
    pub compression: Compression,
    /// One layered `NAME.exr`, or `NAME.<aov>.exr` per AOV.
    pub exr_layout: ExrLayout,
    /// How the pool's threads share the work.
    pub schedule: Schedule,
    /// Fraction of views also checked against an independent reference (Mitsuba), chosen
    /// by [`view_selected`](super::view_selected) from `verify_seed` and the view's id.
    pub verify_fraction: f64,
    /// Seed of the `verify_fraction` choice.
    pub verify_seed: u64,
}

impl Default for BatchOptions {
    fn default() -> Self {
        BatchOptions {
            aovs: None,
            precision: Precision::default(),
            formula: FormulaKind::default(),
            depth_scale: 1000.0,
            png: true,
            depth_out_of_range: OutOfRange::Fail,
            ply: false,
            compression: Compression::None,
            exr_layout: ExrLayout::Layers,
            schedule: Schedule::default(),
            verify_fraction: 0.0,
            verify_seed: 0,
        }
    }
}

impl BatchOptions {
    /// Check the values the command line cannot range-check: `depth_scale` finite and > 0,
    /// `verify_fraction` in [0, 1] and 0 unless the EXR is layered; the error names the
    /// option (see [`crate::spelling`]).
    pub fn validate(&self) -> Result<(), String> {
        use crate::spelling::opt;
        let s = self.depth_scale;
        if !(s.is_finite() && s > 0.0) {
            return Err(format!(
                "{}: must be finite and > 0, got {s}",
                opt("depth_scale")
            ));
        }
        let f = self.verify_fraction;
        if !(0.0..=1.0).contains(&f) {
            return Err(format!(
                "{}: must be in [0, 1], got {f}",
                opt("verify_fraction")
            ));
        }
        if f > 0.0 && self.exr_layout == ExrLayout::PerAov {
            return Err(format!(
                "{}: needs {} layers (the check reads the layered EXR)",
                opt("verify_fraction"),
                opt("exr_layout")
            ));
        }
        Ok(())
    }

    /// The AOVs stored in the EXR of `scene` (`--aov`'s repeats dropped, as a scene's are).
    pub fn exr_aovs(&self, scene: &Scene) -> Vec<Aov> {
        match &self.aovs {
            Some(list) => Aov::without_repeats(list),
            None => scene.aovs.clone(),
        }
    }
}
