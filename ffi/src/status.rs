//! The status codes and how an error becomes one.

use super::*;

/// A status code: [`GMAN_OK`] or one of the `GMAN_ERR_*` values.
pub type gman_status = i32;
/// Success.
pub const GMAN_OK: gman_status = 0;
/// A required pointer was null (or a null pointer was given with a non-zero length).
pub const GMAN_ERR_NULL: gman_status = 1;
/// A pointer is not aligned for what it points to: 4 bytes for a float buffer, the
/// struct's alignment for [`gman_options`] and the out-parameters.
pub const GMAN_ERR_ALIGNMENT: gman_status = 2;
/// The arena is smaller than [`gman_arena_size`].
pub const GMAN_ERR_ARENA_TOO_SMALL: gman_status = 3;
/// The handle is not a live navigator (never initialised, overwritten, or poisoned).
pub const GMAN_ERR_BAD_HANDLE: gman_status = 4;
/// The blob is truncated or malformed, or its tensors do not fit its sizes.
pub const GMAN_ERR_BLOB: gman_status = 5;
/// The blob's CRC-32 does not match its payload (a corrupt or partial download).
pub const GMAN_ERR_BLOB_CRC: gman_status = 6;
/// The blob's format version is not one this library reads, or (with
/// [`gman_options::require_header_crc`]) one whose checksum does not cover the header.
pub const GMAN_ERR_BLOB_VERSION: gman_status = 7;
/// A buffer has the wrong length for the model's sizes.
pub const GMAN_ERR_SHAPE: gman_status = 8;
/// An input holds NaN or infinity.
pub const GMAN_ERR_NON_FINITE: gman_status = 9;
/// A computation produced NaN or infinity from finite inputs; no action was returned.
pub const GMAN_ERR_NUMERICAL: gman_status = 10;
/// A configuration value is out of range, or a call was made out of order (e.g. a step
/// before the first reset).
pub const GMAN_ERR_CONFIG: gman_status = 11;
/// A panic was caught at the boundary (host build only); the handle is poisoned.
pub const GMAN_ERR_PANIC: gman_status = 12;
/// With the background schedule ([`gman_options::schedule`] = 2): this step would commit an
/// inner update whose slices have not all run yet ([`gman_adapt_slice`]). The step changed
/// nothing (no action, no counter, no state): run the remaining slices and step again.
pub const GMAN_ERR_UPDATE_NOT_READY: gman_status = 13;
/// An output buffer overlaps an input buffer, or a buffer overlaps the navigator's arena
/// (or, for [`gman_init`], the blob overlaps the arena). Nothing was read or written.
pub const GMAN_ERR_OVERLAP: gman_status = 14;

pub(crate) fn status_of_blob(e: &BlobError) -> gman_status {
    match e {
        BlobError::ChecksumMismatch { .. } | BlobError::HeaderChecksumMismatch { .. } => {
            GMAN_ERR_BLOB_CRC
        }
        BlobError::UnsupportedVersion { .. } | BlobError::HeaderNotCovered { .. } => {
            GMAN_ERR_BLOB_VERSION
        }
        _ => GMAN_ERR_BLOB,
    }
}

pub(crate) fn status_of(e: &Error) -> gman_status {
    // Errors a newer core adds map to GMAN_ERR_CONFIG until they get their own code.
    #[allow(unreachable_patterns)]
    match e {
        Error::Shape(_) => GMAN_ERR_SHAPE,
        Error::NonFiniteInput { .. } => GMAN_ERR_NON_FINITE,
        Error::Blob(b) => status_of_blob(b),
        Error::NumericalFault { .. } => GMAN_ERR_NUMERICAL,
        Error::Config { .. } => GMAN_ERR_CONFIG,
        Error::UpdateNotReady { .. } => GMAN_ERR_UPDATE_NOT_READY,
        _ => GMAN_ERR_CONFIG,
    }
}

pub(crate) fn core_err(e: Error) -> (gman_status, Option<Error>) {
    (status_of(&e), Some(e))
}

pub(crate) fn ffi_err(s: gman_status) -> (gman_status, Option<Error>) {
    (s, None)
}

/// The text of a status code, NUL-terminated.
pub(crate) fn status_cstr(s: gman_status) -> &'static str {
    match s {
        GMAN_OK => "ok\0",
        GMAN_ERR_NULL => "a required pointer is null\0",
        GMAN_ERR_ALIGNMENT => {
            "a pointer is not aligned for its type (4 bytes for floats, the struct's alignment for gman_options and out-parameters)\0"
        }
        GMAN_ERR_ARENA_TOO_SMALL => "the arena is smaller than gman_arena_size()\0",
        GMAN_ERR_BAD_HANDLE => {
            "not a live navigator handle (not initialised, overwritten or poisoned)\0"
        }
        GMAN_ERR_BLOB => "the weight blob is truncated or malformed\0",
        GMAN_ERR_BLOB_CRC => "the weight blob's CRC-32 does not match (corrupt or partial copy)\0",
        GMAN_ERR_BLOB_VERSION => {
            "the weight blob's format version is not supported by this library, or its checksum does not cover the header and the options require it\0"
        }
        GMAN_ERR_SHAPE => "a buffer has the wrong length for the model\0",
        GMAN_ERR_NON_FINITE => "an input holds NaN or infinity\0",
        GMAN_ERR_NUMERICAL => "a computation produced NaN or infinity\0",
        GMAN_ERR_CONFIG => "a setting is out of range or a call was made out of order\0",
        GMAN_ERR_PANIC => "internal panic caught at the C boundary (handle poisoned)\0",
        GMAN_ERR_UPDATE_NOT_READY => {
            "the pending inner update has slices left: run gman_adapt_slice() first (nothing changed)\0"
        }
        GMAN_ERR_OVERLAP => {
            "an output buffer overlaps an input buffer or the navigator's arena (nothing changed)\0"
        }
        _ => "unknown status code\0",
    }
}

pub(crate) fn status_text(s: gman_status) -> &'static str {
    status_cstr(s).trim_end_matches('\0')
}
