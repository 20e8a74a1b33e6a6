//! A POSIX ustar writer whose bytes are a pure function of the members: the tar shards of
//! `batch --format webdataset`.
//!
//! Every member is a regular file with mode 0644, uid and gid 0, owner and group `cylaov`,
//! mtime 0, in the order it is appended; each header and each member's data fill whole
//! 512-byte blocks, and the archive ends with two zero blocks. Names up to 100 bytes go in
//! the name field; a longer name with a `/` is split into the 155-byte prefix and the name
//! (ustar's rule); anything else, or a non-ASCII name, is refused rather than written in
//! an extension other readers may not share. Written here rather than with the `tar` crate:
//! the format is a few fields of fixed width, and owning them means no builder default
//! (mtime, owner, GNU or PAX headers) can change a shard's bytes.

use std::io::{self, Write};

/// Bytes of a tar block.
pub const BLOCK: usize = 512;

/// Owner and group name of every member.
const OWNER: &[u8] = b"cylaov";

/// The largest member the 11 octal digits of the size field hold (8 GiB - 1).
const MAX_SIZE: u64 = (1 << 33) - 1;

/// Bytes an archive of members of these sizes takes: a header block per member, the data
/// rounded up to whole blocks, and the two closing zero blocks.
pub fn archive_size(member_sizes: impl IntoIterator<Item = u64>) -> u64 {
    let blocks: u64 = member_sizes
        .into_iter()
        .map(|s| 1 + s.div_ceil(BLOCK as u64))
        .sum();
    (blocks + 2) * BLOCK as u64
}

/// Split `name` into ustar's (prefix, name) fields, or say why it cannot be stored.
fn split_name(name: &str) -> Result<(&str, &str), String> {
    if name.is_empty() || !name.is_ascii() || name.contains('\0') {
        return Err(format!(
            "tar member name must be non-empty ASCII without NUL, got {name:?}"
        ));
    }
    if name.len() <= 100 {
        return Ok(("", name));
    }
    // The prefix ends at a '/', which is not stored: prefix <= 155 bytes, rest <= 100.
    name.match_indices('/')
        .map(|(at, _)| (&name[..at], &name[at + 1..]))
        .find(|(p, n)| p.len() <= 155 && !n.is_empty() && n.len() <= 100)
        .ok_or_else(|| {
            format!(
                "tar member name is too long for ustar ({} bytes; at most 100, or 255 split \
                 at a '/'): {name:?}",
                name.len()
            )
        })
}

/// `value` in octal, zero-padded to `field.len() - 1` digits, then NUL.
fn octal(field: &mut [u8], value: u64) {
    let digits = field.len() - 1;
    let text = format!("{value:0digits$o}");
    field[..digits].copy_from_slice(text.as_bytes());
    field[digits] = 0;
}

/// The header block of a regular file `name` of `size` bytes.
pub fn header(name: &str, size: u64) -> Result<[u8; BLOCK], String> {
    let (prefix, rest) = split_name(name)?;
    if size > MAX_SIZE {
        return Err(format!(
            "tar member {name:?}: {size} bytes, more than ustar holds ({MAX_SIZE})"
        ));
    }
    let mut h = [0u8; BLOCK];
    h[..rest.len()].copy_from_slice(rest.as_bytes());
    octal(&mut h[100..108], 0o644);
    octal(&mut h[108..116], 0);
    octal(&mut h[116..124], 0);
    octal(&mut h[124..136], size);
    octal(&mut h[136..148], 0);
    h[156] = b'0';
    h[257..263].copy_from_slice(b"ustar\0");
    h[263..265].copy_from_slice(b"00");
    h[265..265 + OWNER.len()].copy_from_slice(OWNER);
    h[297..297 + OWNER.len()].copy_from_slice(OWNER);
    octal(&mut h[329..337], 0);
    octal(&mut h[337..345], 0);
    h[345..345 + prefix.len()].copy_from_slice(prefix.as_bytes());
    // The checksum is the byte sum with its own field read as spaces: six octal digits,
    // NUL, space.
    h[148..156].fill(b' ');
    let sum: u32 = h.iter().map(|&b| b as u32).sum();
    octal(&mut h[148..155], sum as u64);
    h[155] = b' ';
    Ok(h)
}

/// Appends members to a ustar archive in `W`.
pub struct TarWriter<W: Write> {
    out: W,
    written: u64,
}

impl<W: Write> TarWriter<W> {
    /// An empty archive writing into `out`.
    pub fn new(out: W) -> Self {
        TarWriter { out, written: 0 }
    }

    /// Append the regular file `name` holding `data`. A name ustar cannot hold is an
    /// `InvalidInput` error and nothing is written.
    pub fn append(&mut self, name: &str, data: &[u8]) -> io::Result<()> {
        let h = header(name, data.len() as u64)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        self.out.write_all(&h)?;
        self.out.write_all(data)?;
        let pad = data.len().next_multiple_of(BLOCK) - data.len();
        self.out.write_all(&[0u8; BLOCK][..pad])?;
        self.written += (BLOCK + data.len() + pad) as u64;
        Ok(())
    }

    /// Write the two closing zero blocks and return the writer and the archive's size.
    pub fn finish(mut self) -> io::Result<(W, u64)> {
        self.out.write_all(&[0u8; 2 * BLOCK])?;
        self.written += 2 * BLOCK as u64;
        self.out.flush()?;
        Ok((self.out, self.written))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(h: &[u8], range: std::ops::Range<usize>) -> String {
        String::from_utf8_lossy(&h[range])
            .trim_end_matches('\0')
            .to_string()
    }

    /// The fields a reader checks, at their ustar offsets, and a checksum that a reader's
    /// own sum (the field as spaces) reproduces.
    #[test]
    fn header_fields_and_checksum() {
        let h = header("000123.depth.npy", 1000).unwrap();
        assert_eq!(field(&h, 0..100), "000123.depth.npy");
        assert_eq!(field(&h, 100..108), "0000644");
        assert_eq!(field(&h, 124..136), "00000001750");
        assert_eq!(field(&h, 136..148), "00000000000");
        assert_eq!(h[156], b'0');
        assert_eq!(&h[257..265], b"ustar\x0000");
        assert_eq!(field(&h, 265..297), "cylaov");
        let mut spaced = h;
        spaced[148..156].fill(b' ');
        let sum: u32 = spaced.iter().map(|&b| b as u32).sum();
        let stored = u32::from_str_radix(&field(&h, 148..154), 8).unwrap();
        assert_eq!(stored, sum);
        assert_eq!(&h[154..156], b"\0 ");
    }

    /// Data padded to whole blocks, two zero blocks at the end, the size `archive_size`
    /// predicts, and the same bytes on a second write.
    #[test]
    fn archive_layout_is_fixed() {
        let write = || {
            let mut t = TarWriter::new(Vec::new());
            t.append("a.json", b"{}").unwrap();
            t.append("a.bin", &[7u8; 513]).unwrap();
            t.finish().unwrap()
        };
        let (bytes, size) = write();
        assert_eq!(size as usize, bytes.len());
        assert_eq!(bytes.len(), 512 + 512 + 512 + 1024 + 1024);
        assert_eq!(archive_size([2, 513]), bytes.len() as u64);
        assert_eq!(&bytes[512..514], b"{}");
        assert!(bytes[514..1024].iter().all(|&b| b == 0));
        assert!(bytes[bytes.len() - 1024..].iter().all(|&b| b == 0));
        assert_eq!(write().0, bytes);
    }

    /// A long name is split at a '/' into the prefix field; one that cannot be split, or
    /// is not ASCII, is refused with its length and nothing is written.
    #[test]
    fn long_names_split_or_refused() {
        let long = format!("{}/{}", "d".repeat(120), "f".repeat(90));
        let h = header(&long, 0).unwrap();
        assert_eq!(field(&h, 0..100), "f".repeat(90));
        assert_eq!(field(&h, 345..500), "d".repeat(120));
        let e = header(&"x".repeat(101), 0).unwrap_err();
        assert!(e.contains("101 bytes"), "{e}");
        assert!(header("é.npy", 0).is_err());
        let mut t = TarWriter::new(Vec::new());
        assert!(t.append(&"x".repeat(101), b"").is_err());
        assert!(t.finish().unwrap().0.len() == 1024);
    }
}
