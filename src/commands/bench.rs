//! `cylaov bench`: print the time-vs-error table, optionally as CSV and as a figure.

use crate::bench::{self, Anchors, BenchOptions, Row};
use crate::output::console::say;
use crate::output::format::camera_files::csv_bytes;
use crate::output::store::atomic::atomic_write_bytes;
use crate::output::store::targets::check_outputs;
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};

mod plot;

/// Fail before a run of minutes, not after it, when an output's folder is missing.
fn check_parent(path: &Path, flag: &str) -> Result<()> {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() && !dir.is_dir() => {
            bail!("{flag}: folder {} does not exist", dir.display())
        }
        _ => Ok(()),
    }
}

/// Run the table, printing rows as they finish; then the anchors' (Mitsuba, Open3D), if
/// asked; write CSV if asked (`OUT.csv`, the kernel-alone rows to `OUT.kernel.csv`, the
/// anchors' to `OUT.anchors.csv`) and the figure if asked.
pub fn run(
    opts: &BenchOptions,
    anchors: Option<Anchors>,
    csv: Option<PathBuf>,
    plot: Option<PathBuf>,
) -> Result<Vec<Row>> {
    let mut outputs: Vec<(&str, PathBuf)> = Vec::new();
    if let Some(p) = &csv {
        check_parent(p, "--csv")?;
        for q in [
            p.clone(),
            p.with_extension("kernel.csv"),
            p.with_extension("anchors.csv"),
        ] {
            outputs.push(("--csv", q));
        }
    }
    if let Some(dir) = &opts.keep_scenes {
        if !dir.is_dir() {
            bail!("--keep-scenes: {} is not a folder", dir.display());
        }
        for f in &opts.families {
            for n in &opts.counts {
                outputs.push(("--keep-scenes", dir.join(format!("{}-{n}.json", f.name()))));
            }
        }
    }
    if let Some(p) = &plot {
        check_parent(p, "--plot")?;
        outputs.push(("--plot", p.clone()));
    }
    let outputs: Vec<(&str, &Path)> = outputs.iter().map(|(f, p)| (*f, p.as_path())).collect();
    check_outputs(&outputs, &[])?;
    say(&format!(
        "cylaov bench: {} family, {}x{}, seed {}, accel {:?}, min of {} runs, {} threads; times in ms (parse: the scene JSON; prep: kernel forms; build: tiles or BVH), err = relative distance error vs stable-f64",
        opts.families
            .iter()
            .map(|f| f.name())
            .collect::<Vec<_>>()
            .join(" and "),
        opts.width,
        opts.height,
        opts.seed,
        opts.accel,
        opts.repeats,
        rayon::current_num_threads()
    ))?;
    say(&bench::header())?;
    // A row that cannot be printed (a full disk behind stdout) stops nothing mid-row: the
    // first such error is returned once the table is done.
    let mut print_err: Option<std::io::Error> = None;
    let mut row_out = |line: &str| {
        if print_err.is_none() {
            print_err = say(line).err();
        }
    };
    let rows = bench::run(opts, |r| row_out(&bench::format_row(r)))?;
    say(
        "\nThe kernel alone, one thread, 1000-cylinder scene (rays across each cylinder, no set-up or shading):",
    )?;
    say(&format!(
        "{:<14} {:<7} {:>12}",
        "kernel", "form", "Mtests/s"
    ))?;
    let kernel_rows = bench::kernel_rows(opts);
    for k in &kernel_rows {
        say(&format!(
            "{:<14} {:<7} {:>12.1}",
            k.kernel, k.form, k.mtests_per_s
        ))?;
    }
    // The load table: with the processes timed, and the dense 1 000 and 100 000 in the run.
    if let Some(exe) = &opts.exe
        && opts.families.contains(&bench::Family::Dense)
        && [1000, 100_000].iter().all(|n| opts.counts.contains(n))
    {
        say(
            "\nLoading at scale: whole `cylaov render` processes, dense family, depth+normal; ratio = time / 1 000 cylinders at 1920x1080:",
        )?;
        say(&format!("{:<28} {:>10} {:>6}", "case", "process", "ratio"))?;
        let scratch = tempfile::Builder::new().prefix("cylaov-load-").tempdir()?;
        for r in bench::load::run(exe, opts.seed, opts.repeats, scratch.path())? {
            say(&format!(
                "{:<28} {:>10.1} {:>6.2}",
                r.case, r.process_ms, r.ratio
            ))?;
        }
    }
    let mut mi_rows = Vec::new();
    if let Some(a) = &anchors {
        say(
            "\nMitsuba 3 and Open3D (Embree, 16-segment meshes) on the same scenes; ratios = their time / cylaov stable-f64 depth+normal time",
        )?;
        mi_rows = bench::run_anchors(opts, a, &rows, |line| row_out(line))?;
    }
    if let Some(e) = print_err {
        return Err(e.into());
    }
    if let Some(path) = csv {
        atomic_write_bytes(&path, &csv_bytes(&rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
        say(&format!("wrote {}", path.display()))?;
        let kpath = path.with_extension("kernel.csv");
        atomic_write_bytes(&kpath, &csv_bytes(&kernel_rows)?)
            .with_context(|| format!("writing {}", kpath.display()))?;
        say(&format!("wrote {}", kpath.display()))?;
        if !mi_rows.is_empty() {
            let mpath = path.with_extension("anchors.csv");
            atomic_write_bytes(&mpath, &csv_bytes(&mi_rows)?)
                .with_context(|| format!("writing {}", mpath.display()))?;
            say(&format!("wrote {}", mpath.display()))?;
        }
    }
    if let Some(path) = plot {
        let img = plot::plot(&rows, &mi_rows, &opts.kernels);
        crate::output::pipeline::files::write_png(&img, &path)?;
        say(&format!("wrote {}", path.display()))?;
    }
    Ok(rows)
}

/// `scripts/bench_python.py`, compiled in so the binary runs it from anywhere.
pub const PYTHON_SCRIPT: &str = include_str!("../../scripts/bench_python.py");

/// `cylaov bench --python`: the Python package's `Dataset[i]` against reading the same
/// views' EXRs with OpenEXR, and `render`'s call overhead on a 16×16 view, measured by
/// `python` (a venv with the package installed, `pip install .`, and OpenEXR); views of
/// scenes rendered by `exe`. With `csv`, the script also writes its measures there
/// (`measure,value,unit`). Returns the script's report.
pub fn python(python: &Path, exe: &Path, csv: Option<&Path>) -> Result<String> {
    let csv = match csv {
        Some(p) => {
            check_parent(p, "--csv")?;
            check_outputs(&[("--csv", p)], &[])?;
            Some(std::path::absolute(p).with_context(|| format!("--csv {}", p.display()))?)
        }
        None => None,
    };
    let dir = tempfile::tempdir().context("making a folder for the Python bench")?;
    let script = dir.path().join("bench_python.py");
    std::fs::write(&script, PYTHON_SCRIPT).context("writing the Python bench script")?;
    let mut cmd = std::process::Command::new(python);
    cmd.arg(&script).arg("--cli").arg(exe);
    if let Some(p) = &csv {
        cmd.arg("--csv").arg(p);
    }
    let out = cmd
        .output()
        .with_context(|| format!("running {}", python.display()))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        bail!(
            "--python: {} {} failed ({}; is the package installed there? pip install .): {}",
            python.display(),
            script.display(),
            out.status,
            err.trim().lines().last().unwrap_or("")
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim_end().to_string())
}

/// `views` scenes of `cylinders` cylinders at `width`×`height` from `seed`, generated by
/// `generate`'s own code into a fresh temp folder (kept while the first value lives) and
/// synced to disk, so the timed runs read them as a user's batch would: the input of the
/// dataset benches.
fn generated(
    views: u64,
    seed: u64,
    cylinders: u64,
    width: u32,
    height: u32,
) -> Result<(tempfile::TempDir, PathBuf)> {
    use crate::dataset::generate::{ConfigFile, Range};
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-bench-data-")
        .tempdir()
        .context("making a temp folder")?;
    let data = tmp.path().join("data");
    crate::commands::generate::run(&crate::commands::generate::GenerateArgs {
        out: data.clone(),
        config: None,
        flags: ConfigFile {
            count: Some(views),
            seed: Some(seed),
            cylinders: Some(Range::parse(&cylinders.to_string()).map_err(anyhow::Error::msg)?),
            width: Some(width),
            height: Some(height),
            ..ConfigFile::default()
        },
        force: false,
    })?;
    bench::batch_formats::sync_tree(&data)?;
    Ok((tmp, data))
}

/// `cylaov bench --batch-formats`: the dataset formats side by side on `views` generated
/// views (320×240, depth+normal, 100 cylinders a scene), each the fastest of `passes`, and
/// the two ceilings on the tar shards, printed as a table; with `csv`, the same rows
/// written there.
pub fn batch_formats(views: u64, passes: usize, csv: Option<&Path>) -> Result<()> {
    if let Some(p) = csv {
        check_parent(p, "--csv")?;
        check_outputs(&[("--csv", p)], &[])?;
    }
    say(&format!(
        "cylaov bench --batch-formats: {views} views, 320x240, depth+normal, 100 cylinders a scene, {} threads, fastest of {} passes",
        rayon::current_num_threads(),
        passes.max(1)
    ))?;
    let (_tmp, data) = generated(views, 1, 100, 320, 240)?;
    let rows = bench::batch_formats::run(&data, passes)?;
    say(&format!(
        "{:<22} {:>7} {:>9} {:>10} {:>10}",
        "format", "views", "seconds", "views/s", "MiB"
    ))?;
    for r in &rows {
        say(&format!(
            "{:<22} {:>7} {:>9.3} {:>10.1} {:>10.1}",
            r.format,
            r.views,
            r.seconds,
            r.views_per_s,
            r.bytes as f64 / (1u64 << 20) as f64
        ))?;
    }
    if let Some(path) = csv {
        atomic_write_bytes(path, &csv_bytes(&rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
        say(&format!("wrote {}", path.display()))?;
    }
    Ok(())
}

/// `cylaov bench --scaling`: each way of making views at 1, 2, 4, … threads up to `cores`,
/// printed as a table (see [`bench::scaling`]); with `csv`, the rows written there. The
/// `DataLoader` rows run in the reference venv's Python when it has the package and torch;
/// otherwise the first line says why they are left out.
pub fn scaling(views: u64, cores: usize, csv: Option<&Path>) -> Result<()> {
    if let Some(p) = csv {
        check_parent(p, "--csv")?;
        check_outputs(&[("--csv", p)], &[])?;
    }
    let python = match crate::verify::reference::Mitsuba::find() {
        Ok(m) => {
            let probe = std::process::Command::new(&m.python)
                .args(["-c", "import cylaov, torch"])
                .output();
            match probe {
                Ok(o) if o.status.success() => Ok(m.python),
                Ok(o) => Err(format!(
                    "{} cannot import cylaov and torch ({}; pip install . there)",
                    m.python.display(),
                    String::from_utf8_lossy(&o.stderr)
                        .trim()
                        .lines()
                        .last()
                        .unwrap_or("")
                )),
                Err(e) => Err(format!("running {}: {e}", m.python.display())),
            }
        }
        Err(why) => Err(why),
    };
    let threads = bench::scaling::thread_counts(cores);
    say(&format!(
        "cylaov bench --scaling: {views} views, {}x{}, depth+normal, {} cylinders a scene, threads {threads:?}",
        bench::scaling::WIDTH,
        bench::scaling::HEIGHT,
        bench::scaling::CYLINDERS,
    ))?;
    if let Err(why) = &python {
        say(&format!("DataLoader rows left out: {why}"))?;
    }
    let (_tmp, data) = generated(
        views,
        bench::scaling::SEED,
        bench::scaling::CYLINDERS,
        bench::scaling::WIDTH,
        bench::scaling::HEIGHT,
    )?;
    let rows = bench::scaling::run(&data, views, &threads, python.as_deref().ok(), |r| {
        say(&format!(
            "  {} threads, {}: {:.1} views/s (efficiency {:.2})",
            r.threads, r.workload, r.views_per_s, r.efficiency
        ))
        .map_err(anyhow::Error::from)
    })?;
    say(&bench::scaling::table(&rows))?;
    if let Some(path) = csv {
        atomic_write_bytes(path, &csv_bytes(&rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
        say(&format!("wrote {}", path.display()))?;
    }
    Ok(())
}
