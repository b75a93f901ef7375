//! The two forms of Eq. 3's loss from the scores of the buffer's generated features, and the
//! cosine score of the CosSim variant: the pure loss maths under [`crate::adapt`] (its
//! batch-1 gradients) and [`crate::adapt::inner`] (the batched passes), which both use it; re-exported
//! from [`crate::adapt`].

use crate::error::{check_len, Result};
use crate::nn::matrix::dot;
use crate::NUM_ACTIONS;

pub use crate::spec::schema::AdaptLossKind;

/// L_ad from the discriminator scores `d` (`n`) and action probabilities `probs` (`n x 6`).
/// Writes `∂L/∂d_t` into `dd` (`n`) and `∂L/∂a_t` into `dprobs` (`n x 6`).
pub fn adapt_loss(
    kind: AdaptLossKind,
    d: &[f32],
    probs: &[f32],
    dd: &mut [f32],
    dprobs: &mut [f32],
) -> Result<f32> {
    let n = d.len();
    check_len("adapt.probs", n * NUM_ACTIONS, probs.len())?;
    check_len("adapt.dd", n, dd.len())?;
    check_len("adapt.dprobs", n * NUM_ACTIONS, dprobs.len())?;
    if n == 0 {
        return Ok(0.0);
    }
    match kind {
        AdaptLossKind::Paper => {
            let inv = 1.0 / n as f32;
            let mut loss = 0.0;
            for t in 0..n {
                let a = &probs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS];
                let norm = libm::sqrtf(dot(a, a));
                loss -= d[t] * norm * inv;
                dd[t] = -norm * inv;
                let da = &mut dprobs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS];
                let coef = if norm > 0.0 { -d[t] * inv / norm } else { 0.0 };
                for (o, &ai) in da.iter_mut().zip(a) {
                    *o = coef * ai;
                }
            }
            Ok(loss)
        }
        AdaptLossKind::Reference => {
            let mut v = [0.0f32; NUM_ACTIONS];
            for t in 0..n {
                for (vi, &ai) in v
                    .iter_mut()
                    .zip(&probs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS])
                {
                    *vi -= ai * d[t];
                }
            }
            let norm = libm::sqrtf(dot(&v, &v));
            let mut u = [0.0f32; NUM_ACTIONS];
            if norm > 0.0 {
                for (ui, &vi) in u.iter_mut().zip(&v) {
                    *ui = vi / norm;
                }
            }
            for t in 0..n {
                let a = &probs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS];
                dd[t] = -dot(a, &u);
                for (o, &ui) in dprobs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS]
                    .iter_mut()
                    .zip(&u)
                {
                    *o = -d[t] * ui;
                }
            }
            Ok(norm)
        }
    }
}

/// `cos(x, s)`; when `dx` is given, writes `∂cos/∂x = s / (‖x‖‖s‖) − cos · x / ‖x‖²` into it.
/// A zero vector has similarity 0 and gradient 0.
pub fn cosine(x: &[f32], s: &[f32], dx: Option<&mut [f32]>) -> Result<f32> {
    check_len("cosine.s", x.len(), s.len())?;
    let nx = libm::sqrtf(dot(x, x));
    let ns = libm::sqrtf(dot(s, s));
    if nx == 0.0 || ns == 0.0 {
        if let Some(d) = dx {
            d.fill(0.0);
        }
        return Ok(0.0);
    }
    let c = dot(x, s) / (nx * ns);
    if let Some(d) = dx {
        check_len("cosine.dx", x.len(), d.len())?;
        let a = 1.0 / (nx * ns);
        let b = c / (nx * nx);
        for ((o, &xi), &si) in d.iter_mut().zip(x).zip(s) {
            *o = a * si - b * xi;
        }
    }
    Ok(c)
}
