//! `cylaov import`: a cylinder table (a tree's QSM, or plain CSV) → a complete scene file
//! with one camera that frames every cylinder (see [`crate::scene::table`]).

use crate::dataset::generate::VectorFormatter;
use crate::output::store::targets::check_outputs;
use crate::scene::framing::Frame;
use crate::scene::table::{LabelRule, TableOptions, load_table};
use crate::scene::{CylinderFile, MAX_SCENE_BYTES, SceneFile, num};
use anyhow::{Result, anyhow};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Everything `import` needs from the command line.
#[derive(Clone, Debug)]
pub struct ImportArgs {
    /// The table file.
    pub table: PathBuf,
    /// The scene file to write (`-o`).
    pub out: PathBuf,
    /// Format, label rule and caps.
    pub options: TableOptions,
    /// The camera's image size and field of view.
    pub frame: Frame,
}

/// Import the table and return the one-line summary. Nothing is written unless every row
/// is good.
pub fn run(args: &ImportArgs) -> Result<String> {
    let (table_path, out) = (&args.table, &args.out);
    check_outputs(&[("-o", out)], &[table_path])?;
    let table = load_table(table_path, &args.options)
        .map_err(|e| anyhow!("{}: {e}", table_path.display()))?;
    let (format, ids_shifted) = (table.format, table.ids_shifted);
    let at_least = (table.cylinders.len() as u64).saturating_mul(cylinder_json_bytes()?);
    if at_least > MAX_SCENE_BYTES {
        return Err(too_large(table_path, table.cylinders.len(), at_least, true));
    }
    let file = table.into_scene_file(args.frame);
    file.validate()
        .map_err(|e| match e.field.strip_prefix("camera") {
            Some(field) => camera_error(table_path, &file, args.frame, field, &e.message),
            None => anyhow!("{}: the imported scene: {e}", table_path.display()),
        })?;
    if !surely_fits(&file)? {
        let bytes = scene_bytes(&file)?;
        if bytes > MAX_SCENE_BYTES {
            return Err(too_large(table_path, file.cylinders.len(), bytes, false));
        }
    }
    super::write_scene_file(out, &file)?;
    let label = args.options.label.unwrap_or(LabelRule::None);
    let labels = if file.cylinders.iter().any(|c| c.label != 0) {
        match args.options.label {
            Some(rule) => format!(", labels {}", rule.name()),
            None => ", labels from the label column".to_string(),
        }
    } else if label != LabelRule::None {
        format!(", labels {} (all 0)", label.name())
    } else {
        String::new()
    };
    let shifted = if ids_shifted {
        ", ids counted from 0 moved up by 1"
    } else {
        ""
    };
    Ok(format!(
        "{}: {} from {} ({}){labels}{shifted}, one camera {}x{} framing them all",
        out.display(),
        crate::output::console::count(file.cylinders.len(), "cylinder"),
        table_path.display(),
        format.name(),
        args.frame.width,
        args.frame.height,
    ))
}

/// Bytes of the scene file `write_scene_file` writes for `file`, counted as it is encoded
/// and not kept (the encoding of a scene of 512 MiB takes about a second).
fn scene_bytes(file: &SceneFile) -> Result<u64> {
    /// Counts what is written.
    struct Count(u64);
    impl std::io::Write for Count {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0 += b.len() as u64;
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let mut count = Count(0);
    file.serialize(&mut serde_json::Serializer::with_formatter(
        &mut count,
        VectorFormatter::default(),
    ))
    .map_err(|e| anyhow!("encoding the scene: {e}"))?;
    // `to_json`'s newline and the one `write_scene_file` adds.
    Ok(count.0 + 2)
}

/// The fewest bytes one more cylinder adds to a scene file (ends at 0 and 1, radius 1,
/// id 1: the shortest numbers), from the encoding itself.
fn cylinder_json_bytes() -> Result<u64> {
    let c = CylinderFile {
        p0: Some([0.0; 3]),
        p1: Some([0.0, 0.0, 1.0]),
        radius: 1.0,
        caps: true,
        id: Some(1),
        ..CylinderFile::default()
    };
    let size = |n: usize| {
        scene_bytes(&SceneFile {
            camera: None,
            cameras: None,
            cylinders: vec![c.clone(); n],
            aovs: None,
        })
    };
    Ok(size(2)? - size(1)?)
}

/// Whether `file` fits in [`MAX_SCENE_BYTES`] even if every cylinder took the most bytes
/// one can (every number of 17 digits and an exponent, the longest id and label), so that
/// most tables are not encoded twice (a million cylinders take about a second).
fn surely_fits(file: &SceneFile) -> Result<bool> {
    let x = -1.234_567_890_123_456_7e-300;
    let longest = CylinderFile {
        p0: Some([x; 3]),
        p1: Some([x; 3]),
        radius: x,
        caps: false,
        id: Some(u32::MAX),
        label: u32::MAX,
        ..CylinderFile::default()
    };
    let with = |cylinders: Vec<CylinderFile>| {
        scene_bytes(&SceneFile {
            camera: file.camera.clone(),
            cameras: None,
            cylinders,
            aovs: file.aovs.clone(),
        })
    };
    let rest = with(Vec::new())?;
    // Eight bytes more for each of the 7 numbers, should one ever print longer.
    let each = with(vec![longest.clone(); 2])? - with(vec![longest])? + 7 * 8;
    let n = file.cylinders.len() as u64;
    Ok(rest.saturating_add(n.saturating_mul(each)) <= MAX_SCENE_BYTES)
}

/// A scene of `n` cylinders too large to write: its size (`at_least`: a lower bound), the
/// limit, and what to do.
fn too_large(table: &Path, n: usize, bytes: u64, at_least: bool) -> anyhow::Error {
    let per = (bytes as f64 / n.max(1) as f64).round().max(1.0);
    anyhow!(
        "{}: the scene of its {n} cylinders would take {}{bytes} bytes, more than the {MAX_SCENE_BYTES} \
         (512 MiB) a scene file may have (render and every other reader refuse a larger one); \
         import fewer cylinders: at {} bytes each, about {} fit (split the table, or drop its \
         smallest cylinders)",
        table.display(),
        if at_least { "at least " } else { "" },
        per,
        (MAX_SCENE_BYTES as f64 / per).floor()
    )
}

/// An error of the camera that frames the table, in the terms the user gave: `--width`,
/// `--height`, `--fov` and the table's extent, not the fields of a camera they never
/// wrote. `field` is the camera field's path after `camera`.
fn camera_error(
    table: &Path,
    file: &SceneFile,
    frame: Frame,
    field: &str,
    message: &str,
) -> anyhow::Error {
    let flags = format!(
        "--fov {} with --width {} --height {}",
        num(frame.fov_deg),
        frame.width,
        frame.height
    );
    if field == ".fov_deg" {
        return anyhow!(
            "{}: --fov {}: {message}; give a wider --fov",
            table.display(),
            num(frame.fov_deg)
        );
    }
    if field == ".width" || field == ".height" {
        return anyhow!("{}: --width/--height: {message}", table.display());
    }
    let (centre, radius) = crate::scene::framing::bounding_sphere(&file.cylinders);
    let dist =
        crate::scene::framing::fit_distance(radius, frame.fov_deg, frame.width, frame.height);
    anyhow!(
        "{}: the camera framing every cylinder cannot be placed: the cylinders fill a sphere of \
         radius {} about {:?}, which {flags} sees whole from {} away, and there the camera's \
         {} {message}; give a wider --fov, or a table of smaller extent",
        table.display(),
        num(radius),
        centre.to_array(),
        num(dist),
        field.trim_start_matches('.'),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(cylinders: Vec<CylinderFile>) -> SceneFile {
        crate::scene::table::Table {
            format: crate::scene::table::TableFormat::Csv,
            cylinders,
            ids_shifted: false,
        }
        .into_scene_file(Frame::default())
    }

    /// The count is the file `write_scene_file` writes, byte for byte, and the estimate is
    /// what each cylinder of the shortest numbers adds (never more than a real one adds).
    #[test]
    fn sizes_are_the_written_files() {
        let c = |z: f64, id: u32| CylinderFile {
            p0: Some([0.0; 3]),
            p1: Some([0.0, 0.0, z]),
            radius: 1.0,
            caps: true,
            id: Some(id),
            ..CylinderFile::default()
        };
        let one = scene(vec![c(1.0, 1)]);
        let json = crate::dataset::generate::to_json(&one).unwrap();
        assert_eq!(scene_bytes(&one).unwrap(), json.len() as u64 + 1);
        assert!(surely_fits(&one).unwrap());
        // Cylinders alone (the camera's numbers change with them).
        let bare = |cylinders| {
            let mut s = scene(cylinders);
            s.camera = None;
            scene_bytes(&s).unwrap()
        };
        let min = cylinder_json_bytes().unwrap();
        let three = bare(vec![c(1.0, 1), c(1.0, 2), c(1.0, 3)]);
        assert_eq!(three - bare(vec![c(1.0, 1)]), 2 * min);
        let longer = bare(vec![c(1.0, 1), c(1.25, 2), c(1.0, 12)]);
        assert_eq!(longer - three, 2);
        // "p0": [0.0, 0.0, 0.0], "p1", "radius", "caps", "id" at six spaces, the braces at four.
        assert_eq!(min, 126);
    }
}
