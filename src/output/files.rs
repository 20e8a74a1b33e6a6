//! Opening files in place without following a link or blocking on a FIFO, and the folders
//! cylaov never writes in.
//!
//! Everything cylaov writes goes to a new temporary file that is renamed into place
//! (`io::stage`, a batch's partial folder); the few files it opens where they are (a
//! shard's lock, the outputs a resumed batch reads back) are opened with `O_NOFOLLOW` and
//! `O_NONBLOCK` and checked to be regular files, so a planted link is never written
//! through and a FIFO never blocks a run.

use std::fs::{File, OpenOptions};
use std::io;
use std::path::{Path, PathBuf};

/// What a path is, in words, for a refusal message.
pub fn kind_name(ft: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_dir() {
        "a folder"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_fifo() {
        "a FIFO (named pipe)"
    } else if ft.is_socket() {
        "a socket"
    } else if ft.is_symlink() {
        "a symbolic link"
    } else {
        "a regular file"
    }
}

fn with_path(path: &Path, why: String) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{}: {why}", path.display()),
    )
}

/// Open an existing regular file for reading without following a link at its last
/// component or blocking if it is a FIFO; anything but a regular file is an error naming
/// the path and what it is.
pub fn open_regular(path: &Path) -> io::Result<File> {
    let mut opts = OpenOptions::new();
    opts.read(true);
    no_follow(&mut opts);
    let file = opts.open(path).map_err(|e| explain_open(path, e))?;
    let ft = file.metadata()?.file_type();
    if !ft.is_file() {
        return Err(with_path(
            path,
            format!("is {}, not a regular file", kind_name(ft)),
        ));
    }
    Ok(file)
}

/// The whole content of a regular file ([`open_regular`]).
pub fn read_regular(path: &Path) -> io::Result<Vec<u8>> {
    use std::io::Read;
    let mut bytes = Vec::new();
    open_regular(path)?.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Create a file that must not exist yet (`O_EXCL`: a link or FIFO planted at the name
/// makes it fail rather than be written through), for writing.
pub fn create_new(path: &Path) -> io::Result<File> {
    let mut opts = OpenOptions::new();
    opts.write(true).create_new(true);
    no_follow(&mut opts);
    opts.open(path)
}

/// `O_NOFOLLOW | O_NONBLOCK` (Linux).
pub fn no_follow(opts: &mut OpenOptions) {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    }
    #[cfg(not(target_os = "linux"))]
    let _ = opts;
}

/// An open error that names a link as a link (`O_NOFOLLOW` says only ELOOP).
pub fn explain_open(path: &Path, e: io::Error) -> io::Error {
    #[cfg(target_os = "linux")]
    if e.raw_os_error() == Some(libc::ELOOP)
        && path
            .symlink_metadata()
            .is_ok_and(|m| m.file_type().is_symlink())
    {
        return with_path(path, "is a symbolic link, not a regular file".into());
    }
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

/// `Err` naming `path` and what it is when something other than a regular file is there
/// (a link, a FIFO, a device, a folder); a missing path or a regular file is fine.
pub fn refuse_non_regular(path: &Path) -> io::Result<()> {
    match path.symlink_metadata() {
        Ok(m) if !m.is_file() => Err(with_path(
            path,
            format!(
                "is {}, not a regular file; refusing to replace it (remove it and run again)",
                kind_name(m.file_type())
            ),
        )),
        _ => Ok(()),
    }
}

/// The folders where cylaov never creates or renames anything: device nodes, the process
/// and the kernel's pseudo files (`-o /dev/stdout` would replace the machine's link).
pub const SYSTEM_FOLDERS: [&str; 3] = ["/dev", "/proc", "/sys"];

/// The system folder (see [`SYSTEM_FOLDERS`]) that `path` lies in, judged by its
/// absolute path and by where its existing folders lead (folders on the way may be
/// links); `resolve_last` also follows `path` itself (a folder target).
pub fn system_folder(path: &Path, resolve_last: bool) -> Option<&'static str> {
    let abs = std::path::absolute(path).ok()?;
    let mut seen: Vec<PathBuf> = vec![abs.clone()];
    let skip = usize::from(!resolve_last);
    for dir in abs.ancestors().skip(skip) {
        if let Ok(real) = dir.canonicalize() {
            let rest = abs.strip_prefix(dir).unwrap_or(Path::new(""));
            seen.push(if rest.as_os_str().is_empty() {
                real
            } else {
                real.join(rest)
            });
            break;
        }
    }
    SYSTEM_FOLDERS
        .iter()
        .find(|root| seen.iter().any(|p| p.starts_with(root)))
        .copied()
}
