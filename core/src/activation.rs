//! Element-wise activations and softmax, forward and backward.
//!
//! All transcendental functions come from `libm`, never from the platform, so host and
//! microcontroller builds compute the same bits.

use crate::error::{check_len, Result};

/// Negative slope of every LeakyReLU in GMAN (G's and D's hidden layers, paper Sec. 5.1).
pub const LEAKY_SLOPE: f32 = 0.2;

/// LeakyReLU(0.2).
#[inline]
pub fn leaky_relu(x: f32) -> f32 {
    if x > 0.0 {
        x
    } else {
        LEAKY_SLOPE * x
    }
}

/// Derivative of LeakyReLU(0.2), from the pre-activation *or* the output (same sign).
#[inline]
pub fn leaky_relu_grad(x: f32) -> f32 {
    if x > 0.0 {
        1.0
    } else {
        LEAKY_SLOPE
    }
}

/// Numerically stable logistic sigmoid.
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + libm::expf(-x))
    } else {
        let e = libm::expf(x);
        e / (1.0 + e)
    }
}

/// Hyperbolic tangent.
#[inline]
pub fn tanh(x: f32) -> f32 {
    libm::tanhf(x)
}

/// In-place LeakyReLU over a slice.
pub fn leaky_relu_inplace(x: &mut [f32]) {
    for v in x {
        *v = leaky_relu(*v);
    }
}

/// In-place sigmoid over a slice.
pub fn sigmoid_inplace(x: &mut [f32]) {
    for v in x {
        *v = sigmoid(*v);
    }
}

/// `dpre = dout * LeakyReLU'(out)` given the activation's *output* `out`
/// (its sign equals the pre-activation's, so the output suffices).
pub fn leaky_relu_backward(out: &[f32], dout: &[f32], dpre: &mut [f32]) -> Result<()> {
    check_len("leaky_relu_backward.dout", out.len(), dout.len())?;
    check_len("leaky_relu_backward.dpre", out.len(), dpre.len())?;
    for ((d, &o), &g) in dpre.iter_mut().zip(out).zip(dout) {
        *d = g * leaky_relu_grad(o);
    }
    Ok(())
}

/// `dpre = dout * y (1 - y)` given the sigmoid's output `y`.
pub fn sigmoid_backward(y: &[f32], dout: &[f32], dpre: &mut [f32]) -> Result<()> {
    check_len("sigmoid_backward.dout", y.len(), dout.len())?;
    check_len("sigmoid_backward.dpre", y.len(), dpre.len())?;
    for ((d, &yi), &g) in dpre.iter_mut().zip(y).zip(dout) {
        *d = g * yi * (1.0 - yi);
    }
    Ok(())
}

/// Numerically stable softmax: `probs = exp(l - max l) / sum`.
/// A non-finite logit yields non-finite probabilities; callers that must not act on NaN
/// check the result (the navigator does).
pub fn softmax(logits: &[f32], probs: &mut [f32]) -> Result<()> {
    check_len("softmax.probs", logits.len(), probs.len())?;
    let mut m = f32::NEG_INFINITY;
    for &l in logits {
        if l > m {
            m = l;
        }
    }
    let mut s = 0.0f32;
    for (p, &l) in probs.iter_mut().zip(logits) {
        *p = libm::expf(l - m);
        s += *p;
    }
    let inv = 1.0 / s;
    for p in probs.iter_mut() {
        *p *= inv;
    }
    Ok(())
}

/// Natural log of the softmax, stable: `logp_i = l_i - max - ln(sum exp(l - max))`.
pub fn log_softmax(logits: &[f32], logp: &mut [f32]) -> Result<()> {
    check_len("log_softmax.logp", logits.len(), logp.len())?;
    let mut m = f32::NEG_INFINITY;
    for &l in logits {
        if l > m {
            m = l;
        }
    }
    let mut s = 0.0f32;
    for &l in logits {
        s += libm::expf(l - m);
    }
    let lse = m + libm::logf(s);
    for (o, &l) in logp.iter_mut().zip(logits) {
        *o = l - lse;
    }
    Ok(())
}

/// Backward of softmax: `dlogits_i = p_i (dp_i - sum_j p_j dp_j)`.
pub fn softmax_backward(probs: &[f32], dprobs: &[f32], dlogits: &mut [f32]) -> Result<()> {
    check_len("softmax_backward.dprobs", probs.len(), dprobs.len())?;
    check_len("softmax_backward.dlogits", probs.len(), dlogits.len())?;
    let mut s = 0.0f32;
    for (&p, &g) in probs.iter().zip(dprobs) {
        s += p * g;
    }
    for ((d, &p), &g) in dlogits.iter_mut().zip(probs).zip(dprobs) {
        *d = p * (g - s);
    }
    Ok(())
}

/// True when every value is finite.
#[inline]
pub fn all_finite(x: &[f32]) -> bool {
    x.iter().all(|v| v.is_finite())
}
