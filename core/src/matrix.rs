//! Weight matrices: f32 or int8 with a per-output-row f32 scale, and the dense kernels on them.
//!
//! A [`MatRef`] is a read-only, row-major view of a `rows x cols` matrix `W`. It never owns
//! memory: the values live in a caller's RAM buffer (f32, e.g. adapted parameters) or directly
//! in a weight blob in flash (int8; see [`crate::blob`]), which is why int8 scales can also be
//! read straight from little-endian bytes ([`Scales::Le`]) without a copy.
//!
//! The int8 scheme is symmetric per row: `W[i][j] ~= scale[i] * q[i][j]` with `q` in
//! `-127..=127` and `scale[i] = max_j |W[i][j]| / 127`, so the rounding error of every weight
//! is at most `scale[i] / 2` (see [`crate::quant`]).
//!
//! # Inputs made of segments
//! Layers of GMAN take concatenated inputs (G takes `concat(z, SE(y))`, the policy fuses the
//! observation, the generated feature and more). Instead of copying the pieces into one
//! scratch vector, every kernel takes its input as a list of *segments* whose lengths add up
//! to `cols`: `W [x_1; x_2] = W_1 x_1 + W_2 x_2` where `W_i` are column blocks of `W`.
//!
//! # Arithmetic and determinism
//! Dot products use eight independent accumulators over `chunks_exact(8)`, then a fixed
//! reduction tree and a sequential tail. This lets LLVM use SIMD on the host without any
//! reassociation (the order of operations is fixed by the source), so an x86 build and a
//! Cortex-M4F build of the same code produce bit-identical results: no fused multiply-add
//! is ever introduced because Rust never contracts `a * b + c`.

use crate::batch::{self, Kernels, MAX_SEGS};
use crate::error::{check_len, Result};

/// Row scales of an int8 matrix.
#[derive(Clone, Copy, Debug)]
pub enum Scales<'a> {
    /// Scales already in RAM.
    F32(&'a [f32]),
    /// Little-endian f32 bytes, four per row, as stored in a blob (read in place).
    Le(&'a [u8]),
}

impl Scales<'_> {
    /// Number of scales.
    #[inline]
    pub fn len(&self) -> usize {
        match self {
            Scales::F32(s) => s.len(),
            Scales::Le(b) => b.len() / 4,
        }
    }

    /// True when there are no scales.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Scale of row `i` (0.0 past the end; callers check lengths first).
    #[inline]
    pub fn get(&self, i: usize) -> f32 {
        match self {
            Scales::F32(s) => s.get(i).copied().unwrap_or(0.0),
            Scales::Le(b) => match b.get(4 * i..4 * i + 4) {
                Some(&[a, b2, c, d]) => f32::from_le_bytes([a, b2, c, d]),
                _ => 0.0,
            },
        }
    }
}

/// Storage of a matrix's values.
#[derive(Clone, Copy, Debug)]
pub enum Weights<'a> {
    /// Plain f32 values, row-major.
    F32(&'a [f32]),
    /// f32 values as little-endian bytes (4 per value), row-major: an f32 tensor read in
    /// place from a blob, with no copy and no alignment requirement.
    F32Le(&'a [u8]),
    /// Int8 values (stored as bytes, read as `i8`), row-major, with one scale per row.
    I8 {
        /// The quantised values; byte `b` means the integer `b as i8`.
        q: &'a [u8],
        /// One scale per row.
        scales: Scales<'a>,
    },
}

/// A read-only `rows x cols` row-major matrix view. Construct with [`MatRef::f32`] or
/// [`MatRef::i8`], which check the lengths once so the kernels can trust them.
///
/// A view may carry a table of [`Kernels`] ([`MatRef::with_kernels`]): the host's way to run
/// the same kernels compiled for a wider instruction set (same bits, see [`crate::batch`]).
#[derive(Clone, Copy, Debug)]
pub struct MatRef<'a> {
    rows: usize,
    cols: usize,
    w: Weights<'a>,
    k: Option<&'static dyn Kernels>,
}

impl<'a> MatRef<'a> {
    /// An f32 matrix view; `data.len()` must be `rows * cols`.
    pub fn f32(rows: usize, cols: usize, data: &'a [f32]) -> Result<Self> {
        check_len("matrix.f32", rows.saturating_mul(cols), data.len())?;
        Ok(MatRef {
            rows,
            cols,
            w: Weights::F32(data),
            k: None,
        })
    }

    /// An f32 matrix view over little-endian bytes; `data.len()` must be `4 * rows * cols`.
    pub fn f32_le(rows: usize, cols: usize, data: &'a [u8]) -> Result<Self> {
        check_len(
            "matrix.f32_le",
            rows.saturating_mul(cols).saturating_mul(4),
            data.len(),
        )?;
        Ok(MatRef {
            rows,
            cols,
            w: Weights::F32Le(data),
            k: None,
        })
    }

    /// An int8 matrix view; `q.len()` must be `rows * cols` and there must be `rows` scales.
    pub fn i8(rows: usize, cols: usize, q: &'a [u8], scales: Scales<'a>) -> Result<Self> {
        check_len("matrix.i8", rows.saturating_mul(cols), q.len())?;
        check_len("matrix.scales", rows, scales.len())?;
        Ok(MatRef {
            rows,
            cols,
            w: Weights::I8 { q, scales },
            k: None,
        })
    }

    /// The same view, running its kernels through `k` (see [`Kernels`]; the results are the
    /// same bits, only the speed changes).
    #[inline]
    pub fn with_kernels(self, k: &'static dyn Kernels) -> Self {
        MatRef { k: Some(k), ..self }
    }

    /// The same view with the crate's own (portable) kernels.
    #[inline]
    pub fn without_kernels(self) -> Self {
        MatRef { k: None, ..self }
    }

    /// The kernel table attached with [`MatRef::with_kernels`], if any.
    #[inline]
    pub fn kernels(&self) -> Option<&'static dyn Kernels> {
        self.k
    }

    /// A view of other storage with the same kernel table as `self` (e.g. adapted f32
    /// weights in RAM standing in for the blob's).
    #[inline]
    pub fn kernels_from(self, other: &MatRef<'_>) -> Self {
        MatRef { k: other.k, ..self }
    }

    /// Number of rows (outputs).
    #[inline]
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Number of columns (inputs).
    #[inline]
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// The underlying storage.
    #[inline]
    pub fn weights(&self) -> Weights<'a> {
        self.w
    }

    /// True for int8 storage.
    #[inline]
    pub fn is_int8(&self) -> bool {
        matches!(self.w, Weights::I8 { .. })
    }

    /// Bytes of weight storage read by one full pass over the matrix (values plus scales).
    pub fn storage_bytes(&self) -> usize {
        match self.w {
            Weights::F32(d) => d.len() * 4,
            Weights::F32Le(d) => d.len(),
            Weights::I8 { q, scales } => q.len() + scales.len() * 4,
        }
    }

    /// The (dequantised) value at `(r, c)`, or 0.0 outside the matrix.
    pub fn get(&self, r: usize, c: usize) -> f32 {
        if r >= self.rows || c >= self.cols {
            return 0.0;
        }
        let i = r * self.cols + c;
        match self.w {
            Weights::F32(d) => d.get(i).copied().unwrap_or(0.0),
            Weights::F32Le(d) => le_at(d, i),
            Weights::I8 { q, scales } => {
                q.get(i).map(|&b| b as i8 as f32).unwrap_or(0.0) * scales.get(r)
            }
        }
    }

    /// Copies the (dequantised) values into `out` (`rows * cols`, row-major).
    pub fn copy_to(&self, out: &mut [f32]) -> Result<()> {
        check_len("matrix.copy_to", self.rows * self.cols, out.len())?;
        if self.cols == 0 {
            return Ok(());
        }
        match self.w {
            Weights::F32(d) => out.copy_from_slice(d),
            Weights::F32Le(d) => {
                for (o, b) in out.iter_mut().zip(d.chunks_exact(4)) {
                    *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
            Weights::I8 { q, scales } => {
                for (i, (orow, qrow)) in out
                    .chunks_exact_mut(self.cols)
                    .zip(q.chunks_exact(self.cols))
                    .enumerate()
                {
                    let s = scales.get(i);
                    for (o, &b) in orow.iter_mut().zip(qrow) {
                        *o = (b as i8) as f32 * s;
                    }
                }
            }
        }
        Ok(())
    }

    /// `y += W x`, where the input `x` is given as consecutive segments.
    pub fn matvec_acc(&self, x: &[&[f32]], y: &mut [f32]) -> Result<()> {
        check_len("matvec.x", self.cols, seg_len(x))?;
        check_len("matvec.y", self.rows, y.len())?;
        if self.cols == 0 {
            return Ok(());
        }
        // The Cortex-M4F (no vector unit) runs the row-at-a-time loop: the same canonical
        // order, fewer instructions there than the blocked body (measured in QEMU).
        if x.len() > MAX_SEGS || cfg!(target_arch = "arm") {
            self.matvec_acc_many(x, y);
            return Ok(());
        }
        match self.k {
            Some(k) => k.matmul_acc(&self.without_kernels(), x, 1, y),
            None => batch::matmul_acc_blocked::<MV_R, 1>(self, x, 1, y),
        }
    }

    /// [`MatRef::matvec_t_acc_cols`] one row at a time (the Cortex-M4F's loop; the same
    /// order as the blocked body: every element sums its rows in order).
    fn matvec_t_rowwise(&self, dy: &[f32], col0: usize, dx: &mut [f32]) {
        let end = col0 + dx.len();
        match self.w {
            Weights::F32(d) => {
                for (row, &g) in d.chunks_exact(self.cols).zip(dy) {
                    axpy(g, &row[col0..end], dx);
                }
            }
            Weights::F32Le(d) => {
                for (row, &g) in d.chunks_exact(4 * self.cols).zip(dy) {
                    for (o, b) in dx.iter_mut().zip(row[4 * col0..4 * end].chunks_exact(4)) {
                        *o += g * f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                    }
                }
            }
            Weights::I8 { q, scales } => {
                for (i, (row, &g)) in q.chunks_exact(self.cols).zip(dy).enumerate() {
                    axpy_i8(g * scales.get(i), &row[col0..end], dx);
                }
            }
        }
    }

    /// [`MatRef::matvec_acc`] one row at a time: for more than [`MAX_SEGS`] segments, and on
    /// the Cortex-M4F (the same canonical order as the blocked body).
    fn matvec_acc_many(&self, x: &[&[f32]], y: &mut [f32]) {
        match self.w {
            Weights::F32(d) => {
                for (row, yi) in d.chunks_exact(self.cols).zip(y.iter_mut()) {
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
                for (row, yi) in d.chunks_exact(4 * self.cols).zip(y.iter_mut()) {
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
                for (i, (row, yi)) in q.chunks_exact(self.cols).zip(y.iter_mut()).enumerate() {
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
        check_len("matvec_t.dx", self.cols, total)?;
        check_len("matvec_t.dy", self.rows, dy.len())?;
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
        check_len("matvec_t.dy", self.rows, dy.len())?;
        if col0.saturating_add(dx.len()) > self.cols {
            return Err(crate::Error::Shape(crate::ShapeError {
                what: "matvec_t.cols",
                expected: self.cols,
                actual: col0.saturating_add(dx.len()),
            }));
        }
        if self.cols == 0 {
            return Ok(());
        }
        if cfg!(target_arch = "arm") {
            self.matvec_t_rowwise(dy, col0, dx);
            return Ok(());
        }
        match self.k {
            Some(k) => k.matmul_t_acc(&self.without_kernels(), dy, 1, &mut [dx], col0),
            None => batch::matmul_t_acc_blocked::<MVT_C, 1>(self, dy, 1, &mut [dx], col0),
        }
    }
}

// Block shapes of the batch-1 kernels on hosts (speed only, never the bits): four rows per
// pass share each input load (16 vector registers on x86-64).
const MV_R: usize = 4;
const MVT_C: usize = 4;
const OUTER_R: usize = 2;
const OUTER_C: usize = 2;

/// Total length of a segmented vector.
#[inline]
pub fn seg_len(x: &[&[f32]]) -> usize {
    x.iter().map(|s| s.len()).sum()
}

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
    batch::outer_acc_batch_blocked::<OUTER_R, OUTER_C>(dw, dy, x, 1, alpha)
}

/// Dot product with eight independent accumulators (deterministic order; see module docs).
/// Lengths are truncated to the shorter slice.
#[inline]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f32; 8];
    let ca = a.chunks_exact(8);
    let cb = b.chunks_exact(8);
    let (ta, tb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (x, y) in ta.iter().zip(tb) {
        s += x * y;
    }
    s
}

/// Dot product of an int8 row (bytes read as `i8`) with an f32 vector, unscaled.
#[inline]
pub fn dot_i8(q: &[u8], x: &[f32]) -> f32 {
    let n = q.len().min(x.len());
    let (q, x) = (&q[..n], &x[..n]);
    let mut acc = [0.0f32; 8];
    let cq = q.chunks_exact(8);
    let cx = x.chunks_exact(8);
    let (tq, tx) = (cq.remainder(), cx.remainder());
    for (a, b) in cq.zip(cx) {
        for k in 0..8 {
            acc[k] += (a[k] as i8 as f32) * b[k];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (a, b) in tq.iter().zip(tx) {
        s += (*a as i8 as f32) * b;
    }
    s
}

/// `y += a * x` (truncated to the shorter slice).
#[inline]
pub fn axpy(a: f32, x: &[f32], y: &mut [f32]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// `y += a * q` for an int8 row `q`.
#[inline]
pub fn axpy_i8(a: f32, q: &[u8], y: &mut [f32]) {
    for (yi, qi) in y.iter_mut().zip(q) {
        *yi += a * (*qi as i8 as f32);
    }
}

#[inline]
fn le_at(d: &[u8], i: usize) -> f32 {
    match d.get(4 * i..4 * i + 4) {
        Some(&[a, b, c, e]) => f32::from_le_bytes([a, b, c, e]),
        _ => 0.0,
    }
}

/// Dot product of little-endian f32 bytes with an f32 vector (same order as [`dot`]).
#[inline]
pub fn dot_le(w: &[u8], x: &[f32]) -> f32 {
    let n = (w.len() / 4).min(x.len());
    let (w, x) = (&w[..4 * n], &x[..n]);
    let mut acc = [0.0f32; 8];
    let cw = w.chunks_exact(32);
    let cx = x.chunks_exact(8);
    let (tw, tx) = (cw.remainder(), cx.remainder());
    for (a, b) in cw.zip(cx) {
        for k in 0..8 {
            let v = f32::from_le_bytes([a[4 * k], a[4 * k + 1], a[4 * k + 2], a[4 * k + 3]]);
            acc[k] += v * b[k];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (a, b) in tw.chunks_exact(4).zip(tx) {
        s += f32::from_le_bytes([a[0], a[1], a[2], a[3]]) * b;
    }
    s
}
