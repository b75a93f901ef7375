//! `dX += W^T dY` for a batch: the blocked body (tiles of `8 C` columns x `B` vectors, rows in
//! order).

use crate::error::{check_len, Result};
use crate::nn::batch::kind::with_kind;
use crate::nn::batch::kind::{ld8, Kind, LeK, F32K, I8K, M};
use crate::nn::matrix::{MatRef, Weights};

/// Rows per block of [`crate::nn::batch::matmul_t_acc_rows`] and of the hosts' `mt_seg`: the
/// row coefficients of a block are computed once into a small buffer on the stack.
pub(super) const MT_ROWS: usize = 64;

/// The shape check of the `dx += W^T dy` bodies: `dy` is `n x rows`, the segments of `dx`
/// (per-vector lengths `len / n`) fit in the columns from `col0`. `None` when there is
/// nothing to do (no vector or no column), else the row count.
#[inline(always)]
pub(super) fn check_t(
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

/// [`matmul_t_acc`](crate::nn::batch::matmul_t_acc) with an explicit block of `8 C` columns x `B` vectors, on the column
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
pub(super) fn mt_seg<K: Kind, const C: usize, const B: usize>(
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
pub(super) fn row_coef<K: Kind>(m: &M<'_, K>, i: usize, g: f32) -> f32 {
    match m.scales {
        None => g,
        Some(s) => g * s.get(i),
    }
}

/// The row coefficients ([`row_coef`]) of rows `r0 .. r0 + rb` (`rb <= MT_ROWS`) for
/// vectors `b0 .. b0 + B`.
#[inline(always)]
pub(super) fn mt_coefs<K: Kind, const B: usize>(
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
pub(super) fn mt_tile<K: Kind, const C: usize, const B: usize>(
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
