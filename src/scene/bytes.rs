//! A scene file's bytes, read without filling fresh memory when the file is large.
//!
//! Reading a file copies it from the page cache into memory the process has never touched,
//! which the kernel must first zero: for the 150 MB of a million-cylinder scene, zeroing
//! took about a fifth of the whole render (measured with `perf`). On Linux a large file is
//! instead mapped read-only, so the parser reads the page cache itself. Small files, and
//! any file the mapping fails for, are read as before.
//!
//! The mapping is private and read-only, so the process never writes the file. If another
//! process truncates the file while it is being parsed, touching the lost pages raises
//! SIGBUS (as for every program that maps its input); if it rewrites it, the parse may see
//! a mix of old and new text, which reads as some scene or fails as invalid JSON.

use std::fs::File;
use std::io::Read;

/// Files at least this long are mapped: below it, reading costs less than mapping.
const MAP_FROM: u64 = 1 << 20;

/// The bytes of one file.
pub enum FileBytes {
    /// Read into memory.
    Read(Vec<u8>),
    /// Mapped from the page cache.
    #[cfg(target_os = "linux")]
    Mapped(Mapping),
}

impl FileBytes {
    /// The contents of `file`, whose size was `len` when asked, reading at most `limit`
    /// bytes and one more (so a caller can tell a file that grew past `limit`).
    pub fn new(file: File, len: u64, limit: u64) -> std::io::Result<FileBytes> {
        #[cfg(target_os = "linux")]
        if (MAP_FROM..=limit).contains(&len)
            && let Some(m) = Mapping::new(&file, len as usize)
        {
            return Ok(FileBytes::Mapped(m));
        }
        // Bounded even when the size was wrong (files in /proc report 0).
        let mut bytes = Vec::with_capacity(len.min(limit) as usize);
        file.take(limit + 1).read_to_end(&mut bytes)?;
        Ok(FileBytes::Read(bytes))
    }

    /// The bytes.
    pub fn bytes(&self) -> &[u8] {
        match self {
            FileBytes::Read(v) => v,
            #[cfg(target_os = "linux")]
            FileBytes::Mapped(m) => m.bytes(),
        }
    }
}

/// A private read-only mapping of a whole file.
#[cfg(target_os = "linux")]
pub struct Mapping {
    ptr: std::ptr::NonNull<u8>,
    len: usize,
}

#[cfg(target_os = "linux")]
impl Mapping {
    /// Map the first `len` (> 0) bytes of `file`, its pages entered into the page table
    /// now (`MAP_POPULATE`: one call instead of a fault per 64 KiB in the parsing
    /// threads); `None` when the kernel refuses.
    fn new(file: &File, len: usize) -> Option<Mapping> {
        use std::os::fd::AsRawFd;
        // SAFETY: a new mapping at an address the kernel chooses, of an open file; it
        // aliases no Rust object, and the kernel checks the length and descriptor.
        let p = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ,
                libc::MAP_PRIVATE | libc::MAP_POPULATE,
                file.as_raw_fd(),
                0,
            )
        };
        if p == libc::MAP_FAILED {
            return None;
        }
        Some(Mapping {
            ptr: std::ptr::NonNull::new(p.cast())?,
            len,
        })
    }

    fn bytes(&self) -> &[u8] {
        // SAFETY: `ptr` is a live read-only mapping of `len` bytes (unmapped only in
        // `drop`), never written through; the module doc says what another process
        // changing the file does.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), self.len) }
    }
}

#[cfg(target_os = "linux")]
impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: the mapping made in `new`, unmapped once; no slice of it outlives
        // `self` (`bytes` borrows it).
        unsafe { libc::munmap(self.ptr.as_ptr().cast(), self.len) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file under the threshold is read, one over it mapped (on Linux), both giving the
    /// file's bytes; a mapped scene loads as its text parses, and one that is not UTF-8
    /// fails with the read path's message.
    #[test]
    fn large_files_are_mapped_and_read_the_same() {
        let dir = std::env::temp_dir().join(format!("cylaov-bytes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let sc = crate::bench::dense_scene(12_000, 3, 16, 16);
        let text = serde_json::to_string(&crate::scene::SceneFile::from_scene(&sc)).unwrap();
        assert!(text.len() as u64 > MAP_FROM, "{} bytes", text.len());
        let (big, small) = (dir.join("big.json"), dir.join("small.json"));
        std::fs::write(&big, &text).unwrap();
        std::fs::write(&small, &text.as_bytes()[..1000]).unwrap();
        for (path, mapped) in [(&big, cfg!(target_os = "linux")), (&small, false)] {
            let want = std::fs::read(path).unwrap();
            let len = want.len() as u64;
            let got = FileBytes::new(File::open(path).unwrap(), len, 1 << 30).unwrap();
            assert_eq!(matches!(got, FileBytes::Read(_)), !mapped);
            assert!(got.bytes() == want.as_slice());
        }
        assert_eq!(
            crate::scene::load(&big).unwrap(),
            crate::scene::parse(&text).unwrap()
        );
        let mut bad = text.into_bytes();
        let at = bad.len() - 100;
        bad[at] = 0xff;
        std::fs::write(&big, &bad).unwrap();
        let e = crate::scene::load(&big).unwrap_err();
        assert_eq!(e.to_string(), format!("not UTF-8 text (byte {at})"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
