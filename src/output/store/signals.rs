//! Interrupted runs leave nothing behind. SIGINT, SIGTERM and SIGHUP remove every file and
//! folder a command staged but did not put in place, kill the process group of the
//! reference renderer (Mitsuba's Python) it started, and exit with 128 + the signal number:
//! 129 (SIGHUP), 130 (SIGINT), 143 (SIGTERM), the status shells give a process killed by
//! that signal. SIGXFSZ is ignored, so a write past the file size limit (`ulimit -f`) fails
//! with `EFBIG` and the command's own clean-up and one-line error run instead of a silent
//! kill.
//!
//! How: [`install`], the first thing `main` does, blocks the three signals before any other
//! thread exists (every later thread inherits the mask; `std::process::Command` clears it
//! in children) and starts one thread that waits for them with `sigwait`. That thread runs
//! ordinary code, not a signal handler, so it may lock, allocate and remove folders: it
//! takes the registry's lock and keeps it until `_exit`, kills the registered process
//! groups, removes the registered paths (newest first) and exits. Every file and folder a
//! command may leave unfinished is created and registered under that same lock ([`hold`],
//! [`create_registered`]): the other threads keep running until `_exit`, so a path made
//! first and registered after, or registered first and made after, could appear after the
//! clean-up looked and stay behind. A signal ignored when cylaov starts (`nohup` ignores SIGHUP) stays
//! ignored.

use std::io;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, MutexGuard};

/// What the clean-up does with a registered path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Cleanup {
    /// A staged file: removed.
    File,
    /// A work folder of cylaov's own (a shard's partial folder, a Mitsuba scratch folder):
    /// removed with everything in it.
    Tree,
    /// A folder a command made for its outputs: removed if it is empty by then.
    EmptyDir,
    /// A lock file this process may have just created and not locked yet: removed if no
    /// process holds its lock (a held one is another run's, and stays).
    FreeLock,
}

struct Entry {
    id: u64,
    cleanup: Cleanup,
    path: PathBuf,
}

struct Registry {
    next: u64,
    paths: Vec<Entry>,
    /// Process groups of children (their leaders' pids).
    groups: Vec<(u64, i32)>,
}

static REGISTRY: Mutex<Registry> = Mutex::new(Registry {
    next: 0,
    paths: Vec::new(),
    groups: Vec::new(),
});

fn registry() -> MutexGuard<'static, Registry> {
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

/// A path or process group in the registry; dropping it takes it out (the command
/// committed, removed or waited for it itself).
#[must_use = "the registration ends when this is dropped"]
#[derive(Debug)]
pub struct Registration {
    id: u64,
}

impl Drop for Registration {
    fn drop(&mut self) {
        let mut r = registry();
        r.paths.retain(|e| e.id != self.id);
        r.groups.retain(|g| g.0 != self.id);
    }
}

fn add(r: &mut Registry, cleanup: Cleanup, path: PathBuf) -> Registration {
    r.next += 1;
    let id = r.next;
    r.paths.push(Entry { id, cleanup, path });
    Registration { id }
}

/// Register `path` (which exists already) for the clean-up of a signal.
pub fn register(cleanup: Cleanup, path: &Path) -> Registration {
    hold().register(cleanup, path)
}

/// The registry held: while this lives no clean-up runs, and once a clean-up has begun
/// [`hold`] never returns (the clean-up keeps the lock until `_exit`). A file system change
/// made while holding it is therefore either seen by the clean-up or never made: make a
/// path and register it under one `Held`, never the one after the other.
pub struct Held(MutexGuard<'static, Registry>);

impl Held {
    /// Register `path` for the clean-up of a signal.
    pub fn register(&mut self, cleanup: Cleanup, path: &Path) -> Registration {
        add(&mut self.0, cleanup, absolute(path))
    }
}

/// Take the registry (see [`Held`]). Not reentrant: nothing called while it is held may
/// register or create a registered path itself.
pub fn hold() -> Held {
    Held(registry())
}

/// Create something with `create` and register the path `path_of` names, under the
/// registry's lock (see the module docs).
pub fn create_registered<T>(
    cleanup: Cleanup,
    create: impl FnOnce() -> io::Result<T>,
    path_of: impl FnOnce(&T) -> PathBuf,
) -> io::Result<(T, Registration)> {
    let mut held = hold();
    let made = create()?;
    let reg = held.register(cleanup, &path_of(&made));
    Ok((made, reg))
}

/// Spawn `cmd` as the leader of a new process group (so a Ctrl-C in the terminal reaches
/// cylaov only) and register the group: a signal to cylaov kills the whole group.
pub fn spawn_in_group(cmd: &mut Command) -> io::Result<(Child, Registration)> {
    use std::os::unix::process::CommandExt;
    cmd.process_group(0);
    let mut held = hold();
    let child = cmd.spawn()?;
    let r = &mut held.0;
    r.next += 1;
    let id = r.next;
    r.groups.push((id, child.id() as i32));
    Ok((child, Registration { id }))
}

/// The path made absolute against the current folder (the clean-up must not depend on it).
fn absolute(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// The exit status after signal `sig`: 128 + its number.
pub fn exit_status(sig: i32) -> i32 {
    128 + sig
}

/// The signals that stop a command cleanly.
#[cfg(target_os = "linux")]
const STOPPING: [(i32, &str); 3] = [
    (libc::SIGHUP, "SIGHUP"),
    (libc::SIGINT, "SIGINT"),
    (libc::SIGTERM, "SIGTERM"),
];

/// Ignore SIGXFSZ and route SIGINT, SIGTERM and SIGHUP to the clean-up thread (see the
/// module docs). Call it first in `main`, before any thread is started.
#[cfg(target_os = "linux")]
pub fn install() {
    crate::mem::set_cleanup(out_of_memory_cleanup);
    // SAFETY: plain libc calls on local, initialised signal sets; no handler is installed.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        for (sig, _) in STOPPING {
            let mut old: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(sig, std::ptr::null(), &mut old) == 0
                && old.sa_sigaction == libc::SIG_IGN
            {
                continue;
            }
            libc::sigaddset(&mut set, sig);
        }
        if libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut()) != 0 {
            return;
        }
        let waiter = std::thread::Builder::new()
            .name("signals".into())
            .spawn(move || {
                loop {
                    let mut sig = 0;
                    // SAFETY: sigwait reads the set and writes one int.
                    if libc::sigwait(&set, &mut sig) == 0 {
                        stop(sig);
                    }
                }
            });
        if waiter.is_err() {
            // No thread to take the signals: let them act as before.
            libc::pthread_sigmask(libc::SIG_UNBLOCK, &set, std::ptr::null_mut());
        }
    }
}

/// No signal handling off Linux.
#[cfg(not(target_os = "linux"))]
pub fn install() {}

/// Set by the clean-up thread once it has a signal, before it waits for the registry.
static CAUGHT: AtomicBool = AtomicBool::new(false);

/// Call last in `main`, before it returns: a signal the clean-up thread already has is
/// that thread's to finish (128 + its number). A signal that came while a commit held the
/// registry ([`hold`]) has the clean-up waiting for the lock the commit just let go; a
/// `main` returning at once would race it to the exit and could exit 0.
pub fn settle() {
    if CAUGHT.load(Ordering::SeqCst) {
        // The clean-up thread `_exit`s once it has the lock; wait for it.
        loop {
            std::thread::park();
        }
    }
}

/// Kill the children's groups, remove what is registered, say so, exit.
#[cfg(target_os = "linux")]
fn stop(sig: i32) -> ! {
    CAUGHT.store(true, Ordering::SeqCst);
    // Held until `_exit`: nothing is staged or spawned after this point.
    let r = registry();
    let removed = remove_all(&r);
    let name = STOPPING
        .iter()
        .find(|s| s.0 == sig)
        .map_or("a signal", |s| s.1);
    let lead = if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        "\n"
    } else {
        ""
    };
    crate::output::console::warn(&format!(
        "{lead}cylaov: stopped by {name}: {removed} unfinished files and folders removed \
         (exit {})",
        exit_status(sig)
    ));
    // SAFETY: ends the process without running destructors (other threads are mid-work).
    unsafe { libc::_exit(exit_status(sig)) }
}

/// The clean-up of a refused allocation ([`crate::mem::set_cleanup`]): the same removals
/// as a signal's, then the allocator's report exits. `try_lock`: the failing thread may be
/// the one holding the registry (it is staging a file), and must not wait for itself; then
/// nothing is removed.
fn out_of_memory_cleanup() -> usize {
    REGISTRY.try_lock().map_or(0, |r| remove_all(&r))
}

/// Kill the registered process groups, then remove the registered paths, newest first;
/// returns how many paths went.
fn remove_all(r: &Registry) -> usize {
    for &(_, pid) in &r.groups {
        // SAFETY: signals a process group this process made; waitpid reaps its leader,
        // our child, so its files are closed before its scratch folder goes.
        unsafe {
            libc::killpg(pid, libc::SIGKILL);
            let mut status = 0;
            libc::waitpid(pid, &mut status, 0);
        }
    }
    let mut removed = 0;
    for e in r.paths.iter().rev() {
        let gone = match e.cleanup {
            Cleanup::File => std::fs::remove_file(&e.path),
            Cleanup::Tree => std::fs::remove_dir_all(&e.path),
            Cleanup::EmptyDir => std::fs::remove_dir(&e.path),
            Cleanup::FreeLock => remove_free_lock(&e.path),
        };
        removed += gone.is_ok() as usize;
    }
    removed
}

/// Remove the lock file at `path` if no process holds its lock: taken here without
/// waiting (`flock` on a new open file description conflicts with every other holder,
/// this process's own included), so a lock in use is never removed.
#[cfg(target_os = "linux")]
fn remove_free_lock(path: &Path) -> io::Result<()> {
    use std::os::unix::io::AsRawFd;
    let mut opts = std::fs::OpenOptions::new();
    opts.read(true);
    crate::output::store::files::no_follow(&mut opts);
    let file = opts.open(path)?;
    if !file.metadata()?.is_file() {
        return Err(io::Error::other("not a regular file"));
    }
    // SAFETY: flock on a file descriptor `file` owns for the duration of the call.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
        return Err(io::Error::last_os_error());
    }
    std::fs::remove_file(path)
}

#[cfg(not(target_os = "linux"))]
fn remove_free_lock(_: &Path) -> io::Result<()> {
    Ok(())
}

// ---- stale temporary files -----------------------------------------------------------------

/// Whether process `pid` of this host is alive (`kill(pid, 0)`: only ESRCH says no).
#[cfg(target_os = "linux")]
fn alive(pid: i32) -> bool {
    // SAFETY: signal 0 only checks that the process exists.
    let rc = unsafe { libc::kill(pid, 0) };
    rc == 0 || io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

#[cfg(not(target_os = "linux"))]
fn alive(_pid: i32) -> bool {
    true
}

/// The pid in a temporary name of `host` (`.NAME.HOST.PID.XXXXXXXX.tmp`, see
/// `io::stage`), if `name` is one.
fn temp_pid(name: &str, host: &str, random: usize) -> Option<i32> {
    let rest = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let (rest, rand) = rest.rsplit_once('.')?;
    if rand.len() != random || !rand.chars().all(|c| c.is_ascii_alphanumeric()) {
        return None;
    }
    let (rest, pid) = rest.rsplit_once('.')?;
    if pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    rest.strip_suffix(host)?.strip_suffix('.')?;
    pid.parse().ok().filter(|&p| p > 0)
}

/// Remove the temporary files in `dir` that a process of `host` which no longer runs left
/// behind (killed with SIGKILL, or by a power cut). Files of other hosts (a shared file
/// system) and of live processes stay; so does anything that is not a regular file.
pub fn sweep_stale_temps(dir: &Path, host: &str, random: usize) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let me = std::process::id() as i32;
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(|n| temp_pid(n, host, random)) else {
            continue;
        };
        if pid != me && !alive(pid) && e.file_type().is_ok_and(|t| t.is_file()) {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// [`sweep_stale_temps`] once per folder per process: the first file staged in a folder
/// clears what dead runs left there.
pub fn sweep_once(dir: &Path, host: &str, random: usize) {
    use std::collections::HashSet;
    static SWEPT: Mutex<Option<HashSet<PathBuf>>> = Mutex::new(None);
    let key = absolute(dir);
    {
        let mut swept = SWEPT.lock().unwrap_or_else(|e| e.into_inner());
        if !swept.get_or_insert_with(HashSet::new).insert(key) {
            return;
        }
    }
    sweep_stale_temps(dir, host, random);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only names of this host's pattern give a pid; host names with dots and output
    /// names with dots parse from the right.
    #[test]
    fn temp_names_give_their_pid() {
        assert_eq!(
            temp_pid(".x.exr.node1.lan.123.Ab3dEf9h.tmp", "node1.lan", 8),
            Some(123)
        );
        assert_eq!(temp_pid(".x.exr.node2.123.Ab3dEf9h.tmp", "node1", 8), None);
        assert_eq!(temp_pid(".x.exr.node1.12a.Ab3dEf9h.tmp", "node1", 8), None);
        assert_eq!(temp_pid(".x.exr.node1.123.Ab3d.tmp", "node1", 8), None);
        assert_eq!(temp_pid("x.exr.node1.123.Ab3dEf9h.tmp", "node1", 8), None);
        assert_eq!(temp_pid(".node1.123.Ab3dEf9h.tmp", "node1", 8), None);
    }
}
