//! `verify --report DIR`: one self-contained page, `DIR/index.html`, with its images beside
//! it (no network): a per-view table sortable by worst error, and per view the candidate's
//! and Mitsuba's depth, the difference heatmap with its legend and colour bar, and the worst
//! disagreeing pixels with their three answers (candidate, Mitsuba, exact) and class. Each
//! proven reference error gets a script beside the page ([`crate::verify::repro`]), linked
//! from it and listed in `DIR/README.md` with how to check one before filing it upstream.

use crate::image::AovImage;
use crate::verify::arbiter::{Arbitration, Pixel, PixelClass};
use crate::verify::repro::{ReproHit, script};
use anyhow::{Context, Result};
use image::{Luma, RgbImage};
use std::fmt::Write as _;
use std::path::Path;

/// One view of the page.
pub struct ReportView<'a> {
    /// The view's batch id (`scene` or `scene/NN`).
    pub name: &'a str,
    /// PASS, FAIL or UNCHECKED.
    pub verdict: &'a str,
    /// The table row's text (counts and largest errors, or why it was not checked).
    pub summary: String,
    /// The sort key: the largest relative distance error (0 when unchecked).
    pub worst: f64,
    /// The classified pixels, when checked.
    pub arbitration: Option<&'a Arbitration>,
    /// The failure and accepted lines.
    pub lines: Vec<String>,
    /// The images: candidate, Mitsuba, heatmap (when checked).
    pub images: Option<(&'a AovImage, &'a AovImage, &'a RgbImage)>,
}

/// How many of the worst pixels a view lists.
const WORST: usize = 10;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A grey picture of `img`'s depth (or distance), near white, far dark, misses black, with
/// the range it spans.
fn depth_picture(img: &AovImage) -> Option<(image::GrayImage, f32, f32)> {
    let v = img
        .f32_channel("depth")
        .or_else(|| img.f32_channel("distance"))?;
    let hits = v.iter().copied().filter(|x| x.is_finite() && *x > 0.0);
    let (lo, hi) = hits.fold((f32::INFINITY, 0f32), |(a, b), x| (a.min(x), b.max(x)));
    let span = if hi > lo { hi - lo } else { 1.0 };
    let mut out = image::GrayImage::new(img.width as u32, img.height as u32);
    for (k, &x) in v.iter().enumerate() {
        let g = if x.is_finite() && x > 0.0 {
            (255.0 - 200.0 * (x - lo) / span).round() as u8
        } else {
            0
        };
        out.put_pixel((k % img.width) as u32, (k / img.width) as u32, Luma([g]));
    }
    Some((out, lo, hi))
}

const LEGEND: &str = "<p class=\"legend\"><span style=\"background:#1c1c1c\"></span>both miss \
<span style=\"background:#ff8c00\"></span>silhouette (another cylinder or hit vs miss) \
<span style=\"background:#00c8e6\"></span>seam (same cylinder, another part) \
<span style=\"background:#ff0000\"></span>mismatch away from any boundary \
<span style=\"background:#ff00ff\"></span>above its bound</p>\
<div class=\"bar\"></div><p class=\"ticks\"><span>1e-4</span><span>1e-2</span><span>1 (the bound)</span></p>\
<p class=\"note\">Same cylinder and part: the largest of the relative distance, relative depth and normal errors over its bound (the flat tolerance, or the pixel's float32 bound where larger), log scale.</p>";

const STYLE: &str = "body{font-family:sans-serif;margin:1em 2em}table{border-collapse:collapse}\
td,th{border:1px solid #bbb;padding:2px 6px;font-size:13px}th{cursor:pointer;background:#eee}\
.PASS{color:#070}.FAIL{color:#b00}.UNCHECKED{color:#a60}img{image-rendering:pixelated;width:320px;border:1px solid #888}\
figure{display:inline-block;margin:4px}.legend span{display:inline-block;width:12px;height:12px;margin:0 4px 0 12px}\
.bar{width:320px;height:12px;background:linear-gradient(to right,#00145a,#00aa3c,#ffe600)}\
.ticks{width:320px;display:flex;justify-content:space-between;font-size:11px;margin:0}.note{font-size:12px;color:#444}";

const SCRIPT: &str = "function sortBy(c){const t=document.getElementById('views');const r=[...t.tBodies[0].rows];\
const d=t.dataset.dir==='1'?-1:1;t.dataset.dir=d===1?'1':'0';r.sort((a,b)=>{const x=a.cells[c].dataset.v||a.cells[c].textContent;\
const y=b.cells[c].dataset.v||b.cells[c].textContent;const n=parseFloat(x)-parseFloat(y);return d*(isNaN(n)?x.localeCompare(y):n)});\
r.forEach(e=>t.tBodies[0].appendChild(e));}";

/// The picture files of view `i`: candidate depth, Mitsuba depth, heatmap.
fn pictures(i: usize) -> [String; 3] {
    ["candidate", "mitsuba", "heatmap"].map(|what| format!("view{i}.{what}.png"))
}

/// Write `dir/index.html` and its images for `views`. Every file is checked as an output
/// target first (a planted link, FIFO or folder at any of them refuses the whole page before
/// anything is written), then all are staged under temporary names and committed together,
/// so nothing outside `dir` is touched and a failure leaves no half-written page.
pub fn write_report(dir: &Path, title: &str, views: &[ReportView]) -> Result<()> {
    use crate::output::store::atomic::commit_all;
    use crate::output::store::targets::check_output;
    let repros: Vec<Vec<(String, &Pixel)>> = views
        .iter()
        .enumerate()
        .map(|(i, v)| repro_files(i, v))
        .collect();
    let any_repro = repros.iter().any(|r| !r.is_empty());
    // Every file, named before anything is written so all can be checked first.
    let mut targets = vec![dir.join("index.html")];
    for (i, v) in views.iter().enumerate() {
        if v.images.is_some() {
            targets.extend(pictures(i).iter().map(|f| dir.join(f)));
        }
    }
    targets.extend(repros.iter().flatten().map(|(f, _)| dir.join(f)));
    if any_repro {
        targets.push(dir.join("README.md"));
    }
    for t in &targets {
        check_output(&crate::spelling::opt("report"), t, &[])?;
    }
    crate::output::store::atomic::make_dir_all(dir)
        .with_context(|| format!("creating {}", dir.display()))?;
    let mut staged = Vec::new();
    let mut html = format!(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>cylaov verify: {}</title><style>{STYLE}</style><script>{SCRIPT}</script></head><body><h1>cylaov verify: {}</h1>",
        esc(title),
        esc(title)
    );
    html += &views_table(views);
    if any_repro {
        html += "<p>Proven reference errors: Mitsuba's shape differs from the exact answer on its own float32 inputs. Each has a script below; see <a href=\"README.md\">README.md</a> before filing one upstream.</p>";
    }
    for (i, (v, repros)) in views.iter().zip(&repros).enumerate() {
        html += &view_section(dir, i, v, repros, &mut staged)?;
    }
    if any_repro {
        let readme = readme(title, views, &repros);
        staged.push(stage_text(&dir.join("README.md"), &readme)?);
    }
    html += "</body></html>\n";
    staged.push(stage_text(&dir.join("index.html"), &html)?);
    commit_all(staged).with_context(|| format!("writing the report in {}", dir.display()))
}

/// The page's table of views, a row each, sortable by any column.
fn views_table(views: &[ReportView]) -> String {
    let mut html = String::from(
        "<table id=\"views\"><thead><tr><th onclick=\"sortBy(0)\">view</th><th onclick=\"sortBy(1)\">verdict</th><th onclick=\"sortBy(2)\">worst rel distance</th><th onclick=\"sortBy(3)\">reference errors</th><th onclick=\"sortBy(4)\">candidate errors</th><th onclick=\"sortBy(5)\">unexplained</th><th>result</th></tr></thead><tbody>",
    );
    for (i, v) in views.iter().enumerate() {
        let count = |f: fn(&Arbitration) -> usize| v.arbitration.map_or(0, f);
        let _ = write!(
            html,
            "<tr class=\"view\"><td><a href=\"#v{i}\">{}</a></td><td class=\"{}\">{}</td><td data-v=\"{}\">{:.2e}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(v.name),
            v.verdict,
            v.verdict,
            v.worst,
            v.worst,
            count(|a| a.reference_errors),
            count(|a| a.candidate_errors),
            count(|a| a.unexplained_reference_errors),
            esc(&v.summary)
        );
    }
    html += "</tbody></table>";
    html
}

/// View `i`'s section of the page: its verdict and lines, its pictures, its worst pixels
/// and its reproductions (`repros`); the files it names are staged into `staged`.
fn view_section(
    dir: &Path,
    i: usize,
    v: &ReportView,
    repros: &[(String, &Pixel)],
    staged: &mut Vec<crate::output::store::atomic::Staged>,
) -> Result<String> {
    use crate::output::pipeline::files::stage_png;
    let mut html = format!(
        "<h2 id=\"v{i}\">{} <span class=\"{}\">{}</span></h2>",
        esc(v.name),
        v.verdict,
        v.verdict
    );
    for l in &v.lines {
        let _ = write!(html, "<p>{}</p>", esc(l));
    }
    if let Some((cand, reference, heat)) = v.images {
        let [cand_file, mitsuba_file, heat_file] = pictures(i);
        for (img, label, file) in [
            (cand, "candidate", cand_file),
            (reference, "Mitsuba", mitsuba_file),
        ] {
            if let Some((pic, lo, hi)) = depth_picture(img) {
                staged.push(stage_png(&pic, &dir.join(&file))?);
                let _ = write!(
                    html,
                    "<figure><img src=\"{file}\" alt=\"{label} depth\"><figcaption>{label} depth: white {lo:.4} to dark {hi:.4}, black: miss</figcaption></figure>"
                );
            }
        }
        staged.push(stage_png(heat, &dir.join(&heat_file))?);
        let _ = write!(
            html,
            "<figure><img src=\"{heat_file}\" alt=\"difference\"><figcaption>{}: difference, candidate against Mitsuba ({})</figcaption>{LEGEND}</figure>",
            esc(v.name),
            v.verdict
        );
    }
    if let Some(a) = v.arbitration {
        html += &worst_pixels(a);
    }
    if !repros.is_empty() {
        html += "<h3>Proven reference errors: reproductions</h3><ul>";
        for (file, p) in repros {
            let r = p.repro.as_ref().expect("a reproduction");
            staged.push(stage_text(&dir.join(file), &script(r, &repro_title(v, p)))?);
            let _ = write!(
                html,
                "<li><a href=\"{file}\">{file}</a>: pixel [{}, {}], Mitsuba {}, exact {}</li>",
                p.at[0],
                p.at[1],
                esc(&ReproHit::describe(&r.reference)),
                esc(&ReproHit::describe(&r.exact))
            );
        }
        html += "</ul>";
    }
    Ok(html)
}

/// The table of a view's [`WORST`] pixels: candidate errors first, then unexplained and
/// proven reference errors, ties and input rounding; within a class, farthest from the
/// reference first. Empty when no pixel disagrees.
fn worst_pixels(a: &Arbitration) -> String {
    let mut worst: Vec<_> = a.pixels.iter().collect();
    let rank = |c: PixelClass| match c {
        PixelClass::CandidateError => 0,
        PixelClass::UnexplainedReferenceError => 1,
        PixelClass::ReferenceError => 2,
        PixelClass::Tie => 3,
        PixelClass::InputRounding => 4,
    };
    worst.sort_by(|p, q| {
        rank(p.class)
            .cmp(&rank(q.class))
            .then(q.reference_off.total_cmp(&p.reference_off))
    });
    if worst.is_empty() {
        return String::new();
    }
    let mut html = String::from(
        "<table><tr><th>pixel</th><th>class</th><th>kind</th><th>candidate</th><th>Mitsuba</th><th>exact</th></tr>",
    );
    for p in worst.iter().take(WORST) {
        let _ = write!(
            html,
            "<tr><td>[{}, {}]</td><td>{}</td><td>{:?}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            p.at[0],
            p.at[1],
            p.class.label(),
            p.kind,
            esc(&p.candidate.to_string()),
            esc(&p.reference.to_string()),
            esc(&p.exact.to_string())
        );
    }
    html += "</table>";
    html
}

/// How many reproductions a view writes at most (the first in image order).
const REPROS: usize = 20;

/// A text file staged for [`write_report`]'s commit.
fn stage_text(path: &Path, text: &str) -> Result<crate::output::store::atomic::Staged> {
    crate::output::store::atomic::stage(path, |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
    })
    .with_context(|| format!("writing {}", path.display()))
}

/// View `i`'s pixels with a reproduction and their script files, `view{i}.repro{n}.py`.
fn repro_files<'a>(i: usize, v: &ReportView<'a>) -> Vec<(String, &'a Pixel)> {
    v.arbitration
        .into_iter()
        .flat_map(|a| a.pixels.iter())
        .filter(|p| p.repro.is_some())
        .take(REPROS)
        .enumerate()
        .map(|(n, p)| (format!("view{i}.repro{n}.py"), p))
        .collect()
}

/// The docstring's first line of a reproduction.
fn repro_title(v: &ReportView, p: &Pixel) -> String {
    format!(
        "{}, pixel [{}, {}]: {} where Mitsuba's shape is not the exact answer's on its float32 inputs",
        v.name,
        p.at[0],
        p.at[1],
        p.class.label()
    )
}

/// `README.md` of a report with reproductions: how to check one before filing it, and the
/// list of scripts with the answers each should print.
fn readme(title: &str, views: &[ReportView], repros: &[Vec<(String, &Pixel)>]) -> String {
    let mut s = format!(
        "# Proven reference errors: {title}\n\n\
At these pixels Mitsuba's shape (another cylinder, another part, or hit vs miss) is not the \
exact answer's on the inputs Mitsuba was given: the cylinders' p0, p1 and radius rounded to \
float32, and the pixel ray rounded to float32 with its origin on the near plane. Each \
`*.py` script holds the one or two cylinders involved, written as the Mitsuba export writes \
them, and that one ray; it prints Mitsuba's answer (shape id, part, t) beside the exact one, \
computed by cylaov in double-double on the same float32 inputs.\n\n\
Before filing one upstream:\n\n\
1. Run the script with the pinned Mitsuba: `pip install mitsuba==3.9.1 numpy`, then \
`python view0.repro0.py`.\n\
2. The finding stands only if the script prints `REPRODUCED`: Mitsuba's shape differs from \
the exact answer's on that ray. `NOT REPRODUCED` means Mitsuba's render used a ray that \
differs from this one in its last bits; there is nothing to file.\n\
3. File the script, not the dataset: it needs nothing else.\n\n\
| script | view | pixel | class | Mitsuba in the render | exact |\n|---|---|---|---|---|---|\n"
    );
    for (v, files) in views.iter().zip(repros) {
        for (file, p) in files {
            let r = p.repro.as_ref().expect("a reproduction");
            let _ = writeln!(
                s,
                "| [{file}]({file}) | {} | [{}, {}] | {} | {} | {} |",
                v.name.replace('|', "\\|"),
                p.at[0],
                p.at[1],
                p.class.label(),
                ReproHit::describe(&r.reference),
                ReproHit::describe(&r.exact)
            );
        }
    }
    s
}
