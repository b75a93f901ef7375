//! Symmetric per-row int8 quantisation of weight matrices.
//!
//! For each row `i`: `scale_i = max_j |w_ij| / 127` and `q_ij = round(w_ij / scale_i)` clamped
//! to `-127..=127`. Dequantisation is `scale_i * q_ij`, so every weight's error is at most
//! `scale_i / 2 = max_j |w_ij| / 254` (plus f32 rounding): the documented per-tensor bound is
//! `max |w - ŵ| <= max|w| / 254 * (1 + 1e-6)`, and the tests check it.

use crate::error::{check_len, Result};

/// Quantises a `rows x cols` f32 matrix into `q` (bytes holding `i8`) and `scales` (`rows`).
/// A row of zeros gets scale 0. Non-finite weights are the caller's error to avoid (the blob
/// writer rejects them); here they quantise to 0.
pub fn quantize_rows(
    w: &[f32],
    rows: usize,
    cols: usize,
    q: &mut [u8],
    scales: &mut [f32],
) -> Result<()> {
    check_len("quantize.w", rows.saturating_mul(cols), w.len())?;
    check_len("quantize.q", w.len(), q.len())?;
    check_len("quantize.scales", rows, scales.len())?;
    if cols == 0 {
        scales.fill(0.0);
        return Ok(());
    }
    for ((row, qrow), s) in w
        .chunks_exact(cols)
        .zip(q.chunks_exact_mut(cols))
        .zip(scales.iter_mut())
    {
        let mut m = 0.0f32;
        for &v in row {
            if v.is_finite() && libm::fabsf(v) > m {
                m = libm::fabsf(v);
            }
        }
        let scale = m / 127.0;
        *s = scale;
        for (qi, &v) in qrow.iter_mut().zip(row) {
            let r = if scale > 0.0 && v.is_finite() {
                libm::roundf(v / scale).clamp(-127.0, 127.0)
            } else {
                0.0
            };
            *qi = (r as i8) as u8;
        }
    }
    Ok(())
}

/// Dequantises `q`/`scales` back to f32 into `out`.
pub fn dequantize_rows(q: &[u8], scales: &[f32], cols: usize, out: &mut [f32]) -> Result<()> {
    check_len("dequantize.q", scales.len().saturating_mul(cols), q.len())?;
    check_len("dequantize.out", q.len(), out.len())?;
    if cols == 0 {
        return Ok(());
    }
    for ((qrow, orow), &s) in q
        .chunks_exact(cols)
        .zip(out.chunks_exact_mut(cols))
        .zip(scales)
    {
        for (o, &b) in orow.iter_mut().zip(qrow) {
            *o = (b as i8) as f32 * s;
        }
    }
    Ok(())
}
