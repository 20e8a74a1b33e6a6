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
use std::path::Path;

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
    regular(path, opts.open(path).map_err(|e| explain_open(path, e))?)
}

/// Open an input file for reading: links are followed (datasets are often linked in), but
/// the open never blocks on a FIFO (`O_NONBLOCK`) and anything that is not a regular file
/// in the end (a FIFO, a device, a folder) is an error naming the path and what it is.
pub fn open_input(path: &Path) -> io::Result<File> {
    let mut opts = OpenOptions::new();
    opts.read(true);
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.custom_flags(libc::O_NONBLOCK);
    }
    regular(path, opts.open(path)?)
}

/// `file` (opened from `path`) if it is a regular file; else an error naming what it is.
fn regular(path: &Path, file: File) -> io::Result<File> {
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

/// The system folder (see [`SYSTEM_FOLDERS`]) that `path` would be written in, judged by
/// where it really leads: its deepest existing folder resolved (links and `..`, as the
/// kernel will), the missing rest normalised; `resolve_last` also follows `path` itself
/// (a folder target). Inside `/proc` and `/sys` nothing is written. Inside `/dev` only a
/// RAM disk is writable: a tmpfs folder below `/dev` itself (`/dev/shm`); `/dev`'s own
/// entries (device nodes and links such as `/dev/stdout`) and other file systems mounted
/// there (`/dev/pts`, `/dev/mqueue`) are not.
pub fn system_folder(path: &Path, resolve_last: bool) -> Option<&'static str> {
    let abs = std::path::absolute(path).ok()?;
    let skip = usize::from(!resolve_last);
    // The deepest existing ancestor, canonical, and the path below it.
    let (real, rest) = abs.ancestors().skip(skip).find_map(|dir| {
        let real = dir.canonicalize().ok()?;
        Some((real, abs.strip_prefix(dir).ok()?.to_path_buf()))
    })?;
    let mut resolved = real.clone();
    for part in rest.components() {
        match part {
            std::path::Component::ParentDir => {
                resolved.pop();
            }
            std::path::Component::Normal(name) => resolved.push(name),
            _ => {}
        }
    }
    let root = SYSTEM_FOLDERS
        .iter()
        .find(|root| resolved.starts_with(root))
        .copied()?;
    if root != "/dev" {
        return Some(root);
    }
    // The folder the file (or the folders still to make) would be created in.
    let folder = if resolve_last {
        resolved.as_path()
    } else {
        resolved.parent().unwrap_or(Path::new("/"))
    };
    let folder = folder.ancestors().find(|d| d.is_dir())?;
    if folder != Path::new("/dev") && is_tmpfs(folder) {
        None
    } else {
        Some(root)
    }
}

/// Whether `dir` is on a tmpfs (a RAM disk such as `/dev/shm`), by `statfs(2)`.
fn is_tmpfs(dir: &Path) -> bool {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::ffi::OsStrExt;
        let Ok(c) = std::ffi::CString::new(dir.as_os_str().as_bytes()) else {
            return false;
        };
        let mut st = std::mem::MaybeUninit::<libc::statfs>::uninit();
        // SAFETY: `c` is a NUL-terminated path that outlives the call, and `st` points to
        // writable memory of the size statfs(2) fills; it is read only when the call
        // succeeded (returned 0), which initialises it.
        let ok = unsafe { libc::statfs(c.as_ptr(), st.as_mut_ptr()) } == 0;
        // SAFETY: initialised by the successful call above.
        ok && unsafe { st.assume_init() }.f_type == libc::TMPFS_MAGIC
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = dir;
        false
    }
}
