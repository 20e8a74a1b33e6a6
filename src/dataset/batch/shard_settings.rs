//! One dataset per tar-shard folder: `OUT/shards.settings.json` records the settings every
//! tar, sidecar and `shards.json` in the folder is written with (shard size, tar and view
//! counts, the inputs' keys, AOVs, members, kernel). A run with the same settings resumes
//! the folder; a run with others is refused before anything renders, naming each
//! difference, unless it is told to replace the dataset (`force`), which removes the
//! recorded dataset's own files first. The record is read and written under the folder's
//! settings lock, and a run moves each finished tar into place, and merges the index, only
//! under that lock after checking the record is still its own ([`still_held`]): a run whose
//! dataset another replaced meanwhile stops before its next tar lands, so two runs with
//! different settings never interleave their tars or failures files, and the recorded
//! tars of a dataset with another shard size cannot sit beside an index that does not list
//! them.

use super::lock::{ShardLock, lock_named};
use crate::output::store::atomic::atomic_write_bytes;
use crate::output::store::files::read_regular;
use crate::spelling::opt;
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
    /// The AOVs asked for, in their fixed order (the arrays add depth and normal).
    pub aovs: Vec<String>,
    /// The optional members of every view.
    pub members: Vec<String>,
    /// Kernel precision.
    pub precision: String,
    /// Kernel formulation.
    pub formula: String,
    /// EXR compression of the `exr` member; `None` without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compression: Option<String>,
    /// Depth PNG value per world unit of the `depth.png` member; `None` without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_scale: Option<f64>,
    /// What the `depth.png` member does with a hit beyond 16 bits; `None` without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_out_of_range: Option<String>,
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
            field(
                "compression",
                or_none(&self.compression),
                or_none(&there.compression),
            ),
            field(
                "depth scale",
                or_none(&self.depth_scale),
                or_none(&there.depth_scale),
            ),
            field(
                "depth out of range",
                or_none(&self.depth_out_of_range),
                or_none(&there.depth_out_of_range),
            ),
        ]
        .into_iter()
        .flatten()
        .collect()
    }
}

/// A setting that only some datasets have (it goes with a member), or `none`.
fn or_none<T: std::fmt::Display>(v: &Option<T>) -> String {
    v.as_ref().map_or_else(|| "none".into(), |v| v.to_string())
}

fn list_or_none(v: &[String]) -> String {
    if v.is_empty() {
        "none".into()
    } else {
        v.join(",")
    }
}

/// Whether `name` is one of the files a tar-shard run writes in its output folder: a
/// tar or sidecar (`shard-000003.tar`, `.json`), the index, the record, or a failures file
/// by one of the names a run gives it (`failures.0-of-2.jsonl` for `--shard 0/2`,
/// `failures.tar-000003.jsonl`, `failures.tars-000001-000003.jsonl` for a list of tars).
fn is_shard_file(name: &str) -> bool {
    let numbered = |rest: &str, ext: &str| {
        rest.strip_suffix(ext)
            .is_some_and(|n| n.len() == 6 && n.bytes().all(|b| b.is_ascii_digit()))
    };
    match name.strip_prefix("shard-") {
        Some(rest) => numbered(rest, ".tar") || numbered(rest, ".json"),
        None => name == "shards.json" || name == FILE || is_failures_file(name),
    }
}

/// Whether `name` is a failures file as a tar-shard run names it (see [`is_shard_file`]).
fn is_failures_file(name: &str) -> bool {
    let Some(label) = name
        .strip_prefix("failures.")
        .and_then(|n| n.strip_suffix(".jsonl"))
    else {
        return false;
    };
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if let Some((k, n)) = label.split_once("-of-") {
        return digits(k) && digits(n);
    }
    if let Some(j) = label.strip_prefix("tar-") {
        return j.len() == 6 && digits(j);
    }
    label.strip_prefix("tars-").is_some_and(|l| {
        l.starts_with(|c: char| c.is_ascii_digit())
            && l.bytes()
                .all(|b| b.is_ascii_digit() || b.is_ascii_lowercase() || b == b'-')
    })
}

/// The files of the dataset `there` records in `out`: its tars and sidecars, the index,
/// the record and the failures files; not a numbered tar the record does not count.
fn recorded_files(out: &Path, there: &Settings) -> Result<Vec<String>> {
    Ok(shard_files(out)?
        .into_iter()
        .filter(|name| {
            let index = name
                .strip_prefix("shard-")
                .and_then(|r| r.split_once('.'))
                .and_then(|(n, _)| n.parse::<usize>().ok());
            index.is_none_or(|j| j < there.tars)
        })
        .collect())
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
        // A folder at such a name is no file a run wrote: it is never removed.
        let not_a_folder = e.file_type().is_ok_and(|t| !t.is_dir());
        if is_shard_file(&name) && not_a_folder {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

/// What a run whose settings the folder does not hold may do: each way out, in the front
/// end's spelling.
fn ways_out(resumable: bool) -> String {
    let force = format!(
        "{} to replace it (its tars, sidecars, shards.json and failures files go first)",
        opt("force")
    );
    let other = format!("another {}", opt("out"));
    match resumable {
        true => format!("give the same options (and inputs) to resume it, {force}, or {other}"),
        false => format!("{force}, or {other}"),
    }
}

/// The record in `out`: `None` when there is none, `Some(Err(why))` when it cannot be read.
fn read_record(path: &Path) -> Option<std::result::Result<Settings, String>> {
    match read_regular(path) {
        Ok(bytes) => Some(serde_json::from_slice(&bytes).map_err(|e| e.to_string())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => Some(Err(e.to_string())),
    }
}

/// Remove the files `names` from `out`.
fn remove_all(out: &Path, names: &[String]) -> Result<()> {
    for name in names {
        let p = out.join(name);
        match std::fs::remove_file(&p) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("removing {}", p.display()));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Hold `out` to one dataset (see the module docs): `settings` is recorded when the folder
/// holds none, accepted when it equals the record, and otherwise refused, unless `force`:
/// then the recorded dataset's files (every tar-shard file, where the folder has no
/// readable record) are removed and `settings` recorded. `root` is the folder's
/// `.partial`, where the settings lock lives.
pub fn hold(out: &Path, root: &Path, settings: &Settings, force: bool) -> Result<()> {
    let _lock = lock_named(out, root, "settings")?;
    let path = out.join(FILE);
    match read_record(&path) {
        Some(Ok(there)) if there == *settings => return Ok(()),
        Some(Ok(there)) if force => remove_all(out, &recorded_files(out, &there)?)?,
        _ if force => remove_all(out, &shard_files(out)?)?,
        Some(Ok(there)) => bail!(
            "{} holds a tar-shard dataset written with other settings ({}); {}",
            out.display(),
            settings.differences(&there).join("; "),
            ways_out(true)
        ),
        Some(Err(why)) => bail!(
            "{}: not a settings record cylaov can read ({why}), so the dataset in the folder \
             cannot be resumed; {}",
            path.display(),
            ways_out(false)
        ),
        None => {
            let found = shard_files(out)?;
            if !found.is_empty() {
                bail!(
                    "{} holds tar-shard files without a settings record ({}{}), so whether \
                     they belong to this dataset cannot be told; {}",
                    out.display(),
                    found.iter().take(3).cloned().collect::<Vec<_>>().join(", "),
                    if found.len() > 3 { ", ..." } else { "" },
                    ways_out(false)
                );
            }
        }
    }
    let mut text = serde_json::to_string_pretty(settings)?;
    text.push('\n');
    atomic_write_bytes(&path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

/// The settings lock, taken once the record in `out` is checked to be still `settings`:
/// what a run holds while it moves a finished tar into place or merges the index, so a run
/// whose dataset another replaced (`force`) since [`hold`] stops instead of adding its tars
/// to the other dataset. The error names what changed.
pub fn still_held(out: &Path, root: &Path, settings: &Settings) -> Result<ShardLock> {
    let lock = lock_named(out, root, "settings")?;
    let path = out.join(FILE);
    let why = match read_record(&path) {
        Some(Ok(there)) if there == *settings => return Ok(lock),
        Some(Ok(there)) => settings.differences(&there).join("; "),
        Some(Err(why)) => format!("{} cannot be read: {why}", path.display()),
        None => format!("{} is gone", path.display()),
    };
    bail!(
        "another run replaced the dataset in {} while this one was writing it ({why}); this \
         run's unfinished tars are not kept",
        out.display()
    )
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
            compression: None,
            depth_scale: None,
            depth_out_of_range: None,
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
            "failures.tars-000001-000003.jsonl",
            "failures.tars-000000-to-000011-12-9f3a01bc.jsonl",
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
            "failures.mine.jsonl",
            "failures.7-of-.jsonl",
            "failures.tar-12.jsonl",
            "failures.tars-.jsonl",
        ] {
            assert!(!is_shard_file(other), "{other}");
        }
    }

    #[test]
    fn differences_name_each_field() {
        let now = Settings {
            shard_size: 10,
            tars: 1,
            members: vec!["exr".into(), "depth.png".into()],
            compression: Some("zip".into()),
            depth_scale: Some(250.0),
            depth_out_of_range: Some("fail".into()),
            ..settings()
        };
        assert_eq!(
            now.differences(&settings()),
            [
                "shard size: 10 now, 4 in the folder",
                "tars: 1 now, 3 in the folder",
                "members: exr,depth.png now, none in the folder",
                "compression: zip now, none in the folder",
                "depth scale: 250 now, none in the folder",
                "depth out of range: fail now, none in the folder",
            ]
        );
        let scale = Settings {
            depth_scale: Some(1000.0),
            ..now.clone()
        };
        assert_eq!(
            scale.differences(&now),
            ["depth scale: 1000 now, 250 in the folder"]
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
        // Files of the names a run gives, but not of the recorded dataset (3 tars), and a
        // folder at a tar's name, stay.
        std::fs::write(out.join("shard-000099.tar"), b"x").unwrap();
        std::fs::write(out.join("failures.mine.jsonl"), b"x").unwrap();
        std::fs::write(out.join("failures.0-of-2.jsonl"), b"x").unwrap();
        std::fs::create_dir(out.join("shard-000001.tar")).unwrap();
        hold(&out, &root, &bigger, true).unwrap();
        assert!(!out.join("shard-000002.tar").exists());
        assert!(!out.join("failures.0-of-2.jsonl").exists());
        assert!(out.join("shard-000099.tar").exists());
        assert!(out.join("failures.mine.jsonl").exists());
        assert!(out.join("shard-000001.tar").is_dir());
        assert_eq!(std::fs::read(out.join("keep.txt")).unwrap(), b"mine");
        std::fs::remove_file(out.join("shard-000099.tar")).unwrap();
        std::fs::remove_dir(out.join("shard-000001.tar")).unwrap();
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
        assert!(!e.contains("same options"), "{e}");
    }

    /// A run checks, before each tar lands, that the folder still records its dataset: one
    /// that another run replaced meanwhile is told so, naming what changed.
    #[test]
    fn a_replaced_dataset_is_no_longer_held() {
        let d = tempfile::tempdir().unwrap();
        let (out, root) = (d.path().join("out"), d.path().join("out/.partial"));
        std::fs::create_dir_all(&root).unwrap();
        hold(&out, &root, &settings(), false).unwrap();
        drop(still_held(&out, &root, &settings()).unwrap());
        let other = Settings {
            aovs: vec!["depth".into(), "normal".into(), "uv".into()],
            ..settings()
        };
        hold(&out, &root, &other, true).unwrap();
        let e = still_held(&out, &root, &settings())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("another run replaced the dataset"), "{e}");
        assert!(
            e.contains("aovs: depth,normal now, depth,normal,uv in the folder"),
            "{e}"
        );
        std::fs::remove_file(out.join(FILE)).unwrap();
        let e = still_held(&out, &root, &other).err().unwrap().to_string();
        assert!(e.contains("is gone"), "{e}");
    }
}
