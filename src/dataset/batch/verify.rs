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

/// Check `view` with `verifier` in the private folder `work`, made here and removed after;
/// `exr` is the view's EXR file, written there first from `bytes` when given (a tar's view
/// has no file of its own). `Ok` when the view agrees; else the line its failure records.
pub fn check_view(
    verifier: &dyn Verifier,
    view: &ViewSource,
    scene: &Scene,
    exr: &Path,
    bytes: Option<&[u8]>,
    work: &Path,
) -> Result<(), String> {
    let checked = crate::output::store::atomic::make_dir_all(work)
        .map_err(anyhow::Error::from)
        .and_then(|()| match bytes {
            Some(b) => std::fs::write(exr, b)
                .map_err(|e| anyhow::anyhow!("writing {}: {e}", exr.display())),
            None => Ok(()),
        })
        .and_then(|()| verifier.check(view, scene, exr, work));
    let _ = std::fs::remove_dir_all(work);
    match checked {
        Ok(verdict) if verdict.passes => Ok(()),
        Ok(verdict) => Err(format!(
            "{}: disagrees with the reference: {}",
            view.path.display(),
            verdict.report
        )),
        Err(e) => Err(format!(
            "{}: verification could not run: {e:#}",
            view.path.display()
        )),
    }
}

/// Whether `view` is in the seed-determined `fraction` checked against Mitsuba: the one
/// choice of `batch --verify-fraction` and `cylaov verify --fraction`, keyed on the view's
/// batch id (`scene`, or `scene/00` for camera 0 of a several-camera scene), so each scene's
/// cameras are chosen apart and a verdict batch kept stays the one verify looks for.
pub fn view_selected(seed: u64, view: &ViewSource, fraction: f64) -> bool {
    selected_for_verify(seed, &view.id(), fraction)
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

    /// Camera k of two scenes is chosen apart: keyed on the camera number alone, each seed
    /// would pick the same cameras in every scene.
    #[test]
    fn view_choice_is_keyed_on_scene_and_camera() {
        let scene = |name: &str| ViewSource::scene(name.into(), format!("{name}.json").into());
        let picks = |name: &str| -> Vec<bool> {
            scene(name)
                .cameras(16)
                .iter()
                .map(|v| view_selected(3, v, 0.5))
                .collect()
        };
        let (a, b) = (picks("a"), picks("b"));
        assert_ne!(a, b);
        assert_eq!(a, picks("a"));
        let ids: Vec<String> = scene("a").cameras(16).iter().map(ViewSource::id).collect();
        for (k, id) in ids.iter().enumerate() {
            assert_eq!(a[k], selected_for_verify(3, id, 0.5), "{id}");
        }
        assert_eq!(ids[4], "a/04");
    }
}
