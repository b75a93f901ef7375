//! Weight matrices: f32 or int8 with a per-output-row f32 scale, viewed in place, and the
//! canonical scalar operations ([`dot`], [`axpy`] and their int8 / little-endian forms) that fix
//! the order of every floating-point operation. The kernels over these views, batch-1 and
//! batched, are in [`crate::nn::batch`], which builds on this module (never the other way round).
//!
//! A [`MatRef`] is a read-only, row-major view of a `rows x cols` matrix `W`. It never owns
//! memory: the values live in a caller's RAM buffer (f32, e.g. adapted parameters) or directly
//! in a weight blob in flash (int8; see [`crate::blob`]), which is why int8 scales can also be
//! read straight from little-endian bytes ([`Scales::Le`]) without a copy.
//!
//! The int8 scheme is symmetric per row: `W[i][j] ~= scale[i] * q[i][j]` with `q` in
//! `-127..=127` and `scale[i] = max_j |W[i][j]| / 127`, so the rounding error of every weight
//! is at most `scale[i] / 2` (see [`crate::blob::quant`]).
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

/// Dense kernels a host can compile for another instruction set and attach to a matrix view
/// ([`MatRef::with_kernels`]); every kernel of the view then runs through them. An
/// implementation must keep the contract of [`crate::nn::batch`] (the same bits as the canonical
/// order): the intended implementation calls the `*_blocked` functions of [`crate::nn::batch`] from
/// code compiled with more vector features (e.g. AVX2), which keeps every operation and only
/// widens the registers. The argument lists are those of [`crate::nn::batch`]'s functions; the
/// shapes are already checked when a kernel is called.
pub trait Kernels: Sync + core::fmt::Debug {
    /// [`crate::nn::batch::matmul_acc`] (the matrix `w` carries no kernels, so calling back into [`crate::nn::batch`]
    /// does not recurse).
    fn matmul_acc(&self, w: &MatRef<'_>, x: &[&[f32]], n: usize, y: &mut [f32]) -> Result<()>;
    /// [`crate::nn::batch::matmul_t_acc`] on the column block starting at `col0` (the segments of `dx` cover
    /// columns `col0 ..` in order).
    fn matmul_t_acc(
        &self,
        w: &MatRef<'_>,
        dy: &[f32],
        n: usize,
        dx: &mut [&mut [f32]],
        col0: usize,
    ) -> Result<()>;
    /// [`crate::nn::batch::outer_acc_batch`] for a gradient of `rows = dy.len() / n` rows.
    fn outer_acc_batch(
        &self,
        dw: &mut [f32],
        dy: &[f32],
        x: &[&[f32]],
        n: usize,
        alpha: f32,
    ) -> Result<()>;

    /// [`dots_i8`]: the integer dot products of `out.len()` int8 rows with an
    /// int8 input block. Integers are exact, so any order of additions gives the same
    /// result; the default is the portable kernel.
    fn dots_i8(&self, q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
        dots_i8(q, cols, col0, xq, out)
    }

    /// [`dots_i16`]: the same on an int16 input block (the map layer's products of two
    /// quantised values, `crate::nn::qkernel::cell_layer_int8`); the default is the portable
    /// kernel.
    fn dots_i16(&self, q: &[u8], cols: usize, col0: usize, x: &[i16], out: &mut [i32]) {
        dots_i16(q, cols, col0, x, out)
    }

    /// The whole of [`crate::nn::qkernel::matvec_acc_int8`] (`y += W x` on int8 activations, its
    /// canonical computation: the same bits) in one call, for a table that can run the
    /// quantisation, the integer products and the requantisation of a layer together. `w`
    /// is int8 and the lengths are checked by the caller. Returns `false` (having written
    /// nothing) when it does not take the shapes; then the driver runs its blocks through
    /// [`Kernels::dots_i8`]. The default takes none.
    fn matvec_int8(&self, w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> bool {
        let _ = (w, x, y);
        false
    }
}

/// A read-only `rows x cols` row-major matrix view. Construct with [`MatRef::f32`] or
/// [`MatRef::i8`], which check the lengths once so the kernels can trust them.
///
/// A view may carry a table of [`Kernels`] ([`MatRef::with_kernels`]): the host's way to run
/// the same kernels compiled for a wider instruction set (same bits, see [`crate::nn::batch`]).
#[derive(Clone, Copy, Debug)]
pub struct MatRef<'a> {
    rows: usize,
    cols: usize,
    w: Weights<'a>,
    k: Option<&'static dyn Kernels>,
    act8: bool,
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
            act8: false,
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
            act8: false,
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
            act8: false,
        })
    }

    /// The same view, running its kernels through `k` (see [`Kernels`]; the results are the
    /// same bits, only the speed changes).
    #[inline]
    pub fn with_kernels(self, k: &'static dyn Kernels) -> Self {
        MatRef { k: Some(k), ..self }
    }

    /// The same view computing `W x` on int8 activations ([`crate::nn::qkernel`]): every input
    /// segment is quantised to int8 with its own scale, multiplied by the int8 weights into
    /// i32 accumulators and requantised with the row scale. Only int8 views change (an f32
    /// view ignores the setting); the transposed kernels (gradients) stay f32.
    #[inline]
    pub fn with_int8_activations(self) -> Self {
        MatRef {
            act8: self.is_int8(),
            ..self
        }
    }

    /// True when [`MatRef::matvec_acc`] and [`crate::nn::batch::matmul_acc`] run the integer
    /// kernel of [`crate::nn::qkernel`] ([`MatRef::with_int8_activations`]).
    #[inline]
    pub fn int8_activations(&self) -> bool {
        // Without the feature the integer branches of the kernels are dead code and vanish.
        cfg!(feature = "int8-activations") && self.act8
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
        MatRef {
            k: other.k,
            act8: self.is_int8() && other.act8,
            ..self
        }
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
}

/// Total length of a segmented vector.
#[inline]
pub fn seg_len(x: &[&[f32]]) -> usize {
    x.iter().map(|s| s.len()).sum()
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

/// `out[r] = sum_j (q[r * cols + col0 + j] as i8) * xq[j]` for `r in 0..out.len()`: the
/// portable integer kernel (one row at a time). `q` holds at least `out.len()` rows of
/// `cols` bytes and `col0 + xq.len() <= cols` (the driver checks; shorter rows are cut).
pub fn dots_i8(q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
    dots_i8_body(q, cols, col0, xq, out)
}

/// The body of [`dots_i8`], inlined into its caller so that a host can compile it for a
/// wider instruction set (the integers are exact: any vectorisation gives the same values).
#[inline(always)]
pub fn dots_i8_body(q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
    let end = col0 + xq.len();
    if cols == 0 || end > cols {
        out.fill(0);
        return;
    }
    for (row, o) in q.chunks_exact(cols).zip(out.iter_mut()) {
        let mut acc = 0i32;
        for (&w, &x) in row[col0..end].iter().zip(xq) {
            acc += (w as i8 as i32) * (x as i32);
        }
        *o = acc;
    }
}

/// [`dots_i8`] on int16 inputs: `out[r] = sum_j (q[r * cols + col0 + j] as i8) * x[j]`, the
/// portable kernel of the map layer's products (`crate::nn::qkernel::cell_layer_int8`).
pub fn dots_i16(q: &[u8], cols: usize, col0: usize, x: &[i16], out: &mut [i32]) {
    let end = col0 + x.len();
    if cols == 0 || end > cols {
        out.fill(0);
        return;
    }
    for (row, o) in q.chunks_exact(cols).zip(out.iter_mut()) {
        let mut acc = 0i32;
        for (&w, &v) in row[col0..end].iter().zip(x) {
            acc += (w as i8 as i32) * (v as i32);
        }
        *o = acc;
    }
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
