//! Measurements on the device: instruction counts from SysTick under QEMU's `-icount`, the
//! peak stack by painting, and the flash and static RAM from the linker's symbols.
//!
//! # Instructions (SysTick under `-icount shift=0`)
//! QEMU's `-icount shift=0` advances virtual time by exactly 1 ns per executed instruction.
//! SysTick on `mps2-an386`, clocked from the core clock (CLKSOURCE = 1, which QEMU models at
//! the board's 25 MHz), then decrements once every 40 ns, i.e. once per **40 instructions**:
//! that is the resolution. It is a 24-bit down-counter; with the reload at its maximum an
//! interval up to 2^24 ticks (671 M instructions) is measured by a wrapping subtraction, with no
//! interrupt. [`calibrate`] checks the 40-instruction ratio on every run with a loop of a known
//! instruction count. DWT's CYCCNT is no help here: QEMU does not model it (it reads 0).
//! Without `-icount` the counts follow the host's wall clock and mean nothing.
//!
//! # Peak stack (painting)
//! [`paint_stack`] fills the stack region below the current stack pointer with a pattern at
//! startup; [`stack_peak`] later finds the lowest word that no longer holds it. The region is
//! the [`STACK_WINDOW`] bytes below `_stack_start` (cortex-m-rt's initial stack pointer, the
//! top of RAM), clipped at `_stack_end` (the end of the statics). A stack that reached the
//! bottom of the window is reported as an error, never as a too-small number.

use core::ptr::{addr_of, read_volatile, write_volatile};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;

/// Instructions per SysTick tick under `-icount shift=0` on `mps2-an386` (1 ns per
/// instruction, SysTick at 25 MHz).
pub const INSNS_PER_TICK: u32 = 40;

/// Bytes of stack painted and checked: more than the whole RAM budget (192 KiB), so any stack
/// that fits the budget is measured exactly.
pub const STACK_WINDOW: usize = 256 * 1024;

const PAINT: u32 = 0x5354_4B21; // "STK!"

extern "C" {
    // cortex-m-rt's linker script (link.x).
    static _stack_start: u32;
    static _stack_end: u32;
    static __sdata: u32;
    static __edata: u32;
    static __sidata: u32;
}

fn sym(p: *const u32) -> usize {
    p as usize
}

/// Flash the image occupies: code and read-only data up to the load image of `.data`
/// (flash starts at 0 on `mps2-an386`).
pub fn flash_bytes() -> usize {
    // Only the addresses of the linker symbols are taken, never their contents.
    sym(addr_of!(__sidata)) + sym(addr_of!(__edata)) - sym(addr_of!(__sdata))
}

/// Static RAM: `.data`, `.bss` and `.uninit`, from the start of RAM to `_stack_end`.
pub fn static_ram_bytes() -> usize {
    sym(addr_of!(_stack_end)) - sym(addr_of!(__sdata))
}

fn stack_bounds() -> (usize, usize) {
    let (top, end) = (sym(addr_of!(_stack_start)), sym(addr_of!(_stack_end)));
    (top, top.saturating_sub(STACK_WINDOW).max(end))
}

/// Paints the stack window below the current stack pointer (minus a margin for this
/// function's own frame). Call first thing in `main`.
#[inline(never)]
pub fn paint_stack() {
    let (_, bottom) = stack_bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = bottom;
    while p < sp - 64 {
        // SAFETY: [bottom, sp - 64) is RAM below the live stack and above the statics, which
        // nothing uses yet.
        unsafe { write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// Peak stack use in bytes since [`paint_stack`] (measured from the top of RAM, so what
/// `main`'s caller used is included), or `None` if it reached the bottom of the window.
pub fn stack_peak() -> Option<usize> {
    let (top, bottom) = stack_bounds();
    let mut p = bottom;
    // SAFETY: reads of RAM in the painted window.
    while p < top && unsafe { read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    (p > bottom).then_some(top - p)
}

/// SysTick as a free-running down-counter of the core clock. Owning `SYST` guarantees nobody
/// else reconfigures it.
pub struct Clock {
    _syst: SYST,
}

impl Clock {
    /// Starts SysTick from the core clock, reload at the 24-bit maximum, no interrupt.
    pub fn start(mut syst: SYST) -> Self {
        syst.disable_interrupt();
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(0x00FF_FFFF);
        syst.clear_current();
        syst.enable_counter();
        Clock { _syst: syst }
    }

    /// The current count (it counts down).
    #[inline(always)]
    pub fn now(&self) -> u32 {
        SYST::get_current()
    }

    /// Ticks from `start` to now, for intervals shorter than 2^24 ticks.
    #[inline(always)]
    pub fn ticks_since(&self, start: u32) -> u32 {
        start.wrapping_sub(self.now()) & 0x00FF_FFFF
    }
}

/// Instructions executed by [`calibrate`]'s loop: two per iteration (`subs`, `bne`).
pub const CALIBRATION_INSNS: u32 = 2 * CALIBRATION_ITERS;
const CALIBRATION_ITERS: u32 = 1_000_000;

/// Ticks taken by a loop of exactly [`CALIBRATION_INSNS`] instructions; `CALIBRATION_INSNS /
/// ticks` should be [`INSNS_PER_TICK`].
pub fn calibrate(clock: &Clock) -> u32 {
    let t0 = clock.now();
    // SAFETY: a register-only countdown loop.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {n}, {n}, #1",
            "bne 2b",
            n = inout(reg) CALIBRATION_ITERS => _,
            options(nomem, nostack),
        );
    }
    clock.ticks_since(t0)
}

/// Instruction statistics of a set of intervals.
#[derive(Clone, Copy, Debug)]
pub struct Stats {
    /// Intervals recorded.
    pub n: u32,
    /// Smallest, in ticks.
    pub min: u32,
    /// Largest, in ticks.
    pub max: u32,
    /// Sum, in ticks.
    pub sum: u64,
}

impl Stats {
    /// No intervals.
    pub const EMPTY: Stats = Stats {
        n: 0,
        min: u32::MAX,
        max: 0,
        sum: 0,
    };

    /// Adds one interval of `ticks`.
    pub fn add(&mut self, ticks: u32) {
        self.n += 1;
        self.min = self.min.min(ticks);
        self.max = self.max.max(ticks);
        self.sum += ticks as u64;
    }

    /// Mean in instructions.
    pub fn mean_insns(&self) -> u64 {
        self.sum * INSNS_PER_TICK as u64 / (self.n.max(1) as u64)
    }
}
