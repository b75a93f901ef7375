//! Integer kernels: `y += W x` with int8 activations times int8 weights into i32
//! accumulators (the opt-in path of a blob with [`crate::spec::schema::FLAG_INT8_ACTIVATIONS`]).
//!
//! # The canonical computation
//! For an int8 matrix (`W[i][j] ~= s_i q_ij`, see [`crate::blob::quant`]) and an input given as
//! segments (see [`crate::nn::matrix`]), every segment `x` is quantised on its own:
//!
//! * `a = max_j |x_j|` over its finite values; `a == 0` (or an empty segment) adds nothing;
//! * `s_x = a / 127`, `inv = 127 / a`, `p_j = clamp(round_half_away(x_j * inv), -127, 127)`
//!   (NaN quantises to 0, ±inf to ±127);
//! * the segment is cut into blocks of [`QCOLS`] columns; for every block and row `i` the
//!   integer `acc_i = sum_j q_ij p_j` is exact in an `i32` (`|acc| <= 127 * 127 * QCOLS`),
//!   and `y_i += (acc_i as f32) * (s_x * s_i)`, blocks in order.
//!
//! The integers do not depend on the order of the additions, so the portable kernel
//! ([`dots_i8`]), the Cortex-M4F's `SMLAD` kernel ([`dots_i8_dsp`], through the `gman-dsp`
//! crate), the row-blocked one of Arm targets without DSP instructions ([`dots_i8_rows`])
//! and a host's SIMD build (the `dots_i8` method of [`Kernels`]) give the same `acc_i`, and
//! the few f32
//! operations around them run in one fixed order in this module: host and device compute
//! the same bits by construction.
//!
//! The scale of each activation segment is computed at run time from the values
//! themselves (dynamic quantisation, as ONNX Runtime's dynamically quantised int8): one pass
//! of `cols` comparisons per matrix-vector product, next to `rows x cols` MACs, and no
//! calibration data whose range a new scene could exceed.

use crate::error::{check_len, Result};
pub use crate::nn::matrix::{dots_i16, dots_i8, dots_i8_body};
use crate::nn::matrix::{seg_len, Kernels, MatRef, Scales, Weights};

/// Columns of one quantised input block (a stack buffer of this many `i8`).
pub const QCOLS: usize = 256;
/// Rows whose accumulators one kernel call fills (a stack buffer of this many `i32`).
pub const QROWS: usize = 64;
/// Words of one input block packed for [`dots_i8_dsp`] (two int16 halves per word).
pub const QWORDS: usize = QCOLS / 2;
/// True when gman-core is built with its feature `int8-activations` (the integer path is
/// compiled in; without it, callers can compile out their own uses of this module).
pub const INT8_ACTIVATIONS: bool = cfg!(feature = "int8-activations");
/// True when gman-core is built with its feature `f32-activations` (the f32-activation
/// forward kernels for int8 weights; without it only int8-activation views of int8 weights
/// run forward).
pub const F32_ACTIVATIONS: bool = cfg!(feature = "f32-activations");
/// The error of an int8 weight matrix with f32 activations in a build without them.
pub(crate) const NO_F32_ACTIVATIONS: crate::Error = crate::Error::Config {
    what: "f32 activations: needs gman-core's feature `f32-activations` (or `--activations int8`)",
};
/// True when [`dots_i8_dsp`] runs the `SXTB16` / `SMLAD` instructions (Armv7E-M targets),
/// false where it runs their plain-Rust model; the integers are the same.
pub const DSP_KERNEL: bool = gman_dsp::HAS_DSP;

/// Packs an int8 input block for [`dots_i8_dsp`] (see [`gman_dsp::pack`]); returns the
/// number of inputs packed.
pub fn pack_dsp(xq: &[i8], xp: &mut [u32]) -> usize {
    gman_dsp::pack(xq, xp)
}

/// The activation scale of a segment: `(s_x, inv) = (a / 127, 127 / a)` with `a` the largest
/// finite `|x_j|`; `(0, 0)` when `a == 0`.
#[inline]
pub fn act_scale(x: &[f32]) -> (f32, f32) {
    let (sx, inv, _) = act_range(x);
    (sx, inv)
}

/// [`act_scale`], and whether no `x_j` has its sign bit set (then [`quantize_act`] may take
/// its shorter non-negative form, [`quantize_nonneg`], with the same results).
///
/// The largest `|x_j|` is found on the bit patterns: for finite non-negative floats (and the
/// magnitudes `bits & 0x7fff_ffff` are those) the integer order is the numeric order, so the
/// integer maximum is the very value a float comparison finds. A segment holding an infinity
/// or a NaN (a magnitude `>= 0x7f80_0000`) takes a second pass that skips them.
#[inline]
pub fn act_range(x: &[f32]) -> (f32, f32, bool) {
    let (mut m, mut signs) = (0u32, 0u32);
    for &v in x {
        let b = v.to_bits();
        signs |= b;
        let h = b & 0x7fff_ffff;
        if h > m {
            m = h;
        }
    }
    if m >= 0x7f80_0000 {
        m = 0;
        for &v in x {
            let h = v.to_bits() & 0x7fff_ffff;
            if h < 0x7f80_0000 && h > m {
                m = h;
            }
        }
    }
    let a = f32::from_bits(m);
    let nonneg = signs >> 31 == 0;
    if a > 0.0 {
        (a / 127.0, 127.0 / a, nonneg)
    } else {
        (0.0, 0.0, nonneg)
    }
}

/// One activation quantised with `inv`: `clamp(round_half_away(v * inv), -127, 127)`, NaN to
/// 0. Written as the magnitude `min(trunc(|t| + 0.5), 127)` with the sign of `t` put back
/// (`t - 0.5 == -(|t| + 0.5)` exactly, so this is `trunc(t - 0.5)` for negative `t`; `-0.0`
/// and NaN give 0 either way), which needs no floating-point comparison.
#[inline(always)]
pub fn quantize_one(v: f32, inv: f32) -> i32 {
    let t = v * inv;
    // `as` saturates and maps NaN to 0.
    let m = ((libm::fabsf(t) + 0.5) as i32).clamp(0, 127);
    let s = (t.to_bits() as i32) >> 31;
    (m ^ s) - s
}

/// [`quantize_one`] for a `v` whose sign bit is clear (`t = v * inv` is then `+0`, positive
/// or a NaN): `min(trunc(t + 0.5), 127)`, the same value.
#[inline(always)]
pub fn quantize_nonneg(v: f32, inv: f32) -> i32 {
    ((v * inv + 0.5) as i32).clamp(0, 127)
}

/// Quantises `x` with `inv` (from [`act_scale`]) into `out` (truncated to the shorter):
/// [`quantize_one`] of every value.
#[inline]
pub fn quantize_act(x: &[f32], inv: f32, out: &mut [i8]) {
    for (o, &v) in out.iter_mut().zip(x) {
        *o = quantize_one(v, inv) as i8;
    }
}

/// [`quantize_act`] for the DSP kernel: the integers packed by [`gman_dsp::pair_words`] into
/// `xp` (four inputs at a time, as many groups as `xp` and `xq` hold), the rest (fewer than
/// four when `xp` holds the block) into `xq` at the same positions, which is all
/// [`dots_i8_dsp`] reads of `xq`; `nonneg` (from [`act_range`]) picks [`quantize_nonneg`].
/// Returns the number of inputs packed.
#[inline]
fn quantize_pack(x: &[f32], inv: f32, nonneg: bool, xq: &mut [i8], xp: &mut [u32]) -> usize {
    if nonneg {
        quantize_pack_with(x, xq, xp, |v| quantize_nonneg(v, inv))
    } else {
        quantize_pack_with(x, xq, xp, |v| quantize_one(v, inv))
    }
}

#[inline(always)]
fn quantize_pack_with<T: Copy>(
    x: &[T],
    xq: &mut [i8],
    xp: &mut [u32],
    f: impl Fn(T) -> i32,
) -> usize {
    let mut packed = 0;
    for (xs, ps) in x
        .chunks_exact(4)
        .zip(xp.chunks_exact_mut(2))
        .take(xq.len() / 4)
    {
        let v = [f(xs[0]), f(xs[1]), f(xs[2]), f(xs[3])];
        let [a, b] = gman_dsp::pair_words(v);
        ps[0] = a;
        ps[1] = b;
        packed += 4;
    }
    for (q, &v) in xq.iter_mut().zip(x).skip(packed) {
        *q = f(v) as i8;
    }
    packed
}

/// [`dots_i8`] four rows at a time (each input byte loaded once for four rows, columns in
/// steps of four): the Cortex-M4F's kernel. The same integers as [`dots_i8`].
pub fn dots_i8_rows(q: &[u8], cols: usize, col0: usize, xq: &[i8], out: &mut [i32]) {
    let end = col0 + xq.len();
    if cols == 0 || end > cols {
        out.fill(0);
        return;
    }
    let n = xq.len();
    let n4 = n - n % 4;
    let mut rows = q.chunks_exact(cols);
    let mut outs = out.chunks_exact_mut(4);
    for o in &mut outs {
        let (Some(a), Some(b), Some(c), Some(d)) =
            (rows.next(), rows.next(), rows.next(), rows.next())
        else {
            o.fill(0);
            continue;
        };
        let (a, b, c, d) = (&a[col0..end], &b[col0..end], &c[col0..end], &d[col0..end]);
        let mut acc = [0i32; 4];
        for ((((xc, ac), bc), cc), dc) in xq[..n4]
            .chunks_exact(4)
            .zip(a.chunks_exact(4))
            .zip(b.chunks_exact(4))
            .zip(c.chunks_exact(4))
            .zip(d.chunks_exact(4))
        {
            for k in 0..4 {
                let x = xc[k] as i32;
                acc[0] += (ac[k] as i8 as i32) * x;
                acc[1] += (bc[k] as i8 as i32) * x;
                acc[2] += (cc[k] as i8 as i32) * x;
                acc[3] += (dc[k] as i8 as i32) * x;
            }
        }
        for j in n4..n {
            let x = xq[j] as i32;
            acc[0] += (a[j] as i8 as i32) * x;
            acc[1] += (b[j] as i8 as i32) * x;
            acc[2] += (c[j] as i8 as i32) * x;
            acc[3] += (d[j] as i8 as i32) * x;
        }
        o.copy_from_slice(&acc);
    }
    let rest = outs.into_remainder();
    let done = out_len_done(q, cols, rest.len());
    dots_i8(&q[done..], cols, col0, xq, rest);
}

/// [`dots_i8`] with the Cortex-M4F's DSP instructions: two rows at a time through
/// [`gman_dsp::dots2`] (`SXTB16` unpacks four int8 weights into two pairs of int16, `SMLAD`
/// adds two products per instruction) on the input block `xq` packed by [`gman_dsp::pack`]
/// into `xp`, the last `xq.len() % 4` columns (and an odd last row) in plain Rust. The same
/// integers as [`dots_i8`] (`xq` is read only past the columns `xp` holds); off DSP targets
/// `gman_dsp::dots2` is its plain-Rust model of the instructions, which is how a host test
/// checks this function.
#[inline(always)]
pub fn dots_i8_dsp(q: &[u8], cols: usize, col0: usize, xq: &[i8], xp: &[u32], out: &mut [i32]) {
    dots_dsp(q, cols, col0, xq, xp, out)
}

/// [`dots_i8_dsp`] on int16 inputs (the map layer's products, [`cell_layer_int8`]): `xp`
/// holds them packed as [`gman_dsp::pair_words`] packs them, `xq` the columns past those.
/// The same integers as [`dots_i16`].
#[inline(always)]
pub fn dots_i16_dsp(q: &[u8], cols: usize, col0: usize, xq: &[i16], xp: &[u32], out: &mut [i32]) {
    dots_dsp(q, cols, col0, xq, xp, out)
}

#[inline(always)]
fn dots_dsp<T: Copy + Into<i32>>(
    q: &[u8],
    cols: usize,
    col0: usize,
    xq: &[T],
    xp: &[u32],
    out: &mut [i32],
) {
    let end = col0 + xq.len();
    if cols == 0 || end > cols {
        out.fill(0);
        return;
    }
    let n = xq.len();
    let main = gman_dsp::span(n, n, xp.len());
    let tail = |row: &[u8]| -> i32 {
        let mut acc = 0i32;
        for (&w, &x) in row[main..].iter().zip(&xq[main..]) {
            acc += (w as i8 as i32) * x.into();
        }
        acc
    };
    let mut rows = q.chunks_exact(cols).map(|r| &r[col0..end]);
    let mut outs = out.chunks_exact_mut(2);
    for o in &mut outs {
        let (Some(a), Some(b)) = (rows.next(), rows.next()) else {
            o.fill(0);
            continue;
        };
        let (sa, sb) = gman_dsp::dots2(a, b, xp);
        o[0] = sa + tail(a);
        o[1] = sb + tail(b);
    }
    if let [last] = outs.into_remainder() {
        *last = match rows.next() {
            Some(a) => gman_dsp::dots2(a, a, xp).0 + tail(a),
            None => 0,
        };
    }
}

/// Byte offset of the rows [`dots_i8_rows`] leaves to [`dots_i8`].
#[inline]
fn out_len_done(q: &[u8], cols: usize, rest: usize) -> usize {
    let rows = q.len() / cols;
    rows.saturating_sub(rest) * cols
}

/// Which integer kernel fills the accumulators.
#[derive(Clone, Copy)]
enum Dots {
    Portable,
    Rows,
    Dsp,
    Table(&'static dyn Kernels),
}

/// `y += W x` on int8 activations, the canonical computation of the module docs. `w` must be
/// int8 (else the call is an error naming it); `x` are segments adding up to `w.cols()`.
/// A kernel table attached to `w` fills the accumulators (same integers).
pub fn matvec_acc_int8(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> Result<()> {
    matvec_int8_with(w, x, &[], y, pick(w))
}

/// What one input segment adds to `y` in [`matvec_acc_int8`], kept from an earlier call of
/// [`segment_terms_int8`] on the same values: `blocks` rows of `terms`, each `W.rows()` wide,
/// the term `(acc_i as f32) * (s_x * s_i)` of every row for each block of [`QCOLS`] columns
/// in order (`blocks` is 0 for a segment whose scale is 0: it adds nothing).
#[derive(Clone, Copy, Debug)]
pub struct SegTerms<'a> {
    /// `blocks x rows` terms, block-major.
    pub terms: &'a [f32],
    /// Blocks that add a term.
    pub blocks: usize,
}

/// Rows of `terms` [`segment_terms_int8`] writes for a segment of `len` values (its
/// blocks of [`QCOLS`] columns).
pub const fn segment_blocks(len: usize) -> usize {
    len.div_ceil(QCOLS)
}

/// The terms the segment `seg`, at columns `col0 .. col0 + seg.len()` of `w`, adds to `y` in
/// [`matvec_acc_int8`] (see [`SegTerms`]), into `terms` (at least
/// [`segment_blocks`]`(seg.len()) x rows`); returns the number of blocks written. Adding
/// them block by block, in order, at the segment's place among the others
/// ([`matvec_acc_int8_terms`]) gives `y` exactly the bits of quantising the segment again:
/// each block adds one f32 term per row, and these are the terms (each computed into
/// `-0.0`, the exact identity of `+`).
pub fn segment_terms_int8(
    w: &MatRef<'_>,
    col0: usize,
    seg: &[f32],
    terms: &mut [f32],
) -> Result<usize> {
    let (rows, cols) = (w.rows(), w.cols());
    check_len(
        "segment_terms.cols",
        cols,
        cols.max(col0.saturating_add(seg.len())),
    )?;
    let nb = segment_blocks(seg.len());
    let need = nb.saturating_mul(rows);
    check_len("segment_terms.terms", need, terms.len().min(need))?;
    let Weights::I8 { q, scales } = w.weights() else {
        return Err(crate::Error::Config {
            what: "segment_terms_int8: the matrix is not int8",
        });
    };
    // (A host's table fills the same integers block by block.)
    let terms = &mut terms[..need];
    terms.fill(-0.0);
    let added = seg_blocks((q, &scales, cols), col0, seg, (terms, rows), pick(w));
    Ok(if added { nb } else { 0 })
}

/// The blocks of one input segment at columns `off ..` of an int8 matrix (`(q, scales,
/// cols)`): quantised with its own scale, block `b`'s terms added to `y[b * stride ..]`
/// (`(y, stride)`; stride 0: all into `y`). Returns false when the segment's scale is 0
/// (nothing added).
// Not inlined: one copy for matvec_acc_int8 and segment_terms_int8.
#[inline(never)]
fn seg_blocks(
    (q, scales, cols): (&[u8], &Scales<'_>, usize),
    off: usize,
    seg: &[f32],
    (y, stride): (&mut [f32], usize),
    dots: Dots,
) -> bool {
    let (sx, inv, nonneg) = act_range(seg);
    if sx <= 0.0 {
        return false;
    }
    let mut xq = [0i8; QCOLS];
    let mut xp = [0u32; QWORDS];
    let mut acc = [0i32; QROWS];
    let rows = y.len().min(if stride == 0 { y.len() } else { stride });
    for (b, xs) in seg.chunks(QCOLS).enumerate() {
        let xq = &mut xq[..xs.len()];
        let xp = quantize_for(dots, xs, inv, nonneg, xq, &mut xp);
        let yb = &mut y[b * stride..b * stride + rows];
        block(
            q,
            scales,
            cols,
            off + b * QCOLS,
            xq,
            xp,
            sx,
            &mut acc,
            yb,
            dots,
        );
    }
    true
}

/// [`matvec_acc_int8`] with some segments' terms given (`cached[i]`, when `Some`, stands for
/// segment `i`, whose values in `x` are then not read, only its length): the bits of
/// [`matvec_acc_int8`] on the values the terms were computed from. `cached` is empty or as
/// long as `x`.
pub fn matvec_acc_int8_terms(
    w: &MatRef<'_>,
    x: &[&[f32]],
    cached: &[Option<SegTerms<'_>>],
    y: &mut [f32],
) -> Result<()> {
    if !cached.is_empty() {
        check_len("matvec_int8.cached", x.len(), cached.len())?;
    }
    matvec_int8_with(w, x, cached, y, pick(w))
}

/// Quantises one input block for `dots` (packed for the DSP kernel); returns the packed words.
#[inline(always)]
fn quantize_for<'p>(
    dots: Dots,
    xs: &[f32],
    inv: f32,
    nonneg: bool,
    xq: &mut [i8],
    xp: &'p mut [u32; QWORDS],
) -> &'p [u32] {
    match dots {
        Dots::Dsp => {
            let packed = quantize_pack(xs, inv, nonneg, xq, xp);
            &xp[..packed / 2]
        }
        _ => {
            quantize_act(xs, inv, xq);
            &xp[..0]
        }
    }
}

/// The kernel of a view: the DSP kernel on a DSP target (a constant there, so that a firmware
/// image holds the drivers' DSP form only), else the view's table if it has one, else the
/// target's.
#[inline]
fn pick(w: &MatRef<'_>) -> Dots {
    if gman_dsp::HAS_DSP {
        return Dots::Dsp;
    }
    match w.kernels() {
        Some(k) => Dots::Table(k),
        None if gman_dsp::HAS_DSP => Dots::Dsp,
        None if cfg!(target_arch = "arm") => Dots::Rows,
        None => Dots::Portable,
    }
}

/// [`matvec_acc_int8`] with gman-core's portable kernel whatever the target or the view's
/// kernel table (the reference a test compares the optimised kernels with).
pub fn matvec_acc_int8_portable(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> Result<()> {
    matvec_int8_with(w, x, &[], y, Dots::Portable)
}

/// [`matvec_acc_int8`] with [`dots_i8_dsp`] whatever the target (on a host: its plain-Rust
/// model of the DSP instructions), for the tests that compare it with the portable kernel.
pub fn matvec_acc_int8_dsp(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> Result<()> {
    matvec_int8_with(w, x, &[], y, Dots::Dsp)
}

// Not inlined: one copy of the driver in a firmware image, whatever the call sites.
#[inline(never)]
fn matvec_int8_with(
    w: &MatRef<'_>,
    x: &[&[f32]],
    cached: &[Option<SegTerms<'_>>],
    y: &mut [f32],
    dots: Dots,
) -> Result<()> {
    let (rows, cols) = (w.rows(), w.cols());
    check_len("matvec_int8.x", cols, seg_len(x))?;
    check_len("matvec_int8.y", rows, y.len())?;
    let Weights::I8 { q, scales } = w.weights() else {
        return Err(crate::Error::Config {
            what: "matvec_int8: the matrix is not int8",
        });
    };
    if cols == 0 {
        return Ok(());
    }
    // A host's table may run the whole layer at once (same bits); a DSP target never has one.
    if let (false, Dots::Table(k), true) = (gman_dsp::HAS_DSP, dots, cached.is_empty()) {
        if k.matvec_int8(w, x, y) {
            return Ok(());
        }
    }
    let mut off = 0;
    for (i, seg) in x.iter().enumerate() {
        if let Some(Some(t)) = cached.get(i) {
            // The segment's terms, block by block (one add per row and block, as below).
            let need = t.blocks.saturating_mul(rows);
            check_len("matvec_int8.terms", need, t.terms.len().min(need))?;
            if t.blocks > segment_blocks(seg.len()) {
                return Err(crate::Error::Config {
                    what: "matvec_int8: more cached blocks than the segment has",
                });
            }
            for tb in t.terms.chunks_exact(rows.max(1)).take(t.blocks) {
                for (yi, &v) in y.iter_mut().zip(tb) {
                    *yi += v;
                }
            }
        } else {
            seg_blocks((q, &scales, cols), off, seg, (&mut *y, 0), dots);
        }
        off += seg.len();
    }
    Ok(())
}

/// Map cells whose scales [`cell_layer_int8`] holds at once (more cells run in groups of
/// this many; each cell's computation is the same).
const CELL_GROUP: usize = 16;

/// The map's per-cell layer on int8 activations: `out_c += W [m_c; m_c ⊙ x]` for every cell
/// `c` of `map` (`cells x f`, cell-major; `x` is `f` wide, `W` is `rows x 2f`, `out` is
/// `cells x rows`, holding the bias). Its canonical computation differs from
/// [`matvec_acc_int8`] of the two segments in one point: the product `m_c ⊙ x` is not
/// formed in f32 and quantised again, it is the product of the two quantised factors,
/// exact in int16 (`|p| <= 127 * 127`):
///
/// * `x` is quantised once for all cells (its own scale `s_x`, [`act_range`]), `m_c` once
///   per cell (scale `s_m`); a segment whose scale is 0 adds nothing;
/// * per block of [`QCOLS`] columns `b`, in order: `y_i += (acc_i as f32) * (s_m * s_i)`
///   with `acc_i = sum_j q_ij pm_j` over the block of the `m` half, then
///   `y_i += (acc_i as f32) * ((s_m * s_x) * s_i)` with `acc_i = sum_j q_i,f+j (pm_j px_j)`
///   over the same block of the product half (`|acc| <= 128 * 127 * 127 * QCOLS < 2^31`).
///
/// Each value of the map is quantised once and serves both halves; `x` is quantised once
/// per step instead of nine products per cell. The DSP kernel runs the int16 products as
/// they are (`SMLAD` multiplies int16 halves; [`dots_i16_dsp`]).
pub fn cell_layer_int8(w: &MatRef<'_>, map: &[f32], x: &[f32], out: &mut [f32]) -> Result<()> {
    cell_layer_in(w, CellIn::F32(map), x, out)
}

/// [`cell_layer_int8`] on a map given as the camera quantised it: `map[j] * scale` is the
/// value of feature `j` (u8 codes with one scale for the whole map). Each cell is quantised
/// to int8 in integers, not through f32: with `a = max_j map_j` over the cell (a cell of
/// zeros adds nothing), `s_m = (a as f32 * scale) / 127` and `p_j = (map_j r + 2^15) >> 16`
/// with `r = (127 · 2^16 + a / 2) / a` (so `p_j <= 127`); the rest is
/// [`cell_layer_int8`]'s computation with these `p_j` and `s_m`. `scale` must be finite and
/// positive (the caller checks).
pub fn cell_layer_int8_u8(
    w: &MatRef<'_>,
    map: &[u8],
    scale: f32,
    x: &[f32],
    out: &mut [f32],
) -> Result<()> {
    cell_layer_in(w, CellIn::U8(map, scale), x, out)
}

/// A map as the cell layer's integer form takes it.
#[derive(Clone, Copy)]
enum CellIn<'a> {
    /// f32 values, each cell quantised by [`act_range`] and [`quantize_act`].
    F32(&'a [f32]),
    /// u8 codes and their one scale ([`cell_layer_int8_u8`]).
    U8(&'a [u8], f32),
}

/// A cell's quantisation: its scale `s_m`, the f32 form's `inv` and sign, the u8 form's `r`.
type CellScale = (f32, f32, bool, u32);

impl CellIn<'_> {
    fn len(&self) -> usize {
        match self {
            CellIn::F32(m) => m.len(),
            CellIn::U8(m, _) => m.len(),
        }
    }

    /// The quantisation of cell `c` (`f` values).
    fn range(&self, c: usize, f: usize) -> CellScale {
        match *self {
            CellIn::F32(m) => {
                let (s, inv, nonneg) = act_range(&m[c * f..(c + 1) * f]);
                (s, inv, nonneg, 0)
            }
            CellIn::U8(m, scale) => {
                let a = m[c * f..(c + 1) * f].iter().copied().max().unwrap_or(0) as u32;
                if a == 0 {
                    return (0.0, 0.0, true, 0);
                }
                let r = ((127u32 << 16) + a / 2) / a;
                ((a as f32 * scale) / 127.0, 0.0, true, r)
            }
        }
    }

    /// Quantises columns `c0 .. c0 + len` of cell `c` into `mq` (and, for the DSP kernel,
    /// packed into `mw`); returns the number of inputs packed.
    #[inline(always)]
    fn quantize(
        &self,
        (c, f, c0, len): (usize, usize, usize, usize),
        (_, inv, nonneg, r): CellScale,
        dsp: bool,
        mq: &mut [i8],
        mw: &mut [u32],
    ) -> usize {
        match *self {
            CellIn::F32(m) => {
                let mb = &m[c * f + c0..c * f + c0 + len];
                if dsp {
                    quantize_pack(mb, inv, nonneg, mq, mw)
                } else {
                    quantize_act(mb, inv, mq);
                    0
                }
            }
            CellIn::U8(m, _) => {
                let mb = &m[c * f + c0..c * f + c0 + len];
                let qf = |v: u8| ((v as u32 * r + (1 << 15)) >> 16) as i32;
                if dsp {
                    quantize_pack_with(mb, mq, mw, qf)
                } else {
                    for (o, &v) in mq.iter_mut().zip(mb) {
                        *o = qf(v) as i8;
                    }
                    0
                }
            }
        }
    }
}

/// [`cell_layer_int8`] or [`cell_layer_int8_u8`] with the target's kernel.
fn cell_layer_in(w: &MatRef<'_>, map: CellIn<'_>, x: &[f32], out: &mut [f32]) -> Result<()> {
    if gman_dsp::HAS_DSP {
        return cell_layer_with::<true>(w, map, x, out, Dots::Dsp);
    }
    cell_layer_with::<false>(w, map, x, out, pick(w))
}

/// [`cell_layer_int8`] with the portable kernels whatever the target or kernel table.
pub fn cell_layer_int8_portable(
    w: &MatRef<'_>,
    map: &[f32],
    x: &[f32],
    out: &mut [f32],
) -> Result<()> {
    cell_layer_with::<false>(w, CellIn::F32(map), x, out, Dots::Portable)
}

/// [`cell_layer_int8`] with the DSP kernels whatever the target (on a host: their model).
pub fn cell_layer_int8_dsp(w: &MatRef<'_>, map: &[f32], x: &[f32], out: &mut [f32]) -> Result<()> {
    cell_layer_with::<true>(w, CellIn::F32(map), x, out, Dots::Dsp)
}

/// Multiplies the int16 halves of two words packed by [`gman_dsp::pair_words`]: the packed
/// words of the four products (each product must fit in an int16).
#[inline(always)]
fn mul_halves(a: u32, b: u32) -> u32 {
    let lo = (a as u16 as i16 as i32) * (b as u16 as i16 as i32);
    let hi = ((a as i32) >> 16) * ((b as i32) >> 16);
    (lo as u32 & 0xffff) | ((hi as u32) << 16)
}

/// `DSP`: the kernel is [`Dots::Dsp`] (a constant, so that an image holds that form only).
#[inline(never)]
fn cell_layer_with<const DSP: bool>(
    w: &MatRef<'_>,
    map: CellIn<'_>,
    x: &[f32],
    out: &mut [f32],
    dots: Dots,
) -> Result<()> {
    let (rows, cols, f) = (w.rows(), w.cols(), x.len());
    check_len("cell_int8.w", 2 * f, cols)?;
    let Weights::I8 { q, scales } = w.weights() else {
        return Err(crate::Error::Config {
            what: "cell_layer_int8: the matrix is not int8",
        });
    };
    let cells = map.len().checked_div(f).unwrap_or(0);
    check_len("cell_int8.map", cells * f, map.len())?;
    check_len("cell_int8.out", cells * rows, out.len())?;
    if f == 0 || rows == 0 {
        return Ok(());
    }
    let dots = if DSP { Dots::Dsp } else { dots };
    let dsp = DSP || matches!(dots, Dots::Dsp);
    let (sx, xinv, xnonneg) = act_range(x);
    let mut xq = [0i8; QCOLS];
    let mut xw = [0u32; QWORDS];
    let mut mq = [0i8; QCOLS];
    let mut mw = [0u32; QWORDS];
    let mut pq = [0i16; QCOLS];
    let mut acc = [0i32; QROWS];
    let mut sc: [CellScale; CELL_GROUP] = [(0.0, 0.0, false, 0); CELL_GROUP];
    for (gi, og) in out.chunks_mut(CELL_GROUP * rows).enumerate() {
        let g0 = gi * CELL_GROUP;
        for (i, s) in sc.iter_mut().enumerate().take(og.len() / rows) {
            *s = map.range(g0 + i, f);
        }
        for c0 in (0..f).step_by(QCOLS) {
            let len = (f - c0).min(QCOLS);
            let (xq, mq, pq) = (&mut xq[..len], &mut mq[..len], &mut pq[..len]);
            let mut xpacked = 0;
            if sx > 0.0 {
                if dsp {
                    xpacked = quantize_pack(&x[c0..c0 + len], xinv, xnonneg, xq, &mut xw);
                } else {
                    quantize_act(&x[c0..c0 + len], xinv, xq);
                }
            }
            for (i, (o, &cs)) in og.chunks_exact_mut(rows).zip(&sc).enumerate() {
                let sm = cs.0;
                if sm <= 0.0 {
                    continue;
                }
                let packed = map.quantize((g0 + i, f, c0, len), cs, dsp, mq, &mut mw);
                let words = &mut mw[..packed / 2];
                block(q, &scales, cols, c0, &*mq, words, sm, &mut acc, o, dots);
                if sx > 0.0 {
                    // The product block: packed words multiplied half by half, the columns
                    // past them (all of them off the DSP path) one by one.
                    let done = packed.min(xpacked);
                    for (a, &b) in words[..done / 2].iter_mut().zip(&xw) {
                        *a = mul_halves(*a, b);
                    }
                    for ((p, &a), &b) in pq.iter_mut().zip(mq.iter()).zip(xq.iter()).skip(done) {
                        *p = a as i16 * b as i16;
                    }
                    let words = &mw[..done / 2];
                    block(
                        q,
                        &scales,
                        cols,
                        f + c0,
                        &*pq,
                        words,
                        sm * sx,
                        &mut acc,
                        o,
                        dots,
                    );
                }
            }
        }
    }
    Ok(())
}

/// An input type of the integer kernels and the kernel that takes it: `i8` (quantised
/// activations, every kernel) or `i16` (the map layer's products of two quantised values:
/// the DSP kernel, whose `SMLAD` multiplies int16 halves, or the portable one).
trait Act: Copy + Into<i32> {
    fn dots(dots: Dots, q: &[u8], cols: usize, c0: usize, x: &[Self], xp: &[u32], acc: &mut [i32]);
}

impl Act for i8 {
    #[inline(always)]
    fn dots(dots: Dots, q: &[u8], cols: usize, c0: usize, x: &[i8], xp: &[u32], acc: &mut [i32]) {
        match dots {
            Dots::Portable => dots_i8(q, cols, c0, x, acc),
            // (No DSP target runs the row-blocked kernel: one kernel less in its image.)
            Dots::Rows if gman_dsp::HAS_DSP => dots_i8(q, cols, c0, x, acc),
            Dots::Rows => dots_i8_rows(q, cols, c0, x, acc),
            Dots::Dsp => dots_i8_dsp(q, cols, c0, x, xp, acc),
            Dots::Table(k) => k.dots_i8(q, cols, c0, x, acc),
        }
    }
}

impl Act for i16 {
    #[inline(always)]
    fn dots(dots: Dots, q: &[u8], cols: usize, c0: usize, x: &[i16], xp: &[u32], acc: &mut [i32]) {
        // A DSP target always runs the DSP form (the same integers; one kernel in its image).
        match dots {
            _ if gman_dsp::HAS_DSP => dots_i16_dsp(q, cols, c0, x, xp, acc),
            Dots::Dsp => dots_i16_dsp(q, cols, c0, x, xp, acc),
            Dots::Table(k) => k.dots_i16(q, cols, c0, x, acc),
            _ => dots_i16(q, cols, c0, x, acc),
        }
    }
}

/// One quantised input block against every row: accumulators [`QROWS`] rows at a time, then
/// `y_i += (acc_i as f32) * (s_x * s_i)`.
// Not inlined: one copy per input type in an image, shared by the drivers.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn block<T: Act>(
    q: &[u8],
    scales: &Scales<'_>,
    cols: usize,
    c0: usize,
    xq: &[T],
    xp: &[u32],
    sx: f32,
    acc: &mut [i32; QROWS],
    y: &mut [f32],
    dots: Dots,
) {
    for (r0, (qr, yr)) in q.chunks(QROWS * cols).zip(y.chunks_mut(QROWS)).enumerate() {
        let acc = &mut acc[..yr.len()];
        T::dots(dots, qr, cols, c0, xq, xp, acc);
        let first = r0 * QROWS;
        match scales {
            // The scales of these rows as one slice (`MatRef::i8` checked there is one per row).
            Scales::F32(s) => {
                for ((yi, &a), &si) in yr
                    .iter_mut()
                    .zip(acc.iter())
                    .zip(s.get(first..).unwrap_or(&[]))
                {
                    *yi += (a as f32) * (sx * si);
                }
            }
            Scales::Le(b) => {
                for ((yi, &a), si) in yr
                    .iter_mut()
                    .zip(acc.iter())
                    .zip(b.get(4 * first..).unwrap_or(&[]).chunks_exact(4))
                {
                    let si = f32::from_le_bytes([si[0], si[1], si[2], si[3]]);
                    *yi += (a as f32) * (sx * si);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
