//! The integer kernels against their f32 reading and the canonical order, bit for bit.

use super::*;
use crate::rng::Xoshiro128 as Rng;
use rand_core::RngCore;

fn rand_i8(rng: &mut Rng, n: usize) -> [u8; 32768] {
    let mut v = [0u8; 32768];
    for b in v.iter_mut().take(n) {
        *b = ((rng.next_u32() % 255) as i32 - 127) as i8 as u8;
    }
    v
}

#[test]
fn row_blocked_kernel_gives_the_portable_integers() {
    let mut rng = Rng::seed_from_u64(7);
    for &(rows, cols, col0, len) in &[
        (1, 1, 0, 1),
        (3, 7, 2, 5),
        (4, 8, 0, 8),
        (9, 33, 1, 31),
        (13, 64, 0, 64),
        (6, 300, 44, 256),
    ] {
        let q = rand_i8(&mut rng, rows * cols);
        let xb = rand_i8(&mut rng, len);
        let xq: [i8; 256] = core::array::from_fn(|j| xb[j] as i8);
        let mut a = [0i32; 16];
        let mut b = [1i32; 16];
        dots_i8(&q[..rows * cols], cols, col0, &xq[..len], &mut a[..rows]);
        dots_i8_rows(&q[..rows * cols], cols, col0, &xq[..len], &mut b[..rows]);
        assert_eq!(a[..rows], b[..rows], "rows {rows} cols {cols}");
        // Against a plain double loop.
        for r in 0..rows {
            let want: i32 = (0..len)
                .map(|j| (q[r * cols + col0 + j] as i8 as i32) * (xq[j] as i32))
                .sum();
            assert_eq!(a[r], want);
        }
    }
}

#[test]
fn dsp_kernel_gives_the_portable_integers() {
    // Off DSP targets `gman_dsp::dots2` is its model of SXTB16 / SMLAD; the firmware's
    // self-test runs the same comparison with the `asm!` kernel under QEMU.
    let mut rng = Rng::seed_from_u64(11);
    for &(rows, cols, col0, len) in &[
        (1, 1, 0, 1),
        (2, 8, 0, 8),
        (3, 7, 2, 5),
        (5, 45, 0, 45),
        (7, 90, 45, 45),
        (8, 1024, 512, 256),
        (9, 33, 1, 31),
        (13, 64, 0, 64),
        (6, 300, 44, 256),
        (4, 30, 3, 24),
    ] {
        let q = rand_i8(&mut rng, rows * cols);
        let xb = rand_i8(&mut rng, len);
        let mut xq: [i8; 256] = core::array::from_fn(|j| xb[j] as i8);
        xq[0] = -127;
        if len > 1 {
            xq[len - 1] = 127;
        }
        let mut xp = [0u32; QWORDS];
        let packed = gman_dsp::pack(&xq[..len], &mut xp);
        let mut a = [0i32; 16];
        let mut b = [1i32; 16];
        dots_i8(&q[..rows * cols], cols, col0, &xq[..len], &mut a[..rows]);
        dots_i8_dsp(
            &q[..rows * cols],
            cols,
            col0,
            &xq[..len],
            &xp[..packed / 2],
            &mut b[..rows],
        );
        assert_eq!(a[..rows], b[..rows], "rows {rows} cols {cols} col0 {col0}");
    }
}

#[test]
fn dsp_driver_gives_the_portable_bits() {
    let mut rng = Rng::seed_from_u64(5);
    let (rows, cols) = (67, 301);
    let qb = rand_i8(&mut rng, rows * cols);
    let sc: [f32; 67] = core::array::from_fn(|i| 0.02 + i as f32 * 1e-4);
    let w = MatRef::i8(rows, cols, &qb[..rows * cols], Scales::F32(&sc)).unwrap();
    let mut le = [0u8; 4 * 67];
    for (b, s) in le.chunks_exact_mut(4).zip(&sc) {
        b.copy_from_slice(&s.to_le_bytes());
    }
    let wl = MatRef::i8(rows, cols, &qb[..rows * cols], Scales::Le(&le)).unwrap();
    // Segments: non-negative, signed, with an infinity and a NaN, all zero.
    let mut x: [f32; 301] = core::array::from_fn(|j| libm::sinf(j as f32 * 0.71) * 3.0);
    for v in &mut x[..37] {
        *v = libm::fabsf(*v);
    }
    x[50] = f32::INFINITY;
    x[51] = f32::NAN;
    x[52] = -0.0;
    for v in &mut x[290..] {
        *v = 0.0;
    }
    let segs: [&[f32]; 4] = [&x[..37], &x[37..45], &x[45..290], &x[290..]];
    let mut y = [0.25f32; 67];
    matvec_acc_int8_portable(&w, &segs, &mut y).unwrap();
    for m in [&w, &wl] {
        let mut yd = [0.25f32; 67];
        matvec_acc_int8_dsp(m, &segs, &mut yd).unwrap();
        assert_eq!(y.map(f32::to_bits), yd.map(f32::to_bits));
    }
}

/// The quantisation as first written (float comparisons), the reference of the faster
/// forms.
fn quantize_reference(v: f32, inv: f32) -> i32 {
    let t = v * inv;
    let r = if t >= 0.0 { t + 0.5 } else { t - 0.5 };
    (r as i32).clamp(-127, 127)
}

fn scale_reference(x: &[f32]) -> f32 {
    let mut a = 0.0f32;
    for &v in x {
        let m = libm::fabsf(v);
        if m > a && m != f32::INFINITY {
            a = m;
        }
    }
    a
}

#[test]
fn fast_quantisation_is_the_reference() {
    // A stride through all 2^32 bit patterns (every exponent, both signs, NaNs,
    // infinities, subnormals), against several scales, and the ties k + 0.5.
    let invs = [
        1.0f32,
        127.0,
        0.37,
        1e-3,
        3.0e5,
        f32::from_bits(0x3f80_0001),
    ];
    let mut bits = 0u32;
    loop {
        let v = f32::from_bits(bits);
        for &inv in &invs {
            let want = quantize_reference(v, inv);
            assert_eq!(quantize_one(v, inv), want, "v {v:e} inv {inv}");
            if bits >> 31 == 0 {
                assert_eq!(quantize_nonneg(v, inv), want, "v {v:e} inv {inv}");
            }
        }
        match bits.checked_add(65_521) {
            Some(b) => bits = b,
            None => break,
        }
    }
    for k in -130i32..=130 {
        let v = k as f32 + 0.5;
        assert_eq!(quantize_one(v, 1.0), quantize_reference(v, 1.0), "{v}");
        assert_eq!(quantize_one(-v, 1.0), quantize_reference(-v, 1.0), "{v}");
    }
    // The range on the bit patterns is the float maximum over finite values.
    let mut rng = Rng::seed_from_u64(9);
    for case in 0..200 {
        let mut x = [0.0f32; 40];
        for v in x.iter_mut() {
            *v = f32::from_bits(rng.next_u32());
        }
        if case % 3 == 0 {
            x[case % 40] = f32::INFINITY;
        }
        if case % 5 == 0 {
            x[(case + 7) % 40] = f32::NAN;
        }
        let n = case % 41;
        let a = scale_reference(&x[..n]);
        let (sx, inv, nonneg) = act_range(&x[..n]);
        if a > 0.0 {
            assert_eq!((sx, inv), (a / 127.0, 127.0 / a), "case {case}");
        } else {
            assert_eq!((sx, inv), (0.0, 0.0));
        }
        assert_eq!(nonneg, x[..n].iter().all(|v| v.to_bits() >> 31 == 0));
    }
}

#[test]
fn quantisation_rounds_half_away_and_saturates() {
    let x = [
        1.0f32,
        -1.0,
        0.5 / 127.0,
        -0.5 / 127.0,
        f32::NAN,
        f32::INFINITY,
        0.25,
    ];
    let (sx, inv) = act_scale(&x);
    assert_eq!(sx, 1.0 / 127.0);
    let mut p = [0i8; 7];
    quantize_act(&x, inv, &mut p);
    assert_eq!(p, [127, -127, 1, -1, 0, 127, 32]);
    assert_eq!(act_scale(&[0.0, -0.0]), (0.0, 0.0));
}

#[test]
fn int8_matvec_is_close_to_f32_and_blocks_add_in_order() {
    let mut rng = Rng::seed_from_u64(3);
    let (rows, cols) = (70, 300);
    let qb = rand_i8(&mut rng, rows * cols);
    let q = &qb[..rows * cols];
    let sc: [f32; 70] = core::array::from_fn(|i| 0.01 + i as f32 * 1e-4);
    let w = MatRef::i8(rows, cols, q, Scales::F32(&sc)).unwrap();
    let x: [f32; 300] = core::array::from_fn(|j| libm::sinf(j as f32 * 0.37) * 2.0);
    let (x1, x2) = x.split_at(40);
    let mut y = [0.5f32; 70];
    matvec_acc_int8_portable(&w, &[x1, x2], &mut y).unwrap();
    let mut yr = [0.5f32; 70];
    matvec_acc_int8(&w, &[x1, x2], &mut yr).unwrap();
    assert_eq!(y.map(f32::to_bits), yr.map(f32::to_bits));
    // Close to the f32 product.
    let mut yf = [0.5f32; 70];
    w.matvec_acc(&[x1, x2], &mut yf).unwrap();
    // Within the rounding bound: |x_j - p_j s_x| <= s_x / 2 for every input.
    let (s1, s2) = (act_scale(x1).0, act_scale(x2).0);
    for (i, (a, b)) in y.iter().zip(&yf).enumerate() {
        let bound: f32 = (0..cols)
            .map(|j| {
                let sx = if j < 40 { s1 } else { s2 };
                (q[i * cols + j] as i8 as f32).abs() * sc[i] * sx / 2.0
            })
            .sum();
        assert!(
            (a - b).abs() <= bound * 1.01 + 1e-4,
            "{a} vs {b} (bound {bound})"
        );
    }
    // The canonical formula, written out.
    let mut want = [0.5f32; 70];
    for (seg, off) in [(x1, 0usize), (x2, 40)] {
        let (sx, inv) = act_scale(seg);
        let mut p = [0i8; 300];
        quantize_act(seg, inv, &mut p[..seg.len()]);
        for (b, c0) in (0..seg.len()).step_by(QCOLS).enumerate() {
            let len = (seg.len() - c0).min(QCOLS);
            for (i, wi) in want.iter_mut().enumerate() {
                let acc: i32 = (0..len)
                    .map(|j| (q[i * cols + off + b * QCOLS + j] as i8 as i32) * (p[c0 + j] as i32))
                    .sum();
                *wi += (acc as f32) * (sx * sc[i]);
            }
        }
    }
    assert_eq!(y.map(f32::to_bits), want.map(f32::to_bits));
}

/// A segment's kept terms added in its place give the bits of quantising it again, for
/// a segment of two blocks, one of one block and one of zeros (no block), with a bias of
/// `-0.0` (which adding a `+0.0` would change); a bad cache is refused.
#[test]
fn kept_segment_terms_give_the_bits_of_recomputing() {
    let mut rng = Rng::seed_from_u64(9);
    let (rows, cols) = (70, 300 + 45 + 20);
    let qb = rand_i8(&mut rng, rows * cols);
    let q = &qb[..rows * cols];
    let sc: [f32; 70] = core::array::from_fn(|i| 0.01 + i as f32 * 1e-4);
    let w = MatRef::i8(rows, cols, q, Scales::F32(&sc)).unwrap();
    let x: [f32; 300] = core::array::from_fn(|j| libm::sinf(j as f32 * 0.37) * 2.0);
    let a: [f32; 45] = core::array::from_fn(|j| libm::cosf(j as f32) * 0.3);
    let z = [0.0f32; 20];
    let segs: [&[f32]; 3] = [&x, &a, &z];
    let bias: [f32; 70] = core::array::from_fn(|i| if i % 3 == 0 { -0.0 } else { 0.25 });
    let mut want = bias;
    matvec_acc_int8(&w, &segs, &mut want).unwrap();
    let (mut tx, mut ta, mut tz) = ([0.0f32; 140], [0.0f32; 70], [0.0f32; 70]);
    assert_eq!(segment_blocks(300), 2);
    assert_eq!(segment_terms_int8(&w, 0, &x, &mut tx).unwrap(), 2);
    assert_eq!(segment_terms_int8(&w, 300, &a, &mut ta).unwrap(), 1);
    assert_eq!(segment_terms_int8(&w, 345, &z, &mut tz).unwrap(), 0);
    fn t(terms: &[f32], blocks: usize) -> Option<SegTerms<'_>> {
        Some(SegTerms { terms, blocks })
    }
    for cached in [
        [t(&tx, 2), None, None],
        [None, t(&ta, 1), t(&tz, 0)],
        [t(&tx, 2), t(&ta, 1), t(&tz, 0)],
    ] {
        let mut y = bias;
        matvec_acc_int8_terms(&w, &segs, &cached, &mut y).unwrap();
        assert_eq!(y.map(f32::to_bits), want.map(f32::to_bits));
    }
    // Too few terms, more blocks than the segment has, a segment past the last column.
    let mut y = bias;
    assert!(matvec_acc_int8_terms(&w, &segs, &[t(&tx[..70], 2), None, None], &mut y).is_err());
    assert!(matvec_acc_int8_terms(&w, &segs, &[None, t(&tx, 2), None], &mut y).is_err());
    assert!(matvec_acc_int8_terms(&w, &segs, &[None, None], &mut y).is_err());
    assert!(segment_terms_int8(&w, 330, &a, &mut ta).is_err());
    assert!(segment_terms_int8(&w, 0, &x, &mut tx[..139]).is_err());
}

/// A map layer: `rows x 2f` int8 weights, `cells` cells (some all zero, some signed).
fn cell_case(rng: &mut Rng, rows: usize, f: usize, cells: usize) -> ([u8; 32768], [f32; 64]) {
    assert!(rows * 2 * f <= 32768 && rows <= 64 && cells * f <= 8192);
    let mut q = rand_i8(rng, rows * 2 * f);
    q[0] = 0x80; // -128
    let sc: [f32; 64] = core::array::from_fn(|i| 0.015 + i as f32 * 1e-4);
    (q, sc)
}

fn cell_inputs(f: usize, cells: usize, signed_x: bool) -> ([f32; 8192], [f32; 512]) {
    let mut map = [0.0f32; 8192];
    for (i, v) in map[..cells * f].iter_mut().enumerate() {
        *v = (((i * 37) % 256) as f32) / 255.0;
    }
    // An all-zero cell, a signed one.
    if cells > 2 {
        map[f..2 * f].fill(0.0);
        for v in &mut map[2 * f..3 * f] {
            *v -= 0.4;
        }
    }
    let x: [f32; 512] = core::array::from_fn(|j| {
        let v = libm::sinf(j as f32 * 0.53) * 1.7;
        if signed_x {
            v
        } else {
            libm::fabsf(v)
        }
    });
    (map, x)
}

#[test]
fn cell_layer_dsp_gives_the_portable_bits_and_the_formula() {
    let mut rng = Rng::seed_from_u64(21);
    for &(rows, f, cells, signed_x) in &[
        (8, 512, 9, false),
        (9, 300, 18, true),
        (3, 7, 20, false),
        (1, 1, 2, true),
        (5, 257, 3, true),
    ] {
        let (q, sc) = cell_case(&mut rng, rows, f, cells);
        let q = &q[..rows * 2 * f];
        let w = MatRef::i8(rows, 2 * f, q, Scales::F32(&sc[..rows])).unwrap();
        let mut le = [0u8; 4 * 64];
        for (b, s) in le.chunks_exact_mut(4).zip(&sc) {
            b.copy_from_slice(&s.to_le_bytes());
        }
        let wl = MatRef::i8(rows, 2 * f, q, Scales::Le(&le[..4 * rows])).unwrap();
        let (map, x) = cell_inputs(f, cells, signed_x);
        let (map, x) = (&map[..cells * f], &x[..f]);
        let n = cells * rows;
        let mut y = [0.125f32; 512];
        cell_layer_int8_portable(&w, map, x, &mut y[..n]).unwrap();
        for m in [&w, &wl] {
            let mut yd = [0.125f32; 512];
            cell_layer_int8_dsp(m, map, x, &mut yd[..n]).unwrap();
            for k in 0..n {
                assert_eq!(y[k].to_bits(), yd[k].to_bits(), "rows {rows} f {f} k {k}");
            }
            let mut yt = [0.125f32; 512];
            cell_layer_int8(m, map, x, &mut yt[..n]).unwrap();
            for k in 0..n {
                assert_eq!(y[k].to_bits(), yt[k].to_bits(), "rows {rows} f {f} k {k}");
            }
        }
        // The canonical formula, written out.
        let (sx, xinv) = act_scale(x);
        let mut px = [0i8; 512];
        quantize_act(x, xinv, &mut px[..f]);
        for c in 0..cells {
            let m = &map[c * f..(c + 1) * f];
            let (sm, minv) = act_scale(m);
            let mut pm = [0i8; 512];
            quantize_act(m, minv, &mut pm[..f]);
            for i in 0..rows {
                let mut want = 0.125f32;
                if sm > 0.0 {
                    for c0 in (0..f).step_by(QCOLS) {
                        let len = (f - c0).min(QCOLS);
                        let w = |j: usize| q[i * 2 * f + j] as i8 as i32;
                        let a: i32 = (c0..c0 + len).map(|j| w(j) * pm[j] as i32).sum();
                        want += (a as f32) * (sm * sc[i]);
                        if sx > 0.0 {
                            let a: i32 = (c0..c0 + len)
                                .map(|j| w(f + j) * (pm[j] as i32 * px[j] as i32))
                                .sum();
                            want += (a as f32) * ((sm * sx) * sc[i]);
                        }
                    }
                }
                assert_eq!(
                    y[c * rows + i].to_bits(),
                    want.to_bits(),
                    "cell {c} row {i}"
                );
            }
            // Close to the f32 layer: |m x - pm px sm sx| <= (|m| sx + |x| sm) / 2 + sm sx / 4.
            let mut prod = [0.0f32; 512];
            for j in 0..f {
                prod[j] = m[j] * x[j];
            }
            let mut yf = [0.125f32; 64];
            MatRef::i8(rows, 2 * f, q, Scales::F32(&sc[..rows]))
                .unwrap()
                .matvec_acc(&[m, &prod[..f]], &mut yf[..rows])
                .unwrap();
            for i in 0..rows {
                let bound: f32 = (0..f)
                    .map(|j| {
                        let wm = (q[i * 2 * f + j] as i8 as f32).abs() * sc[i];
                        let wp = (q[i * 2 * f + f + j] as i8 as f32).abs() * sc[i];
                        wm * sm / 2.0
                            + wp * ((m[j].abs() * sx + x[j].abs() * sm) / 2.0 + sm * sx / 4.0)
                    })
                    .sum();
                let got = y[c * rows + i];
                assert!(
                    (got - yf[i]).abs() <= bound * 1.01 + 1e-4,
                    "{got} vs {} ({bound})",
                    yf[i]
                );
            }
        }
    }
}

#[test]
fn products_multiply_half_by_half() {
    for &(a, b) in &[(127i32, -127i32), (-127, -127), (0, 5), (-1, 1), (64, 2)] {
        let wa = gman_dsp::pair_words([a, -a, b, a]);
        let wb = gman_dsp::pair_words([b, b, -a, 1]);
        let want = gman_dsp::pair_words([a * b, -a * b, -b * a, a]);
        assert_eq!(mul_halves(wa[0], wb[0]), want[0]);
        assert_eq!(mul_halves(wa[1], wb[1]), want[1]);
    }
}

#[test]
fn f32_views_are_refused() {
    let w = MatRef::f32(1, 1, &[1.0]).unwrap();
    let mut y = [0.0];
    assert!(matvec_acc_int8(&w, &[&[1.0]], &mut y).is_err());
}
