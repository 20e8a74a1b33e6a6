//! `cylaov import`: a cylinder table (a tree's QSM, or plain CSV) → a complete scene file
//! with one camera that frames every cylinder (see [`crate::scene::table`]).

use crate::output::store::targets::check_outputs;
use crate::scene::framing::Frame;
use crate::scene::table::{LabelRule, TableOptions, load_table};
use anyhow::{Context, Result, anyhow};
use std::path::PathBuf;

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
    let file = table.scene_file(args.frame);
    file.validate()
        .with_context(|| format!("{}: the imported scene", table_path.display()))?;
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
    let shifted = if table.ids_shifted {
        ", ids counted from 0 moved up by 1"
    } else {
        ""
    };
    Ok(format!(
        "{}: {} from {} ({}){labels}{shifted}, one camera {}x{} framing them all",
        out.display(),
        crate::output::console::count(file.cylinders.len(), "cylinder"),
        table_path.display(),
        table.format.name(),
        args.frame.width,
        args.frame.height,
    ))
}
