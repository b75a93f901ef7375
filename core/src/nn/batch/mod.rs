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
//!
//! # Where each part lives
//! This file holds the checked entry points (the batch-1 kernels of [`MatRef`],
//! [`matmul_acc`], [`matmul_t_acc`], [`outer_acc_batch`]) and the choice of body for each
//! target; `kind` the weight formats as the bodies read them and the one dispatch on a view's
//! format (`with_kind!`); `matmul`, `matmul_t` and `outer` the blocked bodies of the three
//! products; `lanes` the bodies for few registers (the Cortex-M4F's).

use crate::error::{check_len, Result};
pub use crate::nn::matrix::Kernels;
use crate::nn::matrix::{axpy, axpy_i8, dot, dot_i8, dot_le, seg_len, MatRef, Weights};

mod kind;
mod lanes;
mod matmul;
mod matmul_t;
mod outer;
#[cfg(test)]
mod tests;

pub use kind::MAX_SEGS;
pub use lanes::{matmul_acc_lanes, matmul_t_acc_rows, matvec_acc_pairs};
pub use matmul::matmul_acc_blocked;
pub use matmul_t::matmul_t_acc_blocked;
pub use outer::outer_acc_batch_blocked;

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
