//! `y += W x` for AVX2 with the canonical reduction tree in vector registers.
//!
//! gman-core's `matmul_acc_blocked` fixes the order of every dot product: eight accumulators
//! (accumulator `k` sums the products of elements `8 c + k`, chunks `c` in order, multiply
//! then add), the tree `((a0 + a4) + (a1 + a5)) + ((a2 + a6) + (a3 + a7))`, the segment's
//! tail elements added one by one in order, the segments' sums added in order to a total
//! that starts at +0, and `y += total` (times the row scale for int8). Compiled for AVX2 the
//! eight accumulators of one dot product sit in one register, and the portable body ends
//! each dot product with a scalar tree (eight loads, seven dependent adds): for the short
//! rows of the LSTM (64 columns) and G's first layer (45 + 45) that costs as much as the
//! products. Here the tile's eight dot products (`R` rows x `B` vectors, `R B <= 8`) end
//! together: the same additions, on the same operands, as three vector steps —
//!
//! ```text
//! step 1  (a_k + a_{k+4})         perm2f128 of two accumulators: lo half + hi half
//! step 2  (s_0 + s_1), (s_2 + s_3)  hadd of two step-1 results
//! step 3  (h_0 + h_1)               hadd of two step-2 results: lanes [0 2 4 6 1 3 5 7]
//! ```
//!
//! so every lane holds exactly the canonical value of its dot product (the tests in
//! `host-sim/tests/avx2_parity.rs` compare the bits with the portable build on every weight
//! storage and many shapes, infinities and NaN included). No fused multiply-add: only
//! `avx2` is enabled, and the intrinsics are separate `mul` and `add`.

use core::arch::x86_64::*;

use gman_core::nn::matrix::{MatRef, Scales, Weights};

/// Most segments of an input (gman-core's `batch::MAX_SEGS`).
const MAX_SEGS: usize = gman_core::nn::batch::MAX_SEGS;

/// One storage kind of weights: eight weights (or one) of a row segment as f32, exactly as
/// gman-core converts them (f32 copy, little-endian decode, i8 -> f32).
trait Kind {
    /// Raw unit of storage.
    type R: Copy;
    /// Raw units per weight.
    const U: usize;
    /// Weights `8 c .. 8 c + 8` of a row segment starting at `p`.
    ///
    /// # Safety
    /// `p` must point to at least `8 (c + 1)` weights, and AVX2 must be available.
    unsafe fn w8(p: *const Self::R, c: usize) -> __m256;
    /// Weight `j` of a row segment.
    fn w1(s: &[Self::R], j: usize) -> f32;
}

struct F32K;
impl Kind for F32K {
    type R = f32;
    const U: usize = 1;
    #[inline(always)]
    unsafe fn w8(p: *const f32, c: usize) -> __m256 {
        _mm256_loadu_ps(p.add(8 * c))
    }
    #[inline(always)]
    fn w1(s: &[f32], j: usize) -> f32 {
        s[j]
    }
}

struct LeK;
impl Kind for LeK {
    type R = u8;
    const U: usize = 4;
    #[inline(always)]
    unsafe fn w8(p: *const u8, c: usize) -> __m256 {
        // x86-64 is little-endian: the bytes are the f32 values.
        _mm256_loadu_ps(p.add(32 * c).cast::<f32>())
    }
    #[inline(always)]
    fn w1(s: &[u8], j: usize) -> f32 {
        f32::from_le_bytes([s[4 * j], s[4 * j + 1], s[4 * j + 2], s[4 * j + 3]])
    }
}

struct I8K;
impl Kind for I8K {
    type R = u8;
    const U: usize = 1;
    #[inline(always)]
    unsafe fn w8(p: *const u8, c: usize) -> __m256 {
        let q = _mm_loadl_epi64(p.add(8 * c).cast::<__m128i>());
        _mm256_cvtepi32_ps(_mm256_cvtepi8_epi32(q))
    }
    #[inline(always)]
    fn w1(s: &[u8], j: usize) -> f32 {
        s[j] as i8 as f32
    }
}

/// `y += W x` for `n` vectors of batch-major segments `x` (gman-core's `batch::matmul_acc`
/// contract, the same bits). `None` when the shapes are not the ones that function accepts
/// silently: the caller then runs the portable body, which reports the error.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn matmul_acc(
    w: &MatRef<'_>,
    x: &[&[f32]],
    n: usize,
    y: &mut [f32],
) -> Option<()> {
    let (rows, cols) = (w.rows(), w.cols());
    if n.checked_mul(rows)? != y.len() || x.len() > MAX_SEGS {
        return None;
    }
    if n == 0 || cols == 0 {
        return Some(());
    }
    let mut lens = [0usize; MAX_SEGS];
    for (l, s) in lens.iter_mut().zip(x) {
        *l = s.len() / n;
    }
    if lens.iter().sum::<usize>() != cols {
        return None;
    }
    let lens = &lens[..x.len()];
    match w.weights() {
        Weights::F32(d) => all::<F32K>(d, cols, None, rows, x, lens, n, y),
        Weights::F32Le(d) => all::<LeK>(d, cols, None, rows, x, lens, n, y),
        Weights::I8 { q, scales } => all::<I8K>(q, cols, Some(scales), rows, x, lens, n, y),
    }
    Some(())
}

/// Every tile: `8 x 1` for one vector, else `2 x 4`, with `1 x B`, `R x 1`, `1 x 1` tiles
/// for the remainders.
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn all<K: Kind>(
    d: &[K::R],
    cols: usize,
    scales: Option<Scales<'_>>,
    rows: usize,
    x: &[&[f32]],
    lens: &[usize],
    n: usize,
    y: &mut [f32],
) {
    let t = Tiles::<K> {
        d,
        cols,
        scales,
        rows,
        x,
        lens,
    };
    if n == 1 {
        t.run::<8, 1>(n, y);
    } else {
        t.run::<2, 4>(n, y);
    }
}

/// The operands of one `y += W x`.
struct Tiles<'a, 'x, K: Kind> {
    d: &'a [K::R],
    cols: usize,
    scales: Option<Scales<'a>>,
    rows: usize,
    x: &'x [&'x [f32]],
    lens: &'x [usize],
}

impl<K: Kind> Tiles<'_, '_, K> {
    #[target_feature(enable = "avx2")]
    unsafe fn run<const R: usize, const B: usize>(&self, n: usize, y: &mut [f32]) {
        let rb = self.rows / R * R;
        let nb = n / B * B;
        let mut r0 = 0;
        while r0 < rb {
            let mut b0 = 0;
            while b0 < nb {
                self.tile::<R, B>(r0, b0, y);
                b0 += B;
            }
            while b0 < n {
                self.tile::<R, 1>(r0, b0, y);
                b0 += 1;
            }
            r0 += R;
        }
        while r0 < self.rows {
            let mut b0 = 0;
            while b0 < nb {
                self.tile::<1, B>(r0, b0, y);
                b0 += B;
            }
            while b0 < n {
                self.tile::<1, 1>(r0, b0, y);
                b0 += 1;
            }
            r0 += 1;
        }
    }

    /// Rows `r0 .. r0 + R` x vectors `b0 .. b0 + B` (`R B <= 8`; lane `r B + b`).
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn tile<const R: usize, const B: usize>(&self, r0: usize, b0: usize, y: &mut [f32]) {
        let mut tot = _mm256_setzero_ps();
        let mut off = 0;
        for (seg, &l) in self.x.iter().zip(self.lens) {
            let n8 = l / 8;
            // Checked slices: the loads below stay inside them (c < n8, 8 n8 <= l).
            // (Loops, not `array::from_fn`: its closures would not inherit AVX2, and the
            // intrinsics in them would be calls.)
            let mut ws: [&[K::R]; R] = [&[]; R];
            for (r, wr) in ws.iter_mut().enumerate() {
                let s = ((r0 + r) * self.cols + off) * K::U;
                *wr = &self.d[s..s + l * K::U];
            }
            let mut xs: [&[f32]; B] = [&[]; B];
            for (b, xb) in xs.iter_mut().enumerate() {
                *xb = &seg[(b0 + b) * l..(b0 + b + 1) * l];
            }
            let mut acc = [_mm256_setzero_ps(); 8];
            for c in 0..n8 {
                let mut xv = [_mm256_setzero_ps(); B];
                for (v, xb) in xv.iter_mut().zip(&xs) {
                    *v = _mm256_loadu_ps(xb.as_ptr().add(8 * c));
                }
                for r in 0..R {
                    let wv = K::w8(ws[r].as_ptr(), c);
                    for b in 0..B {
                        acc[r * B + b] = _mm256_add_ps(acc[r * B + b], _mm256_mul_ps(wv, xv[b]));
                    }
                }
            }
            let mut s = tree8(&acc);
            if 8 * n8 < l {
                // The tail, element by element in order (as the portable body).
                let mut v = [0.0f32; 8];
                _mm256_storeu_ps(v.as_mut_ptr(), s);
                for r in 0..R {
                    for b in 0..B {
                        let t = &mut v[r * B + b];
                        for (j, &xj) in xs[b].iter().enumerate().skip(8 * n8) {
                            *t += K::w1(ws[r], j) * xj;
                        }
                    }
                }
                s = _mm256_loadu_ps(v.as_ptr());
            }
            tot = _mm256_add_ps(tot, s);
            off += l;
        }
        let mut t = [0.0f32; 8];
        _mm256_storeu_ps(t.as_mut_ptr(), tot);
        for r in 0..R {
            let sc = self.scales.map(|s| s.get(r0 + r));
            for b in 0..B {
                let o = &mut y[(b0 + b) * self.rows + r0 + r];
                match sc {
                    None => *o += t[r * B + b],
                    Some(s) => *o += t[r * B + b] * s,
                }
            }
        }
    }
}

/// The canonical tree of each of eight accumulator registers, lane `i` from `a[i]` (see the
/// module docs for why every lane's additions are those of gman-core's `tree`).
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn tree8(a: &[__m256; 8]) -> __m256 {
    // Step 1: [a_i0 + a_i4, .., a_i3 + a_i7 | a_j0 + a_j4, ..] for the pairs (i, j).
    macro_rules! fold {
        ($p:expr, $q:expr) => {
            _mm256_add_ps(
                _mm256_permute2f128_ps::<0x20>($p, $q),
                _mm256_permute2f128_ps::<0x31>($p, $q),
            )
        };
    }
    let s01 = fold!(a[0], a[1]);
    let s23 = fold!(a[2], a[3]);
    let s45 = fold!(a[4], a[5]);
    let s67 = fold!(a[6], a[7]);
    // Step 2: [(s0 + s1), (s2 + s3)] of accumulators 0, 2 | 1, 3 (and 4, 6 | 5, 7).
    let h0 = _mm256_hadd_ps(s01, s23);
    let h1 = _mm256_hadd_ps(s45, s67);
    // Step 3: lanes [0 2 4 6 | 1 3 5 7], put back in order.
    let h = _mm256_hadd_ps(h0, h1);
    _mm256_permutevar8x32_ps(h, _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7))
}
