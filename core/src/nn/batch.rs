//! Batched dense kernels: one matrix `W` against `n` vectors at once, and the register- and
//! cache-blocked bodies every dense kernel of the crate runs on (the batch-1 kernels of
//! [`MatRef`] are these with `n = 1`).
//!
//! A batch of `n` vectors is stored **batch-major**: vector `b` of a segment of length `len`
//! is `seg[b * len .. (b + 1) * len]`, so a batch of inputs given as segments is a list of
//! `n x len_s` row-major blocks (the same segment convention as [`crate::nn::matrix`]).
//!
//! # Contract: the same bits as the batch-1 kernels
//! Every kernel here gives, for every vector `b` of the batch, exactly the bits the
//! corresponding batch-1 kernel of [`MatRef`] gives for that vector alone, and
//! [`outer_acc_batch`] gives exactly the bits of calling [`outer_acc`] for
//! `b = 0, 1, .., n - 1` in that order. A batch is therefore a pure speed-up: results,
//! training runs and the host/device parity do not depend on how work is batched. The unit
//! tests below pin this contract against a plain transcription of the canonical order
//! ([`crate::nn::matrix::dot`], [`crate::nn::matrix::axpy`]).
//!
//! # The canonical order, and how the blocked bodies keep it
//! * `y = W x`: per (row, vector, segment) eight accumulators over the segment's chunks of
//!   eight, the fixed tree `((a0+a4)+(a1+a5))+((a2+a6)+(a3+a7))`, then the tail in order;
//!   the segment sums are added to `0.0` in segment order, then to `y` (after the int8 row
//!   scale). The blocked body computes `R` rows x `B` vectors of these at once (each weight
//!   chunk is loaded and converted once for `B` vectors, each input chunk once for `R`
//!   rows), which changes which dot products run side by side, never the operations inside
//!   one.
//! * `dx += W^T dy` and `dW += alpha dy x^T`: every output element is a sequence of
//!   `+= c * w` over rows (resp. vectors) in ascending order, with no reduction. The blocked
//!   bodies keep a tile of `8 C` columns x `B` vectors (resp. `R` rows) in registers and walk
//!   the rows (resp. vectors) in order.
//! * Multiply and add are always separate (Rust never contracts `a * b + c` into an FMA), so
//!   the bits are the same whatever the vector width the compiler picks: SSE2, AVX2 (see
//!   [`Kernels`]) or the Cortex-M4F's scalar FPU.
//!
//! The block shapes (`R`, `B`, `C`) are const parameters of the `*_blocked` functions; they
//! change speed only. [`matmul_acc`], [`matmul_t_acc`] and [`outer_acc_batch`] use shapes
//! that fit the 16 vector registers of baseline x86-64 and the Cortex-M4F's 32 single
//! registers; a host can compile the same bodies for a wider instruction set and install
//! them on a matrix view with [`MatRef::with_kernels`].

use crate::error::{check_len, Result};
pub use crate::nn::matrix::Kernels;
use crate::nn::matrix::{axpy, axpy_i8, dot, dot_i8, dot_le, seg_len, MatRef, Scales, Weights};

/// Most segments a batched input may have (the layers use at most four).
pub const MAX_SEGS: usize = 8;

/// The batch-1 kernels of a matrix view: [`MatRef::matvec_acc`] and its transposes are the
/// batched bodies below with `n = 1` (the Cortex-M4F runs its own loops in the same
/// canonical order, see [`matvec_acc_pairs`] and [`matmul_t_acc_rows`]).
impl MatRef<'_> {
    /// `y += W x`, where the input `x` is given as consecutive segments.
    pub fn matvec_acc(&self, x: &[&[f32]], y: &mut [f32]) -> Result<()> {
        check_len("matvec.x", self.cols(), seg_len(x))?;
        check_len("matvec.y", self.rows(), y.len())?;
        if self.cols() == 0 {
            return Ok(());
        }
        if self.int8_activations() {
            return crate::nn::qkernel::matvec_acc_int8(self, x, y);
        }
        if !crate::nn::qkernel::F32_ACTIVATIONS && self.is_int8() {
            return Err(crate::nn::qkernel::NO_F32_ACTIVATIONS);
        }
        if x.len() > MAX_SEGS {
            self.matvec_acc_many(x, y);
            return Ok(());
        }
        // The Cortex-M4F (no vector unit): two rows at a time, the same canonical order,
        // fewer instructions there than the hosts' blocked body (measured in QEMU).
        if cfg!(target_arch = "arm") {
            return matvec_acc_pairs(self, x, y);
        }
        match self.kernels() {
            Some(k) => k.matmul_acc(&self.without_kernels(), x, 1, y),
            None => matmul_acc_blocked::<MV_R, 1>(self, x, 1, y),
        }
    }

    /// [`MatRef::matvec_t_acc_cols`] one row at a time (the Cortex-M4F's loop for
    /// little-endian f32 weights; the same order as the blocked body: every element sums its
    /// rows in order).
    fn matvec_t_rowwise(&self, dy: &[f32], col0: usize, dx: &mut [f32]) {
        let end = col0 + dx.len();
        match self.weights() {
            Weights::F32(d) => {
                for (row, &g) in d.chunks_exact(self.cols()).zip(dy) {
                    axpy(g, &row[col0..end], dx);
                }
            }
            Weights::F32Le(d) => {
                for (row, &g) in d.chunks_exact(4 * self.cols()).zip(dy) {
                    for (o, b) in dx.iter_mut().zip(row[4 * col0..4 * end].chunks_exact(4)) {
                        *o += g * f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                    }
                }
            }
            Weights::I8 { q, scales } => {
                for (i, (row, &g)) in q.chunks_exact(self.cols()).zip(dy).enumerate() {
                    axpy_i8(g * scales.get(i), &row[col0..end], dx);
                }
            }
        }
    }

    /// [`MatRef::matvec_acc`] one row at a time: for more than [`MAX_SEGS`] segments, and on
    /// the Cortex-M4F for f32 weights (the same canonical order as the blocked body).
    fn matvec_acc_many(&self, x: &[&[f32]], y: &mut [f32]) {
        // (Without `f32-activations` its callers refuse int8 weights first.)
        if !crate::nn::qkernel::F32_ACTIVATIONS && self.is_int8() {
            return;
        }
        match self.weights() {
            Weights::F32(d) => {
                for (row, yi) in d.chunks_exact(self.cols()).zip(y.iter_mut()) {
                    let mut acc = 0.0f32;
                    let mut off = 0;
                    for seg in x {
                        acc += dot(&row[off..off + seg.len()], seg);
                        off += seg.len();
                    }
                    *yi += acc;
                }
            }
            Weights::F32Le(d) => {
                for (row, yi) in d.chunks_exact(4 * self.cols()).zip(y.iter_mut()) {
                    let mut acc = 0.0f32;
                    let mut off = 0;
                    for seg in x {
                        acc += dot_le(&row[4 * off..4 * (off + seg.len())], seg);
                        off += seg.len();
                    }
                    *yi += acc;
                }
            }
            Weights::I8 { q, scales } => {
                for (i, (row, yi)) in q.chunks_exact(self.cols()).zip(y.iter_mut()).enumerate() {
                    let mut acc = 0.0f32;
                    let mut off = 0;
                    for seg in x {
                        acc += dot_i8(&row[off..off + seg.len()], seg);
                        off += seg.len();
                    }
                    *yi += acc * scales.get(i);
                }
            }
        }
    }

    /// `dx += W^T dy`, where `dx` is given as consecutive segments (the input gradient of a
    /// layer whose input was segmented the same way). To compute the gradient of only one
    /// column block, use [`MatRef::matvec_t_acc_cols`].
    pub fn matvec_t_acc(&self, dy: &[f32], dx: &mut [&mut [f32]]) -> Result<()> {
        let total: usize = dx.iter().map(|s| s.len()).sum();
        check_len("matvec_t.dx", self.cols(), total)?;
        check_len("matvec_t.dy", self.rows(), dy.len())?;
        let mut off = 0;
        for seg in dx.iter_mut() {
            let n = seg.len();
            self.matvec_t_acc_cols(dy, off, seg)?;
            off += n;
        }
        Ok(())
    }

    /// `dx += (W[:, col0 .. col0 + dx.len()])^T dy`: the input gradient of one column block.
    pub fn matvec_t_acc_cols(&self, dy: &[f32], col0: usize, dx: &mut [f32]) -> Result<()> {
        check_len("matvec_t.dy", self.rows(), dy.len())?;
        if col0.saturating_add(dx.len()) > self.cols() {
            return Err(crate::Error::Shape(crate::ShapeError {
                what: "matvec_t.cols",
                expected: self.cols(),
                actual: col0.saturating_add(dx.len()),
            }));
        }
        if self.cols() == 0 {
            return Ok(());
        }
        // The Cortex-M4F: 8 columns at a time over blocks of rows whose coefficients are
        // computed once (`matmul_t_acc_rows`).
        if cfg!(target_arch = "arm") {
            return matmul_t_acc_rows::<1>(self, dy, 1, &mut [dx], col0);
        }
        match self.kernels() {
            Some(k) => k.matmul_t_acc(&self.without_kernels(), dy, 1, &mut [dx], col0),
            None => matmul_t_acc_blocked::<MVT_C, 1>(self, dy, 1, &mut [dx], col0),
        }
    }
}

// Block shapes of the batch-1 kernels on hosts (speed only, never the bits): four rows per
// pass share each input load (16 vector registers on x86-64).
const MV_R: usize = 4;
const MVT_C: usize = 4;
const OUTER_R: usize = 2;
// Block shapes of the Cortex-M4F's loops (rows x vectors x lanes of accumulators; see
// `matmul_acc_lanes`), measured in QEMU.
const ARM_MM_R: usize = 2;
const ARM_MM_B: usize = 2;
const ARM_MM_L: usize = 4;
const OUTER_C: usize = 2;

/// `dW += alpha * dy x^T` for an f32 gradient matrix `dW` (`dy.len() x cols`, row-major), with
/// `x` given as segments. This is the weight gradient of `y = W x`.
pub fn outer_acc(dw: &mut [f32], dy: &[f32], x: &[&[f32]], alpha: f32) -> Result<()> {
    let cols = seg_len(x);
    check_len("outer.dw", dy.len().saturating_mul(cols), dw.len())?;
    if cols == 0 {
        return Ok(());
    }
    if x.len() > MAX_SEGS || cfg!(target_arch = "arm") {
        for (row, &g) in dw.chunks_exact_mut(cols).zip(dy) {
            let a = alpha * g;
            if a == 0.0 {
                continue;
            }
            let mut off = 0;
            for seg in x {
                axpy(a, seg, &mut row[off..off + seg.len()]);
                off += seg.len();
            }
        }
        return Ok(());
    }
    outer_acc_batch_blocked::<OUTER_R, OUTER_C>(dw, dy, x, 1, alpha)
}

/// The per-vector segment lengths of one segmented vector (a batch of `n = 1`), to call a
/// batched function with; at most [`MAX_SEGS`] segments.
pub fn seg_lens(lens: impl ExactSizeIterator<Item = usize>) -> Result<[usize; MAX_SEGS]> {
    if lens.len() > MAX_SEGS {
        check_len("batch.segments", MAX_SEGS, lens.len())?;
    }
    let mut out = [0usize; MAX_SEGS];
    for (o, l) in out.iter_mut().zip(lens) {
        *o = l;
    }
    Ok(out)
}

/// Checks a batch-major segmented input: at most [`MAX_SEGS`] segments, one per-vector length
/// per segment, segment `s` holding `n * lens[s]` values, lengths adding up to `cols`.
fn check_batch(
    what: &'static str,
    seg_totals: impl ExactSizeIterator<Item = usize>,
    lens: &[usize],
    n: usize,
    cols: usize,
) -> Result<()> {
    check_len(what, lens.len(), seg_totals.len())?;
    if lens.len() > MAX_SEGS {
        return check_len(what, MAX_SEGS, lens.len());
    }
    for (t, &l) in seg_totals.zip(lens) {
        check_len(what, l.saturating_mul(n), t)?;
    }
    check_len(what, cols, lens.iter().sum())
}

/// `Y[b] += W X[b]` for `b in 0..n`: `x` are batch-major segments whose per-vector lengths add
/// up to `W.cols()`, `y` is `n x W.rows()` batch-major. `lens[s]` is the per-vector length of
/// segment `s` (`x[s].len() == n * lens[s]`).
pub fn matmul_acc(
    w: &MatRef<'_>,
    x: &[&[f32]],
    lens: &[usize],
    n: usize,
    y: &mut [f32],
) -> Result<()> {
    check_batch("matmul.x", x.iter().map(|s| s.len()), lens, n, w.cols())?;
    check_len("matmul.y", n.saturating_mul(w.rows()), y.len())?;
    if n == 0 {
        return Ok(());
    }
    if w.int8_activations() {
        // One vector at a time: the batch-1 integer kernel's bits for every vector.
        let rows = w.rows();
        let mut xs: [&[f32]; MAX_SEGS] = [&[]; MAX_SEGS];
        for (b, yb) in y.chunks_exact_mut(rows.max(1)).enumerate().take(n) {
            for ((s, seg), &l) in xs.iter_mut().zip(x).zip(lens) {
                *s = &seg[b * l..(b + 1) * l];
            }
            crate::nn::qkernel::matvec_acc_int8(w, &xs[..x.len()], yb)?;
        }
        return Ok(());
    }
    if !crate::nn::qkernel::F32_ACTIVATIONS && w.is_int8() {
        return Err(crate::nn::qkernel::NO_F32_ACTIVATIONS);
    }
    match w.kernels() {
        Some(k) => k.matmul_acc(&w.without_kernels(), x, n, y),
        // The Cortex-M4F takes 2 rows x 2 vectors x 4 lanes of accumulators
        // (`matmul_acc_lanes`: 16 accumulators, each weight converted once for 2 vectors and
        // each input loaded once for 2 rows, in its 32 single registers).
        // A single vector takes the batch-1 kernel (its row blocking on hosts, two rows at
        // a time on the device; the same bits).
        None if n == 1 => w.matvec_acc(x, y),
        None if cfg!(target_arch = "arm") => {
            matmul_acc_lanes::<ARM_MM_R, ARM_MM_B, ARM_MM_L>(w, x, n, y)
        }
        None => matmul_acc_blocked::<1, 4>(w, x, n, y),
    }
}

/// `dX[b] += W^T dY[b]` for `b in 0..n`: `dy` is `n x W.rows()` batch-major, `dx` are
/// batch-major segments with per-vector lengths `lens` adding up to `W.cols()`.
pub fn matmul_t_acc(
    w: &MatRef<'_>,
    dy: &[f32],
    n: usize,
    dx: &mut [&mut [f32]],
    lens: &[usize],
) -> Result<()> {
    check_batch("matmul_t.dx", dx.iter().map(|s| s.len()), lens, n, w.cols())?;
    check_len("matmul_t.dy", n.saturating_mul(w.rows()), dy.len())?;
    if n == 0 {
        return Ok(());
    }
    match w.kernels() {
        Some(k) => k.matmul_t_acc(&w.without_kernels(), dy, n, dx, 0),
        None if n == 1 => w.matvec_t_acc(dy, dx),
        None if cfg!(target_arch = "arm") => matmul_t_acc_rows::<2>(w, dy, n, dx, 0),
        None => matmul_t_acc_blocked::<1, 4>(w, dy, n, dx, 0),
    }
}

/// `dW += alpha * sum_b dY[b] X[b]^T`, accumulated for `b = 0, 1, .., n - 1` in that order
/// (bit for bit as [`outer_acc`] called once per vector): the weight gradient
/// of `Y[b] = W X[b]` summed over the batch. `dy` is `n x rows` batch-major, `x` batch-major
/// segments with per-vector lengths `lens`.
pub fn outer_acc_batch(
    dw: &mut [f32],
    dy: &[f32],
    x: &[&[f32]],
    lens: &[usize],
    n: usize,
    alpha: f32,
) -> Result<()> {
    outer_acc_batch_with(None, dw, dy, x, lens, n, alpha)
}

/// [`outer_acc_batch`] through `kernels` when given (e.g. those of the matrix the gradient
/// belongs to, [`MatRef::kernels`]); the same bits either way.
pub fn outer_acc_batch_with(
    kernels: Option<&dyn Kernels>,
    dw: &mut [f32],
    dy: &[f32],
    x: &[&[f32]],
    lens: &[usize],
    n: usize,
    alpha: f32,
) -> Result<()> {
    let cols: usize = lens.iter().sum();
    check_batch("outer_batch.x", x.iter().map(|s| s.len()), lens, n, cols)?;
    if n == 0 {
        return Ok(());
    }
    let rows = dy.len() / n;
    check_len("outer_batch.dy", n.saturating_mul(rows), dy.len())?;
    check_len("outer_batch.dw", rows.saturating_mul(cols), dw.len())?;
    match kernels {
        Some(k) => k.outer_acc_batch(dw, dy, x, n, alpha),
        // One vector: the batch-1 kernel (the row-at-a-time loop on the device).
        None if n == 1 => outer_acc(dw, dy, x, alpha),
        None => outer_acc_batch_blocked::<2, 2>(dw, dy, x, n, alpha),
    }
}

// ---------------------------------------------------------------------------------------
// Weight storage: how a chunk of eight weights (or one weight) of a row is read as f32.
// Every conversion is exact (f32 copy, little-endian decode, i8 -> f32).

/// One storage kind of weights.
trait Kind {
    /// Raw unit of storage (`f32` or a byte).
    type R: Copy;
    /// Raw units per weight.
    const U: usize;
    /// Weights `8 c .. 8 c + 8` of a raw row segment.
    fn w8(raw: &[Self::R], c: usize) -> [f32; 8];
    /// Weight `j` of a raw row segment.
    fn w1(raw: &[Self::R], j: usize) -> f32;
}

struct F32K;
impl Kind for F32K {
    type R = f32;
    const U: usize = 1;
    #[inline(always)]
    fn w8(raw: &[f32], c: usize) -> [f32; 8] {
        ld8(raw, c)
    }
    #[inline(always)]
    fn w1(raw: &[f32], j: usize) -> f32 {
        raw[j]
    }
}

struct LeK;
impl Kind for LeK {
    type R = u8;
    const U: usize = 4;
    #[inline(always)]
    fn w8(raw: &[u8], c: usize) -> [f32; 8] {
        let s = &raw[32 * c..32 * c + 32];
        let mut o = [0.0f32; 8];
        for (k, v) in o.iter_mut().enumerate() {
            *v = f32::from_le_bytes([s[4 * k], s[4 * k + 1], s[4 * k + 2], s[4 * k + 3]]);
        }
        o
    }
    #[inline(always)]
    fn w1(raw: &[u8], j: usize) -> f32 {
        let s = &raw[4 * j..4 * j + 4];
        f32::from_le_bytes([s[0], s[1], s[2], s[3]])
    }
}

struct I8K;
impl Kind for I8K {
    type R = u8;
    const U: usize = 1;
    #[inline(always)]
    fn w8(raw: &[u8], c: usize) -> [f32; 8] {
        let s = &raw[8 * c..8 * c + 8];
        let mut o = [0.0f32; 8];
        for (v, &b) in o.iter_mut().zip(s) {
            *v = b as i8 as f32;
        }
        o
    }
    #[inline(always)]
    fn w1(raw: &[u8], j: usize) -> f32 {
        raw[j] as i8 as f32
    }
}

/// A `rows x cols` matrix of one storage kind, with the int8 row scales.
struct M<'a, K: Kind> {
    d: &'a [K::R],
    cols: usize,
    scales: Option<Scales<'a>>,
}

impl<'a, K: Kind> M<'a, K> {
    /// Raw storage of row `r`, columns `c0 .. c0 + len`.
    #[inline(always)]
    fn seg(&self, r: usize, c0: usize, len: usize) -> &'a [K::R] {
        let s = (r * self.cols + c0) * K::U;
        &self.d[s..s + len * K::U]
    }
}

/// Chunk `c` (elements `8 c .. 8 c + 8`) of an f32 slice.
#[inline(always)]
fn ld8(s: &[f32], c: usize) -> [f32; 8] {
    let s = &s[8 * c..8 * c + 8];
    [s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]]
}

/// The fixed reduction tree of the eight accumulators.
#[inline(always)]
fn tree(a: &[f32; 8]) -> f32 {
    ((a[0] + a[4]) + (a[1] + a[5])) + ((a[2] + a[6]) + (a[3] + a[7]))
}

/// Calls `$body` with `$m` bound to the typed view of `$w`'s storage.
macro_rules! with_kind {
    ($w:expr, |$m:ident| $body:expr) => {
        match $w.weights() {
            Weights::F32(d) => {
                let $m = M::<F32K> {
                    d,
                    cols: $w.cols(),
                    scales: None,
                };
                $body
            }
            Weights::F32Le(d) => {
                let $m = M::<LeK> {
                    d,
                    cols: $w.cols(),
                    scales: None,
                };
                $body
            }
            Weights::I8 { q, scales } => {
                let $m = M::<I8K> {
                    d: q,
                    cols: $w.cols(),
                    scales: Some(scales),
                };
                $body
            }
        }
    };
}

// ---------------------------------------------------------------------------------------
// y += W x

/// [`matmul_acc`] with an explicit block of `R` rows x `B` vectors (speed only; the same
/// bits for every shape). The shapes must already be checked (`x[s].len()` a multiple of
/// `n`, per-vector lengths adding up to `w.cols()`, `y` holding `n x w.rows()`); a kernel
/// table ([`Kernels`]) on `w` is not consulted. `#[inline(always)]` so that a caller
/// compiled with more vector features gets the whole body in those features.
#[inline(always)]
pub fn matmul_acc_blocked<const R: usize, const B: usize>(
    w: &MatRef<'_>,
    x: &[&[f32]],
    n: usize,
    y: &mut [f32],
) -> Result<()> {
    let (rows, cols) = (w.rows(), w.cols());
    check_len("matmul.y", n.saturating_mul(rows), y.len())?;
    if n == 0 || cols == 0 || x.len() > MAX_SEGS {
        return Ok(());
    }
    let mut lens = [0usize; MAX_SEGS];
    for (l, s) in lens.iter_mut().zip(x) {
        *l = s.len() / n;
    }
    check_len("matmul.x", cols, lens.iter().sum())?;
    let lens = &lens[..x.len()];
    with_kind!(w, |m| mm_all::<_, R, B>(&m, rows, x, lens, n, y));
    Ok(())
}

#[inline(always)]
fn mm_all<K: Kind, const R: usize, const B: usize>(
    m: &M<'_, K>,
    rows: usize,
    x: &[&[f32]],
    lens: &[usize],
    n: usize,
    y: &mut [f32],
) {
    let rb = rows / R * R;
    let nb = n / B * B;
    let mut r0 = 0;
    while r0 < rb {
        let mut b0 = 0;
        while b0 < nb {
            mm_tile::<K, R, B>(m, rows, x, lens, r0, b0, y);
            b0 += B;
        }
        while b0 < n {
            mm_tile::<K, R, 1>(m, rows, x, lens, r0, b0, y);
            b0 += 1;
        }
        r0 += R;
    }
    while r0 < rows {
        let mut b0 = 0;
        while b0 < nb {
            mm_tile::<K, 1, B>(m, rows, x, lens, r0, b0, y);
            b0 += B;
        }
        while b0 < n {
            mm_tile::<K, 1, 1>(m, rows, x, lens, r0, b0, y);
            b0 += 1;
        }
        r0 += 1;
    }
}

/// The end of one segment of a tile of `y += W x`: each dot product's eight accumulators
/// through the fixed tree, then the segment's tail (past the chunks of eight) in order, added
/// to the tile's totals.
#[inline(always)]
fn add_tails<K: Kind, const R: usize, const B: usize>(
    acc: &[[[f32; 8]; B]; R],
    ws: &[&[K::R]; R],
    xs: &[&[f32]; B],
    n8: usize,
    tot: &mut [[f32; B]; R],
) {
    for r in 0..R {
        for b in 0..B {
            let mut s = tree(&acc[r][b]);
            for (j, &xj) in xs[b].iter().enumerate().skip(8 * n8) {
                s += K::w1(ws[r], j) * xj;
            }
            tot[r][b] += s;
        }
    }
}

/// A tile's totals (the segment sums) into `y`, after the int8 row scale.
#[inline(always)]
fn store_tile<K: Kind, const R: usize, const B: usize>(
    m: &M<'_, K>,
    tot: &[[f32; B]; R],
    rows: usize,
    r0: usize,
    b0: usize,
    y: &mut [f32],
) {
    for r in 0..R {
        let sc = m.scales.map(|s| s.get(r0 + r));
        for b in 0..B {
            let o = &mut y[(b0 + b) * rows + r0 + r];
            match sc {
                None => *o += tot[r][b],
                Some(s) => *o += tot[r][b] * s,
            }
        }
    }
}

/// Rows `r0 .. r0 + R` x vectors `b0 .. b0 + B` of `y += W x`.
#[inline(always)]
fn mm_tile<K: Kind, const R: usize, const B: usize>(
    m: &M<'_, K>,
    rows: usize,
    x: &[&[f32]],
    lens: &[usize],
    r0: usize,
    b0: usize,
    y: &mut [f32],
) {
    let mut tot = [[0.0f32; B]; R];
    let mut off = 0;
    for (seg, &l) in x.iter().zip(lens) {
        let n8 = l / 8;
        let ws: [&[K::R]; R] = core::array::from_fn(|r| m.seg(r0 + r, off, l));
        let xs: [&[f32]; B] = core::array::from_fn(|b| &seg[(b0 + b) * l..(b0 + b + 1) * l]);
        let mut acc = [[[0.0f32; 8]; B]; R];
        for c in 0..n8 {
            let xv: [[f32; 8]; B] = core::array::from_fn(|b| ld8(xs[b], c));
            for r in 0..R {
                let wv = K::w8(ws[r], c);
                for b in 0..B {
                    for k in 0..8 {
                        acc[r][b][k] += wv[k] * xv[b][k];
                    }
                }
            }
        }
        // Through memory, eight contiguous floats per dot product: this steers LLVM's
        // vectoriser to put the eight accumulators of one dot product in the lanes (rather
        // than the same accumulator of several vectors, which costs shuffles). No effect on
        // the values.
        let acc = core::hint::black_box(acc);
        add_tails::<K, R, B>(&acc, &ws, &xs, n8, &mut tot);
        off += l;
    }
    store_tile::<K, R, B>(m, &tot, rows, r0, b0, y);
}

// ---------------------------------------------------------------------------------------
// dx += W^T dy

/// The shape check of the `dx += W^T dy` bodies: `dy` is `n x rows`, the segments of `dx`
/// (per-vector lengths `len / n`) fit in the columns from `col0`. `None` when there is
/// nothing to do (no vector or no column), else the row count.
#[inline(always)]
fn check_t(
    w: &MatRef<'_>,
    dy: &[f32],
    n: usize,
    dx: &[&mut [f32]],
    col0: usize,
) -> Result<Option<usize>> {
    let (rows, cols) = (w.rows(), w.cols());
    check_len("matmul_t.dy", n.saturating_mul(rows), dy.len())?;
    if n == 0 || cols == 0 {
        return Ok(None);
    }
    let total: usize = dx.iter().map(|s| s.len() / n).sum();
    if col0.saturating_add(total) > cols {
        return Err(crate::Error::Shape(crate::ShapeError {
            what: "matmul_t.cols",
            expected: cols,
            actual: col0.saturating_add(total),
        }));
    }
    Ok(Some(rows))
}

/// [`matmul_t_acc`] with an explicit block of `8 C` columns x `B` vectors, on the column
/// block of `w` starting at `col0` (the segments of `dx` cover columns `col0 ..` in order;
/// per-vector lengths are `dx[s].len() / n`). Speed only: the same bits for every shape.
/// Shapes must already be checked; a kernel table on `w` is not consulted.
#[inline(always)]
pub fn matmul_t_acc_blocked<const C: usize, const B: usize>(
    w: &MatRef<'_>,
    dy: &[f32],
    n: usize,
    dx: &mut [&mut [f32]],
    col0: usize,
) -> Result<()> {
    let Some(rows) = check_t(w, dy, n, dx, col0)? else {
        return Ok(());
    };
    with_kind!(w, |m| {
        let mut off = col0;
        for seg in dx.iter_mut() {
            let l = seg.len() / n;
            mt_seg::<_, C, B>(&m, rows, dy, n, seg, l, off);
            off += l;
        }
    });
    Ok(())
}

#[inline(always)]
fn mt_seg<K: Kind, const C: usize, const B: usize>(
    m: &M<'_, K>,
    rows: usize,
    dy: &[f32],
    n: usize,
    seg: &mut [f32],
    l: usize,
    off: usize,
) {
    let n8 = l / 8;
    let cb = n8 / C * C;
    let nb = n / B * B;
    // Rows in blocks of `MT_ROWS`, in order, each block's row coefficients computed once per
    // vector tile (not once per column tile): every output element still receives its
    // `+= c * w` for rows 0, 1, .. in that order (the accumulators go through `seg` between
    // blocks).
    let mut r0 = 0;
    while r0 < rows && n8 > 0 {
        let rb = MT_ROWS.min(rows - r0);
        let mut b0 = 0;
        while b0 < nb {
            let coef = mt_coefs::<K, B>(m, rows, dy, b0, r0, rb);
            let mut c = 0;
            while c < cb {
                mt_tile::<K, C, B>(m, (r0, rb), &coef, seg, l, off, b0, c);
                c += C;
            }
            while c < n8 {
                mt_tile::<K, 1, B>(m, (r0, rb), &coef, seg, l, off, b0, c);
                c += 1;
            }
            b0 += B;
        }
        // The vectors left over: 8 C columns x 1 vector per tile.
        while b0 < n {
            let coef = mt_coefs::<K, 1>(m, rows, dy, b0, r0, rb);
            let mut c = 0;
            while c < cb {
                mt_tile::<K, C, 1>(m, (r0, rb), &coef, seg, l, off, b0, c);
                c += C;
            }
            while c < n8 {
                mt_tile::<K, 1, 1>(m, (r0, rb), &coef, seg, l, off, b0, c);
                c += 1;
            }
            b0 += 1;
        }
        r0 += rb;
    }
    // The tail columns, element by element (rows in order).
    for b in 0..n {
        let out = &mut seg[b * l..(b + 1) * l];
        for (i, &g) in dy[b * rows..(b + 1) * rows].iter().enumerate() {
            let coef = row_coef(m, i, g);
            let ws = m.seg(i, off, l);
            for (j, o) in out.iter_mut().enumerate().skip(8 * n8) {
                *o += coef * K::w1(ws, j);
            }
        }
    }
}

/// The factor of row `i` in `dx += W^T dy`: `dy_i`, times the row scale for int8 (as in the
/// batch-1 kernel, `dy_i * scale_i` first).
#[inline(always)]
fn row_coef<K: Kind>(m: &M<'_, K>, i: usize, g: f32) -> f32 {
    match m.scales {
        None => g,
        Some(s) => g * s.get(i),
    }
}

/// The row coefficients ([`row_coef`]) of rows `r0 .. r0 + rb` (`rb <= MT_ROWS`) for
/// vectors `b0 .. b0 + B`.
#[inline(always)]
fn mt_coefs<K: Kind, const B: usize>(
    m: &M<'_, K>,
    rows: usize,
    dy: &[f32],
    b0: usize,
    r0: usize,
    rb: usize,
) -> [[f32; B]; MT_ROWS] {
    let mut coef = [[0.0f32; B]; MT_ROWS];
    for (i, cf) in coef.iter_mut().enumerate().take(rb) {
        for (b, v) in cf.iter_mut().enumerate() {
            *v = row_coef(m, r0 + i, dy[(b0 + b) * rows + r0 + i]);
        }
    }
    coef
}

/// Columns `8 c .. 8 (c + C)` of the segment x vectors `b0 .. b0 + B`, over the rows
/// `r0 .. r0 + rb` in order, with their coefficients `coef` ([`mt_coefs`]).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn mt_tile<K: Kind, const C: usize, const B: usize>(
    m: &M<'_, K>,
    (r0, rb): (usize, usize),
    coef: &[[f32; B]; MT_ROWS],
    seg: &mut [f32],
    l: usize,
    off: usize,
    b0: usize,
    c: usize,
) {
    let mut acc = [[[0.0f32; 8]; C]; B];
    for (b, a) in acc.iter_mut().enumerate() {
        let o = &seg[(b0 + b) * l..(b0 + b + 1) * l];
        for (cc, v) in a.iter_mut().enumerate() {
            *v = ld8(o, c + cc);
        }
    }
    for (i, cf) in coef.iter().enumerate().take(rb) {
        let ws = m.seg(r0 + i, off, l);
        let wv: [[f32; 8]; C] = core::array::from_fn(|cc| K::w8(ws, c + cc));
        for b in 0..B {
            let k_b = cf[b];
            for cc in 0..C {
                for k in 0..8 {
                    acc[b][cc][k] += k_b * wv[cc][k];
                }
            }
        }
    }
    for (b, a) in acc.iter().enumerate() {
        let o = &mut seg[(b0 + b) * l..(b0 + b + 1) * l];
        for (cc, v) in a.iter().enumerate() {
            o[8 * (c + cc)..8 * (c + cc) + 8].copy_from_slice(v);
        }
    }
}

// ---------------------------------------------------------------------------------------
// dW += alpha dy x^T

/// [`outer_acc_batch`] with an explicit block of `R` rows x `8 C` columns (speed only; the
/// same bits for every shape). `rows = dy.len() / n`, per-vector lengths `x[s].len() / n`;
/// shapes must already be checked.
#[inline(always)]
pub fn outer_acc_batch_blocked<const R: usize, const C: usize>(
    dw: &mut [f32],
    dy: &[f32],
    x: &[&[f32]],
    n: usize,
    alpha: f32,
) -> Result<()> {
    if n == 0 || x.len() > MAX_SEGS {
        return Ok(());
    }
    let mut lens = [0usize; MAX_SEGS];
    for (l, s) in lens.iter_mut().zip(x) {
        *l = s.len() / n;
    }
    let lens = &lens[..x.len()];
    let cols: usize = lens.iter().sum();
    let rows = dy.len() / n;
    check_len("outer_batch.dw", rows.saturating_mul(cols), dw.len())?;
    if cols == 0 {
        return Ok(());
    }
    let rb = rows / R * R;
    let mut off = 0;
    for (seg, &l) in x.iter().zip(lens) {
        let n8 = l / 8;
        let cb = n8 / C * C;
        let mut r0 = 0;
        while r0 < rb {
            let mut c = 0;
            while c < cb {
                op_tile::<R, C>(dw, cols, dy, rows, n, alpha, seg, l, off, r0, c);
                c += C;
            }
            while c < n8 {
                op_tile::<R, 1>(dw, cols, dy, rows, n, alpha, seg, l, off, r0, c);
                c += 1;
            }
            r0 += R;
        }
        while r0 < rows {
            for c in 0..n8 {
                op_tile::<1, 1>(dw, cols, dy, rows, n, alpha, seg, l, off, r0, c);
            }
            r0 += 1;
        }
        // The tail columns, element by element (vectors in order).
        if 8 * n8 < l {
            for i in 0..rows {
                let drow = &mut dw[i * cols + off + 8 * n8..i * cols + off + l];
                for b in 0..n {
                    let a = alpha * dy[b * rows + i];
                    if a == 0.0 {
                        continue;
                    }
                    let xs = &seg[b * l + 8 * n8..(b + 1) * l];
                    for (o, &xv) in drow.iter_mut().zip(xs) {
                        *o += a * xv;
                    }
                }
            }
        }
        off += l;
    }
    Ok(())
}

/// Rows `r0 .. r0 + R` x columns `8 c .. 8 (c + C)` of one segment, over all vectors in order.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn op_tile<const R: usize, const C: usize>(
    dw: &mut [f32],
    cols: usize,
    dy: &[f32],
    rows: usize,
    n: usize,
    alpha: f32,
    seg: &[f32],
    l: usize,
    off: usize,
    r0: usize,
    c: usize,
) {
    let mut acc = [[[0.0f32; 8]; C]; R];
    for (r, a) in acc.iter_mut().enumerate() {
        let o = &dw[(r0 + r) * cols + off..(r0 + r) * cols + off + l];
        for (cc, v) in a.iter_mut().enumerate() {
            *v = ld8(o, c + cc);
        }
    }
    for b in 0..n {
        let xs = &seg[b * l..(b + 1) * l];
        let xv: [[f32; 8]; C] = core::array::from_fn(|cc| ld8(xs, c + cc));
        for r in 0..R {
            let a = alpha * dy[b * rows + r0 + r];
            if a == 0.0 {
                continue;
            }
            for cc in 0..C {
                for k in 0..8 {
                    acc[r][cc][k] += a * xv[cc][k];
                }
            }
        }
    }
    for (r, a) in acc.iter().enumerate() {
        let o = &mut dw[(r0 + r) * cols + off..(r0 + r) * cols + off + l];
        for (cc, v) in a.iter().enumerate() {
            o[8 * (c + cc)..8 * (c + cc) + 8].copy_from_slice(v);
        }
    }
}

// ---------------------------------------------------------------------------------------
// The Cortex-M4F's loops (no vector unit, 32 single registers): the same canonical order,
// blocked for a scalar FPU. Compiled and unit-tested on every target (the tests below run
// them on the host against the reference); only `target_arch = "arm"` calls them.

/// `y += W x` for `n` vectors, `R` rows x `B` vectors x `L` lanes of accumulators at a time.
///
/// The eight accumulators of one dot product are independent chains (accumulator `k` sums
/// the products of elements `8 c + k`, `c` in order), so they are run `L` at a time: the
/// lanes `0 .. L` over all chunks, then `L .. 2 L`, and so on, each chain still summing its
/// products in chunk order. That leaves the operations of every dot product as they are (the
/// same tree over the same eight sums afterwards) and frees registers for more rows and
/// vectors: each weight is converted once for `B` vectors, each input loaded once for `R`
/// rows. `L` is 8 (one pass) or 4 (two passes; any other `L` is an error). Shapes must
/// already be checked.
#[inline(always)]
pub fn matmul_acc_lanes<const R: usize, const B: usize, const L: usize>(
    w: &MatRef<'_>,
    x: &[&[f32]],
    n: usize,
    y: &mut [f32],
) -> Result<()> {
    if L != 4 && L != 8 {
        check_len("matmul.lanes", 8, L)?;
    }
    let (rows, cols) = (w.rows(), w.cols());
    check_len("matmul.y", n.saturating_mul(rows), y.len())?;
    if n == 0 || cols == 0 || x.len() > MAX_SEGS {
        return Ok(());
    }
    let mut lens = [0usize; MAX_SEGS];
    for (l, s) in lens.iter_mut().zip(x) {
        *l = s.len() / n;
    }
    check_len("matmul.x", cols, lens.iter().sum())?;
    let lens = &lens[..x.len()];
    // Leftover vectors take `R` rows x 1 vector x 8 lanes, leftover rows 1 x 1 x 8 (the
    // device's batch-1 shapes: fewer copies of the body in flash).
    macro_rules! body {
        ($m:expr) => {{
            let m = $m;
            let rb = rows / R * R;
            let nb = n / B * B;
            let mut r0 = 0;
            while r0 < rb {
                let mut b0 = 0;
                while b0 < nb {
                    ml_tile::<_, R, B, L>(&m, rows, x, lens, r0, b0, y);
                    b0 += B;
                }
                while b0 < n {
                    ml_tile::<_, R, 1, 8>(&m, rows, x, lens, r0, b0, y);
                    b0 += 1;
                }
                r0 += R;
            }
            while r0 < rows {
                for b0 in 0..n {
                    ml_tile::<_, 1, 1, 8>(&m, rows, x, lens, r0, b0, y);
                }
                r0 += 1;
            }
        }};
    }
    match w.weights() {
        Weights::I8 { q, scales } => body!(M::<I8K> {
            d: q,
            cols,
            scales: Some(scales)
        }),
        // f32 weights (on the device only the small adapted matrices) and little-endian f32
        // (not in the device's blobs): one vector at a time, row by row.
        Weights::F32(_) | Weights::F32Le(_) => {
            for (b, yb) in y.chunks_exact_mut(rows.max(1)).enumerate().take(n) {
                let mut xb: [&[f32]; MAX_SEGS] = [&[]; MAX_SEGS];
                for ((o, seg), &l) in xb.iter_mut().zip(x).zip(lens) {
                    *o = &seg[b * l..(b + 1) * l];
                }
                w.matvec_acc_many(&xb[..x.len()], yb);
            }
        }
    }
    Ok(())
}

/// Rows `r0 .. r0 + R` x vectors `b0 .. b0 + B` of `y += W x`, lanes `L` at a time.
#[inline(always)]
fn ml_tile<K: Kind, const R: usize, const B: usize, const L: usize>(
    m: &M<'_, K>,
    rows: usize,
    x: &[&[f32]],
    lens: &[usize],
    r0: usize,
    b0: usize,
    y: &mut [f32],
) {
    let mut tot = [[0.0f32; B]; R];
    let mut off = 0;
    for (seg, &l) in x.iter().zip(lens) {
        let n8 = l / 8;
        let ws: [&[K::R]; R] = core::array::from_fn(|r| m.seg(r0 + r, off, l));
        let xs: [&[f32]; B] = core::array::from_fn(|b| &seg[(b0 + b) * l..(b0 + b + 1) * l]);
        let mut lo = [[[0.0f32; L]; B]; R];
        let mut hi = lo;
        let mut g = 0;
        while g < 8 && n8 > 0 {
            let mut acc = [[[0.0f32; L]; B]; R];
            let wc: [&[K::R]; R] = core::array::from_fn(|r| &ws[r][..8 * n8 * K::U]);
            let xc: [&[f32]; B] = core::array::from_fn(|b| &xs[b][..8 * n8]);
            for c in 0..n8 {
                let j = 8 * c + g;
                let xv: [[f32; L]; B] = core::array::from_fn(|b| ldl::<L>(xc[b], j));
                for r in 0..R {
                    let wv: [f32; L] = core::array::from_fn(|k| K::w1(wc[r], j + k));
                    for b in 0..B {
                        for k in 0..L {
                            acc[r][b][k] += wv[k] * xv[b][k];
                        }
                    }
                }
            }
            if g == 0 {
                lo = acc;
            } else {
                hi = acc;
            }
            g += L;
        }
        // `L` is 8 (one pass) or 4 (two passes).
        let full: [[[f32; 8]; B]; R] = core::array::from_fn(|r| {
            core::array::from_fn(|b| {
                core::array::from_fn(|k| {
                    if k < L {
                        lo[r][b][k % L]
                    } else {
                        hi[r][b][(k - L) % L]
                    }
                })
            })
        });
        add_tails::<K, R, B>(&full, &ws, &xs, n8, &mut tot);
        off += l;
    }
    store_tile::<K, R, B>(m, &tot, rows, r0, b0, y);
}

/// `y += W x` for one vector, two rows at a time (the Cortex-M4F's batch-1 loop): the two
/// rows share every input load, and their eight accumulators each run in two passes of four
/// lanes (see [`matmul_acc_lanes`]), so 8 accumulators, 4 inputs and the converted weights
/// fit the FPU's registers. The same canonical order; shapes must already be checked.
pub fn matvec_acc_pairs(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> Result<()> {
    let (rows, cols) = (w.rows(), w.cols());
    check_len("matvec.x", cols, seg_len(x))?;
    check_len("matvec.y", rows, y.len())?;
    if cols == 0 {
        return Ok(());
    }
    macro_rules! body {
        ($m:expr) => {{
            let m = $m;
            let mut r0 = 0;
            while r0 + 2 <= rows {
                mv_pair::<_, 2>(&m, x, r0, y);
                r0 += 2;
            }
            if r0 < rows {
                mv_pair::<_, 1>(&m, x, r0, y);
            }
        }};
    }
    match w.weights() {
        Weights::I8 { q, scales } => body!(M::<I8K> {
            d: q,
            cols,
            scales: Some(scales)
        }),
        // f32 weights (on the device only the small adapted matrices) and little-endian f32:
        // one row at a time.
        Weights::F32(_) | Weights::F32Le(_) => w.matvec_acc_many(x, y),
    }
    Ok(())
}

/// Rows `r0 .. r0 + R` (`R` is 1 or 2) of [`matvec_acc_pairs`].
#[inline(always)]
fn mv_pair<K: Kind, const R: usize>(m: &M<'_, K>, x: &[&[f32]], r0: usize, y: &mut [f32]) {
    let mut tot = [0.0f32; R];
    let mut off = 0;
    for seg in x {
        let l = seg.len();
        let n8 = l / 8;
        let ws: [&[K::R]; R] = core::array::from_fn(|r| m.seg(r0 + r, off, l));
        let w0 = ws[0];
        let w1 = ws[R - 1];
        // Lanes `g .. g + 4` of the two rows' accumulators over all chunks, in order.
        let pass = |g: usize| {
            let mut acc = [[0.0f32; 4]; R];
            for ((c0, c1), xc) in w0
                .chunks_exact(8 * K::U)
                .zip(w1.chunks_exact(8 * K::U))
                .zip(seg.chunks_exact(8))
            {
                let xv = [xc[g], xc[g + 1], xc[g + 2], xc[g + 3]];
                let wc = [c0, c1];
                for r in 0..R {
                    let wv: [f32; 4] = core::array::from_fn(|k| K::w1(wc[r], g + k));
                    for k in 0..4 {
                        acc[r][k] += wv[k] * xv[k];
                    }
                }
            }
            acc
        };
        let (lo, hi) = (pass(0), pass(4));
        for r in 0..R {
            let (a, b) = (&lo[r], &hi[r]);
            let mut s = tree(&[a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]]);
            for (j, &xj) in seg.iter().enumerate().skip(8 * n8) {
                s += K::w1(ws[r], j) * xj;
            }
            tot[r] += s;
        }
        off += l;
    }
    for r in 0..R {
        let o = &mut y[r0 + r];
        match m.scales {
            None => *o += tot[r],
            Some(s) => *o += tot[r] * s.get(r0 + r),
        }
    }
}

/// Elements `j .. j + L` of an f32 slice.
#[inline(always)]
fn ldl<const L: usize>(s: &[f32], j: usize) -> [f32; L] {
    let s = &s[j..j + L];
    core::array::from_fn(|k| s[k])
}

/// Rows per block of [`matmul_t_acc_rows`] and of the hosts' `mt_seg`: the row coefficients
/// of a block are computed once into a small buffer on the stack.
const MT_ROWS: usize = 64;
/// Vectors per pass of [`matmul_t_acc_rows`] (its coefficient buffer holds this many).
const MT_MAXB: usize = 2;

/// `dX[b] += W^T dY[b]` (on the column block of `w` starting at `col0`, as
/// [`matmul_t_acc_blocked`]) with tiles of 8 columns x `B` vectors (`B <= 2`), rows in order:
/// the row coefficients (`dy_i`, times the row scale for int8, as the blocked body computes them) are
/// computed once per block of rows instead of once per tile, and the tile's sums are kept in
/// registers over a block and in `dx` between blocks (an exact store and reload). Shapes
/// must already be checked.
#[inline(always)]
pub fn matmul_t_acc_rows<const B: usize>(
    w: &MatRef<'_>,
    dy: &[f32],
    n: usize,
    dx: &mut [&mut [f32]],
    col0: usize,
) -> Result<()> {
    let cols = w.cols();
    let Some(rows) = check_t(w, dy, n, dx, col0)? else {
        return Ok(());
    };
    macro_rules! body {
        ($m:expr) => {{
            let m = $m;
            let nb = n / B * B;
            let mut b0 = 0;
            while b0 < n {
                let nv = if b0 < nb { B } else { 1 };
                let mut i0 = 0;
                while i0 < rows {
                    let i1 = (i0 + MT_ROWS).min(rows);
                    let mut coef = [[0.0f32; MT_ROWS]; MT_MAXB];
                    for (b, cb) in coef.iter_mut().enumerate().take(nv) {
                        let d = &dy[(b0 + b) * rows + i0..(b0 + b) * rows + i1];
                        for (i, (c, &g)) in cb.iter_mut().zip(d).enumerate() {
                            *c = row_coef(&m, i0 + i, g);
                        }
                    }
                    let mut off = col0;
                    for seg in dx.iter_mut() {
                        let l = seg.len() / n;
                        if nv == B {
                            mr_seg::<_, B>(&m, &coef, i0, i1, seg, l, off, b0);
                        } else {
                            mr_seg::<_, 1>(&m, &coef, i0, i1, seg, l, off, b0);
                        }
                        off += l;
                    }
                    i0 = i1;
                }
                b0 += nv;
            }
        }};
    }
    match w.weights() {
        Weights::I8 { q, scales } => body!(M::<I8K> {
            d: q,
            cols,
            scales: Some(scales)
        }),
        // f32 weights (on the device only the small adapted matrices) and little-endian f32
        // (not in the device's blobs): one vector at a time, row by row.
        Weights::F32(_) | Weights::F32Le(_) => {
            for b in 0..n {
                let mut off = col0;
                for seg in dx.iter_mut() {
                    let l = seg.len() / n;
                    w.matvec_t_rowwise(
                        &dy[b * rows..(b + 1) * rows],
                        off,
                        &mut seg[b * l..(b + 1) * l],
                    );
                    off += l;
                }
            }
        }
    }
    Ok(())
}

/// One segment of [`matmul_t_acc_rows`] for rows `i0 .. i1` and vectors `b0 .. b0 + B`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
// Indexed loops over the rows: the form whose instruction count was measured on the device.
#[allow(clippy::needless_range_loop)]
fn mr_seg<K: Kind, const B: usize>(
    m: &M<'_, K>,
    coef: &[[f32; MT_ROWS]; MT_MAXB],
    i0: usize,
    i1: usize,
    seg: &mut [f32],
    l: usize,
    off: usize,
    b0: usize,
) {
    let n8 = l / 8;
    let nr = i1.saturating_sub(i0);
    if nr == 0 || l == 0 {
        return;
    }
    let stride = m.cols * K::U;
    let base = (i0 * m.cols + off) * K::U;
    // The rows' raw storage of this segment: row `i0 + i` starts at `i * stride`.
    let Some(raw) = m.d.get(base..base + (nr - 1) * stride + l * K::U) else {
        return;
    };
    let cf: [&[f32]; B] = core::array::from_fn(|b| &coef[b][..nr]);
    for c in 0..n8 {
        let mut acc = [[0.0f32; 8]; B];
        for (b, a) in acc.iter_mut().enumerate() {
            *a = ld8(&seg[(b0 + b) * l..(b0 + b + 1) * l], c);
        }
        let mut p = 8 * c * K::U;
        for i in 0..nr {
            let wv = K::w8(&raw[p..p + 8 * K::U], 0);
            for b in 0..B {
                let g = cf[b][i];
                for k in 0..8 {
                    acc[b][k] += g * wv[k];
                }
            }
            p += stride;
        }
        for (b, a) in acc.iter().enumerate() {
            seg[(b0 + b) * l + 8 * c..(b0 + b) * l + 8 * c + 8].copy_from_slice(a);
        }
    }
    // The tail columns, element by element (rows in order).
    if 8 * n8 < l {
        for b in 0..B {
            let out = &mut seg[(b0 + b) * l + 8 * n8..(b0 + b + 1) * l];
            let mut p = 8 * n8 * K::U;
            for i in 0..nr {
                let g = cf[b][i];
                for (j, o) in out.iter_mut().enumerate() {
                    *o += g * K::w1(&raw[p..], j);
                }
                p += stride;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::outer_acc;
    use super::*;
    use crate::nn::matrix::MatRef;

    fn vals(n: usize, seed: u32) -> [f32; 512] {
        let mut out = [0.0f32; 512];
        let mut s = seed.wrapping_mul(2654435761).wrapping_add(1);
        for v in out.iter_mut().take(n) {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            *v = (s % 2001) as f32 / 1000.0 - 1.0;
        }
        out
    }

    // W is 5 x 11 (segments 3 + 8), batch of 4.
    const R: usize = 5;
    const C: usize = 11;
    const N: usize = 4;

    #[test]
    fn matmul_matches_matvec_bit_for_bit() {
        let wv = vals(R * C, 1);
        let w = MatRef::f32(R, C, &wv[..R * C]).unwrap();
        let a = vals(N * 3, 2);
        let b = vals(N * 8, 3);
        let mut y = vals(N * R, 4);
        let y0 = y;
        matmul_acc(&w, &[&a[..N * 3], &b[..N * 8]], &[3, 8], N, &mut y[..N * R]).unwrap();
        for k in 0..N {
            let mut yk = [0.0f32; R];
            yk.copy_from_slice(&y0[k * R..(k + 1) * R]);
            w.matvec_acc(&[&a[k * 3..k * 3 + 3], &b[k * 8..k * 8 + 8]], &mut yk)
                .unwrap();
            for r in 0..R {
                assert_eq!(y[k * R + r].to_bits(), yk[r].to_bits());
            }
        }
    }

    #[test]
    fn matmul_t_matches_matvec_t_bit_for_bit() {
        let wv = vals(R * C, 5);
        let w = MatRef::f32(R, C, &wv[..R * C]).unwrap();
        let dy = vals(N * R, 6);
        let mut da = vals(N * 3, 7);
        let mut db = vals(N * 8, 8);
        let (da0, db0) = (da, db);
        {
            let (sa, sb) = (&mut da[..N * 3], &mut db[..N * 8]);
            matmul_t_acc(&w, &dy[..N * R], N, &mut [sa, sb], &[3, 8]).unwrap();
        }
        for k in 0..N {
            let mut ea = [0.0f32; 3];
            let mut eb = [0.0f32; 8];
            ea.copy_from_slice(&da0[k * 3..k * 3 + 3]);
            eb.copy_from_slice(&db0[k * 8..k * 8 + 8]);
            w.matvec_t_acc(&dy[k * R..(k + 1) * R], &mut [&mut ea, &mut eb])
                .unwrap();
            for i in 0..3 {
                assert_eq!(da[k * 3 + i].to_bits(), ea[i].to_bits());
            }
            for i in 0..8 {
                assert_eq!(db[k * 8 + i].to_bits(), eb[i].to_bits());
            }
        }
    }

    #[test]
    fn outer_batch_matches_sequential_outer() {
        let dy = vals(N * R, 9);
        let a = vals(N * 3, 10);
        let b = vals(N * 8, 11);
        let mut dw = vals(R * C, 12);
        let mut want = dw;
        outer_acc_batch(
            &mut dw[..R * C],
            &dy[..N * R],
            &[&a[..N * 3], &b[..N * 8]],
            &[3, 8],
            N,
            0.5,
        )
        .unwrap();
        for k in 0..N {
            outer_acc(
                &mut want[..R * C],
                &dy[k * R..(k + 1) * R],
                &[&a[k * 3..k * 3 + 3], &b[k * 8..k * 8 + 8]],
                0.5,
            )
            .unwrap();
        }
        for i in 0..R * C {
            assert_eq!(dw[i].to_bits(), want[i].to_bits());
        }
    }

    #[test]
    fn bad_shapes_are_errors() {
        let wv = vals(R * C, 1);
        let w = MatRef::f32(R, C, &wv[..R * C]).unwrap();
        let a = vals(N * 3, 2);
        let mut y = [0.0f32; N * R];
        // per-vector lengths that do not add up to cols
        assert!(matmul_acc(&w, &[&a[..N * 3]], &[3], N, &mut y).is_err());
        // a segment shorter than n * len
        assert!(matmul_acc(&w, &[&a[..N * 3], &a[..8]], &[3, 8], N, &mut y).is_err());
        // too many segments
        let many: [&[f32]; 9] = [&a[..N]; 9];
        assert!(matmul_acc(&w, &many, &[1; 9], N, &mut y).is_err());
    }

    // ---- against a plain transcription of the canonical order, every storage kind ----

    /// The canonical `y += W x` of one vector, written out (no blocking).
    fn ref_matvec(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) {
        use crate::nn::matrix::{dot, dot_i8, dot_le};
        if w.cols() == 0 {
            return;
        }
        for (i, yi) in y.iter_mut().enumerate() {
            let mut acc = 0.0f32;
            let mut off = 0;
            for seg in x {
                let l = seg.len();
                acc += match w.weights() {
                    Weights::F32(d) => dot(&d[i * w.cols() + off..i * w.cols() + off + l], seg),
                    Weights::F32Le(d) => dot_le(
                        &d[4 * (i * w.cols() + off)..4 * (i * w.cols() + off + l)],
                        seg,
                    ),
                    Weights::I8 { q, .. } => {
                        dot_i8(&q[i * w.cols() + off..i * w.cols() + off + l], seg)
                    }
                };
                off += l;
            }
            match w.weights() {
                Weights::I8 { scales, .. } => *yi += acc * scales.get(i),
                _ => *yi += acc,
            }
        }
    }

    /// The canonical `dx += W[:, col0..]^T dy` of one vector.
    fn ref_matvec_t(w: &MatRef<'_>, dy: &[f32], col0: usize, dx: &mut [f32]) {
        for (i, &g) in dy.iter().enumerate() {
            let c = match w.weights() {
                Weights::I8 { scales, .. } => g * scales.get(i),
                _ => g,
            };
            for (j, o) in dx.iter_mut().enumerate() {
                let wij = match w.weights() {
                    Weights::I8 { q, .. } => q[i * w.cols() + col0 + j] as i8 as f32,
                    _ => w.get(i, col0 + j),
                };
                *o += c * wij;
            }
        }
    }

    /// The canonical `dW += alpha dy x^T` of one vector.
    fn ref_outer(dw: &mut [f32], dy: &[f32], x: &[f32], alpha: f32) {
        let cols = x.len();
        for (i, &g) in dy.iter().enumerate() {
            let a = alpha * g;
            if a == 0.0 {
                continue;
            }
            crate::nn::matrix::axpy(a, x, &mut dw[i * cols..(i + 1) * cols]);
        }
    }

    const BIG: usize = 4096;

    fn big(n: usize, seed: u32) -> [f32; BIG] {
        let mut out = [0.0f32; BIG];
        out[..n.min(512)].copy_from_slice(&vals(n.min(512), seed)[..n.min(512)]);
        let mut s = seed.wrapping_mul(747796405).wrapping_add(3);
        for v in out.iter_mut().take(n).skip(512) {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            *v = (s % 4001) as f32 / 997.0 - 2.0;
        }
        // Special values the canonical order must treat identically.
        if n > 7 {
            out[1] = -0.0;
            out[3] = 0.0;
            out[n - 2] = 1.0e-39; // subnormal
        }
        out
    }

    /// Matrices of every kind over the same values: f32, little-endian f32, int8.
    fn kinds<'a>(
        r: usize,
        c: usize,
        wv: &'a [f32],
        le: &'a mut [u8],
        q: &'a mut [u8],
        sc: &'a mut [f32],
    ) -> [MatRef<'a>; 3] {
        for (b, v) in le.chunks_exact_mut(4).zip(wv) {
            b.copy_from_slice(&v.to_le_bytes());
        }
        for (i, qv) in q.iter_mut().enumerate() {
            *qv = ((wv[i] * 60.0) as i32).clamp(-127, 127) as i8 as u8;
        }
        for (i, s) in sc.iter_mut().enumerate() {
            *s = 0.01 + i as f32 * 0.003;
        }
        [
            MatRef::f32(r, c, wv).unwrap(),
            MatRef::f32_le(r, c, le).unwrap(),
            MatRef::i8(r, c, q, Scales::F32(sc)).unwrap(),
        ]
    }

    /// Every kernel form (forward, transposed, outer product) against its batch-1 twin, bit
    /// for bit, over every weight kind and a table of shapes with tails; long because it is
    /// one loop over that table with one comparison per form, kept together so a new form
    /// cannot skip a shape.
    #[test]
    fn blocked_kernels_keep_the_canonical_order_for_every_kind_and_shape() {
        // (rows, segment lengths, batch) with tails, short segments, empty segments.
        let cases: &[(usize, &[usize], usize)] = &[
            (1, &[1], 1),
            (3, &[7], 5),
            (5, &[3, 8], 4),
            (6, &[64], 20),
            (7, &[45, 45], 3),
            (9, &[17, 0, 6, 33], 6),
            (4, &[0], 2),
            (2, &[100, 9], 9),
            // more rows than a block of `matmul_t_acc_rows`
            (70, &[13], 3),
        ];
        for (ci, &(r, lens, n)) in cases.iter().enumerate() {
            let c: usize = lens.iter().sum();
            let wv = big(r * c, 100 + ci as u32);
            let mut le = [0u8; 4 * 1024];
            let mut q = [0u8; 1024];
            let mut sc = [0.0f32; 128];
            let mats = kinds(
                r,
                c,
                &wv[..r * c],
                &mut le[..4 * r * c],
                &mut q[..r * c],
                &mut sc[..r],
            );
            let xs: [[f32; BIG]; 4] = core::array::from_fn(|s| big(n * 128, 200 + s as u32));
            let segs: [&[f32]; 4] =
                core::array::from_fn(|s| &xs[s][..n * lens.get(s).copied().unwrap_or(0)]);
            let segs = &segs[..lens.len()];
            let dy = {
                let mut d = big(n * r, 300 + ci as u32);
                d[0] = 0.0; // a skipped outer-product row
                d
            };
            for (mi, m) in mats.iter().enumerate() {
                // y += W x
                let y0 = big(n * r, 400);
                let mut y = y0;
                matmul_acc(m, segs, lens, n, &mut y[..n * r]).unwrap();
                let mut y2 = y0;
                matmul_acc_blocked::<3, 5>(m, segs, n, &mut y2[..n * r]).unwrap();
                // the Cortex-M4F's lane-blocked loops, run here on the host
                let mut y3 = y0;
                matmul_acc_lanes::<2, 2, 4>(m, segs, n, &mut y3[..n * r]).unwrap();
                let mut y4 = y0;
                matmul_acc_lanes::<3, 1, 8>(m, segs, n, &mut y4[..n * r]).unwrap();
                for b in 0..n {
                    let mut want = [0.0f32; 128];
                    want[..r].copy_from_slice(&y0[b * r..(b + 1) * r]);
                    let mut one: [&[f32]; 4] = [&[]; 4];
                    for (s, &l) in lens.iter().enumerate() {
                        one[s] = &segs[s][b * l..(b + 1) * l];
                    }
                    ref_matvec(m, &one[..lens.len()], &mut want[..r]);
                    let mut mv = [0.0f32; 128];
                    mv[..r].copy_from_slice(&y0[b * r..(b + 1) * r]);
                    m.matvec_acc(&one[..lens.len()], &mut mv[..r]).unwrap();
                    let mut mp = [0.0f32; 128];
                    mp[..r].copy_from_slice(&y0[b * r..(b + 1) * r]);
                    matvec_acc_pairs(m, &one[..lens.len()], &mut mp[..r]).unwrap();
                    for i in 0..r {
                        let w = want[i].to_bits();
                        assert_eq!(
                            y[b * r + i].to_bits(),
                            w,
                            "matmul case {ci} kind {mi} b {b} i {i}"
                        );
                        assert_eq!(y2[b * r + i].to_bits(), w, "matmul 3x5 case {ci} kind {mi}");
                        assert_eq!(
                            y3[b * r + i].to_bits(),
                            w,
                            "lanes 2x2x4 case {ci} kind {mi}"
                        );
                        assert_eq!(
                            y4[b * r + i].to_bits(),
                            w,
                            "lanes 3x1x8 case {ci} kind {mi}"
                        );
                        assert_eq!(mv[i].to_bits(), w, "matvec case {ci} kind {mi}");
                        assert_eq!(mp[i].to_bits(), w, "matvec pairs case {ci} kind {mi}");
                    }
                }
                // dx += W^T dy
                let mut dxs: [[f32; BIG]; 4] =
                    core::array::from_fn(|s| big(n * 128, 500 + s as u32));
                let dx0 = dxs;
                {
                    let [a, b2, c2, d2] = &mut dxs;
                    let mut parts: [&mut [f32]; 4] = [
                        &mut a[..n * lens.first().copied().unwrap_or(0)],
                        &mut b2[..n * lens.get(1).copied().unwrap_or(0)],
                        &mut c2[..n * lens.get(2).copied().unwrap_or(0)],
                        &mut d2[..n * lens.get(3).copied().unwrap_or(0)],
                    ];
                    matmul_t_acc(m, &dy[..n * r], n, &mut parts[..lens.len()], lens).unwrap();
                }
                let mut dxs2 = dx0;
                {
                    let [a, b2, c2, d2] = &mut dxs2;
                    let mut parts: [&mut [f32]; 4] = [
                        &mut a[..n * lens.first().copied().unwrap_or(0)],
                        &mut b2[..n * lens.get(1).copied().unwrap_or(0)],
                        &mut c2[..n * lens.get(2).copied().unwrap_or(0)],
                        &mut d2[..n * lens.get(3).copied().unwrap_or(0)],
                    ];
                    matmul_t_acc_blocked::<3, 2>(m, &dy[..n * r], n, &mut parts[..lens.len()], 0)
                        .unwrap();
                }
                let mut dxs3 = dx0;
                let mut dxs4 = dx0;
                for (dd, two) in [(&mut dxs3, true), (&mut dxs4, false)] {
                    let [a, b2, c2, d2] = dd;
                    let mut parts: [&mut [f32]; 4] = [
                        &mut a[..n * lens.first().copied().unwrap_or(0)],
                        &mut b2[..n * lens.get(1).copied().unwrap_or(0)],
                        &mut c2[..n * lens.get(2).copied().unwrap_or(0)],
                        &mut d2[..n * lens.get(3).copied().unwrap_or(0)],
                    ];
                    let p = &mut parts[..lens.len()];
                    if two {
                        matmul_t_acc_rows::<2>(m, &dy[..n * r], n, p, 0).unwrap();
                    } else {
                        matmul_t_acc_rows::<1>(m, &dy[..n * r], n, p, 0).unwrap();
                    }
                }
                let mut off = 0;
                for (s, &l) in lens.iter().enumerate() {
                    for b in 0..n {
                        let mut want = [0.0f32; 128];
                        want[..l].copy_from_slice(&dx0[s][b * l..(b + 1) * l]);
                        ref_matvec_t(m, &dy[b * r..(b + 1) * r], off, &mut want[..l]);
                        for j in 0..l {
                            assert_eq!(
                                dxs[s][b * l + j].to_bits(),
                                want[j].to_bits(),
                                "matmul_t case {ci} kind {mi} seg {s}"
                            );
                            assert_eq!(
                                dxs2[s][b * l + j].to_bits(),
                                want[j].to_bits(),
                                "matmul_t 3x2 case {ci} kind {mi}"
                            );
                            assert_eq!(
                                dxs3[s][b * l + j].to_bits(),
                                want[j].to_bits(),
                                "matmul_t rows x2 case {ci} kind {mi}"
                            );
                            assert_eq!(
                                dxs4[s][b * l + j].to_bits(),
                                want[j].to_bits(),
                                "matmul_t rows x1 case {ci} kind {mi}"
                            );
                        }
                    }
                    off += l;
                }
            }
            // dW += alpha sum_b dy_b x_b^T
            let dw0 = big(r * c, 600 + ci as u32);
            let mut dw = dw0;
            outer_acc_batch(&mut dw[..r * c], &dy[..n * r], segs, lens, n, 0.75).unwrap();
            let mut dw2 = dw0;
            outer_acc_batch_blocked::<3, 2>(&mut dw2[..r * c], &dy[..n * r], segs, n, 0.75)
                .unwrap();
            let mut want = dw0;
            for b in 0..n {
                let mut xb = [0.0f32; 512];
                let mut off = 0;
                for (s, &l) in lens.iter().enumerate() {
                    xb[off..off + l].copy_from_slice(&segs[s][b * l..(b + 1) * l]);
                    off += l;
                }
                ref_outer(&mut want[..r * c], &dy[b * r..(b + 1) * r], &xb[..c], 0.75);
            }
            for i in 0..r * c {
                assert_eq!(
                    dw[i].to_bits(),
                    want[i].to_bits(),
                    "outer case {ci} elem {i}"
                );
                assert_eq!(dw2[i].to_bits(), want[i].to_bits(), "outer 3x2 case {ci}");
            }
        }
    }

    #[test]
    fn non_finite_values_propagate_exactly_as_the_canonical_order() {
        let (r, c, n) = (3, 19, 4);
        let mut wv = big(r * c, 7);
        wv[5] = f32::INFINITY;
        wv[30] = f32::NAN;
        let w = MatRef::f32(r, c, &wv[..r * c]).unwrap();
        let mut x = big(n * c, 8);
        x[c + 2] = f32::NEG_INFINITY;
        let mut y = [0.0f32; 12];
        matmul_acc(&w, &[&x[..n * c]], &[c], n, &mut y).unwrap();
        for b in 0..n {
            let mut want = [0.0f32; 3];
            ref_matvec(&w, &[&x[b * c..(b + 1) * c]], &mut want);
            for i in 0..r {
                assert_eq!(y[b * r + i].to_bits(), want[i].to_bits());
            }
        }
        assert!(y.iter().any(|v| v.is_nan()), "the NaN weight reaches y");
    }
}
