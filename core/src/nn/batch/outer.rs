//! `dW += alpha dY X^T` for a batch: the blocked body (tiles of `R` rows x `8 C` columns, vectors
//! in order).

use crate::error::{check_len, Result};
use crate::nn::batch::kind::ld8;
use crate::nn::batch::kind::MAX_SEGS;

/// [`outer_acc_batch`](crate::nn::batch::outer_acc_batch) with an explicit block of `R` rows x `8 C` columns (speed only; the
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
pub(super) fn op_tile<const R: usize, const C: usize>(
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
