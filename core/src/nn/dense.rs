//! A dense (fully connected) layer `pre = gain ⊙ (W x) + b`, forward and backward.
//!
//! The optional per-output `gain` is what makes the parameter-efficient adaptation mode
//! possible on a microcontroller: `W` stays int8 in flash and only `gain` (initialised to 1)
//! and `b` live in RAM and are adapted. Without a gain the layer is the ordinary `W x + b`
//! and, in the `Full` mode, `W` itself is an f32 tensor in RAM that adaptation updates.

use crate::error::{check_len, Result};
use crate::nn::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with, seg_lens};
use crate::nn::matrix::{seg_len, MatRef};

/// A read-only view of a dense layer.
#[derive(Clone, Copy, Debug)]
pub struct Dense<'a> {
    /// Weight matrix, `out x in`.
    pub w: MatRef<'a>,
    /// Bias, `out`.
    pub b: &'a [f32],
    /// Optional per-output gain, `out`.
    pub gain: Option<&'a [f32]>,
}

/// Where the gradients of a dense layer's parameters are accumulated (`+=`).
#[derive(Debug)]
pub enum DenseGrads<'g> {
    /// No parameter of this layer is trained.
    None,
    /// Gradients of `W` (`out x in`, row-major) and `b`.
    Full {
        /// dL/dW.
        w: &'g mut [f32],
        /// dL/db.
        b: &'g mut [f32],
    },
    /// Gradients of the per-output gain and of `b` (the base `W` is frozen).
    Gain {
        /// dL/dgain.
        gain: &'g mut [f32],
        /// dL/db.
        b: &'g mut [f32],
    },
}

/// `out = g u + b`, element by element: the step of a layer with a gain after `u = W x`
/// (also run by `Navigator::generate_batch`, which does `W x` for many navigators at once
/// and must give each the bits of [`Dense::forward`]).
pub(crate) fn gain_bias(out: &mut [f32], u: &[f32], g: &[f32], b: &[f32]) -> Result<()> {
    check_len("dense.gain_bias.u", out.len(), u.len())?;
    check_len("dense.gain_bias.g", out.len(), g.len())?;
    check_len("dense.gain_bias.b", out.len(), b.len())?;
    for (((o, &ui), &gi), &bi) in out.iter_mut().zip(u).zip(g).zip(b) {
        *o = gi * ui + bi;
    }
    Ok(())
}

impl<'a> Dense<'a> {
    /// Number of outputs.
    #[inline]
    pub fn out_dim(&self) -> usize {
        self.w.rows()
    }

    /// Number of inputs.
    #[inline]
    pub fn in_dim(&self) -> usize {
        self.w.cols()
    }

    /// Checks that `b` (and `gain`) match `W`'s rows.
    pub fn validate(&self) -> Result<()> {
        check_len("dense.b", self.w.rows(), self.b.len())?;
        if let Some(g) = self.gain {
            check_len("dense.gain", self.w.rows(), g.len())?;
        }
        Ok(())
    }

    /// Forward pass. `x` is the (segmented, at most [`crate::nn::batch::MAX_SEGS`] segments)
    /// input; `pre` receives `gain ⊙ (W x) + b`. When the layer has a gain, `u` must have
    /// `out` elements and receives `W x` (needed by the backward pass); otherwise `u` may be
    /// empty. [`Dense::forward_batch`] with a batch of one.
    pub fn forward(&self, x: &[&[f32]], u: &mut [f32], pre: &mut [f32]) -> Result<()> {
        let lens = seg_lens(x.iter().map(|s| s.len()))?;
        self.forward_batch(x, &lens[..x.len()], 1, u, pre)
    }

    /// Backward pass from `dpre = dL/dpre`.
    ///
    /// Accumulates the parameter gradients into `grads`, and, when `dx` is given, adds
    /// `dL/dx` into its segments. `u` is the `W x` saved by [`Dense::forward`] (only read
    /// for [`DenseGrads::Gain`]); `scratch` (length `out`) is used when the layer has a gain
    /// and `dx` is requested, to form `gain ⊙ dpre`. [`Dense::backward_batch`] with a batch
    /// of one.
    pub fn backward(
        &self,
        x: &[&[f32]],
        u: &[f32],
        dpre: &[f32],
        dx: Option<&mut [&mut [f32]]>,
        grads: &mut DenseGrads<'_>,
        scratch: &mut [f32],
    ) -> Result<()> {
        check_len("dense.x", self.in_dim(), seg_len(x))?;
        let lens = seg_lens(x.iter().map(|s| s.len()))?;
        match dx {
            None => self.backward_batch(x, &lens[..x.len()], 1, u, dpre, None, grads, scratch),
            Some(dx) => {
                let dlens = seg_lens(dx.iter().map(|s| s.len()))?;
                let nd = dx.len();
                let dx = Some((dx, &dlens[..nd]));
                self.backward_batch(x, &lens[..x.len()], 1, u, dpre, dx, grads, scratch)
            }
        }
    }
}

/// The input gradient requested from [`Dense::backward_batch`]: batch-major segments and
/// their per-vector lengths.
pub type BatchDx<'s, 'x> = (&'s mut [&'x mut [f32]], &'s [usize]);

impl<'a> Dense<'a> {
    /// [`Dense::forward`] over a batch of `n` inputs (batch-major segments `x` with per-vector
    /// lengths `lens`, see [`crate::nn::batch`]): `pre` (`n x out`) and, with a gain, `u`
    /// (`n x out`) receive for every vector exactly the bits [`Dense::forward`] gives it.
    pub fn forward_batch(
        &self,
        x: &[&[f32]],
        lens: &[usize],
        n: usize,
        u: &mut [f32],
        pre: &mut [f32],
    ) -> Result<()> {
        self.validate()?;
        let o = self.out_dim();
        check_len("dense.pre", n.saturating_mul(o), pre.len())?;
        if o == 0 {
            return Ok(());
        }
        match self.gain {
            None => {
                for p in pre.chunks_exact_mut(o) {
                    p.copy_from_slice(self.b);
                }
                matmul_acc(&self.w, x, lens, n, pre)
            }
            Some(g) => {
                check_len("dense.u", n.saturating_mul(o), u.len())?;
                u.fill(0.0);
                matmul_acc(&self.w, x, lens, n, u)?;
                for (p, ur) in pre.chunks_exact_mut(o).zip(u.chunks_exact(o)) {
                    gain_bias(p, ur, g, self.b)?;
                }
                Ok(())
            }
        }
    }

    /// [`Dense::backward`] over a batch of `n` vectors: `dpre` and `u` are `n x out`, `x` are
    /// batch-major segments with per-vector lengths `lens`, `dx` (if given) batch-major
    /// segments with their lengths, `scratch` `n x out` (used with a gain). The parameter
    /// gradients are accumulated for `b = 0, 1, .., n - 1` in that order, so the result is
    /// bit for bit that of calling [`Dense::backward`] for each vector in batch order.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_batch(
        &self,
        x: &[&[f32]],
        lens: &[usize],
        n: usize,
        u: &[f32],
        dpre: &[f32],
        dx: Option<BatchDx<'_, '_>>,
        grads: &mut DenseGrads<'_>,
        scratch: &mut [f32],
    ) -> Result<()> {
        self.validate()?;
        let o = self.out_dim();
        check_len("dense.dpre", n.saturating_mul(o), dpre.len())?;
        if n == 0 || o == 0 {
            return Ok(());
        }
        // gain ⊙ dpre, when the layer has a gain and something needs it.
        let scaled = |scratch: &mut [f32], g: &[f32]| -> Result<()> {
            check_len("dense.scratch", n.saturating_mul(o), scratch.len())?;
            for (s, d) in scratch.chunks_exact_mut(o).zip(dpre.chunks_exact(o)) {
                for ((s, &d), &gi) in s.iter_mut().zip(d).zip(g) {
                    *s = d * gi;
                }
            }
            Ok(())
        };
        match grads {
            DenseGrads::None => {}
            DenseGrads::Full { w, b } => {
                check_len("dense.db", o, b.len())?;
                match self.gain {
                    None => outer_acc_batch_with(self.w.kernels(), w, dpre, x, lens, n, 1.0)?,
                    Some(g) => {
                        scaled(scratch, g)?;
                        outer_acc_batch_with(self.w.kernels(), w, scratch, x, lens, n, 1.0)?;
                    }
                }
                for d in dpre.chunks_exact(o) {
                    for (bi, &d) in b.iter_mut().zip(d) {
                        *bi += d;
                    }
                }
            }
            DenseGrads::Gain { gain, b } => {
                check_len("dense.dgain", o, gain.len())?;
                check_len("dense.db", o, b.len())?;
                check_len("dense.u", n.saturating_mul(o), u.len())?;
                for (d, ur) in dpre.chunks_exact(o).zip(u.chunks_exact(o)) {
                    for ((gg, &d), &ui) in gain.iter_mut().zip(d).zip(ur) {
                        *gg += d * ui;
                    }
                    for (bi, &d) in b.iter_mut().zip(d) {
                        *bi += d;
                    }
                }
            }
        }
        if let Some((dx, dx_lens)) = dx {
            match self.gain {
                None => matmul_t_acc(&self.w, dpre, n, dx, dx_lens)?,
                Some(g) => {
                    scaled(scratch, g)?;
                    matmul_t_acc(&self.w, scratch, n, dx, dx_lens)?;
                }
            }
        }
        Ok(())
    }
}
