//! gman-core's dense kernels compiled for AVX2, chosen at run time.
//!
//! # Design
//! gman-core is `no_std` and `#![forbid(unsafe_code)]`, and its kernels fix one canonical
//! order of floating-point operations (eight accumulators over chunks of eight, a fixed
//! reduction tree, separate multiply and add; see `gman_core::nn::batch`). The bits therefore do
//! not depend on the vector width the compiler picks, only the speed does. The host binary
//! is built for baseline x86-64 (SSE2, four lanes) so that it runs on any x86-64 CPU; this
//! module compiles the *same* kernel bodies a second time inside
//! `#[target_feature(enable = "avx2")]` functions (the bodies are `#[inline(always)]`
//! generics in gman-core, so they are instantiated here, with eight-lane registers) and
//! exposes them as a `gman_core::nn::batch::Kernels` table. A matrix view (or a whole
//! `NavWeights`) runs through the table once it is attached with `with_kernels`.
//!
//! * FMA is **not** enabled: Rust never contracts `a * b + c`, and enabling only `avx2`
//!   keeps even the instruction selection free of fused operations.
//! * The table is handed out only after `is_x86_feature_detected!("avx2")` said yes, which is
//!   what makes the `unsafe` calls below sound.
//! * `GMAN_KERNELS=portable` in the environment makes [`host_kernels`] return `None`
//!   (gman-core's own build), e.g. to compare speeds; the results are identical either way
//!   (pinned by this module's tests and `tests/avx2_parity.rs`).

use gman_core::nn::batch::Kernels;
#[cfg(target_arch = "x86_64")]
use gman_core::{
    nn::batch::{matmul_acc_blocked, matmul_t_acc_blocked, outer_acc_batch_blocked},
    nn::matrix::MatRef,
    Result,
};

/// The AVX2 build of gman-core's kernels. Only reachable through [`avx2`], i.e. on a CPU that
/// has AVX2 (x86-64 only: elsewhere the host runs gman-core's portable build).
#[cfg(target_arch = "x86_64")]
#[derive(Debug)]
pub(crate) struct Avx2 {
    _private: (),
}

#[cfg(target_arch = "x86_64")]
static AVX2: Avx2 = Avx2 { _private: () };

/// The AVX2 kernel table if this CPU supports AVX2 (always `None` off x86-64).
pub fn avx2() -> Option<&'static dyn Kernels> {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx2") {
            return Some(&AVX2);
        }
    }
    None
}

/// The fastest kernel table for this CPU ([`avx2`]), unless `GMAN_KERNELS=portable` is set;
/// `None` means gman-core's portable build. Same bits in every case.
pub fn host_kernels() -> Option<&'static dyn Kernels> {
    if std::env::var("GMAN_KERNELS").is_ok_and(|v| v == "portable") {
        return None;
    }
    avx2()
}

/// `GMAN_KERNELS=avx2` in the environment: the AVX2 table without its AVX-VNNI form of the
/// integer kernel (the same integers; to compare speeds). Read once.
#[cfg(target_arch = "x86_64")]
fn no_vnni() -> bool {
    static NO: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *NO.get_or_init(|| std::env::var("GMAN_KERNELS").is_ok_and(|v| v == "avx2"))
}

/// Name of what [`host_kernels`] selects, for reports.
pub fn host_kernels_name() -> &'static str {
    if host_kernels().is_some() {
        "avx2"
    } else {
        "portable (sse2)"
    }
}

#[cfg(target_arch = "x86_64")]
impl Kernels for Avx2 {
    fn matmul_acc(&self, w: &MatRef<'_>, x: &[&[f32]], n: usize, y: &mut [f32]) -> Result<()> {
        // SAFETY: an `Avx2` is only handed out by `avx2()` after detecting AVX2.
        match unsafe { avx2_matmul::matmul_acc(w, x, n, y) } {
            Some(()) => Ok(()),
            // Shapes it does not take: the portable body names the error.
            None => matmul_acc_blocked::<2, 4>(w, x, n, y),
        }
    }

    fn matmul_t_acc(
        &self,
        w: &MatRef<'_>,
        dy: &[f32],
        n: usize,
        dx: &mut [&mut [f32]],
        col0: usize,
    ) -> Result<()> {
        // SAFETY: as above.
        unsafe { x86::matmul_t_acc(w, dy, n, dx, col0) }
    }

    fn outer_acc_batch(
        &self,
        dw: &mut [f32],
        dy: &[f32],
        x: &[&[f32]],
        n: usize,
        alpha: f32,
    ) -> Result<()> {
        // SAFETY: as above.
        unsafe { x86::outer_acc_batch(dw, dy, x, n, alpha) }
    }

    fn dots_i8(&self, q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
        // SAFETY: as above.
        unsafe { avx2_int8::dots_i8(q, cols, col0, xq, out) }
    }

    fn dots_i16(&self, q: &[u8], cols: usize, col0: usize, x: &[i16], out: &mut [i32]) {
        // SAFETY: as above.
        unsafe { avx2_int8::dots_i16(q, cols, col0, x, out) }
    }

    fn matvec_int8(&self, w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> bool {
        if std::is_x86_feature_detected!("avxvnni") && !no_vnni() {
            // SAFETY: AVX2 as above, AVX-VNNI detected just now.
            return unsafe { avx2_int8::matvec_int8_vnni(w, x, y) };
        }
        // SAFETY: as above.
        unsafe { avx2_int8::matvec_int8(w, x, y) }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2_int8;
#[cfg(target_arch = "x86_64")]
mod avx2_matmul;

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::*;

    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn matmul_t_acc(
        w: &MatRef<'_>,
        dy: &[f32],
        n: usize,
        dx: &mut [&mut [f32]],
        col0: usize,
    ) -> Result<()> {
        if n == 1 {
            matmul_t_acc_blocked::<8, 1>(w, dy, n, dx, col0)
        } else if n.is_multiple_of(4) {
            matmul_t_acc_blocked::<2, 4>(w, dy, n, dx, col0)
        } else {
            // Small batches (the Efficient inner update's pairs): 32 columns x 2 vectors.
            matmul_t_acc_blocked::<4, 2>(w, dy, n, dx, col0)
        }
    }

    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn outer_acc_batch(
        dw: &mut [f32],
        dy: &[f32],
        x: &[&[f32]],
        n: usize,
        alpha: f32,
    ) -> Result<()> {
        outer_acc_batch_blocked::<2, 4>(dw, dy, x, n, alpha)
    }
}

#[cfg(test)]
mod tests {
    use gman_core::nn::qkernel::{dots_i8, QCOLS};

    #[test]
    fn avx2_int8_dots_equal_the_portable_kernel() {
        let Some(k) = super::avx2() else {
            eprintln!("SKIPPED: no AVX2 on this CPU");
            return;
        };
        let mut state = 12345u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        for &(rows, cols, col0, len) in &[
            (1, 1, 0, 1),
            (3, 17, 1, 16),
            (5, 40, 3, 33),
            (64, 256, 0, 256),
            (7, 600, 100, QCOLS),
            (2, 300, 290, 10),
        ] {
            // Extremes included: -127 and 127 in every position class.
            let q: Vec<u8> = (0..rows * cols)
                .map(|i| match i % 7 {
                    0 => 127u8,
                    1 => (-127i8) as u8,
                    _ => ((next() % 255) as i32 - 127) as i8 as u8,
                })
                .collect();
            let xq: Vec<i8> = (0..len)
                .map(|j| match j % 5 {
                    0 => 127,
                    1 => -127,
                    _ => ((next() % 255) as i32 - 127) as i8,
                })
                .collect();
            let mut a = vec![0i32; rows];
            let mut b = vec![7i32; rows];
            dots_i8(&q, cols, col0, &xq, &mut a);
            k.dots_i8(&q, cols, col0, &xq, &mut b);
            assert_eq!(a, b, "rows {rows} cols {cols} col0 {col0} len {len}");
        }
    }

    /// Every length 0..=70 (all the 32-, 16- and 1-column steps and their mixes), the
    /// full block, row counts 0..=9 (four-row passes and every remainder), offsets into a
    /// wider matrix; random values and the extremes (all +-127, alternating signs, zeros),
    /// and inputs holding -128 (the widening fallback). Every integer is compared.
    #[test]
    fn avx2_int8_dots_every_length_and_row_count() {
        use gman_core::nn::qkernel::dots_i16;
        let Some(k) = super::avx2() else {
            eprintln!("SKIPPED: no AVX2 on this CPU");
            return;
        };
        let mut state = 0x9e37_79b9u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let lens: Vec<usize> = (0..=70).chain([95, 128, 200, 255, QCOLS]).collect();
        for &len in &lens {
            for rows in 0..=9usize {
                for pattern in 0..5 {
                    let col0 = (len * 7 + rows) % 5;
                    let cols = col0 + len + rows % 3;
                    // every weight byte, -128 (which the quantisation never makes) included
                    let wv = |i: usize, r: u32| -> u8 {
                        (match pattern {
                            0 => (r % 256) as i32 - 128,
                            1 => 127,
                            2 => -128,
                            3 => [127, -128][i % 2],
                            _ => [0, 127, -127, 1, -1, -128][i % 6],
                        }) as i8 as u8
                    };
                    let q: Vec<u8> = (0..rows * cols).map(|i| wv(i, next())).collect();
                    let mut xq: Vec<i8> = (0..len)
                        .map(|j| match pattern {
                            0 => ((next() % 255) as i32 - 127) as i8,
                            1 => 127,
                            2 => -127,
                            3 => [-127, 127][j % 2],
                            _ => [127, -127, 0][j % 3],
                        })
                        .collect();
                    let mut a = vec![0i32; rows];
                    let mut b = vec![7i32; rows];
                    dots_i8(&q, cols, col0, &xq, &mut a);
                    k.dots_i8(&q, cols, col0, &xq, &mut b);
                    assert_eq!(a, b, "i8: len {len} rows {rows} pattern {pattern}");
                    if len > 0 {
                        // An input of -128 (never made by the quantisation): the fallback.
                        xq[(next() as usize) % len] = i8::MIN;
                        dots_i8(&q, cols, col0, &xq, &mut a);
                        k.dots_i8(&q, cols, col0, &xq, &mut b);
                        assert_eq!(
                            a, b,
                            "i8 with -128: len {len} rows {rows} pattern {pattern}"
                        );
                    }
                    // The int16 kernel: products of two quantised values, their extremes,
                    // and any int16 (the kernel takes every weight byte and every int16).
                    let q16: Vec<u8> = (0..rows * cols)
                        .map(|i| {
                            if pattern == 4 {
                                [0x80u8, 0x7f][i % 2]
                            } else {
                                wv(i, next())
                            }
                        })
                        .collect();
                    let x16: Vec<i16> = (0..len)
                        .map(|j| match pattern {
                            0 => ((next() % 255) as i16 - 127) * ((next() % 255) as i16 - 127),
                            1 => 16129,
                            2 => -16129,
                            3 => next() as i16,
                            _ => [i16::MIN, i16::MAX][j % 2],
                        })
                        .collect();
                    let mut a = vec![0i32; rows];
                    let mut b = vec![7i32; rows];
                    dots_i16(&q16, cols, col0, &x16, &mut a);
                    k.dots_i16(&q16, cols, col0, &x16, &mut b);
                    assert_eq!(a, b, "i16: len {len} rows {rows} pattern {pattern}");
                }
            }
        }
    }

    /// The whole-layer call (`Kernels::matvec_int8`, reached through
    /// `qkernel::matvec_acc_int8` of a view with the AVX2 table) against gman-core's portable
    /// driver, bit for bit: row counts around the four-row passes and gman-core's 64-row
    /// chunks, segments of every kind of length (0, under 16, 16-, 32-column steps with
    /// tails, one and several `QCOLS` blocks), signed, non-negative, all-zero, tiny
    /// (subnormal scales), infinite and NaN segments, values on the rounding ties, F32 and
    /// little-endian scales, and a `y` that already holds values.
    #[test]
    fn avx2_whole_layer_int8_equals_the_portable_driver() {
        use gman_core::nn::matrix::{MatRef, Scales};
        use gman_core::nn::qkernel::{matvec_acc_int8, matvec_acc_int8_portable};
        let Some(k) = super::avx2() else {
            eprintln!("SKIPPED: no AVX2 on this CPU");
            return;
        };
        let mut state = 0x1234_5678u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let seg_sets: &[&[usize]] = &[
            &[1],
            &[5, 0, 7],
            &[16, 31, 33],
            &[45, 45],
            &[64, 64],
            &[256],
            &[257, 3],
            &[600, 70, 512],
            &[1000, 24, 1],
            &[4096],
        ];
        let (mut checked, mut vnni) = (0, 0);
        for (si, segs) in seg_sets.iter().enumerate() {
            let cols: usize = segs.iter().sum();
            for &rows in &[1usize, 2, 3, 4, 5, 7, 8, 9, 63, 64, 65, 67, 130] {
                if rows * cols > 600_000 {
                    continue;
                }
                for kind in 0..8 {
                    let q: Vec<u8> = (0..rows * cols)
                        .map(|i| match (kind + i) % 9 {
                            0 => 127u8,
                            1 => (-127i8) as u8,
                            2 => 0x80,
                            _ => next() as u8,
                        })
                        .collect();
                    let sc: Vec<f32> = (0..rows)
                        .map(|i| (1 + next() % 1000) as f32 * 1e-4 + i as f32 * 1e-7)
                        .collect();
                    let le: Vec<u8> = sc.iter().flat_map(|v| v.to_le_bytes()).collect();
                    let data: Vec<Vec<f32>> = segs
                        .iter()
                        .enumerate()
                        .map(|(s, &len)| {
                            (0..len)
                                .map(|j| {
                                    let u = (next() % 20001) as f32 / 10000.0 - 1.0;
                                    match (kind + s) % 8 {
                                        0 => u,
                                        1 => u.abs(),
                                        2 => 0.0,
                                        3 => u * 1e-41,
                                        4 if j % 37 == 5 => f32::INFINITY,
                                        4 => u,
                                        5 if j % 11 == 2 => f32::NAN,
                                        5 if j % 11 == 3 => -f32::INFINITY,
                                        5 => -u.abs(),
                                        // ties of the rounding: k + 0.5 of 127 / max
                                        6 => [127.0, -0.5, 0.5, 1.5, -2.5, 63.5, -0.0][j % 7],
                                        _ => [3.0, -3.0, 1.0 / 3.0][j % 3] * u,
                                    }
                                })
                                .collect()
                        })
                        .collect();
                    let x: Vec<&[f32]> = data.iter().map(|v| v.as_slice()).collect();
                    for scales in [Scales::F32(&sc), Scales::Le(&le)] {
                        let w = MatRef::i8(rows, cols, &q, scales)
                            .unwrap()
                            .with_int8_activations();
                        let y0: Vec<f32> = (0..rows).map(|i| (i as f32 - 3.0) * 0.25).collect();
                        let mut a = y0.clone();
                        let mut b = y0.clone();
                        matvec_acc_int8_portable(&w, &x, &mut a).unwrap();
                        matvec_acc_int8(&w.with_kernels(k), &x, &mut b).unwrap();
                        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                        assert_eq!(bits(&a), bits(&b), "set {si} rows {rows} kind {kind}");
                        let mut c = y0.clone();
                        assert!(k.matvec_int8(&w, &x, &mut c), "set {si} rows {rows}");
                        assert_eq!(bits(&a), bits(&c), "set {si} rows {rows} kind {kind}");
                        // Both forms whatever the table picks: plain AVX2 and AVX-VNNI.
                        let mut c = y0.clone();
                        // SAFETY: `avx2()` said this CPU has AVX2.
                        assert!(unsafe { super::avx2_int8::matvec_int8(&w, &x, &mut c) });
                        assert_eq!(bits(&a), bits(&c), "avx2: set {si} rows {rows} kind {kind}");
                        if std::is_x86_feature_detected!("avxvnni") {
                            let mut c = y0.clone();
                            // SAFETY: AVX2 as above, AVX-VNNI detected just now.
                            assert!(unsafe { super::avx2_int8::matvec_int8_vnni(&w, &x, &mut c) });
                            assert_eq!(
                                bits(&a),
                                bits(&c),
                                "vnni: set {si} rows {rows} kind {kind}"
                            );
                            vnni += 1;
                        }
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 500, "{checked}");
        eprintln!("{checked} layers compared, {vnni} with the AVX-VNNI form too");
    }

    #[test]
    fn avx2_map_layer_equals_the_portable_one() {
        use gman_core::nn::matrix::{MatRef, Scales};
        use gman_core::nn::qkernel::{cell_layer_int8, cell_layer_int8_portable};
        let Some(k) = super::avx2() else {
            eprintln!("SKIPPED: no AVX2 on this CPU");
            return;
        };
        let (rows, f, cells) = (8, 512, 9);
        let q: Vec<u8> = (0..rows * 2 * f)
            .map(|i| ((i * 97 % 255) as i32 - 127) as i8 as u8)
            .collect();
        let sc: Vec<f32> = (0..rows).map(|i| 0.01 + i as f32 * 1e-3).collect();
        let map: Vec<f32> = (0..cells * f)
            .map(|i| (i * 31 % 256) as f32 / 255.0)
            .collect();
        let x: Vec<f32> = (0..f).map(|j| (j as f32 * 0.7).sin().abs()).collect();
        let w = MatRef::i8(rows, 2 * f, &q, Scales::F32(&sc))
            .unwrap()
            .with_int8_activations();
        let mut a = vec![0.5f32; cells * rows];
        let mut b = a.clone();
        cell_layer_int8_portable(&w, &map, &x, &mut a).unwrap();
        cell_layer_int8(&w.with_kernels(k), &map, &x, &mut b).unwrap();
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a), bits(&b));
    }
}
