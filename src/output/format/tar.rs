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

use std::io::{self, Read, Write};

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

/// The two zero blocks that close an archive (a member's padding is a part of one).
pub const CLOSING: [u8; 2 * BLOCK] = [0; 2 * BLOCK];

/// A member as it lies in an archive: its header block, its bytes, then zeros to a whole
/// block. Framing a member does not write it, so an archive can be laid out and hashed in
/// member order while the members are written at their offsets in any order.
pub struct Framed {
    header: [u8; BLOCK],
    pad: usize,
}

impl Framed {
    /// Frame member `name` whose bytes are `pieces` one after the other, or say why ustar
    /// cannot hold it.
    pub fn new(name: &str, pieces: &[&[u8]]) -> Result<Framed, String> {
        let len: usize = pieces.iter().map(|p| p.len()).sum();
        Ok(Framed {
            header: header(name, len as u64)?,
            pad: len.next_multiple_of(BLOCK) - len,
        })
    }

    /// The member's bytes in archive order (header, `pieces`, padding): `pieces` must be
    /// the ones it was framed with.
    pub fn bytes<'a>(
        &'a self,
        pieces: impl IntoIterator<Item = &'a [u8]>,
    ) -> impl Iterator<Item = &'a [u8]> {
        std::iter::once(&self.header[..])
            .chain(pieces)
            .chain(std::iter::once(&CLOSING[..self.pad]))
    }
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
        self.append_pieces(name, &[data])
    }

    /// [`TarWriter::append`] of the member whose bytes are `pieces` one after the other
    /// (a header and an array kept apart, written without joining them).
    pub fn append_pieces(&mut self, name: &str, pieces: &[&[u8]]) -> io::Result<()> {
        let framed = Framed::new(name, pieces)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        for b in framed.bytes(pieces.iter().copied()) {
            self.out.write_all(b)?;
            self.written += b.len() as u64;
        }
        Ok(())
    }

    /// Write the two closing zero blocks and return the writer and the archive's size.
    pub fn finish(mut self) -> io::Result<(W, u64)> {
        self.out.write_all(&CLOSING)?;
        self.written += CLOSING.len() as u64;
        self.out.flush()?;
        Ok((self.out, self.written))
    }
}

/// Reads the members of a ustar archive (the ones [`TarWriter`] writes) one at a time, so
/// a tar of a thousand views is never held whole. Only regular files are returned; other
/// entries are skipped.
pub struct TarReader<R: Read> {
    input: R,
}

impl<R: Read> TarReader<R> {
    /// A reader of the archive in `input`.
    pub fn new(input: R) -> Self {
        TarReader { input }
    }

    /// The next regular file's name (with its ustar prefix) and bytes; `None` at the
    /// closing zero block. A header whose checksum or size field does not parse is an
    /// `InvalidData` error (a truncated or foreign file), never a guess.
    pub fn next_member(&mut self) -> io::Result<Option<(String, Vec<u8>)>> {
        let bad = |what: String| io::Error::new(io::ErrorKind::InvalidData, what);
        loop {
            let mut h = [0u8; BLOCK];
            match self.input.read_exact(&mut h) {
                Ok(()) => {}
                // Every archive ends with zero blocks: one cut short, even at a member's
                // end, is not taken for a whole one.
                Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => {
                    return Err(bad(
                        "the archive ends without its closing zero blocks: cut short, or not a tar"
                            .into(),
                    ));
                }
                Err(e) => return Err(e),
            }
            if h.iter().all(|&b| b == 0) {
                return Ok(None);
            }
            let text = |r: std::ops::Range<usize>| {
                let f = &h[r];
                let end = f.iter().position(|&b| b == 0).unwrap_or(f.len());
                String::from_utf8_lossy(&f[..end]).into_owned()
            };
            let number = |r: std::ops::Range<usize>, what: &str| {
                let t = text(r);
                u64::from_str_radix(t.trim_matches(' '), 8)
                    .map_err(|_| bad(format!("a tar header's {what} field reads {t:?}")))
            };
            // The checksum: the byte sum with its own field read as spaces.
            let want = number(148..156, "checksum")?;
            let sum: u64 = h
                .iter()
                .enumerate()
                .map(|(i, &b)| {
                    if (148..156).contains(&i) {
                        32
                    } else {
                        b as u64
                    }
                })
                .sum();
            if sum != want {
                return Err(bad(format!(
                    "a tar header's checksum is {want}, its bytes sum to {sum}: not a tar, or damaged"
                )));
            }
            let size = number(124..136, "size")?;
            let name = match text(345..500) {
                p if !p.is_empty() && &h[257..262] == b"ustar" => format!("{p}/{}", text(0..100)),
                _ => text(0..100),
            };
            let mut data = Vec::new();
            (&mut self.input).take(size).read_to_end(&mut data)?;
            if (data.len() as u64) < size {
                return Err(bad(format!(
                    "tar member {name:?}: {} of its {size} bytes, the archive ends early",
                    data.len()
                )));
            }
            let pad = (size.next_multiple_of(BLOCK as u64) - size) as usize;
            self.input.read_exact(&mut [0u8; BLOCK][..pad])?;
            // '0' and NUL are regular files; directories, links and the rest are skipped.
            if h[156] == b'0' || h[156] == 0 {
                return Ok(Some((name, data)));
            }
        }
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

    /// The reader gives back what the writer wrote, long (prefixed) names included; a
    /// damaged header or a cut member is an error naming it, not a short read.
    #[test]
    fn reader_reads_what_the_writer_wrote() {
        let long = format!("{}/{}", "d".repeat(120), "f".repeat(90));
        let mut t = TarWriter::new(Vec::new());
        t.append("a.json", b"{}").unwrap();
        t.append(&long, &[7u8; 513]).unwrap();
        t.append("empty", b"").unwrap();
        let (bytes, _) = t.finish().unwrap();
        let mut r = TarReader::new(&bytes[..]);
        assert_eq!(
            r.next_member().unwrap(),
            Some(("a.json".into(), b"{}".to_vec()))
        );
        assert_eq!(r.next_member().unwrap(), Some((long, vec![7u8; 513])));
        assert_eq!(r.next_member().unwrap(), Some(("empty".into(), Vec::new())));
        assert_eq!(r.next_member().unwrap(), None);
        let mut damaged = bytes.clone();
        damaged[0] = b'b';
        let e = TarReader::new(&damaged[..]).next_member().unwrap_err();
        assert!(e.to_string().contains("checksum"), "{e}");
        // Cut after the first member: that member, then an error, not the end.
        let mut r = TarReader::new(&bytes[..512 * 2]);
        assert!(r.next_member().unwrap().is_some());
        let e = r.next_member().unwrap_err();
        assert!(e.to_string().contains("closing zero blocks"), "{e}");
        let cut = &bytes[..512 * 3 + 100];
        let mut r = TarReader::new(cut);
        r.next_member().unwrap();
        let e = r.next_member().unwrap_err();
        assert!(e.to_string().contains("100 of its 513 bytes"), "{e}");
    }

    /// A member appended in pieces is the member appended whole, byte for byte, however
    /// the pieces fall against the 512-byte blocks.
    #[test]
    fn pieces_make_the_member_they_join_into() {
        let data: Vec<u8> = (0..1500u32).map(|i| (i * 7 % 251) as u8).collect();
        for cut in [0, 1, 128, 511, 512, 513, 1024, 1499, 1500] {
            let mut whole = TarWriter::new(Vec::new());
            whole.append("k.depth.npy", &data).unwrap();
            let mut pieces = TarWriter::new(Vec::new());
            let (a, b) = data.split_at(cut);
            pieces.append_pieces("k.depth.npy", &[a, b]).unwrap();
            assert_eq!(
                pieces.finish().unwrap(),
                whole.finish().unwrap(),
                "cut at {cut}"
            );
        }
    }
}
