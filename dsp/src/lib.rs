//! # gman-dsp
//!
//! The integer dot-product kernel of gman-core's int8-activation path on Cortex-M4F/M7
//! (Armv7E-M): two int8 weight rows against one int8 input block, two multiply-accumulates
//! per `SMLAD` instruction, the int8 weights unpacked to pairs of int16 by `SXTB16`, as in
//! CMSIS-NN's `arm_nn_vec_mat_mult_t_s8`.
//!
//! This crate exists so that gman-core itself stays `#![forbid(unsafe_code)]`: the only
//! `unsafe` here is the `asm!` of [`dots2`] on DSP targets (`cfg(gman_dsp)`, set by
//! `build.rs` for `thumbv7em-*`), which reads within the slices it is given and writes only
//! registers. On every other target [`dots2`] is [`dots2_model`], plain Rust that computes
//! what the instructions compute, step by step (so a host test exercises the packing, the
//! pairing of columns and the tails of the device's kernel). Integers are exact: any kernel
//! here gives the same sums as a plain loop, `sum_j (a_j as i8) * x_j`; the firmware's
//! self-test compares the `asm!` kernel with gman-core's portable one under QEMU.
//!
//! # Operand layout
//! [`pack`] turns the int8 inputs `x` into one `u32` per two inputs, in the order `SXTB16`
//! unpacks a little-endian word of four weights `w0 w1 w2 w3`: `SXTB16(w) = (w0, w2)` and
//! `SXTB16(w, ROR #8) = (w1, w3)` (low half first), so every four inputs give the words
//! `(x0, x2)` and `(x1, x3)`, and `SMLAD` adds `w0 x0 + w2 x2` and `w1 x1 + w3 x3`.
#![no_std]
#![deny(unsafe_code)]
#![warn(missing_docs)]

/// True when [`dots2`] runs the `SXTB16` / `SMLAD` kernel (DSP targets), false when it runs
/// [`dots2_model`].
pub const HAS_DSP: bool = cfg!(gman_dsp);

/// Columns [`dots2`] consumes per step (its loop runs 32 at a time, then 16, 8 and 4).
pub const STEP: usize = 4;

/// Packs `xq` into the operand words of [`dots2`] (see the crate docs): for every group of
/// four inputs `x[4g..4g + 4]`, `out[2g] = (x0, x2)` and `out[2g + 1] = (x1, x3)` as two
/// int16 halves, low half first. Packs `min(xq.len() / 4, out.len() / 2)` groups and returns
/// the number of inputs packed (a multiple of 4); the caller handles the rest.
pub fn pack(xq: &[i8], out: &mut [u32]) -> usize {
    let mut done = 0;
    for (x, o) in xq.chunks_exact(4).zip(out.chunks_exact_mut(2)) {
        let [a, b] = pair_words([x[0] as i32, x[1] as i32, x[2] as i32, x[3] as i32]);
        o[0] = a;
        o[1] = b;
        done += 4;
    }
    done
}

/// The two operand words of four inputs `x0 x1 x2 x3` (each in `-32768..=32767`, only
/// their low 16 bits are kept): `[(x0, x2), (x1, x3)]`, low half first (one `PKHBT` each).
#[inline(always)]
pub fn pair_words(x: [i32; 4]) -> [u32; 2] {
    let half = |v: i32| (v as u32) & 0xffff;
    [
        half(x[0]) | ((x[2] as u32) << 16),
        half(x[1]) | ((x[3] as u32) << 16),
    ]
}

/// Columns [`dots2`] covers for rows of `a` and `b` bytes and `words` packed words: the
/// largest multiple of [`STEP`] that fits all three.
#[inline]
pub fn span(a: usize, b: usize, words: usize) -> usize {
    let n = a.min(b).min(words.saturating_mul(2));
    n - n % STEP
}

/// `(sum_j (a[j] as i8) * x_j, sum_j (b[j] as i8) * x_j)` over the first
/// [`span`]`(a.len(), b.len(), xp.len())` columns, where `xp` are the inputs `x` packed by
/// [`pack`]. The sums must fit in an `i32` (they do for `|x_j| <= 127` and fewer than
/// 133,000 columns); past that they wrap, in every kernel alike.
#[inline]
pub fn dots2(a: &[u8], b: &[u8], xp: &[u32]) -> (i32, i32) {
    #[cfg(gman_dsp)]
    {
        arm::dots2(a, b, xp)
    }
    #[cfg(not(gman_dsp))]
    {
        dots2_model(a, b, xp)
    }
}

/// `SXTB16(w)`: bytes 0 and 2 of `w`, sign-extended, as (low, high).
#[inline(always)]
fn sxtb16(w: u32) -> (i32, i32) {
    (w as u8 as i8 as i32, (w >> 16) as u8 as i8 as i32)
}

/// `SMLAD(acc, p, q)`: `acc + p.lo * q.lo + p.hi * q.hi` on signed int16 halves, wrapping.
#[inline(always)]
fn smlad(acc: i32, p: (i32, i32), q: u32) -> i32 {
    let (q0, q1) = (q as u16 as i16 as i32, (q >> 16) as u16 as i16 as i32);
    acc.wrapping_add(p.0.wrapping_mul(q0))
        .wrapping_add(p.1.wrapping_mul(q1))
}

/// [`dots2`] in plain Rust, instruction by instruction as the `asm!` kernel runs them (little
/// -endian weight words, `SXTB16`, `SMLAD`): the reference a host test checks, and the
/// kernel on targets without DSP instructions.
pub fn dots2_model(a: &[u8], b: &[u8], xp: &[u32]) -> (i32, i32) {
    let n = span(a.len(), b.len(), xp.len());
    let (mut sa, mut sb) = (0i32, 0i32);
    for ((wa, wb), x) in a[..n]
        .chunks_exact(4)
        .zip(b[..n].chunks_exact(4))
        .zip(xp.chunks_exact(2))
    {
        let wa = u32::from_le_bytes([wa[0], wa[1], wa[2], wa[3]]);
        let wb = u32::from_le_bytes([wb[0], wb[1], wb[2], wb[3]]);
        sa = smlad(sa, sxtb16(wa), x[0]);
        sa = smlad(sa, sxtb16(wa >> 8), x[1]);
        sb = smlad(sb, sxtb16(wb), x[0]);
        sb = smlad(sb, sxtb16(wb >> 8), x[1]);
    }
    (sa, sb)
}

/// The `asm!` kernel (Armv7E-M only).
///
/// # Audit
/// * Reads: `n` bytes from each of `a` and `b` (word loads, `LDR`, which the Armv7-M
///   architecture allows unaligned unless `CCR.UNALIGN_TRP` is set; cortex-m-rt leaves it
///   clear), and `n / 2` words from `xp` (`LDM` / `LDRD`, which need word alignment: `xp` is
///   a `&[u32]`), every pointer advancing by what it read. The blocks run 32, 16, 8 and 4
///   columns (`n = span(..)` is a multiple of 4 and at most each slice's length), so every
///   read is inside a slice; `n == 0` runs none of them.
/// * Writes: only the registers bound as outputs (accumulators, pointers, counter, the input
///   words r2-r5 and the scratch registers); no memory (`readonly`), no stack (`nostack`);
///   the flags are clobbered (`SUBS`), which `asm!` assumes by default. The registers named
///   explicitly (r0-r5, r8-r12) are ones `asm!` allows on `thumbv7em` (not r6, r7, sp, pc).
/// * Arithmetic: `SMLAD` wraps on overflow (it only sets the Q flag, which nothing reads),
///   exactly as [`super::dots2_model`] does.
#[cfg(gman_dsp)]
#[allow(unsafe_code)]
mod arm {
    use core::arch::asm;

    /// Four columns of both rows: two input words, one weight word per row.
    macro_rules! quad {
        () => {
            concat!(
                "ldrd {x0}, {x1}, [{px}], #8\n",
                "ldr {w}, [{pa}], #4\n",
                "sxtb16 {t}, {w}\n",
                "smlad {sa}, {t}, {x0}, {sa}\n",
                "sxtb16 {w}, {w}, ror #8\n",
                "smlad {sa}, {w}, {x1}, {sa}\n",
                "ldr {w}, [{pb}], #4\n",
                "sxtb16 {t}, {w}\n",
                "smlad {sb}, {t}, {x0}, {sb}\n",
                "sxtb16 {w}, {w}, ror #8\n",
                "smlad {sb}, {w}, {x1}, {sb}\n",
            )
        };
    }

    /// Eight columns of both rows with the registers of the 16-column loop: four input
    /// words by one `LDM` (r2-r5), weights in r9, scratch r11, accumulators r0 / r1, row
    /// pointers r8 / r10, input pointer r12.
    macro_rules! eight {
        () => {
            concat!(
                "ldm r12!, {{r2, r3, r4, r5}}\n",
                "ldr r9, [r8], #4\n",
                "sxtb16 r11, r9\n",
                "smlad r0, r11, r2, r0\n",
                "sxtb16 r9, r9, ror #8\n",
                "smlad r0, r9, r3, r0\n",
                "ldr r9, [r10], #4\n",
                "sxtb16 r11, r9\n",
                "smlad r1, r11, r2, r1\n",
                "sxtb16 r9, r9, ror #8\n",
                "smlad r1, r9, r3, r1\n",
                "ldr r9, [r8], #4\n",
                "sxtb16 r11, r9\n",
                "smlad r0, r11, r4, r0\n",
                "sxtb16 r9, r9, ror #8\n",
                "smlad r0, r9, r5, r0\n",
                "ldr r9, [r10], #4\n",
                "sxtb16 r11, r9\n",
                "smlad r1, r11, r4, r1\n",
                "sxtb16 r9, r9, ror #8\n",
                "smlad r1, r9, r5, r1\n",
            )
        };
    }

    pub(super) fn dots2(a: &[u8], b: &[u8], xp: &[u32]) -> (i32, i32) {
        let n = super::span(a.len(), b.len(), xp.len());
        let (mut sa, mut sb) = (0i32, 0i32);
        let (mut pa, mut pb, mut px) = (a.as_ptr(), b.as_ptr(), xp.as_ptr());
        let thirty_twos = n / 32;
        if thirty_twos > 0 {
            // SAFETY: see the module's audit: 32 * thirty_twos <= n bytes of `a` and `b` and
            // 16 * thirty_twos <= n / 2 words of `xp` are read; only registers are written.
            // Explicit registers: `LDM` needs its list in ascending order (r2-r5).
            unsafe {
                asm!(
                    "2:",
                    eight!(),
                    eight!(),
                    eight!(),
                    eight!(),
                    "subs {k}, {k}, #1",
                    "bne 2b",
                    inout("r0") sa,
                    inout("r1") sb,
                    out("r2") _,
                    out("r3") _,
                    out("r4") _,
                    out("r5") _,
                    inout("r8") pa,
                    inout("r10") pb,
                    inout("r12") px,
                    k = inout(reg) thirty_twos => _,
                    out("r9") _,
                    out("r11") _,
                    options(nostack, readonly),
                );
            }
        }
        if n % 32 >= 16 {
            // Sixteen more columns.
            // SAFETY: as above, for the 16 columns after the loop's 32 * thirty_twos.
            unsafe {
                asm!(
                    eight!(),
                    eight!(),
                    inout("r0") sa,
                    inout("r1") sb,
                    out("r2") _,
                    out("r3") _,
                    out("r4") _,
                    out("r5") _,
                    inout("r8") pa,
                    inout("r10") pb,
                    inout("r12") px,
                    out("r9") _,
                    out("r11") _,
                    options(nostack, readonly),
                );
            }
        }
        if n % 16 >= 8 {
            // Eight more columns.
            // SAFETY: as above, for the 8 columns after the 32- and 16-column steps.
            unsafe {
                asm!(
                    quad!(),
                    quad!(),
                    sa = inout(reg) sa,
                    sb = inout(reg) sb,
                    pa = inout(reg) pa,
                    pb = inout(reg) pb,
                    px = inout(reg) px,
                    x0 = out(reg) _,
                    x1 = out(reg) _,
                    w = out(reg) _,
                    t = out(reg) _,
                    options(nostack, readonly),
                );
            }
        }
        if n % 8 == 4 {
            // The last four columns (n is a multiple of 4).
            // SAFETY: as above, for the 4 columns after the 16- and 8-column steps.
            unsafe {
                asm!(
                    quad!(),
                    sa = inout(reg) sa,
                    sb = inout(reg) sb,
                    pa = inout(reg) pa => _,
                    pb = inout(reg) pb => _,
                    px = inout(reg) px => _,
                    x0 = out(reg) _,
                    x1 = out(reg) _,
                    w = out(reg) _,
                    t = out(reg) _,
                    options(nostack, readonly),
                );
            }
        }
        (sa, sb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plain(w: &[u8], x: &[i8], n: usize) -> i32 {
        (0..n).map(|j| (w[j] as i8 as i32) * (x[j] as i32)).sum()
    }

    #[test]
    fn model_gives_the_plain_sums() {
        // A small LCG: every byte value, both signs, the extremes.
        let mut s = 12345u32;
        let mut next = || {
            s = s.wrapping_mul(1_103_515_245).wrapping_add(12345);
            (s >> 16) as u8
        };
        for &n in &[0usize, 1, 4, 7, 8, 9, 15, 16, 17, 24, 40, 45, 256] {
            let a: [u8; 256] = core::array::from_fn(|_| next());
            let b: [u8; 256] = core::array::from_fn(|_| next());
            let mut x: [i8; 256] = core::array::from_fn(|_| (next() % 255) as i8);
            x[0] = -127;
            x[1] = 127;
            let mut xp = [0u32; 128];
            let packed = pack(&x[..n], &mut xp);
            assert_eq!(packed, n - n % 4);
            let m = span(n, n, packed / 2);
            assert_eq!(m, n - n % 4);
            let (sa, sb) = dots2_model(&a[..n], &b[..n], &xp[..packed / 2]);
            assert_eq!(sa, plain(&a, &x, m), "n {n}");
            assert_eq!(sb, plain(&b, &x, m), "n {n}");
            assert_eq!(dots2(&a[..n], &b[..n], &xp[..packed / 2]), (sa, sb));
        }
        // All -128 weights (0x80) against all -127 inputs: the largest magnitudes.
        let a = [0x80u8; 256];
        let x = [-127i8; 256];
        let mut xp = [0u32; 128];
        pack(&x, &mut xp);
        assert_eq!(dots2_model(&a, &a, &xp), (128 * 127 * 256, 128 * 127 * 256));
    }

    #[test]
    fn span_is_the_shortest_operand_in_steps() {
        assert_eq!(span(22, 30, 100), 20);
        assert_eq!(span(100, 100, 5), 8);
        assert_eq!(span(3, 100, 100), 0);
    }
}
