//! The handle inside the caller's arena: its layout, its checks, the last error's message, and the panic guard.

use super::*;

// ---------------------------------------------------------------------------------------
// The handle inside the arena.

pub(crate) const MAGIC: u64 = 0x4e41_564e_414d_4721; // "!GMANVAN"
pub(crate) const POISONED: u64 = 0x4445_4e4f_5349_4f50; // "POISONED"
pub(crate) const MSG_LEN: usize = 160;

pub(crate) enum Nav {
    Efficient(Navigator<'static, Efficient, K>),
    Full(Navigator<'static, Full, K>),
}

macro_rules! each {
    ($nav:expr, $n:ident => $body:expr) => {
        match $nav {
            Nav::Efficient($n) => $body,
            Nav::Full($n) => $body,
        }
    };
}
pub(crate) use each;

#[repr(C)]
pub(crate) struct Handle {
    pub(crate) magic: u64,
    /// The bytes of the arena the navigator uses (handle and state), `[lo, hi)`.
    pub(crate) arena: Span,
    pub(crate) info: gman_info,
    pub(crate) msg: [u8; MSG_LEN],
    pub(crate) nav: Nav,
}

const _: () = assert!(size_of::<Handle>() <= GMAN_HANDLE_BYTES);
const _: () = assert!(align_of::<Handle>() <= GMAN_ARENA_ALIGN);
const _: () = assert!(GMAN_HANDLE_BYTES.is_multiple_of(GMAN_ARENA_ALIGN));

impl Handle {
    /// [`disjoint`] against this navigator's arena, as a call's error. Called before any
    /// caller buffer becomes a Rust reference (and after the lengths are checked, so a
    /// huge length is a shape error, not an overlap).
    pub(crate) fn disjoint(
        &self,
        inputs: &[Span],
        outputs: &[Span],
    ) -> Result<(), (gman_status, Option<Error>)> {
        disjoint(self.arena, inputs, outputs).map_err(ffi_err)
    }
}

/// A message buffer written with `core::fmt`, truncated at `MSG_LEN - 1` bytes, always
/// NUL-terminated.
pub(crate) struct Msg<'a> {
    pub(crate) buf: &'a mut [u8; MSG_LEN],
    pub(crate) len: usize,
}

impl fmt::Write for Msg<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for &b in s.as_bytes() {
            if self.len + 1 >= MSG_LEN {
                break;
            }
            self.buf[self.len] = b;
            self.len += 1;
        }
        self.buf[self.len] = 0;
        Ok(())
    }
}

pub(crate) fn set_msg(buf: &mut [u8; MSG_LEN], args: fmt::Arguments<'_>) {
    buf[0] = 0;
    let mut m = Msg { buf, len: 0 };
    let _ = m.write_fmt(args);
}

/// Runs `f`, turning a panic into [`GMAN_ERR_PANIC`] on the host.
#[cfg(feature = "std")]
pub(crate) fn guard(f: impl FnOnce() -> gman_status) -> gman_status {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or(GMAN_ERR_PANIC)
}

#[cfg(not(feature = "std"))]
pub(crate) fn guard(f: impl FnOnce() -> gman_status) -> gman_status {
    f()
}

#[cfg(all(not(feature = "std"), target_os = "none", not(test)))]
#[panic_handler]
pub(crate) fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    loop {
        #[cfg(target_arch = "arm")]
        // SAFETY: `udf` only raises an undefined-instruction exception (HardFault); it
        // touches no memory.
        unsafe {
            core::arch::asm!("udf #0")
        };
    }
}

/// The handle behind `nav`, checked (non-null, aligned, magic), as a raw pointer.
///
/// # Safety
/// A non-null `nav` must point to readable memory of at least [`GMAN_HANDLE_BYTES`] (an
/// arena given to [`gman_init`]) that nobody else accesses during the call.
pub(crate) unsafe fn handle_ptr(nav: *mut gman_nav) -> Result<*mut Handle, gman_status> {
    let h = nav as *mut Handle;
    if h.is_null() {
        return Err(GMAN_ERR_NULL);
    }
    if !h.is_aligned() {
        return Err(GMAN_ERR_BAD_HANDLE);
    }
    // SAFETY: aligned and, per the caller, readable; `magic` is the first field of the
    // `repr(C)` handle and a `u64` is valid for any bits.
    let magic = unsafe { ptr::read(ptr::addr_of!((*h).magic)) };
    if magic != MAGIC {
        return Err(GMAN_ERR_BAD_HANDLE);
    }
    Ok(h)
}

/// Runs `f` on the handle; a failure's message goes to the handle's last error, a panic
/// poisons it.
///
/// # Safety
/// See [`handle_ptr`].
pub(crate) unsafe fn with_handle(
    nav: *mut gman_nav,
    f: impl FnOnce(&mut Handle) -> Result<(), (gman_status, Option<Error>)>,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    let hp = match unsafe { handle_ptr(nav) } {
        Ok(h) => h,
        Err(s) => return s,
    };
    let status = guard(|| {
        // SAFETY: the magic is only ever written by `gman_init` after a complete `Handle`
        // was written at this address, so the memory holds an initialised `Handle`; the
        // caller guarantees exclusive access for the call. The reference ends with the
        // closure.
        let h = unsafe { &mut *hp };
        match f(h) {
            Ok(()) => GMAN_OK,
            Err((s, e)) => {
                match e {
                    // The C names of what to do.
                    Some(Error::UpdateNotReady { slices_left }) => set_msg(
                        &mut h.msg,
                        format_args!(
                            "inner update not ready at its commit point: {slices_left} slices left (run gman_adapt_slice, then the same step again; the step changed nothing)"
                        ),
                    ),
                    Some(e) => set_msg(&mut h.msg, format_args!("{e}")),
                    None => set_msg(&mut h.msg, format_args!("{}", status_text(s))),
                }
                s
            }
        }
    });
    if status == GMAN_ERR_PANIC {
        // SAFETY: `hp` is the handle checked above (no reference to it is live any more);
        // only its first field is written.
        unsafe { ptr::write(ptr::addr_of_mut!((*hp).magic), POISONED) };
    }
    status
}
