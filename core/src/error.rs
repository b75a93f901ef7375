//! Typed errors of the core.
//!
//! Every fallible operation returns one of these; nothing in the crate panics on bad input.
//! The variants are small `Copy` values so they can travel through a robot controller's
//! error handling without allocation.

use core::fmt;

use crate::spec::setting_key::SettingKey;

/// Which buffer or tensor had the wrong length.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShapeError {
    /// A short, static name of the argument (e.g. `"linear.x"`).
    pub what: &'static str,
    /// The length the operation needed.
    pub expected: usize,
    /// The length it was given.
    pub actual: usize,
}

/// Every error the core can return.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// A caller-provided buffer or a tensor has the wrong length.
    Shape(ShapeError),
    /// An input (observation, attribute vector, PS vector) holds NaN or infinity.
    NonFiniteInput {
        /// Which input.
        what: &'static str,
    },
    /// A weight blob could not be used; see [`BlobError`].
    Blob(BlobError),
    /// A computation produced NaN or infinity although its inputs were finite (e.g. from
    /// diverged adapted parameters); no action is returned from it.
    NumericalFault {
        /// Which quantity.
        what: &'static str,
    },
    /// A configuration value is out of range (e.g. a zero buffer capacity), or a call was
    /// made out of order (e.g. `step` before `reset`).
    Config {
        /// What is wrong, in a few words.
        what: &'static str,
    },
    /// The step would reach the commit point of a pending inner update
    /// ([commit delay](crate::spec::InnerRule::commit_delay) steps after Ψ
    /// filled) before the update is complete: with
    /// [`Schedule::Background`](crate::navigator::Schedule::Background) the caller's
    /// lower-priority context has not yet run all of
    /// [`Navigator::adapt_slice`](crate::navigator::Navigator::adapt_slice). Nothing was
    /// changed: run the remaining slices, then the same step again.
    UpdateNotReady {
        /// Slices of the update still to run.
        slices_left: u32,
    },
}

/// The first bytes of a word found in a blob (a setting's key or a value's name), kept
/// without allocation so that an error can name it: up to [`SettingText::CAP`] bytes, any
/// byte outside printable ASCII shown as `?`, a longer word ending in `...`.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct SettingText {
    bytes: [u8; SettingText::CAP],
    /// The word's length (saturating): more than `CAP` when it was cut.
    len: u8,
}

impl SettingText {
    /// Bytes kept (16 with the length: an error holding one stays as small as the others).
    pub const CAP: usize = 15;

    /// The first bytes of `s`.
    #[inline(never)]
    pub fn new(s: &[u8]) -> SettingText {
        let mut bytes = [b'?'; SettingText::CAP];
        for (d, &b) in bytes.iter_mut().zip(s) {
            if b.is_ascii_graphic() {
                *d = b;
            }
        }
        SettingText {
            bytes,
            len: s.len().min(255) as u8,
        }
    }

    /// The kept bytes (printable ASCII).
    pub fn as_str(&self) -> &str {
        let n = usize::from(self.len).min(SettingText::CAP);
        core::str::from_utf8(&self.bytes[..n]).unwrap_or("?")
    }
}

impl fmt::Display for SettingText {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())?;
        if usize::from(self.len) > SettingText::CAP {
            f.write_str("...")?;
        }
        Ok(())
    }
}

impl fmt::Debug for SettingText {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

/// Why a weight blob was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlobError {
    /// The blob ended before the header or a tensor record was complete.
    Truncated,
    /// The first bytes are not the GMAN magic.
    BadMagic,
    /// The format version is not one this build reads.
    UnsupportedVersion {
        /// The version found in the blob.
        found: u16,
    },
    /// A format v1-v4 blob given to a build without gman-core's `legacy-blobs` feature (a
    /// device image that reads only the current format).
    LegacyFormat {
        /// The version found in the blob.
        found: u16,
    },
    /// The header's payload length does not match the bytes present.
    PayloadLength {
        /// Length announced by the header.
        expected: u32,
        /// Bytes actually following the header.
        actual: usize,
    },
    /// The CRC-32 of the payload does not match the header.
    ChecksumMismatch {
        /// Checksum announced by the header.
        expected: u32,
        /// Checksum of the payload as found.
        actual: u32,
    },
    /// The blob was made for other network sizes than the model loading it.
    DimensionMismatch {
        /// Name of the first differing dimension.
        field: &'static str,
        /// The model's value.
        expected: u32,
        /// The blob's value.
        found: u32,
    },
    /// A tensor id this build does not know.
    UnknownTensor {
        /// The raw id.
        id: u16,
    },
    /// The same tensor appears twice.
    DuplicateTensor {
        /// The raw id.
        id: u16,
    },
    /// A tensor the model needs is absent.
    MissingTensor {
        /// The raw id.
        id: u16,
    },
    /// A tensor's rows/cols differ from what the dimensions imply, or its byte length
    /// does not match rows x cols for its quantisation.
    BadTensorShape {
        /// The raw id.
        id: u16,
    },
    /// A quantisation code that is unknown, or not allowed for this tensor (biases are f32).
    BadQuantization {
        /// The raw id.
        id: u16,
    },
    /// An int8 row scale is NaN, infinite or negative.
    NonFiniteScale {
        /// The raw id.
        id: u16,
    },
    /// An f32 weight is NaN or infinite.
    NonFiniteWeight {
        /// The raw id.
        id: u16,
    },
    /// An inner-loop rate in the header (format v2) is NaN, infinite or negative; the
    /// encoder refuses such settings too (see [`crate::blob::AdaptSettings`]).
    BadInnerRate {
        /// Which rate: `"alpha_disc"` (α1, D's ascent) or `"alpha_adapt"` (α2, θ/φ's
        /// descent).
        field: &'static str,
        /// Its value as `f32::to_bits` (bits keep the error `Eq`; `f32::from_bits` gives the
        /// value back).
        bits: u32,
    },
    /// The header's dims are so large that a size derived from them (a parameter count, a
    /// tensor's bytes, the navigator's RAM) does not fit in `usize`; see
    /// [`Dims::checked_sizes`](crate::Dims::checked_sizes).
    DimsTooLarge,
    /// A width the networks need is zero, or the map's dims are inconsistent (see
    /// [`Dims::degenerate_field`](crate::Dims::degenerate_field)).
    DegenerateDims {
        /// The first degenerate field (`"disc_hidden"`, `"map_cols"`, ...).
        field: &'static str,
    },
    /// The header's checksum (format v4: CRC-32 of the header's other bytes and the
    /// payload) does not match: some byte of the header or the payload changed.
    HeaderChecksumMismatch {
        /// Checksum announced by the header.
        expected: u32,
        /// Checksum of the bytes as found.
        actual: u32,
    },
    /// The blob's format (v1-v3) checksums the payload only, not the header, and the parse
    /// asked for a header-covering format
    /// ([`ParseOptions::require_header_crc`](crate::blob::ParseOptions::require_header_crc)).
    HeaderNotCovered {
        /// The version found in the blob.
        found: u16,
    },
    /// A format v4 blob (or a blob being encoded) sets a flag bit this build does not know
    /// ([`crate::spec::schema::KNOWN_FLAGS`]): a setting of a newer build, which this one would
    /// run as if it were off.
    UnknownFlagBit {
        /// The lowest unknown bit (0-31).
        bit: u8,
        /// All of the header's flags.
        flags: u32,
    },
    /// A format v5 header names a setting this build does not know: a setting of a newer
    /// build, which this one would run as if it were at its default.
    UnknownSetting {
        /// The key as found (its first bytes).
        key: SettingText,
    },
    /// A format v5 header gives a setting a value of another type than the setting's.
    SettingType {
        /// The setting.
        key: SettingKey,
        /// The setting's type (`"u32"`, `"f32"`, `"name"`, `"bool"`).
        expected: &'static str,
    },
    /// A format v5 header gives a setting a name none of its values has.
    UnknownSettingValue {
        /// The setting.
        key: SettingKey,
        /// The name as found (its first bytes).
        value: SettingText,
    },
    /// A format v5 header (or a blob being encoded) holds a count out of its setting's
    /// range ([`ModelSpec::validate`](crate::spec::ModelSpec::validate)).
    SettingOutOfRange {
        /// The setting (`disc_steps`, `commit_delay`).
        key: SettingKey,
        /// Its value.
        value: u32,
    },
    /// A format v5 header names the same setting twice.
    DuplicateSetting {
        /// The setting.
        key: SettingKey,
    },
    /// The postcard encoding itself is malformed (bad varint, trailing bytes, ...).
    Malformed,
    /// The output buffer given to the encoder is too small.
    BufferTooSmall,
}

impl From<ShapeError> for Error {
    fn from(e: ShapeError) -> Self {
        Error::Shape(e)
    }
}

impl From<BlobError> for Error {
    fn from(e: BlobError) -> Self {
        Error::Blob(e)
    }
}

impl fmt::Display for ShapeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: expected length {}, got {}",
            self.what, self.expected, self.actual
        )
    }
}

impl fmt::Display for BlobError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BlobError::Truncated => write!(f, "blob is truncated"),
            BlobError::BadMagic => write!(f, "not a GMAN weight blob (bad magic)"),
            BlobError::UnsupportedVersion { found } => {
                write!(f, "unsupported blob format version {found}")
            }
            BlobError::LegacyFormat { found } => write!(
                f,
                "blob format v{found}: run `gman upgrade-blob` or build with `legacy-blobs`"
            ),
            BlobError::PayloadLength { expected, actual } => write!(
                f,
                "payload length mismatch: header says {expected} bytes, found {actual}"
            ),
            BlobError::ChecksumMismatch { expected, actual } => write!(
                f,
                "payload checksum mismatch: header {expected:#010x}, computed {actual:#010x}"
            ),
            BlobError::DimensionMismatch {
                field,
                expected,
                found,
            } => write!(
                f,
                "dimension `{field}` mismatch: model expects {expected}, blob has {found}"
            ),
            BlobError::UnknownTensor { id } => write!(f, "unknown tensor id {id}"),
            BlobError::DuplicateTensor { id } => write!(f, "tensor id {id} appears twice"),
            BlobError::MissingTensor { id } => write!(f, "tensor id {id} is missing"),
            BlobError::BadTensorShape { id } => write!(f, "tensor id {id} has a wrong shape"),
            BlobError::BadQuantization { id } => {
                write!(f, "tensor id {id} has a bad or disallowed quantisation")
            }
            BlobError::NonFiniteScale { id } => {
                write!(f, "tensor id {id} has a NaN, infinite or negative scale")
            }
            BlobError::NonFiniteWeight { id } => {
                write!(f, "tensor id {id} has a NaN or infinite weight")
            }
            // The value is named by its class and bits, not printed in decimal: formatting
            // an f32 would link core's float printing (about 15 KB of a Cortex-M4F's flash)
            // into every program that reports errors.
            BlobError::BadInnerRate { field, bits } => write!(
                f,
                "inner-loop rate `{field}` is {} (f32 bits {bits:#010x}); it must be finite, non-negative and at most {}",
                rate_class(*bits),
                MAX_INNER_RATE_TEXT
            ),
            BlobError::DimsTooLarge => write!(
                f,
                "dimensions too large: a parameter count, tensor size or RAM size derived from them overflows"
            ),
            BlobError::DegenerateDims { field } => write!(
                f,
                "degenerate dims: `{field}` is zero or inconsistent with the other map dims"
            ),
            BlobError::HeaderChecksumMismatch { expected, actual } => write!(
                f,
                "checksum mismatch over header and payload (header says {expected:#010x}, bytes give {actual:#010x}): the blob was altered"
            ),
            BlobError::HeaderNotCovered { found } => write!(
                f,
                "blob format v{found} checksums the payload only; v4 required (gman upgrade-blob)"
            ),
            BlobError::UnknownFlagBit { bit, flags } => write!(
                f,
                "unknown model flag bit {bit} (flags {flags:#x})"
            ),
            BlobError::UnknownSetting { key } => write!(
                f,
                "unknown model setting `{key}` (a setting of a newer build)"
            ),
            BlobError::SettingType { key, expected } => {
                write!(f, "model setting `{key}` is not a {expected}")
            }
            BlobError::UnknownSettingValue { key, value } => {
                write!(f, "model setting `{key}` has the unknown value `{value}`")
            }
            BlobError::SettingOutOfRange { key, value } => {
                write!(f, "model setting `{key}` is out of range: {value}")
            }
            BlobError::DuplicateSetting { key } => write!(f, "model setting `{key}` appears twice"),
            BlobError::Malformed => write!(f, "malformed postcard encoding"),
            BlobError::BufferTooSmall => write!(f, "output buffer too small"),
        }
    }
}

/// [`crate::spec::preset::MAX_INNER_RATE`] as text (checked by a unit test below).
const MAX_INNER_RATE_TEXT: &str = "1.0";

/// What is wrong with a rejected inner-loop rate, from its bits alone.
fn rate_class(bits: u32) -> &'static str {
    let v = f32::from_bits(bits);
    if v.is_nan() {
        "NaN"
    } else if v.is_infinite() {
        "infinite"
    } else if v < 0.0 {
        "negative"
    } else if v > crate::spec::preset::MAX_INNER_RATE {
        "too large"
    } else {
        "valid"
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Shape(e) => write!(f, "shape error: {e}"),
            Error::NonFiniteInput { what } => write!(f, "non-finite value in input `{what}`"),
            Error::Blob(e) => write!(f, "weight blob error: {e}"),
            Error::NumericalFault { what } => write!(f, "numerical fault: `{what}` is not finite"),
            Error::Config { what } => write!(f, "configuration error: {what}"),
            Error::UpdateNotReady { slices_left } => write!(
                f,
                "inner update not ready at its commit point: {slices_left} slices left (run Navigator::adapt_slice)"
            ),
        }
    }
}

impl core::error::Error for ShapeError {}
impl core::error::Error for BlobError {}
impl core::error::Error for Error {}

/// Result alias of the crate.
pub type Result<T> = core::result::Result<T, Error>;

/// Returns a [`ShapeError`] unless `actual == expected`.
#[inline]
pub(crate) fn check_len(what: &'static str, expected: usize, actual: usize) -> Result<()> {
    if expected == actual {
        Ok(())
    } else {
        Err(Error::Shape(ShapeError {
            what,
            expected,
            actual,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::fmt::Write;

    struct Buf([u8; 256], usize);
    impl Write for Buf {
        fn write_str(&mut self, s: &str) -> fmt::Result {
            let end = self.1 + s.len();
            self.0
                .get_mut(self.1..end)
                .ok_or(fmt::Error)?
                .copy_from_slice(s.as_bytes());
            self.1 = end;
            Ok(())
        }
    }
    fn text(e: &BlobError) -> Buf {
        let mut b = Buf([0; 256], 0);
        write!(b, "{e}").expect("fits");
        b
    }

    #[test]
    fn max_inner_rate_text_is_the_constant() {
        let v: f32 = MAX_INNER_RATE_TEXT.parse().expect("a number");
        assert_eq!(v.to_bits(), crate::spec::preset::MAX_INNER_RATE.to_bits());
    }

    #[test]
    fn bad_inner_rate_names_class_and_bits() {
        for (v, class) in [
            (f32::NAN, "NaN"),
            (f32::INFINITY, "infinite"),
            (f32::NEG_INFINITY, "infinite"),
            (-1e-4, "negative"),
            (2.0, "too large"),
        ] {
            let bits = v.to_bits();
            let b = text(&BlobError::BadInnerRate {
                field: "alpha_disc",
                bits,
            });
            let s = core::str::from_utf8(&b.0[..b.1]).expect("utf-8");
            assert!(s.contains(class), "{s}");
            let mut hex = Buf([0; 256], 0);
            write!(hex, "{bits:#010x}").expect("fits");
            let hex = core::str::from_utf8(&hex.0[..hex.1]).expect("utf-8");
            assert!(s.contains(hex), "{s}");
            assert!(
                s.contains("`alpha_disc`") && s.ends_with("at most 1.0"),
                "{s}"
            );
        }
    }
}
