//! Checking rendered views against an independent reference: the interface batch calls and
//! the seeded choice of which views are checked.

use super::resume::Fnv1a;
use super::views::ViewSource;
use crate::rng::mix64;
use crate::scene::Scene;
use anyhow::Result;
use std::path::Path;

/// The verdict of a [`Verifier`] on one view.
#[derive(Clone, Debug)]
pub struct Verdict {
    /// Whether the view agrees with the reference.
    pub passes: bool,
    /// One line for the log or the failures file (error statistics, mismatches).
    pub report: String,
}

/// Checks a rendered view against an independent reference. The Mitsuba implementation is
/// `crate::verify::reference::MitsubaVerifier`; batch only knows this interface.
pub trait Verifier: Sync {
    /// `exr` is the view's finished EXR; `work` a private folder for temporary files.
    fn check(&self, view: &ViewSource, scene: &Scene, exr: &Path, work: &Path) -> Result<Verdict>;
}

/// Whether view `name` is in the seed-determined `fraction` checked against Mitsuba:
/// a hash of (seed, name), so the choice does not depend on sharding or order.
pub fn selected_for_verify(seed: u64, name: &str, fraction: f64) -> bool {
    if fraction <= 0.0 {
        return false;
    }
    if fraction >= 1.0 {
        return true;
    }
    // FNV-1a over the name, then mixed with the seed.
    let h = Fnv1a::new().bytes(name.as_bytes()).0;
    let u = (mix64(h ^ mix64(seed)) >> 11) as f64 / (1u64 << 53) as f64;
    u < fraction
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verify_selection_is_a_stable_fraction() {
        let picked = (0..10_000)
            .filter(|i| selected_for_verify(7, &format!("{i:06}"), 0.1))
            .count();
        assert!((900..1100).contains(&picked), "{picked}");
        assert!(!selected_for_verify(7, "a", 0.0));
        assert!(selected_for_verify(7, "a", 1.0));
    }
}
