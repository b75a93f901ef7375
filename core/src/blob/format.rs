//! The format's constants (magic, versions) and the quantisation of a stored tensor.

use serde::{Serialize, Serializer};

#[cfg(doc)]
use crate::spec::AdaptSettings;

/// The four magic bytes at the start of every blob.
pub const MAGIC: [u8; 4] = *b"GMAN";
/// The format version this build writes (v5: the header names its settings, the CRC covers
/// the header and the payload).
pub const FORMAT_VERSION: u16 = 5;
/// The oldest format version this build still reads (v1: no inner-loop settings in the
/// header; they default to [`AdaptSettings::PAPER`]).
pub const MIN_FORMAT_VERSION: u16 = 1;
/// Bytes reserved for the header while encoding (the real header is shorter: at most 98
/// bytes for v3, about 410 for v5 with every setting at its longest).
pub(super) const HEADER_RESERVE: usize = 512;

/// Quantisation of a stored tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quant {
    /// Little-endian f32.
    F32,
    /// int8 with one f32 scale per row.
    I8,
}

impl Quant {
    pub(super) fn code(self) -> u8 {
        match self {
            Quant::F32 => 0,
            Quant::I8 => 1,
        }
    }
}

/// Bytes serialised as postcard's `serialize_bytes` writes them (varint length, raw bytes).
pub(super) struct RawBytes<'a>(pub(super) &'a [u8]);
impl Serialize for RawBytes<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bytes(self.0)
    }
}
