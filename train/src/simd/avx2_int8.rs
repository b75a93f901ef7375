//! gman-core's integer kernels (`gman_core::nn::qkernel`) with AVX2: the same integers, four
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

use gman_core::nn::matrix::{seg_len, MatRef, Scales, Weights};
use gman_core::nn::qkernel::{
    act_range, dots_i16 as dots_i16_portable, dots_i8_body, quantize_one, QCOLS,
};

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

/// `gman_core::nn::qkernel::dots_i8` (see the module docs). `out.len()` rows of `q` (rows of
/// `cols` bytes), columns `col0 .. col0 + xq.len()`: [`dots4`] four rows per pass.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn dots_i8(q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
    if !rows_fit(q, cols, col0, xq.len(), out.len()) {
        return dots_i8_body(q, cols, col0, xq, out);
    }
    if xq.contains(&i8::MIN) {
        return dots_i8_wide(q, cols, col0, xq, out);
    }
    dots_rows(q, cols, col0, xq, out)
}

/// `gman_core::nn::qkernel::dots_i8` for any input byte (-128 included): the input widened to
/// i16 once, then per row 16 weights at a time sign-extended (`vpmovsxbw`) and multiplied
/// pairwise into i32 (`vpmaddwd`). Reached only from [`dots_i8`] after [`rows_fit`], so
/// `xq.len() <= QCOLS`; [`dots_i16`] checks the shapes again.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
unsafe fn dots_i8_wide(q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
    let mut xw = [0i16; QCOLS];
    for (d, &s) in xw.iter_mut().zip(xq) {
        *d = s as i16;
    }
    dots_i16(q, cols, col0, &xw[..xq.len()], out)
}

/// `gman_core::nn::qkernel::dots_i16`: int8 weights times an int16 input block, four rows per
/// pass ([`dots4_i16`]), 16 columns per step (`vpmovsxbw` + `vpmaddwd`), the last
/// `len % 16` one by one.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn dots_i16(q: &[u8], cols: usize, col0: usize, x: &[i16], out: &mut [i32]) {
    if !rows_fit(q, cols, col0, x.len(), out.len()) {
        return dots_i16_portable(q, cols, col0, x, out);
    }
    dots_rows(q, cols, col0, x, out)
}

/// True when `q` holds `rows` rows of `cols` bytes whose columns `col0 .. col0 + n` exist,
/// with `n <= QCOLS` (the shapes [`dots_rows`] takes).
fn rows_fit(q: &[u8], cols: usize, col0: usize, n: usize, rows: usize) -> bool {
    cols > 0 && col0 + n <= cols && n <= QCOLS && q.len() / cols >= rows
}

/// An input element of the integer dot products, with its four-row and one-row kernels.
trait Input: Copy + Into<i32> {
    /// The dot products of the four rows at `w`, `w + stride`, .. with the `n` inputs at `x`.
    ///
    /// # Safety
    /// AVX2; the four rows' `n` bytes and the `n` inputs readable.
    unsafe fn dots4(w: *const u8, stride: usize, x: *const Self, n: usize) -> __m128i;
    /// The same for one row.
    ///
    /// # Safety
    /// As [`Input::dots4`], for one row.
    unsafe fn dots1(w: *const u8, x: *const Self, n: usize) -> i32;
}

/// Int8 inputs in `-127..=127` (the caller sends an input holding -128 to
/// [`dots_i8_wide`]).
impl Input for i8 {
    #[inline(always)]
    unsafe fn dots4(w: *const u8, stride: usize, x: *const i8, n: usize) -> __m128i {
        dots4::<false>(w, stride, x, n)
    }
    #[inline(always)]
    unsafe fn dots1(w: *const u8, x: *const i8, n: usize) -> i32 {
        dots1::<false>(w, x, n)
    }
}

impl Input for i16 {
    #[inline(always)]
    unsafe fn dots4(w: *const u8, stride: usize, x: *const i16, n: usize) -> __m128i {
        dots4_i16(w, stride, x, n)
    }
    #[inline(always)]
    unsafe fn dots1(w: *const u8, x: *const i16, n: usize) -> i32 {
        let mut a = _mm256_setzero_si256();
        let mut j = 0;
        while j + 16 <= n {
            a = mac(a, _mm256_loadu_si256(x.add(j) as *const __m256i), w.add(j));
            j += 16;
        }
        sum1(a) + tail([w], x, j, n)[0]
    }
}

/// `out[r]` = row `r`'s dot product with `x` (columns `col0 ..`), four rows per pass, then
/// the rest one by one.
///
/// # Safety
/// AVX2, and [`rows_fit`]`(q, cols, col0, x.len(), out.len())`.
#[inline(always)]
unsafe fn dots_rows<X: Input>(q: &[u8], cols: usize, col0: usize, x: &[X], out: &mut [i32]) {
    let (n, rows) = (x.len(), out.len());
    let mut r = 0;
    while r + 4 <= rows {
        // SAFETY: rows r .. r + 4 <= rows of `cols` bytes are in `q`, and their columns
        // col0 .. col0 + n within each (`rows_fit`); out[r .. r + 4] is in `out`.
        let s = X::dots4(q.as_ptr().add(r * cols + col0), cols, x.as_ptr(), n);
        _mm_storeu_si128(out.as_mut_ptr().add(r) as *mut __m128i, s);
        r += 4;
    }
    while r < rows {
        // SAFETY: as above, for the one row r < rows.
        out[r] = X::dots1(q.as_ptr().add(r * cols + col0), x.as_ptr(), n);
        r += 1;
    }
}

/// The `R` rows' products over the last columns `j .. n`, one by one.
///
/// # Safety
/// Columns `j .. n` of the `R` rows at `w` and of the inputs at `x` readable.
#[inline(always)]
unsafe fn tail<X: Input, const R: usize>(
    w: [*const u8; R],
    x: *const X,
    mut j: usize,
    n: usize,
) -> [i32; R] {
    let mut t = [0i32; R];
    while j < n {
        let xj: i32 = (*x.add(j)).into();
        for (tk, wk) in t.iter_mut().zip(w) {
            *tk += (*wk.add(j) as i8 as i32) * xj;
        }
        j += 1;
    }
    t
}

/// The four rows' sums: their accumulators' lanes plus their last columns `j .. n` one by
/// one ([`tail`]).
///
/// # Safety
/// AVX2; columns `j .. n` of the four rows at `w` and of the inputs at `x` readable.
#[inline(always)]
unsafe fn finish4<X: Input>(
    a: [__m256i; 4],
    w: [*const u8; 4],
    x: *const X,
    j: usize,
    n: usize,
) -> __m128i {
    let s = sum4(a[0], a[1], a[2], a[3]);
    if j == n {
        return s;
    }
    let t = tail(w, x, j, n);
    _mm_add_epi32(s, _mm_loadu_si128(t.as_ptr() as *const __m128i))
}

/// [`Input::dots4`] of int16 inputs: 16 columns per step (`vpmovsxbw` + `vpmaddwd`, exact
/// for any int16), the last `n % 16` one by one.
///
/// # Safety
/// As [`Input::dots4`].
#[inline(always)]
unsafe fn dots4_i16(w: *const u8, stride: usize, x: *const i16, n: usize) -> __m128i {
    let (w0, w1, w2, w3) = (w, w.add(stride), w.add(2 * stride), w.add(3 * stride));
    let [mut a0, mut a1, mut a2, mut a3] = [_mm256_setzero_si256(); 4];
    let mut j = 0;
    while j + 16 <= n {
        let xv = _mm256_loadu_si256(x.add(j) as *const __m256i);
        a0 = mac(a0, xv, w0.add(j));
        a1 = mac(a1, xv, w1.add(j));
        a2 = mac(a2, xv, w2.add(j));
        a3 = mac(a3, xv, w3.add(j));
        j += 16;
    }
    finish4([a0, a1, a2, a3], [w0, w1, w2, w3], x, j, n)
}

/// Most columns of a layer [`matvec_int8`] takes (its quantised input is a stack buffer of
/// this many bytes); wider layers, or more than [`MV_SEGS`] segments, run gman-core's driver.
const MV_COLS: usize = 16384;
/// Weight bytes from which [`matvec_int8`] prefetches the next rows (a layer of this size
/// is not expected to stay in the L2 cache between steps).
const PREFETCH_BYTES: usize = 1 << 18;
/// Most input segments [`matvec_int8`] takes.
const MV_SEGS: usize = 16;

/// `gman_core::nn::qkernel::act_range`'s `(s_x, inv)`: the largest magnitude on the bit patterns
/// (`vpmaxud` of `bits & 0x7fff_ffff`, the integer order of finite magnitudes is their
/// numeric order), then the same two divisions. A segment holding an infinity or a NaN
/// takes gman-core's own function (its second pass skips them).
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
unsafe fn act_scale(x: &[f32]) -> (f32, f32) {
    let n8 = x.len() - x.len() % 8;
    let mask = _mm256_set1_epi32(0x7fff_ffff);
    let mut m = _mm256_setzero_si256();
    let mut i = 0;
    while i < n8 {
        // SAFETY: i + 8 <= n8 <= x.len().
        let b = _mm256_loadu_si256(x.as_ptr().add(i) as *const __m256i);
        m = _mm256_max_epu32(m, _mm256_and_si256(b, mask));
        i += 8;
    }
    let h = _mm_max_epu32(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
    let h = _mm_max_epu32(h, _mm_shuffle_epi32(h, 0b01_00_11_10));
    let h = _mm_max_epu32(h, _mm_shuffle_epi32(h, 0b10_11_00_01));
    let mut mx = _mm_cvtsi128_si32(h) as u32;
    for &v in &x[n8..] {
        mx = mx.max(v.to_bits() & 0x7fff_ffff);
    }
    if mx >= 0x7f80_0000 {
        let (sx, inv, _) = act_range(x);
        return (sx, inv);
    }
    let a = f32::from_bits(mx);
    if a > 0.0 {
        (a / 127.0, 127.0 / a)
    } else {
        (0.0, 0.0)
    }
}

/// Eight values quantised as `gman_core::nn::qkernel::quantize_one` does: `t = v * inv`,
/// `m = min(trunc(|t| + 0.5), 127)` with the sign of `t` put back. The clamp runs on the
/// float before the conversion, `vminps(127, u)`, which returns `u` when it is a NaN, and
/// `vcvttps2dq` of a NaN is `i32::MIN`, which the `max(.., 0)` makes 0, as `as i32` does;
/// an infinite `u` becomes 127, as the saturating `as i32` and the clamp do.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn quant8(v: __m256, inv: __m256) -> __m256i {
    let t = _mm256_mul_ps(v, inv);
    let abs = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
    let u = _mm256_add_ps(_mm256_and_ps(t, abs), _mm256_set1_ps(0.5));
    let u = _mm256_min_ps(_mm256_set1_ps(127.0), u);
    let m = _mm256_max_epi32(_mm256_cvttps_epi32(u), _mm256_setzero_si256());
    let s = _mm256_srai_epi32::<31>(_mm256_castps_si256(t));
    _mm256_sub_epi32(_mm256_xor_si256(m, s), s)
}

/// `gman_core::nn::qkernel::quantize_act` of `x` into the `x.len()` bytes at `out`: 32 values
/// per step, narrowed with `vpackssdw` / `vpacksswb` (values within +-127: no saturation)
/// and put back in order with `vpermd`; the last `len % 32` with `quantize_one`. `out` may
/// be uninitialised memory (it is only written).
///
/// # Safety
/// The CPU must support AVX2; `out` must be valid for writes of `x.len()` bytes.
#[target_feature(enable = "avx2")]
unsafe fn quantize(x: &[f32], inv: f32, out: *mut i8) {
    let n = x.len();
    let n32 = n - n % 32;
    let vinv = _mm256_set1_ps(inv);
    let order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let mut i = 0;
    while i < n32 {
        // SAFETY: i + 32 <= n32 <= n, within `x` and the `n` bytes at `out`.
        let p = x.as_ptr().add(i);
        let q0 = quant8(_mm256_loadu_ps(p), vinv);
        let q1 = quant8(_mm256_loadu_ps(p.add(8)), vinv);
        let q2 = quant8(_mm256_loadu_ps(p.add(16)), vinv);
        let q3 = quant8(_mm256_loadu_ps(p.add(24)), vinv);
        let b = _mm256_packs_epi16(_mm256_packs_epi32(q0, q1), _mm256_packs_epi32(q2, q3));
        let b = _mm256_permutevar8x32_epi32(b, order);
        _mm256_storeu_si256(out.add(i) as *mut __m256i, b);
        i += 32;
    }
    for (j, &v) in x.iter().enumerate().skip(n32) {
        // SAFETY: j < n, within the `n` bytes at `out`.
        out.add(j).write(quantize_one(v, inv) as i8);
    }
}

/// [`mac32`] with AVX-VNNI: `vpdpbusd` multiplies the same unsigned `|w|` by the signed
/// `sign(w) x` and adds each four products into an i32 lane (at most `4 * 128 * 127` per
/// step, no int16 intermediate; the sums wrap only past i32, far above `QCOLS` columns).
#[target_feature(enable = "avx2,avxvnni")]
#[inline]
unsafe fn mac32_vnni(acc: __m256i, x: __m256i, w: *const u8) -> __m256i {
    let w = _mm256_loadu_si256(w as *const __m256i);
    _mm256_dpbusd_avx_epi32(acc, _mm256_abs_epi8(w), _mm256_sign_epi8(x, w))
}

/// One 32-column step of a row: [`mac32_vnni`] when `VNNI` (the caller's CPU has AVX-VNNI),
/// else [`mac32`]; the same integers.
///
/// # Safety
/// AVX2 (and AVX-VNNI when `VNNI`); 32 readable bytes at `w`.
#[inline(always)]
unsafe fn step32<const VNNI: bool>(acc: __m256i, x: __m256i, w: *const u8) -> __m256i {
    if VNNI {
        mac32_vnni(acc, x, w)
    } else {
        mac32(acc, x, w, _mm256_set1_epi16(1))
    }
}

/// The integer dot products of four rows (`w`, `w + stride`, ..) with `n <= QCOLS` inputs
/// in `-127..=127` (the quantisation's range), as `[s0, s1, s2, s3]`.
///
/// # Safety
/// The CPU must support AVX2 (and AVX-VNNI when `VNNI`); the four rows' `n` bytes and the
/// `n` inputs must be readable.
#[inline(always)]
unsafe fn dots4<const VNNI: bool>(w: *const u8, stride: usize, x: *const i8, n: usize) -> __m128i {
    let (w0, w1, w2, w3) = (w, w.add(stride), w.add(2 * stride), w.add(3 * stride));
    let [mut a0, mut a1, mut a2, mut a3] = [_mm256_setzero_si256(); 4];
    let mut j = 0;
    while j + 32 <= n {
        let xv = _mm256_loadu_si256(x.add(j) as *const __m256i);
        a0 = step32::<VNNI>(a0, xv, w0.add(j));
        a1 = step32::<VNNI>(a1, xv, w1.add(j));
        a2 = step32::<VNNI>(a2, xv, w2.add(j));
        a3 = step32::<VNNI>(a3, xv, w3.add(j));
        j += 32;
    }
    if j + 16 <= n {
        let xv = _mm_loadu_si128(x.add(j) as *const __m128i);
        a0 = mac16(a0, xv, w0.add(j));
        a1 = mac16(a1, xv, w1.add(j));
        a2 = mac16(a2, xv, w2.add(j));
        a3 = mac16(a3, xv, w3.add(j));
        j += 16;
    }
    finish4([a0, a1, a2, a3], [w0, w1, w2, w3], x, j, n)
}

/// [`dots4`] of one row.
///
/// # Safety
/// As [`dots4`], for one row.
#[inline(always)]
unsafe fn dots1<const VNNI: bool>(w: *const u8, x: *const i8, n: usize) -> i32 {
    let mut a = _mm256_setzero_si256();
    let mut j = 0;
    while j + 32 <= n {
        a = step32::<VNNI>(a, _mm256_loadu_si256(x.add(j) as *const __m256i), w.add(j));
        j += 32;
    }
    if j + 16 <= n {
        a = mac16(a, _mm_loadu_si128(x.add(j) as *const __m128i), w.add(j));
        j += 16;
    }
    sum1(a) + tail([w], x, j, n)[0]
}

/// `gman_core::nn::qkernel::matvec_acc_int8` in one call (`Kernels::matvec_int8`): every
/// segment's scale ([`act_scale`]) and quantisation ([`quantize`]) first, into one buffer,
/// then four rows at a time, each row read once from its first column to its last: per
/// segment whose scale is not 0 and per block of `QCOLS` columns of it, in order, the four
/// integer sums ([`dots4`]) and `y_i += (acc_i as f32) * (s_x * s_i)` on four lanes
/// (`vcvtdq2ps` rounds to nearest like `as f32`; then `vmulps`, `vmulps`, `vaddps`: the
/// driver's operations in its order, for each `y_i`). The same bits as the driver; `false`
/// (nothing written) for shapes it does not take.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn matvec_int8(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> bool {
    matvec_body::<false>(w, x, y)
}

/// [`matvec_int8`] with AVX-VNNI's `vpdpbusd` in the 32-column steps (the same integers).
///
/// # Safety
/// The CPU must support AVX2 and AVX-VNNI.
#[target_feature(enable = "avx2,avxvnni")]
pub(super) unsafe fn matvec_int8_vnni(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> bool {
    matvec_body::<true>(w, x, y)
}

/// The body of [`matvec_int8`] and [`matvec_int8_vnni`].
///
/// # Safety
/// The CPU must support AVX2 (and AVX-VNNI when `VNNI`).
#[inline(always)]
unsafe fn matvec_body<const VNNI: bool>(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> bool {
    let (rows, cols) = (w.rows(), w.cols());
    let Weights::I8 { q, scales } = w.weights() else {
        return false;
    };
    // The scales as f32 at `sp` (little-endian bytes are the f32 of an x86 CPU), read with
    // unaligned loads only.
    let (sp, ns) = match scales {
        Scales::F32(s) => (s.as_ptr(), s.len()),
        Scales::Le(b) => (b.as_ptr() as *const f32, b.len() / 4),
    };
    if cols == 0
        || cols > MV_COLS
        || x.len() > MV_SEGS
        || seg_len(x) != cols
        || y.len() != rows
        || ns < rows
        || q.len() / cols < rows
    {
        return false;
    }
    // The quantised input, written by `quantize` before it is read: only the columns of the
    // segments in `segs` are read, and `quantize` wrote all of those (no zeroing of 16 KiB
    // per call).
    let mut xq = core::mem::MaybeUninit::<[i8; MV_COLS]>::uninit();
    let xw = xq.as_mut_ptr() as *mut i8;
    let mut segs = [(0usize, 0usize, 0.0f32); MV_SEGS];
    let mut nseg = 0;
    let mut off = 0;
    for seg in x {
        let (sx, inv) = act_scale(seg);
        if sx > 0.0 {
            // SAFETY: off + seg.len() <= cols <= MV_COLS bytes of `xq`.
            quantize(seg, inv, xw.add(off));
            segs[nseg] = (off, seg.len(), sx);
            nseg += 1;
        }
        off += seg.len();
    }
    let segs = &segs[..nseg];
    let (qp, xp) = (q.as_ptr(), xw as *const i8);
    let rows4 = rows - rows % 4;
    let prefetch = rows * cols >= PREFETCH_BYTES;
    let mut r = 0;
    while r < rows4 {
        // SAFETY: rows r..r + 4 < rows of `cols` bytes are within `q` (checked above), the
        // scales r..r + 4 within the `ns >= rows` at `sp`, y[r..r + 4] within `y`; every
        // block (off + b, n) lies within its segment's columns, within `cols` and `xq`.
        let wr = qp.add(r * cols);
        let mut yv = _mm_loadu_ps(y.as_ptr().add(r));
        let s4 = _mm_loadu_ps(sp.add(r));
        for &(off, len, sx) in segs {
            let f = _mm_mul_ps(_mm_set1_ps(sx), s4);
            let mut b = 0;
            while b < len {
                let n = (len - b).min(QCOLS);
                // A large layer (not resident in L2): the next four rows' lines of this block
                // (a hint: it never faults, and the address is formed with `wrapping_add`, so
                // past the last row is harmless).
                let next = wr.wrapping_add(4 * cols + off + b);
                for k in 0..if prefetch { 4 } else { 0 } {
                    let mut l = 0;
                    while l < n {
                        _mm_prefetch::<_MM_HINT_T0>(next.wrapping_add(k * cols + l) as *const i8);
                        l += 64;
                    }
                }
                let acc = dots4::<VNNI>(wr.add(off + b), cols, xp.add(off + b), n);
                yv = _mm_add_ps(yv, _mm_mul_ps(_mm_cvtepi32_ps(acc), f));
                b += QCOLS;
            }
        }
        _mm_storeu_ps(y.as_mut_ptr().add(r), yv);
        r += 4;
    }
    while r < rows {
        // SAFETY: as above, for the one row r < rows.
        let wr = qp.add(r * cols);
        let si = sp.add(r).read_unaligned();
        let mut yi = y[r];
        for &(off, len, sx) in segs {
            let mut b = 0;
            while b < len {
                let n = (len - b).min(QCOLS);
                let acc = dots1::<VNNI>(wr.add(off + b), xp.add(off + b), n);
                yi += (acc as f32) * (sx * si);
                b += QCOLS;
            }
        }
        y[r] = yi;
        r += 1;
    }
    true
}
