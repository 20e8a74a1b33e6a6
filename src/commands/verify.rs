//! `cylaov verify`: the cross-renderer check for any scene, folder or manifest. Each
//! selected view is rendered by cylaov (in memory) and by Mitsuba 3 and compared by
//! [`crate::verify::reference::verify_scene`], the code path of `batch --verify-fraction`
//! and the reference tests: where they disagree, the exact answer decides who is wrong
//! ([`crate::verify::arbiter`]). Perspective and orthographic cameras are checked against
//! Mitsuba; the lens models, which Mitsuba has no camera for, against the exact answer
//! alone (no venv needed), and their rows say so. Prints a per-view table and a summary (or JSON with every
//! disagreeing pixel's class); the exit status is 1 if any view fails (a candidate error or
//! an unexplained reference error), else 2 if any could not be checked, else 0.

use crate::dataset::batch::{ViewSource, list_views, view_selected};
use crate::geometry::{FormulaKind, Precision};
use crate::image::AovImage;
use crate::output::pipeline::files::write_png;
use crate::verify::arbiter::{Arbitration, Bound, Reference};
use crate::verify::compare::{Conditioning, Report, Tolerances, heatmap_figure};
use crate::verify::reference::{
    Mitsuba, ViewCheck, check_against_with, reference_image, summary_line, verify_scene,
};
use crate::verify::report::{ReportView, write_report};
use anyhow::Result;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Everything `verify` needs from the command line.
#[derive(Clone, Debug)]
pub struct VerifyArgs {
    /// A scene file, a folder of them, or a `.jsonl` manifest.
    pub input: PathBuf,
    /// Fraction of the views to check (chosen from `seed` and the views' batch ids).
    pub fraction: f64,
    /// Seed of the `fraction` choice (the same choice as `batch --verify-seed`).
    pub seed: u64,
    /// Folder for `NAME.heatmap.png` of every checked view.
    pub heatmap: Option<PathBuf>,
    /// Print the results as JSON instead of the table.
    pub json: bool,
    /// The pass/fail bounds.
    pub tolerances: Tolerances,
    /// Kernel precision of cylaov's side.
    pub precision: Precision,
    /// Kernel formulation of cylaov's side.
    pub formula: FormulaKind,
    /// Another renderer's AOV EXR of `input` (a scene file) to check instead of cylaov's
    /// render.
    pub candidate: Option<PathBuf>,
    /// `aov=NAME` maps of the candidate's channels (`normal=N`: `N.X/N.Y/N.Z` or
    /// `N.R/N.G/N.B`).
    pub channels: Vec<String>,
    /// The candidate's bound: float32 ulps of storage and of sideways ray error.
    pub candidate_ulps: f64,
    /// The scene's camera the candidate shows (needed when the scene has several).
    pub camera: Option<usize>,
    /// Folder for the report page (`index.html` and its images).
    pub report: Option<PathBuf>,
    /// With a batch's output as `input`: the folder (or manifest) the batch read its
    /// scenes from.
    pub scenes: Option<PathBuf>,
}

/// One view of a batch's `index.json`.
#[derive(serde::Deserialize)]
struct IndexView {
    scene: String,
    scene_file: String,
    camera: usize,
    exr_file_path: String,
}

/// A record file a batch wrote (`index.json`, `shards.json`), read as `T`; an error names
/// the file.
fn read_record<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text =
        std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// `verify OUT/` of a batch's output: the EXR files on disk, each judged against Mitsuba
/// and the exact answer (the check of `batch --verify-fraction`, its verdict kept beside
/// the file keyed on the file's sha256).
fn run_written(args: &VerifyArgs) -> Result<VerifyOutcome> {
    let index_path = args.input.join("index.json");
    #[derive(serde::Deserialize)]
    struct Index {
        /// The batch's input, absolute (absent in the indexes of older versions).
        input: Option<PathBuf>,
        views: Vec<IndexView>,
    }
    let index: Index = read_record(&index_path)?;
    // `--scenes` overrides the recorded input (a dataset whose scenes moved).
    let scenes = match (&args.scenes, &index.input) {
        (Some(scenes), _) => scenes.clone(),
        (None, Some(input)) if input.exists() => input.clone(),
        (None, Some(input)) => anyhow::bail!(
            "{}: the batch's input {} is gone; give the folder or manifest its scenes are in now with --scenes DIR",
            index_path.display(),
            input.display()
        ),
        (None, None) => anyhow::bail!(
            "{}: a batch's output that does not record its input; give the folder or manifest its scenes came from with --scenes DIR",
            index_path.display()
        ),
    };
    let scene_dir = if scenes.is_file() {
        scenes.parent().unwrap_or(Path::new(".")).to_path_buf()
    } else {
        scenes
    };
    let verifier = crate::verify::reference::MitsubaVerifier::find(
        args.tolerances,
        args.precision,
        args.formula,
    )
    .map(|v| crate::verify::reference::MitsubaVerifier { log: false, ..v });
    // The pixels' classes (JSON) and the pictures (the page) need a fresh check: a cached
    // verdict has neither.
    let pictures = args.report.is_some();
    let fresh = args.json || pictures;
    let mut images: Vec<Option<Images>> = Vec::new();
    if let Err(why) = &verifier {
        crate::output::console::warn(&format!("verify: {why}"));
    }
    let mut results = Vec::new();
    let mut all = 0;
    for (k, v) in index.views.iter().enumerate() {
        let (folder, name) = match v.exr_file_path.rsplit_once('/') {
            Some((f, n)) => (Some(f.to_string()), n),
            None => (None, v.exr_file_path.as_str()),
        };
        let view = ViewSource {
            name: name.trim_end_matches(".exr").to_string(),
            path: scene_dir.join(&v.scene_file),
            scene: v.scene.clone(),
            camera: v.camera,
            folder,
        };
        all += 1;
        if !view_selected(args.seed, &view, args.fraction) {
            continue;
        }
        // A path that is absolute or climbs out would read (and write the verdict beside) a
        // file outside OUT.
        let rel = Path::new(&v.exr_file_path);
        if !rel
            .components()
            .all(|c| matches!(c, std::path::Component::Normal(_)))
        {
            anyhow::bail!(
                "{}: exr_file_path {:?} is not a path inside {}",
                index_path.display(),
                v.exr_file_path,
                args.input.display()
            );
        }
        let exr = args.input.join(rel);
        // The stamp records the AOVs and the kernel the file was rendered with: without
        // it, what the file should hold is not known.
        let stamp = crate::verify::reference::stamp_path(&exr);
        let (result, pics) = check_written(&verifier, &view, k, fresh, pictures, |_| {
            if !stamp.is_file() {
                anyhow::bail!(
                    "{}: missing: it records the AOVs and the kernel {} was rendered with",
                    stamp.display(),
                    exr.display()
                );
            }
            Ok(exr.clone())
        });
        results.push(result);
        images.push(pics);
    }
    if let Some(dir) = &args.report {
        write_page(dir, &args.input.display().to_string(), &results, &images)?;
    }
    outcome(args, results, |results, counts| {
        written_table(results, all, counts)
    })
}

/// One written view checked (see [`MitsubaVerifier::check_file`]): its scene loaded, its
/// EXR (the file itself, or a sample written to the scratch folder by `exr`) judged; a view
/// that could not be checked says why in its row.
///
/// [`MitsubaVerifier::check_file`]: crate::verify::reference::MitsubaVerifier::check_file
fn check_written(
    verifier: &std::result::Result<crate::verify::reference::MitsubaVerifier, String>,
    view: &ViewSource,
    k: usize,
    fresh: bool,
    pictures: bool,
    exr: impl FnOnce(&Path) -> Result<PathBuf>,
) -> (ViewResult, Option<Images>) {
    let outcome = (|| -> Result<crate::verify::reference::Checked> {
        let verifier = verifier.as_ref().map_err(|why| anyhow::anyhow!("{why}"))?;
        let mut scene = crate::scene::load(&view.path)
            .map_err(|e| anyhow::anyhow!("{}: {e}", view.path.display()))?;
        scene
            .select_camera(view.camera)
            .map_err(|e| anyhow::anyhow!("{}: {e}", view.path.display()))?;
        let work = work_dir(k)?;
        let exr = exr(work.path())?;
        verifier.check_file(view, &scene, &exr, work.path(), fresh, pictures)
    })();
    match outcome {
        Ok(c) => checked_result(c),
        Err(e) => (ViewResult::unchecked(view, &e), None),
    }
}

/// The table of `verify OUT`: a line per checked view, then the counts.
fn written_table(
    results: &[ViewResult],
    all: usize,
    (passed, failed, unchecked): (usize, usize, usize),
) -> String {
    let mut s = format!("{:<24} {:<9} result\n", "view", "verdict");
    for r in results {
        let mut lines = r
            .failures
            .iter()
            .chain(&r.accepted)
            .cloned()
            .collect::<Vec<_>>();
        // A view checked now has its summary in the row (as `verify SCENE` prints it); a
        // verdict read from the cache has its summary as its first line.
        let head = if r.report.is_some() || lines.is_empty() {
            row(r)
        } else {
            format!(
                "{:<24} {:<9} {}",
                r.name,
                verdict_word(r.status),
                lines.remove(0)
            )
        };
        s += &head;
        for line in lines {
            s += &format!("\n  {line}");
        }
        s.push('\n');
    }
    s += &format!(
        "verify: {} of {all} written views checked: {passed} passed, {failed} failed, {unchecked} could not be checked",
        results.len()
    );
    s
}

/// `verify OUT/` of a tar-shard dataset (`batch --format webdataset`): the samples in the
/// tars `shards.json` lists, each one's arrays judged against Mitsuba and the exact answer
/// as the EXR of the files format is (written to a scratch EXR for the check), its scene
/// read from `shards.json`'s `scenes_dir` (or `--scenes`). The tars are read one sample at
/// a time; nothing is written beside them.
fn run_shards(args: &VerifyArgs) -> Result<VerifyOutcome> {
    use crate::dataset::batch::samples::Samples;
    let index_path = args.input.join("shards.json");
    #[derive(serde::Deserialize)]
    struct Entry {
        name: String,
        samples: usize,
    }
    #[derive(serde::Deserialize)]
    struct Index {
        /// Absent in the records of older versions.
        scenes_dir: Option<PathBuf>,
        shards: Vec<Entry>,
    }
    let index: Index = read_record(&index_path)?;
    // What every sample holds and the kernel that rendered it.
    let text = std::fs::read_to_string(&index_path)
        .map_err(|e| anyhow::anyhow!("{}: {e}", index_path.display()))?;
    let written =
        crate::verify::reference::Written::from_record(&text, &index_path.display().to_string())?;
    let scene_dir = match (&args.scenes, &index.scenes_dir) {
        (Some(s), _) if s.is_file() => s.parent().unwrap_or(Path::new(".")).to_path_buf(),
        (Some(s), _) => s.clone(),
        (None, Some(d)) if d.is_dir() => d.clone(),
        (None, Some(d)) => anyhow::bail!(
            "{}: the scenes' folder {} is gone; give the folder its scenes are in now with --scenes DIR",
            index_path.display(),
            d.display()
        ),
        (None, None) => anyhow::bail!(
            "{}: a dataset that does not record its scenes' folder; give it with --scenes DIR",
            index_path.display()
        ),
    };
    let verifier = crate::verify::reference::MitsubaVerifier::find(
        args.tolerances,
        args.precision,
        args.formula,
    )
    .map(|v| crate::verify::reference::MitsubaVerifier {
        log: false,
        written: Some(written),
        ..v
    });
    if let Err(why) = &verifier {
        crate::output::console::warn(&format!("verify: {why}"));
    }
    let pictures = args.report.is_some();
    let (mut results, mut images, mut all) = (Vec::new(), Vec::new(), 0);
    for entry in &index.shards {
        // A name that is not a plain file name would lead out of OUT.
        if entry.name.contains(['/', '\\']) || entry.name.starts_with('.') {
            anyhow::bail!(
                "{}: shard name {:?} is not a file name",
                index_path.display(),
                entry.name
            );
        }
        let path = args.input.join(&entry.name);
        let file = crate::output::store::files::open_input(&path)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let mut samples = Samples::new(std::io::BufReader::with_capacity(1 << 20, file));
        let mut read = 0;
        loop {
            let sample = samples
                .next_sample()
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            let Some(sample) = sample else {
                if read != entry.samples {
                    anyhow::bail!(
                        "{}: {read} samples, where shards.json lists {}",
                        path.display(),
                        entry.samples
                    );
                }
                break;
            };
            read += 1;
            let info = &sample.info;
            let view = ViewSource {
                name: info.key.clone(),
                path: scene_dir.join(&info.scene_file),
                scene: info.scene.clone(),
                camera: info.camera_index,
                folder: None,
            };
            all += 1;
            if !view_selected(args.seed, &view, args.fraction) {
                continue;
            }
            let exr = |work: &Path| -> Result<PathBuf> {
                let exr = work.join(format!("{}.exr", sample.info.key));
                sample
                    .image
                    .write_exr(&exr, crate::output::format::exr::Compression::None)?;
                Ok(exr)
            };
            let (result, pics) =
                check_written(&verifier, &view, results.len(), true, pictures, exr);
            results.push(result);
            images.push(pics);
        }
    }
    if let Some(dir) = &args.report {
        write_page(dir, &args.input.display().to_string(), &results, &images)?;
    }
    outcome(args, results, |results, counts| {
        written_table(results, all, counts)
    })
}

/// The AOVs a candidate's channels can be mapped to, and whether each is a 3-vector.
const CANDIDATE_AOVS: [(&str, bool); 6] = [
    ("distance", false),
    ("depth", false),
    ("normal", true),
    ("position", true),
    ("shape_id", false),
    ("part", false),
];

/// The `--channels aov=NAME` maps as (map, AOV, NAME, whether the AOV is a 3-vector); an
/// AOV named twice is refused (which of the two would the check read?).
fn channel_maps(maps: &[String]) -> Result<Vec<(&str, &str, &str, bool)>> {
    let mut out: Vec<(&str, &str, &str, bool)> = Vec::new();
    for m in maps {
        let Some((aov, name)) = m.split_once('=') else {
            anyhow::bail!("--channels: expected AOV=NAME, got {m:?}");
        };
        let Some(&(_, vector)) = CANDIDATE_AOVS.iter().find(|(a, _)| *a == aov) else {
            let names: Vec<&str> = CANDIDATE_AOVS.iter().map(|a| a.0).collect();
            anyhow::bail!("--channels: {aov:?} is not one of {}", names.join(", "));
        };
        if let Some((first, ..)) = out.iter().find(|(_, a, ..)| *a == aov) {
            anyhow::bail!(
                "--channels: {aov} is mapped twice ({first} and {m}); give one map an AOV"
            );
        }
        out.push((m, aov, name, vector));
    }
    Ok(out)
}

/// `img`'s channels renamed by `--channels aov=NAME` maps: a vector AOV takes `NAME.X/Y/Z`
/// or `NAME.R/G/B`; channels not mapped keep their names (cylaov's, if the renderer used
/// them).
pub fn map_channels(mut img: AovImage, maps: &[String]) -> Result<AovImage> {
    for (m, aov, name, vector) in channel_maps(maps)? {
        let has = |img: &AovImage, n: &str| img.has_channel(n);
        let pairs: Vec<(String, String)> = if !vector {
            vec![(name.to_string(), aov.to_string())]
        } else if ["X", "Y", "Z"]
            .iter()
            .all(|c| has(&img, &format!("{name}.{c}")))
        {
            ["X", "Y", "Z"]
                .iter()
                .map(|c| (format!("{name}.{c}"), format!("{aov}.{c}")))
                .collect()
        } else {
            ["R", "G", "B"]
                .iter()
                .zip(["X", "Y", "Z"])
                .map(|(c, x)| (format!("{name}.{c}"), format!("{aov}.{x}")))
                .collect()
        };
        for (from, to) in pairs {
            if !has(&img, &from) {
                anyhow::bail!("--channels {m}: the candidate has no channel {from}");
            }
            img.rename_channel(&from, &to);
        }
    }
    Ok(img.regrouped())
}

/// How one view came out.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// No candidate error and no unexplained reference error.
    Pass,
    /// A candidate error or an unexplained reference error.
    Fail,
    /// The check could not be made (bad scene, Mitsuba failed, no venv).
    Unchecked,
}

/// One view's row.
#[derive(Clone, Debug, Serialize)]
pub struct ViewResult {
    /// The view's batch id: the scene's name, or `scene/00` for a camera of a several-camera
    /// scene (as `batch` names it).
    pub name: String,
    /// The scene file's path.
    pub scene: String,
    /// Pass, fail or unchecked.
    pub status: Status,
    /// Why it failed (candidate errors, unexplained reference errors), or why it could not
    /// be checked.
    pub failures: Vec<String>,
    /// What passed without being exact: reference errors, ties, the note where Mitsuba
    /// cannot discriminate.
    pub accepted: Vec<String>,
    /// The comparison, when the view could be checked.
    pub report: Option<Report>,
    /// Every disagreeing pixel classified by the exact answer, when the view was checked.
    pub arbitration: Option<Arbitration>,
}

impl ViewResult {
    /// The row of a view that could not be checked, saying why.
    fn unchecked(view: &ViewSource, e: &anyhow::Error) -> ViewResult {
        ViewResult {
            name: view.id(),
            scene: view.path.display().to_string(),
            status: Status::Unchecked,
            failures: vec![format!("{e:#}")],
            accepted: Vec::new(),
            report: None,
            arbitration: None,
        }
    }
}

/// The outcome: text to print and the exit status.
pub struct VerifyOutcome {
    /// The table (or JSON) to print.
    pub text: String,
    /// Exit status: 1 if any view failed, else 2 if any was unchecked, else 0.
    pub code: u8,
    /// Every checked view, in order.
    pub views: Vec<ViewResult>,
}

#[derive(Serialize)]
struct JsonOut<'a> {
    input: String,
    tolerances: Tolerances,
    checked: usize,
    passed: usize,
    failed: usize,
    unchecked: usize,
    views: &'a [ViewResult],
}

/// The views of `input`: every camera of one scene file, or what `batch` would render.
fn views(input: &Path) -> Result<Vec<ViewSource>> {
    let is_scene = input.is_file() && input.extension().is_some_and(|e| e == "json");
    let scenes = if is_scene {
        let name = input
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        vec![ViewSource::scene(name, input.to_path_buf())]
    } else {
        list_views(input, None)?.0
    };
    // A scene that does not load counts as one view: its check reports why.
    Ok(scenes
        .iter()
        .flat_map(|s| {
            let cameras = crate::scene::load(&s.path).map_or(1, |sc| sc.cameras.len());
            s.cameras(cameras)
        })
        .collect())
}

/// A private scratch folder for one view's Mitsuba files, removed when dropped (also when
/// the check fails).
fn work_dir(k: usize) -> Result<tempfile::TempDir> {
    Ok(tempfile::Builder::new()
        .prefix(&format!("cylaov-verify-{k}-"))
        .tempdir()?)
}

/// Check one view against its reference: Mitsuba (`mitsuba`, or why there is none) for a
/// perspective or orthographic camera, the exact answer alone for a lens model.
fn check_one(
    args: &VerifyArgs,
    mitsuba: Result<&Mitsuba, &str>,
    view: &ViewSource,
    k: usize,
) -> Result<(ViewCheck, Option<Images>)> {
    let mut scene = crate::scene::load(&view.path)
        .map_err(|e| anyhow::anyhow!("{}: {e}", view.path.display()))?;
    scene
        .select_camera(view.camera)
        .map_err(|e| anyhow::anyhow!("{}: {e}", view.path.display()))?;
    let work = work_dir(k)?;
    let result = match &args.candidate {
        None => verify_scene(
            mitsuba,
            &scene,
            &view.path.display().to_string(),
            args.precision,
            args.formula,
            &args.tolerances,
            work.path(),
        ),
        Some(file) => (|| {
            let theirs = AovImage::read_exr(file)
                .map_err(|e| anyhow::anyhow!("--candidate {}: {e:#}", file.display()))?;
            let theirs = map_channels(theirs, &args.channels)?;
            let reference = reference_image(
                mitsuba,
                &scene,
                &view.path.display().to_string(),
                work.path(),
            )?;
            let mut check = check_against_with(
                &scene,
                &theirs,
                &reference,
                &args.tolerances,
                Bound::float32_ulps(args.candidate_ulps),
            )
            .map_err(|e| anyhow::anyhow!("--candidate {}: {e:#}", file.display()))?;
            // Channels the exact answer has no value for: said, not passed in silence.
            let unjudged = crate::verify::arbiter::unjudged_channels(&theirs);
            if !unjudged.is_empty() {
                check.accepted.push(format!(
                    "not judged: {}: the exact answer has no value for them",
                    unjudged.join(", ")
                ));
            }
            Ok((check, theirs, reference))
        })(),
    };
    drop(work);
    let (check, ours, reference) = result?;
    if args.heatmap.is_none() && args.report.is_none() {
        return Ok((check, None));
    }
    let cond = Conditioning::new(&scene, &ours);
    let title = format!(
        "{}: {} VS {}: {}",
        view.name,
        if args.candidate.is_some() {
            "CANDIDATE"
        } else {
            "CYLAOV"
        },
        match check.arbitration.reference {
            Reference::Mitsuba => "MITSUBA",
            Reference::Exact => "EXACT ANSWER",
        },
        if check.passed() { "PASS" } else { "FAIL" }
    );
    let img = heatmap_figure(
        &ours,
        &reference,
        &check.report,
        &args.tolerances,
        cond.as_ref(),
        &title,
    );
    if let Some(dir) = &args.heatmap {
        let path = view.dir(dir).join(format!("{}.heatmap.png", view.name));
        crate::output::store::targets::check_output("--heatmap", &path, &[&view.path])?;
        if let Some(parent) = path.parent() {
            crate::output::store::atomic::make_dir_all(parent)?;
        }
        write_png(&img, &path)?;
    }
    Ok((check, Some((ours, reference, img))))
}

/// A checked view's pictures for the report: candidate, Mitsuba, difference heatmap.
type Images = (AovImage, AovImage, image::RgbImage);

/// Check every selected view of `args.input`.
pub fn run(args: &VerifyArgs) -> Result<VerifyOutcome> {
    if !(0.0..=1.0).contains(&args.fraction) || args.fraction.is_nan() {
        return super::usage(format!(
            "--fraction: must be in [0, 1], got {}",
            args.fraction
        ));
    }
    if let Some(dir) = &args.heatmap {
        crate::output::store::targets::check_output_dir("--heatmap", dir)?;
    }
    if let Some(dir) = &args.report {
        crate::output::store::targets::check_output_dir("--report", dir)?;
    }
    // A candidate that is not a regular file is refused before Mitsuba is asked for
    // anything (reading a FIFO would block).
    channel_maps(&args.channels)?;
    if let Some(file) = &args.candidate {
        crate::output::store::files::open_input(file)
            .map_err(|e| anyhow::anyhow!("--candidate: {e}"))?;
    }
    if args.input.join("index.json").is_file() {
        return run_written(args);
    }
    if args.input.join("shards.json").is_file() {
        return run_shards(args);
    }
    let mut all = views(&args.input)?;
    if let Some(file) = &args.candidate {
        if !(args.input.is_file() && args.input.extension().is_some_and(|e| e == "json")) {
            anyhow::bail!(
                "--candidate {}: needs the scene file it shows, got {}",
                file.display(),
                args.input.display()
            );
        }
        if !(args.candidate_ulps.is_finite() && args.candidate_ulps > 0.0) {
            anyhow::bail!("--candidate-ulps: must be > 0, got {}", args.candidate_ulps);
        }
        let n = all.len();
        let k = match args.camera {
            Some(k) if k < n => k,
            Some(k) => anyhow::bail!("--camera: the scene has {n} camera(s), got {k}"),
            None if n == 1 => 0,
            None => anyhow::bail!(
                "--camera: the scene has {n} cameras; say which one {} shows",
                file.display()
            ),
        };
        all = vec![all.swap_remove(k)];
    } else if args.camera.is_some() || !args.channels.is_empty() {
        anyhow::bail!("--camera and --channels go with --candidate");
    }
    let selected: Vec<&ViewSource> = all
        .iter()
        .filter(|v| view_selected(args.seed, v, args.fraction))
        .collect();
    let mitsuba = Mitsuba::find();
    // Without the venv nothing can be checked. The table says how to make it once, under
    // the rows; JSON on stdout gets it on stderr as well, for the person reading the run.
    if let (Err(why), true) = (&mitsuba, args.json) {
        crate::output::console::warn(&format!("verify: {why}"));
    }
    // Progress: one line redrawn in place, on a terminal only (the table goes to stdout).
    let live = !args.json && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut results = Vec::with_capacity(selected.len());
    let mut pictures: Vec<Option<Images>> = Vec::new();
    for (k, view) in selected.iter().enumerate() {
        if live && mitsuba.is_ok() {
            progress(&format!(
                "[{}/{}] verifying {}",
                k + 1,
                selected.len(),
                view.id()
            ));
        }
        // A lens model needs no venv: its reference is the exact answer alone.
        let m = match &mitsuba {
            Ok(m) => Ok(m),
            Err(why) if args.json => Err(why.as_str()),
            Err(_) => Err("no Mitsuba venv (how to make one: below)"),
        };
        let outcome = check_one(args, m, view, k);
        let r = match outcome {
            Ok((check, images)) => {
                pictures.push(images);
                ViewResult {
                    name: view.id(),
                    scene: view.path.display().to_string(),
                    status: if check.passed() {
                        Status::Pass
                    } else {
                        Status::Fail
                    },
                    failures: check.failures.clone(),
                    accepted: check.accepted.clone(),
                    report: Some(check.report),
                    arbitration: Some(check.arbitration),
                }
            }
            Err(e) => {
                pictures.push(None);
                ViewResult::unchecked(view, &e)
            }
        };
        results.push(r);
    }
    if live && mitsuba.is_ok() && !selected.is_empty() {
        progress("");
    }
    if let Some(dir) = &args.report {
        write_page(dir, &args.input.display().to_string(), &results, &pictures)?;
    }
    outcome(args, results, |results, counts| {
        table(args, &all, results, counts, &mitsuba)
    })
}

/// A view checked by the batch verifier as a row, with its pictures: a verdict read from the
/// cache has its line and no pixels.
fn checked_result(c: crate::verify::reference::Checked) -> (ViewResult, Option<Images>) {
    let v = &c.verdict;
    let status = if v.passes { Status::Pass } else { Status::Fail };
    let (failures, accepted) = match &c.check {
        // The file's failures: the first differing sample, then the exact answer's classes.
        Some(check) if !v.passes => (vec![v.report.clone()], check.accepted.clone()),
        Some(check) => (Vec::new(), check.accepted.clone()),
        None if v.passes => (Vec::new(), vec![v.report.clone()]),
        None => (vec![v.report.clone()], Vec::new()),
    };
    let (report, arbitration) = c
        .check
        .map(|check| (check.report, check.arbitration))
        .unzip();
    let result = ViewResult {
        name: c.name,
        scene: c.scene,
        status,
        failures,
        accepted,
        report,
        arbitration,
    };
    (result, c.images)
}

/// `DIR/index.html` of checked views and their pictures, titled `title`.
fn write_page(
    dir: &Path,
    title: &str,
    results: &[ViewResult],
    pictures: &[Option<Images>],
) -> Result<()> {
    let views: Vec<ReportView> = results
        .iter()
        .zip(pictures)
        .map(|(r, p)| ReportView {
            name: &r.name,
            verdict: verdict_word(r.status),
            summary: row(r),
            worst: r
                .report
                .as_ref()
                .and_then(|rep| rep.rel_distance.as_ref())
                .map_or(0.0, |m| m.all.max),
            arbitration: r.arbitration.as_ref(),
            lines: r.failures.iter().chain(&r.accepted).cloned().collect(),
            images: p.as_ref().map(|(a, b, h)| (a, b, h)),
        })
        .collect();
    write_report(dir, title, &views)
}

/// `batch --verify-fraction F --report DIR`: the page of `verify --report` for the views the
/// batch checked (kept by its verifier), sorted by view id.
pub fn batch_report(
    dir: &Path,
    title: &str,
    mut checked: Vec<crate::verify::reference::Checked>,
) -> Result<()> {
    checked.sort_by(|a, b| a.name.cmp(&b.name));
    let (results, pictures): (Vec<ViewResult>, Vec<Option<Images>>) =
        checked.into_iter().map(checked_result).unzip();
    write_page(dir, title, &results, &pictures)
}

/// The exit status and the printed text (JSON, or the table `table` makes from the views and
/// their (passed, failed, unchecked) counts) of checked views: 1 if any failed, else 2 if
/// any could not be checked, else 0.
fn outcome(
    args: &VerifyArgs,
    results: Vec<ViewResult>,
    table: impl FnOnce(&[ViewResult], (usize, usize, usize)) -> String,
) -> Result<VerifyOutcome> {
    let count = |s: Status| results.iter().filter(|r| r.status == s).count();
    let (passed, failed, unchecked) = (
        count(Status::Pass),
        count(Status::Fail),
        count(Status::Unchecked),
    );
    let code = if failed > 0 {
        1
    } else if unchecked > 0 {
        2
    } else {
        0
    };
    let text = if args.json {
        serde_json::to_string_pretty(&JsonOut {
            input: args.input.display().to_string(),
            tolerances: args.tolerances,
            checked: results.len(),
            passed,
            failed,
            unchecked,
            views: &results,
        })?
    } else {
        table(&results, (passed, failed, unchecked))
    };
    Ok(VerifyOutcome {
        text,
        code,
        views: results,
    })
}

/// Redraw the one progress line on stderr (a terminal): `text` replaces what was there.
fn progress(text: &str) {
    use std::io::Write;
    let mut err = std::io::stderr().lock();
    let _ = write!(err, "\r\x1b[2K{text}");
    let _ = err.flush();
}

fn verdict_word(s: Status) -> &'static str {
    match s {
        Status::Pass => "PASS",
        Status::Fail => "FAIL",
        Status::Unchecked => "UNCHECKED",
    }
}

/// One table row: name, verdict, mismatch counts, largest errors.
fn row(r: &ViewResult) -> String {
    let verdict = verdict_word(r.status);
    match (&r.report, &r.arbitration) {
        // Against the exact answer alone there is no reference to be in error.
        (Some(rep), Some(a)) if a.reference == Reference::Exact => format!(
            "{:<24} {verdict:<9} {}; candidate errors {}, ties {} (against the exact answer alone)",
            r.name,
            summary_line(rep),
            a.candidate_errors,
            a.ties
        ),
        (Some(rep), Some(a)) => format!(
            "{:<24} {verdict:<9} {}; reference errors {}, unexplained {}, candidate errors {}, ties {}",
            r.name,
            summary_line(rep),
            a.reference_errors,
            a.unexplained_reference_errors,
            a.candidate_errors,
            a.ties
        ),
        _ => format!("{:<24} {verdict:<9} {}", r.name, r.failures.join("; ")),
    }
}

fn table(
    args: &VerifyArgs,
    all: &[ViewSource],
    results: &[ViewResult],
    (passed, failed, unchecked): (usize, usize, usize),
    mitsuba: &Result<Mitsuba, String>,
) -> String {
    let mut s = format!("{:<24} {:<9} result\n", "view", "verdict");
    for r in results {
        s += &row(r);
        s.push('\n');
    }
    for r in results.iter().filter(|r| r.status == Status::Fail) {
        s += &format!("{} FAIL:\n", r.name);
        for f in &r.failures {
            s += &format!("  {f}\n");
        }
    }
    for r in results {
        for a in &r.accepted {
            s += &format!("{} accepted: {a}\n", r.name);
        }
    }
    s += &crate::verify::compare::tolerance_line(&args.tolerances);
    s.push('\n');
    // Said only where it kept a view from being checked: the lens models need no venv.
    if let Err(why) = mitsuba
        && unchecked > 0
    {
        s += &format!("verify: {why}\n");
    }
    s += &format!(
        "verify: {} of {} views checked: {passed} passed, {failed} failed, {unchecked} could not be checked",
        results.len(),
        all.len()
    );
    s
}
