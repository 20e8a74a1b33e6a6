//! `cylaov generate`: procedural scene files and their manifest.
//!
//! Layout: `OUT/scenes/NNNNNN.json` (complete scene files), `OUT/manifest.jsonl`
//! (`{"name": ..., "scene": "scenes/NNNNNN.json"}` per line) and `OUT/generate.json` (the
//! resolved options, itself a valid `--config`). Every file is written atomically; the
//! manifest last, so a manifest on disk always names scene files that exist.

use crate::dataset::generate::{ConfigFile, GenerateOptions, to_json, view_name};
use crate::output::io::{NewDirs, atomic_write_bytes, check_output_dir};
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
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let de = &mut serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let field = e.path().to_string();
        anyhow::anyhow!("{}: {field}: {}", path.display(), e.into_inner())
    })
}

/// Resolve defaults < config file < flags.
pub fn resolve(args: &GenerateArgs) -> Result<(u64, u64, GenerateOptions)> {
    let config = match &args.config {
        Some(p) => load_config(p)?,
        None => ConfigFile::default(),
    };
    let mut o = GenerateOptions::default();
    o.apply(&config);
    o.apply(&args.flags);
    let count = args
        .flags
        .count
        .or(config.count)
        .context("--count: required (or \"count\" in --config)")?;
    if count == 0 || count > MAX_COUNT {
        bail!("--count: must be in 1..={MAX_COUNT}, got {count}");
    }
    let seed = args.flags.seed.or(config.seed).unwrap_or(0);
    o.validate().map_err(anyhow::Error::msg)?;
    Ok((count, seed, o))
}

/// Generate the dataset's scene files; returns the one-line summary.
pub fn run(args: &GenerateArgs) -> Result<String> {
    let (count, seed, options) = resolve(args)?;
    let scenes_dir = args.out.join("scenes");
    check_output_dir("--out", &args.out)?;
    // A failed run into a new folder removes what it wrote, then the folders it made.
    let mut dirs = NewDirs::default();
    dirs.create(&scenes_dir)
        .with_context(|| format!("creating {}", scenes_dir.display()))?;
    let new_folder = dirs.made_any();
    let written = write_files(args, count, seed, &options, &scenes_dir);
    if written.is_err() && new_folder {
        for i in 0..count {
            let _ = std::fs::remove_file(scenes_dir.join(format!("{}.json", view_name(i))));
        }
        for name in ["generate.json", "manifest.jsonl"] {
            let _ = std::fs::remove_file(args.out.join(name));
        }
    }
    let manifest_path = written?;
    dirs.keep();
    let views = match options.views_per_scene {
        1 => String::new(),
        v => format!(" x {v} cameras"),
    };
    Ok(format!(
        "{count} scenes{views} (seed {seed}, {} cylinders, {}x{}) in {}; manifest {}",
        options.cylinders,
        options.width,
        options.height,
        scenes_dir.display(),
        manifest_path.display()
    ))
}

/// Write the scene files, `generate.json` and the manifest (last); returns the manifest's
/// path.
fn write_files(
    args: &GenerateArgs,
    count: u64,
    seed: u64,
    options: &GenerateOptions,
    scenes_dir: &Path,
) -> Result<PathBuf> {
    (0..count).into_par_iter().try_for_each(|i| -> Result<()> {
        let file = options.scene(seed, i).map_err(anyhow::Error::msg)?;
        let text = to_json(&file)?;
        let path = scenes_dir.join(format!("{}.json", view_name(i)));
        atomic_write_bytes(&path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))
    })?;
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
    let resolved = to_json(&Resolved {
        count,
        seed,
        options,
    })?;
    let config_path = args.out.join("generate.json");
    atomic_write_bytes(&config_path, resolved.as_bytes())
        .with_context(|| format!("writing {}", config_path.display()))?;
    let manifest_path = args.out.join("manifest.jsonl");
    atomic_write_bytes(&manifest_path, manifest.as_bytes())
        .with_context(|| format!("writing {}", manifest_path.display()))?;
    Ok(manifest_path)
}
