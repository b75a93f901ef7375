//! CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320), the payload checksum of weight blobs.
//! Four bits at a time: the 64-byte table is built at compile time and lives in flash (a
//! byte-wise table would be 1 KiB of a microcontroller's flash for twice the speed, which
//! only the checks at start-up would see).

const fn make_table() -> [u32; 16] {
    let mut t = [0u32; 16];
    let mut i = 0;
    while i < 16 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 4 {
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

static TABLE: [u32; 16] = make_table();

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
        c = TABLE[((c ^ b as u32) & 0xF) as usize] ^ (c >> 4);
        c = TABLE[((c ^ (b as u32 >> 4)) & 0xF) as usize] ^ (c >> 4);
    }
    !c
}

#[cfg(test)]
mod tests {
    /// The bit-by-bit definition, on bytes of every value.
    #[test]
    fn table_form_is_the_bitwise_definition() {
        let data: [u8; 512] = core::array::from_fn(|i| (i * 97 % 256) as u8 ^ (i / 256) as u8);
        let mut c = !0u32;
        for &b in &data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        assert_eq!(super::crc32(&data), !c);
    }

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
