//! A dense (fully connected) layer `pre = gain ⊙ (W x) + b`, forward and backward.
//!
//! The optional per-output `gain` is what makes the parameter-efficient adaptation mode
//! possible on a microcontroller: `W` stays int8 in flash and only `gain` (initialised to 1)
//! and `b` live in RAM and are adapted. Without a gain the layer is the ordinary `W x + b`
//! and, in the `Full` mode, `W` itself is an f32 tensor in RAM that adaptation updates.

use crate::error::{check_len, Result};
use crate::matrix::{outer_acc, seg_len, MatRef};

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

    /// Forward pass. `x` is the (segmented) input; `pre` receives `gain ⊙ (W x) + b`.
    /// When the layer has a gain, `u` must have `out` elements and receives `W x` (needed by
    /// the backward pass); otherwise `u` may be empty.
    pub fn forward(&self, x: &[&[f32]], u: &mut [f32], pre: &mut [f32]) -> Result<()> {
        self.validate()?;
        check_len("dense.pre", self.out_dim(), pre.len())?;
        match self.gain {
            None => {
                pre.copy_from_slice(self.b);
                self.w.matvec_acc(x, pre)
            }
            Some(g) => {
                check_len("dense.u", self.out_dim(), u.len())?;
                u.fill(0.0);
                self.w.matvec_acc(x, u)?;
                for (((p, &ui), &gi), &bi) in pre.iter_mut().zip(u.iter()).zip(g).zip(self.b) {
                    *p = gi * ui + bi;
                }
                Ok(())
            }
        }
    }

    /// Backward pass from `dpre = dL/dpre`.
    ///
    /// Accumulates the parameter gradients into `grads`, and, when `dx` is given, adds
    /// `dL/dx` into its segments. `u` is the `W x` saved by [`Dense::forward`] (only read
    /// for [`DenseGrads::Gain`]); `scratch` (length `out`) is used when the layer has a gain
    /// and `dx` is requested, to form `gain ⊙ dpre`.
    pub fn backward(
        &self,
        x: &[&[f32]],
        u: &[f32],
        dpre: &[f32],
        dx: Option<&mut [&mut [f32]]>,
        grads: &mut DenseGrads<'_>,
        scratch: &mut [f32],
    ) -> Result<()> {
        self.validate()?;
        check_len("dense.dpre", self.out_dim(), dpre.len())?;
        check_len("dense.x", self.in_dim(), seg_len(x))?;
        match grads {
            DenseGrads::None => {}
            DenseGrads::Full { w, b } => {
                check_len("dense.db", self.out_dim(), b.len())?;
                // With a gain, dL/d(Wx) = gain ⊙ dpre; W's gradient uses that.
                match self.gain {
                    None => outer_acc(w, dpre, x, 1.0)?,
                    Some(g) => {
                        check_len("dense.scratch", self.out_dim(), scratch.len())?;
                        for ((s, &d), &gi) in scratch.iter_mut().zip(dpre).zip(g) {
                            *s = d * gi;
                        }
                        outer_acc(w, scratch, x, 1.0)?;
                    }
                }
                for (bi, &d) in b.iter_mut().zip(dpre) {
                    *bi += d;
                }
            }
            DenseGrads::Gain { gain, b } => {
                check_len("dense.dgain", self.out_dim(), gain.len())?;
                check_len("dense.db", self.out_dim(), b.len())?;
                check_len("dense.u", self.out_dim(), u.len())?;
                for ((gg, &d), &ui) in gain.iter_mut().zip(dpre).zip(u) {
                    *gg += d * ui;
                }
                for (bi, &d) in b.iter_mut().zip(dpre) {
                    *bi += d;
                }
            }
        }
        if let Some(dx) = dx {
            match self.gain {
                None => self.w.matvec_t_acc(dpre, dx)?,
                Some(g) => {
                    check_len("dense.scratch", self.out_dim(), scratch.len())?;
                    for ((s, &d), &gi) in scratch.iter_mut().zip(dpre).zip(g) {
                        *s = d * gi;
                    }
                    self.w.matvec_t_acc(scratch, dx)?;
                }
            }
        }
        Ok(())
    }
}
