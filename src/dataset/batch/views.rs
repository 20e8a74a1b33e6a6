//! The view list: a `.jsonl` manifest or a folder scanned for scene files, each scene named
//! by its scene file's stem (or the manifest's `name`), names checked to be usable stems.
//!
//! A view is one (scene, camera) pair. [`list_views`] lists scenes (each as its camera 0);
//! [`ViewSource::cameras`] expands a scene with several cameras, once it is read, into one
//! view per camera in the sub folder `OUT/<scene>/`, named `00`, `01`, … A one-camera scene
//! stays one view, `OUT/<scene>.*`.

use anyhow::{Context, Result, bail};
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// One view of the input: which scene file and camera, and where its outputs go.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ViewSource {
    /// Output file stem: the scene's name for a one-camera scene, else the camera number
    /// (`00`, `01`, …) inside the scene's folder.
    pub name: String,
    /// The scene file to read.
    pub path: PathBuf,
    /// The scene's name: its file's stem, or the manifest's `name`.
    pub scene: String,
    /// Which camera of the scene (0-based, file order).
    pub camera: usize,
    /// The output sub folder (the scene's name) of a several-camera scene; `None`: `OUT`.
    pub folder: Option<String>,
}

impl ViewSource {
    /// Camera 0 of scene `name`, flat in `OUT`: what a listed scene is before it is read.
    pub fn scene(name: String, path: PathBuf) -> ViewSource {
        ViewSource {
            name: name.clone(),
            path,
            scene: name,
            camera: 0,
            folder: None,
        }
    }

    /// The views of this scene once it is known to have `count` cameras: itself for one
    /// camera, else one view per camera in the folder `<scene>/`, named by the camera
    /// number, zero-padded to at least two digits (all of one width).
    pub fn cameras(&self, count: usize) -> Vec<ViewSource> {
        if count <= 1 {
            return vec![self.clone()];
        }
        let width = (count - 1).to_string().len().max(2);
        (0..count)
            .map(|k| ViewSource {
                name: format!("{k:0width$}"),
                path: self.path.clone(),
                scene: self.scene.clone(),
                camera: k,
                folder: Some(self.scene.clone()),
            })
            .collect()
    }

    /// The view's name relative to `OUT`: `scene` or `scene/00`. Unique in a batch; used in
    /// messages, the failures file and the verify choice.
    pub fn id(&self) -> String {
        match &self.folder {
            Some(f) => format!("{f}/{}", self.name),
            None => self.name.clone(),
        }
    }

    /// The folder the view's files go in.
    pub fn dir(&self, out: &Path) -> PathBuf {
        match &self.folder {
            Some(f) => out.join(f),
            None => out.to_path_buf(),
        }
    }
}

/// A manifest line: `{"name": ..., "scene": ...}`; the scene path is relative to the
/// manifest's folder; `name` defaults to the scene file's stem. Other keys are ignored.
#[derive(Deserialize)]
struct ManifestLine {
    name: Option<String>,
    scene: String,
}

/// Why a view name cannot be an output file stem, if it cannot.
fn check_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.starts_with('.') {
        return Err(format!(
            "view name must be non-empty and not start with '.', got {name:?}"
        ));
    }
    if name
        .chars()
        .any(|c| c == '/' || c == '\\' || c.is_control())
    {
        return Err(format!(
            "view name must not contain '/', '\\' or control characters, got {name:?}"
        ));
    }
    Ok(())
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The views of INPUT: a `.jsonl` manifest, a folder holding `manifest.jsonl` (read through
/// it), or a folder whose `*.json` files are taken recursively in sorted relative-path order
/// (hidden entries and anything under `exclude`, the output folder, skipped; so are
/// cylaov's own outputs by name, dangling links, links to folders and special files, and
/// [`Skipped`] says which).
/// Errors here concern the input as a whole: no view is rendered. An input without views
/// is one (a wrong path or an `--out` that holds the input must not pass as "0 views").
pub fn list_views(input: &Path, exclude: Option<&Path>) -> Result<(Vec<ViewSource>, Skipped)> {
    // Entries skipped because they lie under `exclude`: `*.json` files and folders.
    let mut excluded = Excluded::default();
    let mut skipped = Skipped::default();
    let views = if input.is_dir() {
        let manifest = input.join("manifest.jsonl");
        if manifest.is_file() {
            read_manifest(&manifest)?
        } else {
            let exclude = exclude.and_then(|p| p.canonicalize().ok());
            let mut files = Vec::new();
            scan(
                input,
                exclude.as_deref(),
                &mut files,
                &mut excluded,
                &mut skipped,
            )
            .with_context(|| format!("listing {}", input.display()))?;
            files.sort_by(|a, b| a.strip_prefix(input).ok().cmp(&b.strip_prefix(input).ok()));
            files
                .into_iter()
                .map(|path| ViewSource::scene(stem(&path), path))
                .collect()
        }
    } else if input.extension().is_some_and(|e| e == "jsonl") {
        read_manifest(input)?
    } else if !input.exists() {
        bail!("INPUT {}: no such file or folder", input.display());
    } else {
        bail!(
            "INPUT {}: expected a folder of scene files or a .jsonl manifest",
            input.display()
        );
    };
    if views.is_empty() {
        if excluded.files + excluded.folders > 0 {
            let count = |n: usize, what: &str| match n {
                0 => None,
                1 => Some(format!("1 {what}")),
                n => Some(format!("{n} {what}s")),
            };
            let what: Vec<String> = [
                count(excluded.files, "*.json file"),
                count(excluded.folders, "folder"),
            ]
            .into_iter()
            .flatten()
            .collect();
            bail!(
                "INPUT {}: no scene files outside {} {}: skipped {} under it (outputs \
                 are not read as input; give an output folder outside the input)",
                input.display(),
                crate::spelling::opt("out"),
                exclude.map_or(String::new(), |p| p.display().to_string()),
                what.join(" and ")
            );
        }
        if input.is_dir() {
            let also = if skipped.is_empty() {
                String::new()
            } else {
                format!("; skipped {skipped}")
            };
            bail!(
                "INPUT {}: no scene files (*.json, hidden entries skipped) and no \
                 manifest.jsonl{also}",
                input.display()
            );
        }
        bail!("INPUT {}: the manifest lists no views", input.display());
    }
    let mut seen: HashMap<&str, &Path> = HashMap::new();
    for v in &views {
        check_name(&v.name).map_err(|e| anyhow::anyhow!("{}: {e}", v.path.display()))?;
        if let Some(first) = seen.insert(&v.name, &v.path) {
            bail!(
                "view name {:?} is used twice ({} and {}): outputs would collide; rename one \
                 or use a manifest with distinct names",
                v.name,
                first.display(),
                v.path.display()
            );
        }
    }
    skipped.under_out = excluded.files + excluded.folders;
    Ok((views, skipped))
}

/// What [`scan`] left out because it lies under the output folder (not walked into).
#[derive(Default)]
struct Excluded {
    files: usize,
    folders: usize,
}

/// What a folder scan left out, besides hidden entries and the output folder: reported
/// (on stderr, by `run`) so nothing is dropped without a word.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Skipped {
    /// `*.json` files cylaov writes beside its data (`NAME.camera.json`, `index.json`, …:
    /// the names of `crate::dataset::names`), e.g. an earlier batch's outputs.
    pub outputs: Vec<PathBuf>,
    /// Entries under the `--out` folder (files and folders).
    pub under_out: usize,
    /// Symbolic links to nothing.
    pub dangling: Vec<PathBuf>,
    /// Symbolic links to folders: not followed (they can loop, or lead out of the input).
    pub linked_folders: Vec<PathBuf>,
    /// `*.json` entries that are neither files nor folders (FIFOs, sockets, devices).
    pub special: Vec<PathBuf>,
}

impl Skipped {
    /// Whether nothing was skipped.
    pub fn is_empty(&self) -> bool {
        *self == Skipped::default()
    }
}

impl std::fmt::Display for Skipped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        let mut list = |paths: &[PathBuf], what: &str| {
            if let Some(first) = paths.first() {
                let more = match paths.len() {
                    1 => String::new(),
                    n => format!(" and {} more", n - 1),
                };
                parts.push(format!(
                    "{} {what} ({}{more})",
                    paths.len(),
                    first.display()
                ));
            }
        };
        list(&self.outputs, "of cylaov's own output files");
        list(&self.dangling, "dangling symbolic links");
        list(
            &self.linked_folders,
            "symbolic links to folders, not followed",
        );
        list(&self.special, "special files (not regular files)");
        if self.under_out > 0 {
            parts.push(format!(
                "{} entries under {}",
                self.under_out,
                crate::spelling::opt("out")
            ));
        }
        write!(f, "{}", parts.join("; "))
    }
}

/// Collect the scene files (`*.json`) under `dir` into `out`; entries under `exclude` are
/// counted in `excluded`, everything else left out in `skipped`.
fn scan(
    dir: &Path,
    exclude: Option<&Path>,
    out: &mut Vec<PathBuf>,
    excluded: &mut Excluded,
    skipped: &mut Skipped,
) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') {
            continue;
        }
        let skip = matches!(
            (exclude, path.canonicalize()),
            (Some(ex), Ok(canon)) if canon.starts_with(ex)
        );
        let json = path.extension().is_some_and(|e| e == "json");
        let own = entry.file_type()?;
        // What a link points to; an entry that is not a link is itself.
        let target = if own.is_symlink() {
            match std::fs::metadata(&path) {
                Ok(m) => m.file_type(),
                Err(_) => {
                    skipped.dangling.push(path);
                    continue;
                }
            }
        } else {
            own
        };
        if target.is_dir() {
            if skip {
                excluded.folders += 1;
            } else if own.is_symlink() {
                skipped.linked_folders.push(path);
            } else {
                scan(&path, exclude, out, excluded, skipped)?;
            }
        } else if !json {
            continue;
        } else if skip {
            excluded.files += 1;
        } else if !target.is_file() {
            skipped.special.push(path);
        } else if crate::dataset::names::is_cylaov_output(&name) {
            skipped.outputs.push(path);
        } else {
            out.push(path);
        }
    }
    Ok(())
}

fn read_manifest(path: &Path) -> Result<Vec<ViewSource>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let base = path.parent().unwrap_or(Path::new(""));
    let mut views = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let m: ManifestLine = serde_json::from_str(line).map_err(|e| {
            anyhow::anyhow!(
                "{}:{}: expected {{\"name\": ..., \"scene\": ...}}: {e}",
                path.display(),
                k + 1
            )
        })?;
        let scene = base.join(&m.scene);
        let name = m.name.unwrap_or_else(|| stem(&scene));
        check_name(&name).map_err(|e| anyhow::anyhow!("{}:{}: {e}", path.display(), k + 1))?;
        views.push(ViewSource::scene(name, scene));
    }
    Ok(views)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_checked() {
        assert!(check_name("000001").is_ok());
        assert!(check_name("a/b").is_err());
        assert!(check_name(".hidden").is_err());
        assert!(check_name("").is_err());
    }
}
