//! The feature generator G(SE(y), z) of the paper (Sec. 4.1), parameters θ.
//!
//! ```text
//! x = σ( W2 · LeakyReLU_0.2( W1 · [z; SE(y)] + b1 ) + b2 )
//! ```
//!
//! `W1` is `H x (Z + A)` with the noise columns first (as the reference concatenates
//! `(noise, attribute)`), `W2` is `F x H`; the sigmoid keeps generated features in `(0, 1)`
//! like the observation embeddings they imitate. Each layer may carry a per-unit gain (see
//! [`crate::nn::dense`]) for the parameter-efficient adaptation mode.

use crate::error::{check_len, Result};
use crate::nn::activation::{
    leaky_relu_backward, leaky_relu_inplace, sigmoid_backward, sigmoid_inplace,
};
use crate::nn::dense::{Dense, DenseGrads};

/// A read-only view of G.
#[derive(Clone, Copy, Debug)]
pub struct Generator<'a> {
    /// Hidden layer, `H x (Z + A)`.
    pub l1: Dense<'a>,
    /// Output layer, `F x H`.
    pub l2: Dense<'a>,
}

/// Activations of one forward pass of G, kept for the backward pass.
#[derive(Debug)]
pub struct GeneratorCache<'a> {
    /// `W1 [z; a]` before the gain (`H`; may be empty when layer 1 has no gain).
    pub u1: &'a mut [f32],
    /// Hidden activation after LeakyReLU (`H`).
    pub h1: &'a mut [f32],
    /// `W2 h1` before the gain (`F`; may be empty when layer 2 has no gain).
    pub u2: &'a mut [f32],
    /// The generated feature x (`F`).
    pub x: &'a mut [f32],
}

/// Scratch space of the backward pass of G.
#[derive(Debug)]
pub struct GeneratorScratch<'a> {
    /// `F` floats.
    pub dpre2: &'a mut [f32],
    /// `H` floats.
    pub dh1: &'a mut [f32],
    /// `H` floats.
    pub dpre1: &'a mut [f32],
    /// `max(F, H)` floats.
    pub tmp: &'a mut [f32],
}

impl<'a> Generator<'a> {
    /// Noise width Z + attribute width A.
    #[inline]
    pub fn in_dim(&self) -> usize {
        self.l1.in_dim()
    }

    /// Hidden width H.
    #[inline]
    pub fn hidden(&self) -> usize {
        self.l1.out_dim()
    }

    /// Feature width F.
    #[inline]
    pub fn feat(&self) -> usize {
        self.l2.out_dim()
    }

    /// Checks the layers against each other.
    pub fn validate(&self) -> Result<()> {
        self.l1.validate()?;
        self.l2.validate()?;
        check_len("generator.l2.in", self.hidden(), self.l2.in_dim())
    }

    /// x = G(attr, z); activations go to `cache`, the feature to `cache.x`.
    pub fn forward(&self, z: &[f32], attr: &[f32], cache: &mut GeneratorCache<'_>) -> Result<()> {
        self.validate()?;
        check_len("generator.z+attr", self.in_dim(), z.len() + attr.len())?;
        self.l1.forward(&[z, attr], cache.u1, cache.h1)?;
        leaky_relu_inplace(cache.h1);
        self.l2.forward(&[cache.h1], cache.u2, cache.x)?;
        sigmoid_inplace(cache.x);
        Ok(())
    }

    /// Backward from `dx = dL/dx`, accumulating into the parameter gradients of each layer.
    /// `cache` must hold the forward pass of the same `(z, attr)`.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        z: &[f32],
        attr: &[f32],
        cache: &GeneratorCache<'_>,
        dx: &[f32],
        grads1: &mut DenseGrads<'_>,
        grads2: &mut DenseGrads<'_>,
        s: &mut GeneratorScratch<'_>,
    ) -> Result<()> {
        self.validate()?;
        let (h, f) = (self.hidden(), self.feat());
        check_len("generator.dx", f, dx.len())?;
        check_len("generator.scratch.dh1", h, s.dh1.len())?;
        if s.tmp.len() < h.max(f) {
            check_len("generator.scratch.tmp", h.max(f), s.tmp.len())?;
        }
        sigmoid_backward(cache.x, dx, s.dpre2)?;
        s.dh1.fill(0.0);
        self.l2.backward(
            &[cache.h1],
            cache.u2,
            s.dpre2,
            Some(&mut [&mut *s.dh1]),
            grads2,
            &mut s.tmp[..f],
        )?;
        leaky_relu_backward(cache.h1, s.dh1, s.dpre1)?;
        self.l1
            .backward(&[z, attr], cache.u1, s.dpre1, None, grads1, &mut s.tmp[..h])
    }
}
