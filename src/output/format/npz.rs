//! NumPy `.npz`: a zip archive of `.npy` members, each stored (not compressed), which
//! `numpy.load` reads as a dict of arrays. The writer is the smallest zip a reader
//! accepts (APPNOTE 6.3.x): per member a local header, the data, and at the end the
//! central directory and its end record; no zip64, so the archive and each member stay
//! below 4 GiB (refused above, naming the member), and at most 65 535 members.

/// CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320) of `bytes`, as zip stores it,
/// table-driven one byte at a time.
pub fn crc32(bytes: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut t = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
                k += 1;
            }
            t[i] = c;
            i += 1;
        }
        t
    };
    !bytes.iter().fold(!0u32, |c, &b| {
        TABLE[((c ^ b as u32) & 0xFF) as usize] ^ (c >> 8)
    })
}

/// The zip of `members` (`(name, bytes)`, names ASCII without `/` at the start), stored,
/// with the DOS date 1980-01-01 00:00 on every member so the same arrays give the same bytes.
pub fn zip_stored(members: &[(String, Vec<u8>)]) -> Result<Vec<u8>, String> {
    let limit = u32::MAX as usize;
    if members.len() > u16::MAX as usize {
        return Err(format!(
            "{} members is more than a zip holds",
            members.len()
        ));
    }
    let mut out = Vec::new();
    let mut central = Vec::new();
    // Version 2.0 needed; no flags; method 0 (stored); time 0; date 1980-01-01 (day 1,
    // month 1: (0 << 9) | (1 << 5) | 1).
    let fixed = |out: &mut Vec<u8>, crc: u32, size: u32, name: &str| {
        out.extend_from_slice(&20u16.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&0x21u16.to_le_bytes());
        out.extend_from_slice(&crc.to_le_bytes());
        out.extend_from_slice(&size.to_le_bytes());
        out.extend_from_slice(&size.to_le_bytes());
        out.extend_from_slice(&(name.len() as u16).to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
    };
    for (name, data) in members {
        let offset = out.len();
        if data.len() > limit || offset > limit || name.len() > u16::MAX as usize {
            return Err(format!("{name}: too large for a zip without zip64 (4 GiB)"));
        }
        let crc = crc32(data);
        out.extend_from_slice(&0x0403_4b50u32.to_le_bytes());
        fixed(&mut out, crc, data.len() as u32, name);
        out.extend_from_slice(name.as_bytes());
        out.extend_from_slice(data);
        central.extend_from_slice(&0x0201_4b50u32.to_le_bytes());
        central.extend_from_slice(&20u16.to_le_bytes()); // made by: 2.0, MS-DOS
        fixed(&mut central, crc, data.len() as u32, name);
        // Comment length, disk number, internal and external attributes, local offset.
        central.extend_from_slice(&[0; 10]);
        central.extend_from_slice(&(offset as u32).to_le_bytes());
        central.extend_from_slice(name.as_bytes());
    }
    let (cd_at, cd_len) = (out.len(), central.len());
    if cd_at + cd_len > limit {
        return Err("the archive is too large for a zip without zip64 (4 GiB)".to_string());
    }
    out.extend_from_slice(&central);
    let n = (members.len() as u16).to_le_bytes();
    out.extend_from_slice(&0x0605_4b50u32.to_le_bytes());
    out.extend_from_slice(&[0; 4]); // this disk, the directory's disk
    out.extend_from_slice(&n);
    out.extend_from_slice(&n);
    out.extend_from_slice(&(cd_len as u32).to_le_bytes());
    out.extend_from_slice(&(cd_at as u32).to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes()); // comment length
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_of_the_check_string() {
        // The CRC-32 catalogue's check value for "123456789".
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn archive_layout() {
        let z = zip_stored(&[("a.npy".into(), vec![1, 2, 3])]).unwrap();
        // Local header 30 + name 5 + data 3, central 46 + 5, end 22.
        assert_eq!(z.len(), 30 + 5 + 3 + 46 + 5 + 22);
        assert_eq!(&z[..4], b"PK\x03\x04");
        assert_eq!(&z[z.len() - 22..z.len() - 18], b"PK\x05\x06");
    }
}
