//! gman-core's integer kernels (`gman_core::qkernel`) with AVX2: the same integers, four
//! weight rows per pass sharing each input load.
//!
//! * [`dots_i8`]: `vpmaddubsw` takes unsigned bytes times signed bytes, so the sign of each
//!   weight moves onto the input (`vpsignb`): `w_j x_j = |w_j| * (sign(w_j) x_j)`. `vpabsb`
//!   of -128 is the byte 0x80, which `vpmaddubsw` reads as the unsigned 128, so every weight
//!   byte is exact; with `|x_j| <= 127` a pair of products is at most
//!   `2 * 128 * 127 = 32,512 < 2^15`, so the int16 sums never saturate; `vpmaddwd` by ones
//!   widens them into i32. 32 columns per step (then 16 with the 128-bit forms, then one by
//!   one). Exact for every weight byte and every input in `-127..=127` (the quantisation's
//!   range: an input block holding -128, which `vpsignb` cannot negate, runs the widening
//!   kernel [`dots_i8_wide`]).
//! * [`dots_i16`]: the map layer's int16 products times int8 weights, weights widened with
//!   `vpmovsxbw` and multiplied pairwise into i32 (`vpmaddwd`, exact for any int16 input).
//!
//! Integers are exact, so the order of the additions does not matter: every accumulator
//! equals the portable kernel's (`tests::avx2_int8_dots_equal_the_portable_kernel`,
//! `tests::avx2_i16_dots_equal_the_portable_kernel`).

use core::arch::x86_64::*;

use gman_core::qkernel::{dots_i16 as dots_i16_portable, dots_i8_body, QCOLS};

/// The four i32 lanes' sums of four accumulators, as `[s(a), s(b), s(c), s(d)]`.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn sum4(a: __m256i, b: __m256i, c: __m256i, d: __m256i) -> __m128i {
    let h = _mm256_hadd_epi32(_mm256_hadd_epi32(a, b), _mm256_hadd_epi32(c, d));
    _mm_add_epi32(_mm256_castsi256_si128(h), _mm256_extracti128_si256(h, 1))
}

/// The sum of the lanes of one accumulator.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn sum1(a: __m256i) -> i32 {
    let s = _mm_add_epi32(_mm256_castsi256_si128(a), _mm256_extracti128_si256(a, 1));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32(s, 0b01_00_11_10));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32(s, 0b10_11_00_01));
    _mm_cvtsi128_si32(s)
}

/// `|w| * (sign(w) x)` summed pairwise into i32 lanes (32 columns).
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn mac32(acc: __m256i, x: __m256i, w: *const u8, ones: __m256i) -> __m256i {
    let w = _mm256_loadu_si256(w as *const __m256i);
    let p = _mm256_maddubs_epi16(_mm256_abs_epi8(w), _mm256_sign_epi8(x, w));
    _mm256_add_epi32(acc, _mm256_madd_epi16(p, ones))
}

/// The same on 16 columns (128-bit forms), added into the low half of `acc`.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn mac16(acc: __m256i, x: __m128i, w: *const u8) -> __m256i {
    let w = _mm_loadu_si128(w as *const __m128i);
    let p = _mm_maddubs_epi16(_mm_abs_epi8(w), _mm_sign_epi8(x, w));
    let s = _mm_madd_epi16(p, _mm_set1_epi16(1));
    _mm256_add_epi32(acc, _mm256_inserti128_si256::<0>(_mm256_setzero_si256(), s))
}

/// Int8 weights widened to i16 times int16 inputs, summed pairwise into i32 lanes (16 columns).
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn mac(acc: __m256i, xv: __m256i, w: *const u8) -> __m256i {
    let w = _mm256_cvtepi8_epi16(_mm_loadu_si128(w as *const __m128i));
    _mm256_add_epi32(acc, _mm256_madd_epi16(w, xv))
}

/// `gman_core::qkernel::dots_i8` (see the module docs). `out.len()` rows of `q` (rows of
/// `cols` bytes), columns `col0 .. col0 + xq.len()`.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn dots_i8(q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
    let n = xq.len();
    let end = col0 + n;
    let rows = out.len();
    if cols == 0 || end > cols || n > QCOLS || q.len() / cols < rows {
        return dots_i8_body(q, cols, col0, xq, out);
    }
    if xq.contains(&i8::MIN) {
        return dots_i8_wide(q, cols, col0, xq, out);
    }
    let n32 = n - n % 32;
    let n16 = n - n % 16;
    // x per 32 columns, loaded once for every row.
    let mut xv = [_mm256_setzero_si256(); QCOLS / 32];
    for (c, v) in xv.iter_mut().enumerate().take(n32 / 32) {
        // SAFETY: 32 (c + 1) <= n32 <= xq.len().
        *v = _mm256_loadu_si256(xq.as_ptr().add(32 * c) as *const __m256i);
    }
    let x16 = if n16 > n32 {
        // SAFETY: n32 + 16 = n16 <= xq.len().
        _mm_loadu_si128(xq.as_ptr().add(n32) as *const __m128i)
    } else {
        _mm_setzero_si128()
    };
    let ones = _mm256_set1_epi16(1);
    let tail = |row: &[u8]| -> i32 {
        let mut t = 0i32;
        for (&w, &x) in row[n16..].iter().zip(&xq[n16..]) {
            t += (w as i8 as i32) * (x as i32);
        }
        t
    };
    let rows4 = rows - rows % 4;
    let mut r = 0;
    while r < rows4 {
        // Checked row slices: every load below stays inside them (j + 32 <= n32 <= n).
        let w0 = &q[r * cols + col0..r * cols + end];
        let w1 = &q[(r + 1) * cols + col0..(r + 1) * cols + end];
        let w2 = &q[(r + 2) * cols + col0..(r + 2) * cols + end];
        let w3 = &q[(r + 3) * cols + col0..(r + 3) * cols + end];
        let (mut a0, mut a1, mut a2, mut a3) = (
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
        );
        for (c, &x) in xv.iter().enumerate().take(n32 / 32) {
            let j = 32 * c;
            a0 = mac32(a0, x, w0.as_ptr().add(j), ones);
            a1 = mac32(a1, x, w1.as_ptr().add(j), ones);
            a2 = mac32(a2, x, w2.as_ptr().add(j), ones);
            a3 = mac32(a3, x, w3.as_ptr().add(j), ones);
        }
        if n16 > n32 {
            a0 = mac16(a0, x16, w0.as_ptr().add(n32));
            a1 = mac16(a1, x16, w1.as_ptr().add(n32));
            a2 = mac16(a2, x16, w2.as_ptr().add(n32));
            a3 = mac16(a3, x16, w3.as_ptr().add(n32));
        }
        let s = sum4(a0, a1, a2, a3);
        let mut v = [0i32; 4];
        _mm_storeu_si128(v.as_mut_ptr() as *mut __m128i, s);
        if n16 < n {
            v[0] += tail(w0);
            v[1] += tail(w1);
            v[2] += tail(w2);
            v[3] += tail(w3);
        }
        out[r..r + 4].copy_from_slice(&v);
        r += 4;
    }
    while r < rows {
        let w0 = &q[r * cols + col0..r * cols + end];
        let mut a0 = _mm256_setzero_si256();
        for (c, &x) in xv.iter().enumerate().take(n32 / 32) {
            a0 = mac32(a0, x, w0.as_ptr().add(32 * c), ones);
        }
        if n16 > n32 {
            a0 = mac16(a0, x16, w0.as_ptr().add(n32));
        }
        out[r] = sum1(a0) + tail(w0);
        r += 1;
    }
}

/// `gman_core::qkernel::dots_i8` for any input byte (-128 included): the input widened to
/// i16 once, then per row 16 weights at a time sign-extended (`vpmovsxbw`) and multiplied
/// pairwise into i32 (`vpmaddwd`).
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn dots_i8_wide(q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
    let n = xq.len();
    if cols == 0 || col0 + n > cols || n > QCOLS {
        return dots_i8_body(q, cols, col0, xq, out);
    }
    let mut xw = [0i16; QCOLS];
    for (d, &s) in xw.iter_mut().zip(xq) {
        *d = s as i16;
    }
    dots_i16(q, cols, col0, &xw[..n], out)
}

/// `gman_core::qkernel::dots_i16`: int8 weights times an int16 input block, four rows per
/// pass, 16 columns per step (`vpmovsxbw` + `vpmaddwd`), the last `len % 16` one by one.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn dots_i16(q: &[u8], cols: usize, col0: usize, x: &[i16], out: &mut [i32]) {
    let n = x.len();
    let end = col0 + n;
    let rows = out.len();
    if cols == 0 || end > cols || n > QCOLS || q.len() / cols < rows {
        return dots_i16_portable(q, cols, col0, x, out);
    }
    let n16 = n - n % 16;
    let tail = |row: &[u8]| -> i32 {
        let mut t = 0i32;
        for (&w, &v) in row[n16..].iter().zip(&x[n16..]) {
            t += (w as i8 as i32) * (v as i32);
        }
        t
    };
    let rows4 = rows - rows % 4;
    let mut r = 0;
    while r < rows4 {
        // Checked row slices: every load below stays inside them (j + 16 <= n16 <= n).
        let w0 = &q[r * cols + col0..r * cols + end];
        let w1 = &q[(r + 1) * cols + col0..(r + 1) * cols + end];
        let w2 = &q[(r + 2) * cols + col0..(r + 2) * cols + end];
        let w3 = &q[(r + 3) * cols + col0..(r + 3) * cols + end];
        let (mut a0, mut a1, mut a2, mut a3) = (
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
            _mm256_setzero_si256(),
        );
        let mut j = 0;
        while j < n16 {
            let xv = _mm256_loadu_si256(x.as_ptr().add(j) as *const __m256i);
            a0 = mac(a0, xv, w0.as_ptr().add(j));
            a1 = mac(a1, xv, w1.as_ptr().add(j));
            a2 = mac(a2, xv, w2.as_ptr().add(j));
            a3 = mac(a3, xv, w3.as_ptr().add(j));
            j += 16;
        }
        let s = sum4(a0, a1, a2, a3);
        let mut v = [0i32; 4];
        _mm_storeu_si128(v.as_mut_ptr() as *mut __m128i, s);
        if n16 < n {
            v[0] += tail(w0);
            v[1] += tail(w1);
            v[2] += tail(w2);
            v[3] += tail(w3);
        }
        out[r..r + 4].copy_from_slice(&v);
        r += 4;
    }
    while r < rows {
        let w0 = &q[r * cols + col0..r * cols + end];
        let mut a0 = _mm256_setzero_si256();
        let mut j = 0;
        while j < n16 {
            let xv = _mm256_loadu_si256(x.as_ptr().add(j) as *const __m256i);
            a0 = mac(a0, xv, w0.as_ptr().add(j));
            j += 16;
        }
        out[r] = sum1(a0) + tail(w0);
        r += 1;
    }
}
