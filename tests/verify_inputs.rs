//! The exact answer on Mitsuba's own float32 inputs: a planted export error (one
//! cylinder's radius changed in what Mitsuba renders) is not explained by input rounding
//! and still fails as unexplained. Skipped (saying so) without the reference venv, unless
//! `CYLAOV_REQUIRE_VENV=1`.

mod common;
use common::venv_python;

use cylaov::geometry::{FormulaKind, Precision};
use cylaov::scene;
use cylaov::verify::compare::Tolerances;
use cylaov::verify::reference::{Mitsuba, check_against, check_render};
use std::path::PathBuf;

#[test]
fn a_planted_export_error_stays_unexplained() {
    let Some(python) = venv_python() else { return };
    let mitsuba = Mitsuba { python };
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let scene = scene::load(&root.join("scenes/cluster.json")).expect("scene");
    let ours = check_render(&scene, Precision::F64, FormulaKind::Stable);
    // The cylinder seen at the image's centre, 1% wider in what Mitsuba renders.
    let ids = ours.u32_channel("shape_id").expect("ids");
    let centre = ids[(ours.height / 2) * ours.width + ours.width / 2];
    assert_ne!(centre, 0, "a cylinder at the centre");
    let mut planted = scene.clone();
    let c = planted
        .cylinders
        .iter_mut()
        .find(|c| c.id == centre)
        .expect("the centre's cylinder");
    c.radius *= 1.01;
    let work = common::fresh_dir("verify_inputs", "planted");
    let reference = mitsuba
        .render(&planted, "planted", work.path())
        .expect("mitsuba");
    let c = check_against(&scene, &ours, &reference, &Tolerances::default()).expect("check");
    let a = &c.arbitration;
    println!(
        "unexplained {}, input rounding {}, reference errors {}",
        a.unexplained_reference_errors, a.input_rounding, a.reference_errors
    );
    assert!(!c.passed(), "{}", c.text());
    assert_eq!(a.candidate_errors, 0);
    assert!(a.unexplained_reference_errors > 10, "{}", c.text());
    assert_eq!(a.input_rounding, 0, "{}", c.text());
    // The same scene rendered as exported passes.
    let reference = mitsuba
        .render(&scene, "as_is", work.path())
        .expect("mitsuba");
    let c = check_against(&scene, &ours, &reference, &Tolerances::default()).expect("check");
    assert!(c.passed(), "{}", c.text());
}
