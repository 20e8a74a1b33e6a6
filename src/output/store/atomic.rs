//! Files that are never half-written: each is staged under a temporary name in the
//! target's folder (or a work folder on the same file system) and renamed into place
//! when complete, alone ([`atomic_write`]) or together with the other files of one
//! command ([`commit_all`]). Staged files are registered with [`crate::output::store::signals`], so a
//! signal removes them too; the folders a command made go again if it fails
//! ([`NewDirs`]).

use crate::output::store::signals::{self, Cleanup, Registration};
use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// The start of the temporary name used while `path` is written: `.NAME.HOST.PID.`, to
/// which [`stage`] adds random characters and `.tmp`, in the same folder so the rename is
/// atomic. Hidden and ending in `.tmp`, the suffix every work-in-progress file of cylaov
/// carries; the host (`/proc/sys/kernel/hostname`, else `$HOSTNAME`) and PID say who left a
/// file behind (shards on different nodes of a shared filesystem can have equal PIDs).
/// `NAME` is shortened (at a character boundary) when the whole would pass the 255-byte
/// file name limit: any output name the file system accepts also has a temporary name it
/// accepts.
fn temp_prefix(path: &Path) -> String {
    let host = temp_host();
    let mut name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tail = format!(".{host}.{}.", std::process::id());
    // One byte for the leading dot, the random part and `.tmp`; the tail is at most ~30 bytes.
    let room = NAME_MAX.saturating_sub(1 + tail.len() + TEMP_RANDOM + ".tmp".len());
    if name.len() > room {
        let mut cut = room;
        while !name.is_char_boundary(cut) {
            cut -= 1;
        }
        name.truncate(cut);
    }
    format!(".{name}{tail}")
}

/// The host part of a temporary name (see [`temp_prefix`]).
fn temp_host() -> &'static str {
    use std::sync::OnceLock;
    static HOST: OnceLock<String> = OnceLock::new();
    HOST.get_or_init(|| {
        let host = hostname()
            .or_else(|| std::env::var("HOSTNAME").ok())
            .unwrap_or_default();
        // File-name safe and short: a long name must still fit NAME_MAX with the rest.
        let host: String = host
            .trim()
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '.')
            .take(16)
            .collect();
        if host.is_empty() { "host".into() } else { host }
    })
}

/// This machine's name (`gethostname`, which needs no file handle: a run out of them
/// still names its temporary files like every other run of this host).
#[cfg(target_os = "linux")]
fn hostname() -> Option<String> {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most `buf.len()` bytes into the buffer it is given.
    if unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } != 0 {
        return None;
    }
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    Some(String::from_utf8_lossy(&buf[..end]).into_owned())
}

#[cfg(not(target_os = "linux"))]
fn hostname() -> Option<String> {
    std::fs::read_to_string("/proc/sys/kernel/hostname").ok()
}

/// Random characters in a temporary name; with exclusive creation (`O_EXCL`, retried by
/// `tempfile` on a clash) two threads, two processes or two nodes never share one.
const TEMP_RANDOM: usize = 8;

/// The longest file name (one path component, in bytes) of Linux file systems.
pub(crate) const NAME_MAX: usize = 255;

/// The folders a command created, removed again (innermost first, where empty) when it is
/// dropped before [`NewDirs::keep`]: a failed `-o new/sub/x.exr` leaves no `new/`.
#[derive(Default)]
#[must_use = "the folders are removed when this is dropped without keep()"]
pub struct NewDirs {
    made: Vec<PathBuf>,
    /// Each made folder is also removed (if empty) by a signal's clean-up.
    registered: Vec<Registration>,
}

impl NewDirs {
    /// Create `dir` and its missing parents, remembering the ones this call made. Each is
    /// made and registered while the signal registry is held (see
    /// [`signals::hold`]): a signal's clean-up either sees it or runs before it exists.
    pub fn create(&mut self, dir: &Path) -> io::Result<()> {
        let mut missing: Vec<PathBuf> = Vec::new();
        for d in dir.ancestors() {
            if d.as_os_str().is_empty() || d.exists() {
                break;
            }
            missing.push(d.to_path_buf());
        }
        let mut held = signals::hold();
        for d in missing.into_iter().rev() {
            match std::fs::create_dir(&d) {
                Ok(()) => {
                    self.registered.push(held.register(Cleanup::EmptyDir, &d));
                    self.made.push(d);
                }
                // Made meanwhile by another thread or process: not ours to remove.
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists && d.is_dir() => {}
                Err(e) => return Err(explain(e)),
            }
        }
        // A file in the way of `dir` itself is refused here, as create_dir_all refuses it;
        // still held, so nothing is made after a clean-up looked.
        std::fs::create_dir_all(dir).map_err(explain)?;
        drop(held);
        Ok(())
    }

    /// [`NewDirs::create`] for the parent folder of a file target, if it has one.
    pub fn create_parent(&mut self, file: &Path) -> io::Result<()> {
        match file.parent() {
            Some(d) if !d.as_os_str().is_empty() => self.create(d),
            _ => Ok(()),
        }
    }

    /// Whether any folder was made (the target is new: what the command wrote in it is all
    /// its own).
    pub fn made_any(&self) -> bool {
        !self.made.is_empty()
    }

    /// The command succeeded: keep every folder.
    pub fn keep(mut self) {
        self.made.clear();
        self.registered.clear();
    }
}

impl Drop for NewDirs {
    fn drop(&mut self) {
        for d in self.made.iter().rev() {
            let _ = std::fs::remove_dir(d);
        }
    }
}

/// `create_dir_all` while the signal registry is held ([`signals::hold`]): never after a
/// signal's clean-up looked. The folders it makes are not registered: for folders inside
/// one a command made with [`NewDirs`] or registered itself, or where a left-over empty
/// folder is harmless.
pub fn make_dir_all(dir: &Path) -> io::Result<()> {
    let _held = signals::hold();
    std::fs::create_dir_all(dir)
}

/// Add the advice a person needs to an IO error: a full disk, the file size limit and
/// the open-file limit say so.
pub fn explain(e: io::Error) -> io::Error {
    let advice = match e.raw_os_error() {
        Some(28) => "the disk is full; free space and run again".to_string(),
        Some(122) => "the disk quota is exceeded; free space and run again".to_string(),
        Some(27) => {
            "the file size limit is reached (ulimit -f); raise it and run again".to_string()
        }
        Some(24) | Some(23) => format!(
            "too many open files (ulimit -n); raise the limit or use fewer {}",
            crate::spelling::opt("threads")
        ),
        _ if e.kind() == io::ErrorKind::StorageFull => {
            "the disk is full; free space and run again".to_string()
        }
        _ => return e,
    };
    io::Error::new(e.kind(), format!("{e}: {advice}"))
}

/// Write `path` through `fill` into a temporary file, then rename it into place. On any
/// error the temporary file is removed and `path` is untouched. A killed process leaves at
/// most a `.tmp` file, never a partial `path`. No fsync: that guards against power loss,
/// not process death, and costs more than encoding a 1080p EXR.
pub fn atomic_write(path: &Path, fill: impl FnOnce(&mut File) -> io::Result<()>) -> io::Result<()> {
    stage(path, fill)?.commit()
}

/// A file written under its temporary name and not yet renamed into place: a command that
/// writes several files stages them all, then commits them, so a failure half-way leaves
/// none of them behind. Dropped uncommitted, the temporary file is removed (`tempfile`'s
/// `NamedTempFile`, which also created it exclusively).
#[must_use = "a staged file is removed unless committed"]
pub struct Staged {
    file: tempfile::NamedTempFile,
    path: PathBuf,
    /// Removed by a signal's clean-up until committed or dropped.
    _registered: Registration,
}

/// Write `path`'s content through `fill` to its temporary name (see [`Staged`]), in
/// `path`'s own folder.
pub fn stage(path: &Path, fill: impl FnOnce(&mut File) -> io::Result<()>) -> io::Result<Staged> {
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(dir) => {
            make_dir_all(dir)?;
            dir
        }
        None => Path::new("."),
    };
    // What runs killed outright (SIGKILL, a power cut) left here goes first.
    signals::sweep_once(dir, temp_host(), TEMP_RANDOM);
    stage_at(path, dir, &temp_prefix(path), fill)
}

/// [`stage`] with `bytes` as the content, written in pieces of at most [`PIECE`] bytes: a
/// signal's clean-up removes the temporary file, and its `unlink` waits for a write in
/// progress to that file, so one write of a whole large file would hold Ctrl-C up for as
/// long as the disk takes (0.4–1.8 s for 420 MB); a 4 MiB piece takes milliseconds.
pub fn stage_bytes(path: &Path, bytes: &[u8]) -> io::Result<Staged> {
    stage(path, |f| {
        bytes.chunks(PIECE).try_for_each(|piece| f.write_all(piece))
    })
}

/// The most [`stage_bytes`] writes at once.
pub const PIECE: usize = 4 << 20;

/// [`stage`] with the temporary file in `work` (a folder of cylaov's own on the same file
/// system, such as a batch shard's partial folder, which goes as a whole) named
/// `PREFIX` + random characters + `.tmp`.
pub fn stage_in(
    path: &Path,
    work: &Path,
    prefix: &str,
    fill: impl FnOnce(&mut File) -> io::Result<()>,
) -> io::Result<Staged> {
    stage_at(path, work, prefix, fill)
}

fn stage_at(
    path: &Path,
    dir: &Path,
    prefix: &str,
    fill: impl FnOnce(&mut File) -> io::Result<()>,
) -> io::Result<Staged> {
    let (mut file, registered) = signals::create_registered(
        Cleanup::File,
        || {
            tempfile::Builder::new()
                .prefix(prefix)
                .suffix(".tmp")
                .rand_bytes(TEMP_RANDOM)
                // The mode `File::create` gives (0666 less the umask), not tempfile's
                // private 0600: the renamed file is the user's output.
                .permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666))
                .tempfile_in(dir)
                .map_err(explain)
        },
        |f| f.path().to_path_buf(),
    )?;
    if let Some(errno) = injected_failure() {
        return Err(explain(io::Error::from_raw_os_error(errno)));
    }
    fill(file.as_file_mut()).map_err(explain)?;
    file.as_file_mut().flush().map_err(explain)?;
    Ok(Staged {
        file,
        path: path.to_path_buf(),
        _registered: registered,
    })
}

impl Staged {
    /// Where the content waits until [`Staged::commit`].
    pub fn temp_path(&self) -> &Path {
        self.file.path()
    }

    /// The temporary file, for a writer that fills it in place (positional writes).
    pub fn file(&self) -> &File {
        self.file.as_file()
    }

    /// Where the file goes.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Rename the file into place.
    pub fn commit(self) -> io::Result<()> {
        self.file.persist(&self.path).map_err(|e| e.error)?;
        Ok(())
    }
}

/// Commit staged files together: none is renamed while any destination is a folder, and
/// if a rename still fails, the files this call already put in place are removed again.
pub fn commit_all(staged: Vec<Staged>) -> io::Result<()> {
    commit_replacing(&[], staged)
}

/// [`commit_all`], removing the files `stale` names first (an older run's files the new
/// ones would contradict; a missing one is fine). The removals and renames run under the
/// signal registry ([`signals::hold`]): a Ctrl-C meanwhile waits for them, so the files are
/// all old or all new, never a mix.
pub fn commit_replacing(stale: &[PathBuf], staged: Vec<Staged>) -> io::Result<()> {
    if let Some(s) = staged.iter().find(|s| s.path.is_dir()) {
        return Err(io::Error::other(format!(
            "{} is a folder",
            s.path.display()
        )));
    }
    // Registrations end (which takes the registry) only after `held` is gone.
    let (files, registrations): (Vec<_>, Vec<_>) = staged
        .into_iter()
        .map(|s| ((s.file, s.path), s._registered))
        .unzip();
    let held = signals::hold();
    let result = rename_all(stale, files);
    drop(held);
    drop(registrations);
    result
}

/// The removals and renames of [`commit_replacing`], rolled back on a failed rename.
fn rename_all(stale: &[PathBuf], files: Vec<(tempfile::NamedTempFile, PathBuf)>) -> io::Result<()> {
    for path in stale {
        match std::fs::remove_file(path) {
            Err(e) if e.kind() != io::ErrorKind::NotFound => {
                return Err(io::Error::new(
                    e.kind(),
                    format!("removing the old {}: {e}", path.display()),
                ));
            }
            _ => {}
        }
    }
    let mut done: Vec<PathBuf> = Vec::new();
    let last = files.len().saturating_sub(1);
    for (i, (file, path)) in files.into_iter().enumerate() {
        if i > 0 && injected() == Some(Injected::SlowCommit) {
            std::thread::sleep(std::time::Duration::from_millis(300));
        }
        let committed = if i == last && i > 0 && injected() == Some(Injected::LastRename) {
            Err(io::Error::from_raw_os_error(5))
        } else {
            file.persist(&path).map(drop).map_err(|e| e.error)
        };
        if let Err(e) = committed {
            for p in &done {
                let _ = std::fs::remove_file(p);
            }
            return Err(io::Error::other(format!("{}: {e}", path.display())));
        }
        done.push(path);
    }
    Ok(())
}

/// A failure injected for tests (`CYLAOV_FAIL_WRITES`, read once; any other value is
/// ignored).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Injected {
    /// `ENOSPC`: every staged write fails as a full disk would, after its temporary file
    /// was created (so the clean-up runs).
    Write(i32),
    /// `COMMIT`: the last rename of every [`commit_all`] of several files fails (EIO) after
    /// the others were put in place (so the roll-back runs).
    LastRename,
    /// `SLOW_COMMIT`: every rename after the first of a [`commit_all`] waits 0.3 s (so a
    /// signal can arrive half-way through).
    SlowCommit,
}

fn injected() -> Option<Injected> {
    use std::sync::OnceLock;
    static FAIL: OnceLock<Option<Injected>> = OnceLock::new();
    *FAIL.get_or_init(
        || match std::env::var("CYLAOV_FAIL_WRITES").ok()?.as_str() {
            "ENOSPC" => Some(Injected::Write(28)),
            "COMMIT" => Some(Injected::LastRename),
            "SLOW_COMMIT" => Some(Injected::SlowCommit),
            _ => None,
        },
    )
}

/// The errno of an injected write failure (see [`Injected::Write`]).
fn injected_failure() -> Option<i32> {
    match injected()? {
        Injected::Write(errno) => Some(errno),
        Injected::LastRename | Injected::SlowCommit => None,
    }
}

/// Write bytes atomically.
pub fn atomic_write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    atomic_write(path, |f| f.write_all(bytes))
}
