//! Batched dense kernels: one matrix `W` against `n` vectors at once.
//!
//! A batch of `n` vectors is stored **batch-major**: vector `b` of a segment of length `len`
//! is `seg[b * len .. (b + 1) * len]`, so a batch of inputs given as segments is a list of
//! `n x len_s` row-major blocks (the same segment convention as [`crate::matrix`]).
//!
//! # Contract: the same bits as the batch-1 kernels
//! Every kernel here gives, for every vector `b` of the batch, exactly the bits the
//! corresponding batch-1 kernel of [`MatRef`] gives for that vector alone, and
//! [`outer_acc_batch`] gives exactly the bits of calling [`crate::matrix::outer_acc`] for
//! `b = 0, 1, .., n - 1` in that order. A batch is therefore a pure speed-up: results,
//! training runs and the host/device parity do not depend on how work is batched. The unit
//! tests below pin this contract against the batch-1 kernels.
//!
//! These are the reference implementations (a loop over the batch calling the batch-1
//! kernels); faster bodies keep the signatures and the contract.

use crate::error::{check_len, Result};
use crate::matrix::{outer_acc, MatRef};

/// Vector `b` of a batch-major block of vectors of length `len`.
#[inline]
fn row(block: &[f32], b: usize, len: usize) -> &[f32] {
    &block[b * len..(b + 1) * len]
}

/// Most segments a batched input may have (the layers use at most four).
pub const MAX_SEGS: usize = 8;

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
    let rows = w.rows();
    for b in 0..n {
        let mut segs: [&[f32]; MAX_SEGS] = [&[]; MAX_SEGS];
        for (s, (seg, &l)) in x.iter().zip(lens).enumerate() {
            segs[s] = row(seg, b, l);
        }
        w.matvec_acc(&segs[..x.len()], &mut y[b * rows..(b + 1) * rows])?;
    }
    Ok(())
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
    let rows = w.rows();
    for b in 0..n {
        let mut off = 0;
        for (seg, &l) in dx.iter_mut().zip(lens) {
            w.matvec_t_acc_cols(row(dy, b, rows), off, &mut seg[b * l..(b + 1) * l])?;
            off += l;
        }
    }
    Ok(())
}

/// `dW += alpha * sum_b dY[b] X[b]^T`, accumulated for `b = 0, 1, .., n - 1` in that order
/// (bit for bit as [`outer_acc`] called once per vector): the weight gradient of
/// `Y[b] = W X[b]` summed over the batch. `dy` is `n x rows` batch-major, `x` batch-major
/// segments with per-vector lengths `lens`.
pub fn outer_acc_batch(
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
    for b in 0..n {
        let mut segs: [&[f32]; MAX_SEGS] = [&[]; MAX_SEGS];
        for (s, (seg, &l)) in x.iter().zip(lens).enumerate() {
            segs[s] = row(seg, b, l);
        }
        outer_acc(dw, row(dy, b, rows), &segs[..x.len()], alpha)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matrix::MatRef;

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
}
