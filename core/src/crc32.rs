//! CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320), the payload checksum of weight blobs.
//! The 1 KiB table is built at compile time and lives in flash.

const fn make_table() -> [u32; 256] {
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
}

static TABLE: [u32; 256] = make_table();

/// CRC-32 of `data` (the common zlib/PNG CRC; `crc32(b"123456789") == 0xCBF43926`).
pub fn crc32(data: &[u8]) -> u32 {
    crc32_update(0, data)
}

/// Continues a CRC-32 over more bytes: `crc32_update(crc32(a), b) == crc32(a ++ b)` (zlib's
/// `crc32(crc, buf, len)` convention; start from 0). For data read in pieces, e.g. a file
/// streamed from a host.
pub fn crc32_update(crc: u32, data: &[u8]) -> u32 {
    let mut c = !crc;
    for &b in data {
        c = TABLE[((c ^ b as u32) & 0xFF) as usize] ^ (c >> 8);
    }
    !c
}

#[cfg(test)]
mod tests {
    #[test]
    fn check_value() {
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(super::crc32(b""), 0);
        let whole = super::crc32(b"123456789");
        for cut in 0..=9 {
            let (a, b) = b"123456789".split_at(cut);
            assert_eq!(
                super::crc32_update(super::crc32(a), b),
                whole,
                "cut at {cut}"
            );
        }
    }
}
