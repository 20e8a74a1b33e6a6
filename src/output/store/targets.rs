//! Output-target checks: every command checks its targets with [`check_outputs`] before
//! it reads or computes anything, so a refused target costs nothing and leaves nothing
//! behind.

use crate::output::store::atomic::NAME_MAX;
use crate::output::store::files::{kind_name, system_folder};
use std::io;
use std::path::{Path, PathBuf};

/// The identity of an existing file, through links: (device, inode).
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

fn refuse(flag: &str, path: &Path, why: String) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{flag} {}: {why}", path.display()),
    )
}

/// Check one output target before anything is written: it may be missing or a regular file,
/// but not a device, FIFO, socket, folder or symbolic link: the write goes to a temporary
/// file that is renamed over the target, which would replace `/dev/null` itself or the
/// user's link (writing through it instead would change a file the link's owner may not
/// expect to change), and sidecar files would litter the device's folder. Nothing is
/// created inside `/dev`, `/proc` or `/sys`, however the path gets there (folders on the
/// way may be links). Nor may the target be any of `inputs` (compared by device and inode,
/// so hard and symbolic links count). The existing part of its folder path must be
/// folders. `flag` names the option in the message (`-o`, `--heatmap`, ...).
pub fn check_output(flag: &str, path: &Path, inputs: &[&Path]) -> io::Result<()> {
    if path.as_os_str().is_empty() {
        return Err(refuse(flag, path, "empty path".into()));
    }
    if let Some(name) = path.file_name()
        && name.len() > NAME_MAX
    {
        return Err(refuse(
            flag,
            path,
            format!("file name is {} bytes, the limit is {NAME_MAX}", name.len()),
        ));
    }
    if let Some(root) = system_folder(path, false) {
        return Err(refuse(flag, path, system_refusal(root)));
    }
    match std::fs::symlink_metadata(path) {
        Ok(link) => {
            let id = file_id(path);
            for input in inputs {
                if id.is_some() && file_id(input) == id {
                    return Err(refuse(
                        flag,
                        path,
                        format!("would overwrite the input {}", input.display()),
                    ));
                }
            }
            if link.file_type().is_symlink() {
                let to = match std::fs::metadata(path) {
                    Ok(m) => kind_name(m.file_type()),
                    Err(_) => "nothing",
                };
                return Err(refuse(
                    flag,
                    path,
                    format!(
                        "is a symbolic link (to {to}), not a regular file: cylaov neither \
                         replaces a link nor writes through one; give the path it points to \
                         or another name"
                    ),
                ));
            }
            if !link.is_file() {
                return Err(refuse(
                    flag,
                    path,
                    format!(
                        "is {}, not a regular file; refusing to replace it",
                        kind_name(link.file_type())
                    ),
                ));
            }
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound || e.raw_os_error() == Some(20) => {
            check_folders(flag, path)?
        }
        Err(e) => return Err(refuse(flag, path, e.to_string())),
    }
    Ok(())
}

/// Why nothing is written under `root`, one of the system folders.
fn system_refusal(root: &str) -> String {
    format!(
        "is inside {root}: cylaov never creates or renames files in /proc, /sys, or in /dev \
         outside a RAM disk such as /dev/shm (write to a regular file and copy it from there)"
    )
}

/// The nearest existing ancestor of a missing `path` must be a folder (else creating the
/// folders says only "File exists" or "Not a directory").
fn check_folders(flag: &str, path: &Path) -> io::Result<()> {
    for dir in path.ancestors().skip(1) {
        if dir.as_os_str().is_empty() {
            return Ok(());
        }
        match std::fs::metadata(dir) {
            Ok(m) if m.is_dir() => return Ok(()),
            Ok(m) => {
                return Err(refuse(
                    flag,
                    path,
                    format!(
                        "{} is {}, not a folder",
                        dir.display(),
                        kind_name(m.file_type())
                    ),
                ));
            }
            // Missing, or below a file (ENOTDIR): look further up.
            Err(e) if e.kind() == io::ErrorKind::NotFound || e.raw_os_error() == Some(20) => {
                continue;
            }
            Err(e) => return Err(refuse(flag, path, format!("{}: {e}", dir.display()))),
        }
    }
    Ok(())
}

/// [`check_output`] for every `(flag, path)` of a command; also refuses two outputs that are
/// one file (the second would silently replace the first).
pub fn check_outputs(outputs: &[(&str, &Path)], inputs: &[&Path]) -> io::Result<()> {
    for (i, (flag, path)) in outputs.iter().enumerate() {
        check_output(flag, path, inputs)?;
        for (flag2, other) in &outputs[..i] {
            if same_target(path, other) {
                return Err(refuse(
                    flag,
                    path,
                    format!("is also the {flag2} output {}", other.display()),
                ));
            }
        }
    }
    Ok(())
}

/// Two output paths that name one file: equal identities if both exist, else equal after
/// resolving their folders.
fn same_target(a: &Path, b: &Path) -> bool {
    if let (Some(x), Some(y)) = (file_id(a), file_id(b)) {
        return x == y;
    }
    let resolve = |p: &Path| -> Option<PathBuf> {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        Some(dir.canonicalize().ok()?.join(p.file_name()?))
    };
    match (resolve(a), resolve(b)) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}

/// Check that a folder target (`--preview DIR`) is a folder or can be made one.
pub fn check_output_dir(flag: &str, dir: &Path) -> io::Result<()> {
    let system = || match system_folder(dir, true) {
        Some(root) => Err(refuse(flag, dir, system_refusal(root))),
        None => Ok(()),
    };
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => system(),
        Ok(m) => Err(refuse(
            flag,
            dir,
            format!("is {}, not a folder", kind_name(m.file_type())),
        )),
        Err(e) if e.kind() == io::ErrorKind::NotFound || e.raw_os_error() == Some(20) => {
            system()?;
            check_folders(flag, dir)
        }
        Err(e) => Err(refuse(flag, dir, e.to_string())),
    }
}
