//! `cylaov generate`: procedural scene files and their manifest.
//!
//! Layout: `OUT/scenes/NNNNNN.json` (complete scene files), `OUT/manifest.jsonl`
//! (`{"name": ..., "scene": "scenes/NNNNNN.json"}` per line) and `OUT/generate.json` (the
//! resolved options, itself a valid `--config`). Every file is written atomically; the
//! manifest last, so a manifest on disk always names scene files that exist, and
//! `generate.json` first (except under `--force`), so a run cut short is completed by the
//! same command.
//!
//! **An `--out` that holds a dataset** (a `generate.json`) is kept, extended or refused,
//! never silently rewritten: with the same seed and options and the same `--count` there is
//! nothing to do; a larger `--count` extends it (the first scenes are not touched, the new
//! ones are the ones a fresh run would write, the manifest grows); other settings or a
//! smaller `--count` are refused, naming what differs. A `manifest.jsonl` or scene files
//! without a `generate.json` are refused too (whose they are cannot be told). `--force`
//! replaces generate's own files (`generate.json`, `manifest.jsonl`, `scenes/NNNNNN.json`)
//! and nothing else in the folder.
//!
//! **Outputs are not inputs**: a run that would overwrite or remove its own `--config` is
//! refused before anything is written.
//!
//! **Files it does not own**: `generate.json`, `manifest.jsonl` and every scene file the
//! run would write must be missing or regular files; a symbolic link (even to a regular
//! file), a FIFO, a device or a folder at one of those names is refused before anything is
//! written, naming the path and what it is. What it reads back from `--out` is opened
//! without following a link or blocking on a FIFO.

use crate::dataset::generate::{ConfigFile, GenerateOptions, to_json, view_name};
use crate::output::store::atomic::{NewDirs, atomic_write_bytes};
use crate::output::store::files::read_regular;
use crate::output::store::targets::{check_output, check_output_dir};
use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Largest `--count`.
pub const MAX_COUNT: u64 = 100_000_000;

/// The command line.
#[derive(Clone, Debug, Default)]
pub struct GenerateArgs {
    /// Output folder (`--out`).
    pub out: PathBuf,
    /// `--config FILE`.
    pub config: Option<PathBuf>,
    /// The other flags: the config file's fields (`--caps-prob` is `caps_prob`); `None`
    /// means "from the config file, else the default".
    pub flags: ConfigFile,
    /// `--force`: replace a dataset already in `--out` (generate's own files only).
    pub force: bool,
}

#[derive(Serialize)]
struct ManifestLine<'a> {
    name: &'a str,
    scene: &'a str,
}

#[derive(Serialize)]
struct Resolved<'a> {
    count: u64,
    seed: u64,
    #[serde(flatten)]
    options: &'a GenerateOptions,
}

/// Read a config file; errors name the file and the field.
pub fn load_config(path: &Path) -> Result<ConfigFile> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    parse_config(path, &bytes)
}

/// The config file `path` holding `bytes`; errors name the file and the field.
fn parse_config(path: &Path, bytes: &[u8]) -> Result<ConfigFile> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let config = serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let field = e.path().to_string();
        anyhow::anyhow!("{}: {field}: {}", path.display(), e.into_inner())
    })?;
    // A second object after the first would otherwise be ignored, settings and all.
    de.end().map_err(|e| {
        anyhow::anyhow!(
            "{}: text after the end of the settings' JSON object at line {} column {}",
            path.display(),
            e.line(),
            e.column()
        )
    })?;
    Ok(config)
}

/// Resolve defaults < config file < flags.
pub fn resolve(args: &GenerateArgs) -> Result<(u64, u64, GenerateOptions)> {
    let config = match &args.config {
        Some(p) => load_config(p)?,
        None => ConfigFile::default(),
    };
    // The flags alone first: a flag's bad value is a usage error. What is wrong after
    // that is the config file's (every option is checked on its own). Without a config
    // file the flags are all there is: every check, options together too.
    let mut flags = GenerateOptions::default();
    flags.apply(&args.flags);
    match &args.config {
        None => flags.validate(),
        Some(_) => flags.validate_each_naming(&crate::spelling::opt),
    }
    .map_err(super::Usage)?;
    let mut o = GenerateOptions::default();
    o.apply(&config);
    o.apply(&args.flags);
    let Some(count) = args.flags.count.or(config.count) else {
        return super::usage("--count: required (or \"count\" in --config)");
    };
    // Each option named where its value came from: the config file's key, else the flag
    // (the flags passed their own checks above, so what fails below is mostly the file's).
    let from_file = |key: &str| !args.flags.sets(key) && config.sets(key);
    let source_key = |key: &str| match &args.config {
        Some(path) if from_file(key) => format!("{}: {key}", path.display()),
        _ => crate::spelling::opt(key),
    };
    if count == 0 || count > MAX_COUNT {
        // The flag is range-checked as it is parsed: this one is the config file's.
        bail!(
            "{}: must be in 1..={MAX_COUNT}, got {count}",
            source_key("count")
        );
    }
    let seed = args.flags.seed.or(config.seed).unwrap_or(0);
    o.validate_each_naming(&source_key)
        .map_err(anyhow::Error::msg)?;
    // Options that only together make invalid scenes: a usage error unless the config file
    // set one of them.
    if let Err(c) = o.validate_together(&source_key) {
        if c.keys.iter().any(|k| from_file(k)) {
            bail!("{}", c.message);
        }
        return super::usage(c.message);
    }
    Ok((count, seed, o))
}

/// What is already in `--out`.
enum Existing {
    /// Nothing of generate's own.
    Nothing,
    /// A dataset: what its `generate.json` says.
    Dataset {
        count: u64,
        seed: u64,
        options: GenerateOptions,
    },
}

/// What this run writes, decided before anything is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Plan {
    /// A new dataset: every file.
    Fresh,
    /// `--force` over an existing dataset: every file, and scene files past `--count` go.
    Replace,
    /// The same settings: scenes from `from` on, any missing before it, `generate.json`
    /// when the count changes and the manifest when its bytes would change.
    Extend {
        /// The existing dataset's count.
        from: u64,
    },
}

/// The file of scene `i` in `scenes_dir`.
fn scene_path(scenes_dir: &Path, i: u64) -> PathBuf {
    scenes_dir.join(format!("{}.json", view_name(i)))
}

/// The index of a scene file name generate writes (`NNNNNN.json`, exactly as
/// [`view_name`] spells it), if it is one.
fn scene_index(file_name: &str) -> Option<u64> {
    let stem = file_name.strip_suffix(".json")?;
    if !stem.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let i: u64 = stem.parse().ok()?;
    (view_name(i) == stem).then_some(i)
}

/// The scene files generate wrote in `scenes_dir` (by name), with their indices.
fn own_scene_files(scenes_dir: &Path) -> Result<Vec<(u64, PathBuf)>> {
    let entries = match std::fs::read_dir(scenes_dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("listing {}", scenes_dir.display())),
    };
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.with_context(|| format!("listing {}", scenes_dir.display()))?;
        let name = entry.file_name();
        let Some(i) = name.to_str().and_then(scene_index) else {
            continue;
        };
        // A folder under a scene's name is not a file generate wrote.
        if entry.file_type().is_ok_and(|t| !t.is_dir()) {
            files.push((i, entry.path()));
        }
    }
    Ok(files)
}

/// Read what `--out` holds: its `generate.json`, or an error when it holds a manifest or
/// scene files without one.
fn existing(out: &Path, scenes_dir: &Path) -> Result<Existing> {
    let config_path = out.join("generate.json");
    let replace = "use another --out, or --force to replace generate's files (generate.json, \
                   manifest.jsonl, scenes/NNNNNN.json)";
    if config_path.symlink_metadata().is_err() {
        let manifest = out.join("manifest.jsonl");
        if manifest.symlink_metadata().is_ok() {
            bail!(
                "--out {}: holds {} but no generate.json: not a dataset generate made, or one \
                 whose writing was cut short; {replace}",
                out.display(),
                manifest.display()
            );
        }
        if let Some((_, first)) = own_scene_files(scenes_dir)?.first() {
            bail!(
                "--out {}: holds scene files ({} ...) but no generate.json: not a dataset \
                 generate made, or one whose writing was cut short; {replace}",
                out.display(),
                first.display()
            );
        }
        return Ok(Existing::Nothing);
    }
    let unreadable = |why: String| {
        anyhow::anyhow!(
            "--out {}: holds a dataset whose generate.json cannot be read ({why}); {replace}",
            out.display()
        )
    };
    let file = read_regular(&config_path)
        .map_err(anyhow::Error::from)
        .and_then(|bytes| parse_config(&config_path, &bytes))
        .map_err(|e| unreadable(format!("{e:#}")))?;
    let (Some(count), Some(seed)) = (file.count, file.seed) else {
        return Err(unreadable(format!(
            "{}: expected \"count\" and \"seed\"",
            config_path.display()
        )));
    };
    let mut options = GenerateOptions::default();
    options.apply(&file);
    Ok(Existing::Dataset {
        count,
        seed,
        options,
    })
}

/// The options as `name -> value`, with the fields `generate.json` leaves out when they
/// have their default.
fn option_fields(o: &GenerateOptions) -> serde_json::Map<String, serde_json::Value> {
    let mut m = match serde_json::to_value(o) {
        Ok(serde_json::Value::Object(m)) => m,
        _ => serde_json::Map::new(),
    };
    m.entry("views_per_scene").or_insert(1.into());
    m.entry("orbit").or_insert(false.into());
    m.entry("camera_model").or_insert("perspective".into());
    m
}

/// A value as a flag takes it: ranges as `A..B`, triples as `X,Y,Z`.
fn flag_value(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::String(s) => s.clone(),
        serde_json::Value::Array(a) => a.iter().map(flag_value).collect::<Vec<_>>().join(","),
        // As a flag is written: `50`, not serde's `50.0`.
        serde_json::Value::Number(n) if n.is_f64() => {
            n.as_f64().map_or(n.to_string(), |x| x.to_string())
        }
        v => v.to_string(),
    }
}

/// Each setting that differs between the dataset in `--out` and this run, as
/// `--flag THERE there, HERE here`.
fn differences(old: (u64, &GenerateOptions), new: (u64, &GenerateOptions)) -> Vec<String> {
    let mut diffs = Vec::new();
    if old.0 != new.0 {
        diffs.push(format!("--seed {} there, {} here", old.0, new.0));
    }
    let (a, b) = (option_fields(old.1), option_fields(new.1));
    for (key, there) in &a {
        let here = b.get(key).unwrap_or(&serde_json::Value::Null);
        if there != here {
            diffs.push(format!(
                "--{} {} there, {} here",
                key.replace('_', "-"),
                flag_value(there),
                flag_value(here)
            ));
        }
    }
    if diffs.is_empty() && old.1 != new.1 {
        diffs.push("the options differ".into());
    }
    diffs
}

/// Decide what to write into `--out` (see the module docs), or refuse.
fn plan(
    args: &GenerateArgs,
    count: u64,
    seed: u64,
    options: &GenerateOptions,
    scenes_dir: &Path,
) -> Result<Plan> {
    if args.force {
        return Ok(
            if args.out.join("generate.json").symlink_metadata().is_ok()
                || args.out.join("manifest.jsonl").symlink_metadata().is_ok()
                || !own_scene_files(scenes_dir)?.is_empty()
            {
                Plan::Replace
            } else {
                Plan::Fresh
            },
        );
    }
    let out = args.out.display();
    match existing(&args.out, scenes_dir)? {
        Existing::Nothing => Ok(Plan::Fresh),
        Existing::Dataset {
            count: had,
            seed: old_seed,
            options: old,
        } => {
            if old_seed != seed || old != *options {
                bail!(
                    "--out {out}: holds a dataset made with other settings ({}/generate.json): \
                     {}; give the same settings to keep or extend it (--config \
                     {out}/generate.json), another --out, or --force to replace generate's \
                     files",
                    out,
                    differences((old_seed, &old), (seed, options)).join("; ")
                );
            }
            if count < had {
                bail!(
                    "--count {count}: --out {out} holds {had} scenes made with these settings; \
                     a smaller count would cut the dataset: give --count {had} (nothing to do) \
                     or more (extends it), another --out, or --force to replace it"
                );
            }
            Ok(Plan::Extend { from: had })
        }
    }
}

/// The manifest of `count` scenes.
fn manifest_text(count: u64) -> Result<String> {
    let mut manifest = String::new();
    for i in 0..count {
        let name = view_name(i);
        let scene = format!("scenes/{name}.json");
        manifest.push_str(&serde_json::to_string(&ManifestLine {
            name: &name,
            scene: &scene,
        })?);
        manifest.push('\n');
    }
    Ok(manifest)
}

/// The identity of an existing file, through links: (device, inode).
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// Everything a run writes or removes, and how to undo it.
struct Work<'a> {
    args: &'a GenerateArgs,
    count: u64,
    seed: u64,
    options: &'a GenerateOptions,
    scenes_dir: PathBuf,
    plan: Plan,
    /// The manifest's new bytes.
    manifest: &'a str,
    /// Whether `generate.json` is written.
    write_config: bool,
    /// Whether the manifest is written.
    write_manifest: bool,
}

impl Work<'_> {
    /// Whether scene `i` is written (scenes of an extended dataset before its old count
    /// are written only when missing).
    fn writes_scene(&self, i: u64) -> bool {
        match self.plan {
            Plan::Fresh | Plan::Replace => i < self.count,
            Plan::Extend { from } => {
                i < self.count
                    && (i >= from || scene_path(&self.scenes_dir, i).symlink_metadata().is_err())
            }
        }
    }

    /// Refuse, before anything is written, a scene file this run would write whose name
    /// holds something other than a regular file (a link, a FIFO, a folder: see
    /// [`check_output`]).
    fn check_scene_targets(&self) -> Result<()> {
        let listing = || format!("listing {}", self.scenes_dir.display());
        let entries = match std::fs::read_dir(&self.scenes_dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
            Err(e) => return Err(e).with_context(listing),
        };
        for entry in entries {
            let entry = entry.with_context(listing)?;
            let Some(i) = entry.file_name().to_str().and_then(scene_index) else {
                continue;
            };
            if !entry.file_type().is_ok_and(|t| t.is_file()) && self.writes_scene(i) {
                check_output("--out", &entry.path(), &[])?;
            }
        }
        Ok(())
    }

    /// Whether the run would write or remove nothing.
    fn is_empty(&self) -> bool {
        !self.write_config && !self.write_manifest && !(0..self.count).any(|i| self.writes_scene(i))
    }

    /// The file among those this run writes or removes that is `--config`, if one is.
    fn overwritten_config(&self) -> Result<Option<PathBuf>> {
        let Some(config) = &self.args.config else {
            return Ok(None);
        };
        let Some(id) = file_id(config) else {
            return Ok(None);
        };
        let out = &self.args.out;
        for (path, written) in [
            (out.join("generate.json"), self.write_config),
            (out.join("manifest.jsonl"), self.write_manifest),
        ] {
            if written && file_id(&path) == Some(id) {
                return Ok(Some(path));
            }
        }
        // Scene files: by name when the config has one name, else every one by identity.
        let Ok(scenes) = self.scenes_dir.canonicalize() else {
            return Ok(None);
        };
        let single_name = {
            use std::os::unix::fs::MetadataExt;
            std::fs::metadata(config).is_ok_and(|m| m.nlink() == 1)
        };
        let touched = |i: u64| self.writes_scene(i) || self.plan == Plan::Replace;
        if single_name {
            let Ok(real) = config.canonicalize() else {
                return Ok(None);
            };
            let index = real
                .file_name()
                .and_then(|n| n.to_str())
                .and_then(scene_index);
            return Ok(match index {
                Some(i) if real.parent() == Some(scenes.as_path()) && touched(i) => {
                    Some(scene_path(&self.scenes_dir, i))
                }
                _ => None,
            });
        }
        Ok(own_scene_files(&self.scenes_dir)?
            .into_iter()
            .find(|(i, p)| touched(*i) && file_id(p) == Some(id))
            .map(|(_, p)| p))
    }

    /// Write `generate.json`, the scene files and the manifest (last). On failure, what
    /// this run added is removed and a rewritten `generate.json` restored.
    fn write(&self) -> Result<()> {
        let config_path = self.args.out.join("generate.json");
        let manifest_path = self.args.out.join("manifest.jsonl");
        let old_config = read_regular(&config_path).ok();
        let written: Vec<u64> = (0..self.count).filter(|&i| self.writes_scene(i)).collect();
        if self.plan == Plan::Replace {
            // No manifest and no generate.json while the scenes change: a run cut short is
            // refused next time, never taken for a dataset.
            for path in [&manifest_path, &config_path] {
                remove_if_there(path)?;
            }
        }
        let write_config = || -> Result<()> {
            let resolved = to_json(&Resolved {
                count: self.count,
                seed: self.seed,
                options: self.options,
            })?;
            atomic_write_bytes(&config_path, resolved.as_bytes())
                .with_context(|| format!("writing {}", config_path.display()))
        };
        // A new or extended dataset records its settings first: a run cut short (killed)
        // is completed by the same command, which writes only the missing scenes. A
        // replaced one records them last: its old scenes must never pass for new ones.
        let config_first = self.write_config && self.plan != Plan::Replace;
        let result = (|| -> Result<()> {
            if config_first {
                write_config()?;
            }
            written.par_iter().try_for_each(|&i| -> Result<()> {
                let file = self
                    .options
                    .scene(self.seed, i)
                    .map_err(anyhow::Error::msg)?;
                let text = to_json(&file)?;
                let path = scene_path(&self.scenes_dir, i);
                atomic_write_bytes(&path, text.as_bytes())
                    .with_context(|| format!("writing {}", path.display()))
            })?;
            if self.write_config && !config_first {
                write_config()?;
            }
            if self.write_manifest {
                atomic_write_bytes(&manifest_path, self.manifest.as_bytes())
                    .with_context(|| format!("writing {}", manifest_path.display()))?;
            }
            Ok(())
        })();
        if result.is_err() {
            // An extended dataset keeps its old manifest: the scenes it lists stay, the
            // new ones go; a new or replaced one loses everything of this run.
            for &i in &written {
                let _ = std::fs::remove_file(scene_path(&self.scenes_dir, i));
            }
            match (self.plan, &old_config) {
                (Plan::Extend { .. }, Some(bytes)) if self.write_config => {
                    let _ = atomic_write_bytes(&config_path, bytes);
                }
                (Plan::Extend { .. }, _) => {}
                _ => {
                    let _ = std::fs::remove_file(&config_path);
                    let _ = std::fs::remove_file(&manifest_path);
                }
            }
            return result;
        }
        if self.plan == Plan::Replace {
            // Scene files of the replaced dataset past the new count.
            for (i, path) in own_scene_files(&self.scenes_dir)? {
                if i >= self.count {
                    remove_if_there(&path)?;
                }
            }
        }
        Ok(())
    }
}

/// Refuse a run whose `work` would overwrite or remove its own `--config`.
fn refuse_own_config(args: &GenerateArgs, work: &Work) -> Result<()> {
    if let (Some(config), Some(target)) = (&args.config, work.overwritten_config()?) {
        bail!(
            "--config {}: this run would overwrite its own input ({}); copy the config \
             outside --out and give that",
            config.display(),
            target.display()
        );
    }
    Ok(())
}

/// Remove a file (or a link itself); a missing one is fine.
fn remove_if_there(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("removing {}", path.display()))
        }
        _ => Ok(()),
    }
}

/// Generate the dataset's scene files; returns the one-line summary.
pub fn run(args: &GenerateArgs) -> Result<String> {
    let (count, seed, options) = resolve(args)?;
    let scenes_dir = args.out.join("scenes");
    check_output_dir("--out", &args.out)?;
    let manifest_path = args.out.join("manifest.jsonl");
    for path in [&args.out.join("generate.json"), &manifest_path] {
        check_output("--out", path, &[])?;
    }
    let manifest = manifest_text(count)?;
    let work = |plan: Plan| {
        let (write_config, write_manifest) = match plan {
            Plan::Fresh | Plan::Replace => (true, true),
            Plan::Extend { from } => (
                count != from,
                read_regular(&manifest_path).map_or(true, |b| b != manifest.as_bytes()),
            ),
        };
        Work {
            args,
            count,
            seed,
            options: &options,
            scenes_dir: scenes_dir.clone(),
            plan,
            manifest: &manifest,
            write_config,
            write_manifest,
        }
    };
    // Without a generate.json in --out a run writes every file (or is refused for what it
    // would overwrite): a --config among them is named first.
    if args.out.join("generate.json").symlink_metadata().is_err() {
        let every = work(if args.force {
            Plan::Replace
        } else {
            Plan::Fresh
        });
        refuse_own_config(args, &every)?;
    }
    let plan = plan(args, count, seed, &options, &scenes_dir)?;
    let work = work(plan);
    work.check_scene_targets()?;
    let views = match options.views_per_scene {
        1 => String::new(),
        v => format!(" x {v} cameras"),
    };
    let what = format!(
        "{}{views} (seed {seed}, {}, {}x{})",
        crate::output::console::count(count, "scene"),
        crate::output::console::count(options.cylinders, "cylinder"),
        options.width,
        options.height
    );
    if work.is_empty() {
        return Ok(format!(
            "nothing to do: {} holds these {what} already; manifest {}",
            scenes_dir.display(),
            manifest_path.display()
        ));
    }
    refuse_own_config(args, &work)?;
    // A failed run into a new folder removes what it wrote, then the folders it made.
    let mut dirs = NewDirs::default();
    dirs.create(&scenes_dir)
        .with_context(|| format!("creating {}", scenes_dir.display()))?;
    work.write()?;
    dirs.keep();
    let verb = match plan {
        Plan::Extend { from } if from < count => format!("extended from {from} to "),
        Plan::Extend { .. } => "completed ".into(),
        Plan::Replace => "replaced the dataset: ".into(),
        Plan::Fresh => String::new(),
    };
    Ok(format!(
        "{verb}{what} in {}; manifest {}",
        scenes_dir.display(),
        manifest_path.display()
    ))
}
