//! `cylaov import`: a table of cylinders to a framed scene file.

use crate::cli::common::{say, shorten};
use clap::Args;
use cylaov::commands;
use cylaov::commands::usage;
use cylaov::scene::framing::Frame;
use cylaov::scene::table::{LabelRule, TableFormat, TableOptions};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct ImportCli {
    /// The table: TreeQSM cyl_data text, SimpleForest or aRchi CSV, or a CSV with
    /// x0,y0,z0,x1,y1,z1,radius columns.
    table: PathBuf,
    /// The scene file to write (JSON, docs/scene-format.md).
    #[arg(short, long)]
    out: PathBuf,
    /// The table's layout; default: from the header's names, or TreeQSM when there is no
    /// header and 14 or 15 columns.
    #[arg(long, value_parser = table_format, value_name = "csv|npz|treeqsm|simpleforest|archi")]
    format: Option<TableFormat>,
    /// Each cylinder's label (the label AOV): branch_order = BranchOrder + 1 (stem 1, its
    /// branches 2, ...; 0 stays "no hit"), branch = branch id + 1, segment = the cylinder's
    /// id, none = 0. Default: a csv table's label column, else none.
    #[arg(long, value_parser = label_rule, value_name = "none|branch_order|branch|segment")]
    label: Option<LabelRule>,
    /// Close the cylinders' ends (default on; a csv table's caps column wins).
    #[arg(long, value_parser = on_off, value_name = "on|off")]
    caps: Option<bool>,
    /// Image width of the camera, pixels.
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Image height of the camera, pixels.
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Horizontal field of view of the camera, degrees.
    #[arg(long, default_value_t = 50.0)]
    fov: f64,
}

pub fn table_format(s: &str) -> Result<TableFormat, String> {
    TableFormat::parse(s).ok_or_else(|| {
        format!(
            "unknown format {:?}; expected one of {}",
            shorten(s),
            TableFormat::ALL.map(|f| f.name()).join(", ")
        )
    })
}

pub fn label_rule(s: &str) -> Result<LabelRule, String> {
    LabelRule::parse(s).ok_or_else(|| {
        format!(
            "unknown label rule {:?}; expected one of {}",
            shorten(s),
            LabelRule::ALL.map(|f| f.name()).join(", ")
        )
    })
}

pub fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("expected on or off, got {:?}", shorten(s))),
    }
}

pub fn run(a: ImportCli) -> anyhow::Result<ExitCode> {
    if a.width == 0 || a.width > cylaov::scene::MAX_SIDE {
        return usage(format!(
            "--width: must be in 1..={}, got {}",
            cylaov::scene::MAX_SIDE,
            a.width
        ));
    }
    if a.height == 0 || a.height > cylaov::scene::MAX_SIDE {
        return usage(format!(
            "--height: must be in 1..={}, got {}",
            cylaov::scene::MAX_SIDE,
            a.height
        ));
    }
    let pixels = a.width as u64 * a.height as u64;
    if pixels > cylaov::scene::MAX_PIXELS {
        return usage(format!(
            "--width/--height: width × height must be <= {} pixels (64 megapixels, e.g. 8192 × 8192), got {} × {} = {pixels}",
            cylaov::scene::MAX_PIXELS,
            a.width,
            a.height
        ));
    }
    if !(a.fov > 0.0 && a.fov < 180.0) {
        return usage(format!("--fov: must be in (0, 180), got {}", a.fov));
    }
    let args = commands::import::ImportArgs {
        table: a.table,
        out: a.out,
        options: TableOptions {
            format: a.format,
            label: a.label,
            caps: a.caps,
        },
        frame: Frame {
            width: a.width,
            height: a.height,
            fov_deg: a.fov,
        },
    };
    say(&commands::import::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}
