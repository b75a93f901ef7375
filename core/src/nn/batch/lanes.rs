//! The bodies with fewer registers (the Cortex-M4F's): accumulators run a few lanes at a time,
//! and the batch-1 loops two rows at a time or by blocks of rows, in the same canonical order.

use crate::error::{check_len, Result};
use crate::nn::batch::kind::MAX_SEGS;
use crate::nn::batch::kind::{ld8, tree, Kind, I8K, M};
use crate::nn::batch::matmul::{add_tails, store_tile};
use crate::nn::batch::matmul_t::{check_t, row_coef, MT_ROWS};
use crate::nn::matrix::{seg_len, MatRef, Weights};

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
pub(super) fn ml_tile<K: Kind, const R: usize, const B: usize, const L: usize>(
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
pub(super) fn mv_pair<K: Kind, const R: usize>(
    m: &M<'_, K>,
    x: &[&[f32]],
    r0: usize,
    y: &mut [f32],
) {
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
pub(super) fn ldl<const L: usize>(s: &[f32], j: usize) -> [f32; L] {
    let s = &s[j..j + L];
    core::array::from_fn(|k| s[k])
}

/// Vectors per pass of [`matmul_t_acc_rows`] (its coefficient buffer holds this many).
pub(super) const MT_MAXB: usize = 2;

/// `dX[b] += W^T dY[b]` (on the column block of `w` starting at `col0`, as
/// [`matmul_t_acc_blocked`](crate::nn::batch::matmul_t_acc_blocked)) with tiles of 8 columns x `B` vectors (`B <= 2`), rows in order:
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
pub(super) fn mr_seg<K: Kind, const B: usize>(
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
