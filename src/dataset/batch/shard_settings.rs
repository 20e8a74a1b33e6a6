//! One dataset per tar-shard folder: `OUT/shards.settings.json` records the settings every
//! tar, sidecar and `shards.json` in the folder is written with (shard size, tar and view
//! counts, the inputs' keys, AOVs, members, kernel). A run with the same settings resumes
//! the folder; a run with others is refused before anything renders, naming each
//! difference, unless it is told to replace the dataset (`force`), which removes this
//! format's own files first. The record is read and written under the folder's settings
//! lock, so two runs with different settings never interleave their tars, and tars left by
//! a run with another shard size cannot sit beside an index that does not list them.

use super::lock::lock_named;
use crate::output::store::atomic::atomic_write_bytes;
use crate::output::store::files::read_regular;
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The record's file name in the output folder.
pub const FILE: &str = "shards.settings.json";

/// What a tar-shard dataset is written with: two runs agree on every field or write two
/// different datasets.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Settings {
    /// Views per tar.
    pub shard_size: usize,
    /// Tars in the dataset.
    pub tars: usize,
    /// Views in the dataset.
    pub views: usize,
    /// sha256 of the view keys in order: another input list (other scenes, another order)
    /// differs here.
    pub inputs: String,
    /// The arrays of every view.
    pub aovs: Vec<String>,
    /// The optional members of every view.
    pub members: Vec<String>,
    /// Kernel precision.
    pub precision: String,
    /// Kernel formulation.
    pub formula: String,
}

impl Settings {
    /// The fields where `self` (this run) and `there` (the folder) differ, as
    /// `field: VALUE now, VALUE in the folder`.
    fn differences(&self, there: &Settings) -> Vec<String> {
        let field = |name: &str, now: String, was: String| {
            (now != was).then(|| format!("{name}: {now} now, {was} in the folder"))
        };
        let inputs = (self.views == there.views && self.inputs != there.inputs)
            .then(|| "inputs: other scenes or another order than in the folder".to_string());
        [
            field(
                "shard size",
                self.shard_size.to_string(),
                there.shard_size.to_string(),
            ),
            field("tars", self.tars.to_string(), there.tars.to_string()),
            field("views", self.views.to_string(), there.views.to_string()),
            inputs,
            field("aovs", self.aovs.join(","), there.aovs.join(",")),
            field(
                "members",
                list_or_none(&self.members),
                list_or_none(&there.members),
            ),
            field("precision", self.precision.clone(), there.precision.clone()),
            field("formula", self.formula.clone(), there.formula.clone()),
        ]
        .into_iter()
        .flatten()
        .collect()
    }
}

fn list_or_none(v: &[String]) -> String {
    if v.is_empty() {
        "none".into()
    } else {
        v.join(",")
    }
}

/// Whether `name` is one of the files a tar-shard run writes in its output folder.
fn is_shard_file(name: &str) -> bool {
    let numbered = |rest: &str, ext: &str| {
        rest.strip_suffix(ext)
            .is_some_and(|n| n.len() == 6 && n.bytes().all(|b| b.is_ascii_digit()))
    };
    match name.strip_prefix("shard-") {
        Some(rest) => numbered(rest, ".tar") || numbered(rest, ".json"),
        None => {
            name == "shards.json"
                || name == FILE
                || (name.starts_with("failures.") && name.ends_with(".jsonl"))
        }
    }
}

/// The tar-shard files in `out`, sorted.
fn shard_files(out: &Path) -> Result<Vec<String>> {
    let mut names = Vec::new();
    let entries = match std::fs::read_dir(out) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(names),
        Err(e) => return Err(e).with_context(|| format!("reading {}", out.display())),
    };
    for e in entries {
        let e = e.with_context(|| format!("reading {}", out.display()))?;
        let name = e.file_name().to_string_lossy().into_owned();
        if is_shard_file(&name) {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

/// Hold `out` to one dataset (see the module docs): `settings` is recorded when the folder
/// holds none, accepted when it equals the record, and otherwise refused, unless `force`:
/// then every tar-shard file in `out` is removed and `settings` recorded. `root` is the
/// folder's `.partial`, where the settings lock lives.
pub fn hold(out: &Path, root: &Path, settings: &Settings, force: bool) -> Result<()> {
    let _lock = lock_named(out, root, "settings")?;
    let path = out.join(FILE);
    let recorded: Option<std::result::Result<Settings, String>> = match read_regular(&path) {
        Ok(bytes) => Some(serde_json::from_slice(&bytes).map_err(|e| e.to_string())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => Some(Err(e.to_string())),
    };
    let replace = "give the same options (and inputs) to resume it, force to replace it \
                   (its tars, sidecars, shards.json and failures files go first), or another \
                   output folder";
    match recorded {
        Some(Ok(there)) if there == *settings => return Ok(()),
        _ if force => {
            for name in shard_files(out)? {
                let p = out.join(&name);
                std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
            }
        }
        Some(Ok(there)) => bail!(
            "{} holds a tar-shard dataset written with other settings ({}); {replace}",
            out.display(),
            settings.differences(&there).join("; ")
        ),
        Some(Err(why)) => bail!(
            "{}: not a settings record cylaov can read ({why}); {replace}",
            path.display()
        ),
        None => {
            let found = shard_files(out)?;
            if !found.is_empty() {
                bail!(
                    "{} holds tar-shard files without a settings record ({}{}), so whether \
                     they belong to this dataset cannot be told; {replace}",
                    out.display(),
                    found.iter().take(3).cloned().collect::<Vec<_>>().join(", "),
                    if found.len() > 3 { ", ..." } else { "" }
                );
            }
        }
    }
    let mut text = serde_json::to_string_pretty(settings)?;
    text.push('\n');
    atomic_write_bytes(&path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> Settings {
        Settings {
            shard_size: 4,
            tars: 3,
            views: 10,
            inputs: "ab".into(),
            aovs: vec!["depth".into(), "normal".into()],
            members: Vec::new(),
            precision: "f64".into(),
            formula: "stable".into(),
        }
    }

    #[test]
    fn the_files_of_the_format_and_nothing_else() {
        for ok in [
            "shard-000000.tar",
            "shard-123456.json",
            "shards.json",
            FILE,
            "failures.0-of-1.jsonl",
            "failures.tar-000003.jsonl",
        ] {
            assert!(is_shard_file(ok), "{ok}");
        }
        for other in [
            "shard-1.tar",
            "shard-000000.tar.tmp",
            "scene.json",
            "index.json",
            "shard-00000a.json",
            "failures.txt",
        ] {
            assert!(!is_shard_file(other), "{other}");
        }
    }

    #[test]
    fn differences_name_each_field() {
        let now = Settings {
            shard_size: 10,
            tars: 1,
            members: vec!["exr".into()],
            ..settings()
        };
        assert_eq!(
            now.differences(&settings()),
            [
                "shard size: 10 now, 4 in the folder",
                "tars: 1 now, 3 in the folder",
                "members: exr now, none in the folder"
            ]
        );
        let other_inputs = Settings {
            inputs: "cd".into(),
            ..settings()
        };
        assert_eq!(
            other_inputs.differences(&settings()),
            ["inputs: other scenes or another order than in the folder"]
        );
    }

    #[test]
    fn a_folder_holds_one_dataset_unless_replaced() {
        let d = tempfile::tempdir().unwrap();
        let (out, root) = (d.path().join("out"), d.path().join("out/.partial"));
        std::fs::create_dir_all(&root).unwrap();
        hold(&out, &root, &settings(), false).unwrap();
        hold(&out, &root, &settings(), false).unwrap();
        std::fs::write(out.join("shard-000002.tar"), b"x").unwrap();
        std::fs::write(out.join("keep.txt"), b"mine").unwrap();
        let bigger = Settings {
            shard_size: 10,
            tars: 1,
            ..settings()
        };
        let e = hold(&out, &root, &bigger, false).unwrap_err().to_string();
        assert!(e.contains("shard size: 10 now, 4 in the folder"), "{e}");
        assert!(out.join("shard-000002.tar").exists());
        hold(&out, &root, &bigger, true).unwrap();
        assert!(!out.join("shard-000002.tar").exists());
        assert_eq!(std::fs::read(out.join("keep.txt")).unwrap(), b"mine");
        let record: Settings =
            serde_json::from_slice(&std::fs::read(out.join(FILE)).unwrap()).unwrap();
        assert_eq!(record, bigger);
        // Tar files without a record (an older run) are not silently adopted.
        std::fs::remove_file(out.join(FILE)).unwrap();
        std::fs::write(out.join("shard-000000.json"), b"{}").unwrap();
        let e = hold(&out, &root, &bigger, false).unwrap_err().to_string();
        assert!(
            e.contains("without a settings record (shard-000000.json)"),
            "{e}"
        );
    }
}
