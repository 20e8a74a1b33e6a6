//! Every file name cylaov writes, in one list ([`OUTPUT_NAMES`]): the table in docs/datasets.md and the
//! batch folder scan (which never reads cylaov's own outputs as scenes) both come from it.
//!
//! | name | written by | what it is |
//! |---|---|---|
//! | `OUT.exr` (`-o`) | render | the AOVs, one layered EXR |
//! | `OUT.AOV.exr` | render `--exr-layout per-aov` | one EXR per AOV, names OpenCV reads |
//! | `OUT.camera.json` | render | camera metadata: K in both pixel conventions, poses |
//! | `OUT.depth.png` | render `--depth-png` | 16-bit planar depth × scale |
//! | `NAME.normal.preview.png`, `NAME.depth.preview.png`, `NAME.distance.preview.png` | render `--preview`, batch | pictures for people, not data |
//! | `NAME.exr`, `NAME.AOV.exr` | batch | the view's AOVs (layered, or per AOV) |
//! | `NAME.camera.json` | batch | as for render |
//! | `NAME.open3d.json` | batch | Open3D `PinholeCameraParameters` |
//! | `NAME.depth.png` | batch | 16-bit planar depth × `--depth-scale` |
//! | `NAME.mask.png` | batch | 8-bit hit mask, 255 = hit |
//! | `NAME.render.json` | batch | what made the view's files, checked on resume |
//! | `NAME.verify.json` | batch `--verify-fraction` | the view's Mitsuba verdict, keyed to its render stamp |
//! | `NAME.heatmap.png` | verify `--heatmap` | where and how much cylaov and Mitsuba differ |
//! | `index.json` | batch | every view of the batch: scene, camera, files, pose |
//! | `SCENE/transforms.json` | batch | nerfstudio index of one several-camera scene |
//! | `failures.K-of-N.jsonl` | batch | the views of shard K that failed, and why |
//! | `.partial/` | batch | work in progress, cleared when a shard starts |
//! | `shard-J.tar` | batch `--format webdataset` | tar shard J: each view's `.npy` arrays and JSON |
//! | `shard-J.json` | batch `--format webdataset` | tar J's sidecar: samples, sha256, input stamp |
//! | `shards.json` | batch `--format webdataset` | every shard's name, count, sha256; the settings |
//! | `shards.settings.json` | batch `--format webdataset` | the settings the folder's one dataset is written with |
//! | `failures.tar-J.jsonl` | Python `write_shards` | the views of tar J that failed, and why |
//! | `scenes/NNNNNN.json` | generate | the scene files |
//! | `manifest.jsonl`, `generate.json` | generate | the scene list; the resolved options |
//!
//! `NAME` is a view's name (a scene's name, or `00`, `01`, … inside `SCENE/`), `AOV` an AOV
//! name, `OUT` the `-o` path without `.exr`. Until 0.2 the normal preview of a batch was
//! `NAME.normal.png` and the batch index `OUT/transforms.json`; a new batch run removes both.

/// One entry of the list: a pattern (`NAME`, `SCENE`, `OUT`, `AOV`, `K`, `N` stand for any
/// non-empty text) and what writes it.
#[derive(Clone, Copy, Debug)]
pub struct OutputName {
    /// The file name pattern, e.g. `NAME.camera.json`.
    pub pattern: &'static str,
    /// The command (and flag) that writes it.
    pub written_by: &'static str,
}

/// Every file name cylaov writes (see the module docs for the meanings).
pub const OUTPUT_NAMES: &[OutputName] = &[
    out("OUT.exr", "render"),
    out("OUT.AOV.exr", "render --exr-layout per-aov"),
    out("OUT.camera.json", "render"),
    out("OUT.open3d.json", "render"),
    out("OUT.depth.png", "render --depth-png"),
    out("NAME.normal.preview.png", "render --preview, batch"),
    out("NAME.depth.preview.png", "render --preview"),
    out("NAME.distance.preview.png", "render --preview"),
    out("NAME.exr", "batch"),
    out("NAME.AOV.exr", "batch --exr-layout per-aov"),
    out("NAME.camera.json", "batch"),
    out("NAME.open3d.json", "batch"),
    out("NAME.depth.png", "batch"),
    out("NAME.mask.png", "batch"),
    out("NAME.render.json", "batch"),
    out("NAME.verify.json", "batch --verify-fraction"),
    out("NAME.heatmap.png", "verify --heatmap"),
    out("index.json", "batch"),
    out("transforms.json", "batch (in SCENE/)"),
    out("failures.K-of-N.jsonl", "batch"),
    out(".partial", "batch"),
    out("shard-J.tar", "batch --format webdataset"),
    out("shard-J.json", "batch --format webdataset"),
    out("shards.json", "batch --format webdataset"),
    out("shards.settings.json", "batch --format webdataset"),
    out("failures.tar-J.jsonl", "Python write_shards"),
    out("scenes/NNNNNN.json", "generate"),
    out("manifest.jsonl", "generate"),
    out("generate.json", "generate"),
];

const fn out(pattern: &'static str, written_by: &'static str) -> OutputName {
    OutputName {
        pattern,
        written_by,
    }
}

/// JSON files cylaov writes that are not scene files: what a folder scan must skip. Scene
/// files (`scenes/NNNNNN.json`) and the `.exr`/`.png` outputs are not in it.
fn is_output_json(file_name: &str) -> bool {
    OUTPUT_NAMES
        .iter()
        .map(|n| n.pattern.rsplit('/').next().unwrap_or(n.pattern))
        .filter(|p| p.ends_with(".json") && !p.starts_with("NNNNNN"))
        .any(|p| matches(p, file_name))
}

/// Whether `file_name` (no folder) is one cylaov writes beside its data, not a scene file.
pub fn is_cylaov_output(file_name: &str) -> bool {
    is_output_json(file_name)
}

/// Match a pattern whose upper-case words (`NAME`, `OUT`, `AOV`, `J`, `K`, `N`) stand for any
/// non-empty text; everything else is literal.
fn matches(pattern: &str, name: &str) -> bool {
    let Some(at) = pattern.find(|c: char| c.is_ascii_uppercase()) else {
        return pattern == name;
    };
    let (literal, rest) = pattern.split_at(at);
    let Some(name) = name.strip_prefix(literal) else {
        return false;
    };
    let rest = rest.trim_start_matches(|c: char| c.is_ascii_uppercase());
    // The wildcard takes 1.. characters; the remaining pattern matches what follows.
    name.char_indices()
        .skip(1)
        .map(|(i, _)| i)
        .chain(std::iter::once(name.len()).filter(|&n| n > 0))
        .any(|i| matches(rest, &name[i..]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_are_told_from_scene_files() {
        for own in [
            "000001.camera.json",
            "a.b.render.json",
            "00.open3d.json",
            "index.json",
            "transforms.json",
            "generate.json",
            "shard-000003.json",
            "shards.json",
            "shards.settings.json",
        ] {
            assert!(is_cylaov_output(own), "{own}");
        }
        for scene in [
            "000001.json",
            "camera.json",
            "scene.json",
            "render.json",
            "x.jsonl",
        ] {
            assert!(!is_cylaov_output(scene), "{scene}");
        }
        assert!(matches("failures.K-of-N.jsonl", "failures.0-of-4.jsonl"));
        assert!(!matches("failures.K-of-N.jsonl", "failures.-of-4.jsonl"));
        assert!(matches("NAME.AOV.exr", "000001.depth.exr"));
        assert!(!matches("NAME.AOV.exr", "000001.exr"));
    }
}
