//! The work-in-progress folder of a shard and its lock.
//!
//! `OUT/.partial/` must be a real folder inside `--out`: a symlink there (or a file) is
//! refused, never followed, so clearing a shard's partial folder cannot delete anything
//! outside `--out` and temporary files never land elsewhere.
//!
//! Two batches writing the same shard into one `--out` would clear each other's work. Each
//! shard therefore takes an advisory lock (`flock`, exclusive, non-blocking) on
//! `OUT/.partial/K-of-N.lock` before anything in its partial folder is cleared, and writes
//! its host and pid into the file: advisory locks can be node-local on cluster file systems,
//! so the recorded host tells a user which machine to look at. A second batch fails at once
//! with "another batch is writing shard K of N in OUT (host …, pid …)". The lock goes with
//! the process (a kill -9 releases it); the file is removed on a normal exit while the lock
//! is still held, and whoever locks checks that the file it locked is still the one at the
//! path (else it retries), so a lock taken on a just-removed file never counts.
//! (On systems other than Linux the lock is not taken.)
//!
//! The lock file is opened in place, so it is opened with `O_NOFOLLOW` and `O_NONBLOCK`
//! and must be a regular file with a single link: a symbolic link, a hard link to a file
//! elsewhere, a FIFO or a device planted at its name is refused (naming it), never written
//! through.

use super::shard::Shard;
use crate::output::store::files::{explain_open, kind_name, no_follow};
use crate::output::store::signals::{self, Cleanup, Registration};
use anyhow::{Context, Result, bail};
use std::fs::File;
use std::path::{Path, PathBuf};

/// A held shard lock; dropping it removes the lock file and releases the lock.
pub struct ShardLock {
    path: PathBuf,
    _file: File,
    /// A signal's clean-up removes the file too.
    _registered: Registration,
}

impl Drop for ShardLock {
    fn drop(&mut self) {
        // Removed while still locked (the file closes after this): see the module docs.
        let _ = std::fs::remove_file(&self.path);
    }
}

/// `OUT/.partial`, created if needed; an error if it exists and is not a real folder.
/// The shards of an array start together, so creating it races: a shard that finds it made
/// by another checks it like one that was there before.
///
/// The returned registration removes it, if empty, on a signal: made and registered while
/// the signal registry is held ([`signals::hold`]), so a signal's clean-up either sees it
/// or runs before it exists. Registered before the lock and the shard's folder, a signal's clean-up (newest first)
/// tries it last, when it may be empty.
pub fn partial_root(out: &Path) -> Result<(PathBuf, Registration)> {
    let root = out.join(".partial");
    let mut held = signals::hold();
    let reg = held.register(Cleanup::EmptyDir, &root);
    let made = std::fs::create_dir(&root);
    // Before `reg` can drop: ending a registration takes the registry `held` holds.
    drop(held);
    if let Err(e) = made
        && e.kind() != std::io::ErrorKind::AlreadyExists
    {
        return Err(e).with_context(|| format!("creating {}", root.display()));
    }
    let m = root
        .symlink_metadata()
        .with_context(|| format!("reading {}", root.display()))?;
    if m.file_type().is_symlink() {
        bail!(
            "{} is a symbolic link: the work-in-progress folder must be a real folder inside \
             {} (it is cleared and written to); remove the link",
            root.display(),
            crate::spelling::opt("out")
        );
    }
    if !m.is_dir() {
        bail!(
            "{} exists and is not a folder: remove it (batch keeps its work in progress there)",
            root.display()
        );
    }
    Ok((root, reg))
}

/// This machine's name, for the lock file.
fn host() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "?".into())
}

/// Lock `shard` of the batch writing into `out` (see the module docs).
pub fn lock_shard(out: &Path, root: &Path, shard: Shard) -> Result<ShardLock> {
    lock_file(out, &root.join(format!("{shard}.lock")), false, &|| {
        format!("shard {} of {}", shard.index, shard.count)
    })
}

/// Lock `OUT/.partial/NAME.lock` as [`lock_shard`] locks a shard, but waiting for another
/// holder instead of refusing: for what every process writes in turn besides its shard (the
/// merged index of tar shards, which the last one to finish must see whole).
pub fn lock_named(out: &Path, root: &Path, name: &str) -> Result<ShardLock> {
    lock_file(out, &root.join(format!("{name}.lock")), true, &|| {
        name.to_string()
    })
}

/// Lock `path` (in `OUT/.partial`), refusing when another process holds it, or waiting for
/// it when `wait`. `.partial` is removed by the last process to leave it, so it can vanish
/// between one lock and the next of a process still working: then it is made again.
///
/// The file is created, locked and registered for a signal's clean-up in one hold of the
/// signal registry ([`signals::hold`]): a clean-up never meets a lock file this process
/// created but did not list, nor one it holds but listed only as free (which the clean-up
/// must leave, as it may be another run's). So the lock is only ever tried, never waited
/// for inside `flock`: waiting polls every [`LOCK_POLL`] with the registry let go.
fn lock_file(out: &Path, path: &Path, wait: bool, what: &dyn Fn() -> String) -> Result<ShardLock> {
    let path = path.to_path_buf();
    // A signal between creating the file and holding its lock removes it if still free
    // (it is ours, or a stale one); kept until the held lock's own registration exists.
    let _creating = signals::register(Cleanup::FreeLock, &path);
    loop {
        let mut held = signals::hold();
        let file = match open_lock(&path) {
            Err(e)
                if e.chain().any(|c| {
                    c.downcast_ref::<std::io::Error>()
                        .is_some_and(|io| io.kind() == std::io::ErrorKind::NotFound)
                }) && path.parent() == Some(&out.join(".partial")) =>
            {
                // Made again; its registration is the caller's, held since the first.
                drop(held);
                drop(partial_root(out)?);
                continue;
            }
            // A peer removed the file between our open and our look at it: try again.
            Ok(None) => continue,
            Ok(Some(file)) => file,
            Err(e) => return Err(e),
        };
        if !try_lock(&file).with_context(|| path.display().to_string())? {
            drop(held);
            if wait {
                drop(file);
                std::thread::sleep(LOCK_POLL);
                continue;
            }
            let mut holder = String::new();
            let _ = std::io::Read::read_to_string(&mut &file, &mut holder);
            let holder = holder.trim();
            let holder = if holder.is_empty() {
                "host ?, pid ?"
            } else {
                holder
            };
            bail!(
                "another batch is writing {} in {} ({holder}); wait for it, or give this one \
                 another {}",
                what(),
                out.display(),
                crate::spelling::opt("out")
            );
        }
        if same_file(&file, &path) {
            use std::io::Write;
            let mut f = &file;
            f.set_len(0)?;
            write!(f, "host {}, pid {}", host(), std::process::id())
                .with_context(|| format!("writing {}", path.display()))?;
            let registered = held.register(Cleanup::File, &path);
            return Ok(ShardLock {
                path,
                _file: file,
                _registered: registered,
            });
        }
        // The holder removed the file between our open and our lock: try again.
    }
}

/// How often a process waiting for a named lock ([`lock_named`]) tries it again: its
/// holders keep it for one small file's write.
const LOCK_POLL: std::time::Duration = std::time::Duration::from_millis(5);

/// Open (or create) the lock file at `path` in place: a regular file with one link, not
/// followed if it is a link, not waited on if it is a FIFO (see the module docs). `None`
/// when the file opened has no name left (no link: its holder removed it after our open).
fn open_lock(path: &Path) -> Result<Option<File>> {
    use std::os::unix::fs::MetadataExt;
    let refuse = |what: String| {
        anyhow::anyhow!(
            "{}: {what}: a shard lock must be cylaov's own file; remove it and run again",
            path.display()
        )
    };
    if let Ok(m) = path.symlink_metadata()
        && !m.is_file()
    {
        return Err(refuse(format!(
            "is {}, not a regular file",
            kind_name(m.file_type())
        )));
    }
    let mut opts = std::fs::OpenOptions::new();
    opts.read(true).write(true).create(true).truncate(false);
    no_follow(&mut opts);
    let file = opts
        .open(path)
        .map_err(|e| explain_open(path, e))
        .context("opening the shard lock")?;
    let m = file
        .metadata()
        .with_context(|| format!("reading {}", path.display()))?;
    if !m.is_file() {
        return Err(refuse(format!(
            "is {}, not a regular file",
            kind_name(m.file_type())
        )));
    }
    match m.nlink() {
        0 => Ok(None),
        1 => Ok(Some(file)),
        n => Err(refuse(format!(
            "has {n} hard links (another name shares its content)"
        ))),
    }
}

/// Take `file`'s exclusive lock at once, or not at all (`false`: another holds it).
#[cfg(target_os = "linux")]
fn try_lock(file: &File) -> Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a file descriptor this function borrows; no memory is involved.
    let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if rc == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e).context("locking the shard")
    }
}

#[cfg(not(target_os = "linux"))]
fn try_lock(_file: &File) -> Result<bool> {
    Ok(true)
}

/// Whether the open `file` is the file now at `path` (same device and inode).
#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), path.symlink_metadata()) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_file: &File, path: &Path) -> bool {
    path.exists()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shards of an array create `OUT/.partial` at the same moment: every one of them
    /// gets it (before, all but the first failed with "File exists").
    #[cfg(unix)]
    #[test]
    fn shards_starting_together_all_get_the_partial_root() {
        let scratch = tempfile::Builder::new()
            .prefix("cylaov-partial-race-")
            .tempdir()
            .unwrap();
        let base = scratch.path();
        for round in 0..40 {
            let out = base.join(round.to_string());
            std::fs::create_dir_all(&out).unwrap();
            let results: Vec<bool> = std::thread::scope(|s| {
                let handles: Vec<_> = (0..4)
                    .map(|_| s.spawn(|| partial_root(&out).is_ok()))
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            assert!(results.iter().all(|&ok| ok), "round {round}: {results:?}");
        }
        // A link in its place is still refused.
        let out = base.join("link");
        std::fs::create_dir_all(&out).unwrap();
        std::os::unix::fs::symlink(base, out.join(".partial")).unwrap();
        assert!(partial_root(&out).is_err());
    }
}
