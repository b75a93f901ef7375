//! A batched column-block kernel next to [`crate::nn::batch`]: the input gradient of one column
//! block of `W` for a batch of vectors, with the same contract (every vector of the batch gets
//! exactly the bits of the batch-1 kernel, [`MatRef::matvec_t_acc_cols`]).
//!
//! Reference body (a loop over the batch); a faster body keeps the signature and contract.

use crate::error::{check_len, Result};
use crate::nn::matrix::MatRef;

/// `dX[b] += (W[:, col0 .. col0 + len])^T dY[b]` for `b in 0..n`: `dy` is `n x W.rows()`
/// batch-major, `dx` is `n x len` batch-major.
pub fn matmul_t_acc_cols(
    w: &MatRef<'_>,
    dy: &[f32],
    n: usize,
    col0: usize,
    dx: &mut [f32],
    len: usize,
) -> Result<()> {
    let rows = w.rows();
    check_len("matmul_t_cols.dy", n.saturating_mul(rows), dy.len())?;
    check_len("matmul_t_cols.dx", n.saturating_mul(len), dx.len())?;
    if len == 0 || rows == 0 {
        // Still check the column range like the batch-1 kernel does.
        return if n == 0 {
            Ok(())
        } else {
            w.matvec_t_acc_cols(&dy[..rows], col0, &mut dx[..0])
        };
    }
    for (g, d) in dy.chunks_exact(rows).zip(dx.chunks_exact_mut(len)) {
        w.matvec_t_acc_cols(g, col0, d)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_batch1_bit_for_bit() {
        let wv: [f32; 24] = core::array::from_fn(|i| (i as f32 * 0.37).sin());
        let w = MatRef::f32(4, 6, &wv).unwrap();
        let dy: [f32; 12] = core::array::from_fn(|i| (i as f32 * 1.3).cos());
        let mut dx: [f32; 6] = core::array::from_fn(|i| i as f32 * 0.1);
        let mut want = dx;
        matmul_t_acc_cols(&w, &dy, 3, 2, &mut dx, 2).unwrap();
        for b in 0..3 {
            w.matvec_t_acc_cols(&dy[b * 4..b * 4 + 4], 2, &mut want[b * 2..b * 2 + 2])
                .unwrap();
        }
        for i in 0..6 {
            assert_eq!(dx[i].to_bits(), want[i].to_bits());
        }
        // a block past the last column is an error
        assert!(matmul_t_acc_cols(&w, &dy, 3, 5, &mut dx, 2).is_err());
        assert!(matmul_t_acc_cols(&w, &dy[..8], 3, 0, &mut dx, 2).is_err());
    }
}
