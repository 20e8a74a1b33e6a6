//! The work behind each CLI subcommand: IO orchestration around the pure library.
//! The binary's `src/cli/` parses each command's arguments and calls these.

pub mod batch;
pub mod bench;
pub mod cameras;
pub mod compare;
pub mod export_mitsuba;
pub mod generate;
pub mod import;
pub mod render;
pub mod scan;
pub mod stress;
pub mod verify;

/// Write `file` to `out` (`-o`) as a scene file, one vector a line: atomically, making its
/// missing parent folders (removed again if the write fails). `import` and `cameras`
/// write their scenes through it.
fn write_scene_file(out: &std::path::Path, file: &crate::scene::SceneFile) -> anyhow::Result<()> {
    use anyhow::Context;
    let json = crate::dataset::generate::to_json(file).context("encoding the scene")?;
    let mut dirs = crate::output::store::atomic::NewDirs::default();
    dirs.create_parent(out)
        .with_context(|| format!("-o {}", out.display()))?;
    crate::output::store::atomic::atomic_write_bytes(out, format!("{json}\n").as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    dirs.keep();
    Ok(())
}
