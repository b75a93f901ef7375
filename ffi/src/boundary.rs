//! What can be checked of C pointers and lengths before they are read: spans, overlaps, lengths.

use super::*;

/// What can be checked of a C span of `len > 0` elements without reading it: `p` is non-null
/// and aligned for `T`, and the byte length fits `isize` (`core::slice::from_raw_parts`'s
/// preconditions other than validity, which only the caller can promise).
pub(crate) fn check_span<T>(p: *const T, len: usize) -> Result<(), gman_status> {
    if p.is_null() {
        return Err(GMAN_ERR_NULL);
    }
    if !p.is_aligned() {
        return Err(GMAN_ERR_ALIGNMENT);
    }
    if len
        .checked_mul(size_of::<T>())
        .is_none_or(|b| b > isize::MAX as usize)
    {
        return Err(GMAN_ERR_SHAPE);
    }
    Ok(())
}

/// A slice from a C pointer and length: null is allowed only with length 0.
///
/// # Safety
/// A non-null `p` must be valid for reads of `len` elements for `'a`.
pub(crate) unsafe fn slice_in<'a, T>(p: *const T, len: usize) -> Result<&'a [T], gman_status> {
    if len == 0 {
        return Ok(&[]);
    }
    check_span(p, len)?;
    // SAFETY: `check_span` saw `p` non-null, aligned and of a byte length that fits `isize`;
    // the caller guarantees `len` readable elements.
    Ok(unsafe { core::slice::from_raw_parts(p, len) })
}

/// A mutable slice from a C pointer and length (see [`slice_in`]).
///
/// # Safety
/// A non-null `p` must be valid for writes of `len` elements for `'a`, and not aliased.
pub(crate) unsafe fn slice_out<'a, T>(p: *mut T, len: usize) -> Result<&'a mut [T], gman_status> {
    if len == 0 {
        return Ok(&mut []);
    }
    check_span(p.cast_const(), len)?;
    // SAFETY: as in `slice_in`, plus exclusive access guaranteed by the caller.
    Ok(unsafe { core::slice::from_raw_parts_mut(p, len) })
}

/// A mutable reference to a C out-parameter.
///
/// # Safety
/// A non-null `p` must be valid for writes of one `T`.
pub(crate) unsafe fn out_ref<'a, T>(p: *mut T) -> Result<&'a mut T, gman_status> {
    if p.is_null() {
        return Err(GMAN_ERR_NULL);
    }
    if !p.is_aligned() {
        return Err(GMAN_ERR_ALIGNMENT);
    }
    // SAFETY: non-null and aligned; the caller guarantees it is writable. Every `T` used here
    // is plain old data, valid for any bit pattern the caller may have left in it.
    Ok(unsafe { &mut *p })
}

/// The bytes `[lo, hi)` of a C span, by address only (nothing is read). A null pointer or a
/// zero length is empty; a byte length past the address space ends at `usize::MAX` (such a
/// span is refused by [`check_span`] anyway).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Span {
    pub(crate) lo: usize,
    pub(crate) hi: usize,
}

impl Span {
    pub(crate) const EMPTY: Span = Span { lo: 0, hi: 0 };

    pub(crate) fn of<T>(p: *const T, len: usize) -> Span {
        if p.is_null() || len == 0 {
            return Span::EMPTY;
        }
        let lo = p as usize;
        let bytes = len.saturating_mul(size_of::<T>());
        Span {
            lo,
            hi: lo.saturating_add(bytes),
        }
    }

    pub(crate) fn one<T>(p: *const T) -> Span {
        Span::of(p, 1)
    }

    pub(crate) fn overlaps(self, o: Span) -> bool {
        self.lo < self.hi && o.lo < o.hi && self.lo < o.hi && o.lo < self.hi
    }
}

/// [`GMAN_ERR_OVERLAP`] when an output overlaps an input or another output, or any of them
/// overlaps `arena` (inputs may overlap each other: they are only read).
pub(crate) fn disjoint(arena: Span, inputs: &[Span], outputs: &[Span]) -> Result<(), gman_status> {
    let clash = inputs.iter().chain(outputs).any(|s| s.overlaps(arena))
        || outputs.iter().enumerate().any(|(i, o)| {
            inputs.iter().any(|s| s.overlaps(*o)) || outputs[..i].iter().any(|s| s.overlaps(*o))
        });
    if clash {
        Err(GMAN_ERR_OVERLAP)
    } else {
        Ok(())
    }
}

/// [`GMAN_ERR_SHAPE`] (with the core's message) unless a caller's `len` is the model's
/// `expected` length: checked before a slice is made, so no length a caller gives ever
/// reaches a Rust slice beyond the model's sizes.
pub(crate) fn want_len(
    what: &'static str,
    expected: u32,
    len: usize,
) -> Result<(), (gman_status, Option<Error>)> {
    let expected = expected as usize;
    if len == expected {
        Ok(())
    } else {
        Err(core_err(Error::Shape(gman_core::ShapeError {
            what,
            expected,
            actual: len,
        })))
    }
}

/// The longest blob a caller may give: the header (well under 1 KiB) and a payload, whose
/// length the header stores as a `u32`. Longer is [`GMAN_ERR_BLOB`] before anything is read
/// (on a 32-bit target no length is longer).
pub(crate) const MAX_BLOB_BYTES: u64 = u32::MAX as u64 + 1024;

/// True when a blob of `len` bytes is longer than any blob ([`MAX_BLOB_BYTES`]).
pub(crate) fn blob_too_long(len: usize) -> bool {
    len as u64 > MAX_BLOB_BYTES
}
