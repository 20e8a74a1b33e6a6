//! A tar's temporary file, written one view at a time by whichever worker holds the pen.
//!
//! Views are laid out (and hashed) in order elsewhere; each is then written at its offset
//! by a positional write. Two positional writes to one file do not run side by side: the
//! kernel holds the file's lock for each buffered write, and a second writer spins on it
//! while the first copies (7.7% of the tar path's samples on 2 cores, measured with perf).
//! So a worker that finds the pen taken hands its view over and goes back to rendering;
//! the holder writes it after its own. At most one view waits: a worker that finds one
//! waiting already sleeps until the holder takes it, so what waits stays within one view
//! a tar whatever the disk's speed.

use super::Members;
use crate::output::format::tar;
use anyhow::{Context, Result, anyhow};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Condvar, Mutex, MutexGuard};

/// Pieces shorter than this are gathered into one write (headers, padding, JSON); longer
/// ones (the arrays) are written from where they lie.
const GATHER: usize = 64 << 10;

/// A view's members framed for its tar, to be written at `at`.
pub(super) struct ViewBytes {
    /// Its offset in the tar.
    at: u64,
    /// Its members, in order.
    members: Members,
    /// Each member's header and padding, in the same order.
    framed: Vec<tar::Framed>,
}

impl ViewBytes {
    /// Frame `members` to be written at `at`, or say why ustar cannot hold one (naming
    /// `tmp`, the tar).
    pub fn new(at: u64, members: Members, tmp: &Path) -> Result<ViewBytes> {
        let framed = members
            .iter()
            .map(|(name, bytes)| {
                tar::Framed::new(name, &bytes.pieces())
                    .map_err(|e| anyhow!(e))
                    .with_context(|| format!("writing {}", tmp.display()))
            })
            .collect::<Result<_>>()?;
        Ok(ViewBytes {
            at,
            members,
            framed,
        })
    }

    /// The view's bytes in archive order, from `at` on.
    pub fn pieces(&self) -> impl Iterator<Item = &[u8]> {
        self.framed
            .iter()
            .zip(&self.members)
            .flat_map(|(f, (_, bytes))| f.bytes(bytes.pieces()))
    }
}

/// A tar file being written under its work folder (see the module docs).
pub(super) struct TarFile {
    file: File,
    tmp: PathBuf,
    pen: Mutex<Pen>,
    /// Signalled when the waiting view is taken or the pen is put down.
    taken: Condvar,
}

/// Who writes, and what waits for them.
#[derive(Default)]
struct Pen {
    held: bool,
    waiting: Option<ViewBytes>,
}

impl TarFile {
    /// Write into `file`, the temporary tar at `tmp` (named in errors).
    pub fn new(file: File, tmp: PathBuf) -> TarFile {
        TarFile {
            file,
            tmp,
            pen: Mutex::new(Pen::default()),
            taken: Condvar::new(),
        }
    }

    /// The temporary tar's path.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Write `view` at its offset, now or by the worker writing already (see the module
    /// docs). Every view handed over is written before the holder returns, so once every
    /// caller has returned `Ok`, every view is in the file; an error leaves the file
    /// incomplete (the tar is not committed).
    pub fn write(&self, view: ViewBytes) -> Result<()> {
        let mut pen = self.lock();
        while pen.held && pen.waiting.is_some() {
            pen = self.taken.wait(pen).unwrap_or_else(|e| e.into_inner());
        }
        if pen.held {
            pen.waiting = Some(view);
            return Ok(());
        }
        pen.held = true;
        drop(pen);
        // Put the pen down however this ends (an error, a panic), waking the sleepers;
        // a view left waiting by an error is dropped with the failed tar.
        let mut down = PutDown {
            tar: self,
            armed: true,
        };
        let mut next = view;
        loop {
            self.write_view(&next)?;
            drop(next);
            let mut pen = self.lock();
            match pen.waiting.take() {
                Some(v) => {
                    drop(pen);
                    self.taken.notify_all();
                    next = v;
                }
                None => {
                    // Down under the same lock that found nothing waiting: a view handed
                    // over after this finds the pen free and writes itself.
                    pen.held = false;
                    down.armed = false;
                    return Ok(());
                }
            }
        }
    }

    /// Write one view's bytes at its offset, small pieces gathered into one write.
    fn write_view(&self, view: &ViewBytes) -> Result<()> {
        let mut at = view.at;
        let mut gathered: Vec<u8> = Vec::new();
        let mut gathered_at = at;
        let write = |bytes: &[u8], to: u64| {
            self.file
                .write_all_at(bytes, to)
                .map_err(crate::output::store::atomic::explain)
                .with_context(|| format!("writing {}", self.tmp.display()))
        };
        for b in view.pieces() {
            if b.len() < GATHER {
                if gathered.is_empty() {
                    gathered_at = at;
                }
                gathered.extend_from_slice(b);
            } else {
                if !gathered.is_empty() {
                    write(&gathered, gathered_at)?;
                    gathered.clear();
                }
                write(b, at)?;
            }
            at += b.len() as u64;
        }
        if !gathered.is_empty() {
            write(&gathered, gathered_at)?;
        }
        Ok(())
    }

    /// Write the archive's closing blocks at `at`, after every view's write returned.
    pub fn close(&self, at: u64) -> Result<()> {
        self.file
            .write_all_at(&tar::CLOSING, at)
            .map_err(crate::output::store::atomic::explain)
            .with_context(|| format!("writing {}", self.tmp.display()))
    }

    fn lock(&self) -> MutexGuard<'_, Pen> {
        self.pen.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Puts the pen down when dropped armed (a write failed or panicked).
struct PutDown<'a> {
    tar: &'a TarFile,
    armed: bool,
}

impl Drop for PutDown<'_> {
    fn drop(&mut self) {
        if self.armed {
            let mut pen = self.tar.lock();
            pen.held = false;
            pen.waiting = None;
            drop(pen);
            self.tar.taken.notify_all();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::batch::shards::MemberBytes;
    use crate::rng::SplitMix64;
    use std::sync::Arc;

    /// Views laid out one after another, some with arrays past [`GATHER`] (written from
    /// where they lie) and some small (gathered), and the archive they make in order.
    fn views(n: usize, seed: u64) -> (Vec<ViewBytes>, Vec<u8>) {
        let mut rng = SplitMix64::new(seed);
        let mut at = 0u64;
        let mut whole = Vec::new();
        let views = (0..n)
            .map(|k| {
                let members: Members = (0..3)
                    .map(|m| {
                        let len = (rng.next_u64() % (3 * GATHER as u64 / 2)) as usize;
                        let bytes = (0..len).map(|_| rng.next_u64() as u8).collect();
                        (format!("{k:06}.m{m}"), MemberBytes::Whole(bytes))
                    })
                    .collect();
                let view = ViewBytes::new(at, members, Path::new("t.tar")).expect("short names");
                for p in view.pieces() {
                    whole.extend_from_slice(p);
                    at += p.len() as u64;
                }
                view
            })
            .collect();
        (views, whole)
    }

    /// Many workers writing at once, each its own views in a shuffled order: the file is
    /// the archive laid out in order, every view handed over written by the holder.
    #[test]
    fn views_written_at_once_make_the_archive_as_laid_out() {
        for (threads, seed) in [(2, 1), (4, 2), (8, 3)] {
            let dir = tempfile::tempdir().expect("a temp dir");
            let path = dir.path().join("t.tar");
            let file = File::create(&path).expect("a file");
            let tar = Arc::new(TarFile::new(file, path.clone()));
            let (views, whole) = views(60, seed);
            let mut shares: Vec<Vec<ViewBytes>> = (0..threads).map(|_| Vec::new()).collect();
            for (k, v) in views.into_iter().rev().enumerate() {
                shares[k % threads].push(v);
            }
            std::thread::scope(|s| {
                for share in shares {
                    let tar = tar.clone();
                    s.spawn(move || {
                        for v in share {
                            tar.write(v).expect("writes");
                        }
                    });
                }
            });
            tar.close(whole.len() as u64).expect("closes");
            let mut expected = whole;
            expected.extend_from_slice(&tar::CLOSING);
            let got = std::fs::read(&path).expect("reads back");
            assert_eq!(got.len(), expected.len(), "{threads} threads");
            assert!(got == expected, "{threads} threads: the bytes differ");
        }
    }

    /// A view handed over while the pen is held is written by the holder before it
    /// returns: the holder is held inside its write until the view is waiting.
    #[test]
    fn a_view_handed_over_is_written_by_the_holder() {
        let dir = tempfile::tempdir().expect("a temp dir");
        let path = dir.path().join("t.tar");
        let file = File::create(&path).expect("a file");
        let tar = TarFile::new(file, path.clone());
        let (mut views, whole) = views(2, 9);
        let second = views.pop().expect("two views");
        let first = views.pop().expect("two views");
        // Take the pen by hand, hand the second view over, then write the first as the
        // holder would: the second must follow.
        tar.lock().held = true;
        tar.write(second).expect("handed over");
        assert!(
            tar.lock().waiting.is_some(),
            "the view waits for the holder"
        );
        tar.lock().held = false;
        tar.write(first).expect("writes both");
        let pen = tar.lock();
        assert!(
            !pen.held && pen.waiting.is_none(),
            "the pen is put down, nothing waits"
        );
        drop(pen);
        let got = std::fs::read(&path).expect("reads back");
        assert!(got == whole, "both views in place");
    }
}
