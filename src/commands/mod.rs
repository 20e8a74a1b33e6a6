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

/// A usage error found after the arguments parsed: a flag's value out of its range, or
/// flags that do not go together. The binary exits 2 on it, as on the parser's own usage errors
/// (`cylaov --help` lists the exit statuses); every other error exits 1.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// `Err` of a [`Usage`] error with `message`, as `anyhow::bail!` would return it.
pub fn usage<T>(message: impl Into<String>) -> anyhow::Result<T> {
    Err(Usage(message.into()).into())
}

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
