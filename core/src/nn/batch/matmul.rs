//! `Y += W X` for a batch: the register-blocked body (`R` rows x `B` vectors per tile).

use crate::error::{check_len, Result};
use crate::nn::batch::kind::with_kind;
use crate::nn::batch::kind::MAX_SEGS;
use crate::nn::batch::kind::{ld8, tree, Kind, LeK, F32K, I8K, M};
use crate::nn::matrix::{MatRef, Weights};

/// [`matmul_acc`](crate::nn::batch::matmul_acc) with an explicit block of `R` rows x `B` vectors (speed only; the same
/// bits for every shape). The shapes must already be checked (`x[s].len()` a multiple of
/// `n`, per-vector lengths adding up to `w.cols()`, `y` holding `n x w.rows()`); a kernel
/// table ([`Kernels`](crate::nn::matrix::Kernels)) on `w` is not consulted. `#[inline(always)]` so that a caller
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
pub(super) fn mm_all<K: Kind, const R: usize, const B: usize>(
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
pub(super) fn add_tails<K: Kind, const R: usize, const B: usize>(
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
pub(super) fn store_tile<K: Kind, const R: usize, const B: usize>(
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
pub(super) fn mm_tile<K: Kind, const R: usize, const B: usize>(
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
