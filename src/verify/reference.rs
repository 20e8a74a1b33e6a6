//! A view checked against Mitsuba 3: the one code path of `cylaov verify`,
//! `batch --verify-fraction` and the reference tests.
//!
//! 1. cylaov renders the view in memory with every AOV the check needs ([`check_render`]:
//!    all of them, `shape_id` and `part` included), whatever the dataset stores.
//! 2. Mitsuba renders the reference ([`Mitsuba::render`]): the scene goes through
//!    `output::format::mitsuba::to_xml`, and the reference script, compiled into this binary
//!    ([`SCRIPT`]), runs in the pinned venv's Python (mitsuba 3.9.1, `scalar_rgb`). That
//!    is the perspective and the orthographic camera; the lens models (`opencv`,
//!    `opencv_fisheye`, `equirectangular`), which Mitsuba has no sensor for, are checked
//!    against the exact answer alone: their reference is the double-double answer on every
//!    pixel ray ([`exact_render`]), no venv needed, and the verdict says so
//!    ([`exact_alone_line`]).
//! 3. [`check_against`] compares them with the rule of [`crate::verify::compare`]: identity
//!    by (cylinder, part), the flat [`Tolerances`], and per-pixel float32 conditioning
//!    bounds from the scene.
//!
//! In a batch, [`MitsubaVerifier`] renders the view again with the kernel its record gives
//! ([`Written`]: `NAME.render.json`, or a tar dataset's `shards.json`) and checks that the
//! dataset's EXR holds exactly the samples of that render: every channel of the AOVs the
//! record lists, of the same type, bit for bit, and no other (so the file is what was
//! verified; where it differs, the file fails, naming the first differing channel, and its
//! samples are judged against Mitsuba and the exact answer, naming the pixels). It keeps
//! the verdict in `NAME.verify.json` beside it, keyed to everything the verdict depends
//! on (`CacheKey`): the sha256 of the EXR and of the scene as loaded now, the view, the
//! render stamp, the kernel, the tolerances, the rule and the script. A resumed batch does
//! not run Mitsuba again for a view already verified; a file or scene altered since is
//! checked again.
//!
//! **Signals**: Mitsuba's Python runs in a process group of its own (a Ctrl-C reaches
//! cylaov, not it) registered with `crate::output::store::signals`, as is the scratch folder, so
//! a signal to cylaov kills the group and removes the folder before cylaov exits.
//!
//! **The venv** is the first of: `$CYLAOV_VENV`; `.venv` in the source tree this binary
//! was built from (where `scripts/setup-venv` puts it); `~/.local/share/cylaov/venv`
//! (`CYLAOV_VENV=~/.local/share/cylaov/venv scripts/setup-venv` makes it for an installed
//! binary).

use crate::dataset::batch::{Verdict, Verifier, ViewSource};
use crate::geometry::{FormulaKind, Precision};
use crate::image::AovImage;
use crate::output::format::exr::channel_names;
use crate::output::store::atomic::atomic_write_bytes;
use crate::output::store::signals::{self, Cleanup};
use crate::render::{RenderOptions, render};
use crate::scene::{Aov, Scene};
use crate::verify::arbiter::{
    Arbitration, Bound, Reference, arbitrate_against, exact_render, has_mitsuba_sensor,
};
use crate::verify::compare::{Conditioning, Report, Tolerances, compare_with, heatmap_figure};
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;

/// The reference script (`scripts/mitsuba_reference.py`), carried by the binary.
pub const SCRIPT: &str = include_str!("../../scripts/mitsuba_reference.py");

/// The one line a user without the venv sees.
pub const NO_VENV_HINT: &str = "make it with `scripts/setup-venv` in the cylaov source tree (CYLAOV_VENV=DIR picks another place)";

/// The Mitsuba reference renderer: the venv's Python.
#[derive(Clone, Debug)]
pub struct Mitsuba {
    /// The Python interpreter with Mitsuba installed (`VENV/bin/python`).
    pub python: PathBuf,
}

impl Mitsuba {
    /// The venv's Python, or one line saying where it was looked for and how to make it.
    pub fn find() -> Result<Mitsuba, String> {
        let candidates: Vec<PathBuf> = match std::env::var_os("CYLAOV_VENV") {
            Some(v) => vec![PathBuf::from(v)],
            None => {
                let mut c = vec![PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(".venv")];
                if let Some(home) = std::env::var_os("HOME") {
                    c.push(PathBuf::from(home).join(".local/share/cylaov/venv"));
                }
                c
            }
        };
        for venv in &candidates {
            let python = venv.join("bin/python");
            if python.exists() {
                return Ok(Mitsuba { python });
            }
        }
        let looked: Vec<String> = candidates.iter().map(|p| p.display().to_string()).collect();
        Err(format!(
            "no Mitsuba venv (looked in {}): {NO_VENV_HINT}",
            looked.join(", ")
        ))
    }

    /// Render `scene`'s reference AOVs in `work` (a private folder) and read them back.
    /// `source_name` goes into the XML's header comment.
    pub fn render(&self, scene: &Scene, source_name: &str, work: &Path) -> Result<AovImage> {
        self.render_with(scene, source_name, work, &[])
    }

    /// [`Mitsuba::render`], with the AOVs of `on_request` (those whose
    /// [`MitsubaSource`](crate::scene::aov::MitsubaSource) is `OnRequest`: `uv`) rendered
    /// too.
    pub fn render_with(
        &self,
        scene: &Scene,
        source_name: &str,
        work: &Path,
        on_request: &[Aov],
    ) -> Result<AovImage> {
        // The reference script converts the rays of Mitsuba's two sensors; the lens models
        // have none (their reference is the exact answer alone, see `reference_image`).
        if !has_mitsuba_sensor(&scene.camera.projection) {
            anyhow::bail!(
                "camera.model: Mitsuba 3 has no \"{}\" camera",
                scene.camera.projection.model().name()
            );
        }
        let xml = work.join("scene.xml");
        let camera = work.join("camera.json");
        let script = work.join("mitsuba_reference.py");
        let out = work.join("reference.exr");
        let write = |p: &Path, bytes: &[u8]| {
            std::fs::write(p, bytes).with_context(|| format!("writing {}", p.display()))
        };
        // Only the camera being checked becomes a sensor: the script renders sensor 0.
        let one_camera = Scene {
            cameras: vec![scene.camera],
            ..scene.clone()
        };
        write(
            &xml,
            crate::output::format::mitsuba::to_xml(&one_camera, source_name)?.as_bytes(),
        )?;
        write(&camera, camera_file(scene).as_bytes())?;
        write(&script, SCRIPT.as_bytes())?;
        let mut cmd = Command::new(&self.python);
        cmd.arg(&script).arg(&xml).arg(&camera).arg(&out);
        for a in on_request {
            if !matches!(
                a.spec().mitsuba,
                crate::scene::aov::MitsubaSource::OnRequest(_)
            ) {
                bail!("{}: not an AOV a reference renders on request", a.name());
            }
            cmd.arg("--aov").arg(a.name());
        }
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let (child, _group) = signals::spawn_in_group(&mut cmd)
            .with_context(|| format!("running {}", self.python.display()))?;
        let run = child
            .wait_with_output()
            .with_context(|| format!("running {}", self.python.display()))?;
        if !run.status.success() {
            bail!(
                "the Mitsuba reference script failed: {}",
                String::from_utf8_lossy(&run.stderr).trim()
            );
        }
        AovImage::read_exr(&out)
    }
}

/// The script's camera input: `{"camera": {...}}` of the validated camera, so a scene with
/// several cameras or defaults left out still gives the script every field (the
/// orthographic camera's `model` and `ortho_width` too).
fn camera_file(scene: &Scene) -> String {
    let c = &scene.camera;
    let mut cam = serde_json::json!({
        "origin": c.origin.to_array(),
        "target": c.target.to_array(),
        "up": c.up.to_array(),
        "fov_deg": c.fov_deg,
        "fov_axis": c.fov_axis.name(),
        "width": c.width,
        "height": c.height,
        "near_clip": c.near_clip,
        "far_clip": c.far_clip,
        "model": c.projection.model().name(),
    });
    if let (Some(map), crate::scene::camera::Projection::Orthographic { half_width, .. }) =
        (cam.as_object_mut(), c.projection)
    {
        map.insert("ortho_width".into(), serde_json::json!(2.0 * half_width));
    }
    serde_json::json!({ "camera": cam }).to_string()
}

/// The words of a view checked against the exact answer alone (a lens model).
pub fn exact_alone_line(scene: &Scene) -> String {
    format!(
        "checked against the exact answer alone: Mitsuba has no {} camera",
        scene.camera.projection.model().name()
    )
}

/// The reference `scene`'s view is checked against: Mitsuba's render for the cameras it has
/// a sensor for (`mitsuba` is then needed: its error says why there is none), the exact
/// answer's own image ([`exact_render`]) for the lens models, which need no venv.
pub fn reference_image(
    mitsuba: Result<&Mitsuba, &str>,
    scene: &Scene,
    source_name: &str,
    work: &Path,
) -> Result<AovImage> {
    if !has_mitsuba_sensor(&scene.camera.projection) {
        return exact_render(scene);
    }
    mitsuba
        .map_err(|why| anyhow::anyhow!("{why}"))?
        .render(scene, source_name, work)
}

/// cylaov's render for a check: every AOV a reference renders by default (identity and
/// the channels conditioning needs; not those a reference renders only on request).
pub fn check_render(scene: &Scene, precision: Precision, formula: FormulaKind) -> AovImage {
    check_render_with(scene, precision, formula, &[])
}

/// [`check_render`] with the AOVs of `also` too (those a checked file holds).
fn check_render_with(
    scene: &Scene,
    precision: Precision,
    formula: FormulaKind,
    also: &[Aov],
) -> AovImage {
    let aovs = Aov::ALL
        .into_iter()
        .filter(|a| {
            also.contains(a)
                || !matches!(
                    a.spec().mitsuba,
                    crate::scene::aov::MitsubaSource::OnRequest(_)
                )
        })
        .collect();
    let opts = RenderOptions {
        precision,
        formula,
        ..RenderOptions::new(aovs)
    };
    render(scene, &opts).image
}

/// The outcome of one view's check.
#[derive(Clone, Debug)]
pub struct ViewCheck {
    /// The comparison of the candidate (A: cylaov's render or a file) with Mitsuba's (B).
    pub report: Report,
    /// The bounds the report was judged by.
    pub tolerances: Tolerances,
    /// Every pixel where A and B disagree beyond `tolerances`, classified by the exact answer.
    pub arbitration: Arbitration,
    /// Why the view fails (candidate errors, unexplained reference errors); empty: it passed.
    pub failures: Vec<String>,
    /// What passed without being exact (reference errors, ties, the note where Mitsuba
    /// cannot discriminate).
    pub accepted: Vec<String>,
}

impl ViewCheck {
    /// Whether the view passes (no failures).
    pub fn passed(&self) -> bool {
        self.failures.is_empty()
    }

    /// `PASS` or `FAIL:` with one indented line per failure, as `compare` prints.
    pub fn verdict_text(&self) -> String {
        crate::verify::compare::verdict_lines(&self.failures)
    }

    /// The report, tolerances, accepted lines and verdict, as `compare` prints them.
    pub fn text(&self) -> String {
        let mut s = format!(
            "{}\n{}\n",
            self.report,
            crate::verify::compare::tolerance_line(&self.tolerances)
        );
        for line in &self.accepted {
            s += &format!("accepted: {line}\n");
        }
        s + &self.verdict_text()
    }
}

/// Check cylaov's f64 render `ours` of `scene` against Mitsuba's `reference`: see
/// [`check_against_with`].
pub fn check_against(
    scene: &Scene,
    ours: &AovImage,
    reference: &AovImage,
    tol: &Tolerances,
) -> Result<ViewCheck> {
    check_against_with(scene, ours, reference, tol, Bound::cylaov(Precision::F64))
}

/// Compare `candidate` with `reference` (identity by cylinder and part, per-pixel float32
/// conditioning in the statistics), and classify every pixel where they disagree beyond
/// `tol` with the exact answer as arbiter ([`crate::verify::arbiter`]): the view fails on
/// a candidate error or an unexplained reference error, or a non-finite sample.
///
/// `reference` is Mitsuba's render for a perspective or orthographic camera, and the exact
/// answer's image ([`reference_image`]) for a lens model: that check is against the exact
/// answer alone, and its first accepted line says so ([`exact_alone_line`]).
pub fn check_against_with(
    scene: &Scene,
    candidate: &AovImage,
    reference: &AovImage,
    tol: &Tolerances,
    bound: Bound,
) -> Result<ViewCheck> {
    let exact_alone = !has_mitsuba_sensor(&scene.camera.projection);
    let against = if exact_alone {
        Reference::Exact
    } else {
        Reference::Mitsuba
    };
    // No float32 conditioning against the exact answer: nothing there is float32 but the
    // storage, which the candidate's bound covers.
    let cond = Conditioning::new(scene, candidate).filter(|_| !exact_alone);
    let report = compare_with(candidate, reference, cond.as_ref())?;
    let arbitration = arbitrate_against(scene, candidate, reference, tol, bound, against)?;
    let mut accepted = arbitration.accepted_lines();
    if exact_alone {
        accepted.insert(0, exact_alone_line(scene));
    }
    Ok(ViewCheck {
        failures: arbitration.failure_lines(),
        accepted,
        tolerances: *tol,
        arbitration,
        report,
    })
}

/// Render `scene` with cylaov and its reference ([`reference_image`]: Mitsuba in `work`,
/// or the exact answer for a lens model) and check them.
pub fn verify_scene(
    mitsuba: Result<&Mitsuba, &str>,
    scene: &Scene,
    source_name: &str,
    precision: Precision,
    formula: FormulaKind,
    tol: &Tolerances,
    work: &Path,
) -> Result<(ViewCheck, AovImage, AovImage)> {
    let _scratch = signals::register(Cleanup::Tree, work);
    let ours = check_render(scene, precision, formula);
    let reference = reference_image(mitsuba, scene, source_name, work)?;
    let check = check_against_with(scene, &ours, &reference, tol, Bound::cylaov(precision))?;
    Ok((check, ours, reference))
}

/// One line for a log: counts of both mismatch kinds and the largest errors.
pub fn summary_line(r: &Report) -> String {
    let max = |m: &Option<crate::verify::compare::Metric>| m.as_ref().map_or(0.0, |m| m.all.max);
    format!(
        "silhouette {} px, seam {} px, rel distance max {:.2e}, rel depth max {:.2e}, normal max {:.3}°",
        r.silhouette_mismatches,
        r.seams,
        max(&r.rel_distance),
        max(&r.rel_depth),
        max(&r.normal_deg)
    )
}

/// [`summary_line`] and the exact answer's classes: one line for a log or a table row.
pub fn check_line(c: &ViewCheck) -> String {
    let a = &c.arbitration;
    format!(
        "{}; reference errors {}, unexplained {}, candidate errors {}, ties {}",
        summary_line(&c.report),
        a.reference_errors,
        a.unexplained_reference_errors,
        a.candidate_errors,
        a.ties
    )
}

/// The rule a cached verdict was reached by: a verdict of another rule is checked again.
const RULE: &str = "exact-answer-arbiter-2";

/// Everything a cached verdict depends on: a verdict whose key differs in any field is
/// reached again.
#[derive(Serialize, Deserialize, PartialEq, Debug)]
struct CacheKey {
    /// The rule of the verdict ([`RULE`]).
    rule: String,
    /// The view's batch id (`scene` or `scene/NN`).
    view: String,
    /// The sha256 of the scene as loaded for this check (every field, the selected camera
    /// included): a scene edited since the file was rendered is checked again.
    scene_sha256: String,
    /// The view's render stamp (`NAME.render.json`), verbatim.
    stamp: String,
    /// The kernel the view was rendered again with.
    precision: String,
    formula: String,
    tolerances: [f64; 5],
    /// The sha256 of the EXR verified.
    exr_sha256: String,
    /// FNV-1a of the reference script.
    script: String,
}

/// What `NAME.verify.json` holds: the verdict and what it is valid for.
#[derive(Serialize, Deserialize, PartialEq, Debug)]
struct CachedVerdict {
    key: CacheKey,
    passed: bool,
    silhouette_px: usize,
    seam_px: usize,
    summary: String,
    /// The text of a failed check (the FAIL lines included); empty when it passed.
    report: String,
}

fn fnv1a(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    format!("{h:016x}")
}

fn tolerance_key(t: &Tolerances) -> [f64; 5] {
    [
        t.max_mismatch_fraction,
        t.max_seam_fraction,
        t.rel_distance,
        t.rel_depth,
        t.normal_deg,
    ]
}

/// What a checked file was written with, as its record says (a batch's `NAME.render.json`
/// beside the EXR, or a tar dataset's `shards.json`): the AOVs it holds and the kernel that
/// rendered them. The check renders the view again with that kernel, and the file must hold
/// exactly the channels of those AOVs.
#[derive(Clone, Debug, PartialEq)]
pub struct Written {
    /// The AOVs the file holds.
    pub aovs: Vec<Aov>,
    /// The kernel's precision.
    pub precision: Precision,
    /// The kernel's formulation.
    pub formula: FormulaKind,
}

impl Written {
    /// The record's `aovs`, `precision` and `formula` fields (a render stamp or
    /// `shards.json`); `what` names the record in errors. A per-AOV stamp is refused: the
    /// check reads a layered EXR.
    pub fn from_record(text: &str, what: &str) -> Result<Written> {
        use crate::choice::Choice;
        let v: serde_json::Value =
            serde_json::from_str(text).with_context(|| format!("reading {what}"))?;
        let field = |name: &str| {
            v.get(name)
                .ok_or_else(|| anyhow::anyhow!("{what}: no {name:?} field"))
        };
        let text_field = |name: &str| -> Result<String> {
            field(name)?
                .as_str()
                .map(str::to_string)
                .ok_or_else(|| anyhow::anyhow!("{what}: {name}: expected a string"))
        };
        if let Some(layout) = v.get("exr_layout").and_then(|l| l.as_str())
            && layout != "layers"
        {
            bail!("{what}: exr_layout {layout:?}: the check reads a layered EXR");
        }
        let aovs = field("aovs")?
            .as_array()
            .ok_or_else(|| anyhow::anyhow!("{what}: aovs: expected a list"))?
            .iter()
            .map(|a| {
                a.as_str()
                    .and_then(Aov::parse)
                    .ok_or_else(|| anyhow::anyhow!("{what}: aovs: {a} is not an AOV"))
            })
            .collect::<Result<Vec<Aov>>>()?;
        let precision = text_field("precision")?;
        let formula = text_field("formula")?;
        Ok(Written {
            aovs,
            precision: Precision::parse(&precision).map_err(|e| {
                anyhow::anyhow!(
                    "{what}: precision: {precision:?} is not one of {}",
                    e.known.join(", ")
                )
            })?,
            formula: FormulaKind::parse(&formula).map_err(|e| {
                anyhow::anyhow!(
                    "{what}: formula: {formula:?} is not one of {}",
                    e.known.join(", ")
                )
            })?,
        })
    }
}

/// `batch --verify-fraction`'s verifier.
pub struct MitsubaVerifier {
    /// The reference renderer.
    pub mitsuba: Mitsuba,
    /// The bounds each view is judged by (also part of the cached verdict's key).
    pub tolerances: Tolerances,
    /// The batch's precision; with `formula` it names the batch's kernel, so the check
    /// re-renders the view exactly as the batch did. A file with a record ([`Written`])
    /// is rendered with the record's kernel instead.
    pub precision: Precision,
    /// The batch's ray–cylinder formulation (literal or stable), the kernel's other half.
    pub formula: FormulaKind,
    /// What every file holds where no render stamp lies beside it (a tar dataset's
    /// `shards.json`); `None`: the kernel above and the AOVs whose channels the file has.
    pub written: Option<Written>,
    /// Print one line per verified view on stderr (batch's log); `verify` prints its table
    /// instead.
    pub log: bool,
    /// Where `batch --report` keeps every checked view for the page (`None`: nothing kept).
    /// Kept views are checked afresh: a cached verdict has no pixels or pictures.
    pub keep: Option<Mutex<Vec<Checked>>>,
}

/// One view checked by [`MitsubaVerifier::check_file`]: the verdict, and when it was checked
/// now (not read from the cache) the comparison and, if asked for, the pictures.
pub struct Checked {
    /// The view's batch id (`scene` or `scene/NN`).
    pub name: String,
    /// The scene file's path.
    pub scene: String,
    /// The verdict.
    pub verdict: Verdict,
    /// The comparison of the file's samples (or the identical fresh render) with Mitsuba's,
    /// every disagreeing pixel classified; `None` for a verdict read from the cache.
    pub check: Option<ViewCheck>,
    /// Candidate, Mitsuba and the difference heatmap, when pictures were asked for.
    pub images: Option<(AovImage, AovImage, image::RgbImage)>,
}

impl MitsubaVerifier {
    /// The verifier with the venv found by [`Mitsuba::find`].
    pub fn find(
        tolerances: Tolerances,
        precision: Precision,
        formula: FormulaKind,
    ) -> Result<MitsubaVerifier, String> {
        Ok(MitsubaVerifier {
            mitsuba: Mitsuba::find()?,
            tolerances,
            precision,
            formula,
            written: None,
            log: true,
            keep: None,
        })
    }
}

/// `DIR/NAME.exr` → `DIR/NAME.SUFFIX`.
fn beside(exr: &Path, suffix: &str) -> PathBuf {
    let stem = exr.file_stem().unwrap_or_default().to_string_lossy();
    exr.with_file_name(format!("{stem}.{suffix}"))
}

/// The render stamp of a batch's EXR: `DIR/NAME.exr` → `DIR/NAME.render.json`.
pub fn stamp_path(exr: &Path) -> PathBuf {
    beside(exr, "render.json")
}

/// The AOVs some channel of which `img` holds (a file without a record).
fn aovs_held(img: &AovImage) -> Vec<Aov> {
    Aov::ALL
        .into_iter()
        .filter(|&a| channel_names(a).iter().any(|c| img.has_channel(c)))
        .collect()
}

/// Where `file` differs from `fresh` (a render with every one of `aovs`), one phrase per
/// channel: a channel of `aovs` the file lacks or holds with another sample type, a channel
/// of no AOV in `aovs`, or its first differing sample, `depth at [x, y]: file 1.5, render
/// 1.49` (empty: the file holds exactly the render's samples of `aovs`).
fn differing_samples(file: &AovImage, fresh: &AovImage, aovs: &[Aov]) -> Vec<String> {
    if (file.width, file.height) != (fresh.width, fresh.height) {
        return vec![format!(
            "image size: file {}x{}, render {}x{}",
            file.width, file.height, fresh.width, fresh.height
        )];
    }
    let w = file.width;
    let at = |k: usize| format!("[{}, {}]", k % w, k / w);
    let kind = |c: &crate::image::ChannelRef| match c {
        crate::image::ChannelRef::F32(_) => "float32",
        crate::image::ChannelRef::U32(_) => "u32",
    };
    let expected: Vec<&str> = aovs
        .iter()
        .flat_map(|&a| channel_names(a))
        .copied()
        .collect();
    let listed = || {
        let names: Vec<&str> = aovs.iter().map(|a| a.name()).collect();
        names.join(",")
    };
    let mut out = Vec::new();
    let missing: Vec<&str> = expected
        .iter()
        .copied()
        .filter(|n| !file.has_channel(n))
        .collect();
    if !missing.is_empty() {
        out.push(format!(
            "missing from the file: {} (its record lists the AOVs {})",
            missing.join(", "),
            listed()
        ));
    }
    for name in &expected {
        use crate::image::ChannelRef as C;
        let Some(b) = fresh.channel(name) else {
            out.push(format!("{name}: not a channel of the render"));
            continue;
        };
        let differ = match (file.channel(name), b) {
            (None, _) => None,
            (Some(C::F32(a)), C::F32(b)) => (0..a.len().min(b.len()))
                .find(|&k| a[k].to_bits() != b[k].to_bits())
                .map(|k| format!("{name} at {}: file {}, render {}", at(k), a[k], b[k])),
            (Some(C::U32(a)), C::U32(b)) => (0..a.len().min(b.len()))
                .find(|&k| a[k] != b[k])
                .map(|k| format!("{name} at {}: file {}, render {}", at(k), a[k], b[k])),
            (Some(a), b) => Some(format!(
                "{name}: {} in the file, {} in the render",
                kind(&a),
                kind(&b)
            )),
        };
        out.extend(differ);
    }
    for name in file.names() {
        if !expected.contains(&name) {
            out.push(format!(
                "{name}: not a channel of the AOVs its record lists ({})",
                listed()
            ));
        }
    }
    out
}

/// The sha256 of `scene` as loaded (its `Debug` form: every field, floats to the last bit).
fn scene_sha256(scene: &Scene) -> String {
    use sha2::Digest;
    format!(
        "{:x}",
        sha2::Sha256::digest(format!("{scene:?}").as_bytes())
    )
}

/// The sha256 of a file's bytes, hex.
fn sha256_of(path: &Path) -> Result<String> {
    use sha2::Digest;
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(format!("{:x}", sha2::Sha256::digest(&bytes)))
}

impl Verifier for MitsubaVerifier {
    fn check(&self, view: &ViewSource, scene: &Scene, exr: &Path, work: &Path) -> Result<Verdict> {
        let keep = self.keep.is_some();
        let checked = self.check_file(view, scene, exr, work, keep, keep)?;
        let verdict = checked.verdict.clone();
        if let Some(kept) = &self.keep {
            kept.lock().unwrap_or_else(|e| e.into_inner()).push(checked);
        }
        Ok(verdict)
    }
}

impl MitsubaVerifier {
    /// Check the view's file `exr` (see the module docs): `fresh` skips the cached verdict
    /// (so the pixels are classified), `pictures` also keeps the images for a report.
    pub fn check_file(
        &self,
        view: &ViewSource,
        scene: &Scene,
        exr: &Path,
        work: &Path,
        fresh: bool,
        pictures: bool,
    ) -> Result<Checked> {
        let done = |verdict: Verdict, check: Option<ViewCheck>, images| Checked {
            name: view.id(),
            scene: view.path.display().to_string(),
            verdict,
            check,
            images,
        };
        let stamp_file = stamp_path(exr);
        let stamp = std::fs::read_to_string(&stamp_file).unwrap_or_default();
        let file = AovImage::read_exr(exr)?;
        // The record says what the file holds and which kernel made it: the view is
        // rendered again with that kernel, whatever this run's options.
        let written = if !stamp.is_empty() {
            Written::from_record(&stamp, &stamp_file.display().to_string())?
        } else if let Some(w) = &self.written {
            w.clone()
        } else {
            Written {
                aovs: aovs_held(&file),
                precision: self.precision,
                formula: self.formula,
            }
        };
        let cache_path = beside(exr, "verify.json");
        let key = CacheKey {
            rule: RULE.into(),
            view: view.id(),
            scene_sha256: scene_sha256(scene),
            stamp: stamp.clone(),
            precision: crate::choice::Choice::choice_name(written.precision).into(),
            formula: crate::choice::Choice::choice_name(written.formula).into(),
            tolerances: tolerance_key(&self.tolerances),
            // The verdict is the file's: an EXR changed after it was verified is checked
            // again.
            exr_sha256: sha256_of(exr)?,
            script: fnv1a(SCRIPT.as_bytes()),
        };
        if !fresh
            && !stamp.is_empty()
            && let Ok(text) = std::fs::read_to_string(&cache_path)
            && let Ok(c) = serde_json::from_str::<CachedVerdict>(&text)
            && c.key == key
        {
            let verdict = Verdict {
                passes: c.passed,
                report: if c.passed { c.summary } else { c.report },
            };
            return Ok(done(verdict, None, None));
        }
        let bound = Bound::cylaov(written.precision);
        let ours = check_render_with(scene, written.precision, written.formula, &written.aovs);
        let differ = differing_samples(&file, &ours, &written.aovs);
        let _scratch = signals::register(Cleanup::Tree, work);
        let reference = reference_image(
            Ok(&self.mitsuba),
            scene,
            &view.path.display().to_string(),
            work,
        )?;
        if !differ.is_empty() {
            // The file on disk is what is judged: its samples against Mitsuba and the exact
            // answer name the pixels at fault. Not cached: a file that does not match its
            // render is re-rendered on resume.
            let mut report = format!(
                "{} differs from a fresh render of its scene: {}",
                exr.display(),
                differ.join("; ")
            );
            let check = check_against_with(scene, &file, &reference, &self.tolerances, bound).ok();
            for f in check.iter().flat_map(|c| &c.failures) {
                report += &format!("\n  {f}");
            }
            let verdict = Verdict {
                passes: false,
                report,
            };
            let images = check
                .as_ref()
                .filter(|_| pictures)
                .map(|c| self.pictures(&view.name, scene, file, reference, c));
            return Ok(done(verdict, check, images));
        }
        let check = check_against_with(scene, &ours, &reference, &self.tolerances, bound)?;
        let summary = check_line(&check);
        // One line per verified view (seam and silhouette counts); a failure adds the FAIL
        // lines of `compare`. The bar, if any, redraws on the next view.
        let mut line = format!("verify {}: {summary}; {}", view.name, check.verdict_text());
        if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
            line.insert_str(0, "\r\x1b[2K");
        }
        if self.log {
            crate::output::console::warn(&line);
        }
        let cached = CachedVerdict {
            key,
            passed: check.passed(),
            silhouette_px: check.report.silhouette_mismatches,
            seam_px: check.report.seams,
            summary: summary.clone(),
            report: if check.passed() {
                String::new()
            } else {
                check.text()
            },
        };
        if !stamp.is_empty() {
            let json = serde_json::to_string_pretty(&cached)?;
            atomic_write_bytes(&cache_path, json.as_bytes())
                .with_context(|| format!("writing {}", cache_path.display()))?;
        }
        let verdict = Verdict {
            passes: check.passed(),
            report: if check.passed() {
                summary
            } else {
                check.text()
            },
        };
        let images = pictures.then(|| self.pictures(&view.name, scene, ours, reference, &check));
        Ok(done(verdict, Some(check), images))
    }

    /// The candidate, Mitsuba's render and the difference heatmap of a check.
    fn pictures(
        &self,
        name: &str,
        scene: &Scene,
        candidate: AovImage,
        reference: AovImage,
        check: &ViewCheck,
    ) -> (AovImage, AovImage, image::RgbImage) {
        let cond = Conditioning::new(scene, &candidate);
        let title = format!(
            "{name}: CYLAOV VS MITSUBA: {}",
            if check.passed() { "PASS" } else { "FAIL" }
        );
        let heatmap = heatmap_figure(
            &candidate,
            &reference,
            &check.report,
            &self.tolerances,
            cond.as_ref(),
            &title,
        );
        (candidate, reference, heatmap)
    }
}
