//! `batch --verify-fraction`: a view checked against Mitsuba 3.
//!
//! For each selected view: the scene goes through `mitsuba::to_xml`, the reference venv's
//! Python runs `scripts/mitsuba_reference.py XML SCENE.json OUT.exr`, and `compare` judges
//! our EXR against the reference with the tolerances of the reference tests
//! (`Tolerances::default()`, the rule of [`crate::verify::compare`]).
//!
//! The venv and the script are looked up under `$CYLAOV_ROOT`, else the source tree this
//! binary was built from; without them verification is skipped with a notice (the issue:
//! "when the reference venv is present").

use crate::dataset::batch::{Verdict, Verifier, ViewSource};
use crate::output::aov::AovImage;
use crate::scene::Scene;
use crate::verify::compare::{Tolerances, compare};
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The Mitsuba reference, found on disk.
pub struct MitsubaVerifier {
    python: PathBuf,
    script: PathBuf,
    tolerances: Tolerances,
}

impl MitsubaVerifier {
    /// The venv's Python and the reference script, or why they are not usable.
    pub fn find() -> Result<MitsubaVerifier, String> {
        let root = std::env::var_os("CYLAOV_ROOT")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")));
        let python = std::env::var_os("CYLAOV_VENV")
            .map(PathBuf::from)
            .unwrap_or_else(|| root.join(".venv"))
            .join("bin/python");
        let script = root.join("scripts/mitsuba_reference.py");
        for p in [&python, &script] {
            if !p.exists() {
                return Err(format!(
                    "{} not found (set CYLAOV_ROOT to the cylaov source tree; make the venv \
                     with scripts/setup-venv)",
                    p.display()
                ));
            }
        }
        Ok(MitsubaVerifier {
            python,
            script,
            tolerances: Tolerances::default(),
        })
    }
}

impl Verifier for MitsubaVerifier {
    fn check(&self, view: &ViewSource, scene: &Scene, exr: &Path, work: &Path) -> Result<Verdict> {
        let xml_path = work.join("scene.xml");
        let reference = work.join("reference.exr");
        let xml = crate::output::mitsuba::to_xml(scene, &view.path.display().to_string());
        std::fs::write(&xml_path, xml)
            .with_context(|| format!("writing {}", xml_path.display()))?;
        let out = Command::new(&self.python)
            .arg(&self.script)
            .arg(&xml_path)
            .arg(&view.path)
            .arg(&reference)
            .arg(view.camera.to_string())
            .output()
            .with_context(|| format!("running {}", self.python.display()))?;
        if !out.status.success() {
            bail!(
                "{} failed: {}",
                self.script.display(),
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        let ours = AovImage::read_exr(exr)?;
        let theirs = AovImage::read_exr(&reference)?;
        let report = compare(&ours, &theirs)?;
        Ok(Verdict {
            passes: report.passes(&self.tolerances),
            report: report.to_string(),
        })
    }
}
